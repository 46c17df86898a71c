//! The bit-sliced interpolation against a per-pixel loop over the 24-bit reachability masks.
use super::*;
use crate::epi::reach::mask_bit;
use crate::epi::testutil::{random_epi, random_points, Rng};

#[test]
fn interpolation_matches_a_per_pixel_loop_over_reachable_samples() {
    let mut rng = Rng(31);
    for (w, h, density, own_sample, fallback) in [
        (37, 21, 0.3, OwnSample::Show, true),
        (66, 13, 0.05, OwnSample::Filter, true),
        (20, 20, 0.6, OwnSample::Filter, false),
        (130, 5, 0.15, OwnSample::Show, false),
    ] {
        let points = random_points(w, h, density, &mut rng);
        let mut epi = random_epi(&points, 5, 8, false, &mut rng);
        let background = Vec3::new(0.1, 0.2, 0.3);
        let options = InterpOptions { sigma: 0.9, own_sample, fallback };
        let (mut image, mut weights) = (vec![Vec3::splat(-1.0); w * h], vec![-1.0f32; w * h]);
        let mut times = crate::stage_times::StageTimes::new();
        // Complex filter off: the image holds the interpolation plus anti-aliasing; compare
        // the non-simple pixels (anti-aliasing only changes simple ones).
        let counts = epi.reconstruct(&points, background, &options, false, &mut image, &mut weights, &mut times);
        let kernel = Kernel::gaussian(0.9);
        let flags = epi.flags();
        let (mut with_point, mut filled, mut empty) = (0, 0, 0);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let p = epi.pixels()[i];
                let has = flags.get(x, y, Flags::HAS);
                let own = own_sample == OwnSample::Show && (p.usable() || (p.is_complex() && has));
                let m = epi.reachability().mask24(x, y);
                let (mut c, mut s) = (Vec3::ZERO, 0.0f32);
                let (mut fc, mut fs) = (Vec3::ZERO, 0.0f32);
                for k in 0..25 {
                    let (dx, dy) = offset(k);
                    let (px, py) = (x as i64 + dx as i64, y as i64 + dy as i64);
                    if px < 0 || py < 0 || px >= w as i64 || py >= h as i64 {
                        continue;
                    }
                    let j = py as usize * w + px as usize;
                    let (q, q_has) = (epi.pixels()[j], flags.get(px as usize, py as usize, Flags::HAS));
                    if q_has {
                        fc += points.color[j] * kernel.0[k];
                        fs += kernel.0[k];
                    }
                    let take = if p.is_complex() { q_has } else { q.usable() && (k == 12 || (m >> mask_bit(k)) & 1 == 1) };
                    if take {
                        c += points.color[j] * kernel.0[k];
                        s += kernel.0[k];
                    }
                }
                let (want, want_w) = if own {
                    (points.color[i], kernel.0[12])
                } else if s > 0.0 {
                    (c / s, s)
                } else if fallback && fs > 0.0 {
                    (fc / fs, 0.0)
                } else {
                    (background, 0.0)
                };
                // Anti-aliasing changes simple pixels, spreading the pixels that reach nothing.
                let unreached = !own && s == 0.0 && !(fallback && fs > 0.0);
                if !p.is_simple() && !unreached {
                    assert!((image[i] - want).abs().max_element() < 1e-5, "{w}x{h} ({x},{y}) {p:?}: {} vs {want}", image[i]);
                }
                assert!((weights[i] - want_w).abs() < 1e-5, "({x},{y}) weight {} vs {want_w}", weights[i]);
                if has {
                    with_point += 1;
                } else if own || s > 0.0 || (fallback && fs > 0.0) {
                    filled += 1;
                } else {
                    empty += 1;
                }
            }
        }
        assert_eq!((counts.interp.with_point, counts.interp.filled, counts.interp.empty), (with_point, filled, empty));
        assert_eq!(with_point + filled + empty, (w * h) as u32);
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
