//! The two-level BVH against brute force: every triangle of every instance tested.
mod common_scenes;
use common_scenes::*;
use edgepoint_scene::{NoProgress, Scene};
use edgepoint_worker::{Instances, LoadedScene, Simd};
use glam::{Affine3A, Quat, Vec3};

use edgepoint_worker::ray_oracle::{barycentric_margin, ray_triangle as tri_t};

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

/// The instruction sets this CPU runs: the traversal is checked with each.
fn simds() -> Vec<Simd> {
    let mut v = vec![Simd::Baseline];
    if Simd::detect() != Simd::Baseline {
        v.push(Simd::detect());
    }
    v
}

fn check(scene: Scene, tf: Vec<Affine3A>, rays: usize, seed: u64) {
    let loaded = LoadedScene::build(scene.clone(), "t".into(), &NoProgress);
    for simd in simds() {
        let inst = loaded.instances(&tf).with_simd(simd);
        assert_eq!(inst.simd(), simd);
        check_with(&scene, &tf, &loaded, &inst, rays, seed);
    }
}

fn check_with(scene: &Scene, tf: &[Affine3A], loaded: &LoadedScene, inst: &Instances, rays: usize, seed: u64) {
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
        let want = brute(scene, tf, o, d);
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
                // The object-space hit is the same point: the object's transform takes it
                // to the world hit.
                let back = tf[g.object as usize].transform_point3(g.local);
                assert!((back - g.position).length() < 1e-3 * r, "local {:?} -> {back:?} vs {:?}", g.local, g.position);
                let n = (tf[g.object as usize].matrix3.inverse().transpose() * glam::Vec3A::from(g.local_normal)).normalize();
                assert!(Vec3::from(n).dot(g.normal) > 0.9999, "local normal {:?} -> {n:?} vs {:?}", g.local_normal, g.normal);
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

/// The nearest triangle along the ray with `t >= tmin`, and how far inside it the hit is
/// (the smallest barycentric coordinate: near 0 the ray grazes an edge).
fn brute_margin(scene: &Scene, tf: &[Affine3A], o: Vec3, d: Vec3, tmin: f64) -> Option<(u32, u32, f64, f64)> {
    let meshes: Vec<_> = scene.objects.iter().map(|o| o.mesh.as_ref()).collect();
    edgepoint_worker::ray_oracle::closest(&meshes, tf, o, d, tmin, f64::INFINITY)
}

/// The six axis directions, each written two ways: with `+0.0` components and negated
/// from the opposite direction (`-Vec3::X` has `-0.0` in y and z). obvhs orders a node's
/// slabs by `direction < 0.0` but took the reciprocal of `-0.0` as negative, so a `-0.0`
/// component emptied every slab interval on that axis and the ray missed everything.
fn axis_directions() -> Vec<Vec3> {
    let mut v = Vec::new();
    for a in [Vec3::X, Vec3::Y, Vec3::Z] {
        v.extend([a, -a, -(-a), Vec3::ZERO - a]);
    }
    v
}

/// Rays running exactly along the axes, from random origins in (and around) the scene,
/// against brute force: the same hit (or both none), at the same distance. A hit within
/// 1e-5 (barycentric) of a triangle's edge may go either way (f32 against f64); those must
/// be rare. Also checks `occluded` on the same segments. Returns the number of hits.
fn check_axis_rays(scene: &Scene, tf: &[Affine3A], per_direction: usize, seed: u64) -> usize {
    let loaded = LoadedScene::build(scene.clone(), "t".into(), &NoProgress);
    let inst = loaded.instances(tf);
    let (lo, hi) = world_bounds(scene, tf);
    let size = (hi - lo).length();
    let tmin = 1e-3 * size;
    let mut rng = Lcg(seed);
    let (mut hits, mut grazing, mut rays) = (0, 0, 0);
    for d in axis_directions() {
        for _ in 0..per_direction {
            rays += 1;
            let u = Vec3::new(rng.f(), rng.f(), rng.f()) * 1.2 - Vec3::splat(0.1);
            let o = lo + (hi - lo) * u;
            let got = inst.closest_hit(&loaded.bvh, o, d, tmin, f32::INFINITY);
            let want = brute_margin(scene, tf, o, d, tmin as f64);
            let ctx = || format!("origin {o} direction {d} (bits {:x} {:x} {:x}): bvh {got:?} brute {want:?}", d.x.to_bits(), d.y.to_bits(), d.z.to_bits());
            match (got, want) {
                (None, None) => {}
                (Some(g), Some((wo, wt, t, margin))) => {
                    hits += 1;
                    assert!((g.t as f64 - t).abs() <= 1e-5 * size as f64, "{}", ctx());
                    // Another triangle at the same distance is a tie (coincident faces: a
                    // box standing on the floor, both sides of a zero-thickness plate);
                    // otherwise only a hit on a shared edge may pick the neighbour.
                    if (g.object, g.triangle) != (wo, wt) {
                        let [a, b, c] = scene.objects[g.object as usize]
                            .mesh
                            .triangle(g.triangle as usize)
                            .map(|v| tf[g.object as usize].transform_point3(v).as_dvec3());
                        let tie = tri_t(o.as_dvec3(), d.as_dvec3(), a, b, c).is_some_and(|t2| (t2 - t).abs() <= 1e-6 * size as f64);
                        assert!(tie || margin < 1e-5, "{}", ctx());
                    }
                    assert!(inst.occluded(&loaded.bvh, o, d, tmin, g.t + 1e-4 * size).is_some(), "{}", ctx());
                    assert!(inst.occluded(&loaded.bvh, o, d, tmin, g.t - 1e-4 * size).is_none() || margin < 1e-5, "{}", ctx());
                }
                (Some(g), None) => {
                    let [a, b, c] = scene.objects[g.object as usize]
                        .mesh
                        .triangle(g.triangle as usize)
                        .map(|v| tf[g.object as usize].transform_point3(v).as_dvec3());
                    let m = barycentric_margin(g.position.as_dvec3(), a, b, c);
                    assert!(m.abs() < 1e-5, "{} (margin {m})", ctx());
                    grazing += 1;
                }
                (None, Some((_, _, _, margin))) => {
                    assert!(margin < 1e-5, "{}", ctx());
                    grazing += 1;
                }
            }
        }
    }
    assert!(grazing * 1000 <= rays, "{grazing} of {rays} rays graze an edge");
    hits
}

fn world_bounds(scene: &Scene, tf: &[Affine3A]) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for (o, t) in scene.objects.iter().zip(tf) {
        for p in &o.mesh.positions {
            let w = t.transform_point3(*p);
            lo = lo.min(w);
            hi = hi.max(w);
        }
    }
    (lo, hi)
}

