//! `FRAME_ENCODING_LINEAR_HALF_LZ4`: a frame's linear RGB as IEEE half floats, compressed
//! losslessly, for viewers that keep the radiance (EXR files, tev, their own exposure and
//! tone mapping). The renderer encodes it, the viewer decodes it; both live here so the
//! layout has one definition.
//!
//! Layout (all integers little-endian):
//! ```text
//! "EPH1" | width u32 | height u32 | band_rows u32 | bands u32 | bands × compressed length u32 | bands × LZ4 block
//! ```
//! A band is `band_rows` rows (the last may be shorter), compressed alone so the renderer
//! encodes bands in parallel. A band's uncompressed bytes are six planes of `rows × width`
//! bytes: for R, G and B, the high bytes then the low bytes of each pixel's half-float bits
//! minus those of its predictor (the pixel to its left; for the first pixel of a row the one
//! above; 0 for the band's first pixel), wrapping. Why: neighbouring pixels are close, so
//! the differences are small numbers whose high bytes are nearly all 0x00 or 0xff and
//! compress to almost nothing; measured on the converged 512² Cornell box, LZ4 of the raw
//! half floats kept 55 % of the bytes, of the delta planes 43 % (zstd level 1: 31 %, but
//! at twice the time).
//!
//! Conversion: round to nearest half; NaN becomes 0 and magnitudes beyond the largest half
//! (65504) saturate to it, so no infinity or NaN ever reaches a file. Nothing is clipped to
//! [0, 1] and nothing is tone-mapped.
use glam::Vec3;
use half::f16;
use half::slice::{HalfBitsSliceExt, HalfFloatSliceExt};

/// The first four bytes of every linear frame.
pub const MAGIC: [u8; 4] = *b"EPH1";
/// Rows per band the renderer uses (a decoder takes any count from the header).
pub const BAND_ROWS: usize = 16;
/// Bytes of the fixed part of the header.
pub const HEADER_LEN: usize = 20;
/// The largest finite half.
pub const HALF_MAX: f32 = 65504.0;
/// LZ4 cannot expand a block by more than this factor (a run of one byte costs at least one
/// byte per 255): a claimed size past it is refused before anything is allocated for it.
const LZ4_MAX_RATIO: usize = 255;

/// A decoded linear frame: half-float bits, interleaved R, G, B, rows top to bottom.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LinearFrame {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u16>,
}

impl LinearFrame {
    /// The frame as f32 values (interleaved R, G, B).
    pub fn to_f32(&self) -> Vec<f32> {
        let mut out = vec![0.0f32; self.rgb.len()];
        self.halves().convert_to_f32_slice(&mut out);
        out
    }

    /// The half-float values (interleaved R, G, B).
    pub fn halves(&self) -> &[f16] {
        self.rgb.reinterpret_cast::<f16>()
    }

    /// The frame of linear `pixels`, converted to half floats as the encoder does.
    pub fn from_linear(pixels: &[Vec3], width: u32, height: u32) -> Self {
        let mut rgb = Vec::with_capacity(pixels.len() * 3);
        let mut row = Vec::new();
        let mut halves = Vec::new();
        for chunk in pixels.chunks(width.max(1) as usize) {
            to_half_row(chunk, &mut row, &mut halves);
            rgb.extend_from_slice(&halves);
        }
        LinearFrame { width, height, rgb }
    }
}

/// The half float a linear value is stored as (the conversion of [`MAGIC`] frames).
pub fn to_half(x: f32) -> f16 {
    f16::from_f32(saturate(x))
}

#[inline(always)]
fn saturate(x: f32) -> f32 {
    // `max` and `min` drop a NaN operand, so NaN becomes -HALF_MAX here: test it first.
    if x.is_nan() {
        0.0
    } else {
        x.clamp(-HALF_MAX, HALF_MAX)
    }
}

/// One row of linear pixels to half-float bits (`halves` gets 3 per pixel).
fn to_half_row(src: &[Vec3], flat: &mut Vec<f32>, halves: &mut Vec<u16>) {
    flat.clear();
    flat.extend(src.iter().flat_map(|c| [saturate(c.x), saturate(c.y), saturate(c.z)]));
    halves.resize(flat.len(), 0);
    // F16C instructions when the processor has them (detected at run time).
    halves.as_mut_slice().reinterpret_cast_mut::<f16>().convert_from_f32_slice(flat);
}

