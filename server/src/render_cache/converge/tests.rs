//! Converging at rest: samples re-aimed at a cached point are averaged into it exactly, a
//! pixel's variance falls as 1/n over still frames, and anything that changes a point's
//! shading resets its count.
use super::super::*;
use super::{tone, PRIOR_SAMPLES};
use crate::rng::Rng;
use crate::sampling::{aim_at_points, PixelRequest, Sampler, SamplingConfig};
use crate::stage_times::StageTimes;
use edgepoint_scene::camera::{Camera, CameraFrame};

fn camera(w: u32, h: u32) -> CameraFrame {
    Camera { eye: Vec3::new(0.5, 0.8, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 50.0 }.frame(w, h)
}

/// The little scene of the cache tests, traced: a sphere (object 0) before a slanted plane
/// (object 1), sky elsewhere. Returns (hit, position or direction, object).
fn trace(cam: &CameraFrame, sx: f32, sy: f32) -> (bool, Vec3, u32) {
    let (o, d) = cam.ray(sx, sy);
    let (centre, radius) = (Vec3::new(0.3, 0.2, 0.0), 0.8);
    let (plane_n, plane_d) = (Vec3::new(0.2, 0.3, 1.0).normalize(), -1.5);
    let mut best = (f32::INFINITY, u32::MAX);
    let oc = o - centre;
    let b = oc.dot(d);
    let disc = b * b - (oc.length_squared() - radius * radius);
    if disc >= 0.0 && -b - disc.sqrt() > 0.0 {
        best = (-b - disc.sqrt(), 0);
    }
    let t = (plane_d - plane_n.dot(o)) / plane_n.dot(d);
    if t > 0.0 && t < best.0 && (o + d * t).x.abs() < 1.5 {
        best = (t, 1);
    }
    if best.1 == u32::MAX {
        (false, d, u32::MAX)
    } else {
        (true, o + d * best.0, best.1)
    }
}

/// A sample of the ray through (sx, sy) of pixel `pixel` with colour `color`.
fn shade(cam: &CameraFrame, pixel: [u32; 2], (sx, sy): (f32, f32), color: Vec3, epoch: u64) -> Sample {
    let (hit, position, object) = trace(cam, sx, sy);
    let normal = if hit { (cam.eye - position).normalize() } else { Vec3::ZERO };
    Sample { hit, position, normal, color, object, epoch, pixel }
}

/// One jittered sample per pixel, then a frame.
fn first_samples(c: &mut RenderCache, cam: &CameraFrame, rng: &mut Rng, color: impl Fn(&mut Rng) -> Vec3) {
    for y in 0..cam.height {
        for x in 0..cam.width {
            let s = shade(cam, [x, y], (x as f32 + rng.unit(), y as f32 + rng.unit()), color(rng), 1);
            assert!(c.insert(&s));
        }
    }
    c.reproject_points(cam, None, &mut StageTimes::new());
}

/// A pick of every pixel that shows a point, aimed at it.
fn aimed_picks(c: &RenderCache, rng: &mut Rng) -> Vec<PixelRequest> {
    let (w, h) = (c.width(), c.height());
    let pi = c.point_image();
    let mut picks: Vec<PixelRequest> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .filter(|&(x, y)| pi.point[(y * w + x) as usize] != NO_POINT)
        .map(|(x, y)| PixelRequest { x, y, sx: x as f32 + 0.5, sy: y as f32 + 0.5, point: NO_POINT })
        .collect();
    for p in &mut picks {
        (p.sx, p.sy) = (p.x as f32 + rng.unit(), p.y as f32 + rng.unit());
    }
    aim_at_points(&mut picks, c.point_image(), |_, _| true, |_, _, _, _| false);
    picks
}

#[test]
fn a_point_re_shaded_n_times_holds_the_mean_of_its_samples() {
    let (w, h) = (40u32, 30u32);
    let cam = camera(w, h);
    let mut rng = Rng::new(3);
    let mut c = RenderCache::new(CacheConfig::new(w, h));
    // Per pixel: the oracle's sum of the samples given to the point it shows (f64).
    let mut sums = vec![glam::DVec3::ZERO; (w * h) as usize];
    first_samples(&mut c, &cam, &mut rng, |r| r.vec3(0.0, 1.0));
    for (i, s) in sums.iter_mut().enumerate() {
        *s = c.point_image().color[i].as_dvec3();
    }
    let shown: Vec<u32> = c.point_image().point.clone();
    let with_point = shown.iter().filter(|&&p| p != NO_POINT).count();
    assert!(with_point > (w * h) as usize * 9 / 10, "nearly every pixel shows its point ({with_point})");
    let rounds = 24u32;
    for _ in 0..rounds {
        for p in aimed_picks(&c, &mut rng) {
            // A noisy value around a known mean (uniform noise of a wide range).
            let color = Vec3::new(0.3, 0.5, 0.7) + rng.vec3(-0.3, 0.3);
            let i = (p.y * w + p.x) as usize;
            sums[i] += color.as_dvec3();
            assert!(c.insert_aimed(&shade(&cam, [p.x, p.y], (p.sx, p.sy), color, 1), false, p.point));
        }
        c.reproject_points(&cam, None, &mut StageTimes::new());
        assert_eq!(c.point_image().point, shown, "averaging keeps every point in its place");
    }
    assert_eq!(c.averaged(), u64::from(rounds) * with_point as u64, "every re-aimed sample found its point");
    assert_eq!(c.len(), (w * h) as usize, "and took no slot of its own");
    for (i, &slot) in shown.iter().enumerate().filter(|&(_, &slot)| slot != NO_POINT) {
        let p = c.point(slot).unwrap();
        assert_eq!(p.samples, rounds + 1);
        let mean = sums[i] / f64::from(rounds + 1);
        assert!((p.color.as_dvec3() - mean).abs().max_element() < 1e-5, "pixel {i}: {} vs mean {mean}", p.color);
        assert_eq!(c.point_image().color[i], p.color, "the point image shows the mean");
        assert_eq!(p.age, 1.0, "a point averaged before the last frame counts as shaded then");
    }
}

#[test]
fn a_pixel_s_variance_falls_as_one_over_its_samples_over_still_frames() {
    // Frames at rest as a session makes them: prioritized sampling of 1/4 of the pixels per
    // frame, picks aimed at the points, shaded with noise of known variance, inserted,
    // reprojected. The points' errors against the true value, scaled by their sample counts,
    // have variance σ² whatever the counts are (the samples are averaged with their count),
    // and the image's mean squared error falls as the mean of 1/n.
    let (w, h) = (64u32, 64u32);
    let cam = camera(w, h);
    let mut rng = Rng::new(11);
    let truth = Vec3::splat(0.5);
    let sigma = 0.2f64; // standard deviation of uniform noise on [-a, a]: a / √3
    let a = (sigma * 3f64.sqrt()) as f32;
    let noisy = move |r: &mut Rng| truth + Vec3::splat(r.range(-a, a));
    let mut c = RenderCache::new(CacheConfig::new(w, h));
    first_samples(&mut c, &cam, &mut rng, noisy);
    let mut sampler = Sampler::new(w, h, 5);
    let cfg = SamplingConfig::default();
    let mut picks = Vec::new();
    let n_px = (w * h) as usize;
    let mut last_mse = f64::INFINITY;
    for f in 1..=96u32 {
        c.reproject_and_interpolate(&cam, &mut StageTimes::new());
        if f % 32 == 0 {
            let pi = c.point_image();
            let (mut scaled, mut mse, mut inv_n) = (0.0f64, 0.0f64, 0.0f64);
            let shown: Vec<CachedPoint> = pi.point.iter().filter_map(|&j| c.point(j)).collect();
            assert!(shown.len() > n_px * 9 / 10, "frame {f}: most pixels show a point");
            let n_px = shown.len();
            for p in shown {
                let e = f64::from(p.color.x - truth.x);
                scaled += e * e * f64::from(p.samples);
                mse += e * e;
                inv_n += 1.0 / f64::from(p.samples);
            }
            let (scaled, mse, inv_n) = (scaled / n_px as f64 / (sigma * sigma), mse / n_px as f64, inv_n / n_px as f64);
            // 4096 pixels: the relative standard error of a variance estimate is about
            // √(2/4096) = 2.2 % (less for uniform noise); ±10 % is 4.5 of them.
            assert!((scaled - 1.0).abs() < 0.1, "frame {f}: n·error²/σ² averages {scaled:.3}, not 1");
            assert!((mse / (sigma * sigma * inv_n) - 1.0).abs() < 0.15, "frame {f}: MSE {mse:.2e} vs σ²·mean(1/n) {:.2e}", sigma * sigma * inv_n);
            assert!(mse < last_mse * 0.85, "frame {f}: the image's error falls ({mse:.2e} after {last_mse:.2e})");
            last_mse = mse;
        }
        sampler.select(c.filter_weights(), &c.point_image().age, &cfg, n_px / 4, &mut picks);
        aim_at_points(&mut picks, c.point_image(), |_, _| true, |_, _, _, _| false);
        for p in &picks {
            c.insert_aimed(&shade(&cam, [p.x, p.y], (p.sx, p.sy), noisy(&mut rng), 1), false, p.point);
        }
    }
    // 95 frames × 1/4 of the pixels: about 24 samples a point.
    assert!(c.averaged() as f64 > 0.95 * 95.0 * (n_px / 4) as f64, "nearly every sample was averaged ({})", c.averaged());
}

#[test]
fn changes_reset_the_count_and_other_samples_do_not_join_a_point() {
    let (w, h) = (24u32, 18u32);
    let cam = camera(w, h);
    let mut rng = Rng::new(8);
    let mut c = RenderCache::new(CacheConfig::new(w, h));
    first_samples(&mut c, &cam, &mut rng, |_| Vec3::splat(0.25));
    for _ in 0..3 {
        for p in aimed_picks(&c, &mut rng) {
            c.insert_aimed(&shade(&cam, [p.x, p.y], (p.sx, p.sy), Vec3::splat(0.25), 1), false, p.point);
        }
        c.reproject_points(&cam, None, &mut StageTimes::new());
    }
    let pi = c.point_image().clone();
    let count = |c: &RenderCache, i: usize| c.point(pi.point[i]).map(|p| p.samples);
    // A pixel on the sphere (object 0) and one on the plane (object 1).
    let find = |o: u32| (0..pi.point.len()).find(|&i| c.point(pi.point[i]).is_some_and(|p| p.hit && p.object == o)).unwrap();
    let (on_sphere, on_plane) = (find(0), find(1));
    assert_eq!(count(&c, on_plane), Some(4));
    let xy = |i: usize| [(i % w as usize) as u32, (i / w as usize) as u32];
    let aim = |i: usize| {
        let [x, y] = xy(i);
        (x as f32 + pi.subpixel[i][0], y as f32 + pi.subpixel[i][1])
    };

    // A sample elsewhere in the pixel is another point: it is not averaged in.
    let [x, y] = xy(on_plane);
    let [u, v] = pi.subpixel[on_plane];
    let away = (x as f32 + if u < 0.5 { u + 0.4 } else { u - 0.4 }, y as f32 + v);
    let plane_point = pi.point[on_plane];
    let before = c.averaged();
    c.insert_aimed(&shade(&cam, [x, y], away, Vec3::ONE, 1), false, plane_point);
    assert_eq!(c.averaged(), before, "a sample a part of a pixel away");
    assert_eq!(count(&c, on_plane), Some(4));
    // Another object's sample at the same place is not (it cannot be the same point).
    let mut other = shade(&cam, [x, y], aim(on_plane), Vec3::ONE, 1);
    other.object = 7;
    c.insert_aimed(&other, false, plane_point);
    assert_eq!(c.averaged(), before);
    // Nor is a sample of the point that was not aimed at it (a jittered pick that happens to
    // land there), nor one aimed at a point another pixel shows.
    c.insert(&shade(&cam, [x, y], aim(on_plane), Vec3::ONE, 1));
    c.insert_aimed(&shade(&cam, [x, y], aim(on_plane), Vec3::ONE, 1), false, pi.point[on_plane + 1]);
    assert_eq!((c.averaged(), count(&c, on_plane)), (before, Some(4)));
    // A sample of a later epoch (an object moved meanwhile) replaces the point: count 1.
    c.insert_aimed(&shade(&cam, [x, y], aim(on_plane), Vec3::splat(0.75), 2), false, plane_point);
    let p = c.point(pi.point[on_plane]).unwrap();
    assert_eq!((p.samples, p.color, p.epoch), (1, Vec3::splat(0.75), 2), "replaced in place");
    assert_eq!(c.averaged(), before);
    // The sphere moves: its points are carried and stale; the next sample of one replaces it.
    let to = glam::Affine3A::from_translation(Vec3::new(0.0, 0.0, 1e-3));
    assert!(c.move_object(0, &glam::Affine3A::IDENTITY, &to) > 0);
    c.reproject_points(&cam, None, &mut StageTimes::new());
    let slot = c.point_image().point[on_sphere];
    let carried = c.point(slot).unwrap();
    assert_eq!((carried.object, carried.samples, carried.age), (0, 4, STALE_AGE), "carried with its count, stale");
    let [sx, sy] = xy(on_sphere);
    let aimed = (sx as f32 + c.point_image().subpixel[on_sphere][0], sy as f32 + c.point_image().subpixel[on_sphere][1]);
    // Shaded where the sphere is now (its carried point), at the same epoch.
    let mut s = shade(&cam, [sx, sy], aimed, Vec3::splat(0.9), 1);
    s.position = carried.position;
    c.insert_aimed(&s, false, slot);
    let p = c.point(slot).unwrap();
    assert_eq!((p.samples, p.color, p.age), (1, Vec3::splat(0.9), 0.0), "a stale point is replaced, not averaged");
    // A stale sample never joins a point either.
    let before = c.len();
    assert!(c.insert_aimed(&shade(&cam, [x, y], aim(on_plane), Vec3::ZERO, 2), true, plane_point));
    assert_eq!(c.point(pi.point[on_plane]).unwrap().samples, 1);
    assert_eq!(c.len(), before + 1, "it became a point of its own");
    // Removing the plane's points removes their counts with them.
    c.invalidate_objects(&[1]);
    assert!(c.point(pi.point[on_plane]).is_none());
}

#[test]
fn a_point_of_an_edge_free_pixel_averages_samples_from_anywhere_in_its_pixel() {
    let cam = camera(24, 16);
    let mut c = RenderCache::new(CacheConfig { width: 24, height: 16, points_per_pixel: 2.0, background: Vec3::ZERO });
    let mut rng = Rng::new(5);
    first_samples(&mut c, &cam, &mut rng, |_| Vec3::splat(0.5));
    let mut picks: Vec<PixelRequest> =
        (0..16).flat_map(|y| (0..24).map(move |x| PixelRequest { x, y, sx: x as f32 + 0.9, sy: y as f32 + 0.1, point: NO_POINT })).collect();
    // Edge-free pixels: the left half.
    aim_at_points(&mut picks, c.point_image(), |_, _| true, |x, _, _, _| x < 12);
    let pi = c.point_image().clone();
    let mut averaged = 0;
    for p in &picks {
        let i = (p.y * 24 + p.x) as usize;
        let (slot, anywhere) = crate::sampling::aimed_point(p.point);
        assert_eq!(slot, pi.point[i], "aimed at the pixel's point");
        if slot == NO_POINT {
            continue;
        }
        assert_eq!(anywhere, p.x < 12);
        if anywhere {
            assert_eq!((p.sx, p.sy), (p.x as f32 + 0.9, p.y as f32 + 0.1), "keeps its jittered position");
        } else {
            let [u, v] = pi.subpixel[i];
            assert!((p.sx - (p.x as f32 + u)).abs() < 1e-4 && (p.sy - (p.y as f32 + v)).abs() < 1e-4, "at the point");
        }
        let before = c.point(slot).unwrap();
        let s = shade(&cam, [p.x, p.y], (p.sx, p.sy), Vec3::splat(1.0), 1);
        c.insert_aimed(&s, false, p.point);
        if s.object != before.object || s.hit != before.hit {
            continue; // another surface: never the same point
        }
        let after = c.point(slot).unwrap();
        assert_eq!(after.position, before.position, "the point stays where it is");
        assert_eq!(after.samples, 2, "averaged, wherever in the pixel it was shaded");
        assert!((after.color - Vec3::splat(0.75)).abs().max_element() < 1e-6);
        averaged += 1;
    }
    assert!(averaged >= 300, "most pixels averaged: {averaged}");
    // Away from the point in a pixel an edge may cross, the same sample is a point of its own.
    let p = picks.iter().find(|p| p.x == 20 && p.y == 8).unwrap();
    let slot = c.point_image().point[8 * 24 + 20];
    let n = c.point(slot).unwrap().samples;
    let away = shade(&cam, [20, 8], (20.95, 8.05), Vec3::ONE, 1);
    if (away.position - c.point(slot).unwrap().position).length() > 1e-3 {
        c.insert_aimed(&away, false, p.point);
        assert_eq!(c.point(slot).unwrap().samples, n, "not averaged");
    }
}

#[test]
fn picks_aim_only_at_fresh_usable_points() {
    let (w, h) = (12u32, 10u32);
    let cam = camera(w, h);
    let mut rng = Rng::new(21);
    let mut c = RenderCache::new(CacheConfig::new(w, h));
    // Points in every other column; the rest of the pixels have none.
    for y in 0..h {
        for x in (0..w).step_by(2) {
            c.insert(&shade(&cam, [x, y], (x as f32 + rng.unit(), y as f32 + rng.unit()), Vec3::ONE, 1));
        }
    }
    c.reproject_points(&cam, None, &mut StageTimes::new());
    let pi = c.point_image().clone();
    let jittered: Vec<PixelRequest> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| PixelRequest { x, y, sx: x as f32 + 0.123, sy: y as f32 + 0.877, point: NO_POINT })
        .collect();
    let mut picks = jittered.clone();
    // Row 0 unusable (as edge-ambiguous samples are).
    aim_at_points(&mut picks, &pi, |_, y| y != 0, |_, _, _, _| false);
    for (p, j) in picks.iter().zip(&jittered) {
        let i = (p.y * w + p.x) as usize;
        let aimed = pi.point[i] != NO_POINT && p.y != 0;
        if aimed {
            assert_eq!((p.sx, p.sy), (p.x as f32 + pi.subpixel[i][0], p.y as f32 + pi.subpixel[i][1]));
        } else {
            assert_eq!((p.sx, p.sy), (j.sx, j.sy), "pixel {},{} keeps its jitter", p.x, p.y);
        }
    }
    assert!(picks.iter().zip(&jittered).filter(|(p, j)| p != j).count() >= 40);
    // Stale points are not aimed at.
    c.mark_stale();
    c.reproject_points(&cam, None, &mut StageTimes::new());
    let mut picks = jittered.clone();
    aim_at_points(&mut picks, c.point_image(), |_, _| true, |_, _, _, _| false);
    assert_eq!(picks, jittered);
}