/// Rotations by quarter turns, exact (permutation matrices, some with `-0.0` entries) and
/// from quaternions (entries like `cos(π/2) ≈ -4.4e-8`).
fn quarter_turns() -> Vec<Affine3A> {
    use std::f32::consts::{FRAC_PI_2, PI};
    let exact_y = glam::Mat3::from_cols(Vec3::new(0.0, 0.0, -1.0), Vec3::Y, Vec3::X);
    let exact_x = glam::Mat3::from_cols(Vec3::X, -Vec3::NEG_Z, -Vec3::Y);
    vec![
        Affine3A::from_mat3(exact_y),
        Affine3A::from_mat3(exact_x),
        Affine3A::from_mat3(exact_x * exact_y),
        Affine3A::from_quat(Quat::from_rotation_y(FRAC_PI_2)),
        Affine3A::from_quat(Quat::from_rotation_x(-FRAC_PI_2)),
        Affine3A::from_quat(Quat::from_rotation_z(PI)),
        Affine3A::from_quat(Quat::from_rotation_x(FRAC_PI_2) * Quat::from_rotation_z(FRAC_PI_2)),
    ]
}

#[test]
fn axis_aligned_rays_hit_the_cornell_box_like_brute_force() {
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let tf: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    // The reported case: straight down from above the floor.
    let loaded = LoadedScene::build(scene.clone(), "t".into(), &NoProgress);
    let inst = loaded.instances(&tf);
    let floor = scene.object_id("floor").unwrap();
    for d in [Vec3::new(0.0, -1.0, 0.0), -Vec3::Y, Vec3::NEG_Y] {
        let h = inst.closest_hit(&loaded.bvh, Vec3::new(0.3, 0.1, 0.1), d, 0.0, f32::INFINITY);
        // The distance within an ulp or two: the watertight test's t·det sums the corners'
        // three terms, each rounded.
        assert!(h.is_some_and(|h| h.object == floor && (h.t - 0.1).abs() <= 2.0 * f32::EPSILON * 0.1), "direction {d}: {h:?}");
    }
    assert!(check_axis_rays(&scene, &tf, 300, 11) > 2000);
    // The boxes turned by quarter turns about their centres (and scaled), the rest still.
    let tall = scene.object_id("tallbox").unwrap() as usize;
    let short = scene.object_id("shortbox").unwrap() as usize;
    for (k, r) in quarter_turns().into_iter().enumerate() {
        let mut moved = tf.clone();
        for (o, s) in [(tall, 0.7), (short, 1.2)] {
            let (lo, hi) = scene.objects[o].mesh.bounds;
            let c = (lo + hi) * 0.5;
            moved[o] = Affine3A::from_translation(c) * r * Affine3A::from_scale(Vec3::splat(s)) * Affine3A::from_translation(-c);
        }
        assert!(check_axis_rays(&scene, &moved, 60, 100 + k as u64) > 300);
    }
}

