//! Reprojection and depth culling of the Render Cache (paper 000 §4.3; Walter et al. 1999
//! §3.2 "depth culling"). Data-parallel over points and rows, without locks or atomic
//! read-modify-writes (which cost more than the projection itself): each worker thread owns
//! a plain depth buffer for its contiguous share of the points, and a parallel pass over
//! rows merges them. A depth-buffer entry is `(depth bits << 32) | point index`, the
//! minimum wins: positive `f32` bit patterns order like the floats, a point at infinity (a
//! miss) is behind every hit, and equal depths go to the lower index.
use super::{pixel_bit, GeometryCull, Projected, RenderCache, Shade, DEPTH_CULL_RELATIVE, EMPTY_KEY, FLAG_HIT, FLAG_STALE, FLAG_VALID, GEOMETRY_CULL_RELATIVE, STALE_AGE, STATUS_CULLED, STATUS_STALE, NO_POINT};
use edgepoint_scene::camera::CameraFrame;
use glam::Vec3;
use rayon::prelude::*;

/// The camera prepared for projecting many points: the image-plane axes pre-scaled to pixels,
/// so a point costs three dot products and one division.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Projector {
    eye: Vec3,
    rx: Vec3,
    uy: Vec3,
    f: Vec3,
    cx: f32,
    cy: f32,
    width: u32,
    height: u32,
    wf: f32,
    hf: f32,
}

impl Projector {
    pub(crate) fn new(cam: &CameraFrame) -> Self {
        let cx = 0.5 * cam.width as f32;
        let cy = 0.5 * cam.height as f32;
        let rx = cam.right * (cx / (cam.tan_half_y * cam.aspect));
        let uy = cam.up * (cy / cam.tan_half_y);
        let f = cam.forward;
        Self { eye: cam.eye, rx, uy, f, cx, cy, width: cam.width, height: cam.height, wf: cam.width as f32, hf: cam.height as f32 }
    }

    /// Whether `other` projects every point exactly as this does (bitwise the same view).
    pub(crate) fn same_as(&self, other: &Projector) -> bool {
        let bits = |p: &Projector| {
            let v = [p.eye, p.rx, p.uy, p.f].map(|v| v.to_array().map(f32::to_bits));
            (v, [p.cx, p.cy, p.wf, p.hf].map(f32::to_bits), p.width, p.height)
        };
        bits(self) == bits(other)
    }

    /// Projects a cached point: a hit is a world position, a miss a direction (a point at
    /// infinity, view depth `+inf`). Returns continuous pixel coordinates and view depth, or
    /// `None` behind (or too near) the eye. Agrees with `CameraFrame::project` up to
    /// rounding. The reference for the hand-written loop of `project_share` (the tests
    /// check that the cache reproduces it exactly).
    #[cfg(test)]
    pub(crate) fn project(&self, p: Vec3, hit: bool) -> Option<(f32, f32, f32)> {
        let d = if hit { p - self.eye } else { p };
        // Same expression as `CameraFrame::project`, so hit depths are identical.
        let z = d.dot(self.f);
        if z <= 1e-6 {
            return None;
        }
        let inv = 1.0 / z;
        let sx = self.cx + d.dot(self.rx) * inv;
        let sy = self.cy - d.dot(self.uy) * inv;
        Some((sx, sy, if hit { z } else { f32::INFINITY }))
    }
}

/// Depth of a depth-buffer entry; NaN for an empty one (all ones).
#[inline]
pub(crate) fn key_depth(key: u64) -> f32 {
    f32::from_bits((key >> 32) as u32)
}

/// Offsets of the 8 neighbours, ordered so that direction `k` and `k + 4` are opposite.
const NEIGHBOURS: [(isize, isize); 8] = [(-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1), (0, 1), (-1, 1)];

