//! Oracle for the `direct` shader's Lambertian path: the shader as it was before materials
//! ([`crate::baseline`]), against which every procedural built-in scene —
//! all `Bsdf::Diffuse`, two-sided, without per-corner normals — must shade to the same bits
//! and report the same light–blocker–receiver triples.
use crate::baseline::shade_direct_before_materials;
use crate::loaded::LoadedScene;
use crate::shader::{shade_batch, DirectParams, RayRequest, ShaderSpec};
use edgepoint_scene::NoProgress;
use std::collections::HashMap;

#[test]
fn builtin_scenes_shade_exactly_as_before_materials() {
    for name in ["cornell", "cornell-point", "chains", "torus-capsule", "rooms"] {
        let s = edgepoint_scene::builtin::load(name).unwrap();
        let cam = s.camera.frame(48, 48);
        let loaded = LoadedScene::build(s, name.into(), &NoProgress);
        let inst = loaded.instances(&loaded.default_transforms());
        for params in [HashMap::new(), HashMap::from([("shadow_rays".to_string(), 5.0), ("ambient".to_string(), 0.3)])] {
            let spec = ShaderSpec::parse("direct", &params).unwrap();
            let ShaderSpec::Direct(dp) = spec.clone() else { unreachable!("parsed as direct") };
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
