//! Exposure and tone mapping of linear frames for PNG files and the window: the displayed
//! value is `curve(x · 2^EV)`, then the sRGB transfer function (IEC 61966-2-1), rounded to 8
//! bits. The linear data itself (EXR files, tev) is never touched.
//!
//! Curves:
//! - `clip`: values above 1 are clipped. At exposure 0 this is exactly what the renderer's
//!   own sRGB frames hold (the same correctly rounded codes: the tests check every half
//!   float against the renderer's table).
//! - `filmic`: the ACES filmic fit of Krzysztof Narkowicz (2016),
//!   `f(x) = x(2.51x + 0.03) / (x(2.43x + 0.59) + 0.14)`, clamped to [0, 1], applied to each
//!   channel of the exposed value as it is (no extra 0.6 pre-scale). It rises as `x/4.7`
//!   near black, rolls off highlights smoothly and reaches white at x ≈ 7.2, so a scene
//!   several stops over 1 keeps its detail where `clip` burns it out.
//!
//! Why a table over half floats: linear frames arrive as half floats (65,536 possible
//! values), so the whole chain — exposure, curve, transfer, rounding — is evaluated once per
//! half value in f64 when the look changes (a few ms) and a frame is then one table lookup
//! per channel, cheaper than the renderer's sRGB conversion itself.
use edgepoint_proto::linear_frame::LinearFrame;
use half::f16;
use image::RgbImage;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

/// The tone curve applied after exposure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ToneCurve {
    /// Clip at 1 (the renderer's own sRGB frames at exposure 0).
    #[default]
    Clip,
    /// ACES filmic fit (Narkowicz 2016): highlights roll off instead of clipping.
    Filmic,
}

impl ToneCurve {
    pub fn name(self) -> &'static str {
        match self {
            ToneCurve::Clip => "clip",
            ToneCurve::Filmic => "filmic",
        }
    }

    /// The other curve (the window's T key).
    pub fn toggled(self) -> Self {
        match self {
            ToneCurve::Clip => ToneCurve::Filmic,
            ToneCurve::Filmic => ToneCurve::Clip,
        }
    }

    /// The curve on an exposed linear value; the result is in [0, 1] (NaN and values ≤ 0
    /// give 0).
    pub fn apply(self, x: f64) -> f64 {
        // Written so NaN falls into the first branch.
        if x.is_nan() || x <= 0.0 {
            return 0.0;
        }
        match self {
            ToneCurve::Clip => x.min(1.0),
            // The fit is past 1 from x ≈ 7.24 on; stopping there also keeps x² finite.
            ToneCurve::Filmic if x >= 8.0 => 1.0,
            ToneCurve::Filmic => {
                let (a, b, c, d, e) = (2.51, 0.03, 2.43, 0.59, 0.14);
                ((x * (a * x + b)) / (x * (c * x + d) + e)).clamp(0.0, 1.0)
            }
        }
    }
}

/// How linear frames are shown: exposure in stops, then a tone curve.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Look {
    pub exposure: f32,
    pub curve: ToneCurve,
}

impl Look {
    /// Whether this look is what the renderer's sRGB frames show (so those can be used).
    pub fn is_identity(&self) -> bool {
        self.exposure == 0.0 && self.curve == ToneCurve::Clip
    }

    /// The displayed value in [0, 1] before the sRGB transfer.
    pub fn display(&self, x: f32) -> f64 {
        // 2^0 is exactly 1, so exposure 0 leaves every value as it is.
        self.curve.apply(x as f64 * (self.exposure as f64).exp2())
    }

    /// The 8-bit sRGB code of the linear value `x`, correctly rounded.
    pub fn srgb8(&self, x: f32) -> u8 {
        srgb_code(self.display(x))
    }

    /// A short description for logs and the window (`EV +1.0 filmic`).
    pub fn describe(&self) -> String {
        format!("EV {:+.1} {}", self.exposure, self.curve.name())
    }
}

/// The look the window's keys change and the frame receiver applies, shared between them.
pub struct LookControl {
    look: Mutex<Look>,
    /// Whether the session sends (or was asked for) linear frames.
    linear: AtomicBool,
}

impl LookControl {
    pub fn new(look: Look, linear: bool) -> Self {
        LookControl { look: Mutex::new(look), linear: AtomicBool::new(linear) }
    }

    pub fn get(&self) -> Look {
        *self.look.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Changes the look; returns it, and whether the session must now be asked for linear
    /// frames (the first change of a session that started with sRGB frames).
    pub fn adjust(&self, change: impl FnOnce(&mut Look)) -> (Look, bool) {
        let mut l = self.look.lock().unwrap_or_else(|e| e.into_inner());
        change(&mut l);
        (*l, !self.linear.swap(true, Ordering::Relaxed))
    }
}

/// `round(255 · srgb(y))` for a display value `y` in [0, 1], the transfer in f64.
pub fn srgb_code(y: f64) -> u8 {
    if y.is_nan() || y <= 0.0 {
        return 0;
    }
    if y >= 1.0 {
        return 255;
    }
    let s = if y <= 0.003_130_8 { 12.92 * y } else { 1.055 * y.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0).round() as u8
}

/// The look's codes for every half float, rebuilt only when the look changes.
pub struct ToneMapper {
    look: Look,
    table: Vec<u8>,
}

impl ToneMapper {
    pub fn new(look: Look) -> Self {
        let mut t = ToneMapper { look, table: Vec::new() };
        t.rebuild();
        t
    }