/// Depth culling after Walter et al.'s relative depth test, made silhouette- and
/// slope-safe. The point of pixel (x, y) at depth `dc` is occluded when
/// - some opposite pair of its 8 neighbours are both nearer than it by the relative
///   threshold: it lies *inside* the footprint of a nearer surface, as when it shows
///   through a gap between that surface's points; outside a convex silhouette no opposite
///   pair can both be nearer, so backgrounds are not eaten away beside objects (a mean-depth
///   test culls them there every frame); and
/// - no opposite pair brackets it (one nearer, the other farther by the threshold): that is
///   a surface whose depth changes fast across the pixel (a plane at a grazing angle, where
///   jittered sample positions alone change depth by more than the threshold), which the
///   point belongs to.
///
/// `zbuf` is the merged depth buffer; an empty entry decodes to NaN, which is neither
/// nearer nor farther.
#[inline]
pub(crate) fn is_occluded(zbuf: &[u64], w: usize, h: usize, x: usize, y: usize, dc: f32) -> bool {
    let mut nb = [f32::NAN; 8];
    if x > 0 && y > 0 && x + 1 < w && y + 1 < h {
        let i = y * w + x;
        for (k, o) in [i - 1, i - w - 1, i - w, i - w + 1, i + 1, i + w + 1, i + w, i + w - 1].into_iter().enumerate() {
            nb[k] = key_depth(zbuf[o]);
        }
    } else {
        for (k, &(dx, dy)) in NEIGHBOURS.iter().enumerate() {
            let (nx, ny) = (x as isize + dx, y as isize + dy);
            if nx >= 0 && ny >= 0 && nx < w as isize && ny < h as isize {
                nb[k] = key_depth(zbuf[ny as usize * w + nx as usize]);
            }
        }
    }
    let t = 1.0 + DEPTH_CULL_RELATIVE;
    let (mut near, mut far) = (0u32, 0u32);
    for (k, &d) in nb.iter().enumerate() {
        near |= u32::from(d * t < dc) << k;
        far |= u32::from(d > dc * t) << k;
    }
    // Bit k of the low nibble is pair (k, k+4).
    let sandwich = near & (near >> 4) & 0xF;
    let bracket = ((near & (far >> 4)) | (far & (near >> 4))) & 0xF;
    sandwich != 0 && bracket == 0
}

impl RenderCache {
    /// Projects every point, keeps the nearest per pixel, culls occluded ones and builds the
    /// point image. Returns the number of pixels whose point was culled. Which points lost
    /// their pixel is left in the depth buffer (`zbufs[0]`) and `proj` for replacement to read.
    pub(super) fn reproject(&mut self, cam: &CameraFrame, geometry: Option<GeometryCull>) -> u32 {
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        let pixels = w * h;
        if pixels == 0 {
            return 0;
        }
        // One depth buffer per share of the points; allocated again only if the thread
        // count changes.
        let shares = rayon::current_num_threads().clamp(1, 16).min(self.capacity.max(1));
        if self.zbufs.len() != shares {
            self.zbufs.resize_with(shares, || vec![EMPTY_KEY; pixels]);
        }
        let share = self.capacity.div_ceil(shares).max(1);

        let prj = Projector::new(cam);
        // The same view as last frame and no point moved: only the points inserted since
        // need projecting (see `reproject_inserted`).
        let same_view = self.last_view.is_some_and(|v| v.same_as(&prj));
        if same_view && !self.reproject_all {
            // And pass 2 may recompute only the pixels around those whose depth-buffer
            // entry changed, when its last result stands and it culls against the same
            // geometry.
            let in_place = self.point_image_from == Some(geometry.as_ref().map(|g| g.generation));
            self.reproject_inserted(in_place);
            return if in_place { self.update_point_image(geometry) } else { self.build_point_image(geometry) };
        }
        self.reproject_all = false;
        self.last_view = Some(prj);
        self.inserted_slots.clear();
        self.lost_pixels.clear();

        // Pass 1, over points: project, nearest per pixel into the share's depth buffer.
        let pool = &self.pool;
        self.zbufs.par_iter_mut().for_each(|z| z.fill(EMPTY_KEY));
        self.zbufs.par_iter_mut().zip(self.proj.par_chunks_mut(share)).enumerate().for_each(|(k, (zbuf, proj))| {
            let base = k * share;
            let n = proj.len();
            let r = base..base + n;
            let xyz = [&pool.px[r.clone()], &pool.py[r.clone()], &pool.pz[r.clone()]];
            let n = [&pool.nx[r.clone()], &pool.ny[r.clone()], &pool.nz[r.clone()]];
            project_share(&prj, base, &pool.flags[r], xyz, n, proj, zbuf);
        });

        // Merge the shares into zbufs[0] and take the nearest depth over each pixel and its
        // row neighbours.
        let (z0, rest) = self.zbufs.split_first_mut().expect("at least one depth buffer");
        z0.par_chunks_mut(w).zip(self.zmin_row.par_chunks_mut(w)).enumerate().for_each(|(y, (zrow, mrow))| merge_row(rest, y, zrow, mrow));
        self.build_point_image(geometry)
    }

