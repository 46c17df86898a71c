//! Converging at rest (issue 14 item 3; DESIGN.md "Shaders": "repeated samples of a cached
//! point are averaged at the renderer while nothing changes"). With a still camera and still
//! objects the sampler keeps re-picking pixels (their points age), and it aims such a pick at
//! the very point the pixel shows (`sampling::aim_at_points`). The worker's answer is then a
//! new, independent estimate of the same surface point's radiance, and it is averaged into
//! that point with the count of samples it holds, so the point's noise falls as 1/√n
//! instead of staying at one sample's noise, as a progressive renderer's pixels do.
//!
//! "Its" point is the one the request was aimed at (the session remembers it with the
//! request), when the last frame still showed it at the sample's pixel and it lies on the
//! same object (or is the same background direction) within [`SAME_POINT_RELATIVE`] of the
//! sample's position: exact, and O(1). Where the edge-and-point image puts the pick's jittered
//! position in the point's region of the pixel (`Epi::same_region`: a pixel no edge crosses,
//! the point's side of a simple pixel's edge), the request is instead for the point anywhere
//! there (`sampling::AIM_IN_PIXEL`): a sample of the same object is averaged in, and the
//! point converges to its region's mean, of which the converged reference's pixel is made
//! (the anti-aliasing weighs a simple pixel's sides by their exact areas). The sample is
//! averaged in only while
//! nothing can have changed the point's shading since it was shaded: the point is not stale
//! (its object moved, a moved object may shadow it) and the sample was shaded at the point's
//! epoch (no object moved in between). Otherwise the sample replaces the point as a new
//! point of one sample: the count resets. Invalidated points (`invalidate_objects`, `clear`)
//! leave the pool, and a slot reused for another sample starts from one.
//!
//! **Where to sample next at rest.** A progressive renderer gives every pixel the same
//! number of samples. The squared error of a point's mean after n samples is σ²/n, so for a
//! fixed number of samples the total error is least when n grows in proportion to σ
//! (Neyman allocation): where the shading is noisy (soft shadows, indirect light in the
//! corners, the luminaire's rim) more samples pay more. Each point keeps the spread of its
//! samples (Welford's running sum of squared deviations of their [`tone`], a stand-in for
//! the sRGB values the error is measured in), and [`RenderCache::update_noise_gains`] turns it into
//! a per-pixel gain on the sampling priority of a still view (`sampling::Sampler::select_gained`).
//! One sample's spread is unknown and a few samples' is itself noisy, so each estimate is
//! shrunk toward the image's mean variance by [`PRIOR_SAMPLES`] samples' worth.
use super::{RenderCache, Sample, FLAG_HIT, FLAG_STALE, FLAG_VALID, NO_POINT};
use crate::prefetch::prefetch;
use glam::Vec3;
use rayon::prelude::*;

/// The prior's weight, in samples, in a point's variance estimate ([`RenderCache::update_noise_gains`]).
pub const PRIOR_SAMPLES: f32 = 1.0;
/// Gains are clamped to [1 / this, this]: one firefly sample makes a large spread, and a
/// pixel whose samples have all agreed so far must still be visited.
pub const MAX_GAIN: f32 = 8.0;

/// What a point's spread is measured in: the mean over the channels of the square root of
/// the colour clamped to [0, 1], close to the sRGB encoding the error is judged in (the
/// same weight to dark and bright noise as the eye and the PSNR give) and cheap per sample.
#[inline]
pub fn tone(c: Vec3) -> f32 {
    let c = c.clamp(Vec3::ZERO, Vec3::ONE);
    (c.x.sqrt() + c.y.sqrt() + c.z.sqrt()) * (1.0 / 3.0)
}

/// A sample is of the point a pixel shows when their positions differ by at most this
/// fraction of the point's view depth (for a background miss: of the unit direction). A
/// re-aimed ray passes through the point to within the 1/65536 pixel of its projection and
/// f32 rounding (about 1e-6 of the depth, some 1e-5 on a surface seen at a grazing angle):
/// far below this. A pixel at 512² and 40° spans 1.4e-3 of the depth (at 2048², 3.5e-4), so
/// a jittered sample elsewhere in the pixel is a different point.
pub const SAME_POINT_RELATIVE: f32 = 1e-4;

