//! The `edgepoint-worker` command line. It lives in the library so that the deploy tests can
//! parse the container arguments of the compose file and the Kubernetes manifests with the
//! very parser the binary uses.
use clap::Parser;
use std::path::PathBuf;

/// Default address of a worker: loopback only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:50061";

/// edgepoint shader worker: shades batches of ray requests for the renderer over gRPC.
///
/// Listens on 127.0.0.1 unless told otherwise. Any other address needs the renderer to
/// authenticate — a shared token (--token-file here, --worker-token-file on the renderer) or
/// mutual TLS (--tls-client-ca here, --worker-tls-cert/--worker-tls-key there) — and TLS
/// (--tls-cert/--tls-key) unless --insecure (plaintext, for a private network, e.g. a
/// Kubernetes pod network restricted by a NetworkPolicy). On SIGTERM it finishes the batches
/// it is shading, ends its streams (the renderer re-issues whatever was still queued) and exits.
#[derive(Parser, Debug, Clone)]
#[command(name = "edgepoint-worker", version, after_help = edgepoint_proto::shaders::help_text())]
pub struct WorkerArgs {
    /// Address to listen on (port 0 picks a free port; the bound address is printed on
    /// stdout as `listening <addr>`).
    #[arg(long, value_name = "ADDR", default_value = DEFAULT_LISTEN)]
    pub listen: String,
    /// Shading threads (default: all cores).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub threads: Option<u32>,
    /// Scenes kept loaded (least recently used ones are dropped first).
    #[arg(long, value_name = "N", default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub scene_cache: u32,
    /// Largest gRPC message accepted or sent, in MiB (scenes travel as bytes).
    #[arg(long, value_name = "MIB", default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=2047))]
    pub max_message_mib: u32,
    /// PEM certificate chain for TLS (with --tls-key).
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key of --tls-cert.
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// File of accepted renderer tokens, one per line (`#` comments; several lines let old
    /// and new overlap while rotating). Every call must carry `authorization: Bearer <token>`
    /// (the renderer's --worker-token-file), else it is refused with UNAUTHENTICATED; the
    /// health service stays open for probes.
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// PEM CA certificate(s): require the renderer to present a client certificate signed by
    /// them (mutual TLS; needs --tls-cert/--tls-key).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_client_ca: Option<PathBuf>,
    /// Allow listening on a non-loopback address without TLS (only on a network you trust;
    /// the renderer must still authenticate).
    #[arg(long)]
    pub insecure: bool,
    /// Serve Prometheus metrics at http://ADDR/metrics (e.g. 127.0.0.1:9465; port 0 picks
    /// one, printed on stdout as `metrics <addr>`). Off unless given.
    #[arg(long, value_name = "ADDR")]
    pub metrics_listen: Option<String>,
    /// Allow --metrics-listen on a non-loopback address (the endpoint is plain HTTP without
    /// authentication).
    #[arg(long, requires = "metrics_listen")]
    pub metrics_public: bool,
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_consistent() {
        WorkerArgs::command().debug_assert();
        let a = WorkerArgs::try_parse_from(["edgepoint-worker"]).unwrap();
        assert_eq!((a.listen.as_str(), a.threads, a.insecure), (DEFAULT_LISTEN, None, false));
        assert!(WorkerArgs::try_parse_from(["edgepoint-worker", "--threads", "0"]).is_err());
        assert!(WorkerArgs::try_parse_from(["edgepoint-worker", "--tls-key", "k.pem"]).is_err());
    }
}
