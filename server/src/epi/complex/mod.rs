//! The complex-pixel filter, paper 000 §5.4: the crossings of the two centre lines recorded
//! during rasterization cut every pixel into 2 × 2 subpixels whose sides are half pixel
//! sides, still at 1/8-pixel precision. For each complex pixel, its 3 × 3 neighbourhood
//! becomes a 6 × 6 grid of subpixels, each classified and encoded like a pixel
//! ([`super::code::SUBPIXEL`]: 4 segments per side, 2 × 2 sample regions). Reachability is
//! propagated over the grid from each of the complex pixel's four subpixels along monotone
//! paths (the neighbour and chaining tables are the pixels' own: they depend only on
//! topology), and each subpixel region's colour is interpolated from the samples reachable
//! from it. A region that reaches no sample takes the colour of the other region of its
//! subpixel (beyond the paper, which takes the unconstrained interpolation: that is the
//! pixel's own sample when it has one, from whichever region), else the complex pixel's
//! unconstrained colour. The pixel is the area-weighted sum of its subpixel regions.
//!
//! Beyond the paper, for a subpixel that is still complex: where n ≥ 2 edges all run across
//! it between one pair of opposite sides (two close, nearly parallel boundaries — a
//! luminaire 0.5 mm below a ceiling, the two sides of a thin slab), it is cut into n + 1
//! bands ([`banded`]); each outer band continues the subpixel beyond the side it touches, a
//! band holding the pixel's own sample takes that sample, and an inner band with neither
//! takes the mean of the outer ones. Only other shapes (edges crossing or ending inside)
//! take the unconstrained interpolation, which for a pixel holding a sample is that
//! sample: one colour for the whole subpixel, whichever band it fell in.
use super::code::{EpiPixel, EMPTY, SUBPIXEL};
use super::raster::Boundaries;
use super::tables::{orient, tables, Tables, AMBIGUOUS, CLASS_COMPLEX, CLASS_EMPTY, DIR_DOWN, DIR_LEFT, DIR_RIGHT, DIR_UP, PP, SIDE_B, SP, SS};
use super::Flags;
use crate::render_cache::PointImage;
use glam::Vec3;
use rayon::prelude::*;

/// One subpixel of the 6 × 6 grid.
#[derive(Debug, Clone, Copy, Default)]
struct Sub {
    c4: u8,
    code: u16,
    primary_b: bool,
    /// Point-image index of a usable sample in this subpixel, or `usize::MAX`.
    sample: usize,
    /// Where no pixel of the grid but the complex one holds a sample in this subpixel: an
    /// edge-free pixel's reconstructed colour, standing as a sample at the pixel's centre.
    proxy: Option<Vec3>,
}

/// The 4-bit crossing masks of subpixel (qx, qy) of pixel (x, y), side-major.
#[inline]
pub fn subpixel_mask(b: &Boundaries, x: usize, y: usize, qx: usize, qy: usize) -> u32 {
    let half = |m: u8, q: usize| u32::from((m >> (4 * q)) & 0xF);
    let top = half(if qy == 0 { b.top(x, y) } else { b.centre_horizontal(x, y) }, qx);
    let bottom = half(if qy == 0 { b.centre_horizontal(x, y) } else { b.bottom(x, y) }, qx);
    let left = half(if qx == 0 { b.left(x, y) } else { b.centre_vertical(x, y) }, qy);
    let right = half(if qx == 0 { b.centre_vertical(x, y) } else { b.right(x, y) }, qy);
    top | right << 4 | bottom << 8 | left << 12
}

/// Inputs of [`complex_filter`].
pub struct ComplexInput<'a> {
    pub bounds: &'a Boundaries,
    pub pixels: &'a [EpiPixel],
    pub flags: &'a Flags,
    pub points: &'a PointImage,
    /// Bit rows (as the flags') of the pixels the interpolation gave a colour.
    pub filled: &'a [u64],
    pub sigma: f32,
}

