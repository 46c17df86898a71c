//! Tests of the Render Cache against brute-force oracles on random cases.
use super::interpolate::INTERP_SIGMA;
use super::reproject::Projector;
use super::*;
use crate::stage_times::StageTimes;
use edgepoint_scene::camera::{Camera, CameraFrame};

use crate::rng::Rng;

fn hit(position: Vec3, color: Vec3, object: u32) -> Sample {
    Sample { hit: true, position, normal: Vec3::ZERO, color, object, epoch: 1, pixel: [0, 0] }
}

fn miss(direction: Vec3, color: Vec3) -> Sample {
    Sample { hit: false, position: direction.normalize(), normal: Vec3::ZERO, color, object: u32::MAX, epoch: 1, pixel: [0, 0] }
}

/// The sample with the pixel it was shaded for.
fn at(mut s: Sample, x: u32, y: u32) -> Sample {
    s.pixel = [x, y];
    s
}

fn camera(eye: Vec3, target: Vec3, w: u32, h: u32) -> CameraFrame {
    Camera { eye, target, up: Vec3::Y, fov_y_degrees: 50.0 }.frame(w, h)
}

fn cache(w: u32, h: u32, ppp: f32) -> RenderCache {
    RenderCache::new(CacheConfig { width: w, height: h, points_per_pixel: ppp, background: Vec3::new(0.1, 0.2, 0.3) })
}

fn frame(c: &mut RenderCache, cam: &CameraFrame) -> FrameCounts {
    c.reproject_and_interpolate(cam, &mut StageTimes::new())
}

/// Projection for the oracle: the cache's projector (checked against
/// `CameraFrame::project` in `projector_agrees_with_the_camera`), pixel by `floor`.
fn oracle_project(cam: &CameraFrame, p: &CachedPoint) -> Option<(usize, f32)> {
    let (sx, sy, z) = Projector::new(cam).project(p.position, p.hit)?;
    if !(sx >= 0.0 && sy >= 0.0 && sx < cam.width as f32 && sy < cam.height as f32) {
        return None;
    }
    Some((sy.floor() as usize * cam.width as usize + sx.floor() as usize, z))
}

#[test]
fn projector_agrees_with_the_camera() {
    let mut rng = Rng(41);
    for _ in 0..20 {
        let (w, h) = (16 + (rng.next_u64() % 1000) as u32, 16 + (rng.next_u64() % 800) as u32);
        let cam = camera(rng.vec3(-20.0, 20.0), rng.vec3(-1.0, 1.0), w, h);
        let prj = Projector::new(&cam);
        for _ in 0..500 {
            let p = cam.eye + rng.vec3(-30.0, 30.0);
            match (prj.project(p, true), cam.project(p)) {
                (Some((sx, sy, z)), Some((cx, cy, cz))) => {
                    assert_eq!(z, cz, "depth is computed the same way");
                    let tol = 1e-3 + 1e-5 * sx.abs().max(sy.abs());
                    assert!((sx - cx).abs() < tol && (sy - cy).abs() < tol, "{sx},{sy} vs {cx},{cy}");
                }
                (None, None) => {}
                (a, b) => panic!("{a:?} vs {b:?}"),
            }
            // A miss direction projects like a very far point in that direction.
            let d = (p - cam.eye).normalize();
            if let (Some((sx, sy, z)), Some((fx, fy, _))) = (prj.project(d, false), cam.project(cam.eye + d * 1.0e4)) {
                assert_eq!(z, f32::INFINITY);
                if fx.abs() > 2.0 * w as f32 || fy.abs() > 2.0 * h as f32 {
                    continue; // far outside the view the far-point reference is imprecise
                }
                let tol = 0.05;
                assert!((sx - fx).abs() < tol && (sy - fy).abs() < tol, "{sx},{sy} vs {fx},{fy}");
            }
        }
    }
}

#[test]
fn reprojection_and_culling_match_brute_force() {
    let mut rng = Rng(11);
    let (mut total_culled, mut total_kept) = (0, 0);
    for case in 0..12 {
        let (w, h) = (8 + (rng.next_u64() % 40) as u32, 8 + (rng.next_u64() % 30) as u32);
        let mut c = cache(w, h, 1.0 + rng.unit() * 3.0);
        let eye = rng.vec3(-4.0, 4.0) + Vec3::new(0.0, 0.0, 6.0);
        let cam = camera(eye, rng.vec3(-0.5, 0.5), w, h);
        let n = c.capacity() + c.capacity() / 3; // overfill: replacement runs too
        for _ in 0..n {
            let s = match rng.next_u64() % 10 {
                0 => miss(rng.vec3(-1.0, 1.0), rng.vec3(0.0, 1.0)),
                // Several points on few depths make exact depth ties (index decides).
                1 => hit(Vec3::new(rng.range(-2.0, 2.0), rng.range(-2.0, 2.0), 0.0), rng.vec3(0.0, 1.0), 1),
                _ => hit(rng.vec3(-2.0, 2.0), rng.vec3(0.0, 1.0), 2),
            };
            // The pixel it was "shaded for": where it projects, else anywhere.
            let (x, y) = match cam.project(s.position) {
                Some((sx, sy, _)) if s.hit && sx >= 0.0 && sy >= 0.0 => (sx as u32, sy as u32),
                _ => ((rng.next_u64() % w as u64) as u32, (rng.next_u64() % h as u64) as u32),
            };
            assert!(c.insert(&at(s, x.min(w - 1), y.min(h - 1))));
        }
        let counts = frame(&mut c, &cam);

        // Nearest point per pixel by a naive loop.
        let px = (w * h) as usize;
        let mut best = vec![EMPTY_KEY; px];
        for i in 0..c.capacity() as u32 {
            let Some(p) = c.point(i) else { continue };
            assert_eq!(p.age, 1.0, "one frame ages every point once");
            if let Some((pix, z)) = oracle_project(&cam, &p) {
                best[pix] = best[pix].min((u64::from(z.to_bits()) << 32) | u64::from(i));
            }
        }
        for (pix, b) in best.iter().enumerate() {
            assert_eq!(c.zbufs[0][pix], *b, "case {case}: winner of pixel {pix}");
        }

        // Culling oracle: some opposite pair of neighbours both nearer by the relative
        // threshold, and no opposite pair with one nearer and the other farther by it.
        let depth = |k: u64| f32::from_bits((k >> 32) as u32);
        let t = 1.0 + DEPTH_CULL_RELATIVE;
        let (mut culled, mut kept) = (0u32, 0u32);
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let i = (y * w as i64 + x) as usize;
                let pi = c.point_image();
                if best[i] == EMPTY_KEY {
                    assert_eq!(pi.point[i], NO_POINT);
                    assert_eq!(pi.age[i], f32::INFINITY);
                    continue;
                }
                let dc = depth(best[i]);
                let at = |dx: i64, dy: i64| -> Option<f32> {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        return None;
                    }
                    let k = best[(ny * w as i64 + nx) as usize];
                    (k != EMPTY_KEY).then(|| depth(k))
                };
                let is_near = |d: Option<f32>| d.is_some_and(|d| d * t < dc);
                let is_far = |d: Option<f32>| d.is_some_and(|d| d > dc * t);
                let mut sandwich = false;
                let mut bracket = false;
                for dy in -1..=1i64 {
                    for dx in -1..=1i64 {
                        if dx == 0 && dy == 0 {
                            continue;
                        }
                        sandwich |= is_near(at(dx, dy)) && is_near(at(-dx, -dy));
                        bracket |= is_near(at(dx, dy)) && is_far(at(-dx, -dy));
                    }
                }
                let occluded = sandwich && !bracket;
                let winner = best[i] as u32;
                if occluded {
                    culled += 1;
                    assert_eq!(pi.point[i], NO_POINT, "case {case}: pixel {i} should be culled");
                } else {
                    kept += 1;
                    assert_eq!(pi.point[i], winner, "case {case}: pixel {i} should keep its winner");
                    let p = c.point(winner).unwrap();
                    assert_eq!(pi.color[i], p.color);
                    assert_eq!(pi.depth[i], dc);
                    assert_eq!(pi.age[i], 1.0);
                    // Subpixel position reproduces the projection (to 1/65536 of a pixel).
                    let [u, v] = pi.subpixel[i];
                    assert!((0.0..1.0).contains(&u) && (0.0..1.0).contains(&v));
                    let (sx, sy, _) = Projector::new(&cam).project(p.position, p.hit).unwrap();
                    assert!((x as f32 + u - sx).abs() < 1e-3 && (y as f32 + v - sy).abs() < 1e-3);
                }
            }
        }
        assert_eq!(counts.occluded, culled, "case {case}");
        assert_eq!(counts.with_point, kept, "case {case}");
        assert_eq!(counts.with_point + counts.filled + counts.empty, w * h);
        assert_eq!(counts.cache_points as usize, c.len());
        total_culled += culled;
        total_kept += kept;

        // Hidden points are marked for replacement: culled winners, and points behind their
        // pixel's winner (by the threshold, or behind a culled winner).
        for i in 0..c.capacity() as u32 {
            let Some(p) = c.point(i) else { continue };
            let want = match oracle_project(&cam, &p) {
                None => false,
                Some((pix, z)) => {
                    let wk = best[pix];
                    let winner = wk as u32;
                    let winner_culled = c.point_image().point[pix] == NO_POINT;
                    if winner == i {
                        winner_culled
                    } else {
                        winner_culled || depth(wk) * (1.0 + DEPTH_CULL_RELATIVE) < z
                    }
                }
            };
            assert_eq!(c.was_hidden(i as usize), want, "case {case}: hidden flag of point {i}");
        }
    }
    assert!(total_culled > 20 && total_kept > 1000, "the random scenes should exercise both ({total_culled}, {total_kept})");
}

