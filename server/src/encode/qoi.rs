//! A QOI encoder (the "Quite OK Image" format, qoiformat.org, specification 1.0) for RGB
//! frames that can encode horizontal bands of a frame independently, so the bands of one
//! frame are encoded in parallel and joined into one standard stream.
//!
//! Why bands can be encoded apart: a QOI decoder keeps two pieces of state, the previous
//! pixel and a 64-entry index of recently seen pixels. A band's encoder starts from the
//! true previous pixel (the last pixel of the band before it, which is known: the whole
//! frame is at hand) but from an empty index. It only emits `QOI_OP_INDEX` for slots it has
//! itself written during the band, and every such write mirrors the write the decoder
//! makes when it decodes the same pixel, so each slot the encoder uses holds the same pixel
//! in the decoder. A band's trailing run is flushed at its end. The stream is a valid QOI
//! file that any decoder reads exactly; the bands only lose the index hits and runs that
//! would have crossed their boundaries (a few bytes per band).
//!
//! Pixels are packed RGBA words, `r | g << 8 | b << 16 | a << 24`, alpha always 255 (an
//! RGB image in QOI's terms).
pub const HEADER_LEN: usize = 14;
/// The stream's end: seven zero bytes and a one.
pub const END_MARKER: [u8; 8] = [0, 0, 0, 0, 0, 0, 0, 1];
/// The previous pixel a QOI stream starts from: black, opaque.
pub const START_PIXEL: u32 = 0xff00_0000;
/// The most bytes one pixel takes (`QOI_OP_RGB`).
pub const MAX_BYTES_PER_PIXEL: usize = 4;

const OP_INDEX: u8 = 0x00;
const OP_DIFF: u8 = 0x40;
const OP_LUMA: u8 = 0x80;
const OP_RUN: u8 = 0xc0;
const OP_RGB: u8 = 0xfe;
/// Runs are 1..=62 pixels long (63 and 64 would collide with `QOI_OP_RGB(A)`).
const MAX_RUN: u32 = 62;

/// The header of an RGB (3-channel), sRGB-tagged QOI stream.
pub fn header(width: u32, height: u32) -> [u8; HEADER_LEN] {
    let mut h = [0u8; HEADER_LEN];
    h[..4].copy_from_slice(b"qoif");
    h[4..8].copy_from_slice(&width.to_be_bytes());
    h[8..12].copy_from_slice(&height.to_be_bytes());
    h[12] = 3;
    h[13] = 0;
    h
}

/// QOI's index hash, `(3r + 5g + 7b + 11a) % 64`, for alpha 255 (11 * 255 = 53 mod 64).
#[inline(always)]
fn hash(px: u32) -> usize {
    let (r, g, b) = (px & 0xff, (px >> 8) & 0xff, (px >> 16) & 0xff);
    ((r * 3 + g * 5 + b * 7 + 53) & 63) as usize
}

/// `if c { a } else { b }`, compiled to a conditional move: the conditions are data.
#[inline(always)]
fn select(c: bool, a: u32, b: u32) -> u32 {
    std::hint::select_unpredictable(c, a, b)
}

/// A pixel that repeats the previous one: the run grows, and a full run is written.
#[inline(always)]
fn extend_run(buf: &mut [u8], n: &mut usize, run: &mut u32) {
    *run += 1;
    if *run == MAX_RUN {
        buf[*n] = OP_RUN | (MAX_RUN - 1) as u8;
        *n += 1;
        *run = 0;
    }
}

/// Before a pixel that differs from the previous one: the byte ending a pending run,
/// written always and kept only if there is one (no branch).
#[inline(always)]
fn end_run(buf: &mut [u8], n: &mut usize, run: &mut u32) {
    buf[*n] = OP_RUN | run.wrapping_sub(1) as u8;
    *n += (*run > 0) as usize;
    *run = 0;
}

/// The encoder state of one band: previous pixel, index, pending run, and the bytes so far.
///
/// It writes into a buffer from its start, using the buffer's current length as working
/// space (growing it when a band might not fit) so that a buffer kept from frame to frame
/// is neither reallocated nor cleared: [`Self::finish`] says how many bytes are the band's.
pub struct BandEncoder<'a> {
    prev: u32,
    run: u32,
    index: [u32; 64],
    buf: &'a mut Vec<u8>,
    len: usize,
}

impl<'a> BandEncoder<'a> {
    /// Starts a band after the pixel `prev` ([`START_PIXEL`] for the first band), writing
    /// into `buf` from its start.
    pub fn new(prev: u32, buf: &'a mut Vec<u8>) -> Self {
        // 0 never equals a pixel (their alpha is 255), so an empty slot never matches.
        BandEncoder { prev, run: 0, index: [0; 64], buf, len: 0 }
    }

