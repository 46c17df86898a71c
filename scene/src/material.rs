//! Materials: a base colour (linear RGB, optionally a texture), a scattering model
//! ([`Bsdf`]) and emission.
//!
//! These are the data every loader fills in and every shader reads. The scattering
//! models are the ones physically based renderers share (pbrt-v4 §9, Mitsuba 3's BSDF
//! plugins): Lambertian, GGX microfacet conductor, smooth or rough dielectric, plastic
//! (a diffuse base under a dielectric coat). Evaluation, sampling and pdfs live with them.
use glam::{Vec2, Vec3};
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

/// A base-colour texture: linear RGB texels, row 0 at v = 0 (the loader flips images
/// whose rows run the other way), repeated outside [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub name: String,
    pub width: u32,
    pub height: u32,
    /// `width * height` linear RGB texels, row-major.
    pub texels: Vec<Vec3>,
}

impl Texture {
    /// Bilinear lookup with wrap-around; black for an empty texture.
    pub fn sample(&self, uv: Vec2) -> Vec3 {
        let (w, h) = (self.width as usize, self.height as usize);
        if w == 0 || h == 0 || self.texels.len() < w * h {
            return Vec3::ZERO;
        }
        let x = uv.x.rem_euclid(1.0) * w as f32 - 0.5;
        let y = uv.y.rem_euclid(1.0) * h as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |i: f32, n: usize| (i as i64).rem_euclid(n as i64) as usize;
        let (xa, xb) = (wrap(x0, w), wrap(x0 + 1.0, w));
        let (ya, yb) = (wrap(y0, h), wrap(y0 + 1.0, h));
        let t = |x: usize, y: usize| self.texels[y * w + x];
        let top = t(xa, ya) * (1.0 - fx) + t(xb, ya) * fx;
        let bottom = t(xa, yb) * (1.0 - fx) + t(xb, yb) * fx;
        top * (1.0 - fy) + bottom * fy
    }
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
        Material { name: name.to_string(), diffuse, texture: None, bsdf: Bsdf::Diffuse, two_sided: true, emission: Vec3::ZERO }
    }
    pub fn emissive(name: &str, emission: Vec3) -> Self {
        Material { emission, ..Material::diffuse(name, Vec3::splat(0.78)) }
    }
}

impl Default for Material {
    fn default() -> Self {
        Material::diffuse("default", Vec3::splat(0.7))
    }
}
