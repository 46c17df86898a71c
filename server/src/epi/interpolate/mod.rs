//! Edge-respecting interpolation, paper 000 §5.3: the colour of each pixel's primary region
//! is the weighted mean of the usable samples of its 5 × 5 window whose pixel's primary
//! region is reachable from it (§5.2), with a sharply peaked kernel renormalised over the
//! samples used. Complex pixels "interpolate a color … while ignoring reachability"
//! (§5.4): every sample of their window counts, and nothing about them changes other
//! pixels' reachability.
//!
//! The kernel is fixed per pixel offset, as in the paper (Figure 6 shows one weight per
//! pixel of the window): a separable Gaussian of the offset. The un-normalised weight sum is
//! kept per pixel: prioritized sampling (§5.3) gives pixels with little reachable weight —
//! sparse regions and the neighbourhood of edges — high priority.
//!
//! A pixel with its own usable sample shows it as shaded ([`OwnSample::Show`], the Render
//! Cache rule) or filters it with its neighbours ([`OwnSample::Filter`]). A pixel that
//! reaches no sample is left at the background and marked a hole, for
//! [`super::spread`] to colour from its region (optionally, [`InterpOptions::fallback`],
//! it takes the unconstrained mean of its window instead, as the Render Cache baseline
//! would); its weight stays 0 so sampling treats it as unreached.
//!
//! Bit-sliced like [`super::reach`]: for 64 pixels of a row and one window offset, the
//! pixels that reach a usable sample there are one AND of three words; the work per pixel
//! is then proportional to the samples it actually uses.
use super::code::EpiPixel;
use super::reach::{offset, shifted, Reach};
use super::Flags;
use crate::render_cache::PointImage;
use glam::Vec3;
use rayon::prelude::*;

/// Default standard deviation (pixels) of the interpolation kernel.
pub const DEFAULT_SIGMA: f32 = 0.8;

/// What a pixel with its own usable sample shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OwnSample {
    /// The sample's colour, unfiltered (the Render Cache rule).
    Show,
    /// The kernel-weighted mean with its reachable neighbours.
    Filter,
}

/// Interpolation options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterpOptions {
    pub sigma: f32,
    pub own_sample: OwnSample,
    /// Fall back to the unconstrained window mean where no sample is reachable (edge-blind;
    /// off by default: spreading within the region does better, see the bench `quality`).
    pub fallback: bool,
}

impl Default for InterpOptions {
    fn default() -> Self {
        InterpOptions { sigma: DEFAULT_SIGMA, own_sample: OwnSample::Show, fallback: false }
    }
}

/// Weights of the 25 window offsets (window index `k`, see [`offset`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kernel(pub [f32; 25]);

impl Kernel {
    pub fn gaussian(sigma: f32) -> Kernel {
        let s = if sigma.is_finite() && sigma > 0.05 { sigma } else { DEFAULT_SIGMA };
        Kernel(std::array::from_fn(|k| {
            let (dx, dy) = offset(k);
            (-((dx * dx + dy * dy) as f32) / (2.0 * s * s)).exp()
        }))
    }
}

/// What interpolation did (the frame's pixel counts).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InterpCounts {
    /// Pixels holding a reprojected point.
    pub with_point: u32,
    /// Pixels without a point that got a colour from samples.
    pub filled: u32,
    /// Pixels without a point and no sample in their window (background).
    pub empty: u32,
    /// Pixels that reached no sample and took the unconstrained window mean.
    pub fallback: u32,
}

impl std::ops::Add for InterpCounts {
    type Output = InterpCounts;
    fn add(self, o: Self) -> Self {
        InterpCounts { with_point: self.with_point + o.with_point, filled: self.filled + o.filled, empty: self.empty + o.empty, fallback: self.fallback + o.fallback }
    }
}

/// Inputs of [`interpolate`].
pub struct InterpInput<'a> {
    pub pixels: &'a [EpiPixel],
    pub flags: &'a Flags,
    pub reach: &'a Reach,
    pub points: &'a PointImage,
    pub kernel: &'a Kernel,
    pub options: InterpOptions,
    pub background: Vec3,
}

/// Rows per parallel task.
const BAND_ROWS: usize = 16;

