//! A local cluster: N `edgepoint-worker` processes and one `edgepoint-server` wired to
//! them, started as children of this process (DESIGN.md, "Processes and data flow").
//!
//! Every child binds port 0 and reports its address with one `listening <addr>` line on
//! stdout (the launcher contract of COMMON.md), preceded by `metrics <addr>` when it serves
//! metrics. With [`LocalOptions::workers_file`] the server discovers the workers from a file
//! the cluster rewrites, so workers can be added while sessions run ([`LocalCluster::add_worker`]). The children die with the cluster: `Drop`
//! kills and reaps them; on Linux they also carry `PR_SET_PDEATHSIG(SIGKILL)` so a hard kill
//! of this process takes them along; and they run in their own process group so a terminal
//! Ctrl-C reaches only the viewer, which then shuts them down itself instead of racing them.
use anyhow::{anyhow, bail, Context, Result};
use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufRead, BufReader, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

/// File name of the shader worker binary.
pub const WORKER_BIN: &str = "edgepoint-worker";
/// File name of the render server binary.
pub const SERVER_BIN: &str = "edgepoint-server";
/// Environment variable naming a directory that holds the edgepoint binaries.
pub const BIN_DIR_ENV: &str = "EDGEPOINT_BIN_DIR";

/// How many of a child's last stderr lines an error message quotes.
const STDERR_TAIL_LINES: usize = 40;

/// What to start and how.
#[derive(Debug, Clone)]
pub struct LocalOptions {
    /// Number of shader workers (at least 1).
    pub workers: usize,
    /// `--threads N` for each worker; `None` lets the worker choose.
    pub worker_threads: Option<usize>,
    /// Extra arguments appended to the server's command line.
    pub server_args: Vec<String>,
    /// Extra arguments appended to every worker's command line.
    pub worker_args: Vec<String>,
    /// Directory searched first for the binaries (before [`find_binary`]'s search).
    pub bin_dir: Option<PathBuf>,
    /// `RUST_LOG` for the children; `None` passes this process's environment on.
    pub log_level: Option<String>,
    /// Append the children's stderr (prefixed with their name) to this file instead of
    /// forwarding it to this process's stderr.
    pub log_file: Option<PathBuf>,
    /// How long a child may take to print its `listening` line.
    pub startup_timeout: Duration,
    /// Give every child `--metrics-listen 127.0.0.1:0` (see [`LocalCluster::server_metrics_addr`]).
    pub metrics: bool,
    /// Point the server at a workers file that the cluster keeps up to date (re-read every
    /// 200 ms) instead of `--worker` flags, so [`LocalCluster::add_worker`] works.
    pub workers_file: bool,
    /// Niceness added to the worker processes (Unix; 0 = this process's priority). They
    /// share the machine with the server, whose frame loop is latency work while shading is
    /// throughput work: at a lower priority the workers take the cores the frame loop leaves
    /// (measured on 2 cores, 1024 x 1024: frame loop 108 -> 80 ms per frame, encode stage
    /// 17 -> 7 ms).
    pub worker_nice: i32,
    /// Run the worker processes under Linux's `SCHED_IDLE` policy as well: the kernel gives
    /// them only the time the server and viewer leave, and a waking server thread takes a
    /// core from a worker at once. With niceness alone a woken frame-loop or pool thread can
    /// wait for the running worker's time slice at every parallel stage (measured on 2
    /// cores, `edgepoint-bench frame --scene cornell` at 512²: encode stage 3.0–3.2 → 1.7–1.8
    /// ms with the faster QOI encoder, samples a frame unchanged). Ignored elsewhere.
    pub worker_idle: bool,
    /// Give the server `--web-listen ADDR`: the browser viewer (see [`LocalCluster::web_url`]).
    pub web: Option<String>,
}

/// Default [`LocalOptions::worker_nice`] (as the server's background pool).
pub const WORKER_NICE: i32 = 10;

impl Default for LocalOptions {
    fn default() -> Self {
        LocalOptions {
            workers: 2,
            worker_threads: None,
            web: None,
            server_args: Vec::new(),
            worker_args: Vec::new(),
            bin_dir: None,
            log_level: None,
            log_file: None,
            startup_timeout: Duration::from_secs(60),
            metrics: false,
            workers_file: false,
            worker_nice: WORKER_NICE,
            worker_idle: true,
        }
    }
}

/// A running local cluster. Dropping it kills and reaps every child.
pub struct LocalCluster {
    opts: LocalOptions,
    worker_bin: PathBuf,
    server_bin: PathBuf,
    /// Worker slots keep their address after a kill so a restart reuses the port.
    workers: Vec<WorkerSlot>,
    server: Option<ChildProc>,
    server_addr: SocketAddr,
    spawner: Spawner,
    log_sink: LogSink,
    /// The workers file and its directory (removed on drop), with `workers_file`.
    workers_file: Option<(PathBuf, PathBuf)>,
}

