//! EEE surfaces with one edge on the light (paper 002 §4.3.2, "EEE Surfaces", and Figure
//! 12; after Drettakis and Fiume's complete discontinuity mesh): light edge `l` × blocker
//! edges `e1`, `e2`. From each point `y(s)` of the light edge one line meets both blocker
//! edges' lines — the intersection of the planes through `y(s)` and each edge — and the
//! surface is the ruled quadric these lines sweep. Where it exists (the line meets both
//! edges, between the light and the receiver, both edges silhouettes seen from `y(s)`) and
//! its line is not blocked, the shadows of `e1` and `e2` seen from the receiver point cross
//! exactly on the light edge: a vertex of the visible part of the light enters or leaves
//! through the edge. Such a crossing is made where two VE surfaces of one light corner cross
//! (the paper's Figure 12, its `checkForEEE`), and also where a surface starts or ends in
//! the middle of the light edge, at an EV surface of a blocker edge's end; both are found
//! here the same way, from the pairs of blocker edges.
//!
//! Everything along the surface is a function of the light edge's parameter `s` whose
//! changes come at the roots of polynomials of degree ≤ 2 in `s`:
//!
//! - the line through `y(s)` passes a point `c` of `e2` (it leaves or enters `e2`'s segment):
//!   `c` in the plane through `y(s)` and `e1` — a triple product, linear in `s`;
//! - it meets a third line `f` (a receiver side, or an edge of a triangle that may hide it:
//!   **1D visibility**, paper 002 §3.3): the three planes through `y(s)` and `e1`, `e2`, `f`
//!   share a line — their normals' determinant, of degree 2 in `s` (the cubic terms cancel);
//! - an edge turns into or out of a silhouette: `y(s)` crosses a plane of its triangles;
//! - the line turns parallel to the receiver: degree 2.
//!
//! The light edge's parameter range is cut at every such root and each piece is judged at
//! its middle, so the parts where the surface exists and the intervals each blocker hides are
//! exact up to the roots' rounding. The trace on the receiver is a conic arc; it enters the
//! arrangement as a polyline whose corners lie on the arc and whose chords stay within
//! [`CHORD_TOLERANCE`] of the receiver's longest side of it.
use super::geometry::{boxes_meet, edge_key, union_of, EdgeKey, Geometry};
use super::receiver::{part_above, LightAbove, Receiver};
use super::segments::{is_silhouette, sort_hidden, Generator, Runs, Segment, Step};
use edgepoint_scene::backprojection::{LightPlane, LIGHT_GAP};
use glam::{DVec2, DVec3};

/// How far a trace's chords may stray from its arc, as a fraction of the receiver's longest
/// side: 10⁻⁴ is a twentieth of a pixel for a receiver across a 512-pixel frame.
pub const CHORD_TOLERANCE: f64 = 1e-4;
/// At most 2⁸ chords per part of a trace.
const MAX_DEPTH: u32 = 8;

/// One EEE surface on a receiver with its intersection list (as [`super::segments::TraceVis`]
/// for the straight traces): the parts of the light edge where it exists and lands on the
/// receiver, and the parameter intervals each blocker hides.
#[derive(Debug, Clone)]
pub struct EeeSurface {
    /// The light edge (its index among the light's edges) and the two blocker edges, the
    /// smaller key first.
    pub light_edge: u32,
    pub edges: (EdgeKey, EdgeKey),
    /// The light edge's part above the receiver: `y(s) = y0 + s (y1 − y0)`.
    pub y0: DVec3,
    pub y1: DVec3,
    /// One interval of `s` where the surface exists and its lines end inside the receiver.
    pub part: (f64, f64),
    /// The box of its lines over the part, from the light to the receiver.
    pub bbox: (DVec3, DVec3),
    /// `(triangle, s0, s1)`, sorted by start.
    pub hidden: Vec<(u32, f64, f64)>,
}

/// The two blocker edges' segments and the light edge, for the lines through both.
#[derive(Debug, Clone, Copy)]
pub struct Lines {
    pub y0: DVec3,
    pub y1: DVec3,
    pub e1: [DVec3; 2],
    pub e2: [DVec3; 2],
}

/// The line of the surface at one `s`, pointing from the light to the receiver's plane.
#[derive(Debug, Clone, Copy)]
pub struct Ruling {
    pub y: DVec3,
    /// Where it meets the receiver's plane.
    pub end: DVec3,
    /// Parameters along `e1` and `e2` where it meets them, and along the line (0 at `y`, 1 at
    /// `end`) where it does.
    pub u: [f64; 2],
    pub t: [f64; 2],
}

/// The parameters `(u, t)` where the coplanar lines `p + u (q − p)` and `y + t d` meet.
fn meet(y: DVec3, d: DVec3, p: DVec3, q: DVec3) -> Option<(f64, f64)> {
    let e = q - p;
    let c = e.cross(d);
    let cc = c.length_squared();
    // (NaN fails too.)
    if cc.is_nan() || cc <= 1e-300 {
        return None;
    }
    let u = (y - p).cross(d).dot(c) / cc;
    let t = (p + e * u - y).dot(d) / d.length_squared();
    Some((u, t))
}

