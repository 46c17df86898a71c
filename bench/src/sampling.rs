//! `edgepoint-bench sampling`: the frame loop's work after a frame is published — picking
//! the next frame's pixels (`Sampler::select`: priorities, scaling to the budget,
//! error-diffusion dither), aiming picks at cached points (`aim_at_points`) and building
//! the request batches (`build_batches`: a ray per pick, the request ring) — on the
//! priorities of a real frame: the scene's edge-and-point reconstruction from a Render
//! Cache holding samples at the given density, its points given ages spread over
//! `max_age_frames` as a still camera's cache has them.
//!
//! Budgets are given as sparseness (pixels per pick): 64 is a frame's interactive budget,
//! about 10 what a session at rest asks for per frame (every free place in flight, 25,000
//! picks at 512²). The baseline, in the same process on the same thread, is one streaming
//! pass computing every pixel's priority into a buffer (the first of `select`'s passes), so
//! `over_priority_pass` says how many such passes the whole step costs.
use crate::clock::{median_ms as time, thread_cpu_ms, wall_ms};
use crate::inprocess::{jittered_picks, reconstructed_frame, Staged};
use anyhow::{bail, Result};
use edgepoint_server::rng::mix64;
use edgepoint_server::sampling::{aim_at_points, priority, PixelRequest, Sampler, SamplingConfig};
use edgepoint_server::session::requests::{build_batches, BatchSpec, RequestRing};
use serde_json::json;
use std::collections::{BTreeMap, HashMap};

