//! Discontinuity segments on one receiver face from one area light (paper 002 §2, after
//! Drettakis and Fiume's complete discontinuity mesh): the traces of the EV surfaces with
//! the vertex or the edge on the light (the EEE surfaces are [`super::eee`]'s, the
//! blockers' contacts with the receiver [`contacts`]),
//!
//! - **VE** — light corner `v` × blocker edge `ab`: the fan of rays from `v` through `ab`,
//!   beyond it; a discontinuity where `ab` is a silhouette seen from `v` (the triangles at
//!   `ab` all lie on one side of the plane `v a b`), because there `v` appears or vanishes
//!   behind the blocker;
//! - **EV** — light edge `l` × blocker vertex `w`: the rays from points of `l` through `w`,
//!   beyond it; a discontinuity for the points of `l` from which `w` is on its object's
//!   outline (one of its edges a silhouette), because there `w`'s shadow crosses `l`;
//!
//! each clipped to the receiver triangle and then by **1D visibility** (paper 002 §3.3:
//! the surface's intersections sorted along it): a point of a trace is kept only if its
//! generating line, from the receiver through the blocker to the light, meets no other
//! triangle. The occluders of one surface are found in its fan triangle(s) and projected
//! from the fan's apex onto the trace, which is an interval computation.
use super::geometry::{edge_key, union_of, EdgeKey, Geometry};
use super::receiver::{LightAbove, Receiver};
use edgepoint_scene::backprojection::{LightPlane, LIGHT_GAP};
use glam::{DVec2, DVec3};

/// What generates a segment. Vertex ids are [`Geometry`] ids; light corners and edges are
/// indices into the light's corners (edge `i` runs from corner `i` to `i + 1`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Generator {
    Ve { light_vertex: u32, edge: EdgeKey },
    Ev { light_edge: u32, vertex: u32 },
    /// Light edge × two blocker edges, the smaller key first ([`super::eee`]).
    Eee { light_edge: u32, edges: (EdgeKey, EdgeKey) },
    /// Where blocker triangle `tri` passes through the receiver's plane ([`contacts`]).
    Contact { tri: u32 },
}

impl Generator {
    /// Whether the generator involves vertex `v` of the scene.
    pub fn uses_vertex(&self, v: u32) -> bool {
        match *self {
            Generator::Ve { edge, .. } => edge.0 == v || edge.1 == v,
            Generator::Ev { vertex, .. } => vertex == v,
            Generator::Eee { edges: (a, b), .. } => a.0 == v || a.1 == v || b.0 == v || b.1 == v,
            // Contacts are made again from the blockers whenever the segments are (none is
            // kept through a move), so they are never looked up by vertex.
            Generator::Contact { .. } => false,
        }
    }
}

/// A visible discontinuity segment in the receiver's 2D frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub generator: Generator,
    pub a: DVec2,
    pub b: DVec2,
}

/// A surface's trace on the receiver before visibility: the segment and the fan of
/// generating lines (apex and, for EV, the light-side triangle too).
#[derive(Debug, Clone, Copy)]
pub struct Trace {
    pub generator: Generator,
    /// 2D ends on the receiver.
    pub a: DVec2,
    pub b: DVec2,
    /// The fan's apex: the light corner (VE) or the blocker vertex (EV).
    pub apex: DVec3,
    /// EV: the light-edge points of the lines through `a` and `b` (pulled back by
    /// `LIGHT_GAP` so that the light's own fixture does not hide them).
    pub light_side: Option<(DVec3, DVec3)>,
}

/// Keeps the part of `[t0, t1]` where the affine `f(t) = f0 + t (f1 − f0)` is positive.
fn keep_positive(t: (f64, f64), f0: f64, f1: f64) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = t;
    let d = f1 - f0;
    if d.abs() < 1e-300 {
        return (f0 > 0.0).then_some((t0, t1));
    }
    let z = -f0 / d;
    if d > 0.0 {
        t0 = t0.max(z);
    } else {
        t1 = t1.min(z);
    }
    (t1 > t0).then_some((t0, t1))
}

/// Whether the points `others` lie on one side of the plane through `p` with normal `m`
/// (points within `tol` of it count for either side).
fn one_side(p: DVec3, m: DVec3, others: impl Iterator<Item = DVec3>, tol: f64) -> bool {
    let m = match m.try_normalize() {
        Some(m) => m,
        None => return false,
    };
    let (mut pos, mut neg) = (false, false);
    for c in others {
        let d = m.dot(c - p);
        pos |= d > tol;
        neg |= d < -tol;
    }
    !(pos && neg)
}

