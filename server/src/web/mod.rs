//! Remote viewing in a browser (issue 16; README "Remote viewing in a browser"; no paper section:
//! a transport, like the gRPC service, of the frames of paper 000 §3): `--web-listen ADDR`
//! serves one page (HTML and JavaScript embedded in the binary, no build step, no CDN) and
//! its live connection, a WebSocket that drives the very session machinery of the gRPC
//! `Session` stream ([`crate::service::RendererService::serve_session`]).
//!
//! Same rules as gRPC: loopback unless TLS and viewer tokens (or `--insecure`) protect it
//! ([`edgepoint_proto::net::check_exposure`]); the token travels in the page's first message
//! (the URL's `#token=` fragment, which browsers never send to a server) and is checked like
//! a gRPC bearer token; a WebSocket from a page of another origin is refused (a site the
//! user visits cannot drive a loopback renderer); session, pixel and memory limits are the
//! service's own; a page message above [`MAX_PAGE_MESSAGE`] closes the socket saying so.
//! Connections at once are capped and silent ones closed ([`edgepoint_proto::net`]'s
//! guards). Frames: [`live`] (latest frame wins, changed tiles only, [`tiles`]).
pub mod live;
pub mod protocol;
pub mod tiles;

use crate::service::RendererService;
use edgepoint_proto::net::{check_exposure, GuardedStream, Protection, HANDSHAKE_TIMEOUT, IDLE_TIMEOUT};
use http_body_util::Full;
use hyper::body::Bytes;
use hyper::{header, Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;

/// The page and its script, shipped inside the binary.
pub const PAGE_HTML: &str = include_str!("page.html");
pub const PAGE_JS: &str = include_str!("page.js");

/// Connections served at once (pages and their sockets); more wait in the listen backlog.
pub const MAX_WEB_CONNECTIONS: usize = 64;
/// Largest message a page may send (its messages are camera moves and switches: small).
pub const MAX_PAGE_MESSAGE: usize = 64 << 10;
/// Time a client has to send an HTTP request head.
const HEADER_TIMEOUT: Duration = Duration::from_secs(10);

/// How the listener is protected.
#[derive(Clone, Default)]
pub struct WebOptions {
    /// TLS (`--tls-cert/--tls-key`, the same as the gRPC port's): the page is then `https://`
    /// and its socket `wss://`.
    pub tls: Option<Arc<rustls::ServerConfig>>,
    /// `--insecure`: serve a non-loopback address without full protection.
    pub insecure: bool,
}

/// Binds `addr`, checks it may serve there, prints `web <url>` on stdout and serves pages
/// and live connections on a spawned task. Answers the page's URL.
pub async fn start(addr: &str, service: Arc<RendererService>, opts: WebOptions) -> anyhow::Result<String> {
    let listener = TcpListener::bind(addr).await.map_err(|e| anyhow::anyhow!("cannot listen for the web viewer on {addr}: {e}"))?;
    let bound = listener.local_addr()?;
    let tokens = service.config().tokens.is_some();
    check_exposure(bound, Protection { tls: opts.tls.is_some(), token: Some(tokens), insecure: opts.insecure })
        .map_err(|e| anyhow::anyhow!("--web-listen: {e}"))?;
    let url = page_url(bound, opts.tls.is_some());
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "web {url}")?;
        out.flush()?;
    }
    tracing::info!(%url, tls = opts.tls.is_some(), tokens, "web viewer serving");
    tokio::spawn(serve(listener, service, opts));
    Ok(url)
}

/// `http://127.0.0.1:PORT/` (or `https://`), with IPv6 addresses bracketed.
pub fn page_url(addr: SocketAddr, tls: bool) -> String {
    format!("{}://{addr}/", if tls { "https" } else { "http" })
}

