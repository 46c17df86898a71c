//! Tests of prioritized sampling on random priority images.
use super::*;

use crate::rng::Rng;

fn check_picks(out: &[PixelRequest], w: u32, h: u32, budget: usize) {
    assert!(out.len() <= budget.min((w * h) as usize), "{} picks for budget {budget}", out.len());
    let mut seen = vec![false; (w * h) as usize];
    for r in out {
        assert!(r.x < w && r.y < h);
        let i = (r.y * w + r.x) as usize;
        assert!(!seen[i], "pixel {},{} picked twice", r.x, r.y);
        seen[i] = true;
        assert!(r.sx >= r.x as f32 && r.sx < (r.x + 1) as f32, "sx {} outside pixel {}", r.sx, r.x);
        assert!(r.sy >= r.y as f32 && r.sy < (r.y + 1) as f32, "sy {} outside pixel {}", r.sy, r.y);
    }
}

#[test]
fn picks_are_distinct_inside_their_pixels_and_within_budget() {
    let mut rng = Rng::new(1);
    let cfg = SamplingConfig::default();
    let mut out = Vec::new();
    for case in 0..30 {
        let (w, h) = (1 + (rng.next_u64() % 90) as u32, 1 + (rng.next_u64() % 70) as u32);
        let n = (w * h) as usize;
        let mut s = Sampler::new(w, h, case);
        let weights: Vec<f32> = (0..n).map(|_| if rng.next_u64().is_multiple_of(4) { 0.0 } else { rng.unit() * 3.0 }).collect();
        let ages: Vec<f32> =
            (0..n).map(|_| if rng.next_u64().is_multiple_of(3) { f32::INFINITY } else { (rng.next_u64() % 200) as f32 }).collect();
        for budget in [0, 1, n / 64 + 1, n / 5, n, n + 17] {
            s.select(&weights, &ages, &cfg, budget, &mut out);
            check_picks(&out, w, h, budget);
            let want = budget.min(n);
            if want == n {
                assert_eq!(out.len(), n, "case {case}: a budget covering the image picks every pixel");
            } else {
                // Error diffusion loses at most the error pushed over the image border.
                let slack = 2 + (w + h) as usize / 2;
                assert!(out.len() + slack >= want, "case {case}: {} picks for budget {want}", out.len());
            }
        }
    }
}

#[test]
fn jitter_stays_inside_large_coordinates() {
    // Near x = 16383, x + u rounds to x + 1 for u close to 1 unless clamped.
    for x in [0u32, 1, 1000, 16383, 1 << 20] {
        for u in [0.0f32, 0.5, 0.999_999_9, 1.0 - f32::EPSILON / 2.0] {
            let v = inside_pixel(x, u);
            assert!(v >= x as f32 && v < (x as f32 + 1.0) || (x >= 1 << 20 && v == x as f32), "x {x} u {u} -> {v}");
        }
    }
}

#[test]
fn sampling_concentrates_on_low_weight_pixels() {
    let (w, h) = (128u32, 96u32);
    let n = (w * h) as usize;
    let cfg = SamplingConfig::default();
    let mut s = Sampler::new(w, h, 42);
    // Left half: filled pixels (no point) in 24-row bands of weight 0, 1, 2, 3; right half:
    // fresh points.
    let band = |i: usize| (i / w as usize) / 24;
    let weights: Vec<f32> = (0..n).map(|i| if (i as u32 % w) < w / 2 { band(i) as f32 } else { 1.5 }).collect();
    let ages: Vec<f32> = (0..n).map(|i| if (i as u32 % w) < w / 2 { f32::INFINITY } else { 0.0 }).collect();
    let budget = n / 64;
    let mut out = Vec::new();
    let mut by_weight = [0usize; 4];
    let mut right = 0usize;
    let mut total = 0usize;
    for _ in 0..20 {
        s.select(&weights, &ages, &cfg, budget, &mut out);
        check_picks(&out, w, h, budget);
        for r in &out {
            if r.x < w / 2 {
                by_weight[(r.y / 24) as usize] += 1;
            } else {
                right += 1;
            }
        }
        total += out.len();
    }
    // Expected shares follow the priorities 1/(1+w) for w = 0, 1, 2, 3 and 0.02 for the points.
    let pr = [1.0, 0.5, 1.0 / 3.0, 0.25, PRIORITY_FRESH_POINT as f64];
    let rows = [1.0, 1.0, 1.0, 1.0, 4.0]; // the right half has as many pixels as the 4 bands
    let z: f64 = pr.iter().zip(&rows).map(|(p, r)| p * r).sum();
    let got = [by_weight[0], by_weight[1], by_weight[2], by_weight[3], right];
    for k in 0..5 {
        let want = pr[k] * rows[k] / z * total as f64;
        let rel = (got[k] as f64 - want).abs() / want;
        if k < 4 {
            assert!(rel < 0.1, "class {k}: {} picks, expected {want:.0}", got[k]);
        } else {
            // Error diffusion carries some error from the busy half over the border into the
            // sparse half (a few picks per frame along the border).
            assert!(rel < 0.6, "class {k}: {} picks, expected {want:.0}", got[k]);
        }
    }
    assert!(by_weight[0] > 3 * by_weight[3]);
}

