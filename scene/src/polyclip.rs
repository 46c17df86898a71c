//! Convex polygon clipping, the geometric kernel of the exact backprojection (paper 002 §1:
//! "the exact visible part of the source … encoded with the backprojections"): one
//! Sutherland–Hodgman pass per half-space in 2D or 3D, and the difference of two convex
//! polygons as convex pieces. Everything is in f64: the pieces are cut again and again by
//! later blockers, and f32 would let their rounding add up.
use glam::{DVec2, DVec3};

/// A point type that polygons are made of (2D in a light's plane, 3D in the scene).
pub trait Point: Copy {
    fn lerp_to(self, other: Self, t: f64) -> Self;
}

impl Point for DVec2 {
    #[inline]
    fn lerp_to(self, other: Self, t: f64) -> Self {
        self + (other - self) * t
    }
}

impl Point for DVec3 {
    #[inline]
    fn lerp_to(self, other: Self, t: f64) -> Self {
        self + (other - self) * t
    }
}

/// The part of convex polygon `poly` where `dist(x) >= 0` (`dist` affine, so the part is
/// convex and its new corners lie where `dist` crosses zero along an edge). Fewer than three
/// corners left means nothing is left: the result is then empty.
pub fn clip<P: Point>(poly: &[P], dist: impl Fn(P) -> f64) -> Vec<P> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    clip_into(poly, &dist, &mut out);
    out
}

fn clip_into<P: Point>(poly: &[P], dist: &impl Fn(P) -> f64, out: &mut Vec<P>) {
    out.clear();
    let n = poly.len();
    if n < 3 {
        return;
    }
    let mut prev = poly[n - 1];
    let mut dp = dist(prev);
    for &cur in poly {
        let dc = dist(cur);
        // A crossing only where the signs are strictly opposite: a corner on the line is
        // kept once as it is, not again as a crossing (a repeated corner would make a
        // zero-length edge, whose line is undefined, in a polygon later used as a cutter).
        if (dp > 0.0 && dc < 0.0) || (dp < 0.0 && dc > 0.0) {
            // dp and dc have opposite signs, so the ratio is in [0, 1].
            out.push(prev.lerp_to(cur, dp / (dp - dc)));
        }
        if dc >= 0.0 {
            out.push(cur);
        }
        prev = cur;
        dp = dc;
    }
    if out.len() < 3 {
        out.clear();
    }
}

/// Removes corners within `tol` of the corner kept before them (cyclically): each edge of
/// the result is longer than `tol`, so its direction, and the line a subtraction cuts along,
/// is well defined.
pub fn drop_repeated(poly: &mut Vec<DVec2>, tol: f64) {
    let tol2 = tol * tol;
    let mut kept: Vec<DVec2> = Vec::with_capacity(poly.len());
    for &p in poly.iter() {
        if kept.last().is_none_or(|q| q.distance_squared(p) > tol2) {
            kept.push(p);
        }
    }
    while kept.len() > 1 && kept[0].distance_squared(kept[kept.len() - 1]) <= tol2 {
        kept.pop();
    }
    *poly = kept;
}

/// The convex hull, counter-clockwise (Andrew's monotone chain); collinear points dropped.
pub fn convex_hull(mut p: Vec<DVec2>) -> Vec<DVec2> {
    p.sort_unstable_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross = |o: DVec2, a: DVec2, b: DVec2| (a - o).perp_dot(b - o);
    let mut h: Vec<DVec2> = Vec::with_capacity(2 * p.len());
    // The lower chain left to right, then the upper one back.
    for pass in 0..2 {
        let start = h.len();
        for i in 0..p.len() {
            let x = if pass == 0 { p[i] } else { p[p.len() - 1 - i] };
            while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], x) <= 0.0 {
                h.pop();
            }
            h.push(x);
        }
        h.pop();
    }
    h
}

/// Twice the signed area of a 2D polygon (positive when counter-clockwise).
pub fn signed_area2(poly: &[DVec2]) -> f64 {
    let n = poly.len();
    (0..n).map(|i| poly[i].perp_dot(poly[(i + 1) % n])).sum()
}

