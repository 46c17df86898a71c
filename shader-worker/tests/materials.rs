//! The `direct` shader with each material on spheres and planes, against closed forms:
//! Lambert's radiance under a point light, a mirror showing an area light at the mirror
//! direction with the conductor's Fresnel value, glass and plastic coats reflecting it with
//! the dielectric Fresnel value, plastic's diffuse term, rough lobes under an area light
//! against quadrature over the light (the MIS estimate must be unbiased), sidedness and
//! textures.
mod common_scenes;
use common_scenes::*;
use edgepoint_scene::material::{fresnel, Frame, Scatter};
use edgepoint_scene::{Bsdf, Light, Material, NoProgress, Scene, Texture};
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, SampleOut, ShaderSpec};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::f32::consts::PI;
use std::sync::Arc;

fn shade(scene: &Scene, rays: &[(Vec3, Vec3)], params: &[(&str, f64)], seed: u64) -> Vec<SampleOut> {
    let loaded = LoadedScene::build(scene.clone(), "t".into(), &NoProgress);
    let inst = loaded.instances(&loaded.default_transforms());
    let p: HashMap<String, f64> = params.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    let spec = ShaderSpec::parse("direct", &p).unwrap();
    let reqs: Vec<RayRequest> = rays.iter().enumerate().map(|(i, (o, d))| RayRequest { id: i as u64, pixel: [0, 0], origin: *o, direction: *d }).collect();
    let out = shade_batch(&loaded, &inst, &spec, seed, &reqs);
    assert_eq!(out.nonfinite, 0);
    out.samples
}

/// Rays from `eye` through a grid of points covering the unit sphere's disc as seen from it.
fn rays_at_sphere(eye: Vec3, n: usize) -> Vec<(Vec3, Vec3)> {
    let f = Frame::from_normal((-eye).normalize());
    let mut v = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let x = -1.1 + 2.2 * (i as f32 + 0.5) / n as f32;
            let y = -1.1 + 2.2 * (j as f32 + 0.5) / n as f32;
            let target = f.s * x + f.t * y;
            v.push((eye, target - eye));
        }
    }
    v
}

fn sphere_scene(bsdf: Bsdf, base: Vec3, lights: Vec<Light>) -> Scene {
    let mut o = object("ball", sphere(64, 128), 0.0);
    o.material = Material { bsdf, diffuse: base, ..Material::diffuse("ball", base) };
    scene(vec![o], lights, 0.0)
}

fn square_light(y: f32, half: f32, radiance: f32) -> (Light, Vec<Vec3>) {
    // Wound to face down.
    let v = vec![Vec3::new(-half, y, -half), Vec3::new(half, y, -half), Vec3::new(half, y, half), Vec3::new(-half, y, half)];
    let l = Light::Area { vertices: v.clone(), radiance: Vec3::splat(radiance) };
    assert!(l.normal().unwrap().y < 0.0);
    (l, v)
}

/// Where the mirror reflection of a view ray at a hit meets the square light of half-size
/// `half` at height `y` (well inside it, away from the edges, when `margin` > 0).
fn mirror_hits_light(hit: Vec3, n: Vec3, view: Vec3, y: f32, half: f32, margin: f32) -> Option<f32> {
    let r = fresnel::reflect(-view, n);
    if r.y <= 0.0 {
        return None;
    }
    let t = (y - hit.y) / r.y;
    let q = hit + r * t;
    (q.x.abs() < half - margin && q.z.abs() < half - margin).then_some(n.dot(-view))
}

#[test]
fn lambertian_sphere_under_a_point_light_has_lamberts_radiance() {
    let (lp, i) = (Vec3::new(2.0, 3.0, 1.0), Vec3::new(4.0, 3.0, 2.0));
    let s = sphere_scene(Bsdf::Diffuse, Vec3::new(0.8, 0.5, 0.2), vec![Light::Point { position: lp, intensity: i }]);
    let eye = Vec3::new(0.5, 1.0, 4.0);
    let rays = rays_at_sphere(eye, 40);
    let mut lit = 0;
    for (s, _) in shade(&s, &rays, &[], 1).iter().zip(&rays) {
        let Some(h) = s.hit else { continue };
        let to = lp - h.position;
        let cos = h.normal.dot(to.normalize()).max(0.0);
        let expect = Vec3::new(0.8, 0.5, 0.2) / PI * i * cos / to.length_squared();
        assert!((s.rgb - expect).abs().max_element() <= 1e-3 * expect.max_element() + 1e-4, "{} vs {expect}", s.rgb);
        lit += (cos > 0.0) as u32;
    }
    assert!(lit > 300, "{lit}");
}

