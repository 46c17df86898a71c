//! Plastic: a Lambertian base under a dielectric coat, after Mitsuba 3's `plastic` (the
//! smooth coat) with its linear internal-reflection term (`nonlinear = false`, Mitsuba's
//! default):
//!
//! f_diffuse(wo, wi) = ρ / (1 − F̄_int) · (1 − F(θi)) (1 − F(θo)) / (η² π),
//!
//! where F is the coat's Fresnel reflectance and F̄_int the diffuse Fresnel reflectance of
//! its inside (light the base scatters back up that the coat reflects down again, summed
//! over bounces with the base's albedo taken as 1: the texture colour is kept, as
//! Mitsuba's default does). Its cosine-weighted albedo is exactly (1 − F(θo)) ρ, because
//! (1 − F̄_ext) / η² = 1 − F̄_int.
//!
//! The coat reflects with a delta lobe (smooth) or a GGX microfacet lobe (rough, as the
//! rough conductor with a dielectric Fresnel). For the rough coat the transmission through
//! it is still the smooth 1 − F(θ) of the macro-normal — an approximation; Mitsuba 3's
//! `roughplastic` uses a tabulated rough-dielectric transmittance instead (not done here).
//!
//! Sampling picks the coat with probability ∝ F(θo) · w and the base ∝ (1 − F(θo)) (1 − w),
//! w = 1 / (1 + mean ρ) (Mitsuba's specular sampling weight).
use super::fresnel::{self, reflect};
use super::microfacet::Ggx;
use super::warp::{cosine_hemisphere_pdf, square_to_cosine_hemisphere};
use super::{BsdfSample, Scatter};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plastic {
    pub eta: f32,
    /// `None` for a smooth coat.
    pub ggx: Option<Ggx>,
    pub albedo: Vec3,
    /// ρ / (1 − F̄_int) / η² / π: the diffuse value before the two transmittances.
    diffuse_scale: Vec3,
    specular_weight: f32,
}

impl Plastic {
    pub fn new(ior: f32, alpha: f32, albedo: Vec3) -> Plastic {
        let eta = ior.max(1e-3);
        let fdr_int = fresnel::diffuse_reflectance(1.0 / eta);
        let diffuse_scale = albedo * (FRAC_1_PI / ((1.0 - fdr_int) * eta * eta));
        let mean = (albedo.x + albedo.y + albedo.z) / 3.0;
        Plastic {
            eta,
            ggx: (!Ggx::is_smooth(alpha)).then(|| Ggx::new(alpha)),
            albedo,
            diffuse_scale,
            specular_weight: 1.0 / (1.0 + mean.max(0.0)),
        }
    }

    /// Probability of sampling the coat for `wo` (given its Fresnel reflectance).
    #[inline]
    fn prob_coat(&self, f_o: f32) -> f32 {
        let s = f_o * self.specular_weight;
        let d = (1.0 - f_o) * (1.0 - self.specular_weight);
        if s + d > 0.0 {
            s / (s + d)
        } else {
            1.0
        }
    }

    #[inline]
    fn diffuse(&self, f_o: f32, wi: Vec3) -> Vec3 {
        self.diffuse_scale * ((1.0 - f_o) * (1.0 - fresnel::dielectric(wi.z, self.eta)))
    }

    /// The rough coat's value and its sampling density (not yet times its probability).
    #[inline]
    fn coat(&self, g: &Ggx, wo: Vec3, wi: Vec3) -> (f32, f32) {
        let h = wo + wi;
        if h.length_squared() == 0.0 {
            return (0.0, 0.0);
        }
        let h = h.normalize();
        let f =
            fresnel::dielectric(wo.dot(h), self.eta) * g.d(h) * g.g(wo, wi) / (4.0 * wo.z * wi.z);
        (f, g.visible_pdf(wo, h) / (4.0 * wo.dot(h).abs()))
    }
}

impl Scatter for Plastic {
    fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if !(wo.z > 0.0 && wi.z > 0.0) {
            return Vec3::ZERO;
        }
        let f_o = fresnel::dielectric(wo.z, self.eta);
        let d = self.diffuse(f_o, wi);
        match &self.ggx {
            Some(g) => d + Vec3::splat(self.coat(g, wo, wi).0),
            None => d,
        }
    }

    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if !(wo.z > 0.0 && wi.z > 0.0) {
            return 0.0;
        }
        let p = self.prob_coat(fresnel::dielectric(wo.z, self.eta));
        let d = (1.0 - p) * cosine_hemisphere_pdf(wi);
        match &self.ggx {
            Some(g) => d + p * self.coat(g, wo, wi).1,
            None => d,
        }
    }

    fn sample(&self, wo: Vec3, u: Vec3) -> Option<BsdfSample> {
        if !(wo.z > 0.0) {
            return None;
        }
        let f_o = fresnel::dielectric(wo.z, self.eta);
        let p = self.prob_coat(f_o);
        let uv = Vec2::new(u.y, u.z);
        let wi = if u.x < p {
            let Some(g) = self.ggx else {
                let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                return Some(BsdfSample {
                    wi,
                    value: Vec3::splat(f_o / wi.z),
                    pdf: p,
                    delta: true,
                });
            };
            let wi = reflect(wo, g.sample_visible(wo, uv));
            if !(wi.z > 0.0) {
                return None;
            }
            wi
        } else {
            square_to_cosine_hemisphere(uv)
        };
        let pdf = self.pdf(wo, wi);
        (pdf > 0.0).then(|| BsdfSample {
            wi,
            value: self.eval(wo, wi),
            pdf,
            delta: false,
        })
    }

    fn has_delta(&self) -> bool {
        self.ggx.is_none()
    }
    fn has_non_delta(&self) -> bool {
        true
    }
    fn diffuse_albedo(&self, wo: Vec3) -> Vec3 {
        if wo.z > 0.0 {
            self.albedo * (1.0 - fresnel::dielectric(wo.z, self.eta))
        } else {
            Vec3::ZERO
        }
    }
}