/// Ray-traces a little scene (a sphere before a slanted plane, sky elsewhere) at pixel
/// centres: one sample per pixel, random colours.
fn one_sample_per_pixel(c: &mut RenderCache, cam: &CameraFrame, rng: &mut Rng) -> Vec<Vec3> {
    let (w, h) = (c.width(), c.height());
    let centre = Vec3::new(0.3, 0.2, 0.0);
    let radius = 0.8;
    let plane_n = Vec3::new(0.2, 0.3, 1.0).normalize();
    let plane_d = -1.5; // plane: n.p = d
    let mut colors = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            let mut t_hit = f32::INFINITY;
            let mut obj = u32::MAX;
            let oc = o - centre;
            let b = oc.dot(d);
            let disc = b * b - (oc.length_squared() - radius * radius);
            if disc >= 0.0 {
                let t = -b - disc.sqrt();
                if t > 0.0 {
                    t_hit = t;
                    obj = 0;
                }
            }
            let denom = plane_n.dot(d);
            if denom.abs() > 1e-6 {
                let t = (plane_d - plane_n.dot(o)) / denom;
                if t > 0.0 && t < t_hit && (o + d * t).x.abs() < 1.0 {
                    t_hit = t;
                    obj = 1;
                }
            }
            let col = rng.vec3(0.0, 1.0);
            colors.push(col);
            let mut s = if obj == u32::MAX { miss(d, col) } else { hit(o + d * t_hit, col, obj) };
            s.pixel = [x, y];
            assert!(c.insert(&s));
        }
    }
    colors
}

#[test]
fn static_camera_with_one_point_per_pixel_reproduces_the_colours() {
    let mut rng = Rng(5);
    for &(w, h) in &[(64u32, 48u32), (33, 71)] {
        let mut c = cache(w, h, 2.0);
        let cam = camera(Vec3::new(0.5, 0.8, 5.0), Vec3::ZERO, w, h);
        let colors = one_sample_per_pixel(&mut c, &cam, &mut rng);
        let objects: std::collections::HashSet<u32> = (0..c.capacity() as u32).filter_map(|i| c.point(i)).map(|p| p.object).collect();
        assert_eq!(objects.len(), 3, "sphere, plane and sky are all in view: {objects:?}");
        for _ in 0..2 {
            let counts = frame(&mut c, &cam);
            assert_eq!(counts.with_point, w * h, "no pixel lost its point (nothing culled at silhouettes)");
            assert_eq!(counts.occluded, 0);
            assert_eq!(c.image(), &colors[..]);
        }
    }
}

/// A grid of points at the pixel centres of a plane facing the camera at distance `z`.
fn plane_points(cam: &CameraFrame, depth: f32) -> Vec<Vec3> {
    let mut v = Vec::new();
    for y in 0..cam.height {
        for x in 0..cam.width {
            let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            v.push(o + d * (depth / d.dot(cam.forward)));
        }
    }
    v
}

#[test]
fn occluded_point_in_a_gap_is_culled_and_filled() {
    let (w, h) = (15u32, 11u32);
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, w, h);
    let near = plane_points(&cam, 3.0);
    let (cx, cy) = (7usize, 5usize);
    let gap = cy * w as usize + cx;
    let mut c = cache(w, h, 2.0);
    let mut rng = Rng(9);
    let mut colors = vec![Vec3::ZERO; near.len()];
    for (i, p) in near.iter().enumerate() {
        if i != gap {
            colors[i] = rng.vec3(0.0, 1.0);
            c.insert(&at(hit(*p, colors[i], 0), i as u32 % w, i as u32 / w));
        }
    }
    // A far point (background wall) showing through the gap.
    let (o, d) = cam.ray(cx as f32 + 0.5, cy as f32 + 0.5);
    let far = o + d * 9.0;
    c.insert(&at(hit(far, Vec3::new(5.0, 0.0, 0.0), 1), cx as u32, cy as u32));
    let far_slot = (0..c.capacity() as u32).find(|&i| c.point(i).map(|p| p.object) == Some(1)).unwrap();
    let counts = frame(&mut c, &cam);
    assert_eq!(counts.occluded, 1);
    assert_eq!(c.point_image().point[gap], NO_POINT);
    assert!(c.was_hidden(far_slot as usize));
    // Filled from the eight near neighbours with the Gaussian kernel (points at centres).
    let mut want = Vec3::ZERO;
    let mut ws = 0.0;
    for dy in -1..=1i32 {
        for dx in -1..=1i32 {
            if dx == 0 && dy == 0 {
                continue;
            }
            let j = (cy as i32 + dy) as usize * w as usize + (cx as i32 + dx) as usize;
            let wt = (-((dx * dx + dy * dy) as f32) / (2.0 * INTERP_SIGMA * INTERP_SIGMA)).exp();
            want += colors[j] * wt;
            ws += wt;
        }
    }
    want /= ws;
    let got = c.image()[gap];
    assert!((got - want).abs().max_element() < 1e-3, "filled {got} vs {want}");
    assert!((c.filter_weights()[gap] - ws).abs() < 1e-2 * ws);
    assert_eq!(counts.filled, 1);
}