/// The VE trace of light corner `v` and blocker edge `(ia, ib)`, or `None` when the edge is
/// no silhouette from `v` or its shadow misses the receiver.
pub fn ve_trace(g: &Geometry, light: &LightPlane, r: &Receiver, li: u32, v: DVec3, edge: EdgeKey) -> Option<Trace> {
    let (pa, pb) = ve_ends(g, light, r, v, edge)?;
    // The silhouette test last: most edges' shadows miss a given receiver.
    if !is_silhouette(g, v, edge, r.tol) {
        return None;
    }
    Some(ve_trace_unchecked(li, v, edge, pa, pb))
}

/// Whether blocker edge `edge` is a silhouette seen from `v`: its triangles lie on one side
/// of the plane through `v` and the edge.
pub fn is_silhouette(g: &Geometry, v: DVec3, edge: EdgeKey, tol: f64) -> bool {
    let (a, b) = (g.pos[edge.0 as usize], g.pos[edge.1 as usize]);
    let m = (a - v).cross(b - v);
    let Some(tris) = g.edge_tris.get(&edge) else { return false };
    let third = tris.iter().flat_map(|t| g.tris[*t as usize]).filter(|x| *x != edge.0 && *x != edge.1).map(|x| g.pos[x as usize]);
    one_side(v, m, third, tol)
}

/// The ends on the receiver of the shadow of `edge` from light corner `v`, or `None` when it
/// misses the receiver.
fn ve_ends(g: &Geometry, light: &LightPlane, r: &Receiver, v: DVec3, edge: EdgeKey) -> Option<(DVec2, DVec2)> {
    let (a, b) = (g.pos[edge.0 as usize], g.pos[edge.1 as usize]);
    let hv = r.height(v);
    let (ha, hb) = (r.height(a), r.height(b));
    // Between the receiver's plane and the light corner's height, and in front of the light.
    // The edge's part above the receiver's plane, of an edge that rises above it by more
    // than the tolerance: clipped at the plane itself, so that the trace of an edge through
    // the plane starts where the blocker's contact with it ends ([`contacts`]).
    if ha.max(hb) <= r.tol {
        return None;
    }
    let t = keep_positive((0.0, 1.0), ha, hb)?;
    let t = keep_positive(t, hv - ha - r.tol, hv - hb - r.tol)?;
    let t = keep_positive(t, light.height(a), light.height(b))?;
    let map = |t: f64| {
        let x = a + (b - a) * t;
        r.to2(v + (x - v) * (hv / (hv - r.height(x))))
    };
    let (p0, p1) = (map(t.0), map(t.1));
    let (s0, s1) = r.clip_segment(p0, p1)?;
    let (pa, pb) = (p0.lerp(p1, s0), p0.lerp(p1, s1));
    if pa.distance(pb) <= r.tol {
        return None;
    }
    Some((pa, pb))
}

/// The VE trace with ends `pa pb`, its edge known to be a silhouette from `v`.
fn ve_trace_unchecked(li: u32, v: DVec3, edge: EdgeKey, pa: DVec2, pb: DVec2) -> Trace {
    Trace { generator: Generator::Ve { light_vertex: li, edge }, a: pa, b: pb, apex: v, light_side: None }
}

/// Whether blocker vertex `w` lies on its object's outline seen from `y`: one of its edges
/// is a silhouette from `y` (the triangles at the edge on one side of the plane through `y`
/// and the edge) or a boundary.
pub fn on_outline(g: &Geometry, w: u32, y: DVec3, tol: f64) -> bool {
    let wp = g.pos[w as usize];
    g.neighbours[w as usize].iter().any(|&x| {
        let key = edge_key(w, x);
        let Some(tris) = g.edge_tris.get(&key) else { return false };
        let xp = g.pos[x as usize];
        let third = tris.iter().flat_map(|t| g.tris[*t as usize]).filter(|c| *c != w && *c != x).map(|c| g.pos[c as usize]);
        one_side(y, (wp - y).cross(xp - y), third, tol)
    })
}