    /// Encodes the next pixels of the band.
    ///
    /// A pixel that repeats the previous one only counts (runs are long enough on rendered
    /// frames for that branch to pay). For any other pixel the op is chosen without
    /// branching: whether it hits the index or takes a difference, luma or full colour op
    /// is close to random, and mispredicted branches cost more than computing every
    /// candidate. The byte ending a pending run is written and the length advanced by 0 or
    /// 1, then the chosen op is written as four bytes and the length advanced by its size.
    pub fn push(&mut self, pixels: &[u32]) {
        // Room for the worst case: four bytes per pixel (a run's byte takes the place of
        // its pixels'), plus the four-byte write of the last op.
        let need = self.len + MAX_BYTES_PER_PIXEL * pixels.len() + 4;
        if self.buf.len() < need {
            self.buf.resize(need, 0);
        }
        let mut rest = pixels;
        #[cfg(target_arch = "x86_64")]
        // (The detection is cached by the standard library.)
        if is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 and the buffer holds the worst case (above).
            let done = unsafe { avx2::push(self, pixels) };
            rest = &pixels[done..];
        }
        self.push_scalar(rest);
    }

    /// [`Self::push`] one pixel at a time; the buffer must already hold the worst case.
    fn push_scalar(&mut self, pixels: &[u32]) {
        let (mut prev, mut run, mut n) = (self.prev, self.run, self.len);
        let index = &mut self.index;
        let buf = &mut self.buf[..];
        for &px in pixels {
            if px == prev {
                extend_run(buf, &mut n, &mut run);
                continue;
            }
            end_run(buf, &mut n, &mut run);

            let h = hash(px);
            let slot = index[h];
            let hit = slot == px;
            index[h] = px;
            let dr = (px as u8).wrapping_sub(prev as u8) as i8;
            let dg = ((px >> 8) as u8).wrapping_sub((prev >> 8) as u8) as i8;
            let db = ((px >> 16) as u8).wrapping_sub((prev >> 16) as u8) as i8;
            // Biased differences: each fits its field exactly when it is in range.
            let (ur, ug, ub) = (dr.wrapping_add(2) as u8 as u32, dg.wrapping_add(2) as u8 as u32, db.wrapping_add(2) as u8 as u32);
            let g = dg.wrapping_add(32) as u8 as u32;
            let rg = dr.wrapping_sub(dg).wrapping_add(8) as u8 as u32;
            let bg = db.wrapping_sub(dg).wrapping_add(8) as u8 as u32;
            let diff = (ur | ug | ub) < 4;
            let luma = (g < 64) & ((rg | bg) < 16);
            let mut word = OP_RGB as u32 | (px & 0x00ff_ffff) << 8;
            let mut size = 4;
            word = select(luma, OP_LUMA as u32 | g | (rg << 4 | bg) << 8, word);
            size = select(luma, 2, size);
            word = select(diff, OP_DIFF as u32 | ur << 4 | ug << 2 | ub, word);
            size = select(diff, 1, size);
            word = select(hit, OP_INDEX as u32 | h as u32, word);
            size = select(hit, 1, size);
            buf[n..n + 4].copy_from_slice(&word.to_le_bytes());
            n += size as usize;
            prev = px;
        }
        self.prev = prev;
        self.run = run;
        self.len = n;
    }

    /// Ends the band (flushes a pending run); returns the band's length in bytes, the
    /// first bytes of the buffer.
    pub fn finish(self) -> usize {
        let mut n = self.len;
        if self.run > 0 {
            if self.buf.len() < n + 1 {
                self.buf.resize(n + 1, 0);
            }
            self.buf[n] = OP_RUN | (self.run - 1) as u8;
            n += 1;
        }
        n
    }
}

