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
//! The mix's areas are exact where the rasterizer recorded the crossings' fine positions
//! ([`Boundaries::fine`]), not those of the quantised edge between the centres of the two
//! crossed eighths (§4.2): on a long, nearly horizontal edge every pixel's crossings lie in
//! the same eighths, so the quantised area is off by the same amount along the whole run
//! (up to 1/16 of the pixel; the luminaire's upper edge on `cornell` held a quarter of the
//! converged image's squared error). The edge is the line between the two exact crossings;
//! in a pixel holding a segment end ([`Boundaries::holds_end`]) it is two lines meeting
//! inside it, each continuing its neighbour's edge (the line from the shared crossing to the
//! neighbour's other one, from a simple neighbour without a segment end), when they meet
//! inside the pixel: a rectangle's corner, whose area the one line (a triangle) halves. Only
//! the areas change: which neighbours give the secondary colour stays with the codes.
//!
//! The pass reads primary colours while it writes mixed ones, so the primary colours of
//! simple pixels (the only ones it changes) are first copied into a compact array in scan
//! order (a pixel's index is the number of simple pixels before it, from a count per
//! 64-pixel word), the first step's secondary colours go into a second compact array, and a
//! last pass, which also takes the second step, writes the mixes into the image: no
//! full-size colour buffer, and no pixel is read after it changed.
use super::code::{BOTTOM, PIXEL, RIGHT, TOP};
use super::raster::{fine_fraction, Boundaries};
use super::reach::{Neighbours, NB_PLANES};
use super::tables::{tables, DIRS, DIR_DOWN, DIR_LEFT, DIR_RIGHT, DIR_UP, PS, SIDE_A, SIDE_B, SP, SS};
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

/// Where the crossing at perimeter index `e` of pixel (x, y) lies in its unit square: in
/// the eighth `e` names, at the fine position within it (a simple pixel's crossing is the
/// only one on its side); `None` without fine positions.
#[inline]
fn crossing(bounds: &Boundaries, x: usize, y: usize, e: u32) -> Option<[f32; 2]> {
    let (side, pos) = (e / PIXEL.segments, e % PIXEL.segments);
    let t = fine_fraction(pos << 8 | bounds.fine_at(x, y, side)?);
    Some(match side {
        TOP => [t, 0.0],
        RIGHT => [1.0, t],
        BOTTOM => [t, 1.0],
        _ => [0.0, t],
    })
}

/// Perimeter side → the neighbour across it.
const SIDE_DIR: [usize; 4] = [DIR_UP, DIR_RIGHT, DIR_DOWN, DIR_LEFT];

/// `orient(p, q, r) > 0`: `r` on side A of the directed line `p → q` (as the tables'
/// [`super::tables::orient`]).
#[inline]
fn orient(p: [f32; 2], q: [f32; 2], r: [f32; 2]) -> f32 {
    (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
}

/// Area of side A of the chord from `p` on side `sp` to `q` on side `sq > sp` of the unit
/// square (closed form of [`super::tables::side_a_area`]): the polygon `p`, the corners
/// passed going clockwise from `p`'s side to `q`'s (at least one, the sides differing), `q`.
#[inline]
fn chord_area_a(p: [f32; 2], sp: u32, q: [f32; 2], sq: u32) -> f32 {
    // The corner at the end of each side, clockwise (top → right → bottom → left).
    const CORNER: [[f32; 2]; 4] = [[1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0]];
    let cross = |u: [f32; 2], v: [f32; 2]| u[0] * v[1] - v[0] * u[1];
    let mut twice = cross(q, p);
    let mut last = p;
    for c in &CORNER[sp as usize..sq as usize] {
        twice += cross(last, *c);
        last = *c;
    }
    twice += cross(last, q);
    let area = 0.5 * twice.abs();
    if orient(p, q, CORNER[sp as usize]) > 0.0 {
        area
    } else {
        1.0 - area
    }
}

/// Area of side A (as the code's tables orient it) of simple pixel (x, y)'s exact edge, from
/// the fine positions of its crossings (see the module's comment); `None` without them.
fn exact_area_a(bounds: &Boundaries, pixels: &[EpiPixel], x: usize, y: usize, code: u16) -> Option<f32> {
    let (w, h) = (bounds.width, bounds.height);
    let (a, b) = PIXEL.ends(code);
    let (p, q) = (crossing(bounds, x, y, a)?, crossing(bounds, x, y, b)?);
    let chord = chord_area_a(p, a / PIXEL.segments, q, b / PIXEL.segments);
    if !bounds.holds_end(x, y) {
        return Some(chord);
    }
    // The line continuing the neighbour's edge across the side of crossing `e` at `at`: a
    // point of it beyond the side, in this pixel's coordinates.
    let beyond = |e: u32, at: [f32; 2]| -> Option<[f32; 2]> {
        let side = e / PIXEL.segments;
        let (dx, dy) = DIRS[SIDE_DIR[side as usize]];
        let (nx, ny) = (x as i64 + dx as i64, y as i64 + dy as i64);
        if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
            return None;
        }
        let (nx, ny) = (nx as usize, ny as usize);
        let n = pixels[ny * w + nx];
        if !n.is_simple() || bounds.holds_end(nx, ny) {
            return None;
        }
        // The neighbour's end on the shared side is this crossing; its other end:
        let (na, nb) = PIXEL.ends(n.code());
        let shared = (side + 2) % 4;
        let far = if na / PIXEL.segments == shared { nb } else { na };
        let f = crossing(bounds, nx, ny, far)?;
        let f = [f[0] + dx as f32, f[1] + dy as f32];
        (f != at).then_some(f)
    };
    let (Some(fp), Some(fq)) = (beyond(a, p), beyond(b, q)) else { return Some(chord) };
    // Where the line p–fp meets the line q–fq.
    let (d1, d2) = ([p[0] - fp[0], p[1] - fp[1]], [q[0] - fq[0], q[1] - fq[1]]);
    let det = d1[0] * d2[1] - d1[1] * d2[0];
    if det.abs() <= 1e-6 * (d1[0].hypot(d1[1]) * d2[0].hypot(d2[1])) {
        return Some(chord);
    }
    let s = ((q[0] - p[0]) * d2[1] - (q[1] - p[1]) * d2[0]) / det;
    let corner = [p[0] + s * d1[0], p[1] + s * d1[1]];
    if !(0.0..=1.0).contains(&corner[0]) || !(0.0..=1.0).contains(&corner[1]) {
        return Some(chord);
    }
    // The outline p → corner → q bends into side A by the triangle (p, q, corner) where
    // the corner lies on side A of p → q (orient > 0), and out of it otherwise.
    Some((chord - 0.5 * orient(p, q, corner)).clamp(0.0, 1.0))
}

