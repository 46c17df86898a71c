//! Lambert's formula (paper 002 §1: "exact (analytical) irradiance values" from the
//! backprojection): the irradiance at a point from a uniformly emitting polygon, in closed
//! form. For radiance L, E = L/2 · Σ_i β_i · n · γ_i over the polygon's edges, β_i the angle
//! the edge subtends at the point and γ_i the unit normal of the plane through the point
//! and the edge. It is exact only for a polygon wholly above the point's tangent plane:
//! callers clip to that plane first ([`crate::backprojection`] does).
use glam::DVec3;

/// ∫ cos θ_x cos θ_y / r² dA over `poly` seen from `p` with unit normal `n`: the irradiance
/// per unit radiance (π times the form factor). `poly` winds counter-clockwise around the
/// normal that faces `p` (a light's own winding, seen from a point it lights); the other
/// winding gives the same magnitude negated, so the sum over pieces of one winding adds up.
pub fn polygon_irradiance(p: DVec3, n: DVec3, poly: &[DVec3]) -> f64 {
    let k = poly.len();
    let mut sum = 0.0;
    for i in 0..k {
        let a = (poly[i] - p).normalize_or_zero();
        let b = (poly[(i + 1) % k] - p).normalize_or_zero();
        let c = a.cross(b);
        let s = c.length();
        if s <= 0.0 {
            continue; // a zero-length edge, or one seen end on: it subtends no angle
        }
        // atan2 of (sin, cos) keeps full precision at small angles, where acos does not.
        let beta = s.atan2(a.dot(b));
        sum += beta * n.dot(c / s);
    }
    // Counter-clockwise around the normal facing p, each γ_i points away from n's side.
    -0.5 * sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// A square light of half-side a at height h, facing down, centred over the point:
    /// E/L = 2 · [a/√(a²+h²) · atan(a/√(a²+h²))] (the classic form factor of a square to a
    /// parallel differential area on its axis, times π).
    #[test]
    fn square_over_a_point_has_the_closed_form() {
        for (a, h) in [(0.5, 1.0), (1.0, 0.3), (2.0, 5.0)] {
            // Counter-clockwise about -y (the light faces down).
            let sq = [DVec3::new(-a, h, -a), DVec3::new(a, h, -a), DVec3::new(a, h, a), DVec3::new(-a, h, a)];
            let e = polygon_irradiance(DVec3::ZERO, DVec3::Y, &sq);
            let r = (a * a + h * h).sqrt();
            let want = 4.0 * (a / r) * (a / r).atan();
            assert!((e - want).abs() < 1e-12, "a {a} h {h}: {e} vs {want}");
            let mut rev = sq;
            rev.reverse();
            assert!((polygon_irradiance(DVec3::ZERO, DVec3::Y, &rev) + e).abs() < 1e-12, "the other winding negates");
        }
        // A huge square close by fills the hemisphere: E/L → π.
        let a = 1e4;
        let sq = [DVec3::new(-a, 1.0, -a), DVec3::new(a, 1.0, -a), DVec3::new(a, 1.0, a), DVec3::new(-a, 1.0, a)];
        assert!((polygon_irradiance(DVec3::ZERO, DVec3::Y, &sq) - PI).abs() < 1e-3);
    }

    /// A unit square in a plane perpendicular to the receiver's (x = d, facing the point),
    /// one edge on the receiver's plane: against the integral of cos θ_x cos θ_y / r² by the
    /// midpoint rule on a fine grid (smooth integrand: d > 0).
    #[test]
    fn perpendicular_rectangle_matches_a_numeric_integral() {
        let d = 0.7;
        // Rectangle in the plane x = d, y ∈ [0, 1], z ∈ [0, 1]; it faces -x (towards p).
        let rect = [DVec3::new(d, 0.0, 0.0), DVec3::new(d, 0.0, 1.0), DVec3::new(d, 1.0, 1.0), DVec3::new(d, 1.0, 0.0)];
        let nl = (rect[1] - rect[0]).cross(rect[2] - rect[1]).normalize();
        assert!(nl.x < 0.0, "wound about the normal that faces p");
        let e = polygon_irradiance(DVec3::ZERO, DVec3::Z, &rect);
        // Midpoint rule on a fine grid: cos_x = z/r, cos_l = d/r.
        let m = 2000;
        let mut num = 0.0;
        for i in 0..m {
            for j in 0..m {
                let (y, z) = ((i as f64 + 0.5) / m as f64, (j as f64 + 0.5) / m as f64);
                let r2 = d * d + y * y + z * z;
                num += z * d / (r2 * r2);
            }
        }
        num /= (m * m) as f64;
        assert!((e - num).abs() < 1e-6, "{e} vs {num}");
    }
}
