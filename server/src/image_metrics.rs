//! Image quality against a reference (DESIGN.md "Measuring": PSNR / SSIM of edge-and-point
//! reconstruction vs. a converged reference) and the sRGB transfer function the frames are
//! encoded with. Both metrics work on sRGB-encoded values, as a viewer sees the images.
use glam::Vec3;
use std::sync::OnceLock;

/// The sRGB transfer function (IEC 61966-2-1) on one channel, input clamped to [0, 1].
#[inline]
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Inverse of [`linear_to_srgb`], input clamped to [0, 1].
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear RGB (clamped to [0, 1]) to 8-bit sRGB, correctly rounded in the encoded domain
/// (what `round(255 * linear_to_srgb(x))` gives in exact arithmetic), by table:
/// [`crate::srgb`].
#[inline]
pub fn linear_to_srgb8(c: Vec3) -> [u8; 3] {
    crate::srgb::encode_rgb(c)
}

fn to_linear_table() -> &'static [f32; 256] {
    static T: OnceLock<[f32; 256]> = OnceLock::new();
    T.get_or_init(|| std::array::from_fn(|k| srgb_to_linear(k as f32 / 255.0)))
}

/// 8-bit sRGB to linear RGB.
#[inline]
pub fn srgb8_to_linear(c: [u8; 3]) -> Vec3 {
    let t = to_linear_table();
    Vec3::new(t[c[0] as usize], t[c[1] as usize], t[c[2] as usize])
}

fn check_sizes(a: &[Vec3], b: &[Vec3]) {
    assert_eq!(a.len(), b.len(), "image metrics: images differ in size ({} vs {} pixels)", a.len(), b.len());
}

/// The squared difference of two linear colours after the sRGB transfer function, summed
/// over the channels: one pixel's share of [`psnr`]'s squared error.
#[inline]
pub fn srgb_squared_error(x: Vec3, y: Vec3) -> f64 {
    (0..3).map(|k| (linear_to_srgb(x[k]) as f64 - linear_to_srgb(y[k]) as f64).powi(2)).sum()
}

/// Peak signal-to-noise ratio in dB over all three channels, computed on **sRGB-encoded
/// values in [0, 1]** (linear inputs are clamped to [0, 1] and encoded with the sRGB
/// transfer function first, not quantised), peak value 1. Identical images (or two empty
/// ones) give `f64::INFINITY`.
///
/// Panics if the two images have different pixel counts (a caller bug, not input).
pub fn psnr(a: &[Vec3], b: &[Vec3]) -> f64 {
    check_sizes(a, b);
    if a.is_empty() {
        return f64::INFINITY;
    }
    use rayon::prelude::*;
    let sse: f64 = a
        .par_chunks(4096)
        .zip(b.par_chunks(4096))
        .map(|(ca, cb)| {
            let mut s = 0.0f64;
            for (x, y) in ca.iter().zip(cb) {
                s += srgb_squared_error(*x, *y);
            }
            s
        })
        .sum();
    let mse = sse / (3 * a.len()) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// Luma of sRGB-encoded values (Rec. 709 weights on the encoded channels).
fn luma(img: &[Vec3]) -> Vec<f64> {
    img.iter()
        .map(|c| {
            0.2126 * linear_to_srgb(c.x) as f64 + 0.7152 * linear_to_srgb(c.y) as f64 + 0.0722 * linear_to_srgb(c.z) as f64
        })
        .collect()
}

/// Gaussian window of Wang et al. 2004: 11 taps, sigma 1.5, normalised.
fn gaussian_window() -> [f64; 11] {
    let mut w = [0.0f64; 11];
    for (i, v) in w.iter_mut().enumerate() {
        let d = i as f64 - 5.0;
        *v = (-d * d / (2.0 * 1.5 * 1.5)).exp();
    }
    let s: f64 = w.iter().sum();
    w.iter_mut().for_each(|v| *v /= s);
    w
}

/// Separable "valid" filtering: output is (w-10) x (h-10).
fn blur_valid(src: &[f64], w: usize, h: usize, k: &[f64; 11]) -> Vec<f64> {
    let ow = w - 10;
    let oh = h - 10;
    let mut tmp = vec![0.0; ow * h];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for x in 0..ow {
            tmp[y * ow + x] = (0..11).map(|i| k[i] * row[x + i]).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..11).map(|i| k[i] * tmp[(y + i) * ow + x]).sum();
        }
    }
    out
}

const C1: f64 = 0.01 * 0.01; // (K1 L)^2, L = 1
const C2: f64 = 0.03 * 0.03; // (K2 L)^2

fn ssim_from_moments(mx: f64, my: f64, sxx: f64, syy: f64, sxy: f64) -> f64 {
    ((2.0 * mx * my + C1) * (2.0 * sxy + C2)) / ((mx * mx + my * my + C1) * (sxx + syy + C2))
}

