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
use crate::dmesh::face::{visible_at, visible_in};
use crate::dmesh::segments::Runs;
use crate::dmesh::geometry::Geometry;
use crate::dmesh::segments::Generator;
use crate::dmesh::{DiscontinuityMesh, ReceiverMesh};
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
    match visible_at(g, light, &m.receiver, &m.blockers, q, hit) {
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
    match visible_in(g, light, r, runs, q, hit) {
        None => Lighting::Umbra,
        Some(v) if v.is_empty() => Lighting::Umbra,
        Some(_) if hit.is_empty() => Lighting::Lit,
        Some(_) => Lighting::Penumbra,
    }
}

/// How far beside an edge its sides are looked at, in mesh tolerances (10⁻⁹ of the scene's
/// size each): far above the arrangement's snapping, far below any feature the EPI draws.
pub const SIDE_OFFSET_TOLERANCES: f64 = 1000.0;

/// A shadow edge of the mesh with its penumbra at its ends (world vectors across it), and
/// what paper 003's estimate of it needs ([`crate::edges::simplify`]): its light and the
/// blocker segment whose shadow it bounds.
#[derive(Debug, Clone, Copy)]
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
    let receivers: Vec<(u32, u32)> = mesh.meshes.iter().enumerate().flat_map(|(l, ms)| ms.iter().enumerate().filter(|(_, m)| m.is_some()).map(move |(t, _)| (l as u32, t as u32))).collect();
    let mut counts = MeshEdgeCounts::default();
    for (c, v) in receivers_shadow_edges(mesh, g, &receivers) {
        counts = counts + c;
        out.extend(v);
    }
    counts
}

/// The shadow edges of each of `receivers` (light, triangle; none for one with no mesh), as
/// [`mesh_shadow_edges`] makes them, in parallel on the caller's pool: after a move only the
/// receivers whose mesh changed need theirs made again.
pub fn receivers_shadow_edges(mesh: &DiscontinuityMesh, g: &Geometry, receivers: &[(u32, u32)]) -> Vec<(MeshEdgeCounts, Vec<MeshShadowEdge>)> {
    let lights: Vec<(f64, DVec3)> = mesh.lights.iter().map(diameter_and_centre).collect();
    receivers
        .par_iter()
        .map(|&(l, t)| {
            let (mut c, mut v) = (MeshEdgeCounts::default(), Vec::new());
            if let Some(m) = mesh.meshes.get(l as usize).and_then(|ms| ms.get(t as usize)).and_then(|m| m.as_deref()) {
                receiver_edges(m, g, (l, &mesh.lights[l as usize]), lights[l as usize], &mut c, &mut v);
            }
            (c, v)
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

/// [`mesh_shadow_edges`] of one receiver mesh.
fn receiver_edges(m: &ReceiverMesh, g: &Geometry, (li, light): (u32, &LightPlane), (diameter, centre): (f64, DVec3), counts: &mut MeshEdgeCounts, out: &mut Vec<MeshShadowEdge>) {
    if m.umbra || m.segments.is_empty() {
        return;
    }
    let a = &m.arrangement;
    let r = &m.receiver;
    let object = g.object[r.tri as usize];
    let mut hit = Vec::new();
    let runs = Runs::new(g, &m.blockers, false);
    for (ends, gen) in &a.edges {
        let Some(gen) = gen else { continue };
        let (q0, q1) = (a.vertices[ends[0] as usize], a.vertices[ends[1] as usize]);
        let Some([ql, qr]) = sides(r, q0, q1) else { continue };
        let (ll, lr) = (lighting_in(g, light, r, &runs, ql, &mut hit), lighting_in(g, light, r, &runs, qr, &mut hit));
        let (p0, p1) = (r.to3(q0), r.to3(q1));
        let (s0, s1) = blocker_segment(g, gen, (p0, p1));
        let width = |p: DVec3| penumbra_width_of(diameter, centre, p, r.n, s0, s1);
        let across = r.n.cross(p1 - p0).try_normalize().unwrap_or(DVec3::ZERO);
        let penumbra = [(across * width(p0)).as_vec3(), (across * width(p1)).as_vec3()];
        use Lighting::*;
        let (kind, penumbra) = match (ll, lr) {
            (Lit, Penumbra) | (Penumbra, Lit) => {
                counts.penumbral += 1;
                (EdgeKind::ShadowPenumbral, penumbra)
            }
            (Umbra, Penumbra) | (Penumbra, Umbra) => {
                counts.umbral += 1;
                (EdgeKind::ShadowUmbral, penumbra)
            }
            (Lit, Umbra) | (Umbra, Lit) => {
                counts.hard += 1;
                (EdgeKind::ShadowUmbral, [Vec3::ZERO; 2])
            }
            (Penumbra, Penumbra) => {
                let mid = 0.5 * (q0 + q1);
                if steep(m, g, light, &runs, mid, q1 - q0, width(r.to3(mid))) {
                    counts.interior_steep += 1;
                    (EdgeKind::ShadowPenumbral, penumbra)
                } else {
                    counts.interior_smooth += 1;
                    continue;
                }
            }
            // Both sides see the same whole light or none of it: nothing changes across.
            _ => continue,
        };
        out.push(MeshShadowEdge { edge: EdgeSegment { a: p0.as_vec3(), b: p1.as_vec3(), kind, object }, penumbra, light: li, blocker: (s0, s1) });
    }
}

/// Whether the irradiance's slope across an interior edge (midpoint `mid`, direction `dir`,
/// receiver frame) jumps by at least [`STEEP_SLOPE_JUMP`] of the penumbra's mean slope
/// (unoccluded irradiance over the penumbra's `width`): one-sided differences of the exact
/// irradiance at 1 and 2 steps of `width / 16` on each side. An edge whose steps leave the
/// receiver, or whose penumbra has no width, is kept. The receiver's blockers are in `runs`,
/// in list order.
pub fn steep(m: &ReceiverMesh, g: &Geometry, light: &LightPlane, runs: &Runs, mid: DVec2, dir: DVec2, width: f64) -> bool {
    let r = &m.receiver;
    let Some(nu) = dir.perp().try_normalize() else { return true };
    let delta = width / 16.0;
    // (NaN widths too.)
    if delta.is_nan() || delta <= 100.0 * r.tol {
        return true;
    }
    let q = |k: f64| mid + nu * (k * delta);
    if ![-2.0, 2.0].iter().all(|&k| r.contains(q(k))) {
        return true;
    }
    let mut hit = Vec::new();
    let mut e = |k: f64| visible_in(g, light, r, runs, q(k), &mut hit).map_or(0.0, |v| v.irradiance());
    let below = (e(-1.0) - e(-2.0)) / delta;
    let above = (e(2.0) - e(1.0)) / delta;
    let full = Visible::new(light, r.to3(mid).as_vec3(), r.n.as_vec3()).map_or(0.0, |v| v.irradiance());
    (above - below).abs() >= STEEP_SLOPE_JUMP * full / width
}

#[cfg(test)]
mod tests;
