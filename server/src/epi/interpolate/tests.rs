//! The interpolation against a per-pixel loop over the 24-bit reachability masks: every
//! path and instruction set, bit for bit.
use super::*;
use crate::epi::reach::mask_bit;
use crate::epi::testutil::{random_epi, random_points, Rng};

#[test]
fn reconstruction_interpolates_as_the_per_pixel_loop() {
    let mut rng = Rng(31);
    for (w, h, density, own_sample, fallback) in [
        (37, 21, 0.3, OwnSample::Show, true),
        (66, 13, 0.05, OwnSample::Filter, true),
        (20, 20, 0.6, OwnSample::Filter, false),
        (70, 19, 0.4, OwnSample::FilterAwayFromStale, false),
        (33, 9, 0.1, OwnSample::FilterAwayFromStale, true),
        (130, 5, 0.15, OwnSample::Show, false),
    ] {
        let mut points = random_points(w, h, density, &mut rng);
        mark_some_stale(&mut points, &mut rng);
        let mut epi = random_epi(&points, 5, 8, false, &mut rng);
        let background = Vec3::new(0.1, 0.2, 0.3);
        let options = InterpOptions { sigma: 0.9, own_sample, fallback };
        let (mut image, mut weights) = (vec![Vec3::splat(-1.0); w * h], vec![-1.0f32; w * h]);
        let mut times = crate::stage_times::StageTimes::new();
        // Complex filter off: the image holds the interpolation plus anti-aliasing and
        // spreading; compare the non-simple pixels (anti-aliasing only changes simple ones)
        // that were not holes (spreading only fills those).
        let counts = epi.reconstruct(&points, background, &options, false, &mut image, &mut weights, &mut times);
        let (want, want_weights, _, holes, want_counts) = per_pixel(&epi, &points, &Kernel::gaussian(0.9), options, background);
        for i in 0..w * h {
            let (x, y) = (i % w, i / w);
            let hole = (holes[y * w.div_ceil(64) + x / 64] >> (x % 64)) & 1 == 1;
            if !epi.pixels()[i].is_simple() && !hole {
                assert_eq!(image[i], want[i], "{w}x{h} ({x},{y})");
            }
            assert_eq!(weights[i], want_weights[i], "{w}x{h} ({x},{y}) weight");
        }
        assert_eq!(counts.interp, want_counts);
        assert_eq!(want_counts.with_point + want_counts.filled + want_counts.empty, (w * h) as u32);
    }
}

#[test]
fn kernel_is_a_peaked_separable_gaussian() {
    let k = Kernel::gaussian(1.0);
    assert_eq!(k.0[12], 1.0);
    assert!((k.0[13] - (-0.5f32).exp()).abs() < 1e-6);
    assert!((k.0[24] - k.0[14] * k.0[22]).abs() < 1e-6, "separable");
    assert!(k.0.iter().all(|&v| v > 0.0 && v <= 1.0));
    assert_eq!(Kernel::gaussian(f32::NAN), Kernel::gaussian(DEFAULT_SIGMA));
}

/// Exactly what every path must compute: per pixel, the kernel-weighted sums over the
/// samples it takes in window order — one product and one sum each, non-finite colours read
/// as 0 — then own colour, mean, fallback mean or background. Returns the image, the weights,
/// the filled and hole bit rows and the counts.
fn per_pixel(epi: &crate::epi::Epi, points: &PointImage, kernel: &Kernel, options: InterpOptions, background: Vec3) -> (Vec<Vec3>, Vec<f32>, Vec<u64>, Vec<u64>, InterpCounts) {
    let (w, h) = (epi.width() as usize, epi.height() as usize);
    let words = w.div_ceil(64);
    let flags = epi.flags();
    let finite = |v: f32| if v.is_finite() { v } else { 0.0 };
    let (mut image, mut weights) = (vec![Vec3::ZERO; w * h], vec![0f32; w * h]);
    let (mut filled, mut holes) = (vec![0u64; h * words], vec![0u64; h * words]);
    let mut counts = InterpCounts::default();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let p = epi.pixels()[i];
            let has = flags.get(x, y, Flags::HAS);
            // A stale point in the window, found directly (the oracle of the bit rows).
            let near_stale = (-2i64..=2).any(|dy| {
                (-2i64..=2).any(|dx| {
                    let (px, py) = (x as i64 + dx, y as i64 + dy);
                    px >= 0 && py >= 0 && px < w as i64 && py < h as i64 && {
                        let a = points.age[py as usize * w + px as usize];
                        a >= crate::render_cache::STALE_AGE && a.is_finite()
                    }
                })
            });
            let shows = match options.own_sample {
                OwnSample::Show => true,
                OwnSample::Filter => false,
                OwnSample::FilterAwayFromStale => near_stale || p.is_complex(),
            };
            let own = shows && (p.usable() || (p.is_complex() && has));
            let m = epi.reachability().mask24(x, y);
            let (mut s, mut f) = ([0f32; 4], [0f32; 4]);
            for k in 0..25 {
                let (dx, dy) = offset(k);
                let (px, py) = (x as i64 + dx as i64, y as i64 + dy as i64);
                if px < 0 || py < 0 || px >= w as i64 || py >= h as i64 {
                    continue;
                }
                let j = py as usize * w + px as usize;
                let (q, q_has) = (epi.pixels()[j], flags.get(px as usize, py as usize, Flags::HAS));
                let c = points.color[j];
                let wk = kernel.0[k];
                let add = |s: &mut [f32; 4]| {
                    s[0] += wk * finite(c.x);
                    s[1] += wk * finite(c.y);
                    s[2] += wk * finite(c.z);
                    s[3] += wk;
                };
                if q_has {
                    add(&mut f);
                }
                if if p.is_complex() { q_has } else { q.usable() && (k == 12 || (m >> mask_bit(k)) & 1 == 1) } {
                    add(&mut s);
                }
            }
            let mean = |s: [f32; 4]| {
                let inv = 1.0 / s[3];
                Vec3::new(s[0] * inv, s[1] * inv, s[2] * inv)
            };
            let bit = 1u64 << (x % 64);
            if own {
                (image[i], weights[i]) = (points.color[i], kernel.0[12]);
                filled[y * words + x / 64] |= bit;
            } else if s[3] > 0.0 {
                (image[i], weights[i]) = (mean(s), s[3]);
                filled[y * words + x / 64] |= bit;
            } else if options.fallback && f[3] > 0.0 {
                image[i] = mean(f);
                counts.fallback += 1;
            } else {
                image[i] = background;
                holes[y * words + x / 64] |= bit;
            }
            let hole = holes[y * words + x / 64] & bit != 0;
            if has {
                counts.with_point += 1;
            } else if hole {
                counts.empty += 1;
            } else {
                counts.filled += 1;
            }
        }
    }
    (image, weights, filled, holes, counts)
}

