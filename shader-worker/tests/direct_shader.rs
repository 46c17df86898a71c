//! The `direct` shader against closed-form values.
mod common_scenes;
use common_scenes::*;
use edgepoint_scene::{Light, NoProgress, Scene};
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, ShaderSpec};
use glam::Vec3;
use std::collections::HashMap;
use std::f32::consts::PI;

fn shade_one(scene: Scene, origin: Vec3, target: Vec3, params: &[(&str, f64)]) -> edgepoint_worker::ShadeOutput {
    let loaded = LoadedScene::build(scene, "t".into(), &NoProgress);
    let inst = loaded.instances(&loaded.default_transforms());
    let p: HashMap<String, f64> = params.iter().map(|(k, v)| (k.to_string(), *v)).collect();
    let spec = ShaderSpec::parse("direct", &p).unwrap();
    let r = RayRequest { id: 7, pixel: [0, 0], origin, direction: target - origin };
    shade_batch(&loaded, &inst, &spec, 42, &[r])
}

#[test]
fn point_light_on_a_plane_is_exact() {
    let i = Vec3::new(2.0, 1.5, 1.0);
    let s = scene(vec![object("floor", quad(0.0, 10.0, true), 0.6)], vec![Light::Point { position: Vec3::new(0.0, 1.0, 0.0), intensity: i }], 0.05);
    let hitp = Vec3::new(0.5, 0.0, 0.25);
    let out = shade_one(s, Vec3::new(0.5, 3.0, 2.0), hitp, &[]);
    let h = out.samples[0].hit.unwrap();
    assert!((h.position - hitp).length() < 1e-5);
    let to = Vec3::new(0.0, 1.0, 0.0) - hitp;
    let expect = Vec3::splat(0.6) / PI * i * (to.normalize().y / to.length_squared()) + Vec3::splat(0.6 * 0.05);
    assert!((out.samples[0].rgb - expect).abs().max_element() < 1e-4, "{} vs {expect}", out.samples[0].rgb);
    assert!(out.triples.is_empty());
    assert_eq!(out.visible, vec![0]);
}

#[test]
fn square_area_light_matches_lambert_formula() {
    let h = 0.8;
    let poly = vec![Vec3::new(-0.3, h, -0.3), Vec3::new(0.3, h, -0.3), Vec3::new(0.3, h, 0.3), Vec3::new(-0.3, h, 0.3)];
    let light = Light::Area { vertices: poly.clone(), radiance: Vec3::splat(5.0) };
    assert!(light.normal().unwrap().y < 0.0, "light faces down");
    let s = scene(vec![object("floor", quad(0.0, 10.0, true), 0.5)], vec![light], 0.0);
    for p in [Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.7, 0.0, -0.2)] {
        let out = shade_one(s.clone(), p + Vec3::new(0.1, 2.0, 0.3), p, &[("shadow_rays", 4096.0)]);
        let e = polygon_irradiance(p, Vec3::Y, &poly) * 5.0;
        let expect = 0.5 / PI * e;
        let got = out.samples[0].rgb.x;
        assert!((got - expect).abs() / expect < 0.02, "at {p}: {got} vs {expect}");
    }
}

#[test]
fn a_blocker_casts_a_shadow_and_reports_the_triple() {
    let s = scene(
        vec![object("floor", quad(0.0, 10.0, true), 0.5), object("blocker", quad(0.5, 0.2, false), 0.5)],
        vec![Light::Point { position: Vec3::new(0.0, 1.0, 0.0), intensity: Vec3::ONE }],
        0.1,
    );
    let out = shade_one(s.clone(), Vec3::new(0.0, 0.3, 3.0), Vec3::new(0.0, 0.0, 0.0), &[]);
    assert_eq!(out.samples[0].hit.unwrap().object, 0);
    assert!((out.samples[0].rgb - Vec3::splat(0.05)).abs().max_element() < 1e-5, "only ambient in the shadow");
    assert_eq!(out.triples, vec![[0, 1, 0]]);
    // Outside the shadow the light is seen, and nothing is reported.
    let out = shade_one(s, Vec3::new(2.0, 0.3, 3.0), Vec3::new(2.0, 0.0, 0.0), &[]);
    assert!(out.samples[0].rgb.x > 0.05 + 1e-3);
    assert!(out.triples.is_empty());
}

