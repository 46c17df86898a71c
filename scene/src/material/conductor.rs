//! A metal: GGX microfacet reflection with the conductor Fresnel term of a complex index of
//! refraction (pbrt-v4 §9.6 `ConductorBxDF`, Mitsuba 3 `conductor` / `roughconductor`);
//! a mirror (delta lobe) below [`SMOOTH_ALPHA`](super::microfacet::SMOOTH_ALPHA).
//! Microfacet multiple scattering is not modelled, so rough metals lose some energy.
use super::fresnel::{self, reflect};
use super::microfacet::Ggx;
use super::{BsdfSample, Scatter};
use glam::{Vec2, Vec3};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Conductor {
    pub eta: Vec3,
    pub k: Vec3,
    /// `None` for a smooth (mirror) surface.
    pub ggx: Option<Ggx>,
    /// Multiplies the Fresnel reflectance (the base colour).
    pub scale: Vec3,
}

/// A real index of refraction with the normal-incidence reflectance `f0` (k = 0), for
/// formats that give F0 instead of a complex index: `f0 = ((η-1)/(η+1))²`. The angular
/// falloff is a dielectric's, close to Schlick's curve for the F0 of common metals' tints.
pub fn eta_from_f0(f0: Vec3) -> Vec3 {
    let s = f0.clamp(Vec3::ZERO, Vec3::splat(0.999)).powf(0.5);
    (Vec3::ONE + s) / (Vec3::ONE - s)
}

impl Conductor {
    pub fn new(eta: Vec3, k: Vec3, alpha: f32, scale: Vec3) -> Conductor {
        Conductor {
            eta,
            k,
            ggx: (!Ggx::is_smooth(alpha)).then(|| Ggx::new(alpha)),
            scale,
        }
    }

    #[inline]
    fn fresnel(&self, cos: f32) -> Vec3 {
        self.scale * fresnel::conductor(cos, self.eta, self.k)
    }
}

impl Scatter for Conductor {
    fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        let Some(g) = self.ggx else { return Vec3::ZERO };
        if !(wo.z > 0.0 && wi.z > 0.0) {
            return Vec3::ZERO;
        }
        let h = wo + wi;
        if h.length_squared() == 0.0 {
            return Vec3::ZERO;
        }
        let h = h.normalize();
        self.fresnel(wo.dot(h)) * (g.d(h) * g.g(wo, wi) / (4.0 * wo.z * wi.z))
    }

    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        let Some(g) = self.ggx else { return 0.0 };
        if !(wo.z > 0.0 && wi.z > 0.0) {
            return 0.0;
        }
        let h = wo + wi;
        if h.length_squared() == 0.0 {
            return 0.0;
        }
        let h = h.normalize();
        g.visible_pdf(wo, h) / (4.0 * wo.dot(h).abs())
    }

    fn sample(&self, wo: Vec3, u: Vec3) -> Option<BsdfSample> {
        if !(wo.z > 0.0) {
            return None;
        }
        let Some(g) = self.ggx else {
            let wi = Vec3::new(-wo.x, -wo.y, wo.z);
            return Some(BsdfSample {
                wi,
                value: self.fresnel(wo.z) / wi.z,
                pdf: 1.0,
                delta: true,
            });
        };
        let h = g.sample_visible(wo, Vec2::new(u.y, u.z));
        let wi = reflect(wo, h);
        if !(wi.z > 0.0) {
            return None;
        }
        let pdf = g.visible_pdf(wo, h) / (4.0 * wo.dot(h).abs());
        if !(pdf > 0.0) {
            return None;
        }
        let value = self.fresnel(wo.dot(h)) * (g.d(h) * g.g(wo, wi) / (4.0 * wo.z * wi.z));
        Some(BsdfSample {
            wi,
            value,
            pdf,
            delta: false,
        })
    }

    fn has_delta(&self) -> bool {
        self.ggx.is_none()
    }
    fn has_non_delta(&self) -> bool {
        self.ggx.is_some()
    }
    fn diffuse_albedo(&self, _wo: Vec3) -> Vec3 {
        Vec3::ZERO
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eta_from_f0_reproduces_f0_at_normal_incidence() {
        for f0 in [Vec3::new(0.04, 0.5, 0.95), Vec3::new(1.0, 0.0, 0.2)] {
            let eta = eta_from_f0(f0);
            let f = fresnel::conductor(1.0, eta, Vec3::ZERO);
            // F0 = 1 is clamped to 0.999 (an infinite index is no use).
            assert!((f - f0.min(Vec3::splat(0.999))).abs().max_element() < 1e-4, "{f} vs {f0}");
            assert!(eta.is_finite());
        }
        // The model is Mitsuba's and pbrt's: grazing light is reflected whole.
        let m = Conductor::new(eta_from_f0(Vec3::splat(0.5)), Vec3::ZERO, 0.0, Vec3::ONE);
        assert!((m.fresnel(0.0) - Vec3::ONE).abs().max_element() < 1e-5);
    }
}
