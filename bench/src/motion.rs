//! `edgepoint-bench motion`: image quality in motion (issue "interaction that holds up";
//! paper 000 §4.3 and §5.3). A local cluster and a real session follow a scripted path —
//! the scene's orbit, a dolly, a still camera, an object sliding back and forth, or a camera
//! path file — one step per frame, in lock step: step k+1 is sent when the frame rendered
//! with step k (its echoed camera and scene epoch) has arrived, as a viewer following the
//! path would. Afterwards the converged reference of every step's exact camera and object
//! state is rendered through the same workers (cached on disk), and each frame is measured
//! against its own reference:
//!
//! - PSNR and SSIM (on sRGB values, as a viewer sees them);
//! - outlier pixels: any channel off by more than 0.25 in sRGB (speckles, ghosts,
//!   see-through surfaces, stale shadows);
//! - for `move-object:NAME`, the moved object's coverage: of the pixels inside the object in
//!   the reference (the pixel and its 8 neighbours show the object, from the exact visibility
//!   of that state; its anti-aliased outline is left out), the fraction the frame shows
//!   within that tolerance;
//! - newly exposed surfaces: pixels whose surface point was hidden or off-screen in the
//!   previous step's view; each frame's exposed points are followed (in their object's own
//!   coordinates, so through object moves too) until 95 % of those still in view are within
//!   tolerance: the frames that takes.
//!
//! Edge-and-point and Render Cache reconstruction run the same path one after the other
//! (`--modes`), on the same cluster.
use crate::frame::{start_cluster, SceneArgs};
use crate::inprocess::write_png;
use crate::reference_cache::RefCache;
use crate::stats::median;
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_scene::camera::CameraFrame;
use edgepoint_scene::{Camera, NoProgress, Scene};
use edgepoint_server::image_metrics::{linear_to_srgb8, psnr, srgb8_to_linear, ssim};
use edgepoint_server::reference::{render_reference, LogProgress};
use edgepoint_server::visibility::{Visibility, NO_OBJECT};
use edgepoint_server::workers::WorkerPool;
use edgepoint_viewer::camera_path::{read_path, resolve_path, suggested_orbit};
use edgepoint_viewer::client::{camera_to_wire, scene_source_from_arg_in, Event, SessionClient};
use edgepoint_viewer::script::ObjectSlide;
use edgepoint_viewer::reconstruction::ReconstructionMode;
use glam::{Affine3A, Vec3};
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// A pixel is an outlier when a channel differs from the reference by more than this, in
/// 8-bit sRGB units (0.25 of the range).
pub const OUTLIER_SRGB8: i32 = 64;
/// Fraction of a cohort of newly exposed points (those still in view) that must be within
/// tolerance for the region to count as filled.
const FILLED_FRACTION: f64 = 0.95;
/// Newly exposed points followed per frame at most (a deterministic subsample beyond).
const COHORT_MAX: usize = 4000;
/// A surface point counts as seen in a view when its depth is within this fraction of the
/// nearest surface's there.
const SEEN_RELATIVE: f32 = 0.01;

#[derive(clap::Args, Debug)]
pub struct MotionArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// The path: `orbit` (the scene's suggested orbit, which stays inside the built-in
    /// rooms, at --degrees-per-frame; `--camera fov=` sets its lens), `dolly` (toward the
    /// camera's target to 60 % of the distance and back, 120 frames a cycle), `still`,
    /// `move-object:NAME` (NAME slides back and forth along X, 25 % of the scene's width, 120
    /// frames a cycle, camera still), or a camera path file (one JSON camera per line, as
    /// `edgepoint-viewer --record-path` writes). The still, dolly and object paths start
    /// from the scene's camera with `--camera` over it.
    #[arg(long, default_value = "orbit")]
    pub path: String,
    /// Orbit step in degrees per frame (with `--path orbit`).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    pub degrees_per_frame: f32,
    /// Frames (steps of the path) to measure.
    #[arg(long, default_value_t = 60)]
    pub frames: u32,
    /// Reconstructions to run, comma-separated: `epr` (edge-and-point), `render-cache`.
    #[arg(long, default_value = "epr,render-cache", value_delimiter = ',')]
    pub modes: Vec<String>,
    /// Pixels per new sample per frame (server default 64).
    #[arg(long)]
    pub sparseness: Option<f64>,
    /// Frame-rate cap of the server's frame loop (server default 30).
    #[arg(long)]
    pub max_fps: Option<f64>,
    /// Frames after which the PSNR median is taken (the targets: after frame 10).
    #[arg(long, default_value_t = 10)]
    pub settle_frames: u32,
    /// Write every frame, its reference and an outlier map as PNG into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One step of a path: the camera, and the objects placed somewhere else than at the