#[test]
fn older_points_get_more_samples_and_unreached_pixels_most() {
    assert_eq!(priority(0.0, f32::INFINITY, 120.0), PRIORITY_UNREACHED);
    assert!(priority(0.5, f32::INFINITY, 120.0) < PRIORITY_UNREACHED);
    assert!(priority(1.0, 10.0, 120.0) < priority(1.0, 100.0, 120.0));
    assert_eq!(priority(1.0, 1e8, 120.0), PRIORITY_OLD_POINT);
    assert_eq!(priority(1.0, crate::render_cache::STALE_AGE, 120.0), PRIORITY_STALE_POINT);
    const { assert!(PRIORITY_OLD_POINT < PRIORITY_STALE_POINT && PRIORITY_STALE_POINT < PRIORITY_UNREACHED) };
    assert_eq!(priority(1.0, 500.0, 120.0), PRIORITY_OLD_POINT);
    assert!(priority(f32::NAN, 0.0, 120.0).is_finite());
    assert!(PRIORITY_OLD_POINT < priority(1.0, f32::INFINITY, 120.0));
}

#[test]
fn pattern_changes_per_frame_and_is_reproducible() {
    let (w, h) = (64u32, 64u32);
    let n = (w * h) as usize;
    let cfg = SamplingConfig::default();
    let weights = vec![1.0f32; n];
    let ages = vec![f32::INFINITY; n];
    let run = |seed: u64| {
        let mut s = Sampler::new(w, h, seed);
        let mut frames = Vec::new();
        let mut out = Vec::new();
        for _ in 0..4 {
            s.select(&weights, &ages, &cfg, n / 64, &mut out);
            frames.push(out.iter().map(|r| (r.x, r.y)).collect::<Vec<_>>());
        }
        frames
    };
    let a = run(7);
    assert_eq!(a, run(7));
    assert_ne!(a, run(8));
    for f in 1..4 {
        let same = a[f].iter().filter(|p| a[0].contains(p)).count();
        assert!(same * 4 < a[0].len(), "frame {f} repeats {same} of {} picks of frame 0", a[0].len());
    }
    // Over many frames equal-priority pixels are covered evenly: 256 frames at 1/64 density
    // pick each pixel 4 times on average; no more pixels are left out than independent
    // frames would leave (e^-4 = 1.8%), none is picked hugely more often.
    let mut s = Sampler::new(w, h, 3);
    let mut out = Vec::new();
    let mut hits = vec![0u32; n];
    for _ in 0..256 {
        s.select(&weights, &ages, &cfg, n / 64, &mut out);
        for r in &out {
            hits[(r.y * w + r.x) as usize] += 1;
        }
    }
    let zero = hits.iter().filter(|&&c| c == 0).count();
    let max = *hits.iter().max().unwrap();
    assert!(zero * 100 < n * 3, "{zero} pixels never sampled");
    assert!(max <= 16, "a pixel was sampled {max} times (mean 4)");
}

#[test]
fn budget_from_sparseness() {
    let c = SamplingConfig { sparseness: 64.0, max_age_frames: 120.0 };
    assert_eq!(c.budget(512 * 512), 4096);
    assert_eq!(c.budget(10), 1);
    assert_eq!(c.budget(0), 0);
    assert_eq!(SamplingConfig { sparseness: f64::NAN, ..c }.budget(100), 100);
    assert_eq!(SamplingConfig { sparseness: 0.5, ..c }.budget(100), 100);
}


