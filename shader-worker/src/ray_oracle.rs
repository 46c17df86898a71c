//! The brute-force oracle the BVH is checked against (its tests and `edgepoint-bench rays`):
//! every triangle of every instance, in f64. Slow by design; never on a shading path.
use edgepoint_scene::Mesh;
use glam::{Affine3A, DVec3, Vec3};

/// Möller–Trumbore in f64: the distance along `d` (in units of its length) at which the ray
/// from `o` meets triangle `abc`, if it does in front of `o`.
pub fn ray_triangle(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Option<f64> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-14 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t)
}

/// The smallest barycentric coordinate of `p` (in the triangle's plane) in triangle `abc`:
/// near 0 the point is on an edge, where f32 and f64 may pick different neighbours.
pub fn barycentric_margin(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let (e1, e2, r) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (r1, r2) = (r.dot(e1), r.dot(e2));
    let den = d11 * d22 - d12 * d12;
    let v = (d22 * r1 - d12 * r2) / den;
    let w = (d11 * r2 - d12 * r1) / den;
    v.min(w).min(1.0 - v - w)
}

/// The nearest hit with `tmin <= t <= tmax` over `meshes` placed by `transforms`:
/// (object, triangle, t, barycentric margin of the hit).
pub fn closest(meshes: &[&Mesh], transforms: &[Affine3A], o: Vec3, d: Vec3, tmin: f64, tmax: f64) -> Option<(u32, u32, f64, f64)> {
    let (od, dd) = (o.as_dvec3(), d.as_dvec3());
    let mut best: Option<(u32, u32, f64)> = None;
    for (oi, (mesh, tf)) in meshes.iter().zip(transforms).enumerate() {
        for f in 0..mesh.triangles.len() {
            let [a, b, c] = mesh.triangle(f).map(|v| tf.transform_point3(v).as_dvec3());
            if let Some(t) = ray_triangle(od, dd, a, b, c) {
                if t >= tmin && t <= tmax && best.is_none_or(|x| t < x.2) {
                    best = Some((oi as u32, f as u32, t));
                }
            }
        }
    }
    best.map(|(oi, f, t)| {
        let [a, b, c] = meshes[oi as usize].triangle(f as usize).map(|v| transforms[oi as usize].transform_point3(v).as_dvec3());
        (oi, f, t, barycentric_margin(od + dd * t, a, b, c))
    })
}

/// The world-space corners of triangle `f` of object `object`, in f64.
pub fn world_triangle(meshes: &[&Mesh], transforms: &[Affine3A], object: u32, f: u32) -> [DVec3; 3] {
    meshes[object as usize].triangle(f as usize).map(|v| transforms[object as usize].transform_point3(v).as_dvec3())
}
