//! Chi-square goodness of fit of a sampler against its density, after Mitsuba's
//! `chi2.py`: directions are binned on an equal-area (cos θ, φ) grid over the sphere, the
//! expected count of each bin is the pdf integrated over it by Gauss–Legendre quadrature,
//! low-expectation bins are pooled, and the statistic's p-value comes from the regularised
//! upper incomplete gamma function.
use glam::Vec3;
use std::f64::consts::PI;

pub const COS_BINS: usize = 40;
pub const PHI_BINS: usize = 80;
/// Pool bins until they expect at least this many samples (the usual rule for chi²).
const MIN_EXPECTED: f64 = 5.0;

/// The bin of a unit direction.
pub fn bin(w: Vec3) -> usize {
    let c = ((w.z as f64 + 1.0) * 0.5 * COS_BINS as f64)
        .floor()
        .clamp(0.0, COS_BINS as f64 - 1.0) as usize;
    let phi = (w.y as f64).atan2(w.x as f64) + PI;
    let p = (phi / (2.0 * PI) * PHI_BINS as f64)
        .floor()
        .clamp(0.0, PHI_BINS as f64 - 1.0) as usize;
    c * PHI_BINS + p
}

/// 8-point Gauss–Legendre nodes and weights on [-1, 1].
const GL_X: [f64; 8] = [
    -0.9602898564975363,
    -0.7966664774136267,
    -0.525532409916329,
    -0.1834346424956498,
    0.1834346424956498,
    0.525532409916329,
    0.7966664774136267,
    0.9602898564975363,
];
const GL_W: [f64; 8] = [
    0.1012285362903763,
    0.2223810344533745,
    0.3137066458778873,
    0.362683783378362,
    0.362683783378362,
    0.3137066458778873,
    0.2223810344533745,
    0.1012285362903763,
];

/// ∫ pdf over each bin (solid angle = d cos θ dφ), with `sub`×`sub` sub-cells per bin each
/// integrated by 8×8-point Gauss–Legendre.
pub fn integrate_bins(pdf: &dyn Fn(Vec3) -> f64, sub: usize) -> Vec<f64> {
    let mut out = vec![0.0; COS_BINS * PHI_BINS];
    let dc = 2.0 / (COS_BINS * sub) as f64;
    let dp = 2.0 * PI / (PHI_BINS * sub) as f64;
    for ci in 0..COS_BINS * sub {
        let c0 = -1.0 + ci as f64 * dc;
        for pi in 0..PHI_BINS * sub {
            let p0 = -PI + pi as f64 * dp;
            let mut s = 0.0;
            for (xa, wa) in GL_X.iter().zip(GL_W) {
                let z = c0 + 0.5 * dc * (xa + 1.0);
                let r = (1.0 - z * z).max(0.0).sqrt();
                for (xb, wb) in GL_X.iter().zip(GL_W) {
                    let phi = p0 + 0.5 * dp * (xb + 1.0);
                    let w = Vec3::new((r * phi.cos()) as f32, (r * phi.sin()) as f32, z as f32);
                    s += wa * wb * pdf(w);
                }
            }
            out[(ci / sub) * PHI_BINS + pi / sub] += s * 0.25 * dc * dp;
        }
    }
    out
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        return (PI / (PI * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Regularised upper incomplete gamma Q(a, x) (series below a + 1, Lentz's continued
/// fraction above).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let front = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        let (mut ap, mut del) = (a, 1.0 / a);
        let mut sum = del;
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * front
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        front * h
    }
}

/// The outcome of one chi² test.
#[derive(Debug)]
pub struct Chi2 {
    pub statistic: f64,
    pub dof: usize,
    pub p_value: f64,
    /// Samples that fell in bins whose integrated pdf is zero.
    pub impossible: u64,
}

/// Compares observed counts (the last entry: samples the pdf does not cover — delta or
/// rejected draws) with expected ones, pooling bins that expect fewer than
/// [`MIN_EXPECTED`].
pub fn test(observed: &[u64], expected: &[f64]) -> Chi2 {
    let mut order: Vec<usize> = (0..expected.len()).collect();
    order.sort_by(|&a, &b| expected[a].total_cmp(&expected[b]));
    let (mut stat, mut cells, mut impossible) = (0.0, 0usize, 0u64);
    let (mut pool_o, mut pool_e) = (0.0, 0.0);
    for i in order {
        let (o, e) = (observed[i] as f64, expected[i]);
        if e <= 0.0 {
            impossible += observed[i];
            continue;
        }
        if e < MIN_EXPECTED {
            pool_o += o;
            pool_e += e;
            if pool_e >= MIN_EXPECTED {
                stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
                cells += 1;
                pool_o = 0.0;
                pool_e = 0.0;
            }
        } else {
            stat += (o - e) * (o - e) / e;
            cells += 1;
        }
    }
    if pool_e > 0.0 {
        stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        cells += 1;
    }
    let dof = cells.saturating_sub(1).max(1);
    Chi2 {
        statistic: stat,
        dof,
        p_value: gamma_q(dof as f64 / 2.0, stat / 2.0),
        impossible,
    }
}

#[test]
fn gamma_q_matches_closed_forms() {
    // Two degrees of freedom: Q(1, x/2) = exp(-x/2); Q(1/2, x) = erfc(√x).
    for x in [0.1f64, 1.0, 3.0, 10.0, 40.0] {
        assert!(
            (gamma_q(1.0, x / 2.0) - (-x / 2.0).exp()).abs() < 1e-12,
            "{x}"
        );
    }
    // erfc(1) = 0.157299207050285; the chi² 95 % point of 10 dof is 18.307.
    assert!((gamma_q(0.5, 1.0) - 0.157_299_207_050_285).abs() < 1e-10);
    assert!((gamma_q(5.0, 18.307 / 2.0) - 0.05).abs() < 1e-4);
    assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-12);
}