    /// Pass 1 for a still view: the depth buffer of the last frame stays, less the entries
    /// of points replaced since (their pixels are recomputed from every point that landed
    /// there, read from `proj`), plus the points inserted since. The result equals a full
    /// pass 1 (the tests compare them): the same arithmetic, the same keys. With `track`,
    /// the pixels whose entry may have changed go to `changed` and only their row minima
    /// are recomputed (for [`Self::update_point_image`]).
    fn reproject_inserted(&mut self, track: bool) {
        let w = self.cfg.width as usize;
        let z0 = &mut self.zbufs[0];
        let lost = &mut self.give_way;
        self.changed.clear();
        if !self.lost_pixels.is_empty() {
            lost.iter_mut().for_each(|b| *b = 0);
            for &p in &self.lost_pixels {
                let p = p as usize;
                let (word, bit) = pixel_bit(w, p);
                lost[word] |= bit;
                z0[p] = EMPTY_KEY;
            }
            if track {
                self.changed.extend_from_slice(&self.lost_pixels);
            }
            // Every point that landed on a lost pixel competes for it again: a scan of the
            // projections in parallel chunks, each keeping its candidates.
            let lost = &*lost;
            let candidates: Vec<(u32, u64)> = self
                .proj
                .par_chunks(64 * 1024)
                .enumerate()
                .flat_map_iter(|(c, chunk)| {
                    chunk.iter().enumerate().filter_map(move |(k, pr)| {
                        let p = pr.pixel as usize;
                        let (word, bit) = pixel_bit(w, p);
                        (pr.pixel != NO_POINT && lost[word] & bit != 0).then(|| (pr.pixel, key_of(pr.depth, c * 64 * 1024 + k)))
                    })
                })
                .collect();
            for (p, key) in candidates {
                let e = &mut z0[p as usize];
                if key < *e {
                    *e = key;
                }
            }
        }
        let stamps = &self.pool.stamp;
        for &(i, stamp, placed) in &self.inserted_slots {
            let i = i as usize;
            if stamps[i] != stamp {
                // Written again since: a later entry holds its point.
                continue;
            }
            self.proj[i] = placed;
            if placed.pixel != NO_POINT {
                let p = placed.pixel as usize;
                let key = key_of(placed.depth, i);
                if key < z0[p] {
                    z0[p] = key;
                    if track {
                        self.changed.push(p as u32);
                    }
                }
            }
        }
        self.inserted_slots.clear();
        self.lost_pixels.clear();
        if track {
            // The row minima of a pixel read it and its two row neighbours.
            for &p in &self.changed {
                let (y, x) = (p as usize / w, p as usize % w);
                let (zrow, mrow) = (&z0[y * w..(y + 1) * w], &mut self.zmin_row[y * w..(y + 1) * w]);
                let x0 = x.saturating_sub(1);
                for (k, m) in mrow[x0..(x + 2).min(w)].iter_mut().enumerate() {
                    *m = row_min(zrow, x0 + k);
                }
            }
        } else {
            z0.par_chunks_mut(w).zip(self.zmin_row.par_chunks_mut(w)).for_each(|(zrow, mrow)| merge_row(&[], 0, zrow, mrow));
        }
    }