#[test]
fn scaling_meets_the_budget_with_saturated_pixels() {
    // Water-filling: sum over pixels of min(1, s * p) equals the budget, also when many
    // pixels would exceed 1 with the plain scale budget / sum(p).
    let mut rng = Rng::new(77);
    for case in 0..40 {
        let (w, h) = (50u32, 40u32);
        let n = (w * h) as usize;
        let mut s = Sampler::new(w, h, case);
        let hot = rng.unit();
        for p in s.prio.iter_mut() {
            *p = if rng.unit() < hot { 1.0 } else { 0.001 + 0.05 * rng.unit() };
        }
        let total: f64 = s.prio.iter().map(|&p| p as f64).sum();
        let max = s.prio.iter().cloned().fold(0.0f32, f32::max);
        let budget = 1 + (rng.next_u64() % (n as u64 - 1)) as usize;
        let scale = s.scale_to_budget(total, max, budget as f64);
        let got: f64 = s.prio.iter().map(|&p| (p * scale).min(1.0) as f64).sum();
        assert!((got - budget as f64).abs() <= 1e-3 * budget as f64 + 0.5, "case {case}: {got} for budget {budget}");
    }
}

/// The selection written plainly (one loop over the pixels in scan order per step, the next
/// row's error added into its buffer pixel by pixel), the oracle of the optimised [`Sampler::select`]. Row sums are
/// added up in row order, as the optimised one does (the first version added them in the
/// order rayon's reduction happened to split the rows).
#[allow(clippy::too_many_arguments)]
fn reference_select(seed: u64, frame: u64, w: u32, h: u32, weights: &[f32], ages: &[f32], cfg: &SamplingConfig, budget: usize) -> Vec<PixelRequest> {
    let (w, h) = (w as usize, h as usize);
    let n = w * h;
    let mut out = Vec::new();
    let budget = budget.min(n);
    let mut s = Sampler::new(w as u32, h as u32, seed);
    if budget == 0 || budget == n {
        s.frame = frame;
        s.select(weights, ages, cfg, budget, &mut out);
        return out;
    }
    let (mut total, mut max) = (0.0f64, 0.0f32);
    for y in 0..h {
        // Four partial sums over the columns x % 4, added pairwise (the sum's definition).
        let mut part = [0.0f64; 4];
        for x in 0..w {
            let p = priority(weights[y * w + x], ages[y * w + x], cfg.max_age_frames);
            s.prio[y * w + x] = p;
            part[x % 4] += p as f64;
            max = max.max(p);
        }
        total += (part[0] + part[1]) + (part[2] + part[3]);
    }
    let scale = s.scale_to_budget(total, max, budget as f64);
    let frame_key = mix64(seed ^ mix64(frame));
    let ox = (mix64(frame_key ^ 1) % w as u64) as usize;
    let oy = (mix64(frame_key ^ 2) % h as u64) as usize;
    let flip = frame & 1 == 1;
    // Bands of rows, each from zero error with its own key, warmed up on the rows before
    // it (their picks dropped), its picks after the band before's, cut at the budget.
    for first in (0..h).step_by(DITHER_BAND_ROWS) {
        let key = band_key(frame_key, first / DITHER_BAND_ROWS);
        let mut cur = vec![0.0f32; w + 2];
        let mut band_out = Vec::new();
        'rows: for ly in first.saturating_sub(DITHER_WARM_UP_ROWS)..(first + DITHER_BAND_ROWS).min(h) {
            if ly == first {
                band_out.clear();
            }
            let y = (ly + oy) % h;
            let ltr = (ly % 2 == 0) != flip;
            let row = &s.prio[y * w..(y + 1) * w];
            let mut next = vec![0.0f32; w + 2];
            // The value reached at the pixel scanned before, and whether it was picked.
            let mut before: Option<(f32, bool)> = None;
            for step in 0..w {
                let lx = if ltr { step } else { w - 1 - step };
                let x = (lx + ox) % w;
                let q = (row[x] * scale).min(1.0);
                let a = q + cur[lx + 1];
                // v = a + 7/16 (v_before - picked_before), as one fused multiply-add.
                let v = match before {
                    None => a,
                    Some((vb, picked)) => (7.0f32 / 16.0).mul_add(vb, if picked { a - 7.0 / 16.0 } else { a }),
                };
                let idx = (ly * w + lx) as u32;
                let threshold = (fmix32(key ^ idx) >> 8) as f32 / (1u32 << 24) as f32;
                let picked = q > 0.0 && (v >= threshold || q >= 1.0);
                if picked && ly >= first {
                    band_out.push(pick_at(key, idx, x, y));
                    if band_out.len() == budget {
                        break 'rows;
                    }
                }
                before = Some((v, picked));
                let e = if picked { v - 1.0 } else { v };
                let (ahead, behind) = if ltr { (lx + 2, lx) } else { (lx, lx + 2) };
                next[behind] += e * (3.0 / 16.0);
                next[lx + 1] += e * (5.0 / 16.0);
                next[ahead] += e * (1.0 / 16.0);
            }
            let (vb, picked) = before.expect("a row has a pixel");
            next[if ltr { w } else { 1 }] += (if picked { vb - 1.0 } else { vb }) * (7.0 / 16.0);
            next[1] += next[0];
            next[w] += next[w + 1];
            next[0] = 0.0;
            next[w + 1] = 0.0;
            cur = next;
        }
        out.append(&mut band_out);
    }
    out.truncate(budget);
    out
}