#[test]
fn axis_aligned_rays_hit_flat_and_solid_instances_like_brute_force() {
    use edgepoint_scene::builtin::shapes;
    // Flat objects (a quad, a square plate with holes, one triangle) and solid ones (a box,
    // a sphere), each instanced under every quarter turn, spread along x.
    let meshes = [
        quad(0.0, 0.5, true),
        shapes::grid_plate(1.0, 3, 0.1, 0.0),
        shapes::polygon(&[Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 0.0, -0.3), Vec3::new(0.0, 0.0, 0.5)]),
        shapes::cuboid(Vec3::new(-0.4, -0.2, -0.3), Vec3::new(0.4, 0.2, 0.3)),
        sphere(8, 12),
    ];
    for (m, mesh) in meshes.iter().enumerate() {
        let turns = quarter_turns();
        let objs = (0..=turns.len()).map(|i| object(&format!("m{m}r{i}"), mesh.clone(), 0.5)).collect();
        let scene = scene(objs, vec![], 0.0);
        let mut tf = vec![Affine3A::IDENTITY];
        tf.extend(turns);
        for (i, t) in tf.iter_mut().enumerate() {
            *t = Affine3A::from_translation(Vec3::new(1.5 * i as f32, 0.25 * (i % 3) as f32, 0.0)) * *t;
        }
        assert!(check_axis_rays(&scene, &tf, 400, 7 + m as u64) > 100, "mesh {m}");
    }
}

/// Random triangle soups (sizes from slivers to large, many overlapping) and random rays
/// from inside and outside them: the closest hit's distance and triangle equal brute
/// force's (up to hits on an edge), and any-hit queries agree with it on segments that end
/// just before, just after, and at random distances along the ray.
#[test]
fn random_triangle_soups_match_brute_force_closest_and_any_hit() {
    let mut rng = Lcg(77);
    let (mut hits, mut grazing, mut rays) = (0, 0, 0);
    for case in 0..12 {
        let n = [1, 2, 3, 4, 5, 9, 40, 200, 1000, 3000, 64, 500][case];
        let scale = [0.02, 0.2, 1.0][case % 3];
        let (mut positions, mut triangles) = (Vec::new(), Vec::new());
        for i in 0..n {
            let c = rng.v(1.0);
            for _ in 0..3 {
                positions.push(c + rng.v(scale));
            }
            triangles.push([3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2]);
        }
        let mesh = edgepoint_scene::Mesh::from_triangles(positions, triangles, &NoProgress);
        let objs = vec![object("soup", mesh, 0.5)];
        let scene = scene(objs, vec![], 0.0);
        let tf = vec![Affine3A::IDENTITY];
        let loaded = LoadedScene::build(scene.clone(), "t".into(), &NoProgress);
        let meshes: Vec<_> = scene.objects.iter().map(|o| o.mesh.as_ref()).collect();
        let insts: Vec<_> = simds().into_iter().map(|s| loaded.instances(&tf).with_simd(s)).collect();
        for k in 0..800 {
            // Each instruction set on alternate rays.
            let inst = &insts[k % insts.len()];
            rays += 1;
            let o = rng.v(1.5);
            let d = (rng.v(1.0) - o * 0.5).normalize_or(Vec3::X);
            let got = inst.closest_hit(&loaded.bvh, o, d, 0.0, f32::INFINITY);
            let want = edgepoint_worker::ray_oracle::closest(&meshes, &tf, o, d, 0.0, f64::INFINITY);
            let tmax = rng.f() * 4.0;
            let any = inst.occluded(&loaded.bvh, o, d, 0.0, tmax).is_some();
            match (got, want) {
                (None, None) => assert!(!any, "case {case}: any hit without a closest hit"),
                (Some(g), Some((_, wt, t, margin))) => {
                    hits += 1;
                    // The hit's normal is the mesh's face normal, bit for bit.
                    assert_eq!(g.local_normal, scene.objects[0].mesh.face_normals[g.triangle as usize], "case {case}");
                    // f32 coordinates of magnitude ~1: absolute errors of a few 1e-7 at any distance.
                    assert!((g.t as f64 - t).abs() <= 1e-5 * (t + 1.0), "case {case}: t {} vs {t}", g.t);
                    if g.triangle != wt {
                        let [a, b, c] = edgepoint_worker::ray_oracle::world_triangle(&meshes, &tf, 0, g.triangle);
                        let tie = tri_t(o.as_dvec3(), d.as_dvec3(), a, b, c).is_some_and(|t2| (t2 - t).abs() <= 1e-6 * (t + 1.0));
                        assert!(tie || margin < 1e-5, "case {case}: triangle {} vs {wt}", g.triangle);
                    }
                    if margin >= 1e-5 && ((tmax as f64) - t).abs() > 1e-4 * t {
                        assert_eq!(any, (tmax as f64) > t, "case {case}: any hit to {tmax} with the closest at {t}");
                    }
                    assert!(inst.occluded(&loaded.bvh, o, d, 0.0, g.t * 1.001).is_some(), "case {case}");
                    assert!(inst.occluded(&loaded.bvh, o, d, 0.0, (t * 0.999) as f32).is_none() || margin < 1e-5, "case {case}");
                }
                (Some(g), None) => {
                    let [a, b, c] = edgepoint_worker::ray_oracle::world_triangle(&meshes, &tf, 0, g.triangle);
                    assert!(barycentric_margin(g.position.as_dvec3(), a, b, c).abs() < 1e-5, "case {case}: a hit brute force misses");
                    grazing += 1;
                }
                (None, Some((_, _, _, margin))) => {
                    assert!(margin < 1e-5, "case {case}: a miss where brute force hits {margin} inside");
                    grazing += 1;
                }
            }
        }
    }
    assert!(hits > rays / 5, "{hits} of {rays} rays hit");
    assert!(grazing * 500 <= rays, "{grazing} of {rays} rays graze an edge");
}