#[test]
fn background_showing_through_a_sparse_surface_is_culled() {
    // Near surface sampled on a checkerboard (half density, as after moving closer) in front
    // of a densely sampled wall: every wall point between near points is culled, and the
    // wall around the near surface is kept.
    let (w, h) = (24u32, 20u32);
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, w, h);
    let near = plane_points(&cam, 2.0);
    let wall = plane_points(&cam, 6.0);
    let mut c = cache(w, h, 2.0);
    let inside = |x: u32, y: u32| (4..w - 4).contains(&x) && (4..h - 4).contains(&y);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            if inside(x, y) && (x + y) % 2 == 0 {
                c.insert(&at(hit(near[i], Vec3::X, 0), x, y));
            } else {
                c.insert(&at(hit(wall[i], Vec3::Y, 1), x, y));
            }
        }
    }
    let counts = frame(&mut c, &cam);
    let pi = c.point_image();
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let p = pi.point[i];
            let interior = (5..w - 5).contains(&x) && (5..h - 5).contains(&y);
            if interior && (x + y) % 2 == 1 {
                assert_eq!(p, NO_POINT, "wall point at {x},{y} shows through");
                // Away from the two kept corner gaps, only near points are around.
                if (6..w - 6).contains(&x) && (6..h - 6).contains(&y) {
                    assert_eq!(c.image()[i], Vec3::X, "{x},{y} filled from the near surface");
                }
            } else if !inside(x, y) || (x + y) % 2 == 0 {
                assert_ne!(p, NO_POINT, "point at {x},{y} culled");
            }
        }
    }
    // Interior gaps plus the border gaps that have near points on two opposite sides (all\n    // but the two corner gaps).
    assert_eq!(counts.occluded, (w - 8) * (h - 8) / 2 - 2);
}

#[test]
fn points_on_a_slanted_plane_are_kept() {
    let mut rng = Rng(21);
    for tilt_deg in [0.0f32, 45.0, 70.0, 80.0, 85.0] {
        let (w, h) = (40u32, 30u32);
        let cam = camera(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, w, h);
        // Plane through the origin, normal tilted away from the view direction about Y.
        let n = Vec3::new(tilt_deg.to_radians().sin(), 0.0, tilt_deg.to_radians().cos());
        let mut c = cache(w, h, 1.0);
        for y in 0..h {
            for x in 0..w {
                let (o, d) = cam.ray(x as f32 + rng.unit(), y as f32 + rng.unit());
                let t = -n.dot(o) / n.dot(d);
                if t > 0.0 {
                    c.insert(&at(hit(o + d * t, rng.vec3(0.0, 1.0), 0), x, y));
                }
            }
        }
        let counts = frame(&mut c, &cam);
        // Only where the plane meets its horizon (a neighbour pixel sees no plane), whose
        // depth grows without bound, may the local test take a point for occluded.
        let (w, h) = (w as i64, h as i64);
        let mut at_horizon = 0;
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                if c.zbufs[0][i] == EMPTY_KEY || c.point_image().point[i] != NO_POINT {
                    continue;
                }
                let beside_empty = (-1..=1i64).any(|dy| {
                    (-1..=1i64).any(|dx| {
                        let (nx, ny) = (x + dx, y + dy);
                        nx >= 0 && ny >= 0 && nx < w && ny < h && c.zbufs[0][(ny * w + nx) as usize] == EMPTY_KEY
                    })
                });
                assert!(beside_empty, "tilt {tilt_deg}: plane point at {x},{y} culled");
                at_horizon += 1;
            }
        }
        assert!(at_horizon <= h / 5, "tilt {tilt_deg}: {at_horizon} horizon points culled");
        assert_eq!(counts.occluded as i64, at_horizon);
        assert_eq!((counts.with_point + counts.occluded) as usize, c.len(), "tilt {tilt_deg}");
    }
}

#[test]
fn interpolation_uses_5x5_when_3x3_is_empty_and_background_beyond() {
    let (w, h) = (9u32, 9u32);
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, w, h);
    let grid = plane_points(&cam, 3.0);
    let mut c = cache(w, h, 1.0);
    let col = Vec3::new(0.9, 0.5, 0.1);
    c.insert(&hit(grid[4 * 9 + 4], col, 0)); // the centre pixel only
    let counts = frame(&mut c, &cam);
    assert_eq!(counts.with_point, 1);
    assert_eq!(counts.filled, 24, "the 5x5 around the point");
    assert_eq!(counts.empty, 81 - 25);
    let wts = c.filter_weights();
    for y in 0..9i32 {
        for x in 0..9i32 {
            let i = (y * 9 + x) as usize;
            let r = (x - 4).abs().max((y - 4).abs());
            if r <= 2 {
                assert!((c.image()[i] - col).abs().max_element() < 1e-6);
                let want = (-(((x - 4) * (x - 4) + (y - 4) * (y - 4)) as f32) / (2.0 * INTERP_SIGMA * INTERP_SIGMA)).exp();
                assert!((wts[i] - want).abs() < 0.02 * want.max(0.01), "weight at {x},{y}: {} vs {want}", wts[i]);
            } else {
                assert_eq!(c.image()[i], c.config().background);
                assert_eq!(wts[i], 0.0);
            }
        }
    }
    // Weights fall with distance: the sampler's priority rises away from the point.
    assert!(wts[4 * 9 + 5] > wts[4 * 9 + 6] && wts[4 * 9 + 6] > 0.0);
}

#[test]
fn insert_replaces_invalid_then_occluded_then_oldest() {
    let (w, h) = (4u32, 4u32);
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, w, h);
    let grid = plane_points(&cam, 3.0);
    let mut c = cache(w, h, 1.0);
    assert_eq!(c.capacity(), 16);
    // 12 front points (pixels 0..12), 4 points behind pixels 0..4 (slots 12..16).
    for (i, p) in grid.iter().take(12).enumerate() {
        assert!(c.insert(&hit(*p, Vec3::splat(0.5), i as u32)));
    }
    for (i, p) in grid.iter().take(4).enumerate() {
        let far = cam.eye + (*p - cam.eye) * 2.0;
        assert!(c.insert(&hit(far, Vec3::ONE, 100 + i as u32)));
    }
    assert_eq!(c.len(), 16);
    frame(&mut c, &cam);
    // Invalid first: free two slots (objects 5 and 7 are in slots 5 and 7).
    c.invalidate_objects(&[5, 7]);
    assert_eq!(c.len(), 14);
    let mut tag = 1000;
    let mut insert_where = |c: &mut RenderCache| -> u32 {
        tag += 1;
        assert!(c.insert(&hit(Vec3::new(0.0, 0.0, -50.0), Vec3::ZERO, tag)));
        (0..16).find(|&i| c.point(i).map(|p| p.object) == Some(tag)).unwrap()
    };
    assert_eq!([insert_where(&mut c), insert_where(&mut c)], [5, 7]);
    // Then the four hidden points, in slot order.
    for want in 12..16 {
        assert_eq!(insert_where(&mut c), want);
    }
    // Then the oldest in insertion order: the original slots 0..12 except the re-used 5 and
    // 7, then the re-used slots in the order they were re-used (free slots go lowest first:
    // 5, then 7), then the former hidden slots.
    for want in [0, 1, 2, 3, 4, 6, 8, 9, 10, 11, 5, 7, 12, 13, 14, 15, 0] {
        assert_eq!(insert_where(&mut c), want);
    }
    assert_eq!(c.len(), 16);
}

#[test]
fn invalidate_objects_removes_exactly_those_points() {
    let mut rng = Rng(3);
    for _ in 0..5 {
        let mut c = cache(16, 16, 2.0);
        let n = (rng.next_u64() % 600) as usize;
        for _ in 0..n {
            let obj = (rng.next_u64() % 10) as u32;
            if obj == 9 {
                c.insert(&at(miss(rng.vec3(-1.0, 1.0), rng.vec3(0.0, 1.0)), 0, (rng.next_u64() % 16) as u32));
            } else {
                c.insert(&at(hit(rng.vec3(-1.0, 1.0), rng.vec3(0.0, 1.0), obj), 0, (rng.next_u64() % 16) as u32));
            }
        }
        let before: Vec<Option<CachedPoint>> = (0..c.capacity() as u32).map(|i| c.point(i)).collect();
        let drop: Vec<u32> = (0..10).filter(|_| rng.next_u64().is_multiple_of(3)).collect();
        c.invalidate_objects(&drop);
        let mut kept = 0;
        for (i, b) in before.iter().enumerate() {
            let after = c.point(i as u32);
            match b {
                Some(p) if drop.contains(&p.object) => assert!(after.is_none()),
                Some(p) => {
                    assert_eq!(after.as_ref(), Some(p));
                    kept += 1;
                }
                None => assert!(after.is_none()),
            }
        }
        assert_eq!(c.len(), kept);
    }
}