/// The pieces of convex polygon `a` outside convex counter-clockwise polygon `b` (no
/// zero-length edges: [`drop_repeated`]), each
/// convex, appended to `out` (at most one per edge of `b`): walking `b`'s edges, the part of
/// what is left of `a` to the right of an edge's line is a piece, and the rest goes on to the
/// next edge; what survives every edge lies inside `b` and is dropped. Pieces thinner than
/// `min_area2` (twice the area) are dropped too: they are rounding, not light.
pub fn subtract_convex(a: &[DVec2], b: &[DVec2], min_area2: f64, out: &mut Vec<Vec<DVec2>>) {
    let mut rest = a.to_vec();
    let mut inside = Vec::with_capacity(a.len() + b.len());
    let n = b.len();
    for i in 0..n {
        let (p, q) = (b[i], b[(i + 1) % n]);
        let e = q - p;
        let left = |x: DVec2| e.perp_dot(x - p);
        // Wholly on one side of the edge's line (most edges, for most pieces): the clips
        // would copy `rest` to one side and leave nothing on the other, so no clipping.
        let (mut any_in, mut any_out) = (false, false);
        for x in &rest {
            // (A NaN counts as both: the clips decide.)
            let d = left(*x);
            any_in |= !(d <= 0.0);
            any_out |= !(d >= 0.0);
        }
        if !any_out {
            continue;
        }
        if !any_in {
            if rest.len() >= 3 && signed_area2(&rest) > min_area2 {
                out.push(rest);
            }
            return;
        }
        let outside = clip(&rest, |x| -left(x));
        if !outside.is_empty() && signed_area2(&outside) > min_area2 {
            out.push(outside);
        }
        clip_into(&rest, &left, &mut inside);
        std::mem::swap(&mut rest, &mut inside);
        if rest.is_empty() {
            return;
        }
    }
}

/// Whether the boxes around two point sets overlap (a cheap rejection before a
/// subtraction).
pub fn boxes_overlap(a: &[DVec2], b: &[DVec2]) -> bool {
    box_overlaps(a, bounds(b))
}

/// The box around a point set.
pub fn bounds(p: &[DVec2]) -> (DVec2, DVec2) {
    p.iter().fold((DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)), |(lo, hi), v| (lo.min(*v), hi.max(*v)))
}