/// start (absolute object-to-world transforms).
#[derive(Debug, Clone, PartialEq)]
struct Step {
    camera: Camera,
    moved: Vec<(u32, Affine3A)>,
}

/// What a session showed at each step.
struct Recorded {
    frames: Vec<pb::Frame>,
    /// Frames received that were not the first of a step (rendered before the step's input
    /// took effect, or between steps).
    skipped: u64,
}

pub fn run(args: MotionArgs) -> Result<()> {
    let a = &args.scene;
    if args.frames == 0 {
        bail!("--frames must be at least 1");
    }
    let modes: Vec<ReconstructionMode> = args
        .modes
        .iter()
        .map(|m| match m.trim() {
            "epr" => Ok(ReconstructionMode::Epr),
            "render-cache" => Ok(ReconstructionMode::RenderCache),
            other => bail!("--modes: unknown reconstruction '{other}' (epr, render-cache)"),
        })
        .collect::<Result<_>>()?;
    let source = scene_source_from_arg_in(&a.scene, a.data_dir.as_deref())?;
    let scene = pb::scene_from_source(&source, &NoProgress).map_err(|e| anyhow::anyhow!("{}: {e}", a.scene))?;
    let cluster = start_cluster(a)?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    rt.block_on(async {
        let mut steps: Option<Vec<Step>> = None;
        let mut runs = Vec::new();
        for &mode in &modes {
            let (rec, st) = record(&cluster, &args, &source, &scene, mode, steps.as_deref()).await?;
            steps.get_or_insert(st);
            runs.push((mode, rec));
        }
        let steps = steps.expect("at least one mode");
        let refs = references(&cluster, &args, &source, &steps).await?;
        let moved_object = args.path.strip_prefix("move-object:").map(|n| scene.object_id(n).expect("checked when the path was made"));
        let truth = Truth::new(&scene, &steps, a.width, a.height);
        let mut modes_out = serde_json::Map::new();
        let mut table = String::new();
        use std::fmt::Write;
        writeln!(table, "motion benchmark: {} path {} {}x{}, {} frames, references {} spp", a.scene, args.path, a.width, a.height, steps.len(), reference_spp(&args))?;
        for (mode, rec) in &runs {
            let name = mode.name();
            let m = measure(&args, rec, &refs, &truth, moved_object, name)?;
            writeln!(table, "  {name}: {}", m.summary())?;
            modes_out.insert(name.to_string(), m.json);
        }
        let mut out = json!({
            "scene": a.scene,
            "path": args.path,
            "width": a.width,
            "height": a.height,
            "frames": steps.len(),
            "workers": a.workers,
            "shader": a.shader,
            "reference_spp": reference_spp(&args),
            "outlier_threshold_srgb": OUTLIER_SRGB8 as f64 / 255.0,
            "settle_frames": args.settle_frames,
            "modes": modes_out,
        });
        if let (Some(e), Some(r)) = (out["modes"].get("epr"), out["modes"].get("render-cache")) {
            let d = e["psnr_median_after_settle_db"].as_f64().unwrap_or(0.0) - r["psnr_median_after_settle_db"].as_f64().unwrap_or(0.0);
            out["epr_minus_render_cache_psnr_db"] = json!(d);
            writeln!(table, "  edge-and-point minus Render Cache (median PSNR after frame {}): {d:+.2} dB", args.settle_frames)?;
        }
        crate::emit(args.json, &out, &table);
        Ok(())
    })
}

fn reference_spp(args: &MotionArgs) -> u32 {
    args.scene.reference_spp.unwrap_or(16)
}

