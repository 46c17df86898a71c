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
use super::{RenderCache, FLAG_STALE, NO_POINT, STALE_AGE};
use glam::Vec3;

/// Half the side of the window searched for a newer point (pixels): 5 × 5. After k
/// frames of resampling at 1/64 of the pixels, a point shaded in them lies in such a window
/// with probability 1 − (1 − k/64)^25: 70 % after 3 frames, 96 % after 8.
pub const FRESH_RADIUS: usize = 2;

/// Two colours disagree when a channel differs by more than this after a square root (a
/// display-like curve: about 0.15–0.2 in sRGB, below the 0.25 of an outlier pixel).
pub const DISAGREE: f32 = 0.15;

/// Whether two linear colours disagree (see [`DISAGREE`]).
pub fn disagree(a: Vec3, b: Vec3) -> bool {
    let d = (a.max(Vec3::ZERO)).powf(0.5) - (b.max(Vec3::ZERO)).powf(0.5);
    d.abs().max_element() > DISAGREE
}

impl RenderCache {
    /// Leaves out of the point image every stale hit point that [`disagree`]s with a point
    /// trusted more — not stale, or shaded in a later frame — on the same object
    /// (`objects`: the exact visibility's object per pixel; without it, depths within 5 %
    /// decide) within [`FRESH_RADIUS`] pixels. Call after reprojection. Returns how many
    /// points were left out.
    pub fn hide_stale_near_fresh(&mut self, objects: Option<&[u32]>) -> u32 {
        let p = &mut self.points;
        let (flags, shade) = (&self.pool.flags, &self.pool.shade);
        let (w, h) = (p.width as usize, p.height as usize);
        let r = FRESH_RADIUS;
        // Decided on the image as reprojected, then applied: the outcome does not depend on
        // the order of the pixels.
        let mut hidden = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if p.age[i] != STALE_AGE || p.point[i] == NO_POINT || !p.depth[i].is_finite() {
                    continue;
                }
                let born = shade[p.point[i] as usize].born;
                let same = |j: usize| match objects {
                    Some(o) => o[j] == o[i],
                    None => (p.depth[j] - p.depth[i]).abs() <= 0.05 * p.depth[i],
                };
                let trusted = |j: usize| {
                    let k = p.point[j] as usize;
                    flags[k] & FLAG_STALE == 0 || (shade[k].born.wrapping_sub(born) as i32) > 0
                };
                let mut newer = false;
                'window: for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let j = yy * w + xx;
                        if j != i && p.point[j] != NO_POINT && p.depth[j].is_finite() && same(j) && trusted(j) && disagree(p.color[i], p.color[j]) {
                            newer = true;
                            break 'window;
                        }
                    }
                }
                if newer {
                    hidden.push(i);
                }
            }
        }
        for &i in &hidden {
            p.point[i] = NO_POINT;
            p.depth[i] = f32::INFINITY;
            p.color[i] = Vec3::ZERO;
            p.age[i] = f32::INFINITY;
            p.subpixel[i] = [0.0; 2];
        }
        hidden.len() as u32
    }
}
