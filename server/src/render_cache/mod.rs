//! The Render Cache of paper 000 §4.3 "Point processing" (after Walter et al. 1999): a
//! fixed-size pool of recently shaded point samples kept as coloured 3D points. Each frame
//! the points are aged, reprojected with the current camera (nearest point per pixel),
//! filtered to remove points that their neighbourhood shows to be occluded, and
//! interpolated to fill the small gaps between them. The resulting per-pixel points
//! ([`PointImage`]) are what the edge-and-point image is built from (§4.4–4.5); the filled
//! image and the un-normalised filter weights feed display and prioritized sampling (§5.3).
//!
//! Replacement policy when the pool is full (DESIGN.md "Render Cache"): invalid slots
//! first, then points found hidden (occluded) in the last frame, then the oldest point.
//! The pool is split into one region per band of [`BAND_ROWS`] image rows, sized in
//! proportion to the band's pixels, and a sample goes into the region of the row it was
//! shaded for. Points near each other on screen then sit near each other in memory, which
//! keeps the per-frame passes' random accesses (depth buffer, point gathers) inside a small
//! working set instead of the whole pool: reprojection is memory-bound, and this is what
//! makes it fast. Replacement order holds within each region.
//!
//! No networking here; all per-frame buffers are allocated once in [`RenderCache::new`].

mod converge;
pub mod fresh;
pub mod holes;
pub mod reshadow;
mod interpolate;
mod reproject;

use glam::Vec3;
use std::collections::VecDeque;

/// Name of the stage (in [`crate::stage_times::StageTimes`]) that projects the points, keeps
/// the nearest per pixel and culls occluded ones — paper Table 2 "point reprojection".
pub const STAGE_REPROJECT: &str = "reproject";
/// Name of the gap-filling interpolation stage.
pub const STAGE_INTERPOLATE: &str = "interpolate";

/// Slots an insert examines for a hidden point before it takes the oldest.
const HIDDEN_SCAN: u32 = 16;

/// Image rows per pool region (see the module doc).
pub const BAND_ROWS: u32 = 8;

/// Age given by [`RenderCache::mark_stale`] (and the largest age reported): larger than any
/// sensible `max_age_frames`, finite so that it stays distinguishable from "no point"
/// (`f32::INFINITY`) in age images.
pub const STALE_AGE: f32 = 1.0e9;

/// A point is occluded when it is farther than its neighbours' depth by more than this
/// fraction (Walter et al.'s relative depth test).
pub const DEPTH_CULL_RELATIVE: f32 = 0.1;

/// A point is hidden by the scene's surfaces when it lies farther than the farthest surface
/// around its pixel by more than this fraction: far above the rounding of either depth
/// (both come from the same triangles, in f32), far below any real gap between surfaces.
pub const GEOMETRY_CULL_RELATIVE: f32 = 1e-3;

/// The exact primary visibility of the frame (from `crate::visibility`), which reprojection
/// culls against: every point hidden by a surface goes, wherever it reprojects, also where
/// no neighbouring point could show it hidden; a background miss never lands on geometry.
#[derive(Debug, Clone, Copy)]
pub struct GeometryCull<'a> {
    /// Per pixel: the farthest surface depth over its 3x3 neighbourhood (infinity where any
    /// of those centres is uncovered).
    pub far3: &'a [f32],
    /// Per pixel: 1 / depth of the surface at the pixel centre, 0 where none covers it.
    pub inverse_depth: &'a [f32],
    /// Changes whenever the two images do (the visibility raster's draw count): a still
    /// view reprojected against the same generation may update its point image in place.
    pub generation: u64,
}

/// Where a light emits from, as shadow tests need it: every emitting point lies within
/// `radius` of `center` (a point light: radius 0; an area light: its bounding sphere).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightBound {
    pub center: Vec3,
    pub radius: f32,
}

impl LightBound {
    /// The box `region` grown by the light's radius: it holds every ray from a point to the
    /// light's emitting surface where the ray crosses `region`, so testing the segment to
    /// the light's centre against it is conservative.
    pub fn grow(&self, (lo, hi): (Vec3, Vec3)) -> (Vec3, Vec3) {
        (lo - Vec3::splat(self.radius), hi + Vec3::splat(self.radius))
    }

    /// Whether something inside `region` may block light from this light to `p`.
    pub fn may_shadow(&self, p: Vec3, region: (Vec3, Vec3)) -> bool {
        let (lo, hi) = self.grow(region);
        segment_hits_box(p, self.center, lo, hi)
    }
}

/// One shaded point sample as the worker returned it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub hit: bool,
    /// World hit point; for a miss: the unit ray direction (a point at infinity).
    pub position: Vec3,
    /// Unit surface normal at a hit, facing the eye it was shaded for (zero: unknown, and for
    /// a miss). The point is valid only while the eye stays on that side of its surface.
    pub normal: Vec3,
    /// Linear RGB.
    pub color: Vec3,
    /// Object id, `u32::MAX` for a miss.
    pub object: u32,
    pub epoch: u64,
    /// Pixel the sample was requested for.
    pub pixel: [u32; 2],
}

