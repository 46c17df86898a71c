//! `edgepoint-bench load`: how long a scene takes to become renderable — parse + weld +
//! edge adjacency (scene crate) and the two-level BVH build (worker) — measured in-process.
use anyhow::{Context, Result};
use edgepoint_server::reference::LogProgress;
use serde_json::json;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct LoadArgs {
    /// A .ply / .obj file (e.g. ../shared/data/dragon/dragon_vrip.ply); the same as --scene PATH.
    #[arg(long, conflicts_with = "scene")]
    pub mesh: Option<std::path::PathBuf>,
    /// A built-in scene name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz) [default: cornell].
    #[arg(long)]
    pub scene: Option<String>,
    /// Repeat the measurement this many times and report the median.
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: LoadArgs) -> Result<()> {
    let what = match (&a.mesh, &a.scene) {
        (Some(p), _) => p.display().to_string(),
        (None, Some(s)) => s.clone(),
        (None, None) => "cornell".to_string(),
    };
    // Read the files once, outside the timing: the workers parse scenes from bytes too.
    let source = edgepoint_viewer::client::scene_source_from_arg(&what)?;
    let (mut load_ms, mut bvh_ms) = (Vec::new(), Vec::new());
    let mut summary = json!({});
    for i in 0..a.repeat.max(1) {
        let progress = LogProgress::new(&format!("load {what}"));
        let t = Instant::now();
        let scene = edgepoint_proto::scene_from_source(&source, &progress).map_err(|e| anyhow::anyhow!("{e}"))?;
        load_ms.push(t.elapsed().as_secs_f64() * 1e3);
        if i == 0 {
            let big = scene.objects.iter().max_by_key(|o| o.mesh.triangles.len()).context("scene has no objects")?;
            let s = &big.mesh.stats;
            summary = json!({
                "objects": scene.objects.len(),
                "triangles": scene.triangle_count(),
                "largest_object": big.name,
                "input_triangles": s.input_triangles,
                "welded_triangles": s.triangles,
                "degenerate_dropped": s.degenerate_dropped,
                "vertices": s.vertices,
                "edges": s.edges,
                "boundary_edges": s.boundary_edges,
                "non_manifold_edges": s.non_manifold_edges,
            });
        }
        let t = Instant::now();
        let loaded = edgepoint_worker::LoadedScene::build(scene, what.clone(), &progress);
        bvh_ms.push(t.elapsed().as_secs_f64() * 1e3);
        drop(loaded);
    }
    let (l, b) = (crate::stats::median(&load_ms), crate::stats::median(&bvh_ms));
    let out = json!({
        "input": what,
        "mesh": summary,
        "load_weld_ms_median": l,
        "bvh_build_ms_median": b,
        "total_ms_median": l + b,
        "load_weld_ms": load_ms,
        "bvh_build_ms": bvh_ms,
        "threads": rayon::current_num_threads(),
    });
    let table = format!(
        "load {what}: {} triangles ({} edges, {} boundary); parse+weld+adjacency {:.0} ms, BVH {:.0} ms, total {:.0} ms (median of {})\n",
        out["mesh"]["welded_triangles"], out["mesh"]["edges"], out["mesh"]["boundary_edges"], l, b, l + b, a.repeat.max(1)
    );
    crate::emit(a.json, &out, &table);
    Ok(())
}
