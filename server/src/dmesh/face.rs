//! The backprojection of each mesh face (paper 002 §4.4, after Drettakis and Fiume): the
//! part of the light visible from the face, computed at a point inside it and kept as the
//! visible polygons, with the blockers that hide part of the light there. Inside a face no
//! discontinuity surface is crossed, so the visible part keeps its combinatorial form and
//! moves continuously; at any point of the face the irradiance is Lambert's formula over
//! the visible part from that point, occluded by the receiver's shaft blockers (which hold
//! every triangle that can hide the light from any point of the face).
use super::geometry::Geometry;
use super::receiver::Receiver;
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
    let p = r.to3(q).as_vec3();
    let mut vis = Visible::new(light, p, r.n.as_vec3())?;
    // Only triangles meeting the pyramid from the point to the light can hide any of it: a
    // box test first spares the clipping of the others (the shaft holds far more).
    let (apex, base) = vis.pyramid();
    let (lo, hi) = base.iter().fold((apex, apex), |(lo, hi), c| (lo.min(*c), hi.max(*c)));
    for &t in blockers {
        let tri = g.tri(t);
        if tri.iter().all(|x| x.x < lo.x) || tri.iter().all(|x| x.x > hi.x) || tri.iter().all(|x| x.y < lo.y) || tri.iter().all(|x| x.y > hi.y) || tri.iter().all(|x| x.z < lo.z) || tri.iter().all(|x| x.z > hi.z) {
            continue;
        }
        if solid::faces_away(g, t, tri, p.as_dvec3()) {
            continue;
        }
        if vis.occlude(tri) {
            hit.push(t);
        }
        if vis.is_empty() {
            break;
        }
    }
    Some(vis)
}

impl FaceBackprojection {
    pub fn compute(g: &Geometry, light: &LightPlane, r: &Receiver, blockers: &[u32], point: DVec2) -> FaceBackprojection {
        let mut occluders = Vec::new();
        match visible_at(g, light, r, blockers, point, &mut occluders) {
            Some(vis) => FaceBackprojection { point, pieces: vis.pieces(), occluders, irradiance: vis.irradiance() },
            None => FaceBackprojection { point, ..Default::default() },
        }
    }

    pub fn bytes(&self) -> usize {
        48 + self.pieces.iter().map(|p| 24 + p.len() * 24).sum::<usize>() + self.occluders.len() * 4
    }
}
