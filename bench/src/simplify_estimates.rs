//! `edgepoint-bench simplify --estimates`: paper 003's estimates alone, in this process (no
//! session, no workers). The scene's shadow edges from the triples a shader would report
//! (surface points ray-cast to the lights, as `edges --scene` samples them), every edge
//! estimated with the culls of lights that cannot reach its band, closed meshes' exit faces
//! and the bounds; then `--compare` edges spread over the set estimated again with every
//! face and nothing skipped, with exit faces only, and with the culls too, all timed on the
//! pool (CPU time of the process), with the largest differences from the first; and the
//! same with the other lights bounded where not comparable (a different estimate: its largest
//! relative difference, and how many decisions at the tolerance it changes).
//!
//! With `--moves N`, an object then slides N times along X, and after each move the
//! estimates kept across it ([`SceneLights::still_holds`]) are measured against all made
//! afresh there — how many kept, how many made again, the times, and how many differ (must
//! be 0) — for the finder's shadow edges and for the discontinuity mesh's
//! ([`MeshShadows`]).
use crate::clock::process_cpu_ms;
use anyhow::Result;
use edgepoint_scene::Scene;
use edgepoint_server::edges::finder::{EdgeFinder, ViewVolume};
use edgepoint_server::edges::simplify::{estimate, jobs, Culls, EdgeErrors, Estimate, Rules, SceneLights};
use edgepoint_server::session::mesh_shadows::MeshShadows;
use edgepoint_server::edges::EdgeSegment;
use edgepoint_server::reference::LogProgress;
use edgepoint_server::session::TripleKey;
use glam::Affine3A;
use serde_json::{json, Value};
use std::time::Instant;

fn culls_json(c: &Culls) -> Value {
    json!({"pairs": c.pairs, "facing": c.facing, "behind": c.behind, "blocked": c.blocked})
}

