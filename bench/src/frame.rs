//! `edgepoint-bench frame` and `edgepoint-bench reference`.
//!
//! `frame` runs what a user runs — a local cluster (server + workers as child processes) and a
//! headless session — for N frames with a static camera, then renders, through the same
//! workers and shader, the converged reference (many samples per pixel, cached on disk) and
//! a 1-sample-per-pixel full ray trace (timed: the baseline for the speedup, paper Table 2
//! "Full RT" and "Speedup").
use crate::reference_cache::RefCache;
use crate::stats::{mean, median};
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_server::image_metrics::{psnr, srgb8_to_linear, ssim};
use edgepoint_server::reference::{render_reference, LogProgress, ReferenceImage};
use edgepoint_server::workers::{Dispatcher, WorkerPool};
use edgepoint_viewer::client::{camera_from_wire, scene_source_from_arg_in, Event, SessionClient};
use edgepoint_viewer::local::{LocalCluster, LocalOptions};
use glam::Vec3;
use serde_json::json;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Options shared by `frame` and `reference`.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneArgs {
    /// Built-in scene name (cornell, cornell-point, chains, torus-capsule, grid-dragon,
    /// rooms, materials) or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz).
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Shared data directory for built-ins made from data (default: $EDGEPOINT_DATA, else
    /// a shared/data directory above the working directory or the executable).
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Image width in pixels.
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    /// Number of shader-worker processes to start.
    #[arg(long, default_value_t = 2)]
    pub workers: usize,
    /// Threads per worker process (default: the worker's choice, all cores).
    #[arg(long)]
    pub worker_threads: Option<usize>,
    /// Niceness added to the worker processes, so that the server's frame loop gets the
    /// shared cores first (0 = same priority as the server).
    #[arg(long, default_value_t = edgepoint_viewer::local::WORKER_NICE)]
    pub worker_nice: i32,
    /// Run the workers under Linux's SCHED_IDLE policy as well (`--worker-idle false`:
    /// niceness only): a waking frame-loop thread then takes a core from a worker at once
    /// instead of waiting for its time slice.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set, value_name = "BOOL")]
    pub worker_idle: bool,
    /// Shader name.
    #[arg(long, default_value = "direct")]
    pub shader: String,
    /// Shader parameter KEY=VALUE (repeatable), e.g. shadow_rays=16.
    #[arg(long = "shader-param", value_parser = parse_param)]
    pub shader_params: Vec<(String, f64)>,
    /// Samples per pixel of the converged reference (default: 64 for `frame` and
    /// `reference`, 16 for `motion`, which renders one per frame, 1024 for `converge`). Also
    /// `--spp`.
    #[arg(long, visible_alias = "spp")]
    pub reference_spp: Option<u32>,
    /// Shader parameter KEY=VALUE of the converged reference only (repeatable), over
    /// --shader-param. Without one for `cache_max_rays`, a shader with an irradiance cache
    /// (`gi`) renders its reference with REFERENCE_CACHE_RAYS_FACTOR (8) times the renders'
    /// `cache_max_rays` (at most the parameter's maximum): records of the renders' size
    /// would leave the reference's own record noise as large as the error it measures.
    #[arg(long = "reference-param", value_parser = parse_param, value_name = "KEY=VALUE")]
    pub reference_params: Vec<(String, f64)>,
    /// Directory caching converged references (keyed by scene, camera, size, spp, shader
    /// and the reference's parameters). Default: $XDG_CACHE_HOME/edgepoint/references (else
    /// ~/.cache/edgepoint/references).
    #[arg(long, value_name = "DIR")]
    pub ref_cache: Option<PathBuf>,
    /// Camera overriding the scene's, any subset of "eye=X,Y,Z target=X,Y,Z up=X,Y,Z
    /// fov=DEG" (the viewer's --camera).
    #[arg(long, value_name = "KEYS", value_parser = edgepoint_viewer::camera_path::parse_camera_spec)]
    pub camera: Option<edgepoint_viewer::CameraSpec>,
    /// How one pixel's shading is spread over the workers in the session (paper 004 §4.4):
    /// `pixels` (default) or `lights:N` (each sample in N parts by lights, added by the
    /// server before caching; the viewer's --split).
    #[arg(long, value_name = "pixels|lights:N", default_value = "pixels")]
    pub split: edgepoint_proto::split::SplitMode,
}

/// How fast a bench session samples and makes frames.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct PaceArgs {
    /// Pixels per new sample per frame (the paper's sparseness ratio target; server default 64).
    #[arg(long)]
    pub sparseness: Option<f64>,
    /// Frame-rate cap of the server's frame loop (server default 30).
    #[arg(long)]
    pub max_fps: Option<f64>,
    /// Frame-rate cap while the camera and the objects are still (server default 10; the
    /// frame loop leaves the rest of the machine to the workers; equal to --max-fps: off).
    #[arg(long)]
    pub rest_fps: Option<f64>,
}