/// Runs `frames` still frames of a quarter of the pixels each, aimed at the points, where
/// the left half of the image shades with noise of standard deviation `sigma_left` and the
/// right half `sigma_right` about 0.5, with or without the noise gains. Returns the mean
/// squared error of the points shown in each half and their mean sample counts.
fn still_frames_by_noise(gained: bool, frames: u32, sigma_left: f32, sigma_right: f32) -> ([f64; 2], [f64; 2]) {
    let (w, h) = (64u32, 64u32);
    let cam = camera(w, h);
    let mut rng = Rng::new(12);
    let truth = 0.5f32;
    // Uniform noise on [-a, a] has standard deviation a / √3.
    let noise = move |r: &mut Rng, x: u32| {
        let a = if x < w / 2 { sigma_left } else { sigma_right } * 3f32.sqrt();
        Vec3::splat(truth + r.range(-a, a))
    };
    let mut c = RenderCache::new(CacheConfig::new(w, h));
    for y in 0..h {
        for x in 0..w {
            let s = shade(&cam, [x, y], (x as f32 + rng.unit(), y as f32 + rng.unit()), noise(&mut rng, x), 1);
            assert!(c.insert(&s));
        }
    }
    let mut sampler = Sampler::new(w, h, 5);
    let cfg = SamplingConfig::default();
    let mut picks = Vec::new();
    let n_px = (w * h) as usize;
    for _ in 0..frames {
        c.reproject_and_interpolate(&cam, &mut StageTimes::new());
        let with_gains = gained && c.update_noise_gains();
        let gains = with_gains.then(|| c.noise_gains());
        sampler.select_gained(c.filter_weights(), &c.point_image().age, gains, None, &cfg, n_px / 4, &mut picks);
        aim_at_points(&mut picks, c.point_image(), |_, _| true, |_, _, _, _| false);
        for p in &picks {
            c.insert_aimed(&shade(&cam, [p.x, p.y], (p.sx, p.sy), noise(&mut rng, p.x), 1), false, p.point);
        }
    }
    c.reproject_points(&cam, None, &mut StageTimes::new());
    let pi = c.point_image();
    let (mut se, mut n, mut count) = ([0.0f64; 2], [0.0f64; 2], [0u32; 2]);
    for (i, &j) in pi.point.iter().enumerate() {
        let Some(p) = c.point(j) else { continue };
        let half = usize::from(i % w as usize >= w as usize / 2);
        se[half] += f64::from(p.color.x - truth).powi(2);
        n[half] += f64::from(p.samples);
        count[half] += 1;
    }
    assert!(count.iter().all(|&k| k > n_px as u32 * 2 / 5), "most pixels show a point: {count:?}");
    let k = count.map(f64::from);
    ([se[0] / k[0], se[1] / k[1]], [n[0] / k[0], n[1] / k[1]])
}