/// The steps of `--path` for a session that started as `started`.
fn make_steps(args: &MotionArgs, started: &pb::Started, scene: &Scene) -> Result<Vec<Step>> {
    let n = args.frames as usize;
    let base = edgepoint_viewer::client::camera_from_wire(started.camera.as_ref().context("the server sent no camera")?);
    let p = args.path.as_str();
    let still = |camera: Camera| (0..n).map(|_| Step { camera, moved: Vec::new() }).collect::<Vec<_>>();
    Ok(match p {
        "still" => still(base),
        "orbit" => {
            let mut orbit = suggested_orbit(started)?;
            if let Some(fov) = args.scene.camera.as_ref().and_then(|c| c.fov_y_degrees) {
                orbit.fov_y_degrees = fov;
            }
            (0..n).map(|k| Step { camera: orbit.camera_after(k as f32 * args.degrees_per_frame), moved: Vec::new() }).collect()
        }
        "dolly" => (0..n)
            .map(|k| {
                let s = 1.0 - 0.4 * 0.5 * (1.0 - (std::f32::consts::TAU * k as f32 / 120.0).cos());
                Step { camera: Camera { eye: base.target + (base.eye - base.target) * s, ..base }, moved: Vec::new() }
            })
            .collect(),
        _ if p.starts_with("move-object:") => {
            let name = &p["move-object:".len()..];
            if scene.object_id(name).is_none() {
                let names: Vec<_> = scene.objects.iter().map(|o| o.name.as_str()).collect();
                bail!("--path {p}: the scene has no object '{name}' (objects: {})", names.join(", "));
            }
            let slide = ObjectSlide::new(started, name)?;
            let (id, _) = slide.object();
            (0..n).map(|k| Step { camera: base, moved: vec![(id, slide.transform_at(k as u64))] }).collect()
        }
        file => {
            let entries = read_path(std::path::Path::new(file)).with_context(|| format!("--path {file}: not orbit, dolly, still or move-object:NAME, and not a readable camera path"))?;
            let cams = resolve_path(&entries, &base, file)?;
            if cams.is_empty() {
                bail!("--path {file}: the camera path is empty");
            }
            (0..n).map(|k| Step { camera: cams[k.min(cams.len() - 1)], moved: Vec::new() }).collect()
        }
    })
}

/// Runs one session along the path in lock step; returns the frames of the steps (and the
/// steps, made from the session's `started`, or checked against `expected`).
async fn record(
    cluster: &edgepoint_viewer::local::LocalCluster,
    args: &MotionArgs,
    source: &pb::SceneSource,
    scene: &Scene,
    mode: ReconstructionMode,
    expected: Option<&[Step]>,
) -> Result<(Recorded, Vec<Step>)> {
    let a = &args.scene;
    // The first camera is the path's: open the session once to learn the scene's suggested
    // orbit, then again with the first step's camera, so frame 1 already shows step 1.
    let settings = pb::Settings {
        sparseness: args.sparseness.unwrap_or(0.0),
        max_fps: args.max_fps.unwrap_or(0.0),
        reconstruction: mode.to_wire() as i32,
        ..Default::default()
    };
    // --camera over the scene's camera: the base of the still, dolly and object paths.
    let mut start = crate::frame::start_message(source, (a.width, a.height), (&a.shader, &a.shader_params), a.camera.as_ref(), settings);
    let steps = match expected {
        Some(s) => s.to_vec(),
        None => {
            let (probe, started) = SessionClient::connect(&cluster.server_url(), start.clone()).await?;
            drop(probe);
            make_steps(args, &started, scene)?
        }
    };
    start.camera = Some(camera_to_wire(&steps[0].camera));
    let (mut client, _started) = SessionClient::connect(&cluster.server_url(), start).await?;
    // Object moves of step 0 (a slide starts at offset 0, but a path may start elsewhere).
    let mut epoch = 0u64;
    let mut placed: HashMap<u32, Affine3A> = HashMap::new();
    let send_step = |client: &SessionClient, step: &Step, epoch: &mut u64, placed: &mut HashMap<u32, Affine3A>, prev: Option<&Step>| -> Result<()> {
        for &(id, t) in &step.moved {
            if placed.get(&id) != Some(&t) {
                client.send_move(pb::ObjectMove { object_id: id, name: String::new(), transform: Some(pb::affine_to_wire(&t)) })?;
                placed.insert(id, t);
                *epoch += 1;
            }
        }
        if prev.is_some_and(|p| p.camera != step.camera) {
            client.send_camera(camera_to_wire(&step.camera))?;
        }
        Ok(())
    };
    let initial: Vec<(u32, Affine3A)> = scene.objects.iter().enumerate().map(|(i, o)| (i as u32, o.transform)).collect();
    for &(id, t) in &initial {
        placed.insert(id, t);
    }
    send_step(&client, &steps[0], &mut epoch, &mut placed, None)?;
    let mut frames = Vec::with_capacity(steps.len());
    let mut skipped = 0u64;
    let started_at = Instant::now();
    for (k, step) in steps.iter().enumerate() {
        let want_camera = camera_to_wire(&step.camera);
        loop {
            let ev = tokio::time::timeout(Duration::from_secs(120), client.next_event())
                .await
                .with_context(|| format!("no frame for step {} within 120 s", k + 1))?;
            match ev {
                None => bail!("the session ended after {} of {} steps", k, steps.len()),
                Some(Err(e)) => return Err(e.into()),
                Some(Ok(Event::Rejected(r))) => bail!("the server rejected a message of the path: {}", r.message),
                Some(Ok(Event::Frame(f))) => {
                    if f.epoch == epoch && f.camera.as_ref() == Some(&want_camera) {
                        frames.push(f);
                        break;
                    }
                    skipped += 1;
                }
                Some(Ok(_)) => {}
            }
        }
        if let Some(next) = steps.get(k + 1) {
            send_step(&client, next, &mut epoch, &mut placed, Some(step))?;
        }
    }
    tracing::info!(mode = mode.name(), steps = steps.len(), skipped, secs = started_at.elapsed().as_secs_f64(), "path recorded");
    Ok((Recorded { frames, skipped }, steps))
}

