//! Linear to 8-bit sRGB by one table lookup and one comparison per channel, exactly
//! rounded: every output byte is `round(255 * srgb(x))` with the transfer function
//! (IEC 61966-2-1) evaluated in f64, for every f32 input (NaN and negatives give 0, values
//! above 1 give 255).
//!
//! Why a table of buckets: frames leave the renderer as sRGB bytes, three per pixel, every
//! frame (DESIGN.md step 12), so the conversion must cost a few instructions, not a `powf`.
//! The inputs that need a table are the f32 values in [2^-13, 1] (below 2^-13 every input
//! encodes to 0: the first rounding boundary is at 1.52e-4). Indexed by their bit pattern
//! shifted right by [`SHIFT`], that range splits into [`BUCKETS`] buckets of 2^16
//! consecutive floats each (128 per power of two). A bucket spans at most 2^-7 of its
//! value, and two rounding boundaries are never closer than 0.89 % of their value (the
//! tightest spacing is next to 1.0), so a bucket holds at most one boundary: its entry is
//! the code at its start and the offset (in float steps) of the boundary inside it, and
//! the code of `x` is that code plus one when `x` lies at or past the boundary. The
//! entries are found from the f64 formula itself when the table is built, and the tests
//! check the result against the formula for every float in [2^-13, 1].
use glam::Vec3;
use std::sync::OnceLock;

/// Bits of a float's pattern below the bucket index: 2^16 floats per bucket.
pub const SHIFT: u32 = 16;
/// The smallest input the table covers (2^-13); everything below encodes to 0.
pub const LO_BITS: u32 = 0x3900_0000;
/// The pattern of 1.0, the last input the table covers (its own one-float bucket).
const ONE_BITS: u32 = 0x3f80_0000;
/// Buckets from 2^-13 up to 1.0, plus the bucket of 1.0 itself.
pub const BUCKETS: usize = ((ONE_BITS - LO_BITS) >> SHIFT) as usize + 1;
/// Offset meaning "no boundary in this bucket" (past every offset a bucket holds).
const NO_BOUNDARY: u32 = 1 << SHIFT;
const OFFSET_MASK: u32 = (1 << SHIFT) - 1;

/// The sRGB transfer function in f64, the reference the table reproduces.
#[inline]
pub fn encode_f64(x: f64) -> f64 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// The correctly rounded 8-bit code of `x` (NaN and negatives 0, above 1 255), computed
/// with the f64 formula: the oracle of [`encode`], and what builds its table.
pub fn reference_code(x: f32) -> u8 {
    if x.is_nan() || x <= 0.0 {
        return 0;
    }
    if x >= 1.0 {
        return 255;
    }
    (encode_f64(x as f64) * 255.0).round() as u8
}

/// One entry per bucket: the code at the bucket's first float in the top 8 bits, the offset
/// of the float where the code steps up by one (or [`NO_BOUNDARY`]) in the low 24.
fn table() -> &'static [u32; BUCKETS] {
    static T: OnceLock<Box<[u32; BUCKETS]>> = OnceLock::new();
    T.get_or_init(|| {
        let mut t = Box::new([0u32; BUCKETS]);
        for (i, e) in t.iter_mut().enumerate() {
            let start = LO_BITS + ((i as u32) << SHIFT);
            let last = if start == ONE_BITS { start } else { start + OFFSET_MASK };
            let code = |bits: u32| reference_code(f32::from_bits(bits));
            let (lo, hi) = (code(start), code(last));
            assert!(hi - lo <= 1, "sRGB table: bucket {i} holds {} rounding boundaries", hi - lo);
            let offset = if hi == lo {
                NO_BOUNDARY
            } else {
                // The first float of the bucket with the higher code (the formula is
                // monotone, so the codes in a bucket are lo...lo, hi...hi).
                let (mut a, mut b) = (start, last);
                while a + 1 < b {
                    let m = a + (b - a) / 2;
                    if code(m) == lo {
                        a = m;
                    } else {
                        b = m;
                    }
                }
                b - start
            };
            *e = (lo as u32) << 24 | offset;
        }
        t
    })
}

/// The correctly rounded 8-bit sRGB code of the linear value `x`.
#[inline(always)]
pub fn encode(x: f32) -> u8 {
    encode_with(table(), x)
}

