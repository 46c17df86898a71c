//! `edgepoint-bench epi`: the edge-and-point image's per-stage times (paper 000 Table 2
//! columns: rasterize, reach, interpolate, anti-alias, complex) at several image sizes, on one
//! thread and on all, and its memory per pixel, structure by structure.
//!
//! The EPI is built from a real frame: the scene's brute-force discontinuity edges and a
//! Render Cache holding shaded samples at jittered positions of the chosen density (1 = every
//! pixel holds a sample, the steady state of the interactive renderer). The Render Cache's
//! own gap-filling interpolation and the per-pixel (paper-style) reachability are timed on the
//! same frame as baselines.
use crate::clock::{thread_cpu_ms, wall_ms};
use crate::inprocess::{cache_with, jittered_picks, Staged};
use crate::stats::median;
use anyhow::{bail, Result};
use edgepoint_server::edges::brute::scene_edges;
use edgepoint_server::epi::reach::scalar::ScalarReach;
use edgepoint_server::epi::interpolate::Isa;
use edgepoint_server::epi::{Epi, InterpOptions, STAGE_ANTIALIAS, STAGE_INTERPOLATE, STAGE_REACH};
use edgepoint_server::render_cache::RenderCache;
use edgepoint_server::stage_times::StageTimes;
use glam::{Affine3A, Vec3};
use serde_json::json;
use std::collections::{BTreeMap, HashMap};

