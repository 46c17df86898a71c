//! `edgepoint-bench split`: split shading (paper 004 §4.4) against splitting by pixels on the
//! same workers, in one process. Requests are built as a session builds them
//! (`session::build_batches`: jittered picks all over the image, batches of the session's
//! size, sibling batches per part with one seed) and the answers go through the session's
//! [`PartSums`], so a sample counts when it is complete — every part in, summed.
//!
//! Two loads, each for both ways of splitting:
//! - `light`: one batch of samples in flight at a time (a session whose workers keep up:
//!   what a sample's latency is when nothing queues). Split shading spreads the one batch
//!   over the workers; by pixels it goes to one worker.
//! - `saturated`: `--window` batches of samples in flight per worker (the workers always
//!   busy: samples/s is the capacity).
//!
//! Reported per run: complete samples per second and the latency from submitting a sample's
//! requests to its completion (median, 90th percentile), plus split / pixels ratios.
use crate::stats::{median, percentile};
use anyhow::{Context, Result};
use edgepoint_proto as pb;
use edgepoint_proto::split::SplitMode;
use edgepoint_server::rng::mix64;
use edgepoint_server::sampling::PixelRequest;
use edgepoint_server::session::split::{PartOutcome, PartSums};
use edgepoint_server::session::{build_batches, BatchSpec, RequestRing};
use edgepoint_server::workers::{Answer, Dispatcher, WorkerPool};
use edgepoint_viewer::client::scene_source_from_arg_in;
use edgepoint_viewer::local::{LocalCluster, LocalOptions};
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
pub struct SplitArgs {
    /// Built-in scene name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz).
    #[arg(long, default_value = "rooms")]
    pub scene: String,
    /// Shared data directory for built-ins made from data (default: $EDGEPOINT_DATA, else a
    /// shared/data directory above the working directory or the executable).
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Shader name.
    #[arg(long, default_value = "direct")]
    pub shader: String,
    /// Shader parameter KEY=VALUE (repeatable).
    #[arg(long = "shader-param", value_parser = crate::requests::parse_param)]
    pub shader_params: Vec<(String, f64)>,
    /// The split measured against splitting by pixels: `lights:N` (default: one part per
    /// worker).
    #[arg(long, value_name = "lights:N")]
    pub split: Option<SplitMode>,
    /// Shader-worker processes.
    #[arg(long, default_value_t = 2)]
    pub workers: usize,
    /// Threads per worker process.
    #[arg(long, default_value_t = 1)]
    pub worker_threads: usize,
    /// Samples per batch (the session's default batch size).
    #[arg(long, default_value_t = 256)]
    pub batch: usize,
    /// Batches of samples in flight per worker under the saturated load.
    #[arg(long, default_value_t = 4)]
    pub window: usize,
    /// Seconds of shading per run (four runs: two loads, two ways of splitting).
    #[arg(long, default_value_t = 4.0)]
    pub seconds: f64,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One run's figures.
struct Run {
    samples_per_s: f64,
    latency_ms: Vec<f64>,
    incomplete: usize,
}

pub fn run(a: SplitArgs) -> Result<()> {
    let split = a.split.unwrap_or(SplitMode::Lights(a.workers.clamp(2, 64) as u32));
    if split == SplitMode::Pixels {
        anyhow::bail!("--split must be lights:N with N >= 2 (it is measured against pixels)");
    }
    let source = scene_source_from_arg_in(&a.scene, a.data_dir.as_deref())?;
    let hash = pb::scene_hash(&source);
    let params: HashMap<String, f64> = a.shader_params.iter().cloned().collect();
    pb::shaders::resolve(&a.shader, &params).map_err(|e| anyhow::anyhow!(e))?;
    let scene = pb::scene_from_source(&source, &edgepoint_scene::NoProgress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let lights = scene.lights.len();
    let cam = scene.camera.frame(512, 512);
    let cluster = LocalCluster::start(LocalOptions {
        workers: a.workers.max(1),
        worker_threads: Some(a.worker_threads.max(1)),
        log_level: Some(std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into())),
        ..Default::default()
    })
    .context("starting workers (run `cargo build --release` first)")?;
    let endpoints: Vec<String> = cluster.worker_addrs().iter().map(|w| format!("http://{w}")).collect();
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    let results = rt.block_on(async {
        let pool = WorkerPool::new(endpoints)?;
        let d = pool.open(source.clone(), hash.clone());
        // Warm-up: every worker loads the scene and opens its stream (and a `gi` worker's
        // irradiance cache fills a little) before anything is timed.
        let mut job = Job::new(&cam, &a.shader, &params, a.batch, 1);
        measure(&d, &mut job, 2 * a.workers.max(1), Duration::from_secs_f64(a.seconds.min(2.0))).await?;
        let saturated = a.window.max(1) * a.workers.max(1);
        let mut out = Vec::new();
        // Alternated, so a change in the machine's load hits both ways alike.
        for (load, window) in [("light", 1), ("saturated", saturated)] {
            for mode in [SplitMode::Pixels, split] {
                let mut job = Job::new(&cam, &a.shader, &params, a.batch, mode.parts());
                let r = measure(&d, &mut job, window, Duration::from_secs_f64(a.seconds)).await?;
                out.push((load, mode, r));
            }
        }
        anyhow::Ok(out)
    })?;

    let row = |r: &Run| {
        json!({
            "samples_per_s": r.samples_per_s,
            "latency_median_ms": median(&r.latency_ms),
            "latency_p90_ms": percentile(&r.latency_ms, 90.0),
            "complete_samples": r.latency_ms.len(),
            "incomplete_at_end": r.incomplete,
        })
    };
    let mut loads = serde_json::Map::new();
    let mut table = format!(
        "split shading {} ({} lights) shader={} workers={} threads/worker={} batch={}: {} vs pixels\n",
        a.scene, lights, a.shader, a.workers, a.worker_threads, a.batch, split
    );
    for pair in results.chunks(2) {
        let (load, _, px) = &pair[0];
        let (_, mode, sp) = &pair[1];
        let ratio = |f: fn(&Run) -> f64| f(sp) / f(px);
        loads.insert(
            load.to_string(),
            json!({
                "pixels": row(px),
                mode.to_string(): row(sp),
                "samples_per_s_ratio": ratio(|r| r.samples_per_s),
                "latency_median_ratio": ratio(|r| median(&r.latency_ms)),
            }),
        );
        for (name, r) in [("pixels", px), (&mode.to_string()[..], sp)] {
            table += &format!(
                "  {load:<9} {name:<9} {:>9.0} samples/s  latency median {:>7.2} ms  p90 {:>7.2} ms\n",
                r.samples_per_s,
                median(&r.latency_ms),
                percentile(&r.latency_ms, 90.0)
            );
        }
        table += &format!(
            "  {load:<9} split/pixels: samples/s x{:.2}, median latency x{:.2}\n",
            ratio(|r| r.samples_per_s),
            ratio(|r| median(&r.latency_ms))
        );
    }
    let out = json!({
        "scene": a.scene,
        "lights": lights,
        "shader": a.shader,
        "shader_params": params,
        "split": split.to_string(),
        "workers": a.workers,
        "worker_threads": a.worker_threads,
        "batch": a.batch,
        "window_saturated": a.window * a.workers,
        "seconds": a.seconds,
        "loads": loads,
    });
    crate::emit(a.json, &out, &table);
    Ok(())
}

/// A stream of session-like request batches, split into `parts`.
struct Job<'a> {
    cam: edgepoint_scene::camera::CameraFrame,
    shader: &'a str,
    params: &'a HashMap<String, f64>,
    batch: usize,
    parts: u32,
    ring: RequestRing,
    next_batch: u64,
    seed: u64,
    rng: u64,
}

