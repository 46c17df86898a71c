//! Oracle for the `direct` shader's Lambertian path: the shader as it was before materials
//! (commit e30fa8d, kept verbatim below), against which every procedural built-in scene —
//! all `Bsdf::Diffuse`, two-sided, without per-corner normals — must shade to the same bits
//! and report the same light–blocker–receiver triples.
use crate::bvh::Instances;
use crate::loaded::{LoadedScene, PreparedLight};
use crate::rng::Rng;
use crate::shade::{push_unique, shade_batch, DirectParams, HitInfo, RayRequest, SampleOut, ShaderSpec};
use edgepoint_scene::NoProgress;
use glam::Vec3;
use std::collections::HashMap;
use std::f32::consts::FRAC_1_PI;

fn shade_direct_before_materials(
    scene: &LoadedScene,
    inst: &Instances,
    p: &DirectParams,
    seed: u64,
    r: &RayRequest,
) -> (SampleOut, Vec<[u32; 3]>, bool) {
    let s = &scene.scene;
    let len = r.direction.length();
    let mut triples = Vec::new();
    if !(len.is_finite() && len > 0.0 && r.origin.is_finite()) {
        return (SampleOut { id: r.id, hit: None, rgb: Vec3::ZERO }, triples, true);
    }
    let d = r.direction / len;
    let Some(h) = inst.closest_hit(&scene.bvh, r.origin, d, 0.0, f32::INFINITY) else {
        return (SampleOut { id: r.id, hit: None, rgb: s.background }, triples, false);
    };
    let obj = &s.objects[h.object as usize];
    let mat = &obj.material;
    let front = h.normal.dot(d) < 0.0;
    let n = if front { h.normal } else { -h.normal };
    let mut rgb = Vec3::ZERO;
    if front {
        rgb += mat.emission;
    }
    let albedo = mat.diffuse;
    let eps = scene.epsilon;
    let origin = h.position + n * eps;
    let mut rng = Rng::new(seed, r.id);
    for (li, light) in scene.lights.iter().enumerate() {
        let li = li as u32;
        match light {
            PreparedLight::Point { position, intensity } => {
                let to = *position - origin;
                let d2 = to.length_squared();
                let dist = d2.sqrt();
                let wi = to / dist;
                let cos = n.dot(wi);
                if cos <= 0.0 {
                    continue;
                }
                match inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)) {
                    Some(b) => push_unique(&mut triples, [li, b, h.object]),
                    None => rgb += albedo * FRAC_1_PI * *intensity * (cos / d2),
                }
            }
            PreparedLight::Area(a) => {
                // A point behind the emitting side, or a light wholly below the point's
                // tangent plane, receives nothing: no rays needed.
                if a.normal.dot(origin - a.centroid) <= 0.0 || a.vertices.iter().all(|v| n.dot(*v - origin) <= 0.0) {
                    continue;
                }
                let k = p.shadow_rays;
                let nx = (k as f32).sqrt().ceil() as u32;
                let ny = k.div_ceil(nx);
                let cells = nx * ny;
                let rot = (rng.next_u64() % cells as u64) as u32;
                let mut sum = Vec3::ZERO;
                for i in 0..k {
                    let c = (i + rot) % cells;
                    let u = ((c % nx) as f32 + rng.next_f32()) / nx as f32;
                    let v = ((c / nx) as f32 + rng.next_f32()) / ny as f32;
                    let q = a.sample(u, v);
                    let to = q - origin;
                    let d2 = to.length_squared();
                    let dist = d2.sqrt();
                    let wi = to / dist;
                    let cos_x = n.dot(wi);
                    let cos_l = -a.normal.dot(wi);
                    if cos_x <= 0.0 || cos_l <= 0.0 {
                        continue;
                    }
                    match inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)) {
                        Some(b) => push_unique(&mut triples, [li, b, h.object]),
                        None => sum += a.radiance * (cos_x * cos_l / d2),
                    }
                }
                rgb += albedo * FRAC_1_PI * sum * (a.area / k as f32);
            }
        }
    }
    rgb += albedo * s.ambient * p.ambient;
    let bad = !rgb.is_finite();
    if bad {
        rgb = Vec3::ZERO;
    }
    let local_normal = if front { h.local_normal } else { -h.local_normal }.normalize_or_zero();
    let hit = HitInfo { position: h.position, local_position: h.local, local_normal, normal: n, object: h.object, triangle: h.triangle, distance: h.t };
    (SampleOut { id: r.id, hit: Some(hit), rgb }, triples, bad)
}

#[test]
fn builtin_scenes_shade_exactly_as_before_materials() {
    for name in ["cornell", "cornell-point", "chains", "torus-capsule", "rooms"] {
        let s = edgepoint_scene::builtin::load(name).unwrap();
        let cam = s.camera.frame(48, 48);
        let loaded = LoadedScene::build(s, name.into(), &NoProgress);
        let inst = loaded.instances(&loaded.default_transforms());
        for params in [HashMap::new(), HashMap::from([("shadow_rays".to_string(), 5.0), ("ambient".to_string(), 0.3)])] {
            let spec = ShaderSpec::parse("direct", &params).unwrap();
            let ShaderSpec::Direct(dp) = spec.clone();
            let reqs: Vec<RayRequest> = (0..48 * 48)
                .map(|i| {
                    let (o, d) = cam.ray((i % 48) as f32 + 0.37, (i / 48) as f32 + 0.61);
                    RayRequest { id: i as u64 * 7 + 3, pixel: [i % 48, i / 48], origin: o, direction: d }
                })
                .collect();
            let now = shade_batch(&loaded, &inst, &spec, 99, &reqs);
            let mut triples = std::collections::BTreeSet::new();
            let mut lit = 0;
            for (r, got) in reqs.iter().zip(&now.samples) {
                let (want, t, _) = shade_direct_before_materials(&loaded, &inst, &dp, 99, r);
                triples.extend(t);
                assert_eq!(got.hit, want.hit, "{name}: hit of request {}", r.id);
                assert_eq!(got.rgb.to_array().map(f32::to_bits), want.rgb.to_array().map(f32::to_bits), "{name}: {} vs {}", got.rgb, want.rgb);
                lit += (want.rgb.max_element() > 0.0) as u32;
            }
            assert_eq!(now.triples, triples.into_iter().collect::<Vec<_>>(), "{name}: triples");
            assert!(lit > 48 * 48 / 2, "{name}: the oracle comparison saw lit samples ({lit})");
        }
    }
}

/// The oracle's own inputs are sound: a diffuse point's shading differs when its albedo
/// does (so bit-equality above cannot come from both sides ignoring the material).
#[test]
fn the_oracle_reads_the_albedo() {
    let mut s = edgepoint_scene::builtin::load("cornell-point").unwrap();
    let cam = s.camera.frame(8, 8);
    let (o, d) = cam.ray(4.0, 6.0);
    let r = RayRequest { id: 1, pixel: [4, 6], origin: o, direction: d };
    let shade = |s: edgepoint_scene::Scene| {
        let loaded = LoadedScene::build(s, "t".into(), &NoProgress);
        let inst = loaded.instances(&loaded.default_transforms());
        shade_direct_before_materials(&loaded, &inst, &DirectParams::default(), 1, &r).0.rgb
    };
    let a = shade(s.clone());
    for o in &mut s.objects {
        o.material.diffuse *= 0.5;
    }
    let b = shade(s);
    assert!((a * 0.5 - b).abs().max_element() < 1e-5 && a.max_element() > 0.0, "{a} {b}");
}