/// [`boxes_overlap`] with the second set's box given (one shadow against many pieces).
pub fn box_overlaps(a: &[DVec2], (blo, bhi): (DVec2, DVec2)) -> bool {
    let (alo, ahi) = bounds(a);
    alo.x <= bhi.x && blo.x <= ahi.x && alo.y <= bhi.y && blo.y <= ahi.y
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuzz::mutate::Rng;

    fn square(lo: f64, hi: f64) -> Vec<DVec2> {
        vec![DVec2::new(lo, lo), DVec2::new(hi, lo), DVec2::new(hi, hi), DVec2::new(lo, hi)]
    }

    fn unit(r: &mut Rng) -> f64 {
        (r.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn clipping_a_square_by_a_half_plane_has_the_closed_form_area() {
        let s = square(0.0, 2.0);
        // x + y >= 1 cuts a corner triangle of area 1/2 off the 2×2 square.
        let c = clip(&s, |p| p.x + p.y - 1.0);
        assert!((signed_area2(&c) * 0.5 - 3.5).abs() < 1e-12, "{c:?}");
        assert!(clip(&s, |p| p.x - 3.0).is_empty(), "wholly outside");
        // A cut through two corners keeps each once (no zero-length edge).
        assert_eq!(clip(&s, |p| p.y - p.x), vec![DVec2::new(0.0, 0.0), DVec2::new(2.0, 2.0), DVec2::new(0.0, 2.0)]);
        let mut r = vec![DVec2::ZERO, DVec2::new(1e-12, 0.0), DVec2::X, DVec2::ONE, DVec2::new(0.0, 1e-13)];
        drop_repeated(&mut r, 1e-9);
        assert_eq!(r, vec![DVec2::ZERO, DVec2::X, DVec2::ONE]);
        assert_eq!(clip(&s, |p| p.x + 1.0), s, "wholly inside: unchanged");
        // In 3D: a triangle cut by the plane z = 0.5 keeps the part above it.
        let t = [DVec3::ZERO, DVec3::new(1.0, 0.0, 1.0), DVec3::new(0.0, 1.0, 1.0)];
        let c = clip(&t, |p| p.z - 0.5);
        assert_eq!(c.len(), 4);
        assert!(c.iter().all(|p| p.z >= 0.5 - 1e-15));
    }

    /// The subtraction with the one-side shortcut gives the pieces the plain two clips per
    /// edge give, bit for bit, on random pairs (apart, overlapping, one inside the other).
    #[test]
    fn one_sided_edges_skipped_give_the_same_pieces() {
        fn plain(a: &[DVec2], b: &[DVec2], min_area2: f64, out: &mut Vec<Vec<DVec2>>) {
            let mut rest = a.to_vec();
            for i in 0..b.len() {
                let (p, q) = (b[i], b[(i + 1) % b.len()]);
                let left = |x: DVec2| (q - p).perp_dot(x - p);
                let outside = clip(&rest, |x| -left(x));
                if !outside.is_empty() && signed_area2(&outside) > min_area2 {
                    out.push(outside);
                }
                rest = clip(&rest, left);
                if rest.is_empty() {
                    return;
                }
            }
        }
        let mut r = Rng::new(11);
        let (mut apart, mut overlapping) = (0, 0);
        for case in 0..2000 {
            let mut poly = |cx: f64, cy: f64, rad: f64| {
                let mut ang: Vec<f64> = (0..3 + r.below(5)).map(|_| unit(&mut r) * std::f64::consts::TAU).collect();
                ang.sort_by(f64::total_cmp);
                ang.iter().map(|a| DVec2::new(cx + rad * a.cos(), cy + rad * a.sin())).collect::<Vec<_>>()
            };
            let a = poly(0.0, 0.0, 1.0);
            let k = (case % 5) as f64;
            let b = poly(0.9 * k - 1.8, 0.2 * k, 0.3 + 0.4 * k);
            let (mut got, mut want) = (Vec::new(), Vec::new());
            subtract_convex(&a, &b, 1e-12, &mut got);
            plain(&a, &b, 1e-12, &mut want);
            assert_eq!(got, want, "case {case}");
            if got == [a.clone()] {
                apart += 1;
            } else if !got.is_empty() {
                overlapping += 1;
            }
        }
        assert!(apart > 100 && overlapping > 100, "{apart} apart, {overlapping} overlapping");
    }

    /// The pieces of A − B are disjoint and cover exactly A minus B: checked at random points
    /// against point-in-polygon membership, and by area against the area of A ∩ B found by
    /// clipping A by every edge of B.
    #[test]
    fn difference_pieces_tile_a_minus_b() {
        let mut r = Rng::new(7);
        let inside = |poly: &[DVec2], x: DVec2| (0..poly.len()).all(|i| (poly[(i + 1) % poly.len()] - poly[i]).perp_dot(x - poly[i]) > 0.0);
        for case in 0..200 {
            // Random convex polygons: points on a circle in angle order.
            let mut poly = |cx: f64, cy: f64, rad: f64| {
                let mut ang: Vec<f64> = (0..3 + r.below(5)).map(|_| unit(&mut r) * std::f64::consts::TAU).collect();
                ang.sort_by(f64::total_cmp);
                ang.iter().map(|a| DVec2::new(cx + rad * a.cos(), cy + rad * a.sin())).collect::<Vec<_>>()
            };
            let a = poly(0.0, 0.0, 1.0);
            let b = poly(0.6 * (case % 3) as f64 - 0.6, 0.3, 0.8);
            if signed_area2(&a) <= 1e-6 || signed_area2(&b) <= 1e-6 {
                continue;
            }
            let mut pieces = Vec::new();
            subtract_convex(&a, &b, 0.0, &mut pieces);
            let mut ab = a.clone();
            for i in 0..b.len() {
                let (p, q) = (b[i], b[(i + 1) % b.len()]);
                ab = clip(&ab, |x| (q - p).perp_dot(x - p));
            }
            let area = |p: &[DVec2]| signed_area2(p) * 0.5;
            let total: f64 = pieces.iter().map(|p| area(p)).sum();
            assert!((total - (area(&a) - area(&ab))).abs() < 1e-9, "case {case}: {total} vs {} - {}", area(&a), area(&ab));
            for _ in 0..200 {
                let x = DVec2::new(unit(&mut r) * 2.4 - 1.2, unit(&mut r) * 2.4 - 1.2);
                let want = inside(&a, x) && !inside(&b, x);
                let hits = pieces.iter().filter(|p| inside(p, x)).count();
                // Points exactly on a cut are in no open piece; random points never are.
                assert_eq!(hits, want as usize, "case {case} at {x}");
            }
        }
    }
}
