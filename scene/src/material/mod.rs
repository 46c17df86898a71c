//! Materials: a base colour (linear RGB, optionally a texture), a scattering model
//! ([`Bsdf`]) and emission.
//!
//! These are the data every loader fills in and every shader reads. The scattering
//! models are the ones physically based renderers share (pbrt-v4 §9, Mitsuba 3's BSDF
//! plugins): Lambertian ([`lambert`]), GGX microfacet conductor ([`conductor`]), smooth or
//! rough dielectric ([`dielectric`]), plastic (a diffuse base under a dielectric coat,
//! [`plastic`]), all behind one interface ([`Scatter`], dispatched by [`Scattering`]),
//! on shared GGX ([`microfacet`]) and Fresnel ([`fresnel`]) modules.
//!
//! Conventions (every model, tested in `scene/tests/bsdf_*.rs`):
//! - Directions are unit vectors in the local shading frame ([`Frame`]): +z is the shading
//!   normal, `wo` points toward the viewer, `wi` toward the light; both point away from the
//!   surface.
//! - [`Scatter::eval`] is the BSDF value f(wo, wi) WITHOUT the cosine factor; reflected
//!   radiance is `∫ f(wo, wi) Li |cos θi| dwi`. Delta lobes are not part of `eval`/`pdf`.
//! - [`Scatter::pdf`] is the density per unit solid angle with which [`Scatter::sample`]
//!   returns a non-delta `wi` (it includes the probability of choosing that lobe, so it
//!   integrates to less than 1 where a delta lobe or a rejected sample takes the rest).
//! - Reflection-only models (Lambert, conductor, plastic) scatter on the +z side: `wo.z > 0`
//!   or nothing (the shader flips the frame of two-sided surfaces). The dielectric sees
//!   both sides: +z is outside, `ior` the index inside over outside.
//! - Transmission is for radiance: its value carries the 1/η² scaling of radiance crossing
//!   an interface (pbrt-v4 §9.5.2, `TransportMode::Radiance`), so it is not reciprocal;
//!   reflection is.
mod conductor;
mod dielectric;
mod frame;
pub mod fresnel;
mod lambert;
pub mod microfacet;
mod plastic;
mod texture;
pub mod warp;

pub use conductor::{eta_from_f0, Conductor};
pub use dielectric::Dielectric;
pub use frame::Frame;
pub use lambert::Lambert;
pub use plastic::Plastic;
pub use texture::Texture;

use glam::Vec3;
use std::sync::Arc;

/// How a surface scatters light. Roughness is GGX alpha (0 = perfectly smooth, a delta
/// lobe); indices of refraction are relative (inside / outside).
#[derive(Debug, Clone, PartialEq)]
pub enum Bsdf {
    /// Lambertian reflection of the base colour.
    Diffuse,
    /// A metal: Fresnel from the complex index of refraction `eta + i k` (per channel),
    /// scaled by the base colour (Mitsuba's `specular_reflectance`; white for real metals).
    Conductor { eta: Vec3, k: Vec3, roughness: f32 },
    /// Glass: reflection and refraction at index `ior`; the base colour tints transmission.
    Dielectric { ior: f32, roughness: f32 },
    /// Diffuse base colour under a dielectric coat of index `ior`.
    Plastic { ior: f32, roughness: f32 },
}

#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    pub name: String,
    /// Base colour in [0, 1] per channel: the Lambertian albedo of `Diffuse` and `Plastic`,
    /// the reflectance scale of `Conductor`, the transmittance tint of `Dielectric`.
    pub diffuse: Vec3,
    /// Multiplies `diffuse` where the mesh has UVs.
    pub texture: Option<Arc<Texture>>,
    pub bsdf: Bsdf,
    /// Scatters on both sides (Mitsuba's `twosided`; every diffuse surface of the built-ins).
    pub two_sided: bool,
    /// Emitted radiance (linear RGB); non-zero for light fixtures seen by the camera.
    pub emission: Vec3,
}

impl Material {
    pub fn diffuse(name: &str, diffuse: Vec3) -> Self {
        Material {
            name: name.to_string(),
            diffuse,
            texture: None,
            bsdf: Bsdf::Diffuse,
            two_sided: true,
            emission: Vec3::ZERO,
        }
    }
    pub fn emissive(name: &str, emission: Vec3) -> Self {
        Material {
            emission,
            ..Material::diffuse(name, Vec3::splat(0.78))
        }
    }
}

impl Default for Material {
    fn default() -> Self {
        Material::diffuse("default", Vec3::splat(0.7))
    }
}

/// A sampled direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BsdfSample {
    /// The sampled incident direction (local frame).
    pub wi: Vec3,
    /// f(wo, wi) for a non-delta sample (equal to `eval`); for a delta sample the
    /// coefficient of the delta, so that `value · |cos θi| / pdf` is the path weight either way.
    pub value: Vec3,
    /// Solid-angle density for a non-delta sample (equal to `pdf`); for a delta sample the
    /// probability of having chosen that delta lobe.
    pub pdf: f32,
    pub delta: bool,
}