/// The parts of light edge `y0 y1` from which `w` is on its object's outline: the edge is
/// cut where it crosses the planes of `w`'s triangles (only there can an edge at `w` turn
/// into or out of a silhouette) and each piece is tested at its middle.
pub fn outline_parts(g: &Geometry, w: u32, y0: DVec3, y1: DVec3, tol: f64, out: &mut Vec<(f64, f64)>) {
    out.clear();
    let mut cuts = vec![0.0, 1.0];
    let wp = g.pos[w as usize];
    for &x in &g.neighbours[w as usize] {
        if let Some(tris) = g.edge_tris.get(&edge_key(w, x)) {
            for t in tris {
                let [a, b, c] = g.tri(*t);
                if let Some(n) = (b - a).cross(c - a).try_normalize() {
                    let (d0, d1) = (n.dot(y0 - wp), n.dot(y1 - wp));
                    if (d0 > 0.0) != (d1 > 0.0) {
                        cuts.push(d0 / (d0 - d1));
                    }
                }
            }
        }
    }
    cuts.sort_by(f64::total_cmp);
    for c in cuts.windows(2) {
        if c[1] - c[0] <= 1e-12 {
            continue;
        }
        let mid = y0 + (y1 - y0) * (0.5 * (c[0] + c[1]));
        if on_outline(g, w, mid, tol) {
            match out.last_mut() {
                Some(last) if (last.1 - c[0]).abs() <= 1e-12 => last.1 = c[1],
                _ => out.push((c[0], c[1])),
            }
        }
    }
}

/// The EV traces of light edge `li` (its part above the receiver, `y0 y1`) and blocker
/// vertex `w`: one per part of the edge from which `w` is on the outline and whose shadow
/// reaches the receiver.
#[allow(clippy::too_many_arguments)] // the caller's scratch (parts) and output are passed in, reused across traces
pub fn ev_traces(g: &Geometry, light: &LightPlane, r: &Receiver, li: u32, (y0, y1): (DVec3, DVec3), w: u32, parts: &mut Vec<(f64, f64)>, out: &mut Vec<Trace>) {
    let wp = g.pos[w as usize];
    let hw = r.height(wp);
    if hw <= r.tol || light.height(wp) <= 0.0 {
        return;
    }
    // Whether the shadow of w from the whole edge reaches the receiver at all, before the
    // outline test (most vertices' shadows miss a given receiver).
    {
        let Some(t) = keep_positive((0.0, 1.0), r.height(y0) - hw - r.tol, r.height(y1) - hw - r.tol) else { return };
        let map = |t: f64| {
            let y = y0 + (y1 - y0) * t;
            let hy = r.height(y);
            r.to2(y + (wp - y) * (hy / (hy - hw)))
        };
        if r.clip_segment(map(t.0), map(t.1)).is_none() {
            return;
        }
    }
    outline_parts(g, w, y0, y1, r.tol, parts);
    for &part in parts.iter() {
        let Some(t) = keep_positive(part, r.height(y0) - hw - r.tol, r.height(y1) - hw - r.tol) else { continue };
        let map = |t: f64| {
            let y = y0 + (y1 - y0) * t;
            let hy = r.height(y);
            r.to2(y + (wp - y) * (hy / (hy - hw)))
        };
        let (p0, p1) = (map(t.0), map(t.1));
        let Some((s0, s1)) = r.clip_segment(p0, p1) else { continue };
        let (pa, pb) = (p0.lerp(p1, s0), p0.lerp(p1, s1));
        if pa.distance(pb) <= r.tol {
            continue;
        }
        // The light-edge end of the line from a receiver point through w.
        let back = |q: DVec2| {
            let p = r.to3(q);
            let (hp, hw) = (light.height(p), light.height(wp));
            let y = p + (wp - p) * (hp / (hp - hw));
            p + (y - p) * (1.0 - LIGHT_GAP)
        };
        out.push(Trace { generator: Generator::Ev { light_edge: li, vertex: w }, a: pa, b: pb, apex: wp, light_side: Some((back(pa), back(pb))) });
    }
}

/// The edges of some triangles (a moved object's) that are silhouettes seen from each corner
/// of a light ([`is_silhouette`], which depends on the corner and the edge only, not on the
/// receiver): found once for a move and a light instead of once per receiver, they spare
/// the receivers the test of every edge whose shadow reaches them.
#[derive(Debug, Clone)]
pub struct Silhouettes {
    /// Per light corner, sorted.
    per_corner: Vec<Vec<EdgeKey>>,
}

impl Silhouettes {
    pub fn new(g: &Geometry, light: &LightPlane, tris: std::ops::Range<u32>, tol: f64) -> Silhouettes {
        let mut edges: Vec<EdgeKey> = tris.flat_map(|t| {
            let v = g.tris[t as usize];
            [edge_key(v[0], v[1]), edge_key(v[1], v[2]), edge_key(v[2], v[0])]
        }).collect();
        edges.sort_unstable();
        edges.dedup();
        let per_corner = light.corners.iter().map(|q| {
            let v = light.lift(*q);
            edges.iter().copied().filter(|e| is_silhouette(g, v, *e, tol)).collect()
        }).collect();
        Silhouettes { per_corner }
    }
}