/// Fills `image` (primary-region colours), `weights` (un-normalised reachable weight), the
/// `filled` bit rows (pixels whose colour came from reachable samples or their own) and the
/// `holes` bit rows (pixels without a sample in their window: background colour).
pub fn interpolate(input: &InterpInput, image: &mut [Vec3], weights: &mut [f32], filled: &mut [u64], holes: &mut [u64]) -> InterpCounts {
    let (w, words) = (input.flags.width, input.flags.words);
    if w == 0 || words == 0 {
        return InterpCounts::default();
    }
    image
        .par_chunks_mut(BAND_ROWS * w)
        .zip(weights.par_chunks_mut(BAND_ROWS * w))
        .zip(filled.par_chunks_mut(BAND_ROWS * words))
        .zip(holes.par_chunks_mut(BAND_ROWS * words))
        .enumerate()
        .map(|(b, (((img, wt), fl), ho))| SCRATCH.with_borrow_mut(|scratch| interpolate_band(input, b * BAND_ROWS, img, wt, fl, ho, scratch)))
        .reduce(InterpCounts::default, |a, b| a + b)
}

thread_local! {
    /// Per-thread rows of the separable pass, kept across frames.
    static SCRATCH: std::cell::RefCell<Vec<[f32; 4]>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Which pixels of a word need interpolation, and how.
struct WordPlan {
    valid: u64,
    has: u64,
    own: u64,
    /// Non-complex pixels: reachable usable samples.
    plain: u64,
    /// Complex pixels: every sample of the window.
    complex: u64,
}

impl WordPlan {
    #[inline(always)]
    fn new(input: &InterpInput, y: usize, j: usize) -> Self {
        let f = input.flags;
        let valid = valid_bits(f.width, j);
        let has = f.row(y, Flags::HAS)[j];
        let usable = f.row(y, Flags::USABLE)[j];
        let complex = f.row(y, Flags::COMPLEX)[j];
        let own = match input.options.own_sample {
            OwnSample::Show => usable | (complex & has),
            OwnSample::Filter => 0,
        } & valid;
        let need = valid & !own;
        WordPlan { valid, has, own, plain: need & !complex, complex: need & complex }
    }
}

/// Bits of word `j` inside a row `w` wide.
#[inline(always)]
fn valid_bits(w: usize, j: usize) -> u64 {
    let n = (w - 64 * j).min(64);
    if n == 64 {
        !0
    } else {
        (1u64 << n) - 1
    }
}

/// The pixels of word `j` of row `y` whose 5 x 5 window holds no pixel with an edge: they
/// reach their whole window, and every sample there is usable. The edge pixels dilated by
/// two pixels, bit-sliced.
#[inline(always)]
fn quiet_bits(f: &Flags, y: usize, j: usize) -> u64 {
    let mut near = 0u64;
    for yy in y.saturating_sub(2)..(y + 3).min(f.height) {
        let (s, c) = (f.row(yy, Flags::SIMPLE), f.row(yy, Flags::COMPLEX));
        let e = |jj: usize| s[jj] | c[jj];
        let (prev, here, next) = (if j > 0 { e(j - 1) } else { 0 }, e(j), if j + 1 < f.words { e(j + 1) } else { 0 });
        near |= here | here << 1 | here << 2 | here >> 1 | here >> 2 | prev >> 63 | prev >> 62 | next << 63 | next << 62;
    }
    !near
}

/// Rows `y0 ..` (as many as `img` holds). When the band's pixels would gather many samples
/// one by one, the usable samples of its rows (and two rows either side) are first filtered
/// along the rows with the kernel's 1D factor; pixels whose window holds no edge then take
/// their sums from five of those rows (the separable filter, SIMD over the four channels),
/// and only pixels near edges gather sample by sample under the reachability masks.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn interpolate_band(input: &InterpInput, y0: usize, img: &mut [Vec3], wt: &mut [f32], fl: &mut [u64], ho: &mut [u64], scratch: &mut Vec<[f32; 4]>) -> InterpCounts {
    let f = input.flags;
    let (w, h, words) = (f.width, f.height, f.words);
    let rows = img.len() / w;
    let (mut need, mut samples) = (0usize, 0usize);
    for y in y0..y0 + rows {
        for j in 0..words {
            let p = WordPlan::new(input, y, j);
            need += (p.plain | p.complex).count_ones() as usize;
            samples += p.has.count_ones() as usize;
        }
    }
    // Gathering costs about a third of the row pass per sample: filter the rows when the
    // band's pixels would gather more than three samples per pixel of the band.
    let separable = need * samples * 25 > 3 * (rows * w) * (rows * w);
    let (ya, yb) = (y0.saturating_sub(2), (y0 + rows + 2).min(h));
    if separable {
        row_pass(input, ya, yb, scratch);
    }
    let mut counts = InterpCounts::default();
    for r in 0..rows {
        let y = y0 + r;
        let (img, wt) = (&mut img[r * w..(r + 1) * w], &mut wt[r * w..(r + 1) * w]);
        let (fl, ho) = (&mut fl[r * words..(r + 1) * words], &mut ho[r * words..(r + 1) * words]);
        for j in 0..words {
            let plan = WordPlan::new(input, y, j);
            let mut acc = [[0f32; 4]; 64];
            let mut plain = plan.plain;
            if separable && plain != 0 {
                let quiet = quiet_bits(f, y, j) & plain;
                if quiet != 0 {
                    column_pass(input, scratch, ya, y, j, &mut acc);
                    each_bit(!quiet & valid_bits(w, j), |i| acc[i] = [0.0; 4]);
                    plain &= !quiet;
                }
            }
            if plain != 0 {
                window_sum(input, y, j, plain, Flags::USABLE, true, &mut acc);
            }
            if plan.complex != 0 {
                window_sum(input, y, j, plan.complex, Flags::HAS, false, &mut acc);
            }
            counts = counts + finish_word(input, y, j, &plan, &mut acc, img, wt, &mut fl[j], &mut ho[j]);
        }
    }
    counts
}

