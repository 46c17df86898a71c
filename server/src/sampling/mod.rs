//! Prioritized sampling, paper 000 §5.3 (as in the Render Cache, Walter et al. 1999 §3.4):
//! every pixel gets a priority from the last frame — pixels without a point get priority
//! inversely related to the un-normalised interpolation weight (no reachable point ->
//! highest), pixels with a point get a priority growing with the point's age — and the
//! frame's budget of pixels is picked by error diffusion (serpentine Floyd–Steinberg) over
//! the priority image scaled to sum to the budget, so samples are spread evenly in
//! proportion to priority. Each pick gets a jittered position inside its pixel.
//!
//! The scan's offset and the dither's thresholds change per frame (hashed), so pixels of
//! equal priority are not picked in the same pattern every frame. No networking, no allocation per frame
//! once the buffers exist.
use rayon::prelude::*;

/// Sampling settings the user controls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplingConfig {
    /// Pixels per new sample (default 64; paper: 40–125).
    pub sparseness: f64,
    /// Age in frames at which a point's priority reaches its maximum (default 120).
    pub max_age_frames: f32,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        Self { sparseness: 64.0, max_age_frames: 120.0 }
    }
}

impl SamplingConfig {
    /// The per-frame sample budget for `pixels` pixels: `ceil(pixels / sparseness)`, at least
    /// 1 for a non-empty image; a non-finite or < 1 sparseness counts as 1 (every pixel).
    pub fn budget(&self, pixels: usize) -> usize {
        if pixels == 0 {
            return 0;
        }
        let s = if self.sparseness.is_finite() && self.sparseness >= 1.0 { self.sparseness } else { 1.0 };
        ((pixels as f64 / s).ceil() as usize).clamp(1, pixels)
    }
}

/// One picked pixel and the jittered continuous image position to shade inside it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelRequest {
    pub x: u32,
    pub y: u32,
    /// Continuous image position in [x, x+1) x [y, y+1) (DESIGN.md conventions).
    pub sx: f32,
    pub sy: f32,
    /// The cached point the pick shades again ([`aim_at_points`]; with [`AIM_IN_PIXEL`]:
    /// anywhere in its pixel), or [`crate::render_cache::NO_POINT`] for a jittered pick.
    pub point: u32,
}

/// Priority of a pixel without a point and no reachable point at all.
pub const PRIORITY_UNREACHED: f32 = 1.0;
/// Priority of a pixel with a freshly shaded point (never 0, so a converged image keeps
/// being refreshed everywhere).
pub const PRIORITY_FRESH_POINT: f32 = 0.02;
/// Priority of a pixel whose point reached `max_age_frames`.
pub const PRIORITY_OLD_POINT: f32 = 0.3;
/// Priority of a pixel whose point is stale ([`crate::render_cache::STALE_AGE`]): shaded
/// before a change that can alter it (its object moved, or a moved object can shadow it).
/// Above any merely old point, so that what a move changed is re-shaded first; below a
/// pixel no sample reaches.
pub const PRIORITY_STALE_POINT: f32 = 0.6;

/// Priority of one pixel (see the module doc). `weight` is the un-normalised interpolation
/// weight, `age` the age of the pixel's point in frames (`f32::INFINITY` if it has none).
#[inline]
pub fn priority(weight: f32, age: f32, max_age_frames: f32) -> f32 {
    // Every case computed and the answer selected, without branches: the priority loop
    // over the image then vectorises (the same values as choosing first).
    let weight = if weight.is_finite() { weight.max(0.0) } else { 0.0 };
    let unreached = PRIORITY_UNREACHED / (1.0 + weight);
    let a = if max_age_frames > 0.0 { (age.max(0.0) / max_age_frames).min(1.0) } else { 1.0 };
    let aged = PRIORITY_FRESH_POINT + (PRIORITY_OLD_POINT - PRIORITY_FRESH_POINT) * a;
    let point = if age >= crate::render_cache::STALE_AGE { PRIORITY_STALE_POINT } else { aged };
    if age.is_nan() || age == f32::INFINITY {
        unreached
    } else {
        point
    }
}

/// Priority of a pixel with a starved region (the edge-and-point image's
/// `Epi::starved`: a simple pixel whose secondary region no sample reached, so it shows its
/// primary colour alone): as a stale point's — part of the pixel shows the wrong colour —
/// below a pixel no sample reaches at all.
pub const PRIORITY_STARVED_REGION: f32 = PRIORITY_STALE_POINT;

/// The most a point's priority reaches with its gain ([`priority_gained`]): below a stale
/// point's, so that what a move changed and what no sample reaches still go first.
pub const PRIORITY_GAINED_MAX: f32 = 0.5;