/// Every trace on the receiver: VE for each light corner above it and each edge of the
/// blockers, EV for each light edge above it and each blocker vertex.
pub fn traces(g: &Geometry, light: &LightPlane, above: &LightAbove, r: &Receiver, blockers: &[u32], out: &mut Vec<Trace>) {
    traces_with(g, light, above, r, blockers, None, out);
}

/// [`traces`], with the blockers' silhouette edges from each light corner given when they
/// are known (`silhouettes`, made from triangles that include `blockers`, with the
/// receiver's tolerance): only those are traced for VE.
pub fn traces_with(g: &Geometry, light: &LightPlane, above: &LightAbove, r: &Receiver, blockers: &[u32], silhouettes: Option<&Silhouettes>, out: &mut Vec<Trace>) {
    out.clear();
    let mut edges: Vec<EdgeKey> = Vec::with_capacity(blockers.len() * 3);
    let mut verts: Vec<u32> = Vec::with_capacity(blockers.len() * 3);
    for &t in blockers {
        let v = g.tris[t as usize];
        for k in 0..3 {
            edges.push(edge_key(v[k], v[(k + 1) % 3]));
            verts.push(v[k]);
        }
    }
    edges.sort_unstable();
    edges.dedup();
    verts.sort_unstable();
    verts.dedup();
    for (li, v) in above.vertices.iter().enumerate() {
        let Some(v) = *v else { continue };
        match silhouettes {
            Some(s) => {
                let sil = &s.per_corner[li];
                out.extend(edges.iter().filter(|e| sil.binary_search(e).is_ok()).filter_map(|e| {
                    let (pa, pb) = ve_ends(g, light, r, v, *e)?;
                    Some(ve_trace_unchecked(li as u32, v, *e, pa, pb))
                }));
            }
            None => out.extend(edges.iter().filter_map(|e| ve_trace(g, light, r, li as u32, v, *e))),
        }
    }
    let mut parts = Vec::new();
    for (li, e) in above.edges.iter().enumerate() {
        let Some(e) = *e else { continue };
        for w in &verts {
            ev_traces(g, light, r, li as u32, e, *w, &mut parts, out);
        }
    }
}

/// The segments where blockers pass through the receiver's plane, inside the receiver
/// triangle (paper 002 §2's mesh holds the receiver's intersections with the other
/// polygons): on one side the blocker stands above the receiver and may hide the light
/// right up to the line, on the other it is below and hides nothing — a discontinuity that
/// no surface of the light makes. The traces of the blocker's edges (VE, EEE) start on it
/// and the hidden parts of other traces end on it: all are clipped at the plane itself (at
/// the tolerance's height a shallow edge left a gap of a few tolerances between them, through
/// which one face joined the blocker's umbra to the light beside it). `blockers` sorted;
/// appended to `out` in their order.
pub fn contacts(g: &Geometry, r: &Receiver, blockers: &[u32], out: &mut Vec<Segment>) {
    for &t in blockers {
        let tri = g.tri(t);
        let h = tri.map(|p| r.height(p));
        if !(h.iter().any(|x| *x > r.tol) && h.iter().any(|x| *x < -r.tol)) {
            continue;
        }
        let Some(q) = r.plane_crossing(&tri).map(|c| c.map(|p| r.to2(p))) else { continue };
        let Some((s0, s1)) = r.clip_segment(q[0], q[1]) else { continue };
        let (a, b) = (q[0].lerp(q[1], s0), q[0].lerp(q[1], s1));
        if a.distance(b) > r.tol {
            out.push(Segment { generator: Generator::Contact { tri: t }, a, b });
        }
    }
}

/// Whether triangle `t` is one of the generator's own (it touches the fan along the edge or
/// at the vertex, which is no occlusion).
fn is_own(g: &Geometry, gen: &Generator, t: u32) -> bool {
    let v = g.tris[t as usize];
    match *gen {
        Generator::Ve { edge, .. } => v.contains(&edge.0) && v.contains(&edge.1),
        Generator::Ev { vertex, .. } => v.contains(&vertex),
        Generator::Eee { edges: (a, b), .. } => (v.contains(&a.0) && v.contains(&a.1)) || (v.contains(&b.0) && v.contains(&b.1)),
        Generator::Contact { tri } => tri == t,
    }
}

