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
//! Bit-sliced like [`super::reach`]: for 64 pixels of a row (a word) and one window offset,
//! the pixels that take the sample there are one AND of three words (the pixels needing
//! interpolation, the usable-sample plane shifted by the offset, the reachability plane;
//! complex pixels take every sample). A word is then summed one of two ways, by the number of
//! (pixel, sample) pairs it has:
//!
//! - **sparse**: pair by pair — words with few pixels to interpolate (dense sampling, where
//!   only edge-ambiguous samples and holes need it) or few samples;
//! - **dense**: all 64 pixels for every offset, each offset a contiguous pass over planar R,
//!   G, B rows (converted once per row, read 25 times) with the pixel's weight for the sample
//!   — the kernel weight or 0 — as a multiplier or, with AVX-512, a mask register, and the
//!   four sums of a chunk of pixels held in registers across the 25 offsets; then the mean or
//!   own colour of all pixels at once.
//!
//! Both add the same products in the same order as a per-pixel loop, so the result does not
//! depend on the path or on the instruction set the dense path is compiled for ([`Isa`]:
//! SSE2, AVX2 or AVX-512, chosen at run time) — bit for bit; the tests check every path
//! against a per-pixel loop. A sample colour that is not finite (a failed shade) is read as
//! black by its neighbours (its own pixel still shows it): the dense path's zero weights must
//! not meet an infinity.
//!
//! Measured with `edgepoint-bench epi` (cornell-point, 512², one core with AVX-512): the
//! dense path wins from ~32 pairs per word, so at 20 % and 5 % sample density almost every
//! word takes it (interpolation ~1.4 ms, from ~3 ms pair by pair); AVX2 from ~160 pairs, and
//! SSE2 never. Skipping the reachability masks in words with no edge near was measured
//! slower: at that image size an edge lies within reach of ~80 % of the words.
use super::code::EpiPixel;
use super::reach::{around, offset, Reach};
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
    /// [`Self::Filter`] for pixels that are not complex, but [`Self::Show`] where a stale
    /// point (age [`crate::render_cache::STALE_AGE`]: shaded before a move that may have
    /// changed it) lies in the pixel's 5 × 5 window ([`InterpInput::near_stale`]): a fresh
    /// sample amid stale ones (a moving box's new shadow on points shaded lit) shows as
    /// shaded, not diluted by them, and a stale one stays in its pixel. A complex pixel with
    /// a sample shows it as [`Self::Show`] does: its window mean ignores reachability, so
    /// filtered it would mix the surfaces its edges separate.
    FilterAwayFromStale,
}

/// Bit rows (`ceil(width / 64)` words a row) of the pixels whose 5 × 5 window holds a stale
/// point (age [`crate::render_cache::STALE_AGE`] or more, finite), into `out`: the stale
/// points' bits dilated by two pixels each way. `rows` is scratch (the row-dilated bits),
/// kept by the caller so that a frame in motion allocates nothing.
pub fn near_stale_rows(points: &PointImage, rows: &mut Vec<u64>, out: &mut Vec<u64>) {
    let (w, h) = (points.width as usize, points.height as usize);
    let words = w.div_ceil(64);
    out.clear();
    out.resize(h * words, 0);
    rows.clear();
    rows.resize(h * words, 0);
    if w == 0 {
        return;
    }
    // The stale points' bits, then dilated along their row in place: each word reads its
    // neighbours' bits before the dilation (the previous one kept aside, the next one not
    // yet written).
    rows.par_chunks_mut(words).zip(points.age.par_chunks(w)).for_each(|(row, ages)| {
        for (x, &a) in ages.iter().enumerate() {
            if (crate::render_cache::STALE_AGE..f32::INFINITY).contains(&a) {
                row[x / 64] |= 1 << (x % 64);
            }
        }
        let mut prev = 0u64;
        for j in 0..words {
            let (cur, next) = (row[j], row.get(j + 1).copied().unwrap_or(0));
            let up = cur << 1 | cur << 2 | prev >> 63 | prev >> 62;
            let down = cur >> 1 | cur >> 2 | next << 63 | next << 62;
            row[j] = (cur | up | down) & valid_bits(w, j);
            prev = cur;
        }
    });
    // Then across rows.
    let rows = &*rows;
    out.par_chunks_mut(words).enumerate().for_each(|(y, o)| {
        for r in y.saturating_sub(2)..(y + 3).min(h) {
            for (a, b) in o.iter_mut().zip(&rows[r * words..(r + 1) * words]) {
                *a |= b;
            }
        }
    });
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
    /// For [`OwnSample::FilterAwayFromStale`]: [`near_stale_rows`] of `points` (any other
    /// mode ignores it; empty reads as no stale point).
    pub near_stale: &'a [u64],
}

