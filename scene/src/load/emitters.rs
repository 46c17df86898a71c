//! Emissive surfaces as area lights. [`crate::Light::Area`] is a planar convex polygon, and
//! a mesh light arrives as triangles (glTF, PLY, a Mitsuba shape), usually pairs that make
//! quads: each run of triangles is merged greedily with the next while the union stays one
//! planar convex polygon, so a quad lamp is one light (one set of shadow rays), not two.
use crate::Light;
use glam::Vec3;

/// Lights for a light's triangles in world space, `radiance` each. Degenerate triangles
/// are skipped; `what` names the source in warnings.
pub fn area_lights(what: &str, triangles: &[[Vec3; 3]], radiance: Vec3) -> Vec<Light> {
    let mut out = Vec::new();
    let mut cur: Vec<Vec3> = Vec::new();
    for t in triangles {
        if cur.is_empty() {
            cur = t.to_vec();
            continue;
        }
        match merged(&cur, t) {
            Some(m) => cur = m,
            None => out.push(std::mem::replace(&mut cur, t.to_vec())),
        }
    }
    if !cur.is_empty() {
        out.push(cur);
    }
    let mut lights = Vec::new();
    let mut bad = 0;
    for vertices in out {
        let l = Light::Area { vertices, radiance };
        match l.validate() {
            Ok(()) => lights.push(l),
            Err(_) => bad += 1,
        }
    }
    if bad > 0 {
        tracing::warn!("{what}: {bad} emissive face(s) are not usable area lights (zero area or not planar); they glow but cast no light");
    }
    lights
}

/// `poly` and triangle `t` as one convex planar polygon, when `t` shares an edge of `poly`
/// (in the opposite direction, i.e. the same winding), lies in its plane and the union is
/// convex.
fn merged(poly: &[Vec3], t: &[Vec3; 3]) -> Option<Vec<Vec3>> {
    let n = crate::light::polygon_normal(poly);
    let nt = (t[1] - t[0]).cross(t[2] - t[0]);
    if n.length() == 0.0 || nt.length() == 0.0 || n.normalize().dot(nt.normalize()) < 1.0 - 1e-5 {
        return None;
    }
    let size = poly.iter().map(|p| (*p - poly[0]).length()).fold(0.0f32, f32::max).max(1e-12);
    let nn = n.normalize();
    if t.iter().any(|p| (*p - poly[0]).dot(nn).abs() > 1e-5 * size) {
        return None;
    }
    let k = poly.len();
    for i in 0..k {
        let (a, b) = (poly[i], poly[(i + 1) % k]);
        for j in 0..3 {
            // The triangle runs the shared edge b → a; its third corner goes between a and b.
            if t[j] == b && t[(j + 1) % 3] == a {
                let c = t[(j + 2) % 3];
                let mut out = poly.to_vec();
                out.insert(i + 1, c);
                return convex(&out, nn).then_some(out);
            }
        }
    }
    None
}

fn convex(v: &[Vec3], n: Vec3) -> bool {
    let k = v.len();
    (0..k).all(|i| (v[(i + 1) % k] - v[i]).cross(v[(i + 2) % k] - v[(i + 1) % k]).dot(n) > 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_quad_as_two_triangles_is_one_light() {
        let q = [Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 1.0, 1.0), Vec3::new(1.0, 1.0, 1.0), Vec3::new(1.0, 1.0, 0.0)];
        let l = area_lights("lamp", &[[q[0], q[1], q[2]], [q[0], q[2], q[3]]], Vec3::ONE);
        assert_eq!(l.len(), 1);
        let Light::Area { vertices, .. } = &l[0] else { unreachable!() };
        assert_eq!(vertices.len(), 4);
        assert!((l[0].area() - 1.0).abs() < 1e-6);
        // Two triangles that are not coplanar stay two lights; a zero-area one is dropped.
        let bent = [[q[0], q[1], q[2]], [q[0], q[2], Vec3::new(1.0, 2.0, 0.0)], [q[0], q[0], q[1]]];
        let l = area_lights("bent", &bent, Vec3::ONE);
        assert_eq!(l.len(), 2);
        // An L of three triangles: the third would make the union concave, so it starts
        // a new light; the total area is kept.
        let p = |x: f32, z: f32| Vec3::new(x, 0.0, z);
        let tris = [[p(0.0, 0.0), p(0.0, 1.0), p(1.0, 1.0)], [p(0.0, 0.0), p(1.0, 1.0), p(1.0, 0.0)], [p(1.0, 0.0), p(1.0, 1.0), p(2.0, 1.0)]];
        let l = area_lights("L", &tris, Vec3::ONE);
        let area: f32 = l.iter().map(|l| l.area()).sum();
        assert!((area - 1.5).abs() < 1e-6, "{area}");
        for x in &l {
            x.validate().unwrap();
        }
    }
}
