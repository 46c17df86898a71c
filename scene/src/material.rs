//! Materials: diffuse reflectance and emission (linear RGB).
use glam::Vec3;

#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    pub name: String,
    /// Lambertian albedo in [0, 1] per channel.
    pub diffuse: Vec3,
    /// Emitted radiance (linear RGB); non-zero for light fixtures seen by the camera.
    pub emission: Vec3,
}

impl Material {
    pub fn diffuse(name: &str, diffuse: Vec3) -> Self {
        Material { name: name.to_string(), diffuse, emission: Vec3::ZERO }
    }
    pub fn emissive(name: &str, emission: Vec3) -> Self {
        Material { name: name.to_string(), diffuse: Vec3::splat(0.78), emission }
    }
}

impl Default for Material {
    fn default() -> Self {
        Material::diffuse("default", Vec3::splat(0.7))
    }
}