/// [`priority`] with a point's (fresh or aged, not stale) priority multiplied by `gain`
/// (a non-finite or negative gain counts as 1) and capped at [`PRIORITY_GAINED_MAX`]. With
/// the age ramp a pixel's rate of picks grows about as the gain's 0.8th power (the ramp's
/// floor keeps it below linear): a gain of σ over the image's σ comes close to picks in
/// proportion to σ, which minimises the squared error (`render_cache/converge.rs`).
#[inline]
pub fn priority_gained(weight: f32, age: f32, max_age_frames: f32, gain: f32) -> f32 {
    let p = priority(weight, age, max_age_frames);
    let gain = if gain >= 0.0 && gain.is_finite() { gain } else { 1.0 };
    let point = age < crate::render_cache::STALE_AGE;
    if point {
        (p * gain).min(PRIORITY_GAINED_MAX.max(p))
    } else {
        p
    }
}

/// The sum of a row's priorities in f64: four partial sums over the columns `x % 4`,
/// added pairwise (four independent additions per step instead of one long chain).
#[inline]
pub fn row_sum(row: &[f32]) -> f64 {
    let mut acc = [0.0f64; 4];
    let chunks = row.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        for k in 0..4 {
            acc[k] += c[k] as f64;
        }
    }
    for (k, &p) in rest.iter().enumerate() {
        acc[k] += p as f64;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// The largest of a row's priorities (never NaN: see [`priority`]), over eight lanes: one
/// running maximum is a chain of dependent compares.
#[inline]
fn row_max(row: &[f32]) -> f32 {
    let mut m = [0.0f32; 8];
    let chunks = row.chunks_exact(8);
    let tail = chunks.remainder();
    for c in chunks {
        for k in 0..8 {
            m[k] = m[k].max(c[k]);
        }
    }
    tail.iter().chain(&m).fold(0.0f32, |a, &p| a.max(p))
}

/// Picks the pixels to shade each frame.
pub struct Sampler {
    width: u32,
    height: u32,
    seed: u64,
    frame: u64,
    /// Per pixel priority of this frame (before scaling to the budget).
    prio: Vec<f32>,
    /// Per row: the sum of its priorities (summed in row order into the frame's total, so
    /// the total does not depend on how the rows were split among threads).
    row_sums: Vec<f64>,
    /// Working buffers of the bands of rows dithered in parallel.
    bands: Vec<DitherBand>,
}

/// One band of rows of the dithering, with its own buffers and picks.
#[derive(Default)]
struct DitherBand {
    /// Diffused error of the current and the next row, by logical column + 1 (one guard
    /// cell each side).
    err_cur: Vec<f32>,
    err_next: Vec<f32>,
    /// The row being dithered, in scan order: scaled priority plus the error diffused into
    /// it from the row before (`a`), the same minus the 7/16 a pick passes on (`b`), the
    /// threshold (`t`), and the diffused value the scan reaches at each pixel (`v`).
    a: Vec<f32>,
    b: Vec<f32>,
    t: Vec<f32>,
    v: Vec<f32>,
    picks: Vec<PixelRequest>,
}

impl DitherBand {
    fn new(w: usize) -> Self {
        DitherBand { err_cur: vec![0.0; w + 2], err_next: vec![0.0; w + 2], a: vec![0.0; w], b: vec![0.0; w], t: vec![0.0; w], v: vec![0.0; w], picks: Vec::new() }
    }
}

/// Logical rows per band of the dithering. The error diffusion is serial along a band (a
/// chain of a compare, a select and a multiply-add per pixel), so bands run in parallel,
/// in pairs whose chains share the instructions ([`dither_pair_rows`]).
pub const DITHER_BAND_ROWS: usize = 64;
/// Rows of the band before that a band dithers first without keeping their picks. Started
/// from zero error, a band's first rows pick too often where priorities are low: the
/// steady-state error there is negative (each pick leaves about -1 behind), and a zero
/// start drops that debt — about one extra pick per 20 pixels of a sparse row per band.
/// A few rows bring the error field to its steady state (its memory is short).
pub const DITHER_WARM_UP_ROWS: usize = 8;

use crate::render_cache::NO_POINT;
use crate::rng::mix64;

/// Uniform in [0, 1) from the top 24 bits.
#[inline]
fn unit(h: u64) -> f32 {
    // Via i32: a single int-to-float instruction, unlike u64.
    ((h >> 40) as i32) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// `x + u` for `u` in [0, 1), kept below `x + 1` despite rounding.
#[inline]
fn inside_pixel(x: u32, u: f32) -> f32 {
    let v = x as f32 + u;
    let top = (x + 1) as f32;
    if v < top {
        v
    } else {
        f32::from_bits(top.to_bits() - 1)
    }
}

/// Converging at rest (issue 14 item 3, `render_cache/converge.rs`): a pick of a pixel that
/// shows a fresh point, whose sample the reconstruction can use (`usable(x, y)`), is aimed
/// at that point (`point`). Where its jittered position lies in the point's region of the
/// pixel (`in_region(x, y, jittered, at)`, both positions in the pixel's unit square; the
/// session asks `Epi::same_region`: anywhere in a pixel no edge crosses, the point's side of
/// a simple pixel's edge) it keeps that position and is marked [`AIM_IN_PIXEL`]: the cache
/// averages its sample into the point all the same, so the point converges to the mean of
/// its region — what the converged reference's pixel is made of — rather than to the value
/// at the one position it was first shaded at (on `cornell` with `gi` that difference had
/// held edge-and-point at 49.7–50.1 dB at 30 s with 43–66 samples per pixel; with it,
/// 50.4–50.6 dB with 43–63). Elsewhere it is aimed at the point's position inside the pixel
/// instead of a jittered one: the worker shades the same surface point again. A pixel
/// without a point, with a stale one (something changed it: it is replaced, not averaged),
/// or whose sample is edge-ambiguous keeps its jittered position and no point, so new
/// points still land elsewhere in it.
pub fn aim_at_points(
    picks: &mut [PixelRequest],
    points: &crate::render_cache::PointImage,
    usable: impl Fn(u32, u32) -> bool + Sync,
    in_region: impl Fn(u32, u32, [f32; 2], [f32; 2]) -> bool + Sync,
) {
    let w = points.width as usize;
    // In parallel: each pick reads three arrays of the point image at its own pixel, most of
    // them cache misses (the frame loop's other passes have run since).
    picks.par_chunks_mut(2048).for_each(|chunk| {
        for p in chunk {
            let i = p.y as usize * w + p.x as usize;
            let Some(&point) = points.point.get(i) else { continue };
            if point != NO_POINT && points.age[i] < crate::render_cache::STALE_AGE && usable(p.x, p.y) {
                debug_assert!(point < AIM_IN_PIXEL, "point slots stay below the flag bit");
                let at = points.subpixel[i];
                if in_region(p.x, p.y, [p.sx - p.x as f32, p.sy - p.y as f32], at) {
                    p.point = point | AIM_IN_PIXEL;
                } else {
                    (p.sx, p.sy, p.point) = (inside_pixel(p.x, at[0]), inside_pixel(p.y, at[1]), point);
                }
            }
        }
    });
}

/// Picks of pixels with a starved region (see [`PRIORITY_STARVED_REGION`]) moved into it:
/// `position(x, y, u, v)` (the session asks `Epi::secondary_position`, with the pick's
/// jitter in its pixel as `u`, `v`) gives the place in the pixel's unit square, `None` for a
/// pixel without one. Such a pick shades a new point there, not a cached one: after
/// [`aim_at_points`], which may have aimed it at the pixel's point.
pub fn aim_into_starved(picks: &mut [PixelRequest], position: impl Fn(u32, u32, f32, f32) -> Option<[f32; 2]> + Sync) {
    picks.par_chunks_mut(2048).for_each(|chunk| {
        for p in chunk {
            if let Some([u, v]) = position(p.x, p.y, p.sx - p.x as f32, p.sy - p.y as f32) {
                (p.sx, p.sy, p.point) = (inside_pixel(p.x, u), inside_pixel(p.y, v), NO_POINT);
            }
        }
    });
}

/// Flag bit of [`PixelRequest::point`] ([`aim_at_points`]): the pick is a sample of the
/// point anywhere in its pixel, not at its position. (Point slots are far below 2³¹: the
/// cache holds a few points per pixel.)
pub const AIM_IN_PIXEL: u32 = 1 << 31;

/// The point slot a pick or request was aimed at and whether anywhere in its pixel
/// ([`AIM_IN_PIXEL`]); [`crate::render_cache::NO_POINT`] stays itself.
pub fn aimed_point(point: u32) -> (u32, bool) {
    if point != NO_POINT && point & AIM_IN_PIXEL != 0 {
        (point & !AIM_IN_PIXEL, true)
    } else {
        (point, false)
    }
}

/// Of the priorities `c` at scale `s`: how many saturate (`p · s ≥ 1`, picked for sure), and
/// the sum of the others. Eight lanes of counts and sums, added at the end: the compare and
/// the select vectorise, where one running f64 sum was a chain of dependent additions (a
/// water-filling pass took about 2 ns a pixel).
#[inline]
fn saturation(c: &[f32], s: f64) -> (f64, f64) {
    const LANES: usize = 8;
    let (mut sat, mut rest) = ([0u32; LANES], [0.0f64; LANES]);
    let mut add = |k: usize, p: f32| {
        let p = p as f64;
        let full = p * s >= 1.0;
        sat[k] += full as u32;
        rest[k] += if full { 0.0 } else { p };
    };
    let chunks = c.chunks_exact(LANES);
    let tail = chunks.remainder();
    for ch in chunks {
        for (k, &p) in ch.iter().enumerate() {
            add(k, p);
        }
    }
    for (k, &p) in tail.iter().enumerate() {
        add(k, p);
    }
    (sat.iter().map(|&n| n as f64).sum(), rest.iter().sum())
}

impl Sampler {
    /// Bytes [`Self::new`] allocates for a `width` × `height` image.
    pub fn bytes_for(width: u32, height: u32) -> usize {
        let (w, n) = (width as usize, width as usize * height as usize);
        let bands = (height as usize).div_ceil(DITHER_BAND_ROWS);
        // Priorities and row sums; per band its rows' buffers.
        4 * n + 8 * height as usize + bands * (2 * 4 * (w + 2) + 4 * 4 * w)
    }

    /// Bytes the bands' picks grow to at most (they start empty): a band picks a pixel of
    /// its rows and of its warm-up rows at most once.
    pub fn picks_bytes_for(width: u32, height: u32) -> usize {
        let bands = (height as usize).div_ceil(DITHER_BAND_ROWS);
        let rows = height as usize + bands.saturating_sub(1) * DITHER_WARM_UP_ROWS;
        std::mem::size_of::<PixelRequest>() * rows * width as usize
    }

    pub fn new(width: u32, height: u32, seed: u64) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            seed,
            frame: 0,
            prio: vec![0.0; n],
            row_sums: vec![0.0; height as usize],
            bands: (0..(height as usize).div_ceil(DITHER_BAND_ROWS)).map(|_| DitherBand::new(width as usize)).collect(),
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Frames selected so far.
    pub fn frame(&self) -> u64 {
        self.frame
    }

    /// Priorities from the last frame (low un-normalised filter weight -> high priority, no
    /// reachable point -> highest, older points -> higher), then a dithered pick of at most
    /// `budget` distinct pixels (≈ `min(budget, pixels)`) into `out` (cleared first).
    ///
    /// Panics if `weights` or `ages` do not have one entry per pixel (a caller bug).
    pub fn select(&mut self, weights: &[f32], ages: &[f32], cfg: &SamplingConfig, budget: usize, out: &mut Vec<PixelRequest>) {
        self.select_gained(weights, ages, None, None, cfg, budget, out);
    }

    /// [`Self::select`] with the priority of each pixel's (fresh or aged, not stale) point
    /// multiplied by `gains` (one per pixel; `render_cache`'s `noise_gains`: noisier points
    /// are re-shaded more often while the view is still), and capped at
    /// [`PRIORITY_GAINED_MAX`], below stale points and unreached pixels. The pixels of
    /// `starved` (bit rows, `ceil(width / 64)` words a row) get at least
    /// [`PRIORITY_STARVED_REGION`].
    ///
    /// Panics if `weights`, `ages`, `gains` or `starved` do not fit the image (a caller bug).
    #[allow(clippy::too_many_arguments)] // the per-pixel inputs, the settings and the output
    pub fn select_gained(&mut self, weights: &[f32], ages: &[f32], gains: Option<&[f32]>, starved: Option<&[u64]>, cfg: &SamplingConfig, budget: usize, out: &mut Vec<PixelRequest>) {
        out.clear();
        let (w, h) = (self.width as usize, self.height as usize);
        let n = w * h;
        assert_eq!(weights.len(), n, "sampler: {} weights for a {w}x{h} image", weights.len());
        assert_eq!(ages.len(), n, "sampler: {} ages for a {w}x{h} image", ages.len());
        let frame = self.frame;
        self.frame += 1;
        let budget = budget.min(n);
        if budget == 0 {
            return;
        }
        if budget == n {
            // Every pixel: no priorities needed.
            let key = mix64(self.seed ^ mix64(frame));
            for y in 0..h as u32 {
                for x in 0..w as u32 {
                    let hsh = mix64(mix64(key ^ (y as u64 * w as u64 + x as u64)));
                    out.push(PixelRequest { x, y, sx: inside_pixel(x, unit(hsh)), sy: inside_pixel(y, unit(hsh << 24)), point: NO_POINT });
                }
            }
            return;
        }
        let max_age = cfg.max_age_frames;
        if let Some(g) = gains {
            assert_eq!(g.len(), n, "sampler: {} gains for a {w}x{h} image", g.len());
        }
        let words = w.div_ceil(64);
        if let Some(s) = starved {
            assert_eq!(s.len(), h * words, "sampler: {} starved words for a {w}x{h} image", s.len());
        }
        // Priorities in one straight loop per row (it vectorises), then the row's sum (see
        // `row_sum`) and its maximum.
        let max = self
            .prio
            .par_chunks_mut(w)
            .enumerate()
            .zip(weights.par_chunks(w).zip(ages.par_chunks(w)))
            .zip(self.row_sums.par_iter_mut())
            .map(|(((y, row), (wr, ar)), sum)| {
                match gains {
                    None => {
                        for ((p, &wt), &age) in row.iter_mut().zip(wr).zip(ar) {
                            *p = priority(wt, age, max_age);
                        }
                    }
                    Some(g) => {
                        for (((p, &wt), &age), &gain) in row.iter_mut().zip(wr).zip(ar).zip(&g[y * w..(y + 1) * w]) {
                            *p = priority_gained(wt, age, max_age, gain);
                        }
                    }
                }
                if let Some(s) = starved {
                    for (j, &word) in s[y * words..(y + 1) * words].iter().enumerate() {
                        let mut bits = word;
                        while bits != 0 {
                            let x = 64 * j + bits.trailing_zeros() as usize;
                            bits &= bits - 1;
                            row[x] = row[x].max(PRIORITY_STARVED_REGION);
                        }
                    }
                }
                *sum = row_sum(row);
                row_max(row)
            })
            .reduce(|| 0.0, f32::max);
        let total = self.row_sums.iter().sum::<f64>();
        let scale = self.scale_to_budget(total, max, budget as f64);
        self.dither(frame, scale, budget, out);
    }

    /// The factor that scales the priorities to sum to `budget` with each capped at 1 (a
    /// pixel is picked at most once): water-filling, extra passes only when some pixels
    /// saturate.
    fn scale_to_budget(&self, total: f64, max: f32, budget: f64) -> f32 {
        let mut s = budget / total.max(f64::MIN_POSITIVE);
        if max as f64 * s < 1.0 {
            return s as f32;
        }
        for _ in 0..16 {
            let (saturated, rest): (f64, f64) = self.prio.par_chunks(16 * 1024).map(|c| saturation(c, s)).reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
            if saturated == 0.0 || rest <= 0.0 {
                break;
            }
            let next = (budget - saturated).max(0.0) / rest;
            // Raising s only adds saturated pixels; stop once it no longer moves.
            if next <= s * (1.0 + 1e-6) {
                break;
            }
            s = next;
        }
        s as f32
    }

    /// Serpentine Floyd–Steinberg over the priorities times `scale` (capped at 1), in bands
    /// of [`DITHER_BAND_ROWS`] rows in parallel (each warmed up on the rows before it); the
    /// picks in band order, cut at `budget`.
    ///
    /// Per frame, the scan runs over the image shifted cyclically by a random offset, starts
    /// in alternating directions and uses hashed thresholds, so equal-priority pixels are not
    /// picked in the same pattern every frame.
    fn dither(&mut self, frame: u64, scale: f32, budget: usize, out: &mut Vec<PixelRequest>) {
        let (w, h) = (self.width as usize, self.height as usize);
        let frame_key = mix64(self.seed ^ mix64(frame));
        let scan = FrameScan {
            w,
            h,
            ox: (mix64(frame_key ^ 1) % w as u64) as usize,
            oy: (mix64(frame_key ^ 2) % h as u64) as usize,
            flip: frame & 1 == 1,
            frame_key,
            scale,
            budget,
        };
        let prio = &self.prio;
        self.bands.par_chunks_mut(2).enumerate().for_each(|(p, pair)| {
            let (first, second) = pair.split_first_mut().expect("chunks are not empty");
            dither_pair(&scan, prio, 2 * p, first, second.first_mut())
        });
        for band in &self.bands {
            let take = (budget - out.len()).min(band.picks.len());
            out.extend_from_slice(&band.picks[..take]);
            if out.len() == budget {
                break;
            }
        }
    }
}

/// What every band of one frame's dithering shares.
struct FrameScan {
    w: usize,
    h: usize,
    /// Cyclic shift of the scan: logical pixel (lx, ly) is physical ((lx + ox) % w, (ly + oy) % h).
    ox: usize,
    oy: usize,
    /// Whether even logical rows run right to left this frame.
    flip: bool,
    frame_key: u64,
    scale: f32,
    budget: usize,
}

/// The share of a pixel's error passed to the next pixel of its row (Floyd–Steinberg 7/16).
const AHEAD: f32 = 7.0 / 16.0;

/// The threshold key of band `b`'s rows in the frame of `frame_key`.
#[inline]
fn band_key(frame_key: u64, b: usize) -> u32 {
    (mix64(frame_key ^ (3 + b as u64)) >> 32) as u32
}

/// A 32-bit hash with full avalanche (MurmurHash3's finaliser): independent thresholds per
/// pixel from a counter, in straight loops that vectorise (no serial random stream).
#[inline(always)]
fn fmix32(mut h: u32) -> u32 {
    h ^= h >> 16;
    h = h.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 13;
    h = h.wrapping_mul(0xc2b2_ae35);
    h ^ (h >> 16)
}

/// The dither threshold of logical pixel index `idx` under `key`, uniform in [0, 1) from 24
/// bits; `-inf` where the scaled priority `q` is saturated (always picked) and `+inf` where
/// it is 0 (never picked).
#[inline(always)]
fn threshold(key: u32, idx: u32, q: f32) -> f32 {
    let u = THRESHOLD_LO + (THRESHOLD_HI - THRESHOLD_LO) * ((fmix32(key ^ idx) >> 8) as f32 * (1.0 / (1u32 << 24) as f32));
    if q >= 1.0 {
        f32::NEG_INFINITY
    } else if q > 0.0 {
        u
    } else {
        f32::INFINITY
    }
}

/// Step 1 of [`dither_pair_rows`] over a run of logical columns starting at index `base`:
/// scaled, capped priorities plus the error from the row before, and their thresholds.
#[inline(always)]
fn scaled_row(a: &mut [f32], t: &mut [f32], prio: &[f32], err: &[f32], scale: f32, key: u32, base: u32) {
    for (i, ((a, t), (&p, &e))) in a.iter_mut().zip(t.iter_mut()).zip(prio.iter().zip(err)).enumerate() {
        let q = (p * scale).min(1.0);
        *a = q + e;
        *t = threshold(key, base.wrapping_add(i as u32), q);
    }
}

/// The jittered position of a pick at physical pixel (x, y), hashed from the band's key and
/// the pixel's logical index.
#[inline]
fn pick_at(key: u32, idx: u32, x: usize, y: usize) -> PixelRequest {
    let h = mix64((key as u64) << 32 | idx as u64);
    PixelRequest { x: x as u32, y: y as u32, sx: inside_pixel(x as u32, unit(h)), sy: inside_pixel(y as u32, unit(h << 24)), point: NO_POINT }
}

/// Bands `b` and `b + 1` (if `second` is given), with AVX2 and FMA where the CPU has them.
/// Both paths make the same IEEE operations in the same order (the serial step is a fused
/// multiply-add either way), so they pick the same pixels.
fn dither_pair(scan: &FrameScan, prio: &[f32], b: usize, first: &mut DitherBand, second: Option<&mut DitherBand>) {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU has AVX2 and FMA (checked above).
            unsafe { dither_pair_avx2(scan, prio, b, first, second) };
            return;
        }
    }
    dither_pair_rows(scan, prio, b, first, second, chain, |x, y| {
        chain(x.0, x.1, x.2, x.3);
        chain(y.0, y.1, y.2, y.3);
    })
}

