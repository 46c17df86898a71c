//! `edgepoint-bench dmesh`: the discontinuity mesh of a scene's area lights (paper 002,
//! issue 15 items 1 and 6): the time of a full computation (uniform grid, then every light
//! on every receiver triangle: segments, arrangement, face backprojections), the counts of
//! segments, faces and receivers, and the memory of the grid and the mesh; then `--moves`
//! random rigid moves of one object, each applied incrementally (§3–4) and recomputed in
//! full: the time of each, their ratio (`incremental_speedup`) and the receivers where the
//! two differ (`mismatches`, which must be 0).
use anyhow::Result;
use edgepoint_server::dmesh::geometry::Geometry;
use edgepoint_server::dmesh::grid::Grid;
use edgepoint_server::dmesh::update::mismatches;
use edgepoint_server::dmesh::{area_lights, point_lights_as_squares, tolerance, DiscontinuityMesh, GRID_TRIANGLES_PER_VOXEL};
use edgepoint_server::rng::Rng;
use edgepoint_server::reference::LogProgress;
use serde_json::json;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct DmeshArgs {
    /// A built-in scene name (cornell, chains, rooms, grid-dragon, …) or a scene file.
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Shared data directory for built-ins made from data (grid-dragon).
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Full computations to time (the median is reported).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
    /// Side of the square area lights standing in for point and spot lights, as a fraction of
    /// the scene's diagonal (scenes lit only by points, as chains and grid-dragon, have no
    /// mesh otherwise); 0 keeps only the scene's own area lights.
    #[arg(long, default_value_t = 0.05)]
    pub point_light_size: f64,
    /// Random moves of `--object` to time incrementally against a full recomputation.
    #[arg(long, default_value_t = 5)]
    pub moves: usize,
    /// The object to move (default: the smallest object of at least 8 triangles).
    #[arg(long)]
    pub object: Option<String>,
    /// Largest translation per axis of a move, as a fraction of the object's diagonal
    /// (rotations are up to 0.2 rad about a random axis through its centre).
    #[arg(long, default_value_t = 0.1)]
    pub step: f64,
    /// Seed of the random moves.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Mesh every N-th triangle only as a receiver (all still block), in the full
    /// computations and the updates alike, for scenes too large to mesh whole in a short run
    /// (grid-dragon); 1 meshes every triangle.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub receiver_stride: u32,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// The object `name`, or with none the smallest object (by its box's diagonal) of 8
/// triangles or more: the object the benchmarks move.
pub fn object_to_move(scene: &edgepoint_scene::Scene, name: Option<&str>) -> Result<usize> {
    match name {
        Some(name) => scene.object_id(name).map(|o| o as usize).ok_or_else(|| anyhow::anyhow!("{} has no object {name}", scene.name)),
        None => (0..scene.objects.len())
            .filter(|i| scene.objects[*i].mesh.triangles.len() >= 8)
            .min_by(|i, j| {
                let d = |k: usize| {
                    let (lo, hi) = scene.object_bounds(k);
                    (hi - lo).length()
                };
                d(*i).total_cmp(&d(*j))
            })
            .ok_or_else(|| anyhow::anyhow!("{} has no object of 8 triangles or more", scene.name)),
    }
}

/// Receivers listed per move: the slowest ones, and the objects whose receivers took most.
const WHERE_LISTED: usize = 8;

/// Where a move's update went, from its receivers' costs: the [`WHERE_LISTED`] slowest
/// receivers (light, triangle, the triangle's object, CPU time, faces redone, traces and
/// EEE surfaces made anew), the objects whose receivers took most (receivers, CPU time,
/// faces redone), and the receivers' CPU time in all.
fn where_it_went(scene: &edgepoint_scene::Scene, g: &Geometry, costs: &mut [edgepoint_server::dmesh::update::ReceiverCost]) -> (serde_json::Value, serde_json::Value, f64) {
    let name = |t: u32| scene.objects[g.object[t as usize] as usize].name.clone();
    costs.sort_by(|a, b| b.cpu_ns.cmp(&a.cpu_ns));
    let slowest: Vec<serde_json::Value> = costs
        .iter()
        .take(WHERE_LISTED)
        .map(|c| {
            json!({
                "light": c.light, "triangle": c.tri, "object": name(c.tri), "cpu_ms": c.cpu_ns as f64 / 1e6,
                "faces_recomputed": c.stats.faces_recomputed, "faces_kept": c.stats.faces_kept, "traces_recast": c.stats.traces_recast, "eee_recast": c.stats.eee_recast,
                "parts_cpu_ms": cpu_parts(&c.stats),
            })
        })
        .collect();
    let mut by: std::collections::BTreeMap<String, (usize, u64, usize)> = std::collections::BTreeMap::new();
    for c in costs.iter() {
        let e = by.entry(name(c.tri)).or_default();
        *e = (e.0 + 1, e.1 + c.cpu_ns, e.2 + c.stats.faces_recomputed);
    }
    let mut by: Vec<(String, (usize, u64, usize))> = by.into_iter().collect();
    by.sort_by(|a, b| b.1 .1.cmp(&a.1 .1));
    let by_object: Vec<serde_json::Value> = by.iter().take(WHERE_LISTED).map(|(n, (r, t, f))| json!({"object": n, "receivers": r, "cpu_ms": *t as f64 / 1e6, "faces_recomputed": f})).collect();
    let total = costs.iter().map(|c| c.cpu_ns).sum::<u64>() as f64 / 1e6;
    (json!(slowest), json!(by_object), total)
}

/// The CPU time of an update's parts (a move's, summed over threads, or one receiver's).
fn cpu_parts(s: &edgepoint_server::dmesh::update::UpdateStats) -> serde_json::Value {
    let ms = |ns: u64| ns as f64 / 1e6;
    json!({
        "own_receivers": ms(s.own_receivers_ns), "scan": ms(s.scan_ns),
        "reintersect": ms(s.reintersect_ns), "recast": ms(s.recast_ns), "eee": ms(s.eee_ns), "eee_dynamic": ms(s.eee_dynamic_ns),
        "arrangement": ms(s.arrangement_ns), "faces": ms(s.faces_ns),
    })
}

pub fn run(a: DmeshArgs) -> Result<()> {
    let progress = LogProgress::new("dmesh");
    let p = std::path::Path::new(&a.scene);
    let scene = if p.extension().is_some() && p.is_file() {
        edgepoint_scene::load::load_path(p, &progress).map_err(|e| anyhow::anyhow!("{e}"))?
    } else {
        edgepoint_scene::data::load_builtin(&a.scene, a.data_dir.as_deref(), &progress).map_err(anyhow::Error::msg)?
    };
    scene.validate().map_err(anyhow::Error::msg)?;
    let mut lights = area_lights(&scene);
    let (lo, hi) = scene.bounds();
    let diagonal = (hi - lo).length() as f64;
    let from_points = a.point_light_size > 0.0;
    if from_points {
        lights.extend(point_lights_as_squares(&scene, a.point_light_size * diagonal));
    }
    if lights.is_empty() {
        anyhow::bail!("{} has no area light (and --point-light-size 0 adds none)", a.scene);
    }
    let g = Geometry::from_scene(&scene);
    let only = (a.receiver_stride > 1).then(|| (0..g.tris.len() as u32).map(|t| t.is_multiple_of(a.receiver_stride)).collect::<Vec<bool>>());
    let (mut times, mut grid_ms) = (Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..a.repeat.max(1) {
        let t = Instant::now();
        let grid = Grid::build(&g, GRID_TRIANGLES_PER_VOXEL);
        grid_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let mesh = DiscontinuityMesh::compute_for(&g, &grid, &lights, tolerance(&g), only.clone());
        times.push(t.elapsed().as_secs_f64() * 1e3);
        last = Some((grid, mesh));
    }
    let (mut grid, mut mesh) = last.expect("one run");
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (full_ms, grid_ms) = (median(&mut times), median(&mut grid_ms));
    let receivers = mesh.receivers().count();
    let with_segments = mesh.receivers().filter(|m| !m.segments.is_empty()).count();
    let (segments, faces) = (mesh.segment_count(), mesh.face_count());
    let eee_surfaces: usize = mesh.receivers().map(|m| m.eee.len()).sum();
    let traces: usize = mesh.receivers().map(|m| m.traces.len()).sum();
    let eee_segments: usize = mesh.receivers().map(|m| m.segments.iter().filter(|s| matches!(s.generator, edgepoint_server::dmesh::segments::Generator::Eee { .. })).count()).sum();
    let (mesh_bytes, grid_bytes, geometry_bytes) = (mesh.bytes(), grid.bytes(), g.bytes());
    let threads = rayon::current_num_threads();
    let object = object_to_move(&scene, a.object.as_deref())? as u32;
    let intersection_bytes: usize = mesh.receivers().map(|m| m.traces.iter().map(|t| t.bytes()).sum::<usize>() + m.eee.iter().map(|t| t.bytes()).sum::<usize>()).sum();
    let mut rng = Rng::new(a.seed);
    let mut g = g;
    let (mut incr_ms, mut full_after_ms, mut bad, mut moves) = (Vec::new(), Vec::new(), 0usize, Vec::new());
    let mut where_lines = Vec::new();
    for _ in 0..a.moves {
        let (olo, ohi) = g.object_bounds(object);
        let step = a.step * (ohi - olo).length();
        let axis = glam::DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5).normalize_or(glam::DVec3::Y);
        let rot = glam::DQuat::from_axis_angle(axis, (rng.f64() - 0.5) * 0.4);
        let d = glam::DVec3::new(rng.f64() - 0.5, rng.f64() - 0.5, rng.f64() - 0.5) * 2.0 * step;
        let new = g.moved_rigidly(object, rot, d);
        let t = Instant::now();
        let mut costs = Vec::new();
        let stats = mesh.move_object_profiled(&g, &new, &mut grid, object, &mut costs);
        let ti = t.elapsed().as_secs_f64() * 1e3;
        g = new;
        let t = Instant::now();
        // With the mesh's tolerance (fixed when it was made; the scene's bounds may have grown).
        let full = DiscontinuityMesh::compute_for(&g, &Grid::build(&g, GRID_TRIANGLES_PER_VOXEL), &lights, mesh.tol, mesh.only.clone());
        let tf = t.elapsed().as_secs_f64() * 1e3;
        let m = mismatches(&mesh, &full);
        bad += m;
        incr_ms.push(ti);
        full_after_ms.push(tf);
        let (slowest, by_object, receivers_cpu_ms) = where_it_went(&scene, &g, &mut costs);
        let objects: Vec<String> = by_object.as_array().into_iter().flatten().take(3).map(|o| format!("{} {:.1} ms ({} receivers)", o["object"].as_str().unwrap_or("?"), o["cpu_ms"].as_f64().unwrap_or(0.0), o["receivers"])).collect();
        where_lines.push(format!("  move {}: receivers' CPU {receivers_cpu_ms:.1} ms, most on {}\n", moves.len() + 1, objects.join(", ")));
        moves.push(json!({
            "receivers_cpu_ms": receivers_cpu_ms, "slowest_receivers": slowest, "by_receiver_object": by_object,
            "incremental_ms": ti, "full_ms": tf, "speedup": tf / ti, "mismatches": m,
            "receivers_in_motion_volume": stats.receivers_in_motion_volume, "receivers_updated": stats.receivers_updated,
            "receivers_recomputed": stats.receivers_recomputed, "receivers_rebuilt": stats.receivers_rebuilt, "receivers_kept_in_umbra": stats.receivers_kept_in_umbra, "arrangements_kept": stats.arrangements_kept, "traces_reintersected": stats.traces_reintersected,
            "traces_untouched": stats.traces_untouched,
            "traces_recast": stats.traces_recast, "eee_reintersected": stats.eee_reintersected, "eee_untouched": stats.eee_untouched, "eee_recast": stats.eee_recast, "faces_kept": stats.faces_kept, "faces_recomputed": stats.faces_recomputed,
            // CPU time of the update's parts, summed over threads.
            "cpu_ms": cpu_parts(&stats),
        }));
    }
    let (si, sf) = (incr_ms.iter().sum::<f64>(), full_after_ms.iter().sum::<f64>());
    let speedup = if a.moves > 0 { Some(sf / si) } else { None };
    let table = format!(
        "{}: {} triangles, {} area lights, {threads} threads\nfull computation {full_ms:.1} ms (grid {grid_ms:.1} ms)\nreceivers lit {receivers}, with segments {with_segments}\ntraces {traces}, segments {segments} (EEE polyline chords {eee_segments} from {eee_surfaces} EEE surface parts), faces {faces}\nmemory: mesh {:.2} MB (intersection lists {:.2} MB), grid {:.2} MB, geometry {:.2} MB\nmoved {} ({} moves): incremental {:.2} ms, full {:.1} ms per move, speedup {:.1}×, mismatches {bad}\n",
        a.scene,
        g.tris.len(),
        lights.len(),
        mesh_bytes as f64 / 1e6,
        intersection_bytes as f64 / 1e6,
        grid_bytes as f64 / 1e6,
        geometry_bytes as f64 / 1e6,
        scene.objects[object as usize].name,
        a.moves,
        si / a.moves.max(1) as f64,
        sf / a.moves.max(1) as f64,
        speedup.unwrap_or(f64::NAN)
    ) + &where_lines.concat();
    let mut out = json!({
        "scene": a.scene,
        "triangles": g.tris.len(),
        "area_lights": lights.len(),
        "threads": threads,
        "full_ms": full_ms,
        "grid_ms": grid_ms,
        "receivers": receivers,
        "receivers_with_segments": with_segments,
        "traces": traces,
        "segments": segments,
        "eee_surfaces": eee_surfaces,
        "eee_segments": eee_segments,
        "faces": faces,
        "mesh_bytes": mesh_bytes,
        "grid_bytes": grid_bytes,
        "geometry_bytes": geometry_bytes,
        "intersection_list_bytes": intersection_bytes,
        "point_lights_as_squares": from_points,
        "receiver_stride": a.receiver_stride,
        "moved_object": scene.objects[object as usize].name,
        "moved_object_triangles": scene.objects[object as usize].mesh.triangles.len(),
        "moves": moves,
    });
    if let Some(s) = speedup {
        out["incremental_speedup"] = json!(s);
        out["mismatches"] = json!(bad);
    }
    crate::emit(a.json, &out, &table);
    Ok(())
}
