//! A session's discontinuity mesh, kept on its shadow thread when the session takes its
//! area lights' shadow edges from the mesh (`--shadow-edges mesh`, issue 15 item 4): built
//! once for the objects where they are, updated incrementally for each object that moves
//! ([`crate::dmesh::update`], paper 002 §3–4), and turned into the EPI's shadow edges
//! ([`crate::edges::mesh_edges`]).
//!
//! With a simplification tolerance (paper 003) each mesh edge is estimated as the finder's
//! shadow edges are ([`crate::edges::simplify`]: the L2 error of leaving it out over a band
//! across it, against the irradiance of every light), once per state of the mesh, and only
//! the edges at or above the tolerance are published.
use crate::dmesh::geometry::Geometry;
use crate::dmesh::grid::Grid;
use crate::dmesh::{area_lights_indexed, DiscontinuityMesh, GRID_TRIANGLES_PER_VOXEL};
use crate::edges::mesh_edges::{receivers_shadow_edges, Decisions, MeshEdgeCounts, MeshShadowEdge, Moved, OldDecisions};
use crate::edges::shadow::daffine;
use crate::edges::simplify::{self, Estimate, Job, Rules, SceneLights};
use crate::edges::EdgeSegment;
use edgepoint_scene::Scene;
use glam::{Affine3A, Vec3};
use std::collections::BTreeMap;
use std::time::Instant;

pub struct MeshShadows {
    geometry: Geometry,
    grid: Grid,
    mesh: DiscontinuityMesh,
    transforms: Vec<Affine3A>,
    /// The scene light of each of the mesh's lights.
    scene_light: Vec<u32>,
    /// Each receiver's shadow edges (light, triangle; receivers with no arrangement edge
    /// left out), and what each of its arrangement edges gave: after a move only the
    /// receivers whose mesh changed make theirs again, keeping the decisions the moved
    /// object cannot have changed.
    by_receiver: BTreeMap<(u32, u32), (Vec<MeshShadowEdge>, Decisions)>,
    /// All of them in that order (lights × receivers × mesh edges), for the objects at
    /// `transforms`.
    edges: Vec<MeshShadowEdge>,
    /// The edges' estimates (paper 003), in order, as far as made: complete when there is
    /// one per edge.
    errors: Vec<f64>,
    rules: Rules,
}

impl MeshShadows {
    /// The mesh of `scene`'s area lights with its objects at `transforms`; `None` when the
    /// scene has no area light (nothing to mesh).
    pub fn build(scene: &Scene, transforms: &[Affine3A]) -> Option<MeshShadows> {
        let (scene_light, lights): (Vec<u32>, Vec<_>) = area_lights_indexed(scene).into_iter().unzip();
        if lights.is_empty() {
            return None;
        }
        let t = Instant::now();
        let geometry = Geometry::from_scene_at(scene, transforms);
        let grid = Grid::build(&geometry, GRID_TRIANGLES_PER_VOXEL);
        let mesh = DiscontinuityMesh::compute(&geometry, &grid, &lights);
        let mut m = MeshShadows { geometry, grid, mesh, transforms: transforms.to_vec(), scene_light, by_receiver: BTreeMap::new(), edges: Vec::new(), errors: Vec::new(), rules: Rules::new() };
        m.refresh_edges(&m.mesh.receiver_ids(), None);
        tracing::info!(
            lights = m.mesh.lights.len(),
            triangles = m.geometry.tris.len(),
            segments = m.mesh.segment_count(),
            faces = m.mesh.face_count(),
            shadow_edges = m.edges.len(),
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
            let before = std::mem::replace(&mut self.geometry, new);
            one = (moved == 0).then_some((before, o as u32, boxes));
            self.transforms[o] = *to;
            moved += 1;
        }
        if moved > 0 {
            changed.sort_unstable();
            changed.dedup();
            let mv = one.as_ref().map(|(old, object, boxes)| Moved { old, object: *object, boxes: *boxes });
            self.refresh_edges(&changed, mv.as_ref());
            tracing::debug!(objects = moved, receivers_changed = changed.len(), shadow_edges = self.edges.len(), ms = t.elapsed().as_secs_f64() * 1e3, "mesh shadow edges after a move");
        }
        moved > 0
    }