#[cfg(target_arch = "x86_64")]
fn has_avx2_fma() -> bool {
    static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *HAS.get_or_init(|| is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn dither_pair_avx2(scan: &FrameScan, prio: &[f32], b: usize, first: &mut DitherBand, second: Option<&mut DitherBand>) {
    // SAFETY (of the calls inside): this function only runs where the CPU has AVX2 and FMA.
    dither_pair_rows(scan, prio, b, first, second, |a, b, t, v| unsafe { chain_avx2(a, b, t, v) }, |x, y| unsafe { chain2_avx2(x, y) })
}

/// One row's inputs and output of step 2: `a`, `b`, `t`, `v` (see [`dither_pair_rows`]).
type ChainRow<'a> = (&'a [f32], &'a [f32], &'a [f32], &'a mut [f32]);

/// Step 2 of [`dither_pair_rows`] written plainly.
#[inline(always)]
fn chain(a: &[f32], b: &[f32], t: &[f32], v: &mut [f32]) {
    let w = v.len();
    let mut x = a[0];
    for (((v, &t), &a), &b) in v.iter_mut().zip(&t[..w - 1]).zip(&a[1..]).zip(&b[1..]) {
        *v = x;
        x = AHEAD.mul_add(x, if x >= t { b } else { a });
    }
    v[w - 1] = x;
}

/// Step 2 with the compare, the select and the fused multiply-add as instructions: written
/// plainly, the compiler turns the select into a branch, mispredicted at every pick.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn chain_avx2(a: &[f32], b: &[f32], t: &[f32], v: &mut [f32]) {
    use std::arch::x86_64::*;
    let w = v.len();
    assert!(a.len() == w && b.len() == w && t.len() == w);
    // Lane 0 carries the values; the other lanes compute alongside (whole-register
    // instructions need no merging of the upper lanes) and are never read.
    let ahead = _mm_set1_ps(AHEAD);
    let mut x = _mm_set1_ps(a[0]);
    for (i, v) in v[..w - 1].iter_mut().enumerate() {
        *v = _mm_cvtss_f32(x);
        // SAFETY: i + 1 < w, the length of every slice (asserted above).
        let (an, bn, ti) = unsafe { (_mm_load_ss(a.as_ptr().add(i + 1)), _mm_load_ss(b.as_ptr().add(i + 1)), _mm_load_ss(t.as_ptr().add(i))) };
        // All ones where x >= t (ordered: no NaN reaches here).
        let picked = _mm_cmp_ps::<_CMP_GE_OQ>(x, ti);
        x = _mm_fmadd_ps(ahead, x, _mm_blendv_ps(an, bn, picked));
    }
    v[w - 1] = _mm_cvtss_f32(x);
}

/// [`chain_avx2`] over two rows of the same width at once, one in lane 0 and one in lane
/// 1: the chain is latency-bound (compare, select, multiply-add: about 8 cycles a pixel),
/// and the second row's steps fill the same instructions for free.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn chain2_avx2(x: ChainRow<'_>, y: ChainRow<'_>) {
    use std::arch::x86_64::*;
    let w = x.3.len();
    assert!([x.0.len(), x.1.len(), x.2.len(), y.0.len(), y.1.len(), y.2.len(), y.3.len()].iter().all(|&n| n == w));
    let ahead = _mm_set1_ps(AHEAD);
    // Lanes (0, 1) = (row x, row y); lanes 2 and 3 are never read.
    let pair = |p: &[f32], q: &[f32], i: usize| {
        // SAFETY: i < w, the length of both slices (asserted above).
        unsafe { _mm_unpacklo_ps(_mm_load_ss(p.as_ptr().add(i)), _mm_load_ss(q.as_ptr().add(i))) }
    };
    let mut val = pair(x.0, y.0, 0);
    for i in 0..w - 1 {
        x.3[i] = _mm_cvtss_f32(val);
        y.3[i] = _mm_cvtss_f32(_mm_movehdup_ps(val));
        let (an, bn, ti) = (pair(x.0, y.0, i + 1), pair(x.1, y.1, i + 1), pair(x.2, y.2, i));
        let picked = _mm_cmp_ps::<_CMP_GE_OQ>(val, ti);
        val = _mm_fmadd_ps(ahead, val, _mm_blendv_ps(an, bn, picked));
    }
    x.3[w - 1] = _mm_cvtss_f32(val);
    y.3[w - 1] = _mm_cvtss_f32(_mm_movehdup_ps(val));
}