/// The optimised selection picks exactly the pixels and positions of the plain one, over
/// successive frames of random priority images (sizes from one pixel up, budgets from one
/// pick to saturation, images where scaling must water-fill).
#[test]
fn select_equals_the_plain_reference_bit_for_bit() {
    let mut rng = Rng::new(2024);
    let cfg = SamplingConfig::default();
    let mut out = Vec::new();
    for case in 0..60u64 {
        let (w, h) = if case < 4 { (1 + case as u32, 1) } else { (1 + (rng.next_u64() % 150) as u32, 1 + (rng.next_u64() % 90) as u32) };
        let n = (w * h) as usize;
        let saturating = case % 3 == 0;
        let weights: Vec<f32> = (0..n).map(|_| if rng.next_u64().is_multiple_of(4) { 0.0 } else { rng.unit() * 3.0 }).collect();
        let ages: Vec<f32> = (0..n)
            .map(|_| {
                if saturating || rng.next_u64().is_multiple_of(3) {
                    f32::INFINITY
                } else {
                    (rng.next_u64() % 200) as f32
                }
            })
            .collect();
        let mut s = Sampler::new(w, h, case);
        for frame in 0..4u64 {
            let budget = match frame {
                0 => 1,
                1 => n / 64 + 1,
                2 => n / 3 + 1,
                _ => (rng.next_u64() % (n as u64 + 2)) as usize,
            };
            s.select(&weights, &ages, &cfg, budget, &mut out);
            let want = reference_select(case, frame, w, h, &weights, &ages, &cfg, budget);
            assert_eq!(out, want, "case {case} ({w}x{h}), frame {frame}, budget {budget}");
        }
    }
}

/// The plain dithering (the path of CPUs without AVX2 and FMA) picks what the path this CPU
/// takes picks, pair of bands by pair of bands, with the budget cutting either band.
#[test]
fn plain_and_vector_dithering_agree() {
    let mut rng = Rng::new(99);
    for case in 0..40 {
        let (w, h) = (1 + rng.below(300), 65 + rng.below(100));
        let prio: Vec<f32> = (0..w * h).map(|_| if rng.chance(0.2) { 0.0 } else if rng.chance(0.05) { 1.0 } else { rng.unit() * 0.3 }).collect();
        let scan = FrameScan { w, h, ox: rng.below(w), oy: rng.below(h), flip: rng.chance(0.5), frame_key: rng.next_u64(), scale: 0.2 + rng.unit() * 3.0, budget: 1 + rng.below(w * h / 3 + 1) };
        let run = |plain: bool| {
            let (mut x, mut y) = (DitherBand::new(w), DitherBand::new(w));
            if plain {
                dither_pair_rows(&scan, &prio, 0, &mut x, Some(&mut y), chain, |p, q| {
                    chain(p.0, p.1, p.2, p.3);
                    chain(q.0, q.1, q.2, q.3);
                });
            } else {
                dither_pair(&scan, &prio, 0, &mut x, Some(&mut y));
            }
            (x.picks, y.picks, x.err_cur, y.err_cur)
        };
        let (plain, fast) = (run(true), run(false));
        assert!(!plain.0.is_empty() || !plain.1.is_empty(), "case {case}: no picks at all");
        assert_eq!(plain, fast, "case {case} ({w}x{h})");
    }
}

