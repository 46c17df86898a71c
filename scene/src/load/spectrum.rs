//! Spectra to linear sRGB the way Mitsuba 3's RGB variants convert a `<spectrum>` of
//! `wavelength:value` pairs at load time (its XML parser and `spectrum_list_to_srgb`):
//!
//! - values are scaled by 1 / ∫ȳ (so a unit spectrum has luminance 1), linearly
//!   interpolated between the given wavelengths and zero outside them;
//! - integrated against the CIE 1931 2° colour matching functions (5 nm table, linearly
//!   interpolated) by a 1000-point sum over 360–830 nm;
//! - a **reflectance** is weighted by the CIE D65 illuminant (normalized to unit luminance),
//!   because sRGB's white point is D65: a flat reflectance of 1 becomes RGB ≈ (1, 1, 1), and
//!   the result is clamped to [0, 1];
//! - an **emitter** spectrum (inside `<emitter>`) is not weighted (it is the light itself)
//!   and only clamped below at 0; a flat emitter spectrum is therefore slightly purple in sRGB,
//!   as in Mitsuba.
//!
//! Then XYZ → linear sRGB with the Rec. 709 matrix. The tables are the CIE standard data
//! (1931 observer, D65 relative spectral power).
use glam::{DVec3, Vec3};

const CIE_MIN: f64 = 360.0;
const CIE_MAX: f64 = 830.0;
/// ∫ȳ(λ) dλ over the table (Mitsuba's `MI_CIE_Y_NORMALIZATION` is its inverse).
const CIE_Y_INTEGRAL: f64 = 106.75025939941406;
/// ∫ȳ(λ) D65(λ) dλ / ∫ȳ: scales D65 (100 at 560 nm) to unit luminance.
const D65_NORMALIZATION: f64 = 1.0 / 98.99741751876255;

const CIE_X: [f32; 95] = [
    0.0001299, 0.0002321, 0.0004149, 0.0007416, 0.001368, 0.002236, 0.004243, 0.00765,
    0.01431, 0.02319, 0.04351, 0.07763, 0.13438, 0.21477, 0.2839, 0.3285,
    0.34828, 0.34806, 0.3362, 0.3187, 0.2908, 0.2511, 0.19536, 0.1421,
    0.09564, 0.05795001, 0.03201, 0.0147, 0.0049, 0.0024, 0.0093, 0.0291,
    0.06327, 0.1096, 0.1655, 0.2257499, 0.2904, 0.3597, 0.4334499, 0.5120501,
    0.5945, 0.6784, 0.7621, 0.8425, 0.9163, 0.9786, 1.0263, 1.0567,
    1.0622, 1.0456, 1.0026, 0.9384, 0.8544499, 0.7514, 0.6424, 0.5419,
    0.4479, 0.3608, 0.2835, 0.2187, 0.1649, 0.1212, 0.0874, 0.0636,
    0.04677, 0.0329, 0.0227, 0.01584, 0.01135916, 0.008110916, 0.005790346, 0.004109457,
    0.002899327, 0.00204919, 0.001439971, 0.0009999493, 0.0006900786, 0.0004760213, 0.0003323011, 0.0002348261,
    0.0001661505, 0.000117413, 8.307527e-05, 5.870652e-05, 4.150994e-05, 2.935326e-05, 2.067383e-05, 1.455977e-05,
    1.025398e-05, 7.221456e-06, 5.085868e-06, 3.581652e-06, 2.522525e-06, 1.776509e-06, 1.251141e-06,
];
const CIE_Y: [f32; 95] = [
    3.917e-06, 6.965e-06, 1.239e-05, 2.202e-05, 3.9e-05, 6.4e-05, 0.00012, 0.000217,
    0.000396, 0.00064, 0.00121, 0.00218, 0.004, 0.0073, 0.0116, 0.01684,
    0.023, 0.0298, 0.038, 0.048, 0.06, 0.0739, 0.09098, 0.1126,
    0.13902, 0.1693, 0.20802, 0.2586, 0.323, 0.4073, 0.503, 0.6082,
    0.71, 0.7932, 0.862, 0.9148501, 0.954, 0.9803, 0.9949501, 1.0,
    0.995, 0.9786, 0.952, 0.9154, 0.87, 0.8163, 0.757, 0.6949,
    0.631, 0.5668, 0.503, 0.4412, 0.381, 0.321, 0.265, 0.217,
    0.175, 0.1382, 0.107, 0.0816, 0.061, 0.04458, 0.032, 0.0232,
    0.017, 0.01192, 0.00821, 0.005723, 0.004102, 0.002929, 0.002091, 0.001484,
    0.001047, 0.00074, 0.00052, 0.0003611, 0.0002492, 0.0001719, 0.00012, 8.48e-05,
    6e-05, 4.24e-05, 3e-05, 2.12e-05, 1.499e-05, 1.06e-05, 7.4657e-06, 5.2578e-06,
    3.7029e-06, 2.6078e-06, 1.8366e-06, 1.2934e-06, 9.1093e-07, 6.4153e-07, 4.5181e-07,
];
const CIE_Z: [f32; 95] = [
    0.0006061, 0.001086, 0.001946, 0.003486, 0.006450001, 0.01054999, 0.02005001, 0.03621,
    0.06785001, 0.1102, 0.2074, 0.3713, 0.6456, 1.0390501, 1.3856, 1.62296,
    1.74706, 1.7826, 1.77211, 1.7441, 1.6692, 1.5281, 1.28764, 1.0419,
    0.8129501, 0.6162, 0.46518, 0.3533, 0.272, 0.2123, 0.1582, 0.1117,
    0.07824999, 0.05725001, 0.04216, 0.02984, 0.0203, 0.0134, 0.008749999, 0.005749999,
    0.0039, 0.002749999, 0.0021, 0.0018, 0.001650001, 0.0014, 0.0011, 0.001,
    0.0008, 0.0006, 0.00034, 0.00024, 0.00019, 0.0001, 4.999999e-05, 3e-05,
    2e-05, 1e-05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
];
const D65: [f32; 95] = [
    46.6383, 49.3637, 52.0891, 51.0323, 49.9755, 52.3118, 54.6482, 68.7015,
    82.7549, 87.1204, 91.486, 92.4589, 93.4318, 90.057, 86.6823, 95.7736,
    104.865, 110.936, 117.008, 117.41, 117.812, 116.336, 114.861, 115.392,
    115.923, 112.367, 108.811, 109.082, 109.354, 108.578, 107.802, 106.296,
    104.79, 106.239, 107.689, 106.047, 104.405, 104.225, 104.046, 102.023,
    100.0, 98.1671, 96.3342, 96.0611, 95.788, 92.2368, 88.6856, 89.3459,
    90.0062, 89.8026, 89.5991, 88.6489, 87.6987, 85.4936, 83.2886, 83.4939,
    83.6992, 81.863, 80.0268, 80.1207, 80.2146, 81.2462, 82.2778, 80.281,
    78.2842, 74.0027, 69.7213, 70.6652, 71.6091, 72.979, 74.349, 67.9765,
    61.604, 65.7448, 69.8856, 72.4863, 75.087, 69.3398, 63.5927, 55.0054,
    46.4182, 56.6118, 66.8054, 65.0941, 63.3828, 63.8434, 64.304, 61.8779,
    59.4519, 55.7054, 51.959, 54.6998, 57.4406, 58.8765, 60.3125,
];

