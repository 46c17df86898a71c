//! Closed solids, to cull receivers wholly in umbra before any work (issue 15's "cull
//! receivers wholly in umbra"; paper 002 §2 computes the mesh on the faces that can see the
//! source). A triangle of a closed, consistently wound component faces out of its solid; when
//! every corner of the light lies behind its outward plane and the light is outside the
//! component's box, every line from a point of the triangle to the light starts into the
//! solid and must leave it through another of its triangles before reaching the light: the
//! triangle receives nothing, like one facing away from a one-sided light.
//!
//! Components are the triangles joined across edges that have exactly two triangles; one is
//! closed when every edge of it has two triangles walking it in opposite directions (a
//! manifold, consistently wound surface) and it encloses a volume. A self-intersecting
//! surface is taken for a solid too (the scenes' meshes are not).
use super::geometry::{edge_key, EdgeKey, Geometry};
use glam::DVec3;
use std::collections::HashMap;

/// Not in a closed component.
pub const OPEN: u32 = u32::MAX;

#[derive(Debug, Clone, Default)]
pub struct Solids {
    /// Per triangle: its closed component, or [`OPEN`].
    pub component: Vec<u32>,
    /// Per triangle: whether its winding normal `(b − a) × (c − a)` points out of its solid
    /// (meaningless for [`OPEN`]).
    pub outward: Vec<bool>,
    /// Per closed component: its box.
    pub boxes: Vec<(DVec3, DVec3)>,
    /// Per closed component: whether it is convex (no edge folds inward by more than
    /// [`CONVEX_SLACK`]), so that its shadow from a point outside it is
    /// the hull of its corners' shadows ([`edgepoint_scene::backprojection::Visible::convex_shadow`]).
    pub convex: Vec<bool>,
    /// Per closed component: its corners (vertex ids), for the shadow of a convex one.
    pub corners: Vec<Vec<u32>>,
}

/// How far a closed component's edge may fold inward for it to count as convex, in the size
/// of its coordinates (its box's largest absolute coordinate plus its diagonal): above the
/// f32 rounding of the scenes' vertices (6·10⁻⁸ of a coordinate), which leaves a box's face
/// split in two triangles, turned by an object's transform, folded either way by that much.
/// Taking a solid so slightly folded for convex hides at most that sliver of light behind
/// its hull.
pub const CONVEX_SLACK: f64 = 1e-6;

fn find(p: &mut [u32], mut x: u32) -> u32 {
    while p[x as usize] != x {
        p[x as usize] = p[p[x as usize] as usize];
        x = p[x as usize];
    }
    x
}

/// Pairs the triangles around edge `key` where more than two meet (two boxes of a chair
/// welded along the edge where the back stands on the seat): each triangle with its neighbour
/// in angle about the edge on the side its winding normal turns away from — inside its solid
/// when the surface is wound outward, as the scenes' are. Appends the pairs and says whether
/// they are mutual and walk the edge in opposite directions; if not, the triangles are left
/// open. (Wound inward, the pairs join the solids' outsides instead: still closed, consistent
/// surfaces, taken as one solid of them both.)
fn pair_around(pos: &[DVec3], tris: &[[u32; 3]], (a, b): EdgeKey, ts: &[u32], pairs: &mut Vec<(u32, u32)>) -> bool {
    let (pa, pb) = (pos[a as usize], pos[b as usize]);
    let Some(d) = (pb - pa).try_normalize() else { return false };
    let u = d.any_orthonormal_vector();
    let w = d.cross(u);
    // Per triangle: its angle about the edge, whether it walks a → b, and whether its winding
    // normal points counter-clockwise (about d) from its half-plane.
    let mut around: Vec<(f64, u32, bool, bool)> = Vec::with_capacity(ts.len());
    for &t in ts {
        let v = tris[t as usize];
        let Some(&c) = v.iter().find(|x| **x != a && **x != b) else { return false };
        let k = (0..3).find(|k| v[*k] == a).expect("the edge's triangle has its corner");
        let forward = v[(k + 1) % 3] == b;
        let x = pos[c as usize] - pa;
        let (xu, xw) = (x.dot(u), x.dot(w));
        if xu * xu + xw * xw <= 0.0 {
            return false;
        }
        let [p, q, r] = v.map(|i| pos[i as usize]);
        let n = (q - p).cross(r - p);
        // Counter-clockwise of the half-plane at angle θ is the direction (−sin θ, cos θ).
        let ccw = n.dot(w) * xu - n.dot(u) * xw > 0.0;
        around.push((xw.atan2(xu), t, forward, ccw));
    }
    around.sort_by(|x, y| x.0.total_cmp(&y.0));
    // Two faces lying on each other (the back's underside on the seat) share a half-plane:
    // of the two, the one whose inside is clockwise goes first, so that each meets its own
    // solid's other face, not the other's.
    for i in 1..around.len() {
        if around[i].0 - around[i - 1].0 <= 1e-9 && !around[i - 1].3 && around[i].3 {
            around.swap(i - 1, i);
        }
    }
    let m = around.len();
    // The inside of a triangle's solid lies against its normal: clockwise of it when the
    // normal points counter-clockwise.
    let partner = |i: usize| if around[i].3 { (i + m - 1) % m } else { (i + 1) % m };
    for i in 0..m {
        let j = partner(i);
        if partner(j) != i || around[i].2 == around[j].2 {
            return false;
        }
        if i < j {
            pairs.push((around[i].1, around[j].1));
        }
    }
    true
}