impl RenderCache {
    /// [`Self::insert_aged`] for a sample whose request was aimed at cached point `point`
    /// (`sampling::aim_at_points`; [`NO_POINT`]: none): when it is a sample of that point,
    /// it is averaged into it while nothing changed since the point was shaded, else it
    /// replaces it (see the module doc). Any other sample is inserted as a new point.
    pub fn insert_aimed(&mut self, s: &Sample, stale: bool, point: u32) -> bool {
        if !(s.position.is_finite() && s.color.is_finite()) {
            return false;
        }
        let (point, anywhere) = crate::sampling::aimed_point(point);
        match self.own_point(s, point, anywhere).filter(|_| !stale) {
            Some((i, pixel)) if self.may_average(i, s) => self.average_into(i, pixel, s),
            Some((i, _)) => return self.write(i as u32, self.region_of(i as u32), s, false),
            None => return self.insert_aged(s, stale),
        }
        true
    }

    /// Brings into the cache what [`Self::insert_aimed`] reads and writes of the point a
    /// request was aimed at (`point` as the request carries it). Points are scattered over
    /// the pool, so each sample's dozen reads of them would each wait for memory (a fifth of
    /// the server's time at rest); issued a few samples ahead, the waits overlap.
    #[inline]
    pub fn prefetch_aimed(&self, point: u32) {
        let (point, anywhere) = crate::sampling::aimed_point(point);
        let i = point as usize;
        let p = &self.pool;
        if i >= p.flags.len() {
            return;
        }
        prefetch(&p.flags[i]);
        prefetch(&p.object[i]);
        prefetch(&p.epoch[i]);
        prefetch(&p.samples[i]);
        prefetch(&p.shade[i]);
        prefetch(&p.spread[i]);
        prefetch(&p.stamp[i]);
        prefetch(&self.proj[i]);
        if !anywhere {
            prefetch(&p.px[i]);
            prefetch(&p.py[i]);
            prefetch(&p.pz[i]);
        }
    }

    /// Slot `point` and the index of `s`'s pixel, when the last frame showed that point at
    /// the pixel and `s` is a sample of the same surface point (module doc) — or, when the
    /// request was for the point `anywhere` in its region of the pixel
    /// (`sampling::AIM_IN_PIXEL`), of the same object.
    fn own_point(&self, s: &Sample, point: u32, anywhere: bool) -> Option<(usize, usize)> {
        let [x, y] = s.pixel;
        if point == NO_POINT || x >= self.cfg.width || y >= self.cfg.height {
            return None;
        }
        let pixel = y as usize * self.cfg.width as usize + x as usize;
        if self.points.point[pixel] != point {
            return None;
        }
        let i = point as usize;
        let p = &self.pool;
        let flags = p.flags[i];
        if flags & FLAG_VALID == 0 || (flags & FLAG_HIT != 0) != s.hit || p.object[i] != s.object {
            return None;
        }
        if anywhere {
            return Some((i, pixel));
        }
        let (position, scale) = if s.hit { (s.position, self.points.depth[pixel]) } else { (s.position.normalize(), 1.0) };
        let tolerance = SAME_POINT_RELATIVE * scale;
        let d = position - Vec3::new(p.px[i], p.py[i], p.pz[i]);
        (d.length_squared() <= tolerance * tolerance).then_some((i, pixel))
    }

    /// Whether sample `s` of point `i` may be averaged into it: nothing changed its shading
    /// in between (module doc).
    fn may_average(&self, i: usize, s: &Sample) -> bool {
        self.pool.flags[i] & FLAG_STALE == 0 && self.pool.epoch[i] == s.epoch
    }