/// Linear interpolation in a 95-entry table sampled every 5 nm from 360 nm; 0 outside.
fn table(t: &[f32; 95], w: f64) -> f64 {
    if !(CIE_MIN..=CIE_MAX).contains(&w) {
        return 0.0;
    }
    let x = (w - CIE_MIN) / 5.0;
    let i = (x as usize).min(93);
    let f = x - i as f64;
    t[i] as f64 * (1.0 - f) + t[i + 1] as f64 * f
}

/// CIE 1931 x̄, ȳ, z̄ at `w` nm.
pub fn cie1931_xyz(w: f64) -> DVec3 {
    DVec3::new(table(&CIE_X, w), table(&CIE_Y, w), table(&CIE_Z, w))
}

/// CIE D65 at `w` nm, normalized to unit luminance.
pub fn d65(w: f64) -> f64 {
    table(&D65, w) * D65_NORMALIZATION
}

/// XYZ to linear sRGB (Rec. 709 primaries, D65 white).
pub fn xyz_to_srgb(c: DVec3) -> DVec3 {
    DVec3::new(
        3.240479 * c.x - 1.537150 * c.y - 0.498535 * c.z,
        -0.969256 * c.x + 1.875991 * c.y + 0.041556 * c.z,
        0.055648 * c.x - 0.204043 * c.y + 1.057311 * c.z,
    )
}

/// What a spectrum describes: the conversion differs (see the module comment).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpectrumKind {
    Reflectance,
    Emitter,
}

/// Linear sRGB of the piecewise-linear spectrum through `(wavelength nm, value)` pairs
/// (wavelengths increasing; the caller checks), converted as Mitsuba 3's RGB variants do.
pub fn spectrum_to_rgb(pairs: &[(f64, f64)], kind: SpectrumKind) -> Vec3 {
    let (Some(first), Some(last)) = (pairs.first(), pairs.last()) else { return Vec3::ZERO };
    const STEPS: usize = 1000;
    let mut xyz = DVec3::ZERO;
    let mut k = 0;
    for i in 0..STEPS {
        let w = CIE_MIN + i as f64 / (STEPS - 1) as f64 * (CIE_MAX - CIE_MIN);
        if w < first.0 || w > last.0 {
            continue;
        }
        while k + 2 < pairs.len() && pairs[k + 1].0 <= w {
            k += 1;
        }
        let (a, b) = if pairs.len() == 1 { (pairs[0], pairs[0]) } else { (pairs[k], pairs[k + 1]) };
        let v = if b.0 > a.0 { a.1 + (b.1 - a.1) * (w - a.0) / (b.0 - a.0) } else { a.1 };
        let weight = match kind {
            SpectrumKind::Reflectance => d65(w),
            SpectrumKind::Emitter => 1.0,
        };
        xyz += cie1931_xyz(w) * (v / CIE_Y_INTEGRAL * weight);
    }
    xyz *= (CIE_MAX - CIE_MIN) / STEPS as f64;
    let rgb = xyz_to_srgb(xyz);
    let rgb = match kind {
        SpectrumKind::Reflectance => rgb.clamp(DVec3::ZERO, DVec3::ONE),
        SpectrumKind::Emitter => rgb.max(DVec3::ZERO),
    };
    rgb.as_vec3()
}