    /// Where the point just written to slot `i` lands in the still view, for the next
    /// [`Self::reproject_inserted`]: computed now, while the point is in cache (its arrays,
    /// read later at scattered slots, cost a cache miss each), by the same arithmetic as
    /// pass 1. Nothing when the next reprojection is a full one.
    pub(super) fn project_inserted(&mut self, i: usize) {
        let Some(prj) = self.last_view.filter(|_| !self.reproject_all) else { return };
        let Some(last) = self.inserted_slots.last_mut().filter(|e| e.0 as usize == i) else { return };
        let pool = &self.pool;
        let flag = pool.flags[i];
        let math = project_math(&prj, flag, (pool.px[i], pool.py[i], pool.pz[i]), (pool.nx[i], pool.ny[i], pool.nz[i]));
        *last = (i as u32, pool.stamp[i], place(&prj, flag, math).map_or(Projected::NONE, |(_, placed)| placed));
    }

    /// Pass 2 of a still view, in place: the last point image stands except around the
    /// pixels whose depth-buffer entry changed (`changed`) — a pixel's outcome reads the
    /// depth buffer over its 3x3 neighbourhood only — and for the ages, which grow by a
    /// frame. Recomputes those pixels exactly as [`Self::build_point_image`] would and keeps
    /// the counts by the difference (the tests compare the two).
    fn update_point_image(&mut self, geometry: Option<GeometryCull>) -> u32 {
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        let words = w.div_ceil(64);
        let mask = &mut self.recompute;
        mask.iter_mut().for_each(|b| *b = 0);
        let changed = &mut self.give_way;
        changed.iter_mut().for_each(|b| *b = 0);
        for &p in &self.changed {
            let (y, x) = (p as usize / w, p as usize % w);
            changed[y * words + x / 64] |= 1 << (x % 64);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    mask[yy * words + xx / 64] |= 1 << (xx % 64);
                }
            }
        }
        self.changed.clear();
        let ctx = RowContext::new(&self.zbufs[0], &self.zmin_row, &self.proj, &self.pool, self.frame, w, h, geometry);
        let pi = &mut self.points;
        let frame = self.frame;
        let (dc, ds) = rows(pi, &mut self.status, w)
            .zip(self.recompute.par_chunks(words))
            .zip(self.give_way.par_chunks(words))
            .enumerate()
            .map(|(y, ((mut r, bits), changed))| {
                // Ages first (a stale point's stays STALE_AGE; a missing point's infinity).
                // As a select, not a branch, so that the loop vectorises.
                for (a, &b) in r.ag.iter_mut().zip(r.bo.iter()) {
                    let grown = RenderCache::age_of(frame, b);
                    *a = if *a < STALE_AGE { grown } else { *a };
                }
                let (mut dc, mut ds) = (0i64, 0i64);
                for (k, &word) in bits.iter().enumerate() {
                    let mut b = word;
                    while b != 0 {
                        let x = k * 64 + b.trailing_zeros() as usize;
                        b &= b - 1;
                        let (old, old_point) = (r.st[x], r.pt[x]);
                        let kept = cull_pixel(&ctx, y, x, &mut r);
                        // Around a changed pixel the nearest point is the same one: only
                        // whether it is culled may change (the point read costs a cache miss).
                        let same = changed[k] & (1 << (x % 64)) == 0 && old_point == r.pt[x];
                        if same {
                            r.st[x] |= old & STATUS_STALE;
                        } else if kept {
                            fill_pixel(&ctx, x, &mut r);
                        } else {
                            clear_pixel(x, &mut r);
                        }
                        dc += i64::from(r.st[x] & STATUS_CULLED) - i64::from(old & STATUS_CULLED);
                        ds += i64::from((r.st[x] & STATUS_STALE) >> 1) - i64::from((old & STATUS_STALE) >> 1);
                    }
                }
                (dc, ds)
            })
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        self.culled_shown = (i64::from(self.culled_shown) + dc) as u32;
        self.stale_shown = (i64::from(self.stale_shown) + ds) as u32;
        self.culled_shown
    }

    /// Pass 2, over rows: depth culling against the 3x3 neighbourhood, then the point
    /// image. Returns the number of culled points; counts the stale points shown.
    fn build_point_image(&mut self, geometry: Option<GeometryCull>) -> u32 {
        let (w, h) = (self.cfg.width as usize, self.cfg.height as usize);
        let ctx = RowContext::new(&self.zbufs[0], &self.zmin_row, &self.proj, &self.pool, self.frame, w, h, geometry);
        let pi = &mut self.points;
        let counts = rows(pi, &mut self.status, w)
            .enumerate()
            .map(|(y, mut r)| build_row(&ctx, y, &mut r))
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        let (culled, stale) = counts;
        self.stale_shown = stale;
        self.culled_shown = culled;
        self.point_image_from = Some(geometry.as_ref().map(|g| g.generation));
        culled
    }
}