#[test]
fn bad_samples_are_rejected_and_stale_points_get_max_age() {
    let mut c = cache(8, 8, 1.0);
    assert!(!c.insert(&hit(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::ONE, 0)));
    assert!(!c.insert(&hit(Vec3::ZERO, Vec3::new(0.0, f32::INFINITY, 0.0), 0)));
    assert!(!c.insert(&miss(Vec3::ZERO, Vec3::ONE)));
    assert_eq!(c.len(), 0);
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, 8, 8);
    for p in plane_points(&cam, 2.0) {
        assert!(c.insert(&hit(p, Vec3::ONE, 0)));
    }
    frame(&mut c, &cam);
    frame(&mut c, &cam);
    assert!(c.point_image().age.iter().all(|&a| a == 2.0));
    c.mark_stale();
    frame(&mut c, &cam);
    assert!(c.point_image().age.iter().all(|&a| a == STALE_AGE));
    assert_eq!(c.point_image().point.iter().filter(|&&p| p != NO_POINT).count(), 64, "stale points stay visible");
    let empty = RenderCache::new(CacheConfig::new(0, 0));
    assert_eq!(empty.capacity(), 0);
    let mut empty = empty;
    assert!(!empty.insert(&hit(Vec3::ZERO, Vec3::ONE, 0)));
    assert_eq!(frame(&mut empty, &cam), FrameCounts::default());
}

#[test]
fn moving_camera_keeps_points_where_they_project() {
    // After a camera move, every kept point sits in the pixel its world position projects to.
    let mut rng = Rng(17);
    let (w, h) = (48u32, 36u32);
    let mut c = cache(w, h, 2.0);
    let cam0 = camera(Vec3::new(0.5, 0.8, 5.0), Vec3::ZERO, w, h);
    one_sample_per_pixel(&mut c, &cam0, &mut rng);
    let cam1 = Camera { eye: Vec3::new(0.5, 0.8, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 }
        .orbit(Vec3::ZERO, 0.15)
        .frame(w, h);
    let counts = frame(&mut c, &cam1);
    assert!(counts.with_point > w * h / 2);
    let pi = c.point_image();
    for (i, &p) in pi.point.iter().enumerate() {
        if p == NO_POINT {
            continue;
        }
        let cp = c.point(p).unwrap();
        let (pix, _) = oracle_project(&cam1, &cp).unwrap();
        assert_eq!(pix, i);
    }
}

#[test]
fn samples_stay_in_the_pool_region_of_their_row_band() {
    let (w, h) = (10u32, 30u32); // bands of rows 0-7, 8-15, 16-23, 24-29
    let mut c = cache(w, h, 1.5);
    let mut rng = Rng(8);
    assert_eq!(c.regions.len(), 4);
    assert_eq!(c.regions[0].start, 0);
    assert_eq!(c.regions.last().unwrap().end as usize, c.capacity());
    for r in c.regions.windows(2) {
        assert_eq!(r[0].end, r[1].start);
    }
    // Sizes follow the bands' pixel counts.
    assert_eq!(c.regions[1].end - c.regions[1].start, 120);
    assert_eq!(c.regions[3].end - c.regions[3].start, 90);
    // Over-fill: every insert lands in its band's region, the other regions keep their points.
    for k in 0..2000u32 {
        let y = (rng.next_u64() % (h as u64 + 5)) as u32; // rows past the end count as the last
        let tag = 10_000 + k;
        assert!(c.insert(&at(hit(rng.vec3(-1.0, 1.0), rng.vec3(0.0, 1.0), tag), 3, y)));
        let slot = (0..c.capacity() as u32).find(|&i| c.point(i).map(|p| p.object) == Some(tag)).unwrap();
        let band = (y / BAND_ROWS).min(3) as usize;
        let r = &c.regions[band];
        assert!((r.start..r.end).contains(&slot), "row {y} went to slot {slot}");
    }
    assert_eq!(c.len(), c.capacity());
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    // Depth buffers per share of the points are merged: any split gives the same frame.
    let mut rng = Rng(23);
    let (w, h) = (40u32, 30u32);
    let cam = camera(Vec3::new(1.0, 2.0, 6.0), Vec3::ZERO, w, h);
    let samples: Vec<Sample> = (0..3000)
        .map(|_| {
            let s = if rng.next_u64().is_multiple_of(8) { miss(rng.vec3(-1.0, 1.0), rng.vec3(0.0, 1.0)) } else { hit(rng.vec3(-2.0, 2.0), rng.vec3(0.0, 1.0), 0) };
            at(s, (rng.next_u64() % w as u64) as u32, (rng.next_u64() % h as u64) as u32)
        })
        .collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut c = cache(w, h, 2.0);
            for s in &samples {
                c.insert(s);
            }
            let counts = frame(&mut c, &cam);
            let counts2 = frame(&mut c, &cam);
            (counts, counts2, c.point_image().point.clone(), c.image().to_vec(), c.filter_weights().to_vec())
        })
    };
    let one = run(1);
    assert!(one.0.with_point > 0 && one.0.occluded > 0, "{:?}", one.0);
    for threads in [2, 3, 5] {
        assert!(run(threads) == one, "{threads} threads differ from 1");
    }
}

#[test]
fn segment_box_test_matches_dense_sampling_along_the_segment() {
    let mut rng = Rng(41);
    let (mut hits, mut misses) = (0, 0);
    for _ in 0..4000 {
        let lo = rng.vec3(-1.0, 0.5);
        let hi = lo + rng.vec3(0.05, 1.0);
        let (a, b) = (rng.vec3(-2.0, 2.0), rng.vec3(-2.0, 2.0));
        // Points strictly inside the box along the segment prove a hit; staying clear of the
        // box by a margin proves a miss.
        let mut inside = false;
        let mut near = false;
        for k in 0..=2000 {
            let p = a + (b - a) * (k as f32 / 2000.0);
            let d = (lo - p).max(p - hi).max_element();
            inside |= d < -1e-3;
            near |= d < 1e-2;
        }
        let got = segment_hits_box(a, b, lo, hi);
        if inside {
            assert!(got, "{a} {b} in [{lo}, {hi}]");
            hits += 1;
        } else if !near {
            assert!(!got, "{a} {b} clear of [{lo}, {hi}]");
            misses += 1;
        }
    }
    assert!(hits > 100 && misses > 1000, "{hits} hits, {misses} misses");
    // Axis-parallel segments (zero direction components) and a segment starting inside.
    assert!(segment_hits_box(Vec3::new(0.5, 0.5, -1.0), Vec3::new(0.5, 0.5, 2.0), Vec3::ZERO, Vec3::ONE));
    assert!(!segment_hits_box(Vec3::new(1.5, 0.5, -1.0), Vec3::new(1.5, 0.5, 2.0), Vec3::ZERO, Vec3::ONE));
    assert!(segment_hits_box(Vec3::splat(0.5), Vec3::splat(5.0), Vec3::ZERO, Vec3::ONE));
    assert!(!segment_hits_box(Vec3::new(0.5, 0.5, -3.0), Vec3::new(0.5, 0.5, -2.0), Vec3::ZERO, Vec3::ONE), "stops short");
}