impl PaceArgs {
    /// Session settings with this pace (0: the server's default).
    pub fn settings(&self) -> pb::Settings {
        pb::Settings {
            sparseness: self.sparseness.unwrap_or(0.0),
            max_fps: self.max_fps.unwrap_or(0.0),
            rest_fps: self.rest_fps.unwrap_or(0.0),
            ..Default::default()
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct FrameArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Frames to run the session for; statistics cover all of them, PSNR the last.
    #[arg(long, default_value_t = 60)]
    pub frames: u32,
    #[command(flatten)]
    pub pace: PaceArgs,
    #[command(flatten)]
    pub reconstruction: edgepoint_viewer::ReconstructionArgs,
    /// Orbit the camera this many degrees a frame along the scene's suggested orbit (the
    /// viewer's --orbit), one step after each frame received: the stages of frames in
    /// motion (0: a still camera). PSNR is then the last frame's, against the reference of
    /// its camera; `motion` measures quality along a path frame by frame.
    #[arg(long, default_value_t = 0.0, value_name = "DEG")]
    pub orbit_degrees: f32,
    /// Skip the reference renders (no PSNR, no speedup).
    #[arg(long)]
    pub no_reference: bool,
    /// Write the last frame and the references as PNG (or, with --format exr, EXR) files into
    /// this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// File format of the images --out writes: png (8-bit sRGB, clipped) or exr (linear RGB
    /// float, never tone-mapped or clipped).
    #[arg(long, value_enum, default_value_t = FileFormat::Png)]
    pub format: FileFormat,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct ReferenceArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Directory for reference_1spp.png and reference_<spp>spp.png (.exr with --format exr).
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// File format of the references: png (8-bit sRGB, clipped) or exr (linear RGB float,
    /// never tone-mapped or clipped).
    #[arg(long, value_enum, default_value_t = FileFormat::Png)]
    pub format: FileFormat,
    /// Also write the converged reference to FILE as linear RGB float EXR (never tone-mapped
    /// or clipped), whatever `--format` says.
    #[arg(long, value_name = "FILE")]
    pub exr: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub use edgepoint_proto::shaders::parse_param;

pub(crate) fn start_cluster(a: &SceneArgs) -> Result<LocalCluster> {
    LocalCluster::start(LocalOptions {
        workers: a.workers,
        worker_threads: a.worker_threads,
        worker_nice: a.worker_nice,
        worker_idle: a.worker_idle,
        log_level: Some(std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into())),
        ..Default::default()
    })
    .context("starting the local cluster (run `cargo build --release` first)")
}

/// Samples per pixel of `frame`'s and `reference`'s converged references.
pub const DEFAULT_REFERENCE_SPP: u32 = 64;

/// The two reference renders of a frame setup.
pub struct References {
    pub converged: ReferenceImage,
    pub converged_cached: bool,
    pub one_spp: ReferenceImage,
}

/// Renders (or loads from the cache) the converged reference, and always renders the
/// timed 1-spp full ray trace, through the cluster's workers.
async fn references(
    cluster: &LocalCluster,
    a: &SceneArgs,
    source: &pb::SceneSource,
    camera: &edgepoint_scene::Camera,
) -> Result<References> {
    let dispatcher = open_dispatcher(cluster, source)?;
    let params: HashMap<String, f64> = a.shader_params.iter().cloned().collect();
    let spp = a.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP);
    let (converged, converged_cached) = converged_reference(&dispatcher, a, source, camera, spp).await?;
    let progress = LogProgress::new("full ray trace 1spp");
    let one_spp = render_reference(&dispatcher, camera, a.width, a.height, 1, &a.shader, &params, &progress)
        .await
        .context("1-spp full ray trace")?;
    Ok(References { converged, converged_cached, one_spp })
}

/// A dispatcher of its own to the cluster's workers, for renders outside a session.
pub(crate) fn open_dispatcher(cluster: &LocalCluster, source: &pb::SceneSource) -> Result<Dispatcher> {
    let endpoints = cluster.worker_addrs().iter().map(|w| format!("http://{w}")).collect();
    let pool = WorkerPool::new(endpoints)?;
    Ok(pool.open(source.clone(), edgepoint_proto::scene_hash(source)))
}

/// How many times the renders' `cache_max_rays` a converged reference's irradiance records
/// grow to (`--reference-param`'s help). At the default 1024 rays the `gi` reference of
/// `cornell` (256 spp) was 50.2 dB from one with 8192, and against that one both renderers
/// of `converge` measured 1 dB more at 30 s: half of their error had been the reference's.
pub const REFERENCE_CACHE_RAYS_FACTOR: f64 = 8.0;

/// The shader parameters of a converged reference: `--shader-param`, then
/// `--reference-param`, and `cache_max_rays` raised (see [`REFERENCE_CACHE_RAYS_FACTOR`])
/// where the shader has it and no `--reference-param` sets it.
pub(crate) fn reference_params(a: &SceneArgs) -> HashMap<String, f64> {
    let mut params: HashMap<String, f64> = a.shader_params.iter().chain(&a.reference_params).cloned().collect();
    const KEY: &str = "cache_max_rays";
    let table = edgepoint_proto::shaders::shader(&a.shader).and_then(|s| s.params.iter().find(|p| p.name == KEY));
    if let Some(p) = table {
        if !a.reference_params.iter().any(|(k, _)| k == KEY) {
            let renders = a.shader_params.iter().rev().find(|(k, _)| k == KEY).map_or(p.default, |(_, v)| *v);
            params.insert(KEY.to_string(), (renders * REFERENCE_CACHE_RAYS_FACTOR).min(p.max));
        }
    }
    params
}

/// The converged reference at `spp` samples per pixel through `dispatcher`: from the on-disk
/// cache when an earlier run stored it (then `true`), else rendered and stored.
pub(crate) async fn converged_reference(
    dispatcher: &Dispatcher,
    a: &SceneArgs,
    source: &pb::SceneSource,
    camera: &edgepoint_scene::Camera,
    spp: u32,
) -> Result<(ReferenceImage, bool)> {
    let params = reference_params(a);
    let cache = RefCache::at(a.ref_cache.as_deref());
    let key = RefCache::key(&edgepoint_proto::scene_hash(source), camera, a.width, a.height, spp, &a.shader, &params);
    if let Some(img) = cache.load(&key, a.width, a.height, spp) {
        return Ok((img, true));
    }
    let progress = LogProgress::new(&format!("reference {spp}spp"));
    let img = render_reference(dispatcher, camera, a.width, a.height, spp, &a.shader, &params, &progress)
        .await
        .context("converged reference render")?;
    cache.store(&key, &img)?;
    Ok((img, false))
}

use crate::inprocess::write_image;
use edgepoint_viewer::headless::FileFormat;

/// The `start` message of a bench session: `source` at `width` × `height` with the shader,
/// its parameters, the viewer's --camera (over the scene's) and `settings`.
pub fn start_message(
    source: &pb::SceneSource,
    (width, height): (u32, u32),
    (shader, params): (&str, &[(String, f64)]),
    camera: Option<&edgepoint_viewer::CameraSpec>,
    settings: pb::Settings,
) -> pb::Start {
    pb::Start {
        scene: Some(source.clone()),
        width,
        height,
        shader: shader.to_string(),
        shader_params: params.iter().cloned().collect(),
        encoding: pb::FrameEncoding::Qoi as i32,
        settings: Some(settings),
        camera: camera.map(|c| c.to_wire()),
        split: None,
    }
}

pub fn run(args: FrameArgs) -> Result<()> {
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    let source = scene_source_from_arg_in(&args.scene.scene, args.scene.data_dir.as_deref())?;
    let cluster = start_cluster(&args.scene)?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    rt.block_on(async {
        let mut settings = args.pace.settings();
        args.reconstruction.apply(&mut settings);
        let (out, table) = session_report(&cluster, &args, &source, settings).await?;
        crate::emit(args.json, &out, &table);
        Ok(())
    })
}

/// One session of `args.frames` frames with `settings` on `cluster`: its report (the
/// fields of `edgepoint-bench frame --json`) and its table.
pub async fn session_report(cluster: &LocalCluster, args: &FrameArgs, source: &pb::SceneSource, settings: pb::Settings) -> Result<(serde_json::Value, String)> {
        let a = &args.scene;
        let mut start = start_message(source, (a.width, a.height), (&a.shader, &a.shader_params), a.camera.as_ref(), settings);
        start.split = a.split.to_wire();
        let t0 = Instant::now();
        let (mut client, started) = SessionClient::connect(&cluster.server_url(), start).await?;
        let mut camera = camera_from_wire(started.camera.as_ref().context("server sent no camera")?);
        let session_start_ms = t0.elapsed().as_secs_f64() * 1e3;
        if !args.orbit_degrees.is_finite() {
            bail!("--orbit-degrees must be a finite number of degrees");
        }
        let orbit = if args.orbit_degrees != 0.0 {
            let mut o = edgepoint_viewer::camera_path::suggested_orbit(&started)?;
            if let Some(fov) = a.camera.as_ref().and_then(|c| c.fov_y_degrees) {
                o.fov_y_degrees = fov;
            }
            Some(o)
        } else {
            None
        };

        let mut stage_ms: BTreeMap<String, Vec<f64>> = BTreeMap::new();
        let mut stage_order: Vec<String> = Vec::new();
        let mut totals = Vec::new();
        let mut samples = Vec::new();
        let mut between = Vec::new();
        // Per frame: the picking and requests made after the frame before (not in its total),
        // and the loop's whole work for the frame (total + that).
        let (mut after, mut loops) = (Vec::new(), Vec::new());
        let mut last: Option<pb::Frame> = None;
        let mut first_at: Option<Instant> = None;
        // The server's CPU time (every thread: the frame loop, its rayon pool, the gRPC
        // threads decoding samples) from the first frame on: what a frame costs the machine,
        // which the wall-clock stage times show only through the noise of other load.
        let mut server_cpu0: Option<f64> = None;
        let mut dropped = 0u64;
        let mut first_tree_frame: Option<u64> = None;
        // The same per-stage times, only of frames whose edges came from the edge trees (the
        // steady state; before them the brute-force finder runs while the trees build).
        let mut tree_stage_ms: BTreeMap<String, Vec<f64>> = BTreeMap::new();
        let mut tree_totals = Vec::new();
        while (totals.len() as u32) < args.frames {
            let ev = tokio::time::timeout(Duration::from_secs(60), client.next_event())
                .await
                .context("no frame for 60 s")?;
            match ev {
                None => bail!("the session ended after {} frames", totals.len()),
                Some(Err(e)) => return Err(e.into()),
                Some(Ok(Event::Rejected(r))) => bail!("server rejected a message: {}", r.message),
                Some(Ok(Event::Progress(_) | Event::Picked(_))) => {}
                Some(Ok(Event::Frame(f))) => {
                    if first_at.is_none() {
                        first_at = Some(Instant::now());
                        server_cpu0 = cluster.server_pid().and_then(process_cpu_seconds);
                    }
                    for s in &f.stages {
                        if !stage_ms.contains_key(&s.stage) {
                            stage_order.push(s.stage.clone());
                        }
                        stage_ms.entry(s.stage.clone()).or_default().push(s.ms);
                    }
                    totals.push(f.total_ms);
                    if let Some(o) = &orbit {
                        let step = o.camera_after(totals.len() as f32 * args.orbit_degrees);
                        client.send_camera(edgepoint_viewer::client::camera_to_wire(&step))?;
                    }
                    samples.push(f.samples_used as f64);
                    between.push(f.between_ms);
                    after.push(f.after_ms);
                    loops.push(f.total_ms + f.after_ms);
                    dropped = f.frames_dropped;
                    if f.edges.as_ref().is_some_and(|e| e.edge_trees) {
                        first_tree_frame.get_or_insert(f.sequence);
                        for s in &f.stages {
                            tree_stage_ms.entry(s.stage.clone()).or_default().push(s.ms);
                        }
                        tree_totals.push(f.total_ms);
                    }
                    last = Some(f);
                }
            }
        }
        let wall = first_at.map(|t| t.elapsed().as_secs_f64()).unwrap_or(0.0);
        let server_cpu_ms_per_frame = match (server_cpu0, cluster.server_pid().and_then(process_cpu_seconds)) {
            (Some(a), Some(b)) if totals.len() > 1 => Some((b - a) * 1e3 / (totals.len() - 1) as f64),
            _ => None,
        };
        drop(client);
        let last = last.expect("at least one frame");
        if orbit.is_some() {
            // The reference of the camera the last frame shows.
            camera = camera_from_wire(last.camera.as_ref().context("the last frame carries no camera")?);
        }
        let img = edgepoint_viewer::frame::decode_frame(&last)?;
        let frame_lin: Vec<Vec3> = img.pixels().map(|p| srgb8_to_linear(p.0)).collect();

        let pixels = a.width as f64 * a.height as f64;
        let mean_samples = mean(&samples);
        // Frames after the first arrive at the loop's pace; the first waits for the session.
        let fps = if totals.len() > 1 && wall > 0.0 { (totals.len() - 1) as f64 / wall } else { 0.0 };
        let median_total = median(&totals);
        let median_loop = median(&loops);
        let mut out = json!({
            "scene": a.scene,
            "width": a.width,
            "height": a.height,
            "workers": a.workers,
            "worker_threads": a.worker_threads,
            "worker_nice": a.worker_nice,
            "worker_idle": a.worker_idle,
            "orbit_degrees_per_frame": args.orbit_degrees,
            "shader": a.shader,
            "split": a.split.to_string(),
            "frames": totals.len(),
            "session_start_ms": session_start_ms,
            "stages_median_ms": stage_order.iter().map(|s| (s.clone(), json!(median(&stage_ms[s])))).collect::<serde_json::Map<_, _>>(),
            "total_median_ms": median_total,
            "server_cpu_ms_per_frame": server_cpu_ms_per_frame,
            // Samples that arrived while the loop waited for the frame are inserted then,
            // outside the frame's time (its count is in the samples per frame).
            "between_frames_median_ms": median(&between),
            // Picking the next pixels and sending their requests, after each frame is out
            // (the stages `sampling` and `requests`): not in the total, which is the time
            // from the frame's start to its publication.
            "after_publish_median_ms": median(&after),
            // The frame loop's work per frame, total + after: what bounds its frame rate.
            "loop_median_ms": median_loop,
            "pipeline_fps": if median_loop > 0.0 { 1000.0 / median_loop } else { 0.0 },
            "fps": fps,
            "samples_per_frame_mean": mean_samples,
            "samples_per_frame_median": median(&samples),
            "sparseness_ratio": if mean_samples > 0.0 { pixels / mean_samples } else { f64::INFINITY },
            "frames_dropped": dropped,
            "last_frame_sequence": last.sequence,
            "reconstruction": edgepoint_viewer::reconstruction::reconstruction_name(last.reconstruction),
            // Paper Table 3 for the last frame.
            "pixel_classes": last.pixels.as_ref().map(|p| json!({
                "empty": p.empty_class, "simple": p.simple_class, "complex": p.complex_class,
            })),
            "edges": last.edges.as_ref().map(|e| json!({
                "silhouette": e.silhouette, "sharp": e.sharp, "boundary": e.boundary,
                "shadow_hard": e.shadow_hard, "shadow_umbral": e.shadow_umbral, "shadow_penumbral": e.shadow_penumbral,
                "fragments": e.fragments, "culled": e.culled,
                "edge_trees": e.edge_trees, "shadow_pairs": e.shadow_pairs,
            })),
            // The first frame found with the edge trees (before it: brute force while they build).
            "first_frame_with_edge_trees": first_tree_frame,
            "frames_with_edge_trees": tree_totals.len(),
            "stages_median_ms_with_edge_trees": stage_order.iter().filter_map(|s| tree_stage_ms.get(s).map(|v| (s.clone(), json!(median(v))))).collect::<serde_json::Map<_, _>>(),
            "total_median_ms_with_edge_trees": if tree_totals.is_empty() { json!(null) } else { json!(median(&tree_totals)) },
        });
        if let Some(dir) = &args.out {
            std::fs::create_dir_all(dir)?;
            write_image(&dir.join("last_frame"), args.format, a.width, a.height, &frame_lin)?;
        }
        if !args.no_reference {
            let refs = references(cluster, a, source, &camera).await?;
            let p = psnr(&frame_lin, &refs.converged.pixels);
            let s = ssim(&frame_lin, &refs.converged.pixels, a.width, a.height);
            let p1 = psnr(&refs.one_spp.pixels, &refs.converged.pixels);
            let full_rt_s = refs.one_spp.elapsed.as_secs_f64();
            out["reference_spp"] = json!(a.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP));
            out["reference_cached"] = json!(refs.converged_cached);
            out["psnr_last_frame_db"] = json!(p);
            out["ssim_last_frame"] = json!(s);
            out["psnr_full_rt_1spp_db"] = json!(p1);
            out["full_rt_1spp_s"] = json!(full_rt_s);
            // Paper Table 2: "Full RT (s)" over the frame's whole pipeline time (the loop's
            // work, with the picking of the next frame's samples).
            out["speedup_vs_full_rt"] = json!(if median_loop > 0.0 { full_rt_s * 1e3 / median_loop } else { 0.0 });
            if let Some(dir) = &args.out {
                let stem = dir.join(format!("reference_{}spp", a.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP)));
                write_image(&stem, args.format, a.width, a.height, &refs.converged.pixels)?;
                write_image(&dir.join("reference_1spp"), args.format, a.width, a.height, &refs.one_spp.pixels)?;
            }
        }
        let mut table = String::new();
        use std::fmt::Write;
        writeln!(table, "frame benchmark: {} {}x{}, {} workers, {} frames", a.scene, a.width, a.height, a.workers, totals.len())?;
        for s in &stage_order {
            writeln!(table, "  {:<14} {:>8.2} ms (median)", s, median(&stage_ms[s]))?;
        }
        writeln!(table, "  {:<14} {:>8.2} ms (median; frame start to publication)", "total", median_total)?;
        writeln!(table, "  {:<14} {:>8.2} ms (median; sampling and requests after publication) -> loop {median_loop:.2} ms, pipeline {:.1} fps", "after", median(&after), out["pipeline_fps"].as_f64().unwrap_or(0.0))?;
        writeln!(table, "  {:<14} {:>8.2} ms (median; samples inserted while waiting for the frame, not in total)", "between frames", median(&between))?;
        if let Some(cpu) = server_cpu_ms_per_frame {
            writeln!(table, "  server CPU     {cpu:>8.2} ms per frame (all its threads)")?;
        }
        writeln!(table, "  delivered fps  {fps:.1}; samples/frame {mean_samples:.0}; sparseness ratio {:.1}", out["sparseness_ratio"].as_f64().unwrap_or(0.0))?;
        if let (Some(first), Some(t)) = (first_tree_frame, out["total_median_ms_with_edge_trees"].as_f64()) {
            writeln!(
                table,
                "  edge trees from frame {first}; {} frames with them: edges {:.2} ms, total {t:.2} ms (medians)",
                tree_totals.len(),
                tree_stage_ms.get("edges").map_or(0.0, |v| median(v)),
            )?;
        }
        if let (Some(p), Some(e)) = (&last.pixels, &last.edges) {
            writeln!(
                table,
                "  {} reconstruction; pixels empty/simple/complex {}/{}/{}; edges: {} silhouette, {} sharp, {} boundary, {} shadow",
                out["reconstruction"].as_str().unwrap_or("?"),
                p.empty_class, p.simple_class, p.complex_class,
                e.silhouette, e.sharp, e.boundary, e.shadow_hard + e.shadow_umbral + e.shadow_penumbral,
            )?;
        }
        if let Some(p) = out.get("psnr_last_frame_db") {
            writeln!(
                table,
                "  PSNR frame {} vs {}spp reference: {:.2} dB (SSIM {:.4}); 1-spp full RT: {:.2} dB in {:.2} s; speedup {:.1}x",
                last.sequence,
                a.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP),
                p.as_f64().unwrap_or(0.0),
                out["ssim_last_frame"].as_f64().unwrap_or(0.0),
                out["psnr_full_rt_1spp_db"].as_f64().unwrap_or(0.0),
                out["full_rt_1spp_s"].as_f64().unwrap_or(0.0),
                out["speedup_vs_full_rt"].as_f64().unwrap_or(0.0),
            )?;
        }
        Ok((out, table))
}