/// Runs the estimates on `scene` (`what` names it for the workers' scene cache).
pub fn run(scene: Scene, what: &str, triple_points: usize, compare: usize, tolerance: f64, moves: &Moves) -> Result<(Value, String)> {
    let progress = LogProgress::new("simplify");
    let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    let mut finder = EdgeFinder::new(&scene, &progress);
    let loaded = edgepoint_worker::LoadedScene::build(scene.clone(), what.to_string(), &edgepoint_scene::NoProgress);
    let triples: Vec<TripleKey> = edgepoint_worker::sample_triples(&loaded, &t, triple_points, 2, 7)
        .into_iter()
        .map(|(light, blocker, receiver)| TripleKey { light, blocker, receiver })
        .collect();
    let view = ViewVolume::new(&scene.camera, 1.0);
    let mut out: Vec<EdgeSegment> = Vec::new();
    finder.frame(&t, scene.camera.eye, Some(&view), triples.iter().copied(), 85.0, &mut out);
    let (mut lights, transforms) = finder.scene_lights();
    let all = jobs(finder.store(), transforms);
    let rules = Rules::new();

    let mut timed = |js: &[_], how: Estimate, exit_faces: bool| {
        lights.exit_faces = exit_faces;
        let (w, c) = (Instant::now(), process_cpu_ms());
        let (e, culls) = estimate(&lights, js, &rules, how);
        (e, culls, w.elapsed().as_secs_f64() * 1e3, process_cpu_ms() - c)
    };
    let (errs, culls, all_ms, all_cpu) = timed(&all, Estimate::FAST, true);
    let kept = errs.iter().filter(|e| **e >= tolerance).count();

    // Every k-th edge, so the subset spans every light and receiver: fast, culls only,
    // neither.
    let step = (all.len() / compare.max(1)).max(1);
    let sub: Vec<_> = all.iter().step_by(step).take(compare).copied().collect();
    let (fast, sub_culls, fast_ms, fast_cpu) = timed(&sub, Estimate::FAST, true);
    let (with, _, with_ms, with_cpu) = timed(&sub, Estimate { cull: true, bounded: false }, true);
    let (exits, _, _, exits_cpu) = timed(&sub, Estimate::FULL, true);
    let (without, _, without_ms, without_cpu) = timed(&sub, Estimate::FULL, false);
    let differ = |x: &[f64]| {
        x.iter().zip(&without).map(|(a, b)| if a == b { 0.0 } else { (a - b).abs() / b.abs().max(1e-300) }).fold(0.0f64, f64::max)
    };
    let worst = differ(&with);
    let worst_exits = differ(&exits);
    let worst_bounded = differ(&fast);
    let flips = fast.iter().zip(&without).filter(|(a, b)| (**a >= tolerance) != (**b >= tolerance)).count();
    let (moved, moved_table) = if moves.count > 0 { run_moves(&scene, &triples, moves)? } else { (Value::Null, String::new()) };
    let v = json!({
        "moves": moved,
        "scene": scene.name,
        "triples": triples.len(),
        "shadow_edges": all.len(),
        "tolerance": tolerance,
        "kept_at_tolerance": kept,
        "estimate_ms": all_ms,
        "estimate_cpu_ms": all_cpu,
        "culls": culls_json(&culls),
        "compared_edges": sub.len(),
        "compared_culls": culls_json(&sub_culls),
        "fast_ms": fast_ms,
        "fast_cpu_ms": fast_cpu,
        "fast_speedup_cpu": if fast_cpu > 0.0 { json!(without_cpu / fast_cpu) } else { Value::Null },
        "bounded_max_relative_difference": worst_bounded,
        "bounded_decisions_changed": flips,
        "exit_faces_cpu_ms": exits_cpu,
        "exit_faces_speedup_cpu": if exits_cpu > 0.0 { json!(without_cpu / exits_cpu) } else { Value::Null },
        "exit_faces_max_relative_difference": worst_exits,
        "culled_ms": with_ms,
        "culled_cpu_ms": with_cpu,
        "unculled_ms": without_ms,
        "unculled_cpu_ms": without_cpu,
        "cull_speedup_cpu": if with_cpu > 0.0 { json!(without_cpu / with_cpu) } else { Value::Null },
        "max_relative_difference": worst,
    });
    let table = format!(
        "simplify estimates {}: {} shadow edges, estimated in {:.0} ms ({:.0} ms CPU), {} kept at {}; culls of {} (band, light) pairs: {} facing away, {} behind, {} blocked\n\
         {} edges, every face / exit faces / and culls / and bounds: {:.0} / {:.0} / {:.0} / {:.0} ms CPU ({:.2}x / {:.2}x / {:.2}x); largest relative difference of the exit faces {:e}, of the culls {:e}, of the bounds {:.3}, {} decisions at {} changed\n",
        scene.name,
        all.len(),
        all_ms,
        all_cpu,
        kept,
        tolerance,
        culls.pairs,
        culls.facing,
        culls.behind,
        culls.blocked,
        sub.len(),
        without_cpu,
        exits_cpu,
        with_cpu,
        fast_cpu,
        without_cpu / exits_cpu.max(1e-9),
        without_cpu / with_cpu.max(1e-9),
        without_cpu / fast_cpu.max(1e-9),
        worst_exits,
        worst,
        worst_bounded,
        flips,
        tolerance
    );
    Ok((v, table + &moved_table))
}

/// What `--moves` asks for.
pub struct Moves {
    pub count: usize,
    pub object: Option<String>,
    pub step: f64,
}

