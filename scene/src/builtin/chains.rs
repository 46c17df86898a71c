//! `chains` (paper 000 Figure 7, Table 1: "tessellated non-convex objects casting complex
//! shadows on each other", 73,728 polygons, two lights): four chains of eight linked tori
//! (48 × 24 segments each, 2,304 triangles, 73,728 in all) lying on a floor, lit by two
//! point lights.
use super::shapes::{polygon, torus};
use super::{object, object_at};
use crate::{Camera, Light, Material, Orbit, Scene};
use glam::{Affine3A, Quat, Vec3};

/// Ring radius, tube radius and the distance between linked ring centres (metres). Linked
/// rings are perpendicular: each passes through the other's hole with 1 cm to spare.
const R: f32 = 0.1;
const TUBE: f32 = 0.025;
const PITCH: f32 = 0.14;

pub fn chains() -> Scene {
    let ring = torus(R, TUBE, 48, 24);
    let metals = [
        Material::diffuse("steel", Vec3::new(0.62, 0.64, 0.68)),
        Material::diffuse("brass", Vec3::new(0.71, 0.55, 0.24)),
        Material::diffuse("copper", Vec3::new(0.70, 0.38, 0.25)),
        Material::diffuse("iron", Vec3::new(0.42, 0.42, 0.45)),
    ];
    let mut objects = vec![object(
        "floor",
        polygon(&[Vec3::new(-1.5, 0.0, -1.5), Vec3::new(-1.5, 0.0, 1.5), Vec3::new(1.5, 0.0, 1.5), Vec3::new(1.5, 0.0, -1.5)]),
        Material::diffuse("floor", Vec3::splat(0.7)),
    )];
    for c in 0..4 {
        // Each chain runs along x; its rings alternate between two perpendicular tilts
        // about the chain's axis, a different pair per chain.
        let tilt = [45.0f32, 30.0, 60.0, 20.0][c].to_radians();
        let z = -0.45 + 0.3 * c as f32;
        let x0 = -PITCH * 3.5 + 0.05 * c as f32;
        // The torus lies in the x–z plane (axis y); stand it up into the x–y plane, then
        // tilt it about x. A ring tilted by t reaches R |cos t| + TUBE above its centre.
        let reach = |t: f32| R * t.cos().abs() + TUBE;
        let h = reach(tilt).max(reach(tilt + std::f32::consts::FRAC_PI_2)) + 0.001;
        for i in 0..8 {
            let t = tilt + if i % 2 == 1 { std::f32::consts::FRAC_PI_2 } else { 0.0 };
            let rot = Quat::from_rotation_x(t) * Quat::from_rotation_x(std::f32::consts::FRAC_PI_2);
            let xf = Affine3A::from_rotation_translation(rot, Vec3::new(x0 + PITCH * i as f32, h, z));
            objects.push(object_at(&format!("chain{c}-link{i}"), ring.clone(), metals[c].clone(), xf));
        }
    }
    Scene {
        name: "chains".into(),
        objects,
        lights: vec![
            Light::Point { position: Vec3::new(-0.6, 1.3, 0.5), intensity: Vec3::new(4.0, 3.8, 3.4) },
            Light::Point { position: Vec3::new(0.9, 1.0, -0.4), intensity: Vec3::new(1.8, 2.0, 2.4) },
        ],
        camera: Camera { eye: Vec3::new(0.2, 1.05, 1.35), target: Vec3::new(0.0, 0.05, 0.0), up: Vec3::Y, fov_y_degrees: 45.0 },
        ambient: Vec3::splat(0.03),
        background: Vec3::ZERO,
        // Over the floor (±1.5 m), 0.82 m up, looking down at the middle of the chains.
        orbit: Some(Orbit {
            pivot: Vec3::new(0.05, 0.05, 0.0),
            radius: 1.2,
            elevation_degrees: 40.0,
            start_azimuth_degrees: 8.4,
            fov_y_degrees: 45.0,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thirty_two_tori_of_2304_triangles_above_the_floor() {
        let s = chains();
        s.validate().unwrap();
        let links: Vec<_> = s.objects.iter().filter(|o| o.name.starts_with("chain")).collect();
        assert_eq!(links.len(), 32);
        assert_eq!(links.iter().map(|o| o.mesh.triangles.len()).sum::<usize>(), 73_728);
        assert_eq!(s.lights.len(), 2);
        // Every link is above the floor; the lower tilt of each chain rests on it.
        let lowest = |o: &crate::Object| o.mesh.positions.iter().map(|p| o.transform.transform_point3(*p).y).fold(f32::INFINITY, f32::min);
        for c in 0..4 {
            let l: Vec<f32> = links[c * 8..c * 8 + 8].iter().map(|o| lowest(o)).collect();
            assert!(l.iter().all(|&y| y > 0.0), "chain {c}: {l:?}");
            assert!(l.iter().any(|&y| y < 0.005), "chain {c} rests on the floor: {l:?}");
        }
        // Neighbouring links are linked, not touching: every vertex of one ring is more
        // than the tube diameter from the other ring's centre circle.
        for c in 0..4 {
            for i in 0..7 {
                let (a, b) = (&links[c * 8 + i], &links[c * 8 + i + 1]);
                let inv = b.transform.inverse();
                let min = a
                    .mesh
                    .positions
                    .iter()
                    .map(|p| {
                        let q = inv.transform_point3(a.transform.transform_point3(*p));
                        let ring = Vec3::new(q.x, 0.0, q.z).normalize_or_zero() * R;
                        (q - ring).length()
                    })
                    .fold(f32::INFINITY, f32::min);
                assert!(min > TUBE * 1.05, "{} and {} intersect ({min})", a.name, b.name);
                // ... and linked: some of a's vertices pass through b's hole.
                let through = a.mesh.positions.iter().any(|p| {
                    let q = inv.transform_point3(a.transform.transform_point3(*p));
                    q.y.abs() < TUBE && Vec3::new(q.x, 0.0, q.z).length() < R - TUBE
                });
                assert!(through, "{} passes through {}", a.name, b.name);
            }
        }
    }
}
