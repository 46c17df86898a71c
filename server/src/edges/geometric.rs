//! The view-dependent discontinuities of one mesh from its edge trees (paper 000 §6.1
//! silhouettes, §6.2 forward-facing sharp edges, boundary edges), with exactly the answers
//! of the brute-force finder [`super::brute::mesh_edges`].
//!
//! Three structures, because one pruning rule cannot serve all three kinds:
//! - the silhouette tree over every interior edge (both normals non-zero) prunes subtrees
//!   whose faces all face the same way;
//! - sharp edges must be reported exactly where the silhouette tree prunes (every face
//!   facing the eye), so they get their own tree ([`SharpTree`]) over the edges sharp at the
//!   current cut-off, which prunes subtrees facing away and takes subtrees facing the eye
//!   whole. Edges are kept sorted by `n0 · n1`, so the sharp set of any cut-off is a prefix;
//!   the tree is rebuilt only when the cut-off changes the prefix. The cut-off is a session
//!   setting, so the sharp tree belongs to the querying session while everything else here
//!   is immutable once built and shared (between sessions, and with the shadow thread);
//! - boundary edges are discontinuities from everywhere: a plain list.
use super::brute::is_sharp;
use super::tree::{EdgeTree, TreeParams};
use super::EdgeKind;
use edgepoint_scene::{Mesh, NoProgress, Progress};
use glam::Vec3;
use rayon::prelude::*;

/// Edge trees and lists of one mesh (object space), immutable once built.
#[derive(Debug, Clone)]
pub struct MeshEdgeTrees {
    pub silhouette: EdgeTree,
    /// Interior edges with non-zero normals, sorted by `n0 · n1` (most folded first).
    by_fold: Vec<u32>,
    /// `n0 · n1` of `by_fold`, ascending.
    fold_dots: Vec<f32>,
    pub boundary: Vec<u32>,
    params: TreeParams,
}

/// The sharp-edge tree of one mesh at one cut-off: a tree over the first `count` edges of
/// the mesh's fold order ([`MeshEdgeTrees::prepare_sharp`] keeps it current).
#[derive(Debug, Clone, Default)]
pub struct SharpTree {
    count: usize,
    tree: EdgeTree,
}

impl SharpTree {
    /// Edges in the tree.
    pub fn edges(&self) -> usize {
        self.count
    }
}

/// Whether an interior edge can be a silhouette or sharp edge at all ([`super::brute::classify`]
/// rejects edges with a zero-area face).
pub fn is_tree_edge(e: &edgepoint_scene::Edge) -> bool {
    !e.is_boundary() && e.normals[0] != Vec3::ZERO && e.normals[1] != Vec3::ZERO
}

impl MeshEdgeTrees {
    /// Builds the silhouette tree (the long part: `progress` advances per edge) and the
    /// sharp-edge order.
    pub fn build(mesh: &Mesh, progress: &dyn Progress) -> MeshEdgeTrees {
        MeshEdgeTrees::build_with(mesh, TreeParams::for_bounds(mesh.bounds), progress)
    }

    pub fn build_with(mesh: &Mesh, params: TreeParams, progress: &dyn Progress) -> MeshEdgeTrees {
        let interior: Vec<u32> =
            (0..mesh.edges.len() as u32).into_par_iter().filter(|&i| is_tree_edge(&mesh.edges[i as usize])).collect();
        let boundary: Vec<u32> = (0..mesh.edges.len() as u32).filter(|&i| mesh.edges[i as usize].is_boundary()).collect();
        let silhouette = EdgeTree::build(mesh, &interior, params, progress);
        // Progress counts every edge of the mesh.
        progress.advance((mesh.edges.len() - interior.len()) as u64);
        let mut by_fold = interior;
        let dot = |i: u32| {
            let e = &mesh.edges[i as usize];
            e.normals[0].dot(e.normals[1])
        };
        by_fold.par_sort_unstable_by(|&a, &b| dot(a).total_cmp(&dot(b)).then(a.cmp(&b)));
        let fold_dots = by_fold.iter().map(|&i| dot(i)).collect();
        MeshEdgeTrees { silhouette, by_fold, fold_dots, boundary, params }
    }

