//! What an object's move does to the cached points it can shadow (DESIGN.md "Motion", step
//! 1 of a frame), decided exactly where it can be.
//!
//! A point whose segment toward a light crosses the moved object's old or new box *may* be
//! shadowed differently now. Where nothing more can be said the point is marked stale
//! (re-shaded first, shown meanwhile). For an area light and an object of convex solids the
//! session says by how much ([`ShadowChange::Shifted`]): small shifts, added up per point,
//! keep it stale, large ones drop it. For a point light it can say more: the
//! point's shadow from the moved object changed exactly when the segment from the point to
//! the light meets the object in one place and not in the other — a question about the
//! object's triangles that the session answers ([`ShadowQuery`]). Where it did not change,
//! the point's shading is as right as before the move and it stays fresh; where it did, the
//! point is wrong (an old shadow's dark point on a surface now lit, or a lit point now in
//! shadow) and is dropped: its pixel goes back to the sampler at the highest priority, and
//! the frame interpolates its region from the points around it, which are right.
//!
//! Before, every point in the swept box's shadow volume turned stale on every move, right or
//! wrong, and stayed in the frame until re-shaded: while an object keeps moving, that is its
//! whole shadow and its surroundings, more than the sampler re-shades in ten frames, and the
//! wrong ones among them drew the old shadow's ragged outline beside the new shadow edge.
use super::{LightBound, RenderCache, FLAG_HIT, FLAG_STALE, FLAG_VALID};
use glam::Vec3;
use rayon::prelude::*;

/// What a move did to one point's shading from one light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ShadowChange {
    /// Its shadow from the moved object is the same: its shading stays right.
    Unchanged,
    /// Changed by at most this fraction of one light's unblocked light (summed over lights):
    /// kept, marked stale, while its shifts since it was shaded add up to less than
    /// [`DROP_DRIFT`]; dropped once they reach it.
    Shifted(f32),
    /// May have changed, cannot say (no exact test for the object and this light).
    Unknown,
    /// Changed: the point now shows a shadow that is not there, or misses one that is.
    Changed,
}

/// A point whose shadows moves have shifted by this much since it was shaded (in one
/// light's unblocked light, [`ShadowChange::Shifted`] summed over moves: at least the shift
/// between its shading and now) is dropped rather than shown stale: a quarter of a light is
/// an outlier where that light dominates (the motion benchmark's outliers are 64 of 255
/// sRGB levels), smaller shifts are closer to the truth shown than interpolated from afar
/// while the object keeps moving and its whole penumbra shifts every frame.
pub const DROP_DRIFT: f32 = 0.25;

/// [`DROP_DRIFT`] and shifts in the cache's per-point units (1/255 of a light).
fn drift_units(f: f32) -> u32 {
    (f.max(0.0) * 255.0).round().min(255.0) as u32
}

/// The exact question a move asks about a point: `change(p, light)` for the point `p` and
/// the light of index `light`, asked only where the segment from `p` to that light's centre
/// meets the moved object's swept box (grown by the light's radius).
pub trait ShadowQuery: Sync {
    fn change(&self, p: Vec3, light: usize) -> ShadowChange;
}

/// The query with no exact answer anywhere: every point a move can shadow is marked stale
/// ([`RenderCache::age_shadowed_by`]).
pub struct NoExactAnswer;

impl ShadowQuery for NoExactAnswer {
    fn change(&self, _: Vec3, _: usize) -> ShadowChange {
        ShadowChange::Unknown
    }
}

/// Points a move affected (see [`RenderCache::reshadow`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Reshadowed {
    /// Marked stale: their shading may have changed.
    pub stale: u32,
    /// Dropped: their shading is wrong now.
    pub dropped: u32,
}

/// A point's verdict: the worst over the lights whose segment meets `boxes`.
#[inline]
pub fn verdict(p: Vec3, boxes: &[(Vec3, Vec3, Vec3)], query: &dyn ShadowQuery) -> ShadowChange {
    worst_change(p, boxes.iter().enumerate().filter(|(_, &(c, lo, hi))| super::segment_hits_box(p, c, lo, hi)).map(|(l, _)| l), query)
}

/// The worst of `query`'s answers at `p` over the lights `lights` (indices), stopping at the
/// first [`ShadowChange::Changed`].
#[inline]
pub fn worst_change(p: Vec3, lights: impl Iterator<Item = usize>, query: &dyn ShadowQuery) -> ShadowChange {
    let mut worst = Worst::default();
    for l in lights {
        if worst.add(query.change(p, l)) {
            break;
        }
    }
    worst.answer()
}

/// The worst of several answers for one point (lights, or moves): [`ShadowChange::Changed`]
/// over everything, shifts summed, then unknown, then unchanged.
#[derive(Debug, Default, Clone, Copy)]
pub struct Worst {
    changed: bool,
    unknown: bool,
    shift: Option<f32>,
}