/// The rows `ya .. yb` filtered along x: `scratch[(r - ya) * w + x]` = sum over dx of
/// `g(dx) * (colour, 1)` of the usable samples at `x + dx`.
fn row_pass(input: &InterpInput, ya: usize, yb: usize, scratch: &mut Vec<[f32; 4]>) {
    let w = input.flags.width;
    let g: [f32; 5] = std::array::from_fn(|i| input.kernel.0[10 + i]);
    scratch.resize((yb - ya + 1) * w, [0.0; 4]);
    let (rows, src) = scratch.split_at_mut((yb - ya) * w);
    for y in ya..yb {
        let usable = input.flags.row(y, Flags::USABLE);
        let colours = &input.points.color[y * w..(y + 1) * w];
        for (j, (s, c)) in src.chunks_mut(64).zip(colours.chunks(64)).enumerate() {
            let bits = usable[j];
            for (i, (s, c)) in s.iter_mut().zip(c).enumerate() {
                let u = ((bits >> i) & 1) as f32;
                *s = [c.x * u, c.y * u, c.z * u, u];
            }
        }
        let out = &mut rows[(y - ya) * w..(y - ya + 1) * w];
        for (x, o) in out.iter_mut().enumerate() {
            let mut a = [0f32; 4];
            if x >= 2 && x + 2 < w {
                let v = &src[x - 2..x + 3];
                for t in 0..5 {
                    for ch in 0..4 {
                        a[ch] += g[t] * v[t][ch];
                    }
                }
            } else {
                for (t, &gt) in g.iter().enumerate() {
                    let xx = x as i64 + t as i64 - 2;
                    if xx >= 0 && xx < w as i64 {
                        for ch in 0..4 {
                            a[ch] += gt * src[xx as usize][ch];
                        }
                    }
                }
            }
            *o = a;
        }
    }
}

/// Window sums of the 64 pixels of word `j` of row `y` from the row-filtered rows (all of
/// them: branch-free; the caller keeps those it wants).
#[inline(always)]
fn column_pass(input: &InterpInput, scratch: &[[f32; 4]], ya: usize, y: usize, j: usize, acc: &mut [[f32; 4]; 64]) {
    let (w, h) = (input.flags.width, input.flags.height);
    let x0 = 64 * j;
    let n = (w - x0).min(64);
    // Rows outside the image get weight 0 (and read the centre row, any row would do).
    let mut g = [0f32; 5];
    let rows: [&[[f32; 4]]; 5] = std::array::from_fn(|t| {
        let yy = y as i64 + t as i64 - 2;
        let inside = yy >= 0 && yy < h as i64;
        g[t] = if inside { input.kernel.0[t * 5 + 2] } else { 0.0 };
        let yy = if inside { yy as usize } else { y };
        &scratch[(yy - ya) * w + x0..][..n]
    });
    for (i, a) in acc[..n].iter_mut().enumerate() {
        let mut s = [0f32; 4];
        for t in 0..5 {
            let v = rows[t][i];
            for ch in 0..4 {
                s[ch] += g[t] * v[ch];
            }
        }
        *a = s;
    }
}

