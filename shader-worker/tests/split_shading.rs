//! Split shading (paper 004 §4.4): the parts of a sample, shaded with the same seed, add up
//! to the whole shading. Every part draws the random numbers the whole shading draws (it
//! skips those of the lights it does not shade), so the sum differs from the whole sample
//! only by the order of float additions — bounded here at 2e-6 of the sample (measured:
//! under 1e-6) — not by noise; the parts' triples make up the whole sample's triples, each
//! part reporting only its own lights; every part finds the same first hit.
use edgepoint_scene::NoProgress;
use edgepoint_worker::{shade_batch, shade_batch_parts, LoadedScene, Part, RayRequest, ShadeOutput, ShaderSpec};
use std::collections::{BTreeSet, HashMap};

fn spec(name: &str, kv: &[(&str, f64)]) -> ShaderSpec {
    ShaderSpec::parse(name, &kv.iter().map(|(k, v)| (k.to_string(), *v)).collect::<HashMap<_, _>>()).unwrap()
}

fn load(name: &str) -> LoadedScene {
    LoadedScene::build(edgepoint_scene::builtin::load(name).unwrap(), name.into(), &NoProgress)
}

/// Jittered rays over a `w` × `h` image of the scene's camera.
fn rays(s: &LoadedScene, w: u32, h: u32) -> Vec<RayRequest> {
    let cam = s.scene.camera.frame(w, h);
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let j = ((i as f32 * 0.618_034).fract(), (i as f32 * 0.414_214).fract());
            let (o, d) = cam.ray(x as f32 + j.0, y as f32 + j.1);
            RayRequest { id: 1000 + i as u64, pixel: [x, y], origin: o, direction: d }
        })
        .collect()
}

/// Shades `reqs` whole and in `count` parts; checks the parts against the whole. Returns the
/// largest relative difference of a sample's radiance.
fn check(scene: &LoadedScene, spec: &ShaderSpec, reqs: &[RayRequest], count: u32) -> f32 {
    let inst = scene.instances(&scene.default_transforms());
    let seed = 0xfeed;
    let whole = shade_batch(scene, &inst, spec, seed, reqs);
    let parts: Vec<ShadeOutput> = (0..count)
        .map(|index| shade_batch_parts(scene, &inst, spec, seed, reqs, &vec![Part { index, count }; reqs.len()]))
        .collect();
    let mut worst = 0.0f32;
    for (i, w) in whole.samples.iter().enumerate() {
        let mut sum = glam::DVec3::ZERO;
        for p in &parts {
            let s = &p.samples[i];
            assert_eq!(s.id, w.id);
            assert_eq!(s.hit, w.hit, "every part finds the whole sample's first hit");
            sum += s.rgb.as_dvec3();
        }
        let sum = sum.as_vec3();
        let scale = w.rgb.max_element().max(1e-3);
        let rel = (sum - w.rgb).abs().max_element() / scale;
        assert!(rel <= 2e-6, "request {}: parts add up to {sum}, whole {} ({count} parts)", w.id, w.rgb);
        worst = worst.max(rel);
    }
    let mut union = BTreeSet::new();
    for (index, p) in parts.iter().enumerate() {
        for t in &p.triples {
            assert_eq!(t[0] % count, index as u32, "part {index} of {count} reports only its own lights: {t:?}");
            union.insert(*t);
        }
        assert_eq!(p.nonfinite, whole.nonfinite);
    }
    assert_eq!(union, whole.triples.iter().copied().collect::<BTreeSet<_>>(), "the parts' triples are the whole's");
    worst
}

#[test]
fn direct_parts_add_up_to_the_whole_sample() {
    let rooms = load("rooms");
    let reqs = rays(&rooms, 48, 32);
    let p = spec("direct", &[("shadow_rays", 8.0)]);
    for count in [2, 3, 6, 7] {
        check(&rooms, &p, &reqs, count);
    }
    // Metals, glass and plastic under an area and a point light: light samples, BSDF samples
    // toward the area light (delta and rough lobes) and the ambient term all split.
    let mats = load("materials");
    let reqs = rays(&mats, 48, 32);
    for count in [2, 3] {
        check(&mats, &p, &reqs, count);
    }
}

#[test]
fn glossy_and_gi_parts_add_up_to_the_whole_sample() {
    let mats = load("materials");
    let reqs = rays(&mats, 32, 24);
    check(&mats, &spec("glossy", &[("shadow_rays", 4.0)]), &reqs, 2);
    // The irradiance cache off: with it, which records exist depends on the order of shading.
    check(&mats, &spec("gi", &[("cache", 0.0)]), &reqs, 2);
    let rooms = load("rooms");
    let reqs = rays(&rooms, 32, 24);
    check(&rooms, &spec("gi", &[("cache", 0.0), ("max_depth", 4.0)]), &reqs, 4);
}

#[test]
fn hybrid_parts_add_up_to_the_whole_sample() {
    // Parts share the lights by index and the virtual point lights by contiguous ranges;
    // the Cornell box with a glass sphere and a mirror adds the specular tree.
    let glass = load("cornell-glass");
    let reqs = rays(&glass, 32, 24);
    let p = spec("hybrid", &[("shadow_rays", 4.0), ("vpls", 24.0), ("elements", 256.0)]);
    for count in [2, 3, 5] {
        check(&glass, &p, &reqs, count);
    }
    let rooms = load("rooms");
    let reqs = rays(&rooms, 32, 24);
    check(&rooms, &p, &reqs, 4);
}