/// A unit-range component as a 16-bit signed-normalised number.
#[inline]
fn snorm16(v: f32) -> i16 {
    (v.clamp(-1.0, 1.0) * 32767.0).round() as i16
}

/// Inverse of [`snorm16`].
#[inline]
pub(crate) fn unorm(v: i16) -> f32 {
    f32::from(v) * (1.0 / 32767.0)
}

/// Where pixel `i` of a `width`-wide image lives in a bitmask of `ceil(width / 64)` words
/// per row (the layout of the EPI's hole bits): its word and the bit in it.
#[inline]
pub(crate) fn pixel_bit(width: usize, i: usize) -> (usize, u64) {
    let (y, x) = (i / width, i % width);
    (y * width.div_ceil(64) + x / 64, 1 << (x % 64))
}

/// Whether the segment from `a` to `b` meets the box [`lo`, `hi`] (slab test).
#[inline]
pub fn segment_hits_box(a: Vec3, b: Vec3, lo: Vec3, hi: Vec3) -> bool {
    let d = b - a;
    let inv = d.recip();
    let (t0, t1) = ((lo - a) * inv, (hi - a) * inv);
    // A zero direction component gives ±infinity (or NaN exactly on a slab's plane, which
    // `min`/`max` pass over), so the axis constrains nothing when `a` is inside its slab.
    let tmin = t0.min(t1).max_element().max(0.0);
    let tmax = t0.max(t1).min_element().min(1.0);
    tmin <= tmax
}

/// Size and policy of a [`RenderCache`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CacheConfig {
    pub width: u32,
    pub height: u32,
    /// Pool capacity as a multiple of the pixel count (default 2.0). Clamped to [0, 64].
    pub points_per_pixel: f32,
    /// Colour (linear RGB) of pixels no point reaches.
    pub background: Vec3,
}

impl CacheConfig {
    /// Defaults for a `width` x `height` image: 2 points per pixel, black background.
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, points_per_pixel: 2.0, background: Vec3::ZERO }
    }
}

/// Per-frame statistics of [`RenderCache::reproject_and_interpolate`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameCounts {
    /// Pixels that kept a reprojected point after occlusion culling.
    pub with_point: u32,
    /// Pixels without a point, filled by interpolation from neighbours.
    pub filled: u32,
    /// Pixels no point reaches (background colour, filter weight 0).
    pub empty: u32,
    /// Pixels whose nearest point was culled as occluded (by its neighbours or by the
    /// scene's surfaces).
    pub occluded: u32,
    /// Valid points in the cache.
    pub cache_points: u32,
}

/// Per-pixel result of reprojection (after occlusion culling) — the later edge-and-point
/// image (paper §4.3–4.5) reads this. Row-major, `width * height` entries each.
#[derive(Debug, Clone, Default)]
pub struct PointImage {
    pub width: u32,
    pub height: u32,
    /// Cache index of the pixel's point, or `u32::MAX`.
    pub point: Vec<u32>,
    /// View depth of the point (`f32::INFINITY` for a miss point or no point).
    pub depth: Vec<f32>,
    /// Position of the point inside the pixel, in [0, 1)^2.
    pub subpixel: Vec<[f32; 2]>,
    /// Point colour (linear RGB); zero where there is no point.
    pub color: Vec<Vec3>,
    /// Point age in frames since shading; `f32::INFINITY` where there is no point.
    pub age: Vec<f32>,
    /// Frame counter when the point was shaded, stale or not (0 where there is no point):
    /// which of two points is newer.
    pub born: Vec<u32>,
}

impl PointImage {
    /// Bytes per pixel of its arrays.
    pub const BYTES_PER_PIXEL: usize =
        4 + 4 + std::mem::size_of::<[f32; 2]>() + std::mem::size_of::<Vec3>() + 4 + 4;

    fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            point: vec![NO_POINT; n],
            depth: vec![f32::INFINITY; n],
            subpixel: vec![[0.0; 2]; n],
            color: vec![Vec3::ZERO; n],
            age: vec![f32::INFINITY; n],
            born: vec![0; n],
        }
    }
}

/// A copy of one cached point (see [`RenderCache::point`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CachedPoint {
    pub hit: bool,
    pub position: Vec3,
    /// The normal as stored (16-bit components).
    pub normal: Vec3,
    pub color: Vec3,
    pub object: u32,
    pub epoch: u64,
    pub pixel: [u32; 2],
    /// Frames since the point was shaded ([`STALE_AGE`] after [`RenderCache::mark_stale`]).
    pub age: f32,
    /// Samples averaged into its colour (`converge.rs`).
    pub samples: u32,
}

