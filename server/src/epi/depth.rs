//! The conservative depth buffer of paper 000 §4.5: "the maximum depth value in a 4 × 4
//! neighborhood and adding an additional offset that depends on the local point density",
//! used read-only to cull occluded edge fragments during rasterization.
//!
//! One value per pixel grid vertex `(x, y)` (the top-left corner of pixel (x, y)): the 4 × 4
//! window of pixels around the vertex, `[x-2, x+1] × [y-2, y+1]`. Only pixels holding a
//! reprojected point count: a window without points gives `+inf` (nothing known, keep every
//! fragment), and a miss point (background at infinity) gives `+inf` as well, since an edge
//! in front of the background is visible. The offset is relative to the depth (so it is
//! scale-free) and grows as the window's points thin out, because a sparse window is less
//! likely to hold a point from the far side of a silhouette.
//!
//! Beyond the paper, for sparse point sets: a 4 × 4 window without points takes the maximum
//! over the 12 × 12 pixels around it instead (the 3 × 3 blocks of 4 × 4 pixels around the
//! block of its vertex), with the slack of that larger, sparser window. At 5 % density nearly half of the 4 × 4 windows are empty,
//! and edges behind the visible surface there (the far silhouettes of a scanned model) would
//! otherwise all be drawn and cut the surface into false regions. A window whose
//! surroundings hold no point either, or hold a miss, stays at `+inf`.
use super::interpolate::Isa;
use crate::render_cache::{PointImage, NO_POINT};
use rayon::prelude::*;

/// Relative slack added to every window maximum: surface points within two pixels of an
/// edge on that surface (a silhouette's own side, a crease) can be nearer than the edge.
pub const DEPTH_SLACK: f32 = 0.05;
/// Further relative slack for an empty window fraction of 1 (scaled by the fraction of the
/// window's pixels without a point). Measured against ray-cast visibility (the tests): with
/// 0.1, no visible edge point of the bunny or `cornell-point` is culled at point densities
/// of 100 % and 20 % (4 of 540 on `cornell-point` at 5 %, none of the bunny's), while 98 %,
/// 85 % and 78 % of the bunny's clearly hidden ones are (57 % at 5 % before empty windows
/// read their surroundings); with 0.03, visible points start to be culled.
pub const SPARSE_SLACK: f32 = 0.1;

/// Per-vertex conservative depth.
pub struct ConservativeDepth {
    pub width: usize,
    pub height: usize,
    /// Row-major, `width * height` (vertex (x, y) for x < width, y < height; the last row
    /// and column of vertices use their clamped neighbours). NaN where the window holds no
    /// point: read through [`Self::at`].
    pub depth: Vec<f32>,
    /// Per 4 × 4 pixel block: the points' maximum depth and their count (for windows
    /// without points).
    blocks: Blocks,
}

impl ConservativeDepth {
    /// Bytes of a `width` × `height` buffer with its blocks, as [`Self::compute`] sizes them.
    pub fn bytes_for(width: usize, height: usize) -> usize {
        let (cols, rows) = (width.div_ceil(BLOCK), height.div_ceil(BLOCK));
        width * height * 4 + cols * rows * (4 + 1) + cols * (4 + 1)
    }

    pub fn new(width: usize, height: usize) -> Self {
        ConservativeDepth { width, height, depth: vec![f32::INFINITY; width * height], blocks: Blocks::default() }
    }

    pub fn bytes(&self) -> usize {
        self.depth.len() * 4 + self.blocks.bytes()
    }

    /// Recomputes the buffer from the reprojected points.
    pub fn compute(&mut self, points: &PointImage) {
        self.compute_with(points, Isa::detect());
    }