/// The normal of the plane through `y` and the line `p q`.
#[inline]
fn plane(y: DVec3, p: DVec3, q: DVec3) -> DVec3 {
    (p - y).cross(q - y)
}

impl Lines {
    pub fn new(g: &Geometry, (y0, y1): (DVec3, DVec3), e1: EdgeKey, e2: EdgeKey) -> Lines {
        let p = |e: EdgeKey| [g.pos[e.0 as usize], g.pos[e.1 as usize]];
        Lines { y0, y1, e1: p(e1), e2: p(e2) }
    }

    #[inline]
    pub fn y(&self, s: f64) -> DVec3 {
        self.y0 + (self.y1 - self.y0) * s
    }

    /// The planes through `y(s)` and each edge.
    #[inline]
    fn planes(&self, s: f64) -> (DVec3, DVec3, DVec3) {
        let y = self.y(s);
        (y, plane(y, self.e1[0], self.e1[1]), plane(y, self.e2[0], self.e2[1]))
    }

    /// The line from `y(s)` meeting both edges' lines, if it reaches the receiver's plane
    /// going down from the light.
    pub fn ruling(&self, r: &Receiver, s: f64) -> Option<Ruling> {
        let (y, n1, n2) = self.planes(s);
        let mut d = n1.cross(n2);
        let dn = d.dot(r.n);
        if dn.is_nan() || dn.abs() <= 1e-300 {
            return None;
        }
        if dn > 0.0 {
            d = -d;
        }
        let hy = r.height(y);
        if hy <= 0.0 {
            return None;
        }
        // Scaled so that the line reaches the plane at t = 1.
        let d = d * (hy / -d.dot(r.n));
        let (u1, t1) = meet(y, d, self.e1[0], self.e1[1])?;
        let (u2, t2) = meet(y, d, self.e2[0], self.e2[1])?;
        Some(Ruling { y, end: y + d, u: [u1, u2], t: [t1, t2] })
    }

    /// Whether the ruling meets `f`'s line, as a function of `s` of degree 2: the three
    /// planes' determinant.
    fn meets_line(&self, s: f64, f: (DVec3, DVec3)) -> f64 {
        let (y, n1, n2) = self.planes(s);
        n1.cross(n2).dot(plane(y, f.0, f.1))
    }

    /// Which side of the plane through `y(s)` and the other edge point `c` of one edge lies
    /// on (`other` = 1: `c` on `e1`, tested against `e2`'s plane), linear in `s`.
    fn passes(&self, s: f64, c: DVec3, other: usize) -> f64 {
        let (y, n1, n2) = self.planes(s);
        [n1, n2][other].dot(c - y)
    }
}

/// The roots in (0, 1) of `f`, a polynomial of degree ≤ 2 (found from three values and
/// polished on `f` itself), appended to `out`. A polynomial that is zero at all three is
/// taken as zero everywhere (no cut).
fn roots(f: impl Fn(f64) -> f64, out: &mut Vec<f64>) {
    let (f0, fh, f1) = (f(0.0), f(0.5), f(1.0));
    let scale = f0.abs().max(fh.abs()).max(f1.abs());
    let a = 2.0 * (f0 + f1) - 4.0 * fh;
    quadratic([f0, f1 - f0 - a, a], scale, f, (0.0, 1.0), out);
}

/// The roots in `(lo, hi)` of `f`, a polynomial of degree ≤ 2 up to rounding with
/// coefficients `c` (constant first) of size `scale`, polished by two Newton steps on `f`
/// itself, appended to `out`.
fn quadratic(c: [f64; 3], scale: f64, f: impl Fn(f64) -> f64, (lo, hi): (f64, f64), out: &mut Vec<f64>) {
    if !scale.is_finite() || scale <= 0.0 {
        return;
    }
    let [c, b, a] = c;
    let mut found = [f64::NAN; 2];
    if a.abs() <= 1e-12 * scale {
        if b.abs() > 1e-300 {
            found[0] = -c / b;
        }
    } else {
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return; // no real root; a double root touches zero without a sign change
        }
        let q = -0.5 * (b + if b >= 0.0 { disc.sqrt() } else { -disc.sqrt() });
        found[0] = q / a;
        if q != 0.0 {
            found[1] = c / q;
        }
    }
    for mut x in found {
        if !x.is_finite() {
            continue;
        }
        // Two Newton steps on `f` (the coefficients carry their rounding).
        for _ in 0..2 {
            let slope = 2.0 * a * x + b;
            if slope.abs() > 1e-300 {
                let step = f(x) / slope;
                if step.is_finite() {
                    x -= step;
                }
            }
        }
        if x > lo && x < hi {
            out.push(x);
        }
    }
}

