//! Anti-aliasing of simple pixels, paper 000 §5.3: a simple pixel's colour is the
//! area-weighted mix of its primary and secondary regions' colours. Only the primary colour
//! is interpolated; the secondary colour is approximated by the primary colour of a
//! neighbouring pixel that an edge-indexed table picks ([`super::tables::CellTables::aa_candidates`]:
//! the 4-neighbours whose centres lie on the secondary side of the edge, deepest first).
//!
//! Beyond the paper's table, a candidate is taken only if its primary region is reachable
//! from this pixel's secondary region across their shared side (the neighbour mask's
//! Sc↔Pn bit, already computed for reachability) and it got a colour from samples; the next
//! candidate is tried otherwise.
//!
//! Where no candidate qualifies, the secondary region continues into a neighbour's
//! secondary region (Sc↔Sn across their shared side) whose colour the first step found: the
//! secondary colour is the mean of those. This is the pixel holding the corner of a small
//! region, such as a bright luminaire's corner in the ceiling: its edge crosses two
//! adjacent sides, the corner region holds no neighbour's centre, and the neighbours beside
//! it are split by the same outline with their larger, primary region outside — so the
//! first step finds nothing, and without the second the pixel showed the outside colour
//! alone (on `cornell` two such pixels held a third of the converged image's squared error).
//! Without either, the pixel keeps its primary colour.
//!
//! The pass reads primary colours while it writes mixed ones, so the primary colours of
//! simple pixels (the only ones it changes) are first copied into a compact array in scan
//! order (a pixel's index is the number of simple pixels before it, from a count per
//! 64-pixel word), the first step's secondary colours go into a second compact array, and a
//! last pass, which also takes the second step, writes the mixes into the image: no
//! full-size colour buffer, and no pixel is read after it changed.
use super::reach::{Neighbours, NB_PLANES};
use super::tables::{tables, DIRS, DIR_DOWN, DIR_LEFT, DIR_RIGHT, DIR_UP, PS, SP, SS};
use super::{EpiPixel, Flags};
use glam::Vec3;
use rayon::prelude::*;

/// Primary and secondary colours of the simple pixels, in scan order.
#[derive(Default)]
pub struct SimpleColours {
    /// Per (row, word): index of the word's first simple pixel in the colour arrays.
    rank: Vec<u32>,
    primary: Vec<Vec3>,
    /// The first step's secondary colour; [`NONE`] where it found none.
    secondary: Vec<Vec3>,
}

/// No secondary colour (a neighbour's non-finite colour counts as none either).
const NONE: Vec3 = Vec3::splat(f32::NAN);

/// Splits `buf` into the per-row ranges given by `rank` (row starts at `rank[y * words]`).
fn row_chunks<'a>(buf: &'a mut [Vec3], rank: &[u32], words: usize, h: usize) -> Vec<&'a mut [Vec3]> {
    let total = buf.len();
    let mut rest = buf;
    let mut chunks = Vec::with_capacity(h);
    for y in 0..h {
        let end = if y + 1 < h { rank[(y + 1) * words] as usize } else { total };
        let (row, tail) = std::mem::take(&mut rest).split_at_mut(end - rank[y * words] as usize);
        chunks.push(row);
        rest = tail;
    }
    chunks
}

/// The columns of row `y`'s simple pixels, in scan order (their compact indices follow
/// from the row's first, `rank[y * words]`).
#[inline(always)]
fn simple_in_row(flags: &Flags, y: usize) -> impl Iterator<Item = usize> + '_ {
    flags.row(y, Flags::SIMPLE).iter().enumerate().flat_map(|(j, &word)| {
        let mut bits = word;
        std::iter::from_fn(move || {
            (bits != 0).then(|| {
                let i = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                64 * j + i
            })
        })
    })
}

impl SimpleColours {
    /// Bytes at most, for a `width` × `height` image: the ranks, and two colours per simple
    /// pixel if every pixel were simple (they grow to the frame with the most).
    pub fn bytes_for(width: usize, height: usize) -> usize {
        4 * height * width.div_ceil(64) + 2 * std::mem::size_of::<Vec3>() * width * height
    }

    /// Bytes of the ranks: 4 per 64 pixels.
    pub fn rank_bytes(&self) -> usize {
        self.rank.capacity() * 4
    }

    /// Bytes of the colours: 24 per simple pixel (of the frame with the most).
    pub fn colour_bytes(&self) -> usize {
        (self.primary.capacity() + self.secondary.capacity()) * 12
    }

    /// Ranks the simple pixels and copies their primary colours out of `image`.
    fn gather(&mut self, flags: &Flags, image: &[Vec3]) {
        let (w, h, words) = (flags.width, flags.height, flags.words);
        self.rank.resize(h * words, 0);
        let mut total = 0u32;
        for y in 0..h {
            let row = flags.row(y, Flags::SIMPLE);
            for (rank, word) in self.rank[y * words..(y + 1) * words].iter_mut().zip(row) {
                *rank = total;
                total += word.count_ones();
            }
        }
        self.primary.resize(total as usize, Vec3::ZERO);
        self.secondary.resize(total as usize, NONE);
        row_chunks(&mut self.primary, &self.rank, words, h).into_par_iter().enumerate().for_each(|(y, out)| {
            for (o, x) in out.iter_mut().zip(simple_in_row(flags, y)) {
                *o = image[y * w + x];
            }
        });
    }
}

