//! Listener plumbing shared by the gRPC servers: accepted connections with TCP_NODELAY and
//! read deadlines ([`guarded_incoming`]), the exposure policy (loopback by default; any
//! other address needs TLS — and, for the renderer, viewer tokens, for a worker, an
//! authenticated renderer — or an explicit `--insecure`), and TLS configuration from PEM
//! files, checked at start-up.
use std::net::{IpAddr, SocketAddr};
use std::path::Path;
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio_stream::wrappers::TcpListenerStream;
use tokio_stream::{Stream, StreamExt};
use tonic::transport::server::{Connected, TcpConnectInfo};
use tonic::transport::{Certificate, ClientTlsConfig, Identity, ServerTlsConfig};

/// Time a new connection has to send its first bytes (the HTTP/2 preface, or a TLS
/// ClientHello); and the TLS handshake's limit.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);
/// Time a connection may send nothing at all. The servers ping idle HTTP/2 connections
/// every 10 s (keepalive) and every live client answers, so only a silent or half-open
/// connection reaches it.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(45);
/// Bytes that prove a client started talking: the 24-byte HTTP/2 preface plus a frame
/// header (a TLS ClientHello is longer).
const HANDSHAKE_BYTES: u64 = 24 + 9;

/// The listener's accepted connections with Nagle's algorithm off and read deadlines
/// ([`GuardedStream`]). tonic cannot set TCP_NODELAY on sockets handed to
/// `serve_with_incoming`, and with Nagle on, small messages (sample batches, rejections)
/// wait for delayed ACKs — tens of milliseconds each, which measured as a 4x loss of worker
/// throughput on loopback.
pub fn guarded_incoming(listener: tokio::net::TcpListener) -> impl Stream<Item = std::io::Result<GuardedStream>> {
    TcpListenerStream::new(listener).map(|s| {
        s.map(|s| {
            let _ = s.set_nodelay(true);
            GuardedStream::new(s, HANDSHAKE_TIMEOUT, IDLE_TIMEOUT)
        })
    })
}

/// A TCP connection that fails its reads (so the server closes it) when the client has not
/// sent [`HANDSHAKE_BYTES`] within the handshake time, or then sends nothing for the idle
/// time. Without it, a connection that never speaks, or stops in the middle of the HTTP/2
/// preface, would hold its socket and task forever: the HTTP/2 layer's keepalive only
/// starts after the handshake.
pub struct GuardedStream {
    inner: tokio::net::TcpStream,
    read: u64,
    handshake: Duration,
    idle: Duration,
    deadline: Pin<Box<tokio::time::Sleep>>,
}

impl GuardedStream {
    pub fn new(inner: tokio::net::TcpStream, handshake: Duration, idle: Duration) -> Self {
        let deadline = Box::pin(tokio::time::sleep(handshake));
        GuardedStream { inner, read: 0, handshake, idle, deadline }
    }
}

impl AsyncRead for GuardedStream {
    fn poll_read(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        match Pin::new(&mut self.inner).poll_read(cx, buf) {
            Poll::Ready(Ok(())) => {
                let n = (buf.filled().len() - before) as u64;
                if n > 0 {
                    self.read += n;
                    let next = tokio::time::Instant::now() + if self.read >= HANDSHAKE_BYTES { self.idle } else { self.handshake };
                    // The handshake deadline is not moved by its first bytes, only by all.
                    if self.read >= HANDSHAKE_BYTES {
                        self.deadline.as_mut().reset(next);
                    }
                }
                Poll::Ready(Ok(()))
            }
            Poll::Ready(Err(e)) => Poll::Ready(Err(e)),
            Poll::Pending => match self.deadline.as_mut().poll(cx) {
                Poll::Ready(()) => {
                    let what = if self.read < HANDSHAKE_BYTES { "no handshake" } else { "nothing received" };
                    let after = if self.read < HANDSHAKE_BYTES { self.handshake } else { self.idle };
                    Poll::Ready(Err(std::io::Error::new(std::io::ErrorKind::TimedOut, format!("{what} within {after:?}; closing"))))
                }
                Poll::Pending => Poll::Pending,
            },
        }
    }
}

impl AsyncWrite for GuardedStream {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
    fn poll_write_vectored(mut self: Pin<&mut Self>, cx: &mut Context<'_>, bufs: &[std::io::IoSlice<'_>]) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }
    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