/// Whether the line from `y(s)` meets line `f`, as coefficients in `s`: the plane through
/// `y(s)` and `p q` has the normal `p × q + (q − p) × y(s)`, linear in `s`, and the line's
/// direction `d(s)` (the two edge planes' normals crossed) is quadratic, so their product is
/// a cubic whose top term vanishes (left in, to polish the roots on).
fn meets_line_coefficients(d: &[DVec3; 3], lines: &Lines, (p, q): (DVec3, DVec3)) -> ([f64; 4], f64) {
    let f0 = p.cross(q) + (q - p).cross(lines.y0);
    let f1 = (q - p).cross(lines.y1 - lines.y0);
    let c = [d[0].dot(f0), d[0].dot(f1) + d[1].dot(f0), d[1].dot(f1) + d[2].dot(f0), d[2].dot(f1)];
    // The size of the terms summed, for the threshold below which a coefficient is zero.
    let scale = (d[0].length() + d[1].length() + d[2].length()) * (f0.length() + f1.length());
    (c, scale)
}

/// The pieces of `(lo, hi)` cut at `cuts` where `keep` holds at the middle, adjacent ones
/// merged, appended to `out`.
fn pieces(lo: f64, hi: f64, cuts: &mut Vec<f64>, keep: impl FnMut(f64) -> bool) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    each_piece(lo, hi, cuts, keep, |a, b| out.push((a, b)));
    out
}

/// [`pieces`] handed to `emit` one by one, in order (no list made: the per-triangle tests
/// run it a million times a move).
fn each_piece(lo: f64, hi: f64, cuts: &mut Vec<f64>, mut keep: impl FnMut(f64) -> bool, mut emit: impl FnMut(f64, f64)) {
    cuts.retain(|c| *c > lo && *c < hi);
    cuts.push(lo);
    cuts.push(hi);
    cuts.sort_by(f64::total_cmp);
    cuts.dedup();
    let mut run: Option<(f64, f64)> = None;
    for w in cuts.windows(2) {
        if w[1] - w[0] <= 1e-13 || !keep(0.5 * (w[0] + w[1])) {
            continue;
        }
        match &mut run {
            Some(last) if last.1 == w[0] => last.1 = w[1],
            _ => {
                if let Some((a, b)) = run {
                    emit(a, b);
                }
                run = Some((w[0], w[1]));
            }
        }
    }
    if let Some((a, b)) = run {
        emit(a, b);
    }
}

/// The parts of light edge `(y0, y1)` where the EEE surface of candidate edges `c1`, `c2`
/// exists on receiver `r`: its line meets both edges' segments, below the light and above
/// the receiver, in front of the light, both edges silhouettes seen from
/// `y(s)`, and it ends inside the receiver triangle. In two stages: first where the line
/// meets both segments and both edges are silhouettes (linear cuts, and the candidates'
/// own silhouette parts), which most pairs fail; then the rest.
pub fn parts(light: &LightPlane, r: &Receiver, lines: &Lines, c1: &Candidate, c2: &Candidate) -> Vec<(f64, f64)> {
    let mut cuts = Vec::new();
    for (k, e) in [lines.e1, lines.e2].iter().enumerate() {
        for c in e {
            roots(|s| lines.passes(s, *c, 1 - k), &mut cuts);
        }
    }
    cuts.extend(c1.silhouette.iter().chain(&c2.silhouette).flat_map(|p| [p.0, p.1]));
    let first = pieces(0.0, 1.0, &mut cuts, |s| meets_both(lines, s) && c1.silhouette_at(s) && c2.silhouette_at(s));
    let mut out = Vec::new();
    for (lo, hi) in first {
        let mut cuts = Vec::new();
        for (k, e) in [lines.e1, lines.e2].iter().enumerate() {
            // Where the edge crosses the receiver's plane (there the surface ends on the
            // blocker's contact with the receiver, [`super::segments::contacts`]).
            if let Some(c) = r.crossing(e[0], e[1], 0.0) {
                roots(|s| lines.passes(s, c, 1 - k), &mut cuts);
            }
        }
        roots(|s| {
            let (_, n1, n2) = lines.planes(s);
            n1.cross(n2).dot(r.n)
        }, &mut cuts);
        for k in 0..3 {
            let f = (r.to3(r.corners[k]), r.to3(r.corners[(k + 1) % 3]));
            roots(|s| lines.meets_line(s, f), &mut cuts);
        }
        out.extend(pieces(lo, hi, &mut cuts, |s| lands(light, r, lines, s)));
    }
    // Pieces of two stages that touch are one part.
    out.dedup_by(|b, a| {
        let touch = a.1 == b.0;
        if touch {
            a.1 = b.1;
        }
        touch
    });
    out
}

/// Whether the line from `y(s)` meets both edges' segments (strictly inside each): each
/// edge's ends lie on opposite sides of the plane through `y(s)` and the other edge.
fn meets_both(lines: &Lines, s: f64) -> bool {
    let split = |e: &[DVec3; 2], other: usize| {
        let (a, b) = (lines.passes(s, e[0], other), lines.passes(s, e[1], other));
        (a > 0.0 && b < 0.0) || (a < 0.0 && b > 0.0)
    };
    split(&lines.e1, 1) && split(&lines.e2, 0)
}

/// Whether the line from `y(s)` through both edges meets them between the light and the
/// receiver (above its plane), in front of the light, and ends inside the
/// receiver triangle.
fn lands(light: &LightPlane, r: &Receiver, lines: &Lines, s: f64) -> bool {
    let Some(l) = lines.ruling(r, s) else { return false };
    let inside = (0..2).all(|k| {
        let x = l.y + (l.end - l.y) * l.t[k];
        l.u[k] > 0.0 && l.u[k] < 1.0 && l.t[k] > 0.0 && l.t[k] < 1.0 && r.height(x) > 0.0 && light.height(x) > 0.0
    });
    inside && r.contains(r.to2(l.end))
}