pub fn run_reference(args: ReferenceArgs) -> Result<()> {
    let a = &args.scene;
    let source = scene_source_from_arg_in(&a.scene, a.data_dir.as_deref())?;
    let scene = edgepoint_proto::scene_from_source(&source, &edgepoint_scene::NoProgress)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let cluster = start_cluster(a)?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    rt.block_on(async {
        let camera = match a.camera {
            Some(c) => c.apply(&scene.camera).map_err(|e| anyhow::anyhow!("--camera: {e}"))?,
            None => scene.camera,
        };
        let refs = references(&cluster, a, &source, &camera).await?;
        std::fs::create_dir_all(&args.out)?;
        let conv = args.out.join(format!("reference_{}spp", a.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP)));
        let conv = write_image(&conv, args.format, a.width, a.height, &refs.converged.pixels)?;
        let one = write_image(&args.out.join("reference_1spp"), args.format, a.width, a.height, &refs.one_spp.pixels)?;
        let mut files = vec![conv.display().to_string(), one.display().to_string()];
        if let Some(path) = &args.exr {
            if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)?;
            }
            edgepoint_viewer::exr_file::write_f32(path, a.width, a.height, &refs.converged.pixels)
                .with_context(|| format!("writing {}", path.display()))?;
            files.push(path.display().to_string());
        }
        let out = json!({
            "scene": a.scene, "width": a.width, "height": a.height, "workers": a.workers,
            "reference_spp": a.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP),
            "converged_s": refs.converged.elapsed.as_secs_f64(), "converged_cached": refs.converged_cached,
            "full_rt_1spp_s": refs.one_spp.elapsed.as_secs_f64(),
            "psnr_1spp_vs_converged_db": psnr(&refs.one_spp.pixels, &refs.converged.pixels),
            "files": files,
        });
        let table = format!(
            "references of {} at {}x{}: {}spp in {:.2} s{}, 1spp in {:.2} s ({:.2} dB vs converged)\n  {}\n  {}\n",
            a.scene, a.width, a.height, a.reference_spp.unwrap_or(DEFAULT_REFERENCE_SPP), refs.converged.elapsed.as_secs_f64(),
            if refs.converged_cached { " (cached)" } else { "" },
            refs.one_spp.elapsed.as_secs_f64(), out["psnr_1spp_vs_converged_db"].as_f64().unwrap_or(0.0),
            conv.display(), one.display()
        ) + &args.exr.as_ref().map(|p| format!("  {}\n", p.display())).unwrap_or_default();
        crate::emit(args.json, &out, &table);
        Ok(())
    })
}

