//! Reprojection and depth culling of the Render Cache (paper 000 §4.3; Walter et al. 1999
//! §3.2 "depth culling"). Data-parallel over points and rows, without locks or atomic
//! read-modify-writes (which cost more than the projection itself): each worker thread owns
//! a plain depth buffer for its contiguous share of the points, and a parallel pass over
//! rows merges them. A depth-buffer entry is `(depth bits << 32) | point index`, the
//! minimum wins: positive `f32` bit patterns order like the floats, a point at infinity (a
//! miss) is behind every hit, and equal depths go to the lower index.
use super::{Projected, RenderCache, DEPTH_CULL_RELATIVE, EMPTY_KEY, FLAG_HIT, FLAG_VALID, NO_POINT};
use edgepoint_scene::camera::CameraFrame;
use glam::Vec3;
use rayon::prelude::*;

/// Projects a cached point: a hit is a world position, a miss a direction (a point at
/// infinity, view depth `+inf`). Returns continuous pixel coordinates and view depth, or
/// `None` behind the eye. Hits use exactly `CameraFrame::project`.
#[inline]
pub(crate) fn project_point(cam: &CameraFrame, p: Vec3, hit: bool) -> Option<(f32, f32, f32)> {
    if hit {
        return cam.project(p);
    }
    let z = p.dot(cam.forward);
    if z <= 1e-6 {
        return None;
    }
    let x = p.dot(cam.right) / (z * cam.tan_half_y * cam.aspect);
    let y = p.dot(cam.up) / (z * cam.tan_half_y);
    Some(((x + 1.0) * 0.5 * cam.width as f32, (1.0 - y) * 0.5 * cam.height as f32, f32::INFINITY))
}

