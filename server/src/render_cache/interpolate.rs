//! Gap filling of the Render Cache (paper 000 §4.3, Walter et al. 1999 §3.3): a pixel without
//! a point takes the weighted mean of the points in its 3x3 neighbourhood, or its 5x5
//! neighbourhood when the 3x3 one is empty, with a sharply peaked Gaussian of the distance
//! from the pixel centre to each point's actual (subpixel) position. The un-normalised
//! weight sum is kept per pixel: prioritized sampling (§5.3) gives low sums high priority.
//! A pixel with its own point shows that point's colour unfiltered and keeps the point's
//! own kernel weight.
use super::{PointImage, RenderCache, NO_POINT};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::OnceLock;

/// Standard deviation (pixels) of the interpolation kernel.
pub const INTERP_SIGMA: f32 = 0.8;

/// 1D kernel samples over offsets [-2.5, 2.5] pixels at 1/STEPS resolution (separable, so a
/// 2D weight is two lookups and a multiply instead of an `exp`).
const STEPS: f32 = 64.0;
const HALF_RANGE: f32 = 2.5;

fn kernel_table() -> &'static [f32] {
    static T: OnceLock<Vec<f32>> = OnceLock::new();
    T.get_or_init(|| {
        let n = (2.0 * HALF_RANGE * STEPS) as usize + 1;
        (0..n)
            .map(|i| {
                let o = i as f32 / STEPS - HALF_RANGE;
                (-o * o / (2.0 * INTERP_SIGMA * INTERP_SIGMA)).exp()
            })
            .collect()
    })
}

#[inline]
fn k1(table: &[f32], o: f32) -> f32 {
    // Offsets are within [-HALF_RANGE, HALF_RANGE] by construction (|dx| <= 2, subpixel in
    // [0, 1)); the comparisons keep the index in the table whatever comes in (NaN fails the
    // first and becomes 0) without the cost of `clamp`'s NaN handling.
    let f = (o + HALF_RANGE) * STEPS + 0.5;
    let f = if f > 0.0 { f } else { 0.0 };
    let f = if f < 2.0 * HALF_RANGE * STEPS { f } else { 2.0 * HALF_RANGE * STEPS };
    // SAFETY: f is finite and in [0, table.len() - 1] here.
    table[unsafe { f.to_int_unchecked::<i32>() } as usize]
}

impl RenderCache {
    /// Fills [`Self::image`] and [`Self::filter_weights`] from the point image. Returns
    /// (pixels with a point, filled pixels, empty pixels).
    pub(super) fn interpolate(&mut self) -> (u32, u32, u32) {
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        if w == 0 || h == 0 {
            return (0, 0, 0);
        }
        let (pi, bg) = (&self.points, self.cfg.background);
        (self.image.par_chunks_mut(w), self.weights.par_chunks_mut(w))
            .into_par_iter()
            .enumerate()
            .map(|(y, (img, wt))| interpolate_row(pi, bg, y, img, wt))
            .reduce(|| (0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2))
    }
}

/// Weighted sum of the colours of the points at offsets (dx, dy), `r0 <= max(|dx|, |dy|) <= r`,
/// around pixel (x, y), and the sum of the weights.
#[inline]
fn gather(pi: &PointImage, table: &[f32], x: usize, y: usize, r0: usize, r: usize) -> (Vec3, f32) {
    let (w, h) = (pi.width as usize, pi.height as usize);
    let (mut c, mut ws) = (Vec3::ZERO, 0.0f32);
    let (x0, x1) = (x.saturating_sub(r), (x + r).min(w - 1));
    let (y0, y1) = (y.saturating_sub(r), (y + r).min(h - 1));
    for ny in y0..=y1 {
        let dy = ny as f32 - y as f32;
        let inner_row = ny.abs_diff(y) < r0;
        for nx in x0..=x1 {
            if inner_row && nx.abs_diff(x) < r0 {
                continue;
            }
            let j = ny * w + nx;
            if pi.point[j] == NO_POINT {
                continue;
            }
            let [u, v] = pi.subpixel[j];
            let wt = k1(table, nx as f32 - x as f32 + u - 0.5) * k1(table, dy + v - 0.5);
            c += pi.color[j] * wt;
            ws += wt;
        }
    }
    (c, ws)
}

/// [`gather`] over the 3x3 neighbourhood of an interior pixel `i`, unrolled (the common
/// case; the same sums in the same order).
#[inline]
fn gather3_interior(pi: &PointImage, table: &[f32], i: usize, w: usize) -> (Vec3, f32) {
    let (mut c, mut ws) = (Vec3::ZERO, 0.0f32);
    for (dy, row) in [(-1.0f32, i - w), (0.0, i), (1.0, i + w)] {
        for (dx, j) in [(-1.0f32, row - 1), (0.0, row), (1.0, row + 1)] {
            if pi.point[j] == NO_POINT {
                continue;
            }
            let [u, v] = pi.subpixel[j];
            let wt = k1(table, dx + u - 0.5) * k1(table, dy + v - 0.5);
            c += pi.color[j] * wt;
            ws += wt;
        }
    }
    (c, ws)
}

/// Fills row `y` of the image and the weights. Returns (pixels with a point, filled, empty).
#[inline(never)]
fn interpolate_row(pi: &PointImage, bg: Vec3, y: usize, img: &mut [Vec3], wt: &mut [f32]) -> (u32, u32, u32) {
    let table = kernel_table();
    let w = img.len();
    let (mut with_point, mut filled, mut empty) = (0u32, 0u32, 0u32);
    for x in 0..w {
        let i = y * w + x;
        if pi.point[i] != NO_POINT {
            // A pixel's own point is shown as shaded, with its own kernel weight (sampling
            // ranks such pixels by the point's age).
            img[x] = pi.color[i];
            let [u, v] = pi.subpixel[i];
            wt[x] = k1(table, u - 0.5) * k1(table, v - 0.5);
            with_point += 1;
            continue;
        }
        let interior = x > 0 && y > 0 && x + 1 < w && y + 1 < pi.height as usize;
        let (mut c, mut ws) = if interior { gather3_interior(pi, table, i, w) } else { gather(pi, table, x, y, 0, 1) };
        if ws == 0.0 {
            (c, ws) = gather(pi, table, x, y, 2, 2);
        }
        if ws > 0.0 {
            img[x] = c / ws;
            wt[x] = ws;
            filled += 1;
        } else {
            img[x] = bg;
            wt[x] = 0.0;
            empty += 1;
        }
    }
    (with_point, filled, empty)
}