/// The planes through the ends of a part of the light edge, `y(lo)` and `y(hi)`, and each
/// blocker edge: as `s` runs over the part, the plane through `y(s)` and an edge turns about
/// the edge (a pencil of planes), and a point's side of it is linear in `s`, so its sides at
/// the two ends decide its side throughout.
///
/// The lines also lie in the planes through the light edge's line and their point on the
/// first blocker edge; a point's side of those is linear in that point's parameter along the
/// edge, which moves monotonically with `s` (a projective map): a third pencil, about the
/// light edge, for the same test.
#[derive(Debug, Clone, Copy)]
pub struct Pencils {
    part: (f64, f64),
    /// `[end][pencil]`: normal and offset (`n · x = d` on the plane); pencil 2 about the
    /// light edge is all zeros (no test) when a line at an end is missing.
    at: [[(DVec3, f64); 3]; 2],
    /// The lines' direction `d(s) = d0 + s d1 + s² d2` (the two edge planes' normals, each
    /// `a × b + (b − a) × y(s)`, crossed).
    d: [DVec3; 3],
}

impl Pencils {
    pub fn new(lines: &Lines, r: &Receiver, part: (f64, f64)) -> Pencils {
        let l = lines.y1 - lines.y0;
        let normal = |e: &[DVec3; 2]| (e[0].cross(e[1]) + (e[1] - e[0]).cross(lines.y0), (e[1] - e[0]).cross(l));
        let ((n10, n11), (n20, n21)) = (normal(&lines.e1), normal(&lines.e2));
        let d = [n10.cross(n20), n10.cross(n21) + n11.cross(n20), n11.cross(n21)];
        let ends = [part.0, part.1].map(|s| (lines.planes(s), lines.ruling(r, s)));
        let about_light = ends.iter().all(|e| e.1.is_some());
        let at = ends.map(|((y, n1, n2), l)| {
            let light = match l {
                Some(l) if about_light => {
                    let x = lines.e1[0] + (lines.e1[1] - lines.e1[0]) * l.u[0];
                    let n = (lines.y1 - lines.y0).cross(x - lines.y0);
                    (n, n.dot(lines.y0))
                }
                _ => (DVec3::ZERO, 0.0),
            };
            [(n1, n1.dot(y)), (n2, n2.dot(y)), light]
        });
        Pencils { part, at, d }
    }

    /// Whether box `b` lies strictly on one side of a pencil's plane over the whole part (the
    /// same side at both ends): no line of the surface there crosses it.
    pub fn box_apart(&self, b: &(DVec3, DVec3)) -> bool {
        let (mid, ext) = ((b.0 + b.1) * 0.5, (b.1 - b.0) * 0.5);
        (0..3).any(|k| {
            let side = |e: usize| {
                let (n, d) = self.at[e][k];
                let (c, r) = (n.dot(mid) - d, n.abs().dot(ext));
                if c - r > 0.0 {
                    1
                } else if c + r < 0.0 {
                    -1
                } else {
                    0
                }
            };
            let a = side(0);
            a != 0 && a == side(1)
        })
    }

    /// Whether the corners of `tri` lie strictly on one side of pencil `k`'s plane at both
    /// ends, the same side.
    fn apart(&self, k: usize, tri: &[DVec3; 3]) -> bool {
        let side = |e: usize| {
            let (n, d) = self.at[e][k];
            let f = tri.map(|c| n.dot(c) - d);
            if f.iter().all(|v| *v > 0.0) {
                1
            } else if f.iter().all(|v| *v < 0.0) {
                -1
            } else {
                0
            }
        };
        let a = side(0);
        a != 0 && a == side(1)
    }

    /// The smallest interval of the part outside which the plane through `y(s)` and edge `k`
    /// has every corner of `tri` strictly on one side, within `(lo, hi)`; `None` when there
    /// is none.
    fn straddled(&self, k: usize, tri: &[DVec3; 3], (lo, hi): (f64, f64)) -> Option<(f64, f64)> {
        let (p0, p1) = self.part;
        let side = |e: usize, c: DVec3| {
            let (n, d) = self.at[e][k];
            n.dot(c) - d
        };
        let f0 = tri.map(|c| side(0, c));
        let f1 = tri.map(|c| side(1, c));
        // All positive on an interval (the intersection of each corner's positive half-line),
        // all negative on another: the triangle straddles the plane on the rest.
        let mut cuts = [p0, p1, f64::NAN, f64::NAN, f64::NAN];
        let mut n = 2;
        for i in 0..3 {
            if (f0[i] > 0.0) != (f1[i] > 0.0) {
                cuts[n] = p0 + (p1 - p0) * (f0[i] / (f0[i] - f1[i]));
                n += 1;
            }
        }
        let cuts = &mut cuts[..n];
        cuts.sort_by(f64::total_cmp);
        let mut out = (f64::INFINITY, f64::NEG_INFINITY);
        for w in cuts.windows(2) {
            let x = (0.5 * (w[0] + w[1]) - p0) / (p1 - p0);
            let (mut pos, mut neg) = (false, false);
            for i in 0..3 {
                let v = f0[i] + (f1[i] - f0[i]) * x;
                pos |= v > 0.0;
                neg |= v < 0.0;
            }
            if pos && neg {
                out = (out.0.min(w[0]), out.1.max(w[1]));
            }
        }
        let out = (out.0.max(lo), out.1.min(hi));
        (out.0 < out.1).then_some(out)
    }
}

