//! Newer samples before stale ones (the Render Cache's point ageing, paper 000 §4.3 and
//! §5.3, taken one step further for moving objects).
//!
//! A move marks stale the points whose shading the moved object may have changed (its old
//! and new shadows, its own surface). Prioritized sampling then resamples them first, but
//! at a few percent of the pixels per frame a large stale region takes tens of frames to be
//! covered, and while an object keeps moving the samples arriving near it are stale too. Its
//! old points meanwhile show as speckles among the newer ones (an old shadow's dark points
//! on a floor now lit). So a stale point is left out of the frame where a point of the same
//! surface within a few pixels is trusted more — fresh, or shaded in a later frame — and
//! disagrees with it: the newer point says the shading there has changed since the stale one
//! was shaded, and the reconstruction interpolates from the newer points instead. A stale
//! point that agrees with its newer neighbours stays (it keeps the density where nothing
//! changed); one with no newer neighbour stays too, the best guess there is until one
//! arrives. Left out, its pixel counts as unsampled, so the sampler asks for it at the
//! highest priority and the cache replaces the point first when it needs a slot.
use super::{RenderCache, NO_POINT, STALE_AGE};
use rayon::prelude::*;
use glam::Vec3;

/// Stage name of [`RenderCache::hide_stale_near_fresh`] in the frame's stage times.
pub const STAGE_STALE: &str = "stale";

/// Half the side of the window searched for a newer point (pixels): 5 × 5. After k
/// frames of resampling at 1/64 of the pixels, a point shaded in them lies in such a window
/// with probability 1 − (1 − k/64)^25: 70 % after 3 frames, 96 % after 8.
pub const FRESH_RADIUS: usize = 2;

/// Two colours disagree when a channel differs by more than this after a square root (a
/// display-like curve: about 0.15–0.2 in sRGB, below the 0.25 of an outlier pixel), in
/// steps of 1/255.
pub const DISAGREE: u32 = 38;

/// A linear colour as compared: per channel the square root clamped to [0, 1], in 8 bits,
/// packed as r | g << 8 | b << 16.
#[inline]
pub fn display_rgb(c: Vec3) -> u32 {
    let q = |v: f32| (v.clamp(0.0, 1.0).sqrt() * 255.0 + 0.5) as u32;
    q(c.x) | q(c.y) << 8 | q(c.z) << 16
}

/// Whether two packed colours ([`display_rgb`]) disagree (see [`DISAGREE`]).
#[inline]
pub fn disagree(a: u32, b: u32) -> bool {
    (0..3).any(|k| ((a >> (8 * k)) & 255).abs_diff((b >> (8 * k)) & 255) > DISAGREE)
}

impl RenderCache {
    /// Leaves out of the point image every stale hit point that [`disagree`]s with a point
    /// trusted more — not stale, or shaded in a later frame — on the same object
    /// (`objects`: the exact visibility's object per pixel; without it, depths within 5 %
    /// decide) within [`FRESH_RADIUS`] pixels. Call after reprojection. Returns how many
    /// points were left out. Rows are decided in parallel from the point image as
    /// reprojected (into one bit per pixel), then applied, so the order does not matter;
    /// everything a window reads is per pixel and contiguous.
    pub fn hide_stale_near_fresh(&mut self, objects: Option<&[u32]>) -> u32 {
        let p = &self.points;
        let (w, h) = (p.width as usize, p.height as usize);
        if w == 0 || h == 0 {
            return 0;
        }
        if self.stale_shown == 0 {
            return 0;
        }
        let words = w.div_ceil(64);
        let r = FRESH_RADIUS;
        // Colours as compared, once per pixel (the windows overlap 25-fold).
        self.display.par_chunks_mut(w).zip(p.color.par_chunks(w)).for_each(|(d, c)| {
            for (d, &c) in d.iter_mut().zip(c) {
                *d = display_rgb(c);
            }
        });
        let display = &self.display;
        let hidden: u32 = self
            .give_way
            .par_chunks_mut(words)
            .enumerate()
            .map(|(y, bits)| {
                bits.iter_mut().for_each(|b| *b = 0);
                let mut n = 0;
                for x in 0..w {
                    let i = y * w + x;
                    if p.age[i] != STALE_AGE || !p.depth[i].is_finite() {
                        continue;
                    }
                    let (born, depth, color) = (p.born[i], p.depth[i], display[i]);
                    let object = objects.map(|o| o[i]);
                    let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
                    let mut newer = false;
                    'window: for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                        let row = yy * w;
                        // Colour first: in the smooth regions most stale points lie in, no
                        // neighbour disagrees, and only this one contiguous array is read.
                        for (dx, &d) in display[row + x0..row + x1].iter().enumerate() {
                            if !disagree(color, d) {
                                continue;
                            }
                            let j = row + x0 + dx;
                            // Trusted more (a stale point's age is STALE_AGE; no point's is
                            // infinite), a surface point, the same surface.
                            let trusted = p.age[j] < STALE_AGE || (p.age[j] == STALE_AGE && (p.born[j].wrapping_sub(born) as i32) > 0);
                            let same = match (objects, object) {
                                (Some(o), Some(me)) => o[j] == me,
                                _ => (p.depth[j] - depth).abs() <= 0.05 * depth,
                            };
                            if trusted && p.depth[j].is_finite() && same {
                                newer = true;
                                break 'window;
                            }
                        }
                    }
                    if newer {
                        bits[x / 64] |= 1 << (x % 64);
                        n += 1;
                    }
                }
                n
            })
            .sum();
        if hidden == 0 {
            return 0;
        }
        // The point image no longer is what pass 2 made of the depth buffer.
        self.point_image_from = None;
        let p = &mut self.points;
        for (y, bits) in self.give_way.chunks(words).enumerate() {
            for (k, &word) in bits.iter().enumerate() {
                let mut b = word;
                while b != 0 {
                    let i = y * w + k * 64 + b.trailing_zeros() as usize;
                    b &= b - 1;
                    p.point[i] = NO_POINT;
                    p.depth[i] = f32::INFINITY;
                    p.color[i] = Vec3::ZERO;
                    p.age[i] = f32::INFINITY;
                    p.born[i] = 0;
                    p.subpixel[i] = [0.0; 2];
                }
            }
        }
        hidden
    }
}
