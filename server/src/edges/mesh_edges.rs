//! Shadow edges for the edge-and-point image from the discontinuity mesh (issue 15 item 4;
//! paper 002 §2, paper 003 §3's extremal boundaries).
//!
//! Each side of a mesh edge sees the whole light (*lit*), none of it (*umbra*) or a part
//! (*penumbra*): decided by the pointwise backprojection ([`crate::dmesh::face::visible_at`])
//! just beside the edge's middle, on either side — not from the face's own backprojection,
//! which is taken at one interior point: where the mesh lacks a surface (non-emitter EV
//! surfaces and EEE surfaces with no edge on the light are not built; the EEE polylines
//! stand within a chord tolerance of their curves) one face can hold points that see
//! different amounts of the light, and the edge is what the EPI needs right. A mesh edge is
//!
//! - **extremal** when it separates two of those kinds: lit | penumbra is the penumbra's
//!   outer boundary ([`EdgeKind::ShadowPenumbral`]), umbra | penumbra the umbra's
//!   ([`EdgeKind::ShadowUmbral`]), and lit | umbra a boundary with no penumbra at all (a
//!   blocker touching the receiver: a hard step, sent as umbral with a zero penumbra, so the
//!   EPI keeps it as a barrier everywhere);
//! - **interior** when both sides are in penumbra: the irradiance is continuous there (D1 or
//!   D2), and only the edges across which its slope changes steeply are kept — where the
//!   jump of the slope across the edge is at least [`STEEP_SLOPE_JUMP`] of the penumbra's
//!   mean slope (the unoccluded irradiance over the penumbra's width), measured with the
//!   exact irradiance of the mesh on either side. Paper 003 keeps such detail only "where
//!   needed"; it is sent with the penumbral kind (the EPI has no third soft kind; both are
//!   barriers only where the penumbra is narrow on screen, [`crate::epi::soft`]).
//!
//! Each edge carries its penumbra's extent at its ends, as the renderer's own shadow edges
//! do ([`super::simplify::penumbra_width_of`], the same estimate, from the mesh segment's
//! generator: the blocker edge of a VE surface, the blocker vertex of an EV one).
//!
//! An algorithm module: the mesh and its geometry in, world-space segments out.
use super::simplify::penumbra_width_of;
use super::{EdgeKind, EdgeSegment};
use crate::dmesh::receiver::Receiver;
use crate::dmesh::face::{none_can_hide, visible_at, visible_in};
use crate::dmesh::geometry::Geometry;
use crate::dmesh::segments::{Generator, Runs};
use std::collections::HashMap;
use crate::dmesh::{DiscontinuityMesh, ProgressSteps, ReceiverMesh};
use edgepoint_scene::NoProgress;
use edgepoint_scene::backprojection::{LightPlane, Visible};
use glam::{DVec2, DVec3, Vec3};
use rayon::prelude::*;

/// An interior edge is kept when its slope jump is at least this fraction of the
/// penumbra's mean slope: half of it is a kink that interpolation across the edge would
/// visibly round off over the two pixels it blurs, while the many faint D2 lines of a
/// finely tessellated blocker (slope jumps of a few percent) are left out.
pub const STEEP_SLOPE_JUMP: f64 = 0.5;

/// What a face of the mesh sees of its light.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lighting {
    /// The whole light.
    Lit,
    /// A part of it.
    Penumbra,
    /// None of it.
    Umbra,
}

/// What receiver point `q` (receiver frame) of mesh `m` sees of `light`, with the receiver's
/// shaft blockers.
pub fn lighting_at(m: &ReceiverMesh, g: &Geometry, light: &LightPlane, q: DVec2, hit: &mut Vec<u32>) -> Lighting {
    lighting_of(visible_at(g, light, &m.receiver, &m.blockers, q, hit), hit)
}