    /// [`Self::compute`] with the loops compiled for `isa` (which the CPU must have).
    fn compute_with(&mut self, points: &PointImage, isa: Isa) {
        assert!(isa.available(), "conservative depth: this CPU lacks {isa:?}");
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return;
        }
        debug_assert_eq!(points.depth.len(), w * h);
        // The window of vertex (4i + 2, 4j + 2) is block (i, j): the bands record those
        // windows' maxima and counts for the blocks as they go.
        let cols = self.blocks.start(w, h);
        let block_rows = BAND_ROWS / BLOCK;
        self.depth
            .par_chunks_mut(BAND_ROWS * w)
            .zip(self.blocks.value.par_chunks_mut(block_rows * cols))
            .zip(self.blocks.count.par_chunks_mut(block_rows * cols))
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new()),
                |(hmax, hcount), (b, ((out, bv), bc))| {
                    let band = (points, w, h, b * BAND_ROWS);
                    match isa {
                        // SAFETY: `Isa::detect` chose AVX2 only where the CPU has it.
                        #[cfg(target_arch = "x86_64")]
                        Isa::Avx2 | Isa::Avx512 => unsafe { depth_band_avx2(band, hmax, hcount, out, (bv, bc)) },
                        _ => depth_band(band, hmax, hcount, out, (bv, bc)),
                    }
                },
            );
        self.blocks.finish(points, w, h);
    }

    /// Conservative depth at vertex (x, y), clamped into the buffer. A vertex whose window
    /// holds no point (NaN in `depth`) reads the blocks around it: looked up here, per
    /// fragment, rather than filled in for every such vertex.
    #[inline]
    pub fn at(&self, x: i64, y: i64) -> f32 {
        let x = x.clamp(0, self.width as i64 - 1) as usize;
        let y = y.clamp(0, self.height as i64 - 1) as usize;
        let d = self.depth[y * self.width + x];
        if d.is_nan() {
            self.blocks.surroundings(x, y)
        } else {
            d
        }
    }
}

/// Rows per parallel task of [`ConservativeDepth::compute`].
const BAND_ROWS: usize = 16;

/// Maximum of two depths that are never NaN (compiles to one `maxps` lane).
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// [`depth_band`] compiled for AVX2 (eight lanes and blends: the straight loops vectorise
/// twice as wide as with the baseline's SSE2, which lacks blends).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn depth_band_avx2(band: (&PointImage, usize, usize, usize), hmax: &mut Vec<f32>, hcount: &mut Vec<f32>, out: &mut [f32], blocks: (&mut [f32], &mut [u8])) {
    depth_band(band, hmax, hcount, out, blocks)
}

