//! `torus-capsule` (paper 000 Figure 9, "about 30,000 polygons"): a torus resting flat on a
//! capsule that lies on a floor, under a square area light. Where the torus touches the
//! capsule its soft shadow hardens: the umbral and penumbral edges meet at the contact.
use super::shapes::{capsule, polygon, torus};
use super::{object, object_at};
use crate::{Camera, Light, Material, Orbit, Scene};
use glam::{Affine3A, Vec3};

/// Capsule radius and half length of its cylinder; torus ring and tube radii (metres).
const CAPSULE_R: f32 = 0.1;
const CAPSULE_HALF: f32 = 0.25;
const RING: f32 = 0.15;
const TUBE: f32 = 0.04;
/// Gap left at the contact (the tessellations are inscribed, so this keeps them apart).
const GAP: f32 = 0.0002;

pub fn torus_capsule() -> Scene {
    let floor = polygon(&[Vec3::new(-1.2, 0.0, -1.2), Vec3::new(-1.2, 0.0, 1.2), Vec3::new(1.2, 0.0, 1.2), Vec3::new(1.2, 0.0, -1.2)]);
    // 96 × (2 × 24 + 19) rings: about 12,700 triangles.
    let cap = capsule(CAPSULE_R, CAPSULE_HALF, 96, 24, 20);
    // 128 × 56 segments: 14,336 triangles. It lies flat over the capsule's middle; its tube
    // touches the capsule's top ridge where the ring crosses it, at x = ±RING.
    let ring = torus(RING, TUBE, 128, 56);
    let top = 2.0 * CAPSULE_R;
    let l = [Vec3::new(-0.25, 1.1, -0.15), Vec3::new(0.05, 1.1, -0.15), Vec3::new(0.05, 1.1, 0.15), Vec3::new(-0.25, 1.1, 0.15)];
    let radiance = Vec3::new(14.0, 13.0, 11.5);
    Scene {
        name: "torus-capsule".into(),
        objects: vec![
            object("floor", floor, Material::diffuse("floor", Vec3::splat(0.72))),
            object_at(
                "capsule",
                cap,
                Material::diffuse("capsule", Vec3::new(0.25, 0.45, 0.75)),
                Affine3A::from_translation(Vec3::new(0.0, CAPSULE_R, 0.0)),
            ),
            object_at(
                "torus",
                ring,
                Material::diffuse("torus", Vec3::new(0.8, 0.35, 0.2)),
                Affine3A::from_translation(Vec3::new(0.0, top + TUBE + GAP, 0.0)),
            ),
            object("luminaire", polygon(&l), Material::emissive("light", radiance)),
        ],
        lights: vec![Light::Area { vertices: l.to_vec(), radiance }],
        camera: Camera { eye: Vec3::new(0.35, 0.75, 0.95), target: Vec3::new(0.0, 0.15, 0.0), up: Vec3::Y, fov_y_degrees: 40.0 },
        ambient: Vec3::splat(0.03),
        background: Vec3::ZERO,
        // Over the floor (±1.2 m), below the light, looking down at the contact; starts
        // where the default camera stands.
        orbit: Some(Orbit {
            pivot: Vec3::new(0.0, 0.15, 0.0),
            radius: 0.9,
            elevation_degrees: 35.0,
            start_azimuth_degrees: 20.2,
            fov_y_degrees: 40.0,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_torus_touches_the_capsule_without_entering_it() {
        let s = torus_capsule();
        s.validate().unwrap();
        let tris: usize = s.objects.iter().map(|o| o.mesh.triangles.len()).sum();
        assert!((25_000..35_000).contains(&tris), "{tris} triangles");
        let (c, t) = (&s.objects[1], &s.objects[2]);
        // Distance of every torus vertex from the capsule's axis segment.
        let axis = |p: Vec3| {
            let q = p - Vec3::new(0.0, CAPSULE_R, 0.0);
            let x = q.x.clamp(-CAPSULE_HALF, CAPSULE_HALF);
            (q - Vec3::new(x, 0.0, 0.0)).length()
        };
        let min = t.mesh.positions.iter().map(|p| axis(t.transform.transform_point3(*p))).fold(f32::INFINITY, f32::min);
        assert!(min > CAPSULE_R && min < CAPSULE_R + 0.002, "closest torus vertex {min} from the capsule axis");
        assert_eq!(c.mesh.boundary_edges(), 0);
        // The light faces down onto the scene.
        assert!(s.lights[0].normal().unwrap().y < -0.99);
    }
}
