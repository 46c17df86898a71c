//! Lambertian reflection: f = albedo / π on the +z side, sampled cosine-weighted.
use super::warp::{cosine_hemisphere_pdf, square_to_cosine_hemisphere};
use super::{BsdfSample, Scatter};
use glam::{Vec2, Vec3};
use std::f32::consts::FRAC_1_PI;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lambert {
    pub albedo: Vec3,
}

impl Scatter for Lambert {
    #[inline]
    fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        if wo.z > 0.0 && wi.z > 0.0 {
            // The same product as the shader computed before materials existed, so the
            // Lambertian path's output is unchanged bit for bit.
            self.albedo * FRAC_1_PI
        } else {
            Vec3::ZERO
        }
    }

    #[inline]
    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        if wo.z > 0.0 {
            cosine_hemisphere_pdf(wi)
        } else {
            0.0
        }
    }

    fn sample(&self, wo: Vec3, u: Vec3) -> Option<BsdfSample> {
        if !(wo.z > 0.0) {
            return None;
        }
        let wi = square_to_cosine_hemisphere(Vec2::new(u.y, u.z));
        let pdf = cosine_hemisphere_pdf(wi);
        (pdf > 0.0).then(|| BsdfSample {
            wi,
            value: self.albedo * FRAC_1_PI,
            pdf,
            delta: false,
        })
    }

    fn has_delta(&self) -> bool {
        false
    }
    fn has_non_delta(&self) -> bool {
        true
    }
    fn diffuse_albedo(&self, _wo: Vec3) -> Vec3 {
        self.albedo
    }
}