/// Rows `y0 ..` of the buffer (as many as `out` holds) of the `w` x `h` image `points`
/// (`band` = points, w, h, y0): the window maxima and counts along each point row first
/// (rows `y0 - 2 ..= y_last + 1`, into `hmax` / `hcount`), then across four of those rows.
/// Written as straight loops over slices of one length so that they vectorise.
/// `blocks`: the band's rows of [`Blocks`], given the raw maximum and count of their
/// middle vertices' windows.
#[inline(always)]
fn depth_band(band: (&PointImage, usize, usize, usize), hmax: &mut Vec<f32>, hcount: &mut Vec<f32>, out: &mut [f32], blocks: (&mut [f32], &mut [u8])) {
    let (points, w, h, y0) = band;
    let (block_max, block_count) = blocks;
    let block_cols = w.div_ceil(BLOCK);
    let rows_out = out.len() / w;
    let (ya, yb) = (y0.saturating_sub(2), (y0 + rows_out).min(h - 1));
    let rows = yb - ya + 1;
    // One spare row holds the per-pixel depths and counts of the row being filtered.
    hmax.resize((rows + 1) * w, 0.0);
    hcount.resize((rows + 1) * w, 0.0);
    let (hm_all, d) = hmax.split_at_mut(rows * w);
    let (hc_all, c) = hcount.split_at_mut(rows * w);
    for r in 0..rows {
        let y = ya + r;
        let (pt, dp) = (&points.point[y * w..(y + 1) * w], &points.depth[y * w..(y + 1) * w]);
        // A pixel without a point adds nothing (depths are finite or +inf, never NaN).
        for ((dx, cx), (&p, &z)) in d.iter_mut().zip(c.iter_mut()).zip(pt.iter().zip(dp)) {
            let present = p != NO_POINT;
            *dx = if present { z } else { f32::NEG_INFINITY };
            *cx = if present { 1.0 } else { 0.0 };
        }
        let (hm, hc) = (&mut hm_all[r * w..(r + 1) * w], &mut hc_all[r * w..(r + 1) * w]);
        // Window [x - 2, x + 1]: interior in one pass, the clipped ends separately.
        if w >= 4 {
            let n = w - 3;
            let (hm, hc) = (&mut hm[2..2 + n], &mut hc[2..2 + n]);
            let (d0, d1, d2, d3) = (&d[..n], &d[1..1 + n], &d[2..2 + n], &d[3..3 + n]);
            let (c0, c1, c2, c3) = (&c[..n], &c[1..1 + n], &c[2..2 + n], &c[3..3 + n]);
            for i in 0..n {
                hm[i] = max(max(d0[i], d1[i]), max(d2[i], d3[i]));
                hc[i] = (c0[i] + c1[i]) + (c2[i] + c3[i]);
            }
        }
        for x in (0..2.min(w)).chain((w.max(3) - 1).max(2)..w) {
            let (lo, hi) = (x.saturating_sub(2), (x + 1).min(w - 1));
            hm[x] = d[lo..=hi].iter().fold(f32::NEG_INFINITY, |a, &b| max(a, b));
            hc[x] = c[lo..=hi].iter().sum();
        }
    }
    for (ry, o) in out.chunks_mut(w).enumerate() {
        let y = y0 + ry;
        let (lo, hi) = (y.saturating_sub(2) - ya, (y + 1).min(h - 1) - ya);
        let vrows = (hi - lo + 1) as f32;
        let block_row = y % BLOCK == BLOCK / 2;
        if hi - lo == 3 && w >= 4 {
            // A full window height (every row but the image's first two and last): the
            // four rows' maxima and counts and the interior columns' output in one pass.
            // Maxima and small integer counts are exact in any order, and the interior
            // window has 16 pixels, so `n / 16.0` is the same division as the general one.
            let row = |r: usize| (&hm_all[r * w..(r + 1) * w], &hc_all[r * w..(r + 1) * w]);
            let ((m0, c0), (m1, c1), (m2, c2), (m3, c3)) = (row(lo), row(lo + 1), row(lo + 2), row(lo + 3));
            let k = w - 3;
            let (im0, im1, im2, im3) = (&m0[2..2 + k], &m1[2..2 + k], &m2[2..2 + k], &m3[2..2 + k]);
            let (ic0, ic1, ic2, ic3) = (&c0[2..2 + k], &c1[2..2 + k], &c2[2..2 + k], &c3[2..2 + k]);
            let io = &mut o[2..2 + k];
            for i in 0..k {
                let m = max(max(im0[i], im1[i]), max(im2[i], im3[i]));
                let n = (ic0[i] + ic1[i]) + (ic2[i] + ic3[i]);
                let empty = 1.0 - n / 16.0;
                io[i] = if n == 0.0 { f32::NAN } else { m * (1.0 + DEPTH_SLACK + SPARSE_SLACK * empty) };
            }
            let window = |x: usize| (max(max(m0[x], m1[x]), max(m2[x], m3[x])), (c0[x] + c1[x]) + (c2[x] + c3[x]));
            for x in [0, 1, w - 1] {
                let (m, n) = window(x);
                o[x] = conservative(m, n, vrows, x, w);
            }
            if block_row {
                let row = (y - y0) / BLOCK * block_cols;
                for bx in 0..block_cols {
                    let x = bx * BLOCK + BLOCK / 2;
                    if x < w {
                        let (m, n) = window(x);
                        block_max[row + bx] = m;
                        block_count[row + bx] = n as u8;
                    }
                }
            }
            continue;
        }
        // Running maxima and counts over the window's rows, into `d` and `c`.
        d.copy_from_slice(&hm_all[lo * w..(lo + 1) * w]);
        c.copy_from_slice(&hc_all[lo * w..(lo + 1) * w]);
        for r in lo + 1..=hi {
            for ((m, n), (&a, &b)) in d.iter_mut().zip(c.iter_mut()).zip(hm_all[r * w..(r + 1) * w].iter().zip(&hc_all[r * w..(r + 1) * w])) {
                *m = max(*m, a);
                *n += b;
            }
        }
        if block_row {
            let row = (y - y0) / BLOCK * block_cols;
            for bx in 0..block_cols {
                let x = bx * BLOCK + BLOCK / 2;
                if x < w {
                    block_max[row + bx] = d[x];
                    block_count[row + bx] = c[x] as u8;
                }
            }
        }
        for (x, ((o, &m), &n)) in o.iter_mut().zip(d.iter()).zip(c.iter()).enumerate() {
            *o = conservative(m, n, vrows, x, w);
        }
    }
}

/// The conservative depth of vertex `x` of a row whose window spans `vrows` rows, from the
/// window's maximum `m` and point count `n`; NaN when it holds no point (see
/// [`ConservativeDepth::compute`]).
#[inline(always)]
fn conservative(m: f32, n: f32, vrows: f32, x: usize, w: usize) -> f32 {
    let cols = if x >= 2 && x + 1 < w { 4.0 } else { ((x + 1).min(w - 1) - x.saturating_sub(2) + 1) as f32 };
    let empty = 1.0 - n / (vrows * cols);
    if n == 0.0 {
        f32::NAN
    } else {
        m * (1.0 + DEPTH_SLACK + SPARSE_SLACK * empty)
    }
}

