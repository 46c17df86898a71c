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
use crate::edges::mesh_edges::{mesh_shadow_edges, MeshShadowEdge};
use crate::edges::shadow::daffine;
use crate::edges::simplify::{self, Estimate, Job, Rules, SceneLights};
use crate::edges::EdgeSegment;
use edgepoint_scene::Scene;
use glam::{Affine3A, Vec3};
use std::time::Instant;

pub struct MeshShadows {
    geometry: Geometry,
    grid: Grid,
    mesh: DiscontinuityMesh,
    transforms: Vec<Affine3A>,
    /// The scene light of each of the mesh's lights.
    scene_light: Vec<u32>,
    /// The mesh's shadow edges with their penumbrae, for the objects at `transforms`.
    edges: Vec<MeshShadowEdge>,
    /// Each edge's estimate (paper 003), once made for these edges.
    errors: Option<Vec<f64>>,
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
        let mut m = MeshShadows { geometry, grid, mesh, transforms: transforms.to_vec(), scene_light, edges: Vec::new(), errors: None, rules: Rules::new() };
        m.refresh_edges();
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
        for (o, to) in transforms.iter().enumerate().take(self.transforms.len()) {
            if self.transforms[o] == *to {
                continue;
            }
            // The change of place in f64 (as the cache carries its points, `move_object`).
            let d = daffine(to) * daffine(&self.transforms[o]).inverse();
            let new = self.geometry.moved(o as u32, |p| d.transform_point3(p));
            let stats = self.mesh.move_object(&self.geometry, &new, &mut self.grid, o as u32);
            tracing::debug!(object = o, ?stats, "discontinuity mesh updated");
            self.geometry = new;
            self.transforms[o] = *to;
            moved += 1;
        }
        if moved > 0 {
            self.refresh_edges();
            tracing::debug!(objects = moved, shadow_edges = self.edges.len(), ms = t.elapsed().as_secs_f64() * 1e3, "mesh shadow edges after a move");
        }
        moved > 0
    }

    /// Whether the mesh has the objects at `transforms`.
    pub fn at(&self, transforms: &[Affine3A]) -> bool {
        self.transforms == transforms
    }

    /// The edges that go to the EPI at simplification tolerance `tolerance` (0: every one),
    /// each with its penumbra, appended to `out`; returns how many were left out. Until
    /// [`Self::estimate`] has run for these edges every one goes.
    pub fn published(&self, tolerance: f64, out: &mut Vec<(EdgeSegment, [Vec3; 2])>) -> usize {
        let all = self.edges.iter().map(|e| (e.edge, e.penumbra));
        match &self.errors {
            Some(errors) if tolerance > 0.0 => {
                let with: Vec<_> = all.zip(errors.iter().copied()).collect();
                super::edge_source::chosen_shadow_edges(&with, tolerance, out)
            }
            _ => {
                out.extend(all);
                0
            }
        }
    }

    /// Whether [`Self::estimate`] has estimates to make.
    pub fn estimates_missing(&self) -> bool {
        self.errors.is_none() && !self.edges.is_empty()
    }

    /// Estimates every edge (paper 003, [`simplify::estimate`]) against `scene`, which must
    /// have the objects at the mesh's transforms, unless done for these edges already; on
    /// the caller's pool. Returns how many were estimated.
    pub fn estimate(&mut self, scene: &SceneLights) -> usize {
        if !self.estimates_missing() {
            return 0;
        }
        let jobs: Vec<Job> = self.edges.iter().map(|e| (e.edge, self.scene_light[e.light as usize], e.blocker.0, e.blocker.1)).collect();
        let (errors, _) = simplify::estimate(scene, &jobs, &self.rules, Estimate::default());
        self.errors = Some(errors);
        jobs.len()
    }

    fn refresh_edges(&mut self) {
        self.errors = None;
        self.edges.clear();
        let counts = mesh_shadow_edges(&self.mesh, &self.geometry, &mut self.edges);
        tracing::debug!(?counts, "mesh shadow edges");
    }
}
