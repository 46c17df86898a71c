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
        let (mut prev, mut run, mut n) = (self.prev, self.run, self.len);
        let index = &mut self.index;
        let buf = &mut self.buf[..need];
        for &px in pixels {
            if px == prev {
                run += 1;
                if run == MAX_RUN {
                    buf[n] = OP_RUN | (MAX_RUN - 1) as u8;
                    n += 1;
                    run = 0;
                }
                continue;
            }
            // The byte ending a pending run, kept only if there is one.
            buf[n] = OP_RUN | run.wrapping_sub(1) as u8;
            n += (run > 0) as usize;
            run = 0;

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

#[cfg(test)]
mod tests;