/// Whether the segment from `p` to `q` crosses the interior of triangle `tri`.
pub fn pierces(p: DVec3, q: DVec3, tri: &[DVec3; 3]) -> bool {
    let d = q - p;
    let (e1, e2) = (tri[1] - tri[0], tri[2] - tri[0]);
    let h = d.cross(e2);
    let det = e1.dot(h);
    if det.is_nan() || det.abs() <= 1e-300 {
        return false;
    }
    let w = p - tri[0];
    let u = w.dot(h) / det;
    let qv = w.cross(e1);
    let v = d.dot(qv) / det;
    let t = e2.dot(qv) / det;
    u > 0.0 && v > 0.0 && u + v < 1.0 && t > 0.0 && t < 1.0
}

/// The open segment of the ruling at `s` that a blocker may cut: from just below the light
/// (short of it by [`LIGHT_GAP`], as the other surfaces and the backprojection) to the
/// receiver.
fn ruling_segment(lines: &Lines, r: &Receiver, s: f64) -> Option<(DVec3, DVec3)> {
    let l = lines.ruling(r, s)?;
    Some((l.y + (l.end - l.y) * LIGHT_GAP, l.end))
}

impl EeeSurface {
    /// The surface's part `part` with its box and no intersections yet. Its lines run from
    /// the light edge's part to the receiver, where they end inside both edges' shadows
    /// (`shadow`, the two candidates' shadow boxes met): the box holds those ends' box and
    /// the light edge's part, grown by the tolerance.
    fn new(r: &Receiver, lines: &Lines, light_edge: u32, (e1, e2): (EdgeKey, EdgeKey), part: (f64, f64), shadow: (DVec2, DVec2)) -> EeeSurface {
        let (a, b) = (shadow.0, shadow.1);
        let ends = [DVec2::new(a.x, a.y), DVec2::new(b.x, a.y), DVec2::new(b.x, b.y), DVec2::new(a.x, b.y)].map(|q| r.to3(q));
        let (lo, hi) = union_of(ends.iter().chain(&[lines.y(part.0), lines.y(part.1)]).map(|p| (*p, *p)));
        EeeSurface { light_edge, edges: (e1, e2), y0: lines.y0, y1: lines.y1, part, bbox: (lo - r.tol, hi + r.tol), hidden: Vec::new() }
    }

    /// Its [`Generator::Eee`].
    pub fn generator(&self) -> Generator {
        Generator::Eee { light_edge: self.light_edge, edges: self.edges }
    }

    pub fn lines(&self, g: &Geometry) -> Lines {
        let (e1, e2) = self.edges;
        Lines::new(g, (self.y0, self.y1), e1, e2)
    }

    /// Appends the intervals of the part that triangle `t` hides (none for the triangles
    /// at either blocker edge, which the lines only graze).
    /// (`cuts` is scratch.)
    #[allow(clippy::too_many_arguments)] // the surface's lines and pencils made once for every triangle, and a scratch list
    pub fn hide(&self, g: &Geometry, r: &Receiver, lines: &Lines, pencils: &Pencils, t: u32, cuts: &mut Vec<f64>, out: &mut Vec<(u32, f64, f64)>) {
        let (e1, e2) = self.edges;
        let v = g.tris[t as usize];
        let at = |e: EdgeKey| v.contains(&e.0) && v.contains(&e.1);
        if at(e1) || at(e2) {
            return;
        }
        let tri = g.tri(t);
        let tb = (tri[0].min(tri[1]).min(tri[2]), tri[0].max(tri[1]).max(tri[2]));
        if !boxes_meet(tb, self.bbox) {
            return;
        }
        // Only where the triangle reaches across the planes through y(s) and each edge (two
        // pencils of planes about the edges) can the line there cross it.
        if pencils.apart(2, &tri) {
            return;
        }
        let Some((lo, hi)) = pencils.straddled(0, &tri, self.part).and_then(|p| pencils.straddled(1, &tri, p)) else { return };
        cuts.clear();
        let mut meets = |f: (DVec3, DVec3)| {
            let (c, scale) = meets_line_coefficients(&pencils.d, lines, f);
            quadratic([c[0], c[1], c[2]], scale, |s| ((c[3] * s + c[2]) * s + c[1]) * s + c[0], (lo, hi), cuts);
        };
        for k in 0..3 {
            meets((tri[k], tri[(k + 1) % 3]));
        }
        // A triangle through the receiver's plane: the line's end crosses it there.
        if let Some([p, q]) = r.plane_crossing(&tri) {
            meets((p, q));
        }
        each_piece(lo, hi, cuts, |s| ruling_segment(lines, r, s).is_some_and(|(p, q)| pierces(p, q, &tri)), |h0, h1| out.push((t, h0, h1)));
    }