impl Solids {
    pub fn new(pos: &[DVec3], tris: &[[u32; 3]], edge_tris: &super::fast_hash::FastMap<EdgeKey, Vec<u32>>) -> Solids {
        let n = tris.len();
        // +1 for each triangle walking the edge from its smaller id, −1 the other way.
        let mut walk: HashMap<EdgeKey, i32> = HashMap::with_capacity(edge_tris.len());
        for t in tris {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *walk.entry(edge_key(a, b)).or_default() += if a < b { 1 } else { -1 };
            }
        }
        let mut parent: Vec<u32> = (0..n as u32).collect();
        let mut open = vec![false; n];
        // The pairs of triangles joined across an edge (for the convexity test below).
        let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(edge_tris.len());
        for (key, ts) in edge_tris {
            let before = pairs.len();
            if ts.len() == 2 && walk[key] == 0 {
                pairs.push((ts[0], ts[1]));
            } else if !(ts.len() % 2 == 0 && walk[key] == 0 && pair_around(pos, tris, *key, ts, &mut pairs)) {
                pairs.truncate(before);
                ts.iter().for_each(|t| open[*t as usize] = true);
            }
            for &(a, b) in &pairs[before..] {
                let (a, b) = (find(&mut parent, a), find(&mut parent, b));
                parent[a as usize] = b;
            }
        }
        let root: Vec<u32> = (0..n as u32).map(|t| find(&mut parent, t)).collect();
        for t in 0..n {
            if open[t] {
                open[root[t] as usize] = true;
            }
        }
        // Signed volume per component (about its first corner, for precision) and the size
        // it is judged against.
        let mut volume: HashMap<u32, (DVec3, f64, f64)> = HashMap::new();
        for (t, tri) in tris.iter().enumerate() {
            if open[root[t] as usize] {
                continue;
            }
            let [a, b, c] = tri.map(|v| pos[v as usize]);
            let e = volume.entry(root[t]).or_insert((a, 0.0, 0.0));
            let (a, b, c) = (a - e.0, b - e.0, c - e.0);
            e.1 += a.dot(b.cross(c)) / 6.0;
            e.2 += a.length() * b.length() * c.length() / 6.0;
        }
        let mut id: HashMap<u32, u32> = HashMap::new();
        let mut component = vec![OPEN; n];
        let mut outward = vec![false; n];
        for t in 0..n {
            let Some(&(_, v, size)) = volume.get(&root[t]) else { continue };
            if v.abs() <= 1e-9 * size {
                continue; // flat: encloses nothing
            }
            let next = id.len() as u32;
            component[t] = *id.entry(root[t]).or_insert(next);
            outward[t] = v > 0.0;
        }
        let count = id.len();
        let mut s = Solids { component, outward, boxes: vec![(DVec3::INFINITY, DVec3::NEG_INFINITY); count], convex: vec![true; count], corners: vec![Vec::new(); count] };
        s.update_boxes(pos, tris, 0..n as u32);
        for (t, tri) in tris.iter().enumerate() {
            if let Some(c) = s.corners.get_mut(s.component[t] as usize) {
                c.extend_from_slice(tri);
            }
        }
        for c in &mut s.corners {
            c.sort_unstable();
            c.dedup();
        }
        // Convex: at every edge, the far corner of one triangle lies behind the other's
        // outward plane (a closed, connected surface that is locally convex everywhere bounds
        // a convex body).
        for &(a, b) in &pairs {
            let c = s.component[a as usize];
            if c == OPEN || s.component[b as usize] != c || !s.convex[c as usize] {
                continue;
            }
            let [p, q, r] = tris[a as usize].map(|v| pos[v as usize]);
            let Some(n) = (q - p).cross(r - p).try_normalize() else { continue };
            let n = if s.outward[a as usize] { n } else { -n };
            let far = tris[b as usize].iter().map(|v| pos[*v as usize]).map(|x| n.dot(x - p)).fold(f64::NEG_INFINITY, f64::max);
            let (lo, hi) = s.boxes[c as usize];
            if far > CONVEX_SLACK * (lo.abs().max(hi.abs()).max_element() + (hi - lo).length()) {
                s.convex[c as usize] = false;
            }
        }
        s
    }

    /// Whether triangle `t` belongs to a convex closed component, and which.
    pub fn convex_component(&self, t: u32) -> Option<u32> {
        let c = self.component[t as usize];
        self.convex.get(c as usize).is_some_and(|k| *k).then_some(c)
    }

    /// Recomputes the boxes of the components of triangles `range` (an object that moved;
    /// components do not span objects).
    pub fn update_boxes(&mut self, pos: &[DVec3], tris: &[[u32; 3]], range: std::ops::Range<u32>) {
        for t in range.clone() {
            if let Some(b) = self.boxes.get_mut(self.component[t as usize] as usize) {
                *b = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            }
        }
        for t in range {
            if let Some(b) = self.boxes.get_mut(self.component[t as usize] as usize) {
                for v in tris[t as usize] {
                    *b = (b.0.min(pos[v as usize]), b.1.max(pos[v as usize]));
                }
            }
        }
    }
}