/// What a visible part (`None`: none) and the blockers that hid some of it say.
fn lighting_of(vis: Option<Visible>, hit: &[u32]) -> Lighting {
    match vis {
        None => Lighting::Umbra,
        Some(v) if v.is_empty() => Lighting::Umbra,
        Some(_) if hit.is_empty() => Lighting::Lit,
        Some(_) => Lighting::Penumbra,
    }
}

/// [`lighting_at`] with the receiver's blockers in runs in list order ([`visible_in`]: the
/// same answer bit for bit, runs of blockers off the point's pyramid passed over whole; a
/// floor under a table has thousands of blockers, and each of its edges looks at up to six
/// points).
fn lighting_in(g: &Geometry, light: &LightPlane, r: &Receiver, runs: &Runs, q: DVec2, hit: &mut Vec<u32>) -> Lighting {
    lighting_of(visible_in(g, light, r, runs, q, hit), hit)
}

/// How far beside an edge its sides are looked at, in mesh tolerances (10⁻⁹ of the scene's
/// size each): far above the arrangement's snapping, far below any feature the EPI draws.
pub const SIDE_OFFSET_TOLERANCES: f64 = 1000.0;

/// A shadow edge of the mesh with its penumbra at its ends (world vectors across it), and
/// what paper 003's estimate of it needs ([`crate::edges::simplify`]): its light and the
/// blocker segment whose shadow it bounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshShadowEdge {
    pub edge: EdgeSegment,
    pub penumbra: [Vec3; 2],
    /// The light's index in the mesh's lights.
    pub light: u32,
    /// The blocker segment of the edge's generator (world; a vertex as a segment of no
    /// length, a contact the edge itself).
    pub blocker: (DVec3, DVec3),
}

/// How many mesh edges went which way.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MeshEdgeCounts {
    pub penumbral: usize,
    pub umbral: usize,
    /// Lit | umbra: no penumbra between them.
    pub hard: usize,
    /// Interior edges kept (steep) and left out.
    pub interior_steep: usize,
    pub interior_smooth: usize,
}

/// The points just beside the middle of edge `q0 q1` on its left and right
/// ([`SIDE_OFFSET_TOLERANCES`] away), when both lie in the receiver and the edge has a length.
pub fn sides(r: &Receiver, q0: DVec2, q1: DVec2) -> Option<[DVec2; 2]> {
    let nu = (q1 - q0).perp().try_normalize()?;
    let (mid, eps) = (0.5 * (q0 + q1), SIDE_OFFSET_TOLERANCES * r.tol);
    let s = [mid + nu * eps, mid - nu * eps];
    s.iter().all(|q| r.contains(*q)).then_some(s)
}

/// The light's largest corner-to-corner distance and its centre.
fn diameter_and_centre(light: &LightPlane) -> (f64, DVec3) {
    let c: Vec<DVec3> = light.corners.iter().map(|q| light.lift(*q)).collect();
    let d = c.iter().flat_map(|a| c.iter().map(move |b| (*a - *b).length())).fold(0.0, f64::max);
    (d, c.iter().copied().sum::<DVec3>() / c.len() as f64)
}

/// The blocker segment of a generator (a blocker vertex counts as a segment of no length)
/// for the mesh edge `at` (world).
fn blocker_segment(g: &Geometry, gen: &Generator, at: (DVec3, DVec3)) -> (DVec3, DVec3) {
    match *gen {
        Generator::Ve { edge, .. } => (g.pos[edge.0 as usize], g.pos[edge.1 as usize]),
        Generator::Ev { vertex, .. } => (g.pos[vertex as usize], g.pos[vertex as usize]),
        // The first of the two blocker edges: both bound the same corner of the visible part.
        Generator::Eee { edges: (edge, _), .. } => (g.pos[edge.0 as usize], g.pos[edge.1 as usize]),
        // The blocker meets the receiver along the mesh edge `at` itself: no penumbra.
        Generator::Contact { .. } => at,
    }
}