/// Refines every complex pixel of `image` (which holds their unconstrained colours);
/// returns how many were refined. Needs the centre lines (`bounds.centres`). The refined
/// colours are computed from the image as it came (a band next to an edge-free neighbour
/// pixel may read that pixel's colour) and written back at the end.
pub fn complex_filter(input: &ComplexInput, image: &mut [Vec3]) -> u32 {
    let (w, h, words) = (input.flags.width, input.flags.height, input.flags.words);
    if w == 0 || input.bounds.centres.is_empty() {
        return 0;
    }
    let t = tables();
    let read: &[Vec3] = image;
    let refined: Vec<(usize, Vec3)> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..words).flat_map(move |j| {
                let mut bits = input.flags.row(y, Flags::COMPLEX)[j];
                std::iter::from_fn(move || {
                    (bits != 0).then(|| {
                        let i = bits.trailing_zeros() as usize;
                        bits &= bits - 1;
                        let x = 64 * j + i;
                        (y * w + x, refine(t, input, x, y, read))
                    })
                })
            })
        })
        .collect();
    for &(i, c) in &refined {
        image[i] = c;
    }
    refined.len() as u32
}

/// The refined colour of complex pixel (x, y); `image` holds the unconstrained colours.
fn refine(t: &Tables, input: &ComplexInput, x: usize, y: usize, image: &[Vec3]) -> Vec3 {
    let fallback = image[y * input.flags.width + x];
    let grid = subpixel_grid(t, input, x, y, image);
    let mut out = Vec3::ZERO;
    for (sx, sy) in [(2usize, 2usize), (3, 2), (2, 3), (3, 3)] {
        let s = grid[sy * 6 + sx];
        if s.c4 == CLASS_COMPLEX {
            out += banded(t, input, &grid, (x, y), (sx, sy)).unwrap_or(fallback) * 0.25;
            continue;
        }
        // A region that reaches no sample (a sliver between two close edges, one of them
        // possibly hidden but kept by the conservative depth) takes the colour of the other
        // region of its subpixel, across the edge, before the whole pixel's unconstrained
        // colour: it is the nearer estimate.
        let [p, q] = region_colours(t, input, &grid, sx, sy);
        let (cp, cs) = (p.or(q).unwrap_or(fallback), q.or(p).unwrap_or(fallback));
        let primary_area = if s.c4 == CLASS_EMPTY {
            1.0
        } else {
            let a = t.subpixel.area_a(s.code);
            if s.primary_b {
                1.0 - a
            } else {
                a
            }
        };
        out += (cp * primary_area + cs * (1.0 - primary_area)) * 0.25;
    }
    out
}

/// The colours of the primary and secondary regions of the (not complex) subpixel (sx, sy)
/// of the grid: the Gaussian-weighted samples each reaches, `None` where it reaches none.
fn region_colours(t: &Tables, input: &ComplexInput, grid: &[Sub; 36], sx: usize, sy: usize) -> [Option<Vec3>; 2] {
    let inv2s2 = 1.0 / (2.0 * input.sigma * input.sigma);
    let masks = propagate(t, grid, sx, sy);
    // Centre of subpixel s in the complex pixel's coordinates.
    let (cx, cy) = (sx as f32 * 0.5 - 1.0 + 0.25, sy as f32 * 0.5 - 1.0 + 0.25);
    let (mut acc_p, mut acc_s) = ((Vec3::ZERO, 0.0f32), (Vec3::ZERO, 0.0f32));
    for (k, cell) in grid.iter().enumerate() {
        if masks[k] & (PP | SP) == 0 {
            continue;
        }
        let ([u, v], c) = match (cell.sample, cell.proxy) {
            (usize::MAX, None) => continue,
            (usize::MAX, Some(c)) => ([0.5, 0.5], c),
            (i, _) => (input.points.subpixel[i], input.points.color[i]),
        };
        let (px, py) = (k % 6 / 2, k / 6 / 2);
        let (dx, dy) = (px as f32 - 1.0 + u - cx, py as f32 - 1.0 + v - cy);
        let wgt = (-(dx * dx + dy * dy) * inv2s2).exp();
        if masks[k] & PP != 0 {
            acc_p.0 += c * wgt;
            acc_p.1 += wgt;
        }
        if masks[k] & SP != 0 {
            acc_s.0 += c * wgt;
            acc_s.1 += wgt;
        }
    }
    let col = |a: (Vec3, f32)| (a.1 > 0.0).then(|| a.0 / a.1);
    [col(acc_p), col(acc_s)]
}