/// The pixel containing continuous image position (`sx`, `sy`), if inside the image.
#[inline]
pub(crate) fn pixel_of(sx: f32, sy: f32, width: u32, height: u32) -> Option<(u32, u32)> {
    // Written so that NaN fails every comparison.
    if sx >= 0.0 && sy >= 0.0 && sx < width as f32 && sy < height as f32 {
        Some(((sx as u32).min(width - 1), (sy as u32).min(height - 1)))
    } else {
        None
    }
}

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
/// `depth` is the depth image with NaN where a pixel has no point (NaN is neither nearer
/// nor farther).
#[inline]
pub(crate) fn is_occluded(depth: &[f32], w: usize, h: usize, x: usize, y: usize, dc: f32) -> bool {
    let mut nb = [f32::NAN; 8];
    if x > 0 && y > 0 && x + 1 < w && y + 1 < h {
        let i = y * w + x;
        nb = [depth[i - 1], depth[i - w - 1], depth[i - w], depth[i - w + 1], depth[i + 1], depth[i + w + 1], depth[i + w], depth[i + w - 1]];
    } else {
        for (k, &(dx, dy)) in NEIGHBOURS.iter().enumerate() {
            let (nx, ny) = (x as isize + dx, y as isize + dy);
            if nx >= 0 && ny >= 0 && nx < w as isize && ny < h as isize {
                nb[k] = depth[ny as usize * w + nx as usize];
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

/// Largest float below 1, so a subpixel coordinate stays inside [0, 1).
const BELOW_ONE: f32 = 1.0 - f32::EPSILON / 2.0;

impl RenderCache {
    /// Projects every point, keeps the nearest per pixel, culls occluded ones and builds the
    /// point image. Returns the number of pixels whose point was culled. Which points lost
    /// their pixel is left in the depth buffer (`zbufs[0]`) and `proj` for replacement to read.
    pub(super) fn reproject(&mut self, cam: &CameraFrame) -> u32 {
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

        let tt = std::time::Instant::now();
        // Pass 1, over points: project, nearest per pixel into the share's depth buffer.
        let pool = &self.pool;
        let (position, flags, shade) = (&pool.position, &pool.flags, &pool.shade);
        self.zbufs.par_iter_mut().for_each(|z| z.fill(EMPTY_KEY));
        self.zbufs.par_iter_mut().zip(self.proj.par_chunks_mut(share)).enumerate().for_each(|(k, (zbuf, proj))| {
            let base = k * share;
            for (j, pr) in proj.iter_mut().enumerate() {
                let i = base + j;
                pr.pixel = NO_POINT;
                let f = flags[i];
                if f & FLAG_VALID == 0 {
                    continue;
                }
                let Some((sx, sy, z)) = project_point(cam, position[i], f & FLAG_HIT != 0) else { continue };
                let Some((px, py)) = pixel_of(sx, sy, w as u32, h as u32) else { continue };
                let p = py as usize * w + px as usize;
                *pr = Projected { pixel: p as u32, depth: z, sx, sy, shade: shade[i] };
                let key = (u64::from(z.to_bits()) << 32) | i as u64;
                if key < zbuf[p] {
                    zbuf[p] = key;
                }
            }
        });

        let t1 = tt.elapsed();
        // Merge the shares into zbufs[0] and decode the depth image (NaN: no point).
        let (z0, rest) = self.zbufs.split_first_mut().expect("at least one depth buffer");
        z0.par_chunks_mut(w).zip(self.zdepth.par_chunks_mut(w)).enumerate().for_each(|(y, (zrow, drow))| {
            for other in rest.iter() {
                for (a, b) in zrow.iter_mut().zip(&other[y * w..(y + 1) * w]) {
                    *a = (*a).min(*b);
                }
            }
            for (d, &key) in drow.iter_mut().zip(zrow.iter()) {
                *d = if key == EMPTY_KEY { f32::NAN } else { key_depth(key) };
            }
        });

        let t2 = tt.elapsed();
        // Pass 2, over rows: depth culling against the 3x3 neighbourhood, then the point
        // image. Two loops per row: the gathers of the second are independent of each other
        // and short, so many of their cache misses overlap.
        let (zbuf, zdepth, proj, frame) = (&self.zbufs[0], &self.zdepth, &self.proj, self.frame);
        let pi = &mut self.points;
        (
            pi.point.par_chunks_mut(w),
            pi.depth.par_chunks_mut(w),
            pi.subpixel.par_chunks_mut(w),
            pi.color.par_chunks_mut(w),
            pi.age.par_chunks_mut(w),
        )
            .into_par_iter()
            .enumerate()
            .map(|(y, (pt, dp, sp, col, ag))| {
                let mut culled = 0u32;
                let row = &zbuf[y * w..(y + 1) * w];
                for (x, &key) in row.iter().enumerate() {
                    pt[x] = NO_POINT;
                    dp[x] = f32::INFINITY;
                    if key == EMPTY_KEY {
                        continue;
                    }
                    let dc = key_depth(key);
                    if is_occluded(zdepth, w, h, x, y, dc) {
                        culled += 1;
                        continue;
                    }
                    pt[x] = key as u32;
                    dp[x] = dc;
                }
                for x in 0..w {
                    let idx = pt[x];
                    if idx == NO_POINT {
                        sp[x] = [0.0; 2];
                        col[x] = Vec3::ZERO;
                        ag[x] = f32::INFINITY;
                        continue;
                    }
                    let pr = &proj[idx as usize];
                    sp[x] = [(pr.sx - x as f32).clamp(0.0, BELOW_ONE), (pr.sy - y as f32).clamp(0.0, BELOW_ONE)];
                    col[x] = pr.shade.color;
                    ag[x] = RenderCache::age_of(frame, pr.shade.born);
                }
                culled
            })
            .sum::<u32>().max({ if std::env::var("RC_DEBUG").is_ok() { eprintln!("p1 {:?} merge {:?} p2 {:?}", t1, t2 - t1, tt.elapsed() - t2); } 0 })
    }
}
