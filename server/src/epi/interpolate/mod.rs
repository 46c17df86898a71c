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
//! reaches no sample falls back to the unconstrained mean of its window (what the Render
//! Cache baseline shows there), and to the background when its window has no sample at
//! all; its weight stays 0 so sampling treats it as unreached.
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
    /// Fall back to the unconstrained window mean where no sample is reachable.
    pub fallback: bool,
}

impl Default for InterpOptions {
    fn default() -> Self {
        InterpOptions { sigma: DEFAULT_SIGMA, own_sample: OwnSample::Show, fallback: true }
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

/// Fills `image` (primary-region colours), `weights` (un-normalised reachable weight) and
/// the `filled` bit rows (pixels whose colour came from reachable samples or their own).
pub fn interpolate(input: &InterpInput, image: &mut [Vec3], weights: &mut [f32], filled: &mut [u64]) -> InterpCounts {
    let (w, words) = (input.flags.width, input.flags.words);
    if w == 0 || words == 0 {
        return InterpCounts::default();
    }
    image
        .par_chunks_mut(w)
        .zip(weights.par_chunks_mut(w))
        .zip(filled.par_chunks_mut(words))
        .enumerate()
        .map(|(y, ((img, wt), fl))| interpolate_row(input, y, img, wt, fl))
        .reduce(InterpCounts::default, |a, b| a + b)
}

/// Adds `weight * colour` of the samples at window offset `k` of the pixels in `bits`.
#[inline(always)]
fn gather(points: &PointImage, w: usize, y: usize, x0: usize, k: usize, weight: f32, mut bits: u64, acc: &mut [[f32; 4]; 64]) {
    let (dx, dy) = offset(k);
    let base = (y as i64 + dy as i64) as usize * w;
    while bits != 0 {
        let i = bits.trailing_zeros() as usize;
        bits &= bits - 1;
        let s = base + (x0 as i64 + i as i64 + dx as i64) as usize;
        let c = points.color[s];
        let a = &mut acc[i];
        a[0] += weight * c.x;
        a[1] += weight * c.y;
        a[2] += weight * c.z;
        a[3] += weight;
    }
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
        if reachable {
            bits &= input.reach.bits(y, j, k);
        }
        if bits != 0 {
            gather(input.points, w, y, 64 * j, k, input.kernel.0[k], bits, acc);
        }
    }
}

fn interpolate_row(input: &InterpInput, y: usize, img: &mut [Vec3], wt: &mut [f32], fl: &mut [u64]) -> InterpCounts {
    let (w, words) = (input.flags.width, input.flags.words);
    let f = input.flags;
    let mut counts = InterpCounts::default();
    let mut acc = [[0f32; 4]; 64];
    let centre_weight = input.kernel.0[12];
    for j in 0..words {
        let x0 = 64 * j;
        let n = (w - x0).min(64);
        let valid = if n == 64 { !0u64 } else { (1u64 << n) - 1 };
        let has = f.row(y, Flags::HAS)[j];
        let usable = f.row(y, Flags::USABLE)[j];
        let complex = f.row(y, Flags::COMPLEX)[j];
        let own = match input.options.own_sample {
            OwnSample::Show => usable | (complex & has),
            OwnSample::Filter => 0,
        } & valid;
        let need = valid & !own;
        let plain = need & !complex;
        let cx = need & complex;
        if need != 0 {
            acc = [[0f32; 4]; 64];
            if plain != 0 {
                window_sum(input, y, j, plain, Flags::USABLE, true, &mut acc);
            }
            if cx != 0 {
                window_sum(input, y, j, cx, Flags::HAS, false, &mut acc);
            }
        }
        let mut filled_word = own;
        let mut missing = 0u64;
        for i in 0..n {
            let x = x0 + i;
            if (own >> i) & 1 == 1 {
                img[x] = input.points.color[y * w + x];
                wt[x] = centre_weight;
            } else if acc[i][3] > 0.0 {
                let a = acc[i];
                let inv = 1.0 / a[3];
                img[x] = Vec3::new(a[0] * inv, a[1] * inv, a[2] * inv);
                wt[x] = a[3];
                filled_word |= 1 << i;
            } else {
                wt[x] = 0.0;
                missing |= 1 << i;
            }
        }
        fl[j] = filled_word;
        let with_point = (has & valid).count_ones();
        counts.with_point += with_point;
        let mut still_missing = missing;
        if missing != 0 && input.options.fallback {
            for i in 0..64 {
                if (missing >> i) & 1 == 1 {
                    acc[i] = [0.0; 4];
                }
            }
            window_sum(input, y, j, missing, Flags::HAS, false, &mut acc);
            for i in 0..n {
                if (missing >> i) & 1 == 1 && acc[i][3] > 0.0 {
                    let a = acc[i];
                    let inv = 1.0 / a[3];
                    img[x0 + i] = Vec3::new(a[0] * inv, a[1] * inv, a[2] * inv);
                    still_missing &= !(1 << i);
                    counts.fallback += 1;
                }
            }
        }
        for i in 0..n {
            if (still_missing >> i) & 1 == 1 {
                img[x0 + i] = input.background;
            }
        }
        // Pixel counts: with a point / without a point but coloured / background.
        counts.empty += (still_missing & !has).count_ones();
        counts.filled += (valid & !has & !still_missing).count_ones();
    }
    counts
}

#[cfg(test)]
mod tests;
