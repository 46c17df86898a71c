//! `edgepoint-bench rays`: the worker's ray rate on one mesh (issue 14 item 5), on the
//! issue's three workloads — a 1024² pinhole camera's primary rays, shadow rays from their
//! hits to a point light, 2^20 random incoherent closest-hit rays — one ray at a time, on 1
//! and 2 threads, with the BVH build time. Baselines in the same process: the worker's
//! traversal as it was before this work ([`obvhs_baseline`]) and Embree libraries named with
//! `--embree` ([`embree`]: Embree 3 from Debian, Embree 4.4 from PyPI's `embreex` wheel, the
//! version the issue measured); the issue's Embree 4.4 figures on this machine are reported
//! as the constants they are too. A subset of every workload is checked against brute force.
mod embree;
mod obvhs_baseline;
mod workloads;

use anyhow::{Context, Result};
use edgepoint_scene::Mesh;
use edgepoint_server::reference::LogProgress;
use edgepoint_worker::{ray_oracle, Instances, SceneBvh, Simd};
use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use serde_json::{json, Value};
use std::time::Instant;
use workloads::{Workload, WorkloadKind};

#[derive(clap::Args, Debug)]
pub struct RaysArgs {
    /// The mesh (.ply / .obj; e.g. ../shared/data/dragon/dragon_vrip.ply). Its largest
    /// object is traced alone (a bare model's staging floor is left out).
    #[arg(long)]
    pub mesh: std::path::PathBuf,
    /// Timed runs per tracer, workload and thread count; the median is reported.
    #[arg(long, default_value_t = 3)]
    pub repeat: u32,
    /// Image side of the primary-ray camera (the issue's workload: 1024).
    #[arg(long, default_value_t = 1024)]
    pub resolution: u32,
    /// Number of random incoherent rays (the issue's workload: 2^20 = 1048576).
    #[arg(long, default_value_t = 1 << 20)]
    pub incoherent: usize,
    /// Rays per workload checked against brute force (every triangle, f64).
    #[arg(long, default_value_t = 64)]
    pub verify: usize,
    /// An Embree shared library to trace the same rays with in this process, one ray at a
    /// time (repeatable; Embree 3 or 4, told apart by the version the library reports).
    /// Embree 3: `apt-get install libembree3-3`, then
    /// /usr/lib/x86_64-linux-gnu/libembree3.so.3. Embree 4.4 (the issue's): `pip download
    /// --no-deps embreex==4.4.0.post1`, unzip the wheel, and name
    /// embreex.libs/libembree4-*.so.4 (its TBB beside it is found by the library's own rpath).
    #[arg(long = "embree", value_name = "LIB")]
    pub embree: Vec<std::path::PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One ray at a time, closest hit and any hit: what every tracer in the bench offers.
pub trait Tracer: Sync {
    /// Nearest hit with `0 <= t <= tmax`: (t in units of |d|, triangle index in the mesh).
    fn closest(&self, o: Vec3, d: Vec3, tmax: f32) -> Option<(f32, u32)>;
    /// Whether anything lies on the segment `0 <= t <= tmax`.
    fn occluded(&self, o: Vec3, d: Vec3, tmax: f32) -> bool;
}

/// The worker's tracer: the two-level BVH with one instance, its closest hits as
/// [`edgepoint_worker::bvh::RayHit`] (ids, t and the unnormalised geometric normal, what
/// Embree's `rtcIntersect1` returns; the shaders' `closest_hit` adds the position and unit
/// normals to that).
struct WorkerTracer {
    bvh: SceneBvh,
    inst: Instances,
}

impl Tracer for WorkerTracer {
    fn closest(&self, o: Vec3, d: Vec3, tmax: f32) -> Option<(f32, u32)> {
        self.inst.closest(&self.bvh, o, d, 0.0, tmax).map(|h| (h.t, h.triangle))
    }
    fn occluded(&self, o: Vec3, d: Vec3, tmax: f32) -> bool {
        self.inst.occluded(&self.bvh, o, d, 0.0, tmax).is_some()
    }
}

/// Embree 4.4 on this machine, one ray at a time, as issue 14 item 5 states them
/// (Mrays/s; ranges as measured there). Constants, not measured by this program.
const ISSUE_EMBREE_1T: [(f64, f64); 3] = [(9.0, 9.0), (6.0, 6.0), (3.0, 3.7)];
const ISSUE_EMBREE_2T: [(f64, f64); 3] = [(16.5, 17.7), (10.7, 11.3), (6.3, 7.3)];
const ISSUE_EMBREE_BUILD_MS: (f64, f64) = (255.0, 270.0);
/// The worker before this work, as the issue measured it (1 thread, 2 threads, build ms).
const ISSUE_WORKER_1T: [f64; 3] = [2.4, 2.2, 1.2];
const ISSUE_WORKER_2T: [f64; 3] = [5.4, 4.7, 2.8];
const ISSUE_WORKER_BUILD_MS: f64 = 576.0;
/// The issue's hit fractions on the welded dragon (primary hits, shadow rays occluded,
/// incoherent hits): they check that the workloads are set up as there.
const ISSUE_HIT_FRACTION: [f64; 3] = [0.548, 0.163, 0.412];

struct Entry {
    name: &'static str,
    tracer: Box<dyn Tracer>,
    build_ms: Vec<f64>,
    build_wall_ms: Vec<f64>,
}

fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().context("building a thread pool")
}