/// The welded dragon (871,306 triangles), on the bench's three kinds of rays (a camera's
/// primary rays, shadow rays from their hits, random rays from inside the box): closest
/// hit and any hit against brute force.
#[test]
fn dragon_matches_brute_force() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/dragon/dragon_vrip.ply");
    if !path.exists() {
        eprintln!("skipping: {} not found", path.display());
        return;
    }
    let s = edgepoint_scene::load::load_path(&path, &NoProgress).expect("dragon loads");
    let dragon = s.objects.iter().max_by_key(|o| o.mesh.triangles.len()).unwrap();
    let mesh = dragon.mesh.clone();
    let tf = vec![dragon.transform];
    let bvh = edgepoint_worker::SceneBvh::build(&[mesh.as_ref()], &NoProgress);
    // Some leaves hold two blocks (the rays below test that path too).
    let shape = bvh.objects[0].shape();
    assert!(shape.blocks > shape.leaves, "{} blocks in {} leaves", shape.blocks, shape.leaves);
    let insts: Vec<_> = simds().into_iter().map(|s| edgepoint_worker::Instances::new(&bvh, &tf).with_simd(s)).collect();
    let (lo, hi) = edgepoint_scene::geometry::transformed_box(&tf[0], mesh.bounds);
    let c = (lo + hi) * 0.5;
    let eye = c + Vec3::new(0.0, 0.0, 0.25);
    let light = c + Vec3::new(0.2, 0.3, 0.2);
    let meshes = [mesh.as_ref()];
    let mut rng = Lcg(5);
    let mut rays = Vec::new();
    for _ in 0..24 {
        let target = c + (hi - lo) * 0.4 * rng.v(1.0);
        rays.push((eye, (target - eye).normalize()));
        let o = lo + (hi - lo) * Vec3::new(rng.f(), rng.f(), rng.f());
        rays.push((o, rng.v(1.0).normalize_or(Vec3::Y)));
    }
    use rayon::prelude::*;
    let results: Vec<_> = rays.par_iter().map(|&(o, d)| (o, d, edgepoint_worker::ray_oracle::closest(&meshes, &tf, o, d, 0.0, f64::INFINITY))).collect();
    let mut hits = 0;
    for ((o, d, want), inst) in results.into_iter().flat_map(|r| insts.iter().map(move |i| (r, i))) {
        let got = inst.closest_hit(&bvh, o, d, 0.0, f32::INFINITY);
        match (got, want) {
            (None, None) => {}
            (Some(g), Some((_, wt, t, margin))) => {
                hits += 1;
                assert!((g.t as f64 - t).abs() <= 1e-5 * t, "t {} vs {t}", g.t);
                assert!(g.triangle == wt || margin < 1e-5, "triangle {} vs {wt}", g.triangle);
                // A shadow ray from the hit to the light, as the bench makes them.
                let n = if g.normal.dot(d) < 0.0 { g.normal } else { -g.normal };
                let so = g.position + n * 1e-5;
                let to = light - so;
                let dist = to.length();
                let sd = to / dist;
                let blocked = inst.occluded(&bvh, so, sd, 0.0, dist).is_some();
                let brute = edgepoint_worker::ray_oracle::closest(&meshes, &tf, so, sd, 0.0, dist as f64);
                assert!(blocked == brute.is_some() || brute.is_some_and(|b| b.3 < 1e-5), "shadow ray from {so}: {blocked} vs {brute:?}");
            }
            (g, w) => {
                let margin = match (g, w) {
                    (Some(g), None) => {
                        let [a, b, c] = edgepoint_worker::ray_oracle::world_triangle(&meshes, &tf, 0, g.triangle);
                        barycentric_margin(g.position.as_dvec3(), a, b, c)
                    }
                    (None, Some(w)) => w.3,
                    _ => unreachable!(),
                };
                assert!(margin.abs() < 1e-5, "ray {o} {d}: bvh {g:?} brute {w:?}");
            }
        }
    }
    assert!(hits >= 20, "{hits} of {} rays hit the dragon", rays.len());
}