#[test]
fn emission_is_seen_from_the_front_only_and_misses_get_background() {
    let mut lum = object("lum", quad(1.0, 0.5, false), 0.0);
    lum.material.emission = Vec3::new(3.0, 2.0, 1.0);
    let s = scene(vec![lum], vec![], 0.0);
    let below = shade_one(s.clone(), Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.1, 1.0, 0.0), &[]);
    assert_eq!(below.samples[0].rgb, Vec3::new(3.0, 2.0, 1.0));
    let above = shade_one(s.clone(), Vec3::new(0.0, 2.0, 0.0), Vec3::new(0.1, 1.0, 0.0), &[]);
    assert_eq!(above.samples[0].rgb, Vec3::ZERO);
    let miss = shade_one(s, Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, -1.0, 0.0), &[]);
    assert!(miss.samples[0].hit.is_none());
    assert_eq!(miss.samples[0].rgb, Vec3::new(0.1, 0.2, 0.3));
}

#[test]
fn shader_parameters_are_checked() {
    let p = |k: &str, v: f64| HashMap::from([(k.to_string(), v)]);
    assert!(ShaderSpec::parse("direct", &p("shadow_rays", 0.0)).is_err());
    assert!(ShaderSpec::parse("direct", &p("shadow_rays", f64::NAN)).is_err());
    assert!(ShaderSpec::parse("direct", &p("bogus", 1.0)).unwrap_err().contains("shadow_rays"));
    assert!(ShaderSpec::parse("phong", &HashMap::new()).unwrap_err().contains("direct, glossy, gi"));
    assert!(ShaderSpec::parse("", &HashMap::new()).is_ok());
}

#[test]
fn shading_is_reproducible_and_cornell_is_lit() {
    let s = edgepoint_scene::builtin::load("cornell").unwrap();
    let cam = s.camera.frame(64, 64);
    let loaded = LoadedScene::build(s, "c".into(), &NoProgress);
    let inst = loaded.instances(&loaded.default_transforms());
    let spec = ShaderSpec::parse("direct", &HashMap::new()).unwrap();
    let reqs: Vec<RayRequest> = (0..64 * 64)
        .map(|i| {
            let (o, d) = cam.ray((i % 64) as f32 + 0.5, (i / 64) as f32 + 0.5);
            RayRequest { id: i as u64, pixel: [i % 64, i / 64], origin: o, direction: d }
        })
        .collect();
    let a = shade_batch(&loaded, &inst, &spec, 5, &reqs);
    let b = shade_batch(&loaded, &inst, &spec, 5, &reqs);
    assert_eq!(a.samples, b.samples);
    assert_eq!(a.nonfinite, 0);
    let hits = a.samples.iter().filter(|s| s.hit.is_some()).count();
    assert!(hits as f32 > 0.9 * a.samples.len() as f32, "the camera mostly sees the box ({hits} hits)");
    let mean: Vec3 = a.samples.iter().map(|s| s.rgb).sum::<Vec3>() / a.samples.len() as f32;
    assert!(mean.x > 0.05 && mean.x < 5.0, "plausible brightness {mean}");
    // The boxes shadow the floor: triples (area light 0, box, floor) appear.
    let floor = loaded.scene.object_id("floor").unwrap();
    assert!(a.triples.iter().any(|t| t[0] == 0 && t[2] == floor));
    assert!(a.visible.len() >= 6);
}

/// Issue 12 item 8: the worker offers exactly the shaders of the shared table, and parses
/// them with the table's ranges and defaults (the server checks `start` against the same).
#[test]
fn the_worker_offers_the_shared_table() {
    let table: Vec<&str> = edgepoint_proto::shaders::SHADERS.iter().map(|s| s.name).collect();
    assert_eq!(edgepoint_worker::SHADERS, table.as_slice());
    for s in edgepoint_proto::shaders::SHADERS {
        ShaderSpec::parse(s.name, &HashMap::new()).unwrap_or_else(|e| panic!("{}: {e}", s.name));
    }
    let d = edgepoint_worker::DirectParams::default();
    assert_eq!((d.shadow_rays, d.ambient), (16, 1.0));
}