/// Rows per parallel task.
const BAND_ROWS: usize = 16;
/// Zeros before and after every planar row, so that a window offset of up to ±2 pixels reads
/// inside the row (16: the rows' words stay aligned alike).
const PAD: usize = 16;

/// The instruction set the interpolation is compiled for, chosen from what the CPU has (the
/// build targets baseline x86-64). It sets how the dense path keeps its lane masks, how many
/// pixels it sums at a time, and how many (pixel, sample) pairs a word needs for the dense
/// path to beat the sparse one — measured with `edgepoint-bench epi` (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// SSE2 (and any other architecture).
    Baseline,
    /// x86-64-v3: AVX2, BMI1/2, LZCNT, POPCNT.
    Avx2,
    /// x86-64-v4: AVX-512 F/BW/DQ/VL on top of v3.
    Avx512,
}

impl Isa {
    pub const ALL: [Isa; 3] = [Isa::Baseline, Isa::Avx2, Isa::Avx512];

    /// The widest instruction set this CPU runs, capped by the environment variable
    /// `EDGEPOINT_SIMD` (`baseline`, `avx2` or `avx512`; for measurements and debugging).
    pub fn detect() -> Isa {
        static DETECTED: std::sync::OnceLock<Isa> = std::sync::OnceLock::new();
        *DETECTED.get_or_init(|| {
            let cap = match std::env::var("EDGEPOINT_SIMD").as_deref() {
                Ok("baseline") => Isa::Baseline,
                Ok("avx2") => Isa::Avx2,
                Ok("avx512") | Err(_) => Isa::Avx512,
                Ok(other) => {
                    tracing::warn!("EDGEPOINT_SIMD={other:?} is not baseline, avx2 or avx512: ignored");
                    Isa::Avx512
                }
            };
            let isa = *[Isa::Avx512, Isa::Avx2].iter().find(|i| **i as u8 <= cap as u8 && i.available()).unwrap_or(&Isa::Baseline);
            tracing::debug!("interpolation compiled for {isa:?}");
            isa
        })
    }

