//! Small scenes built in code for the worker tests.
#![allow(dead_code)]
use edgepoint_scene::{Bsdf, Camera, Light, Material, Mesh, NoProgress, Object, Scene};
use edgepoint_worker::{LoadedScene, RayRequest, ShaderSpec};
use glam::{Affine3A, Vec3};
use std::sync::Arc;

pub fn quad(y: f32, half: f32, up: bool) -> Mesh {
    let mut p = vec![Vec3::new(-half, y, -half), Vec3::new(-half, y, half), Vec3::new(half, y, half), Vec3::new(half, y, -half)];
    if !up {
        p.reverse();
    }
    Mesh::from_triangles(p, vec![[0, 1, 2], [0, 2, 3]], &NoProgress)
}

/// A UV sphere of radius 1 at the origin.
pub fn sphere(stacks: u32, slices: u32) -> Mesh {
    let mut p = Vec::new();
    for i in 0..=stacks {
        let th = std::f32::consts::PI * i as f32 / stacks as f32;
        for j in 0..slices {
            let ph = std::f32::consts::TAU * j as f32 / slices as f32;
            p.push(Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()));
        }
    }
    let mut t = Vec::new();
    for i in 0..stacks {
        for j in 0..slices {
            let a = i * slices + j;
            let b = i * slices + (j + 1) % slices;
            let c = a + slices;
            let d = b + slices;
            t.push([a, b, d]);
            t.push([a, d, c]);
        }
    }
    Mesh::from_triangles(p, t, &NoProgress)
}

pub fn object(name: &str, mesh: Mesh, albedo: f32) -> Object {
    Object { name: name.into(), mesh: Arc::new(mesh), material: Material::diffuse(name, Vec3::splat(albedo)), transform: Affine3A::IDENTITY }
}

pub fn scene(objects: Vec<Object>, lights: Vec<Light>, ambient: f32) -> Scene {
    Scene {
        name: "test".into(),
        objects,
        lights,
        camera: Camera { eye: Vec3::new(0.0, 3.0, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 45.0 },
        ambient: Vec3::splat(ambient),
        background: Vec3::new(0.1, 0.2, 0.3),
        orbit: None,
    }
}

/// Irradiance at `p` (normal `n`) from a uniform polygon of radiance 1 wholly above the
/// point's tangent plane, either winding: Lambert's formula (`edgepoint_scene::polygon_irradiance`,
/// the exact polygon-to-point form factor times π).
pub fn polygon_irradiance(p: Vec3, n: Vec3, poly: &[Vec3]) -> f32 {
    let poly: Vec<_> = poly.iter().map(|v| v.as_dvec3()).collect();
    edgepoint_scene::polygon_irradiance::polygon_irradiance(p.as_dvec3(), n.as_dvec3(), &poly).abs() as f32
}

/// A shader's spec from its name and parameters (the others at their defaults).
pub fn spec(name: &str, kv: &[(&str, f64)]) -> ShaderSpec {
    ShaderSpec::parse(name, &kv.iter().map(|(k, v)| (k.to_string(), *v)).collect()).unwrap()
}

/// Rays through the pixel centres of a `w` × `h` image of the scene's camera, id = pixel index.
pub fn camera_rays(s: &Scene, w: u32, h: u32) -> Vec<RayRequest> {
    let cam = s.camera.frame(w, h);
    (0..w * h)
        .map(|i| {
            let (o, d) = cam.ray((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            RayRequest { id: i as u64, pixel: [i % w, i / w], origin: o, direction: d }
        })
        .collect()
}

/// Built-in scene `name`, loaded for shading, with its camera's `w` × `h` pixel-centre rays.
pub fn builtin_with_rays(name: &str, w: u32, h: u32) -> (LoadedScene, Vec<RayRequest>) {
    let s = edgepoint_scene::builtin::load(name).unwrap();
    let reqs = camera_rays(&s, w, h);
    (LoadedScene::build(s, name.into(), &NoProgress), reqs)
}

/// The mirror closed-form tests' objects: a smooth conductor floor (y = 0, 6 × 6, base colour
/// (1, 0.9, 0.8), complex index `eta` + i`k`) before a diffuse wall of albedo 0.6 at z = −2.
pub fn mirror_floor_and_wall(eta: Vec3, k: Vec3) -> Vec<Object> {
    let mut floor = object("floor", quad(0.0, 3.0, true), 0.0);
    floor.material.bsdf = Bsdf::Conductor { eta, k, roughness: 0.0 };
    floor.material.diffuse = Vec3::new(1.0, 0.9, 0.8);
    let wall_mesh = Mesh::from_triangles(
        vec![Vec3::new(-3.0, 0.0, -2.0), Vec3::new(3.0, 0.0, -2.0), Vec3::new(3.0, 4.0, -2.0), Vec3::new(-3.0, 4.0, -2.0)],
        vec![[0, 1, 2], [0, 2, 3]],
        &NoProgress,
    );
    let wall = Object { name: "wall".into(), mesh: Arc::new(wall_mesh), material: Material::diffuse("wall", Vec3::splat(0.6)), transform: Affine3A::IDENTITY };
    vec![floor, wall]
}
