//! Brute-force discontinuity finding: every edge of every mesh is tested (paper 000 §6.1
//! Equation 1, §6.2 sharp edges, boundary edges). O(edges) per query; this is the oracle for
//! the edge trees of §6.4 and must stay obviously correct, so it is written for clarity.
//!
//! The facing predicates ([`face_side`], [`classify`]) are shared with the edge trees: the
//! trees prune with interval bounds but decide every edge they reach with these same
//! functions, so the two finders agree exactly, bit for bit.
use super::{EdgeKind, EdgeSegment};
use edgepoint_scene::{Edge, Mesh, Scene};
use glam::{Affine3A, Vec3};

/// Whether the plane of a face with unit normal `n` through `p` faces `eye`: the sign of
/// `N_f · V_f` in Equation 1, with `V_f = eye - p` for a vertex `p` of the face. Exactly zero
/// (the eye in the face's plane) counts as facing away.
#[inline]
pub fn face_side(n: Vec3, p: Vec3, eye: Vec3) -> bool {
    n.dot(eye - p) > 0.0
}

/// Sharp-edge test of §6.2 on unit face normals: the angle between them is at least the
/// cut-off, i.e. `n0 · n1 <= cos(cutoff)`.
#[inline]
pub fn is_sharp(e: &Edge, cos_cutoff: f32) -> bool {
    !e.is_boundary() && e.normals[0].dot(e.normals[1]) <= cos_cutoff
}

/// The kind of discontinuity edge `e` of `mesh` is for a viewer at `eye` (object space), or
/// `None`. Boundary edges are discontinuities whatever their facing; silhouettes follow
/// Equation 1 evaluated at the edge's first vertex (common to both faces, so `V_f0` and
/// `V_f1` are measured from the same point); sharp edges are reported when both faces face
/// the eye. Faces with a zero normal (zero area) face nowhere and make no silhouette.
#[inline]
pub fn classify(mesh: &Mesh, e: &Edge, eye: Vec3, cos_cutoff: f32) -> Option<EdgeKind> {
    if e.is_boundary() {
        return Some(EdgeKind::Boundary);
    }
    let p = mesh.positions[e.v[0] as usize];
    let (n0, n1) = (e.normals[0], e.normals[1]);
    if n0 == Vec3::ZERO || n1 == Vec3::ZERO {
        return None;
    }
    let (s0, s1) = (face_side(n0, p, eye), face_side(n1, p, eye));
    if s0 != s1 {
        Some(EdgeKind::Silhouette)
    } else if s0 && is_sharp(e, cos_cutoff) {
        Some(EdgeKind::Sharp)
    } else {
        None
    }
}

/// Appends (edge index, kind) for every discontinuity edge of `mesh` seen from `eye`
/// (object space).
pub fn mesh_edges(mesh: &Mesh, eye: Vec3, cos_cutoff: f32, out: &mut Vec<(u32, EdgeKind)>) {
    for (i, e) in mesh.edges.iter().enumerate() {
        if let Some(k) = classify(mesh, e, eye, cos_cutoff) {
            out.push((i as u32, k));
        }
    }
}

/// Silhouette edges only (the test the point-light shadow events reuse: §6.4 "for point
/// lights, shadow events are essentially silhouette computations from the light's point of
/// view").
pub fn mesh_silhouettes(mesh: &Mesh, eye: Vec3, out: &mut Vec<u32>) {
    for (i, e) in mesh.edges.iter().enumerate() {
        if !e.is_boundary() && classify(mesh, e, eye, -2.0) == Some(EdgeKind::Silhouette) {
            out.push(i as u32);
        }
    }
}