/// [`PointImage::point`] of a pixel without a point.
pub const NO_POINT: u32 = u32::MAX;
/// Empty entry of the depth buffer: larger than any (depth bits, index) key.
pub(crate) const EMPTY_KEY: u64 = u64::MAX;

const FLAG_VALID: u8 = 1;
const FLAG_HIT: u8 = 2;
/// Shaded before a change that may have altered its shading (it shows [`STALE_AGE`]); its
/// shading frame is kept, so that newer points of the same surface can be preferred.
const FLAG_STALE: u8 = 4;

/// [`RenderCache::status`] bits: the pixel's nearest point was culled; its point is stale.
pub(crate) const STATUS_CULLED: u8 = 1;
pub(crate) const STATUS_STALE: u8 = 2;

/// What pass 2 of reprojection reads of a winning point, packed so that one random access
/// fetches it.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C)]
pub(crate) struct Shade {
    pub color: Vec3,
    /// Frame counter when the point was shaded; age = frames since (wrapping).
    pub born: u32,
}

/// Where a point projected in the last frame: what replacement needs to tell whether it was
/// hidden, and its position inside the pixel for the point image. Kept small (12 bytes):
/// pass 1 writes one per point every frame.
#[derive(Debug, Clone, Copy)]
#[repr(C)]
pub(crate) struct Projected {
    /// Pixel index, or `NO_POINT` when off-screen, behind the eye, or invalid.
    pub pixel: u32,
    pub depth: f32,
    /// Position inside the pixel in units of 1/65536.
    pub fx: u16,
    pub fy: u16,
}

impl Projected {
    pub(crate) const NONE: Projected = Projected { pixel: NO_POINT, depth: f32::INFINITY, fx: 0, fy: 0 };
}

/// The cached points, structure of arrays so each pass streams only what it reads.
struct Pool {
    /// Positions (directions for misses), one array per coordinate so that projection runs
    /// four points per SIMD instruction.
    px: Vec<f32>,
    py: Vec<f32>,
    pz: Vec<f32>,
    /// Surface normals facing the eye that sampled them, 16-bit signed-normalised per
    /// component (6 bytes a point: only the side of the surface the eye is on is read).
    nx: Vec<i16>,
    ny: Vec<i16>,
    nz: Vec<i16>,
    shade: Vec<Shade>,
    object: Vec<u32>,
    epoch: Vec<u64>,
    pixel: Vec<[u32; 2]>,
    flags: Vec<u8>,
    /// Insertion stamp; matches the oldest-first queue entry while the point lives.
    stamp: Vec<u64>,
    /// Samples of the same surface point averaged into `shade.color` (`converge.rs`).
    samples: Vec<u16>,
    /// How much moves have shifted the point's shadows since it was shaded, as far as they
    /// could say (`reshadow.rs`), in 1/255 of one light's unblocked light.
    drift: Vec<u8>,
    /// The spread of those samples (`converge.rs`, [`RenderCache::noise_gains`]): the mean of
    /// their [`converge::tone`] and the sum of its squared deviations (Welford).
    spread: Vec<[f32; 2]>,
}

/// Replacement bookkeeping of one pool region (slots `start..end`).
struct Region {
    start: u32,
    end: u32,
    /// Invalid slots (never used, or invalidated) ready for reuse; popped lowest first.
    free: Vec<u32>,
    /// (stamp, slot) in insertion order; entries whose slot was reused since are skipped.
    oldest: VecDeque<(u64, u32)>,
    /// Clock hand of the scan for hidden points (wraps around the region).
    hidden_cursor: u32,
}

impl Region {
    fn new(start: u32, end: u32) -> Self {
        let n = (end - start) as usize;
        let mut oldest = VecDeque::new();
        oldest.reserve(2 * n + 64);
        Region { start, end, free: (start..end).rev().collect(), oldest, hidden_cursor: start }
    }
}