#[test]
fn noisier_points_get_more_samples_and_the_image_s_error_falls_faster() {
    let (sl, sr) = (0.2f32, 0.02f32);
    let (mse_u, n_u) = still_frames_by_noise(false, 64, sl, sr);
    let (mse_g, n_g) = still_frames_by_noise(true, 64, sl, sr);
    // Without gains every pixel gets about the same number of samples.
    assert!((n_u[0] / n_u[1] - 1.0).abs() < 0.15, "uniform: {n_u:?} samples a point");
    // With them the noisy half gets more (Neyman: in proportion to σ, 10×; the first
    // frames, before any spread is known, and the shrinkage toward the mean keep it far
    // below that: 2.1× here).
    assert!(n_g[0] > 1.8 * n_g[1], "gained: {n_g:?} samples a point");
    assert!((n_g[0] + n_g[1]) > 0.9 * (n_u[0] + n_u[1]), "the same budget: {n_g:?} vs {n_u:?}");
    // And the image's squared error is lower for the same number of samples. Uniformly,
    // (σl² + σr²)/2 / n; at best ((σl + σr)/2)² / n: 0.6 of it (0.79 here).
    let (u, g) = ((mse_u[0] + mse_u[1]) / 2.0, (mse_g[0] + mse_g[1]) / 2.0);
    assert!(g < 0.85 * u, "mean squared error {g:.3e} with gains against {u:.3e} without");
}