/// Every geometric discontinuity of the scene seen from world-space `eye`, as world-space
/// segments. `transforms[i]` is object `i`'s current object-to-world transform (objects
/// without one use their default). Each object is queried in its own space.
pub fn scene_edges(scene: &Scene, transforms: &[Affine3A], eye: Vec3, sharp_cutoff_degrees: f32, out: &mut Vec<EdgeSegment>) {
    let cos_cutoff = sharp_cutoff_degrees.to_radians().cos();
    let mut found = Vec::new();
    for (id, obj) in scene.objects.iter().enumerate() {
        let to_world = transforms.get(id).copied().unwrap_or(obj.transform);
        let eye_obj = to_world.inverse().transform_point3(eye);
        found.clear();
        mesh_edges(&obj.mesh, eye_obj, cos_cutoff, &mut found);
        for &(i, kind) in &found {
            let e = &obj.mesh.edges[i as usize];
            out.push(EdgeSegment {
                a: to_world.transform_point3(obj.mesh.positions[e.v[0] as usize]),
                b: to_world.transform_point3(obj.mesh.positions[e.v[1] as usize]),
                kind,
                object: id as u32,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_scene::NoProgress;

    /// Unit cube [0,1]^3, wound outward.
    fn cube() -> Mesh {
        let c = |i: u32| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32);
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let p: Vec<Vec3> = (0..8).map(c).collect();
        let t = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        Mesh::from_triangles(p, t, &NoProgress)
    }

    fn kinds(mesh: &Mesh, eye: Vec3) -> (usize, usize, usize) {
        let mut out = Vec::new();
        mesh_edges(mesh, eye, 85f32.to_radians().cos(), &mut out);
        let n = |k| out.iter().filter(|(_, kk)| *kk == k).count();
        (n(EdgeKind::Silhouette), n(EdgeKind::Sharp), n(EdgeKind::Boundary))
    }

    #[test]
    fn cube_seen_face_on_corner_on_and_edge_on() {
        let m = cube();
        // Face-on from +z: the 4 edges of the front face are silhouettes (front face vs the
        // four side faces seen edge-on count as facing away), nothing else.
        assert_eq!(kinds(&m, Vec3::new(0.5, 0.5, 5.0)), (4, 0, 0));
        // From a corner direction: 3 faces visible, their 3 shared edges are sharp, the 6
        // outline edges are silhouettes.
        assert_eq!(kinds(&m, Vec3::splat(5.0)), (6, 3, 0));
        // Two faces visible (eye over an edge): 1 sharp edge between them, 6 outline edges.
        assert_eq!(kinds(&m, Vec3::new(5.0, 0.5, 5.0)), (6, 1, 0));
        // Inside the cube: every face faces away, nothing.
        assert_eq!(kinds(&m, Vec3::splat(0.5)), (0, 0, 0));
    }

    #[test]
    fn a_lone_quad_has_four_boundary_edges_from_either_side() {
        let q = Mesh::from_triangles(
            vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
            vec![[0, 1, 2], [0, 2, 3]],
            &NoProgress,
        );
        assert_eq!(kinds(&q, Vec3::new(0.3, 0.3, 2.0)), (0, 0, 4));
        assert_eq!(kinds(&q, Vec3::new(0.3, 0.3, -2.0)), (0, 0, 4));
    }

    #[test]
    fn scene_edges_follow_the_object_transform() {
        let mut scene = edgepoint_scene::builtin::load("cornell-point").unwrap();
        let tall = scene.object_id("tallbox").unwrap() as usize;
        scene.objects.truncate(tall + 1);
        let eye = scene.camera.eye;
        let mut before = Vec::new();
        let ids: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        scene_edges(&scene, &ids, eye, 85.0, &mut before);
        // Move the tall box and the eye by the same translation: same edges, shifted.
        let d = Vec3::new(0.3, 0.0, -0.2);
        let moved: Vec<Affine3A> = ids.iter().map(|t| Affine3A::from_translation(d) * *t).collect();
        let mut after = Vec::new();
        scene_edges(&scene, &moved, eye + d, 85.0, &mut after);
        assert_eq!(before.len(), after.len());
        for (x, y) in before.iter().zip(&after) {
            assert_eq!((x.kind, x.object), (y.kind, y.object));
            assert!((x.a + d).abs_diff_eq(y.a, 1e-5) && (x.b + d).abs_diff_eq(y.b, 1e-5));
        }
        assert!(before.iter().any(|s| s.object == tall as u32 && s.kind == EdgeKind::Silhouette));
    }
}
