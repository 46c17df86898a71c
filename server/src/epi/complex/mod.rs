//! The complex-pixel filter, paper 000 §5.4: the crossings of the two centre lines recorded
//! during rasterization cut every pixel into 2 × 2 subpixels whose sides are half pixel
//! sides, still at 1/8-pixel precision. For each complex pixel, its 3 × 3 neighbourhood
//! becomes a 6 × 6 grid of subpixels, each classified and encoded like a pixel
//! ([`super::code::SUBPIXEL`]: 4 segments per side, 2 × 2 sample regions). Reachability is
//! propagated over the grid from each of the complex pixel's four subpixels along monotone
//! paths (the neighbour and chaining tables are the pixels' own: they depend only on
//! topology), and each subpixel region's colour is interpolated from the samples reachable
//! from it. A subpixel that is still complex, or a region that reaches no sample, takes
//! the complex pixel's colour from the unconstrained interpolation. The pixel is the
//! area-weighted sum of its subpixel regions.
use super::code::{EpiPixel, SUBPIXEL};
use super::raster::Boundaries;
use super::tables::{tables, Tables, AMBIGUOUS, CLASS_COMPLEX, CLASS_EMPTY, DIR_DOWN, DIR_LEFT, DIR_RIGHT, DIR_UP, PP, SIDE_B, SP, SS};
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
    pub sigma: f32,
}

/// Refines every complex pixel of `image` (which holds their unconstrained colours);
/// returns how many were refined. Needs the centre lines (`bounds.centres`).
pub fn complex_filter(input: &ComplexInput, image: &mut [Vec3]) -> u32 {
    let (w, words) = (input.flags.width, input.flags.words);
    if w == 0 || input.bounds.centres.is_empty() {
        return 0;
    }
    let t = tables();
    image
        .par_chunks_mut(w)
        .enumerate()
        .map(|(y, row)| {
            let mut n = 0;
            for j in 0..words {
                let mut bits = input.flags.row(y, Flags::COMPLEX)[j];
                while bits != 0 {
                    let i = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let x = 64 * j + i;
                    row[x] = refine(t, input, x, y, row[x]);
                    n += 1;
                }
            }
            n
        })
        .sum()
}

/// The refined colour of complex pixel (x, y) whose unconstrained colour is `fallback`.
fn refine(t: &Tables, input: &ComplexInput, x: usize, y: usize, fallback: Vec3) -> Vec3 {
    let grid = subpixel_grid(t, input, x, y);
    let inv2s2 = 1.0 / (2.0 * input.sigma * input.sigma);
    let mut out = Vec3::ZERO;
    for (sx, sy) in [(2usize, 2usize), (3, 2), (2, 3), (3, 3)] {
        let s = grid[sy * 6 + sx];
        if s.c4 == CLASS_COMPLEX {
            out += fallback * 0.25;
            continue;
        }
        let masks = propagate(t, &grid, sx, sy);
        // Centre of subpixel s in the complex pixel's coordinates.
        let (cx, cy) = (sx as f32 * 0.5 - 1.0 + 0.25, sy as f32 * 0.5 - 1.0 + 0.25);
        let (mut acc_p, mut acc_s) = ((Vec3::ZERO, 0.0f32), (Vec3::ZERO, 0.0f32));
        for (k, cell) in grid.iter().enumerate() {
            if cell.sample == usize::MAX || masks[k] & (PP | SP) == 0 {
                continue;
            }
            let (px, py) = (k % 6 / 2, k / 6 / 2);
            let [u, v] = input.points.subpixel[cell.sample];
            let (dx, dy) = (px as f32 - 1.0 + u - cx, py as f32 - 1.0 + v - cy);
            let wgt = (-(dx * dx + dy * dy) * inv2s2).exp();
            let c = input.points.color[cell.sample];
            if masks[k] & PP != 0 {
                acc_p.0 += c * wgt;
                acc_p.1 += wgt;
            }
            if masks[k] & SP != 0 {
                acc_s.0 += c * wgt;
                acc_s.1 += wgt;
            }
        }
        let col = |a: (Vec3, f32)| if a.1 > 0.0 { a.0 / a.1 } else { fallback };
        let (cp, cs) = (col(acc_p), col(acc_s));
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

/// The 6 × 6 subpixels of the 3 × 3 pixels around (x, y), row-major. Outside the image:
/// complex (blocking, no sample).
fn subpixel_grid(t: &Tables, input: &ComplexInput, x: usize, y: usize) -> [Sub; 36] {
    let (w, h) = (input.flags.width as i64, input.flags.height as i64);
    let mut grid = [Sub { c4: CLASS_COMPLEX, code: super::code::COMPLEX, primary_b: false, sample: usize::MAX }; 36];
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
                        Sub { c4: t.subpixel.class4(code, primary_b), code, primary_b, sample: if usable { idx } else { usize::MAX } };
                }
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
