//! `edgepoint-bench simplify`: several lights simplified (paper 003). The same scene, camera
//! and frame count in two sessions on the same workers, one after the other: first with
//! every shadow edge (tolerance 0), then leaving out those the other lights wash out below
//! `--tolerance`. Per session: shadow edges in the last frame's EPI by kind, samples per
//! frame, the last frame's PSNR / SSIM against the converged reference (cached on disk, the
//! same for both), and the frame times; then the ratios.
use crate::frame::{session_report, start_cluster, FrameArgs};
use anyhow::{bail, Result};
use edgepoint_viewer::client::scene_source_from_arg_in;
use serde_json::{json, Value};

#[derive(clap::Args, Debug)]
pub struct SimplifyArgs {
    #[command(flatten)]
    pub frame: FrameArgs,
    /// Simplification tolerance of the second session: shadow edges whose estimated
    /// relative L2 error of leaving them out is below it are left out (paper 003).
    #[arg(long, value_name = "T", default_value_t = 0.05)]
    pub tolerance: f64,
    /// Time the estimates alone in this process instead of running sessions: the scene's
    /// shadow edges from sampled triples, estimated with the culls of lights that cannot
    /// reach a band, and a subset again without them (same estimates, compared).
    #[arg(long)]
    pub estimates: bool,
    /// With --estimates: edges estimated both with and without the culls.
    #[arg(long, value_name = "N", default_value_t = 300)]
    pub compare: usize,
    /// With --estimates: surface points per object for the triples.
    #[arg(long, value_name = "N", default_value_t = 4000)]
    pub triple_points: usize,
    /// With --estimates: then slide --object this many times along X (as a drag does) and
    /// measure the estimates kept across each move against all made afresh there, for the
    /// finder's shadow edges and (scenes with an area light) the discontinuity mesh's.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub moves: usize,
    /// With --moves: the object to slide (default: the smallest object of 8 triangles or
    /// more).
    #[arg(long, value_name = "NAME")]
    pub object: Option<String>,
    /// With --moves: each move's length, as a fraction of the object's box diagonal.
    #[arg(long, value_name = "F", default_value_t = 0.05)]
    pub move_step: f64,
}

fn shadow_edges(r: &Value) -> u64 {
    ["shadow_hard", "shadow_umbral", "shadow_penumbral"].iter().map(|k| r["edges"][k].as_u64().unwrap_or(0)).sum()
}

pub fn run(args: SimplifyArgs) -> Result<()> {
    let f = &args.frame;
    if f.frames == 0 {
        bail!("--frames must be at least 1");
    }
    if !args.tolerance.is_finite() || args.tolerance <= 0.0 || args.tolerance > 100.0 {
        bail!("--tolerance must be in (0, 100], got {}", args.tolerance);
    }
    if f.reconstruction.simplify_tolerance.is_some() {
        bail!("give the tolerance as --tolerance (the first session runs at 0)");
    }
    if args.estimates {
        let scene = edgepoint_scene::data::load_builtin(&f.scene.scene, f.scene.data_dir.as_deref(), &edgepoint_scene::NoProgress)
            .map_err(anyhow::Error::msg)?;
        let moves = crate::simplify_estimates::Moves { count: args.moves, object: args.object.clone(), step: args.move_step };
        let (v, table) = crate::simplify_estimates::run(scene, &f.scene.scene, args.triple_points, args.compare, args.tolerance, &moves)?;
        crate::emit(f.json, &v, &table);
        return Ok(());
    }
    let source = scene_source_from_arg_in(&f.scene.scene, f.scene.data_dir.as_deref())?;
    let cluster = start_cluster(&f.scene)?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    rt.block_on(async {
        let mut runs = Vec::new();
        for t in [0.0, args.tolerance] {
            let mut settings = f.pace.settings();
            f.reconstruction.apply(&mut settings);
            settings.simplify_tolerance = Some(t);
            let (out, _) = session_report(&cluster, f, &source, settings).await?;
            runs.push(out);
        }
        let (before, after) = (&runs[0], &runs[1]);
        let ratio = |k: &str| match (before[k].as_f64(), after[k].as_f64()) {
            (Some(b), Some(a)) if b > 0.0 => json!(a / b),
            _ => Value::Null,
        };
        let (eb, ea) = (shadow_edges(before), shadow_edges(after));
        let summary = json!({
            "scene": f.scene.scene,
            "tolerance": args.tolerance,
            "frames": f.frames,
            "shadow_edges_before": eb,
            "shadow_edges_after": ea,
            "shadow_edges_ratio": if eb > 0 { json!(ea as f64 / eb as f64) } else { Value::Null },
            "psnr_before_db": before["psnr_last_frame_db"],
            "psnr_after_db": after["psnr_last_frame_db"],
            "samples_per_frame_before": before["samples_per_frame_mean"],
            "samples_per_frame_after": after["samples_per_frame_mean"],
            "samples_per_frame_ratio": ratio("samples_per_frame_mean"),
            "total_median_ms_ratio": ratio("total_median_ms"),
            "before": before,
            "after": after,
        });
        let table = format!(
            "simplify {} (tolerance {}), {} frames: shadow edges {eb} -> {ea}; PSNR {} -> {} dB; samples/frame {} -> {}; frame median {} -> {} ms\n",
            f.scene.scene,
            args.tolerance,
            f.frames,
            before["psnr_last_frame_db"],
            after["psnr_last_frame_db"],
            before["samples_per_frame_mean"],
            after["samples_per_frame_mean"],
            before["total_median_ms"],
            after["total_median_ms"],
        );
        crate::emit(f.json, &summary, &table);
        Ok(())
    })
}