    fn rebuild(&mut self) {
        let look = self.look;
        self.table = (0..=u16::MAX).map(|h| look.srgb8(f16::from_bits(h).to_f32())).collect();
    }

    pub fn look(&self) -> Look {
        self.look
    }

    /// Switches to `look` (rebuilding the table only if it differs).
    pub fn set_look(&mut self, look: Look) {
        if look != self.look {
            self.look = look;
            self.rebuild();
        }
    }

    /// The code of one half float (its bits).
    #[inline]
    pub fn code(&self, half_bits: u16) -> u8 {
        self.table[half_bits as usize]
    }

    /// The frame as 8-bit sRGB.
    pub fn map(&self, frame: &LinearFrame) -> RgbImage {
        let raw: Vec<u8> = frame.rgb.iter().map(|&h| self.table[h as usize]).collect();
        RgbImage::from_raw(frame.width, frame.height, raw).expect("a linear frame holds width*height*3 values")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curves_are_monotone_from_zero_to_one() {
        for curve in [ToneCurve::Clip, ToneCurve::Filmic] {
            assert_eq!(curve.apply(0.0), 0.0);
            assert_eq!(curve.apply(-3.0), 0.0);
            assert_eq!(curve.apply(f64::NAN), 0.0);
            assert_eq!(curve.apply(1e30), 1.0);
            let mut prev = 0.0;
            for i in 1..200_000 {
                let x = i as f64 * 1e-4;
                let y = curve.apply(x);
                assert!(y >= prev && (0.0..=1.0).contains(&y), "{curve:?} at {x}: {y} after {prev}");
                prev = y;
            }
        }
        // Strictly increasing below the shoulder, 1 past it (the fit's white point, 7.24).
        let f = |x| ToneCurve::Filmic.apply(x);
        assert!(f(1e-6) > 0.0 && f(1.0) < f(2.0) && f(2.0) < f(7.0) && f(7.0) < 1.0 && f(7.3) == 1.0);
        // The fit's closed form at a few points.
        assert!((f(1.0) - 2.54 / 3.16).abs() < 1e-12);
        assert!((f(0.18) - 0.18 * (2.51 * 0.18 + 0.03) / (0.18 * (2.43 * 0.18 + 0.59) + 0.14)).abs() < 1e-15);
    }

    #[test]
    fn exposure_scales_by_powers_of_two() {
        let plus1 = Look { exposure: 1.0, curve: ToneCurve::Clip };
        let id = Look::default();
        for x in [0.001f32, 0.01, 0.1, 0.3, 0.49] {
            assert_eq!(plus1.srgb8(x), id.srgb8(2.0 * x));
        }
        assert!(id.is_identity() && !plus1.is_identity());
        // The codes of a look are monotone in the input, for every half float.
        for curve in [ToneCurve::Clip, ToneCurve::Filmic] {
            let t = ToneMapper::new(Look { exposure: -1.5, curve });
            let mut prev = 0;
            for h in 0..0x7c00u16 {
                let c = t.code(h);
                assert!(c >= prev, "{curve:?}: half {h:#x}");
                prev = c;
            }
            assert_eq!(t.code(0x7c00), 255, "+inf is white");
            assert_eq!(t.code(0x8000 | 0x3c00), 0, "negatives are black");
        }
    }

    #[test]
    fn srgb_codes_match_the_transfer_function() {
        assert_eq!(srgb_code(0.0), 0);
        assert_eq!(srgb_code(1.0), 255);
        assert_eq!(srgb_code(0.5), 188);
        assert_eq!(srgb_code(0.18), 118);
        assert_eq!(srgb_code(0.002), (0.002f64 * 12.92 * 255.0).round() as u8);
    }

    #[test]
    fn maps_frames_through_the_table() {
        let px = [glam::Vec3::new(0.5, 2.0, 0.0), glam::Vec3::new(0.18, -1.0, 100.0)];
        let f = LinearFrame::from_linear(&px, 2, 1);
        let img = ToneMapper::new(Look::default()).map(&f);
        assert_eq!(img.as_raw(), &vec![188, 255, 0, 118, 0, 255]);
        let filmic = ToneMapper::new(Look { exposure: 0.0, curve: ToneCurve::Filmic }).map(&f);
        assert!(filmic.as_raw()[1] < 255 && filmic.as_raw()[5] == 255);
    }
}