/// Points per block of pass 1.
const BLOCK: usize = 256;

/// The arithmetic of pass 1 for one point (position `x, y, zz` as stored, normal `n`,
/// `flag` its flags): view depth, continuous pixel coordinates and the facing value
/// n · (p − eye). Inlined into the vectorised loop of [`project_share`] and called alone for
/// single points, so both give identical results.
#[inline(always)]
fn project_math(prj: &Projector, flag: u8, (px, py, pz): (f32, f32, f32), (nx, ny, nz): (i16, i16, i16)) -> (f32, f32, f32, f32) {
    let (e, r, u, f) = (prj.eye, prj.rx, prj.uy, prj.f);
    // 1 for a hit (subtract the eye), 0 for a miss direction.
    let hm = f32::from((flag >> 1) & 1);
    let (x, y, zz) = (px - e.x * hm, py - e.y * hm, pz - e.z * hm);
    let z = x * f.x + y * f.y + zz * f.z;
    let inv = 1.0 / z;
    // n · (p - eye): negative when the eye is on the side the point was shaded from
    // (a zero normal, unknown side, or a miss gives zero and passes).
    let facing = f32::from(nx) * x + f32::from(ny) * y + f32::from(nz) * zz;
    let sx = prj.cx + (x * r.x + y * r.y + zz * r.z) * inv;
    let sy = prj.cy - (x * u.x + y * u.y + zz * u.z) * inv;
    (z, sx, sy, facing)
}

/// Where a projected point lands ([`project_math`]'s results): its pixel and projection, or
/// `None` when it is invalid, off-screen, behind the eye or facing away.
#[inline(always)]
fn place(prj: &Projector, flag: u8, (z, sx, sy, facing): (f32, f32, f32, f32)) -> Option<(usize, Projected)> {
    let (wmax, hmax) = (prj.width as i64 - 1, prj.height as i64 - 1);
    // Negated comparisons so that NaN is dropped too. A point whose surface turned
    // away from the eye is hidden by that surface itself: it shows no more (its
    // shading was computed for the other side), wherever it lands.
    let visible = z > 1e-6 && sx >= 0.0 && sy >= 0.0 && sx < prj.wf && sy < prj.hf && facing <= 0.0;
    if flag & FLAG_VALID == 0 || !visible {
        return None;
    }
    // SAFETY: finite and in [0, 2^32) after the test above.
    let (px, py) = unsafe { (sx.to_int_unchecked::<i64>(), sy.to_int_unchecked::<i64>()) };
    let px = if px > wmax { wmax } else { px };
    let py = if py > hmax { hmax } else { py };
    let (fx, fy) = ((sx - px as f32) * 65536.0, (sy - py as f32) * 65536.0);
    // SAFETY: in [0, 65536] before the comparison, so in range of i32 after it.
    let fx = unsafe { (if fx < 65535.0 { fx } else { 65535.0 }).to_int_unchecked::<i32>() } as u16;
    let fy = unsafe { (if fy < 65535.0 { fy } else { 65535.0 }).to_int_unchecked::<i32>() } as u16;
    let p = py as usize * prj.width as usize + px as usize;
    let depth = if flag & FLAG_HIT != 0 { z } else { f32::INFINITY };
    Some((p, Projected { pixel: p as u32, depth, fx, fy }))
}