/// Interval at which a local server re-reads its workers file.
pub const WORKERS_FILE_INTERVAL_MS: u64 = 200;

struct WorkerSlot {
    addr: SocketAddr,
    proc: Option<ChildProc>,
}

impl LocalCluster {
    /// Starts `opts.workers` workers, waits for each to report its address, then starts the
    /// server pointed at all of them and waits for its address. On any failure the children
    /// started so far are killed and the error names the binary and quotes its stderr.
    pub fn start(opts: LocalOptions) -> Result<LocalCluster> {
        if opts.workers == 0 {
            bail!("a local cluster needs at least one worker (got --workers 0)");
        }
        let worker_bin = find_binary_in(WORKER_BIN, opts.bin_dir.as_deref())?;
        let server_bin = find_binary_in(SERVER_BIN, opts.bin_dir.as_deref())?;
        let log_sink = LogSink::new(opts.log_file.as_deref())?;
        let spawner = Spawner::new()?;
        let mut cluster = LocalCluster {
            opts,
            worker_bin,
            server_bin,
            workers: Vec::new(),
            server: None,
            server_addr: SocketAddr::from(([127, 0, 0, 1], 0)),
            spawner,
            log_sink,
            workers_file: None,
        };
        // Workers start concurrently (each loads nothing until asked, but process start-up
        // and their runtimes still take a moment); we then wait for each in turn.
        let mut pending = Vec::new();
        for i in 0..cluster.opts.workers {
            let args = cluster.worker_args("127.0.0.1:0");
            let label = format!("{WORKER_BIN} #{i}");
            pending.push(cluster.spawn_child(&label, &cluster.worker_bin.clone(), &args, cluster.worker_priority())?);
        }
        let mut pending = pending.into_iter();
        while let Some(p) = pending.next() {
            let (proc, addr) = match cluster.wait_listening(p) {
                Ok(x) => x,
                Err(e) => {
                    // Those not yet waited for are not in the cluster: its Drop misses them.
                    for mut rest in pending {
                        let _ = rest.child.kill();
                        let _ = rest.child.wait();
                    }
                    return Err(e);
                }
            };
            tracing::info!(worker = cluster.workers.len(), %addr, pid = proc.child.id(), "local worker listening");
            cluster.workers.push(WorkerSlot { addr, proc: Some(proc) });
        }
        let mut args = vec!["--listen".to_string(), "127.0.0.1:0".to_string()];
        if cluster.opts.workers_file {
            let dir = std::env::temp_dir().join(format!("edgepoint-cluster-{}-{}", std::process::id(), unique()));
            std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
            let file = dir.join("workers.txt");
            cluster.workers_file = Some((file.clone(), dir));
            cluster.write_workers_file()?;
            args.push("--workers-file".into());
            args.push(file.display().to_string());
            args.push("--discovery-interval-ms".into());
            args.push(WORKERS_FILE_INTERVAL_MS.to_string());
        } else {
            for w in &cluster.workers {
                args.push("--worker".into());
                args.push(format!("http://{}", w.addr));
            }
        }
        if cluster.opts.metrics {
            args.push("--metrics-listen".into());
            args.push("127.0.0.1:0".into());
        }
        if let Some(w) = &cluster.opts.web {
            args.push("--web-listen".into());
            args.push(w.clone());
        }
        args.extend(cluster.opts.server_args.iter().cloned());
        let p = cluster.spawn_child(SERVER_BIN, &cluster.server_bin.clone(), &args, Priority::default())?;
        let (proc, addr) = cluster.wait_listening(p)?;
        tracing::info!(%addr, pid = proc.child.id(), "local server listening");
        cluster.server = Some(proc);
        cluster.server_addr = addr;
        Ok(cluster)
    }

    /// The server's address.
    pub fn server_addr(&self) -> SocketAddr {
        self.server_addr
    }

    /// The server's URL for [`crate::SessionClient::connect`] (`http://127.0.0.1:PORT`).
    pub fn server_url(&self) -> String {
        format!("http://{}", self.server_addr)
    }

    /// The browser viewer's page URL (`http://127.0.0.1:PORT/`) when started with
    /// [`LocalOptions::web`].
    pub fn web_url(&self) -> Option<&str> {
        self.server.as_ref().and_then(|p| p.web.as_deref())
    }

    /// The workers' addresses, in start order (kept across kills and restarts).
    pub fn worker_addrs(&self) -> Vec<SocketAddr> {
        self.workers.iter().map(|w| w.addr).collect()
    }

    /// Number of worker slots.
    pub fn worker_count(&self) -> usize {
        self.workers.len()
    }