    /// [`EeeSurface::hide`] for the triangles of `runs`, a run or a group of runs passed over
    /// when its box misses the surface's or lies apart from a pencil.
    pub fn hide_all(&self, g: &Geometry, r: &Receiver, lines: &Lines, pencils: &Pencils, runs: &Runs, out: &mut Vec<(u32, f64, f64)>) {
        let mut cuts = Vec::new();
        runs.walk(|step| match step {
            Step::Open(b) => boxes_meet(*b, self.bbox) && !pencils.box_apart(b),
            Step::Triangle(t) => {
                self.hide(g, r, lines, pencils, t, &mut cuts, out);
                true
            }
        });
    }

    /// The visible parts' polylines as segments, appended to `out`.
    pub fn visible(&self, g: &Geometry, r: &Receiver, out: &mut Vec<Segment>) {
        let lines = self.lines(g);
        let (mut at, end) = self.part;
        let mut emit = |s0: f64, s1: f64| {
            if s1 > s0 {
                let pts = arc(r, &lines, (s0, s1));
                for w in pts.windows(2) {
                    out.push(Segment { generator: self.generator(), a: w[0].1, b: w[1].1 });
                }
            }
        };
        for &(_, h0, h1) in &self.hidden {
            if h0 > at {
                emit(at, h0.min(end));
            }
            at = at.max(h1);
            if at >= end {
                break;
            }
        }
        if at < end {
            emit(at, end);
        }
    }

    pub fn bytes(&self) -> usize {
        std::mem::size_of::<EeeSurface>() + self.hidden.len() * 24
    }
}

fn chord_tolerance(r: &Receiver) -> f64 {
    let c = &r.corners;
    CHORD_TOLERANCE * c[0].distance(c[1]).max(c[1].distance(c[2])).max(c[2].distance(c[0]))
}

/// The trace's polyline over `(s0, s1)`: points on the arc, the chords within the
/// tolerance of it at their middles (halving up to [`MAX_DEPTH`] times; a conic arc has no
/// inflection, so its middle strays farthest), points closer than ten tolerances to the last
/// one kept dropped (the last point is always kept).
pub fn arc(r: &Receiver, lines: &Lines, (s0, s1): (f64, f64)) -> Vec<(f64, DVec2)> {
    let at = |s: f64| lines.ruling(r, s).map(|l| r.to2(l.end));
    let (Some(a), Some(b)) = (at(s0), at(s1)) else { return Vec::new() };
    let eps = chord_tolerance(r);
    let mut out = vec![(s0, a)];
    fn split(at: &dyn Fn(f64) -> Option<DVec2>, eps: f64, (s0, a): (f64, DVec2), (s1, b): (f64, DVec2), depth: u32, out: &mut Vec<(f64, DVec2)>) {
        let sm = 0.5 * (s0 + s1);
        if let Some(m) = at(sm) {
            let off = (b - a).perp().try_normalize().map_or(m.distance(a), |n| n.dot(m - a).abs());
            if off > eps && depth < MAX_DEPTH {
                split(at, eps, (s0, a), (sm, m), depth + 1, out);
                split(at, eps, (sm, m), (s1, b), depth + 1, out);
                return;
            }
        }
        out.push((s1, b));
    }
    split(&at, eps, (s0, a), (s1, b), 0, &mut out);
    let min = 10.0 * r.tol;
    let mut kept: Vec<(f64, DVec2)> = Vec::with_capacity(out.len());
    for (i, p) in out.iter().enumerate() {
        let last = i + 1 == out.len();
        match kept.last() {
            Some(k) if k.1.distance(p.1) <= min => {
                if last && kept.len() > 1 {
                    *kept.last_mut().expect("a point") = *p;
                }
            }
            _ => kept.push(*p),
        }
    }
    if kept.len() < 2 {
        kept.clear();
    }
    kept
}

/// A blocker edge that may generate EEE surfaces with a light edge on a receiver: the parts
/// of the light edge from which it is a silhouette (none: not a candidate), and the box of
/// its shadow from the light edge (of its ends' shadows from the light edge's ends), which
/// meets the receiver's box.
#[derive(Debug, Clone)]
pub struct Candidate {
    pub edge: EdgeKey,
    pub shadow: (DVec2, DVec2),
    pub silhouette: Vec<(f64, f64)>,
}

impl Candidate {
    fn silhouette_at(&self, s: f64) -> bool {
        self.silhouette.iter().any(|p| s > p.0 && s < p.1)
    }
}

/// The parts of light edge `(y0, y1)` from which edge `e` is a silhouette: it can turn into
/// or out of one only where the light edge crosses the plane of one of its triangles.
fn silhouette_parts(g: &Geometry, (y0, y1): (DVec3, DVec3), e: EdgeKey, tol: f64) -> Vec<(f64, f64)> {
    let mut cuts = Vec::new();
    for t in g.edge_tris.get(&e).into_iter().flatten() {
        let [a, b, c] = g.tri(*t);
        let n = (b - a).cross(c - a);
        let (d0, d1) = (n.dot(y0 - a), n.dot(y1 - a));
        if (d0 > 0.0) != (d1 > 0.0) {
            cuts.push(d0 / (d0 - d1));
        }
    }
    pieces(0.0, 1.0, &mut cuts, |s| is_silhouette(g, y0 + (y1 - y0) * s, e, tol))
}