/// Pixels per side of a coarse block.
const BLOCK: usize = 4;

/// Coarse 4 × 4 pixel blocks of the point image, each with the conservative depth of the
/// 3 × 3 blocks around it (12 × 12 pixels, which hold the 4 × 4 window of every vertex in
/// the middle block): their points' maximum with the slack of their empty fraction, or
/// `+inf` when they hold no point or a miss.
#[derive(Default)]
struct Blocks {
    cols: usize,
    /// Per block: first its points' maximum depth, then (in place) the value above.
    value: Vec<f32>,
    /// Per block: its points, then those of the 3 × 3 blocks around it (at most 144).
    count: Vec<u8>,
    /// One row of blocks (the vertical pass reads the row above as it was).
    row_value: Vec<f32>,
    row_count: Vec<u8>,
}

impl Blocks {
    fn bytes(&self) -> usize {
        (self.value.capacity() + self.row_value.capacity()) * 4 + self.count.capacity() + self.row_count.capacity()
    }

    /// Sizes the blocks for a `w` × `h` image; returns the columns.
    fn start(&mut self, w: usize, h: usize) -> usize {
        let (cols, rows) = (w.div_ceil(BLOCK), h.div_ceil(BLOCK));
        self.cols = cols;
        self.value.clear();
        self.value.resize(cols * rows, f32::NEG_INFINITY);
        self.count.clear();
        self.count.resize(cols * rows, 0);
        cols
    }

    /// After the bands: the blocks without a middle vertex (a last column or row of one or
    /// two pixels) from the points, then every block's value.
    fn finish(&mut self, points: &PointImage, w: usize, h: usize) {
        let (cols, rows) = (self.cols, h.div_ceil(BLOCK));
        let Blocks { value, count, row_value, row_count, .. } = self;
        for by in 0..rows {
            for bx in 0..cols {
                if bx * BLOCK + BLOCK / 2 < w && by * BLOCK + BLOCK / 2 < h {
                    continue;
                }
                let i = by * cols + bx;
                for y in by * BLOCK..((by + 1) * BLOCK).min(h) {
                    for x in bx * BLOCK..((bx + 1) * BLOCK).min(w) {
                        if points.point[y * w + x] != NO_POINT {
                            value[i] = max(value[i], points.depth[y * w + x]);
                            count[i] += 1;
                        }
                    }
                }
            }
        }
        // 3 × 3 maxima and counts: across each row, then down the columns (in place, the
        // row above kept as it was in `row_*`).
        row_value.resize(cols, 0.0);
        row_count.resize(cols, 0);
        let last = cols - 1;
        for (m, n) in value.chunks_exact_mut(cols).zip(count.chunks_exact_mut(cols)) {
            row_value.copy_from_slice(m);
            row_count.copy_from_slice(n);
            for bx in 0..cols {
                let (lo, hi) = (bx.saturating_sub(1), (bx + 1).min(last));
                m[bx] = max(max(row_value[lo], row_value[bx]), row_value[hi]);
                n[bx] = row_count[lo] + if bx > 0 { row_count[bx] } else { 0 } + if bx < last { row_count[hi] } else { 0 };
            }
        }
        row_value.copy_from_slice(&value[..cols]);
        row_count.copy_from_slice(&count[..cols]);
        for by in 0..rows {
            let (here, below) = value.split_at_mut((by + 1) * cols);
            let (here_n, below_n) = count.split_at_mut((by + 1) * cols);
            let (m, n) = (&mut here[by * cols..], &mut here_n[by * cols..]);
            for bx in 0..cols {
                let (above_m, above_n) = (row_value[bx], row_count[bx]);
                let (own_m, own_n) = (m[bx], n[bx]);
                let (below_m, below_n) = if by + 1 < rows { (below[bx], below_n[bx]) } else { (f32::NEG_INFINITY, 0) };
                (row_value[bx], row_count[bx]) = (own_m, own_n);
                m[bx] = max(max(if by > 0 { above_m } else { f32::NEG_INFINITY }, own_m), below_m);
                n[bx] = if by > 0 { above_n } else { 0 } + own_n + below_n;
            }
        }
        // Pixels in the 3 blocks around block `b` of `len` pixels in `n` blocks.
        let span = |b: usize, n: usize, len: usize| -> f32 {
            (b.saturating_sub(1)..=(b + 1).min(n - 1)).map(|k| BLOCK.min(len - k * BLOCK)).sum::<usize>() as f32
        };
        row_value.clear();
        row_value.extend((0..cols).map(|bx| span(bx, cols, w)));
        for by in 0..rows {
            let ph = span(by, rows, h);
            let (m, n) = (&mut value[by * cols..(by + 1) * cols], &count[by * cols..(by + 1) * cols]);
            for ((m, &n), &pw) in m.iter_mut().zip(n).zip(row_value.iter()) {
                *m = if n == 0 { f32::INFINITY } else { *m * (1.0 + DEPTH_SLACK + SPARSE_SLACK * (1.0 - n as f32 / (pw * ph))) };
            }
        }
    }