/// Eight pixels at a time with AVX2. Everything about a pixel but the index and the run
/// depends only on the pixel and the one before it (the previous pixel of the stream is
/// always the pixel before, runs included), so the hash, the equality with the previous
/// pixel and the difference, luma or full-colour op with its size are computed for eight
/// lanes at once; what is sequential — the index, whose slots the pixels before wrote, and
/// the pending run — stays a short scalar loop over the eight. Eight pixels that all repeat
/// the previous one only lengthen the run. The bytes are those of the scalar loop, op for op
/// (tested against it and against qoi.h's encoder).
#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{end_run, extend_run, select, BandEncoder, MAX_RUN, OP_INDEX};
    use std::arch::x86_64::*;

    /// A constant in every lane.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn c(v: u32) -> __m256i {
        _mm256_set1_epi32(v as i32)
    }

    /// Encodes the longest multiple of eight pixels of `pixels`; returns how many it did.
    ///
    /// # Safety
    /// The CPU must have AVX2, and the encoder's buffer must hold the worst case of these
    /// pixels after its length (four bytes a pixel and four more; [`BandEncoder::push`]).
    #[target_feature(enable = "avx2")]
    pub unsafe fn push(enc: &mut BandEncoder, pixels: &[u32]) -> usize {
        let count = pixels.len() / 8 * 8;
        let (mut run, mut n) = (enc.run, enc.len);
        let index = &mut enc.index;
        let buf = &mut enc.buf[..];
        assert!(buf.len() >= n + 4 * count + 4, "QOI band buffer too small");
        // Each lane's previous pixel: the lanes rotated up by one, lane 0 taking the last
        // pixel of the block before (broadcast in `last`).
        let rotate = _mm256_setr_epi32(7, 0, 1, 2, 3, 4, 5, 6);
        let mut last = _mm256_set1_epi32(enc.prev as i32);
        // QOI's hash weights (3r + 5g + 7b) as bytes for a multiply-add; + 53 is alpha's.
        let weights = _mm256_set1_epi32(i32::from_le_bytes([3, 5, 7, 0]));
        let ones = _mm256_set1_epi16(1);
        // Each lane's green difference in its red, green and blue bytes.
        let green = _mm256_setr_epi8(
            1, 1, 1, -1, 5, 5, 5, -1, 9, 9, 9, -1, 13, 13, 13, -1, 1, 1, 1, -1, 5, 5, 5, -1, 9, 9,
            9, -1, 13, 13, 13, -1,
        );
        let (mut words, mut info) = ([0u32; 8], [0u32; 8]);
        let src = pixels.as_ptr();
        for i in (0..count).step_by(8) {
            let cur = _mm256_loadu_si256(src.add(i) as *const __m256i);
            let prev = _mm256_blend_epi32::<1>(_mm256_permutevar8x32_epi32(cur, rotate), last);
            last = _mm256_permutevar8x32_epi32(cur, c(7));
            let same =
                _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(cur, prev))) as u32;
            if same == 0xff && run + 8 < MAX_RUN {
                run += 8;
                continue;
            }
            let hash = _mm256_and_si256(
                _mm256_add_epi32(
                    _mm256_madd_epi16(_mm256_maddubs_epi16(cur, weights), ones),
                    c(53),
                ),
                c(63),
            );
            let d = _mm256_sub_epi8(cur, prev);
            // Difference op: each biased difference (d + 2) below 4.
            let u = _mm256_add_epi8(d, _mm256_set1_epi8(2));
            let diff =
                _mm256_cmpeq_epi32(_mm256_and_si256(u, c(0x00fc_fcfc)), _mm256_setzero_si256());
            let diff_word = _mm256_or_si256(
                _mm256_or_si256(
                    _mm256_slli_epi32::<4>(_mm256_and_si256(u, c(0x03))),
                    _mm256_and_si256(_mm256_srli_epi32::<6>(u), c(0x0c)),
                ),
                _mm256_or_si256(
                    _mm256_and_si256(_mm256_srli_epi32::<16>(u), c(0x03)),
                    c(0x40),
                ),
            );
            // Luma op: dg + 32 below 64, dr - dg + 8 and db - dg + 8 below 16.
            let gg = _mm256_add_epi8(d, _mm256_set1_epi8(32));
            let e = _mm256_add_epi8(
                _mm256_sub_epi8(d, _mm256_shuffle_epi8(d, green)),
                _mm256_set1_epi8(8),
            );
            let luma = _mm256_cmpeq_epi32(
                _mm256_or_si256(
                    _mm256_and_si256(e, c(0x00f0_00f0)),
                    _mm256_and_si256(gg, c(0x0000_c000)),
                ),
                _mm256_setzero_si256(),
            );
            let luma_word = _mm256_or_si256(
                _mm256_or_si256(
                    _mm256_and_si256(_mm256_srli_epi32::<8>(gg), c(0x3f)),
                    c(0x80),
                ),
                _mm256_or_si256(
                    _mm256_slli_epi32::<12>(_mm256_and_si256(e, c(0x0f))),
                    _mm256_and_si256(_mm256_srli_epi32::<8>(e), c(0x0f00)),
                ),
            );
            // Full colour: the tag and r, g, b (alpha shifts out).
            let rgb_word = _mm256_or_si256(_mm256_slli_epi32::<8>(cur), c(0xfe));
            let word = _mm256_blendv_epi8(
                _mm256_blendv_epi8(rgb_word, luma_word, luma),
                diff_word,
                diff,
            );
            let size = _mm256_blendv_epi8(_mm256_blendv_epi8(c(4), c(2), luma), c(1), diff);
            _mm256_storeu_si256(words.as_mut_ptr() as *mut __m256i, word);
            // The hash in the low byte, the size in the next.
            _mm256_storeu_si256(
                info.as_mut_ptr() as *mut __m256i,
                _mm256_or_si256(hash, _mm256_slli_epi32::<8>(size)),
            );
            for k in 0..8 {
                let px = *src.add(i + k);
                if same >> k & 1 != 0 {
                    extend_run(buf, &mut n, &mut run);
                    continue;
                }
                end_run(buf, &mut n, &mut run);
                let h = (info[k] & 63) as usize;
                let hit = index[h] == px;
                index[h] = px;
                let word = select(hit, OP_INDEX as u32 | h as u32, words[k]);
                let size = select(hit, 1, info[k] >> 8);
                buf[n..n + 4].copy_from_slice(&word.to_le_bytes());
                n += size as usize;
            }
        }
        if count > 0 {
            enc.prev = pixels[count - 1];
        }
        enc.run = run;
        enc.len = n;
        count
    }
}

#[cfg(test)]
mod tests;
