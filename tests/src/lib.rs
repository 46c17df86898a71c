//! Helpers for the multi-process integration tests in `tests/tests/`.
//!
//! The tests spawn the real `edgepoint-server`, `edgepoint-worker` and `edgepoint-viewer`
//! binaries. `cargo test --workspace` builds them first (each binary's package has
//! integration tests of its own, so cargo builds its executables before running any test);
//! [`edgepoint_viewer::local::find_binary`] finds them next to the test executable.
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_viewer::client::{Event, SessionClient};
use std::time::{Duration, Instant};

pub use edgepoint_viewer::local::{LocalCluster, LocalOptions};

pub mod cdp;

/// Polls `cond` every 50 ms until it holds or `limit` has passed; whether it held.
pub fn wait_for(limit: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + limit;
    while Instant::now() < end {
        if cond() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    cond()
}

/// A suffix no other call in this process (nor a recent process) gives: temp names.
pub fn unique_suffix() -> String {
    static N: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.subsec_nanos()).unwrap_or(0);
    format!("{nanos:x}-{}", N.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
}

/// Starts a local cluster of `workers` shader workers and one server, with quiet logs.
pub fn cluster(workers: usize) -> Result<LocalCluster> {
    LocalCluster::start(LocalOptions {
        workers,
        worker_threads: Some(1),
        log_level: Some("warn".into()),
        ..Default::default()
    })
}

/// Runs the real viewer headless with a local cluster (`--local --headless --quiet`), `args`
/// and `--out out`, warnings only in its log; returns its exit status.
pub fn run_viewer_headless(args: &[&str], out: &std::path::Path) -> std::process::ExitStatus {
    let viewer = edgepoint_viewer::local::find_binary("edgepoint-viewer").expect("viewer binary built");
    std::process::Command::new(viewer)
        .args(["--local", "--headless", "--quiet"])
        .args(args)
        .arg("--out")
        .arg(out)
        .env("RUST_LOG", "warn")
        .status()
        .expect("viewer runs")
}

/// A `Start` for a built-in scene at a small size with QOI frames.
pub fn start_builtin(scene: &str, width: u32, height: u32) -> pb::Start {
    pb::Start {
        scene: Some(edgepoint_proto::builtin_source(scene)),
        width,
        height,
        shader: "direct".into(),
        encoding: pb::FrameEncoding::Qoi as i32,
        ..Default::default()
    }
}

/// Receives the next frame (skipping `rejected` notes, which are returned separately),
/// failing after `timeout`.
pub async fn next_frame(client: &mut SessionClient, timeout: Duration) -> Result<(pb::Frame, Vec<pb::Rejected>)> {
    let deadline = Instant::now() + timeout;
    let mut rejected = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            bail!("no frame within {timeout:?}");
        }
        match tokio::time::timeout(left, client.next_event()).await {
            Err(_) => bail!("no frame within {timeout:?}"),
            Ok(None) => bail!("session ended"),
            Ok(Some(Err(e))) => return Err(e).context("session failed"),
            Ok(Some(Ok(Event::Frame(f)))) => return Ok((f, rejected)),
            Ok(Some(Ok(Event::Rejected(r)))) => rejected.push(r),
            Ok(Some(Ok(Event::Progress(_) | Event::Picked(_)))) => {}
        }
    }
}

/// Starts a local cluster of `workers` workers (one shading thread each) with quiet logs,
/// after `tune` adjusted the options.
pub fn cluster_with(workers: usize, tune: impl FnOnce(&mut LocalOptions)) -> Result<LocalCluster> {
    let mut opts = LocalOptions { workers, worker_threads: Some(1), log_level: Some("warn".into()), ..Default::default() };
    tune(&mut opts);
    LocalCluster::start(opts)
}

/// `GET /metrics` from a metrics endpoint (plain HTTP/1.1 over a TCP stream).
pub async fn scrape(addr: std::net::SocketAddr) -> Result<String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let fetch = async {
        let mut s = tokio::net::TcpStream::connect(addr).await?;
        s.write_all(b"GET /metrics HTTP/1.1\r\nHost: edgepoint\r\nConnection: close\r\n\r\n").await?;
        let mut out = Vec::new();
        s.read_to_end(&mut out).await?;
        anyhow::Ok(String::from_utf8_lossy(&out).into_owned())
    };
    let text = tokio::time::timeout(Duration::from_secs(20), fetch).await.context("metrics scrape timed out")??;
    if !text.starts_with("HTTP/1.1 200") {
        bail!("metrics endpoint answered: {}", text.lines().next().unwrap_or(""));
    }
    Ok(text)
}

/// The value of the sample `series` (a metric name with its labels exactly as exported,
/// e.g. `edgepoint_server_workers_live`) in a Prometheus text exposition.
pub fn metric(text: &str, series: &str) -> Option<f64> {
    text.lines().find_map(|l| l.strip_prefix(series).and_then(|rest| rest.strip_prefix(' ')).and_then(|v| v.trim().parse().ok()))
}

/// `metric` of a freshly scraped endpoint.
pub async fn scrape_metric(addr: std::net::SocketAddr, series: &str) -> Result<f64> {
    let text = scrape(addr).await?;
    metric(&text, series).with_context(|| format!("no series `{series}` in the metrics of {addr}"))
}