impl Worst {
    /// Takes one more answer in; returns whether the point changed (no answer can be worse).
    pub fn add(&mut self, c: ShadowChange) -> bool {
        match c {
            ShadowChange::Changed => self.changed = true,
            ShadowChange::Shifted(f) => self.shift = Some(self.shift.unwrap_or(0.0) + f),
            ShadowChange::Unknown => self.unknown = true,
            ShadowChange::Unchanged => {}
        }
        self.changed
    }

    pub fn answer(self) -> ShadowChange {
        // A shift says how much where an unknown part says nothing (both mark the point stale).
        match (self.changed, self.shift, self.unknown) {
            (true, _, _) => ShadowChange::Changed,
            (false, Some(f), _) => ShadowChange::Shifted(f),
            (false, None, true) => ShadowChange::Unknown,
            (false, None, false) => ShadowChange::Unchanged,
        }
    }
}

/// Per light: its centre and `region` grown by its radius (what [`verdict`] tests first).
pub fn light_boxes(region: (Vec3, Vec3), lights: &[LightBound]) -> Vec<(Vec3, Vec3, Vec3)> {
    lights.iter().map(|l| {
        let (lo, hi) = l.grow(region);
        (l.center, lo, hi)
    }).collect()
}

impl RenderCache {
    /// After an object moved through the world box `region` (its old and new place): every
    /// hit point not already stale whose segment toward a light meets the box is asked
    /// `query` ([`verdict`]). Changed: dropped (its slot freed). Unknown: marked stale (with
    /// [`NoExactAnswer`], every such point: [`RenderCache::age_shadowed_by`]). Unchanged: left
    /// as it is.
    /// Shifted: marked stale, its drift (the shifts since it was shaded) grown by it, and
    /// dropped once that reaches [`DROP_DRIFT`].
    /// Points already stale stay stale (shaded at some earlier state, they cannot be
    /// judged against the last one), except those made stale by shifts: their drift goes on
    /// adding up (the sum of the shifts bounds the change since their shading). Call after
    /// [`RenderCache::move_object`], which marks the moved object's own points stale.
    pub fn reshadow(&mut self, region: (Vec3, Vec3), lights: &[LightBound], query: &dyn ShadowQuery) -> Reshadowed {
        if lights.is_empty() || !(region.0.cmple(region.1).all()) {
            return Reshadowed::default();
        }
        self.point_image_from = None;
        let boxes = light_boxes(region, lights);
        let drop_at = drift_units(DROP_DRIFT);
        let p = &mut self.pool;
        const CHUNK: usize = 4096;
        // Decided in parallel (the flags of stale points set there); the drops are applied
        // after, since they touch the regions' free lists.
        let (dropped, stale) = p
            .flags
            .par_chunks_mut(CHUNK)
            .zip(p.drift.par_chunks_mut(CHUNK))
            .zip(p.px.par_chunks(CHUNK).zip(p.py.par_chunks(CHUNK)).zip(p.pz.par_chunks(CHUNK)))
            .enumerate()
            .map(|(c, ((flags, drift), ((xs, ys), zs)))| {
                let (mut out, mut stale) = (Vec::new(), 0u32);
                for k in 0..flags.len() {
                    let was_stale = flags[k] & FLAG_STALE != 0;
                    // Hit points, fresh or stale by shifts only.
                    if flags[k] & (FLAG_VALID | FLAG_HIT) != FLAG_VALID | FLAG_HIT || was_stale && drift[k] == 0 {
                        continue;
                    }
                    match verdict(Vec3::new(xs[k], ys[k], zs[k]), &boxes, query) {
                        ShadowChange::Unchanged => {}
                        ShadowChange::Unknown => {
                            flags[k] |= FLAG_STALE;
                            stale += u32::from(!was_stale);
                        }
                        ShadowChange::Shifted(f) => {
                            // At least one unit: a shift too small to count still marks the
                            // point as judged by shifts.
                            let d = u32::from(drift[k]) + drift_units(f).max(1);
                            if d >= drop_at {
                                out.push((c * CHUNK + k) as u32);
                            } else {
                                drift[k] = d as u8;
                                flags[k] |= FLAG_STALE;
                                stale += u32::from(!was_stale);
                            }
                        }
                        ShadowChange::Changed => out.push((c * CHUNK + k) as u32),
                    }
                }
                (out, stale)
            })
            .reduce(|| (Vec::new(), 0), |mut a, b| {
                a.0.extend(b.0);
                (a.0, a.1 + b.1)
            });
        if !dropped.is_empty() {
            self.drop_points(&dropped);
        }
        Reshadowed { stale, dropped: dropped.len() as u32 }
    }
}
