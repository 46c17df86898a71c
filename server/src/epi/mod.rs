//! The edge-and-point image and its reconstruction, paper 000 §4 and §5 (DESIGN.md "One frame
//! in the renderer", steps 4–10). Per frame:
//!
//! 1. [`depth`] — conservative depth from the reprojected points (§4.5);
//! 2. [`raster`] — edge rasterization: crossings of pixel boundaries at 1/8 pixel (and where
//!    within its eighth, for the anti-aliasing's exact areas), occlusion culling, centre lines
//!    for the complex filter (§4.5, §5.4);
//! 3. [`code`] — classification (empty / simple / complex), 10-bit edge codes, sample
//!    regions and sides through the [`tables`] (§4.1–4.4, §5.1);
//! 4. [`reach`] — reachability in the 5 × 5 neighbourhood (§5.2);
//! 5. [`interpolate`] — edge-respecting interpolation; its weights drive sampling (§5.3);
//!    [`spread`] then colours the pixels that reach no sample from their neighbours within
//!    the same region (our addition);
//! 6. [`antialias`] — anti-aliasing of simple pixels (§5.3), with their real edges' areas;
//! 7. [`complex`] — the complex-pixel filter (§5.4);
//! 8. [`overlay`] — diagnostic views of the EPI.
//!
//! Before step 2 the session cuts every soft-shadow edge to the part of it whose penumbra is
//! narrow on screen ([`soft`]): elsewhere an area light's shadow boundary is continuous and
//! interpolation crosses it.
//!
//! [`Epi`] owns every per-pixel buffer, allocated once for its image size, and times the
//! stages under the names of paper Table 2. The edges come in as `&[EdgeSegment]`, from
//! whichever finder produced them. Pixels left without any sample in reach are marked
//! ([`Epi::holes`]) for the frame's hole fill ([`crate::render_cache::holes`]). No
//! networking.
//!
//! Per-pixel memory (bytes per pixel, see [`Epi::memory`] and the bench `epi`): boundary
//! masks 2 (+2 with the complex filter's centre lines), the crossings' fine positions 2 and
//! segment-end bits 0.125 (for the anti-aliasing's exact areas), conservative depth 4, EPI pixel 2
//! (edge code, sample region, flags), flag planes 0.5, interpolated and hole planes 0.25,
//! neighbour masks 1, reachability 1.5; plus 24 bytes per simple pixel for anti-aliasing and
//! the spreading queues, which scale with the edges and the unreached pixels.
pub mod antialias;
pub mod code;
pub mod complex;
pub mod depth;
pub mod explain;
pub mod interpolate;
pub mod overlay;
pub mod raster;
pub mod reach;
pub mod soft;
pub mod spread;
pub mod tables;
mod testutil;

pub use code::EpiPixel;
pub use interpolate::{InterpCounts, InterpOptions, Kernel, OwnSample, DEFAULT_SIGMA};
pub use overlay::Overlay;
pub use raster::RasterCounts;

use crate::edges::{EdgeKind, EdgeSegment};
use crate::render_cache::{PointImage, NO_POINT};
use crate::stage_times::StageTimes;
use code::PIXEL;
use edgepoint_scene::camera::CameraFrame;
use glam::Vec3;
use rayon::prelude::*;
use tables::{tables, AMBIGUOUS, SIDE_B};


/// Stage names (paper Table 2 columns).
pub const STAGE_EDGES: &str = "edges";
pub const STAGE_RASTERIZE: &str = "rasterize";
pub const STAGE_REACH: &str = "reach";
pub const STAGE_INTERPOLATE: &str = "interpolate";
/// Spreading colour into pixels that reach no sample (not a column of paper Table 2).
pub const STAGE_SPREAD: &str = "spread";
pub const STAGE_ANTIALIAS: &str = "antialias";
pub const STAGE_COMPLEX: &str = "complex";

/// Per-pixel flag bits as bit planes: 64 pixels of a row per word.
pub struct Flags {
    pub width: usize,
    pub height: usize,
    pub words: usize,
    /// `planes[(y * PLANES + p) * words + j]`.
    planes: Vec<u64>,
}