#[inline(always)]
// Not `clamp`: it keeps NaN, which must encode to 0.
#[allow(clippy::manual_clamp)]
fn encode_with(t: &[u32; BUCKETS], x: f32) -> u8 {
    // `max` returns 0 for NaN; after `min` (and without the sign of a -0) the pattern is at
    // most ONE_BITS, so the index is at most BUCKETS - 1, and inputs below 2^-13 land in
    // bucket 0 at offset 0, whose code is 0 with no boundary.
    let x = x.max(0.0).min(1.0);
    // `max` may keep -0 (its sign bit would index far past the table): drop the sign.
    let d = (x.to_bits() & 0x7fff_ffff).saturating_sub(LO_BITS);
    let e = t[(d >> SHIFT) as usize];
    ((e >> 24) + ((d & OFFSET_MASK) >= (e & 0x00ff_ffff)) as u32) as u8
}

/// Linear RGB to 8-bit sRGB, each channel correctly rounded.
#[inline]
pub fn encode_rgb(c: Vec3) -> [u8; 3] {
    let t = table();
    [encode_with(t, c.x), encode_with(t, c.y), encode_with(t, c.z)]
}

/// Encodes a row of linear pixels into packed RGBA words (`r | g << 8 | b << 16 | 255 << 24`,
/// the QOI encoder's pixels). `dst` must be as long as `src`.
pub fn encode_row_rgba(src: &[Vec3], dst: &mut [u32]) {
    assert_eq!(src.len(), dst.len(), "sRGB row: {} pixels into {}", src.len(), dst.len());
    let t = table();
    #[cfg(target_arch = "x86_64")]
    if avx2::available() {
        // SAFETY: the CPU has AVX2 and the lengths match (checked above).
        let done = unsafe { avx2::rows_rgba(t, src, dst) };
        encode_row_rgba_generic(t, &src[done..], &mut dst[done..]);
        return;
    }
    encode_row_rgba_generic(t, src, dst);
}

/// Encodes a row of linear pixels into interleaved RGB bytes (`dst.len() == 3 * src.len()`).
pub fn encode_row_rgb(src: &[Vec3], dst: &mut [u8]) {
    assert_eq!(src.len() * 3, dst.len(), "sRGB row: {} pixels into {} bytes", src.len(), dst.len());
    let t = table();
    #[cfg(target_arch = "x86_64")]
    if avx2::available() {
        // SAFETY: the CPU has AVX2 and the lengths match (checked above).
        let done = unsafe { avx2::rows_rgb(t, src, dst) };
        encode_row_rgb_generic(t, &src[done..], &mut dst[3 * done..]);
        return;
    }
    encode_row_rgb_generic(t, src, dst);
}

fn encode_row_rgba_generic(t: &[u32; BUCKETS], src: &[Vec3], dst: &mut [u32]) {
    for (d, c) in dst.iter_mut().zip(src) {
        let (r, g, b) = (encode_with(t, c.x) as u32, encode_with(t, c.y) as u32, encode_with(t, c.z) as u32);
        *d = r | g << 8 | b << 16 | 0xff00_0000;
    }
}

fn encode_row_rgb_generic(t: &[u32; BUCKETS], src: &[Vec3], dst: &mut [u8]) {
    for (d, c) in dst.chunks_exact_mut(3).zip(src) {
        d[0] = encode_with(t, c.x);
        d[1] = encode_with(t, c.y);
        d[2] = encode_with(t, c.z);
    }
}

