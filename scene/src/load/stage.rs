//! Staging a bare model as a viewable scene: the model standing on a floor, a point light
//! above and in front of it, and a camera framing it (used for the paper's "bunny / dragon on
//! a floor under a point light" setups).
use crate::{Camera, Light, Material, Mesh, NoProgress, Object, Orbit, Scene};
use glam::{Affine3A, Vec3};
use std::sync::Arc;

/// Builds a scene from `objects` and the `lights` they brought. Without lights it adds a
/// floor (object "floor") under the models and a point light; it always frames the camera
/// on the models' bounding sphere (looking along -Z, slightly from above, 40° field of view).
pub fn stage_meshes(name: &str, mut objects: Vec<Object>, mut lights: Vec<Light>) -> Scene {
    let mut scene = Scene {
        name: name.to_string(),
        objects: Vec::new(),
        lights: Vec::new(),
        camera: Camera { eye: Vec3::Z, target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 40.0 },
        ambient: Vec3::splat(0.03),
        background: Vec3::ZERO,
        orbit: None,
    };
    scene.objects.append(&mut objects);
    let (lo, hi) = scene.bounds();
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-6);
    if lights.is_empty() {
        let half = radius * 4.0;
        let y = lo.y;
        let floor = Mesh::from_triangles(
            vec![
                Vec3::new(centre.x - half, y, centre.z - half),
                Vec3::new(centre.x - half, y, centre.z + half),
                Vec3::new(centre.x + half, y, centre.z + half),
                Vec3::new(centre.x + half, y, centre.z - half),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
            &NoProgress,
        );
        scene.objects.push(Object {
            name: "floor".into(),
            mesh: Arc::new(floor),
            material: Material::diffuse("floor", Vec3::splat(0.73)),
            transform: Affine3A::IDENTITY,
        });
        // About 3 units of irradiance on the floor under the model, whatever its size.
        let pos = centre + Vec3::new(0.6, 2.2, 1.2) * radius;
        let d2 = (pos - Vec3::new(centre.x, y, centre.z)).length_squared();
        lights.push(Light::Point { position: pos, intensity: Vec3::splat(3.0 * d2) });
    }
    scene.lights = lights;
    let fov = 40f32;
    let dist = radius / (fov.to_radians() * 0.5).sin() * 1.05;
    let dir = Vec3::new(0.0, 0.35, 1.0).normalize();
    scene.camera = Camera { eye: centre + dir * dist, target: centre, up: Vec3::Y, fov_y_degrees: fov };
    // Round the framing target at the framing distance: inside the floor (4 radii wide,
    // the eye ~2.9 radii out) and outside the model's bounding sphere.
    scene.orbit = Some(Orbit::through(&scene.camera));
    scene
}
