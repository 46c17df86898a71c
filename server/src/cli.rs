//! The `edgepoint-server` command line. It lives in the library so that the deploy tests can
//! parse the container arguments of the compose file and the Kubernetes manifests with the
//! very parser the binary uses.
use crate::service::{DEFAULT_MAX_FRAME_PIXELS, DEFAULT_START_TIMEOUT};
use crate::session::DEFAULT_POINTS_PER_PIXEL;
use clap::Parser;
use std::path::PathBuf;

/// Default address of the renderer: loopback only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:50051";

/// The edgepoint renderer: edge-and-point rendering sessions over gRPC, shading on remote
/// shader workers.
///
/// Workers come from --worker (fixed), --worker-dns (a name whose A/AAAA records are the
/// workers, re-resolved every --discovery-interval-ms: the Kubernetes headless-Service
/// pattern) and --workers-file (re-read as often); they may join and leave while sessions
/// run. The server listens on 127.0.0.1 unless told otherwise; any other address needs TLS
/// (--tls-cert/--tls-key) and viewer tokens (--token-file), or an explicit --insecure.
#[derive(Parser, Debug, Clone)]
#[command(name = "edgepoint-server", version, after_help = edgepoint_proto::shaders::help_text())]
pub struct ServerArgs {
    /// Address to listen on (host:port; port 0 picks a free port). The bound address is
    /// printed on stdout as `listening <addr>`.
    #[arg(long, value_name = "ADDR", default_value = DEFAULT_LISTEN)]
    pub listen: String,

    /// A shader worker: `http://host:port`, `https://host:port` or `host:port`. Repeat the
    /// flag for several workers.
    #[arg(long = "worker", value_name = "URL")]
    pub workers: Vec<String>,

    /// A DNS name whose A/AAAA records are shader workers, `[http[s]://]host:port`, resolved
    /// again every --discovery-interval-ms (e.g. a Kubernetes headless Service:
    /// edgepoint-worker.edgepoint.svc.cluster.local:50061). Repeatable.
    #[arg(long = "worker-dns", value_name = "HOST:PORT")]
    pub worker_dns: Vec<String>,

    /// A file listing shader workers, one address per line (`#` comments), read again every
    /// --discovery-interval-ms. Replace it atomically (write, then rename).
    #[arg(long, value_name = "FILE")]
    pub workers_file: Option<PathBuf>,

    /// How often --worker-dns names are resolved and --workers-file is read, in ms.
    #[arg(long, value_name = "MS", default_value_t = 1000, value_parser = clap::value_parser!(u64).range(50..=3_600_000))]
    pub discovery_interval_ms: u64,

    /// PEM CA certificate(s) to verify `https://` workers with (default: the web PKI roots).
    #[arg(long, value_name = "FILE")]
    pub worker_tls_ca: Option<PathBuf>,

    /// Name the `https://` workers' certificates must carry (default: the name in their
    /// address, or the --worker-dns name).
    #[arg(long, value_name = "NAME")]
    pub worker_tls_domain: Option<String>,

    /// File holding the token sent to the workers on every call (its first token line;
    /// the workers accept it with their --token-file). Workers beyond loopback require it
    /// or mutual TLS.
    #[arg(long, value_name = "FILE")]
    pub worker_token_file: Option<PathBuf>,

    /// PEM certificate chain presented to `https://` workers started with --tls-client-ca
    /// (mutual TLS; with --worker-tls-key).
    #[arg(long, value_name = "FILE", requires = "worker_tls_key")]
    pub worker_tls_cert: Option<PathBuf>,

    /// PEM private key of --worker-tls-cert.
    #[arg(long, value_name = "FILE", requires = "worker_tls_cert")]
    pub worker_tls_key: Option<PathBuf>,

    /// Most render sessions (viewers) served at once; further ones get RESOURCE_EXHAUSTED.
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub max_sessions: u32,

    /// Largest gRPC message in MiB, to and from viewers and workers (a scene travels as the
    /// bytes of its files in one message). Larger ones are refused with OUT_OF_RANGE.
    #[arg(long, value_name = "MIB", default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=2047))]
    pub max_message_mib: u32,

    /// Largest frame a viewer may ask for, in pixels (width x height); larger ones are
    /// refused with RESOURCE_EXHAUSTED.
    #[arg(long, value_name = "PIXELS", default_value_t = DEFAULT_MAX_FRAME_PIXELS, value_parser = clap::value_parser!(u64).range(1..=(1u64 << 28)))]
    pub max_frame_pixels: u64,