/// Runs `build` on a pool of `threads` threads `repeat` times: (the last result, the times
/// in ms). One thread: the building thread's CPU time — its time without the other jobs on a
/// shared machine (Embree, told `threads=1`, builds on the calling thread; process CPU time
/// would also count the task scheduler's idle threads spinning, which made Embree 4's
/// builds after the first look twice as long as they are); the wall clock beside it. More:
/// wall clock (CPU time would add the threads up).
fn timed_builds<T: Send>(repeat: u32, threads: usize, build: impl Fn() -> Result<T> + Sync) -> Result<(T, Vec<f64>, Vec<f64>)> {
    let p = pool(threads)?;
    let (mut ms, mut wall) = (Vec::new(), Vec::new());
    let mut last = None;
    for _ in 0..repeat.max(1) {
        drop(last.take());
        let (t, cpu) = (crate::clock::wall_ms(), p.install(crate::clock::thread_cpu_ms));
        let (built, cpu_end) = p.install(|| build().map(|b| (b, crate::clock::thread_cpu_ms())))?;
        let w = crate::clock::wall_ms() - t;
        ms.push(if threads == 1 { cpu_end - cpu } else { w });
        wall.push(w);
        last = Some(built);
    }
    Ok((last.expect("at least one build"), ms, wall))
}

/// Traces a workload on the current pool: (seconds, hits or occluded rays). On a
/// one-thread pool the seconds are the thread's CPU time (all the work runs on it), which
/// the other jobs on a shared machine inflate far less than the wall clock; on more
/// threads they are wall-clock seconds.
fn trace(tracer: &dyn Tracer, w: &Workload) -> (f64, usize) {
    let one_thread = rayon::current_num_threads() == 1;
    let (t, cpu0) = (Instant::now(), crate::clock::thread_cpu_ms());
    let hits = match w.kind {
        WorkloadKind::Closest => w.rays.par_chunks(1024).map(|c| c.iter().filter(|r| tracer.closest(r.o, r.d, r.tmax).is_some()).count()).sum(),
        WorkloadKind::Occlusion => w.rays.par_chunks(1024).map(|c| c.iter().filter(|r| tracer.occluded(r.o, r.d, r.tmax)).count()).sum(),
    };
    let secs = if one_thread { (crate::clock::thread_cpu_ms() - cpu0) * 1e-3 } else { t.elapsed().as_secs_f64() };
    (secs, hits)
}

