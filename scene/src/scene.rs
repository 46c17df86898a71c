//! The scene: objects (mesh + material + transform), lights, camera, ambient term.
use crate::{Camera, Light, Material, Mesh, Orbit};
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
    /// The orbit the scene suggests for a moving camera (built-ins: inside the room and
    /// outside every object all the way round; loaded models: about the framing target).
    /// `None` falls back to the orbit through the camera ([`Scene::suggested_orbit`]).
    pub orbit: Option<Orbit>,
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

    /// The scene's suggested orbit, or the orbit through its camera when it names none.
    pub fn suggested_orbit(&self) -> Orbit {
        self.orbit.unwrap_or_else(|| Orbit::through(&self.camera))
    }

    /// World-space bounding box of object `i` at its default transform.
    pub fn object_bounds(&self, i: usize) -> (Vec3, Vec3) {
        let o = &self.objects[i];
        crate::geometry::transformed_box(&o.transform, o.mesh.bounds)
    }

    /// World-space bounding box of all objects at their default transforms.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for i in 0..self.objects.len() {
            let (a, b) = self.object_bounds(i);
            lo = lo.min(a);
            hi = hi.max(b);
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
        if let Some(o) = &self.orbit {
            o.validate()?;
        }
        self.camera.validate()
    }
}
