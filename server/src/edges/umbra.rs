//! Where an umbral event stops bounding the umbra (paper 000 §6.3 and Appendix A).
//!
//! An umbral event (VE or EV, light and blocker on the same side of its plane) bounds the
//! umbra next to its blocker edge or vertex, but its wedge runs on to infinity. Behind a
//! blocker narrower than the light the umbra closes: the umbral wedges of opposite sides
//! cross, and past the crossing each one lies in the penumbra (it still marks where one
//! light vertex or edge appears, a D1 discontinuity, but with part of the light visible
//! on both sides). Those parts are not umbral shadow edges.
//!
//! Along a ray of an umbral event `W` (light point `v` through the blocker), leaving the
//! umbra means some light point becomes visible, and the first light to appear does so at
//! a light vertex past a blocker edge or along a light edge past a blocker vertex: on the
//! wedge of *another umbral event* `W'` of the same light and blocker. Not all of `W'`
//! counts — only its *effective* part, where its own light point really is at the edge of
//! visibility: beyond its blocker edge or vertex, on rays the blocker does not hide before
//! it, and before the blocker is met again (past that the light point is hidden anyway).
//! That part is what the 1D clipping of `W'` against its own blocker leaves ([`super::clip1d`]
//! on the blocker's pieces). So the umbra along a ray of `W` ends at its first crossing with
//! another umbral event's effective part, and those crossings, as segments in `W`'s
//! canonical coordinates ([`super::wedge`]), are added to `W`'s 1D clipping as pieces that
//! hide without showing: the receivers' shadow edges past them are dropped.
//!
//! For a convex blocker this is exact: the umbra is the intersection of the shadows of the
//! light's vertices, a convex set whose faces are the umbral VE wedges, and a ray of a face
//! leaves it through another face. For other blockers the umbra can also end at EEE events
//! (a light edge seen through a gap between two blocker edges), which the paper's method
//! does not find (§6.3), and a wedge can lie outside the umbra from its start when the
//! light shows past another part of the blocker; both are left as they are.
//!
//! A light edge parallel to blocker edges (a cylinder's axis, a box's edges) makes the VE
//! events of both its ends and the EV events between them one plane, where the umbra is
//! bounded by rays *within* that plane: the boundary ray of the next, transversal, event
//! (through the end of the parallel run). Such a ray lies in `W`'s plane, so points within
//! rounding of a plane count as on it and a polygon edge lying in the plane is a crossing.
//! Events in exactly one plane are not crossed with each other.
//!
//! Everything here depends only on the light, the blocker and its events — not on the
//! receivers — so it is computed with the pair's events and reused until they change. It
//! costs a plane test per pair of umbral events (both wedges must straddle the other's
//! plane before any polygon is cut), run in parallel over events.
use super::clip1d::{self, ClipScratch, Seg};
use super::events::{Generator, ShadowEvent};
use super::wedge::{Piece, Wedge};
use super::EdgeKind;
use glam::{DAffine3, DVec2, DVec3};
use rayon::prelude::*;

/// How far (in `μ`, multiples of the light–blocker distance along each ray) an effective
/// part that the blocker never closes is followed. Receivers farther than a million times
/// the light–blocker distance would keep umbral edges past the umbra.
const FAR: f64 = 1e6;

/// Per event, the lower envelope of the crossings that end its umbra, as segments in the
/// event's canonical coordinates (none for events that are not umbral).
#[derive(Debug, Clone, Default)]
pub struct UmbraEnds {
    off: Vec<u32>,
    segs: Vec<Seg>,
}

impl UmbraEnds {
    /// The segments of event `i` (empty when there are none, or nothing was computed).
    pub fn of(&self, i: usize) -> &[Seg] {
        match (self.off.get(i), self.off.get(i + 1)) {
            (Some(&a), Some(&b)) => &self.segs[a as usize..b as usize],
            _ => &[],
        }
    }

    pub fn len(&self) -> usize {
        self.segs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.segs.is_empty()
    }
}

/// An umbral event in the blocker's space: its wedge, plane, effective part (convex
/// polygons) and the outline of its whole part beyond the blocker (for culling).
struct Umbral {
    index: usize,
    generator: Generator,
    wedge: Wedge,
    /// Unit normal and a point of the plane.
    n: DVec3,
    c: DVec3,
    parts: Vec<Vec<DVec3>>,
    outline: [DVec3; 4],
    /// Light vertices of the event (one for VE, the light edge's two for EV).
    light: (u32, Option<u32>),
}