/// The Render Cache: point pool, replacement bookkeeping and the per-frame images.
pub struct RenderCache {
    cfg: CacheConfig,
    capacity: usize,
    pool: Pool,
    valid: usize,
    /// Pool regions, one per band of `BAND_ROWS` image rows.
    regions: Vec<Region>,
    next_stamp: u64,
    /// Samples averaged into existing points (`converge.rs`).
    averaged: u64,
    /// Frames reprojected so far (ages are differences of it).
    frame: u32,
    // Per-frame buffers.
    /// Per pixel: (depth bits << 32 | point index), minimum wins; one buffer per worker
    /// share of the points, merged into the first.
    zbufs: Vec<Vec<u64>>,
    /// Per pixel: nearest depth (as `f32` bits, all ones for none) over the pixel and its
    /// left and right neighbours — the culling pre-test.
    zmin_row: Vec<u32>,
    /// Per pixel, one bit: the stale point there gives way to a newer one (`fresh.rs`);
    /// before that, in a still view, the pixels whose point was replaced, then those whose
    /// depth-buffer entry changed (`reproject.rs`).
    give_way: Vec<u64>,
    /// The view of the last full reprojection, and whether something since needs another
    /// (points moved or removed other than by replacement).
    last_view: Option<reproject::Projector>,
    reproject_all: bool,
    /// Since the last reprojection: slots written, and pixels whose nearest point was in one
    /// of them. Bounded by [`MAX_INSERTED`]; beyond, the next frame reprojects everything.
    /// With each slot its stamp and where it projects in the still view (computed on
    /// insertion, while the point is in cache).
    inserted_slots: Vec<(u32, u64, Projected)>,
    lost_pixels: Vec<u32>,
    /// Stale points in the point image of the last reprojection (`fresh.rs` skips its pass
    /// when there are none), and points culled in it.
    stale_shown: u32,
    culled_shown: u32,
    /// Whether the point image, `status` and the counts are exactly what pass 2 made of the
    /// depth buffer (nothing changed them since) and which geometry generation it culled
    /// against (`Some(None)`: none): a still view then recomputes only the pixels near a
    /// change of the depth buffer (`reproject.rs`).
    point_image_from: Option<Option<u64>>,
    /// Per pixel, pass 2's outcome: [`STATUS_CULLED`], [`STATUS_STALE`].
    status: Vec<u8>,
    /// Per pixel, one bit (layout of [`pixel_bit`]): pixels an incremental pass 2 recomputes.
    recompute: Vec<u64>,
    /// Pixels whose depth-buffer entry changed in an incremental pass 1.
    changed: Vec<u32>,
    /// Per pixel: its point's colour as [`fresh::display_rgb`] packs it (`fresh.rs`).
    display: Vec<u32>,
    /// Per point: where it projected in the last frame.
    proj: Vec<Projected>,
    points: PointImage,
    weights: Vec<f32>,
    image: Vec<Vec3>,
    /// Per pixel: the sampling gain of its point's noise ([`Self::update_noise_gains`]).
    gains: Vec<f32>,
}

/// Inserts remembered between two reprojections of a still view (a frame asks for 1/64 of
/// the pixels by default); more make the next reprojection a full one.
fn max_inserted(pixels: usize) -> usize {
    (pixels / 8).max(1024)
}

/// Pool capacity of a cache of `pixels` pixels ([`CacheConfig::points_per_pixel`] clamped).
fn capacity_for(pixels: usize, points_per_pixel: f32) -> usize {
    let ppp = if points_per_pixel.is_finite() { points_per_pixel.clamp(0.0, 64.0) } else { 2.0 };
    // Indices must stay below NO_POINT.
    ((pixels as f64 * ppp as f64) as usize).min(NO_POINT as usize - 1)
}

impl RenderCache {
    /// Bytes a cache of this configuration allocates at its largest: what [`Self::new`]
    /// allocates (the pool, the replacement queues' reserve, the per-pixel buffers) plus the
    /// depth buffers that reprojection adds, one per share of the points on a pool of
    /// `threads` threads. The session's memory accounting adds this up: a buffer added to
    /// the cache is added here (a test compares it with what `new` and a frame allocate).
    pub fn bytes_for(width: u32, height: u32, points_per_pixel: f32, threads: usize) -> usize {
        use std::mem::size_of;
        let pixels = width as usize * height as usize;
        let capacity = capacity_for(pixels, points_per_pixel);
        let pool = 3 * 4 + 3 * 2 + size_of::<Shade>() + 4 + 8 + size_of::<[u32; 2]>() + 1 + 8 + 2 + 1 + size_of::<[f32; 2]>();
        // Projections, the free lists and the oldest-first queues (reserved at 2 entries per
        // slot plus 64 per region).
        let per_point = pool + size_of::<Projected>() + 4 + 2 * size_of::<(u64, u32)>();
        let bands = height.div_ceil(BAND_ROWS).max(1) as usize;
        let per_region = size_of::<Region>() + 64 * size_of::<(u64, u32)>();
        let shares = threads.clamp(1, 16).min(capacity.max(1));
        // The depth buffers, zmin_row, the point image, the weights, the image, the gains.
        let per_pixel = shares * 8 + 4 + PointImage::BYTES_PER_PIXEL + 4 + size_of::<Vec3>() + 4;
        // give_way and recompute (bit masks), display, status, the inserted and lost lists,
        // the changed pixels.
        let masks = 2 * 8 * height as usize * (width as usize).div_ceil(64);
        let lists = (size_of::<(u32, u64, Projected)>() + 4 + 4 * 2) * max_inserted(pixels);
        let give_way = masks + 4 * pixels + pixels + lists;
        capacity * per_point + bands * per_region + size_of::<Vec<u64>>() * shares + pixels * per_pixel + give_way
    }

