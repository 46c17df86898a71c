//! Which soft-shadow edges are barriers this frame (README "Soft-shadow edges in the EPI").
//!
//! An area light's umbral and penumbral edges bound a D1 discontinuity: the irradiance is
//! continuous across them, only its slope jumps. Drawn as D0 barriers they make each side
//! interpolate from its own samples only, and a smooth penumbra gets a false step. Where the
//! penumbra is narrow on screen, though, the shadow looks hard, and there the edges keep it
//! crisp: the hardening near a contact that paper 000 draws shadow edges for (§6), where
//! the penumbra shrinks to a pixel. So every frame each soft-shadow edge is cut to the part
//! whose penumbra, projected, is narrower than [`NARROW_PIXELS`]; interpolation crosses the
//! rest. Hard edges (point lights) and geometric edges carry no penumbra and stay whole.
//!
//! The penumbra comes with the edge from the shadow thread as a world vector across it at
//! each end ([`crate::edges::simplify::SceneLights::penumbra`]); here it costs four point
//! projections an edge.
use super::raster::{SegmentProjector, NEAR};
use crate::edges::EdgeSegment;
use glam::Vec3;

/// A penumbra narrower than this on screen (pixels) is drawn as a barrier: about the
/// reach of the interpolation's own blur, below which crossing it would smear the shadow.
pub const NARROW_PIXELS: f64 = 2.0;

/// Widths are capped here (a penumbra reaching behind the eye is "very wide"), so that the
/// linear cut below stays finite.
const WIDE: f64 = 1e6;

/// The on-screen width (pixels) of penumbra `v` centred on `p`, perpendicular to the
/// edge's unit screen direction `dir` (its whole length where the edge has none on screen).
fn width_px(prj: &SegmentProjector, p: Vec3, v: Vec3, dir: Option<[f64; 2]>) -> f64 {
    let (Some(q0), Some(q1)) = (prj.pixel(p - 0.5 * v), prj.pixel(p + 0.5 * v)) else { return WIDE };
    let d = [q1[0] - q0[0], q1[1] - q0[1]];
    let w = match dir {
        Some(u) => (d[0] * u[1] - d[1] * u[0]).abs(),
        None => d[0].hypot(d[1]),
    };
    if w.is_finite() {
        w.min(WIDE)
    } else {
        WIDE
    }
}

/// The part of shadow edge `e` that is a barrier this frame seen through `prj`: where its
/// penumbra (`penumbra`, the world vectors across it at `e.a` and `e.b`, from the shadow
/// thread) is narrower than `narrow` pixels on screen. `e` itself for a hard or geometric
/// edge (no penumbra), or one wholly behind the near plane (the rasterizer drops it);
/// `None` where the penumbra is at least that wide along all of it.
///
/// Along the edge the penumbra's world width W(t) is taken as linear (it is for a blocker
/// edge parallel to the receiver, and near a contact where it falls to 0) and its on-screen
/// width as W(t) g / z(t), z the view depth (linear in t) and g the slant factor of the
/// projection, taken as constant along the edge: then w(t) z(t) is linear and the cut
/// where w(t) = `narrow` is the root of a linear function, exact under those assumptions.
pub fn barrier_part(e: &EdgeSegment, penumbra: &[Vec3; 2], prj: &SegmentProjector, narrow: f64) -> Option<EdgeSegment> {
    if *penumbra == [Vec3::ZERO; 2] {
        return Some(*e);
    }
    let (za, zb) = (prj.depth(e.a), prj.depth(e.b));
    if za.is_nan() || zb.is_nan() || (za < NEAR && zb < NEAR) {
        return Some(*e);
    }
    // The parameter range in front of the near plane: the rest has no projection.
    let (lo, hi) = if za < NEAR {
        ((NEAR - za) / (zb - za), 1.0)
    } else if zb < NEAR {
        (0.0, (za - NEAR) / (za - zb))
    } else {
        (0.0, 1.0)
    };
    let at = |t: f64| (e.a.lerp(e.b, t as f32), penumbra[0].lerp(penumbra[1], t as f32));
    let ((p0, v0), (p1, v1)) = (at(lo), at(hi));
    let dir = match (prj.pixel(p0), prj.pixel(p1)) {
        (Some(s0), Some(s1)) => {
            let d = [s1[0] - s0[0], s1[1] - s0[1]];
            let len = d[0].hypot(d[1]);
            (len > 1e-9 && len.is_finite()).then(|| [d[0] / len, d[1] / len])
        }
        _ => None,
    };
    // h(t) = z(t) (w(t) − narrow), linear in t: negative where the penumbra is narrow.
    let h0 = prj.depth(p0).max(NEAR) * (width_px(prj, p0, v0, dir) - narrow);
    let h1 = prj.depth(p1).max(NEAR) * (width_px(prj, p1, v1, dir) - narrow);
    let part = |t0: f64, t1: f64| EdgeSegment { a: e.a.lerp(e.b, t0 as f32), b: e.a.lerp(e.b, t1 as f32), ..*e };
    match (h0 < 0.0, h1 < 0.0) {
        (true, true) if lo == 0.0 && hi == 1.0 => Some(*e),
        (true, true) => Some(part(lo, hi)),
        (false, false) => None,
        (n0, _) => {
            let t = lo + (hi - lo) * h0 / (h0 - h1);
            Some(if n0 { part(lo, t) } else { part(t, hi) })
        }
    }
}

/// Appends to `out` the barrier part ([`barrier_part`], at [`NARROW_PIXELS`]) of every
/// shadow edge of `edges`; every edge whole when `prj` is `None`.
pub fn append_barriers(edges: &[(EdgeSegment, [Vec3; 2])], prj: Option<&SegmentProjector>, out: &mut Vec<EdgeSegment>) {
    match prj {
        Some(prj) => out.extend(edges.iter().filter_map(|(e, p)| barrier_part(e, p, prj, NARROW_PIXELS))),
        None => out.extend(edges.iter().map(|(e, _)| *e)),
    }
}

#[cfg(test)]
mod tests;
