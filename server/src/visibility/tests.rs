use super::*;
use crate::rng::Rng;
use edgepoint_scene::{Camera, Material, Mesh, NoProgress, Object, Scene};
use glam::{DVec3, Quat};
use std::sync::Arc;

/// Nearest view depth along the ray through continuous pixel position (`px`, `py`) by
/// testing every triangle in f64. A triangle counts when the pixel position lies at least
/// `margin` pixels inside each of its projected edges (negative: a little outside counts),
/// or, for a triangle reaching behind the eye, when its barycentric coordinates along the ray
/// are at least `margin * 1e-2`. The ray's direction has forward component 1, so `t` is the
/// view depth.
fn brute_depth(scene: &Scene, tf: &[Affine3A], cam: &CameraFrame, px: f64, py: f64, margin: f64, min_depth: f64) -> f64 {
    let (w, h) = (cam.width as f64, cam.height as f64);
    let aspect = w / h;
    let tan = cam.tan_half_y as f64;
    let nx = (2.0 * px / w - 1.0) * tan * aspect;
    let ny = (1.0 - 2.0 * py / h) * tan;
    let d = cam.forward.as_dvec3() + cam.right.as_dvec3() * nx + cam.up.as_dvec3() * ny;
    let o = cam.eye.as_dvec3();
    let (f, r, u) = (cam.forward.as_dvec3(), cam.right.as_dvec3(), cam.up.as_dvec3());
    // Screen position of a world point in front of the eye.
    let screen = |p: DVec3| {
        let v = p - o;
        let z = v.dot(f);
        (0.5 * w * (1.0 + v.dot(r) / (z * tan * aspect)), 0.5 * h * (1.0 - v.dot(u) / (z * tan)), z)
    };
    let mut best = f64::INFINITY;
    for (obj, t) in scene.objects.iter().zip(tf) {
        let m = obj.mesh.as_ref();
        for tri in &m.triangles {
            let [a, b, c] = tri.map(|i| t.transform_point3(m.positions[i as usize]).as_dvec3());
            let Some(depth) = hit(o, d, a, b, c, -0.01) else { continue };
            let s = [screen(a), screen(b), screen(c)];
            let inside = if s.iter().all(|v| v.2 > 1e-6) {
                let area = (s[1].0 - s[0].0) * (s[2].1 - s[0].1) - (s[1].1 - s[0].1) * (s[2].0 - s[0].0);
                (0..3).all(|k| {
                    let (p, q) = (s[k], s[(k + 1) % 3]);
                    let e = (q.0 - p.0) * (py - p.1) - (q.1 - p.1) * (px - p.0);
                    e * area.signum() / (q.0 - p.0).hypot(q.1 - p.1) >= margin
                })
            } else {
                hit(o, d, a, b, c, margin * 1e-2).is_some()
            };
            if inside && depth > min_depth && depth < best {
                best = depth;
            }
        }
    }
    best
}

/// Ray o + t d against triangle abc (both sides): t when every barycentric coordinate is
/// at least `margin`.
fn hit(o: DVec3, d: DVec3, a: DVec3, b: DVec3, c: DVec3, margin: f64) -> Option<f64> {
    let (e1, e2) = (b - a, c - a);
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(p) * inv;
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    let t = e2.dot(q) * inv;
    (u >= margin && v >= margin && 1.0 - u - v >= margin && t > 0.0).then_some(t)
}

fn soup(rng: &mut Rng, n: usize, size: f32) -> Mesh {
    let mut p = Vec::new();
    let mut t = Vec::new();
    for i in 0..n as u32 {
        let c = Vec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5) * 2.0;
        for _ in 0..3 {
            p.push(c + Vec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5) * size);
        }
        t.push([3 * i, 3 * i + 1, 3 * i + 2]);
    }
    Mesh::from_triangles(p, t, &NoProgress)
}

