//! `edgepoint-bench loadtest`: the system under load, as an operator scaling out sees it.
//!
//! Three phases, each optional (`--phases`):
//! - `workers`: K worker processes driven at full rate through the real pool and dispatcher
//!   (every worker kept at `--window` batches in flight): samples/s, p50/p99 batch latency
//!   (submission to answer) and the scaling from 1 to K workers.
//! - `sessions`: S concurrent viewer sessions against one server backed by the K workers:
//!   fps per session, frames dropped (latest-frame-wins replacements), the longest gap
//!   between frames, and the server's memory (VmRSS sampled from /proc, and its peak).
//! - `failover`: one session while worker 0 is killed (-9) and restarted, then stopped
//!   (SIGSTOP) and continued: the longest frame gap in each window (at the viewer and in the
//!   server's frame loop), and how long the worker took to rejoin (until every worker is live
//!   again in the frames' `live_workers`).
//!
//! Everything runs on this machine (loopback); figures are ratios and spreads, not promises.
use crate::requests::{to_wire, RayGen};
use crate::stats::{mean, percentile};
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_server::workers::{Answer, WorkerPool};
use edgepoint_viewer::client::{scene_source_from_arg, Event, SessionClient};
use edgepoint_viewer::local::{LocalCluster, LocalOptions};
use serde_json::{json, Value};
use std::collections::HashMap;
use std::time::{Duration, Instant};

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Phase {
    Workers,
    Sessions,
    Failover,
}

#[derive(clap::Args, Debug)]
pub struct LoadtestArgs {
    /// Built-in scene name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz).
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Worker processes (the workers phase measures 1..=K).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub workers: u32,
    /// Threads per worker process.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=256))]
    pub worker_threads: u32,
    /// Shader name.
    #[arg(long, default_value = "direct")]
    pub shader: String,
    /// Shader parameter KEY=VALUE (repeatable).
    #[arg(long = "shader-param", value_parser = crate::requests::parse_param)]
    pub shader_params: Vec<(String, f64)>,
    /// Requests per batch in the workers phase.
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=65536))]
    pub batch: u32,
    /// Batches in flight per worker in the workers phase.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub window: u32,
    /// Seconds per measurement of the workers phase.
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
    /// Concurrent viewer sessions in the sessions phase.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub sessions: u32,
    /// Seconds the sessions phase runs.
    #[arg(long, default_value_t = 20.0)]
    pub session_seconds: f64,
    /// Frame size of every session.
    #[arg(long, default_value_t = 128)]
    pub width: u32,
    #[arg(long, default_value_t = 96)]
    pub height: u32,
    /// Frame-rate cap of every session (the server's default is 30).
    #[arg(long, default_value_t = 30.0)]
    pub max_fps: f64,
    /// Camera of every session, overriding the scene's: any subset of "eye=X,Y,Z
    /// target=X,Y,Z up=X,Y,Z fov=DEG" (the viewer's --camera).
    #[arg(long, value_name = "KEYS", value_parser = edgepoint_viewer::camera_path::parse_camera_spec)]
    pub camera: Option<edgepoint_viewer::CameraSpec>,
    /// Seconds of each failover window (before, after the kill, after the restart, while
    /// stopped, after continuing).
    #[arg(long, default_value_t = 4.0)]
    pub failover_seconds: f64,
    /// Phases to run, comma-separated.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [Phase::Workers, Phase::Sessions, Phase::Failover])]
    pub phases: Vec<Phase>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: LoadtestArgs) -> Result<()> {
    if !(a.seconds > 0.0 && a.session_seconds > 0.0 && a.failover_seconds > 0.0 && a.max_fps > 0.0) {
        bail!("--seconds, --session-seconds, --failover-seconds and --max-fps must be positive");
    }
    let source = scene_source_from_arg(&a.scene)?;
    let mut cluster = LocalCluster::start(LocalOptions {
        workers: a.workers as usize,
        worker_threads: Some(a.worker_threads as usize),
        log_level: Some(std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into())),
        metrics: true,
        server_args: vec!["--max-sessions".into(), (a.sessions.max(1) + 1).to_string()],
        ..Default::default()
    })
    .context("starting the local cluster (run `cargo build --release` first)")?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    let mut out = json!({
        "scene": a.scene, "shader": a.shader, "workers": a.workers, "worker_threads": a.worker_threads,
    });
    let mut table = format!("loadtest {} shader={} workers={} threads/worker={}\n", a.scene, a.shader, a.workers, a.worker_threads);
    if a.phases.contains(&Phase::Workers) {
        let (v, t) = rt.block_on(workers_phase(&a, &cluster, &source))?;
        out["workers_phase"] = v;
        table += &t;
    }
    if a.phases.contains(&Phase::Sessions) {
        let (v, t) = rt.block_on(sessions_phase(&a, &cluster, &source))?;
        out["sessions_phase"] = v;
        table += &t;
    }
    if a.phases.contains(&Phase::Failover) {
        if a.workers < 2 {
            bail!("the failover phase needs --workers 2 or more");
        }
        let (v, t) = failover_phase(&a, &rt, &mut cluster, &source)?;
        out["failover_phase"] = v;
        table += &t;
    }
    crate::emit(a.json, &out, &table);
    Ok(())
}

