//! Shadow events of one blocker for one light (paper 000 §6.3, §6.4 "Tree traversal for
//! silhouette and shadow events", Appendix A), in the blocker's object space.
//!
//! An event is a wedge: the rays from points `F(u)` of the light through points `S(u)` of
//! the blocker, `u ∈ [0, 1]`, beyond the blocker. Shadow edges are where it meets
//! receivers ([`super::shadow`]).
//!
//! - **Point lights**: "shadow events are essentially silhouette computations from the
//!   light's point of view" — every silhouette edge seen from the light (the edge tree
//!   query with the light as the eye) and every boundary edge (a surface that ends casts a
//!   shadow edge from everywhere) gives a hard event `F = L`, `S = edge`.
//! - **Area lights** (planar convex polygons), Appendix A: a **VE event** (light vertex `v`,
//!   blocker edge `e`) exists when `e` is a silhouette seen from `v` (Equation 1 — the
//!   plane `(v, e)` is tangent to the blocker along `e`) and the light vertices adjacent to
//!   `v` lie on one side of that plane (tangent to the light at `v`). It is **umbral** when
//!   the light and the blocker lie on the same side of the plane and **penumbral**
//!   otherwise (§6.3). The blocker's side is where its surface leaves `e`: the inward
//!   directions `n0 × (b - a)` and `n1 × (a - b)` of the two faces, measured against the
//!   plane normal (for a silhouette both faces leave on one side). The tree is traversed
//!   once for the whole light: internal nodes evaluate Equation 1 with the interval of the
//!   light's bounding box as the eye (both node bounds, [`super::tree::Node::facing_tight`]),
//!   and subtrees entirely behind the (one-sided) light's
//!   plane are pruned; leaves test each light vertex.
//! - **EV events** (light edge `l0 l1`, blocker vertex `w`) are found by walking from the VE
//!   candidates along the shadow-volume boundary: the boundary leaves a VE wedge `(v, e)`
//!   at the end points of `e`, where it continues either on another VE wedge or on an EV
//!   wedge through one of the two light edges at `v` (Appendix A, Figure 14). Each such
//!   (light edge, end point) is tested directly: the plane through `l0`, `l1` and `w` is
//!   tangent to the light (always: the light is convex) and must be tangent to the blocker
//!   at `w` — all of `w`'s neighbours on one side (this is the angle comparison of Appendix
//!   A, made exact: the plane rotates about `w` until it meets the first neighbour). Labels
//!   as for VE. Every EV event of the brute-force definition is reached this way: if the
//!   plane `(l0, l1, w)` has all of `w`'s neighbours on one side, then seen from `l0` the
//!   fan of faces around `w` does not wind around `w`, so it has faces of both facings
//!   and `w` ends a silhouette (or boundary) edge seen from `l0` — a VE candidate. The
//!   tests prove it against the brute-force finder on real meshes.
//!
//! Both finders return events sorted by generator, so results compare directly.
use super::brute::face_side;
use super::geometric::{is_tree_edge, MeshEdgeTrees};
use super::interval::IVec3;
use super::tree::Visit;
use super::EdgeKind;
use edgepoint_scene::{light::polygon_normal, Mesh};
use glam::{Affine3A, Vec3, Vec3A};
use rayon::prelude::*;

/// What defines an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Generator {
    /// A point light and blocker edge `edge`.
    Point { edge: u32 },
    /// Light vertex `vertex` and blocker edge `edge`.
    VE { vertex: u32, edge: u32 },
    /// Light edge from vertex `light_edge` to the next, and blocker vertex `vertex`.
    EV { light_edge: u32, vertex: u32 },
}

/// One shadow event (wedge) in the blocker's object space: the rays from `f[0] + u (f[1] -
/// f[0])` through `s[0] + u (s[1] - s[0])`, `u ∈ [0, 1]`. For point and VE events the
/// light point is fixed (`f[0] == f[1]`), for EV events the blocker point (`s[0] == s[1]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowEvent {
    pub generator: Generator,
    /// `ShadowHard`, `ShadowUmbral` or `ShadowPenumbral`.
    pub kind: EdgeKind,
    pub f: [Vec3; 2],
    pub s: [Vec3; 2],
}

/// A light in a blocker's object space.
#[derive(Debug, Clone, PartialEq)]
pub enum LocalLight {
    Point(Vec3),
    Polygon {
        vertices: Vec<Vec3>,
        /// Unit normal (the side it emits to).
        normal: Vec3,
        centroid: Vec3,
    },
}