/// The converged reference of every step (linear RGB), rendered through the cluster's
/// workers at the step's object transforms, or read from the cache.
async fn references(cluster: &edgepoint_viewer::local::LocalCluster, args: &MotionArgs, source: &pb::SceneSource, steps: &[Step]) -> Result<Vec<Vec<Vec3>>> {
    let a = &args.scene;
    let hash = pb::scene_hash(source);
    let endpoints = cluster.worker_addrs().iter().map(|w| format!("http://{w}")).collect();
    let pool = WorkerPool::new(endpoints)?;
    let dispatcher = pool.open(source.clone(), hash.clone());
    let params = crate::frame::reference_params(a);
    let cache = RefCache::at(a.ref_cache.as_deref());
    let spp = reference_spp(args);
    let mut out = Vec::with_capacity(steps.len());
    let mut epoch = 0u64;
    let mut placed: Vec<(u32, Affine3A)> = Vec::new();
    let t0 = Instant::now();
    let mut rendered = 0;
    for (k, step) in steps.iter().enumerate() {
        let moves: String = step.moved.iter().map(|(id, t)| format!("{id}:{:?};", t.to_cols_array())).collect();
        let key = RefCache::key_with(&hash, &step.camera, a.width, a.height, spp, &a.shader, &params, &moves);
        if let Some(img) = cache.load(&key, a.width, a.height, spp) {
            out.push(img.pixels);
            continue;
        }
        if step.moved != placed {
            epoch += 1;
            if !dispatcher.set_epoch(epoch, step.moved.clone()) {
                bail!("the reference dispatcher refused epoch {epoch}");
            }
            placed = step.moved.clone();
        }
        let progress = LogProgress::new(&format!("reference {}/{} ({spp} spp)", k + 1, steps.len()));
        let img = render_reference(&dispatcher, &step.camera, a.width, a.height, spp, &a.shader, &params, &progress)
            .await
            .with_context(|| format!("reference of step {}", k + 1))?;
        cache.store(&key, &img)?;
        rendered += 1;
        out.push(img.pixels);
    }
    if rendered > 0 {
        tracing::info!(rendered, cached = steps.len() - rendered, secs = t0.elapsed().as_secs_f64(), "references");
    }
    Ok(out)
}

/// The exact visibility of every step (object and depth at each pixel centre) and the
/// newly exposed surface points of each step.
struct Truth {
    width: u32,
    height: u32,
    /// Per step: object per pixel, and depth per pixel.
    objects: Vec<Vec<u32>>,
    depths: Vec<Vec<f32>>,
    frames: Vec<CameraFrame>,
    transforms: Vec<Vec<Affine3A>>,
    /// Per step: newly exposed points as (object, object-space position), subsampled.
    exposed: Vec<Vec<(u32, Vec3)>>,
    /// Per step: how many pixels were newly exposed (before subsampling).
    exposed_pixels: Vec<usize>,
}