#[test]
fn smooth_sphere_coats_reflect_the_area_light_with_their_fresnel_value() {
    let (y, half, radiance) = (3.0, 1.5, 5.0);
    let (light, _) = square_light(y, half, radiance);
    let gold_eta = Vec3::new(0.143, 0.374, 1.442);
    let gold_k = Vec3::new(3.983, 2.385, 1.603);
    let tint = Vec3::new(0.9, 0.8, 0.7);
    let eye = Vec3::new(0.0, 0.6, 4.0);
    let rays = rays_at_sphere(eye, 48);
    for (bsdf, base) in [
        (Bsdf::Conductor { eta: gold_eta, k: gold_k, roughness: 0.0 }, tint),
        (Bsdf::Dielectric { ior: 1.5, roughness: 0.0 }, tint),
        (Bsdf::Plastic { ior: 1.5, roughness: 0.0 }, Vec3::ZERO),
    ] {
        let s = sphere_scene(bsdf.clone(), base, vec![light.clone()]);
        let (mut inside, mut outside) = (0, 0);
        for (out, (o, d)) in shade(&s, &rays, &[], 3).iter().zip(&rays) {
            let Some(h) = out.hit else { continue };
            let view = d.normalize();
            // The sphere's facets: use the facet normal the hit reports (the shader does too,
            // the mesh has no per-corner normals).
            match mirror_hits_light(h.position, h.normal, view, y, half, 0.05) {
                Some(cos) => {
                    let f = match &bsdf {
                        Bsdf::Conductor { eta, k, .. } => base * fresnel::conductor(cos, *eta, *k),
                        Bsdf::Dielectric { ior, .. } | Bsdf::Plastic { ior, .. } => Vec3::splat(fresnel::dielectric(cos, *ior)),
                        Bsdf::Diffuse => unreachable!(),
                    };
                    let expect = f * radiance;
                    assert!((out.rgb - expect).abs().max_element() < 1e-3 * radiance, "{bsdf:?} at {o}: {} vs {expect}", out.rgb);
                    inside += 1;
                }
                None if mirror_hits_light(h.position, h.normal, view, y, half, -0.05).is_none() => {
                    assert_eq!(out.rgb, Vec3::ZERO, "{bsdf:?}: nothing but the light's reflection");
                    outside += 1;
                }
                None => {}
            }
        }
        assert!(inside > 20 && outside > 100, "{bsdf:?}: {inside} {outside}");
    }
}

#[test]
fn plastic_diffuse_term_under_a_point_light_and_its_highlight_below_the_coat_fresnel() {
    let (lp, i) = (Vec3::new(-1.0, 2.5, 2.0), Vec3::splat(6.0));
    let base = Vec3::new(0.7, 0.4, 0.1);
    let eta = 1.5f32;
    let s = sphere_scene(Bsdf::Plastic { ior: eta, roughness: 0.0 }, base, vec![Light::Point { position: lp, intensity: i }]);
    let eye = Vec3::new(0.0, 1.0, 4.0);
    let rays = rays_at_sphere(eye, 32);
    let fdr_int = fresnel::diffuse_reflectance(1.0 / eta);
    for (out, (_, d)) in shade(&s, &rays, &[], 1).iter().zip(&rays) {
        let Some(h) = out.hit else { continue };
        let to = lp - h.position;
        let l = to.normalize();
        let (cos_i, cos_o) = (h.normal.dot(l), h.normal.dot(-d.normalize()));
        let f = if cos_i > 0.0 {
            base / (1.0 - fdr_int) * (1.0 - fresnel::dielectric(cos_i, eta)) * (1.0 - fresnel::dielectric(cos_o, eta)) / (eta * eta * PI)
        } else {
            Vec3::ZERO
        };
        let expect = f * i * cos_i.max(0.0) / to.length_squared();
        assert!((out.rgb - expect).abs().max_element() <= 1e-3 * expect.max_element() + 1e-5, "{} vs {expect}", out.rgb);
    }
    // A rough black plastic's highlight of a light it sees whole is at most the light's
    // radiance times the coat's largest Fresnel reflectance over the light's directions —
    // and near the mirror direction of a smooth-ish coat, close to F.
    let (y, half, radiance) = (3.0, 1.5, 5.0);
    let (light, _) = square_light(y, half, radiance);
    let s = sphere_scene(Bsdf::Plastic { ior: eta, roughness: 0.05 }, Vec3::ZERO, vec![light]);
    let rays = rays_at_sphere(Vec3::new(0.0, 0.6, 4.0), 40);
    let mut near = 0;
    for (out, (_, d)) in shade(&s, &rays, &[("shadow_rays", 64.0)], 2).iter().zip(&rays) {
        let Some(h) = out.hit else { continue };
        let view = d.normalize();
        assert!(out.rgb.max_element() <= radiance * 1.0, "{}", out.rgb);
        if let Some(cos) = mirror_hits_light(h.position, h.normal, view, y, half, 0.6) {
            let f = fresnel::dielectric(cos, eta) * radiance;
            assert!(out.rgb.x <= f * 1.1 && out.rgb.x >= f * 0.8, "highlight {} vs coat Fresnel x L = {f}", out.rgb.x);
            near += 1;
        }
    }
    assert!(near > 5, "{near}");
}