/// The point of ray `u` at depth `mu` in canonical coordinates.
fn on_ray(u: f64, mu: f64) -> DVec2 {
    DVec2::new(1.0 - u, u) * mu
}

impl Umbral {
    fn new(index: usize, ev: &ShadowEvent, blocker_pieces: &[Piece], light_vertices: usize, scratch: &mut ClipScratch) -> Option<Umbral> {
        let wedge = Wedge::new(ev, &DAffine3::IDENTITY)?;
        let n = wedge.d0.cross(wedge.d1).normalize();
        let start = |u: f64| if wedge.ev { DVec2::ZERO } else { on_ray(u, wedge.mu_blocker) };
        // The blocker's own envelope on the event: rays hidden before the blocker (a front
        // piece nearest) have no effective part; elsewhere it runs to the first piece
        // beyond, or to FAR where there is none.
        let segs: Vec<Seg> = blocker_pieces.iter().map(|p| Seg { a: p.a, b: p.b }).collect();
        let mut runs = Vec::new();
        clip1d::visible(&segs, &mut runs, scratch);
        let mut spans: Vec<(f64, f64, Option<usize>)> = Vec::with_capacity(2 * runs.len() + 1);
        let mut at = 0.0;
        for r in &runs {
            if r.u0 > at {
                spans.push((at, r.u0, None));
            }
            spans.push((r.u0, r.u1, Some(r.piece)));
            at = r.u1;
        }
        if at < 1.0 {
            spans.push((at, 1.0, None));
        }
        let mut parts = Vec::with_capacity(spans.len());
        for (u0, u1, piece) in spans {
            let (e0, e1) = match piece {
                Some(k) if !blocker_pieces[k].beyond => continue,
                Some(k) => (clip1d::point_at(&segs[k], u0), clip1d::point_at(&segs[k], u1)),
                None => (on_ray(u0, FAR), on_ray(u1, FAR)),
            };
            let mut poly = vec![start(u0)];
            if !wedge.ev {
                poly.push(start(u1));
            }
            poly.push(e1);
            poly.push(e0);
            parts.push(poly.into_iter().map(|q| wedge.point(q)).collect());
        }
        let outline = [start(0.0), start(1.0), on_ray(1.0, FAR), on_ray(0.0, FAR)].map(|q| wedge.point(q));
        let k = light_vertices as u32;
        let light = match ev.generator {
            Generator::VE { vertex, .. } => (vertex, None),
            Generator::EV { light_edge, .. } => (light_edge, Some((light_edge + 1) % k)),
            Generator::Point { .. } => return None,
        };
        Some(Umbral { index, generator: ev.generator, c: wedge.c, wedge, n, parts, outline, light })
    }

    /// Signed distance to the plane, zero within rounding of the point's distance from
    /// the plane's reference point: a polygon edge that lies in the plane (the boundary
    /// ray of one event through a vertex of another's plane) is found as lying in it.
    fn side(&self, p: DVec3) -> f64 {
        let r = p - self.c;
        let s = r.dot(self.n);
        if s.abs() <= 1e-12 * r.length() {
            0.0
        } else {
            s
        }
    }

    /// Whether the points lie on both sides of the plane, or touch it from one side.
    fn straddled_by(&self, pts: &[DVec3]) -> bool {
        let (mut pos, mut neg, mut zero) = (false, false, false);
        for &p in pts {
            let s = self.side(p);
            pos |= s > 0.0;
            neg |= s < 0.0;
            zero |= s == 0.0;
        }
        (pos && neg) || (zero && (pos || neg))
    }

    fn has_light_vertex(&self, v: u32) -> bool {
        self.light.0 == v || self.light.1 == Some(v)
    }
}

/// Pairs whose crossing runs through a point both wedges are made of (a shared light
/// vertex, blocker edge or blocker vertex): it passes through the apex of one fan, or
/// along the line both start from, and ends nothing.
fn related(a: &Umbral, b: &Umbral, edge_has: &impl Fn(u32, u32) -> bool) -> bool {
    use Generator::*;
    match (a.generator, b.generator) {
        (VE { vertex: v, edge: e }, VE { vertex: v2, edge: e2 }) => v == v2 || e == e2,
        (VE { vertex: v, edge: e }, EV { vertex: w, .. }) => b.has_light_vertex(v) || edge_has(e, w),
        (EV { vertex: w, .. }, VE { vertex: v, edge: e }) => a.has_light_vertex(v) || edge_has(e, w),
        (EV { light_edge: j, vertex: w }, EV { light_edge: j2, vertex: w2 }) => w == w2 || j == j2,
        _ => true,
    }
}