impl Truth {
    fn new(scene: &Scene, steps: &[Step], width: u32, height: u32) -> Truth {
        let mut vis = Visibility::new(width, height);
        let n = width as usize * height as usize;
        let mut t = Truth { width, height, objects: Vec::new(), depths: Vec::new(), frames: Vec::new(), transforms: Vec::new(), exposed: Vec::new(), exposed_pixels: Vec::new() };
        for step in steps {
            let mut tf: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
            for &(id, m) in &step.moved {
                tf[id as usize] = m;
            }
            let frame = step.camera.frame(width, height);
            vis.update(scene, &tf, &frame);
            t.objects.push((0..n).map(|i| vis.object(i)).collect());
            t.depths.push((0..n).map(|i| vis.depth(i)).collect());
            t.frames.push(frame);
            t.transforms.push(tf);
        }
        for k in 0..steps.len() {
            let mut pts = Vec::new();
            if k > 0 {
                for i in 0..n {
                    let o = t.objects[k][i];
                    if o == NO_OBJECT {
                        continue;
                    }
                    let world = t.point_at(k, i);
                    let local = t.transforms[k][o as usize].inverse().transform_point3(world);
                    if !t.seen(k - 1, o, local) {
                        pts.push((o, local));
                    }
                }
            }
            t.exposed_pixels.push(pts.len());
            if pts.len() > COHORT_MAX {
                let stride = pts.len().div_ceil(COHORT_MAX);
                pts = pts.into_iter().step_by(stride).collect();
            }
            t.exposed.push(pts);
        }
        t
    }

    /// The world point seen at the centre of pixel `i` in step `k` (covered pixels only).
    fn point_at(&self, k: usize, i: usize) -> Vec3 {
        let w = self.width as usize;
        let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
        let f = &self.frames[k];
        let (o, d) = f.ray(x, y);
        o + d * (self.depths[k][i] / d.dot(f.forward))
    }

    /// The pixel where object `o`'s point `local` shows in step `k`, if it is in view and not
    /// hidden.
    fn seen_at(&self, k: usize, o: u32, local: Vec3) -> Option<usize> {
        let world = self.transforms[k][o as usize].transform_point3(local);
        let (sx, sy, z) = self.frames[k].project(world)?;
        if !(sx >= 0.0 && sy >= 0.0 && sx < self.width as f32 && sy < self.height as f32) {
            return None;
        }
        let i = sy as usize * self.width as usize + sx as usize;
        let d = self.depths[k][i];
        (z <= d * (1.0 + SEEN_RELATIVE)).then_some(i)
    }

    fn seen(&self, k: usize, o: u32, local: Vec3) -> bool {
        self.seen_at(k, o, local).is_some()
    }
}

/// The measures of one mode.
struct Measured {
    json: serde_json::Value,
    psnr_median: f64,
    max_outliers_after_5: f64,
    min_coverage_after_3: Option<f64>,
    fill_median: Option<f64>,
}

impl Measured {
    fn summary(&self) -> String {
        let mut s = format!(
            "PSNR median after settle {:.2} dB; max outlier fraction after frame 5 {:.4} %",
            self.psnr_median,
            100.0 * self.max_outliers_after_5
        );
        if let Some(c) = self.min_coverage_after_3 {
            s += &format!("; moved object's coverage min after frame 3 {:.2} %", 100.0 * c);
        }
        if let Some(f) = self.fill_median {
            s += &format!("; newly exposed regions filled in {f:.1} frames (median)");
        }
        s
    }
}