/// Why a linear frame could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinearFrameError {
    Truncated { need: usize, got: usize },
    BadMagic,
    SizeMismatch { got_w: u32, got_h: u32, width: u32, height: u32 },
    BadBands { band_rows: u32, bands: u32, height: u32 },
    Lengths { sum: u64, got: usize },
    Implausible { band: usize, raw: usize, compressed: usize },
    Lz4 { band: usize, reason: String },
}

impl std::fmt::Display for LinearFrameError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Truncated { need, got } => write!(f, "linear frame truncated: needs at least {need} bytes, has {got}"),
            Self::BadMagic => write!(f, "not a linear frame (no EPH1 signature)"),
            Self::SizeMismatch { got_w, got_h, width, height } => {
                write!(f, "linear frame is {got_w}x{got_h}, the message says {width}x{height}")
            }
            Self::BadBands { band_rows, bands, height } => {
                write!(f, "linear frame: {bands} bands of {band_rows} rows do not cover {height} rows")
            }
            Self::Lengths { sum, got } => write!(f, "linear frame: band lengths add up to {sum} bytes, {got} follow the header"),
            Self::Implausible { band, raw, compressed } => {
                write!(f, "linear frame: band {band} cannot expand from {compressed} to {raw} bytes")
            }
            Self::Lz4 { band, reason } => write!(f, "linear frame: band {band}: {reason}"),
        }
    }
}

impl std::error::Error for LinearFrameError {}

/// A band's working buffers, kept from frame to frame by the encoder that owns it.
#[derive(Default)]
pub struct BandScratch {
    flat: Vec<f32>,
    halves: Vec<u16>,
    planes: Vec<u8>,
}

/// Encodes `rows` (whole rows of `width` pixels) as one band's LZ4 block into `out`
/// (cleared first).
pub fn encode_band(rows: &[Vec3], width: usize, scratch: &mut BandScratch, out: &mut Vec<u8>) {
    let n = rows.len();
    scratch.planes.resize(n * 6, 0);
    let (p0, rest) = scratch.planes.split_at_mut(2 * n);
    let (p1, p2) = rest.split_at_mut(2 * n);
    let (mut r, mut g, mut b) = (split(p0, n), split(p1, n), split(p2, n));
    // The first pixel of the previous row (the predictor of the next row's first pixel).
    let mut above = [0u16; 3];
    for (y, src) in rows.chunks_exact(width).enumerate() {
        to_half_row(src, &mut scratch.flat, &mut scratch.halves);
        let mut prev = above;
        above = [scratch.halves[0], scratch.halves[1], scratch.halves[2]];
        let base = y * width;
        for (x, px) in scratch.halves.chunks_exact(3).enumerate() {
            let i = base + x;
            put(&mut r, i, px[0].wrapping_sub(prev[0]));
            put(&mut g, i, px[1].wrapping_sub(prev[1]));
            put(&mut b, i, px[2].wrapping_sub(prev[2]));
            prev = [px[0], px[1], px[2]];
        }
    }
    out.clear();
    out.resize(lz4_flex::block::get_maximum_output_size(scratch.planes.len()), 0);
    let len = lz4_flex::block::compress_into(&scratch.planes, out).expect("the buffer has LZ4's maximum output size");
    out.truncate(len);
}

type Planes<'a> = (&'a mut [u8], &'a mut [u8]);

fn split(p: &mut [u8], n: usize) -> Planes<'_> {
    p.split_at_mut(n)
}

#[inline(always)]
fn put(p: &mut Planes<'_>, i: usize, d: u16) {
    p.0[i] = (d >> 8) as u8;
    p.1[i] = d as u8;
}

