//! Reachability in the 5 × 5 neighbourhood, paper 000 §5.2.
//!
//! Per pixel `c` and each other pixel `p` of its 5 × 5 window, the 4-bit mask
//! (Pc↔Pp, Pc↔Sp, Sc↔Pp, Sc↔Sp) is the OR over the "reasonably direct" paths from `c` to
//! `p` of the chained neighbour masks along the path. The paths are the monotone lattice
//! paths (DESIGN.md "Reachability paths"): the predecessors of `p = (dx, dy)` are its
//! 4-neighbours one step closer to `c`, and the mask of `p` is
//! `OR over predecessors q of chain(c↔q, q↔p)`, propagated outward from the centre with
//! the neighbour table (`q↔p` across their shared side) and the chaining table. Complex
//! pixels have all-zero neighbour masks, so they are unreachable and cut every path
//! through them.
//!
//! Only primary-to-primary reachability is kept: 24 bits per pixel. Reachability along
//! monotone paths is exactly symmetric (a reversed monotone path is monotone, and chaining
//! along it gives the transposed mask), so only the 12 offsets after the centre in scan
//! order — (1, 0), (2, 0) and the two rows below — are computed; the other 12 bits of a
//! pixel are read from the pixels before it, on earlier scanlines or earlier in its own
//! ([`Reach::bits`]). The tests check the symmetry and the whole computation against a
//! brute-force flood fill over the regions along every monotone path of random EPIs.
//!
//! The computation is bit-sliced: every mask bit of 64 consecutive pixels of a row lives in
//! one `u64`, so one chaining (12 bitwise operations) serves 64 pixels and a neighbour
//! offset is a funnel shift. The table lookups happen once per pixel pair (right and down
//! neighbour masks, [`Neighbours`]); the propagation is then pure bitwise work, the same
//! for pixels near edges and far from them. This replaced the paper's per-pixel table
//! chaining after measuring both (see the bench `epi`).
use super::code::EpiPixel;
use super::tables::{tables, Tables, DIR_DOWN, DIR_RIGHT};
use super::Flags;
use rayon::prelude::*;

pub mod scalar;

/// Number of neighbour-mask planes per row: right PP, PS, SP, SS, then down PP, PS, SP, SS.
pub const NB_PLANES: usize = 8;
/// Number of stored reachability planes per row (the offsets after the centre).
pub const REACH_PLANES: usize = 12;

/// Offset `(dx, dy)` of window index `k = 5 * (dy + 2) + (dx + 2)` (0..25, centre 12).
#[inline]
pub const fn offset(k: usize) -> (i32, i32) {
    ((k % 5) as i32 - 2, (k / 5) as i32 - 2)
}

/// Bit of window index `k` (not the centre) in a 24-bit mask.
#[inline]
pub const fn mask_bit(k: usize) -> u32 {
    if k < 12 {
        k as u32
    } else {
        k as u32 - 1
    }
}

/// Bits `64 j + dx ..` of a bit row (zero outside the row): bit `i` of the result is bit
/// `64 j + i + dx` of `row`. `dx` in -63..=63.
#[inline(always)]
pub fn shifted(row: &[u64], j: usize, dx: i32) -> u64 {
    funnel(around(row, j), dx)
}

/// Word `j` of a bit row and its two neighbours (zeros outside the row).
#[inline(always)]
pub fn around(row: &[u64], j: usize) -> [u64; 3] {
    [if j > 0 { row[j - 1] } else { 0 }, row[j], if j + 1 < row.len() { row[j + 1] } else { 0 }]
}

/// Bit `i` of the result is bit `i + dx` of the middle word of `[a, b, c]` (from its
/// neighbours past the ends); `dx` in -63..=63.
#[inline(always)]
pub fn funnel([a, b, c]: [u64; 3], dx: i32) -> u64 {
    if dx == 0 {
        b
    } else if dx > 0 {
        (b >> dx) | (c << (64 - dx))
    } else {
        (b << -dx) | (a >> (64 + dx))
    }
}

/// The right and down neighbour masks of every pixel, as bit planes.
pub struct Neighbours {
    pub width: usize,
    pub height: usize,
    /// Words per plane row.
    pub words: usize,
    /// `planes[(y * NB_PLANES + p) * words + j]`.
    pub planes: Vec<u64>,
}

/// Four bit planes of 4-bit masks (PP, PS, SP, SS) for 64 pixels.
#[derive(Clone, Copy, Default)]
struct M4([u64; 4]);

