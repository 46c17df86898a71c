//! A session's discontinuity mesh, kept on its shadow thread when the session takes its
//! area lights' shadow edges from the mesh (`--shadow-edges mesh`, issue 15 item 4): built
//! once for the objects where they are, updated incrementally for each object that moves
//! ([`crate::dmesh::update`], paper 002 §3–4), and turned into the EPI's shadow edges
//! ([`crate::edges::mesh_edges`]).
use crate::dmesh::geometry::Geometry;
use crate::dmesh::grid::Grid;
use crate::dmesh::{area_lights, DiscontinuityMesh, GRID_TRIANGLES_PER_VOXEL};
use crate::edges::mesh_edges::{mesh_shadow_edges, EdgeWithPenumbra};
use crate::edges::shadow::daffine;
use edgepoint_scene::Scene;
use glam::Affine3A;
use std::time::Instant;

pub struct MeshShadows {
    geometry: Geometry,
    grid: Grid,
    mesh: DiscontinuityMesh,
    transforms: Vec<Affine3A>,
    /// The mesh's shadow edges with their penumbrae, for the objects at `transforms`.
    pub edges: Vec<EdgeWithPenumbra>,
}

impl MeshShadows {
    /// The mesh of `scene`'s area lights with its objects at `transforms`; `None` when the
    /// scene has no area light (nothing to mesh).
    pub fn build(scene: &Scene, transforms: &[Affine3A]) -> Option<MeshShadows> {
        let lights = area_lights(scene);
        if lights.is_empty() {
            return None;
        }
        let t = Instant::now();
        let geometry = Geometry::from_scene_at(scene, transforms);
        let grid = Grid::build(&geometry, GRID_TRIANGLES_PER_VOXEL);
        let mesh = DiscontinuityMesh::compute(&geometry, &grid, &lights);
        let mut m = MeshShadows { geometry, grid, mesh, transforms: transforms.to_vec(), edges: Vec::new() };
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

    fn refresh_edges(&mut self) {
        self.edges.clear();
        let counts = mesh_shadow_edges(&self.mesh, &self.geometry, &mut self.edges);
        tracing::debug!(?counts, "mesh shadow edges");
    }
}
