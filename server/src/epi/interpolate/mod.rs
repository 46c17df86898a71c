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
//! is then proportional to the samples it actually uses. (A separable row/column filter
//! for pixels whose windows hold no edge was measured slower than this at every sample
//! density the renderer runs at, and removed.)
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
        .map(|(b, (((img, wt), fl), ho))| interpolate_band(input, b * BAND_ROWS, img, wt, fl, ho))
        .reduce(InterpCounts::default, |a, b| a + b)
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

/// Rows `y0 ..` (as many as `img` holds).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn interpolate_band(input: &InterpInput, y0: usize, img: &mut [Vec3], wt: &mut [f32], fl: &mut [u64], ho: &mut [u64]) -> InterpCounts {
    let f = input.flags;
    let (w, words) = (f.width, f.words);
    let rows = img.len() / w;
    let mut counts = InterpCounts::default();
    for r in 0..rows {
        let y = y0 + r;
        let (img, wt) = (&mut img[r * w..(r + 1) * w], &mut wt[r * w..(r + 1) * w]);
        let (fl, ho) = (&mut fl[r * words..(r + 1) * words], &mut ho[r * words..(r + 1) * words]);
        for j in 0..words {
            let plan = WordPlan::new(input, y, j);
            let mut acc = [[0f32; 4]; 64];
            if plan.plain != 0 {
                window_sum(input, y, j, plan.plain, Flags::USABLE, true, &mut acc);
            }
            if plan.complex != 0 {
                window_sum(input, y, j, plan.complex, Flags::HAS, false, &mut acc);
            }
            counts = counts + finish_word(input, y, j, &plan, &mut acc, img, wt, &mut fl[j], &mut ho[j]);
        }
    }
    counts
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