#[test]
fn gains_follow_each_point_s_spread_and_are_neutral_without_one() {
    let (w, h) = (16u32, 8u32);
    let cam = camera(w, h);
    let mut rng = Rng::new(3);
    let mut c = RenderCache::new(CacheConfig::new(w, h));
    first_samples(&mut c, &cam, &mut rng, |_| Vec3::splat(0.3));
    // One sample a point: no spread known.
    assert!(!c.update_noise_gains(), "no point holds two samples");
    // Every point shaded again: the left half with the same colour, the right half with
    // another (a spread).
    for p in aimed_picks(&c, &mut rng) {
        let color = if p.x < w / 2 { Vec3::splat(0.3) } else { Vec3::splat(0.6) };
        c.insert_aimed(&shade(&cam, [p.x, p.y], (p.sx, p.sy), color, 1), false, p.point);
    }
    c.reproject_points(&cam, None, &mut StageTimes::new());
    assert!(c.update_noise_gains());
    let g = c.noise_gains().to_vec();
    let pi = c.point_image();
    // Steady points have no spread, the others v (two tones t1, t2: (t2 - t1)² / 2), and
    // the image's mean is v times their share: a steady point's gain is
    // √((0 + K·mean) / (1 + K)) / √mean, a spread one's √((v + K·mean) / (1 + K)) / √mean.
    let v = (tone(Vec3::splat(0.6)) - tone(Vec3::splat(0.3))).powi(2) / 2.0;
    let known: Vec<(usize, bool)> = pi
        .point
        .iter()
        .enumerate()
        .filter(|&(_, &j)| c.point(j).is_some_and(|p| p.samples >= 2))
        .map(|(i, _)| (i, (i % w as usize) as u32 >= w / 2))
        .collect();
    assert!(known.len() > pi.point.len() * 3 / 4, "most points were shaded twice");
    let mean = v * known.iter().filter(|k| k.1).count() as f32 / known.len() as f32;
    let k = PRIOR_SAMPLES;
    for (i, &j) in pi.point.iter().enumerate() {
        match known.iter().find(|k| k.0 == i) {
            Some(&(_, spread)) => {
                let want = ((if spread { v } else { 0.0 } + k * mean) / (1.0 + k)).sqrt() / mean.sqrt();
                assert!((g[i] - want).abs() < 1e-4, "pixel {i}: gain {} not {want}", g[i]);
            }
            None => assert_eq!(g[i], 1.0, "pixel {i} (point {j}) without a known spread"),
        }
    }
    // Stale points count as unknown.
    c.mark_stale();
    c.reproject_points(&cam, None, &mut StageTimes::new());
    assert!(!c.update_noise_gains(), "only stale points hold spreads");
}