/// One logical row of a band between step 1 and step 3.
#[derive(Clone, Copy)]
struct BandRow {
    ly: usize,
    /// The physical row.
    y: usize,
    ltr: bool,
    /// Logical index of the row's first pixel (the threshold counter).
    base: u32,
}

impl DitherBand {
    /// The logical rows band `b` scans (its warm-up rows first).
    fn rows(b: usize, h: usize) -> std::ops::Range<usize> {
        (b * DITHER_BAND_ROWS).saturating_sub(DITHER_WARM_UP_ROWS)..((b + 1) * DITHER_BAND_ROWS).min(h)
    }

    /// Step 1 of [`dither_pair_rows`] for logical row `ly`.
    #[inline(always)]
    fn prepare(&mut self, scan: &FrameScan, prio: &[f32], key: u32, ly: usize) -> BandRow {
        let &FrameScan { w, h, ox, oy, flip, scale, .. } = scan;
        let y = (ly + oy) % h;
        let ltr = ly.is_multiple_of(2) != flip;
        let row = &prio[y * w..(y + 1) * w];
        let base = (ly * w) as u32;
        // In logical order (logical column lx is physical column (lx + ox) % w), then
        // reversed for a right-to-left row.
        let cur = &self.err_cur[1..w + 1];
        let (a, bb, t) = (&mut self.a[..w], &mut self.b[..w], &mut self.t[..w]);
        let (a_head, a_tail) = a.split_at_mut(w - ox);
        let (t_head, t_tail) = t.split_at_mut(w - ox);
        let (cur_head, cur_tail) = cur.split_at(w - ox);
        scaled_row(a_head, t_head, &row[ox..], cur_head, scale, key, base);
        scaled_row(a_tail, t_tail, &row[..ox], cur_tail, scale, key, base.wrapping_add((w - ox) as u32));
        if !ltr {
            a.reverse();
            t.reverse();
        }
        for (b, &a) in bb.iter_mut().zip(a.iter()) {
            *b = a - AHEAD;
        }
        BandRow { ly, y, ltr, base }
    }