impl LocalLight {
    /// `light` seen from an object with object-to-world transform `to_world`.
    pub fn new(light: &edgepoint_scene::Light, to_world: &Affine3A) -> LocalLight {
        let inv = to_world.inverse();
        match light {
            // A spot light's shadows are a point light's (the cone only shades).
            edgepoint_scene::Light::Point { position, .. } | edgepoint_scene::Light::Spot { position, .. } => {
                LocalLight::Point(inv.transform_point3(*position))
            }
            edgepoint_scene::Light::Area { vertices, .. } => {
                let v: Vec<Vec3> = vertices.iter().map(|p| inv.transform_point3(*p)).collect();
                // Recomputed in object space: a mirroring transform flips the winding.
                let normal = polygon_normal(&v).normalize_or_zero();
                let centroid = v.iter().copied().sum::<Vec3>() / v.len().max(1) as f32;
                LocalLight::Polygon { vertices: v, normal, centroid }
            }
        }
    }

    /// The light's bounding box.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        match self {
            LocalLight::Point(p) => (*p, *p),
            LocalLight::Polygon { vertices, .. } => {
                let b = IVec3::bounding(vertices);
                (b.lo(), b.hi())
            }
        }
    }
}

/// Vertex neighbours and incident faces of a mesh (compressed rows), for the EV tangency
/// test and for leaving an EV event's own faces out of its intersections.
#[derive(Debug, Clone, Default)]
pub struct VertexRings {
    start: Vec<u32>,
    neighbours: Vec<u32>,
    face_start: Vec<u32>,
    faces: Vec<u32>,
}

