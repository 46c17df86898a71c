//! `edgepoint-bench throughput`: how many samples per second K shader workers deliver for a
//! shader at batch size B, how that scales from 1 to K workers, and what the gRPC path costs
//! against calling the same shader in this process with the same number of threads.
use anyhow::{Context, Result};
use edgepoint_server::workers::WorkerPool;
use edgepoint_viewer::client::scene_source_from_arg;
use edgepoint_viewer::local::{LocalCluster, LocalOptions};
use crate::requests::{to_wire, RayGen};
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, ShaderSpec};
use serde_json::json;
use std::collections::HashMap;
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
pub struct ThroughputArgs {
    /// Built-in scene name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz).
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Largest number of worker processes (runs 1..=K).
    #[arg(long, default_value_t = 2)]
    pub workers: usize,
    /// Threads per worker process, and of the in-process baseline.
    #[arg(long, default_value_t = 1)]
    pub worker_threads: usize,
    /// Requests per batch.
    #[arg(long, default_value_t = 256)]
    pub batch: usize,
    /// Batches in flight at once per worker.
    #[arg(long, default_value_t = 4)]
    pub window: usize,
    /// Shader name.
    #[arg(long, default_value = "direct")]
    pub shader: String,
    /// Shader parameter KEY=VALUE (repeatable).
    #[arg(long = "shader-param", value_parser = crate::requests::parse_param)]
    pub shader_params: Vec<(String, f64)>,
    /// Seconds of shading per measurement.
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Distinct ray batches the in-process baseline cycles through.
const PREPARED_BATCHES: usize = 64;

pub fn run(a: ThroughputArgs) -> Result<()> {
    let source = scene_source_from_arg(&a.scene)?;
    let hash = edgepoint_proto::scene_hash(&source);
    let params: HashMap<String, f64> = a.shader_params.iter().cloned().collect();
    let spec = ShaderSpec::parse(&a.shader, &params).map_err(|e| anyhow::anyhow!(e))?;
    let scene = edgepoint_proto::scene_from_source(&source, &edgepoint_scene::NoProgress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let camera = scene.camera;

    // In-process baseline: the shader called directly, same thread count as one worker. It is
    // measured before and after the gRPC runs and the better figure kept, so a noisy
    // neighbour on the machine during one of them does not flatter the gRPC path.
    let transforms: Vec<_> = scene.objects.iter().map(|o| o.transform).collect();
    let loaded = LoadedScene::build(scene, hash.clone(), &edgepoint_scene::NoProgress);
    let inst = loaded.instances(&transforms);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.worker_threads.max(1)).build()?;
    // Rays are made before the clock starts (the gRPC runs make them on this process while
    // the workers shade, so they cost the workers nothing): only shading is timed here.
    let mut gen = RayGen::new(&camera, 7);
    let prepared: Vec<Vec<RayRequest>> = (0..PREPARED_BATCHES).map(|_| gen.batch(a.batch)).collect();
    let deadline = Duration::from_secs_f64(a.seconds);
    // The whole loop runs inside the pool: entering the pool once per batch would add a
    // thread hand-off and an idle gap per batch that the workers, with batches queued, never
    // pay.
    let in_process = || {
        pool.install(|| {
            let (mut n, t) = (0u64, Instant::now());
            let mut seed = 0u64;
            while t.elapsed() < deadline {
                let reqs = &prepared[seed as usize % prepared.len()];
                seed += 1;
                n += shade_batch(&loaded, &inst, &spec, seed, reqs).samples.len() as u64;
            }
            n as f64 / t.elapsed().as_secs_f64()
        })
    };
    let inproc_before = in_process();

    let cluster = LocalCluster::start(LocalOptions {
        workers: a.workers.max(1),
        worker_threads: Some(a.worker_threads.max(1)),
        log_level: Some(std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into())),
        ..Default::default()
    })
    .context("starting workers (run `cargo build --release` first)")?;
    let endpoints: Vec<String> = cluster.worker_addrs().iter().map(|w| format!("http://{w}")).collect();

    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    let mut runs = Vec::new();
    for k in 1..=a.workers.max(1) {
        let rate = rt.block_on(async {
            let wp = WorkerPool::new(endpoints[..k].to_vec())?;
            let d = wp.open(source.clone(), hash.clone());
            let mut gen = RayGen::new(&camera, 11 + k as u64);
            let shader = a.shader.clone();
            // Warm-up: the workers load the scene and open their streams.
            let warm: Vec<_> = (0..k as u64 * 2).map(|i| to_wire(i + 1, 0, &shader, &params, gen.batch(a.batch))).collect();
            d.shade_all(warm, k * 2, Duration::from_secs(120), |_| {}).await?;
            let mut next = 1000u64;
            let start = Instant::now();
            let mut samples = 0u64;
            let batches = std::iter::from_fn(|| {
                if start.elapsed() >= deadline {
                    return None;
                }
                next += 1;
                Some(to_wire(next, 0, &shader, &params, gen.batch(a.batch)))
            });
            d.shade_all(batches, a.window.max(1) * k, Duration::from_secs(60), |b| samples += b.samples.len() as u64)
                .await?;
            anyhow::Ok(samples as f64 / start.elapsed().as_secs_f64())
        })?;
        runs.push(rate);
    }
    let inproc_rate = inproc_before.max(in_process());
    drop(loaded);
    let one = runs[0];
    let out = json!({
        "scene": a.scene,
        "shader": a.shader,
        "batch": a.batch,
        "worker_threads": a.worker_threads,
        "seconds": a.seconds,
        "in_process_samples_per_s": inproc_rate,
        "grpc_samples_per_s": runs,
        "scaling": runs.iter().map(|r| r / one).collect::<Vec<_>>(),
        "grpc_overhead_fraction": 1.0 - one / inproc_rate,
    });
    let mut table = format!(
        "throughput {} shader={} batch={} threads/worker={}\n  in-process: {:.0} samples/s\n",
        a.scene, a.shader, a.batch, a.worker_threads, inproc_rate
    );
    for (i, r) in runs.iter().enumerate() {
        table += &format!("  {} worker(s): {:.0} samples/s (x{:.2})\n", i + 1, r, r / one);
    }
    table += &format!("  gRPC overhead vs in-process (1 worker): {:.1} %\n", 100.0 * (1.0 - one / inproc_rate));
    crate::emit(a.json, &out, &table);
    Ok(())
}
