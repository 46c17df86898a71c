//! `materials`: one sphere of each scattering model on a floor, under a ceiling-less square
//! area light (with its visible luminaire) and a point light — the demo of the `direct`
//! shader's materials: highlights of both lights on the rough and smooth coats, the area
//! light mirrored in the smooth metal and glass, plastic's diffuse colour under its coat.
//! The spheres carry per-corner normals (smooth shading).
use super::shapes::{polygon, sphere};
use super::{object, object_at};
use crate::{Bsdf, Camera, Light, Material, Mesh, Orbit, Scene};
use glam::{Affine3A, Vec3};

const RADIUS: f32 = 0.35;

/// The sphere with its exact normals at every triangle corner.
fn smooth_sphere() -> Mesh {
    let mut m = sphere(RADIUS, 64, 32);
    let normals = m.triangles.iter().map(|t| t.map(|i| m.positions[i as usize].normalize_or_zero())).collect();
    m.corners.normals = Some(normals);
    m
}

fn material(name: &str, base: Vec3, bsdf: Bsdf) -> Material {
    Material { bsdf, ..Material::diffuse(name, base) }
}

pub fn materials() -> Scene {
    let gold = (Vec3::new(0.143, 0.374, 1.442), Vec3::new(3.983, 2.385, 1.603));
    let silver = (Vec3::new(0.155, 0.117, 0.138), Vec3::new(4.828, 3.122, 2.147));
    let spheres = [
        material("lambert", Vec3::new(0.7, 0.15, 0.1), Bsdf::Diffuse),
        material("plastic", Vec3::new(0.1, 0.2, 0.6), Bsdf::Plastic { ior: 1.5, roughness: 0.0 }),
        material("roughplastic", Vec3::new(0.15, 0.5, 0.15), Bsdf::Plastic { ior: 1.5, roughness: 0.15 }),
        material("roughgold", Vec3::ONE, Bsdf::Conductor { eta: gold.0, k: gold.1, roughness: 0.2 }),
        material("mirror", Vec3::ONE, Bsdf::Conductor { eta: silver.0, k: silver.1, roughness: 0.0 }),
        material("glass", Vec3::ONE, Bsdf::Dielectric { ior: 1.5, roughness: 0.0 }),
        material("roughglass", Vec3::ONE, Bsdf::Dielectric { ior: 1.5, roughness: 0.2 }),
    ];
    let ball = smooth_sphere();
    let half = 4.5;
    let mut objects = vec![object(
        "floor",
        polygon(&[Vec3::new(-half, 0.0, -half), Vec3::new(-half, 0.0, half), Vec3::new(half, 0.0, half), Vec3::new(half, 0.0, -half)]),
        Material::diffuse("floor", Vec3::splat(0.6)),
    )];
    for (i, m) in spheres.into_iter().enumerate() {
        let x = (i as f32 - 3.0) * 0.8;
        let name = m.name.clone();
        objects.push(object_at(&name, ball.clone(), m, Affine3A::from_translation(Vec3::new(x, RADIUS + 1e-3, 0.0))));
    }
    // Wound to face down.
    let lum = [Vec3::new(-1.2, 2.6, -0.6), Vec3::new(1.2, 2.6, -0.6), Vec3::new(1.2, 2.6, 0.6), Vec3::new(-1.2, 2.6, 0.6)];
    let radiance = Vec3::new(6.0, 5.6, 5.0);
    objects.push(object("luminaire", polygon(&lum), Material::emissive("light", radiance)));
    let lights = vec![
        Light::Area { vertices: lum.to_vec(), radiance },
        Light::Point { position: Vec3::new(-2.0, 1.8, 3.0), intensity: Vec3::new(5.0, 5.5, 6.5) },
    ];
    Scene {
        name: "materials".into(),
        objects,
        lights,
        camera: Camera { eye: Vec3::new(0.0, 1.5, 5.0), target: Vec3::new(0.0, 0.3, 0.0), up: Vec3::Y, fov_y_degrees: 40.0 },
        ambient: Vec3::splat(0.03),
        background: Vec3::ZERO,
        orbit: Some(Orbit { pivot: Vec3::new(0.0, 0.35, 0.0), radius: 4.2, elevation_degrees: 14.0, start_azimuth_degrees: 0.0, fov_y_degrees: 70.0 }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_model_is_there_and_valid() {
        let s = materials();
        s.validate().unwrap();
        for o in &s.objects {
            o.material.bsdf.validate().unwrap();
        }
        let kinds = |f: fn(&Bsdf) -> bool| s.objects.iter().filter(|o| f(&o.material.bsdf)).count();
        assert_eq!(kinds(|b| matches!(b, Bsdf::Conductor { .. })), 2);
        assert_eq!(kinds(|b| matches!(b, Bsdf::Dielectric { .. })), 2);
        assert_eq!(kinds(|b| matches!(b, Bsdf::Plastic { .. })), 2);
        let ball = &s.objects[1].mesh;
        let n = ball.corners.normals.as_ref().unwrap();
        assert_eq!(n.len(), ball.triangles.len());
        assert!(n.iter().flatten().all(|v| (v.length() - 1.0).abs() < 1e-5));
    }
}