    pub fn new(cfg: CacheConfig) -> Self {
        let pixels = cfg.width as usize * cfg.height as usize;
        let capacity = capacity_for(pixels, cfg.points_per_pixel);
        let pool = Pool {
            px: vec![0.0; capacity],
            py: vec![0.0; capacity],
            pz: vec![0.0; capacity],
            nx: vec![0; capacity],
            ny: vec![0; capacity],
            nz: vec![0; capacity],
            shade: vec![Shade::default(); capacity],
            object: vec![u32::MAX; capacity],
            epoch: vec![0; capacity],
            pixel: vec![[0; 2]; capacity],
            flags: vec![0; capacity],
            stamp: vec![0; capacity],
            samples: vec![0; capacity],
            drift: vec![0; capacity],
            spread: vec![[0.0; 2]; capacity],
        };
        // Region of band b: slots in proportion to the pixels before the band.
        let bands = (cfg.height.div_ceil(BAND_ROWS)).max(1);
        let slot_at = |row: u32| -> u32 {
            let px = row.min(cfg.height) as u64 * cfg.width as u64;
            if pixels == 0 {
                0
            } else {
                (capacity as u64 * px / pixels as u64) as u32
            }
        };
        let regions = (0..bands)
            .map(|b| {
                let end = if b + 1 == bands { capacity as u32 } else { slot_at((b + 1) * BAND_ROWS) };
                Region::new(slot_at(b * BAND_ROWS), end)
            })
            .collect();
        Self {
            cfg,
            capacity,
            pool,
            valid: 0,
            regions,
            next_stamp: 0,
            averaged: 0,
            frame: 0,
            zbufs: vec![vec![EMPTY_KEY; pixels]],
            zmin_row: vec![u32::MAX; pixels],
            give_way: vec![0; cfg.height as usize * (cfg.width as usize).div_ceil(64)],
            display: vec![0; pixels],
            last_view: None,
            reproject_all: true,
            inserted_slots: Vec::with_capacity(max_inserted(pixels)),
            lost_pixels: Vec::with_capacity(max_inserted(pixels)),
            stale_shown: 0,
            culled_shown: 0,
            point_image_from: None,
            status: vec![0; pixels],
            recompute: vec![0; cfg.height as usize * (cfg.width as usize).div_ceil(64)],
            changed: Vec::with_capacity(2 * max_inserted(pixels)),
            proj: vec![Projected::NONE; capacity],
            points: PointImage::new(cfg.width, cfg.height),
            weights: vec![0.0; pixels],
            image: vec![cfg.background; pixels],
            gains: vec![1.0; pixels],
        }
    }

    pub fn config(&self) -> &CacheConfig {
        &self.cfg
    }

    /// Stores a sample in the fixed pool, in the region of its pixel's row band, replacing (in
    /// this order) an invalid slot, a point that was hidden in the last frame, or the oldest
    /// point (a sample aimed at a cached point goes in by [`Self::insert_aimed`]). Hidden
    /// points are looked for with a clock hand that examines a bounded number of slots per
    /// insert, so when hidden points are rare an insert may take the oldest point although a
    /// hidden one exists elsewhere in the region. A pixel row beyond the
    /// image counts as the last row. Returns `false` (and stores
    /// nothing) for a sample with non-finite position or colour, a miss whose direction is
    /// zero, or a cache of capacity 0.
    pub fn insert(&mut self, s: &Sample) -> bool {
        self.insert_aged(s, false)
    }

    /// [`Self::insert`], with the point given [`STALE_AGE`] when `stale`: its shading was
    /// computed before a change that may have altered it (its object moved while it was
    /// being shaded), so it shows until prioritized sampling re-shades it, first.
    pub fn insert_aged(&mut self, s: &Sample, stale: bool) -> bool {
        if !s.position.is_finite() || !s.color.is_finite() || (!s.hit && s.position.length_squared() < 1e-12) {
            return false;
        }
        let band = (s.pixel[1] / BAND_ROWS).min(self.regions.len() as u32 - 1) as usize;
        let Some(slot) = self.take_slot(band) else { return false };
        self.write(slot, band, s, stale)
    }