/// The estimates across `moves.count` slides of the object, for the finder and the mesh.
fn run_moves(scene: &Scene, triples: &[TripleKey], moves: &Moves) -> Result<(Value, String)> {
    let object = crate::dmesh::object_to_move(scene, moves.object.as_deref())?;
    let (lo, hi) = scene.object_bounds(object);
    let step = (hi - lo).length() * moves.step as f32;
    let mut t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    let mut finder = EdgeFinder::new(scene, &edgepoint_scene::NoProgress);
    let view = ViewVolume::new(&scene.camera, 1.0);
    let mut out: Vec<EdgeSegment> = Vec::new();
    finder.frame(&t, scene.camera.eye, Some(&view), triples.iter().copied(), 85.0, &mut out);
    let mut kept = EdgeErrors::new();
    let w = Instant::now();
    let (all, _) = finder.errors(&mut kept);
    let finder_all_ms = w.elapsed().as_secs_f64() * 1e3;
    let w = Instant::now();
    let mut mesh = MeshShadows::build(scene, &t, &edgepoint_scene::NoProgress);
    let mesh_build_ms = w.elapsed().as_secs_f64() * 1e3;
    let w = Instant::now();
    let mesh_edges = mesh.as_mut().map_or(0, |m| m.estimate(&finder.scene_lights().0, 4096, || false, &edgepoint_scene::NoProgress));
    let mesh_all_ms = w.elapsed().as_secs_f64() * 1e3;
    let bits = |v: &[(EdgeSegment, f64)]| v.iter().map(|(e, x)| (e.a.to_array().map(f32::to_bits), e.b.to_array().map(f32::to_bits), x.to_bits())).collect::<Vec<_>>();
    let mut per_move = Vec::new();
    let mut table = format!("moves of {}: finder {} edges estimated in {finder_all_ms:.0} ms; mesh {mesh_edges} edges (built in {mesh_build_ms:.0} ms) estimated in {mesh_all_ms:.0} ms\n", scene.objects[object].name, all.len());
    for k in 0..moves.count {
        // Back and forth along X, as `--move-object` slides it.
        let dir = if (k / 4) % 2 == 0 { 1.0 } else { -1.0 };
        t[object] = Affine3A::from_translation(glam::Vec3::X * step * dir) * t[object];
        finder.frame(&t, scene.camera.eye, Some(&view), triples.iter().copied(), 85.0, &mut out);
        let (carried, dropped) = (kept.carried, kept.dropped);
        let w = Instant::now();
        let (after, again) = finder.errors(&mut kept);
        let finder_ms = w.elapsed().as_secs_f64() * 1e3;
        let w = Instant::now();
        let (fresh, _) = finder.errors(&mut EdgeErrors::new());
        let finder_fresh_ms = w.elapsed().as_secs_f64() * 1e3;
        let finder_differ = bits(&after).iter().zip(bits(&fresh)).filter(|(a, b)| **a != *b).count() + after.len().abs_diff(fresh.len());
        let mut m = json!({
            "finder": {"edges": after.len(), "kept": kept.carried - carried, "dropped": kept.dropped - dropped, "estimated": again, "ms": finder_ms, "afresh_ms": finder_fresh_ms, "differ": finder_differ},
        });
        table += &format!("move {k}: finder {} edges, {} kept, {again} estimated in {finder_ms:.0} ms (afresh {finder_fresh_ms:.0} ms), {finder_differ} differ", after.len(), kept.carried - carried);
        if let Some(mesh) = mesh.as_mut() {
            let lights: SceneLights = finder.scene_lights().0;
            let w = Instant::now();
            mesh.sync(&t);
            let sync_ms = w.elapsed().as_secs_f64() * 1e3;
            let w = Instant::now();
            let dropped = mesh.check_estimates(&lights);
            let check_ms = w.elapsed().as_secs_f64() * 1e3;
            let w = Instant::now();
            let again = mesh.estimate(&lights, 4096, || false, &edgepoint_scene::NoProgress);
            let est_ms = w.elapsed().as_secs_f64() * 1e3;
            let with_kept = mesh.keyed_estimates();
            mesh.forget_estimates();
            let w = Instant::now();
            let all = mesh.estimate(&lights, 4096, || false, &edgepoint_scene::NoProgress);
            let fresh_ms = w.elapsed().as_secs_f64() * 1e3;
            let differ = with_kept.iter().zip(mesh.keyed_estimates()).filter(|(a, b)| **a != *b).count();
            m["mesh"] = json!({"edges": all, "dropped": dropped, "estimated": again, "kept": all - again, "update_ms": sync_ms, "check_ms": check_ms, "estimate_ms": est_ms, "afresh_ms": fresh_ms, "differ": differ});
            table += &format!("; mesh {all} edges, {} kept, {dropped} dropped, {again} estimated in {:.0} ms (check {check_ms:.0} ms; afresh {fresh_ms:.0} ms), {differ} differ", all - again, est_ms);
        }
        table += "\n";
        per_move.push(m);
    }
    Ok((json!({"object": scene.objects[object].name, "step": step, "finder_all_ms": finder_all_ms, "mesh_build_ms": mesh_build_ms, "mesh_edges": mesh_edges, "mesh_all_ms": mesh_all_ms, "per_move": per_move}), table))
}