#[derive(clap::Args, Debug)]
pub struct SamplingArgs {
    /// Scene the frame is reconstructed from: a built-in name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz).
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Square frame sizes to measure (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "512,1024")]
    pub sizes: Vec<u32>,
    /// Fraction of pixels holding a point in the frame's Render Cache.
    #[arg(long, default_value_t = 0.6)]
    pub density: f64,
    /// Budgets to measure, as pixels per pick (comma-separated; 64 = a frame in motion, 10
    /// ≈ a frame at rest).
    #[arg(long, value_delimiter = ',', default_value = "64,10")]
    pub sparseness: Vec<f64>,
    /// Request batch size (the session's default).
    #[arg(long, default_value_t = 256)]
    pub batch_size: usize,
    /// Timed repetitions per measurement (medians are reported).
    #[arg(long, default_value_t = 40)]
    pub iterations: usize,
    /// Thread count of the "all threads" runs (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: SamplingArgs) -> Result<()> {
    if args.iterations == 0 {
        bail!("--iterations must be at least 1");
    }
    if !(args.density > 0.0 && args.density <= 1.0) {
        bail!("--density {} is not in (0, 1]", args.density);
    }
    if let Some(s) = args.sparseness.iter().find(|s| !(s.is_finite() && **s >= 1.0)) {
        bail!("--sparseness {s} is not a number ≥ 1");
    }
    if let Some(s) = args.sizes.iter().find(|&&s| !(8..=8192).contains(&s)) {
        bail!("--sizes {s}: frame sizes must be in [8, 8192]");
    }
    if args.batch_size == 0 {
        bail!("--batch-size must be at least 1");
    }
    let staged = Staged::load(&args.scene, "direct", &HashMap::new())?;
    let all = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pools = [(1usize, rayon::ThreadPoolBuilder::new().num_threads(1).build()?), (all, rayon::ThreadPoolBuilder::new().num_threads(all).build()?)];
    let cfg = SamplingConfig::default();
    let params = HashMap::new();
    let mut runs = Vec::new();
    let mut table = String::new();
    use std::fmt::Write;
    writeln!(table, "after-publish work, median of {} runs (ms; 1 thread: thread CPU time, more: wall clock)", args.iterations)?;
    writeln!(table, "  {:>16} {:>6} {:>3} | {:>8} {:>8} {:>8} {:>8} | {:>8} {:>7} | {:>6}", "frame", "picks", "thr", "select", "aim", "requests", "total", "prio pass", "ratio", "ns/px")?;
    for &size in &args.sizes {
        let cam = staged.camera(size, size);
        let picks = jittered_picks(size, size, args.density, 0x5a31);
        let samples = staged.shade(&cam, &picks, 1);
        let cache = reconstructed_frame(&staged, &cam, &samples);
        let weights = cache.filter_weights().to_vec();
        let points = cache.point_image();
        // A still camera's points have every age up to the oldest: spread them (hashed).
        let ages: Vec<f32> = points.age.iter().enumerate().map(|(i, &a)| if a.is_finite() { (mix64(i as u64) % (cfg.max_age_frames as u64 + 1)) as f32 } else { a }).collect();
        let n = (size as usize).pow(2);
        for &sparseness in &args.sparseness {
            let budget = ((n as f64 / sparseness).ceil() as usize).min(n);
            for (threads, pool) in &pools {
                let clock: fn() -> f64 = if *threads == 1 { thread_cpu_ms } else { wall_ms };
                let m: BTreeMap<&str, f64> = pool.install(|| {
                    let mut sampler = Sampler::new(size, size, 7);
                    let mut out: Vec<PixelRequest> = Vec::new();
                    let mut prio = vec![0.0f32; n];
                    let mut ring = RequestRing::new(budget * 4);
                    let spec = BatchSpec { epoch: 1, shader: "direct", params: &params, batch_size: args.batch_size, parts: 1, coherent: false };
                    let (mut next_batch, mut seed, mut batches) = (0u64, 1u64, Vec::new());
                    let mut m = BTreeMap::new();
                    m.insert(
                        "priority_pass",
                        time(args.iterations, clock, &mut || {
                            for ((p, &w), &a) in prio.iter_mut().zip(&weights).zip(&ages) {
                                *p = priority(w, a, cfg.max_age_frames);
                            }
                            std::hint::black_box(&prio);
                        }),
                    );
                    m.insert("select", time(args.iterations, clock, &mut || sampler.select(&weights, &ages, &cfg, budget, &mut out)));
                    let picked = out.clone();
                    m.insert(
                        "aim",
                        time(args.iterations, clock, &mut || {
                            out.clone_from(&picked);
                            aim_at_points(&mut out, points, |_, _| true, |_, _, _, _| false);
                        }),
                    );
                    m.insert(
                        "requests",
                        time(args.iterations, clock, &mut || {
                            batches.clear();
                            build_batches(&out, &cam, &mut ring, &spec, &mut next_batch, &mut seed, &mut batches);
                            std::hint::black_box(&batches);
                        }),
                    );
                    m.insert("picks", out.len() as f64);
                    m
                });
                let total = m["select"] + m["aim"] + m["requests"];
                let ratio = total / m["priority_pass"];
                writeln!(
                    table,
                    "  {:>16} {:>6} {:>3} | {:>8.3} {:>8.3} {:>8.3} {:>8.3} | {:>8.3} {:>6.1}x | {:>6.2}",
                    format!("{} {size}²", args.scene),
                    m["picks"],
                    threads,
                    m["select"],
                    m["aim"],
                    m["requests"],
                    total,
                    m["priority_pass"],
                    ratio,
                    total * 1e6 / n as f64
                )?;
                runs.push(json!({
                    "width": size, "height": size, "sparseness": sparseness, "budget": budget, "threads": threads,
                    "clock": if *threads == 1 { "thread CPU time" } else { "wall clock" },
                    "median_ms": m, "total_ms": total, "over_priority_pass": ratio, "ns_per_pixel": total * 1e6 / n as f64,
                }));
            }
        }
    }
    writeln!(table, "  select = priorities + scaling to the budget + dither; aim = aiming picks at cached points; requests = rays, ring and batches")?;
    writeln!(table, "  prio pass = one streaming pass computing every pixel's priority (the baseline); ratio = total / prio pass")?;
    crate::emit(
        args.json,
        &json!({ "scene": args.scene, "density": args.density, "batch_size": args.batch_size, "iterations": args.iterations, "runs": runs }),
        &table,
    );
    Ok(())
}