/// Per pixel of `reqs`, the mean and standard error over `seeds` of the sampled `direct`
/// with `rays` shadow rays (red channel, the brightest in cornell's light).
fn sampled_mean_and_error(loaded: &LoadedScene, reqs: &[RayRequest], rays: f64, seeds: u64) -> Vec<(f64, f64)> {
    let inst = loaded.instances(&loaded.default_transforms());
    let sampled = spec("direct", &[("shadow_rays", rays)]);
    let runs: Vec<Vec<f64>> = (0..seeds).map(|seed| shade_batch(loaded, &inst, &sampled, 1000 + seed, reqs).samples.iter().map(|s| s.rgb.x as f64).collect()).collect();
    (0..reqs.len())
        .map(|i| {
            let n = seeds as f64;
            let m = runs.iter().map(|r| r[i]).sum::<f64>() / n;
            let var = runs.iter().map(|r| (r[i] - m).powi(2)).sum::<f64>() / (n - 1.0);
            (m, (var / n).sqrt())
        })
        .collect()
}

/// How far `exact` lies from the sampled means: per pixel |exact − mean| over its standard
/// error (with a float floor), the worst and the mean of their squares (≈ 1 when the sampled
/// estimate scatters around `exact` by its own noise alone).
fn z_scores(exact: &[f64], sampled: &[(f64, f64)]) -> (f64, f64) {
    let z: Vec<f64> = exact.iter().zip(sampled).map(|(e, (m, se))| (e - m).abs() / (se + 1e-4 * e.abs() + 1e-6)).collect();
    (z.iter().copied().fold(0.0, f64::max), z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64)
}

/// Issue 15 item 2: `area=exact` on cornell (its ceiling light is an area light, two boxes
/// cast soft shadows) equals the sampled `direct` with 16 seeds × 1024 shadow rays to within the
/// sampled estimate's noise at every pixel, and the comparison is sharp: the same check
/// rejects the exact shading of the room without its boxes (no shadows).
#[test]
fn exact_area_light_matches_many_shadow_rays_on_cornell() {
    let (loaded, reqs) = builtin_with_rays("cornell", 32, 32);
    let inst = loaded.instances(&loaded.default_transforms());
    let exact_spec = spec("direct", &[("area", 1.0)]);
    let out = shade_batch(&loaded, &inst, &exact_spec, 1, &reqs);
    let again = shade_batch(&loaded, &inst, &exact_spec, 2, &reqs);
    assert_eq!(out.samples, again.samples, "no noise: the seed changes nothing");
    let exact: Vec<f64> = out.samples.iter().map(|s| s.rgb.x as f64).collect();
    let sampled = sampled_mean_and_error(&loaded, &reqs, 1024.0, 16);
    let (worst, mean_sq) = z_scores(&exact, &sampled);
    eprintln!("cornell 32x32: exact vs 16 x 1024 shadow rays: worst z {worst:.2}, mean z^2 {mean_sq:.3}");
    assert!(worst < 6.0 && mean_sq < 1.5, "worst z {worst}, mean z^2 {mean_sq}");
    // The boxes are reported as blockers of the floor, as the shadow rays report them.
    let floor = loaded.scene.object_id("floor").unwrap();
    for b in ["shortbox", "tallbox"] {
        let b = loaded.scene.object_id(b).unwrap();
        assert!(out.triples.contains(&[0, b, floor]), "{b} shadows the floor: {:?}", out.triples);
    }
    // Without the boxes the exact shading no longer matches: penumbrae are missed.
    let mut open = (*loaded.scene).clone();
    open.objects.retain(|o| !o.name.ends_with("box"));
    let open = LoadedScene::build(open, "open".into(), &NoProgress);
    let unshadowed: Vec<f64> = shade_batch(&open, &open.instances(&open.default_transforms()), &exact_spec, 1, &reqs).samples.iter().map(|s| s.rgb.x as f64).collect();
    let (worst_open, _) = z_scores(&unshadowed, &sampled);
    assert!(worst_open > 20.0, "the check sees the missing shadows (worst z {worst_open})");
}