/// Mean structural similarity (Wang et al. 2004) of the luma of the sRGB-encoded images:
/// 11x11 Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03, dynamic range 1, averaged over
/// all window positions fully inside the image. Images smaller than the window are
/// compared as one window over the whole image. Identical images give 1.0.
///
/// Panics if the pixel counts differ from each other or from `width * height`.
pub fn ssim(a: &[Vec3], b: &[Vec3], width: u32, height: u32) -> f64 {
    check_sizes(a, b);
    let (w, h) = (width as usize, height as usize);
    assert_eq!(a.len(), w * h, "image metrics: {} pixels do not make a {width}x{height} image", a.len());
    if a.is_empty() {
        return 1.0;
    }
    let ya = luma(a);
    let yb = luma(b);
    if w < 11 || h < 11 {
        let n = ya.len() as f64;
        let mx = ya.iter().sum::<f64>() / n;
        let my = yb.iter().sum::<f64>() / n;
        let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
        for (x, y) in ya.iter().zip(&yb) {
            sxx += (x - mx) * (x - mx);
            syy += (y - my) * (y - my);
            sxy += (x - mx) * (y - my);
        }
        return ssim_from_moments(mx, my, sxx / n, syy / n, sxy / n);
    }
    let k = gaussian_window();
    let prod = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f64> { ya.iter().zip(&yb).map(|(x, y)| f(*x, *y)).collect() };
    let (mu_x, mu_y, exx, eyy, exy) = {
        let xx = prod(&|x, _| x * x);
        let yy = prod(&|_, y| y * y);
        let xy = prod(&|x, y| x * y);
        let ((mu_x, mu_y), ((exx, eyy), exy)) = rayon::join(
            || rayon::join(|| blur_valid(&ya, w, h, &k), || blur_valid(&yb, w, h, &k)),
            || rayon::join(|| rayon::join(|| blur_valid(&xx, w, h, &k), || blur_valid(&yy, w, h, &k)), || blur_valid(&xy, w, h, &k)),
        );
        (mu_x, mu_y, exx, eyy, exy)
    };
    let n = mu_x.len();
    let mut sum = 0.0;
    for i in 0..n {
        let (mx, my) = (mu_x[i], mu_y[i]);
        sum += ssim_from_moments(mx, my, exx[i] - mx * mx, eyy[i] - my * my, exy[i] - mx * my);
    }
    sum / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::rng::Rng;

    #[test]
    fn srgb8_round_trips_and_matches_powf_rounding() {
        for k in 0..=255u8 {
            let lin = srgb8_to_linear([k, k, k]);
            assert_eq!(linear_to_srgb8(lin), [k, k, k], "code {k}");
        }
        let mut r = Rng(7);
        for _ in 0..200_000 {
            let x = r.unit() * 1.2 - 0.1;
            let want = (linear_to_srgb(x) * 255.0).round() as u8;
            let got = linear_to_srgb8(Vec3::splat(x))[0];
            // The two can only disagree on values within float error of a rounding boundary.
            if got != want {
                let enc = linear_to_srgb(x) * 255.0;
                assert!((enc - enc.floor() - 0.5).abs() < 1e-3, "x={x}: got {got}, want {want}");
            }
        }
        assert_eq!(linear_to_srgb8(Vec3::new(f32::NAN, -3.0, 7.0)), [0, 0, 255]);
    }

    #[test]
    fn identical_images_are_perfect() {
        let mut r = Rng(1);
        let img: Vec<Vec3> = (0..64 * 48).map(|_| Vec3::new(r.unit(), r.unit(), r.unit())).collect();
        assert_eq!(psnr(&img, &img), f64::INFINITY);
        assert!((ssim(&img, &img, 64, 48) - 1.0).abs() < 1e-12);
        assert!((ssim(&img[..5 * 4], &img[..5 * 4], 5, 4) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn psnr_matches_known_noise_level() {
        // Encoded values in [0.2, 0.8] plus exactly +-delta in the encoded domain: MSE = delta^2.
        let mut r = Rng(3);
        for &delta in &[0.01f32, 0.03, 0.1] {
            let n = 100 * 100;
            let enc: Vec<[f32; 3]> = (0..n).map(|_| [0.2 + 0.6 * r.unit(), 0.2 + 0.6 * r.unit(), 0.2 + 0.6 * r.unit()]).collect();
            let a: Vec<Vec3> = enc.iter().map(|e| Vec3::from_array(e.map(srgb_to_linear))).collect();
            let b: Vec<Vec3> = enc
                .iter()
                .map(|e| Vec3::from_array(e.map(|v| srgb_to_linear(if r.next_u64() & 1 == 0 { v + delta } else { v - delta }))))
                .collect();
            let want = -20.0 * (delta as f64).log10();
            let got = psnr(&a, &b);
            assert!((got - want).abs() < 0.1, "delta {delta}: psnr {got} dB, expected {want} dB");
        }
    }

    #[test]
    fn ssim_drops_with_noise_and_ignores_nothing() {
        let (w, h) = (64u32, 64u32);
        let mut r = Rng(5);
        let a: Vec<Vec3> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                Vec3::splat(0.5 + 0.4 * ((x * 0.3).sin() * (y * 0.2).cos()))
            })
            .collect();
        let small: Vec<Vec3> = a.iter().map(|c| *c * (1.0 + 0.02 * (r.unit() - 0.5))).collect();
        let big: Vec<Vec3> = a.iter().map(|c| (*c * (1.0 + 0.8 * (r.unit() - 0.5))).max(Vec3::ZERO)).collect();
        let s_small = ssim(&a, &small, w, h);
        let s_big = ssim(&a, &big, w, h);
        assert!(s_small > 0.95 && s_small < 1.0, "small noise ssim {s_small}");
        assert!(s_big < s_small - 0.1, "big noise ssim {s_big} vs {s_small}");
        // A constant image against its negative-contrast version is structurally dissimilar.
        let inv: Vec<Vec3> = a.iter().map(|c| Vec3::ONE - *c).collect();
        assert!(ssim(&a, &inv, w, h) < 0.0);
    }
}
