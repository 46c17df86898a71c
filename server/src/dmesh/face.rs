//! The backprojection of each mesh face (paper 002 §4.4, after Drettakis and Fiume): the
//! part of the light visible from the face, computed at a point inside it and kept as the
//! visible polygons, with the blockers that hide part of the light there. Inside a face no
//! discontinuity surface is crossed, so the visible part keeps its combinatorial form and
//! moves continuously; at any point of the face the irradiance is Lambert's formula over
//! the visible part from that point, occluded by the receiver's shaft blockers (which hold
//! every triangle that can hide the light from any point of the face).
use super::geometry::{boxes_meet, Geometry};
use super::receiver::Receiver;
use super::segments::{Runs, Step};
use super::solid;
use edgepoint_scene::backprojection::{LightPlane, Visible};
use glam::{DVec2, DVec3};

#[derive(Debug, Clone, Default)]
pub struct FaceBackprojection {
    /// The interior point it was computed at (receiver frame).
    pub point: DVec2,
    /// The visible part of the light from there: convex pieces in 3D, in the light's plane.
    pub pieces: Vec<Vec<DVec3>>,
    /// The triangles that hide part of the light from there.
    pub occluders: Vec<u32>,
    /// Irradiance per unit radiance at the point.
    pub irradiance: f64,
}

/// The visible part of `light` from receiver point `q` with the shaft's `blockers`, and
/// which of them hid something.
pub fn visible_at<'a>(g: &Geometry, light: &'a LightPlane, r: &Receiver, blockers: &[u32], q: DVec2, hit: &mut Vec<u32>) -> Option<Visible<'a>> {
    hit.clear();
    let mut vis = Visible::new(light, r.to3(q).as_vec3(), r.n.as_vec3())?;
    let pyramid = pyramid_box(&vis);
    let mut solids = Vec::new();
    for &t in blockers {
        if !occlude_by(g, &mut vis, pyramid, t, hit, &mut solids) {
            break;
        }
    }
    Some(vis)
}

/// One blocker's step of [`visible_at`] and [`visible_in`]: `t` clips the visible part
/// unless it is passed over, and is noted in `hit` if it hid something. Whether some of
/// the light is still visible (else the loop ends).
///
/// A triangle of a convex solid ([`solid::Solids::convex`]) that is not passed over brings
/// its whole solid's shadow, subtracted once as one convex polygon (the hull of its corners'
/// shadows: the union of its triangles' shadows, see [`Visible::convex_shadow`]), and the
/// solid's other triangles are skipped; `solids` notes per point each solid met and whether
/// it was projected whole. (A face under a chair subtracted each of its boxes' front
/// triangles, two to six a box, each cutting the pieces further; under a ball, hundreds.)
/// A solid with a corner not between the point and the light is occluded triangle by
/// triangle, as every other blocker.
fn occlude_by(g: &Geometry, vis: &mut Visible, pyramid: (DVec3, DVec3), t: u32, hit: &mut Vec<u32>, solids: &mut Vec<(u32, bool)>) -> bool {
    let convex = g.solids.convex_component(t).map(|c| (c, solids.iter().find(|s| s.0 == c).map(|s| s.1)));
    // A solid subtracted whole already (and some light is left: else the walk had ended).
    if matches!(convex, Some((_, Some(true)))) {
        return true;
    }
    let tri = g.tri(t);
    if passed_over(g, vis, pyramid, t, &tri) {
        return !vis.is_empty();
    }
    // The solid's first triangle not passed over: projected whole if it can be.
    if let Some((c, None)) = convex {
        let shadow = vis.convex_shadow(g.solids.corners[c as usize].iter().map(|v| g.pos[*v as usize]));
        solids.push((c, shadow.is_ok()));
        if let Ok(shadow) = shadow {
            if shadow.is_some_and(|s| vis.subtract(&s)) {
                hit.push(t);
            }
            return !vis.is_empty();
        }
    }
    if vis.occlude(tri) {
        hit.push(t);
    }
    !vis.is_empty()
}