/// Anti-aliases the simple pixels of `image`; returns how many took a secondary colour.
pub fn antialias(pixels: &[EpiPixel], flags: &Flags, filled: &[u64], nb: &Neighbours, simple: &mut SimpleColours, image: &mut [Vec3]) -> u32 {
    let (w, h, words) = (flags.width, flags.height, flags.words);
    if w == 0 || h == 0 {
        return 0;
    }
    simple.gather(flags, image);
    let t = tables();
    let nb_bit = |y: usize, x: usize, plane: usize| (nb.planes[(y * NB_PLANES + plane) * words + x / 64] >> (x % 64)) & 1 == 1;
    let filled_at = |x: usize, y: usize| (filled[y * words + x / 64] >> (x % 64)) & 1 == 1;
    let is_simple = |x: usize, y: usize| (flags.row(y, Flags::SIMPLE)[x / 64] >> (x % 64)) & 1 == 1;
    let plane_of = |mask_bit: u8| mask_bit.trailing_zeros() as usize;
    // Whether the region `from` of pixel (x, y) (a mask bit of the pair: SP for Sc↔Pn, SS
    // for Sc↔Sn) meets its neighbour's in direction `d` across their shared side. The
    // masks are stored for the right and down neighbours; a left or up neighbour's mask
    // seen from this pixel is the transpose of its own.
    let meets = |x: usize, y: usize, d: usize, bit: u8| {
        let (dx, dy) = DIRS[d];
        let (nx, ny) = (x as i64 + dx as i64, y as i64 + dy as i64);
        if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
            return None;
        }
        let (nx, ny) = (nx as usize, ny as usize);
        let transposed = match bit {
            SP => PS,
            b => b,
        };
        let ok = match d {
            DIR_RIGHT => nb_bit(y, x, plane_of(bit)),
            DIR_LEFT => nb_bit(y, nx, plane_of(transposed)),
            DIR_DOWN => nb_bit(y, x, 4 + plane_of(bit)),
            _ => {
                debug_assert_eq!(d, DIR_UP);
                nb_bit(ny, x, 4 + plane_of(transposed))
            }
        };
        ok.then_some((nx, ny))
    };
    let SimpleColours { rank, primary, secondary } = simple;
    let (rank, primary, img) = (&*rank, &*primary, &*image);
    let index = |x: usize, y: usize| {
        let (j, i) = (x / 64, x % 64);
        rank[y * words + j] as usize + (flags.row(y, Flags::SIMPLE)[j] & ((1u64 << i) - 1)).count_ones() as usize
    };
    // First step, into the compact array (reading the primary copies and the unchanged
    // non-simple pixels of the image): the primary colour of the first candidate whose
    // primary region this pixel's secondary region meets.
    row_chunks(secondary, rank, words, h).into_par_iter().enumerate().for_each(|(y, out)| {
        for (o, x) in out.iter_mut().zip(simple_in_row(flags, y)) {
            let p = pixels[y * w + x];
            *o = NONE;
            for d in t.pixel.aa_candidates(p.code(), !p.primary_b()) {
                if d == 0xFF {
                    break;
                }
                let Some((nx, ny)) = meets(x, y, d as usize, SP) else { continue };
                if !filled_at(nx, ny) {
                    continue;
                }
                let c = if is_simple(nx, ny) { primary[index(nx, ny)] } else { img[ny * w + nx] };
                if c.is_finite() {
                    *o = c;
                    break;
                }
            }
        }
    });
    // Second step and the mixes, into the image (which no longer needs to be read): a pixel
    // without a secondary colour takes the mean of the first step's secondary colours of the
    // neighbours whose secondary region its own meets.
    let secondary = &*secondary;
    image
        .par_chunks_mut(w)
        .enumerate()
        .map(|(y, row)| {
            let mut mixed = 0u32;
            for (k, x) in simple_in_row(flags, y).enumerate() {
                let n = rank[y * words] as usize + k;
                let p = pixels[y * w + x];
                let own = primary[n];
                let mut second = secondary[n];
                if second.x.is_nan() {
                    let (mut sum, mut count) = (Vec3::ZERO, 0.0f32);
                    for d in 0..4 {
                        let Some((nx, ny)) = meets(x, y, d, SS) else { continue };
                        // Sc↔Sn holds only for a simple neighbour (checked, as the index
                        // assumes it).
                        if !is_simple(nx, ny) {
                            continue;
                        }
                        let c = secondary[index(nx, ny)];
                        if !c.x.is_nan() {
                            sum += c;
                            count += 1.0;
                        }
                    }
                    if count > 0.0 {
                        second = sum / count;
                    }
                }
                row[x] = if second.x.is_nan() {
                    own
                } else {
                    let area_a = t.pixel.area_a(p.code());
                    let primary_area = if p.primary_b() { 1.0 - area_a } else { area_a };
                    mixed += 1;
                    own * primary_area + second * (1.0 - primary_area)
                };
            }
            mixed
        })
        .sum()
}

#[cfg(test)]
mod tests;
