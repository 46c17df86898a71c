//! The Prometheus scrape endpoint shared by the server and the workers (`--metrics-listen`):
//! a small HTTP/1.1 server answering `GET /metrics` with the text exposition format.
//!
//! It is built to stay up whatever connects: connections are capped, a client gets
//! [`HEADER_TIMEOUT`] to send its request head and [`CONNECTION_TIMEOUT`] in all, anything but
//! `GET /metrics` (and `GET /`) is answered 404 / 405, and garbage is answered 400 by hyper
//! and closed.
use http_body_util::Full;
use hyper::body::Bytes;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;

/// Connections served at once; more wait in the listen backlog.
pub const MAX_CONNECTIONS: usize = 64;
/// Time a client has to send its request head.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// Longest life of one connection (keep-alive included).
pub const CONNECTION_TIMEOUT: Duration = Duration::from_secs(60);

/// Renders the current metrics as Prometheus text.
pub type Render = Arc<dyn Fn() -> String + Send + Sync>;

/// Serves `GET /metrics` on `listener` until the task is dropped. Never returns an error:
/// a failed accept (e.g. out of file descriptors) is logged and retried after a pause.
pub async fn serve_metrics(listener: TcpListener, render: Render) {
    let permits = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    loop {
        let Ok(permit) = permits.clone().acquire_owned().await else { return };
        let stream = match listener.accept().await {
            Ok((s, _)) => s,
            Err(e) => {
                tracing::warn!("metrics endpoint: accept failed: {e}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let render = render.clone();
        tokio::spawn(async move {
            let service = hyper::service::service_fn(move |req: Request<hyper::body::Incoming>| {
                let render = render.clone();
                async move { Ok::<_, std::convert::Infallible>(answer(&req, &render)) }
            });
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT)
                .keep_alive(true)
                .serve_connection(TokioIo::new(stream), service);
            match tokio::time::timeout(CONNECTION_TIMEOUT, conn).await {
                Ok(Err(e)) => tracing::debug!("metrics connection ended: {e}"),
                Err(_) => tracing::debug!("metrics connection closed after {CONNECTION_TIMEOUT:?}"),
                Ok(Ok(())) => {}
            }
            drop(permit);
        });
    }
}

fn answer(req: &Request<hyper::body::Incoming>, render: &Render) -> Response<Full<Bytes>> {
    let reply = |status: StatusCode, ctype: &str, body: String| {
        Response::builder()
            .status(status)
            .header(hyper::header::CONTENT_TYPE, ctype)
            .body(Full::new(Bytes::from(body)))
            .expect("static response parts")
    };
    match (req.method(), req.uri().path()) {
        (&Method::GET, "/metrics") => reply(StatusCode::OK, "text/plain; version=0.0.4; charset=utf-8", render()),
        (&Method::GET, "/") => reply(StatusCode::OK, "text/plain; charset=utf-8", "edgepoint metrics: GET /metrics\n".into()),
        (_, "/metrics") | (_, "/") => reply(StatusCode::METHOD_NOT_ALLOWED, "text/plain; charset=utf-8", "only GET\n".into()),
        _ => reply(StatusCode::NOT_FOUND, "text/plain; charset=utf-8", "not found: try /metrics\n".into()),
    }
}

/// Binds `addr`, prints `metrics <addr>` on stdout (the launcher contract: before the
/// `listening` line) and serves the endpoint on a spawned task. A non-loopback address is
/// refused unless `public` (`--metrics-public`): see [`crate::net::check_metrics_exposure`].
pub async fn start(addr: &str, public: bool, render: Render) -> std::io::Result<std::net::SocketAddr> {
    let listener = TcpListener::bind(addr)
        .await
        .map_err(|e| std::io::Error::new(e.kind(), format!("cannot listen for metrics on {addr}: {e}")))?;
    let bound = listener.local_addr()?;
    crate::net::check_metrics_exposure(bound, public).map_err(std::io::Error::other)?;
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "metrics {bound}")?;
        out.flush()?;
    }
    tracing::info!(addr = %bound, "metrics endpoint serving GET /metrics");
    tokio::spawn(serve_metrics(listener, render));
    Ok(bound)
}

/// The Prometheus text format of `registry`, with `process_resident_memory_bytes` (a gauge
/// registered by [`resident_gauge`]) read now.
pub fn encode(registry: &prometheus::Registry, resident: &prometheus::IntGauge) -> String {
    if let Some(rss) = resident_bytes() {
        resident.set(rss as i64);
    }
    let mut buf = Vec::new();
    // Encoding into a Vec cannot fail on I/O; a collector error would be a bug of ours.
    if let Err(e) = prometheus::Encoder::encode(&prometheus::TextEncoder::new(), &registry.gather(), &mut buf) {
        tracing::error!("metrics encoding failed: {e}");
    }
    String::from_utf8(buf).unwrap_or_default()
}

/// Registers `process_resident_memory_bytes` with `registry`.
pub fn resident_gauge(registry: &prometheus::Registry) -> prometheus::IntGauge {
    let g = prometheus::IntGauge::new("process_resident_memory_bytes", "Resident memory size in bytes.").expect("static metric name");
    registry.register(Box::new(g.clone())).expect("registered once per registry");
    g
}

/// This process's resident memory in bytes (Linux: `VmRSS` of /proc/self/status), for
/// `process_resident_memory_bytes`.
pub fn resident_bytes() -> Option<u64> {
    proc_status_kib("self", "VmRSS:").map(|k| k * 1024)
}

/// A `kB` field of /proc/PID/status (`VmRSS:`, `VmHWM:` …) in KiB; `None` off Linux or
/// when the process is gone.
pub fn proc_status_kib(pid: &str, field: &str) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with(field))?;
    line[field.len()..].split_whitespace().next()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    async fn get(addr: std::net::SocketAddr, raw: &[u8]) -> String {
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        s.write_all(raw).await.unwrap();
        let mut out = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut out)).await;
        String::from_utf8_lossy(&out).into_owned()
    }

    #[tokio::test]
    async fn serves_metrics_and_survives_garbage() {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(serve_metrics(listener, Arc::new(|| "up 1\n".to_string())));
        let ok = get(addr, b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").await;
        assert!(ok.starts_with("HTTP/1.1 200") && ok.ends_with("up 1\n"), "{ok}");
        assert!(ok.contains("text/plain; version=0.0.4"), "{ok}");
        let missing = get(addr, b"GET /nope HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").await;
        assert!(missing.starts_with("HTTP/1.1 404"), "{missing}");
        let post = get(addr, b"POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\nConnection: close\r\n\r\n").await;
        assert!(post.starts_with("HTTP/1.1 405"), "{post}");
        let garbage = get(addr, b"\x00\xff\x13garbage\r\n\r\n").await;
        assert!(garbage.is_empty() || garbage.starts_with("HTTP/1.1 400"), "{garbage}");
        // An HTTP/2 preface on the HTTP/1 port is refused, and the endpoint still serves.
        let h2 = get(addr, b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n").await;
        assert!(!h2.contains("up 1"), "{h2}");
        let again = get(addr, b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").await;
        assert!(again.ends_with("up 1\n"), "{again}");
    }

    #[test]
    fn resident_memory_is_read_on_linux() {
        if cfg!(target_os = "linux") {
            assert!(resident_bytes().unwrap() > 1 << 20);
            assert!(proc_status_kib("self", "VmHWM:").unwrap() * 1024 >= resident_bytes().unwrap() / 2);
            assert!(proc_status_kib("self", "NoSuchField:").is_none());
        }
    }
}
