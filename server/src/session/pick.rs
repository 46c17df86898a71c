//! Picking: which object is under a frame pixel, for the viewer's click-and-drag of objects.
//! An exact ray cast against every object's triangles at its current transform — the ray
//! is taken into each object's space (direction not renormalised, so distances stay in
//! world units), objects whose box it misses closer than the best hit so far are skipped,
//! and the rest are tested triangle by triangle. A pick happens once per mouse press, so
//! this uses no acceleration structure.
use super::settings::camera_to_wire;
use edgepoint_proto as pb;
use edgepoint_scene::camera::CameraFrame;
use edgepoint_scene::geometry::ray_triangle;
use edgepoint_scene::{Camera, Scene};
use glam::{Affine3A, Vec3};

/// The first surface along a ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PickHit {
    pub object: u32,
    /// Distance along the (normalised) ray.
    pub distance: f32,
    pub position: Vec3,
}

/// Entry distance of the ray into box (lo, hi), if it meets it before `t_max`.
fn ray_box(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3, t_max: f32) -> Option<f32> {
    let inv = d.recip();
    let (t0, t1) = ((lo - o) * inv, (hi - o) * inv);
    // NaN (0 * inf on a box face) must not cull: min/max ignore it.
    let near = t0.min(t1).max_element().max(0.0);
    let far = t0.max(t1).min_element().min(t_max);
    (near <= far).then_some(near)
}

/// The first hit of the ray from `origin` along unit `dir` with the scene's objects at
/// `transforms` (one per object).
pub fn cast(scene: &Scene, transforms: &[Affine3A], origin: Vec3, dir: Vec3) -> Option<PickHit> {
    let mut best: Option<PickHit> = None;
    for (i, (obj, t)) in scene.objects.iter().zip(transforms).enumerate() {
        let inv = t.inverse();
        let (o, d) = (inv.transform_point3(origin), inv.transform_vector3(dir));
        let limit = best.map_or(f32::INFINITY, |b| b.distance);
        let (lo, hi) = obj.mesh.bounds;
        // A little slack: a flat wall's box has no thickness.
        let pad = (hi - lo).max_element().max(1e-6) * 1e-4;
        if ray_box(o, d, lo - pad, hi + pad, limit).is_none() {
            continue;
        }
        let p = &obj.mesh.positions;
        for tri in &obj.mesh.triangles {
            let [a, b, c] = tri.map(|k| p[k as usize]);
            if let Some(s) = ray_triangle(o, d, a, b, c) {
                if best.is_none_or(|h| s < h.distance) {
                    best = Some(PickHit { object: i as u32, distance: s, position: origin + dir * s });
                }
            }
        }
    }
    best
}

