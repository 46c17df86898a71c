//! The scene: objects (mesh + material + transform), lights, camera, ambient term.
use crate::{Camera, Light, Material, Mesh};
use glam::{Affine3A, Vec3};
use std::sync::Arc;

#[derive(Debug, Clone)]
pub struct Object {
    pub name: String,
    pub mesh: Arc<Mesh>,
    pub material: Material,
    /// Default object-to-world transform (epoch 0).
    pub transform: Affine3A,
}

#[derive(Debug, Clone)]
pub struct Scene {
    pub name: String,
    pub objects: Vec<Object>,
    pub lights: Vec<Light>,
    pub camera: Camera,
    /// Ambient radiance added as `albedo * ambient` (paper 000's direct shader has an
    /// ambient term standing in for indirect light).
    pub ambient: Vec3,
    /// Radiance of rays that hit nothing.
    pub background: Vec3,
}

impl Scene {
    /// Total triangle count over all objects.
    pub fn triangle_count(&self) -> u64 {
        self.objects.iter().map(|o| o.mesh.triangles.len() as u64).sum()
    }

    /// The id (index) of the object called `name`.
    pub fn object_id(&self, name: &str) -> Option<u32> {
        self.objects.iter().position(|o| o.name == name).map(|i| i as u32)
    }

    /// World-space bounding box of all objects at their default transforms.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for o in &self.objects {
            let (a, b) = o.mesh.bounds;
            for i in 0..8 {
                let c = Vec3::new(
                    if i & 1 == 0 { a.x } else { b.x },
                    if i & 2 == 0 { a.y } else { b.y },
                    if i & 4 == 0 { a.z } else { b.z },
                );
                let w = o.transform.transform_point3(c);
                lo = lo.min(w);
                hi = hi.max(w);
            }
        }
        if lo.x > hi.x {
            (Vec3::ZERO, Vec3::ZERO)
        } else {
            (lo, hi)
        }
    }

    /// Checks the scene is renderable: at least one object with triangles, valid lights and
    /// camera, finite transforms.
    pub fn validate(&self) -> Result<(), String> {
        if self.objects.is_empty() || self.triangle_count() == 0 {
            return Err("scene has no triangles".into());
        }
        for (i, l) in self.lights.iter().enumerate() {
            l.validate().map_err(|e| format!("light {i}: {e}"))?;
        }
        for o in &self.objects {
            crate::limits::check_affine(&o.transform).map_err(|e| format!("object {}: {e}", o.name))?;
        }
        self.camera.validate()
    }
}