/// How often two tracers agree on a workload: closest hits on the same triangle (or at the
/// same t within 1e-5 relative: a tie on a shared edge), and the same occlusion answer.
fn agreement(a: &dyn Tracer, b: &dyn Tracer, w: &Workload) -> f64 {
    let same = w
        .rays
        .par_iter()
        .filter(|r| match w.kind {
            WorkloadKind::Closest => match (a.closest(r.o, r.d, r.tmax), b.closest(r.o, r.d, r.tmax)) {
                (None, None) => true,
                (Some((ta, ia)), Some((tb, ib))) => ia == ib || ((ta - tb) / tb.max(1e-12)).abs() < 1e-5,
                _ => false,
            },
            WorkloadKind::Occlusion => a.occluded(r.o, r.d, r.tmax) == b.occluded(r.o, r.d, r.tmax),
        })
        .count();
    same as f64 / w.rays.len().max(1) as f64
}

/// Brute force on `n` rays spread over the workload: how many of the worker's answers
/// differ from the f64 oracle, not counting hits within 1e-5 (barycentric) of an edge.
fn verify(tracer: &dyn Tracer, mesh: &Mesh, tf: Affine3A, w: &Workload, n: usize) -> Value {
    if n == 0 || w.rays.is_empty() {
        return json!({"rays": 0});
    }
    let step = (w.rays.len() / n).max(1);
    let picked: Vec<_> = w.rays.iter().step_by(step).take(n).collect();
    let meshes = [mesh];
    let tfs = [tf];
    let (mut wrong, mut grazing, mut max_rel_t) = (0usize, 0usize, 0f64);
    let results: Vec<_> = picked
        .par_iter()
        .map(|r| {
            let want = ray_oracle::closest(&meshes, &tfs, r.o, r.d, 0.0, r.tmax as f64);
            (r, want)
        })
        .collect();
    for (r, want) in results {
        match w.kind {
            WorkloadKind::Closest => match (tracer.closest(r.o, r.d, r.tmax), want) {
                (None, None) => {}
                (Some((t, tri)), Some((_, wt, tw, margin))) => {
                    let rel = ((t as f64 - tw) / tw.max(1e-12)).abs();
                    max_rel_t = max_rel_t.max(rel);
                    let tie = tri != wt && {
                        let [a, b, c] = ray_oracle::world_triangle(&meshes, &tfs, 0, tri);
                        ray_oracle::ray_triangle(r.o.as_dvec3(), r.d.as_dvec3(), a, b, c).is_some_and(|t2| ((t2 - tw) / tw).abs() < 1e-6)
                    };
                    if rel > 1e-4 || (tri != wt && !tie) {
                        if margin < 1e-5 {
                            grazing += 1
                        } else {
                            wrong += 1
                        }
                    }
                }
                (None, Some((_, _, _, margin))) if margin < 1e-5 => grazing += 1,
                (Some(_), None) => grazing += 1,
                _ => wrong += 1,
            },
            WorkloadKind::Occlusion => {
                if tracer.occluded(r.o, r.d, r.tmax) != want.is_some() {
                    if want.is_some_and(|w| w.3 < 1e-5 || w.2 > r.tmax as f64 * 0.9999) {
                        grazing += 1
                    } else {
                        wrong += 1
                    }
                }
            }
        }
    }
    json!({"rays": picked.len(), "wrong": wrong, "on_an_edge": grazing, "max_relative_t_error": max_rel_t})
}