impl Flags {
    /// The pixel holds a reprojected point.
    pub const HAS: usize = 0;
    /// Its point is usable by edge-respecting interpolation.
    pub const USABLE: usize = 1;
    pub const SIMPLE: usize = 2;
    pub const COMPLEX: usize = 3;
    pub const PLANES: usize = 4;

    /// Bytes of the flag planes of a `width` × `height` image.
    pub fn bytes_for(width: usize, height: usize) -> usize {
        8 * height * Self::PLANES * width.div_ceil(64)
    }

    pub fn new(width: usize, height: usize) -> Self {
        let words = width.div_ceil(64);
        Flags { width, height, words, planes: vec![0; height * Self::PLANES * words] }
    }

    #[inline(always)]
    pub fn row(&self, y: usize, plane: usize) -> &[u64] {
        let s = (y * Self::PLANES + plane) * self.words;
        &self.planes[s..s + self.words]
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize, plane: usize) -> bool {
        (self.row(y, plane)[x / 64] >> (x % 64)) & 1 == 1
    }

    pub fn bytes(&self) -> usize {
        self.planes.len() * 8
    }
}

/// Pixel classes and edge counts of one EPI (paper Table 3).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EpiCounts {
    pub empty: u32,
    pub simple: u32,
    pub complex: u32,
    /// Pixels with a point whose sample is usable / edge-ambiguous (in simple pixels).
    pub usable_samples: u32,
    pub ambiguous_samples: u32,
    /// Segments per [`EdgeKind`] (in `EdgeKind::ALL` order) given to the rasterizer.
    pub edges: [u32; 6],
    pub raster: RasterCounts,
}

/// What reconstruction did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReconstructCounts {
    pub interp: InterpCounts,
    /// Pixels that reached no sample and took colour from their region's neighbours.
    pub spread: u32,
    /// Simple pixels that took a secondary colour.
    pub antialiased: u32,
    /// Complex pixels refined by the complex filter.
    pub complex_refined: u32,
}

/// The edge-and-point image of one image size, with every per-frame buffer.
pub struct Epi {
    width: usize,
    height: usize,
    depth: depth::ConservativeDepth,
    raster: raster::Rasterizer,
    bounds: raster::Boundaries,
    pixels: Vec<EpiPixel>,
    flags: Flags,
    /// Bit rows: pixels whose colour came from samples (interpolation output).
    filled: Vec<u64>,
    /// Bit rows: pixels with no sample in their window (interpolation output).
    holes: Vec<u64>,
    /// Bit rows: simple pixels whose secondary region found no colour though a sample could
    /// land there usable (anti-aliasing output, [`antialias::antialias`]).
    starved: Vec<u64>,
    /// Bit rows: pixels with a stale point in their 5 × 5 window (interpolation input for
    /// [`interpolate::OwnSample::FilterAwayFromStale`]), and the scratch they are made in.
    near_stale: Vec<u64>,
    near_stale_rows: Vec<u64>,
    neighbours: reach::Neighbours,
    reach: reach::Reach,
    simple: antialias::SimpleColours,
    spread: spread::Spread,
    counts: EpiCounts,
}

impl Epi {
    /// Bytes an EPI of this size allocates at its largest: its image-sized structures with
    /// the complex filter's centre lines, and the content-sized ones at the most an image
    /// of this size can make them hold (every pixel simple, every pixel spread to). The
    /// projected edges grow with the scene, not the image, and are not counted. Each part
    /// is its structure's own `bytes_for`, next to its constructor.
    pub fn bytes_for(width: u32, height: u32) -> usize {
        let (w, h) = (width as usize, height as usize);
        let words = w.div_ceil(64);
        depth::ConservativeDepth::bytes_for(w, h)
            + raster::Boundaries::bytes_for(w, h)
            + raster::Rasterizer::bytes_for(h)
            + std::mem::size_of::<EpiPixel>() * w * h
            + Flags::bytes_for(w, h)
            + 5 * 8 * h * words
            + reach::Neighbours::bytes_for(w, h)
            + reach::Reach::bytes_for(w, h)
            + antialias::SimpleColours::bytes_for(w, h)
            + spread::Spread::bytes_for(w, h)
    }