/// Appends the mesh's shadow edges for the EPI to `out`, each with its penumbra at its ends
/// (world vectors across it; zero for a hard edge), in the order lights × receivers × mesh
/// edges.
/// Receivers in parallel (on the caller's pool), the result in that order whatever the split.
pub fn mesh_shadow_edges(mesh: &DiscontinuityMesh, g: &Geometry, out: &mut Vec<MeshShadowEdge>) -> MeshEdgeCounts {
    let receivers = mesh.receiver_ids();
    let mut counts = MeshEdgeCounts::default();
    for e in receivers_shadow_edges(mesh, g, &receivers, None, &ProgressSteps::new(&NoProgress)) {
        counts = counts + e.counts;
        out.extend(e.edges);
    }
    counts
}

/// What one arrangement edge of a receiver gave: a shadow edge of some kind, or none (an
/// interior edge that is not steep, both sides alike, or no room beside it).
#[derive(Debug, Clone, Copy)]
pub enum Decision {
    Penumbral(MeshShadowEdge),
    Umbral(MeshShadowEdge),
    /// Lit | umbra.
    Hard(MeshShadowEdge),
    Steep(MeshShadowEdge),
    Smooth,
    None,
}

impl Decision {
    fn edge(&self) -> Option<MeshShadowEdge> {
        match self {
            Decision::Penumbral(e) | Decision::Umbral(e) | Decision::Hard(e) | Decision::Steep(e) => Some(*e),
            Decision::Smooth | Decision::None => None,
        }
    }

    fn count(&self, c: &mut MeshEdgeCounts) {
        match self {
            Decision::Penumbral(_) => c.penumbral += 1,
            Decision::Umbral(_) => c.umbral += 1,
            Decision::Hard(_) => c.hard += 1,
            Decision::Steep(_) => c.interior_steep += 1,
            Decision::Smooth => c.interior_smooth += 1,
            Decision::None => {}
        }
    }
}

/// A receiver's arrangement edges (their ends' bits and generator) with what each gave.
pub type Decisions = HashMap<([u64; 4], Generator), Decision>;

/// A receiver's decisions before a move, by (light, triangle).
pub type OldDecisions<'d> = dyn Fn((u32, u32)) -> Option<&'d Decisions> + Sync + 'd;

/// One receiver's shadow edges, in its arrangement's order, with their counts and every
/// arrangement edge's decision.
#[derive(Debug, Clone, Default)]
pub struct ReceiverShadowEdges {
    pub counts: MeshEdgeCounts,
    pub edges: Vec<MeshShadowEdge>,
    pub decisions: Decisions,
    /// Of the decisions, those kept from before the move.
    pub kept: usize,
}

/// The object a move displaced, for the receivers whose mesh the move replaced: `old` the
/// geometry before it, `object` the object, `boxes` its box before and after.
pub struct Moved<'a> {
    pub old: &'a Geometry,
    pub object: u32,
    pub boxes: [(DVec3, DVec3); 2],
}

/// The shadow edges of each of `receivers` (light, triangle; none for one with no mesh), as
/// [`mesh_shadow_edges`] makes them, in parallel on the caller's pool: after a move only the
/// receivers whose mesh changed need theirs made again. With `reuse`, an arrangement edge a
/// receiver had before the move (same ends, same generator, not on the moved object) keeps
/// its old decision when the moved object, where it was and where it is, hides nothing from
/// any point the decision looked at (its two sides and the steep test's four points: the
/// backprojection passes each of its triangles over there, so the answer is the one without
/// it, which did not change); `reuse.1` gives a receiver's old decisions (none for the
/// moved object's own receivers, which moved).
/// Each receiver done is counted to `steps`.
pub fn receivers_shadow_edges<'d>(mesh: &DiscontinuityMesh, g: &Geometry, receivers: &[(u32, u32)], reuse: Option<(&Moved, &OldDecisions<'d>)>, steps: &ProgressSteps) -> Vec<ReceiverShadowEdges> {
    let lights: Vec<(f64, DVec3)> = mesh.lights.iter().map(diameter_and_centre).collect();
    receivers
        .par_iter()
        .map(|&(l, t)| {
            steps.one();
            let mut out = ReceiverShadowEdges::default();
            if let Some(m) = mesh.meshes.get(l as usize).and_then(|ms| ms.get(t as usize)).and_then(|m| m.as_deref()) {
                let old = reuse.and_then(|(moved, old)| old((l, t)).map(|d| (moved, d)));
                receiver_edges(m, g, (l, &mesh.lights[l as usize]), lights[l as usize], old, &mut out);
            }
            out
        })
        .collect()
}