    /// Averages sample `s` into point `i`, which the last frame showed at `pixel`: its colour
    /// becomes the mean of its samples (after `u16::MAX` samples, a running mean over about
    /// that many), it counts as freshly shaded, and it goes to the young end of replacement.
    /// Its place is unchanged, so the point image is updated in place.
    fn average_into(&mut self, i: usize, pixel: usize, s: &Sample) {
        self.averaged += 1;
        let p = &mut self.pool;
        let n = p.samples[i].saturating_add(1);
        p.samples[i] = n;
        let shade = &mut p.shade[i];
        shade.color += (s.color - shade.color) / f32::from(n);
        // Welford: the mean of the tones and the sum of squared deviations from it.
        let y = tone(s.color);
        let [mean, m2] = &mut p.spread[i];
        let delta = y - *mean;
        *mean += delta / f32::from(n);
        *m2 += delta * (y - *mean);
        shade.born = self.frame;
        let (color, born) = (shade.color, shade.born);
        // The point image the next frame updates in place reads these from the pixel, not
        // from the pool (the pixel's depth-buffer entry does not change).
        self.points.color[pixel] = color;
        self.points.born[pixel] = born;
        self.points.age[pixel] = Self::age_of(self.frame, born);
        // To the young end of replacement, unless it was written since the last frame (then
        // it is young already, and a still view's pending projection of the slot, which a
        // new stamp would void, is what places it). A point of the last frame keeps its
        // projection: nothing to redo.
        if self.proj[i].pixel != NO_POINT {
            self.pool.stamp[i] = self.next_stamp;
            let band = self.region_of(i as u32);
            self.enqueue(band, i as u32);
        }
    }

    /// Samples averaged into existing points since the cache was made.
    pub fn averaged(&self) -> u64 {
        self.averaged
    }

    /// Per pixel of the last frame's point image, the factor by which the noise of the point
    /// it shows should raise its sampling priority (module doc: σ relative to the image's
    /// root-mean-square σ, with each point's variance shrunk toward the image's mean by
    /// [`PRIOR_SAMPLES`], clamped to [1/[`MAX_GAIN`], [`MAX_GAIN`]]). Pixels without a
    /// point, with a stale one, or with a point of one sample get the prior's gain (1 when
    /// they are the only ones). Returns whether there are gains ([`Self::noise_gains`]): not
    /// while no point holds two samples, or none varies.
    pub fn update_noise_gains(&mut self) -> bool {
        let w = self.cfg.width as usize;
        let (pool, points) = (&self.pool, &self.points);
        // Pass 1: the raw variance estimates, and their sum and number (per row, then added
        // in row order: the same gains whatever the threads' split).
        let rows: Vec<(f64, u32)> = self
            .gains
            .par_chunks_mut(w.max(1))
            .zip(points.point.par_chunks(w.max(1)))
            .map(|(g, pt)| {
                let (mut sum, mut count) = (0.0f64, 0u32);
                for (g, &i) in g.iter_mut().zip(pt) {
                    *g = -1.0;
                    if i == NO_POINT {
                        continue;
                    }
                    let i = i as usize;
                    let n = pool.samples[i];
                    if n >= 2 && pool.flags[i] & (FLAG_VALID | FLAG_STALE) == FLAG_VALID {
                        // Stored as m2 and n - 1 together: pass 2 needs both.
                        let v = pool.spread[i][1].max(0.0) / f32::from(n - 1);
                        sum += f64::from(v);
                        count += 1;
                        *g = f32::from(n);
                    }
                }
                (sum, count)
            })
            .collect();
        let (sum, count) = rows.iter().fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        if count == 0 || !(sum > 0.0) {
            return false;
        }
        let mean = (sum / f64::from(count)) as f32;
        let prior = PRIOR_SAMPLES * mean;
        let inv_rms = 1.0 / mean.sqrt();
        // Pass 2: the shrunk estimates' σ over the image's.
        self.gains.par_chunks_mut(w.max(1)).zip(points.point.par_chunks(w.max(1))).for_each(|(g, pt)| {
            for (g, &i) in g.iter_mut().zip(pt) {
                *g = if *g < 0.0 {
                    1.0
                } else {
                    let m2 = pool.spread[i as usize][1].max(0.0);
                    let v = (m2 + prior) / (*g - 1.0 + PRIOR_SAMPLES);
                    (v.sqrt() * inv_rms).clamp(1.0 / MAX_GAIN, MAX_GAIN)
                };
            }
        });
        true
    }

    /// The gains of the last [`Self::update_noise_gains`] that returned true, one per pixel.
    pub fn noise_gains(&self) -> &[f32] {
        &self.gains
    }
}

#[cfg(test)]
mod tests;