/// The parameters along the trace `p0 p1` (3D) hidden by triangle `tri` within the convex
/// `region` of the fan's plane (lines through `c`), projected from `c`.
fn hidden_in_fan(c: DVec3, region: &[DVec3], p0: DVec3, p1: DVec3, tri: &[DVec3; 3], tol: f64) -> Option<(f64, f64)> {
    let m = (region[1] - region[0]).cross(region[2] - region[0]).try_normalize()?;
    let d = tri.map(|x| m.dot(x - c));
    if d.iter().all(|x| *x >= -tol) || d.iter().all(|x| *x <= tol) {
        return None; // on one side, touching at most
    }
    // The segment where the triangle crosses the fan's plane.
    let mut q = [DVec3::ZERO; 2];
    let mut n = 0;
    for k in 0..3 {
        let (i, j) = (k, (k + 1) % 3);
        if (d[i] > 0.0) != (d[j] > 0.0) && n < 2 {
            q[n] = tri[i] + (tri[j] - tri[i]) * (d[i] / (d[i] - d[j]));
            n += 1;
        }
    }
    if n < 2 {
        return None;
    }
    // Clip it to the region, side by side.
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    let k = region.len();
    let inner = region.iter().sum::<DVec3>() / k as f64;
    for i in 0..k {
        let (a, b) = (region[i], region[(i + 1) % k]);
        let side = |x: DVec3| (b - a).cross(x - a).dot(m);
        let s = side(inner).signum();
        (t0, t1) = keep_positive((t0, t1), side(q[0]) * s, side(q[1]) * s)?;
    }
    let (x0, x1) = (q[0] + (q[1] - q[0]) * t0, q[0] + (q[1] - q[0]) * t1);
    if x0.distance(x1) <= tol {
        return None;
    }
    let proj = |x: DVec3| {
        let dx = x - c;
        let den = (p1 - p0).cross(dx).dot(m);
        (den.abs() > 1e-300).then(|| -(p0 - c).cross(dx).dot(m) / den)
    };
    let (s0, s1) = (proj(x0)?, proj(x1)?);
    Some((s0.min(s1), s0.max(s1)))
}

/// A trace with its intersection list (paper 002 §3.3): the parameter intervals along it
/// hidden by each blocker triangle, kept so that a move re-intersects only the moved
/// object's triangles.
#[derive(Debug, Clone)]
pub struct TraceVis {
    pub trace: Trace,
    pub hidden: Vec<(u32, f64, f64)>,
}

/// The box of a trace's surface: the fan from its apex over the trace and, for EV, up to
/// the light edge; every triangle that hides part of the trace meets it.
pub fn fan_box(r: &Receiver, t: &Trace) -> (DVec3, DVec3) {
    let (p0, p1) = (r.to3(t.a), r.to3(t.b));
    let (mut lo, mut hi) = (t.apex.min(p0).min(p1), t.apex.max(p0).max(p1));
    if let Some((y0, y1)) = t.light_side {
        (lo, hi) = (lo.min(y0).min(y1), hi.max(y0).max(y1));
    }
    (lo, hi)
}

/// Appends the intervals of `trace` that triangle `t` hides (none for its own triangles).
pub fn hide(g: &Geometry, r: &Receiver, trace: &Trace, t: u32, out: &mut Vec<(u32, f64, f64)>) {
    hide_in_box(g, r, trace, fan_box(r, trace), t, out);
}

/// [`hide`] with the trace's [`fan_box`] given: a triangle missing it (by more than the
/// tolerance) meets no part of the fan and is passed over before any plane test.
pub fn hide_in_box(g: &Geometry, r: &Receiver, trace: &Trace, (lo, hi): (DVec3, DVec3), t: u32, out: &mut Vec<(u32, f64, f64)>) {
    let tri = g.tri(t);
    let (tlo, thi) = (tri[0].min(tri[1]).min(tri[2]), tri[0].max(tri[1]).max(tri[2]));
    if tlo.cmpgt(hi + r.tol).any() || thi.cmplt(lo - r.tol).any() || is_own(g, &trace.generator, t) {
        return;
    }
    let (p0, p1) = (r.to3(trace.a), r.to3(trace.b));
    let c = trace.apex;
    match trace.light_side {
        // VE: the fan from the light corner, short of it by `LIGHT_GAP` (the light's own
        // fixture touches it there, and the pointwise backprojection ignores it too).
        None => {
            let (a, b) = (c + (p0 - c) * LIGHT_GAP, c + (p1 - c) * LIGHT_GAP);
            if let Some(h) = hidden_in_fan(c, &[a, p0, p1, b], p0, p1, &tri, r.tol) {
                out.push((t, h.0, h.1));
            }
        }
        // EV: the fan below the blocker vertex and the one above it, to the light edge.
        Some((y0, y1)) => {
            for region in [[c, p0, p1], [c, y0, y1]] {
                if let Some(h) = hidden_in_fan(c, &region, p0, p1, &tri, r.tol) {
                    out.push((t, h.0, h.1));
                }
            }
        }
    }
}

