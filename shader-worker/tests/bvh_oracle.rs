//! The two-level BVH against brute force: every triangle of every instance tested.
mod common_scenes;
use common_scenes::*;
use edgepoint_scene::{NoProgress, Scene};
use edgepoint_worker::LoadedScene;
use glam::{Affine3A, DVec3, Quat, Vec3};

/// Möller–Trumbore in f64: the oracle.
fn tri_t(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Option<f64> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-14 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t)
}

fn brute(scene: &Scene, tf: &[Affine3A], o: Vec3, d: Vec3) -> Option<(u32, u32, f64)> {
    let mut best: Option<(u32, u32, f64)> = None;
    for (oi, obj) in scene.objects.iter().enumerate() {
        for f in 0..obj.mesh.triangles.len() {
            let [a, b, c] = obj.mesh.triangle(f).map(|v| tf[oi].transform_point3(v).as_dvec3());
            if let Some(t) = tri_t(o.as_dvec3(), d.as_dvec3(), a, b, c) {
                if best.is_none_or(|x| t < x.2) {
                    best = Some((oi as u32, f as u32, t));
                }
            }
        }
    }
    best
}

struct Lcg(u64);
impl Lcg {
    fn f(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
    fn v(&mut self, s: f32) -> Vec3 {
        Vec3::new(self.f() * 2.0 - 1.0, self.f() * 2.0 - 1.0, self.f() * 2.0 - 1.0) * s
    }
}

fn check(scene: Scene, tf: Vec<Affine3A>, rays: usize, seed: u64) {
    let loaded = LoadedScene::build(scene.clone(), "t".into(), &NoProgress);
    let inst = loaded.instances(&tf);
    let (lo, hi) = scene.bounds();
    let c = (lo + hi) * 0.5;
    let r = (hi - lo).length();
    let mut rng = Lcg(seed);
    let (mut hits, mut agree) = (0, 0);
    for _ in 0..rays {
        let o = c + rng.v(r);
        // Aim near the scene so most rays hit something.
        let d = (c + rng.v(r * 0.3) - o).normalize();
        let got = inst.closest_hit(&loaded.bvh, o, d, 0.0, f32::INFINITY);
        let want = brute(&scene, &tf, o, d);
        match (got, want) {
            (None, None) => agree += 1,
            (Some(g), Some((wo, wt, t))) => {
                hits += 1;
                let rel = ((g.t as f64 - t) / t.max(1e-3)).abs();
                assert!(rel < 1e-3, "t {} vs {t}", g.t);
                // Ties along shared edges may pick either face; otherwise the same triangle.
                if (g.object, g.triangle) == (wo, wt) || rel < 1e-5 {
                    agree += 1;
                }
                let p = o + d * g.t;
                assert!((g.position - p).length() < 1e-3 * r);
                assert!((g.normal.length() - 1.0).abs() < 1e-3);
                // occlusion agrees on the same segment
                assert!(inst.occluded(&loaded.bvh, o, d, 0.0, g.t * 1.001).is_some());
                assert!(inst.occluded(&loaded.bvh, o, d, 0.0, (t * 0.999) as f32).is_none() || rel > 1e-4);
            }
            (g, w) => {
                // A grazing ray exactly on an edge may go either way; these must be rare.
                let t = g.map(|h| h.t as f64).or(w.map(|x| x.2)).unwrap();
                assert!(t.is_finite());
                continue;
            }
        }
    }
    assert!(hits > rays / 4, "most rays hit ({hits}/{rays})");
    assert!(agree as f64 >= rays as f64 * 0.995, "{agree}/{rays} agree with brute force");
}

#[test]
fn cornell_identity_and_moved_boxes_match_brute_force() {
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let id: Vec<_> = scene.objects.iter().map(|o| o.transform).collect();
    check(scene.clone(), id.clone(), 3000, 1);
    let mut moved = id;
    let tall = scene.object_id("tallbox").unwrap() as usize;
    let short = scene.object_id("shortbox").unwrap() as usize;
    moved[tall] = Affine3A::from_scale_rotation_translation(Vec3::splat(0.8), Quat::from_rotation_y(0.6), Vec3::new(0.05, 0.0, -0.1));
    moved[short] = Affine3A::from_scale_rotation_translation(Vec3::new(1.0, 1.5, 0.7), Quat::from_rotation_z(0.3), Vec3::new(-0.1, 0.05, 0.0));
    check(scene, moved, 3000, 2);
}

#[test]
fn transformed_spheres_match_brute_force() {
    let objs = (0..5).map(|i| object(&format!("s{i}"), sphere(12, 16), 0.5)).collect();
    let scene = scene(objs, vec![], 0.0);
    let tf = (0..5)
        .map(|i| {
            let f = i as f32;
            Affine3A::from_scale_rotation_translation(
                Vec3::new(0.5 + 0.2 * f, 0.7, 0.4 + 0.1 * f),
                Quat::from_euler(glam::EulerRot::XYZ, f, 0.5 * f, 0.2),
                Vec3::new(f * 1.3 - 2.5, 0.3 * f, -0.5 * f),
            )
        })
        .collect();
    check(scene, tf, 4000, 3);
}

#[test]
fn bunny_matches_brute_force() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/bunny/bun_zipper.ply");
    if !path.exists() {
        eprintln!("skipping: {} not found", path.display());
        return;
    }
    let s = match edgepoint_scene::load::load_files(&[edgepoint_scene::load::NamedBytes { name: "bun_zipper.ply".into(), data: std::fs::read(&path).unwrap() }], &NoProgress) {
        Ok(s) => s,
        Err(e) => panic!("bunny loads: {e}"),
    };
    let mut tf: Vec<_> = s.objects.iter().map(|o| o.transform).collect();
    tf[0] = Affine3A::from_scale_rotation_translation(Vec3::splat(1.3), Quat::from_rotation_y(1.1), Vec3::new(0.01, 0.02, 0.0)) * tf[0];
    check(s, tf, 400, 4);
}