    /// Whether this CPU runs `self`.
    pub fn available(self) -> bool {
        match self {
            Isa::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => {
                is_x86_feature_detected!("avx2")
                    && is_x86_feature_detected!("bmi1")
                    && is_x86_feature_detected!("bmi2")
                    && is_x86_feature_detected!("lzcnt")
                    && is_x86_feature_detected!("popcnt")
            }
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => {
                Isa::Avx2.available()
                    && is_x86_feature_detected!("avx512f")
                    && is_x86_feature_detected!("avx512bw")
                    && is_x86_feature_detected!("avx512dq")
                    && is_x86_feature_detected!("avx512vl")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }
}

/// Fills `image` (primary-region colours), `weights` (un-normalised reachable weight), the
/// `filled` bit rows (pixels whose colour came from reachable samples or their own) and the
/// `holes` bit rows (pixels without a sample in their window: background colour).
pub fn interpolate(input: &InterpInput, image: &mut [Vec3], weights: &mut [f32], filled: &mut [u64], holes: &mut [u64]) -> InterpCounts {
    interpolate_with(Isa::detect(), input, image, weights, filled, holes)
}

/// [`interpolate`] compiled for `isa`, which must be [`Isa::available`]. Every `isa` gives
/// the same result, bit for bit.
pub fn interpolate_with(isa: Isa, input: &InterpInput, image: &mut [Vec3], weights: &mut [f32], filled: &mut [u64], holes: &mut [u64]) -> InterpCounts {
    run(isa, isa.dense_from(), input, image, weights, filled, holes)
}

impl Isa {
    /// The (pixel, sample) pairs from which a word takes the dense path (measured with
    /// `edgepoint-bench epi`): SSE2 never, as its dense path never beats the sparse one.
    fn dense_from(self) -> u32 {
        match self {
            Isa::Baseline => u32::MAX,
            Isa::Avx2 => 160,
            Isa::Avx512 => 32,
        }
    }
}

/// [`interpolate_with`], words with at least `dense_from` (pixel, sample) pairs taking the
/// dense path.
fn run(isa: Isa, dense_from: u32, input: &InterpInput, image: &mut [Vec3], weights: &mut [f32], filled: &mut [u64], holes: &mut [u64]) -> InterpCounts {
    assert!(isa.available(), "{isa:?} is not available on this CPU");
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
        .map_init(
            || Scratch { rows: PlanarRows::new(w), sparse: SparseSums([[0.0; 4]; 64]), dense_from },
            |scratch, (b, (((img, wt), fl), ho))| {
                let band = Band { y0: b * BAND_ROWS, img, wt, fl, ho };
                match isa {
                    Isa::Baseline => interpolate_band::<16, ByTable>(input, scratch, band),
                    // SAFETY: `isa.available()` was asserted: the CPU has the features.
                    #[cfg(target_arch = "x86_64")]
                    Isa::Avx2 => unsafe { interpolate_band_avx2(input, scratch, band) },
                    // SAFETY: as above.
                    #[cfg(target_arch = "x86_64")]
                    Isa::Avx512 => unsafe { interpolate_band_avx512(input, scratch, band) },
                    #[cfg(not(target_arch = "x86_64"))]
                    _ => unreachable!("asserted available"),
                }
            },
        )
        .reduce(InterpCounts::default, |a, b| a + b)
}

/// [`interpolate_band`] compiled for x86-64-v3: chunks of 16 pixels (each sum two registers)
/// and lane masks from [`LANE_ONES`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,lzcnt,popcnt")]
fn interpolate_band_avx2(input: &InterpInput, scratch: &mut Scratch, band: Band) -> InterpCounts {
    interpolate_band::<16, ByTable>(input, scratch, band)
}

/// [`interpolate_band`] compiled for x86-64-v4: chunks of a whole word (each sum four of the
/// 32 registers) and lane masks in mask registers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512dq,avx512vl,avx2,bmi1,bmi2,lzcnt,popcnt")]
fn interpolate_band_avx512(input: &InterpInput, scratch: &mut Scratch, band: Band) -> InterpCounts {
    interpolate_band::<64, ByMaskRegisters>(input, scratch, band)
}

/// Per-task buffers and settings.
struct Scratch {
    rows: PlanarRows,
    sparse: SparseSums,
    /// See [`run`].
    dense_from: u32,
}

/// The output rows of one parallel task, from row `y0`.
struct Band<'a> {
    y0: usize,
    img: &'a mut [Vec3],
    wt: &'a mut [f32],
    fl: &'a mut [u64],
    ho: &'a mut [u64],
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
            OwnSample::FilterAwayFromStale => (complex & has) | (usable & input.near_stale.get(y * f.words + j).copied().unwrap_or(0)),
        } & valid;
        let need = valid & !own;
        WordPlan { valid, has, own, plain: need & !complex, complex: need & complex }
    }

    fn need(&self) -> u64 {
        self.plain | self.complex
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

/// Rows `y0 ..` (as many as the band holds). The dense path sums `C` pixels at a time with
/// `K`.
#[inline(always)]
fn interpolate_band<const C: usize, K: DenseSums>(input: &InterpInput, scratch: &mut Scratch, band: Band) -> InterpCounts {
    let f = input.flags;
    let (w, h, words) = (f.width, f.height, f.words);
    let Band { y0, img, wt, fl, ho } = band;
    let color = &input.points.color;
    let mut counts = InterpCounts::default();
    for r in 0..img.len() / w {
        let y = y0 + r;
        let (img, wt) = (&mut img[r * w..(r + 1) * w], &mut wt[r * w..(r + 1) * w]);
        for j in 0..words {
            let plan = WordPlan::new(input, y, j);
            let (x0, n) = (64 * j, (w - 64 * j).min(64));
            let out = WordOut { img: &mut img[x0..x0 + n], wt: &mut wt[x0..x0 + n], own: &color[y * w + x0..][..n] };
            let need = plan.need();
            let summed = if need == 0 {
                // Every pixel shows its own sample (most words of dense sampling).
                out.img.copy_from_slice(out.own);
                out.wt.fill(input.kernel.0[12]);
                0
            } else {
                let bits = word_bits(input, y, j, &plan);
                let pairs: u32 = bits.iter().map(|b| b.count_ones()).sum();
                if pairs < scratch.dense_from {
                    scratch.sparse.gather(color, w, y, x0, need, &bits, &input.kernel.0);
                    finish_sparse(input, &plan, &scratch.sparse, out)
                } else {
                    let win = scratch.rows.window(color, w, h, y);
                    dense_word::<C, K>(input, &plan, &win.word(j), &bits, win.centre_finite(), out)
                }
            };
            let missing = need & !summed;
            let mut counts_word = InterpCounts::default();
            let mut still_missing = missing;
            if missing != 0 && input.options.fallback {
                still_missing = fallback(input, &mut scratch.sparse, y, j, missing, &mut img[x0..x0 + n]);
                counts_word.fallback = (missing & !still_missing).count_ones();
            }
            fl[r * words + j] = plan.own | (need & summed);
            ho[r * words + j] = still_missing;
            // Pixel counts: with a point / without a point but coloured / background.
            counts_word.with_point = (plan.has & plan.valid).count_ones();
            counts_word.empty = (still_missing & !plan.has).count_ones();
            counts_word.filled = (plan.valid & !plan.has & !still_missing).count_ones();
            counts = counts + counts_word;
        }
    }
    counts
}

/// Per window index `k`, the pixels of the word that take the sample at offset `k`: the
/// non-complex ones needing interpolation where a usable sample is reachable, and the complex
/// ones wherever there is a sample.
#[inline(always)]
fn word_bits(input: &InterpInput, y: usize, j: usize, plan: &WordPlan) -> [u64; 25] {
    let mut bits = window_bits(input.flags, y, j, plan.plain, Flags::USABLE);
    if plan.plain != 0 {
        for (b, r) in bits.iter_mut().zip(input.reach.window(y, j)) {
            *b &= r;
        }
    }
    if plan.complex != 0 {
        for (b, c) in bits.iter_mut().zip(window_bits(input.flags, y, j, plan.complex, Flags::HAS)) {
            *b |= c;
        }
    }
    bits
}

/// Per window index, the pixels of `centres` (of word `j`, row `y`) whose window sample there
/// is in plane `plane`.
#[inline(always)]
fn window_bits(flags: &Flags, y: usize, j: usize, centres: u64, plane: usize) -> [u64; 25] {
    let mut out = [0u64; 25];
    if centres == 0 {
        return out;
    }
    for (dy, row) in out.chunks_exact_mut(5).enumerate() {
        let Some(yy) = (y + dy).checked_sub(2).filter(|&yy| yy < flags.height) else { continue };
        let [a, b, c] = around(flags.row(yy, plane), j);
        // Bit i of the shift for dx is bit i + dx of the row around the word.
        let shifted = [b << 2 | a >> 62, b << 1 | a >> 63, b, b >> 1 | c << 63, b >> 2 | c << 62];
        for (o, s) in row.iter_mut().zip(shifted) {
            *o = centres & s;
        }
    }
    out
}

/// The sample colours of the five rows around the current one as planar rows (R, G, B), with
/// [`PAD`] zeros either side, so that the dense path reads every window offset as
/// contiguous memory: a ring of five rows (row `y` in slot `y % 5`), and a sixth of zeros
/// standing for rows outside the image. Rows are converted when a dense word first needs them
/// (each then serves the 5 rows around it).
///
/// Non-finite colours (a failed shade) are stored as 0: the dense path multiplies every
/// window colour by a weight that is 0 for the samples a pixel does not take, and 0 · ∞ would
/// poison the sum. The sparse path reads them the same way, so they spread as black; the
/// pixel holding one still shows it.
struct PlanarRows {
    /// Floats per planar row: `PAD + 64 * words + PAD`.
    stride: usize,
    data: Vec<f32>,
    /// Image row held by each slot (`usize::MAX`: none).
    held: [usize; 5],
    /// Whether the row held by each slot had only finite colours.
    finite: [bool; 5],
}

impl PlanarRows {
    const ZERO_SLOT: usize = 5;

    fn new(w: usize) -> Self {
        let stride = PAD + 64 * w.div_ceil(64) + PAD;
        PlanarRows { stride, data: vec![0.0; 6 * 3 * stride], held: [usize::MAX; 5], finite: [true; 5] }
    }

    /// Converts row `y` of `color` (rows `w` wide) into its slot, unless it is there.
    #[inline(always)]
    fn load(&mut self, color: &[Vec3], w: usize, y: usize) {
        let s = y % 5;
        if self.held[s] == y {
            return;
        }
        let src = &color[y * w..(y + 1) * w];
        let slot = &mut self.data[s * 3 * self.stride..][..3 * self.stride];
        let (r, gb) = slot.split_at_mut(self.stride);
        let (g, b) = gb.split_at_mut(self.stride);
        let mut bad = false;
        for (((c, r), g), b) in src.iter().zip(&mut r[PAD..]).zip(&mut g[PAD..]).zip(&mut b[PAD..]) {
            // `|`, not `||`: no branch, so that the loop is vectorised.
            bad |= !c.x.is_finite() | !c.y.is_finite() | !c.z.is_finite();
            (*r, *g, *b) = (finite_or_0(c.x), finite_or_0(c.y), finite_or_0(c.z));
        }
        (self.held[s], self.finite[s]) = (y, !bad);
    }

    /// The rows of the window of row `y` of an image `w` × `h`, converted if they are not held.
    #[inline(always)]
    fn window(&mut self, color: &[Vec3], w: usize, h: usize, y: usize) -> Window<'_> {
        for yy in y.saturating_sub(2)..(y + 3).min(h) {
            self.load(color, w, yy);
        }
        let rows = std::array::from_fn(|r| {
            let slot = (y + r).checked_sub(2).filter(|&yy| yy < h).map_or(Self::ZERO_SLOT, |yy| yy % 5);
            std::array::from_fn(|c| &self.data[(3 * slot + c) * self.stride..][..self.stride])
        });
        Window { rows, centre_finite: self.finite[y % 5] }
    }
}