impl VertexRings {
    pub fn build(mesh: &Mesh) -> VertexRings {
        let n = mesh.positions.len();
        let mut count = vec![0u32; n + 1];
        for e in &mesh.edges {
            count[e.v[0] as usize + 1] += 1;
            count[e.v[1] as usize + 1] += 1;
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        let mut neighbours = vec![0u32; count[n] as usize];
        for e in &mesh.edges {
            for (a, b) in [(e.v[0], e.v[1]), (e.v[1], e.v[0])] {
                neighbours[fill[a as usize] as usize] = b;
                fill[a as usize] += 1;
            }
        }
        let mut fcount = vec![0u32; n + 1];
        for t in &mesh.triangles {
            for &v in t {
                fcount[v as usize + 1] += 1;
            }
        }
        for i in 0..n {
            fcount[i + 1] += fcount[i];
        }
        let mut ffill = fcount.clone();
        let mut faces = vec![0u32; fcount[n] as usize];
        for (f, t) in mesh.triangles.iter().enumerate() {
            for &v in t {
                faces[ffill[v as usize] as usize] = f as u32;
                ffill[v as usize] += 1;
            }
        }
        VertexRings { start: count, neighbours, face_start: fcount, faces }
    }

    /// The faces around `v`, ascending.
    pub fn faces_of(&self, v: u32) -> &[u32] {
        &self.faces[self.face_start[v as usize] as usize..self.face_start[v as usize + 1] as usize]
    }

    /// The vertices joined to `v` by an edge (a non-manifold edge may list one twice).
    pub fn of(&self, v: u32) -> &[u32] {
        &self.neighbours[self.start[v as usize] as usize..self.start[v as usize + 1] as usize]
    }
}

/// The one-sided light's plane: `n · (p - c) > 0` in front. Written once so the tree's
/// interval test and the per-edge test evaluate the same expression.
#[derive(Debug, Clone, Copy)]
struct Front {
    n: Vec3,
    c: Vec3,
}

impl Front {
    #[inline]
    fn contains(&self, p: Vec3) -> bool {
        self.n.dot(p - self.c) > 0.0
    }
    /// Some point of the edge `(a, b)` is in front.
    #[inline]
    fn edge(&self, mesh: &Mesh, e: u32) -> bool {
        let v = mesh.edges[e as usize].v;
        self.contains(mesh.positions[v[0] as usize]) || self.contains(mesh.positions[v[1] as usize])
    }
    /// Some point of the box may be in front (interval arithmetic, conservative).
    #[inline]
    fn may_contain(&self, lo: &[f32; 3], hi: &[f32; 3]) -> bool {
        let p = IVec3::from_arrays(lo, hi);
        !IVec3::point(self.n).dot(&p.sub(&IVec3::point(self.c))).all_non_positive()
    }
}

fn sign(x: f32) -> i32 {
    (x > 0.0) as i32 - (x < 0.0) as i32
}

/// The Appendix A leaf test for a VE event: vertex `i` of the light polygon `light`;
/// blocker edge `a → b` (as wound in its first face) with face normals `n0`, `n1` (`n1`
/// unused for a boundary edge). `e` must already be a silhouette seen from `v = light[i]`
/// (or a boundary edge). Returns the event's label, or `None` if the plane is not tangent
/// to the light at `v` (or degenerate), or bounds neither the umbra nor the penumbra.
///
/// Across the edge (a cross-section perpendicular to `e`) the blocker is a wedge between
/// its two faces, on one side of the plane `P = (v, e)`; a point `q` on the event beyond
/// `e` looks back past `e` towards `v` along `P`. The segment from `q` to a light point
/// sweeps, seen from `e`, from `q`'s direction to the light point's, so it enters the
/// blocker exactly when the light point lies on the blocker's side of `P` (strictly) *and*
/// behind the plane of the face turned away from `v` (for a boundary edge: on `v`'s side
/// of its one face's plane).
/// - **Penumbral**: the light lies on the other side of `P` from the blocker; crossing `P`
///   the edge starts to cover the light at `v`.
/// - **Umbral**: the light lies on the blocker's side of `P` and behind the turned-away
///   face: crossing `P` the edge hides the last of the light, at `v`. When the light lies
///   on the blocker's side but partly in front of that face (it reaches around the edge),
///   the light is never all hidden next to the edge and the event bounds no umbra there.
pub fn ve_label(light: &[Vec3], i: usize, a: Vec3, b: Vec3, n0: Vec3, n1: Option<Vec3>) -> Option<EdgeKind> {
    let k = light.len();
    let (v, prev, next) = (light[i], light[(i + k - 1) % k], light[(i + 1) % k]);
    let m = (a - v).cross(b - v);
    let (sp, sn) = (sign(m.dot(prev - v)), sign(m.dot(next - v)));
    let side = if sp >= 0 && sn >= 0 && sp + sn > 0 {
        1
    } else if sp <= 0 && sn <= 0 && sp + sn < 0 {
        -1
    } else {
        return None;
    };
    let mut s = m.dot(n0.cross(b - a));
    if let Some(n1) = n1 {
        s += m.dot(n1.cross(a - b));
    }
    let blocker = sign(s);
    if blocker == 0 {
        return None;
    }
    if side != blocker {
        return Some(EdgeKind::ShadowPenumbral);
    }
    // The face turned away from v (the only face of a boundary edge) and v's side of it.
    let far = match n1 {
        Some(n1) if n0.dot(v - a) > 0.0 => n1,
        _ => n0,
    };
    let sv = sign(far.dot(v - a));
    let behind = sv != 0 && light.iter().all(|&l| sign(far.dot(l - a)) != -sv);
    behind.then_some(EdgeKind::ShadowUmbral)
}

/// The Appendix A test for an EV event: light edge `l0 → l1` of a light with centroid
/// `centroid`, blocker vertex `w` and the other two corners of every face around `w`.
/// Returns the label, or `None` when the wedge bounds neither the umbra nor the penumbra
/// at `w` (or is degenerate).
///
/// Seen from a point `q` on the wedge beyond `w`, the plane `P = (l0, l1, w)` is a line
/// through the images of `w` and of the light edge, with the light on one side. What the
/// blocker looks like there is its cone of faces at `w` projected along the ray from the
/// light through `w`; projecting along a direction in `P` keeps every point's side of `P`.
/// - **Penumbral**: the faces all lie on the side away from the light (tangent at `w`, the
///   light on the other side): crossing `P` the corner `w` starts to cover the light edge.
/// - **Umbral**: the projected faces cover the whole light side of the line near `w` and
///   leave a gap on the other side — `w` is a reflex corner of the silhouette, seen from
///   the light edge, with its notch pointing away from the light. Crossing `P` the notch
///   passes over the light edge, and the light edge is the last of the light to be hidden.
///   This is Appendix A's "for locally concave surfaces, EV events contribute to the
///   umbral boundary but not to the penumbral boundary" made exact. A plane tangent at a
///   convex corner with the light on the blocker's side is *not* an umbral event: from
///   the wedge the light edge is seen grazing past the corner, uncovered on both sides
///   (the umbra of a convex blocker is bounded by VE events alone, the intersection of
///   the shadows of the light's vertices). It is checked at both ends of the light edge.
pub fn ev_label(l0: Vec3, l1: Vec3, centroid: Vec3, w: Vec3, faces: impl Iterator<Item = (Vec3, Vec3)> + Clone) -> Option<EdgeKind> {
    let m = (l1 - l0).cross(w - l0);
    let light = sign(m.dot(centroid - l0));
    if light == 0 {
        return None;
    }
    let (mut pos, mut neg) = (false, false);
    for (x, y) in faces.clone() {
        for p in [x, y] {
            match sign(m.dot(p - w)) {
                1 => pos = true,
                -1 => neg = true,
                _ => {}
            }
        }
    }
    if pos != neg {
        // Tangent at w: penumbral when the blocker lies away from the light.
        let blocker = if pos { 1 } else { -1 };
        return (blocker != light).then_some(EdgeKind::ShadowPenumbral);
    }
    if !(pos && neg) {
        return None;
    }
    let towards_light = m * light as f32;
    let reflex = |l: Vec3| notch_away_from(w - l, towards_light, w, faces.clone());
    (reflex(l0) && reflex(l1)).then_some(EdgeKind::ShadowUmbral)
}

/// Projected along `d` (a direction in the plane with normal `up`), whether the faces
/// around `w` (given by their other two corners) cover every direction on the `up` side
/// of the plane near `w` but not every direction: the umbral EV condition of [`ev_label`].
/// In the 2D projection each face covers the angle between its two other corners; the
/// union of those closed arcs must contain the half turn `[0, π]` (angle 0 along
/// `up × d`, a quarter turn along `up`) and not the whole turn. Angles are pseudo-angles
/// (monotone, a full turn is 4), in f64, so every caller decides alike.
fn notch_away_from(d: Vec3, up: Vec3, w: Vec3, faces: impl Iterator<Item = (Vec3, Vec3)>) -> bool {
    const HALF: f64 = 2.0;
    const TURN: f64 = 4.0;
    let (d, up, w) = (d.as_dvec3(), up.as_dvec3(), w.as_dvec3());
    let side = up.cross(d);
    let to2 = |p: Vec3| {
        let r = p.as_dvec3() - w;
        (r.dot(side), r.dot(up))
    };
    let angle = |(x, y): (f64, f64)| {
        if y >= 0.0 {
            if x >= 0.0 {
                y / (x + y)
            } else {
                1.0 - x / (y - x)
            }
        } else if x < 0.0 {
            2.0 - y / (-x - y)
        } else {
            3.0 + x / (x - y)
        }
    };
    // Arcs in [0, 2 turns); an arc that wraps past a turn also appears a turn lower.
    let mut arcs: Vec<(f64, f64)> = Vec::with_capacity(16);
    for (x, y) in faces {
        let (px, py) = (to2(x), to2(y));
        let c = px.0 * py.1 - px.1 * py.0;
        if c == 0.0 {
            continue; // seen edge-on: covers no direction
        }
        let (a, b) = if c > 0.0 { (angle(px), angle(py)) } else { (angle(py), angle(px)) };
        let b = if b < a { b + TURN } else { b };
        arcs.push((a, b));
        if b > TURN {
            arcs.push((a - TURN, b - TURN));
        }
    }
    arcs.sort_unstable_by(|p, q| p.0.total_cmp(&q.0));
    // How far the arcs reach from angle 0 without a gap: a half turn at least (the light's
    // side covered), short of a whole turn (not everything: w is on the silhouette).
    let mut reach = 0.0f64;
    for &(a, b) in &arcs {
        if a <= reach + 1e-12 {
            reach = reach.max(b);
        }
    }
    (HALF - 1e-12..TURN - 1e-12).contains(&reach)
}

fn point_event(mesh: &Mesh, l: Vec3, edge: u32) -> ShadowEvent {
    let e = &mesh.edges[edge as usize];
    ShadowEvent {
        generator: Generator::Point { edge },
        kind: EdgeKind::ShadowHard,
        f: [l, l],
        s: [mesh.positions[e.v[0] as usize], mesh.positions[e.v[1] as usize]],
    }
}

/// The VE event of light vertex `i` (of `lv`) and blocker edge `edge`, if any.
fn ve_event(mesh: &Mesh, lv: &[Vec3], i: usize, edge: u32) -> Option<ShadowEvent> {
    let e = &mesh.edges[edge as usize];
    let (a, b) = (mesh.positions[e.v[0] as usize], mesh.positions[e.v[1] as usize]);
    let n1 = (!e.is_boundary()).then_some(e.normals[1]);
    let kind = ve_label(lv, i, a, b, e.normals[0], n1)?;
    Some(ShadowEvent { generator: Generator::VE { vertex: i as u32, edge }, kind, f: [lv[i], lv[i]], s: [a, b] })
}

/// The EV event of light edge `j` (from vertex `j` to `j + 1`) and blocker vertex `w`.
fn ev_event(mesh: &Mesh, rings: &VertexRings, lv: &[Vec3], centroid: Vec3, j: usize, w: u32) -> Option<ShadowEvent> {
    let (l0, l1) = (lv[j], lv[(j + 1) % lv.len()]);
    let p = mesh.positions[w as usize];
    let corners = rings.faces_of(w).iter().map(|&f| {
        let t = mesh.triangles[f as usize];
        let k = t.iter().position(|&v| v == w).unwrap_or(0);
        (mesh.positions[t[(k + 1) % 3] as usize], mesh.positions[t[(k + 2) % 3] as usize])
    });
    let kind = ev_label(l0, l1, centroid, p, corners)?;
    Some(ShadowEvent { generator: Generator::EV { light_edge: j as u32, vertex: w }, kind, f: [l0, l1], s: [p, p] })
}

fn sorted(mut v: Vec<ShadowEvent>) -> Vec<ShadowEvent> {
    v.sort_unstable_by_key(|e| e.generator);
    v
}

/// Events of `mesh` (with its trees and rings) for `light`, found with the edge tree.
/// `rings` is needed for polygonal lights only.
pub fn find_events(mesh: &Mesh, trees: &MeshEdgeTrees, rings: Option<&VertexRings>, light: &LocalLight) -> Vec<ShadowEvent> {
    match light {
        LocalLight::Point(l) => {
            let mut sil = Vec::new();
            trees.silhouette.silhouettes(*l, &mut sil);
            let mut out: Vec<ShadowEvent> = sil.iter().map(|&e| point_event(mesh, *l, e)).collect();
            out.extend(trees.boundary.iter().map(|&e| point_event(mesh, *l, e)));
            sorted(out)
        }
        LocalLight::Polygon { vertices: lv, normal, centroid } => {
            let rings = rings.expect("vertex rings are needed for area lights");
            let front = Front { n: *normal, c: lv[0] };
            let (lo, hi) = light.bounds();
            let (lo, hi) = (Vec3A::from(lo), Vec3A::from(hi));
            // VE candidates: (light vertex, edge) with the edge a silhouette from the vertex.
            let mut cand: Vec<(u32, u32)> = Vec::new();
            trees.silhouette.query(
                &mut cand,
                |n| {
                    if !front.may_contain(&n.plo, &n.phi) || n.facing_tight(lo, hi).sign_is_fixed() {
                        Visit::Skip
                    } else {
                        Visit::Test
                    }
                },
                |blocks, _, out| {
                    for b in blocks {
                        for (i, v) in lv.iter().enumerate() {
                            b.select(*v, |s0, s1| s0 ^ s1, |e| out.push((i as u32, e)));
                        }
                    }
                },
            );
            for &e in &trees.boundary {
                for i in 0..lv.len() as u32 {
                    cand.push((i, e));
                }
            }
            cand.retain(|&(_, e)| front.edge(mesh, e));
            area_events_from_candidates(mesh, rings, lv, *centroid, front, &cand)
        }
    }
}

/// VE events from the candidates, and the EV events one step along the shadow-volume
/// boundary from them (see the module docs).
fn area_events_from_candidates(
    mesh: &Mesh,
    rings: &VertexRings,
    lv: &[Vec3],
    centroid: Vec3,
    front: Front,
    cand: &[(u32, u32)],
) -> Vec<ShadowEvent> {
    let k = lv.len() as u32;
    let mut out: Vec<ShadowEvent> = cand.par_iter().filter_map(|&(i, e)| ve_event(mesh, lv, i as usize, e)).collect();
    let mut ev: Vec<(u32, u32)> = Vec::with_capacity(cand.len() * 4);
    for &(i, e) in cand {
        let v = mesh.edges[e as usize].v;
        for w in v {
            ev.push((w, (i + k - 1) % k));
            ev.push((w, i));
        }
    }
    ev.par_sort_unstable();
    ev.dedup();
    out.par_extend(ev.par_iter().filter_map(|&(w, j)| {
        if !front.contains(mesh.positions[w as usize]) {
            return None;
        }
        ev_event(mesh, rings, lv, centroid, j as usize, w)
    }));
    sorted(out)
}

/// The brute-force finder: every edge (and for area lights every vertex) tested with the
/// same predicates. The oracle of [`find_events`].
pub fn find_events_brute(mesh: &Mesh, rings: Option<&VertexRings>, light: &LocalLight) -> Vec<ShadowEvent> {
    match light {
        LocalLight::Point(l) => {
            let out = (0..mesh.edges.len() as u32)
                .filter(|&i| {
                    let e = &mesh.edges[i as usize];
                    let p = mesh.positions[e.v[0] as usize];
                    e.is_boundary()
                        || (is_tree_edge(e) && face_side(e.normals[0], p, *l) != face_side(e.normals[1], p, *l))
                })
                .map(|i| point_event(mesh, *l, i))
                .collect();
            sorted(out)
        }
        LocalLight::Polygon { vertices: lv, normal, centroid } => {
            let rings = rings.expect("vertex rings are needed for area lights");
            let front = Front { n: *normal, c: lv[0] };
            let mut out = Vec::new();
            for (i, e) in mesh.edges.iter().enumerate() {
                if !front.edge(mesh, i as u32) {
                    continue;
                }
                let p = mesh.positions[e.v[0] as usize];
                for (j, v) in lv.iter().enumerate() {
                    let candidate = e.is_boundary()
                        || (is_tree_edge(e) && face_side(e.normals[0], p, *v) != face_side(e.normals[1], p, *v));
                    if candidate {
                        out.extend(ve_event(mesh, lv, j, i as u32));
                    }
                }
            }
            for w in 0..mesh.positions.len() as u32 {
                if !front.contains(mesh.positions[w as usize]) || rings.of(w).is_empty() {
                    continue;
                }
                for j in 0..lv.len() {
                    out.extend(ev_event(mesh, rings, lv, *centroid, j, w));
                }
            }
            sorted(out)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_scene::NoProgress;

    fn cube(lo: Vec3, hi: Vec3) -> Mesh {
        edgepoint_scene::builtin::shapes::cuboid(lo, hi)
    }

    fn square_light(y: f32, half: f32, rot: f32) -> LocalLight {
        let (s, c) = rot.sin_cos();
        let mut v: Vec<Vec3> = [(-1.0, -1.0), (-1.0, 1.0), (1.0, 1.0), (1.0, -1.0)]
            .iter()
            .map(|&(x, z)| Vec3::new(half * (c * x - s * z), y, half * (s * x + c * z)))
            .collect();
        // Facing down (-y): counter-clockwise seen from below.
        if polygon_normal(&v).y > 0.0 {
            v.reverse();
        }
        let normal = polygon_normal(&v).normalize();
        let centroid = v.iter().copied().sum::<Vec3>() / 4.0;
        LocalLight::Polygon { vertices: v, normal, centroid }
    }

    #[test]
    fn a_box_under_a_rotated_square_light() {
        // A unit box under a larger square light rotated by 30°: the umbra and penumbra
        // boundaries each go once around the box. Every light vertex/edge and every
        // silhouette edge/vertex of the box takes part, so there are both VE and EV events
        // of both labels.
        let m = cube(Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5));
        let light = square_light(3.0, 1.0, std::f32::consts::FRAC_PI_6);
        let trees = MeshEdgeTrees::build(&m, &NoProgress);
        let rings = VertexRings::build(&m);
        let ev = find_events(&m, &trees, Some(&rings), &light);
        assert_eq!(ev, find_events_brute(&m, Some(&rings), &light));
        let count = |f: &dyn Fn(&ShadowEvent) -> bool| ev.iter().filter(|e| f(e)).count();
        let umbral = count(&|e| e.kind == EdgeKind::ShadowUmbral);
        let penumbral = count(&|e| e.kind == EdgeKind::ShadowPenumbral);
        let penumbral_ev = count(&|e| e.kind == EdgeKind::ShadowPenumbral && matches!(e.generator, Generator::EV { .. }));
        // The penumbra boundary goes once around the box and turns at every light vertex
        // (a VE event) and every box vertex (an EV event) on the way: at least 4 + 4. The
        // umbra of a convex blocker is the intersection of the shadows of the light's
        // vertices: VE events only (Appendix A: no umbral EV events on convex surfaces).
        assert!(penumbral >= 8 && penumbral_ev >= 4, "{penumbral} {penumbral_ev}");
        assert!(umbral >= 4, "{umbral}");
        assert_eq!(count(&|e| e.kind == EdgeKind::ShadowUmbral && matches!(e.generator, Generator::EV { .. })), 0);
        for e in &ev {
            assert_local_meaning(&m, &light, e);
        }
    }

    /// An L-shaped prism: the outline (x, z) `(0,0) (2,0) (2,1) (1,1) (1,2) (0,2)`, height 1,
    /// with a reflex corner at `(1, ·, 1)`.
    fn l_prism() -> Mesh {
        let outline = [(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (1.0, 1.0), (1.0, 2.0), (0.0, 2.0)];
        let mut p: Vec<Vec3> = outline.iter().map(|&(x, z)| Vec3::new(x, 0.0, z)).collect();
        p.extend(outline.iter().map(|&(x, z)| Vec3::new(x, 1.0, z)));
        let cap = [[0u32, 1, 2], [0, 2, 3], [0, 3, 5], [5, 3, 4]];
        let mut t: Vec<[u32; 3]> = cap.iter().map(|&[a, b, c]| [a, c, b]).collect();
        t.extend(cap.iter().map(|&[a, b, c]| [a + 6, b + 6, c + 6]));
        for i in 0..6u32 {
            let j = (i + 1) % 6;
            t.push([i, j, j + 6]);
            t.push([i, j + 6, i + 6]);
        }
        let mut m = Mesh::from_triangles(p, t, &NoProgress);
        if m.signed_volume() < 0.0 {
            m.flip();
        }
        m
    }

    #[test]
    fn a_reflex_corner_makes_umbral_ev_events() {
        // Lights above the L, turned so that their edges pass over the reflex top corner at
        // different angles: seen from the light edges that pass over the corner with the
        // light over the L's body, the corner is a reflex silhouette corner with its notch
        // away from the light (umbral EV), Appendix A's concave case.
        let m = l_prism();
        let trees = MeshEdgeTrees::build(&m, &NoProgress);
        let rings = VertexRings::build(&m);
        let reflex = m.positions.iter().position(|p| *p == Vec3::new(1.0, 1.0, 1.0)).unwrap() as u32;
        let mut umbral_ev_at_reflex = 0;
        for k in 0..36 {
            let rot = (k % 12) as f32 * 0.26;
            let LocalLight::Polygon { vertices, .. } = square_light(3.0, 0.6, rot) else { unreachable!() };
            let shift = [Vec3::new(0.2, 0.0, 0.2), Vec3::new(0.5, 0.0, 0.4), Vec3::new(1.4, 0.0, 1.4)][k / 12];
            let v: Vec<Vec3> = vertices.iter().map(|p| *p + shift).collect();
            let normal = polygon_normal(&v).normalize();
            let centroid = v.iter().copied().sum::<Vec3>() / 4.0;
            let light = LocalLight::Polygon { vertices: v, normal, centroid };
            let ev = find_events(&m, &trees, Some(&rings), &light);
            assert_eq!(ev, find_events_brute(&m, Some(&rings), &light));
            for e in &ev {
                if e.kind == EdgeKind::ShadowUmbral && matches!(e.generator, Generator::EV { vertex, .. } if vertex == reflex) {
                    umbral_ev_at_reflex += 1;
                }
                assert_local_meaning(&m, &light, e);
            }
        }
        assert!(umbral_ev_at_reflex > 0);
    }

    /// Ray-traced meaning of a label next to the blocker: on the wedge close to its blocker
    /// edge or vertex, points just off either side see the light (sampled densely, more
    /// densely near its boundary, where the sliver next to an umbral event is) — for an
    /// umbral event all hidden on exactly one side, for a penumbral one all visible on
    /// exactly one side. Skipped where the blocker hides the event's own ray.
    fn assert_local_meaning(m: &Mesh, light: &LocalLight, e: &ShadowEvent) {
        let LocalLight::Polygon { vertices: lv, .. } = light else { return };
        let (l, s) = (e.f[0] + (e.f[1] - e.f[0]) * 0.5, e.s[0] + (e.s[1] - e.s[0]) * 0.5);
        let q = s + (s - l) * 0.05;
        let n = (e.f[1] - e.f[0] + e.s[1] - e.s[0]).cross(s - l).normalize();
        let eps = (s - l).length() * 0.05 * 0.01;
        let c = lv.iter().copied().sum::<Vec3>() / lv.len() as f32;
        let mut samples = Vec::new();
        for i in 0..lv.len() {
            let (a, b) = (lv[i], lv[(i + 1) % lv.len()]);
            for k in 0..400 {
                let p = a + (b - a) * (k as f32 / 400.0);
                samples.push(p + (c - p) * 1e-4);
            }
            for r in 1..8 {
                for k in 0..20 {
                    samples.push(c + (a + (b - a) * (k as f32 / 20.0) - c) * (r as f32 / 8.0));
                }
            }
        }
        let blocked = |from: Vec3, to: Vec3| {
            (0..m.triangles.len()).any(|f| {
                let [a, b, c] = m.triangle(f).map(|v| v.as_dvec3());
                let (o, d) = (from.as_dvec3(), (to - from).as_dvec3());
                let (e1, e2) = (b - a, c - a);
                let p = d.cross(e2);
                let det = e1.dot(p);
                if det.abs() < 1e-14 {
                    return false;
                }
                let t0 = o - a;
                let u = t0.dot(p) / det;
                let qv = t0.cross(e1);
                let v = d.dot(qv) / det;
                let t = e2.dot(qv) / det;
                u >= 0.0 && v >= 0.0 && u + v <= 1.0 && t > 1e-9 && t < 1.0 - 1e-9
            })
        };
        if blocked(l, s + (l - s) * 1e-4) {
            // The blocker hides its own event on this ray (the store's 1D clipping drops it).
            return;
        }
        let hidden = |p: Vec3| samples.iter().filter(|&&x| blocked(p, x)).count();
        let (h0, h1) = (hidden(q + n * eps), hidden(q - n * eps));
        let all = samples.len();
        match e.kind {
            EdgeKind::ShadowUmbral => assert!((h0 == all) != (h1 == all), "{:?}: {h0} and {h1} of {all} hidden; f {:?} s {:?} light {lv:?}", e.generator, e.f, e.s),
            _ => assert!((h0 == 0) != (h1 == 0), "{:?}: {h0} and {h1} of {all} hidden", e.generator),
        }
    }

    #[test]
    fn point_light_events_are_silhouettes_and_boundaries() {
        let m = cube(Vec3::ZERO, Vec3::ONE);
        let trees = MeshEdgeTrees::build(&m, &NoProgress);
        let l = LocalLight::Point(Vec3::new(0.3, 4.0, 0.2));
        let ev = find_events(&m, &trees, None, &l);
        assert_eq!(ev, find_events_brute(&m, None, &l));
        // From above, the top face's 4 edges are the silhouette (the sides are edge-on
        // from nowhere here, so they face away).
        assert_eq!(ev.len(), 4);
        assert!(ev.iter().all(|e| e.kind == EdgeKind::ShadowHard && e.s[0].y == 1.0 && e.s[1].y == 1.0));
    }

    #[test]
    fn labels_follow_the_sides_of_the_plane() {
        // 2D picture in the x-y plane (z is the edge direction): light from x=-1..1 at y=1,
        // a blocker edge at (0.2, 0.5) running along z, its surface leaving towards -x.
        let a = Vec3::new(0.2, 0.5, 0.0);
        let b = Vec3::new(0.2, 0.5, 1.0);
        // One face leaving a→b towards -x in the plane y = 0.5, facing down: its inward
        // direction n0 × (b - a) = -y × z = -x.
        let n0 = -Vec3::Y;
        let left = Vec3::new(-1.0, 1.0, 0.5);
        let right = Vec3::new(1.0, 1.0, 0.5);
        // Through the left light end: the light lies above, the blocker below → penumbral.
        let k = ve_label(&[left, right], 0, a, b, n0, None);
        assert_eq!(k, Some(EdgeKind::ShadowPenumbral));
        // Through the right light end: the light (left end) and the blocker lie on the same
        // side → umbral.
        let k = ve_label(&[right, left], 0, a, b, n0, None);
        assert_eq!(k, Some(EdgeKind::ShadowUmbral));
    }
}