    pub fn new(width: u32, height: u32) -> Self {
        let (w, h) = (width as usize, height as usize);
        let flags = Flags::new(w, h);
        Epi {
            width: w,
            height: h,
            depth: depth::ConservativeDepth::new(w, h),
            raster: raster::Rasterizer::new(),
            bounds: raster::Boundaries::new(w, h),
            pixels: vec![EpiPixel::default(); w * h],
            filled: vec![0; h * flags.words],
            holes: vec![0; h * flags.words],
            starved: vec![0; h * flags.words],
            near_stale: vec![0; h * flags.words],
            near_stale_rows: vec![0; h * flags.words],
            flags,
            neighbours: reach::Neighbours::new(w, h),
            reach: reach::Reach::new(w, h),
            simple: antialias::SimpleColours::default(),
            spread: spread::Spread::default(),
            counts: EpiCounts::default(),
        }
    }

    pub fn width(&self) -> u32 {
        self.width as u32
    }

    pub fn height(&self) -> u32 {
        self.height as u32
    }

    /// Builds the EPI of a frame: conservative depth from `points`, edge rasterization
    /// (with centre lines when `centre_lines`, for the complex filter) and classification.
    /// Timed as [`STAGE_RASTERIZE`]. `cam` is used with this EPI's size.
    pub fn build(&mut self, edges: &[EdgeSegment], cam: &CameraFrame, points: &PointImage, centre_lines: bool, times: &mut StageTimes) -> EpiCounts {
        times.time(STAGE_RASTERIZE, || {
            let (w, h) = (self.width, self.height);
            assert_eq!(points.point.len(), w * h, "EPI {w}x{h}: point image of another size");
            self.depth.compute(points);
            if centre_lines && self.bounds.centres.len() != w * h {
                self.bounds.centres = vec![0; w * h];
            } else if !centre_lines && !self.bounds.centres.is_empty() {
                self.bounds.centres = Vec::new();
            }
            let raster = self.raster.rasterize(edges, cam, &self.depth, &mut self.bounds);
            let mut counts = self.classify(points);
            counts.raster = raster;
            for e in edges {
                counts.edges[EdgeKind::ALL.iter().position(|k| *k == e.kind).unwrap_or(0)] += 1;
            }
            self.counts = counts;
            counts
        })
    }

    /// Replaces the boundary masks (tests build EPIs from 2D geometry) and classifies; with
    /// `fine` empty the anti-aliasing uses the quantised edges' areas.
    #[cfg(test)]
    pub(crate) fn classify_with(&mut self, sides: Vec<u16>, centres: Vec<u16>, fine: testutil::Fine, points: &PointImage) -> EpiCounts {
        assert_eq!(sides.len(), (self.width + 1) * (self.height + 1));
        self.bounds.sides = sides;
        self.bounds.centres = centres;
        assert!(fine.positions.is_empty() || fine.positions.len() == self.bounds.sides.len());
        self.bounds.fine = fine.positions;
        self.bounds.ends = fine.ends;
        self.counts = self.classify(points);
        self.counts
    }

    /// Classification and encoding of every pixel from the boundary masks and the points.
    fn classify(&mut self, points: &PointImage) -> EpiCounts {
        self.classify_isa(points, interpolate::Isa::detect())
    }

    /// [`Self::classify`] with the rows compiled for `isa` (which the CPU must have).
    fn classify_isa(&mut self, points: &PointImage, isa: interpolate::Isa) -> EpiCounts {
        assert!(isa.available(), "classification: this CPU lacks {isa:?}");
        let (w, words) = (self.width, self.flags.words);
        if w == 0 {
            return EpiCounts::default();
        }
        let bounds = &self.bounds;
        self.pixels
            .par_chunks_mut(w)
            .zip(self.flags.planes.par_chunks_mut(Flags::PLANES * words))
            .enumerate()
            .map(|(y, (px, fl))| match isa {
                // SAFETY: asserted above that the CPU has AVX2.
                #[cfg(target_arch = "x86_64")]
                interpolate::Isa::Avx2 | interpolate::Isa::Avx512 => unsafe { classify_row_avx2(bounds, points, y, px, fl) },
                _ => classify_row(bounds, points, y, px, fl),
            })
            .reduce(EpiCounts::default, |a, b| EpiCounts {
                empty: a.empty + b.empty,
                simple: a.simple + b.simple,
                complex: a.complex + b.complex,
                usable_samples: a.usable_samples + b.usable_samples,
                ambiguous_samples: a.ambiguous_samples + b.ambiguous_samples,
                ..Default::default()
            })
    }