fn scene_of(meshes: Vec<Mesh>) -> Scene {
    Scene {
        name: "t".into(),
        objects: meshes
            .into_iter()
            .enumerate()
            .map(|(i, m)| Object { name: format!("o{i}"), mesh: Arc::new(m), material: Material::default(), transform: Affine3A::IDENTITY })
            .collect(),
        lights: Vec::new(),
        camera: Camera { eye: Vec3::new(0.0, 0.0, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 },
        ambient: Vec3::ZERO,
        background: Vec3::ZERO,
        orbit: None,
    }
}

fn random_transform(rng: &mut Rng) -> Affine3A {
    let axis = Vec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5).normalize_or(Vec3::Y);
    Affine3A::from_scale_rotation_translation(
        Vec3::splat(0.5 + rng.unit()),
        Quat::from_axis_angle(axis, rng.unit() * 6.0),
        Vec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5) * 2.0,
    )
}

/// Every pixel's depth lies between the oracle's with a hundredth of a pixel's tolerance
/// outside the triangles (vertices are snapped to 1/256 pixel, and a centre on an edge may
/// go either way) and its depth that far inside them.
fn check(scene: &Scene, tf: &[Affine3A], cam: &Camera, w: u32, h: u32) -> (usize, usize) {
    let frame = cam.frame(w, h);
    let mut vis = Visibility::new(w, h);
    let counts = vis.update(scene, tf, &frame);
    assert!(counts.redrawn);
    let mut covered = 0;
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            let got = vis.depth(i) as f64;
            let loose = brute_depth(scene, tf, &frame, px, py, -0.01, 0.0);
            let strict = brute_depth(scene, tf, &frame, px, py, 0.01, 1e-3);
            assert!(
                got >= loose * (1.0 - 1e-4) && got <= strict * (1.0 + 1e-4),
                "pixel {x},{y}: raster depth {got}, oracle {loose} (loose) .. {strict} (strict)"
            );
            if vis.covered(i) {
                covered += 1;
                assert_ne!(vis.object(i), NO_OBJECT);
            } else {
                assert_eq!(vis.object(i), NO_OBJECT);
            }
        }
    }
    (covered, (w * h) as usize)
}

#[test]
fn depth_equals_ray_casting_every_triangle_on_random_soups() {
    let mut rng = Rng::new(7);
    for case in 0..12 {
        let meshes = (0..3).map(|_| soup(&mut rng, 25, 1.2)).collect();
        let scene = scene_of(meshes);
        let tf: Vec<Affine3A> = (0..3).map(|_| random_transform(&mut rng)).collect();
        // Some eyes inside the soup, so triangles cross the near plane and get clipped.
        let r = if case % 3 == 0 { 0.5 } else { 6.0 };
        let eye = Vec3::new(rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5).normalize_or(Vec3::Z) * r;
        let cam = Camera { eye, target: Vec3::new(rng.unit() - 0.5, 0.0, 0.0), up: Vec3::Y, fov_y_degrees: 30.0 + 60.0 * rng.unit() };
        let (covered, total) = check(&scene, &tf, &cam, 37 + case, 29 + 2 * case);
        assert!(covered > 0 && covered < total, "case {case}: the view shows some triangles and some background");
    }
}

#[test]
fn a_closed_mesh_has_no_cracks_and_matches_ray_casting() {
    let scene = scene_of(vec![edgepoint_scene::builtin::shapes::sphere(1.0, 37, 23)]);
    let tf = [Affine3A::from_rotation_y(0.3)];
    for eye in [Vec3::new(0.3, 0.4, 3.0), Vec3::new(2.0, -1.5, 1.0), Vec3::new(0.1, 0.2, 0.3)] {
        let cam = Camera { eye, target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 60.0 };
        check(&scene, &tf, &cam, 64, 48);
        // From inside, every pixel centre sees the sphere: none may fall through a crack.
        if eye.length() < 1.0 {
            let mut vis = Visibility::new(64, 48);
            let c = vis.update(&scene, &tf, &cam.frame(64, 48));
            assert_eq!(c.covered, 64 * 48, "a pixel centre fell between triangles");
        }
    }
}

