//! `edgepoint-bench speedup`: paper 000 Table 2's speedup of an edge-and-point frame over a
//! full ray-traced frame, per scene and shader, with the same shader and the same workers
//! (issue 14 item 6; target ≥ 50× for `gi`, the paper's 19–58×).
//!
//! Per scene one local cluster (server + workers), per shader:
//! 1. an edge-and-point session at its usual sample rate (the server's defaults unless
//!    `--sparseness` / `--max-fps` say otherwise) for `--frames` frames: the median frame
//!    time (the frame loop's total, paper Table 2's frame time) over the frames built with
//!    the edge trees (all frames if none were), and the delivered fps;
//! 2. a full 1-spp frame: one ray through every pixel centre, shaded by the same workers in
//!    batches of the session's size, timed from the first request to the last answer.
//!
//! Speedup = full 1-spp frame time / median edge-and-point frame time. The full frame runs
//! after the session, so a `gi` worker's irradiance cache is already warm for it: the
//! comparison favours the full frame.
use crate::stats::{mean, median};
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_server::reference::{render_reference_with, LogProgress, ReferenceOptions};
use edgepoint_viewer::client::{camera_from_wire, scene_source_from_arg_in, Event, SessionClient};
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(clap::Args, Debug)]
pub struct SpeedupArgs {
    /// Scene: built-in name or scene file (repeatable; default cornell, rooms, glossy-bunny).
    #[arg(long = "scene")]
    pub scenes: Vec<String>,
    /// Shader (repeatable; default direct, glossy, gi).
    #[arg(long = "shader")]
    pub shaders: Vec<String>,
    /// Shader parameter KEY=VALUE for every shader that has it (repeatable).
    #[arg(long = "shader-param", value_parser = crate::requests::parse_param)]
    pub shader_params: Vec<(String, f64)>,
    /// Shared data directory for built-ins made from data (glossy-bunny; default:
    /// $EDGEPOINT_DATA, else a shared/data directory above the working directory or the
    /// executable).
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Image width in pixels.
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    /// Shader-worker processes (each session and full frame use all of them).
    #[arg(long, default_value_t = 2)]
    pub workers: usize,
    /// Threads per worker process (default: the worker's choice, all cores).
    #[arg(long)]
    pub worker_threads: Option<usize>,
    /// Niceness added to the worker processes (the frame loop gets the shared cores first).
    #[arg(long, default_value_t = edgepoint_viewer::local::WORKER_NICE)]
    pub worker_nice: i32,
    /// Run the workers under Linux's SCHED_IDLE policy as well (`--worker-idle false`:
    /// niceness only): a waking frame-loop thread then takes a core from a worker at once
    /// instead of waiting for its time slice.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set, value_name = "BOOL")]
    pub worker_idle: bool,
    /// Frames of each session.
    #[arg(long, default_value_t = 60)]
    pub frames: u32,
    #[command(flatten)]
    pub pace: crate::frame::PaceArgs,
    /// Requests per batch of the full frame: the sessions' batch size (server default 256).
    #[arg(long, default_value_t = 256)]
    pub batch: usize,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// What one session measured.
struct SessionFigures {
    median_frame_ms: f64,
    frames_with_edge_trees: usize,
    fps: f64,
    samples_per_frame: f64,
}

pub fn run(a: SpeedupArgs) -> Result<()> {
    let scenes = if a.scenes.is_empty() { vec!["cornell".into(), "rooms".into(), "glossy-bunny".into()] } else { a.scenes.clone() };
    let shaders = if a.shaders.is_empty() { vec!["direct".into(), "glossy".into(), "gi".into()] } else { a.shaders.clone() };
    if a.frames < 2 {
        bail!("--frames must be at least 2");
    }
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    let mut rows = Vec::new();
    let mut table = format!("speedup of an edge-and-point frame over a full 1-spp frame, {}x{}, {} workers\n", a.width, a.height, a.workers);
    table += "  scene         shader  frame ms (median)  fps   samples/frame  full 1-spp ms  speedup\n";
    for scene in &scenes {
        let source = scene_source_from_arg_in(scene, a.data_dir.as_deref())?;
        let scene_args = crate::frame::SceneArgs {
            scene: scene.clone(),
            data_dir: a.data_dir.clone(),
            width: a.width,
            height: a.height,
            workers: a.workers,
            worker_threads: a.worker_threads,
            worker_nice: a.worker_nice,
            worker_idle: a.worker_idle,
            shader: String::new(),
            shader_params: Vec::new(),
            reference_params: Vec::new(),
            reference_spp: None,
            ref_cache: None,
            camera: None,
            split: Default::default(),
        };
        let cluster = crate::frame::start_cluster(&scene_args)?;
        for shader in &shaders {
            // Each shader takes the parameters it knows.
            let table_row = pb::shaders::shader(shader).with_context(|| format!("unknown shader '{shader}'"))?;
            let params: Vec<(String, f64)> =
                a.shader_params.iter().filter(|(k, _)| table_row.params.iter().any(|p| p.name == k)).cloned().collect();
            let param_map: HashMap<String, f64> = params.iter().cloned().collect();
            let (s, full_ms) = rt.block_on(async {
                let start = crate::frame::start_message(&source, (a.width, a.height), (shader, &params), None, a.pace.settings());
                let (s, camera) = session(&cluster.server_url(), start, a.frames).await?;
                let dispatcher = crate::frame::open_dispatcher(&cluster, &source)?;
                let opts = ReferenceOptions { batch_size: a.batch.max(1), ..Default::default() };
                let progress = LogProgress::new(&format!("full 1-spp frame of {scene} ({shader})"));
                let img = render_reference_with(&dispatcher, &camera, a.width, a.height, 1, shader, &param_map, &progress, &opts)
                    .await
                    .context("full 1-spp frame")?;
                anyhow::Ok((s, img.elapsed.as_secs_f64() * 1e3))
            })?;
            let speedup = full_ms / s.median_frame_ms;
            table += &format!(
                "  {scene:<13} {shader:<7} {:>17.2}  {:>4.1}  {:>13.0}  {:>13.0}  {:>6.1}x\n",
                s.median_frame_ms, s.fps, s.samples_per_frame, full_ms, speedup
            );
            rows.push(json!({
                "scene": scene,
                "shader": shader,
                "shader_params": param_map,
                "frame_median_ms": s.median_frame_ms,
                "frames_with_edge_trees": s.frames_with_edge_trees,
                "fps": s.fps,
                "samples_per_frame_mean": s.samples_per_frame,
                "full_1spp_ms": full_ms,
                "speedup": speedup,
            }));
        }
    }
    let out = json!({
        "width": a.width,
        "height": a.height,
        "workers": a.workers,
        "worker_threads": a.worker_threads,
        "worker_nice": a.worker_nice,
        "worker_idle": a.worker_idle,
        "frames": a.frames,
        "batch": a.batch,
        "runs": rows,
    });
    crate::emit(a.json, &out, &table);
    Ok(())
}

/// Runs a session for `frames` frames; its figures and the camera it rendered.
async fn session(url: &str, start: pb::Start, frames: u32) -> Result<(SessionFigures, edgepoint_scene::Camera)> {
    let (mut client, started) = SessionClient::connect(url, start).await?;
    let camera = camera_from_wire(started.camera.as_ref().context("server sent no camera")?);
    let (mut all, mut trees, mut samples) = (Vec::new(), Vec::new(), Vec::new());
    let mut first_at = None;
    while (all.len() as u32) < frames {
        let ev = tokio::time::timeout(Duration::from_secs(120), client.next_event()).await.context("no frame for 120 s")?;
        match ev {
            None => bail!("the session ended after {} frames", all.len()),
            Some(Err(e)) => return Err(e.into()),
            Some(Ok(Event::Rejected(r))) => bail!("server rejected a message: {}", r.message),
            Some(Ok(Event::Frame(f))) => {
                first_at.get_or_insert_with(Instant::now);
                // The loop's whole work for the frame: its total and the picking of the next
                // samples after it was published.
                let ms = f.total_ms + f.after_ms;
                all.push(ms);
                samples.push(f.samples_used as f64);
                if f.edges.as_ref().is_some_and(|e| e.edge_trees) {
                    trees.push(ms);
                }
            }
            Some(Ok(_)) => {}
        }
    }
    let wall = first_at.map_or(0.0, |t: Instant| t.elapsed().as_secs_f64());
    let steady = if trees.is_empty() { &all } else { &trees };
    Ok((
        SessionFigures {
            median_frame_ms: median(steady),
            frames_with_edge_trees: trees.len(),
            fps: if wall > 0.0 { (all.len() - 1) as f64 / wall } else { 0.0 },
            samples_per_frame: mean(&samples),
        },
        camera,
    ))
}
