//! A session's discontinuity mesh, kept on its shadow thread when the session takes its
//! area lights' shadow edges from the mesh (`--shadow-edges mesh`, issue 15 item 4): built
//! once for the objects where they are, updated incrementally for each object that moves
//! ([`crate::dmesh::update`], paper 002 §3–4), and turned into the EPI's shadow edges
//! ([`crate::edges::mesh_edges`]).
//!
//! With a simplification tolerance (paper 003) each mesh edge is estimated as the finder's
//! shadow edges are ([`crate::edges::simplify`]: the L2 error of leaving it out over a band
//! across it, against the irradiance of every light), and only the edges at or above the
//! tolerance are published. An estimate outlives a move that leaves its edge as it was and
//! cannot reach its band ([`SceneLights::still_holds`]): after a chair moves in `rooms` a
//! few thousand of 70,000 edges are estimated again, not all.
use crate::dmesh::geometry::Geometry;
use crate::dmesh::grid::Grid;
use crate::dmesh::{area_lights_indexed, tolerance, DiscontinuityMesh, ProgressSteps, GRID_TRIANGLES_PER_VOXEL};
use crate::edges::mesh_edges::{receivers_shadow_edges, Decisions, MeshEdgeCounts, MeshShadowEdge, Moved, OldDecisions};
use crate::edges::shadow::daffine;
use crate::edges::simplify::{self, Estimate, Estimated, Job, Rules, SceneLights};
use crate::edges::EdgeSegment;
use edgepoint_scene::{NoProgress, Progress, Scene};
use glam::{Affine3A, DVec3, Vec3};
use std::collections::{BTreeMap, HashMap};
use std::time::Instant;

/// One receiver's shadow edges with their estimates (paper 003; `None` where not made yet),
/// and what each of its arrangement edges gave.
struct ReceiverEdges {
    edges: Vec<MeshShadowEdge>,
    errors: Vec<Option<Estimated>>,
    decisions: Decisions,
}

/// Moved boxes kept apart for [`MeshShadows::check_estimates`] before they are merged into one.
const MAX_UNCHECKED_BOXES: usize = 64;

pub struct MeshShadows {
    geometry: Geometry,
    grid: Grid,
    mesh: DiscontinuityMesh,
    transforms: Vec<Affine3A>,
    /// The scene light of each of the mesh's lights.
    scene_light: Vec<u32>,
    /// Each receiver's shadow edges (light, triangle; receivers with no arrangement edge
    /// left out), what each of its arrangement edges gave and the edges' estimates: after a
    /// move only the receivers whose mesh changed make theirs again, keeping the decisions
    /// the moved object cannot have changed and the estimates of edges made the same. In
    /// this order (lights × receivers × mesh edges) the edges are published.
    by_receiver: BTreeMap<(u32, u32), ReceiverEdges>,
    /// How many edges have no estimate.
    missing: usize,
    /// World boxes (before and after) of the moves since the estimates were last checked
    /// against them: until then none is known to hold.
    unchecked: Vec<(DVec3, DVec3)>,
    rules: Rules,
}

impl MeshShadows {
    /// The mesh of `scene`'s area lights with its objects at `transforms`; `None` when the
    /// scene has no area light (nothing to mesh).
    /// `progress` hears of the receivers meshed and then of their shadow edges made.
    pub fn build(scene: &Scene, transforms: &[Affine3A], progress: &dyn Progress) -> Option<MeshShadows> {
        let (scene_light, lights): (Vec<u32>, Vec<_>) = area_lights_indexed(scene).into_iter().unzip();
        if lights.is_empty() {
            return None;
        }
        let t = Instant::now();
        let geometry = Geometry::from_scene_at(scene, transforms);
        let grid = Grid::build(&geometry, GRID_TRIANGLES_PER_VOXEL);
        let mesh = DiscontinuityMesh::compute_reporting(&geometry, &grid, &lights, tolerance(&geometry), None, progress);
        let mut m = MeshShadows { geometry, grid, mesh, transforms: transforms.to_vec(), scene_light, by_receiver: BTreeMap::new(), missing: 0, unchecked: Vec::new(), rules: Rules::new() };
        let receivers = m.mesh.receiver_ids();
        progress.begin("shadow edges of the receivers", receivers.len() as u64);
        m.refresh_edges(&receivers, None, progress);
        progress.end();
        tracing::info!(
            lights = m.mesh.lights.len(),
            triangles = m.geometry.tris.len(),
            segments = m.mesh.segment_count(),
            faces = m.mesh.face_count(),
            shadow_edges = m.edge_count(),
            ms = t.elapsed().as_secs_f64() * 1e3,
            "discontinuity mesh built"
        );
        Some(m)
    }