    /// Number of edges sharp at `cos_cutoff` (the prefix of `by_fold` that
    /// [`super::brute::is_sharp`] accepts).
    fn sharp_count(&self, mesh: &Mesh, cos_cutoff: f32) -> usize {
        let k = self.fold_dots.partition_point(|&d| d <= cos_cutoff);
        debug_assert!(self.by_fold[..k].iter().all(|&i| is_sharp(&mesh.edges[i as usize], cos_cutoff)));
        k
    }

    /// Makes `sharp` the sharp-edge tree of this mesh at `cos_cutoff`; returns whether it
    /// was rebuilt.
    pub fn prepare_sharp(&self, mesh: &Mesh, cos_cutoff: f32, sharp: &mut SharpTree) -> bool {
        let k = self.sharp_count(mesh, cos_cutoff);
        if k == sharp.count {
            return false;
        }
        *sharp = SharpTree { count: k, tree: EdgeTree::build(mesh, &self.by_fold[..k], self.params, &NoProgress) };
        true
    }

    /// Appends (edge, kind) for every discontinuity edge seen from `eye` (object space),
    /// as [`super::brute::mesh_edges`] does, with `sharp` prepared
    /// ([`Self::prepare_sharp`]) for the cut-off wanted.
    pub fn query(&self, sharp: &SharpTree, eye: Vec3, out: &mut Vec<(u32, EdgeKind)>, scratch: &mut Vec<u32>) {
        scratch.clear();
        self.silhouette.silhouettes(eye, scratch);
        out.extend(scratch.iter().map(|&i| (i, EdgeKind::Silhouette)));
        scratch.clear();
        sharp.tree.both_facing(eye, scratch);
        out.extend(scratch.iter().map(|&i| (i, EdgeKind::Sharp)));
        out.extend(self.boundary.iter().map(|&i| (i, EdgeKind::Boundary)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edges::brute;
    use edgepoint_scene::NoProgress;

    /// An open, folded strip: boundary edges, sharp creases of several angles, flat edges.
    fn folded_strip() -> Mesh {
        let mut p = Vec::new();
        let mut t = Vec::new();
        let n = 24;
        for i in 0..=n {
            let x = i as f32 * 0.1;
            // A zig-zag in z with varying fold angles.
            let z = if i % 2 == 0 { 0.0 } else { 0.02 + 0.01 * (i % 7) as f32 };
            p.push(Vec3::new(x, 0.0, z));
            p.push(Vec3::new(x, 1.0, z * 0.5));
        }
        for i in 0..n as u32 {
            let (a, b, c, d) = (2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3);
            t.push([a, c, d]);
            t.push([a, d, b]);
        }
        Mesh::from_triangles(p, t, &NoProgress)
    }

    #[test]
    fn query_equals_brute_force_at_several_cutoffs() {
        let m = folded_strip();
        let trees = MeshEdgeTrees::build(&m, &NoProgress);
        let mut sharp = SharpTree::default();
        let mut scratch = Vec::new();
        for cutoff in [85.0f32, 30.0, 10.0, 2.0, 85.0] {
            let cos = cutoff.to_radians().cos();
            trees.prepare_sharp(&m, cos, &mut sharp);
            for k in 0..300 {
                let t = k as f32 * 0.7;
                let eye = Vec3::new(1.2 + 2.0 * t.cos(), 0.5 + (t * 0.3).sin(), 2.0 * t.sin());
                let mut want = Vec::new();
                brute::mesh_edges(&m, eye, cos, &mut want);
                let mut got = Vec::new();
                trees.query(&sharp, eye, &mut got, &mut scratch);
                want.sort_unstable();
                got.sort_unstable();
                assert_eq!(got, want, "cutoff {cutoff} eye {eye}");
            }
        }
        assert!(!trees.boundary.is_empty());
    }

    #[test]
    fn the_sharp_tree_is_rebuilt_only_when_the_cutoff_changes_the_set() {
        let m = folded_strip();
        let trees = MeshEdgeTrees::build(&m, &NoProgress);
        let mut sharp = SharpTree::default();
        assert!(trees.prepare_sharp(&m, 5f32.to_radians().cos(), &mut sharp));
        assert!(!trees.prepare_sharp(&m, 5.0001f32.to_radians().cos(), &mut sharp));
        assert!(trees.prepare_sharp(&m, 89f32.to_radians().cos(), &mut sharp));
        assert_eq!(sharp.edges(), 0);
    }
}