impl BsdfSample {
    /// `value · |cos θi| / pdf`: what a path's throughput is multiplied by.
    #[inline]
    pub fn weight(&self) -> Vec3 {
        self.value * (self.wi.z.abs() / self.pdf)
    }
}

/// The interface every scattering model implements (conventions: module docs).
pub trait Scatter {
    /// f(wo, wi) without the cosine; zero for pairs only a delta lobe connects.
    fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3;
    /// Solid-angle density of `sample` returning the non-delta direction `wi`.
    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32;
    /// Draws `wi` from three uniform numbers (`u.x` picks a lobe, `u.y, u.z` the direction);
    /// `None` where the model scatters nothing for this `wo` or the draw is rejected.
    fn sample(&self, wo: Vec3, u: Vec3) -> Option<BsdfSample>;
    /// Has a delta lobe (smooth specular reflection or refraction) that `eval` leaves out.
    fn has_delta(&self) -> bool;
    /// Has a non-delta part that light sampling can reach.
    fn has_non_delta(&self) -> bool;
    /// The Lambertian part's albedo seen from `wo` (what an ambient term multiplies).
    fn diffuse_albedo(&self, wo: Vec3) -> Vec3;
}

/// A [`Bsdf`] with its base colour resolved at one surface point: the models as a plain
/// enum (no allocation, no virtual call per evaluation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scattering {
    Lambert(Lambert),
    Conductor(Conductor),
    Dielectric(Dielectric),
    Plastic(Plastic),
}

macro_rules! dispatch {
    ($self:ident, $m:ident => $e:expr) => {
        match $self {
            Scattering::Lambert($m) => $e,
            Scattering::Conductor($m) => $e,
            Scattering::Dielectric($m) => $e,
            Scattering::Plastic($m) => $e,
        }
    };
}

impl Scatter for Scattering {
    #[inline]
    fn eval(&self, wo: Vec3, wi: Vec3) -> Vec3 {
        dispatch!(self, m => m.eval(wo, wi))
    }
    #[inline]
    fn pdf(&self, wo: Vec3, wi: Vec3) -> f32 {
        dispatch!(self, m => m.pdf(wo, wi))
    }
    #[inline]
    fn sample(&self, wo: Vec3, u: Vec3) -> Option<BsdfSample> {
        dispatch!(self, m => m.sample(wo, u))
    }
    #[inline]
    fn has_delta(&self) -> bool {
        dispatch!(self, m => m.has_delta())
    }
    #[inline]
    fn has_non_delta(&self) -> bool {
        dispatch!(self, m => m.has_non_delta())
    }
    #[inline]
    fn diffuse_albedo(&self, wo: Vec3) -> Vec3 {
        dispatch!(self, m => m.diffuse_albedo(wo))
    }
}

impl Scattering {
    /// Scatters only on the +z side (everything but the dielectric): the shader may flip
    /// the frame of a two-sided surface toward the viewer.
    #[inline]
    pub fn is_reflection_only(&self) -> bool {
        !matches!(self, Scattering::Dielectric(_))
    }
}

impl Bsdf {
    /// The model with base colour `base` (the material's `diffuse` × texture).
    #[inline]
    pub fn at(&self, base: Vec3) -> Scattering {
        match *self {
            Bsdf::Diffuse => Scattering::Lambert(Lambert { albedo: base }),
            Bsdf::Conductor { eta, k, roughness } => {
                Scattering::Conductor(Conductor::new(eta, k, roughness, base))
            }
            Bsdf::Dielectric { ior, roughness } => {
                Scattering::Dielectric(Dielectric::new(ior, roughness, base))
            }
            Bsdf::Plastic { ior, roughness } => {
                Scattering::Plastic(Plastic::new(ior, roughness, base))
            }
        }
    }

    /// Checks the parameters are usable (loaders report the error with the file and line):
    /// finite, indices of refraction in (0, 100], roughness (GGX alpha) in [0, 10].
    pub fn validate(&self) -> Result<(), String> {
        let rough = |r: f32| {
            if !(0.0..=10.0).contains(&r) {
                Err(format!("roughness (GGX alpha) must be in [0, 10], got {r}"))
            } else {
                Ok(())
            }
        };
        let ior = |i: f32| {
            if !(i > 0.0 && i <= 100.0) {
                Err(format!("index of refraction must be in (0, 100], got {i}"))
            } else {
                Ok(())
            }
        };
        match *self {
            Bsdf::Diffuse => Ok(()),
            Bsdf::Conductor { eta, k, roughness } => {
                if !(eta.min_element() > 0.0
                    && eta.max_element() <= 100.0
                    && k.min_element() >= 0.0
                    && k.max_element() <= 100.0)
                {
                    return Err(format!(
                        "conductor eta must be in (0, 100] and k in [0, 100], got eta {eta}, k {k}"
                    ));
                }
                rough(roughness)
            }
            Bsdf::Dielectric { ior: i, roughness } | Bsdf::Plastic { ior: i, roughness } => {
                ior(i).and(rough(roughness))
            }
        }
    }
}