    /// Reconstructs the frame from the last [`Self::build`]: reachability, interpolation,
    /// anti-aliasing and (when `complex_filter` and the build recorded centre lines) the
    /// complex filter, into `image` (linear RGB) and `weights` (the un-normalised reachable
    /// filter weight per pixel, for sampling). Timed as [`STAGE_REACH`],
    /// [`STAGE_INTERPOLATE`], [`STAGE_ANTIALIAS`] and [`STAGE_COMPLEX`].
    #[allow(clippy::too_many_arguments)]
    pub fn reconstruct(
        &mut self,
        points: &PointImage,
        background: Vec3,
        options: &InterpOptions,
        complex_filter: bool,
        image: &mut [Vec3],
        weights: &mut [f32],
        times: &mut StageTimes,
    ) -> ReconstructCounts {
        let n = self.width * self.height;
        assert!(image.len() == n && weights.len() == n && points.point.len() == n, "EPI {}x{}: buffers of another size", self.width, self.height);
        times.time(STAGE_REACH, || {
            self.neighbours.compute(&self.pixels, &self.flags);
            self.reach.compute(&self.neighbours, &self.flags);
        });
        let kernel = Kernel::gaussian(options.sigma);
        let interp = times.time(STAGE_INTERPOLATE, || {
            if options.own_sample == interpolate::OwnSample::FilterAwayFromStale {
                interpolate::near_stale_rows(points, &mut self.near_stale_rows, &mut self.near_stale);
            }
            let input = interpolate::InterpInput {
                pixels: &self.pixels,
                flags: &self.flags,
                reach: &self.reach,
                points,
                kernel: &kernel,
                options: *options,
                background,
                near_stale: &self.near_stale,
            };
            interpolate::interpolate(&input, image, weights, &mut self.filled, &mut self.holes)
        });
        let spread = times.time(STAGE_SPREAD, || self.spread.run(&self.neighbours, &mut self.filled, &mut self.holes, image));
        let antialiased = times.time(STAGE_ANTIALIAS, || {
            antialias::antialias(&self.pixels, &self.bounds, &self.flags, &self.filled, &self.neighbours, &mut self.simple, image, &mut self.starved)
        });
        let mut complex_refined = 0;
        if complex_filter && !self.bounds.centres.is_empty() {
            complex_refined = times.time(STAGE_COMPLEX, || {
                let input = complex::ComplexInput { bounds: &self.bounds, pixels: &self.pixels, flags: &self.flags, points, filled: &self.filled, sigma: options.sigma };
                complex::complex_filter(&input, image)
            });
        }
        ReconstructCounts { interp, spread, antialiased, complex_refined }
    }

    /// Bit rows (`ceil(width / 64)` words per row) of the simple pixels whose secondary
    /// region the last reconstruction found no colour for, though a sample could land there
    /// usable: sampling gives them priority and [`Self::secondary_position`] aims into it.
    pub fn starved(&self) -> &[u64] {
        &self.starved
    }

    /// For a pixel of [`Self::starved`]: a position in its unit square inside one of the
    /// sample regions on its secondary side (so a sample there is usable and makes that side
    /// the pixel's primary region), the region and the place in it chosen by the unit
    /// numbers `u` and `v` (a pick's jitter); `None` for any other pixel.
    pub fn secondary_position(&self, x: usize, y: usize, u: f32, v: f32) -> Option<[f32; 2]> {
        if x >= self.width || y >= self.height || (self.starved[y * self.flags.words + x / 64] >> (x % 64)) & 1 == 0 {
            return None;
        }
        let p = self.pixels[y * self.width + x];
        let mut regions = antialias::secondary_regions(p.code(), p.primary_b());
        let count = regions.count_ones();
        if count == 0 {
            return None;
        }
        // The k-th of the regions (u picks k; what is left of u after k and v place the
        // position in it, kept 5 % of the region's side from its sides).
        let scaled = u.clamp(0.0, 1.0) * count as f32;
        let k = (scaled as u32).min(count - 1);
        for _ in 0..k {
            regions &= regions - 1;
        }
        let r = regions.trailing_zeros();
        let n = PIXEL.regions;
        let (rx, ry) = ((r % n) as f32, (r / n) as f32);
        let (fu, fv) = ((scaled - k as f32).clamp(0.0, 1.0), v.clamp(0.0, 1.0));
        let at = |i: f32, f: f32| ((i + 0.05 + 0.9 * f) / n as f32).min(1.0 - f32::EPSILON);
        Some([at(rx, fu), at(ry, fv)])
    }