/// Eight pixels (24 channels) at a time with AVX2: the same clamp, index and comparison as
/// [`encode_with`] on eight lanes, the table read with gathers (about 4x fewer instructions
/// than the scalar loop, which the compiler does not vectorise).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{BUCKETS, LO_BITS, OFFSET_MASK, SHIFT};
    use glam::Vec3;
    use std::arch::x86_64::*;

    pub fn available() -> bool {
        static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *HAS.get_or_init(|| is_x86_feature_detected!("avx2"))
    }

    /// The codes of eight channels, one per 32-bit lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn codes(t: &[u32; BUCKETS], v: __m256) -> __m256i {
        // MAXPS returns its second operand for NaN and for two zeros, so NaN and -0 become
        // +0; after the MINPS every pattern is at most that of 1.0, the index at most
        // BUCKETS - 1 (the gather stays inside the table).
        let x = _mm256_min_ps(_mm256_max_ps(v, _mm256_setzero_ps()), _mm256_set1_ps(1.0));
        let lo = _mm256_set1_epi32(LO_BITS as i32);
        let d = _mm256_sub_epi32(_mm256_max_epu32(_mm256_castps_si256(x), lo), lo);
        // SAFETY (of the gather): every index is below BUCKETS (see above).
        let e = _mm256_i32gather_epi32::<4>(t.as_ptr() as *const i32, _mm256_srli_epi32::<SHIFT_I32>(d));
        let base = _mm256_srli_epi32::<24>(e);
        let boundary = _mm256_and_si256(e, _mm256_set1_epi32(0x00ff_ffff));
        let offset = _mm256_and_si256(d, _mm256_set1_epi32(OFFSET_MASK as i32));
        // -1 where the offset is before the bucket's boundary: code = base + 1 - 1.
        let before = _mm256_cmpgt_epi32(boundary, offset);
        _mm256_add_epi32(_mm256_add_epi32(base, _mm256_set1_epi32(1)), before)
    }
    const SHIFT_I32: i32 = SHIFT as i32;

    /// The 24 codes of eight pixels as bytes, in 4-byte groups: lane 0 holds channels 0-3,
    /// 8-11, 16-19, 16-19 and lane 1 channels 4-7, 12-15, 20-23, 20-23.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn bytes(t: &[u32; BUCKETS], src: *const f32) -> __m256i {
        let a = codes(t, _mm256_loadu_ps(src));
        let b = codes(t, _mm256_loadu_ps(src.add(8)));
        let c = codes(t, _mm256_loadu_ps(src.add(16)));
        _mm256_packus_epi16(_mm256_packus_epi32(a, b), _mm256_packus_epi32(c, c))
    }

    /// Encodes the longest multiple of eight pixels of `src` into `dst` (3 bytes each);
    /// returns how many pixels it did.
    ///
    /// # Safety
    /// The CPU must have AVX2 and `dst.len() >= 3 * src.len()`.
    #[target_feature(enable = "avx2")]
    pub unsafe fn rows_rgb(t: &[u32; BUCKETS], src: &[Vec3], dst: &mut [u8]) -> usize {
        let n = src.len() / 8 * 8;
        // Groups in channel order: 0-3, 4-7, 8-11, 12-15, 16-19, 20-23.
        let order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
        let (s, d) = (src.as_ptr() as *const f32, dst.as_mut_ptr());
        for i in (0..n).step_by(8) {
            let v = _mm256_permutevar8x32_epi32(bytes(t, s.add(3 * i)), order);
            _mm_storeu_si128(d.add(3 * i) as *mut __m128i, _mm256_castsi256_si128(v));
            _mm_storel_epi64(d.add(3 * i + 16) as *mut __m128i, _mm256_extracti128_si256::<1>(v));
        }
        n
    }

    /// Encodes the longest multiple of eight pixels of `src` into packed RGBA words; returns
    /// how many pixels it did.
    ///
    /// # Safety
    /// The CPU must have AVX2 and `dst.len() >= src.len()`.
    #[target_feature(enable = "avx2")]
    pub unsafe fn rows_rgba(t: &[u32; BUCKETS], src: &[Vec3], dst: &mut [u32]) -> usize {
        let n = src.len() / 8 * 8;
        // Lane 0: channels 0-15 (pixels 0-3 and one more); lane 1: channels 12-27.
        let order = _mm256_setr_epi32(0, 4, 1, 5, 5, 2, 6, 6);
        let spread = _mm256_setr_epi8(
            0, 1, 2, -1, 3, 4, 5, -1, 6, 7, 8, -1, 9, 10, 11, -1, 0, 1, 2, -1, 3, 4, 5, -1, 6, 7, 8, -1, 9, 10, 11, -1,
        );
        let alpha = _mm256_set1_epi32(0xff00_0000u32 as i32);
        let (s, d) = (src.as_ptr() as *const f32, dst.as_mut_ptr());
        for i in (0..n).step_by(8) {
            let v = _mm256_permutevar8x32_epi32(bytes(t, s.add(3 * i)), order);
            let px = _mm256_or_si256(_mm256_shuffle_epi8(v, spread), alpha);
            _mm256_storeu_si256(d.add(i) as *mut __m256i, px);
        }
        n
    }
}

#[cfg(test)]
mod tests;
