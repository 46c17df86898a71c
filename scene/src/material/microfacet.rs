//! The isotropic GGX (Trowbridge–Reitz) microfacet distribution with Smith's
//! height-correlated masking–shadowing, and sampling of the normals visible from a
//! direction (Heitz 2018, "Sampling the GGX Distribution of Visible Normals"; pbrt-v4 §9.6).
//! Directions are local (macro-normal = +z).
use super::warp::square_to_disk_polar;
use glam::{Vec2, Vec3};
use std::f32::consts::PI;

/// Below this alpha a lobe is treated as perfectly smooth (a delta): the distribution is
/// then too peaked for f32 (pbrt-v4 uses the same threshold).
pub const SMOOTH_ALPHA: f32 = 1e-3;

/// GGX with roughness `alpha` (the slope-space standard deviation's scale, not perceptual
/// roughness).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ggx {
    pub alpha: f32,
}

impl Ggx {
    #[inline]
    pub fn new(alpha: f32) -> Ggx {
        Ggx {
            alpha: alpha.max(SMOOTH_ALPHA),
        }
    }

    /// True for roughness too small to evaluate: such lobes are deltas.
    #[inline]
    pub fn is_smooth(alpha: f32) -> bool {
        !(alpha >= SMOOTH_ALPHA)
    }

    /// Microfacet normal density D(m) (per unit solid angle of m, projected: ∫ D cos = 1).
    #[inline]
    pub fn d(&self, m: Vec3) -> f32 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let a2 = self.alpha * self.alpha;
        let t = m.z * m.z * (a2 - 1.0) + 1.0;
        a2 / (PI * t * t)
    }

    /// Smith's Λ(w) for GGX; infinite at grazing.
    #[inline]
    pub fn lambda(&self, w: Vec3) -> f32 {
        let c2 = w.z * w.z;
        if c2 == 0.0 {
            return f32::INFINITY;
        }
        let s2 = (1.0 - c2).max(0.0);
        let a2 = self.alpha * self.alpha;
        0.5 * (((c2 + a2 * s2) / c2).sqrt() - 1.0)
    }

    /// Masking of direction `w` alone.
    #[inline]
    pub fn g1(&self, w: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(w))
    }

    /// Height-correlated masking–shadowing of the pair.
    #[inline]
    pub fn g(&self, wo: Vec3, wi: Vec3) -> f32 {
        1.0 / (1.0 + self.lambda(wo) + self.lambda(wi))
    }

    /// Density of the normals visible from `w` (Heitz's D_w(m)): G1(w) max(0, w·m) D(m) /
    /// cos θw, with `w` mirrored to the upper side when it is below (as the sampler does).
    /// It is the density [`Ggx::sample_visible`] draws `m` with.
    #[inline]
    pub fn visible_pdf(&self, w: Vec3, m: Vec3) -> f32 {
        let c = w.z.abs();
        let wm = w.dot(m) * 1f32.copysign(w.z);
        if c == 0.0 || wm <= 0.0 {
            return 0.0;
        }
        self.g1(w) * wm * self.d(m) / c
    }

    /// Draws a microfacet normal (upper hemisphere) visible from `w` (either side) with
    /// density [`Ggx::visible_pdf`]: stretch `w` to the unit-roughness configuration, sample
    /// the projected hemisphere there, unstretch.
    #[inline]
    pub fn sample_visible(&self, w: Vec3, u: Vec2) -> Vec3 {
        let mut wh = Vec3::new(self.alpha * w.x, self.alpha * w.y, w.z).normalize();
        if wh.z < 0.0 {
            wh = -wh;
        }
        let t1 = if wh.z < 0.99999 {
            Vec3::Z.cross(wh).normalize()
        } else {
            Vec3::X
        };
        let t2 = wh.cross(t1);
        let mut p = square_to_disk_polar(u);
        // Warp the disk so its lower half shrinks to the part of the hemisphere visible
        // from wh (the projected area of the truncated hemisphere).
        let h = (1.0 - p.x * p.x).max(0.0).sqrt();
        let s = 0.5 * (1.0 + wh.z);
        p.y = (1.0 - s) * h + s * p.y;
        let pz = (1.0 - p.length_squared()).max(0.0).sqrt();
        let nh = t1 * p.x + t2 * p.y + wh * pz;
        Vec3::new(self.alpha * nh.x, self.alpha * nh.y, nh.z.max(1e-6)).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sphere_integral(f: impl Fn(Vec3) -> f64, n: usize) -> f64 {
        // Midpoint rule in (cos θ, φ): equal-area cells.
        let mut s = 0.0;
        for i in 0..n {
            let z = -1.0 + 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            for j in 0..2 * n {
                let phi = std::f64::consts::PI * (j as f64 + 0.5) / n as f64;
                s += f(Vec3::new(
                    (r * phi.cos()) as f32,
                    (r * phi.sin()) as f32,
                    z as f32,
                ));
            }
        }
        s * 4.0 * std::f64::consts::PI / (2 * n * n) as f64
    }

    #[test]
    fn projected_normal_density_and_visible_density_integrate_to_one() {
        for alpha in [0.1f32, 0.3, 0.7, 1.0] {
            let g = Ggx::new(alpha);
            let proj = sphere_integral(|m| (g.d(m) * m.z.max(0.0)) as f64, 1200);
            assert!((proj - 1.0).abs() < 0.01, "alpha {alpha}: ∫ D cos = {proj}");
            for wz in [0.9f32, 0.4, 0.05, -0.6] {
                let w = Vec3::new((1.0 - wz * wz).sqrt(), 0.0, wz);
                let vis = sphere_integral(|m| g.visible_pdf(w, m) as f64, 1200);
                assert!(
                    (vis - 1.0).abs() < 0.01,
                    "alpha {alpha} w {w}: ∫ D_w = {vis}"
                );
            }
        }
    }

    #[test]
    fn smith_g1_is_the_projected_area_ratio() {
        // ∫ max(0, w·m) D(m) dm = cos θw / G1(w): the microfacets' projected area toward w.
        let g = Ggx::new(0.5);
        for wz in [0.95f32, 0.5, 0.1] {
            let w = Vec3::new((1.0 - wz * wz).sqrt(), 0.0, wz);
            let proj = sphere_integral(|m| (w.dot(m).max(0.0) * g.d(m)) as f64, 1200);
            assert!(
                (proj - (wz / g.g1(w)) as f64).abs() < 0.005 * wz as f64,
                "{wz}: {proj}"
            );
        }
    }
}