/// A receiver's blockers for the intersection of many fans: in runs of [`RUN`] triangles
/// that lie close together, each run with its box, and runs grouped [`FANOUT`] to a box level
/// by level (an implicit tree of fan-out 16 over the runs). A fan's box and plane are tested
/// against a group's box before the group's runs, and against a run's box before its
/// triangles: a fan is thin, so most groups lie on one side of its plane.
///
/// Long lists for many fans ([`Runs::for_traces`]) are ordered along a Morton curve of their triangles'
/// centroids (quantised in the blockers' box) so that a run is a small patch whatever order
/// the list came in. In index
/// order a run was a strip of the mesh, which is tight for the built-in scenes' boxes and
/// planes but not for a scanned mesh: under the grid over the dragon a receiver's fans each
/// met ~84,000 triangles' boxes, 70 % of them within the fan's box, of which 0.02 % hid part
/// of it. A flat list of runs would still cost a box test per run per fan, which is most of
/// the work for a receiver with 10⁵ blockers.
#[derive(Debug, Clone)]
pub struct Runs {
    /// The triangles, in curve order for long lists.
    tris: Vec<u32>,
    /// `levels[0]`: one box per run; `levels[k]`: one per [`FANOUT`] boxes of level `k - 1`;
    /// the last level holds at most [`FANOUT`] boxes.
    levels: Vec<Vec<(DVec3, DVec3)>>,
}

pub const RUN: usize = 16;
/// Blocker lists at least this long are put in curve order for at least
/// [`CURVE_ORDER_TRACES`] fans: sorting costs about as much as 20 box tests a triangle, a
/// flat scan of the runs one per run and fan. (Sorting every long list made the recasting
/// of a chair's few traces on `rooms` 25–28 → 31–34 ms of CPU a move: its lists are built-in
/// shapes listed strip by strip, tight runs already.)
pub const CURVE_ORDER_FROM: usize = 16384;
pub const CURVE_ORDER_TRACES: usize = 256;
/// Boxes of one level under one box of the next.
pub const FANOUT: usize = 16;

/// Interleaves the low 10 bits of `v` with two zero bits between each.
fn spread(v: u32) -> u64 {
    let mut x = (v & 0x3ff) as u64;
    x = (x | x << 16) & 0x0300_00ff;
    x = (x | x << 8) & 0x0300_f00f;
    x = (x | x << 4) & 0x030c_30c3;
    (x | x << 2) & 0x0924_9249
}

impl Runs {
    /// The runs of `tris` for `traces` fans: in curve order when the list is long
    /// ([`CURVE_ORDER_FROM`]) and the fans many ([`CURVE_ORDER_TRACES`]), else in list order.
    pub fn for_traces(g: &Geometry, tris: &[u32], traces: usize) -> Runs {
        Runs::new(g, tris, tris.len() >= CURVE_ORDER_FROM && traces >= CURVE_ORDER_TRACES)
    }

    /// The runs of `tris`, in curve order if `curve`.
    pub fn new(g: &Geometry, tris: &[u32], curve: bool) -> Runs {
        let (tris, runs) = if !curve {
            let runs = tris.chunks(RUN).map(|c| union_of(c.iter().map(|t| g.tri_bounds(*t))));
            (tris.to_vec(), runs.collect::<Vec<_>>())
        } else {
            let boxes: Vec<(DVec3, DVec3)> = tris.iter().map(|t| g.tri_bounds(*t)).collect();
            let (lo, hi) = union_of(boxes.iter().copied());
            let scale = 1023.0 / (hi - lo).max(DVec3::splat(1e-300));
            let mut keyed: Vec<(u64, u32, u32)> = boxes
                .iter()
                .enumerate()
                .map(|(i, b)| {
                    let q = (((b.0 + b.1) * 0.5 - lo) * scale).clamp(DVec3::ZERO, DVec3::splat(1023.0));
                    (spread(q.x as u32) | spread(q.y as u32) << 1 | spread(q.z as u32) << 2, tris[i], i as u32)
                })
                .collect();
            keyed.sort_unstable();
            let ordered: Vec<(DVec3, DVec3)> = keyed.iter().map(|k| boxes[k.2 as usize]).collect();
            (keyed.iter().map(|k| k.1).collect(), ordered.chunks(RUN).map(|c| union_of(c.iter().copied())).collect())
        };
        let mut levels = vec![runs];
        while levels.last().is_some_and(|l| l.len() > FANOUT) {
            let up = levels.last().expect("a level").chunks(FANOUT).map(|c| union_of(c.iter().copied())).collect();
            levels.push(up);
        }
        Runs { tris, levels }
    }