#[inline(always)]
fn finite_or_0(v: f32) -> f32 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// The planar rows of the window of one row (see [`PlanarRows::window`]).
struct Window<'a> {
    rows: [[&'a [f32]; 3]; 5],
    centre_finite: bool,
}

impl<'a> Window<'a> {
    /// The colours word `j`'s windows read: per window row and channel, the 64 + 4 values
    /// from two pixels left of the word to two right of it.
    #[inline(always)]
    fn word(&self, j: usize) -> WordSource<'a> {
        // Written out: `[T; N]::map` is not always inlined, and a call in this loop costs more
        // than the work.
        let at = PAD + 64 * j - 2;
        let part = |p: &'a [f32]| -> &'a [f32; 68] { p[at..at + 68].try_into().unwrap() };
        let rgb = |[r, g, b]: [&'a [f32]; 3]| [part(r), part(g), part(b)];
        let [a, b, c, d, e] = self.rows;
        WordSource([rgb(a), rgb(b), rgb(c), rgb(d), rgb(e)])
    }

    /// Whether the centre row's colours are all finite.
    fn centre_finite(&self) -> bool {
        self.centre_finite
    }
}

/// Colours around one word: `[window row][channel]`, index `i + dx + 2` for pixel `i` of the
/// word and horizontal offset `dx`.
struct WordSource<'a>([[&'a [f32; 68]; 3]; 5]);