/// User + system CPU seconds of process `pid` so far, from `/proc/PID/stat` (Linux; `None`
/// elsewhere or when it cannot be read). The kernel reports them in USER_HZ ticks, which
/// Linux fixes at 100 per second for user space.
fn process_cpu_seconds(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) is in parentheses and may hold spaces: count from after it.
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // Fields 14 (utime) and 15 (stime) of the whole line are the 12th and 13th after ')'.
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        scene: SceneArgs,
    }

    fn params(args: &[&str]) -> HashMap<String, f64> {
        let cli = Cli::try_parse_from(std::iter::once("bench").chain(args.iter().copied())).expect("arguments parse");
        reference_params(&cli.scene)
    }

    #[test]
    fn references_of_cached_shaders_grow_their_records_further_unless_told() {
        assert_eq!(params(&["--shader", "gi"]).get("cache_max_rays"), Some(&8192.0), "8 × the default 1024");
        let p = params(&["--shader", "gi", "--shader-param", "cache_max_rays=2048", "--shader-param", "cache_rays=128"]);
        assert_eq!((p["cache_max_rays"], p["cache_rays"]), (16384.0, 128.0), "8 × the renders', the rest as given");
        assert_eq!(params(&["--shader", "gi", "--shader-param", "cache_max_rays=16384"])["cache_max_rays"], 65536.0, "at most the parameter's maximum");
        let p = params(&["--shader", "gi", "--shader-param", "cache_max_rays=2048", "--reference-param", "cache_max_rays=512", "--reference-param", "max_depth=9"]);
        assert_eq!((p["cache_max_rays"], p["max_depth"]), (512.0, 9.0), "--reference-param wins");
        assert!(params(&["--shader", "direct", "--shader-param", "shadow_rays=4"]).get("cache_max_rays").is_none(), "direct has no cache");
        assert_eq!(params(&["--shader", "direct", "--shader-param", "shadow_rays=4"])["shadow_rays"], 4.0);
    }
}