#[test]
fn gains_scale_only_points_priorities_and_stay_below_stale_ones() {
    let max_age = 120.0;
    let fresh = priority(0.0, 0.0, max_age);
    assert_eq!(priority_gained(0.0, 0.0, max_age, 1.0), fresh);
    assert_eq!(priority_gained(0.0, 0.0, max_age, 3.0), 3.0 * fresh);
    assert_eq!(priority_gained(0.0, 0.0, max_age, 0.25), 0.25 * fresh);
    // Capped below a stale point's priority, which no gain changes; nor an unreached pixel's.
    assert_eq!(priority_gained(0.0, 1000.0, max_age, 100.0), PRIORITY_GAINED_MAX);
    assert!(PRIORITY_GAINED_MAX < PRIORITY_STALE_POINT);
    let stale = crate::render_cache::STALE_AGE;
    assert_eq!(priority_gained(0.0, stale, max_age, 0.1), PRIORITY_STALE_POINT);
    assert_eq!(priority_gained(2.0, f32::INFINITY, max_age, 0.1), priority(2.0, f32::INFINITY, max_age));
    // Nonsense gains count as 1.
    for g in [f32::NAN, f32::INFINITY, -1.0] {
        assert_eq!(priority_gained(0.0, 5.0, max_age, g), priority(0.0, 5.0, max_age));
    }
    // And select_gained with all gains 1 picks what select picks.
    let (w, h) = (40u32, 30u32);
    let n = (w * h) as usize;
    let mut rng = Rng::new(4);
    let weights: Vec<f32> = (0..n).map(|_| rng.range(0.0, 3.0)).collect();
    let ages: Vec<f32> = (0..n).map(|i| if i % 7 == 0 { f32::INFINITY } else { rng.range(0.0, 200.0) }).collect();
    let cfg = SamplingConfig::default();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    Sampler::new(w, h, 9).select(&weights, &ages, &cfg, n / 16, &mut a);
    Sampler::new(w, h, 9).select_gained(&weights, &ages, Some(&vec![1.0; n]), None, &cfg, n / 16, &mut b);
    assert_eq!(a, b);
}

#[test]
fn starved_pixels_are_picked_as_stale_points_are_and_their_picks_moved_into_the_region() {
    // Every pixel holds a fresh point (priority 0.02) but a scattered few with a starved
    // region: at PRIORITY_STARVED_REGION = 30 times a fresh point's, a budget of 300 scales
    // the priorities by about 2.3, so each of them is picked for sure (a scaled priority of
    // 1.4), where without the plane they get a fresh point's share (about 0.05 each).
    let (w, h) = (130u32, 40u32);
    let n = (w * h) as usize;
    let words = (w as usize).div_ceil(64);
    let mut rng = Rng::new(12);
    let mut starved = vec![0u64; h as usize * words];
    let mut marked = Vec::new();
    for _ in 0..60 {
        let (x, y) = (rng.below(w as usize), rng.below(h as usize));
        if starved[y * words + x / 64] & (1 << (x % 64)) == 0 {
            starved[y * words + x / 64] |= 1 << (x % 64);
            marked.push((x as u32, y as u32));
        }
    }
    let (weights, ages) = (vec![5.0f32; n], vec![0.0f32; n]);
    let cfg = SamplingConfig::default();
    let budget = 300;
    let count = |picks: &[PixelRequest]| picks.iter().filter(|p| marked.contains(&(p.x, p.y))).count();
    let mut picks = Vec::new();
    Sampler::new(w, h, 3).select_gained(&weights, &ages, None, Some(&starved), &cfg, budget, &mut picks);
    check_picks(&picks, w, h, budget);
    let with = count(&picks);
    assert!(with * 10 >= marked.len() * 9, "{with} of {} starved pixels picked", marked.len());
    Sampler::new(w, h, 3).select_gained(&weights, &ages, None, None, &cfg, budget, &mut picks);
    let without = count(&picks);
    assert!(without * 5 < marked.len(), "{without} of {} picked without the plane", marked.len());
    // The picks of the starved pixels move to the position the region gives; the others keep
    // theirs.
    Sampler::new(w, h, 3).select_gained(&weights, &ages, None, Some(&starved), &cfg, budget, &mut picks);
    let before = picks.clone();
    aim_into_starved(&mut picks, |x, y, u, _| marked.contains(&(x, y)).then_some([0.25 * u + 0.7, 0.125]));
    for (p, b) in picks.iter().zip(&before) {
        if marked.contains(&(p.x, p.y)) {
            let u = b.sx - b.x as f32;
            assert_eq!((p.sx, p.sy, p.point), (p.x as f32 + (0.25 * u + 0.7), p.y as f32 + 0.125, crate::render_cache::NO_POINT));
        } else {
            assert_eq!(p, b);
        }
    }
    check_picks(&picks, w, h, budget);
}