    /// Calls `f` on every triangle of the runs that may hold a triangle hiding part of
    /// `trace` (fan box `fan`, see [`hide_in_box`]), in no particular order (intersection
    /// lists are sorted after): a run is passed over when its box, or a box of a level above
    /// that holds it, misses the fan box grown by the tolerance or lies on one side of the
    /// plane of each of the fan's regions (a triangle on one side of a region's plane,
    /// touching it at most, hides nothing there).
    pub fn each_near(&self, r: &Receiver, trace: &Trace, (lo, hi): (DVec3, DVec3), mut f: impl FnMut(u32)) {
        if self.tris.is_empty() {
            return;
        }
        let regions = fan_regions(r, trace);
        self.walk(|step| match step {
            Step::Open(b) => box_near_fan(r, trace, &regions, (lo, hi), b),
            Step::Triangle(t) => {
                f(t);
                true
            }
        });
    }

    /// Walks the boxes and triangles depth first, in the runs' order: `f(Step::Open(box))`
    /// says whether to look inside a box (a group's or a run's), `f(Step::Triangle(t))`
    /// whether to go on (`false` ends the walk). With every box opened the triangles come in
    /// the runs' order, so a walk that opens fewer boxes and only skips triangles its test
    /// would have skipped one by one does what the flat loop does.
    pub fn walk(&self, mut f: impl FnMut(Step) -> bool) {
        if self.tris.is_empty() {
            return;
        }
        let top = self.levels.len() - 1;
        for i in 0..self.levels[top].len() {
            if !self.group(top, i, &mut f) {
                return;
            }
        }
    }

    /// Box `i` of `level` and what it holds, if `f` opens it; `false` when the walk ends.
    fn group(&self, level: usize, i: usize, f: &mut impl FnMut(Step) -> bool) -> bool {
        if !f(Step::Open(&self.levels[level][i])) {
            return true;
        }
        if level == 0 {
            return self.tris[i * RUN..((i + 1) * RUN).min(self.tris.len())].iter().all(|t| f(Step::Triangle(*t)));
        }
        (i * FANOUT..((i + 1) * FANOUT).min(self.levels[level - 1].len())).all(|j| self.group(level - 1, j, f))
    }
}

/// One step of [`Runs::walk`].
pub enum Step<'a> {
    /// A box of a group of runs or of one run, to open or pass over.
    Open(&'a (DVec3, DVec3)),
    Triangle(u32),
}

/// A region of a trace's fan ([`hide_in_box`]'s): the unit normal of its plane, as
/// [`hidden_in_fan`] computes it, and per side a point and the unit normal pointing inward.
struct FanRegion {
    m: DVec3,
    sides: [(DVec3, DVec3); 4],
    k: usize,
}

impl FanRegion {
    /// `None` for a degenerate region, which hides nothing.
    fn new(region: &[DVec3]) -> Option<FanRegion> {
        let m = (region[1] - region[0]).cross(region[2] - region[0]).try_normalize()?;
        let k = region.len();
        let inner = region.iter().sum::<DVec3>() / k as f64;
        let mut sides = [(DVec3::ZERO, DVec3::ZERO); 4];
        for i in 0..k {
            let (a, b) = (region[i], region[(i + 1) % k]);
            // ((b − a) × (x − a)) · m = (m × (b − a)) · (x − a): the side function there.
            let n = m.cross(b - a).normalize_or_zero();
            sides[i] = (a, if n.dot(inner - a) < 0.0 { -n } else { n });
        }
        Some(FanRegion { m, sides, k })
    }
}

/// Whether a triangle inside box `b` may hide part of `trace` (its fan's `regions`, its
/// [`fan_box`] `(lo, hi)`): `false` only when none can ([`hidden_in_fan`] finds nothing for
/// any of them).
fn box_near_fan(r: &Receiver, trace: &Trace, regions: &[Option<FanRegion>; 2], (lo, hi): (DVec3, DVec3), b: &(DVec3, DVec3)) -> bool {
    if b.0.cmpgt(hi + r.tol).any() || b.1.cmplt(lo - r.tol).any() {
        return false;
    }
    let c = trace.apex;
    let (mid, ext) = ((b.0 + b.1) * 0.5, (b.1 - b.0) * 0.5);
    // Near a region when the box reaches across its plane (its extreme heights over it; half
    // the tolerance to spare for the rounding of the corners' heights against those of the
    // triangles inside) and reaches inside each of its sides by more than the tolerance: a
    // triangle whose crossing of the plane stays outside a side, or within the tolerance of
    // it, hides nothing there (`hidden_in_fan`).
    regions.iter().flatten().any(|g| {
        let (d, e) = (g.m.dot(mid - c), g.m.abs().dot(ext));
        let across = d - e <= -0.5 * r.tol && d + e >= 0.5 * r.tol;
        across && g.sides[..g.k].iter().all(|(a, n)| n.dot(mid - *a) + n.abs().dot(ext) >= -r.tol)
    })
}

