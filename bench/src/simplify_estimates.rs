//! `edgepoint-bench simplify --estimates`: paper 003's estimates alone, in this process (no
//! session, no workers). The scene's shadow edges from the triples a shader would report
//! (surface points ray-cast to the lights, as `edges --scene` samples them), every edge
//! estimated with the culls of lights that cannot reach its band, closed meshes' exit faces
//! and the bounds; then `--compare` edges spread over the set estimated again with every
//! face and nothing skipped, with exit faces only, and with the culls too, all timed on the
//! pool (CPU time of the process), with the largest differences from the first; and the
//! same with the other lights bounded where not comparable (a different estimate: its largest
//! relative difference, and how many decisions at the tolerance it changes).
use crate::clock::process_cpu_ms;
use anyhow::Result;
use edgepoint_scene::Scene;
use edgepoint_server::edges::finder::{EdgeFinder, ViewVolume};
use edgepoint_server::edges::simplify::{estimate, jobs, Culls, Estimate, Rules};
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
pub fn run(scene: Scene, what: &str, triple_points: usize, compare: usize, tolerance: f64) -> Result<(Value, String)> {
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
    let v = json!({
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
    Ok((v, table))
}