/// Region (0 primary, 1 secondary) of point `r` (in [0, 1]², v down) of a subpixel; `None`
/// if it is complex.
fn region_at(s: &Sub, r: [f64; 2]) -> Option<usize> {
    if s.c4 == CLASS_COMPLEX {
        return None;
    }
    if s.c4 == CLASS_EMPTY {
        return Some(0);
    }
    let (a, b) = SUBPIXEL.ends(s.code);
    let on_b = orient(SUBPIXEL.boundary_point(a), SUBPIXEL.boundary_point(b), r) < 0.0;
    Some(usize::from(on_b != s.primary_b))
}

/// How n ≥ 2 edges cut a still-complex subpixel into bands: all of them run between one pair
/// of opposite sides, so the i-th crossings of the two sides are joined by chord i.
#[derive(Clone, Copy, PartialEq)]
struct Bands {
    /// Bands stacked along v (chords from the left side to the right), else along u.
    vertical: bool,
    n: usize,
    /// Chord i runs from (along 0, across p) to (along 1, across q), in subpixel units.
    chords: [(f32, f32); 4],
}

impl Bands {
    /// The bands of subpixel (qx, qy) of pixel (x, y), if its crossings have that shape.
    fn of(bounds: &Boundaries, x: usize, y: usize, qx: usize, qy: usize) -> Option<Bands> {
        let m = subpixel_mask(bounds, x, y, qx, qy);
        let side = |k: u32| (m >> (4 * k)) & 0xF;
        let (top, right, bottom, left) = (side(0), side(1), side(2), side(3));
        let (a, b, vertical) = if top == 0 && bottom == 0 {
            (left, right, true)
        } else if left == 0 && right == 0 {
            (top, bottom, false)
        } else {
            return None;
        };
        let n = a.count_ones() as usize;
        if n < 2 || b.count_ones() as usize != n {
            return None;
        }
        // Crossings at their 1/8-pixel segments' centres, in order along each side.
        let positions = |mask: u32| (0..4).filter(move |j| mask >> j & 1 != 0).map(|j| (j as f32 + 0.5) / 4.0);
        let mut chords = [(0.0, 0.0); 4];
        for (c, pq) in chords.iter_mut().zip(positions(a).zip(positions(b))) {
            *c = pq;
        }
        Some(Bands { vertical, n, chords })
    }

    /// The band holding point (u, v) of the subpixel, or `None` if a chord may pass on
    /// either side of it (its ends are known to a quarter of the side: 1/8 pixel).
    fn band_of(&self, u: f32, v: f32) -> Option<usize> {
        let (along, across) = if self.vertical { (u, v) } else { (v, u) };
        let mut band = 0;
        for &(p, q) in &self.chords[..self.n] {
            let at = |d: f32| (1.0 - along) * (p + d) + along * (q + d);
            if across > at(0.125) {
                band += 1;
            } else if across >= at(-0.125) {
                return None;
            }
        }
        Some(band)
    }

    /// Area of each band (trapezoids between the chords).
    fn areas(&self) -> [f32; 5] {
        let mut areas = [0.0; 5];
        let mut before = 0.0;
        for (a, &(p, q)) in areas.iter_mut().zip(&self.chords[..self.n]) {
            let upto = 0.5 * (p + q);
            *a = upto - before;
            before = upto;
        }
        areas[self.n] = 1.0 - before;
        areas
    }
}