/// Whether some triangle inside box `b` may hide part of `trace` (its [`fan_box`] `fan`;
/// see [`box_near_fan`]): the update's test of a static trace against the motion volume,
/// finer than the boxes'.
pub fn fan_may_meet_box(r: &Receiver, trace: &Trace, fan: (DVec3, DVec3), b: (DVec3, DVec3)) -> bool {
    box_near_fan(r, trace, &fan_regions(r, trace), fan, &b)
}

/// The regions of a trace's fan, as [`hide_in_box`] passes them to [`hidden_in_fan`].
fn fan_regions(r: &Receiver, trace: &Trace) -> [Option<FanRegion>; 2] {
    let (p0, p1) = (r.to3(trace.a), r.to3(trace.b));
    let c = trace.apex;
    match trace.light_side {
        None => {
            let (a, b) = (c + (p0 - c) * LIGHT_GAP, c + (p1 - c) * LIGHT_GAP);
            [FanRegion::new(&[a, p0, p1, b]), None]
        }
        Some((y0, y1)) => [FanRegion::new(&[c, p0, p1]), FanRegion::new(&[c, y0, y1])],
    }
}

impl TraceVis {
    /// The trace with every blocker intersected (`blockers` in runs with their boxes: a
    /// triangle missing the fan box hides nothing of it, see [`hide_in_box`]).
    pub fn new(g: &Geometry, r: &Receiver, trace: Trace, blockers: &Runs) -> TraceVis {
        let mut hidden = Vec::new();
        let fan = fan_box(r, &trace);
        blockers.each_near(r, &trace, fan, |t| hide_in_box(g, r, &trace, fan, t, &mut hidden));
        sort_hidden(&mut hidden);
        TraceVis { trace, hidden }
    }

    /// The visible parts (1D visibility: the complement of the hidden intervals, which are
    /// kept sorted by start), appended to `out`.
    pub fn visible(&self, r: &Receiver, out: &mut Vec<Segment>) {
        let trace = &self.trace;
        let min = r.tol / trace.a.distance(trace.b);
        let mut at = 0.0f64;
        let mut emit = |s0: f64, s1: f64| {
            if s1 - s0 > min {
                out.push(Segment { generator: trace.generator, a: trace.a.lerp(trace.b, s0), b: trace.a.lerp(trace.b, s1) });
            }
        };
        for &(_, h0, h1) in &self.hidden {
            if h0 > at {
                emit(at, h0.min(1.0));
            }
            at = at.max(h1);
            if at >= 1.0 {
                break;
            }
        }
        if at < 1.0 {
            emit(at, 1.0);
        }
    }

    pub fn bytes(&self) -> usize {
        std::mem::size_of::<TraceVis>() + self.hidden.len() * 24
    }
}

/// Every trace on one receiver with its intersection list.
pub fn receiver_traces(g: &Geometry, light: &LightPlane, above: &LightAbove, r: &Receiver, blockers: &[u32]) -> Vec<TraceVis> {
    let mut tr = Vec::new();
    traces(g, light, above, r, blockers, &mut tr);
    let runs = Runs::for_traces(g, blockers, tr.len());
    let mut out: Vec<TraceVis> = tr.into_iter().map(|t| TraceVis::new(g, r, t, &runs)).collect();
    canonical_order(&mut out);
    out
}

/// An intersection list in the order 1D visibility walks it: by start, then end (then
/// triangle, so that the order does not depend on the order the triangles were tested in).
pub fn sort_hidden(hidden: &mut [(u32, f64, f64)]) {
    hidden.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.2.total_cmp(&b.2)).then(a.0.cmp(&b.0)));
}

/// Traces in one order whatever found them (by generator, then by where they start), so an
/// updated mesh lists its segments as a full computation does.
pub fn canonical_order(traces: &mut [TraceVis]) {
    traces.sort_by(|a, b| a.trace.generator.cmp(&b.trace.generator).then(a.trace.a.x.total_cmp(&b.trace.a.x)).then(a.trace.a.y.total_cmp(&b.trace.a.y)));
}