impl M4 {
    #[inline(always)]
    fn chain(self, b: M4) -> M4 {
        let [pp, ps, sp, ss] = self.0;
        let [bpp, bps, bsp, bss] = b.0;
        M4([pp & bpp | ps & bsp, pp & bps | ps & bss, sp & bpp | ss & bsp, sp & bps | ss & bss])
    }

    #[inline(always)]
    fn or(self, b: M4) -> M4 {
        M4([self.0[0] | b.0[0], self.0[1] | b.0[1], self.0[2] | b.0[2], self.0[3] | b.0[3]])
    }

    #[inline(always)]
    fn transpose(self) -> M4 {
        M4([self.0[0], self.0[2], self.0[1], self.0[3]])
    }
}

impl Neighbours {
    /// Bytes of the neighbour masks of a `width` × `height` image.
    pub fn bytes_for(width: usize, height: usize) -> usize {
        8 * height * NB_PLANES * width.div_ceil(64)
    }

    pub fn new(width: usize, height: usize) -> Self {
        let words = width.div_ceil(64);
        Neighbours { width, height, words, planes: vec![0; height * NB_PLANES * words] }
    }

    pub fn bytes(&self) -> usize {
        self.planes.len() * 8
    }

    /// Computes every pixel's right and down neighbour masks with the neighbour tables.
    /// Words whose pixels and neighbours are all empty take the all-PP fast path.
    pub fn compute(&mut self, pixels: &[EpiPixel], flags: &Flags) {
        let (w, h, words) = (self.width, self.height, self.words);
        if w == 0 || h == 0 {
            return;
        }
        self.planes.par_chunks_mut(NB_PLANES * words).enumerate().for_each(|(y, out)| neighbour_row(pixels, flags, w, h, y, out));
    }

    /// Plane `p` of row `y` (which must be in the image).
    #[inline(always)]
    fn row(&self, y: usize, p: usize) -> &[u64] {
        let s = (y * NB_PLANES + p) * self.words;
        &self.planes[s..s + self.words]
    }
}

/// Row `y` of the neighbour planes.
#[inline(never)]
fn neighbour_row(pixels: &[EpiPixel], flags: &Flags, w: usize, h: usize, y: usize, out: &mut [u64]) {
    let t = tables();
    let words = w.div_ceil(64);
    let nonempty = |yy: usize, j: usize| flags.row(yy, Flags::SIMPLE)[j] | flags.row(yy, Flags::COMPLEX)[j];
    let has_down = y + 1 < h;
    for j in 0..words {
        let valid = valid_word(w, j as i64);
        // Pixels with a right / down neighbour in the image.
        let right_valid = valid & (valid_word(w, j as i64 + 1) << 63 | valid >> 1);
        let down_valid = if has_down { valid } else { 0 };
        // Two empty neighbours meet primary to primary: set in bulk. Only pairs with an edge
        // in either pixel go through the table.
        let here = nonempty(y, j);
        let right = here >> 1 | if j + 1 < words { nonempty(y, j + 1) << 63 } else { 0 };
        let down = if has_down { nonempty(y + 1, j) } else { 0 };
        let (h_busy, v_busy) = ((here | right) & right_valid, (here | down) & down_valid);
        let mut acc = [0u64; NB_PLANES];
        acc[0] = right_valid & !h_busy;
        acc[4] = down_valid & !v_busy;
        let x0 = 64 * j;
        let mut bits = h_busy;
        while bits != 0 {
            let i = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let x = x0 + i;
            let m = t.neighbour(DIR_RIGHT, class4(t, pixels[y * w + x]), class4(t, pixels[y * w + x + 1]));
            for (b, a) in acc[..4].iter_mut().enumerate() {
                *a |= u64::from((m >> b) & 1) << i;
            }
        }
        let mut bits = v_busy;
        while bits != 0 {
            let i = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let x = x0 + i;
            let m = t.neighbour(DIR_DOWN, class4(t, pixels[y * w + x]), class4(t, pixels[(y + 1) * w + x]));
            for (b, a) in acc[4..].iter_mut().enumerate() {
                *a |= u64::from((m >> b) & 1) << i;
            }
        }
        for (p, a) in acc.into_iter().enumerate() {
            out[p * words + j] = a;
        }
    }
}

/// 4-bit neighbour code of a pixel.
#[inline(always)]
pub fn class4(t: &Tables, p: EpiPixel) -> u8 {
    t.pixel.class4(p.code(), p.primary_b())
}

/// The stored primary-to-primary reachability: 12 planes per row for the offsets after the
/// centre (window indices 13..25, in that order).
pub struct Reach {
    pub width: usize,
    pub height: usize,
    pub words: usize,
    /// `planes[(y * REACH_PLANES + (k - 13)) * words + j]`.
    pub planes: Vec<u64>,
}