    /// Memory all sessions together may take, in MiB (default: half of the machine's
    /// memory, or of the container's limit when that is smaller). Each session's need is estimated at `start` from its image size (its
    /// Render Cache, edge-and-point image and buffers: about 360 bytes per pixel with the
    /// default --points-per-pixel 2); a session that does not fit in what is left is refused
    /// with RESOURCE_EXHAUSTED, and so is a settings change that would outgrow it.
    #[arg(long, value_name = "MIB", value_parser = clap::value_parser!(u64).range(16..=(1u64 << 40)))]
    pub max_memory_mib: Option<u64>,

    /// Seconds a viewer has to send `start` after opening a session (else DEADLINE_EXCEEDED).
    #[arg(long, value_name = "S", default_value_t = DEFAULT_START_TIMEOUT.as_secs(), value_parser = clap::value_parser!(u64).range(1..=3600))]
    pub start_timeout_secs: u64,

    /// Render Cache size per session, in cached points per image pixel.
    #[arg(long, value_name = "RATIO", default_value_t = DEFAULT_POINTS_PER_PIXEL)]
    pub points_per_pixel: f32,

    /// PEM certificate chain for TLS on the viewer port (with --tls-key).
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,

    /// PEM private key of --tls-cert.
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,

    /// File of accepted viewer tokens, one per line (`#` comments; several lines let old and
    /// new tokens overlap while rotating). Viewers send `authorization: Bearer <token>`;
    /// without a valid one a session is refused with UNAUTHENTICATED.
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,

    /// Allow listening on a non-loopback address without TLS or without tokens (only on a
    /// network you trust).
    #[arg(long)]
    pub insecure: bool,

    /// Serve Prometheus metrics at http://ADDR/metrics (e.g. 127.0.0.1:9464; port 0 picks
    /// one, printed on stdout as `metrics <addr>`). Off unless given.
    #[arg(long, value_name = "ADDR")]
    pub metrics_listen: Option<String>,

    /// Serve the browser viewer at http://ADDR/ (https:// with --tls-cert): a page with a
    /// live WebSocket connection that drives sessions like a gRPC viewer, under the same
    /// rules (loopback unless TLS and --token-file, or --insecure; the same limits). Port 0
    /// picks one; the page's URL is printed on stdout as `web <url>` before `listening`.
    #[arg(long, value_name = "ADDR")]
    pub web_listen: Option<String>,

    /// Allow --metrics-listen on a non-loopback address (the endpoint is plain HTTP without
    /// authentication and names the workers' addresses).
    #[arg(long, requires = "metrics_listen")]
    pub metrics_public: bool,

    /// Target shading time of one batch sent to a worker, in ms: a worker's batch size
    /// follows its measured rate so a batch holds about this much work (slow workers get
    /// smaller batches).
    #[arg(long, value_name = "MS", default_value_t = 25, value_parser = clap::value_parser!(u64).range(1..=60_000))]
    pub target_batch_ms: u64,

    /// A worker with batches in flight that answers nothing for a few round trips, and at
    /// least this many ms, counts as stalled: its batches go to the other workers.
    #[arg(long, value_name = "MS", default_value_t = 1000, value_parser = clap::value_parser!(u64).range(100..=600_000))]
    pub worker_stall_ms: u64,

    /// Several lights (paper 003): leave out of every session's edge-and-point image the
    /// shadow edges that other lights wash out — those whose estimated relative L2 error of
    /// leaving them out is below this (0.05: a step of 5 % of the total light). 0 (default)
    /// keeps every shadow edge; a viewer's own setting overrides it.
    #[arg(long, value_name = "T", default_value_t = 0.0, value_parser = parse_simplify_tolerance)]
    pub simplify_tolerance: f64,
}

fn parse_simplify_tolerance(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    let (lo, hi) = crate::session::SIMPLIFY_TOLERANCE_RANGE;
    if !v.is_finite() || v < lo || v > hi {
        return Err(format!("must be in [{lo}, {hi}] (0 = off), got {s}"));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn the_command_line_is_consistent() {
        ServerArgs::command().debug_assert();
        let a = ServerArgs::try_parse_from(["edgepoint-server"]).unwrap();
        assert_eq!(a.listen, DEFAULT_LISTEN);
        assert!(a.workers.is_empty() && a.worker_dns.is_empty() && !a.insecure);
        let a = ServerArgs::try_parse_from([
            "edgepoint-server",
            "--worker-dns",
            "w.ns.svc:50061",
            "--worker",
            "127.0.0.1:1",
            "--metrics-listen",
            "0.0.0.0:9464",
            "--metrics-public",
        ])
        .unwrap();
        assert_eq!((a.worker_dns.len(), a.workers.len()), (1, 1));
        assert!(ServerArgs::try_parse_from(["edgepoint-server", "--tls-cert", "c.pem"]).is_err(), "needs --tls-key");
    }
}