#[test]
fn moved_objects_carry_their_points_and_only_theirs() {
    let mut rng = Rng(8);
    let mut c = cache(16, 16, 2.0);
    for _ in 0..300 {
        let obj = (rng.next_u64() % 3) as u32;
        c.insert(&at(hit(rng.vec3(-1.0, 1.0), rng.vec3(0.0, 1.0), obj), 0, (rng.next_u64() % 16) as u32));
    }
    c.insert(&at(miss(Vec3::Z, Vec3::ONE), 0, 0));
    let before: Vec<Option<CachedPoint>> = (0..c.capacity() as u32).map(|i| c.point(i)).collect();
    let from = glam::Affine3A::from_rotation_translation(glam::Quat::from_rotation_y(0.3), Vec3::new(1.0, 0.0, 0.0));
    let to = glam::Affine3A::from_rotation_translation(glam::Quat::from_rotation_z(-0.7), Vec3::new(0.0, 2.0, -1.0));
    let moved = c.move_object(1, &from, &to);
    let mut n = 0;
    for (i, b) in before.iter().enumerate() {
        let (Some(b), Some(a)) = (b, c.point(i as u32)) else {
            assert!(b.is_none() && c.point(i as u32).is_none());
            continue;
        };
        if b.hit && b.object == 1 {
            n += 1;
            // The same point of the object: its object-space position is unchanged.
            let want = to.transform_point3(from.inverse().transform_point3(b.position));
            assert!((a.position - want).length() < 1e-5, "{} vs {want}", a.position);
            assert_eq!(a.age, STALE_AGE, "shaded in the old place");
        } else {
            assert_eq!(a, *b, "other points stay");
        }
    }
    assert_eq!(moved, n);
    assert!(n > 50);
}

#[test]
fn moves_age_exactly_the_points_a_box_can_shadow() {
    let mut rng = Rng(12);
    let mut c = cache(32, 32, 2.0);
    for _ in 0..1500 {
        c.insert(&at(hit(rng.vec3(-3.0, 3.0), Vec3::ONE, 0), 0, (rng.next_u64() % 32) as u32));
    }
    c.insert(&at(miss(Vec3::Y, Vec3::ONE), 0, 0));
    let lights = [LightBound { center: Vec3::new(0.0, 6.0, 0.0), radius: 0.0 }, LightBound { center: Vec3::new(4.0, 4.0, 4.0), radius: 0.5 }];
    let region = (Vec3::new(-0.5, 1.0, -0.5), Vec3::new(0.5, 1.5, 0.5));
    let aged = c.age_shadowed_by(region, &lights);
    let mut n = 0;
    for i in 0..c.capacity() as u32 {
        let Some(p) = c.point(i) else { continue };
        let want = p.hit
            && lights.iter().any(|l| segment_hits_box(p.position, l.center, region.0 - Vec3::splat(l.radius), region.1 + Vec3::splat(l.radius)));
        assert_eq!(p.age == STALE_AGE, want, "{p:?}");
        n += usize::from(want);
    }
    assert_eq!(aged as usize, n);
    assert!(n > 20 && n < 1400, "{n} of 1500 aged");
    assert_eq!(c.age_shadowed_by(region, &[]), 0);
}

#[test]
fn stale_inserts_are_aged_and_fresh_ones_are_not() {
    let mut c = cache(4, 4, 1.0);
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, 4, 4);
    let grid = plane_points(&cam, 3.0);
    for (i, p) in grid.iter().enumerate() {
        assert!(c.insert_aged(&hit(*p, Vec3::ONE, 0), i % 2 == 0));
    }
    frame(&mut c, &cam);
    let ages = &c.point_image().age;
    assert_eq!(ages.iter().filter(|&&a| a == STALE_AGE).count(), 8);
    assert_eq!(ages.iter().filter(|&&a| a == 1.0).count(), 8);
}

#[test]
fn geometry_culls_hidden_points_and_misses_on_surfaces_wherever_they_land() {
    // A wall at depth 4 and points at depth 4 (on it), 6 (behind it) and misses; the
    // geometry covers the left half of the image only.
    let (w, h) = (16u32, 8u32);
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, w, h);
    let n = (w * h) as usize;
    let covered = |i: usize| (i % w as usize) < 8;
    let inverse_depth: Vec<f32> = (0..n).map(|i| if covered(i) { 0.25 } else { 0.0 }).collect();
    let far3: Vec<f32> = (0..n)
        .map(|i| {
            let x = i % w as usize;
            if x < 7 {
                4.0
            } else {
                f32::INFINITY
            }
        })
        .collect();
    let mut c = cache(w, h, 4.0);
    let on = plane_points(&cam, 4.0);
    // Behind it: in the left quarter of the pixel on even rows, the right quarter on odd ones.
    let left = |i: usize| (i / w as usize).is_multiple_of(2);
    let behind: Vec<Vec3> = (0..n)
        .map(|i| {
            let (x, y) = ((i % w as usize) as f32, (i / w as usize) as f32);
            let (o, d) = cam.ray(x + if left(i) { 0.25 } else { 0.75 }, y + 0.5);
            o + d * (6.0 / d.dot(cam.forward))
        })
        .collect();
    for i in 0..n {
        // One point per pixel: alternate surfaces so neighbours never show a point hidden.
        let s = match i % 3 {
            0 => hit(on[i], Vec3::ONE, 0),
            1 => hit(behind[i], Vec3::ONE, 1),
            _ => miss(on[i] - cam.eye, Vec3::ZERO),
        };
        c.insert(&at(s, (i % w as usize) as u32, (i / w as usize) as u32));
    }
    let g = GeometryCull { far3: &far3, inverse_depth: &inverse_depth, generation: 0 };
    c.reproject_points(&cam, Some(g), &mut StageTimes::new());
    let pi = c.point_image();
    for i in 0..n {
        let x = i % w as usize;
        let kept = pi.point[i] != NO_POINT;
        let want = match i % 3 {
            0 => true,   // on the surface
            // Behind it: culled wherever every centre around the pixel shows it, and in the
            // last covered column where the centres around its place in the pixel do (left).
            1 => x >= 8 || (x == 7 && !left(i)),
            // A miss on the surface goes; beside it, its neighbours decide (they are nearer
            // on all sides here, which the neighbour test culls too).
            _ if covered(i) => false,
            _ => continue,
        };
        assert_eq!(kept, want, "pixel {i} (x {x}, kind {})", i % 3);
    }
}

#[test]
fn points_whose_surface_turned_away_from_the_eye_are_not_shown() {
    // A plane of points facing +z (toward the first eye); from behind it, none may show,
    // from a grazing but still front side all may; points of unknown side always may.
    let (w, h) = (16u32, 16u32);
    let front = camera(Vec3::new(0.0, 0.0, 5.0), Vec3::ZERO, w, h);
    let mut c = cache(w, h, 2.0);
    for (i, p) in plane_points(&front, 5.0).iter().enumerate() {
        let mut s = at(hit(*p, Vec3::ONE, 0), i as u32 % w, i as u32 / w);
        s.normal = Vec3::Z;
        assert!(c.insert(&s));
    }
    let shown = |c: &mut RenderCache, eye: Vec3| {
        let cam = camera(eye, Vec3::ZERO, w, h);
        frame(c, &cam);
        c.point_image().point.iter().filter(|&&p| p != NO_POINT).count()
    };
    assert!(shown(&mut c, Vec3::new(0.0, 0.0, 5.0)) > 200);
    assert!(shown(&mut c, Vec3::new(3.0, 0.0, 4.0)) > 0, "seen from the front at an angle");
    assert_eq!(shown(&mut c, Vec3::new(0.5, 0.2, -5.0)), 0, "seen from behind: the other side");
    // A moved object's points turn with it: rotated half a turn about y, they face -z.
    let half = glam::Affine3A::from_rotation_y(std::f32::consts::PI);
    c.move_object(0, &glam::Affine3A::IDENTITY, &half);
    assert!(shown(&mut c, Vec3::new(0.5, 0.2, -5.0)) > 200, "now the front");
    let p = (0..c.capacity() as u32).find_map(|i| c.point(i)).unwrap();
    assert!((p.normal - Vec3::NEG_Z).length() < 1e-3, "{}", p.normal);
}