impl Reach {
    /// Bytes of the reachability masks of a `width` × `height` image.
    pub fn bytes_for(width: usize, height: usize) -> usize {
        8 * height * REACH_PLANES * width.div_ceil(64)
    }

    pub fn new(width: usize, height: usize) -> Self {
        let words = width.div_ceil(64);
        Reach { width, height, words, planes: vec![0; height * REACH_PLANES * words] }
    }

    pub fn bytes(&self) -> usize {
        self.planes.len() * 8
    }

    /// Propagates reachability outward from every pixel (see the module doc).
    pub fn compute(&mut self, nb: &Neighbours, flags: &Flags) {
        let words = self.words;
        if words == 0 {
            return;
        }
        self.planes.par_chunks_mut(REACH_PLANES * words).enumerate().for_each(|(y, out)| reach_row(nb, flags, y, out));
    }

    /// Stored plane for window index `k` (13..25) of row `y`.
    #[inline(always)]
    pub fn stored(&self, y: usize, k: usize) -> &[u64] {
        let s = (y * REACH_PLANES + (k - 13)) * self.words;
        &self.planes[s..s + self.words]
    }

    /// Primary-to-primary reachability from the 64 pixels of word `j` of row `y` to the
    /// pixel at window index `k` from each (`k = 12`, the pixel itself: all ones). Offsets
    /// before the centre come from the pixel they point to, by symmetry.
    #[inline(always)]
    pub fn bits(&self, y: usize, j: usize, k: usize) -> u64 {
        if k == 12 {
            return !0;
        }
        if k > 12 {
            return self.stored(y, k)[j];
        }
        let (dx, dy) = offset(k);
        let yy = y as i64 + dy as i64;
        if yy < 0 {
            return 0;
        }
        shifted(self.stored(yy as usize, 24 - k), j, dx)
    }

    /// [`Self::bits`] of every window index `k` (0..25) of word `j` of row `y`, without
    /// a branch on the offset (the interpolation reads all 25 for each word).
    #[inline(always)]
    pub fn window(&self, y: usize, j: usize) -> [u64; 25] {
        let words = self.words;
        let mut out = [0u64; 25];
        out[12] = !0;
        let here = &self.planes[y * REACH_PLANES * words..][..REACH_PLANES * words];
        for (l, o) in out[13..].iter_mut().enumerate() {
            *o = here[l * words + j];
        }
        // Before the centre: the reversed offset (window index 24 - k), stored by the pixel
        // pointed to, in the row two above (k = 0..5), one above (k = 5..10) or this one
        // (k = 10, 11). Written out offset by offset: shifts by constants, no division by 5.
        let plane = |dy: usize, k: usize| -> [u64; 3] {
            let Some(yy) = y.checked_sub(dy) else { return [0; 3] };
            around(&self.planes[(yy * REACH_PLANES + 24 - k - 13) * words..][..words], j)
        };
        out[0] = funnel(plane(2, 0), -2);
        out[1] = funnel(plane(2, 1), -1);
        out[2] = funnel(plane(2, 2), 0);
        out[3] = funnel(plane(2, 3), 1);
        out[4] = funnel(plane(2, 4), 2);
        out[5] = funnel(plane(1, 5), -2);
        out[6] = funnel(plane(1, 6), -1);
        out[7] = funnel(plane(1, 7), 0);
        out[8] = funnel(plane(1, 8), 1);
        out[9] = funnel(plane(1, 9), 2);
        out[10] = funnel(plane(0, 10), -2);
        out[11] = funnel(plane(0, 11), -1);
        out
    }

    /// The 24-bit primary-to-primary mask of pixel (x, y) (bit [`mask_bit`]`(k)` for window
    /// index `k`).
    pub fn mask24(&self, x: usize, y: usize) -> u32 {
        let (j, i) = (x / 64, x % 64);
        let mut m = 0;
        for k in (0..25).filter(|&k| k != 12) {
            m |= (((self.bits(y, j, k) >> i) & 1) as u32) << mask_bit(k);
        }
        m
    }
}

/// Bits of the pixels of word `j` (possibly outside the row) that lie in a row `w` wide.
#[inline(always)]
fn valid_word(w: usize, j: i64) -> u64 {
    if j < 0 || 64 * j as usize >= w {
        0
    } else if 64 * (j as usize + 1) <= w {
        !0
    } else {
        (1u64 << (w - 64 * j as usize)) - 1
    }
}