impl Connected for GuardedStream {
    type ConnectInfo = TcpConnectInfo;
    fn connect_info(&self) -> TcpConnectInfo {
        self.inner.connect_info()
    }
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

/// Checks that a worker may serve on `addr`: loopback always may. Any other address needs the
/// renderer to authenticate (`authenticated`: a token file or a client CA for mutual TLS) —
/// `--insecure` does not waive that, since anyone who reaches an open worker can load
/// scenes and use its cores — and TLS unless `--insecure`.
pub fn check_worker_exposure(addr: SocketAddr, tls: bool, authenticated: bool, insecure: bool) -> Result<(), String> {
    if is_loopback(addr.ip()) {
        return Ok(());
    }
    let mut missing = Vec::new();
    if !authenticated {
        missing.push(
            "authentication of the renderer (--token-file FILE, sent by the renderer's --worker-token-file; or \
             --tls-client-ca FILE for mutual TLS, with the renderer's --worker-tls-cert/--worker-tls-key)",
        );
    }
    if !tls && !insecure {
        missing.push("TLS (--tls-cert FILE --tls-key FILE)");
    }
    if missing.is_empty() {
        return Ok(());
    }
    Err(format!(
        "refusing to serve on {addr} without {}: this address is reachable from other machines. Listen on \
         127.0.0.1 or add the missing protection (--insecure allows plaintext on a trusted network, not \
         anonymous callers)",
        missing.join(" and ")
    ))
}

/// Checks that a metrics endpoint may serve on `addr`: loopback always may; any other address
/// only with `public` (`--metrics-public`), since the endpoint is plain HTTP without
/// authentication and names the workers' addresses.
pub fn check_metrics_exposure(addr: SocketAddr, public: bool) -> Result<(), String> {
    if is_loopback(addr.ip()) || public {
        return Ok(());
    }
    Err(format!(
        "refusing to serve metrics on {addr}: the endpoint is plain HTTP without authentication and names the \
         workers' addresses. Bind it to 127.0.0.1, or pass --metrics-public to serve it to a network you trust \
         (e.g. for a Prometheus in the same cluster)"
    ))
}

fn read(path: &Path, what: &str) -> Result<Vec<u8>, String> {
    let data = std::fs::read(path).map_err(|e| format!("cannot read the {what} {}: {e}", path.display()))?;
    if !data.windows(11).any(|w| w == b"-----BEGIN ") {
        return Err(format!("{} is not a PEM file (no `-----BEGIN` line); the {what} must be PEM", path.display()));
    }
    Ok(data)
}

/// Parses a PEM certificate chain and private key and checks that the key belongs to the
/// chain's first certificate, so a mismatch is named at start-up rather than failing every
/// handshake later with an opaque "transport error".
fn checked_identity(cert: &Path, key: &Path) -> Result<Identity, String> {
    let (c, k, _, _) = checked_pem(cert, key)?;
    Ok(Identity::from_pem(c, k))
}

/// A certificate chain, its private key (checked to match) and their PEM bytes.
type CheckedPem = (Vec<u8>, Vec<u8>, Vec<rustls::pki_types::CertificateDer<'static>>, rustls::pki_types::PrivateKeyDer<'static>);

fn checked_pem(cert: &Path, key: &Path) -> Result<CheckedPem, String> {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, PrivateKeyDer};
    let c = read(cert, "TLS certificate")?;
    let k = read(key, "TLS private key")?;
    let chain: Vec<CertificateDer<'static>> = CertificateDer::pem_slice_iter(&c)
        .collect::<Result<_, _>>()
        .map_err(|e| format!("{}: not a PEM certificate chain: {e}", cert.display()))?;
    if chain.is_empty() {
        return Err(format!("{} holds no CERTIFICATE block", cert.display()));
    }
    let der = PrivateKeyDer::from_pem_slice(&k).map_err(|e| format!("{}: no PEM private key: {e}", key.display()))?;
    let provider = rustls::crypto::ring::default_provider();
    let signing = provider.key_provider.load_private_key(der.clone_key()).map_err(|e| format!("{}: unusable private key: {e}", key.display()))?;
    let certified = rustls::sign::CertifiedKey::new(chain.clone(), signing);
    match certified.keys_match() {
        Ok(()) | Err(rustls::Error::InconsistentKeys(rustls::InconsistentKeys::Unknown)) => {}
        Err(rustls::Error::InconsistentKeys(rustls::InconsistentKeys::KeyMismatch)) => {
            return Err(format!(
                "the private key {} does not belong to the certificate {} (their public keys differ)",
                key.display(),
                cert.display()
            ))
        }
        Err(e) => return Err(format!("{}: {e}", cert.display())),
    }
    Ok((c, k, chain, der))
}

/// A rustls server configuration from the same PEM files and checks as [`server_tls`], for
/// listeners tonic does not serve (the browser viewer's `--web-listen`). Offers HTTP/1.1.
pub fn rustls_server_config(cert: &Path, key: &Path) -> Result<std::sync::Arc<rustls::ServerConfig>, String> {
    let (_, _, chain, der) = checked_pem(cert, key)?;
    let mut cfg = rustls::ServerConfig::builder_with_provider(std::sync::Arc::new(rustls::crypto::ring::default_provider()))
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS configuration: {e}"))?
        .with_no_client_auth()
        .with_single_cert(chain, der)
        .map_err(|e| format!("{}: {e}", cert.display()))?;
    cfg.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(std::sync::Arc::new(cfg))
}

/// Server TLS from a PEM certificate chain and its PEM private key (checked to match), with
/// the handshake limited to [`HANDSHAKE_TIMEOUT`]. With `client_ca`, clients must present a
/// certificate signed by it (mutual TLS).
pub fn server_tls(cert: &Path, key: &Path) -> Result<ServerTlsConfig, String> {
    Ok(ServerTlsConfig::new().identity(checked_identity(cert, key)?).timeout(HANDSHAKE_TIMEOUT))
}