#[test]
fn stale_points_give_way_to_newer_disagreeing_ones_of_the_same_surface_nearby() {
    // Random point images against the definition, pixel by pixel: a stale hit point is left
    // out exactly when a point of its object (or, without objects, of a depth within 5 %)
    // within FRESH_RADIUS pixels in both axes is fresh or shaded in a later frame, and
    // disagrees with it in colour.
    use super::fresh::{disagree, display_rgb, FRESH_RADIUS};
    let mut rng = Rng::new(41);
    let palette = [Vec3::splat(0.05), Vec3::splat(0.06), Vec3::splat(0.5), Vec3::new(0.5, 0.1, 0.1)];
    for case in 0..80 {
        let (w, h) = (1 + rng.below(23) as u32, 1 + rng.below(19) as u32);
        let mut c = cache(w, h, 1.0);
        let n = (w * h) as usize;
        assert!(c.capacity() >= n);
        let objects: Vec<u32> = (0..n).map(|_| rng.below(3) as u32).collect();
        c.frame = 10;
        for i in 0..n {
            let kind = rng.below(4);
            let stale = kind <= 2;
            let born = 5 + rng.below(4) as u32;
            c.pool.flags[i] = FLAG_VALID | FLAG_HIT | if stale { FLAG_STALE } else { 0 };
            c.pool.shade[i] = Shade { color: palette[rng.below(4)], born };
            let p = &mut c.points;
            p.point[i] = if kind == 0 { NO_POINT } else { i as u32 };
            p.depth[i] = match kind {
                0 => f32::INFINITY,
                1 if rng.below(4) == 0 => f32::INFINITY, // a miss
                _ => 1.0 + rng.below(3) as f32 * 0.5 + rng.unit() * 0.01,
            };
            p.age[i] = match kind {
                0 => f32::INFINITY,
                1 | 2 => STALE_AGE,
                _ => RenderCache::age_of(c.frame, born),
            };
            p.color[i] = if kind == 0 { Vec3::ZERO } else { c.pool.shade[i].color };
            p.born[i] = if kind == 0 { 0 } else { born };
        }
        // Set by hand, so the count reprojection keeps is set by hand too.
        c.stale_shown = c.points.age.iter().filter(|&&a| a == STALE_AGE).count() as u32;
        let before = c.points.clone();
        let with_objects = case % 2 == 0;
        let hidden = c.hide_stale_near_fresh(with_objects.then_some(&objects[..]));
        let r = FRESH_RADIUS as i64;
        let mut expect = 0;
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let i = (y * w as i64 + x) as usize;
                let stale = before.point[i] != NO_POINT && before.age[i] == STALE_AGE && before.depth[i].is_finite();
                let newer_near = (-r..=r).flat_map(|dy| (-r..=r).map(move |dx| (x + dx, y + dy))).any(|(xx, yy)| {
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        return false;
                    }
                    let j = (yy * w as i64 + xx) as usize;
                    if j == i || before.point[j] == NO_POINT || !before.depth[j].is_finite() {
                        return false;
                    }
                    let same = if with_objects { objects[j] == objects[i] } else { (before.depth[j] - before.depth[i]).abs() <= 0.05 * before.depth[i] };
                    let trusted = before.age[j] < STALE_AGE || c.pool.shade[j].born > c.pool.shade[i].born;
                    same && trusted && disagree(display_rgb(before.color[i]), display_rgb(before.color[j]))
                });
                let gone = stale && newer_near;
                expect += gone as u32;
                assert_eq!(c.points.point[i] == NO_POINT, gone || before.point[i] == NO_POINT, "case {case} pixel {x},{y}");
                if !gone {
                    assert_eq!(c.points.age[i].to_bits(), before.age[i].to_bits());
                    assert_eq!(c.points.color[i], before.color[i]);
                }
            }
        }
        assert_eq!(hidden, expect);
    }
    // The colour test itself: display-like differences.
    let d = |a: Vec3, b: Vec3| disagree(display_rgb(a), display_rgb(b));
    assert!(d(Vec3::splat(0.05), Vec3::splat(0.5)));
    assert!(d(Vec3::new(0.5, 0.5, 0.05), Vec3::splat(0.5)), "one channel is enough");
    assert!(!d(Vec3::splat(0.05), Vec3::splat(0.06)));
    assert!(!d(Vec3::splat(0.5), Vec3::splat(0.55)));
}

#[test]
fn a_still_view_reprojecting_only_new_points_equals_a_full_reprojection() {
    still_view_lockstep(false);
}

#[test]
fn a_still_view_updating_its_point_image_in_place_equals_a_full_pass_with_geometry() {
    still_view_lockstep(true);
}

/// Geometry cull images for the lockstep test: surfaces at random depths around the three
/// layers, some pixels uncovered; `seed` changes them.
fn random_geometry(n: usize, seed: u64) -> (Vec<f32>, Vec<f32>) {
    let mut rng = Rng::new(seed);
    let far3 = (0..n).map(|_| if rng.chance(0.2) { f32::INFINITY } else { 3.2 + rng.unit() * 1.6 }).collect();
    let inverse_depth = (0..n).map(|_| if rng.chance(0.3) { 0.0 } else { 1.0 / (3.0 + rng.unit()) }).collect();
    (far3, inverse_depth)
}