/// A uniform spectrum of `value`: a reflectance is grey; an emitter is `value` times the
/// sRGB of the flat spectrum's XYZ (1, 1, 1) — the slightly purple white Mitsuba's RGB
/// variants give a flat emitter.
pub fn uniform_to_rgb(value: f64, kind: SpectrumKind) -> Vec3 {
    match kind {
        SpectrumKind::Reflectance => Vec3::splat(value as f32),
        SpectrumKind::Emitter => (xyz_to_srgb(DVec3::ONE) * value).max(DVec3::ZERO).as_vec3(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ∫ f·g over [a, b] for f, g linear on it: Simpson's rule is exact for the quadratic
    /// product.
    fn simpson(a: f64, b: f64, f: impl Fn(f64) -> f64) -> f64 {
        (b - a) / 6.0 * (f(a) + 4.0 * f(0.5 * (a + b)) + f(b))
    }

    /// The same conversion computed independently: the exact integral of the product of
    /// the piecewise-linear spectrum and the piecewise-linear tables (every breakpoint of
    /// either), instead of Mitsuba's 1000-point sum. They agree to the sum's error.
    fn exact(pairs: &[(f64, f64)], kind: SpectrumKind) -> DVec3 {
        let mut cuts: Vec<f64> = (0..95).map(|i| CIE_MIN + 5.0 * i as f64).chain(pairs.iter().map(|p| p.0)).collect();
        cuts.retain(|w| *w >= pairs[0].0 && *w <= pairs[pairs.len() - 1].0);
        cuts.sort_by(f64::total_cmp);
        cuts.dedup();
        let value = |w: f64| {
            let k = pairs.windows(2).position(|p| w >= p[0].0 && w <= p[1].0).unwrap();
            let (a, b) = (pairs[k], pairs[k + 1]);
            a.1 + (b.1 - a.1) * (w - a.0) / (b.0 - a.0)
        };
        let mut xyz = DVec3::ZERO;
        for s in cuts.windows(2) {
            for c in 0..3 {
                // D65 is linear on the same 5 nm grid, so the product is cubic there; Simpson
                // is then not exact: split each piece finely instead.
                let n = 16;
                for j in 0..n {
                    let (a, b) = (s[0] + (s[1] - s[0]) * j as f64 / n as f64, s[0] + (s[1] - s[0]) * (j + 1) as f64 / n as f64);
                    xyz[c] += simpson(a, b, |w| {
                        let weight = if kind == SpectrumKind::Reflectance { d65(w) } else { 1.0 };
                        cie1931_xyz(w)[c] * value(w) * weight
                    });
                }
            }
        }
        xyz_to_srgb(xyz / CIE_Y_INTEGRAL)
    }

    #[test]
    fn conversion_matches_the_exact_integral() {
        let light = [(400.0, 0.0), (500.0, 8.0), (600.0, 15.6), (700.0, 18.4)];
        let got = spectrum_to_rgb(&light, SpectrumKind::Emitter).as_dvec3();
        let want = exact(&light, SpectrumKind::Emitter);
        assert!((got - want).abs().max_element() < 5e-3 * want.max_element(), "{got} vs {want}");
        let red = [(400.0, 0.04), (550.0, 0.06), (600.0, 0.287), (650.0, 0.61), (700.0, 0.642)];
        let got = spectrum_to_rgb(&red, SpectrumKind::Reflectance).as_dvec3();
        let want = exact(&red, SpectrumKind::Reflectance);
        assert!((got - want).abs().max_element() < 5e-3, "{got} vs {want}");
        assert!(got.x > 3.0 * got.y && got.x > 3.0 * got.z, "red stays red: {got}");
    }

    #[test]
    fn white_points() {
        // A flat reflectance over the whole table is white under D65 (sRGB's white).
        let white = spectrum_to_rgb(&[(360.0, 1.0), (830.0, 1.0)], SpectrumKind::Reflectance);
        assert!((white - Vec3::ONE).abs().max_element() < 5e-3, "{white}");
        // Luminance of a flat unit emitter is 1; in sRGB it is XYZ (1, 1, 1), a purple white.
        let flat = spectrum_to_rgb(&[(360.0, 1.0), (830.0, 1.0)], SpectrumKind::Emitter);
        let y = 0.212671 * flat.x + 0.715160 * flat.y + 0.072169 * flat.z;
        assert!((y - 1.0).abs() < 5e-3, "{flat}");
        assert!((flat - uniform_to_rgb(1.0, SpectrumKind::Emitter)).abs().max_element() < 1e-2);
        assert!(flat.x > flat.y && flat.z < flat.y, "{flat}");
    }
}