/// Whether no pixel of rows `y ..= y + 2`, words `j - 1 ..= j + 1`, has an edge: then every
/// pixel of word `j` reaches every pixel of its window that is in the image.
#[inline(always)]
fn quiet(flags: &Flags, y: usize, j: usize) -> bool {
    let (lo, hi) = (j.saturating_sub(1), (j + 1).min(flags.words - 1));
    (y..(y + 3).min(flags.height)).all(|yy| {
        let (s, c) = (flags.row(yy, Flags::SIMPLE), flags.row(yy, Flags::COMPLEX));
        (lo..=hi).all(|jj| s[jj] | c[jj] == 0)
    })
}

/// Computes row `y` of the stored planes.
#[inline(never)]
fn reach_row(nb: &Neighbours, flags: &Flags, y: usize, out: &mut [u64]) {
    let (w, h, words) = (nb.width, nb.height, nb.words);
    for j in 0..words {
        let planes = if quiet(flags, y, j) {
            // Window indices 13..25 in order: offsets (dx, dy).
            std::array::from_fn(|l| {
                let (dx, dy) = offset(13 + l);
                if y + dy as usize >= h {
                    return 0;
                }
                let (a, b, c) = (valid_word(w, j as i64 - 1), valid_word(w, j as i64), valid_word(w, j as i64 + 1));
                // Both the centre and the pixel it reaches in the image.
                funnel([a, b, c], dx) & b
            })
        } else {
            propagate(&Window::load(nb, y, j))
        };
        for (l, p) in planes.into_iter().enumerate() {
            out[l * words + j] = p;
        }
    }
}

/// The neighbour planes of rows `y ..= y + 2` around word `j`: `[row][plane][word j-1, j, j+1]`
/// (zeros outside the image), so that every neighbour offset is a shift of registers.
struct Window([[[u64; 3]; NB_PLANES]; 3]);

impl Window {
    #[inline(always)]
    fn load(nb: &Neighbours, y: usize, j: usize) -> Window {
        let mut win = [[[0u64; 3]; NB_PLANES]; 3];
        for (qy, rows) in win.iter_mut().enumerate() {
            if y + qy >= nb.height {
                break;
            }
            for (p, words) in rows.iter_mut().enumerate() {
                let row = nb.row(y + qy, p);
                *words = [if j > 0 { row[j - 1] } else { 0 }, row[j], if j + 1 < row.len() { row[j + 1] } else { 0 }];
            }
        }
        Window(win)
    }

    /// Masks between each pixel `c + (qx, qy)` and its right neighbour.
    #[inline(always)]
    fn right(&self, qx: i32, qy: usize) -> M4 {
        M4(std::array::from_fn(|b| funnel(self.0[qy][b], qx)))
    }

    /// Masks between each pixel `c + (qx, qy)` and its down neighbour.
    #[inline(always)]
    fn down(&self, qx: i32, qy: usize) -> M4 {
        M4(std::array::from_fn(|b| funnel(self.0[qy][4 + b], qx)))
    }
}

/// The 12 primary-to-primary planes (window indices 13..25) of the 64 centres of a word:
/// monotone-path propagation with bit-sliced chaining.
#[inline(always)]
fn propagate(win: &Window) -> [u64; REACH_PLANES] {
    let r = |qx, qy| win.right(qx, qy);
    let d = |qx, qy| win.down(qx, qy);
    // Moving left from q: the transposed right mask of q's left neighbour.
    let l = |qx: i32, qy| win.right(qx - 1, qy).transpose();
    let m10 = r(0, 0);
    let mm10 = l(0, 0);
    let m20 = m10.chain(r(1, 0));
    let mm20 = mm10.chain(l(-1, 0));
    let m01 = d(0, 0);
    let m11 = m10.chain(d(1, 0)).or(m01.chain(r(0, 1)));
    let mm11 = mm10.chain(d(-1, 0)).or(m01.chain(l(0, 1)));
    let m21 = m20.chain(d(2, 0)).or(m11.chain(r(1, 1)));
    let mm21 = mm20.chain(d(-2, 0)).or(mm11.chain(l(-1, 1)));
    let m02 = m01.chain(d(0, 1));
    let m12 = m11.chain(d(1, 1)).or(m02.chain(r(0, 2)));
    let mm12 = mm11.chain(d(-1, 1)).or(m02.chain(l(0, 2)));
    let m22 = m21.chain(d(2, 1)).or(m12.chain(r(1, 2)));
    let mm22 = mm21.chain(d(-2, 1)).or(mm12.chain(l(-1, 2)));
    // Window indices 13..25: (1,0) (2,0) (-2,1) (-1,1) (0,1) (1,1) (2,1) (-2,2) .. (2,2).
    [m10, m20, mm21, mm11, m01, m11, m21, mm22, mm12, m02, m12, m22].map(|m| m.0[0])
}

#[cfg(test)]
mod tests;
