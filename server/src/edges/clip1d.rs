//! 1D clipping of the pieces one event cuts from its receivers (paper 000 §6.5 "Clipping":
//! "A nearby receiver may prevent a shadow event from propagating to more distant
//! receivers. For each shadow event, we sort the shadow edges it generates and clip them
//! against each other, retaining only the unoccluded edges. Clipping is simple and efficient
//! because it is performed in one dimension, along the edge of the VE/EV event.")
//!
//! In the wedge's canonical coordinates ([`super::wedge`]) ray `u ∈ [0, 1]` is the line
//! along `(1 - u, u)` and depth from the light is `μ`. Each piece covers a `u` interval
//! with `μ` varying along it; the visible parts are the lower envelope over `u`. Pieces are
//! sorted by where they start; the envelope is evaluated between consecutive breakpoints
//! (piece ends and crossings of overlapping pieces, so surfaces that pierce each other are
//! right too), keeping the nearest piece of each elementary interval and merging runs.
use glam::DVec2;

/// A piece to clip: a segment in canonical coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seg {
    pub a: DVec2,
    pub b: DVec2,
}

/// A visible part: piece `piece` (an index into the input) on rays `u0..u1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Visible {
    pub piece: usize,
    pub u0: f64,
    pub u1: f64,
}

/// Pieces narrower than this in `u` (seen end-on along a ray) hide nothing.
const MIN_WIDTH: f64 = 1e-12;

#[inline]
fn cross(a: DVec2, b: DVec2) -> f64 {
    a.x * b.y - a.y * b.x
}

#[inline]
fn u_of(q: DVec2) -> f64 {
    super::wedge::u_of(q)
}

/// Depth of the piece on ray `u` (its line met by the ray).
#[inline]
pub fn mu_at(s: &Seg, u: f64) -> f64 {
    let d = DVec2::new(1.0 - u, u);
    let den = cross(d, s.b - s.a);
    if den == 0.0 {
        return f64::INFINITY;
    }
    cross(s.a, s.b) / den
}

/// The point of the piece on ray `u`.
#[inline]
pub fn point_at(s: &Seg, u: f64) -> DVec2 {
    DVec2::new(1.0 - u, u) * mu_at(s, u)
}

/// Reusable allocations of [`visible`].
#[derive(Debug, Default)]
pub struct ClipScratch {
    order: Vec<(f64, f64, usize)>,
    breaks: Vec<f64>,
    active: Vec<usize>,
}