/// How far from a simple pixel's edge, in pixels, two positions must both lie for
/// [`super::Epi::same_side_of_edge`] to put them on one side. The edge is the projection of
/// the scene's to f32 rounding (about 1e-6 pixel at 512²) and its crossings are stored to
/// 1/2048 pixel: a sample within this of it may belong to the other side.
const SIDE_MARGIN: f32 = 1.0 / 256.0;

impl super::Epi {
    /// Whether positions `a` and `b` of pixel (x, y), in its unit square, lie in one region
    /// of it as far as the edge-and-point image knows: anywhere in a pixel no edge crosses,
    /// on one side of a simple pixel's edge ([`Self::same_side_of_edge`]), never in a
    /// complex pixel. Converging at rest uses it to average a sample taken anywhere in a
    /// point's region into that point (`sampling::aim_at_points`).
    pub fn same_region(&self, x: usize, y: usize, a: [f32; 2], b: [f32; 2]) -> bool {
        if self.flags.get(x, y, super::Flags::COMPLEX) {
            false
        } else if self.flags.get(x, y, super::Flags::SIMPLE) {
            self.same_side_of_edge(x, y, a, b)
        } else {
            true
        }
    }

    /// Whether positions `a` and `b` of pixel (x, y), in its unit square, lie on one side of
    /// its edge: for a simple pixel whose crossings have fine positions and which holds no
    /// segment end (its edge one straight line between the crossings), both at least
    /// [`SIDE_MARGIN`] from the line on the same side; false for any other pixel. A point
    /// averaging samples from its side tends to that side's mean, which the anti-aliasing
    /// mixes by the side's exact area.
    fn same_side_of_edge(&self, x: usize, y: usize, a: [f32; 2], b: [f32; 2]) -> bool {
        if x >= self.width || y >= self.height || self.bounds.holds_end(x, y) {
            return false;
        }
        let px = self.pixels[y * self.width + x];
        if !px.is_simple() {
            return false;
        }
        let (ea, eb) = PIXEL.ends(px.code());
        let (Some(p), Some(q)) = (crossing(&self.bounds, x, y, ea), crossing(&self.bounds, x, y, eb)) else {
            return false;
        };
        let len = (q[0] - p[0]).hypot(q[1] - p[1]);
        if !(len > 0.0) {
            return false;
        }
        let (da, db) = (orient(p, q, a) / len, orient(p, q, b) / len);
        (da > SIDE_MARGIN && db > SIDE_MARGIN) || (da < -SIDE_MARGIN && db < -SIDE_MARGIN)
    }
}

/// The regions of a simple pixel (code `code`) whose sample would lie on its secondary
/// side (the side its primary region is not: B's other side when `primary_b`), as a bit per
/// region of [`PIXEL`]: a sample in one of them is usable there, not edge-ambiguous.
pub fn secondary_regions(code: u16, primary_b: bool) -> u16 {
    let t = tables();
    let want = if primary_b { SIDE_A } else { SIDE_B };
    (0..PIXEL.region_count() as u32).filter(|&r| t.pixel.side(code, r) == want).fold(0, |m, r| m | 1 << r)
}

/// Anti-aliases the simple pixels of `image`; returns how many took a secondary colour.
///
/// `starved` (bit rows like `filled`) gets the simple pixels whose secondary region found no
/// colour — no neighbour's primary region it meets was filled, nor a neighbour's secondary
/// region that found one — though a sample could land there usable
/// ([`secondary_regions`]): the pixel shows its primary colour alone, and a region thinner
/// than a pixel along an edge (a box's side seen edge-on, 1 px wide) vanishes wherever no
/// sample reached it. Sampling picks these pixels and aims into that region
/// ([`super::Epi::secondary_position`]), as it does for pixels no sample reaches (beyond
/// the paper, whose priority looks at the primary region's weight only).
#[allow(clippy::too_many_arguments)] // the EPI's parts it reads, and the two outputs
pub fn antialias(pixels: &[EpiPixel], bounds: &Boundaries, flags: &Flags, filled: &[u64], nb: &Neighbours, simple: &mut SimpleColours, image: &mut [Vec3], starved: &mut [u64]) -> u32 {
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
        .zip(starved.par_chunks_mut(words))
        .enumerate()
        .map(|(y, (row, starved))| {
            starved.fill(0);
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
                    if secondary_regions(p.code(), p.primary_b()) != 0 {
                        starved[x / 64] |= 1 << (x % 64);
                    }
                    own
                } else {
                    let area_a = exact_area_a(bounds, pixels, x, y, p.code()).unwrap_or_else(|| t.pixel.area_a(p.code()));
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
