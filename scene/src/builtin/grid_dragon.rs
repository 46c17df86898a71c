//! `grid-dragon` (paper 000 Figure 13: "a grid casting a shadow pattern on a dragon with
//! 871k polygons"): the shared Stanford dragon standing on a floor, a grid of 9 × 9 square
//! holes held above it, and a point light above the grid. The dragon is data; see the
//! module docs of [`super`].
use super::shapes::{grid_plate, polygon};
use super::{object, object_at};
use crate::{Camera, Light, Material, Mesh, Orbit, Scene};
use glam::{Affine3A, Vec3};

/// The data file the dragon comes from.
pub const DRAGON: &str = "dragon/dragon_vrip.ply";

/// Height of the grid's underside above the floor (the dragon stands about 0.144 high).
pub const GRID_HEIGHT: f32 = 0.24;

pub fn grid_dragon(dragon: Mesh) -> Scene {
    let (lo, hi) = dragon.bounds;
    // Stand the dragon on the floor, centred.
    let at = Affine3A::from_translation(Vec3::new(-(lo.x + hi.x) * 0.5, -lo.y, -(lo.z + hi.z) * 0.5));
    let size = (hi - lo).max_element().max(1e-6);
    let half = size * 2.5;
    let floor = polygon(&[Vec3::new(-half, 0.0, -half), Vec3::new(-half, 0.0, half), Vec3::new(half, 0.0, half), Vec3::new(half, 0.0, -half)]);
    // A grid a little wider than the dragon: 9 × 9 holes, 8 mm bars, 4 mm thick, scaled
    // with the dragon (0.205 long as distributed).
    let k = size / 0.205;
    let grid = grid_plate(0.36 * k, 9, 0.008 * k, 0.004 * k);
    let light = Vec3::new(0.05, 0.75, 0.08) * k;
    Scene {
        name: "grid-dragon".into(),
        objects: vec![
            object("floor", floor, Material::diffuse("floor", Vec3::splat(0.7))),
            object_at("dragon", dragon, Material::diffuse("dragon", Vec3::new(0.75, 0.7, 0.55)), at),
            object_at(
                "grid",
                grid,
                Material::diffuse("grid", Vec3::new(0.35, 0.3, 0.28)),
                Affine3A::from_translation(Vec3::new(0.0, GRID_HEIGHT * k, 0.0)),
            ),
        ],
        lights: vec![Light::Point { position: light, intensity: Vec3::splat(3.0 * light.length_squared()) }],
        camera: Camera {
            eye: Vec3::new(0.26, 0.3, 0.42) * k,
            target: Vec3::new(0.0, 0.07, 0.0) * k,
            up: Vec3::Y,
            fov_y_degrees: 40.0,
        },
        ambient: Vec3::splat(0.03),
        background: Vec3::ZERO,
        // Outside the grid's square (±0.18 k) and over the floor (±0.51 k), at the default
        // camera's height and distance, looking under the grid's edge at the dragon.
        orbit: Some(Orbit {
            pivot: Vec3::new(0.0, 0.07, 0.0) * k,
            radius: 0.479 * k,
            elevation_degrees: 28.7,
            start_azimuth_degrees: 31.8,
            fov_y_degrees: 40.0,
        }),
    }
}