/// The sparse path's sums: per pixel (Σ w · R, Σ w · G, Σ w · B, Σ w), kept across words
/// (only the pixels summed are cleared).
struct SparseSums([[f32; 4]; 64]);

impl SparseSums {
    /// The sparse path: the same sums, one (pixel, sample) pair at a time, for words where
    /// few pixels take few samples. Reads the colours of row `y` (`w` wide) around pixels
    /// `x0 ..`; only the pixels of `need` are summed.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn gather(&mut self, color: &[Vec3], w: usize, y: usize, x0: usize, need: u64, bits: &[u64; 25], kernel: &[f32; 25]) {
        each_bit(need, |i| self.0[i] = [0.0; 4]);
        for (k, (&bits, &wk)) in bits.iter().zip(kernel).enumerate() {
            let (dx, dy) = offset(k);
            // Pixel i's sample: index base + i (the bits are 0 outside the image).
            let base = ((y as isize + dy as isize) * w as isize + x0 as isize + dx as isize) as usize;
            each_bit(bits & need, |i| {
                let c = color[base.wrapping_add(i)];
                let s = &mut self.0[i];
                s[0] += wk * finite_or_0(c.x);
                s[1] += wk * finite_or_0(c.y);
                s[2] += wk * finite_or_0(c.z);
                s[3] += wk;
            });
        }
    }
}