#[derive(clap::Args, Debug)]
pub struct EpiArgs {
    /// Scene: a built-in name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz) (a bare model is staged on a floor under a point light).
    #[arg(long, default_value = "cornell-point")]
    pub scene: String,
    /// Square image sizes to measure (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "512,1024")]
    pub sizes: Vec<u32>,
    /// Fractions of pixels holding a sample (comma-separated); 1 is the interactive steady
    /// state, lower values leave most pixels to interpolation.
    #[arg(long, value_delimiter = ',', default_value = "1,0.2,0.05")]
    pub densities: Vec<f64>,
    /// Timed repetitions per configuration (medians are reported).
    #[arg(long, default_value_t = 15)]
    pub iterations: usize,
    /// Thread count of the "all threads" runs (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Shader parameter KEY=VALUE for shading the samples (repeatable).
    #[arg(long = "shader-param", value_parser = crate::frame::parse_param)]
    pub shader_params: Vec<(String, f64)>,
    /// Filter every pixel's own sample with its neighbours instead of showing it (the
    /// renderer shows it: same quality, less work).
    #[arg(long)]
    pub filter_own: bool,
    /// Skip the baselines (per-pixel reachability, Render Cache interpolation), e.g. to
    /// profile the EPI alone.
    #[arg(long)]
    pub no_baselines: bool,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Stage names of the reconstruction the target covers (paper: 27 ms in 2003).
const TARGET_STAGES: [&str; 3] = [STAGE_REACH, STAGE_INTERPOLATE, STAGE_ANTIALIAS];

pub fn run(args: EpiArgs) -> Result<()> {
    if args.iterations == 0 || args.sizes.is_empty() || args.densities.is_empty() {
        bail!("--iterations, --sizes and --densities must not be empty");
    }
    if let Some(d) = args.densities.iter().find(|d| !(**d > 0.0 && **d <= 1.0)) {
        bail!("--densities: {d} is not in (0, 1]");
    }
    let params: HashMap<String, f64> = args.shader_params.iter().cloned().collect();
    let staged = Staged::load(&args.scene, "direct", &params)?;
    let all = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pools = [(1usize, rayon::ThreadPoolBuilder::new().num_threads(1).build()?), (all, rayon::ThreadPoolBuilder::new().num_threads(all).build()?)];
    let transforms: Vec<Affine3A> = staged.loaded.scene.objects.iter().map(|o| o.transform).collect();
    let mut runs = Vec::new();
    let mut table = String::new();
    use std::fmt::Write;
    let simd = Isa::detect();
    writeln!(
        table,
        "EPI stages on {} (median of {} runs, ms; 1 thread: thread CPU time, more: wall clock; interpolation compiled for {simd:?})",
        args.scene, args.iterations
    )?;
    writeln!(
        table,
        "  {:>9} {:>7} {:>3} | {:>7} {:>9} {:>7} {:>7} {:>9} {:>7} {:>8} | {:>9} {:>8} {:>8} | {:>6}",
        "size", "density", "thr", "edges", "rasterize", "reach", "interp", "antialias", "complex", "r+i+aa", "reach/px", "rc-interp", "reproj", "B/px"
    )?;
    for &size in &args.sizes {
        let cam = staged.camera(size, size);
        let mut edges = Vec::new();
        scene_edges(&staged.loaded.scene, &transforms, cam.eye, edgepoint_server::edges::DEFAULT_SHARP_CUTOFF_DEGREES, &mut edges);
        for &density in &args.densities {
            let picks = jittered_picks(size, size, density, 0x0e91);
            let samples = staged.shade(&cam, &picks, 1);
            let background = staged.loaded.scene.background;
            for (threads, pool) in &pools {
                // One thread: that thread's CPU time, which other work on a busy machine does not
                // inflate. All threads: wall-clock time.
                let cpu = *threads == 1;
                let options = InterpOptions {
                    own_sample: if args.filter_own { edgepoint_server::epi::OwnSample::Filter } else { edgepoint_server::epi::OwnSample::Show },
                    ..Default::default()
                };
                let run = pool.install(|| measure(&staged, &cam, &edges, &transforms, &samples, background, size, args.iterations, !args.no_baselines, cpu, &options));
                let m = &run.median;
                let target: f64 = TARGET_STAGES.iter().map(|s| m.get(*s).copied().unwrap_or(0.0)).sum();
                writeln!(
                    table,
                    "  {:>9} {:>7.2} {:>3} | {:>7.2} {:>9.2} {:>7.2} {:>7.2} {:>9.2} {:>7.2} {:>8.2} | {:>9.2} {:>8.2} {:>8.2} | {:>6.2}",
                    format!("{size}x{size}"),
                    density,
                    threads,
                    m["edges"],
                    m["rasterize"],
                    m["reach"],
                    m["interpolate"],
                    m["antialias"],
                    m["complex"],
                    target,
                    m.get("reach_per_pixel").copied().unwrap_or(f64::NAN),
                    m.get("render_cache_interpolate").copied().unwrap_or(f64::NAN),
                    m["reproject"],
                    run.bytes_total_per_pixel
                )?;
                runs.push(json!({
                    "width": size, "height": size, "density": density, "threads": threads,
                    "samples": samples.len(),
                    "clock": if *threads == 1 { "thread CPU time" } else { "wall clock" },
                    "stages_median_ms": m,
                    "reach_interpolate_antialias_ms": target,
                    "target_3ms_one_core": if *threads == 1 && size == 512 { Some(target <= 3.0) } else { None },
                    "pixel_classes": run.classes,
                    "edges": edges.len(),
                    "raster": { "fragments": run.fragments, "culled": run.culled },
                    "bytes_per_pixel": run.bytes,
                    "bytes_per_pixel_total": run.bytes_total_per_pixel,
                    "content_sized_bytes_per_pixel": run.content,
                    "shared_with_render_cache_bytes_per_pixel": {
                        "point image (index, depth, position, colour, age)": 32,
                        "frame image (linear RGB f32)": 12,
                        "filter weights (f32)": 4,
                    },
                }));
            }
        }
    }
    writeln!(table, "  r+i+aa = reach + interpolate + antialias (target: <= 3 ms at 512x512 on one thread)")?;
    writeln!(table, "  reach/px = per-pixel table reachability (the paper's formulation), for comparison with the bit-sliced reach")?;
    writeln!(table, "  B/px = bytes per pixel of the EPI's image-sized structures (--json: the breakdown, and the content-sized ones)")?;
    crate::emit(args.json, &json!({ "scene": args.scene, "iterations": args.iterations, "interpolation_simd": format!("{simd:?}"), "runs": runs }), &table);
    Ok(())
}

struct Run {
    median: BTreeMap<String, f64>,
    classes: serde_json::Value,
    fragments: u32,
    culled: u32,
    bytes: BTreeMap<String, f64>,
    /// Content-sized structures, in bytes per pixel of this frame.
    content: BTreeMap<String, f64>,
    bytes_total_per_pixel: f64,
}

#[allow(clippy::too_many_arguments)]
fn measure(
    staged: &Staged,
    cam: &edgepoint_scene::camera::CameraFrame,
    edges: &[edgepoint_server::edges::EdgeSegment],
    transforms: &[Affine3A],
    samples: &[edgepoint_server::render_cache::Sample],
    background: Vec3,
    size: u32,
    iterations: usize,
    baselines: bool,
    cpu: bool,
    options: &InterpOptions,
) -> Run {
    let clock: fn() -> f64 = if cpu { thread_cpu_ms } else { wall_ms };
    let mut cache: RenderCache = cache_with(size, size, cam, samples, background);
    let mut epi = Epi::new(size, size);
    let mut per_pixel = ScalarReach::new(size as usize, size as usize);
    let mut all: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut counts = *epi.counts();
    let mut scratch = Vec::new();
    for i in 0..iterations + 2 {
        let mut t = StageTimes::with_clock(clock);
        t.time("edges", || {
            scratch.clear();
            scene_edges(&staged.loaded.scene, transforms, cam.eye, edgepoint_server::edges::DEFAULT_SHARP_CUTOFF_DEGREES, &mut scratch);
        });
        cache.reproject_points(cam, None, &mut t);
        counts = epi.build(edges, cam, cache.point_image(), true, &mut t);
        let (points, image, weights) = cache.reconstruction_target();
        epi.reconstruct(points, background, options, true, image, weights, &mut t);
        if baselines {
            t.time("reach_per_pixel", || per_pixel.compute(epi.pixels()));
            let mut t_rc = StageTimes::with_clock(clock);
            cache.interpolate_gaps(&mut t_rc);
            t.add("render_cache_interpolate", t_rc.total_ms());
        }
        if i >= 2 {
            for (s, ms) in t.stages {
                all.entry(s.to_string()).or_default().push(ms);
            }
        }
    }
    let median = all.iter().map(|(k, v)| (k.clone(), median(v))).collect();
    let pixels = (size as f64) * (size as f64);
    let to_per_pixel = |list: Vec<(&'static str, usize)>| -> BTreeMap<String, f64> { list.into_iter().map(|(k, b)| (k.to_string(), b as f64 / pixels)).collect() };
    let mut bytes = to_per_pixel(epi.memory());
    let bytes_total_per_pixel = bytes.values().sum::<f64>();
    let content = to_per_pixel(epi.memory_content());
    bytes.insert("per-pixel reachability masks (the per-pixel baseline, not used)".into(), per_pixel.bytes() as f64 / pixels);
    Run {
        median,
        classes: json!({ "empty": counts.empty, "simple": counts.simple, "complex": counts.complex,
            "usable_samples": counts.usable_samples, "ambiguous_samples": counts.ambiguous_samples }),
        fragments: counts.raster.fragments,
        culled: counts.raster.culled,
        bytes,
        content,
        bytes_total_per_pixel,
    }
}