impl<'a> Job<'a> {
    fn new(cam: &edgepoint_scene::camera::CameraFrame, shader: &'a str, params: &'a HashMap<String, f64>, batch: usize, parts: u32) -> Self {
        Job { cam: *cam, shader, params, batch: batch.max(1), parts, ring: RequestRing::new(1 << 16), next_batch: 0, seed: 0x5eed, rng: 1 }
    }

    /// One batch of samples (as `parts` sibling request batches) at jittered pixels.
    fn next(&mut self, out: &mut Vec<pb::RequestBatch>) {
        let (w, h) = (self.cam.width, self.cam.height);
        let picks: Vec<PixelRequest> = (0..self.batch)
            .map(|_| {
                self.rng = mix64(self.rng);
                let (fx, fy) = ((self.rng >> 40) as f32 / (1u64 << 24) as f32, ((self.rng >> 16) & 0xff_ffff) as f32 / (1u64 << 24) as f32);
                let (sx, sy) = (fx * w as f32, fy * h as f32);
                PixelRequest { x: (sx as u32).min(w - 1), y: (sy as u32).min(h - 1), sx, sy, point: u32::MAX }
            })
            .collect();
        let spec = BatchSpec { epoch: 0, shader: self.shader, params: self.params, batch_size: self.batch, parts: self.parts, coherent: false };
        build_batches(&picks, &self.cam, &mut self.ring, &spec, &mut self.next_batch, &mut self.seed, out);
    }
}

/// Keeps `window` batches of samples in flight for `time`, then waits for what is in flight;
/// samples/s counts the samples completed within `time`.
async fn measure(d: &Dispatcher, job: &mut Job<'_>, window: usize, time: Duration) -> Result<Run> {
    let parts = job.parts;
    let mut sums = PartSums::new(parts);
    let mut submitted: HashMap<u64, Instant> = HashMap::new();
    let mut latency_ms = Vec::new();
    let mut batches = Vec::new();
    let in_flight_cap = (window * job.batch) as u64 * parts as u64;
    let start = Instant::now();
    let mut done_in_time = 0usize;
    loop {
        let open = start.elapsed() < time;
        while open && d.outstanding_requests() + (job.batch as u64 * parts as u64) <= in_flight_cap {
            batches.clear();
            job.next(&mut batches);
            let now = Instant::now();
            for b in batches.drain(..) {
                if b.requests.first().is_none_or(|r| r.part == 0) {
                    for r in &b.requests {
                        submitted.insert(r.id, now);
                    }
                }
                if !d.submit(b) {
                    anyhow::bail!("the dispatcher's queue refused a batch");
                }
            }
        }
        // Until every submitted sample is complete (not "nothing outstanding": the dispatcher
        // settles a batch a moment before its answer is queued).
        if !open && submitted.is_empty() {
            break;
        }
        let answer = tokio::time::timeout(Duration::from_secs(60), d.next_answer())
            .await
            .context("no answer from the workers for 60 s")?
            .context("dispatcher closed")?;
        let Answer::Samples { batch, .. } = answer else { anyhow::bail!("a batch was dropped") };
        let now = Instant::now();
        for s in &batch.samples {
            let id = match sums.add(batch.epoch, s) {
                PartOutcome::Complete(w, _) => w.id,
                PartOutcome::Waiting => continue,
                other => anyhow::bail!("sample {}: {other:?}", s.id),
            };
            if let Some(t) = submitted.remove(&id) {
                latency_ms.push(now.duration_since(t).as_secs_f64() * 1e3);
                if now.duration_since(start) <= time {
                    done_in_time += 1;
                }
            }
        }
    }
    Ok(Run { samples_per_s: done_in_time as f64 / time.as_secs_f64(), latency_ms, incomplete: sums.waiting() })
}
