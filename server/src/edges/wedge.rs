//! Event wedges against receiver faces (paper 000 §6.4 "Shadow edge computation": "each
//! shadow event is walked down the receiver's face tree to find intersections of the event
//! with the geometry").
//!
//! Every event's rays pass through one point `C`: the light point of a point or VE event,
//! the blocker vertex of an EV event. With `D0`, `D1` the directions of its first and last
//! ray, a point of the event's plane is `C + α D0 + β D1`, and `(α, β)` are the wedge's
//! *canonical coordinates*: ray `u` is the line through the origin along `(1 - u, u)`, and
//! `μ = α + β` grows along every ray away from the light. They are affine invariants, so
//! intersections found in different receivers' object spaces compare directly.
//!
//! - Point and VE events (fan at the light point): the light is at `μ = 0`, the blocker
//!   edge at `μ = 1`; `μ < 1` is the part between light and blocker (hits there hide the
//!   event: the blocker edge is not lit), `μ > 1` is where shadow edges lie.
//! - EV events (fan at the blocker vertex `w`): the light edge is at `μ = -1` (the
//!   quadrant `α, β ≤ 0`), `w` at `μ = 0`; shadow edges lie in `α, β ≥ 0`.
//!
//! Intersections are searched front to back along `μ` through the receiver's
//! [`FaceBvh`] and the search stops once the pieces found cover the whole wedge and every
//! unvisited node lies farther: only the first surface along each ray matters for the 1D
//! clipping of [`super::clip1d`], so a wedge costs about what a ray costs.
use super::events::{Generator, ShadowEvent};
use super::face_bvh::{Child, FaceBvh};
use crate::prefetch::prefetch;
use glam::{DAffine3, DVec2, DVec3, Vec3};
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// An event wedge in some object space.
#[derive(Debug, Clone, Copy)]
pub struct Wedge {
    pub c: DVec3,
    pub d0: DVec3,
    pub d1: DVec3,
    /// `μ` of the blocker (1 for point/VE events, 0 for EV events).
    pub mu_blocker: f64,
    /// EV event: the front part is the quadrant `α, β ≤ 0`.
    pub ev: bool,
    /// Unit plane normal.
    n: DVec3,
    /// `α(p) = (p - C) · ga`, `β(p) = (p - C) · gb` (extended off the plane).
    ga: DVec3,
    gb: DVec3,
    /// Points whose distance to the plane is below this count as on it.
    tol: f64,
}

/// A piece of the intersection of a wedge with one face, in canonical coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    pub a: DVec2,
    pub b: DVec2,
    /// Beyond the blocker (`μ` past the blocker), where shadow edges lie; otherwise between
    /// light and blocker, where it only hides.
    pub beyond: bool,
    /// Beyond the blocker on a face that faces the light: a shadow edge if the face belongs
    /// to a receiver of the event and nothing nearer hides it.
    pub output: bool,
}

impl Wedge {
    /// The event's wedge mapped by `to_space` (blocker object space → the space wanted).
    /// `None` for a degenerate event (zero-area fan).
    pub fn new(ev: &ShadowEvent, to_space: &DAffine3) -> Option<Wedge> {
        let p = |v: Vec3| to_space.transform_point3(v.as_dvec3());
        let (f0, f1, s0, s1) = (p(ev.f[0]), p(ev.f[1]), p(ev.s[0]), p(ev.s[1]));
        let (c, ev_fan) = match ev.generator {
            Generator::EV { .. } => (s0, true),
            Generator::Point { .. } | Generator::VE { .. } => (f0, false),
        };
        let (d0, d1) = (s0 - f0, s1 - f1);
        let m = d0.cross(d1);
        let m2 = m.length_squared();
        let scale = d0.length().max(d1.length());
        // (NaN fails the first test too.)
        if m2.is_nan() || m2 <= 0.0 || m2.sqrt() < 1e-12 * scale * scale {
            return None;
        }
        Some(Wedge {
            c,
            d0,
            d1,
            mu_blocker: if ev_fan { 0.0 } else { 1.0 },
            ev: ev_fan,
            n: m / m2.sqrt(),
            ga: d1.cross(m) / m2,
            gb: m.cross(d0) / m2,
            tol: 1e-10 * (scale + c.abs().max_element()),
        })
    }

    #[inline]
    pub fn coords(&self, p: DVec3) -> DVec2 {
        let r = p - self.c;
        DVec2::new(r.dot(self.ga), r.dot(self.gb))
    }