/// The depth-buffer key of point `i` at `depth`: nearest first, then the lowest index.
#[inline(always)]
fn key_of(depth: f32, i: usize) -> u64 {
    (u64::from(depth.to_bits()) << 32) | i as u64
}

/// Pass 1 for one share of the points (slots `base..`): project each valid point, record
/// where it went, keep the nearest per pixel in `zbuf`. Per block of points, a branch-free
/// loop over the coordinate arrays projects them (the compiler vectorises it, four points
/// per instruction), then a scalar loop places them. The arithmetic is that of
/// [`Projector::project`], operation for operation, so the results are identical (the tests
/// check the cache against it).
#[inline(never)]
fn project_share(prj: &Projector, base: usize, flags: &[u8], xyz: [&[f32]; 3], normals: [&[i16]; 3], proj: &mut [Projected], zbuf: &mut [u64]) {
    let (mut zs, mut sxs, mut sys) = ([0f32; BLOCK], [0f32; BLOCK], [0f32; BLOCK]);
    let mut facing = [0f32; BLOCK];
    for (b, proj) in proj.chunks_mut(BLOCK).enumerate() {
        let start = b * BLOCK;
        let n = proj.len();
        let fl = &flags[start..start + n];
        let (bx, by, bz) = (&xyz[0][start..start + n], &xyz[1][start..start + n], &xyz[2][start..start + n]);
        let (nx, ny, nz) = (&normals[0][start..start + n], &normals[1][start..start + n], &normals[2][start..start + n]);
        for k in 0..n {
            (zs[k], sxs[k], sys[k], facing[k]) = project_math(prj, fl[k], (bx[k], by[k], bz[k]), (nx[k], ny[k], nz[k]));
        }
        for (k, pr) in proj.iter_mut().enumerate() {
            *pr = Projected::NONE;
            if let Some((p, placed)) = place(prj, fl[k], (zs[k], sxs[k], sys[k], facing[k])) {
                *pr = placed;
                let key = key_of(placed.depth, base + start + k);
                if key < zbuf[p] {
                    zbuf[p] = key;
                }
            }
        }
    }
}

/// Merges row `y` of the other shares' depth buffers into `zrow` and writes into `mrow` the
/// nearest depth over each pixel and its row neighbours, as `f32` bits: positive floats
/// order like their bits, and an empty entry (all ones) is above every depth, so an integer
/// minimum needs no NaN handling.
#[inline(never)]
fn merge_row(rest: &[Vec<u64>], y: usize, zrow: &mut [u64], mrow: &mut [u32]) {
    let w = zrow.len();
    for other in rest {
        for (a, b) in zrow.iter_mut().zip(&other[y * w..(y + 1) * w]) {
            *a = (*a).min(*b);
        }
    }
    for (x, m) in mrow.iter_mut().enumerate() {
        *m = row_min(zrow, x);
    }
}

/// The nearest depth bits over pixel `x` of a depth-buffer row and its row neighbours.
#[inline(always)]
fn row_min(zrow: &[u64], x: usize) -> u32 {
    let bits = |x: usize| (zrow[x] >> 32) as u32;
    bits(x.saturating_sub(1)).min(bits(x)).min(bits((x + 1).min(zrow.len() - 1)))
}

