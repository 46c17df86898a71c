//! Small exact geometry on triangles and boxes shared by the renderer (picking, world
//! boxes of moved objects), the workers and the tests that check geometry against brute
//! force.
use glam::Vec3;

/// Möller–Trumbore: the ray parameter `t > 0` where `o + t d` meets triangle (a, b, c),
/// either side; `d` need not be normalised (t is then in units of `d`).
#[inline]
pub fn ray_triangle(o: Vec3, d: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Option<f32> {
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-20 {
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

/// The point of triangle (a, b, c) closest to `p` (by regions, Ericson, Real-Time Collision
/// Detection, 5.1.5).
pub fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let den = 1.0 / (va + vb + vc);
    a + ab * (vb * den) + ac * (vc * den)
}

/// The eight corners of the box [`lo`, `hi`] (bit 0 of the index picks x, bit 1 y, bit 2 z).
pub fn box_corners((lo, hi): (Vec3, Vec3)) -> [Vec3; 8] {
    std::array::from_fn(|i| {
        Vec3::new(if i & 1 == 0 { lo.x } else { hi.x }, if i & 2 == 0 { lo.y } else { hi.y }, if i & 4 == 0 { lo.z } else { hi.z })
    })
}

/// The axis-aligned box around the box `b` transformed by `t` (an object's world box).
pub fn transformed_box(t: &glam::Affine3A, b: (Vec3, Vec3)) -> (Vec3, Vec3) {
    box_corners(b).iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), c| {
        let w = t.transform_point3(*c);
        (lo.min(w), hi.max(w))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn against_closed_forms_on_the_unit_triangle() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        assert_eq!(ray_triangle(Vec3::new(0.25, 0.25, 2.0), Vec3::new(0.0, 0.0, -2.0), a, b, c), Some(1.0));
        assert_eq!(ray_triangle(Vec3::new(0.25, 0.25, -1.0), Vec3::Z, a, b, c), Some(1.0), "back side too");
        assert_eq!(ray_triangle(Vec3::new(0.8, 0.8, 1.0), -Vec3::Z, a, b, c), None, "outside the edge");
        assert_eq!(ray_triangle(Vec3::new(0.25, 0.25, 1.0), Vec3::Z, a, b, c), None, "behind the origin");
        assert_eq!(closest_on_triangle(Vec3::new(0.2, 0.3, 5.0), a, b, c), Vec3::new(0.2, 0.3, 0.0));
        assert_eq!(closest_on_triangle(Vec3::new(-1.0, -1.0, 0.0), a, b, c), a);
        assert_eq!(closest_on_triangle(Vec3::new(2.0, -0.5, 0.0), a, b, c), b);
        assert!((closest_on_triangle(Vec3::new(1.0, 1.0, 0.0), a, b, c) - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-6);
    }
}