/// What a ray aimed at a shared edge or corner must find: the hit at `t` (units of the unit
/// direction `d`, from a closed form), nothing on segments that end just before it, and
/// the same surface on segments that end just after it.
fn check_crack_free(inst: &Instances, loaded: &LoadedScene, o: Vec3, d: Vec3, t: f64, ctx: &str) {
    let g = inst.closest_hit(&loaded.bvh, o, d, 0.0, f32::INFINITY);
    let g = g.unwrap_or_else(|| panic!("{ctx}: origin {o} direction {d} misses (a crack between neighbours), want t {t}"));
    assert!((g.t as f64 - t).abs() <= 1e-5 * t, "{ctx}: origin {o} direction {d}: t {} vs {t}", g.t);
    let (before, after) = ((t * (1.0 - 1e-4)) as f32, (t * (1.0 + 1e-4)) as f32);
    assert!(inst.occluded(&loaded.bvh, o, d, 0.0, before).is_none(), "{ctx}: origin {o} direction {d}: blocked before the hit at {t}");
    assert!(inst.closest_hit(&loaded.bvh, o, d, 0.0, before).is_none(), "{ctx}: origin {o} direction {d}: a hit before {t}");
    assert!(inst.occluded(&loaded.bvh, o, d, 0.0, after).is_some(), "{ctx}: origin {o} direction {d}: not blocked past the hit at {t}");
}

