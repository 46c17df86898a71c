//! Turning loaded objects into a scene. A file that brings its own lights or camera (a
//! Mitsuba XML, a glTF with lights, an OBJ with emissive materials) is taken as it is: no
//! floor, no added light, no ambient term. A bare model (every PLY, most OBJs) is staged:
//! the model standing on a floor, a point light above and in front of it, a little ambient
//! light, and a camera framing it (the paper's "bunny / dragon on a floor under a point
//! light" setups). Either way a log line says which happened.
use crate::{Camera, Light, Material, Mesh, NoProgress, Object, Orbit, Scene};
use glam::{Affine3A, Vec3};
use std::sync::Arc;

/// The ambient radiance of a staged bare model (standing in for the indirect light the
/// `direct` shader does not compute).
pub const STAGED_AMBIENT: f32 = 0.03;

/// Builds a scene from `objects` and the `lights` and `camera` their file brought. With
/// neither, it stages the models (floor, point light, ambient, framing camera). With
/// lights but no camera it only adds the framing camera (looking along -Z, slightly from
/// above, 40° field of view), and says so.
pub fn stage_meshes(name: &str, mut objects: Vec<Object>, mut lights: Vec<Light>, camera: Option<Camera>) -> Scene {
    let mut scene = Scene {
        name: name.to_string(),
        objects: Vec::new(),
        lights: Vec::new(),
        camera: Camera { eye: Vec3::Z, target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 40.0 },
        ambient: Vec3::ZERO,
        background: Vec3::ZERO,
        orbit: None,
    };
    scene.objects.append(&mut objects);
    let (lo, hi) = scene.bounds();
    let centre = (lo + hi) * 0.5;
    let radius = ((hi - lo).length() * 0.5).max(1e-6);
    let bare = lights.is_empty() && camera.is_none();
    if bare {
        tracing::info!(
            "{name}: the file brings no lights and no camera: staged on a floor under a point light, with ambient {STAGED_AMBIENT} and a framing camera"
        );
        scene.ambient = Vec3::splat(STAGED_AMBIENT);
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
    } else if lights.is_empty() {
        tracing::warn!("{name}: the file brings a camera but no lights: only emissive surfaces show (nothing is added)");
    }
    scene.lights = lights;
    match camera {
        Some(c) => {
            tracing::info!("{name}: camera from the file (eye {}, target {}, {:.2}° vertical field of view)", c.eye, c.target, c.fov_y_degrees);
            scene.camera = c;
        }
        None => {
            let fov = 40f32;
            let dist = radius / (fov.to_radians() * 0.5).sin() * 1.05;
            let dir = Vec3::new(0.0, 0.35, 1.0).normalize();
            scene.camera = Camera { eye: centre + dir * dist, target: centre, up: Vec3::Y, fov_y_degrees: fov };
            if !bare {
                tracing::info!("{name}: the file brings lights but no camera: framing camera from +Z (give one with --camera)");
            }
            // Round the framing target at the framing distance: inside the floor (4 radii
            // wide, the eye ~2.9 radii out) and outside the model's bounding sphere.
            scene.orbit = Some(Orbit::through(&scene.camera));
        }
    }
    scene
}
