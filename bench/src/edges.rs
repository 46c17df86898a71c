//! `edgepoint-bench edges`: the edge trees and shadow edges of paper 000 §6 measured
//! in-process — tree build time, silhouette time against brute force from the same random
//! viewpoints, and (for scenes) shadow-edge time at load and after a move, with the per-frame
//! counts of silhouette and shadow edges (paper Table 3).
use anyhow::{Context, Result};
use edgepoint_scene::{Mesh, Progress};
use edgepoint_server::edges::brute;
use edgepoint_server::edges::tree::{EdgeTree, SplitAxes, TreeParams};
use edgepoint_server::reference::LogProgress;
use glam::Vec3;
use serde_json::json;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct EdgesArgs {
    /// A .ply / .obj file: its largest object is measured.
    #[arg(long)]
    pub mesh: Option<std::path::PathBuf>,
    /// Random viewpoints for the silhouette timing.
    #[arg(long, default_value_t = 200)]
    pub views: usize,
    /// Seed of the random viewpoints.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Tree split axes: `mixed` (normals and positions, the default) or `normals` (paper).
    #[arg(long, default_value = "mixed")]
    pub split: String,
    /// Leaf size.
    #[arg(long, default_value_t = 8)]
    pub leaf: usize,
    /// Stay fraction ("sharp edges higher"); 0 disables.
    #[arg(long, default_value_t = 0.5)]
    pub stay: f32,
    /// Viewing distance for mixed splits, in bounding-box diagonals.
    #[arg(long, default_value_t = 2.0)]
    pub view_distance: f32,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let x = self.0;
        (x ^ (x >> 33)).wrapping_mul(0xff51afd7ed558ccd) ^ (x >> 29)
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Random eyes around a mesh: uniform directions, distances 1.2–4 bounding radii from the
/// centre.
fn viewpoints(mesh: &Mesh, n: usize, seed: u64) -> Vec<Vec3> {
    let (lo, hi) = mesh.bounds;
    let c = (lo + hi) * 0.5;
    let r = (hi - lo).length() * 0.5;
    let mut g = Rng(seed);
    (0..n)
        .map(|_| {
            let z = g.unit() * 2.0 - 1.0;
            let t = g.unit() * std::f32::consts::TAU;
            let s = (1.0 - z * z).sqrt();
            c + Vec3::new(s * t.cos(), z, s * t.sin()) * r * (1.2 + 2.8 * g.unit())
        })
        .collect()
}

pub fn run(a: EdgesArgs) -> Result<()> {
    let path = a.mesh.clone().context("give --mesh PATH")?;
    let progress = LogProgress::new("edges");
    let scene = edgepoint_scene::load::load_path(&path, &progress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let obj = scene.objects.iter().max_by_key(|o| o.mesh.edges.len()).context("no objects")?;
    let mesh = &obj.mesh;
    let edges: Vec<u32> = (0..mesh.edges.len() as u32)
        .filter(|&i| {
            let e = &mesh.edges[i as usize];
            !e.is_boundary() && e.normals[0] != Vec3::ZERO && e.normals[1] != Vec3::ZERO
        })
        .collect();
    let diag = (mesh.bounds.1 - mesh.bounds.0).length();
    let params = TreeParams {
        leaf_size: a.leaf,
        stay_fraction: (a.stay > 0.0).then_some(a.stay),
        split: match a.split.as_str() {
            "normals" => SplitAxes::Normals,
            "mixed" => SplitAxes::NormalsAndPositions { view_distance: a.view_distance * diag },
            other => anyhow::bail!("--split must be mixed or normals, not {other}"),
        },
    };
    progress.begin("edge tree", edges.len() as u64);
    let t = Instant::now();
    let tree = EdgeTree::build(mesh, &edges, params, &progress);
    let build_ms = t.elapsed().as_secs_f64() * 1e3;
    progress.end();
    let stats = tree.stats();
    let eyes = viewpoints(mesh, a.views, a.seed);
    let (mut brute_ms, mut tree_ms, mut counts) = (Vec::new(), Vec::new(), Vec::new());
    let (mut want, mut got) = (Vec::new(), Vec::new());
    let mut mismatches = 0;
    let (mut visited, mut testedv) = (Vec::new(), Vec::new());
    for eye in &eyes {
        want.clear();
        got.clear();
        let t = Instant::now();
        brute::mesh_silhouettes(mesh, *eye, &mut want);
        brute_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        tree.silhouettes(*eye, &mut got);
        tree_ms.push(t.elapsed().as_secs_f64() * 1e3);
        counts.push(got.len() as f64);
        {
            let e = glam::Vec3A::from(*eye);
            let (mut nodes, mut tested) = (0usize, 0usize);
            tree.traverse(
                |n| {
                    nodes += 1;
                    if n.facing(e, e).sign_is_fixed() { edgepoint_server::edges::tree::Visit::Skip } else { edgepoint_server::edges::tree::Visit::Test }
                },
                |r, _| tested += r.len() * 4,
            );
            visited.push(nodes as f64);
            testedv.push(tested as f64);
        }
        got.sort_unstable();
        if got != want {
            mismatches += 1;
        }
    }
    let (bm, tm) = (crate::stats::median(&brute_ms), crate::stats::median(&tree_ms));
    let out = json!({
        "mesh": path.display().to_string(),
        "edges": mesh.edges.len(),
        "tree_edges": edges.len(),
        "params": format!("{params:?}"),
        "build_ms": build_ms,
        "tree": { "nodes": stats.nodes, "leaves": stats.leaves, "stored_at_internal_nodes": stats.stored_at_internal_nodes, "depth": stats.depth, "bytes": stats.bytes },
        "views": eyes.len(),
        "silhouette_ms_median": tm,
        "silhouette_ms_p90": crate::stats::percentile(&tree_ms, 90.0),
        "brute_ms_median": bm,
        "speedup_median": bm / tm.max(1e-9),
        "silhouettes_median": crate::stats::median(&counts),
        "mismatches": mismatches,
        "nodes_visited_median": crate::stats::median(&visited),
        "edges_tested_median": crate::stats::median(&testedv),
        "threads": rayon::current_num_threads(),
    });
    let table = format!(
        "{}: {} edges; tree build {:.0} ms ({} nodes, depth {}, {} stored at internal nodes)\n\
         silhouettes from {} random views: tree {:.3} ms, brute force {:.2} ms (x{:.1}), median {} silhouette edges, {} mismatches\n",
        path.display(),
        edges.len(),
        build_ms,
        stats.nodes,
        stats.depth,
        stats.stored_at_internal_nodes,
        eyes.len(),
        tm,
        bm,
        bm / tm.max(1e-9),
        crate::stats::median(&counts),
        mismatches
    );
    crate::emit(a.json, &out, &table);
    Ok(())
}
