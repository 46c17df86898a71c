//! A ray's closest hit made ready to shade: the shading point of its material, the face
//! normal on the viewer's side, and the origin secondary rays leave from. Every shader and
//! every bounce starts here.
use super::{finish, HitInfo, RayRequest, Shaded};
use crate::bvh::{Hit, Instances};
use crate::loaded::LoadedScene;
use crate::surface::ShadingPoint;
use edgepoint_proto::split::Part;
use edgepoint_scene::Material;
use glam::Vec3;

pub(crate) struct Surface<'a> {
    pub h: Hit,
    pub material: &'a Material,
    /// The ray meets the winding side.
    pub front: bool,
    /// Unit face normal on the viewer's side.
    pub n: Vec3,
    pub sp: ShadingPoint,
    /// The hit lifted off the surface toward the viewer, where reflected rays start.
    pub origin: Vec3,
}

impl<'a> Surface<'a> {
    /// The surface `h` seen along unit direction `d`.
    pub fn new(scene: &'a LoadedScene, inst: &Instances, h: Hit, d: Vec3) -> Surface<'a> {
        let obj = &scene.scene.objects[h.object as usize];
        let front = h.normal.dot(d) < 0.0;
        let n = if front { h.normal } else { -h.normal };
        let sp = ShadingPoint::new(&obj.material, &obj.mesh, inst, &h, d, front);
        Surface { h, material: &obj.material, front, n, sp, origin: h.position + n * scene.epsilon, }
    }

    /// Where a ray in world direction `wi` leaves from: above the face for reflection, below
    /// it for transmission (so a refracted ray does not hit the surface it leaves).
    #[inline]
    pub fn spawn(&self, wi: Vec3, epsilon: f32) -> Vec3 {
        if wi.dot(self.n) >= 0.0 {
            self.origin
        } else {
            self.h.position - self.n * epsilon
        }
    }

    /// The material's emission toward the viewer (light fixtures are seen from the front).
    #[inline]
    pub fn emitted(&self) -> Vec3 {
        if self.front {
            self.material.emission
        } else {
            Vec3::ZERO
        }
    }

    /// What the renderer learns of a primary hit.
    pub fn info(&self) -> HitInfo {
        let h = &self.h;
        let local_normal = if self.front { h.local_normal } else { -h.local_normal }.normalize_or_zero();
        HitInfo { position: h.position, local_position: h.local, local_normal, normal: self.n, object: h.object, triangle: h.triangle, distance: h.t }
    }
}

/// The unit direction of a request's ray, or `None` for a ray that cannot be traced (zero,
/// infinite or NaN direction or origin): such a request is answered black and counted.
#[inline]
fn unit_direction(origin: Vec3, direction: Vec3) -> Option<Vec3> {
    let len = direction.length();
    (len.is_finite() && len > 0.0 && origin.is_finite()).then(|| direction / len)
}

/// A request's first hit, or its finished sample when there is none: a ray that cannot be
/// traced is answered black and counted, a miss gets the background (in part 0 of a split
/// sample: the background belongs to no light). Every shader starts here.
pub(crate) fn primary<'a>(scene: &'a LoadedScene, inst: &Instances, r: &RayRequest, part: Part) -> Result<Surface<'a>, Shaded> {
    let Some(d) = unit_direction(r.origin, r.direction) else {
        return Err(finish(r.id, None, Vec3::NAN, Vec::new()));
    };
    match inst.closest_hit(&scene.bvh, r.origin, d, 0.0, f32::INFINITY) {
        Some(h) => Ok(Surface::new(scene, inst, h, d)),
        None => Err(finish(r.id, None, if part.shades_unsplit_terms() { scene.scene.background } else { Vec3::ZERO }, Vec::new())),
    }
}