    /// Process id of worker `i`, `None` if it was killed (or `i` is out of range).
    pub fn pid(&self, i: usize) -> Option<u32> {
        self.workers.get(i)?.proc.as_ref().map(|p| p.child.id())
    }

    /// Process id of the server.
    pub fn server_pid(&self) -> Option<u32> {
        self.server.as_ref().map(|p| p.child.id())
    }

    /// Where the server serves metrics (with [`LocalOptions::metrics`]).
    pub fn server_metrics_addr(&self) -> Option<SocketAddr> {
        self.server.as_ref().and_then(|p| p.metrics)
    }

    /// Where worker `i` serves metrics (with [`LocalOptions::metrics`]; `None` once killed).
    pub fn worker_metrics_addr(&self, i: usize) -> Option<SocketAddr> {
        self.workers.get(i)?.proc.as_ref().and_then(|p| p.metrics)
    }

    /// The workers file the server reads (with [`LocalOptions::workers_file`]).
    pub fn workers_file(&self) -> Option<&Path> {
        self.workers_file.as_ref().map(|(f, _)| f.as_path())
    }

    /// Starts one more worker and, with [`LocalOptions::workers_file`], adds it to the
    /// server's pool by rewriting the file. Returns its index.
    pub fn add_worker(&mut self) -> Result<usize> {
        if self.workers_file.is_none() {
            bail!("add_worker needs LocalOptions::workers_file: the server was given a fixed --worker list");
        }
        let i = self.workers.len();
        let args = self.worker_args("127.0.0.1:0");
        let label = format!("{WORKER_BIN} #{i}");
        let p = self.spawn_child(&label, &self.worker_bin.clone(), &args, self.worker_priority())?;
        let (proc, addr) = self.wait_listening(p)?;
        tracing::info!(worker = i, %addr, pid = proc.child.id(), "local worker added");
        self.workers.push(WorkerSlot { addr, proc: Some(proc) });
        self.write_workers_file()?;
        Ok(i)
    }

    /// Writes every worker slot's address to the workers file, atomically (write + rename),
    /// so the server never reads half a file.
    fn write_workers_file(&self) -> Result<()> {
        let Some((file, dir)) = &self.workers_file else { return Ok(()) };
        let tmp = dir.join(format!("workers.txt.{}", unique()));
        let text: String = self.workers.iter().map(|w| format!("http://{}\n", w.addr)).collect();
        std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
        std::fs::rename(&tmp, file).with_context(|| format!("replacing {}", file.display()))?;
        Ok(())
    }

    /// Stops worker `i` with SIGSTOP: its process and connections stay, it answers nothing
    /// (a wedged machine, for failure tests). [`Self::continue_worker`] resumes it.
    pub fn stop_worker(&mut self, i: usize) -> Result<()> {
        self.signal_worker(i, Signal::Stop)
    }

    /// Resumes a worker stopped by [`Self::stop_worker`] (SIGCONT).
    pub fn continue_worker(&mut self, i: usize) -> Result<()> {
        self.signal_worker(i, Signal::Continue)
    }

    fn signal_worker(&mut self, i: usize, sig: Signal) -> Result<()> {
        let n = self.workers.len();
        let slot = self.workers.get(i).ok_or_else(|| anyhow!("no worker {i} (the cluster has {n})"))?;
        let pid = slot.proc.as_ref().map(|p| p.child.id()).ok_or_else(|| anyhow!("worker {i} is not running"))?;
        send_signal(pid, sig).with_context(|| format!("signalling worker {i} (pid {pid})"))?;
        tracing::info!(worker = i, pid, ?sig, "local worker signalled");
        Ok(())
    }

    /// Whether worker `i`'s process is still running.
    pub fn worker_alive(&mut self, i: usize) -> bool {
        match self.workers.get_mut(i).and_then(|w| w.proc.as_mut()) {
            Some(p) => matches!(p.child.try_wait(), Ok(None)),
            None => false,
        }
    }

    /// Kills worker `i` with SIGKILL and reaps it (a crash, for failure tests). Killing a
    /// worker that is already dead is a no-op.
    pub fn kill_worker(&mut self, i: usize) -> Result<()> {
        let n = self.workers.len();
        let slot = self.workers.get_mut(i).ok_or_else(|| anyhow!("no worker {i} (the cluster has {n})"))?;
        if let Some(mut p) = slot.proc.take() {
            p.kill_and_reap();
            tracing::info!(worker = i, addr = %slot.addr, "local worker killed");
        }
        Ok(())
    }