/// The colour of still-complex subpixel (sx, sy) of the grid around pixel `at` as bands
/// (see the module docs), or `None` if its crossings are not [`Bands`] or no band's colour
/// is known. A band's colour: the mean of the samples lying in it — in this subpixel or in
/// the subpixels continuing the same bands along them in the grid — else, for an outer
/// band, the neighbouring subpixel's region beyond the side it touches, else the mean of
/// the outer bands.
fn banded(t: &Tables, input: &ComplexInput, grid: &[Sub; 36], at: (usize, usize), (sx, sy): (usize, usize)) -> Option<Vec3> {
    let cell_bands = |gx: usize, gy: usize| Bands::of(input.bounds, at.0 + gx / 2 - 1, at.1 + gy / 2 - 1, gx % 2, gy % 2);
    let bands = cell_bands(sx, sy)?;
    let n = bands.n;
    let mut sums = [(Vec3::ZERO, 0u32); 5];
    // The samples of the subpixels along the bands: the row (or column) of the grid through
    // s, as far as the cells go on with the same bands (those outside the image are
    // complex with no crossings and end it).
    let (w, h) = (input.flags.width, input.flags.height);
    let mut add = |gx: usize, gy: usize| -> bool {
        // A cell outside the image ends the run before its crossings are read: the
        // boundary masks have no entries there (at the left or top border its pixel
        // coordinate would be -1).
        let (px, py) = ((at.0 + gx / 2).wrapping_sub(1), (at.1 + gy / 2).wrapping_sub(1));
        if px >= w || py >= h || grid[gy * 6 + gx].c4 != CLASS_COMPLEX {
            return false;
        }
        let Some(b) = cell_bands(gx, gy) else { return false };
        if b.vertical != bands.vertical || b.n != n {
            return false;
        }
        if input.flags.get(px, py, Flags::HAS) {
            let idx = py * input.flags.width + px;
            let [u, v] = input.points.subpixel[idx];
            let (su, sv) = (2.0 * u.clamp(0.0, 0.999_999), 2.0 * v.clamp(0.0, 0.999_999));
            if su as usize == gx % 2 && sv as usize == gy % 2 {
                if let Some(band) = b.band_of(su - (gx % 2) as f32, sv - (gy % 2) as f32) {
                    sums[band].0 += input.points.color[idx];
                    sums[band].1 += 1;
                }
            }
        }
        true
    };
    add(sx, sy);
    for dir in [-1i64, 1] {
        for d in 1..6i64 {
            let (gx, gy) = if bands.vertical { (sx as i64 + dir * d, sy as i64) } else { (sx as i64, sy as i64 + dir * d) };
            if !(0..6).contains(&gx) || !(0..6).contains(&gy) || !add(gx as usize, gy as usize) {
                break;
            }
        }
    }
    let mut colours: [Option<Vec3>; 5] = [None; 5];
    for (c, &(sum, k)) in colours.iter_mut().zip(&sums) {
        if k > 0 {
            *c = Some(sum / k as f32);
        }
    }
    // Outer bands without a sample continue the neighbouring subpixels beyond their sides.
    let neighbour = |dx: i64, dy: i64, r: [f64; 2]| -> Option<Vec3> {
        let (nx, ny) = (sx as i64 + dx, sy as i64 + dy);
        if !(0..6).contains(&nx) || !(0..6).contains(&ny) {
            return None;
        }
        let (nx, ny) = (nx as usize, ny as usize);
        let region = region_at(&grid[ny * 6 + nx], r)?;
        region_colours(t, input, grid, nx, ny)[region]
    };
    if colours[0].is_none() {
        colours[0] = if bands.vertical { neighbour(0, -1, [0.5, 0.999]) } else { neighbour(-1, 0, [0.999, 0.5]) };
    }
    if colours[n].is_none() {
        colours[n] = if bands.vertical { neighbour(0, 1, [0.5, 0.001]) } else { neighbour(1, 0, [0.001, 0.5]) };
    }
    let outer = match (colours[0], colours[n]) {
        (Some(a), Some(b)) => 0.5 * (a + b),
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => colours[..=n].iter().flatten().next().copied()?,
    };
    Some(colours[..=n].iter().zip(bands.areas()).map(|(c, a)| c.unwrap_or(outer) * a).sum())
}