/// Calls `f(i)` for every set bit `i` of `bits`, lowest first.
#[inline(always)]
fn each_bit(mut bits: u64, mut f: impl FnMut(usize)) {
    while bits != 0 {
        let i = bits.trailing_zeros() as usize & 63;
        bits &= bits - 1;
        f(i);
    }
}

/// The output of one word: its pixels' colours and weights, and their own samples' colours.
struct WordOut<'a> {
    img: &'a mut [Vec3],
    wt: &'a mut [f32],
    own: &'a [Vec3],
}

/// The dense path's sums of `C` pixels from bit `shift` of a word: `[Σ w · R, Σ w · G,
/// Σ w · B, Σ w]` over the window offsets `k` whose bit each has in `bits[k]`, in window
/// order, with one product and one sum per sample taken — the same operations in the same
/// order as [`SparseSums::gather`] or a per-pixel loop, so the results are equal bit for bit.
/// The sums stay in registers across the 25 offsets.
trait DenseSums {
    /// # Safety
    /// The CPU must have the instruction set the implementation is written for.
    unsafe fn sums<const C: usize>(src: &WordSource, bits: &[u64; 25], kernel: &[f32; 25], shift: usize) -> [[f32; C]; 4];
}

/// Any instruction set: each byte of lane bits selects a row of 0s and 1s to multiply the
/// weight by, so that a pixel's weight for a sample is a multiplier rather than a branch or a
/// select of the sum (which keeps the sums in registers): 2 loads and 2 products per 16
/// pixels instead of a broadcast, compare and widening. Exact: `wk · 1 == wk`, and
/// `s + 0 · c == s` for finite `c` (see [`PlanarRows`]) and sums that are never -0.
struct ByTable;

impl DenseSums for ByTable {
    #[inline(always)]
    unsafe fn sums<const C: usize>(src: &WordSource, bits: &[u64; 25], kernel: &[f32; 25], shift: usize) -> [[f32; C]; 4] {
        let (mut ar, mut ag, mut ab, mut aw) = ([0f32; C], [0f32; C], [0f32; C], [0f32; C]);
        for (dy, rgb) in src.0.iter().enumerate() {
            for dx in 0..5 {
                let k = 5 * dy + dx;
                let wk = kernel[k];
                let at = shift + dx;
                let part = |p: &[f32; 68]| -> [f32; C] { p[at..at + C].try_into().unwrap() };
                let (r, g, b) = (part(rgb[0]), part(rgb[1]), part(rgb[2]));
                let mut ones = [0f32; C];
                for (q, o) in ones.chunks_exact_mut(8).enumerate() {
                    o.copy_from_slice(&LANE_ONES[((bits[k] >> (shift + 8 * q)) & 0xFF) as usize]);
                }
                for l in 0..C {
                    let wl = wk * ones[l];
                    ar[l] += wl * r[l];
                    ag[l] += wl * g[l];
                    ab[l] += wl * b[l];
                    aw[l] += wl;
                }
            }
        }
        [ar, ag, ab, aw]
    }
}

