//! `edgepoint-bench edges`: the edge trees and shadow edges of paper 000 §6 measured
//! in-process.
//!
//! - `--mesh PATH`: edge-tree build time; silhouette time from random viewpoints against
//!   brute force (every edge tested, [`brute::mesh_silhouettes`]) from the same viewpoints,
//!   with the tree queried on all threads and on one; the tree's shape and how much of it
//!   a query visits, with both node bounds and with the paper's interval test alone; and
//!   the floor of any traversal over the same blocks (testing only the blocks that hold a
//!   silhouette, known in advance); and how many silhouette edges change from one frame to
//!   the next along orbits at 1, 0.25 and 0.05 degrees per frame (what any reuse of an
//!   earlier frame's answer would have to keep up with).
//! - `--scene NAME|PATH`: the whole edge finder on a scene: build times, shadow edges at
//!   load (every triple a session's shader would report: shadow rays from random surface
//!   points), then frames from the scene camera: silhouette/sharp/boundary time against
//!   brute force, shadow-store time while nothing moves, and while one object moves
//!   (default: `grid` when the scene has one) — with the per-frame counts of silhouette
//!   and shadow edges (paper Table 3). The pixel classes of Table 3 come from the EPI and
//!   are not measured here.
use anyhow::{bail, Context, Result};
use edgepoint_scene::{Mesh, Progress, Scene};
use edgepoint_server::edges::brute;
use edgepoint_server::edges::finder::{EdgeFinder, ViewVolume};
use edgepoint_server::edges::geometric::is_tree_edge;
use edgepoint_server::edges::tree::{EdgeTree, SplitAxes, TreeParams, Visit};
use edgepoint_server::edges::EdgeSegment;
use edgepoint_server::reference::LogProgress;
use edgepoint_server::session::TripleKey;
use glam::{Affine3A, Vec3, Vec3A};
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct EdgesArgs {
    /// A .ply / .obj file: its largest object's edge tree and silhouettes are measured.
    #[arg(long, conflicts_with = "scene")]
    pub mesh: Option<PathBuf>,
    /// A built-in scene name or a scene file: the whole edge finder is measured.
    #[arg(long)]
    pub scene: Option<String>,
    /// Shared data directory for built-ins made from data (grid-dragon).
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Random viewpoints for the silhouette timing (--mesh).
    #[arg(long, default_value_t = 200)]
    pub views: usize,
    /// Seed of the random viewpoints.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Tree split axes: `mixed` (normals and positions, the default) or `normals` (the
    /// paper's rule).
    #[arg(long, default_value = "mixed")]
    pub split: String,
    /// Edges per leaf.
    #[arg(long, default_value_t = 8)]
    pub leaf: usize,
    /// "Sharp edges higher": an edge stays at a node when its normals span more than this
    /// fraction of the node's normal range on some axis; 0 disables.
    #[arg(long, default_value_t = 0.5)]
    pub stay: f32,
    /// Viewing distance of the mixed split cost, in bounding-box diagonals.
    #[arg(long, default_value_t = 2.0)]
    pub view_distance: f32,
    /// Frames of the scene run (--scene): half static, half moving an object.
    #[arg(long, default_value_t = 40)]
    pub frames: usize,
    /// Object moved in the second half of the scene run (default: `grid` if the scene has
    /// one, else none).
    #[arg(long = "move", value_name = "NAME")]
    pub move_object: Option<String>,
    /// Distance the moved object travels per frame, as a fraction of the scene's size.
    #[arg(long, default_value_t = 0.01)]
    pub step: f32,
    /// Surface points per object for the triples (--scene).
    #[arg(long, default_value_t = 4000)]
    pub triple_points: usize,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Random eyes around a mesh: uniform directions, 1.2 to 4 bounding radii from the centre.
fn viewpoints(mesh: &Mesh, n: usize, seed: u64) -> Vec<Vec3> {
    edgepoint_server::edges::sample::viewpoints(mesh.bounds, n, seed, 1.2, 4.0)
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// CPU time of the whole process (all threads), in milliseconds. The machines these run on
/// are shared: wall time includes time the process waited for a core, CPU time does not
/// (with one thread it is what the wall time would be on an idle machine).
fn cpu_ms() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 * 1e-6
}

fn median(v: &[f64]) -> f64 {
    crate::stats::median(v)
}

pub fn run(a: EdgesArgs) -> Result<()> {
    match (&a.mesh, &a.scene) {
        (Some(p), _) => mesh_run(&a, p.clone()),
        (None, Some(s)) => scene_run(&a, s.clone()),
        (None, None) => bail!("give --mesh PATH or --scene NAME"),
    }
}

fn tree_params(a: &EdgesArgs, mesh: &Mesh) -> Result<TreeParams> {
    let diag = (mesh.bounds.1 - mesh.bounds.0).length();
    Ok(TreeParams {
        leaf_size: a.leaf.max(1),
        stay_fraction: (a.stay > 0.0).then_some(a.stay),
        split: match a.split.as_str() {
            "normals" => SplitAxes::Normals,
            "mixed" => SplitAxes::NormalsAndPositions { view_distance: a.view_distance * diag },
            other => bail!("--split must be mixed or normals, not {other}"),
        },
    })
}

fn mesh_run(a: &EdgesArgs, path: PathBuf) -> Result<()> {
    let progress = LogProgress::new("edges");
    let scene = edgepoint_scene::load::load_path(&path, &progress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let obj = scene.objects.iter().max_by_key(|o| o.mesh.edges.len()).context("no objects")?;
    let mesh = &obj.mesh;
    let edges: Vec<u32> = (0..mesh.edges.len() as u32).filter(|&i| is_tree_edge(&mesh.edges[i as usize])).collect();
    let params = tree_params(a, mesh)?;
    // Build: best of three (the machine is shared; the first build also warms the pages).
    let mut build = Vec::new();
    let mut tree = EdgeTree::default();
    for k in 0..3 {
        if k == 0 {
            progress.begin("edge tree", edges.len() as u64);
        }
        let t = Instant::now();
        tree = EdgeTree::build(mesh, &edges, params, if k == 0 { &progress } else { &edgepoint_scene::NoProgress });
        build.push(ms(t));
        if k == 0 {
            progress.end();
        }
    }
    let build_ms = build.iter().copied().fold(f64::INFINITY, f64::min);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let single_build_ms = one.install(|| {
        let t = Instant::now();
        let _ = EdgeTree::build(mesh, &edges, params, &edgepoint_scene::NoProgress);
        ms(t)
    });
    let stats = tree.stats();

    let eyes = viewpoints(mesh, a.views, a.seed);
    let (mut brute_ms, mut tree_ms, mut tree1_ms, mut counts, mut visited, mut tested) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut visited_interval, mut tested_interval) = (Vec::new(), Vec::new());
    let (mut want, mut got) = (Vec::with_capacity(1 << 16), Vec::with_capacity(1 << 16));
    let mut mismatches = 0;
    for eye in &eyes {
        want.clear();
        let t = Instant::now();
        brute::mesh_silhouettes(mesh, *eye, &mut want);
        brute_ms.push(ms(t));
        // One thread first, then all threads: each query runs once per view, right after
        // brute force, so neither finds the other's lines for this eye in its core's caches.
        got.clear();
        one.install(|| {
            let t = Instant::now();
            tree.silhouettes(*eye, &mut got);
            tree1_ms.push(ms(t));
        });
        got.clear();
        let t = Instant::now();
        tree.silhouettes(*eye, &mut got);
        tree_ms.push(ms(t));
        counts.push(got.len() as f64);
        got.sort_unstable();
        if got != want {
            mismatches += 1;
        }
        // Nodes visited and edge lanes tested with both node bounds, and with the paper's
        // interval test alone (what the spread bound saves).
        let e = Vec3A::from(*eye);
        let count = |tight: bool| {
            let (mut nodes, mut lanes) = (0usize, 0usize);
            tree.traverse(
                |n| {
                    nodes += 1;
                    let f = if tight { n.facing_tight(e, e) } else { n.facing(e, e) };
                    if f.sign_is_fixed() {
                        Visit::Skip
                    } else {
                        Visit::Test
                    }
                },
                |b, _| lanes += b.len() * 4,
            );
            (nodes as f64, lanes as f64)
        };
        let (n, l) = count(true);
        visited.push(n);
        tested.push(l);
        let (n, l) = count(false);
        visited_interval.push(n);
        tested_interval.push(l);
    }
    // The floor of any traversal over these blocks: knowing in advance which blocks hold a
    // silhouette, read and test only those (in memory order), under the same conditions as
    // the tree (right after brute force, one thread).
    let (mut floor_ms, mut floor_blocks) = (Vec::new(), Vec::new());
    for eye in &eyes {
        let hit: Vec<usize> = (0..tree.blocks.len())
            .filter(|&i| {
                let (s0, s1) = tree.blocks[i].sides(*eye);
                s0 ^ s1 != 0
            })
            .collect();
        want.clear();
        brute::mesh_silhouettes(mesh, *eye, &mut want);
        got.clear();
        let t = Instant::now();
        for &i in &hit {
            tree.blocks[i].select(*eye, |s0, s1| s0 ^ s1, |e| got.push(e));
        }
        floor_ms.push(ms(t));
        floor_blocks.push(hit.len() as f64);
        if got.len() != want.len() {
            bail!("the floor pass found {} silhouettes, brute force {}", got.len(), want.len());
        }
    }
    let fl = median(&floor_ms);
    let churn: Vec<(f32, f64, f64)> = [1.0f32, 0.25, 0.05].iter().map(|&d| orbit_churn(mesh, &tree, d)).collect();
    let (bm, tm, t1) = (median(&brute_ms), median(&tree_ms), median(&tree1_ms));
    let out = json!({
        "mesh": path.display().to_string(),
        "edges": mesh.edges.len(),
        "tree_edges": edges.len(),
        "params": format!("{params:?}"),
        "build_ms": build_ms,
        "build_ms_runs": build,
        "build_ms_one_thread": single_build_ms,
        "tree": { "nodes": stats.nodes, "leaves": stats.leaves, "stored_at_internal_nodes": stats.stored_at_internal_nodes, "depth": stats.depth, "bytes": stats.bytes },
        "views": eyes.len(),
        "silhouette_ms_median": tm,
        "silhouette_ms_p90": crate::stats::percentile(&tree_ms, 90.0),
        "silhouette_ms_one_thread_median": t1,
        "brute_ms_median": bm,
        "speedup_median": bm / tm.max(1e-9),
        "speedup_one_thread_median": bm / t1.max(1e-9),
        "silhouettes_median": median(&counts),
        "nodes_visited_median": median(&visited),
        "edge_lanes_tested_median": median(&tested),
        "nodes_visited_interval_test_only_median": median(&visited_interval),
        "edge_lanes_tested_interval_test_only_median": median(&tested_interval),
        "mismatches": mismatches,
        "floor_ms_median": fl,
        "floor_blocks_median": median(&floor_blocks),
        "floor_speedup_median": bm / fl.max(1e-9),
        "threads": rayon::current_num_threads(),
        "orbit_churn": churn.iter().map(|&(d, s, c)| json!({ "degrees_per_frame": d, "silhouettes_median": s, "changed_per_frame_median": c })).collect::<Vec<_>>(),
    });
    let table = format!(
        "{}: {} edges; tree build {:.0} ms ({:.0} ms on one thread; {} nodes, depth {}, {} edges stored at internal nodes)\n\
         silhouettes from {} random views (median {} edges): tree {:.3} ms ({:.3} ms on one thread), brute force {:.2} ms: \
         x{:.1} (x{:.1} on one thread); {} mismatches\n\
         floor (only the {:.0} blocks holding a silhouette, known in advance): {:.3} ms, x{:.1}\n",
        path.display(),
        edges.len(),
        build_ms,
        single_build_ms,
        stats.nodes,
        stats.depth,
        stats.stored_at_internal_nodes,
        eyes.len(),
        median(&counts),
        tm,
        t1,
        bm,
        bm / tm.max(1e-9),
        bm / t1.max(1e-9),
        mismatches,
        median(&floor_blocks),
        fl,
        bm / fl.max(1e-9)
    ) + &churn
        .iter()
        .map(|(d, s, c)| format!("orbit at {d} deg per frame: {s:.0} silhouette edges, {c:.0} of them change per frame\n"))
        .collect::<String>();
    crate::emit(a.json, &out, &table);
    if mismatches > 0 {
        bail!("{mismatches} views where the tree and brute force disagree");
    }
    Ok(())
}

/// How much of the silhouette changes from frame to frame along an orbit at `degrees` per
/// frame (2.5 bounding radii from the centre, the elevation swinging between 5 and 35
/// degrees once every three turns; 60 frames): the median silhouette size and the median
/// number of edges entering or leaving it per frame. What any reuse of an earlier frame's
/// answer would have to keep up with.
fn orbit_churn(mesh: &Mesh, tree: &EdgeTree, degrees: f32) -> (f32, f64, f64) {
    let (lo, hi) = mesh.bounds;
    let (c, r) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
    let (mut sizes, mut changed) = (Vec::new(), Vec::new());
    let mut prev: Vec<u32> = Vec::new();
    for k in 0..60 {
        let az = (k as f32 * degrees).to_radians();
        let el = (20.0 + 15.0 * (az / 3.0).sin()).to_radians();
        let eye = c + Vec3::new(el.cos() * az.cos(), el.sin(), el.cos() * az.sin()) * 2.5 * r;
        let mut cur = Vec::new();
        tree.silhouettes(eye, &mut cur);
        cur.sort_unstable();
        if k > 0 {
            // Size of the symmetric difference of two sorted lists.
            let (mut i, mut j, mut same) = (0, 0, 0);
            while i < prev.len() && j < cur.len() {
                match prev[i].cmp(&cur[j]) {
                    std::cmp::Ordering::Equal => {
                        same += 1;
                        i += 1;
                        j += 1;
                    }
                    std::cmp::Ordering::Less => i += 1,
                    std::cmp::Ordering::Greater => j += 1,
                }
            }
            changed.push((prev.len() + cur.len() - 2 * same) as f64);
        }
        sizes.push(cur.len() as f64);
        prev = cur;
    }
    (degrees, median(&sizes), median(&changed))
}

fn load_scene(a: &EdgesArgs, what: &str, progress: &dyn Progress) -> Result<Scene> {
    let p = std::path::Path::new(what);
    if p.extension().is_some() && p.is_file() {
        edgepoint_scene::load::load_path(p, progress).map_err(|e| anyhow::anyhow!("{e}"))
    } else {
        edgepoint_scene::data::load_builtin(what, a.data_dir.as_deref(), progress).map_err(anyhow::Error::msg)
    }
}

fn scene_run(a: &EdgesArgs, what: String) -> Result<()> {
    let progress = LogProgress::new("edges");
    let scene = load_scene(a, &what, &progress)?;
    scene.validate().map_err(anyhow::Error::msg)?;
    let n = scene.objects.len();
    let mut t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();

    let start = Instant::now();
    let mut finder = EdgeFinder::new(&scene, &progress);
    let finder_build_ms = ms(start);

    // The triples a session's shader would report.
    let start = Instant::now();
    let loaded = edgepoint_worker::LoadedScene::build(scene.clone(), what.clone(), &edgepoint_scene::NoProgress);
    let triples: Vec<TripleKey> = edgepoint_worker::sample_triples(&loaded, &t, a.triple_points, 2, 7)
        .into_iter()
        .map(|(light, blocker, receiver)| TripleKey { light, blocker, receiver })
        .collect();
    let triples_ms = ms(start);

    let moving = match &a.move_object {
        Some(name) => Some(scene.object_id(name).with_context(|| format!("--move: no object called {name}"))?),
        None => scene.object_id("grid"),
    };
    let (lo, hi) = scene.bounds();
    let step = (hi - lo).length() * a.step;
    let aspect = 1.0;
    let view = ViewVolume::new(&scene.camera, aspect);
    let eye = scene.camera.eye;

    let mut out: Vec<EdgeSegment> = Vec::new();
    let c0 = cpu_ms();
    let load = finder.frame(&t, eye, Some(&view), triples.iter().copied(), 85.0, &mut out);
    let load_cpu = cpu_ms() - c0;

    let frames = a.frames.max(2);
    let half = if moving.is_some() { frames / 2 } else { frames };
    let mut rows = Vec::new();
    let (mut find, mut find_cpu, mut brute_find) = (Vec::new(), Vec::new(), Vec::new());
    let (mut shadow_static, mut shadow_move, mut shadow_move_cpu, mut sil, mut shadow_edges) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut cams = Vec::new();
    let mut last_view = None;
    for f in 0..frames {
        // The camera orbits slowly about the scene's centre so silhouettes change.
        let cam = scene.camera.orbit((lo + hi) * 0.5, 0.01 * f as f32);
        let view = ViewVolume::new(&cam, aspect);
        let moved = f >= half;
        if moved {
            if let Some(m) = moving {
                // Back and forth along x, 8 steps each way.
                let dir = if ((f - half) / 8) % 2 == 0 { 1.0 } else { -1.0 };
                t[m as usize] = Affine3A::from_translation(Vec3::new(step * dir, 0.0, 0.0)) * t[m as usize];
            }
        }
        out.clear();
        finder.set_transforms(&t);
        let c = cpu_ms();
        let (find_ms, in_view) = finder.geometric_edges(cam.eye, Some(&view), 85.0, &mut out);
        let fc = cpu_ms() - c;
        let c = cpu_ms();
        let (sh, shadow_ms, output_ms) = finder.shadow_edges(triples.iter().copied(), Some(&view), &mut out);
        let sc = cpu_ms() - c;
        let counts = edgepoint_server::edges::EdgeCounts::of(&out);
        find.push(find_ms);
        find_cpu.push(fc);
        cams.push(cam.eye);
        last_view = Some((cam.eye, view));
        if moved {
            shadow_move.push(shadow_ms);
            shadow_move_cpu.push(sc);
        } else {
            shadow_static.push(shadow_ms);
        }
        sil.push(counts.silhouette as f64);
        shadow_edges.push(counts.shadow as f64);
        rows.push(json!({
            "frame": f,
            "moved": moved && moving.is_some(),
            "find_ms": find_ms,
            "find_cpu_ms": fc,
            "shadow_ms": shadow_ms,
            "shadow_cpu_ms": sc,
            "output_ms": output_ms,
            "objects_in_view": in_view,
            "silhouette": counts.silhouette,
            "sharp": counts.sharp,
            "boundary": counts.boundary,
            "shadow": counts.shadow,
            "events_clipped": sh.events_clipped,
            "events_ms": sh.events_ms,
            "search_ms": sh.search_ms,
            "clip_ms": sh.clip_ms,
            "umbra_ms": sh.umbra_ms,
            "intersections": sh.intersections,
            "nodes_visited": sh.nodes_visited,
            "faces_cut": sh.faces_cut,
            "pairs_recomputed": sh.pairs_recomputed,
        }));
    }
    // The move's shadow update alone, back to back (its working set stays in the caches; in
    // the frame loop the edge queries and the rest of the frame evict it in between).
    let mut shadow_move_warm = Vec::new();
    if let Some(m) = moving {
        for f in 0..16 {
            let dir = if (f / 8) % 2 == 0 { 1.0 } else { -1.0 };
            t[m as usize] = Affine3A::from_translation(Vec3::new(step * dir, 0.0, 0.0)) * t[m as usize];
            finder.set_transforms(&t);
            out.clear();
            let (_, shadow_ms, _) = finder.shadow_edges(triples.iter().copied(), None, &mut out);
            shadow_move_warm.push(shadow_ms);
        }
    }

    // A still camera over still objects (most frames of a converging session): each
    // object's edges of the previous frame are handed out again.
    let mut find_still = Vec::new();
    if let Some((eye, view)) = last_view {
        finder.set_transforms(&t);
        for _ in 0..10 {
            out.clear();
            let (find_ms, _) = finder.geometric_edges(eye, Some(&view), 85.0, &mut out);
            find_still.push(find_ms);
        }
    }

    // Brute force from the same eyes, afterwards (it streams every edge of the scene through
    // the caches, which would slow the finder's frames down if interleaved with them).
    let mut brute_out = Vec::new();
    for eye in &cams {
        brute_out.clear();
        let b = Instant::now();
        brute::scene_edges(&scene, &t, *eye, 85.0, &mut brute_out);
        brute_find.push(ms(b));
    }
    let out_json = json!({
        "scene": what,
        "objects": n,
        "triangles": scene.triangle_count(),
        "lights": scene.lights.len(),
        "build": {
            "total_ms": finder_build_ms,
            "edge_trees_ms": finder.build.edge_trees_ms,
            "face_hierarchies_ms": finder.build.face_bvhs_ms,
            "vertex_rings_ms": finder.build.rings_ms,
            "edges": finder.build.edges,
            "faces": finder.build.faces,
        },
        "triples": triples.len(),
        "triples_sampling_ms": triples_ms,
        "load_frame": {
            "shadow_ms": load.shadow_ms,
            "cpu_ms": load_cpu,
            "events_ms": load.shadow.events_ms,
            "search_ms": load.shadow.search_ms,
            "clip_ms": load.shadow.clip_ms,
            "umbra_ms": load.shadow.umbra_ms,
            "pairs": load.shadow.pairs,
            "events": load.shadow.events_found,
            "intersections": load.shadow.intersections,
            "nodes_visited": load.shadow.nodes_visited,
            "faces_cut": load.shadow.faces_cut,
            "shadow_edges_stored": load.shadow.segments,
            "silhouette": load.counts.silhouette,
            "shadow": load.counts.shadow,
        },
        "moved_object": moving.map(|m| scene.objects[m as usize].name.clone()),
        "step": step,
        "find_ms_median": median(&find),
        "find_cpu_ms_median": median(&find_cpu),
        "brute_find_ms_median": median(&brute_find),
        "find_speedup_median": median(&brute_find) / median(&find).max(1e-9),
        "find_ms_still_camera_median": median(&find_still),
        "shadow_ms_static_median": median(&shadow_static),
        "shadow_ms_moving_median": median(&shadow_move),
        "shadow_ms_moving_max": shadow_move.iter().copied().fold(0.0, f64::max),
        "shadow_cpu_ms_moving_median": median(&shadow_move_cpu),
        "shadow_ms_moving_back_to_back_median": median(&shadow_move_warm),
        "table3": {
            "silhouette_edges_median": median(&sil),
            "shadow_edges_median": median(&shadow_edges),
            "pixel_classes": "measured by the EPI (not part of the edge finder)",
        },
        "frames": rows,
        "threads": rayon::current_num_threads(),
    });
    let table = format!(
        "{what}: {} objects, {} triangles, {} lights; finder build {:.0} ms (edge trees {:.0}, face hierarchies {:.0})\n\
         {} triples; at load: {} pairs, {} events, shadow edges in {:.1} ms ({} segments)\n\
         per frame (median of {frames}): edges {:.2} ms vs brute force {:.2} ms (x{:.1}); {:.3} ms with a still camera; \
         shadow store {:.3} ms static, {:.2} ms (max {:.2}) while moving {}\n\
         Table 3: {} silhouette edges, {} shadow edges per frame (pixel classes: from the EPI)\n",
        n,
        scene.triangle_count(),
        scene.lights.len(),
        finder_build_ms,
        finder.build.edge_trees_ms,
        finder.build.face_bvhs_ms,
        triples.len(),
        load.shadow.pairs,
        load.shadow.events_found,
        load.shadow_ms,
        load.shadow.segments,
        median(&find),
        median(&brute_find),
        median(&brute_find) / median(&find).max(1e-9),
        median(&find_still),
        median(&shadow_static),
        median(&shadow_move),
        shadow_move.iter().copied().fold(0.0, f64::max),
        moving.map(|m| scene.objects[m as usize].name.as_str()).unwrap_or("nothing"),
        median(&sil),
        median(&shadow_edges),
    );
    crate::emit(a.json, &out_json, &table);
    Ok(())
}
