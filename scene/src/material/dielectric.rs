//! Glass: Fresnel-weighted reflection and refraction at a dielectric interface, smooth (two
//! delta lobes) or rough (GGX microfacet, Walter et al. 2007 with the generalised half
//! vector; pbrt-v4 §9.5 and §9.7 `DielectricBxDF`, Mitsuba 3 `dielectric` /
//! `roughdielectric`). +z is outside; `eta` is inside over outside; `wo.z < 0` means the
//! viewer is inside.
//!
//! Transmitted values are divided by η'² (η' = index on `wi`'s side over index on `wo`'s
//! side), because L/η² is what is conserved across an interface: radiance leaving a denser
//! medium spreads over a wider cone and drops by η². That is right for the radiance a camera sees (pbrt's `TransportMode::Radiance`)
//! and makes the transmission half non-reciprocal by exactly that factor. The base colour
//! tints transmission only (Mitsuba's `specular_transmittance`).
use super::fresnel::{self, reflect, refract};
use super::microfacet::Ggx;
use super::{BsdfSample, Scatter};
use glam::{Vec2, Vec3};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dielectric {
    pub eta: f32,
    /// `None` for a smooth interface.
    pub ggx: Option<Ggx>,
    pub tint: Vec3,
}

/// The generalised half vector of a pair and the index ratio its transmission crosses, or
/// `None` for pairs no microfacet connects (pbrt-v4's checks: grazing directions, a
/// microfacet seen from behind by either direction).
#[inline]
fn half_vector(wo: Vec3, wi: Vec3, eta: f32) -> Option<(Vec3, f32, bool)> {
    let reflect = wo.z * wi.z > 0.0;
    let etap = if reflect {
        1.0
    } else if wo.z > 0.0 {
        eta
    } else {
        1.0 / eta
    };
    let m = wi * etap + wo;
    if wo.z == 0.0 || wi.z == 0.0 || m.length_squared() == 0.0 {
        return None;
    }
    let mut m = m.normalize();
    if m.z < 0.0 {
        m = -m;
    }
    if m.dot(wi) * wi.z < 0.0 || m.dot(wo) * wo.z < 0.0 {
        return None;
    }
    Some((m, etap, reflect))
}

impl Dielectric {
    pub fn new(ior: f32, alpha: f32, tint: Vec3) -> Dielectric {
        // An index of exactly 1 is no interface; keep it a hair away so the half vector of
        // a transmission stays defined (validate() rejects non-positive indices).
        let eta = if (ior - 1.0).abs() < 1e-4 {
            1.0 + 1e-4
        } else {
            ior.max(1e-3)
        };
        Dielectric {
            eta,
            ggx: (!Ggx::is_smooth(alpha)).then(|| Ggx::new(alpha)),
            tint,
        }
    }

    /// Value and pdf of a non-delta pair (rough interface only).
    fn eval_pdf(&self, g: &Ggx, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let Some((m, etap, is_reflect)) = half_vector(wo, wi, self.eta) else {
            return (Vec3::ZERO, 0.0);
        };
        let r = fresnel::dielectric(wo.dot(m), self.eta);
        let t = 1.0 - r;
        let dm = g.d(m);
        let gg = g.g(wo, wi);
        if is_reflect {
            let f = dm * gg * r / (4.0 * wi.z * wo.z).abs();
            let pdf = g.visible_pdf(wo, m) / (4.0 * wo.dot(m).abs()) * r;
            (Vec3::splat(f), pdf)
        } else {
            let s = wi.dot(m) + wo.dot(m) / etap;
            let denom = s * s * wi.z * wo.z;
            let f = t * dm * gg * (wi.dot(m) * wo.dot(m) / denom).abs() / (etap * etap);
            let dm_dwi = wi.dot(m).abs() / (s * s);
            let pdf = g.visible_pdf(wo, m) * dm_dwi * t;
            (self.tint * f, pdf)
        }
    }
}

impl Scatter for Dielectric {
    fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        match &self.ggx {
            Some(g) => self.eval_pdf(g, wo, wi).0,
            None => Vec3::ZERO,
        }
    }

    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        match &self.ggx {
            Some(g) => self.eval_pdf(g, wo, wi).1,
            None => 0.0,
        }
    }

    fn sample(&self, wo: Vec3, u: Vec3) -> Option<BsdfSample> {
        if wo.z == 0.0 {
            return None;
        }
        let Some(g) = self.ggx else {
            let r = fresnel::dielectric(wo.z, self.eta);
            return if u.x < r {
                let wi = Vec3::new(-wo.x, -wo.y, wo.z);
                Some(BsdfSample {
                    wi,
                    value: Vec3::splat(r / wi.z.abs()),
                    pdf: r,
                    delta: true,
                })
            } else {
                let (wi, etap) = refract(wo, Vec3::Z, self.eta)?;
                let t = 1.0 - r;
                Some(BsdfSample {
                    wi,
                    value: self.tint * (t / (wi.z.abs() * etap * etap)),
                    pdf: t,
                    delta: true,
                })
            };
        };
        let m = g.sample_visible(wo, Vec2::new(u.y, u.z));
        let r = fresnel::dielectric(wo.dot(m), self.eta);
        let wi = if u.x < r {
            let wi = reflect(wo, m);
            if wi.z * wo.z <= 0.0 {
                return None;
            }
            wi
        } else {
            let (wi, _) = refract(wo, m, self.eta)?;
            if wi.z * wo.z >= 0.0 {
                return None;
            }
            wi
        };
        // Value and pdf through the same code as eval/pdf: the sampled half vector is the
        // pair's generalised half vector up to rounding.
        let (value, pdf) = self.eval_pdf(&g, wo, wi);
        (pdf > 0.0 && value.is_finite()).then_some(BsdfSample {
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