    /// The conservative depth of vertex (x, y) whose own window holds no point.
    #[inline]
    fn surroundings(&self, x: usize, y: usize) -> f32 {
        self.value[(y / BLOCK) * self.cols + x / BLOCK]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::epi::testutil::Rng;
    use glam::Vec3;

    fn image(w: usize, h: usize, rng: &mut Rng, density: f64) -> PointImage {
        let mut pi = PointImage { width: w as u32, height: h as u32, ..Default::default() };
        for i in 0..w * h {
            let has = rng.chance(density);
            pi.point.push(if has { i as u32 } else { crate::render_cache::NO_POINT });
            // Some points are misses (at infinity).
            let miss = rng.chance(0.05);
            pi.depth.push(if !has || miss { f32::INFINITY } else { 1.0 + 9.0 * rng.unit() });
            pi.subpixel.push([0.5, 0.5]);
            pi.color.push(Vec3::ZERO);
            pi.age.push(0.0);
        }
        pi
    }

    /// Maximum depth, points and pixels of the image inside `[x0, x1) × [y0, y1)`.
    fn window(pi: &PointImage, w: usize, h: usize, (x0, x1): (i64, i64), (y0, y1): (i64, i64)) -> (f32, usize, usize) {
        let (mut m, mut n, mut cells) = (f32::NEG_INFINITY, 0, 0);
        for yy in y0.max(0)..y1.min(h as i64) {
            for xx in x0.max(0)..x1.min(w as i64) {
                cells += 1;
                let i = yy as usize * w + xx as usize;
                if pi.point[i] != crate::render_cache::NO_POINT {
                    n += 1;
                    m = m.max(pi.depth[i]);
                }
            }
        }
        (m, n, cells)
    }

    /// The conservative value of a window with `n` points among `cells` pixels, max `m`.
    fn slackened(m: f32, n: usize, cells: usize) -> f32 {
        m * (1.0 + DEPTH_SLACK + SPARSE_SLACK * (1.0 - n as f32 / cells as f32))
    }

    #[test]
    fn window_maximum_with_density_slack_matches_brute_force() {
        let mut rng = Rng(3);
        for (w, h, density) in [(13, 9, 0.7), (31, 17, 0.1), (5, 3, 1.0), (1, 1, 1.0), (64, 2, 0.4), (40, 30, 0.03), (9, 50, 0.01), (23, 23, 0.0), (4, 37, 0.6), (130, 71, 0.5), (67, 33, 1.0)] {
            let pi = image(w, h, &mut rng, density);
            for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
                let mut cd = ConservativeDepth::new(w, h);
                cd.compute_with(&pi, isa);
                for y in 0..h as i64 {
                    for x in 0..w as i64 {
                        let (m, n, cells) = window(&pi, w, h, (x - 2, x + 2), (y - 2, y + 2));
                        let want = if n > 0 {
                            slackened(m, n, cells)
                        } else {
                            // The 3 × 3 blocks of 4 × 4 pixels around the vertex's block.
                            let (bx, by) = (x / BLOCK as i64 * BLOCK as i64, y / BLOCK as i64 * BLOCK as i64);
                            let b = BLOCK as i64;
                            let (m, n, cells) = window(&pi, w, h, (bx - b, bx + 2 * b), (by - b, by + 2 * b));
                            if n == 0 {
                                f32::INFINITY
                            } else {
                                slackened(m, n, cells)
                            }
                        };
                        // Bit for bit: the same maxima, counts and divisions.
                        let got = cd.at(x, y);
                        assert!(got == want, "{isa:?}: ({x},{y}) of {w}x{h}: {got} vs {want}");
                        // Never below any point of the window: conservative.
                        assert!(n == 0 || got >= m);
                    }
                }
            }
        }
    }
}