/// What pass 2 reads.
struct RowContext<'a> {
    zbuf: &'a [u64],
    zmin_row: &'a [u32],
    proj: &'a [Projected],
    shade: &'a [Shade],
    flags: &'a [u8],
    frame: u32,
    w: usize,
    h: usize,
    geometry: Option<GeometryCull<'a>>,
}

impl<'a> RowContext<'a> {
    #[allow(clippy::too_many_arguments)]
    fn new(zbuf: &'a [u64], zmin_row: &'a [u32], proj: &'a [Projected], pool: &'a super::Pool, frame: u32, w: usize, h: usize, geometry: Option<GeometryCull<'a>>) -> Self {
        RowContext { zbuf, zmin_row, proj, shade: &pool.shade, flags: &pool.flags, frame, w, h, geometry }
    }
}

/// Pass 2 for row `y`: culls occluded points and writes the row of the point image and of
/// `status`. Returns the number of culled points and of stale points shown. Two loops: the
/// gathers of the second are independent of each other and short, so many of their cache
/// misses overlap (pool regions keep them local).
#[inline(never)]
fn build_row(c: &RowContext, y: usize, r: &mut Row) -> (u32, u32) {
    let (mut culled, mut stale) = (0u32, 0u32);
    for x in 0..c.w {
        cull_pixel(c, y, x, r);
        culled += u32::from(r.st[x] & STATUS_CULLED);
    }
    for x in 0..c.w {
        if r.pt[x] == NO_POINT {
            clear_pixel(x, r);
        } else {
            fill_pixel(c, x, r);
            stale += u32::from(r.st[x] >> 1);
        }
    }
    (culled, stale)
}

/// Pass 2's decision for pixel (x, y) of the row: its nearest point, unless culled by the
/// geometry or as occluded by its neighbours. Writes `pt`, `dp` and `st` (the culled bit;
/// the stale bit is [`fill_pixel`]'s); returns whether a point is kept.
#[inline(always)]
fn cull_pixel(c: &RowContext, y: usize, x: usize, r: &mut Row) -> bool {
    let (w, h) = (c.w, c.h);
    let (pt, dp, st) = (&mut *r.pt, &mut *r.dp, &mut *r.st);
    let key = c.zbuf[y * w + x];
    pt[x] = NO_POINT;
    dp[x] = f32::INFINITY;
    st[x] = 0;
    if key == EMPTY_KEY {
        return false;
    }
    let dc = key_depth(key);
    if let Some(g) = &c.geometry {
        let i = y * w + x;
        // Behind every surface around the pixel, or a background miss on a surface:
        // hidden, whatever the neighbouring points say. Near a silhouette, behind the
        // surfaces of the four pixel centres around the point's own place in the pixel.
        let hidden = if dc < f32::INFINITY {
            dc > g.far3[i] * (1.0 + GEOMETRY_CULL_RELATIVE) || behind_its_corner(g, &c.proj[key as u32 as usize], w, h, x, y, dc)
        } else {
            g.inverse_depth[i] > 0.0
        };
        if hidden {
            st[x] = STATUS_CULLED;
            return false;
        }
    }
    // Cheap pre-test: without any neighbour nearer by the threshold the point cannot be
    // occluded (most pixels stop here).
    let m = |row: usize| c.zmin_row[row * w + x];
    let nearest = f32::from_bits(m(y.saturating_sub(1)).min(m(y)).min(m((y + 1).min(h - 1))));
    if nearest * (1.0 + DEPTH_CULL_RELATIVE) < dc && is_occluded(c.zbuf, w, h, x, y, dc) {
        st[x] = STATUS_CULLED;
        return false;
    }
    pt[x] = key as u32;
    dp[x] = dc;
    true
}