    /// Brings the mesh to `transforms`: every object whose transform changed is moved from
    /// where the mesh has it, incrementally. Returns whether anything changed.
    pub fn sync(&mut self, transforms: &[Affine3A]) -> bool {
        let t = Instant::now();
        let mut moved = 0;
        let mut changed = Vec::new();
        // With exactly one object moved, the geometry before it and its boxes (for keeping
        // the decisions it cannot have changed); a second one moved clears it.
        let mut one: Option<(Geometry, u32, [(glam::DVec3, glam::DVec3); 2])> = None;
        for (o, to) in transforms.iter().enumerate().take(self.transforms.len()) {
            if self.transforms[o] == *to {
                continue;
            }
            // The change of place in f64 (as the cache carries its points, `move_object`).
            let d = daffine(to) * daffine(&self.transforms[o]).inverse();
            let new = self.geometry.moved(o as u32, |p| d.transform_point3(p));
            let stats = self.mesh.move_object_listing(&self.geometry, &new, &mut self.grid, o as u32, &mut changed);
            tracing::debug!(object = o, ?stats, "discontinuity mesh updated");
            let boxes = [self.geometry.object_bounds(o as u32), new.object_bounds(o as u32)];
            self.unchecked.extend(boxes);
            // Moves made while nothing checks (tolerance 0) would pile up: past a few
            // dozen, their union stands for them all (a larger box only drops more).
            if self.unchecked.len() > MAX_UNCHECKED_BOXES {
                let all = self.unchecked.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), b| (lo.min(b.0), hi.max(b.1)));
                self.unchecked = vec![all];
            }
            let before = std::mem::replace(&mut self.geometry, new);
            one = (moved == 0).then_some((before, o as u32, boxes));
            self.transforms[o] = *to;
            moved += 1;
        }
        if moved > 0 {
            changed.sort_unstable();
            changed.dedup();
            let mv = one.as_ref().map(|(old, object, boxes)| Moved { old, object: *object, boxes: *boxes });
            self.refresh_edges(&changed, mv.as_ref(), &NoProgress);
            tracing::debug!(objects = moved, receivers_changed = changed.len(), shadow_edges = self.edge_count(), ms = t.elapsed().as_secs_f64() * 1e3, "mesh shadow edges after a move");
        }
        moved > 0
    }

    /// Whether the mesh has the objects at `transforms`.
    pub fn at(&self, transforms: &[Affine3A]) -> bool {
        self.transforms == transforms
    }

    /// The edges that go to the EPI at simplification tolerance `tolerance` (0: every one),
    /// each with its penumbra, appended to `out`; returns how many were left out. An edge
    /// not estimated yet goes (and every one while a move's estimates are unchecked).
    pub fn published(&self, tolerance: f64, out: &mut Vec<(EdgeSegment, [Vec3; 2])>) -> usize {
        let all = self.by_receiver.values().flat_map(|r| r.edges.iter().zip(&r.errors));
        if tolerance > 0.0 && self.unchecked.is_empty() {
            let with: Vec<_> = all.map(|(e, x)| ((e.edge, e.penumbra), x.map_or(f64::NAN, |x| x.error))).collect();
            super::edge_source::chosen_shadow_edges(&with, tolerance, out)
        } else {
            out.extend(all.map(|(e, _)| (e.edge, e.penumbra)));
            0
        }
    }

    /// How many shadow edges the mesh has.
    fn edge_count(&self) -> usize {
        self.by_receiver.values().map(|r| r.edges.len()).sum()
    }

    /// Whether [`Self::estimate`] has estimates to make or to check.
    pub fn estimates_missing(&self) -> bool {
        self.missing > 0 || !self.unchecked.is_empty()
    }

    /// Estimates the edges not estimated yet (paper 003, [`simplify::estimate_over_bands`])
    /// against `scene`, which must have the objects at the mesh's transforms, `chunk` edges
    /// at a time on the caller's pool, until all are or `stop` says to stop (asked before
    /// each chunk: `rooms`' 70,000 mesh edges take about a minute). First the estimates kept
    /// across moves are checked against the moved boxes, and those a move can have changed
    /// are dropped. What was estimated stays for the next call, also across moves that do
    /// not reach it. Returns how many were estimated.
    /// `progress` hears of each chunk done (its stage begun and ended by the caller, as the
    /// estimates may take several calls).
    pub fn estimate(&mut self, scene: &SceneLights, chunk: usize, stop: impl Fn() -> bool, progress: &dyn Progress) -> usize {
        self.check_estimates(scene);
        // Where the estimates are missing, in publishing order.
        let todo: Vec<((u32, u32), usize)> = self.by_receiver.iter().flat_map(|(k, r)| r.errors.iter().enumerate().filter(|(_, e)| e.is_none()).map(move |(i, _)| (*k, i))).collect();
        let mut n = 0;
        for at in todo.chunks(chunk.max(1)) {
            if stop() {
                break;
            }
            let jobs: Vec<Job> = at.iter().map(|(k, i)| self.by_receiver[k].edges[*i]).map(|e| (e.edge, self.scene_light[e.light as usize], e.blocker.0, e.blocker.1)).collect();
            let (errors, _) = simplify::estimate_over_bands(scene, &jobs, &self.rules, Estimate::FAST);
            for ((k, i), e) in at.iter().zip(errors) {
                if let Some(r) = self.by_receiver.get_mut(k) {
                    r.errors[*i] = Some(e);
                }
            }
            self.missing -= at.len();
            n += at.len();
            progress.advance(at.len() as u64);
        }
        n
    }

    /// How many edges have no estimate (or one to check against a move).
    pub fn estimates_to_make(&self) -> usize {
        self.missing
    }

    /// Every edge's identity with its estimate's bits, sorted (to compare two meshes'
    /// estimates: tests, the benchmark).
    pub fn keyed_estimates(&self) -> Vec<(EdgeKey, Option<u64>)> {
        let mut v: Vec<_> = self.by_receiver.values().flat_map(|r| r.edges.iter().zip(&r.errors)).map(|(e, x)| (edge_key(e), x.map(|x| x.error.to_bits()))).collect();
        v.sort_unstable();
        v
    }

    /// Forgets every estimate (to make them all afresh: tests, the benchmark).
    pub fn forget_estimates(&mut self) {
        self.by_receiver.values_mut().for_each(|r| r.errors.iter_mut().for_each(|e| *e = None));
        self.missing = self.edge_count();
    }

    /// Checks the estimates kept across moves against the moved boxes (against `scene` at
    /// the mesh's transforms), dropping those a move can have changed; returns how many
    /// were dropped. Fast (no face is walked): done before the edges after a move are
    /// published, so that they go out simplified.
    pub fn check_estimates(&mut self, scene: &SceneLights) -> usize {
        use rayon::prelude::*;
        if self.unchecked.is_empty() {
            return 0;
        }
        let boxes = std::mem::take(&mut self.unchecked);
        let mut receivers: Vec<&mut ReceiverEdges> = self.by_receiver.values_mut().collect();
        let dropped: usize = receivers
            .par_iter_mut()
            .map(|r| {
                let mut n = 0;
                for e in r.errors.iter_mut().filter(|e| e.is_some_and(|x| !scene.still_holds(&x, &boxes))) {
                    *e = None;
                    n += 1;
                }
                n
            })
            .sum();
        self.missing += dropped;
        dropped
    }

    /// Makes the shadow edges of `receivers` again (the others' are as they were), after
    /// `moved` moved if given. An edge made the same as before keeps its estimate, to be
    /// checked against the move ([`Self::estimate`]).
    fn refresh_edges(&mut self, receivers: &[(u32, u32)], moved: Option<&Moved>, progress: &dyn Progress) {
        let (mut counts, mut kept) = (MeshEdgeCounts::default(), 0);
        let by = &self.by_receiver;
        let own = moved.map(|m| m.old.object_tris(m.object));
        let old = |(l, t): (u32, u32)| by.get(&(l, t)).filter(|_| !own.as_ref().is_some_and(|o| o.contains(&t))).map(|e| &e.decisions);
        let made = receivers_shadow_edges(&self.mesh, &self.geometry, receivers, moved.map(|m| (m, &old as &OldDecisions<'_>)), &ProgressSteps::new(progress));
        for (r, e) in receivers.iter().zip(made) {
            counts = counts + e.counts;
            kept += e.kept;
            // The receiver's edges made the same as before keep their estimates.
            let before = self.by_receiver.remove(r);
            let known: HashMap<EdgeKey, Estimated> = before.iter().flat_map(|b| b.edges.iter().zip(&b.errors)).filter_map(|(e, x)| Some((edge_key(e), (*x)?))).collect();
            self.missing -= before.map_or(0, |b| b.errors.iter().filter(|x| x.is_none()).count());
            if !e.decisions.is_empty() {
                let errors: Vec<Option<Estimated>> = e.edges.iter().map(|x| known.get(&edge_key(x)).copied()).collect();
                self.missing += errors.iter().filter(|x| x.is_none()).count();
                self.by_receiver.insert(*r, ReceiverEdges { edges: e.edges, errors, decisions: e.decisions });
            }
        }
        tracing::debug!(receivers = receivers.len(), decisions_kept = kept, ?counts, "mesh shadow edges made");
    }
}

/// An edge's identity across a move: its light, receiver, kind, ends and blocker, bit for
/// bit.
pub type EdgeKey = (u32, u32, u8, [u32; 6], [u64; 6]);

fn edge_key(e: &MeshShadowEdge) -> EdgeKey {
    let [a, b] = [e.edge.a, e.edge.b].map(|p| p.to_array().map(f32::to_bits));
    let [c, d] = [e.blocker.0, e.blocker.1].map(|p| p.to_array().map(f64::to_bits));
    (e.light, e.edge.object, e.edge.kind as u8, [a[0], a[1], a[2], b[0], b[1], b[2]], [c[0], c[1], c[2], d[0], d[1], d[2]])
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Mutex;

    /// Every report, in order: (stage begun, its total) or units advanced or an end.
    #[derive(Default)]
    struct Recorded(Mutex<Vec<(String, u64)>>);

    impl Progress for Recorded {
        fn begin(&self, stage: &str, total: u64) {
            self.0.lock().unwrap().push((stage.to_string(), total));
        }
        fn advance(&self, units: u64) {
            self.0.lock().unwrap().push(("+".into(), units));
        }
        fn end(&self) {
            self.0.lock().unwrap().push(("end".into(), 0));
        }
    }

    /// The build reports its two stages, each begun with its total, advanced by no more
    /// than that and ended; the mesh is the one a computation that reports nothing makes.
    #[test]
    fn the_mesh_build_reports_its_receivers_and_their_edges() {
        let scene = edgepoint_scene::builtin::load("rooms").unwrap();
        let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let rec = Recorded::default();
        let m = MeshShadows::build(&scene, &t, &rec).expect("rooms has area lights");
        let quiet = DiscontinuityMesh::compute(&m.geometry, &m.grid, &m.mesh.lights);
        assert_eq!(crate::dmesh::update::mismatches(&m.mesh, &quiet), 0);
        let log = rec.0.into_inner().unwrap();
        let stages: Vec<(usize, &(String, u64))> = log.iter().enumerate().filter(|(_, (s, _))| s != "+" && s != "end").collect();
        let pairs = (m.mesh.lights.len() * m.geometry.tris.len()) as u64;
        let receivers = m.mesh.receiver_ids().len() as u64;
        assert_eq!(stages.iter().map(|(_, s)| (*s).clone()).collect::<Vec<_>>(), vec![("light-triangle pairs".to_string(), pairs), ("shadow edges of the receivers".to_string(), receivers)]);
        for (k, &(at, _)) in stages.iter().enumerate() {
            let until = stages.get(k + 1).map_or(log.len(), |s| s.0);
            let body = &log[at + 1..until];
            assert_eq!(body.last().map(|s| s.0.as_str()), Some("end"), "stage {k} ended");
            let advanced: u64 = body.iter().filter(|s| s.0 == "+").map(|s| s.1).sum();
            let total = stages[k].1 .1;
            // Whole steps only, the last part of a step left to the end.
            assert!(advanced <= total && total - advanced < crate::dmesh::PROGRESS_STEP, "stage {k}: {advanced} of {total}");
            assert!(body.iter().filter(|s| s.0 == "+").all(|s| s.1 == crate::dmesh::PROGRESS_STEP));
        }
    }
}