fn measure(args: &MotionArgs, rec: &Recorded, refs: &[Vec<Vec3>], truth: &Truth, moved: Option<u32>, name: &str) -> Result<Measured> {
    let (w, h) = (args.scene.width, args.scene.height);
    let n = w as usize * h as usize;
    let mut per_frame = Vec::new();
    let mut outliers_per_frame: Vec<Vec<bool>> = Vec::new();
    let mut psnrs = Vec::new();
    let mut max_out_after_5 = 0f64;
    let mut min_cov_after_3: Option<f64> = None;
    for (k, f) in rec.frames.iter().enumerate() {
        let img = edgepoint_viewer::frame::decode_frame(f)?;
        let lin: Vec<Vec3> = img.pixels().map(|p| srgb8_to_linear(p.0)).collect();
        let reference = &refs[k];
        let p = psnr(&lin, reference);
        let s = ssim(&lin, reference, w, h);
        let out: Vec<bool> = img
            .pixels()
            .zip(reference)
            .map(|(a, r)| {
                let r = linear_to_srgb8(*r);
                (0..3).any(|c| (a.0[c] as i32 - r[c] as i32).abs() >= OUTLIER_SRGB8)
            })
            .collect();
        let outlier_fraction = out.iter().filter(|&&o| o).count() as f64 / n as f64;
        let coverage = moved.map(|o| coverage(truth, k, o, &out));
        let frame_no = k as u32 + 1;
        if frame_no > args.settle_frames {
            psnrs.push(p);
        }
        if frame_no > 5 {
            max_out_after_5 = max_out_after_5.max(outlier_fraction);
        }
        if let (Some(c), true) = (coverage.flatten(), frame_no > 3) {
            min_cov_after_3 = Some(min_cov_after_3.map_or(c, |m: f64| m.min(c)));
        }
        // Of the points newly exposed in this very frame, how many it already shows right.
        let exposed = &truth.exposed[k];
        let shown_right = exposed.iter().filter(|&&(o, l)| truth.seen_at(k, o, l).is_some_and(|i| !out[i])).count();
        per_frame.push(json!({
            "frame": frame_no,
            "sequence": f.sequence,
            "psnr_db": p,
            "ssim": s,
            "outlier_fraction": outlier_fraction,
            "moved_object_coverage": coverage.flatten(),
            "newly_exposed_pixels": truth.exposed_pixels[k],
            "newly_exposed_right_fraction": if exposed.is_empty() { json!(null) } else { json!(shown_right as f64 / exposed.len() as f64) },
            "samples_used": f.samples_used,
            "total_ms": f.total_ms,
        }));
        if let Some(dir) = &args.out {
            let d = dir.join(name);
            std::fs::create_dir_all(&d)?;
            write_png(&d.join(format!("frame_{frame_no:05}.png")), w, h, &lin)?;
            write_png(&d.join(format!("reference_{frame_no:05}.png")), w, h, reference)?;
            let map: Vec<Vec3> = out.iter().zip(&lin).map(|(&o, c)| if o { Vec3::new(1.0, 0.0, 1.0) } else { *c * 0.3 }).collect();
            write_png(&d.join(format!("outliers_{frame_no:05}.png")), w, h, &map)?;
        }
        outliers_per_frame.push(out);
    }
    // Frames each cohort of newly exposed points takes until 95 % of those in view are right.
    let mut fill_frames = Vec::new();
    let mut unfilled = 0usize;
    for k in 1..rec.frames.len() {
        let cohort = &truth.exposed[k];
        if cohort.len() < 16 {
            continue;
        }
        let mut done = None;
        for (j, outliers) in outliers_per_frame.iter().enumerate().take(rec.frames.len()).skip(k) {
            let (mut inview, mut right) = (0usize, 0usize);
            for &(o, l) in cohort {
                if let Some(i) = truth.seen_at(j, o, l) {
                    inview += 1;
                    right += usize::from(!outliers[i]);
                }
            }
            if inview == 0 {
                break;
            }
            if right as f64 >= FILLED_FRACTION * inview as f64 {
                done = Some(j - k);
                break;
            }
        }
        match done {
            Some(d) => fill_frames.push(d as f64),
            None => unfilled += 1,
        }
    }
    let psnr_median = median(&psnrs);
    let fill_median = (!fill_frames.is_empty()).then(|| median(&fill_frames));
    let json = json!({
        "psnr_median_after_settle_db": psnr_median,
        "ssim_median_after_settle": median(&per_frame.iter().skip(args.settle_frames as usize).filter_map(|f| f["ssim"].as_f64()).collect::<Vec<_>>()),
        "max_outlier_fraction_after_frame_5": max_out_after_5,
        "median_outlier_fraction": median(&per_frame.iter().filter_map(|f| f["outlier_fraction"].as_f64()).collect::<Vec<_>>()),
        "moved_object_min_coverage_after_frame_3": min_cov_after_3,
        "newly_exposed_fill_frames_median": fill_median,
        "newly_exposed_fill_frames_max": fill_frames.iter().cloned().fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v)))),
        "newly_exposed_cohorts_never_filled": unfilled,
        "frames_skipped": rec.skipped,
        "frames": per_frame,
    });
    Ok(Measured { json, psnr_median, max_outliers_after_5: max_out_after_5, min_coverage_after_3: min_cov_after_3, fill_median })
}

/// Of the pixels inside object `o` in step `k` (the pixel and its 8 neighbours show it),
/// the fraction that are not outliers; `None` when the object shows no such pixel.
fn coverage(truth: &Truth, k: usize, o: u32, outlier: &[bool]) -> Option<f64> {
    let (w, h) = (truth.width as usize, truth.height as usize);
    let obj = &truth.objects[k];
    let (mut inside, mut right) = (0usize, 0usize);
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            let all = (-1i64..=1).all(|dy| (-1i64..=1).all(|dx| obj[(i as i64 + dy * w as i64 + dx) as usize] == o));
            if all {
                inside += 1;
                right += usize::from(!outlier[i]);
            }
        }
    }
    (inside > 0).then(|| right as f64 / inside as f64)
}