    #[inline]
    pub fn point(&self, q: DVec2) -> DVec3 {
        self.c + self.d0 * q.x + self.d1 * q.y
    }

    /// The light point(s) of the event: `C` for a fan at the light, the light edge's ends
    /// `C - D0`, `C - D1` otherwise. The second is `None` when there is one.
    pub fn light_points(&self) -> (DVec3, Option<DVec3>) {
        if self.ev {
            (self.c - self.d0, Some(self.c - self.d1))
        } else {
            (self.c, None)
        }
    }

    /// The segment where the plane cuts triangle `t`, in canonical coordinates, or `None`
    /// (no cut, a touching corner, or the triangle in the plane).
    pub fn cut(&self, t: &[Vec3; 3]) -> Option<(DVec2, DVec2)> {
        let p = t.map(|v| v.as_dvec3());
        let d = p.map(|v| {
            let x = (v - self.c).dot(self.n);
            if x.abs() <= self.tol {
                0.0
            } else {
                x
            }
        });
        let q = p.map(|v| self.coords(v));
        let mut pts: [DVec2; 2] = [DVec2::ZERO; 2];
        let mut k = 0;
        let zeros = d.iter().filter(|x| **x == 0.0).count();
        match zeros {
            3 => return None,
            2 => {
                for i in 0..3 {
                    if d[i] == 0.0 {
                        pts[k] = q[i];
                        k += 1;
                    }
                }
            }
            _ => {
                for i in 0..3 {
                    let j = (i + 1) % 3;
                    if d[i] == 0.0 {
                        pts[k.min(1)] = q[i];
                        k += 1;
                    } else if d[j] != 0.0 && (d[i] > 0.0) != (d[j] > 0.0) {
                        let s = d[i] / (d[i] - d[j]);
                        pts[k.min(1)] = q[i] + (q[j] - q[i]) * s;
                        k += 1;
                    }
                }
                if k != 2 {
                    return None;
                }
            }
        }
        (pts[0] != pts[1]).then_some((pts[0], pts[1]))
    }

    /// Clips a cut to the wedge and splits it at the blocker: up to two pieces (front,
    /// beyond), pushed to `out`; `facing` says the face faces the light.
    pub fn clip(&self, a: DVec2, b: DVec2, facing: bool, out: &mut Vec<Piece>) {
        let output = facing;
        // Quadrant α, β ≥ 0 (all of a point/VE wedge; the part beyond w of an EV wedge).
        if let Some((a1, b1)) = clip_halfplanes(a, b, &[(DVec2::new(1.0, 0.0), 0.0), (DVec2::new(0.0, 1.0), 0.0)]) {
            if self.ev {
                push(out, a1, b1, true, output);
            } else {
                // Split at μ = 1 (the blocker edge).
                let (ma, mb) = (a1.x + a1.y, b1.x + b1.y);
                if (ma - 1.0) * (mb - 1.0) < 0.0 {
                    let s = (1.0 - ma) / (mb - ma);
                    let m = a1 + (b1 - a1) * s;
                    push(out, a1, m, ma > 1.0, output);
                    push(out, m, b1, mb > 1.0, output);
                } else {
                    let beyond = ma + mb > 2.0;
                    push(out, a1, b1, beyond, output);
                }
            }
        }
        if self.ev {
            // The triangle between the light edge and w: α, β ≤ 0, α + β ≥ -1.
            let hp = [(DVec2::new(-1.0, 0.0), 0.0), (DVec2::new(0.0, -1.0), 0.0), (DVec2::new(1.0, 1.0), -1.0)];
            if let Some((a1, b1)) = clip_halfplanes(a, b, &hp) {
                push(out, a1, b1, false, false);
            }
        }
    }

    /// A segment clipped to the part of the wedge beyond the blocker (`α, β ≥ 0`, and
    /// `μ ≥ 1` for a fan at the light), or `None` if nothing is left.
    pub fn clip_beyond(&self, a: DVec2, b: DVec2) -> Option<(DVec2, DVec2)> {
        let quadrant = [(DVec2::new(1.0, 0.0), 0.0), (DVec2::new(0.0, 1.0), 0.0), (DVec2::new(1.0, 1.0), self.mu_blocker)];
        clip_halfplanes(a, b, &quadrant).filter(|(a, b)| a != b)
    }