pub fn run(a: RaysArgs) -> Result<()> {
    // The Embree libraries first: a wrong path fails before the mesh is loaded.
    let libraries = a.embree.iter().map(|p| embree::Library::open(p)).collect::<Result<Vec<_>>>()?;
    // Their results are keyed by major version ("embree3", "embree4").
    for i in 0..libraries.len() {
        if let Some(j) = (0..i).find(|&j| libraries[j].name == libraries[i].name) {
            anyhow::bail!("--embree {} and --embree {} are both {}: name one library per major version", a.embree[j].display(), a.embree[i].display(), libraries[i].name);
        }
    }
    let progress = LogProgress::new("rays");
    let scene = edgepoint_scene::load::load_path(&a.mesh, &progress).map_err(|e| anyhow::anyhow!("{e}"))?;
    let object = scene.objects.iter().max_by_key(|o| o.mesh.triangles.len()).context("the file has no mesh")?;
    let mesh = object.mesh.clone();
    let tf = object.transform;
    let (lo, hi) = edgepoint_scene::geometry::transformed_box(&tf, mesh.bounds);
    tracing::info!("{}: {} triangles, bounds {lo} .. {hi}", a.mesh.display(), mesh.triangles.len());

    // Builds, one thread each (the issue's build figures are one-thread figures).
    let mut entries = Vec::new();
    let (worker, ms, wall) = timed_builds(a.repeat, 1, || {
        let bvh = SceneBvh::build(&[mesh.as_ref()], &edgepoint_scene::NoProgress);
        let inst = Instances::new(&bvh, &[tf]);
        Ok(WorkerTracer { bvh, inst })
    })?;
    let shape = worker.bvh.objects[0].shape();
    entries.push(Entry { name: "worker", tracer: Box::new(worker), build_ms: ms, build_wall_ms: wall });
    // The worker's traversal with the baseline instruction set (SSE), when the CPU's widest
    // (AVX2 + FMA) is what "worker" runs: the same BVH, built again, untimed.
    if Simd::detect() != Simd::Baseline {
        let bvh = SceneBvh::build(&[mesh.as_ref()], &edgepoint_scene::NoProgress);
        let inst = Instances::new(&bvh, &[tf]).with_simd(Simd::Baseline);
        entries.push(Entry { name: "worker_sse", tracer: Box::new(WorkerTracer { bvh, inst }), build_ms: vec![], build_wall_ms: vec![] });
    }
    let (base, ms, wall) = timed_builds(a.repeat, 1, || Ok(obvhs_baseline::BaselineBvh::build(&mesh, tf)))?;
    entries.push(Entry { name: "baseline", tracer: Box::new(base), build_ms: ms, build_wall_ms: wall });
    let world: Vec<Vec3> = mesh.positions.iter().map(|p| tf.transform_point3(*p)).collect();
    for lib in &libraries {
        tracing::info!("Embree {} ({})", lib.version, lib.name);
        let (e, ms, wall) = timed_builds(a.repeat, 1, || embree::EmbreeMesh::build(lib, &world, &mesh.triangles, 1))?;
        entries.push(Entry { name: lib.name, tracer: Box::new(e), build_ms: ms, build_wall_ms: wall });
    }
    // Builds on two threads (wall clock; the worker's build splits its subtrees over its
    // pool, Embree builds with two threads of its own).
    let mut builds_2t = serde_json::Map::new();
    let (_, ms, _) = timed_builds(a.repeat, 2, || Ok(SceneBvh::build(&[mesh.as_ref()], &edgepoint_scene::NoProgress)))?;
    builds_2t.insert("worker".into(), json!({"ms_median": crate::stats::median(&ms), "ms": ms}));
    for lib in &libraries {
        let (_, ms, _) = timed_builds(a.repeat, 2, || embree::EmbreeMesh::build(lib, &world, &mesh.triangles, 2))?;
        builds_2t.insert(lib.name.into(), json!({"ms_median": crate::stats::median(&ms), "ms": ms}));
    }

    let base = entries.iter().position(|e| e.name == "baseline").context("the baseline tracer")?;

    // The workloads; the shadow rays start at the worker's primary hits.
    let primary = workloads::primary(lo, hi, a.resolution);
    let shadow = workloads::shadow(lo, hi, &primary, |o, d, tmax| {
        entries[0].tracer.closest(o, d, tmax).map(|(t, tri)| (t, (tf.matrix3.inverse().transpose() * glam::Vec3A::from(mesh.face_normals[tri as usize])).normalize().into()))
    });
    let incoherent = workloads::incoherent(lo, hi, a.incoherent, 0x5eed_0014);
    let works = [primary, shadow, incoherent];

    let mut rows = Vec::new();
    let mut table = format!("rays on {} ({} triangles), one ray at a time, median of {}:\n", a.mesh.display(), mesh.triangles.len(), a.repeat.max(1));
    for (wi, w) in works.iter().enumerate() {
        let mut per_threads = Vec::new();
        let mut hit_fraction = json!({});
        for threads in [1usize, 2] {
            let p = pool(threads)?;
            let mut secs = vec![Vec::new(); entries.len()];
            let mut hits = vec![0usize; entries.len()];
            // Round-robin over the tracers, so load on the shared machine falls on all alike.
            for _ in 0..a.repeat.max(1) {
                for (k, e) in entries.iter().enumerate() {
                    let (s, h) = p.install(|| trace(e.tracer.as_ref(), w));
                    secs[k].push(s);
                    hits[k] = h;
                }
            }
            let mrays: Vec<f64> = secs.iter().map(|s| w.rays.len() as f64 / crate::stats::median(s) / 1e6).collect();
            let mut tracers = serde_json::Map::new();
            for (k, e) in entries.iter().enumerate() {
                tracers.insert(e.name.into(), json!({"mrays_per_s": mrays[k], "seconds": secs[k], "hit_fraction": hits[k] as f64 / w.rays.len() as f64}));
                hit_fraction[e.name] = json!(hits[k] as f64 / w.rays.len() as f64);
            }
            let issue = if threads == 1 { ISSUE_EMBREE_1T[wi] } else { ISSUE_EMBREE_2T[wi] };
            let issue_worker = if threads == 1 { ISSUE_WORKER_1T[wi] } else { ISSUE_WORKER_2T[wi] };
            let mut ratios = json!({
                "worker_over_baseline": mrays[0] / mrays[base],
                "worker_over_issue_embree44_low": mrays[0] / issue.0,
                "worker_over_issue_embree44_high": mrays[0] / issue.1,
            });
            table.push_str(&format!(
                "  {:<10} {} thread{}: worker {:6.2} Mrays/s, baseline {:6.2} ({:4.2}x), issue's Embree 4.4 {}-{} ({:4.2}x of the high end)",
                w.name,
                threads,
                if threads == 1 { " " } else { "s" },
                mrays[0],
                mrays[base],
                mrays[0] / mrays[base],
                issue.0,
                issue.1,
                mrays[0] / issue.1
            ));
            if let Some(k) = entries.iter().position(|e| e.name == "worker_sse") {
                ratios["worker_over_worker_sse"] = json!(mrays[0] / mrays[k]);
                table.push_str(&format!(", worker SSE {:6.2} ({:4.2}x)", mrays[k], mrays[0] / mrays[k]));
            }
            for lib in &libraries {
                if let Some(k) = entries.iter().position(|e| e.name == lib.name) {
                    ratios[format!("worker_over_{}_same_process", lib.name)] = json!(mrays[0] / mrays[k]);
                    table.push_str(&format!(", Embree {} here {:6.2} ({:4.2}x)", lib.version, mrays[k], mrays[0] / mrays[k]));
                }
            }
            table.push('\n');
            per_threads.push(json!({
                "threads": threads,
                "tracers": tracers,
                "ratios": ratios,
                "issue_embree44_mrays_per_s": [issue.0, issue.1],
                "issue_worker_before_mrays_per_s": issue_worker,
            }));
        }
        let agree: serde_json::Map<_, _> = entries[1..].iter().map(|e| (format!("worker_vs_{}", e.name), json!(agreement(entries[0].tracer.as_ref(), e.tracer.as_ref(), w)))).collect();
        let check = verify(entries[0].tracer.as_ref(), &mesh, tf, w, a.verify);
        table.push_str(&format!(
            "  {:<10} {} rays, hit fraction {:.3}; agreement {:?}; brute force on {}: {} wrong, {} on an edge\n",
            w.name, w.rays.len(), hit_fraction["worker"].as_f64().unwrap_or(0.0), agree, check["rays"], check["wrong"], check["on_an_edge"]
        ));
        rows.push(json!({
            "workload": w.name,
            "rays": w.rays.len(),
            "hit_fraction": hit_fraction,
            "issue_hit_fraction": ISSUE_HIT_FRACTION[wi],
            "agreement": agree,
            "brute_force": check,
            "runs": per_threads,
        }));
    }
    let builds: serde_json::Map<_, _> = entries
        .iter()
        .filter(|e| !e.build_ms.is_empty())
        .map(|e| {
            let wall = json!({"ms_median": crate::stats::median(&e.build_wall_ms), "ms": e.build_wall_ms});
            (e.name.to_string(), json!({"ms_median": crate::stats::median(&e.build_ms), "ms": e.build_ms, "wall": wall}))
        })
        .collect();
    let wb = crate::stats::median(&entries[0].build_ms);
    table.push_str(&format!(
        "  worker BVH: {} nodes, {} levels, {} leaves of {} blocks, {:.2} triangles per leaf, SAH cost {:.3} (as Embree's statistics count it: verbose=2)\n",
        shape.nodes,
        shape.depth,
        shape.leaves,
        shape.blocks,
        shape.triangles as f64 / shape.leaves.max(1) as f64,
        shape.sah
    ));
    table.push_str(&format!(
        "  BVH build, 2 threads (wall clock): {}\n",
        builds_2t.iter().map(|(k, v)| format!("{k} {:.0} ms", v["ms_median"].as_f64().unwrap_or(f64::NAN))).collect::<Vec<_>>().join(", ")
    ));
    table.push_str(&format!("  BVH build, 1 thread: {}\n", entries.iter().filter(|e| !e.build_ms.is_empty()).map(|e| format!("{} {:.0} ms", e.name, crate::stats::median(&e.build_ms))).collect::<Vec<_>>().join(", ")));
    let mut build_ratios = json!({
        "worker_over_baseline": wb / crate::stats::median(&entries[base].build_ms),
        "worker_over_issue_embree44_low": wb / ISSUE_EMBREE_BUILD_MS.0,
        "worker_over_issue_embree44_high": wb / ISSUE_EMBREE_BUILD_MS.1,
    });
    for e in entries.iter().filter(|e| e.name.starts_with("embree")) {
        build_ratios[format!("worker_over_{}_same_process", e.name)] = json!(wb / crate::stats::median(&e.build_ms));
    }
    let out = json!({
        "mesh": a.mesh.display().to_string(),
        "triangles": mesh.triangles.len(),
        "bounds": [lo.to_array(), hi.to_array()],
        "resolution": a.resolution,
        "repeat": a.repeat.max(1),
        "timing": "1 thread: CPU time of the tracing thread; 2 threads: wall clock; builds: CPU time of the building thread on a one-thread pool (and, under wall, the wall clock)",
        "embree_in_process": libraries.iter().map(|l| (l.name.to_string(), json!(l.version))).collect::<serde_json::Map<_, _>>(),
        "worker_simd": format!("{:?}", Simd::detect()),
        "workloads": rows,
        "build_one_thread": builds,
        "build_two_threads_wall": builds_2t,
        "worker_bvh": {"nodes": shape.nodes, "depth": shape.depth, "leaves": shape.leaves, "blocks": shape.blocks, "triangles": shape.triangles, "sah": shape.sah, "triangles_per_leaf": shape.triangles as f64 / shape.leaves.max(1) as f64},
        "build_ratios": build_ratios,
        "issue_constants": {
            "note": "Measured on this machine by issue 14 item 5 (Embree 4.4, one ray at a time; the worker at main before this work); constants, not measured by this run",
            "embree44_mrays_per_s_1_thread": {"primary": ISSUE_EMBREE_1T[0], "shadow": ISSUE_EMBREE_1T[1], "incoherent": ISSUE_EMBREE_1T[2]},
            "embree44_mrays_per_s_2_threads": {"primary": ISSUE_EMBREE_2T[0], "shadow": ISSUE_EMBREE_2T[1], "incoherent": ISSUE_EMBREE_2T[2]},
            "embree44_build_ms_1_thread": ISSUE_EMBREE_BUILD_MS,
            "worker_before_mrays_per_s_1_thread": ISSUE_WORKER_1T,
            "worker_before_mrays_per_s_2_threads": ISSUE_WORKER_2T,
            "worker_before_build_ms": ISSUE_WORKER_BUILD_MS,
        },
    });
    crate::emit(a.json, &out, &table);
    Ok(())
}