/// Accepts connections until the task is dropped; a failed accept is logged and retried.
pub async fn serve(listener: TcpListener, service: Arc<RendererService>, opts: WebOptions) {
    let permits = Arc::new(Semaphore::new(MAX_WEB_CONNECTIONS));
    let acceptor = opts.tls.clone().map(tokio_rustls::TlsAcceptor::from);
    loop {
        let Ok(permit) = permits.clone().acquire_owned().await else { return };
        let (stream, peer) = match listener.accept().await {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("web viewer: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let _ = stream.set_nodelay(true);
        // Silent connections close: the live loop pings, and browsers answer pings.
        let stream = GuardedStream::new(stream, HANDSHAKE_TIMEOUT, IDLE_TIMEOUT);
        let (service, acceptor) = (service.clone(), acceptor.clone());
        tokio::spawn(async move {
            match acceptor {
                Some(a) => match tokio::time::timeout(HANDSHAKE_TIMEOUT, a.accept(stream)).await {
                    Ok(Ok(tls)) => connection(tls, peer, service, true).await,
                    Ok(Err(e)) => tracing::debug!(%peer, "web viewer: TLS handshake failed: {e}"),
                    Err(_) => tracing::debug!(%peer, "web viewer: no TLS handshake within {HANDSHAKE_TIMEOUT:?}"),
                },
                None => connection(stream, peer, service, false).await,
            }
            drop(permit);
        });
    }
}

async fn connection<S>(io: S, peer: SocketAddr, service: Arc<RendererService>, tls: bool)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let svc = hyper::service::service_fn(move |req: Request<hyper::body::Incoming>| {
        let service = service.clone();
        async move { Ok::<_, std::convert::Infallible>(answer(req, peer, service, tls)) }
    });
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(HEADER_TIMEOUT)
        .serve_connection(TokioIo::new(io), svc)
        .with_upgrades();
    if let Err(e) = conn.await {
        tracing::debug!(%peer, "web viewer connection ended: {e}");
    }
}

fn reply(status: StatusCode, ctype: &str, body: impl Into<Bytes>) -> Response<Full<Bytes>> {
    Response::builder()
        .status(status)
        .header(header::CONTENT_TYPE, ctype)
        .header(header::CACHE_CONTROL, "no-store")
        .header("x-content-type-options", "nosniff")
        .body(Full::new(body.into()))
        .expect("static response parts")
}

/// What the page may offer: built-in scenes that need no data files (the server has none),
/// the shader table, and whether a token is needed.
pub fn info_json(tokens: bool) -> serde_json::Value {
    let scenes: Vec<_> = edgepoint_scene::builtin::BUILTINS
        .iter()
        .filter(|(name, _)| edgepoint_scene::builtin::data_files(name).is_empty())
        .map(|(name, help)| serde_json::json!({"name": name, "help": help}))
        .collect();
    let shaders: Vec<_> = edgepoint_proto::shaders::SHADERS.iter().map(|s| serde_json::json!({"name": s.name, "help": s.help})).collect();
    serde_json::json!({"scenes": scenes, "shaders": shaders, "token_required": tokens, "max_page_message": MAX_PAGE_MESSAGE})
}

/// Does the request's `Origin` (sent by browsers on every WebSocket) name this server? A
/// request without one (not from a browser page) passes: it must still hold the token.
pub fn same_origin(req: &Request<hyper::body::Incoming>) -> bool {
    let Some(origin) = req.headers().get(header::ORIGIN).and_then(|o| o.to_str().ok()) else { return true };
    let Some(host) = req.headers().get(header::HOST).and_then(|h| h.to_str().ok()) else { return false };
    origin.split_once("://").is_some_and(|(_, rest)| rest.eq_ignore_ascii_case(host))
}

fn answer(req: Request<hyper::body::Incoming>, peer: SocketAddr, service: Arc<RendererService>, tls: bool) -> Response<Full<Bytes>> {
    let text = "text/plain; charset=utf-8";
    match (req.method(), req.uri().path()) {
        (&Method::GET, "/") | (&Method::GET, "/index.html") => reply(StatusCode::OK, "text/html; charset=utf-8", PAGE_HTML),
        (&Method::GET, "/page.js") => reply(StatusCode::OK, "text/javascript; charset=utf-8", PAGE_JS),
        (&Method::GET, "/info") => reply(StatusCode::OK, "application/json", info_json(service.config().tokens.is_some()).to_string()),
        (&Method::GET, "/live") => upgrade(req, peer, service, tls),
        (_, "/" | "/page.js" | "/info" | "/live") => reply(StatusCode::METHOD_NOT_ALLOWED, text, "only GET\n"),
        _ => reply(StatusCode::NOT_FOUND, text, "not found: the viewer page is at /\n"),
    }
}

/// Answers the WebSocket handshake and hands the upgraded connection to [`live::run`].
fn upgrade(mut req: Request<hyper::body::Incoming>, peer: SocketAddr, service: Arc<RendererService>, tls: bool) -> Response<Full<Bytes>> {
    let text = "text/plain; charset=utf-8";
    let is_ws = req.headers().get(header::UPGRADE).and_then(|v| v.to_str().ok()).is_some_and(|v| v.eq_ignore_ascii_case("websocket"));
    let Some(key) = req.headers().get(header::SEC_WEBSOCKET_KEY).cloned().filter(|_| is_ws) else {
        return reply(StatusCode::BAD_REQUEST, text, "/live is the viewer's WebSocket: connect with a WebSocket client\n");
    };
    if !same_origin(&req) {
        tracing::info!(%peer, "web viewer: WebSocket from another origin refused");
        return reply(StatusCode::FORBIDDEN, text, "a page of another origin may not open this renderer's live connection\n");
    }
    let on_upgrade = hyper::upgrade::on(&mut req);
    tokio::spawn(async move {
        match on_upgrade.await {
            Ok(upgraded) => live::run(TokioIo::new(upgraded), peer, service).await,
            Err(e) => tracing::debug!(%peer, "web viewer: upgrade failed: {e}"),
        }
    });
    tracing::debug!(%peer, tls, "web viewer: live connection");
    Response::builder()
        .status(StatusCode::SWITCHING_PROTOCOLS)
        .header(header::CONNECTION, "upgrade")
        .header(header::UPGRADE, "websocket")
        .header(header::SEC_WEBSOCKET_ACCEPT, tokio_tungstenite::tungstenite::handshake::derive_accept_key(key.as_bytes()))
        .body(Full::new(Bytes::new()))
        .expect("static response parts")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::ServiceConfig;
    use crate::workers::WorkerPool;
    use futures_util::{SinkExt, StreamExt};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio_tungstenite::tungstenite::Message;

    const GOOD: &str = "good-token-0123456789";

    /// A listener on a service with a viewer token and no workers (a session that passes
    /// the token check is then refused for want of workers).
    async fn listener() -> SocketAddr {
        let pool = Arc::new(WorkerPool::new(vec![]).unwrap());
        let svc = RendererService::new(pool, ServiceConfig { tokens: Some(Arc::new(vec![GOOD.into()])), ..Default::default() });
        let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        tokio::spawn(serve(l, Arc::new(svc), WebOptions::default()));
        addr
    }

    /// The page's first message with `token`, answered by the server's first text message.
    async fn hello(addr: SocketAddr, first: Message) -> (serde_json::Value, Option<String>) {
        let (mut ws, _) = tokio_tungstenite::client_async(format!("ws://{addr}/live"), tokio::net::TcpStream::connect(addr).await.unwrap()).await.unwrap();
        ws.send(first).await.unwrap();
        let mut answer = serde_json::Value::Null;
        let mut close = None;
        while let Some(Ok(m)) = ws.next().await {
            match m {
                Message::Text(t) => answer = serde_json::from_str(&t).unwrap(),
                Message::Close(c) => close = c.map(|c| c.reason.to_string()),
                _ => {}
            }
        }
        (answer, close)
    }

    fn hello_with(token: &str) -> Message {
        Message::text(serde_json::json!({"type": "hello", "token": token, "start": {"scene": "cornell", "width": 64, "height": 64}}).to_string())
    }

    async fn raw_get(addr: SocketAddr, extra: &str) -> String {
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        s.write_all(format!("GET /live HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n{extra}\r\n").as_bytes()).await.unwrap();
        let mut buf = vec![0u8; 512];
        let n = tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf)).await.unwrap().unwrap();
        String::from_utf8_lossy(&buf[..n]).into_owned()
    }

    #[tokio::test]
    async fn the_live_connection_refuses_wrong_tokens_big_messages_and_other_origins() {
        let addr = listener().await;
        let (a, close) = hello(addr, hello_with("wrong-token-0123456789")).await;
        assert_eq!((a["type"].as_str(), a["code"].as_str()), (Some("refused"), Some("UNAUTHENTICATED")), "{a}");
        assert!(a["message"].as_str().unwrap().contains("#token="), "{a}");
        assert!(close.unwrap().starts_with("UNAUTHENTICATED"));
        let (a, _) = hello(addr, Message::text(serde_json::json!({"type": "hello", "start": {"scene": "cornell", "width": 64, "height": 64}}).to_string())).await;
        assert_eq!(a["code"], "UNAUTHENTICATED", "no token: {a}");
        // The right token passes; this service then has no workers to offer.
        let (a, _) = hello(addr, hello_with(GOOD)).await;
        assert_eq!(a["code"], "FAILED_PRECONDITION", "{a}");
        assert!(a["message"].as_str().unwrap().contains("no shader workers"), "{a}");
        // A bad first message and one above the limit are refused, saying why.
        let (a, _) = hello(addr, Message::text(r#"{"type":"hello","start":{"scene":"cornell","width":0,"height":8}}"#)).await;
        assert_eq!((a["code"].as_str(), a["message"].as_str().map(|m| m.contains("start.width"))), (Some("INVALID_ARGUMENT"), Some(true)), "{a}");
        let (a, close) = hello(addr, Message::text("x".repeat(MAX_PAGE_MESSAGE + 1))).await;
        assert_eq!(a["code"], "OUT_OF_RANGE", "{a}");
        assert!(a["message"].as_str().unwrap().contains(&MAX_PAGE_MESSAGE.to_string()), "{a}");
        assert!(close.is_some());
        // The handshake: a page of this origin is let in, another origin is not.
        let ok = raw_get(addr, &format!("Origin: http://{addr}\r\n")).await;
        assert!(ok.starts_with("HTTP/1.1 101"), "{ok}");
        assert!(ok.contains("s3pPLMBiTxaQ9kYGzzhZRbK+xOo="), "the RFC 6455 example key's answer: {ok}");
        let other = raw_get(addr, "Origin: http://evil.example\r\n").await;
        assert!(other.starts_with("HTTP/1.1 403"), "{other}");
    }

    /// A certificate for `localhost` in `dir` (cert.pem, key.pem) and its DER, for a client
    /// to trust.
    fn localhost_cert(dir: &std::path::Path) -> rustls::pki_types::CertificateDer<'static> {
        let key = rcgen::KeyPair::generate().unwrap();
        let cert = rcgen::CertificateParams::new(vec!["localhost".to_string()]).unwrap().self_signed(&key).unwrap();
        std::fs::write(dir.join("cert.pem"), cert.pem()).unwrap();
        std::fs::write(dir.join("key.pem"), key.serialize_pem()).unwrap();
        cert.der().clone()
    }

    /// A TLS connection to `addr` trusting only `ca`, for the name `localhost`.
    async fn tls_to(addr: SocketAddr, ca: &rustls::pki_types::CertificateDer<'static>) -> std::io::Result<tokio_rustls::client::TlsStream<tokio::net::TcpStream>> {
        let mut roots = rustls::RootCertStore::empty();
        roots.add(ca.clone()).unwrap();
        let cfg = rustls::ClientConfig::builder_with_provider(Arc::new(rustls::crypto::ring::default_provider()))
            .with_safe_default_protocol_versions()
            .unwrap()
            .with_root_certificates(roots)
            .with_no_client_auth();
        let name = rustls::pki_types::ServerName::try_from("localhost").unwrap();
        tokio_rustls::TlsConnector::from(Arc::new(cfg)).connect(name, tokio::net::TcpStream::connect(addr).await?).await
    }

    #[tokio::test]
    async fn with_tls_the_page_and_its_socket_are_served_over_tls_only() {
        let dir = std::env::temp_dir().join(format!("edgepoint-web-tls-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ca = localhost_cert(&dir);
        let tls = edgepoint_proto::net::rustls_server_config(&dir.join("cert.pem"), &dir.join("key.pem")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        let pool = Arc::new(WorkerPool::new(vec![]).unwrap());
        let svc = Arc::new(RendererService::new(pool, ServiceConfig { tokens: Some(Arc::new(vec![GOOD.into()])), ..Default::default() }));
        let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        tokio::spawn(serve(l, svc.clone(), WebOptions { tls: Some(tls.clone()), insecure: false }));

        // The page over https.
        let mut s = tls_to(addr, &ca).await.expect("TLS handshake with the page's server");
        s.write_all(format!("GET / HTTP/1.1\r\nHost: localhost:{}\r\nConnection: close\r\n\r\n", addr.port()).as_bytes()).await.unwrap();
        let mut page = Vec::new();
        tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut page)).await.unwrap().ok();
        let page = String::from_utf8_lossy(&page);
        assert!(page.starts_with("HTTP/1.1 200") && page.contains("<canvas"), "{page}");

        // The live socket over wss: the token is checked there as on plain connections.
        for (token, code) in [("wrong-token-0123456789", "UNAUTHENTICATED"), (GOOD, "FAILED_PRECONDITION")] {
            let stream = tls_to(addr, &ca).await.unwrap();
            let (mut ws, _) = tokio_tungstenite::client_async(format!("wss://localhost:{}/live", addr.port()), stream).await.expect("wss handshake");
            ws.send(hello_with(token)).await.unwrap();
            let mut answer = serde_json::Value::Null;
            while let Some(Ok(m)) = ws.next().await {
                if let Message::Text(t) = m {
                    answer = serde_json::from_str(&t).unwrap();
                }
            }
            assert_eq!(answer["code"], code, "token {token}: {answer}");
        }

        // Plain HTTP on the TLS port gets no page, and a certificate the client does not
        // trust is refused by the client.
        let mut plain = tokio::net::TcpStream::connect(addr).await.unwrap();
        plain.write_all(b"GET / HTTP/1.1\r\nHost: localhost\r\n\r\n").await.unwrap();
        let mut buf = vec![0u8; 256];
        let n = tokio::time::timeout(Duration::from_secs(15), plain.read(&mut buf)).await.unwrap().unwrap_or(0);
        assert!(!String::from_utf8_lossy(&buf[..n]).contains("<canvas"), "plain HTTP on the TLS port");
        let other_dir = std::env::temp_dir().join(format!("edgepoint-web-tls-other-{}", std::process::id()));
        std::fs::create_dir_all(&other_dir).unwrap();
        let other = localhost_cert(&other_dir);
        let _ = std::fs::remove_dir_all(&other_dir);
        assert!(tls_to(addr, &other).await.is_err(), "a client trusting another certificate must not connect");

        // Beyond loopback the listener needs TLS and a token (or --insecure), as gRPC does.
        let open = Arc::new(RendererService::new(Arc::new(WorkerPool::new(vec![]).unwrap()), ServiceConfig::default()));
        let e = start("0.0.0.0:0", open.clone(), WebOptions::default()).await.unwrap_err().to_string();
        assert!(e.contains("--web-listen") && e.contains("TLS") && e.contains("token"), "{e}");
        let e = start("0.0.0.0:0", open.clone(), WebOptions { tls: Some(tls), insecure: false }).await.unwrap_err().to_string();
        assert!(e.contains("token") && !e.contains("TLS ("), "{e}");
        assert!(start("0.0.0.0:0", open, WebOptions { tls: None, insecure: true }).await.is_ok(), "--insecure serves unprotected");
    }

    #[test]
    fn the_page_offers_scenes_without_data_files_and_every_shader() {
        let j = info_json(true);
        let scenes: Vec<&str> = j["scenes"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert!(scenes.contains(&"cornell") && scenes.contains(&"rooms"), "{scenes:?}");
        assert!(!scenes.contains(&"grid-dragon"), "needs the dragon's data file, which the server has not");
        assert_eq!(j["shaders"].as_array().unwrap().len(), edgepoint_proto::shaders::SHADERS.len());
        assert_eq!(j["token_required"], true);
        assert_eq!(page_url("[::1]:8080".parse().unwrap(), true), "https://[::1]:8080/");
        // The page loads its script from this server only: no CDN.
        assert!(PAGE_HTML.contains(r#"src="page.js""#) && !PAGE_HTML.contains("://"));
    }
}