/// Whether triangle `t` is wholly in the umbra of its own solid from the light with
/// corners `light` (see the module's doc).
pub fn in_own_umbra(g: &Geometry, t: u32, light: &[DVec3], tol: f64) -> bool {
    let s = &g.solids;
    let c = s.component[t as usize];
    if c == OPEN {
        return false;
    }
    let [a, b, p] = g.tri(t);
    let Some(n) = (b - a).cross(p - a).try_normalize() else { return false };
    let n = if s.outward[t as usize] { n } else { -n };
    if light.iter().any(|y| n.dot(*y - a) > tol) {
        return false;
    }
    let (lo, hi) = s.boxes[c as usize];
    let (llo, lhi) = light.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), y| (lo.min(*y), hi.max(*y)));
    llo.cmpgt(hi + tol).any() || lhi.cmplt(lo - tol).any()
}

/// Whether triangle `t` (corners `tri`) of a closed solid faces away from `p`, a point outside
/// the solid's box: then it hides nothing from `p` that another triangle of the solid does
/// not hide first — a line from `p` that meets the solid enters it through a face turned
/// toward `p` before it can leave through this one — and an occlusion test may pass it over.
pub fn faces_away(g: &Geometry, t: u32, tri: [DVec3; 3], p: DVec3) -> bool {
    let s = &g.solids;
    let c = s.component[t as usize];
    if c == OPEN {
        return false;
    }
    let (lo, hi) = s.boxes[c as usize];
    if p.cmpge(lo).all() && p.cmple(hi).all() {
        return false;
    }
    let [a, b, q] = tri;
    let n = (b - a).cross(q - a);
    let n = if s.outward[t as usize] { n } else { -n };
    n.dot(p - a) < 0.0
}