async fn workers_phase(a: &LoadtestArgs, cluster: &LocalCluster, source: &pb::SceneSource) -> Result<(Value, String)> {
    let hash = pb::scene_hash(source);
    let scene = pb::scene_from_source(source, &edgepoint_scene::NoProgress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let params: HashMap<String, f64> = a.shader_params.iter().cloned().collect();
    let endpoints: Vec<String> = cluster.worker_addrs().iter().map(|w| format!("http://{w}")).collect();
    let mut runs = Vec::new();
    for k in 1..=endpoints.len() {
        let pool = WorkerPool::new(endpoints[..k].to_vec())?;
        let d = pool.open(source.clone(), hash.clone());
        let mut gen = RayGen::new(&scene.camera, 17 + k as u64);
        // Warm-up: scenes loaded, streams open, batch sizes and limits measured.
        let warm: Vec<_> = (0..k as u64 * 4).map(|i| to_wire(i + 1, 0, &a.shader, &params, gen.batch(a.batch as usize))).collect();
        d.shade_all(warm, k * 4, Duration::from_secs(120), |_| {}).await.context("warm-up")?;
        // In requests: a batch may come back in parts when a worker splits it.
        let window = a.window as usize * k * a.batch as usize;
        let mut next = 1_000u64;
        let mut outstanding = 0usize;
        let (mut samples, mut latencies) = (0u64, Vec::new());
        let t0 = Instant::now();
        let deadline = Duration::from_secs_f64(a.seconds);
        loop {
            while outstanding < window && t0.elapsed() < deadline {
                next += 1;
                if !d.submit(to_wire(next, 0, &a.shader, &params, gen.batch(a.batch as usize))) {
                    break;
                }
                outstanding += a.batch as usize;
            }
            if outstanding == 0 {
                break;
            }
            match tokio::time::timeout(Duration::from_secs(60), d.next_answer()).await {
                Ok(Some(Answer::Samples { batch, requests, latency, .. })) => {
                    outstanding = outstanding.saturating_sub(requests);
                    if t0.elapsed() < deadline {
                        samples += batch.samples.len() as u64;
                        latencies.push(latency.as_secs_f64() * 1e3);
                    }
                }
                Ok(Some(Answer::Dropped { requests, .. })) => outstanding = outstanding.saturating_sub(requests),
                _ => bail!("no answer for 60 s with {k} workers ({} live)", d.live_workers()),
            }
        }
        let rate = samples as f64 / deadline.as_secs_f64();
        let status = d.worker_status();
        runs.push(json!({
            "workers": k,
            "samples_per_s": rate,
            "batch_latency_ms_p50": percentile(&latencies, 50.0),
            "batch_latency_ms_p99": percentile(&latencies, 99.0),
            "batches": latencies.len(),
            "per_worker_samples": status.iter().map(|w| w.samples).collect::<Vec<_>>(),
            "per_worker_batch_size": status.iter().map(|w| w.batch_size).collect::<Vec<_>>(),
            "per_worker_in_flight_limit": status.iter().map(|w| w.in_flight_limit).collect::<Vec<_>>(),
        }));
    }
    let one = runs[0]["samples_per_s"].as_f64().unwrap_or(0.0).max(1e-9);
    let mut table = format!("workers phase: batch={} window={}/worker, {:.1} s each\n", a.batch, a.window, a.seconds);
    for r in runs.iter_mut() {
        let s = r["samples_per_s"].as_f64().unwrap_or(0.0);
        r["scaling"] = json!(s / one);
        table += &format!(
            "  {} worker(s): {:.0} samples/s (x{:.2}), batch latency p50 {:.1} ms, p99 {:.1} ms\n",
            r["workers"], s, s / one, r["batch_latency_ms_p50"].as_f64().unwrap_or(0.0), r["batch_latency_ms_p99"].as_f64().unwrap_or(0.0)
        );
    }
    Ok((json!({ "batch": a.batch, "window_per_worker": a.window, "seconds": a.seconds, "runs": runs }), table))
}

fn session_start(a: &LoadtestArgs, source: &pb::SceneSource) -> pb::Start {
    crate::frame::start_message(source, (a.width, a.height), (&a.shader, &a.shader_params), a.camera.as_ref(), pb::Settings { max_fps: a.max_fps, ..Default::default() })
}

/// What one session saw.
#[derive(Debug, Default, Clone)]
struct SessionLog {
    frames: u64,
    dropped: u64,
    samples: u64,
    max_gap_ms: f64,
    seconds: f64,
}

async fn run_session(url: String, start: pb::Start, seconds: f64) -> Result<SessionLog> {
    let (mut c, _) = SessionClient::connect(&url, start).await?;
    let t0 = Instant::now();
    let mut log = SessionLog::default();
    let mut last = None::<Instant>;
    let end = Duration::from_secs_f64(seconds);
    while t0.elapsed() < end {
        let left = end.saturating_sub(t0.elapsed());
        let ev = match tokio::time::timeout(left, c.next_event()).await {
            Err(_) => break,
            Ok(None) => bail!("the session ended"),
            Ok(Some(ev)) => ev?,
        };
        if let Event::Frame(f) = ev {
            let now = Instant::now();
            if let Some(l) = last.replace(now) {
                log.max_gap_ms = log.max_gap_ms.max(now.duration_since(l).as_secs_f64() * 1e3);
            }
            log.frames += 1;
            log.dropped = f.frames_dropped;
            log.samples += f.samples_used as u64;
        }
    }
    log.seconds = t0.elapsed().as_secs_f64();
    Ok(log)
}

fn rss_kib(pid: Option<u32>, field: &str) -> Option<u64> {
    edgepoint_proto::metrics_http::proc_status_kib(&pid?.to_string(), field)
}

async fn sessions_phase(a: &LoadtestArgs, cluster: &LocalCluster, source: &pb::SceneSource) -> Result<(Value, String)> {
    let url = cluster.server_url();
    let pid = cluster.server_pid();
    let rss_before = rss_kib(pid, "VmRSS:");
    let mut tasks = Vec::new();
    for _ in 0..a.sessions {
        tasks.push(tokio::spawn(run_session(url.clone(), session_start(a, source), a.session_seconds)));
    }
    let mut rss = Vec::new();
    let t0 = Instant::now();
    while tasks.iter().any(|t| !t.is_finished()) {
        if let Some(k) = rss_kib(pid, "VmRSS:") {
            rss.push((t0.elapsed().as_secs_f64(), k));
        }
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    let mut logs = Vec::new();
    for t in tasks {
        logs.push(t.await.context("session task")??);
    }
    let fps: Vec<f64> = logs.iter().map(|l| l.frames as f64 / l.seconds.max(1e-9)).collect();
    let dropped: u64 = logs.iter().map(|l| l.dropped).sum();
    let peak = rss.iter().map(|r| r.1).max().unwrap_or(0);
    let hwm = rss_kib(pid, "VmHWM:");
    // Flat memory: the last third of the run against the middle third.
    let third = |lo: f64, hi: f64| {
        let v: Vec<f64> = rss.iter().filter(|r| r.0 >= lo * a.session_seconds && r.0 < hi * a.session_seconds).map(|r| r.1 as f64).collect();
        mean(&v)
    };
    let (mid, late) = (third(1.0 / 3.0, 2.0 / 3.0), third(2.0 / 3.0, 2.0));
    let v = json!({
        "sessions": a.sessions, "width": a.width, "height": a.height, "max_fps": a.max_fps, "seconds": a.session_seconds,
        "fps_per_session": fps,
        "fps_mean": mean(&fps),
        "fps_min": fps.iter().cloned().fold(f64::INFINITY, f64::min),
        "fps_max": fps.iter().cloned().fold(0.0, f64::max),
        "frames_dropped_total": dropped,
        "max_frame_gap_ms": logs.iter().map(|l| l.max_gap_ms).fold(0.0, f64::max),
        "samples_per_session_per_s": mean(&logs.iter().map(|l| l.samples as f64 / l.seconds.max(1e-9)).collect::<Vec<_>>()),
        "server_rss_kib_before": rss_before,
        "server_rss_kib_peak_sampled": peak,
        "server_rss_kib_hwm": hwm,
        "server_rss_kib_mean_middle_third": mid,
        "server_rss_kib_mean_last_third": late,
        // One reading per second: (seconds into the run, KiB).
        "server_rss_kib_per_second": rss.iter().step_by(4).map(|r| json!([(r.0 * 10.0).round() / 10.0, r.1])).collect::<Vec<_>>(),
    });
    let table = format!(
        "sessions phase: {} sessions of {}x{} at <= {} fps for {:.0} s\n  fps per session: mean {:.1}, min {:.1}, max {:.1}; frames dropped {}; longest frame gap {:.0} ms\n  server RSS: {} KiB before, peak {} KiB (VmHWM {} KiB), middle third {:.0} KiB, last third {:.0} KiB\n",
        a.sessions, a.width, a.height, a.max_fps, a.session_seconds,
        v["fps_mean"].as_f64().unwrap_or(0.0), v["fps_min"].as_f64().unwrap_or(0.0), v["fps_max"].as_f64().unwrap_or(0.0),
        dropped, v["max_frame_gap_ms"].as_f64().unwrap_or(0.0),
        rss_before.unwrap_or(0), peak, hwm.unwrap_or(0), mid, late
    );
    Ok((v, table))
}

/// Frames of one session as they arrive, with the gaps measured per window.
struct Watch {
    client: SessionClient,
    workers: u32,
    last_rx: Option<Instant>,
    last_sim: Option<f64>,
}

/// One failover window's figures.
#[derive(Debug, Default)]
struct Window {
    frames: u64,
    samples: u64,
    max_gap_ms: f64,
    max_loop_gap_ms: f64,
    /// Seconds into the window of the first frame with every worker live (if any).
    all_live_after_s: Option<f64>,
    /// Seconds into the window of the first frame with a worker missing (if any).
    degraded_after_s: Option<f64>,
    min_live: u32,
}

impl Watch {
    async fn window(&mut self, seconds: f64) -> Result<Window> {
        let t0 = Instant::now();
        let end = Duration::from_secs_f64(seconds);
        let mut w = Window { min_live: u32::MAX, ..Default::default() };
        while t0.elapsed() < end {
            let left = end.saturating_sub(t0.elapsed());
            let ev = match tokio::time::timeout(left, self.client.next_event()).await {
                Err(_) => break,
                Ok(None) => bail!("the session ended"),
                Ok(Some(ev)) => ev?,
            };
            let Event::Frame(f) = ev else { continue };
            let now = Instant::now();
            if let Some(l) = self.last_rx.replace(now) {
                w.max_gap_ms = w.max_gap_ms.max(now.duration_since(l).as_secs_f64() * 1e3);
            }
            if let Some(s) = self.last_sim.replace(f.sim_time) {
                w.max_loop_gap_ms = w.max_loop_gap_ms.max((f.sim_time - s) * 1e3);
            }
            w.frames += 1;
            w.samples += f.samples_used as u64;
            w.min_live = w.min_live.min(f.live_workers);
            if f.live_workers >= self.workers && w.all_live_after_s.is_none() {
                w.all_live_after_s = Some(t0.elapsed().as_secs_f64());
            }
            if f.live_workers < self.workers && w.degraded_after_s.is_none() {
                w.degraded_after_s = Some(t0.elapsed().as_secs_f64());
            }
        }
        Ok(w)
    }
}

fn window_json(name: &str, w: &Window) -> Value {
    json!({
        "window": name, "frames": w.frames, "samples": w.samples,
        "max_frame_gap_ms": w.max_gap_ms, "max_frame_loop_gap_ms": w.max_loop_gap_ms,
        "min_live_workers": w.min_live, "all_live_after_s": w.all_live_after_s, "degraded_after_s": w.degraded_after_s,
    })
}

fn failover_phase(a: &LoadtestArgs, rt: &tokio::runtime::Runtime, cluster: &mut LocalCluster, source: &pb::SceneSource) -> Result<(Value, String)> {
    let url = cluster.server_url();
    let (client, _) = rt.block_on(SessionClient::connect(&url, session_start(a, source)))?;
    let mut watch = Watch { client, workers: a.workers, last_rx: None, last_sim: None };
    let s = a.failover_seconds;
    let mut windows = Vec::new();
    windows.push(("before", rt.block_on(watch.window(s))?));
    cluster.kill_worker(0)?;
    windows.push(("killed", rt.block_on(watch.window(s))?));
    let restart_at = Instant::now();
    cluster.restart_worker(0)?;
    let restart_ms = restart_at.elapsed().as_secs_f64() * 1e3;
    windows.push(("restarted", rt.block_on(watch.window(s))?));
    cluster.stop_worker(0)?;
    windows.push(("stopped", rt.block_on(watch.window(s))?));
    cluster.continue_worker(0)?;
    windows.push(("continued", rt.block_on(watch.window(s))?));
    let interval_ms = 1e3 / a.max_fps;
    let mut table = format!("failover phase: one {}x{} session, worker 0 killed/restarted then stopped/continued, {:.0} s windows (frame interval {:.0} ms)\n", a.width, a.height, s, interval_ms);
    for (name, w) in &windows {
        table += &format!(
            "  {name:>9}: {} frames, {} samples, longest gap {:.0} ms at the viewer / {:.0} ms in the frame loop, live workers >= {}{}{}\n",
            w.frames,
            w.samples,
            w.max_gap_ms,
            w.max_loop_gap_ms,
            w.min_live,
            w.degraded_after_s.map(|t| format!(", a worker missing from {t:.2} s")).unwrap_or_default(),
            w.all_live_after_s.map(|t| format!(", all live from {t:.2} s")).unwrap_or_default()
        );
    }
    table += &format!("  (the restart itself — process start until it printed `listening` — took {restart_ms:.0} ms of the `restarted` window's lead-in)\n");
    let v = json!({
        "seconds_per_window": s,
        "frame_interval_ms": interval_ms,
        "worker_restart_ms": restart_ms,
        "windows": windows.iter().map(|(n, w)| window_json(n, w)).collect::<Vec<_>>(),
    });
    Ok((v, table))
}