    /// Writes sample `s` into `slot` of region `band` as a new point of one sample.
    fn write(&mut self, slot: u32, band: usize, s: &Sample, stale: bool) -> bool {
        let i = slot as usize;
        let born = self.frame;
        self.note_replaced(i);
        let p = &mut self.pool;
        if p.flags[i] & FLAG_VALID == 0 {
            self.valid += 1;
        }
        let pos = if s.hit { s.position } else { s.position.normalize() };
        (p.px[i], p.py[i], p.pz[i]) = (pos.x, pos.y, pos.z);
        let n = if s.hit && s.normal.is_finite() { s.normal.normalize_or_zero() } else { Vec3::ZERO };
        (p.nx[i], p.ny[i], p.nz[i]) = (snorm16(n.x), snorm16(n.y), snorm16(n.z));
        p.shade[i] = Shade { color: s.color, born };
        p.object[i] = s.object;
        p.epoch[i] = s.epoch;
        p.pixel[i] = s.pixel;
        p.flags[i] = FLAG_VALID | if s.hit { FLAG_HIT } else { 0 } | if stale { FLAG_STALE } else { 0 };
        p.samples[i] = 1;
        p.drift[i] = 0;
        p.spread[i] = [converge::tone(s.color), 0.0];
        p.stamp[i] = self.next_stamp;
        // Not part of the last frame: never taken for a hidden point.
        self.proj[i] = Projected::NONE;
        self.project_inserted(i);
        self.enqueue(band, slot);
        true
    }

    /// Puts `slot`, just stamped `next_stamp`, at the young end of region `band`'s
    /// oldest-first queue.
    fn enqueue(&mut self, band: usize, slot: u32) {
        let r = &mut self.regions[band];
        r.oldest.push_back((self.next_stamp, slot));
        self.next_stamp += 1;
        if r.oldest.len() > 2 * (r.end - r.start) as usize + 64 {
            // Drop entries of reused slots so the queue stays bounded by the region size.
            let (flags, stamp) = (&self.pool.flags, &self.pool.stamp);
            r.oldest.retain(|&(st, j)| flags[j as usize] & FLAG_VALID != 0 && stamp[j as usize] == st);
        }
    }

    /// A slot of region `band`: invalid, else hidden in the last frame (among the next
    /// `HIDDEN_SCAN` slots of a clock-hand scan), else the oldest.
    fn take_slot(&mut self, band: usize) -> Option<u32> {
        if let Some(slot) = self.regions[band].free.pop() {
            return Some(slot);
        }
        // Look at a bounded number of slots per insert, continuing round the region where
        // the last look stopped, so an insert costs O(1) even when few points are hidden.
        let (start, end) = (self.regions[band].start, self.regions[band].end);
        for _ in 0..HIDDEN_SCAN.min(end - start) {
            let mut i = self.regions[band].hidden_cursor;
            if i >= end {
                i = start;
            }
            self.regions[band].hidden_cursor = i + 1;
            if self.pool.flags[i as usize] & FLAG_VALID != 0 && self.was_hidden(i as usize) {
                return Some(i);
            }
        }
        let p = &self.pool;
        let r = &mut self.regions[band];
        while let Some((st, j)) = r.oldest.pop_front() {
            if p.flags[j as usize] & FLAG_VALID != 0 && p.stamp[j as usize] == st {
                return Some(j);
            }
        }
        None
    }

    /// Remembers that slot `i` is about to be written, for the next reprojection of a still
    /// view: its new point needs projecting, and the pixel its old point was nearest in
    /// needs recomputing.
    fn note_replaced(&mut self, i: usize) {
        if self.reproject_all {
            return;
        }
        if self.inserted_slots.len() >= self.inserted_slots.capacity() {
            self.reproject_all = true;
            return;
        }
        let pr = self.proj[i];
        if pr.pixel != NO_POINT && self.zbufs[0][pr.pixel as usize] as u32 as usize == i {
            self.lost_pixels.push(pr.pixel);
        }
        self.inserted_slots.push((i as u32, 0, Projected::NONE));
    }

    /// Index of the region holding slot `i`.
    fn region_of(&self, i: u32) -> usize {
        self.regions.partition_point(|r| r.end <= i)
    }

    /// Whether point `i` was hidden in the last frame: culled as occluded, or behind its
    /// pixel's nearest point by the relative depth threshold, or behind a culled one. Decided
    /// lazily, when replacement looks for a slot, from the last frame's depth buffer and point
    /// image (both stay untouched until the next frame), so reprojection spends nothing on
    /// the points that lost their pixel.
    fn was_hidden(&self, i: usize) -> bool {
        let pr = self.proj[i];
        if pr.pixel == NO_POINT {
            return false;
        }
        let p = pr.pixel as usize;
        let key = self.zbufs[0][p];
        let culled = self.points.point[p] == NO_POINT;
        if key as u32 as usize == i {
            culled
        } else {
            culled || reproject::key_depth(key) * (1.0 + DEPTH_CULL_RELATIVE) < pr.depth
        }
    }

    /// Drops every point on one of `objects` (they moved: their cached shading and position
    /// are wrong). The slots become free for new samples.
    pub fn invalidate_objects(&mut self, objects: &[u32]) {
        if objects.is_empty() {
            return;
        }
        let mut sorted = objects.to_vec();
        sorted.sort_unstable();
        sorted.dedup();
        let p = &self.pool;
        let slots: Vec<u32> = (0..self.capacity as u32)
            .filter(|&i| p.flags[i as usize] & FLAG_VALID != 0 && sorted.binary_search(&p.object[i as usize]).is_ok())
            .collect();
        self.drop_points(&slots);
    }