    /// Bit rows (`ceil(width / 64)` words per row) of the pixels the last reconstruction left
    /// at the background: no sample in their window (see
    /// [`crate::render_cache::holes::HoleFill`]).
    pub fn holes(&self) -> &[u64] {
        &self.holes
    }

    /// Draws a diagnostic overlay of the last build over `image`.
    pub fn draw_overlay(&self, overlay: Overlay, image: &mut [Vec3]) {
        overlay::draw(overlay, &self.pixels, &self.flags, image);
    }

    /// Counts of the last build.
    pub fn counts(&self) -> &EpiCounts {
        &self.counts
    }

    pub fn pixels(&self) -> &[EpiPixel] {
        &self.pixels
    }

    pub fn flags(&self) -> &Flags {
        &self.flags
    }

    pub fn boundaries(&self) -> &raster::Boundaries {
        &self.bounds
    }

    pub fn reachability(&self) -> &reach::Reach {
        &self.reach
    }

    /// Bytes of the structures sized by the image, structure by structure (what paper §7.4
    /// counts per pixel).
    pub fn memory(&self) -> Vec<(&'static str, usize)> {
        vec![
            ("boundary masks (sides)", 2 * self.bounds.sides.len()),
            ("boundary masks (centre lines)", 2 * self.bounds.centres.len()),
            ("crossing positions (anti-aliasing)", 2 * self.bounds.fine.len()),
            ("segment-end bits (anti-aliasing)", 8 * self.bounds.ends.len()),
            ("conservative depth", self.depth.bytes()),
            ("EPI pixels (edge code, sample region, flags)", 2 * self.pixels.len()),
            ("flag planes", self.flags.bytes()),
            ("interpolated-flag plane", 8 * self.filled.len()),
            ("hole plane", 8 * self.holes.len()),
            ("neighbour masks", self.neighbours.bytes()),
            ("reachability masks", self.reach.bytes()),
            ("simple-pixel ranks (anti-aliasing)", self.simple.rank_bytes()),
        ]
    }

    /// Bytes of the structures sized by the frame's content, held at their largest so far:
    /// the rasterizer's projected segments and bins (per on-screen edge), the anti-aliasing
    /// colours (24 per simple pixel), the spreading queues (per pixel that reached no
    /// sample).
    pub fn memory_content(&self) -> Vec<(&'static str, usize)> {
        vec![
            ("rasterizer segments and bins (per edge)", self.raster.bytes()),
            ("simple-pixel colours (per simple pixel)", self.simple.colour_bytes()),
            ("spreading queues (per unreached pixel)", self.spread.bytes()),
        ]
    }
}

/// Bit `i` set where byte `i` is 1 (bytes are 0 or 1): eight bytes at a time, gathered into
/// the top byte by one multiplication (each byte's bit lands on its own position, with no
/// carries between them).
#[inline(always)]
fn pack_bits(bytes: &[u8; 64]) -> u64 {
    let mut bits = 0u64;
    for (k, c) in bytes.chunks_exact(8).enumerate() {
        let v = u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]);
        bits |= (v.wrapping_mul(0x0102_0408_1020_4080) >> 56) << (8 * k);
    }
    bits
}

/// [`classify_row`] compiled for AVX2: the empty words' loops vectorise eight wide.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn classify_row_avx2(bounds: &raster::Boundaries, points: &PointImage, y: usize, px: &mut [EpiPixel], fl: &mut [u64]) -> EpiCounts {
    classify_row(bounds, points, y, px, fl)
}