    /// Whether the mesh has the objects at `transforms`.
    pub fn at(&self, transforms: &[Affine3A]) -> bool {
        self.transforms == transforms
    }

    /// The edges that go to the EPI at simplification tolerance `tolerance` (0: every one),
    /// each with its penumbra, appended to `out`; returns how many were left out. Until
    /// [`Self::estimate`] has made every edge's estimate every one goes.
    pub fn published(&self, tolerance: f64, out: &mut Vec<(EdgeSegment, [Vec3; 2])>) -> usize {
        let all = self.edges.iter().map(|e| (e.edge, e.penumbra));
        if tolerance > 0.0 && !self.estimates_missing() {
            let with: Vec<_> = all.zip(self.errors.iter().copied()).collect();
            super::edge_source::chosen_shadow_edges(&with, tolerance, out)
        } else {
            out.extend(all);
            0
        }
    }

    /// Whether [`Self::estimate`] has estimates to make.
    pub fn estimates_missing(&self) -> bool {
        self.errors.len() < self.edges.len()
    }

    /// Estimates the edges not estimated yet (paper 003, [`simplify::estimate`]) against
    /// `scene`, which must have the objects at the mesh's transforms, `chunk` edges at a
    /// time on the caller's pool, until all are or `stop` says to stop (asked before each
    /// chunk: `rooms`' 70,000 mesh edges take about a minute, and an object moved meanwhile
    /// makes them all stale). What was estimated stays for the next call while the mesh does
    /// not change. Returns how many were estimated.
    pub fn estimate(&mut self, scene: &SceneLights, chunk: usize, stop: impl Fn() -> bool) -> usize {
        let mut n = 0;
        while self.estimates_missing() && !stop() {
            let from = self.errors.len();
            let to = (from + chunk.max(1)).min(self.edges.len());
            let jobs: Vec<Job> = self.edges[from..to].iter().map(|e| (e.edge, self.scene_light[e.light as usize], e.blocker.0, e.blocker.1)).collect();
            let (errors, _) = simplify::estimate(scene, &jobs, &self.rules, Estimate::FAST);
            self.errors.extend(errors);
            n += to - from;
        }
        n
    }

    /// Makes the shadow edges of `receivers` again (the others' are as they were), after
    /// `moved` moved if given, and forgets every estimate: a move can change the
    /// irradiance of any band.
    fn refresh_edges(&mut self, receivers: &[(u32, u32)], moved: Option<&Moved>) {
        self.errors.clear();
        let (mut counts, mut kept) = (MeshEdgeCounts::default(), 0);
        let by = &self.by_receiver;
        let own = moved.map(|m| m.old.object_tris(m.object));
        let old = |(l, t): (u32, u32)| by.get(&(l, t)).filter(|_| !own.as_ref().is_some_and(|o| o.contains(&t))).map(|e| &e.1);
        let made = receivers_shadow_edges(&self.mesh, &self.geometry, receivers, moved.map(|m| (m, &old as &OldDecisions<'_>)));
        for (r, e) in receivers.iter().zip(made) {
            counts = counts + e.counts;
            kept += e.kept;
            if e.decisions.is_empty() {
                self.by_receiver.remove(r);
            } else {
                self.by_receiver.insert(*r, (e.edges, e.decisions));
            }
        }
        self.edges.clear();
        self.edges.extend(self.by_receiver.values().flat_map(|e| e.0.iter().copied()));
        tracing::debug!(receivers = receivers.len(), decisions_kept = kept, ?counts, "mesh shadow edges made");
    }
}
