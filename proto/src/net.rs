//! Listener plumbing shared by the gRPC servers: TCP_NODELAY on accepted connections, the
//! exposure policy (loopback by default; any other address needs TLS — and, for the
//! renderer, a token — or an explicit `--insecure`), and TLS configuration from PEM files.
use std::net::{IpAddr, SocketAddr};
use std::path::Path;
use tokio_stream::wrappers::TcpListenerStream;
use tokio_stream::{Stream, StreamExt};
use tonic::transport::{Certificate, ClientTlsConfig, Identity, ServerTlsConfig};

/// The listener's accepted connections with Nagle's algorithm off. tonic cannot set
/// TCP_NODELAY on sockets handed to `serve_with_incoming`, and with Nagle on, small messages
/// (sample batches, rejections) wait for delayed ACKs — tens of milliseconds each, which
/// measured as a 4x loss of worker throughput on loopback.
pub fn no_delay_incoming(listener: tokio::net::TcpListener) -> impl Stream<Item = std::io::Result<tokio::net::TcpStream>> {
    TcpListenerStream::new(listener).map(|s| {
        if let Ok(s) = &s {
            let _ = s.set_nodelay(true);
        }
        s
    })
}

/// Is `ip` reachable only from this machine (127.0.0.0/8, ::1, or ::ffff:127.x)?
pub fn is_loopback(ip: IpAddr) -> bool {
    match ip {
        IpAddr::V4(v4) => v4.is_loopback(),
        IpAddr::V6(v6) => v6.is_loopback() || v6.to_ipv4_mapped().is_some_and(|v4| v4.is_loopback()),
    }
}

/// What protects a listener.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Protection {
    /// TLS certificate and key are configured.
    pub tls: bool,
    /// `Some(configured)` for a service that authenticates its clients with a token;
    /// `None` for one that has no client authentication of its own (a shader worker).
    pub token: Option<bool>,
    /// The operator passed `--insecure`.
    pub insecure: bool,
}

/// Checks that serving on `addr` is safe: loopback always is; any other address needs TLS
/// and, where the service takes tokens, a token — unless `--insecure` was given. The error
/// says which flags to add.
pub fn check_exposure(addr: SocketAddr, p: Protection) -> Result<(), String> {
    if is_loopback(addr.ip()) || p.insecure {
        return Ok(());
    }
    let mut missing = Vec::new();
    if !p.tls {
        missing.push("TLS (--tls-cert FILE --tls-key FILE)");
    }
    if p.token == Some(false) {
        missing.push("a token (--token-file FILE)");
    }
    if missing.is_empty() {
        return Ok(());
    }
    Err(format!(
        "refusing to serve on {addr} without {}: this address is reachable from other machines. \
         Listen on 127.0.0.1, add the missing protection, or pass --insecure to serve it unprotected on a trusted network",
        missing.join(" and ")
    ))
}

fn read(path: &Path, what: &str) -> Result<Vec<u8>, String> {
    let data = std::fs::read(path).map_err(|e| format!("cannot read the {what} {}: {e}", path.display()))?;
    if !data.windows(11).any(|w| w == b"-----BEGIN ") {
        return Err(format!("{} is not a PEM file (no `-----BEGIN` line); the {what} must be PEM", path.display()));
    }
    Ok(data)
}

/// Server TLS from a PEM certificate chain and its PEM private key.
pub fn server_tls(cert: &Path, key: &Path) -> Result<ServerTlsConfig, String> {
    let c = read(cert, "TLS certificate")?;
    let k = read(key, "TLS private key")?;
    Ok(ServerTlsConfig::new().identity(Identity::from_pem(c, k)))
}

/// Client TLS: trusts the PEM CA certificate(s) in `ca`, or the built-in web PKI roots
/// without one; checks the server's name against `domain` when given (else the URL's host).
pub fn client_tls(ca: Option<&Path>, domain: Option<&str>) -> Result<ClientTlsConfig, String> {
    let mut cfg = ClientTlsConfig::new();
    cfg = match ca {
        Some(p) => cfg.ca_certificate(Certificate::from_pem(read(p, "CA certificate")?)),
        None => cfg.with_webpki_roots(),
    };
    if let Some(d) = domain {
        cfg = cfg.domain_name(d);
    }
    Ok(cfg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_is_always_allowed_anything_else_needs_protection() {
        let open = Protection { tls: false, token: Some(false), insecure: false };
        for a in ["127.0.0.1:1", "127.9.9.9:1", "[::1]:1", "[::ffff:127.0.0.1]:1"] {
            assert!(check_exposure(a.parse().unwrap(), open).is_ok(), "{a}");
        }
        let any: SocketAddr = "0.0.0.0:50051".parse().unwrap();
        let e = check_exposure(any, open).unwrap_err();
        assert!(e.contains("--tls-cert") && e.contains("--token-file") && e.contains("--insecure"), "{e}");
        let e = check_exposure(any, Protection { tls: true, ..open }).unwrap_err();
        assert!(!e.contains("--tls-cert") && e.contains("--token-file"), "{e}");
        assert!(check_exposure(any, Protection { tls: true, token: Some(true), insecure: false }).is_ok());
        assert!(check_exposure(any, Protection { tls: true, token: None, insecure: false }).is_ok(), "workers take no token");
        assert!(check_exposure("[::]:1".parse().unwrap(), Protection { insecure: true, ..open }).is_ok());
        let e = check_exposure("10.0.0.5:1".parse().unwrap(), Protection { token: None, ..open }).unwrap_err();
        assert!(e.contains("--tls-cert") && !e.contains("token"), "{e}");
    }

    #[test]
    fn tls_files_must_exist_and_be_pem() {
        let dir = std::env::temp_dir().join(format!("edgepoint-net-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let not_pem = dir.join("cert.der");
        std::fs::write(&not_pem, [0x30, 0x82, 0x01]).unwrap();
        let e = server_tls(&not_pem, &not_pem).unwrap_err();
        assert!(e.contains("cert.der") && e.contains("PEM"), "{e}");
        let e = server_tls(&dir.join("missing.pem"), &not_pem).unwrap_err();
        assert!(e.contains("missing.pem"), "{e}");
        let e = client_tls(Some(&dir.join("ca.pem")), None).unwrap_err();
        assert!(e.contains("ca.pem"), "{e}");
        assert!(client_tls(None, Some("edgepoint")).is_ok());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