fn still_view_lockstep(with_geometry: bool) {
    // Two caches fed the same samples frame by frame; the second reprojects everything every
    // frame. Still frames (new points replacing old ones, nearest points among them), a
    // camera change, a moved object and removed objects in between: the depth buffers, the
    // projections and the point images must be identical.
    let (w, h) = (37u32, 29u32);
    let mut rng = Rng::new(77);
    let mut inc = cache(w, h, 0.6);
    let mut full = cache(w, h, 0.6);
    let mut cam = camera(Vec3::new(0.3, 0.2, 5.0), Vec3::ZERO, w, h);
    let mut still_frames = 0;
    let mut in_place_frames = 0;
    let mut geometry = random_geometry((w * h) as usize, 1);
    let mut generation = 0;
    for f in 0..40 {
        if f == 15 {
            cam = camera(Vec3::new(0.8, 0.4, 4.5), Vec3::ZERO, w, h);
        }
        if f == 22 {
            let (a, b) = (glam::Affine3A::IDENTITY, glam::Affine3A::from_translation(Vec3::new(0.1, 0.0, 0.0)));
            inc.move_object(1, &a, &b);
            full.move_object(1, &a, &b);
        }
        if f == 30 {
            inc.invalidate_objects(&[2]);
            full.invalidate_objects(&[2]);
        }
        if f == 34 {
            // Points turning stale in a still view: the point image must show it.
            let light = [LightBound { center: Vec3::new(0.0, 3.0, 0.0), radius: 0.5 }];
            let region = (Vec3::splat(-0.5), Vec3::splat(0.5));
            assert_eq!(inc.age_shadowed_by(region, &light), full.age_shadowed_by(region, &light));
        }
        if f == 37 {
            inc.mark_stale();
            full.mark_stale();
        }
        for _ in 0..rng.below(300) {
            let (x, y) = (rng.below(w as usize) as f32 + rng.unit(), rng.below(h as usize) as f32 + rng.unit());
            let (o, d) = cam.ray(x, y);
            let s = if rng.chance(0.1) {
                miss(d, Vec3::splat(rng.unit()))
            } else {
                // Three layers (objects 0, 1, 2) so that new points win and lose pixels.
                let object = rng.below(3) as u32;
                let t = 3.0 + object as f32 * 0.7 + rng.unit() * 0.05;
                let mut s = hit(o + d * t, Vec3::splat(rng.unit()), object);
                s.normal = if rng.chance(0.2) { d } else { -d };
                s
            };
            let mut s = at(s, x as u32, y as u32);
            // Some samples re-shade the point their pixel shows (converge.rs): averaged into
            // it, or replacing it when it is stale.
            let mut aimed = NO_POINT;
            let shown = inc.point_image().point[(y as u32 * w + x as u32) as usize];
            if let Some(p) = inc.point(shown).filter(|_| rng.chance(0.3)) {
                (s.hit, s.position, s.object, s.epoch, aimed) = (p.hit, p.position, p.object, p.epoch, shown);
            }
            let stale = rng.chance(0.05);
            assert_eq!(inc.insert_aimed(&s, stale, aimed), full.insert_aimed(&s, stale, aimed));
        }
        full.reproject_all = true;
        still_frames += usize::from(!inc.reproject_all && inc.last_view.is_some());
        in_place_frames += usize::from(!inc.reproject_all && inc.last_view.is_some() && inc.point_image_from.is_some());
        if f == 10 || f == 26 {
            geometry = random_geometry((w * h) as usize, f as u64);
            generation += 1;
        }
        let g = || with_geometry.then(|| GeometryCull { far3: &geometry.0, inverse_depth: &geometry.1, generation });
        let step = |c: &mut RenderCache| {
            let mut times = StageTimes::new();
            let occluded = c.reproject_points(&cam, g(), &mut times);
            let (with_point, filled, empty) = c.interpolate_gaps(&mut times);
            FrameCounts { with_point, filled, empty, occluded, cache_points: c.valid as u32 }
        };
        let (a, b) = (step(&mut inc), step(&mut full));
        assert_eq!(a, b, "frame {f}: counts");
        assert_eq!(inc.stale_shown, full.stale_shown, "frame {f}: stale points shown");
        assert_eq!(inc.status, full.status, "frame {f}: pass 2 outcomes");
        assert_eq!(inc.zbufs[0], full.zbufs[0], "frame {f}: depth buffer");
        for i in 0..inc.capacity {
            let (a, b) = (inc.proj[i], full.proj[i]);
            assert_eq!((a.pixel, a.depth.to_bits(), a.fx, a.fy), (b.pixel, b.depth.to_bits(), b.fx, b.fy), "frame {f}: projection of slot {i}");
        }
        let (a, b) = (inc.point_image(), full.point_image());
        assert_eq!(a.point, b.point, "frame {f}");
        assert_eq!(a.born, b.born);
        assert_eq!(a.color, b.color);
        assert_eq!(a.subpixel, b.subpixel);
        assert_eq!(a.age.iter().map(|d| d.to_bits()).collect::<Vec<_>>(), b.age.iter().map(|d| d.to_bits()).collect::<Vec<_>>(), "frame {f}: ages");
        assert_eq!(a.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(), b.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>());
    }
    assert!(still_frames >= 25, "most frames took the still-view path ({still_frames})");
    assert!(in_place_frames >= 20, "most still frames updated the point image in place ({in_place_frames})");
    assert!(inc.averaged() > 300, "samples were averaged into points ({})", inc.averaged());
}

#[test]
fn ages_equal_the_wide_conversion() {
    // The oracle: the difference as a 64-bit integer to f32, capped at STALE_AGE.
    let oracle = |frame: u32, born: u32| (i64::from(frame.wrapping_sub(born)) as f32).min(STALE_AGE);
    let mut rng = Rng::new(5);
    let edges = [0u32, 1, 1 << 24, (1 << 24) + 1, 999_999_999, 1_000_000_000, 1_000_000_064, (1 << 31) - 1, 1 << 31, u32::MAX];
    for &d in &edges {
        for born in [0u32, 7, u32::MAX - 3] {
            let frame = born.wrapping_add(d);
            assert_eq!(RenderCache::age_of(frame, born).to_bits(), oracle(frame, born).to_bits(), "difference {d}");
        }
    }
    for _ in 0..100_000 {
        let (frame, born) = (rng.next_u64() as u32, rng.next_u64() as u32);
        assert_eq!(RenderCache::age_of(frame, born).to_bits(), oracle(frame, born).to_bits());
    }
}

/// A cache with one point per pixel of `cam` (at a random place in the pixel, `seed`) on the
/// floor y = 0, shaded `shade`.
fn floor_points(cam: &CameraFrame, seed: u64, shade: impl Fn(Vec3) -> Vec3) -> RenderCache {
    let mut c = cache(cam.width, cam.height, 2.0);
    let mut rng = Rng(seed);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let (o, d) = cam.ray(x as f32 + rng.unit(), y as f32 + rng.unit());
            let p = o + d * (-o.y / d.y);
            assert!(c.insert(&at(hit(p, shade(p), 7), x, y)));
        }
    }
    c
}

/// The exact shading of a floor point under a point light with a square blocker placed by
/// `t`: lit 1, in its shadow 0.1 (the workers' `direct` shader, reduced to its shadow test).
fn floor_shade(bvh: &crate::edges::face_bvh::FaceBvh, t: &glam::Affine3A, light: Vec3, p: Vec3) -> Vec3 {
    if crate::session::move_shadows::segment_blocked(bvh, &t.inverse(), p, light) { Vec3::splat(0.1) } else { Vec3::ONE }
}