    /// Step 2's slices.
    fn chain_row(&mut self, w: usize) -> ChainRow<'_> {
        (&self.a[..w], &self.b[..w], &self.t[..w], &mut self.v[..w])
    }

    /// Step 3 of [`dither_pair_rows`]: the row's picks (kept when `keep`) and the error
    /// into the next row. Returns whether the band's picks reached the budget.
    #[inline(always)]
    fn finish(&mut self, scan: &FrameScan, key: u32, r: BandRow, keep: bool) -> bool {
        let &FrameScan { w, ox, budget, .. } = scan;
        let BandRow { y, ltr, base, .. } = r;
        let (v, t) = (&self.v[..w], &self.t[..w]);
        // The picks, from a bit mask per 32 pixels (the compares vectorise; most pixels are
        // not picked).
        if keep {
            for (c, (vc, tc)) in v.chunks(32).zip(t.chunks(32)).enumerate() {
                let mut bits = vc.iter().zip(tc).enumerate().fold(0u32, |m, (k, (&v, &t))| m | (((v >= t) as u32) << k));
                while bits != 0 {
                    let i = c * 32 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let lx = if ltr { i } else { w - 1 - i };
                    let px = if ox + lx >= w { ox + lx - w } else { ox + lx };
                    self.picks.push(pick_at(key, base.wrapping_add(lx as u32), px, y));
                    if self.picks.len() == budget {
                        return true;
                    }
                }
            }
        }
        // The error each pixel passes on, in scan order (into `b`, free now), then the next
        // row's cells: scan position i gets 1/16 of the error before it, 5/16 of its own and
        // 3/16 of the one after it (whichever way the row ran), added in that order.
        let e = &mut self.b[..w];
        for ((e, &v), &t) in e.iter_mut().zip(v.iter()).zip(t.iter()) {
            *e = if v >= t { v - 1.0 } else { v };
        }
        let next = &mut self.err_next;
        // The cells of scan positions -1..=w, stored by logical column + 1: the interior
        // ones in a straight loop, the two at each end (fewer neighbours) one by one.
        let cell = |i: usize| if ltr { i } else { w + 1 - i };
        if w >= 3 {
            let interior = &mut next[2..w];
            let windows = e[..w - 2].iter().zip(&e[1..w - 1]).zip(&e[2..]);
            if ltr {
                for (c, ((&before, &own), &after)) in interior.iter_mut().zip(windows) {
                    *c = before * (1.0 / 16.0) + own * (5.0 / 16.0) + after * (3.0 / 16.0);
                }
            } else {
                for (c, ((&before, &own), &after)) in interior.iter_mut().rev().zip(windows) {
                    *c = before * (1.0 / 16.0) + own * (5.0 / 16.0) + after * (3.0 / 16.0);
                }
            }
        }
        let at = |i: isize| if i >= 0 && (i as usize) < w { Some(e[i as usize]) } else { None };
        for i in [-1, 0, w as isize - 1, w as isize] {
            let mut c = 0.0f32;
            if let Some(x) = at(i - 1) {
                c += x * (1.0 / 16.0);
            }
            if let Some(x) = at(i) {
                c += x * (5.0 / 16.0);
            }
            if let Some(x) = at(i + 1) {
                c += x * (3.0 / 16.0);
            }
            next[cell((i + 1) as usize)] = c;
        }
        // Fold the error pushed past the row's ends back into the image instead of losing
        // it: at sparse priorities the lost error would cost a good part of the budget. The
        // row's last pixel passes its 7/16 to its own end cell.
        let end_cell = if ltr { w } else { 1 };
        next[end_cell] += e[w - 1] * AHEAD;
        next[1] += next[0];
        next[w] += next[w + 1];
        next[0] = 0.0;
        next[w + 1] = 0.0;
        std::mem::swap(&mut self.err_cur, &mut self.err_next);
        false
    }
}