impl std::ops::Add for MeshEdgeCounts {
    type Output = MeshEdgeCounts;
    fn add(self, o: Self) -> Self {
        MeshEdgeCounts {
            penumbral: self.penumbral + o.penumbral,
            umbral: self.umbral + o.umbral,
            hard: self.hard + o.hard,
            interior_steep: self.interior_steep + o.interior_steep,
            interior_smooth: self.interior_smooth + o.interior_smooth,
        }
    }
}

/// [`mesh_shadow_edges`] of one receiver mesh (see [`receivers_shadow_edges`] for `old`).
fn receiver_edges(m: &ReceiverMesh, g: &Geometry, (li, light): (u32, &LightPlane), (diameter, centre): (f64, DVec3), old: Option<(&Moved, &Decisions)>, out: &mut ReceiverShadowEdges) {
    if m.umbra || m.segments.is_empty() {
        return;
    }
    let a = &m.arrangement;
    let r = &m.receiver;
    let object = g.object[r.tri as usize];
    let mut hit = Vec::new();
    // The blockers' runs once the first decision is to be made (none when all are kept).
    let mut runs = None;
    // The moved object's triangles, for the reuse test (all of them: a superset of those
    // among the blockers before or after, passed over only if each one is).
    let moved: Vec<u32> = old.map_or_else(Vec::new, |(mv, _)| g.object_tris(mv.object).collect());
    let moved_verts = old.map(|(mv, _)| g.object_vertices(mv.object));
    for (ends, gen) in &a.edges {
        let Some(gen) = gen else { continue };
        let (q0, q1) = (a.vertices[ends[0] as usize], a.vertices[ends[1] as usize]);
        let key = ([q0.x.to_bits(), q0.y.to_bits(), q1.x.to_bits(), q1.y.to_bits()], *gen);
        let (p0, p1) = (r.to3(q0), r.to3(q1));
        let (s0, s1) = blocker_segment(g, gen, (p0, p1));
        let width = |p: DVec3| penumbra_width_of(diameter, centre, p, r.n, s0, s1);
        let mid = 0.5 * (q0 + q1);
        let kept = old.and_then(|(mv, decisions)| {
            let d = decisions.get(&key)?;
            if moved_verts.clone().into_iter().flatten().any(|v| gen.uses_vertex(v)) {
                return None;
            }
            let mut points: Vec<DVec2> = sides(r, q0, q1).map_or_else(Vec::new, |s| s.to_vec());
            points.extend(steep_points(r, mid, q1 - q0, width(r.to3(mid))).into_iter().flatten());
            // The boxes grown by the tolerance, as the update's faces have them: a box
            // touching a side of the pyramid within rounding may hold a triangle that
            // clips a sliver there.
            let [b0, b1] = mv.boxes.map(|b| (b.0 - r.tol, b.1 + r.tol));
            points.iter().all(|q| none_can_hide(mv.old, light, r, &moved, b0, *q) && none_can_hide(g, light, r, &moved, b1, *q))
                .then_some(*d)
        });
        out.kept += kept.is_some() as usize;
        let d = kept.unwrap_or_else(|| {
            let Some([ql, qr]) = sides(r, q0, q1) else { return Decision::None };
            let runs = &*runs.get_or_insert_with(|| Runs::new(g, &m.blockers, false));
            let (ll, lr) = (lighting_in(g, light, r, runs, ql, &mut hit), lighting_in(g, light, r, runs, qr, &mut hit));
            let across = r.n.cross(p1 - p0).try_normalize().unwrap_or(DVec3::ZERO);
            let penumbra = [(across * width(p0)).as_vec3(), (across * width(p1)).as_vec3()];
            let edge = |kind: EdgeKind, penumbra: [Vec3; 2]| MeshShadowEdge { edge: EdgeSegment { a: p0.as_vec3(), b: p1.as_vec3(), kind, object }, penumbra, light: li, blocker: (s0, s1) };
            use Lighting::*;
            match (ll, lr) {
                (Lit, Penumbra) | (Penumbra, Lit) => Decision::Penumbral(edge(EdgeKind::ShadowPenumbral, penumbra)),
                (Umbra, Penumbra) | (Penumbra, Umbra) => Decision::Umbral(edge(EdgeKind::ShadowUmbral, penumbra)),
                (Lit, Umbra) | (Umbra, Lit) => Decision::Hard(edge(EdgeKind::ShadowUmbral, [Vec3::ZERO; 2])),
                (Penumbra, Penumbra) => {
                    if steep(g, light, r, runs, mid, q1 - q0, width(r.to3(mid))) {
                        Decision::Steep(edge(EdgeKind::ShadowPenumbral, penumbra))
                    } else {
                        Decision::Smooth
                    }
                }
                // Both sides see the same whole light or none of it: nothing changes across.
                _ => Decision::None,
            }
        });
        d.count(&mut out.counts);
        out.edges.extend(d.edge());
        out.decisions.insert(key, d);
    }
}