/// Rays aimed exactly at the edges and corners neighbouring triangles share must hit: a
/// flat floor of two triangles sharing a diagonal (the direct shader's lit floor: with
/// fused multiply-adds, Möller–Trumbore rejected its centre, which lies on the diagonal,
/// in both triangles, and the camera ray saw the background), a fan of triangles around
/// one corner, and a closed sphere aimed at its vertices and edge midpoints. Distances
/// against closed forms (the floor's plane; the aimed-at point), any-hit queries on
/// segments ending just before and after the hit, and shadow rays leaving just above the
/// floor never blocked by it. With one object (queries skip the top level) and with a
/// second object beside it (they do not), on every instruction set.
#[test]
fn rays_at_shared_edges_and_corners_hit_without_cracks() {
    use edgepoint_scene::builtin::shapes;
    let mut rng = Lcg(2026);
    for half in [10.0f32, 1.3] {
        for with_other in [false, true] {
            let mut objs = vec![object("floor", quad(0.0, half, true), 0.5)];
            if with_other {
                objs.push(object("far", sphere(4, 6), 0.5));
            }
            let n_objs = objs.len();
            let scene = scene(objs, vec![], 0.0);
            let mut tf = vec![Affine3A::IDENTITY; n_objs];
            if with_other {
                tf[1] = Affine3A::from_translation(Vec3::new(0.0, -50.0, 0.0));
            }
            let loaded = LoadedScene::build(scene, "t".into(), &NoProgress);
            for simd in simds() {
                let inst = loaded.instances(&tf).with_simd(simd);
                let ctx = format!("floor {half}, {n_objs} objects, {simd:?}");
                // The failing shader test's ray, then points on the diagonal (exact in f32)
                // from above and below.
                let mut rays = vec![(Vec3::new(0.1, 2.0, 0.3), Vec3::ZERO)];
                for k in -63..=63 {
                    let s = half * 0.9 * k as f32 / 64.0;
                    let mut o = Vec3::new(rng.f() * 4.0 - 2.0, 0.2 + rng.f() * 3.0, rng.f() * 4.0 - 2.0);
                    if k % 3 == 0 {
                        o.y = -o.y;
                    }
                    rays.push((o, Vec3::new(s, 0.0, s)));
                }
                for (o, target) in rays {
                    let d = (target - o).normalize();
                    let t = -(o.y as f64) / d.y as f64;
                    check_crack_free(&inst, &loaded, o, d, t, &ctx);
                    // Shadow rays from just off the floor, away from it, are never blocked.
                    let p = o + d * t as f32;
                    let side = -o.y.signum();
                    let lifted = p - Vec3::Y * side * 1e-4;
                    let away = (rng.v(1.0) - Vec3::Y * side * 1.5).normalize();
                    assert!(inst.occluded(&loaded.bvh, lifted, away, 0.0, 1e3).is_none(), "{ctx}: shadow ray from {lifted} along {away} blocked");
                    assert!(inst.closest_hit(&loaded.bvh, lifted, away, 0.0, 1e3).is_none(), "{ctx}: shadow ray from {lifted} along {away} hits");
                }
            }
        }
    }
    // A fan around corner 0 (its shared edges run from it), a cuboid and a closed sphere.
    // The fan closes around its hub (corner 0), so the hub and its spokes are inside it;
    // its rim corners are not aimed at (a ray there may pass just outside).
    let mut corners = vec![Vec3::new(0.0, 0.3, 0.0)];
    corners.extend((0..9).map(|i| {
        let a = i as f32 * std::f32::consts::TAU / 9.0;
        Vec3::new(a.cos() * (1.0 + 0.1 * i as f32), 0.05 * i as f32, a.sin())
    }));
    let fan = edgepoint_scene::Mesh::from_triangles(corners, (1..10).map(|i| [0, i, i % 9 + 1]).collect(), &NoProgress);
    let cuboid = shapes::cuboid(Vec3::new(-0.4, -0.2, -0.3), Vec3::new(0.4, 0.2, 0.3));
    for (mesh, closed) in [(fan, false), (cuboid, true), (sphere(12, 16), true)] {
        let scene = scene(vec![object("m", mesh.clone(), 0.5)], vec![], 0.0);
        let tf = vec![Affine3A::IDENTITY];
        let loaded = LoadedScene::build(scene, "t".into(), &NoProgress);
        // Shared corners and points of shared edges (within rounding of the edge). Not the
        // UV sphere's south pole: its ring of corners there is sin(π) ≈ 9e-8 wide in f32, a
        // real hole.
        let mut targets = Vec::new();
        for tri in &mesh.triangles {
            for e in 0..3 {
                let (a, b) = (mesh.positions[tri[e] as usize], mesh.positions[tri[(e + 1) % 3] as usize]);
                let shared = mesh.triangles.iter().filter(|u| u.contains(&tri[e]) && u.contains(&tri[(e + 1) % 3])).count() > 1;
                if shared && a.y.min(b.y) > -0.999 {
                    targets.extend([(a + b) * 0.5, a + (b - a) * 0.3]);
                    if closed || tri[e] == 0 {
                        targets.push(a);
                    }
                }
            }
        }
        for simd in simds() {
            let inst = loaded.instances(&tf).with_simd(simd);
            let ctx = format!("{} triangles, {simd:?}", mesh.triangles.len());
            for &q in &targets {
                // From outside a closed convex mesh around the centre, about along the
                // point's own direction (it is then the first thing met), or from above and
                // below the fan.
                let o = if closed { q * 3.0 + rng.v(0.1) } else { q + Vec3::new(rng.f() - 0.5, if rng.f() < 0.5 { 2.0 } else { -2.0 }, rng.f() - 0.5) };
                let d = (q - o).normalize();
                check_crack_free(&inst, &loaded, o, d, (q - o).length() as f64, &ctx);
            }
        }
    }
}