/// Reflected radiance from a square light by quadrature over the light (n×n midpoints).
fn quadrature(bsdf: &Bsdf, base: Vec3, p: Vec3, eye: Vec3, poly: &[Vec3], radiance: f32) -> Vec3 {
    let s = bsdf.at(base);
    let f = Frame::from_normal(Vec3::Y);
    let wo = f.to_local((eye - p).normalize());
    let (a, b, d) = (poly[0], poly[1], poly[3]);
    let n = 400;
    let area = (b - a).cross(d - a).length();
    let ln = (b - a).cross(d - a).normalize();
    let mut sum = Vec3::ZERO;
    for i in 0..n {
        for j in 0..n {
            let q = a + (b - a) * ((i as f32 + 0.5) / n as f32) + (d - a) * ((j as f32 + 0.5) / n as f32);
            let to = q - p;
            let d2 = to.length_squared();
            let wi = to / d2.sqrt();
            let cos_l = ln.dot(-wi).abs();
            let wl = f.to_local(wi);
            sum += s.eval(wo, wl) * wl.z.max(0.0) * cos_l / d2;
        }
    }
    sum * radiance * area / (n * n) as f32
}

#[test]
fn rough_lobes_under_an_area_light_match_quadrature() {
    let (y, half, radiance) = (1.0, 0.4, 4.0);
    let (light, poly) = square_light(y, half, radiance);
    let cases = [
        (Bsdf::Conductor { eta: Vec3::new(0.2, 0.9, 1.1), k: Vec3::new(3.9, 2.4, 2.2), roughness: 0.1 }, Vec3::ONE),
        (Bsdf::Conductor { eta: Vec3::splat(1.5), k: Vec3::splat(3.0), roughness: 0.4 }, Vec3::new(0.9, 0.7, 0.5)),
        (Bsdf::Plastic { ior: 1.5, roughness: 0.2 }, Vec3::new(0.6, 0.3, 0.2)),
        (Bsdf::Dielectric { ior: 1.5, roughness: 0.15 }, Vec3::ONE),
    ];
    for (bsdf, base) in cases {
        let mut floor = object("floor", quad(0.0, 10.0, true), 0.0);
        floor.material = Material { bsdf: bsdf.clone(), ..Material::diffuse("floor", base) };
        let s = scene(vec![floor], vec![light.clone()], 0.0);
        let eye = Vec3::new(0.0, 0.8, 1.6);
        // Points near and away from the highlight of the light's mirror image.
        for p in [Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.0, 0.0, 0.3), Vec3::new(0.3, 0.0, 0.0), Vec3::new(-0.2, 0.0, -0.3)] {
            let expect = quadrature(&bsdf, base, p, eye, &poly, radiance);
            let reps = 64;
            let rays = vec![(eye, p - eye); reps];
            let got: Vec3 = (0..reps as u64).map(|seed| shade(&s, &rays[..1], &[("shadow_rays", 16.0)], seed)[0].rgb).sum::<Vec3>() / reps as f32;
            let tol = 0.03 * expect.max_element() + 1e-4;
            assert!((got - expect).abs().max_element() <= tol, "{bsdf:?} at {p}: {got} vs quadrature {expect}");
        }
    }
}

