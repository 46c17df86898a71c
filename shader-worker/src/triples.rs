//! Light–blocker–receiver triples (paper 000 §6.5) found the way the shader finds them —
//! a shadow ray from a point on a receiver toward a light, blocked by a blocker — but from
//! random points spread over every object's surface rather than from the pixels of a
//! session. The edge finder's benchmarks and tests use them to get the triples a session
//! would report, without running one.
use crate::loaded::{LoadedScene, PreparedLight};
use crate::rng::Rng;
use glam::{Affine3A, Vec3};
use rayon::prelude::*;

/// Distinct `(light, blocker, receiver)` triples from `points` random surface points per
/// object (area-weighted) and `rays` shadow rays per point and light (random points of
/// area lights), sorted.
pub fn sample_triples(scene: &LoadedScene, transforms: &[Affine3A], points: usize, rays: usize, seed: u64) -> Vec<(u32, u32, u32)> {
    let inst = scene.instances(transforms);
    let objects = &scene.scene.objects;
    let mut out: Vec<(u32, u32, u32)> = (0..objects.len())
        .into_par_iter()
        .flat_map_iter(|r| {
            let m = &objects[r].mesh;
            let mut found = Vec::new();
            if m.triangles.is_empty() {
                return found;
            }
            // Area-weighted face choice.
            let mut cdf = Vec::with_capacity(m.triangles.len());
            let mut acc = 0.0f64;
            for f in 0..m.triangles.len() {
                let [a, b, c] = m.triangle(f);
                acc += (b - a).cross(c - a).length() as f64;
                cdf.push(acc);
            }
            let mut rng = Rng::new(seed, r as u64);
            let t = transforms[r];
            let normal_m = t.matrix3.inverse().transpose();
            for _ in 0..points {
                let x = rng.next_f32() as f64 * acc;
                let f = cdf.partition_point(|&c| c < x).min(m.triangles.len() - 1);
                let [a, b, c] = m.triangle(f);
                let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let p = t.transform_point3(a + (b - a) * u + (c - a) * v);
                let n = (normal_m * m.face_normals[f]).normalize_or_zero();
                let o = p + n * scene.epsilon;
                for (li, l) in scene.lights.iter().enumerate() {
                    for _ in 0..rays {
                        let target: Vec3 = match l {
                            PreparedLight::Point { position, .. } => *position,
                            PreparedLight::Area(al) => al.sample(rng.next_f32(), rng.next_f32()),
                        };
                        if n.dot(target - p) <= 0.0 {
                            continue;
                        }
                        if let Some(bl) = inst.occluded(&scene.bvh, o, target - o, 0.0, 1.0 - 1e-4) {
                            found.push((li as u32, bl, r as u32));
                        }
                    }
                }
            }
            found.sort_unstable();
            found.dedup();
            found
        })
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_scene::NoProgress;

    #[test]
    fn the_cornell_boxes_shadow_the_floor() {
        let scene = edgepoint_scene::builtin::load("cornell-point").unwrap();
        let loaded = LoadedScene::build(scene, "test".into(), &NoProgress);
        let t = loaded.default_transforms();
        let tr = sample_triples(&loaded, &t, 2000, 1, 1);
        let id = |n: &str| loaded.scene.object_id(n).unwrap();
        assert!(tr.contains(&(0, id("tallbox"), id("floor"))));
        assert!(tr.contains(&(0, id("shortbox"), id("floor"))));
        // Nothing shadows the ceiling from a light under it.
        assert!(!tr.iter().any(|&(_, _, r)| r == id("ceiling")));
        assert_eq!(tr, sample_triples(&loaded, &t, 2000, 1, 1), "reproducible");
    }
}