    /// Drops the points in `slots` (valid ones, each once): their slots become free for new
    /// samples, and the next reprojection redoes every pixel.
    pub(crate) fn drop_points(&mut self, slots: &[u32]) {
        self.reproject_all = true;
        for &i in slots {
            self.pool.flags[i as usize] = 0;
            let r = self.region_of(i);
            self.regions[r].free.push(i);
            self.valid -= 1;
        }
        // Reuse lowest slots first, as after construction.
        for r in &mut self.regions {
            r.free.sort_unstable_by(|a, b| b.cmp(a));
        }
    }

    /// Ages to [`STALE_AGE`] the hit points whose shading something occupying the world box
    /// `region` may change (DESIGN.md "Motion", step 1 of a frame: an object moved from or
    /// into `region`): those from which a shadow ray toward some light can pass through the
    /// box. Conservative: the segment from the point to the light's centre is tested against
    /// the box grown by the light's radius, which contains every ray from the point to the
    /// light's emitting surface where it crosses the box. Their shading stays visible until
    /// re-shaded; prioritized sampling re-shades stale points first. Returns the points aged
    /// (those not stale already). A move asks more where it can ([`Self::reshadow`]).
    pub fn age_shadowed_by(&mut self, region: (Vec3, Vec3), lights: &[LightBound]) -> u32 {
        self.reshadow(region, lights, &reshadow::NoExactAnswer).stale
    }

    /// Gives every point maximal age ([`STALE_AGE`]): its shading may have changed (e.g. a
    /// light or a shadowing object moved), so prioritized sampling re-shades it first and
    /// replacement takes it before fresh points, but it stays visible until replaced.
    pub fn mark_stale(&mut self) {
        self.point_image_from = None;
        for f in self.pool.flags.iter_mut() {
            if *f & FLAG_VALID != 0 {
                *f |= FLAG_STALE;
            }
        }
    }

    /// Age in frames of a point shaded at frame `born`.
    #[inline]
    pub(crate) fn age_of(frame: u32, born: u32) -> f32 {
        // Through i32, which converts to f32 four or eight at a time (u32 to f32 is emulated
        // on x86-64, i64 to f32 is one at a time): differences of 2^31 and more are negative
        // there, and older than STALE_AGE anyway.
        let d = frame.wrapping_sub(born) as i32;
        let a = d as f32;
        if d >= 0 && a < STALE_AGE {
            a
        } else {
            STALE_AGE
        }
    }

    /// Removes every point.
    pub fn clear(&mut self) {
        self.reproject_all = true;
        self.pool.flags.iter_mut().for_each(|f| *f = 0);
        for r in &mut self.regions {
            r.free.clear();
            r.free.extend((r.start..r.end).rev());
            r.oldest.clear();
        }
        self.valid = 0;
    }

    /// Number of valid points.
    pub fn len(&self) -> usize {
        self.valid
    }