/// Resident memory of process `pid` in KiB (Linux /proc).
pub fn rss_kib(pid: u32) -> Option<u64> {
    edgepoint_proto::metrics_http::proc_status_kib(&pid.to_string(), "VmRSS:")
}

/// Frames received by a watcher, with the longest gap between two of them.
#[derive(Debug, Default, Clone)]
pub struct Seen {
    pub frames: u64,
    pub samples: u64,
    pub max_gap: Duration,
    pub min_live: u32,
    pub max_live: u32,
    pub last: Option<pb::Frame>,
}

/// Receives frames until `done(frame)` holds or `timeout` passes (an error then), keeping
/// the longest gap between frames (measured from `since`, the previous frame's arrival).
pub async fn frames_until(
    client: &mut SessionClient,
    since: &mut Instant,
    timeout: Duration,
    mut done: impl FnMut(&pb::Frame, &Seen) -> bool,
) -> Result<Seen> {
    let deadline = Instant::now() + timeout;
    let mut seen = Seen { min_live: u32::MAX, ..Default::default() };
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let (f, _) = next_frame(client, left.max(Duration::from_millis(1))).await.with_context(|| format!("after {} frames", seen.frames))?;
        let now = Instant::now();
        seen.max_gap = seen.max_gap.max(now.duration_since(*since));
        *since = now;
        seen.frames += 1;
        seen.samples += f.samples_used as u64;
        seen.min_live = seen.min_live.min(f.live_workers);
        seen.max_live = seen.max_live.max(f.live_workers);
        let stop = done(&f, &seen);
        seen.last = Some(f);
        if stop {
            return Ok(seen);
        }
        if Instant::now() >= deadline {
            bail!("condition not met within {timeout:?} ({} frames seen)", seen.frames);
        }
    }
}

/// One edgepoint process started by hand (for set-ups `LocalCluster` does not make: TLS
/// workers, refused addresses). Killed when dropped.
pub struct Spawned {
    pub child: std::process::Child,
    pub addr: Option<std::net::SocketAddr>,
    pub metrics: Option<std::net::SocketAddr>,
    pub stderr: std::sync::Arc<std::sync::Mutex<String>>,
}

impl Spawned {
    /// Starts `bin` with `args` and waits (up to 60 s) for `listening <addr>`, or for it to
    /// exit; either way returns it (check `addr`).
    pub fn start(bin: &str, args: &[&str]) -> Result<Spawned> {
        use std::io::{BufRead, Read};
        let path = edgepoint_viewer::local::find_binary(bin)?;
        let mut child = std::process::Command::new(path)
            .args(args)
            .env("RUST_LOG", "warn")
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .with_context(|| format!("starting {bin}"))?;
        let stderr = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
        {
            let mut err = child.stderr.take().expect("piped");
            let buf = stderr.clone();
            std::thread::spawn(move || {
                let mut chunk = [0u8; 4096];
                while let Ok(n) = err.read(&mut chunk) {
                    if n == 0 {
                        break;
                    }
                    buf.lock().unwrap().push_str(&String::from_utf8_lossy(&chunk[..n]));
                }
            });
        }
        let (tx, rx) = std::sync::mpsc::channel();
        let out = child.stdout.take().expect("piped");
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(out).lines() {
                let Ok(line) = line else { break };
                let _ = tx.send(line);
            }
        });
        let mut s = Spawned { child, addr: None, metrics: None, stderr };
        let deadline = Instant::now() + Duration::from_secs(60);
        while let Ok(line) = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            if let Some(m) = line.strip_prefix("metrics ") {
                s.metrics = m.trim().parse().ok();
            } else if let Some(a) = line.strip_prefix("listening ") {
                s.addr = Some(a.trim().parse().context("listening address")?);
                break;
            }
        }
        Ok(s)
    }

    /// Waits for the process to exit (up to `timeout`); its status, or `None` if it runs on.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Ok(Some(st)) = self.child.try_wait() {
                return Some(st);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }

    /// What the process wrote on stderr so far.
    pub fn stderr(&self) -> String {
        self.stderr.lock().unwrap().clone()
    }
}

impl Drop for Spawned {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Deterministic pseudo-random bytes (xorshift), for garbage-input tests.
pub fn garbage(n: usize, seed: u64) -> Vec<u8> {
    let mut x = seed | 1;
    (0..n)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u8
        })
        .collect()
}

/// Connects to `addr`, sends `payload`, half-closes, and reads whatever comes back until the
/// peer closes (or 5 s pass). Panics only if nothing accepts the connection at all.
pub async fn attack(addr: std::net::SocketAddr, payload: &[u8]) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let Ok(Ok(mut s)) = tokio::time::timeout(Duration::from_secs(5), tokio::net::TcpStream::connect(addr)).await else {
        panic!("cannot connect to {addr} at all");
    };
    let _ = s.write_all(payload).await;
    let _ = s.shutdown().await;
    let mut buf = vec![0u8; 64 << 10];
    let _ = tokio::time::timeout(Duration::from_secs(5), async {
        while let Ok(n) = s.read(&mut buf).await {
            if n == 0 {
                break;
            }
        }
    })
    .await;
}