/// [`server_tls`] requiring client certificates signed by the PEM CA in `client_ca`.
pub fn server_mutual_tls(cert: &Path, key: &Path, client_ca: &Path) -> Result<ServerTlsConfig, String> {
    let ca = read(client_ca, "client CA certificate")?;
    Ok(server_tls(cert, key)?.client_ca_root(Certificate::from_pem(ca)))
}

/// Client TLS that also presents a certificate (mutual TLS), checked like the server's.
pub fn client_identity(cfg: ClientTlsConfig, cert: &Path, key: &Path) -> Result<ClientTlsConfig, String> {
    Ok(cfg.identity(checked_identity(cert, key)?))
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
    fn workers_beyond_loopback_need_an_authenticated_renderer_and_metrics_an_explicit_flag() {
        let any: SocketAddr = "0.0.0.0:50061".parse().unwrap();
        assert!(check_worker_exposure("127.0.0.1:1".parse().unwrap(), false, false, false).is_ok());
        let e = check_worker_exposure(any, true, false, false).unwrap_err();
        assert!(e.contains("--token-file") && e.contains("--tls-client-ca") && !e.contains("--tls-cert FILE"), "TLS alone is not enough: {e}");
        let e = check_worker_exposure(any, false, false, true).unwrap_err();
        assert!(e.contains("--token-file") && e.contains("not anonymous"), "--insecure does not waive it: {e}");
        assert!(check_worker_exposure(any, false, true, true).is_ok(), "plaintext with a token on a trusted network");
        assert!(check_worker_exposure(any, true, true, false).is_ok());
        assert!(check_worker_exposure(any, false, true, false).unwrap_err().contains("--tls-cert"));
        assert!(check_metrics_exposure("127.0.0.1:9464".parse().unwrap(), false).is_ok());
        let e = check_metrics_exposure("0.0.0.0:9464".parse().unwrap(), false).unwrap_err();
        assert!(e.contains("--metrics-public") && e.contains("plain HTTP"), "{e}");
        assert!(check_metrics_exposure("0.0.0.0:9464".parse().unwrap(), true).is_ok());
    }

    /// Issue 12 item 10: a connection that never speaks, or stops halfway through the
    /// preface, is closed by its read deadline; one that talks is not.
    #[tokio::test]
    async fn silent_and_half_open_connections_are_closed() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let server = tokio::spawn(async move {
            let mut outcomes = Vec::new();
            for _ in 0..3 {
                let (s, _) = listener.accept().await.unwrap();
                let mut g = GuardedStream::new(s, Duration::from_millis(1000), Duration::from_millis(1500));
                let mut buf = vec![0u8; 64];
                let mut got = 0;
                let end = loop {
                    match g.read(&mut buf).await {
                        Ok(0) => break "eof".to_string(),
                        Ok(n) => got += n,
                        Err(e) => break format!("{:?}", e.kind()),
                    }
                };
                outcomes.push((got, end));
            }
            outcomes
        });
        let _silent = tokio::net::TcpStream::connect(addr).await.unwrap();
        let mut half = tokio::net::TcpStream::connect(addr).await.unwrap();
        half.write_all(&b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"[..10]).await.unwrap();
        let mut talker = tokio::net::TcpStream::connect(addr).await.unwrap();
        for _ in 0..4 {
            talker.write_all(&[7u8; 20]).await.unwrap();
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        drop(talker);
        let outcomes = tokio::time::timeout(Duration::from_secs(20), server).await.expect("every connection ends").unwrap();
        let mut outcomes = outcomes;
        outcomes.sort();
        assert_eq!(outcomes[0], (0, "TimedOut".to_string()), "{outcomes:?}");
        assert_eq!(outcomes[1], (10, "TimedOut".to_string()), "{outcomes:?}");
        assert_eq!(outcomes[2], (80, "eof".to_string()), "a client that keeps talking is served until it leaves: {outcomes:?}");
    }

    /// Issue 12 item 13: a key that does not belong to the certificate is named at start-up
    /// (it used to surface as "transport error").
    #[test]
    fn a_key_of_another_certificate_is_named() {
        let dir = std::env::temp_dir().join(format!("edgepoint-net-keys-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
        let b = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
        let (cert, key, other) = (dir.join("a.pem"), dir.join("a.key"), dir.join("b.key"));
        std::fs::write(&cert, a.cert.pem()).unwrap();
        std::fs::write(&key, a.signing_key.serialize_pem()).unwrap();
        std::fs::write(&other, b.signing_key.serialize_pem()).unwrap();
        assert!(server_tls(&cert, &key).is_ok());
        let e = server_tls(&cert, &other).unwrap_err();
        assert!(e.contains("b.key") && e.contains("does not belong") && e.contains("a.pem"), "{e}");
        let e = server_tls(&key, &key).unwrap_err();
        assert!(e.contains("no CERTIFICATE") || e.contains("certificate"), "{e}");
        assert!(client_identity(ClientTlsConfig::new(), &cert, &other).unwrap_err().contains("does not belong"));
        let _ = std::fs::remove_dir_all(&dir);
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