/// [`visible_at`] with the blockers in runs ([`Runs`]): a run, or a group of runs, whose box
/// misses the pyramid's box or lies wholly outside a side or an end of the pyramid is passed
/// over whole — each of its triangles would be ([`Visible::passes_over_box`]). The triangles
/// occlude in the runs' order: with the runs in list order (as the mesh's faces use them) the
/// result is [`visible_at`]'s bit for bit. Under the grid over the dragon a receiver's 18,799
/// faces each tested ~10⁵ blockers one by one.
pub fn visible_in<'a>(g: &Geometry, light: &'a LightPlane, r: &Receiver, runs: &Runs, q: DVec2, hit: &mut Vec<u32>) -> Option<Visible<'a>> {
    hit.clear();
    let mut vis = Visible::new(light, r.to3(q).as_vec3(), r.n.as_vec3())?;
    let pyramid = pyramid_box(&vis);
    let mut solids = Vec::new();
    runs.walk(|step| match step {
        // The box grown by far more than the rounding of a corner's height over a side or
        // an end against its triangles' own (`passes_over` on a triangle that touches a
        // side within rounding may clip a sliver): a box passed over holds only triangles
        // the flat loop passes over.
        Step::Open(b) => {
            let pad = 1e-12 * (b.0.abs().max(b.1.abs()).max_element() + 1.0);
            boxes_meet(*b, pyramid) && !vis.passes_over_box((b.0 - pad, b.1 + pad))
        }
        Step::Triangle(t) => occlude_by(g, &mut vis, pyramid, t, hit, &mut solids),
    });
    Some(vis)
}

/// The box of the pyramid from the point to the visible light.
fn pyramid_box(vis: &Visible) -> (DVec3, DVec3) {
    let (apex, base) = vis.pyramid();
    base.iter().fold((apex, apex), |(lo, hi), c| (lo.min(*c), hi.max(*c)))
}

/// Whether [`visible_at`] passes blocker `t` (corners `tri`) over at `vis`'s point without
/// clipping it: only triangles meeting the pyramid from the point to the light can hide any
/// of it, and a box test first spares the clipping of the others (the shaft holds far
/// more); a solid's triangle turned away from the point hides nothing a nearer face of the
/// solid does not; and one wholly outside a side or an end of the pyramid is clipped away.
fn passed_over(g: &Geometry, vis: &Visible, (lo, hi): (DVec3, DVec3), t: u32, tri: &[DVec3; 3]) -> bool {
    tri.iter().all(|x| x.x < lo.x)
        || tri.iter().all(|x| x.x > hi.x)
        || tri.iter().all(|x| x.y < lo.y)
        || tri.iter().all(|x| x.y > hi.y)
        || tri.iter().all(|x| x.z < lo.z)
        || tri.iter().all(|x| x.z > hi.z)
        || solid::faces_away(g, t, *tri, vis.pyramid().0)
        || vis.passes_over(tri)
}

/// Whether every triangle of `tris` is passed over at receiver point `q` (see
/// [`passed_over`]): the visible part computed there with them among the blockers is the
/// one computed without them, as each is skipped before it can change anything.
/// `bounds` holds every corner of `tris`: when it lies wholly outside a side or an end of
/// the pyramid, so does each triangle, and none is looked at.
pub fn none_can_hide(g: &Geometry, light: &LightPlane, r: &Receiver, tris: &[u32], bounds: (DVec3, DVec3), q: DVec2) -> bool {
    let Some(vis) = Visible::new(light, r.to3(q).as_vec3(), r.n.as_vec3()) else { return true };
    if vis.passes_over_box(bounds) {
        return true;
    }
    let pyramid = pyramid_box(&vis);
    tris.iter().all(|&t| passed_over(g, &vis, pyramid, t, &g.tri(t)))
}

impl FaceBackprojection {
    /// The backprojection at `point`, the receiver's blockers in `runs`.
    pub fn compute(g: &Geometry, light: &LightPlane, r: &Receiver, runs: &Runs, point: DVec2) -> FaceBackprojection {
        let mut occluders = Vec::new();
        match visible_in(g, light, r, runs, point, &mut occluders) {
            Some(vis) => FaceBackprojection { point, pieces: vis.pieces(), occluders, irradiance: vis.irradiance() },
            None => FaceBackprojection { point, ..Default::default() },
        }
    }

    pub fn bytes(&self) -> usize {
        48 + self.pieces.iter().map(|p| 24 + p.len() * 24).sum::<usize>() + self.occluders.len() * 4
    }
}