/// The header of a frame of `width` x `height` in bands of `band_rows`, followed by the
/// bands' lengths.
pub fn header(width: u32, height: u32, band_rows: usize, band_lens: &[usize]) -> Vec<u8> {
    let mut h = Vec::with_capacity(HEADER_LEN + 4 * band_lens.len());
    h.extend_from_slice(&MAGIC);
    for v in [width, height, band_rows as u32, band_lens.len() as u32] {
        h.extend_from_slice(&v.to_le_bytes());
    }
    for &l in band_lens {
        h.extend_from_slice(&(l as u32).to_le_bytes());
    }
    h
}

/// Encodes a whole frame on this thread (the renderer's encoder does the bands in parallel).
pub fn encode(pixels: &[Vec3], width: u32, height: u32) -> Vec<u8> {
    let w = width as usize;
    assert_eq!(pixels.len(), w * height as usize, "linear frame: {} pixels for {width}x{height}", pixels.len());
    let mut scratch = BandScratch::default();
    let bands: Vec<Vec<u8>> = pixels
        .chunks(w * BAND_ROWS)
        .map(|rows| {
            let mut out = Vec::new();
            encode_band(rows, w, &mut scratch, &mut out);
            out
        })
        .collect();
    let lens: Vec<usize> = bands.iter().map(Vec::len).collect();
    let mut out = header(width, height, BAND_ROWS, &lens);
    for b in &bands {
        out.extend_from_slice(b);
    }
    out
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

/// Decodes a linear frame that must be `width` x `height`. Every size is checked against
/// the bytes actually present before anything is allocated for it.
pub fn decode(bytes: &[u8], width: u32, height: u32) -> Result<LinearFrame, LinearFrameError> {
    if bytes.len() < HEADER_LEN {
        return Err(LinearFrameError::Truncated { need: HEADER_LEN, got: bytes.len() });
    }
    if bytes[..4] != MAGIC {
        return Err(LinearFrameError::BadMagic);
    }
    let (got_w, got_h) = (u32_at(bytes, 4), u32_at(bytes, 8));
    if (got_w, got_h) != (width, height) || width == 0 || height == 0 {
        return Err(LinearFrameError::SizeMismatch { got_w, got_h, width, height });
    }
    let (band_rows, bands) = (u32_at(bytes, 12), u32_at(bytes, 16));
    if band_rows == 0 || bands as u64 != (height as u64).div_ceil(band_rows as u64) {
        return Err(LinearFrameError::BadBands { band_rows, bands, height });
    }
    let table_end = HEADER_LEN + 4 * bands as usize;
    if bytes.len() < table_end {
        return Err(LinearFrameError::Truncated { need: table_end, got: bytes.len() });
    }
    let lens: Vec<usize> = (0..bands as usize).map(|i| u32_at(bytes, HEADER_LEN + 4 * i) as usize).collect();
    let sum: u64 = lens.iter().map(|&l| l as u64).sum();
    if sum != (bytes.len() - table_end) as u64 {
        return Err(LinearFrameError::Lengths { sum, got: bytes.len() - table_end });
    }
    let (w, band_rows) = (width as usize, band_rows as usize);
    // Each band's size is checked against its compressed length before the output grows.
    let mut rgb: Vec<u16> = Vec::new();
    let mut planes = Vec::new();
    let mut at = table_end;
    for (band, &len) in lens.iter().enumerate() {
        let rows = band_rows.min(height as usize - band * band_rows);
        let n = rows * w;
        let raw = n * 6;
        if raw > len.saturating_mul(LZ4_MAX_RATIO) + 16 {
            return Err(LinearFrameError::Implausible { band, raw, compressed: len });
        }
        planes.clear();
        planes.resize(raw, 0);
        let got = lz4_flex::block::decompress_into(&bytes[at..at + len], &mut planes)
            .map_err(|e| LinearFrameError::Lz4 { band, reason: e.to_string() })?;
        if got != raw {
            return Err(LinearFrameError::Lz4 { band, reason: format!("{got} bytes decompressed, {raw} expected") });
        }
        at += len;
        let start = rgb.len();
        rgb.resize(start + n * 3, 0);
        let out = &mut rgb[start..];
        for c in 0..3 {
            let (hi, lo) = planes[c * 2 * n..(c * 2 + 2) * n].split_at(n);
            // Undo the prediction: left neighbour, or the first pixel of the row above.
            let mut above = 0u16;
            for y in 0..rows {
                let mut prev = above;
                for x in 0..w {
                    let i = y * w + x;
                    let v = prev.wrapping_add(((hi[i] as u16) << 8) | lo[i] as u16);
                    out[i * 3 + c] = v;
                    prev = v;
                    if x == 0 {
                        above = v;
                    }
                }
            }
        }
    }
    Ok(LinearFrame { width, height, rgb })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state_next(s: &mut u64) -> f32 {
        *s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (*s >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Smooth gradients, a hard edge, noise, HDR values past 1, negatives, NaN and huge
    /// values: every branch of the conversion and the predictor.
    fn frame(w: u32, h: u32, seed: u64) -> Vec<Vec3> {
        let mut s = seed;
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
                let n = state_next(&mut s);
                match (i * 7919 + seed as u32) % 97 {
                    0 => Vec3::new(f32::NAN, 1e9, -1e9),
                    1 => Vec3::new(-0.25, 70000.0, f32::INFINITY),
                    2 => Vec3::splat(1e-7),
                    _ => Vec3::new(x * 40.0, y * y, if x + y > 1.0 { 3.0 } else { 0.01 } + n * 0.1),
                }
            })
            .collect()
    }

    #[test]
    fn round_trips_the_half_floats_exactly() {
        for (w, h, seed) in [(1, 1, 1), (1, 40, 2), (57, 1, 3), (5, 15, 4), (5, 16, 5), (5, 17, 6), (33, 49, 7), (64, 100, 8)] {
            let px = frame(w, h, seed);
            let bytes = encode(&px, w, h);
            let got = decode(&bytes, w, h).unwrap();
            assert_eq!(got, LinearFrame::from_linear(&px, w, h), "{w}x{h}");
            // The stored value is the nearest half to the saturated input.
            for (c, v) in px.iter().flat_map(|p| p.to_array()).zip(got.to_f32()) {
                let want = if c.is_nan() { 0.0 } else { c.clamp(-HALF_MAX, HALF_MAX) };
                assert!(v.is_finite(), "{c} -> {v}");
                let tol = (want.abs() * 2f32.powi(-11)).max(2f32.powi(-24));
                assert!((v - want).abs() <= tol, "{c} -> {v}");
            }
        }
    }

    #[test]
    fn smooth_frames_compress() {
        let (w, h) = (256, 128);
        let px: Vec<Vec3> = (0..w * h).map(|i| Vec3::new((i % w) as f32 / w as f32, 0.5, (i / w) as f32 / h as f32)).collect();
        let bytes = encode(&px, w, h);
        assert!(bytes.len() * 4 < (w * h * 6) as usize, "{} bytes", bytes.len());
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let px = frame(20, 20, 9);
        let bytes = encode(&px, 20, 20);
        assert_eq!(decode(&bytes, 20, 21), Err(LinearFrameError::SizeMismatch { got_w: 20, got_h: 20, width: 20, height: 21 }));
        assert_eq!(decode(&bytes[..10], 20, 20), Err(LinearFrameError::Truncated { need: HEADER_LEN, got: 10 }));
        assert_eq!(decode(b"QOIFxxxxxxxxxxxxxxxxxxxxxxx", 20, 20), Err(LinearFrameError::BadMagic));
        assert!(matches!(decode(&bytes[..bytes.len() - 1], 20, 20), Err(LinearFrameError::Lengths { .. })));
        // A huge claimed size is refused from the header alone.
        let mut huge = header(60000, 60000, 60000, &[8]);
        huge.extend_from_slice(&[0u8; 8]);
        assert!(matches!(decode(&huge, 60000, 60000), Err(LinearFrameError::Implausible { .. })));
        // Every truncation and every single-byte corruption decodes or errs, never panics.
        for cut in 0..bytes.len() {
            let _ = decode(&bytes[..cut], 20, 20);
        }
        let mut s = 5u64;
        for i in 0..bytes.len() {
            let mut bad = bytes.clone();
            bad[i] ^= 1 + (state_next(&mut s) * 254.0) as u8;
            let _ = decode(&bad, 20, 20);
        }
    }
}