/// Whether a point at depth `dc` in pixel (x, y), projected at `pr`, lies behind the
/// surfaces at all four pixel centres around its place in the pixel (the centres of the
/// pixel and of its neighbours on the side of each axis it lies on), by more than
/// [`GEOMETRY_CULL_RELATIVE`]. On one plane 1/z is affine across the image, so between
/// those centres the plane is no farther than the farthest of them: a point behind all four
/// is hidden. `far3` (nine centres) keeps every point within a pixel of a nearer surface's
/// silhouette, and a point of the surface behind it that the silhouette's move put on the
/// silhouette's near side stayed there — a moved box's top row kept the wall points it slid
/// over, and drew notches in its edge (issue 11). Only a point behind the surface at its own
/// pixel's centre can be; at the image's border the pixel's own centre stands for the one
/// beyond it.
#[inline(always)]
fn behind_its_corner(g: &GeometryCull, pr: &Projected, w: usize, h: usize, x: usize, y: usize, dc: f32) -> bool {
    let i = y * w + x;
    let t = 1.0 + GEOMETRY_CULL_RELATIVE;
    let own = g.inverse_depth[i];
    // Not behind the surface at its own centre (or none there): not hidden.
    if !(own > 0.0 && dc * own > t) {
        return false;
    }
    let nx = if pr.fx < 0x8000 { x.saturating_sub(1) } else { (x + 1).min(w - 1) };
    let ny = if pr.fy < 0x8000 { y.saturating_sub(1) } else { (y + 1).min(h - 1) };
    // Behind a centre's surface: depth × its 1/z above the threshold (0: uncovered, never).
    [ny * w + x, y * w + nx, ny * w + nx].iter().all(|&j| dc * g.inverse_depth[j] > t)
}

/// The point image at pixel `x` of the row for its kept point `pt[x]`.
#[inline(always)]
fn fill_pixel(c: &RowContext, x: usize, r: &mut Row) {
    let (sp, col, ag, bo, st) = (&mut *r.sp, &mut *r.col, &mut *r.ag, &mut *r.bo, &mut *r.st);
    let i = r.pt[x] as usize;
    let pr = c.proj[i];
    sp[x] = [f32::from(pr.fx) * (1.0 / 65536.0), f32::from(pr.fy) * (1.0 / 65536.0)];
    let sh = c.shade[i];
    col[x] = sh.color;
    let is_stale = c.flags[i] & FLAG_STALE != 0;
    st[x] |= if is_stale { STATUS_STALE } else { 0 };
    ag[x] = if is_stale { STALE_AGE } else { RenderCache::age_of(c.frame, sh.born) };
    bo[x] = sh.born;
}

/// The point image at pixel `x` of the row without a point.
#[inline(always)]
fn clear_pixel(x: usize, r: &mut Row) {
    r.sp[x] = [0.0; 2];
    r.col[x] = Vec3::ZERO;
    r.ag[x] = f32::INFINITY;
    r.bo[x] = 0;
}

/// One row of the point image's arrays and of the pass-2 status.
struct Row<'a> {
    pt: &'a mut [u32],
    dp: &'a mut [f32],
    sp: &'a mut [[f32; 2]],
    col: &'a mut [Vec3],
    ag: &'a mut [f32],
    bo: &'a mut [u32],
    st: &'a mut [u8],
}

/// The rows of `pi` and `status` (`w` pixels each), for the row-parallel passes.
fn rows<'a>(pi: &'a mut super::PointImage, status: &'a mut [u8], w: usize) -> impl IndexedParallelIterator<Item = Row<'a>> + 'a {
    (
        pi.point.par_chunks_mut(w),
        pi.depth.par_chunks_mut(w),
        pi.subpixel.par_chunks_mut(w),
        pi.color.par_chunks_mut(w),
        pi.age.par_chunks_mut(w),
        pi.born.par_chunks_mut(w),
        status.par_chunks_mut(w),
    )
        .into_par_iter()
        .map(|(pt, dp, sp, col, ag, bo, st)| Row { pt, dp, sp, col, ag, bo, st })
}