/// The candidate edges among `edges` for light edge `(y0, y1)` on `r`, their shadows within
/// box `within` (receiver frame; the receiver's box when `None`).
#[allow(clippy::too_many_arguments)] // the light edge, the edges and where their shadows must fall
pub fn candidates(g: &Geometry, light: &LightPlane, r: &Receiver, (y0, y1): (DVec3, DVec3), edges: &[EdgeKey], within: Option<(DVec2, DVec2)>, out: &mut Vec<Candidate>) {
    let rb = r.corners.iter().fold((DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY)), |(lo, hi), c| (lo.min(*c), hi.max(*c)));
    let rb = within.map_or(rb, |w| (rb.0.max(w.0), rb.1.min(w.1)));
    let (h0, h1) = (r.height(y0), r.height(y1));
    let top = h0.min(h1) - r.tol;
    for &e in edges {
        let (a, b) = (g.pos[e.0 as usize], g.pos[e.1 as usize]);
        if light.height(a) <= 0.0 && light.height(b) <= 0.0 {
            continue;
        }
        // The edge's part above the receiver's plane, of an edge that rises above it by
        // more than the tolerance (as VE traces take them).
        let (ha, hb) = (r.height(a), r.height(b));
        if ha.max(hb) <= r.tol {
            continue;
        }
        let Some((a, b)) = part_above(a, b, ha, hb) else { continue };
        // Its shadow's box: unbounded (the receiver's own box) when a part reaches the
        // lower light end's height.
        let shadow = if r.height(a) >= top || r.height(b) >= top {
            rb
        } else {
            let mut lo = DVec2::splat(f64::INFINITY);
            let mut hi = DVec2::splat(f64::NEG_INFINITY);
            for (y, hy) in [(y0, h0), (y1, h1)] {
                for x in [a, b] {
                    let q = r.to2(y + (x - y) * (hy / (hy - r.height(x))));
                    (lo, hi) = (lo.min(q), hi.max(q));
                }
            }
            (lo.max(rb.0), hi.min(rb.1))
        };
        if shadow.0.cmpgt(shadow.1 + r.tol).any() {
            continue;
        }
        let silhouette = silhouette_parts(g, (y0, y1), e, r.tol);
        if !silhouette.is_empty() {
            out.push(Candidate { edge: e, shadow, silhouette });
        }
    }
}

/// Whether two edges share no vertex (edges at one vertex make its EV surface, no EEE).
fn apart(a: EdgeKey, b: EdgeKey) -> bool {
    a.0 != b.0 && a.0 != b.1 && a.1 != b.0 && a.1 != b.1
}

/// Whether, for some `s`, the plane through `y(s)` and one edge separates the other edge's
/// ends, for both edges: only then can a line from the light edge meet both segments. The
/// sides are linear in `s`, so it is decided at the ends.
fn may_meet(lines: &Lines) -> bool {
    let crosses = |other: usize, e: &[DVec3; 2]| -> Option<(f64, f64)> {
        // Parameters where e's ends lie on opposite sides of the other edge's plane.
        let f = |c: DVec3, s: f64| lines.passes(s, c, other);
        let (a0, a1, b0, b1) = (f(e[0], 0.0), f(e[0], 1.0), f(e[1], 0.0), f(e[1], 1.0));
        // g(s) = fa(s) · fb(s) < 0 somewhere in [0, 1]: both linear; test at the ends and
        // at their roots.
        let (mut ss, mut n) = ([0.0, 1.0, 0.0, 0.0], 2);
        for (p, q) in [(a0, a1), (b0, b1)] {
            if (p > 0.0) != (q > 0.0) {
                ss[n] = p / (p - q);
                n += 1;
            }
        }
        let ss = &mut ss[..n];
        ss.sort_by(f64::total_cmp);
        let lerp = |p: f64, q: f64, s: f64| p + (q - p) * s;
        let neg = |s: f64| lerp(a0, a1, s) * lerp(b0, b1, s) < 0.0;
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for w in ss.windows(2) {
            for s in [w[0], 0.5 * (w[0] + w[1]), w[1]] {
                if neg(s) {
                    lo = lo.min(w[0]);
                    hi = hi.max(w[1]);
                }
            }
        }
        (lo <= hi).then_some((lo, hi))
    };
    match (crosses(1, &lines.e1), crosses(0, &lines.e2)) {
        (Some(a), Some(b)) => a.0 <= b.1 && b.0 <= a.1,
        _ => false,
    }
}