    /// Lower bound of `μ` over a box, and whether the box can meet the wedge at all
    /// (straddles the plane and overlaps the wedge's region).
    fn node_bound(&self, lo: &[f32; 3], hi: &[f32; 3]) -> Option<f64> {
        let lo = Vec3::from(*lo).as_dvec3();
        let hi = Vec3::from(*hi).as_dvec3();
        let centre = (lo + hi) * 0.5 - self.c;
        let half = (hi - lo) * 0.5;
        let range = |g: DVec3| {
            let m = centre.dot(g);
            let r = half.dot(g.abs());
            (m - r, m + r)
        };
        let (plo, phi) = range(self.n);
        if plo > self.tol || phi < -self.tol {
            return None;
        }
        let (alo, ahi) = range(self.ga);
        let (blo, bhi) = range(self.gb);
        let (mlo, mhi) = range(self.ga + self.gb);
        let slack = 1e-9;
        let positive = ahi >= -slack && bhi >= -slack;
        let negative = self.ev && alo <= slack && blo <= slack && mhi >= -1.0 - slack;
        (positive || negative).then_some(mlo)
    }
}

fn push(out: &mut Vec<Piece>, a: DVec2, b: DVec2, beyond: bool, output: bool) {
    if a != b {
        out.push(Piece { a, b, beyond, output: output && beyond });
    }
}

/// Clips segment `a b` to `{p : g · p >= k}` for every `(g, k)`.
fn clip_halfplanes(a: DVec2, b: DVec2, planes: &[(DVec2, f64)]) -> Option<(DVec2, DVec2)> {
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    let d = b - a;
    for &(g, k) in planes {
        let fa = g.dot(a) - k;
        let fd = g.dot(d);
        if fd == 0.0 {
            if fa < 0.0 {
                return None;
            }
            continue;
        }
        let t = -fa / fd;
        if fd > 0.0 {
            t0 = t0.max(t);
        } else {
            t1 = t1.min(t);
        }
        if t0 >= t1 {
            return None;
        }
    }
    Some((a + d * t0, a + d * t1))
}

/// A heap entry: a lower bound of `μ` over a subtree, and the subtree (a node index, or
/// a leaf's first face and face count; count 0 marks a node).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Entry(f64, u32, u32);
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        // Min-heap on μ.
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1)).then(o.2.cmp(&self.2))
    }
}

impl Entry {
    fn of(mu: f64, c: Child) -> Option<Entry> {
        match c {
            Child::Node(i) => Some(Entry(mu, i, 0)),
            Child::Leaf { start, count } => Some(Entry(mu, start, count)),
            Child::Empty => None,
        }
    }
}

/// The light point(s) a search tests faces against, with the margin of the box test.
struct Lights {
    a: DVec3,
    b: Option<DVec3>,
    /// Far above the rounding of the box test (relative to the scale of the positions).
    margin: f64,
}

impl Lights {
    fn of(w: &Wedge) -> Lights {
        let (a, b) = w.light_points();
        let scale = a.abs().max_element() + w.d0.length() + w.d1.length();
        Lights { a, b, margin: 1e-9 * scale }
    }

    /// Whether faces with unit normals in `[nlo, nhi]` at positions in `[lo, hi]` may face
    /// one of the light points: the largest `n · (l - p)` over the boxes, by interval
    /// arithmetic in f64 (the face test below is f64 too), against the margin.
    #[inline]
    fn may_face(&self, nlo: &[f32; 3], nhi: &[f32; 3], lo: &[f32; 3], hi: &[f32; 3]) -> bool {
        let top = |l: DVec3| {
            let mut t = 0.0;
            for a in 0..3 {
                let (v0, v1) = (l[a] - hi[a] as f64, l[a] - lo[a] as f64);
                let (n0, n1) = (nlo[a] as f64, nhi[a] as f64);
                t += (n0 * v0).max(n0 * v1).max(n1 * v0).max(n1 * v1);
            }
            t
        };
        top(self.a) > -self.margin || self.b.is_some_and(|b| top(b) > -self.margin)
    }

    /// Whether a face (first corner `p`, unit normal `n`) faces one of the light points.
    #[inline]
    fn faced_by(&self, n: Vec3, p: Vec3) -> bool {
        let (n, p) = (n.as_dvec3(), p.as_dvec3());
        n.dot(self.a - p) > 0.0 || self.b.is_some_and(|b| n.dot(b - p) > 0.0)
    }
}