/// The 6 × 6 subpixels of the 3 × 3 pixels around (x, y), row-major. Outside the image:
/// complex (blocking, no sample). A neighbour pixel free of edges, without a usable sample
/// but with a colour from the interpolation (`image`, `input.filled`), lends that colour as
/// a proxy sample at its centre: in a sparse frame the 3 × 3 pixels often hold no sample
/// on one side of an edge, and the region there would otherwise take the other side's.
fn subpixel_grid(t: &Tables, input: &ComplexInput, x: usize, y: usize, image: &[Vec3]) -> [Sub; 36] {
    let (w, h) = (input.flags.width as i64, input.flags.height as i64);
    let mut grid = [Sub { c4: CLASS_COMPLEX, code: super::code::COMPLEX, primary_b: false, sample: usize::MAX, proxy: None }; 36];
    for py in 0..3 {
        for px in 0..3 {
            let (xx, yy) = (x as i64 + px as i64 - 1, y as i64 + py as i64 - 1);
            if xx < 0 || yy < 0 || xx >= w || yy >= h {
                continue;
            }
            let (xx, yy) = (xx as usize, yy as usize);
            let idx = yy * w as usize + xx;
            let has = input.flags.get(xx, yy, Flags::HAS);
            let [u, v] = input.points.subpixel[idx];
            let (su, sv) = (2.0 * u.clamp(0.0, 0.999_999) as f64, 2.0 * v.clamp(0.0, 0.999_999) as f64);
            let (qsx, qsy) = (su as usize, sv as usize);
            for qy in 0..2 {
                for qx in 0..2 {
                    let code = SUBPIXEL.classify(subpixel_mask(input.bounds, xx, yy, qx, qy));
                    let here = has && qsx == qx && qsy == qy;
                    let side = if here { t.subpixel.side_of_point(code, [su - qx as f64, sv - qy as f64]) } else { AMBIGUOUS };
                    let usable = side != AMBIGUOUS;
                    let primary_b = if usable { side == SIDE_B } else { t.subpixel.area_a(code) < 0.5 };
                    grid[(2 * py + qy) * 6 + 2 * px + qx] =
                        Sub { c4: t.subpixel.class4(code, primary_b), code, primary_b, sample: if usable { idx } else { usize::MAX }, proxy: None };
                }
            }
            let filled = input.filled.get(yy * input.flags.words + xx / 64).is_some_and(|w| w >> (xx % 64) & 1 != 0);
            if (px, py) != (1, 1) && !has && filled && input.pixels[idx].code() == EMPTY {
                grid[(2 * py + 1) * 6 + 2 * px + 1].proxy = Some(image[idx]);
            }
        }
    }
    grid
}

/// Reachability masks from subpixel (sx, sy) to every subpixel of the grid, along monotone
/// paths.
fn propagate(t: &Tables, grid: &[Sub; 36], sx: usize, sy: usize) -> [u8; 36] {
    let mut m = [0u8; 36];
    let s = sy * 6 + sx;
    m[s] = if grid[s].c4 == CLASS_EMPTY { PP } else { PP | SS };
    for d in 1..=10usize {
        for ty in 0..6usize {
            for tx in 0..6usize {
                if tx.abs_diff(sx) + ty.abs_diff(sy) != d {
                    continue;
                }
                let k = ty * 6 + tx;
                let mut acc = 0u8;
                if tx != sx {
                    let qx = if tx > sx { tx - 1 } else { tx + 1 };
                    let q = ty * 6 + qx;
                    let dir = if tx > sx { DIR_RIGHT } else { DIR_LEFT };
                    acc |= t.chain(m[q], t.neighbour(dir, grid[q].c4, grid[k].c4));
                }
                if ty != sy {
                    let qy = if ty > sy { ty - 1 } else { ty + 1 };
                    let q = qy * 6 + tx;
                    let dir = if ty > sy { DIR_DOWN } else { DIR_UP };
                    acc |= t.chain(m[q], t.neighbour(dir, grid[q].c4, grid[k].c4));
                }
                m[k] = acc;
            }
        }
    }
    m
}

#[cfg(test)]
mod tests;