/// The EEE surfaces of the pairs of `cands` (one at least from `first`, the rest from
/// `cands`; every pair of `cands` when `first` is `None`) with light edge `li`, each part
/// intersected with `blockers`, appended to `out`. Pairs whose shadow boxes miss each other
/// are passed over by a sweep along the boxes' x.
#[allow(clippy::too_many_arguments)] // the light edge, its candidates and the receiver's blockers, as the straight traces take them
pub fn surfaces(g: &Geometry, light: &LightPlane, r: &Receiver, li: u32, edge: (DVec3, DVec3), cands: &[Candidate], first: Option<&[Candidate]>, blockers: &Runs, out: &mut Vec<EeeSurface>) {
    let mut one = |c1: &Candidate, c2: &Candidate| {
        let (c1, c2) = if c1.edge < c2.edge { (c1, c2) } else { (c2, c1) };
        let (e1, e2) = (c1.edge, c2.edge);
        if !apart(e1, e2) || c1.shadow.0.y > c2.shadow.1.y + r.tol || c2.shadow.0.y > c1.shadow.1.y + r.tol {
            return;
        }
        let lines = Lines::new(g, edge, e1, e2);
        if !may_meet(&lines) {
            return;
        }
        for part in parts(light, r, &lines, c1, c2) {
            let shadow = (c1.shadow.0.max(c2.shadow.0) - r.tol, c1.shadow.1.min(c2.shadow.1) + r.tol);
            let mut s = EeeSurface::new(r, &lines, li, (e1, e2), part, shadow);
            let pencils = Pencils::new(&lines, r, part);
            let mut hidden = Vec::new();
            s.hide_all(g, r, &lines, &pencils, blockers, &mut hidden);
            sort_hidden(&mut hidden);
            s.hidden = hidden;
            out.push(s);
        }
    };
    // Both lists by the shadows' least x; a pair is looked at from its member that starts
    // first, over the other list's members that start before its end.
    fn by_x(v: &[Candidate]) -> Vec<&Candidate> {
        let mut v: Vec<&Candidate> = v.iter().collect();
        v.sort_by(|a, b| a.shadow.0.x.total_cmp(&b.shadow.0.x));
        v
    }
    let tol = r.tol;
    let sweep = |a: &[&Candidate], b: &[&Candidate], same: bool, one: &mut dyn FnMut(&Candidate, &Candidate)| {
        // Each a[i] with the b[j] whose start lies in [a[i]'s start, a[i]'s end]; when the
        // lists differ, also the other way round (b[j] starting first).
        let mut from = 0;
        for (i, x) in a.iter().enumerate() {
            while from < b.len() && b[from].shadow.0.x < x.shadow.0.x {
                from += 1;
            }
            let start = if same { i + 1 } else { from };
            for y in &b[start.max(from)..] {
                if y.shadow.0.x > x.shadow.1.x + tol {
                    break;
                }
                one(x, y);
            }
        }
    };
    match first {
        None => {
            let a = by_x(cands);
            sweep(&a, &a, true, &mut one);
        }
        Some(first) => {
            let (f, c) = (by_x(first), by_x(cands));
            sweep(&f, &f, true, &mut one);
            sweep(&f, &c, false, &mut one);
            // The rest's members that start strictly before a member of `first`.
            let mut pairs = |y: &Candidate, x: &Candidate| one(x, y);
            let mut from = 0;
            for x in &c {
                while from < f.len() && f[from].shadow.0.x <= x.shadow.0.x {
                    from += 1;
                }
                for y in &f[from..] {
                    if y.shadow.0.x > x.shadow.1.x + tol {
                        break;
                    }
                    pairs(y, x);
                }
            }
        }
    }
}

/// The edges of some triangles, sorted, no repeats.
pub fn edges_of(g: &Geometry, tris: &[u32]) -> Vec<EdgeKey> {
    let mut edges: Vec<EdgeKey> = tris
        .iter()
        .flat_map(|t| {
            let v = g.tris[*t as usize];
            [edge_key(v[0], v[1]), edge_key(v[1], v[2]), edge_key(v[2], v[0])]
        })
        .collect();
    edges.sort_unstable();
    edges.dedup();
    edges
}

/// Every EEE surface on a receiver: per light edge above it, every pair of the blockers'
/// candidate edges, intersected with every blocker.
pub fn receiver_surfaces(g: &Geometry, light: &LightPlane, above: &LightAbove, r: &Receiver, blockers: &[u32]) -> Vec<EeeSurface> {
    let edges = edges_of(g, blockers);
    let mut out = Vec::new();
    let mut cands = Vec::new();
    let mut runs = None;
    for (li, e) in above.edges.iter().enumerate() {
        let Some(e) = *e else { continue };
        cands.clear();
        candidates(g, light, r, e, &edges, None, &mut cands);
        if cands.len() < 2 {
            continue;
        }
        // In curve order for a long list (the intervals are sorted after, so the order does
        // not change them): under the grid over the dragon the list's runs are strips of the
        // scan, and a surface's pencils passed over few of them.
        let runs = runs.get_or_insert_with(|| Runs::for_traces(g, blockers, cands.len()));
        surfaces(g, light, r, li as u32, e, &cands, None, runs, &mut out);
    }
    canonical_order(&mut out);
    out
}

/// Surfaces in one order whatever found them (by generator, then part).
pub fn canonical_order(s: &mut [EeeSurface]) {
    s.sort_by(|a, b| (a.light_edge, a.edges).cmp(&(b.light_edge, b.edges)).then(a.part.0.total_cmp(&b.part.0)));
}