/// The error diffusion of band `b` (and `b + 1`, given `second`), in three steps per row:
///
/// 1. straight loops (they vectorise) put the row into scan order: `a` = scaled priority
///    plus the error from the row before, `b` = `a` − 7/16, `t` = the hashed threshold;
/// 2. the serial scan: with `v` the value reached at a pixel, the pixel is picked when
///    `v ≥ t`, and the next pixel's value is `7/16 · v + (picked ? b : a)` — one compare,
///    one select and one fused multiply-add per pixel on the chain of dependent steps
///    (`7/16 · (v − 1) + a` with the subtraction folded into `b`); two bands' rows go
///    through it together (`chain2`), as their chains are independent;
/// 3. straight loops again: the picks (the compare repeated) in scan order, cut at the
///    budget, and the error `v − picked` passed to the next row's cells (3/16, 5/16, 1/16).
///
/// A band's picks are those of its own rows (not of its warm-up rows), at most the budget.
#[inline(always)]
fn dither_pair_rows(
    scan: &FrameScan,
    prio: &[f32],
    b: usize,
    first: &mut DitherBand,
    second: Option<&mut DitherBand>,
    chain: impl Fn(&[f32], &[f32], &[f32], &mut [f32]),
    chain2: impl Fn(ChainRow<'_>, ChainRow<'_>),
) {
    let w = scan.w;
    let mut second = second;
    let keys = [band_key(scan.frame_key, b), band_key(scan.frame_key, b + 1)];
    // Per band: the rows still to scan, and whether it is still picking.
    let mut left = [DitherBand::rows(b, scan.h), DitherBand::rows(b + 1, scan.h)];
    let mut live = [true, second.is_some()];
    for band in std::iter::once(&mut *first).chain(second.as_deref_mut()) {
        band.picks.clear();
        band.err_cur.iter_mut().for_each(|e| *e = 0.0);
    }
    loop {
        let r0 = if live[0] { left[0].next().map(|ly| first.prepare(scan, prio, keys[0], ly)) } else { None };
        let r1 = match second.as_deref_mut() {
            Some(s) if live[1] => left[1].next().map(|ly| s.prepare(scan, prio, keys[1], ly)),
            _ => None,
        };
        live = [r0.is_some(), r1.is_some()];
        match (r0.is_some(), second.as_deref_mut().filter(|_| r1.is_some())) {
            (false, None) => return,
            (true, Some(s)) => chain2(first.chain_row(w), s.chain_row(w)),
            (true, None) => {
                let (a, b, t, v) = first.chain_row(w);
                chain(a, b, t, v);
            }
            (false, Some(s)) => {
                let (a, b, t, v) = s.chain_row(w);
                chain(a, b, t, v);
            }
        }
        if let Some(r) = r0 {
            live[0] = !first.finish(scan, keys[0], r, r.ly >= b * DITHER_BAND_ROWS);
        }
        if let (Some(r), Some(s)) = (r1, second.as_deref_mut()) {
            live[1] = !s.finish(scan, keys[1], r, r.ly >= (b + 1) * DITHER_BAND_ROWS);
        }
    }
}

/// Range of the per-pixel dither threshold (hashed per frame). A fixed threshold of 0.5
/// turns flat priority areas into a regular lattice and leaves up to half a pick of error
/// pending in every column at the end of the scan — at 1/64 density about 10% of the
/// budget. A uniform random threshold makes each pick's probability exactly the diffused
/// value, so the expected count is the budget, while the diffusion still spreads the picks
/// evenly (measured at 1/64 density: mean nearest-pick distance 5.5 px vs 4.0 for
/// independent random picks and 5.9 for the fixed threshold).
const THRESHOLD_LO: f32 = 0.0;
const THRESHOLD_HI: f32 = 1.0;

#[cfg(test)]
mod tests;