/// The part of convex polygon `poly` (3D, on another plane) on the plane of `w`, as a
/// segment in `w`'s canonical coordinates, clipped to `w`'s part beyond its blocker.
fn crossing(w: &Umbral, poly: &[DVec3]) -> Option<Seg> {
    let mut pts: [DVec3; 2] = [DVec3::ZERO; 2];
    let mut k = 0;
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let (sp, sq) = (w.side(p), w.side(q));
        if sp == 0.0 {
            if k < 2 {
                pts[k] = p;
            }
            k += 1;
        } else if sq != 0.0 && (sp > 0.0) != (sq > 0.0) {
            if k < 2 {
                pts[k] = p + (q - p) * (sp / (sp - sq));
            }
            k += 1;
        }
    }
    if k < 2 {
        return None;
    }
    let (a, b) = (w.wedge.coords(pts[0]), w.wedge.coords(pts[1]));
    w.wedge.clip_beyond(a, b).map(|(a, b)| Seg { a, b })
}

/// The umbra ends of every umbral event of one light–blocker pair. `blocker_pieces(i)` are
/// the pieces event `i` cuts from its own blocker ([`super::wedge::search`], the blocker's
/// own faces at the event left out); `edge_has(e, w)` says whether blocker edge `e` ends
/// at blocker vertex `w`.
pub fn umbra_ends<'a>(
    events: &[ShadowEvent],
    blocker_pieces: impl Fn(usize) -> &'a [Piece] + Sync,
    light_vertices: usize,
    edge_has: impl Fn(u32, u32) -> bool + Sync,
) -> UmbraEnds {
    let umbral: Vec<Umbral> = events
        .par_iter()
        .enumerate()
        .filter(|(_, e)| e.kind == EdgeKind::ShadowUmbral)
        .map_init(ClipScratch::default, |s, (i, e)| Umbral::new(i, e, blocker_pieces(i), light_vertices, s))
        .flatten()
        .collect();
    let ends: Vec<(usize, Vec<Seg>)> = umbral
        .par_iter()
        .map_init(
            || (ClipScratch::default(), Vec::new(), Vec::new()),
            |(scratch, found, runs), w| {
                found.clear();
                for o in &umbral {
                    if std::ptr::eq(o, w) || related(w, o, &edge_has) || w.n.cross(o.n).length_squared() < 1e-18 {
                        continue;
                    }
                    if !o.straddled_by(&w.outline) || !w.straddled_by(&o.outline) {
                        continue;
                    }
                    for poly in &o.parts {
                        if w.straddled_by(poly) {
                            found.extend(crossing(w, poly));
                        }
                    }
                }
                // Only the nearest crossing on each ray matters: keep the lower envelope.
                runs.clear();
                clip1d::visible(found, runs, scratch);
                let env = runs
                    .iter()
                    .map(|r| {
                        let s = &found[r.piece];
                        Seg { a: clip1d::point_at(s, r.u0), b: clip1d::point_at(s, r.u1) }
                    })
                    .collect();
                (w.index, env)
            },
        )
        .collect();
    let mut per: Vec<Vec<Seg>> = vec![Vec::new(); events.len()];
    for (i, v) in ends {
        per[i] = v;
    }
    let mut off = Vec::with_capacity(events.len() + 1);
    let mut segs = Vec::new();
    off.push(0);
    for v in per {
        segs.extend(v);
        off.push(segs.len() as u32);
    }
    UmbraEnds { off, segs }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edges::events::{find_events, LocalLight, VertexRings};
    use crate::edges::face_bvh::FaceBvh;
    use crate::edges::geometric::MeshEdgeTrees;
    use crate::edges::wedge::{search, SearchScratch};
    use edgepoint_scene::{light::polygon_normal, Mesh, NoProgress, NO_FACE};
    use glam::Vec3;

    /// Whether the segment `p q` meets the box `[lo, hi]` (slabs, f64).
    fn segment_meets_box(p: DVec3, q: DVec3, lo: DVec3, hi: DVec3) -> bool {
        let d = q - p;
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        for a in 0..3 {
            if d[a].abs() < 1e-300 {
                if p[a] < lo[a] || p[a] > hi[a] {
                    return false;
                }
                continue;
            }
            let (u, v) = ((lo[a] - p[a]) / d[a], (hi[a] - p[a]) / d[a]);
            t0 = t0.max(u.min(v));
            t1 = t1.min(u.max(v));
        }
        t0 < t1
    }

    /// A box under a larger square light turned by 30°: the umbra is the intersection of the
    /// box's shadows from the four light vertices, a convex region that closes below the
    /// box. Every ray of every umbral event must end, and exactly where the umbra does:
    /// just before the end every light vertex is hidden by the box, just after one is not.
    #[test]
    fn umbral_events_end_where_the_umbra_of_a_convex_blocker_closes() {
        let (lo, hi) = (Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5));
        let m: Mesh = edgepoint_scene::builtin::shapes::cuboid(lo, hi);
        let (s, c) = std::f32::consts::FRAC_PI_6.sin_cos();
        let mut lv: Vec<Vec3> =
            [(-1.0, -1.0), (-1.0, 1.0), (1.0, 1.0), (1.0, -1.0)].iter().map(|&(x, z)| Vec3::new(c * x - s * z, 3.0, s * x + c * z)).collect();
        if polygon_normal(&lv).y > 0.0 {
            lv.reverse();
        }
        let light = LocalLight::Polygon { normal: polygon_normal(&lv).normalize(), centroid: Vec3::new(0.0, 3.0, 0.0), vertices: lv.clone() };
        let trees = MeshEdgeTrees::build(&m, &NoProgress);
        let rings = VertexRings::build(&m);
        let events = find_events(&m, &trees, Some(&rings), &light);
        // The pieces each event cuts from the box itself, as the shadow store finds them.
        let bvh = FaceBvh::build(&m, &NoProgress);
        let mut scratch = SearchScratch::default();
        let pieces: Vec<Vec<Piece>> = events
            .iter()
            .map(|e| {
                let mut out = Vec::new();
                let own: Vec<u32> = match e.generator {
                    Generator::VE { edge, .. } => {
                        let mut f: Vec<u32> = m.edges[edge as usize].faces.iter().copied().filter(|&f| f != NO_FACE).collect();
                        f.sort_unstable();
                        f
                    }
                    Generator::EV { vertex, .. } => rings.faces_of(vertex).to_vec(),
                    Generator::Point { .. } => Vec::new(),
                };
                if let Some(w) = Wedge::new(e, &DAffine3::IDENTITY) {
                    search(&bvh, &w, &own, &mut out, &mut scratch);
                }
                out
            })
            .collect();
        let ends = umbra_ends(&events, |i| pieces[i].as_slice(), lv.len(), |e, w| m.edges[e as usize].v.contains(&w));
        let (blo, bhi) = (lo.as_dvec3(), hi.as_dvec3());
        // Every light vertex but the event's own (seen exactly past the blocker edge).
        let hidden = |q: DVec3, own: u32| {
            lv.iter().enumerate().all(|(k, v)| k as u32 == own || segment_meets_box(q, v.as_dvec3(), blo, bhi))
        };
        let mut checked = 0;
        for (i, e) in events.iter().enumerate() {
            if e.kind != EdgeKind::ShadowUmbral {
                assert!(ends.of(i).is_empty());
                continue;
            }
            let w = Wedge::new(e, &DAffine3::IDENTITY).unwrap();
            let Generator::VE { vertex: own, .. } = e.generator else { panic!("umbral EV on a convex blocker") };
            // The ends cover every ray of the event.
            let mut cover: Vec<(f64, f64)> = ends
                .of(i)
                .iter()
                .map(|s| {
                    let (a, b) = (crate::edges::wedge::u_of(s.a), crate::edges::wedge::u_of(s.b));
                    (a.min(b), a.max(b))
                })
                .collect();
            cover.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut reach = 0.0;
            for (a, b) in cover {
                assert!(a <= reach + 1e-9, "event {:?}: rays {reach}..{a} never leave the umbra", e.generator);
                reach = f64::max(reach, b);
            }
            assert!(reach >= 1.0 - 1e-9, "event {:?}: rays past {reach} never leave the umbra", e.generator);
            for k in 1..20 {
                let u = k as f64 / 20.0;
                let Some(s) = ends.of(i).iter().find(|s| {
                    let (a, b) = (crate::edges::wedge::u_of(s.a), crate::edges::wedge::u_of(s.b));
                    a.min(b) < u && u < a.max(b)
                }) else {
                    continue;
                };
                let mu = clip1d::mu_at(s, u);
                let at = |m: f64| w.point(on_ray(u, m));
                assert!(hidden(at(mu * (1.0 - 1e-7)), own), "event {:?} ray {u}: not in the umbra before its end at μ {mu}", e.generator);
                assert!(!hidden(at(mu * (1.0 + 1e-7)), own), "event {:?} ray {u}: still in the umbra after its end at μ {mu}", e.generator);
                checked += 1;
            }
        }
        assert!(checked >= 40, "{checked}");
    }
}