/// The answer to `pick` for a session at `camera` (`frame`: the camera prepared for the
/// session's image size) and object `transforms`. A position outside the image, or not
/// finite, is an error for a `Rejected`.
pub fn answer(scene: &Scene, transforms: &[Affine3A], camera: &Camera, frame: &CameraFrame, pick: &pb::Pick) -> Result<pb::Picked, String> {
    let (x, y) = (pick.x, pick.y);
    let (w, h) = (frame.width as f32, frame.height as f32);
    if !(x.is_finite() && y.is_finite() && (0.0..=w).contains(&x) && (0.0..=h).contains(&y)) {
        return Err(format!("pick {}: position ({x}, {y}) is outside the {w}x{h} frame", pick.id));
    }
    let (origin, dir) = frame.ray(x, y);
    let mut out = pb::Picked { id: pick.id, camera: Some(camera_to_wire(camera)), ..Default::default() };
    if let Some(hit) = cast(scene, transforms, origin, dir) {
        let i = hit.object as usize;
        out.hit = true;
        out.object_id = hit.object;
        out.name = scene.objects[i].name.clone();
        out.position = Some(hit.position.into());
        out.distance = hit.distance;
        out.transform = Some(pb::affine_to_wire(&transforms[i]));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// Brute force in world space: every triangle of every object transformed to the world.
    fn brute(scene: &Scene, transforms: &[Affine3A], o: Vec3, d: Vec3) -> Option<(u32, f32)> {
        let mut best: Option<(u32, f32)> = None;
        for (i, (obj, t)) in scene.objects.iter().zip(transforms).enumerate() {
            for tri in &obj.mesh.triangles {
                let [a, b, c] = tri.map(|k| t.transform_point3(obj.mesh.positions[k as usize]));
                if let Some(s) = ray_triangle(o, d, a, b, c) {
                    if best.is_none_or(|(_, bd)| s < bd) {
                        best = Some((i as u32, s));
                    }
                }
            }
        }
        best
    }

    fn check_scene(scene: &Scene, rays: usize, seed: u64) {
        let mut rng = Rng::new(seed);
        let (lo, hi) = scene.bounds();
        let size = (hi - lo).length();
        let (mut hits, mut agree) = (0, 0);
        for k in 0..rays {
            // Moved objects: a random rotation and shift for each, new every 50 rays.
            let transforms: Vec<Affine3A> = scene
                .objects
                .iter()
                .map(|o| {
                    if k % 50 == 0 && rng.unit() < 0.5 {
                        return o.transform;
                    }
                    let shift = Vec3::new(rng.unit() - 0.5, rng.unit() * 0.2, rng.unit() - 0.5) * size * 0.1;
                    Affine3A::from_translation(shift) * o.transform * Affine3A::from_rotation_y(rng.unit() * 0.3)
                })
                .collect();
            let origin = lo + (hi - lo) * Vec3::new(rng.unit(), rng.unit(), rng.unit()) + Vec3::Y * size * 0.2;
            let target = lo + (hi - lo) * Vec3::new(rng.unit(), rng.unit(), rng.unit());
            let dir = (target - origin).normalize();
            let got = cast(scene, &transforms, origin, dir);
            let want = brute(scene, &transforms, origin, dir);
            match (got, want) {
                (None, None) => agree += 1,
                (Some(g), Some((obj, t))) => {
                    hits += 1;
                    // Same nearest distance; the object too unless two surfaces tie.
                    assert!((g.distance - t).abs() <= 1e-4 * t.max(1.0), "ray {k}: {} vs {t}", g.distance);
                    if g.object == obj {
                        agree += 1;
                    } else {
                        assert!((g.distance - t).abs() < 1e-5 * size, "ray {k}: object {} vs {obj}", g.object);
                    }
                    assert!((g.position - (origin + dir * t)).length() < 1e-3 * size);
                }
                (g, w) => panic!("ray {k} in {}: cast {g:?}, brute force {w:?}", scene.name),
            }
        }
        assert!(hits > rays / 3, "{}: only {hits} of {rays} rays hit: the test proves little", scene.name);
        assert!(agree >= rays * 99 / 100, "{}: {agree} of {rays} agree", scene.name);
    }

    #[test]
    fn cast_matches_brute_force_on_builtins_with_moved_objects() {
        for (name, rays) in [("cornell", 2000), ("torus-capsule", 400), ("rooms", 400)] {
            check_scene(&edgepoint_scene::builtin::load(name).unwrap(), rays, 7 + rays as u64);
        }
    }

    #[test]
    fn answers_name_the_object_and_refuse_positions_outside_the_frame() {
        let scene = edgepoint_scene::builtin::load("cornell").unwrap();
        let transforms: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let frame = scene.camera.frame(64, 64);
        // The tall box: the pixel where its top front corner projects, a little inside.
        let id = scene.object_id("tallbox").unwrap() as usize;
        let (a, b) = scene.object_bounds(id);
        let (x, y, _) = frame.project(Vec3::new((a.x + b.x) * 0.5, b.y * 0.8, a.z)).unwrap();
        let p = answer(&scene, &transforms, &scene.camera, &frame, &pb::Pick { id: 5, x, y }).unwrap();
        assert!(p.hit && p.id == 5 && p.name == "tallbox", "{p:?}");
        assert_eq!(p.transform, Some(pb::affine_to_wire(&transforms[id])));
        // Moved away, the same pixel shows what is behind it.
        let mut moved = transforms.clone();
        moved[id] = Affine3A::from_translation(Vec3::new(0.0, 0.0, 5.0));
        let p = answer(&scene, &moved, &scene.camera, &frame, &pb::Pick { id: 6, x, y }).unwrap();
        assert!(p.hit && p.name == "back", "{p:?}");
        for (x, y) in [(-1.0, 3.0), (3.0, 65.0), (f32::NAN, 1.0)] {
            assert!(answer(&scene, &transforms, &scene.camera, &frame, &pb::Pick { id: 1, x, y }).unwrap_err().contains("outside"));
        }
        // Up into the open front of the box: nothing.
        let up = Camera { eye: Vec3::new(0.278, 0.3, -1.0), target: Vec3::new(0.278, 3.0, -1.5), ..scene.camera };
        let f = up.frame(8, 8);
        let p = answer(&scene, &transforms, &up, &f, &pb::Pick { id: 2, x: 4.0, y: 4.0 }).unwrap();
        assert!(!p.hit && p.name.is_empty());
    }
}