/// Classifies and encodes row `y`: EPI pixels and flag planes.
#[inline(always)]
fn classify_row(bounds: &raster::Boundaries, points: &PointImage, y: usize, px: &mut [EpiPixel], fl: &mut [u64]) -> EpiCounts {
    let t = tables();
    let w = px.len();
    let words = w.div_ceil(64);
    let mut c = EpiCounts::default();
    let (row, below) = (&bounds.sides[y * (w + 1)..(y + 1) * (w + 1)], &bounds.sides[(y + 1) * (w + 1)..(y + 2) * (w + 1)]);
    let (pt, sub) = (&points.point[y * w..(y + 1) * w], &points.subpixel[y * w..(y + 1) * w]);
    let region = |x: usize| {
        let [u, v] = sub[x];
        PIXEL.region_of(u, v)
    };
    for j in 0..words {
        let x0 = 64 * j;
        let n = (w - x0).min(64);
        let mut planes = [0u64; Flags::PLANES];
        let (wpt, wsub, wpx) = (&pt[x0..x0 + n], &sub[x0..x0 + n], &mut px[x0..x0 + n]);
        // Per pixel as bytes (straight loops that vectorise), then packed into bits.
        let mut has = [0u8; 64];
        for (h, &p) in has.iter_mut().zip(wpt) {
            *h = u8::from(p != NO_POINT);
        }
        let has_bits = pack_bits(&has);
        planes[Flags::HAS] = has_bits;
        // Pixels with a crossing on some side (top and left: the pixel's own vertex; right:
        // the next vertex's vertical side; bottom: the vertex below's horizontal side).
        let (wrow, wright, wbelow) = (&row[x0..x0 + n], &row[x0 + 1..x0 + n + 1], &below[x0..x0 + n]);
        let mut cross = [0u8; 64];
        for (k, ((&v, &r), &b)) in cross.iter_mut().zip(wrow.iter().zip(wright).zip(wbelow)) {
            *k = u8::from((v | (r & 0xff) | (b >> 8)) != 0);
        }
        let crossed = pack_bits(&cross);
        // Every pixel as an empty one first, in a straight loop without branches (it
        // vectorises; the region is computed for every pixel and kept where there is a
        // point); then the few crossed pixels are classified one by one.
        for ((p, &pt), &[u, v]) in wpx.iter_mut().zip(wpt).zip(wsub) {
            let has = pt != NO_POINT;
            let r = PIXEL.region_of(u, v);
            *p = EpiPixel::new(code::EMPTY, if has { r } else { 0 }, has, false);
        }
        let empty_has = has_bits & !crossed;
        planes[Flags::USABLE] = empty_has;
        c.empty += n as u32 - crossed.count_ones();
        c.usable_samples += empty_has.count_ones();
        let mut rest = crossed;
        while rest != 0 {
            let i = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            let x = x0 + i;
            let has = (has_bits >> i) & 1 == 1;
            let m = code::pixel_mask((row[x] >> 8) as u8, row[x + 1] as u8, (below[x] >> 8) as u8, row[x] as u8);
            let bit = 1u64 << i;
            let code = PIXEL.classify(m);
            let r = if has { region(x) } else { 0 };
            let (usable, primary_b) = if has {
                let side = t.pixel.side(code, r);
                let usable = side != AMBIGUOUS;
                (usable, if usable { side == SIDE_B } else { t.pixel.area_a(code) < 0.5 })
            } else {
                (false, t.pixel.area_a(code) < 0.5)
            };
            let p = EpiPixel::new(code, r, usable, primary_b);
            px[x] = p;
            if usable {
                planes[Flags::USABLE] |= bit;
            }
            if p.is_simple() {
                planes[Flags::SIMPLE] |= bit;
                c.simple += 1;
                if has {
                    if usable {
                        c.usable_samples += 1;
                    } else {
                        c.ambiguous_samples += 1;
                    }
                }
            } else {
                planes[Flags::COMPLEX] |= bit;
                c.complex += 1;
            }
        }
        for (p, v) in planes.into_iter().enumerate() {
            fl[p * words + j] = v;
        }
    }
    c
}

#[cfg(test)]
mod tests;