/// The lower envelope of `segs` over `u ∈ [0, 1]`, appended to `out` as runs of one piece.
pub fn visible(segs: &[Seg], out: &mut Vec<Visible>, scratch: &mut ClipScratch) {
    let ClipScratch { order, breaks, active } = scratch;
    order.clear();
    breaks.clear();
    active.clear();
    for (i, s) in segs.iter().enumerate() {
        let (ua, ub) = (u_of(s.a), u_of(s.b));
        let (u0, u1) = (ua.min(ub), ua.max(ub));
        if u1 - u0 > MIN_WIDTH {
            order.push((u0, u1, i));
        }
    }
    if order.is_empty() {
        return;
    }
    order.sort_unstable_by(|x, y| x.0.total_cmp(&y.0).then(x.2.cmp(&y.2)));
    // Breakpoints: ends, and crossings of pieces whose intervals overlap.
    for (k, &(u0, u1, i)) in order.iter().enumerate() {
        breaks.push(u0);
        breaks.push(u1);
        for &(v0, v1, j) in &order[k + 1..] {
            if v0 >= u1 {
                break;
            }
            let (lo, hi) = (u0.max(v0), u1.min(v1));
            let (p, q) = (&segs[i], &segs[j]);
            // Crossing of the two lines, if on both pieces' common rays.
            let (d1, d2) = (p.b - p.a, q.b - q.a);
            let den = cross(d1, d2);
            if den != 0.0 {
                let t = cross(q.a - p.a, d2) / den;
                let x = p.a + d1 * t;
                let u = u_of(x);
                if u > lo && u < hi && (0.0..=1.0).contains(&t) {
                    breaks.push(u);
                }
            }
        }
    }
    breaks.sort_unstable_by(|a, b| a.total_cmp(b));
    breaks.dedup_by(|a, b| (*a - *b).abs() <= MIN_WIDTH);
    // Sweep the elementary intervals.
    let mut next = 0;
    let first = out.len();
    for w in breaks.windows(2) {
        let (lo, hi) = (w[0], w[1]);
        if hi - lo <= MIN_WIDTH {
            continue;
        }
        while next < order.len() && order[next].0 <= lo + MIN_WIDTH {
            active.push(next);
            next += 1;
        }
        active.retain(|&k| order[k].1 > lo + MIN_WIDTH);
        let mid = 0.5 * (lo + hi);
        let mut best: Option<(f64, usize)> = None;
        for &k in active.iter() {
            let (u0, u1, i) = order[k];
            if u0 > lo + MIN_WIDTH || u1 < hi - MIN_WIDTH {
                continue;
            }
            let m = mu_at(&segs[i], mid);
            if best.is_none_or(|(bm, bi)| m < bm || (m == bm && i < bi)) {
                best = Some((m, i));
            }
        }
        if let Some((_, i)) = best {
            let extend = out.len() > first && out.last().is_some_and(|v| v.piece == i && (v.u1 - lo).abs() <= MIN_WIDTH);
            if extend {
                if let Some(v) = out.last_mut() {
                    v.u1 = hi;
                }
            } else {
                out.push(Visible { piece: i, u0: lo, u1: hi });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seg(u0: f64, m0: f64, u1: f64, m1: f64) -> Seg {
        Seg { a: DVec2::new(1.0 - u0, u0) * m0, b: DVec2::new(1.0 - u1, u1) * m1 }
    }

    /// The brute-force envelope: nearest piece on many sample rays.
    fn sampled(segs: &[Seg], u: f64) -> Option<usize> {
        let mut best: Option<(f64, usize)> = None;
        for (i, s) in segs.iter().enumerate() {
            let (ua, ub) = (u_of(s.a), u_of(s.b));
            if u > ua.min(ub) && u < ua.max(ub) {
                let m = mu_at(s, u);
                if best.is_none_or(|(bm, _)| m < bm) {
                    best = Some((m, i));
                }
            }
        }
        best.map(|b| b.1)
    }

    #[test]
    fn nearer_pieces_hide_farther_ones() {
        let segs = [seg(0.0, 3.0, 1.0, 3.0), seg(0.2, 2.0, 0.5, 2.0), seg(0.4, 1.0, 0.6, 1.5)];
        let mut out = Vec::new();
        visible(&segs, &mut out, &mut ClipScratch::default());
        let runs: Vec<(usize, f64, f64)> = out.iter().map(|v| (v.piece, v.u0, v.u1)).collect();
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        let want = [(0, 0.0, 0.2), (1, 0.2, 0.4), (2, 0.4, 0.6), (0, 0.6, 1.0)];
        assert_eq!(runs.len(), want.len(), "{runs:?}");
        for (g, w) in runs.iter().zip(want) {
            assert!(g.0 == w.0 && close(g.1, w.1) && close(g.2, w.2), "{runs:?}");
        }
    }

    #[test]
    fn crossing_pieces_switch_at_the_crossing() {
        // Two pieces crossing on ray u = 0.5.
        let segs = [seg(0.0, 1.0, 1.0, 3.0), seg(0.0, 3.0, 1.0, 1.0)];
        let mut out = Vec::new();
        visible(&segs, &mut out, &mut ClipScratch::default());
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].piece, 0);
        assert_eq!(out[1].piece, 1);
        let u = out[0].u1;
        assert!((mu_at(&segs[0], u) - mu_at(&segs[1], u)).abs() < 1e-9);
    }

    #[test]
    fn random_envelopes_match_sampling() {
        let mut h = 0x1234_5678_9abc_def0u64;
        let mut r = || {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            (h >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..300 {
            let n = 1 + (r() * 8.0) as usize;
            let segs: Vec<Seg> = (0..n)
                .map(|_| {
                    let (u0, u1) = (r(), r());
                    seg(u0, 1.0 + 3.0 * r(), u1, 1.0 + 3.0 * r())
                })
                .collect();
            let mut out = Vec::new();
            visible(&segs, &mut out, &mut ClipScratch::default());
            for k in 0..400 {
                let u = (k as f64 + 0.5) / 400.0;
                let got = out.iter().find(|v| u > v.u0 && u < v.u1).map(|v| v.piece);
                let want = sampled(&segs, u);
                // Sample rays within 1e-9 of a breakpoint are ambiguous.
                if out.iter().any(|v| (v.u0 - u).abs() < 1e-9 || (v.u1 - u).abs() < 1e-9) {
                    continue;
                }
                match (got, want) {
                    (Some(g), Some(w)) if g != w => {
                        // Equal depth (coincident pieces) is a tie either way.
                        assert!((mu_at(&segs[g], u) - mu_at(&segs[w], u)).abs() < 1e-9, "u {u}: {g} vs {w}");
                    }
                    (g, w) => assert_eq!(g.is_some(), w.is_some(), "u {u}"),
                }
            }
        }
    }
}