/// AVX-512: the lane bits are a mask register, and each product is added under it (a pixel
/// without a sample at an offset keeps its sums untouched): per 16 pixels and offset, 3
/// products and 4 masked sums.
#[cfg(target_arch = "x86_64")]
struct ByMaskRegisters;

#[cfg(target_arch = "x86_64")]
impl DenseSums for ByMaskRegisters {
    #[inline(always)]
    unsafe fn sums<const C: usize>(src: &WordSource, bits: &[u64; 25], kernel: &[f32; 25], shift: usize) -> [[f32; C]; 4] {
        // SAFETY: the caller guarantees AVX-512F.
        unsafe { sums_avx512::<C>(src, bits, kernel, shift) }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn sums_avx512<const C: usize>(src: &WordSource, bits: &[u64; 25], kernel: &[f32; 25], shift: usize) -> [[f32; C]; 4] {
    use std::arch::x86_64::{__m512, _mm512_loadu_ps, _mm512_mask_add_ps, _mm512_mul_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps};
    let mut acc = [[_mm512_setzero_ps(); 4]; 4];
    let groups = C / 16;
    for (dy, rgb) in src.0.iter().enumerate() {
        for dx in 0..5 {
            let k = 5 * dy + dx;
            let wk = _mm512_set1_ps(kernel[k]);
            for (q, a) in acc.iter_mut().enumerate().take(groups) {
                let m = (bits[k] >> (shift + 16 * q)) as u16;
                let at = shift + 16 * q + dx;
                for (ch, p) in rgb.iter().enumerate() {
                    let c: &[f32; 16] = p[at..at + 16].try_into().unwrap();
                    // SAFETY: `c` holds the 16 floats read.
                    let v: __m512 = unsafe { _mm512_loadu_ps(c.as_ptr()) };
                    a[ch] = _mm512_mask_add_ps(a[ch], m, a[ch], _mm512_mul_ps(wk, v));
                }
                a[3] = _mm512_mask_add_ps(a[3], m, a[3], wk);
            }
        }
    }
    let mut out = [[0f32; C]; 4];
    for (q, a) in acc.iter().enumerate().take(groups) {
        for (o, v) in out.iter_mut().zip(a) {
            let o: &mut [f32; 16] = (&mut o[16 * q..16 * q + 16]).try_into().unwrap();
            // SAFETY: `o` holds the 16 floats written.
            unsafe { _mm512_storeu_ps(o.as_mut_ptr(), *v) };
        }
    }
    out
}

/// Per byte of lane bits, 1.0 for the lanes set and 0.0 for the others.
static LANE_ONES: [[f32; 8]; 256] = {
    let mut t = [[0f32; 8]; 256];
    let mut m = 0;
    while m < 256 {
        let mut l = 0;
        while l < 8 {
            t[m][l] = if m & (1 << l) != 0 { 1.0 } else { 0.0 };
            l += 1;
        }
        m += 1;
    }
    t
};

/// The dense path: every pixel of the word, `C` at a time (a divisor of 64), sums
/// `kernel[k] · colour` and `kernel[k]` over the window offsets `k` whose bit it has in
/// `bits[k]`, in window order, with one product and one sum per sample taken — the same
/// operations in the same order as [`SparseSums::gather`] or a per-pixel loop, so the results
/// are equal bit for bit. The sums stay in registers; each chunk then takes its own colour,
/// window mean or the background, all lanes at once. Returns the pixels with a positive sum.
#[inline(always)]
fn dense_word<const C: usize, K: DenseSums>(input: &InterpInput, plan: &WordPlan, src: &WordSource, bits: &[u64; 25], centre_finite: bool, out: WordOut) -> u64 {
    let kernel = &input.kernel.0;
    let centre_weight = kernel[12];
    let bg = input.background.to_array();
    let any = bits.iter().fold(0, |a, b| a | b);
    let WordOut { img, wt, own } = out;
    let n = img.len();
    let mut summed = 0u64;
    for c in 0..64 / C {
        let shift = C * c;
        let [ar, ag, ab, aw] = if any >> shift & (u64::MAX >> (64 - C)) != 0 {
            // SAFETY: `K` runs on this CPU (see `interpolate_with`).
            unsafe { K::sums::<C>(src, bits, kernel, shift) }
        } else {
            [[0.0; C]; 4]
        };
        // Own colour (the window's centre), window mean or background.
        let centre = |p: &[f32; 68]| -> [f32; C] { p[2 + shift..2 + shift + C].try_into().unwrap() };
        let (r, g, b) = (centre(src.0[2][0]), centre(src.0[2][1]), centre(src.0[2][2]));
        let (mut or, mut og, mut ob, mut ow) = ([0f32; C], [0f32; C], [0f32; C], [0f32; C]);
        for q in 0..C / 16 {
            // 16 lanes at a time, as the masks: bit tests and the bits of a comparison stay
            // in one register.
            let own = (plan.own >> (shift + 16 * q)) as u16;
            let mut got = 0u16;
            for l in 16 * q..16 * q + 16 {
                let o = own & (1 << (l - 16 * q)) != 0;
                let s = aw[l];
                let f = s > 0.0;
                let inv = 1.0 / s;
                or[l] = if o { r[l] } else if f { ar[l] * inv } else { bg[0] };
                og[l] = if o { g[l] } else if f { ag[l] * inv } else { bg[1] };
                ob[l] = if o { b[l] } else if f { ab[l] * inv } else { bg[2] };
                ow[l] = if o { centre_weight } else { s };
                got |= u16::from(f) << (l - 16 * q);
            }
            summed |= u64::from(got) << (shift + 16 * q);
        }
        if shift + C <= n {
            let img: &mut [Vec3; C] = (&mut img[shift..shift + C]).try_into().unwrap();
            for l in 0..C {
                img[l] = Vec3::new(or[l], og[l], ob[l]);
            }
            wt[shift..shift + C].copy_from_slice(&ow);
        } else {
            for l in 0..n.saturating_sub(shift) {
                (img[shift + l], wt[shift + l]) = (Vec3::new(or[l], og[l], ob[l]), ow[l]);
            }
        }
    }
    if !centre_finite {
        // The planar row holds 0 for a non-finite colour; its own pixel shows it as shaded.
        each_bit(plan.own & valid_bits(n, 0), |i| img[i] = own[i]);
    }
    summed & plan.need()
}

/// Colours and weights of a word from sparse sums: the own samples copied, then each pixel
/// needing interpolation. Returns the pixels with a positive sum.
#[inline(always)]
fn finish_sparse(input: &InterpInput, plan: &WordPlan, sums: &SparseSums, out: WordOut) -> u64 {
    let WordOut { img, wt, own } = out;
    img.copy_from_slice(own);
    wt.fill(input.kernel.0[12]);
    let mut summed = 0u64;
    each_bit(plan.need(), |i| {
        let [r, g, b, s] = sums.0[i];
        if s > 0.0 {
            let inv = 1.0 / s;
            img[i] = Vec3::new(r * inv, g * inv, b * inv);
            summed |= 1 << i;
        } else {
            img[i] = input.background;
        }
        wt[i] = s;
    });
    summed
}

/// [`InterpOptions::fallback`]: the pixels of `missing` (word `j` of row `y`, reaching no
/// sample) take the unconstrained mean of every sample of their window (their weights stay
/// 0). Returns the pixels still without a colour.
fn fallback(input: &InterpInput, sums: &mut SparseSums, y: usize, j: usize, missing: u64, img: &mut [Vec3]) -> u64 {
    let bits = window_bits(input.flags, y, j, missing, Flags::HAS);
    sums.gather(&input.points.color, input.flags.width, y, 64 * j, missing, &bits, &input.kernel.0);
    let mut still = missing;
    each_bit(missing, |i| {
        let [r, g, b, s] = sums.0[i];
        if s > 0.0 {
            let inv = 1.0 / s;
            img[i] = Vec3::new(r * inv, g * inv, b * inv);
            still &= !(1 << i);
        }
    });
    still
}

#[cfg(test)]
mod tests;