    pub fn is_empty(&self) -> bool {
        self.valid == 0
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The point in slot `index` (as found in [`PointImage::point`]), if valid.
    pub fn point(&self, index: u32) -> Option<CachedPoint> {
        let i = index as usize;
        let p = &self.pool;
        if i >= self.capacity || p.flags[i] & FLAG_VALID == 0 {
            return None;
        }
        Some(CachedPoint {
            hit: p.flags[i] & FLAG_HIT != 0,
            position: Vec3::new(p.px[i], p.py[i], p.pz[i]),
            normal: Vec3::new(unorm(p.nx[i]), unorm(p.ny[i]), unorm(p.nz[i])),
            color: p.shade[i].color,
            object: p.object[i],
            epoch: p.epoch[i],
            pixel: p.pixel[i],
            age: if p.flags[i] & FLAG_STALE != 0 { STALE_AGE } else { Self::age_of(self.frame, p.shade[i].born) },
            samples: u32::from(p.samples[i]),
        })
    }

    /// One frame: age the points, reproject them with `cam` (nearest point per pixel), cull
    /// the points their 3x3 neighbourhood shows to be occluded, interpolate to fill gaps ->
    /// [`Self::image`], [`Self::point_image`], [`Self::filter_weights`]. Times go to
    /// `times` under [`STAGE_REPROJECT`] and [`STAGE_INTERPOLATE`].
    ///
    /// `cam` must be a frame for this cache's image size; a frame of another size is used
    /// with this cache's size (only its eye, basis and field of view matter).
    pub fn reproject_and_interpolate(
        &mut self,
        cam: &edgepoint_scene::camera::CameraFrame,
        times: &mut crate::stage_times::StageTimes,
    ) -> FrameCounts {
        let occluded = self.reproject_points(cam, None, times);
        let (with_point, filled, empty) = self.interpolate_gaps(times);
        FrameCounts { with_point, filled, empty, occluded, cache_points: self.valid as u32 }
    }

    /// The first half of [`Self::reproject_and_interpolate`]: ages the points and builds the
    /// point image ([`STAGE_REPROJECT`]), culling points hidden by their neighbours and, when
    /// given, by the scene's surfaces (`geometry`, one entry per pixel). Returns the number of
    /// pixels whose point was culled. Another reconstruction (the edge-and-point image) can
    /// then fill the frame through [`Self::reconstruction_target`].
    ///
    /// Panics if `geometry` does not have one entry per pixel (a caller bug).
    pub fn reproject_points(
        &mut self,
        cam: &edgepoint_scene::camera::CameraFrame,
        geometry: Option<GeometryCull>,
        times: &mut crate::stage_times::StageTimes,
    ) -> u32 {
        let mut cam = *cam;
        cam.width = self.cfg.width;
        cam.height = self.cfg.height;
        cam.aspect = self.cfg.width as f32 / self.cfg.height.max(1) as f32;
        if let Some(g) = &geometry {
            let n = self.cfg.width as usize * self.cfg.height as usize;
            assert!(g.far3.len() == n && g.inverse_depth.len() == n, "geometry cull images of the wrong size");
        }
        self.frame = self.frame.wrapping_add(1);
        times.time(STAGE_REPROJECT, || self.reproject(&cam, geometry))
    }

    /// Carries the points on `object` along when it moves from transform `from` to `to`
    /// (DESIGN.md "Motion": a cached point keeps its place on its object), and ages them to
    /// [`STALE_AGE`]: their shading was computed in the old place, so prioritized sampling
    /// re-shades them first, but they keep showing the object meanwhile. Returns the number
    /// of points moved.
    pub fn move_object(&mut self, object: u32, from: &glam::Affine3A, to: &glam::Affine3A) -> u32 {
        // The change of place, composed in f64 so that a long series of moves does not drift.
        let d = glam::DAffine3::from_cols_array(&to.to_cols_array().map(f64::from))
            * glam::DAffine3::from_cols_array(&from.to_cols_array().map(f64::from)).inverse();
        let d = glam::Affine3A::from_cols_array(&d.to_cols_array().map(|v| v as f32));
        let normal_matrix = glam::Mat3::from(d.matrix3).inverse().transpose();
        self.reproject_all = true;
        let p = &mut self.pool;
        let mut moved = 0;
        for i in 0..self.capacity {
            if p.object[i] == object && p.flags[i] & (FLAG_VALID | FLAG_HIT) == FLAG_VALID | FLAG_HIT {
                let w = d.transform_point3(Vec3::new(p.px[i], p.py[i], p.pz[i]));
                (p.px[i], p.py[i], p.pz[i]) = (w.x, w.y, w.z);
                let n = (normal_matrix * Vec3::new(unorm(p.nx[i]), unorm(p.ny[i]), unorm(p.nz[i]))).normalize_or_zero();
                (p.nx[i], p.ny[i], p.nz[i]) = (snorm16(n.x), snorm16(n.y), snorm16(n.z));
                p.flags[i] |= FLAG_STALE;
                // Stale for its own move, not for a shadow's: no longer judged by `reshadow`.
                p.drift[i] = 0;
                moved += 1;
            }
        }
        moved
    }

    /// The Render Cache's own gap-filling interpolation of the last reprojection
    /// ([`STAGE_INTERPOLATE`]): returns (pixels with a point, filled, empty).
    pub fn interpolate_gaps(&mut self, times: &mut crate::stage_times::StageTimes) -> (u32, u32, u32) {
        times.time(STAGE_INTERPOLATE, || self.interpolate())
    }

    /// The last point image with the frame buffers another reconstruction writes into: the
    /// image ([`Self::image`]) and the un-normalised filter weights ([`Self::filter_weights`]).
    pub fn reconstruction_target(&mut self) -> (&PointImage, &mut [Vec3], &mut [f32]) {
        (&self.points, &mut self.image, &mut self.weights)
    }

    /// The background colour (pixels no sample reaches).
    pub fn background(&self) -> Vec3 {
        self.cfg.background
    }

    /// The filled frame: linear RGB, row-major, `width * height`.
    pub fn image(&self) -> &[Vec3] {
        &self.image
    }

    /// The reprojected per-pixel points of the last frame.
    pub fn point_image(&self) -> &PointImage {
        &self.points
    }

    /// Un-normalised interpolation weight per pixel of the last frame (0 where nothing is
    /// reachable) — the sampling priority's input (§5.3).
    pub fn filter_weights(&self) -> &[f32] {
        &self.weights
    }

    pub fn width(&self) -> u32 {
        self.cfg.width
    }

    pub fn height(&self) -> u32 {
        self.cfg.height
    }
}

#[cfg(test)]
mod tests;