/// Calls `f(i)` for every set bit `i` of `bits`, lowest first (no branch per pixel: the
/// patterns are random and would mispredict).
#[inline(always)]
fn each_bit(mut bits: u64, mut f: impl FnMut(usize)) {
    while bits != 0 {
        let i = bits.trailing_zeros() as usize & 63;
        bits &= bits - 1;
        f(i);
    }
}

/// Colours, weights and filled bits of word `j` of row `y` from the window sums `acc`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn finish_word(
    input: &InterpInput,
    y: usize,
    j: usize,
    plan: &WordPlan,
    acc: &mut [[f32; 4]; 64],
    img: &mut [Vec3],
    wt: &mut [f32],
    fl: &mut u64,
    holes: &mut u64,
) -> InterpCounts {
    let w = input.flags.width;
    let x0 = 64 * j;
    let n = (w - x0).min(64);
    let (img, wt) = (&mut img[x0..x0 + n], &mut wt[x0..x0 + n]);
    let colours = &input.points.color[y * w + x0..y * w + x0 + n];
    let centre_weight = input.kernel.0[12];
    let mut counts = InterpCounts::default();
    let need = plan.plain | plan.complex;
    let mut filled = plan.own;
    let mut missing = 0u64;
    if plan.own == plan.valid {
        // Every pixel shows its own sample.
        img.copy_from_slice(colours);
        wt.fill(centre_weight);
    } else {
        each_bit(plan.own, |i| {
            img[i] = colours[i];
            wt[i] = centre_weight;
        });
        each_bit(need, |i| {
            let a = acc[i];
            if a[3] > 0.0 {
                let inv = 1.0 / a[3];
                img[i] = Vec3::new(a[0] * inv, a[1] * inv, a[2] * inv);
                wt[i] = a[3];
                filled |= 1 << i;
            } else {
                wt[i] = 0.0;
                missing |= 1 << i;
            }
        });
    }
    *fl = filled;
    counts.with_point = (plan.has & plan.valid).count_ones();
    let mut still_missing = missing;
    if missing != 0 && input.options.fallback {
        each_bit(missing, |i| acc[i] = [0.0; 4]);
        window_sum(input, y, j, missing, Flags::HAS, false, acc);
        each_bit(missing, |i| {
            let a = acc[i];
            if a[3] > 0.0 {
                let inv = 1.0 / a[3];
                img[i] = Vec3::new(a[0] * inv, a[1] * inv, a[2] * inv);
                still_missing &= !(1 << i);
            }
        });
        counts.fallback = (missing & !still_missing).count_ones();
    }
    each_bit(still_missing, |i| img[i] = input.background);
    *holes = still_missing;
    // Pixel counts: with a point / without a point but coloured / background.
    counts.empty = (still_missing & !plan.has).count_ones();
    counts.filled = (plan.valid & !plan.has & !still_missing).count_ones();
    counts
}

/// Adds `weight * colour` of the samples at window offset `k` of the pixels in `bits`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn gather(points: &PointImage, w: usize, y: usize, x0: usize, k: usize, weight: f32, bits: u64, acc: &mut [[f32; 4]; 64]) {
    let (dx, dy) = offset(k);
    let row = &points.color[(y as i64 + dy as i64) as usize * w..][..w];
    let base = x0 as i64 + dx as i64;
    each_bit(bits, |i| {
        let c = row[(base + i as i64) as usize];
        let a = &mut acc[i];
        a[0] += weight * c.x;
        a[1] += weight * c.y;
        a[2] += weight * c.z;
        a[3] += weight;
    });
}

/// Sums over the window offsets of the samples in plane `plane` (of rows `y - 2 ..= y + 2`)
/// for the pixels in `centres`, optionally restricted by reachability.
#[inline(always)]
fn window_sum(input: &InterpInput, y: usize, j: usize, centres: u64, plane: usize, reachable: bool, acc: &mut [[f32; 4]; 64]) {
    let (w, h) = (input.flags.width, input.flags.height);
    for k in 0..25 {
        let (dx, dy) = offset(k);
        let yy = y as i64 + dy as i64;
        if yy < 0 || yy >= h as i64 {
            continue;
        }
        let mut bits = centres & shifted(input.flags.row(yy as usize, plane), j, dx);
        if reachable && bits != 0 {
            bits &= input.reach.bits(y, j, k);
        }
        if bits != 0 {
            gather(input.points, w, y, 64 * j, k, input.kernel.0[k], bits, acc);
        }
    }
}

#[cfg(test)]
mod tests;
