//! `glossy-bunny` (issue 14's "the bunny with glossy reflection", for the `glossy` shader):
//! the shared Stanford bunny in rough gold on a dark polished plastic floor, before a silver
//! mirror, under a square area light (soft shadows, a broad highlight) and a point light
//! (a sharp one). What the `glossy` shader adds over `direct` is everywhere: the bunny and
//! the floor blurred in the gold, the bunny's back in the mirror, the floor's sharp coat
//! reflecting the bunny's foot. The bunny is data; see the module docs of [`super`].
use super::shapes::polygon;
use super::{object, object_at};
use crate::{Bsdf, Camera, Light, Material, Mesh, Orbit, Scene};
use glam::{Affine3A, Vec3};

/// The data file the bunny comes from.
pub const BUNNY: &str = "bunny/bun_zipper.ply";

pub fn glossy_bunny(bunny: Mesh) -> Scene {
    let (lo, hi) = bunny.bounds;
    let size = (hi - lo).max_element().max(1e-6);
    // Scaled to 1 unit across, standing on the floor, centred.
    let s = 1.0 / size;
    let at = Affine3A::from_scale(Vec3::splat(s)) * Affine3A::from_translation(Vec3::new(-(lo.x + hi.x) * 0.5, -lo.y, -(lo.z + hi.z) * 0.5));
    let half = 3.0;
    let floor = polygon(&[Vec3::new(-half, 0.0, -half), Vec3::new(-half, 0.0, half), Vec3::new(half, 0.0, half), Vec3::new(half, 0.0, -half)]);
    // The mirror: a panel standing behind the bunny, facing it (+z).
    let mirror = polygon(&[Vec3::new(-1.2, 0.0, -0.9), Vec3::new(1.2, 0.0, -0.9), Vec3::new(1.2, 1.6, -0.9), Vec3::new(-1.2, 1.6, -0.9)]);
    let gold = (Vec3::new(0.143, 0.374, 1.442), Vec3::new(3.983, 2.385, 1.603));
    let silver = (Vec3::new(0.155, 0.117, 0.138), Vec3::new(4.828, 3.122, 2.147));
    let with = |name: &str, base: Vec3, bsdf: Bsdf| Material { bsdf, ..Material::diffuse(name, base) };
    let l = 0.35;
    let y = 2.2;
    Scene {
        name: "glossy-bunny".into(),
        objects: vec![
            object("floor", floor, with("floor", Vec3::new(0.08, 0.09, 0.12), Bsdf::Plastic { ior: 1.5, roughness: 0.0 })),
            object("mirror", mirror, with("mirror", Vec3::ONE, Bsdf::Conductor { eta: silver.0, k: silver.1, roughness: 0.0 })),
            object_at("bunny", bunny, with("bunny", Vec3::ONE, Bsdf::Conductor { eta: gold.0, k: gold.1, roughness: 0.12 }), at),
        ],
        lights: vec![
            // Wound to face down.
            Light::Area {
                vertices: vec![Vec3::new(-l, y, -l + 0.6), Vec3::new(l, y, -l + 0.6), Vec3::new(l, y, l + 0.6), Vec3::new(-l, y, l + 0.6)],
                radiance: Vec3::splat(12.0),
            },
            Light::Point { position: Vec3::new(1.5, 1.8, 1.2), intensity: Vec3::new(2.0, 1.9, 1.7) },
        ],
        camera: Camera { eye: Vec3::new(0.9, 0.9, 2.2), target: Vec3::new(0.0, 0.4, 0.0), up: Vec3::Y, fov_y_degrees: 40.0 },
        ambient: Vec3::splat(0.05),
        background: Vec3::splat(0.02),
        orbit: Some(Orbit { pivot: Vec3::new(0.0, 0.4, 0.0), radius: 2.45, elevation_degrees: 12.0, start_azimuth_degrees: 22.0, fov_y_degrees: 40.0 }),
    }
}