#[test]
fn far3_is_the_farthest_depth_over_each_3x3_window() {
    let mut rng = Rng::new(3);
    let scene = scene_of(vec![soup(&mut rng, 40, 1.5)]);
    let tf = [Affine3A::IDENTITY];
    let cam = Camera { eye: Vec3::new(0.0, 0.0, 4.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 };
    let (w, h) = (41u32, 33u32);
    let mut vis = Visibility::new(w, h);
    vis.update(&scene, &tf, &cam.frame(w, h));
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let mut want = 0f32;
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx >= 0 && ny >= 0 && nx < w as i64 && ny < h as i64 {
                        want = want.max(vis.depth((ny * w as i64 + nx) as usize));
                    }
                }
            }
            assert_eq!(vis.far3()[(y * w as i64 + x) as usize], want, "pixel {x},{y}");
        }
    }
}

#[test]
fn an_unchanged_view_is_reused_and_any_change_redraws() {
    let mut rng = Rng::new(5);
    let scene = scene_of(vec![soup(&mut rng, 10, 1.0), soup(&mut rng, 10, 1.0)]);
    let mut tf = vec![Affine3A::IDENTITY; 2];
    let cam = Camera { eye: Vec3::new(0.0, 0.0, 4.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 };
    let mut vis = Visibility::new(32, 32);
    assert!(vis.update(&scene, &tf, &cam.frame(32, 32)).redrawn);
    assert!(!vis.update(&scene, &tf, &cam.frame(32, 32)).redrawn);
    tf[1] = Affine3A::from_translation(Vec3::X * 0.1);
    assert!(vis.update(&scene, &tf, &cam.frame(32, 32)).redrawn, "a moved object redraws");
    let cam2 = Camera { eye: cam.eye + Vec3::Y * 1e-3, ..cam };
    assert!(vis.update(&scene, &tf, &cam2.frame(32, 32)).redrawn, "a moved camera redraws");
    vis.invalidate();
    assert!(vis.update(&scene, &tf, &cam2.frame(32, 32)).redrawn);
}

#[test]
fn cornell_box_agrees_with_the_workers_ray_tracer() {
    use edgepoint_worker::loaded::LoadedScene;
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let loaded = LoadedScene::build(scene.clone(), "t".into(), &NoProgress);
    let mut tf: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    // Move the tall box, and look from an orbit position, as a session would.
    let tall = scene.object_id("tallbox").unwrap() as usize;
    tf[tall] = Affine3A::from_translation(Vec3::new(-60.0, 0.0, 20.0)) * tf[tall];
    let inst = loaded.instances(&tf);
    let (lo, hi) = scene.bounds();
    let cam = scene.camera.orbit((lo + hi) * 0.5, 0.3);
    let (w, h) = (96u32, 80u32);
    let frame = cam.frame(w, h);
    let mut vis = Visibility::new(w, h);
    vis.update(&scene, &tf, &frame);
    let (mut agree, mut total) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let (o, d) = frame.ray(x as f32 + 0.5, y as f32 + 0.5);
            let i = (y * w + x) as usize;
            total += 1;
            match inst.closest_hit(&loaded.bvh, o, d, 0.0, f32::INFINITY) {
                Some(hit) => {
                    let z = (hit.position - frame.eye).dot(frame.forward);
                    if vis.object(i) == hit.object && (vis.depth(i) - z).abs() <= 1e-3 * z {
                        agree += 1;
                    }
                }
                None => agree += usize::from(!vis.covered(i)),
            }
        }
    }
    // Pixel centres exactly on an edge between two objects may go either way.
    assert!(agree as f64 >= 0.995 * total as f64, "{agree} of {total} pixels agree");
}