/// The pieces of `wedge` on the faces of `bvh` that can matter for the 1D clipping: front
/// to back along `μ`, stopping once the pieces cover every ray and nothing unvisited lies
/// nearer than the farthest of them. Appends to `out`.
/// `exclude` lists (sorted) mesh faces to ignore: the faces touching the event's blocker
/// edge or vertex when the receiver is the blocker itself.
pub fn search(bvh: &FaceBvh, wedge: &Wedge, exclude: &[u32], out: &mut Vec<Piece>, scratch: &mut SearchScratch) {
    let Some(super::face_bvh::Root { child: root, lo, hi, nlo, nhi }) = bvh.root else { return };
    let lights = Lights::of(wedge);
    let cull = bvh.closed;
    let SearchScratch { heap, cov, counts } = scratch;
    heap.clear();
    cov.clear();
    if cull && !lights.may_face(&nlo, &nhi, &lo, &hi) {
        return;
    }
    if let Some(e) = wedge.node_bound(&lo, &hi).and_then(|m| Entry::of(m, root)) {
        heap.push(e);
    }
    // Farthest μ of the pieces found so far, and whether they were seen to cover every
    // ray (checked only when the search reaches that depth: the test sorts the intervals).
    let mut far = f64::NEG_INFINITY;
    let mut dirty = false;
    while let Some(Entry(mu, i, count)) = heap.pop() {
        counts[0] += 1;
        if dirty && mu >= far {
            dirty = false;
            if covers_unit(cov) {
                break;
            }
        }
        if count == 0 {
            // A node: test its children's boxes (one cache line) and push the survivors.
            let node = &bvh.nodes[i as usize];
            for k in 0..2 {
                let c = node.child(k);
                if c == Child::Empty {
                    continue;
                }
                let Some(m) = wedge.node_bound(&node.lo[k], &node.hi[k]) else { continue };
                if cull {
                    let nb = &bvh.normals[i as usize];
                    if !lights.may_face(&nb.lo[k], &nb.hi[k], &node.lo[k], &node.hi[k]) {
                        continue;
                    }
                }
                if let Some(e) = Entry::of(m, c) {
                    // Fetch what the entry will need while the heap works on others.
                    match c {
                        Child::Node(j) => {
                            prefetch(&bvh.nodes[j as usize]);
                            if cull {
                                prefetch(&bvh.normals[j as usize]);
                            }
                        }
                        Child::Leaf { start, count } => {
                            // The whole run: a face is 52 bytes, a leaf of eight spans seven
                            // lines.
                            for f in &bvh.faces[start as usize..(start + count) as usize] {
                                prefetch(f);
                            }
                        }
                        Child::Empty => {}
                    }
                    heap.push(e);
                }
            }
            continue;
        }
        counts[1] += 1;
        let before = out.len();
        for f in &bvh.faces[i as usize..(i + count) as usize] {
            if exclude.binary_search(&f.id).is_ok() {
                continue;
            }
            let facing = lights.faced_by(f.n, f.v[0]);
            if cull && !facing {
                continue;
            }
            if let Some((a, b)) = wedge.cut(&f.v) {
                counts[2] += 1;
                wedge.clip(a, b, facing, out);
            }
        }
        if out.len() > before {
            for p in &out[before..] {
                far = far.max(p.a.x + p.a.y).max(p.b.x + p.b.y);
                let (ua, ub) = (u_of(p.a), u_of(p.b));
                cov.push((ua.min(ub), ua.max(ub)));
            }
            dirty = true;
        }
    }
}

/// Reusable allocations of [`search`].
#[derive(Debug, Default)]
pub struct SearchScratch {
    heap: BinaryHeap<Entry>,
    cov: Vec<(f64, f64)>,
    /// Nodes visited, leaves visited and faces cut, summed over searches.
    pub counts: [u64; 3],
}

/// Ray parameter of a canonical point.
#[inline]
pub fn u_of(q: DVec2) -> f64 {
    let m = q.x + q.y;
    if m == 0.0 {
        0.0
    } else {
        (q.y / m).clamp(0.0, 1.0)
    }
}

/// Whether the intervals cover `[0, 1]` (gaps below 1e-9 ignored). Sorts and merges them.
fn covers_unit(v: &mut Vec<(f64, f64)>) -> bool {
    v.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let mut merged: Vec<(f64, f64)> = Vec::with_capacity(v.len());
    for &(a, b) in v.iter() {
        match merged.last_mut() {
            Some(last) if a <= last.1 + 1e-9 => last.1 = last.1.max(b),
            _ => merged.push((a, b)),
        }
    }
    *v = merged;
    v.len() == 1 && v[0].0 <= 1e-9 && v[0].1 >= 1.0 - 1e-9
}