#[test]
fn every_path_and_instruction_set_equals_a_per_pixel_loop_bit_for_bit() {
    let mut rng = Rng(77);
    let isas: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.available()).collect();
    let mut runs = 0;
    for (w, h) in [(37, 21), (130, 9), (64, 12), (200, 7)] {
        for density in [1.0, 0.6, 0.2, 0.05] {
            let mut points = random_points(w, h, density, &mut rng);
            mark_some_stale(&mut points, &mut rng);
            let mut epi = random_epi(&points, 4, 6, false, &mut rng);
            // A few failed shades: shown by their own pixel, black to their neighbours.
            for c in points.color.iter_mut() {
                if rng.chance(0.01) {
                    *c = [Vec3::new(f32::NAN, 0.5, 0.5), Vec3::new(0.2, f32::INFINITY, 0.1)][rng.below(2)];
                }
            }
            let background = Vec3::new(0.1, 0.2, 0.3);
            let (mut image, mut weights) = (vec![Vec3::ZERO; w * h], vec![0f32; w * h]);
            let mut times = crate::stage_times::StageTimes::new();
            // Computes the reachability the interpolation reads.
            epi.reconstruct(&points, background, &InterpOptions::default(), false, &mut image, &mut weights, &mut times);
            let mut near_stale = Vec::new();
            near_stale_rows(&points, &mut Vec::new(), &mut near_stale);
            for own_sample in [OwnSample::Show, OwnSample::Filter, OwnSample::FilterAwayFromStale] {
                for fallback in [false, true] {
                    let options = InterpOptions { sigma: 0.9, own_sample, fallback };
                    let kernel = Kernel::gaussian(options.sigma);
                    let want = per_pixel(&epi, &points, &kernel, options, background);
                    let input = InterpInput {
                        near_stale: &near_stale,
                        pixels: epi.pixels(),
                        flags: epi.flags(),
                        reach: epi.reachability(),
                        points: &points,
                        kernel: &kernel,
                        options,
                        background,
                    };
                    for &isa in &isas {
                        // Every word dense, the measured choice, every word sparse.
                        for dense_from in [0, isa.dense_from(), u32::MAX] {
                            let words = w.div_ceil(64);
                            let (mut image, mut weights) = (vec![Vec3::splat(-1.0); w * h], vec![-1f32; w * h]);
                            let (mut filled, mut holes) = (vec![!0u64; h * words], vec![!0u64; h * words]);
                            let counts = run(isa, dense_from, &input, &mut image, &mut weights, &mut filled, &mut holes);
                            let what = format!("{w}x{h} density {density} {own_sample:?} fallback {fallback} {isa:?} dense from {dense_from}");
                            for i in 0..w * h {
                                let (got, exp) = (image[i].to_array().map(f32::to_bits), want.0[i].to_array().map(f32::to_bits));
                                assert_eq!(got, exp, "{what}: pixel ({}, {}) colour {} vs {}", i % w, i / w, image[i], want.0[i]);
                                assert_eq!(weights[i].to_bits(), want.1[i].to_bits(), "{what}: pixel ({}, {}) weight", i % w, i / w);
                            }
                            assert_eq!((filled, holes), (want.2.clone(), want.3.clone()), "{what}: filled and hole bits");
                            assert_eq!(counts, want.4, "{what}: counts");
                            runs += 1;
                        }
                    }
                }
            }
        }
    }
    assert_eq!(runs, 4 * 4 * 6 * isas.len() * 3);
}

/// Marks about 3 % of the points stale (age `STALE_AGE`), in clusters of a few pixels.
fn mark_some_stale(points: &mut PointImage, rng: &mut Rng) {
    let (w, h) = (points.width as usize, points.height as usize);
    for _ in 0..(w * h / 100).max(1) {
        let (x, y) = (rng.below(w), rng.below(h));
        for (dx, dy) in [(0, 0), (1, 0), (0, 1)] {
            let i = (y + dy).min(h - 1) * w + (x + dx).min(w - 1);
            if points.point[i] != crate::render_cache::NO_POINT {
                points.age[i] = crate::render_cache::STALE_AGE;
            }
        }
    }
}