#[test]
fn one_sided_surfaces_are_black_from_behind_and_two_sided_ones_are_not() {
    let light = Light::Point { position: Vec3::new(0.3, -1.0, -0.2), intensity: Vec3::ONE };
    for two_sided in [true, false] {
        // A quad facing up, lit and seen from below (light 1 unit straight below the hit).
        let mut o = object("q", quad(0.0, 2.0, true), 0.5);
        o.material.two_sided = two_sided;
        let s = scene(vec![o], vec![light.clone()], 0.2);
        let out = shade(&s, &[(Vec3::new(0.3, -2.0, -0.2), Vec3::new(0.0, 1.0, 0.0))], &[], 1);
        assert!(out[0].hit.is_some());
        if two_sided {
            let expect = 0.5 / PI * 1.0 + 0.5 * 0.2;
            assert!((out[0].rgb.x - expect).abs() < 1e-4, "{}", out[0].rgb);
        } else {
            assert_eq!(out[0].rgb, Vec3::ZERO);
        }
    }
}

#[test]
fn textures_and_shading_normals_come_from_the_corners() {
    // A quad with UVs across it and a 2×1 texture: left half red, right half blue.
    let mut mesh = quad(0.0, 1.0, true);
    let uv_of = |p: Vec3| Vec2::new((p.x + 1.0) / 2.0, (p.z + 1.0) / 2.0);
    mesh.corners.uvs = Some(mesh.triangles.iter().map(|t| t.map(|i| uv_of(mesh.positions[i as usize]))).collect());
    let tex = Texture { name: "rb".into(), width: 2, height: 1, texels: vec![Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 1.0)] };
    let mut o = object("q", mesh, 0.5);
    o.material.texture = Some(Arc::new(tex));
    let s = scene(vec![o], vec![], 1.0);
    let eye = Vec3::new(0.0, 3.0, 0.0);
    let out = shade(&s, &[(eye, Vec3::new(-0.6, -3.0, 0.1)), (eye, Vec3::new(0.6, -3.0, 0.1))], &[], 1);
    // Only ambient (1) × base (0.5) × texel, bilinear: at u = 0.2 and 0.8 the texel centres
    // wrap (0.25 / 0.75 are the centres), so the colours mix in known proportions.
    let t0 = 0.5 * (Vec3::new(1.0, 0.0, 0.0) * 0.9 + Vec3::new(0.0, 0.0, 1.0) * 0.1);
    assert!((out[0].rgb - t0).abs().max_element() < 1e-4, "{}", out[0].rgb);
    let t1 = 0.5 * (Vec3::new(1.0, 0.0, 0.0) * 0.1 + Vec3::new(0.0, 0.0, 1.0) * 0.9);
    assert!((out[1].rgb - t1).abs().max_element() < 1e-4, "{}", out[1].rgb);

    // A flat quad whose corner normals all tilt 60° toward +x: a point light straight above
    // shades it with the tilted normal's cosine (1/2), not the face's (1).
    let mut mesh = quad(0.0, 1.0, true);
    let tilted = Vec3::new(3f32.sqrt() / 2.0, 0.5, 0.0);
    mesh.corners.normals = Some(vec![[tilted; 3]; mesh.triangles.len()]);
    let o = object("q", mesh, 0.5);
    let s = scene(vec![o], vec![Light::Point { position: Vec3::new(0.0, 1.0, 0.0), intensity: Vec3::ONE }], 0.0);
    let out = shade(&s, &[(Vec3::new(1.0, 2.0, 0.0), Vec3::new(-1.0, -2.0, 0.0))], &[], 1);
    let expect = 0.5 / PI * 0.5;
    assert!((out[0].rgb.x - expect).abs() < 1e-4, "{} vs {expect}", out[0].rgb);
    // The hit still reports the face normal (the edge finder's geometry).
    assert!((out[0].hit.unwrap().normal - Vec3::Y).length() < 1e-6);
}