/// Issue 11: a moving object's hard shadow. A blocker between a point light and a floor
/// slides along X; after the move the frame must show no point shaded under its old shadow
/// (those drew the old shadow's ragged outline beside the new shadow edge), and must keep,
/// fresh, every point whose shadow the move did not change (else the whole shadow volume
/// is stale on every move and the sampler cannot keep up with it). An area light, which
/// the exact test cannot answer, still makes the points it may shadow stale.
#[test]
fn a_move_drops_the_points_whose_point_light_shadow_it_changed_and_keeps_the_others_fresh() {
    use crate::edges::face_bvh::FaceBvh;
    use crate::session::move_shadows::{Exact, MoveQuery};
    let (w, h) = (48u32, 48u32);
    // Looking down at the floor y = 0 from above.
    let cam = Camera { eye: Vec3::new(0.0, 5.0, 0.0), target: Vec3::ZERO, up: Vec3::NEG_Z, fov_y_degrees: 50.0 }.frame(w, h);
    let quad = [Vec3::new(-0.5, 1.0, -0.5), Vec3::new(0.5, 1.0, -0.5), Vec3::new(0.5, 1.0, 0.5), Vec3::new(-0.5, 1.0, 0.5)];
    let mesh = edgepoint_scene::Mesh::from_triangles(quad.to_vec(), vec![[0, 1, 2], [0, 2, 3]], &edgepoint_scene::NoProgress);
    let bvh = FaceBvh::build(&mesh, &edgepoint_scene::NoProgress);
    let exact = Exact { bvh: FaceBvh::build(&mesh, &edgepoint_scene::NoProgress), solids: None };
    let light = Vec3::new(0.0, 2.0, 0.0);
    let (from, to) = (glam::Affine3A::IDENTITY, glam::Affine3A::from_translation(Vec3::new(0.4, 0.0, 0.0)));
    // One point per pixel, shaded exactly with the blocker in its old place.
    let filled = || floor_points(&cam, 11, |p| floor_shade(&bvh, &from, light, p));
    let lights = [LightBound { center: light, radius: 0.0 }];
    let region = (Vec3::new(-0.5, 1.0, -0.5), Vec3::new(0.9, 1.0, 0.5));
    // Pixels whose shown point has the wrong shading for the new place, and stale ones.
    let judge = |c: &mut RenderCache| {
        frame(c, &cam);
        let pi = c.point_image();
        let (mut wrong, mut stale, mut shown, mut in_shadow) = (0, 0, 0, 0);
        for i in 0..(w * h) as usize {
            if pi.point[i] == NO_POINT {
                continue;
            }
            let want = floor_shade(&bvh, &to, light, c.point(pi.point[i]).unwrap().position);
            wrong += usize::from(pi.color[i] != want);
            stale += usize::from(pi.age[i] >= STALE_AGE);
            shown += 1;
            in_shadow += usize::from(want.x < 0.5);
        }
        (wrong, stale, shown, in_shadow)
    };
    // What a move did before: every point the swept box can shadow aged, and shown until
    // re-shaded, the wrong ones among them too.
    let mut before = filled();
    before.age_shadowed_by(region, &lights);
    let (wrong, stale, _, _) = judge(&mut before);
    assert!(wrong > 200 && stale > wrong + 100, "before: {wrong} wrong points shown, {stale} stale");
    let mut c = filled();
    let r = c.reshadow(region, &lights, &MoveQuery::new(Some(&exact), &mesh, &from, &to, &lights, &[]));
    let (wrong, stale, shown, in_shadow) = judge(&mut c);
    assert_eq!((wrong, stale), (0, 0), "no point shaded under the blocker's old place is shown, and the others stay fresh");
    // The floor's shadows of the old and new place are squares of side 2 (the blocker's 1,
    // scaled by 2 from height 1 under a light at height 2) shifted by 0.8: 0.8 × 2 changed
    // at each end.
    let floor_per_pixel = {
        let half = 5.0 * (25f32.to_radians()).tan();
        (2.0 * half / w as f32).powi(2)
    };
    let expected = (2.0 * 0.8 * 2.0 / floor_per_pixel) as i64;
    assert!((r.dropped as i64 - expected).abs() < expected / 5, "{} dropped, about {expected} expected", r.dropped);
    assert_eq!(r.stale, 0);
    assert_eq!(c.len() + r.dropped as usize, (w * h) as usize);
    assert!(shown > (w * h) as usize * 3 / 4);
    assert!(in_shadow > 100, "{in_shadow} points in the new shadow are kept");
    // An area light without its polygon: no exact answer, the points it may shadow are
    // aged, none dropped.
    let area = [LightBound { center: light, radius: 0.05 }];
    let before = c.len();
    let r = c.reshadow(region, &area, &MoveQuery::new(Some(&exact), &mesh, &to, &from, &area, &[]));
    assert_eq!((r.dropped, c.len()), (0, before));
    assert!(r.stale as usize > expected as usize, "{} aged", r.stale);
}

/// The exact shading of a floor point under a square area light (side 0.6 at height 2,
/// facing down) with the square blocker placed by `t`: the fraction of the light's
/// irradiance left, from the backprojection with the blocker's two triangles.
fn floor_shade_area(mesh: &edgepoint_scene::Mesh, t: &glam::Affine3A, light: &edgepoint_scene::backprojection::LightPlane, p: Vec3) -> Vec3 {
    use edgepoint_scene::backprojection::Visible;
    let free = Visible::new(light, p, Vec3::Y).map_or(0.0, |v| v.irradiance());
    let left = Visible::new(light, p, Vec3::Y).map_or(0.0, |mut v| {
        for f in 0..mesh.triangles.len() {
            v.occlude(mesh.triangle(f).map(|x| t.transform_point3(x).as_dvec3()));
        }
        v.irradiance()
    });
    Vec3::splat((left / free) as f32)
}

/// An area light's soft shadow, moved twice: the blocker of the point-light test slides
/// under a square light, 0.2 and again 0.2 along x. After each move every point shown fresh
/// is exact for the new place; a point whose shading the moves shifted by less than
/// [`DROP_DRIFT`] of the light in all (the shifts summed over both moves: a point made stale
/// by the first is judged again by the second) is shown stale and is off by no more than
/// that; the others are dropped (those were the old soft shadow's dark speckles). Points lit
/// in both places or in both umbrae stay fresh.
#[test]
fn a_move_keeps_points_it_shifted_a_little_stale_and_drops_the_others() {
    use crate::edges::face_bvh::FaceBvh;
    use crate::render_cache::reshadow::DROP_DRIFT;
    use crate::session::move_shadows::{convex_solids, Exact, MoveQuery};
    use edgepoint_scene::backprojection::LightPlane;
    let (w, h) = (48u32, 48u32);
    let cam = Camera { eye: Vec3::new(0.0, 5.0, 0.0), target: Vec3::ZERO, up: Vec3::NEG_Z, fov_y_degrees: 50.0 }.frame(w, h);
    // A slab (a closed box) 1 × 0.02 × 1 at height 1.
    let slab = edgepoint_scene::builtin::shapes::cuboid(Vec3::new(-0.5, 0.99, -0.5), Vec3::new(0.5, 1.01, 0.5));
    let exact = Exact { bvh: FaceBvh::build(&slab, &edgepoint_scene::NoProgress), solids: convex_solids(&slab) };
    assert_eq!(exact.solids.as_ref().map(|s| s.len()), Some(1), "a box is one convex solid");
    let a = 0.3f32;
    let corners = vec![Vec3::new(-a, 2.0, -a), Vec3::new(a, 2.0, -a), Vec3::new(a, 2.0, a), Vec3::new(-a, 2.0, a)];
    let plane = LightPlane::new(&corners).unwrap();
    assert!(plane.n.y < 0.0, "the light faces down");
    let places = [0.0f32, 0.2, 0.4].map(|x| glam::Affine3A::from_translation(Vec3::new(x, 0.0, 0.0)));
    let mut c = floor_points(&cam, 13, |p| floor_shade_area(&slab, &places[0], &plane, p));
    let lights = [LightBound { center: Vec3::new(0.0, 2.0, 0.0), radius: a * std::f32::consts::SQRT_2 }];
    let areas = [Some(plane.clone())];
    let region = (Vec3::new(-0.5, 0.99, -0.5), Vec3::new(0.9, 1.01, 0.5));
    let (mut dropped, mut stale_total) = (0, 0);
    for k in 1..places.len() {
        let r = c.reshadow(region, &lights, &MoveQuery::new(Some(&exact), &slab, &places[k - 1], &places[k], &lights, &areas));
        dropped += r.dropped;
        frame(&mut c, &cam);
        let pi = c.point_image();
        let (mut shown, mut stale, mut dark, mut lit) = (0, 0, 0, 0);
        for i in 0..(w * h) as usize {
            if pi.point[i] == NO_POINT {
                continue;
            }
            let want = floor_shade_area(&slab, &places[k], &plane, c.point(pi.point[i]).unwrap().position);
            let off = (pi.color[i] - want).abs().max_element();
            if pi.age[i] < STALE_AGE {
                assert!(off < 1e-5, "move {k}, pixel {i}: shown fresh {} but {} in the new place", pi.color[i], want);
                dark += usize::from(want.x < 1e-6);
                lit += usize::from(want.x > 1.0 - 1e-6);
            } else {
                // The drift is kept in 1/255 of the light, rounded.
                assert!(off <= DROP_DRIFT + 1.0 / 255.0, "move {k}, pixel {i}: shown stale {} but {} in the new place", pi.color[i], want);
                stale += 1;
            }
            shown += 1;
        }
        assert!(dark > 20 && lit > (w * h) as usize / 2 && shown > (w * h) as usize / 2, "move {k}: {shown} shown: {dark} in both umbrae, {lit} lit in both");
        stale_total += stale;
    }
    assert!(dropped > 100, "{dropped} dropped");
    assert!(stale_total > 20, "{stale_total} shown stale: some points shifted a little");
}