    /// Starts a new worker `i` on the same address as before (killing the old process
    /// first if it still runs), so the server's link to that address reconnects. The port
    /// may briefly be unavailable after the kill; binding is retried for a few seconds.
    pub fn restart_worker(&mut self, i: usize) -> Result<()> {
        self.kill_worker(i)?;
        let addr = self.workers[i].addr;
        let args = self.worker_args(&addr.to_string());
        let label = format!("{WORKER_BIN} #{i}");
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            let p = self.spawn_child(&label, &self.worker_bin.clone(), &args, self.worker_priority())?;
            match self.wait_listening(p) {
                Ok((proc, got)) => {
                    if got.port() != addr.port() {
                        let mut proc = proc;
                        proc.kill_and_reap();
                        bail!("{label} was asked to listen on {addr} but reported {got}");
                    }
                    tracing::info!(worker = i, %addr, pid = proc.child.id(), "local worker restarted");
                    self.workers[i].proc = Some(proc);
                    return Ok(());
                }
                Err(e) if Instant::now() < deadline => {
                    tracing::debug!("restarting {label} on {addr} failed, retrying: {e:#}");
                    thread::sleep(Duration::from_millis(200));
                }
                Err(e) => return Err(e.context(format!("restarting {label} on {addr}"))),
            }
        }
    }

    fn worker_args(&self, listen: &str) -> Vec<String> {
        let mut args = vec!["--listen".to_string(), listen.to_string()];
        if self.opts.metrics {
            args.push("--metrics-listen".into());
            args.push("127.0.0.1:0".into());
        }
        if let Some(t) = self.opts.worker_threads {
            args.push("--threads".into());
            args.push(t.to_string());
        }
        args.extend(self.opts.worker_args.iter().cloned());
        args
    }

    /// The priority workers start at (see [`LocalOptions::worker_nice`] and
    /// [`LocalOptions::worker_idle`]).
    fn worker_priority(&self) -> Priority {
        Priority { nice: self.opts.worker_nice, idle: self.opts.worker_idle }
    }

    /// Starts a child at `priority` below this process's.
    fn spawn_child(&self, label: &str, bin: &Path, args: &[String], priority: Priority) -> Result<PendingChild> {
        let mut cmd = Command::new(bin);
        cmd.args(args).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
        if let Some(level) = &self.opts.log_level {
            cmd.env("RUST_LOG", level);
        }
        die_with_parent(&mut cmd);
        lower_priority(&mut cmd, priority);
        let mut child = self
            .spawner
            .spawn(cmd)
            .with_context(|| format!("starting {label} ({})", bin.display()))?;
        let stdout = child.stdout.take().expect("stdout is piped");
        let stderr = child.stderr.take().expect("stderr is piped");
        let tail = Arc::new(Mutex::new(VecDeque::with_capacity(STDERR_TAIL_LINES)));
        let stderr_thread = {
            let tail = tail.clone();
            let sink = self.log_sink.clone();
            let prefix = format!("[{label}] ");
            thread::Builder::new().name(format!("{label} stderr")).spawn(move || {
                for line in BufReader::new(stderr).lines() {
                    let Ok(line) = line else { break };
                    sink.write_line(&prefix, &line);
                    let mut t = tail.lock().unwrap_or_else(|e| e.into_inner());
                    if t.len() == STDERR_TAIL_LINES {
                        t.pop_front();
                    }
                    t.push_back(line);
                }
            })?
        };
        let (tx, rx) = mpsc::channel();
        {
            let label = label.to_string();
            thread::Builder::new().name(format!("{label} stdout")).spawn(move || {
                let mut reported = false;
                for line in BufReader::new(stdout).lines() {
                    let Ok(line) = line else { break };
                    if !reported {
                        if let Some(rest) = line.trim().strip_prefix("metrics ") {
                            let _ = tx.send(StdoutEvent::Metrics(rest.trim().to_string()));
                            continue;
                        }
                        if let Some(rest) = line.trim().strip_prefix("web ") {
                            let _ = tx.send(StdoutEvent::Web(rest.trim().to_string()));
                            continue;
                        }
                        if let Some(rest) = line.trim().strip_prefix("listening ") {
                            reported = true;
                            let _ = tx.send(StdoutEvent::Listening(rest.trim().to_string()));
                            continue;
                        }
                    }
                    // Keep draining so the child never blocks on a full pipe.
                    tracing::debug!("{label} stdout: {line}");
                }
                let _ = tx.send(StdoutEvent::Closed);
            })?;
        }
        Ok(PendingChild {
            label: label.to_string(),
            bin: bin.to_path_buf(),
            child,
            tail,
            stderr_thread,
            stdout_events: rx,
        })
    }

    fn wait_listening(&self, p: PendingChild) -> Result<(ChildProc, SocketAddr)> {
        let PendingChild { label, bin, child, tail, stderr_thread, stdout_events } = p;
        let mut proc = ChildProc { child, tail, metrics: None, web: None };
        let timeout = self.opts.startup_timeout;
        let deadline = Instant::now() + timeout;
        let mut event = stdout_events.recv_timeout(timeout);
        loop {
            match &event {
                Ok(StdoutEvent::Metrics(m)) => proc.metrics = m.parse().ok(),
                Ok(StdoutEvent::Web(u)) => proc.web = Some(u.clone()),
                _ => break,
            }
            event = stdout_events.recv_timeout(deadline.saturating_duration_since(Instant::now()));
        }
        let outcome = match event {
            Ok(StdoutEvent::Listening(addr)) => match addr.parse::<SocketAddr>() {
                Ok(a) => return Ok((proc, a)),
                Err(e) => format!("printed `listening {addr}`, which is not a socket address ({e})"),
            },
            Ok(StdoutEvent::Metrics(_) | StdoutEvent::Web(_)) => unreachable!("metrics and web lines are consumed above"),
            Ok(StdoutEvent::Closed) | Err(mpsc::RecvTimeoutError::Disconnected) => {
                // Give the process a moment to exit and its stderr thread to drain.
                let deadline = Instant::now() + Duration::from_secs(2);
                let mut status = None;
                while Instant::now() < deadline {
                    if let Ok(Some(s)) = proc.child.try_wait() {
                        status = Some(s);
                        if stderr_thread.is_finished() {
                            break;
                        }
                    }
                    thread::sleep(Duration::from_millis(20));
                }
                match status {
                    Some(s) => format!("exited ({s}) before printing `listening <addr>`"),
                    None => "closed its stdout without printing `listening <addr>`".to_string(),
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {
                format!("did not print `listening <addr>` within {:.0} s", timeout.as_secs_f64())
            }
        };
        proc.kill_and_reap();
        let deadline = Instant::now() + Duration::from_secs(1);
        while !stderr_thread.is_finished() && Instant::now() < deadline {
            thread::sleep(Duration::from_millis(10));
        }
        let stderr = proc.stderr_tail();
        let stderr = if stderr.trim().is_empty() {
            "its stderr was empty".to_string()
        } else {
            format!("its stderr ended with:\n{stderr}")
        };
        bail!("{label} ({}) {outcome}; {stderr}", bin.display())
    }
}

impl Drop for LocalCluster {
    fn drop(&mut self) {
        // The server first, so it does not log reconnect attempts to dying workers.
        if let Some(mut s) = self.server.take() {
            s.kill_and_reap();
        }
        for w in &mut self.workers {
            if let Some(mut p) = w.proc.take() {
                p.kill_and_reap();
            }
        }
        if let Some((_, dir)) = &self.workers_file {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// A process-unique number for temporary names.
fn unique() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(0);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// Signals for failure tests.
#[derive(Debug, Clone, Copy)]
enum Signal {
    Stop,
    Continue,
}

#[cfg(unix)]
fn send_signal(pid: u32, sig: Signal) -> std::io::Result<()> {
    let s = match sig {
        Signal::Stop => libc::SIGSTOP,
        Signal::Continue => libc::SIGCONT,
    };
    // SAFETY: kill has no memory preconditions; the pid is our own child's.
    if unsafe { libc::kill(pid as libc::pid_t, s) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

#[cfg(not(unix))]
fn send_signal(_pid: u32, _sig: Signal) -> std::io::Result<()> {
    Err(std::io::Error::other("stopping processes needs Unix signals"))
}

impl std::fmt::Debug for LocalCluster {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LocalCluster")
            .field("server_addr", &self.server_addr)
            .field("worker_addrs", &self.worker_addrs())
            .finish()
    }
}

enum StdoutEvent {
    Metrics(String),
    Web(String),
    Listening(String),
    Closed,
}

struct PendingChild {
    label: String,
    bin: PathBuf,
    child: Child,
    tail: Arc<Mutex<VecDeque<String>>>,
    stderr_thread: thread::JoinHandle<()>,
    stdout_events: mpsc::Receiver<StdoutEvent>,
}

struct ChildProc {
    child: Child,
    tail: Arc<Mutex<VecDeque<String>>>,
    /// Its metrics endpoint, when it printed one.
    metrics: Option<SocketAddr>,
    /// Its browser viewer's URL, when it printed one (`web <url>`).
    web: Option<String>,
}

impl ChildProc {
    fn kill_and_reap(&mut self) {
        // std's kill() is SIGKILL on Unix; an error means it already exited.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    fn stderr_tail(&self) -> String {
        let t = self.tail.lock().unwrap_or_else(|e| e.into_inner());
        t.iter().map(String::as_str).collect::<Vec<_>>().join("\n")
    }
}

/// Where children's stderr lines go.
#[derive(Clone)]
enum LogSink {
    Stderr,
    File(Arc<Mutex<File>>),
}

impl LogSink {
    fn new(path: Option<&Path>) -> Result<LogSink> {
        Ok(match path {
            None => LogSink::Stderr,
            Some(p) => {
                let f = std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(p)
                    .with_context(|| format!("opening the cluster log file {}", p.display()))?;
                LogSink::File(Arc::new(Mutex::new(f)))
            }
        })
    }

    fn write_line(&self, prefix: &str, line: &str) {
        use std::io::IsTerminal;
        match self {
            LogSink::Stderr => {
                let mut e = std::io::stderr().lock();
                if e.is_terminal() {
                    let _ = writeln!(e, "{prefix}{line}");
                } else {
                    let _ = writeln!(e, "{prefix}{}", strip_ansi(line));
                }
            }
            LogSink::File(f) => {
                let mut f = f.lock().unwrap_or_else(|e| e.into_inner());
                let _ = writeln!(f, "{prefix}{}", strip_ansi(line));
            }
        }
    }
}

/// Removes ANSI escape sequences (CSI `ESC [ ... final`): children colour their logs even
/// into a pipe, and colour codes are noise in a file or a CI log.
fn strip_ansi(line: &str) -> std::borrow::Cow<'_, str> {
    if !line.contains('\x1b') {
        return std::borrow::Cow::Borrowed(line);
    }
    let mut out = String::with_capacity(line.len());
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        if c == '\x1b' && chars.peek() == Some(&'[') {
            chars.next();
            // Parameter and intermediate bytes, then one final byte in '@'..='~'.
            for d in chars.by_ref() {
                if ('@'..='~').contains(&d) {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    std::borrow::Cow::Owned(out)
}

/// A thread that lives as long as the cluster and forks every child.
///
/// Linux delivers PR_SET_PDEATHSIG when the *thread* that forked the child exits, not the
/// process. Forking from whatever thread calls us (a tokio blocking-pool thread retires
/// after 10 s idle) would kill children at random; this thread exits only when the cluster
/// is dropped, after the cluster has already killed its children.
struct Spawner {
    tx: mpsc::Sender<(Command, mpsc::Sender<std::io::Result<Child>>)>,
}

impl Spawner {
    fn new() -> Result<Spawner> {
        let (tx, rx) = mpsc::channel::<(Command, mpsc::Sender<std::io::Result<Child>>)>();
        thread::Builder::new().name("edgepoint-spawner".into()).spawn(move || {
            while let Ok((mut cmd, reply)) = rx.recv() {
                let _ = reply.send(cmd.spawn());
            }
        })?;
        Ok(Spawner { tx })
    }

    fn spawn(&self, cmd: Command) -> std::io::Result<Child> {
        let (rtx, rrx) = mpsc::channel();
        let gone = || std::io::Error::other("the spawner thread is gone");
        self.tx.send((cmd, rtx)).map_err(|_| gone())?;
        rrx.recv().map_err(|_| gone())?
    }
}

#[cfg(target_os = "linux")]
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: the closure runs between fork and exec and only makes async-signal-safe
    // system calls (prctl, getppid, setpgid), touching no memory but its captured pid.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong, 0, 0, 0) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent may have died between fork and prctl: then nobody would kill us.
            if libc::getppid() != parent {
                return Err(std::io::Error::other("the launching process exited during spawn"));
            }
            if libc::setpgid(0, 0) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

#[cfg(all(unix, not(target_os = "linux")))]
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    cmd.process_group(0);
}

#[cfg(not(unix))]
fn die_with_parent(_cmd: &mut Command) {}

/// How far below this process a child runs.
#[derive(Debug, Clone, Copy, Default)]
struct Priority {
    /// Niceness steps added (0: none).
    nice: i32,
    /// `SCHED_IDLE` (Linux only).
    idle: bool,
}

/// Starts the child at `priority` below this process's (its threads inherit it).
#[cfg(unix)]
fn lower_priority(cmd: &mut Command, priority: Priority) {
    use std::os::unix::process::CommandExt;
    let Priority { nice, idle } = priority;
    if nice <= 0 && !idle {
        return;
    }
    // SAFETY: the closure runs between fork and exec and only makes async-signal-safe
    // system calls (getpriority, setpriority, sched_setscheduler) on the child itself.
    unsafe {
        cmd.pre_exec(move || {
            // Failures are not fatal: the child then runs at a higher priority, that is all.
            if nice > 0 {
                let now = libc::getpriority(libc::PRIO_PROCESS, 0);
                let _ = libc::setpriority(libc::PRIO_PROCESS, 0, (now + nice).min(19));
            }
            #[cfg(not(target_os = "linux"))]
            let _ = idle;
            #[cfg(target_os = "linux")]
            if idle {
                let param = libc::sched_param { sched_priority: 0 };
                let _ = libc::sched_setscheduler(0, libc::SCHED_IDLE, &param);
            }
            Ok(())
        });
    }
}

#[cfg(not(unix))]
fn lower_priority(_cmd: &mut Command, _priority: Priority) {}

/// How to build the server and the worker when this viewer was started by `cargo run`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CargoBuild {
    pub cargo: PathBuf,
    /// Arguments after `cargo`: `build -p edgepoint-server -p edgepoint-worker` and the
    /// viewer's own profile.
    pub args: Vec<String>,
    /// Where to run it: the viewer's package directory (cargo finds the workspace).
    pub dir: PathBuf,
    /// The viewer's target directory, so the binaries land next to it.
    pub target_dir: PathBuf,
}

/// The build that makes the viewer's `edgepoint-server` and `edgepoint-worker` when the
/// viewer runs under `cargo run -p edgepoint-viewer` — cargo tells a program it runs by
/// setting `CARGO` (its own path) and the package's `CARGO_PKG_NAME` and
/// `CARGO_MANIFEST_DIR` — and nothing said where the binaries are (`--bin-dir`,
/// [`BIN_DIR_ENV`]). `None` otherwise: an installed viewer, or one started by a test or
/// another program, never builds anything. `env` reads the environment; `exe` is the
/// viewer's path (`target/<profile>/edgepoint-viewer`).
pub fn cargo_build_plan(env: &dyn Fn(&str) -> Option<String>, exe: &Path, bin_dir: Option<&Path>) -> Option<CargoBuild> {
    if bin_dir.is_some() || env(BIN_DIR_ENV).is_some_and(|d| !d.is_empty()) {
        return None;
    }
    let cargo = env("CARGO")?;
    if env("CARGO_PKG_NAME")? != env!("CARGO_PKG_NAME") {
        return None;
    }
    let dir = PathBuf::from(env("CARGO_MANIFEST_DIR")?);
    let profile_dir = exe.parent()?;
    let profile = profile_dir.file_name()?.to_str()?.to_string();
    let target_dir = profile_dir.parent()?.to_path_buf();
    let mut args: Vec<String> = ["build", "-p", SERVER_BIN, "-p", WORKER_BIN].map(String::from).into();
    match profile.as_str() {
        "debug" => {}
        "release" => args.push("--release".into()),
        other => args.extend(["--profile".to_string(), other.to_string()]),
    }
    Some(CargoBuild { cargo: PathBuf::from(cargo), args, dir, target_dir })
}

/// Under `cargo run` (see [`cargo_build_plan`]), builds `edgepoint-server` and
/// `edgepoint-worker` with the viewer's cargo, profile and target directory before a local
/// cluster starts, so `cargo run --release -p edgepoint-viewer` works on a fresh clone
/// without the viewer carrying the renderer and the shaders itself. Cargo decides what is
/// stale (a second run costs a second); its progress shows on stderr. Returns whether it
/// built.
pub fn build_under_cargo(bin_dir: Option<&Path>) -> Result<bool> {
    let exe = std::env::current_exe().context("locating this executable")?;
    let Some(plan) = cargo_build_plan(&|k| std::env::var(k).ok(), &exe, bin_dir) else { return Ok(false) };
    tracing::info!(
        "building {SERVER_BIN} and {WORKER_BIN} for the local cluster: {} {} (the first build takes a few minutes)",
        plan.cargo.display(),
        plan.args.join(" ")
    );
    let status = Command::new(&plan.cargo)
        .args(&plan.args)
        .current_dir(&plan.dir)
        .env("CARGO_TARGET_DIR", &plan.target_dir)
        .stdin(Stdio::null())
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit())
        .status()
        .with_context(|| format!("running {}", plan.cargo.display()))?;
    if !status.success() {
        bail!(
            "`cargo {}` failed ({status}); its output is above. Build them yourself, or point --bin-dir at existing binaries",
            plan.args.join(" ")
        );
    }
    Ok(true)
}

/// Finds an edgepoint binary: [`BIN_DIR_ENV`] (`EDGEPOINT_BIN_DIR`), the directory of the
/// current executable, that directory's parent (test executables live in
/// `target/<profile>/deps`), then `PATH`. The error lists every place it looked.
pub fn find_binary(name: &str) -> Result<PathBuf> {
    find_binary_in(name, None)
}

/// [`find_binary`], searching `first` before everything else when given.
pub fn find_binary_in(name: &str, first: Option<&Path>) -> Result<PathBuf> {
    let file = format!("{name}{}", std::env::consts::EXE_SUFFIX);
    let mut looked: Vec<String> = Vec::new();
    let mut candidates: Vec<(PathBuf, String)> = Vec::new();
    if let Some(d) = first {
        candidates.push((d.to_path_buf(), "--bin-dir".into()));
    }
    match std::env::var_os(BIN_DIR_ENV) {
        Some(d) if !d.is_empty() => candidates.push((PathBuf::from(d), BIN_DIR_ENV.into())),
        _ => looked.push(format!("{BIN_DIR_ENV} (not set)")),
    }
    if let Ok(exe) = std::env::current_exe() {
        if let Some(dir) = exe.parent() {
            candidates.push((dir.to_path_buf(), "directory of the current executable".into()));
            if let Some(up) = dir.parent() {
                candidates.push((up.to_path_buf(), "its parent".into()));
            }
        }
    }
    for (dir, why) in candidates {
        let p = dir.join(&file);
        if is_executable(&p) {
            return Ok(p);
        }
        looked.push(format!("{} ({why})", dir.display()));
    }
    match std::env::var_os("PATH") {
        Some(path) => {
            let dirs: Vec<PathBuf> = std::env::split_paths(&path).collect();
            for d in &dirs {
                let p = d.join(&file);
                if is_executable(&p) {
                    return Ok(p);
                }
            }
            looked.push(format!("PATH ({} directories)", dirs.len()));
        }
        None => looked.push("PATH (not set)".into()),
    }
    bail!(
        "cannot find the `{name}` binary; looked in:\n  {}\nbuild it with `cargo build --release` \
         (it lands in target/release/) and run the viewer from there, or set {BIN_DIR_ENV} to the \
         directory that holds it",
        looked.join("\n  ")
    )
}

fn is_executable(p: &Path) -> bool {
    let Ok(meta) = std::fs::metadata(p) else { return false };
    if !meta.is_file() {
        return false;
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        meta.permissions().mode() & 0o111 != 0
    }
    #[cfg(not(unix))]
    {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cargo_run_of_the_viewer_builds_server_and_worker_with_its_profile() {
        let env = |vars: &'static [(&'static str, &'static str)]| move |k: &str| vars.iter().find(|(n, _)| *n == k).map(|(_, v)| v.to_string());
        let run_by_cargo: &[(&str, &str)] = &[("CARGO", "/c/bin/cargo"), ("CARGO_PKG_NAME", "edgepoint-viewer"), ("CARGO_MANIFEST_DIR", "/src/ep/viewer")];
        let exe = Path::new("/tmp/t/release/edgepoint-viewer");
        let plan = cargo_build_plan(&env(run_by_cargo), exe, None).expect("a plan under cargo run");
        assert_eq!(plan.cargo, Path::new("/c/bin/cargo"));
        assert_eq!(plan.args, ["build", "-p", "edgepoint-server", "-p", "edgepoint-worker", "--release"]);
        assert_eq!((plan.dir.as_path(), plan.target_dir.as_path()), (Path::new("/src/ep/viewer"), Path::new("/tmp/t")));
        let debug = cargo_build_plan(&env(run_by_cargo), Path::new("/x/target/debug/edgepoint-viewer"), None).unwrap();
        assert!(!debug.args.contains(&"--release".to_string()));
        let custom = cargo_build_plan(&env(run_by_cargo), Path::new("/x/target/bench/edgepoint-viewer"), None).unwrap();
        assert!(custom.args.ends_with(&["--profile".to_string(), "bench".to_string()]));
        // Not under cargo run of the viewer: an installed viewer, a test running it, or
        // binaries named explicitly.
        assert!(cargo_build_plan(&env(&[]), exe, None).is_none());
        let test: &[(&str, &str)] = &[("CARGO", "/c/bin/cargo"), ("CARGO_PKG_NAME", "edgepoint-tests"), ("CARGO_MANIFEST_DIR", "/src/ep/tests")];
        assert!(cargo_build_plan(&env(test), exe, None).is_none());
        assert!(cargo_build_plan(&env(run_by_cargo), exe, Some(Path::new("/bin"))).is_none());
        let with_env: &[(&str, &str)] = &[("CARGO", "/c"), ("CARGO_PKG_NAME", "edgepoint-viewer"), ("CARGO_MANIFEST_DIR", "/v"), ("EDGEPOINT_BIN_DIR", "/b")];
        assert!(cargo_build_plan(&env(with_env), exe, None).is_none());
    }

    #[test]
    fn strips_colour_codes_only() {
        let coloured = "\x1b[2m2026-11-23T04:02:07Z\x1b[0m \x1b[32m INFO\x1b[0m edgepoint: serving \x1b[3maddr\x1b[0m\x1b[2m=\x1b[0m1.2.3.4:5";
        assert_eq!(strip_ansi(coloured), "2026-11-23T04:02:07Z  INFO edgepoint: serving addr=1.2.3.4:5");
        assert_eq!(strip_ansi("plain [text] here"), "plain [text] here");
        assert_eq!(strip_ansi("cut \x1b[3"), "cut ");
    }
}