/// Whether the irradiance's slope across an interior edge (midpoint `mid`, direction `dir`,
/// receiver frame) jumps by at least [`STEEP_SLOPE_JUMP`] of the penumbra's mean slope
/// (unoccluded irradiance over the penumbra's `width`): one-sided differences of the exact
/// irradiance at 1 and 2 steps of `width / 16` on each side. An edge whose steps leave the
/// receiver, or whose penumbra has no width, is kept. The receiver's blockers are in `runs`,
/// in list order.
pub fn steep(g: &Geometry, light: &LightPlane, r: &Receiver, runs: &Runs, mid: DVec2, dir: DVec2, width: f64) -> bool {
    let Some(q) = steep_points(r, mid, dir, width) else { return true };
    let delta = width / 16.0;
    let mut hit = Vec::new();
    let mut e = |k: usize| visible_in(g, light, r, runs, q[k], &mut hit).map_or(0.0, |v| v.irradiance());
    let below = (e(1) - e(0)) / delta;
    let above = (e(3) - e(2)) / delta;
    let full = Visible::new(light, r.to3(mid).as_vec3(), r.n.as_vec3()).map_or(0.0, |v| v.irradiance());
    (above - below).abs() >= STEEP_SLOPE_JUMP * full / width
}

/// The points [`steep`] looks at: 2 and 1 steps of `width / 16` below the edge, 1 and 2
/// above; `None` when it keeps the edge without looking (no direction, no width, a step off
/// the receiver).
fn steep_points(r: &Receiver, mid: DVec2, dir: DVec2, width: f64) -> Option<[DVec2; 4]> {
    let nu = dir.perp().try_normalize()?;
    let delta = width / 16.0;
    // (NaN widths too.)
    if delta.is_nan() || delta <= 100.0 * r.tol {
        return None;
    }
    let q = [-2.0, -1.0, 1.0, 2.0].map(|k: f64| mid + nu * (k * delta));
    (r.contains(q[0]) && r.contains(q[3])).then_some(q)
}

#[cfg(test)]
mod tests;
