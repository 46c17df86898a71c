//! Two-level BVH (DESIGN.md "shader-worker"): one obvhs `CwBvh` per object, built once in
//! OBJECT space, and a small top level over the instances' world boxes, rebuilt per transform
//! epoch in microseconds. A ray is transformed into each candidate instance's object space by
//! the inverse affine with its direction NOT renormalised, so `t` stays in world units and
//! hits from different instances compare directly. Moving an object rebuilds nothing of its
//! own BVH — the property paper 000 §6.5 relies on for moving objects.
use edgepoint_scene::{Mesh, Progress};
use glam::{Affine3A, Mat3A, Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::builder::{build_cwbvh, build_cwbvh_from_tris};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use std::time::Duration;

/// One object's BVH in object space; triangles are stored in BVH leaf order so the traversal
/// callback indexes them directly.
pub struct ObjectBvh {
    bvh: CwBvh,
    tris: Vec<RtTriangle>,
    /// BVH primitive slot -> triangle index in the mesh.
    tri_index: Vec<u32>,
    /// Unit object-space face normal per BVH slot (mesh winding).
    normals: Vec<Vec3A>,
    bounds: (Vec3, Vec3),
}

impl ObjectBvh {
    pub fn build(mesh: &Mesh) -> ObjectBvh {
        let triangles: Vec<Triangle> = (0..mesh.triangles.len())
            .map(|f| {
                let [a, b, c] = mesh.triangle(f);
                Triangle { v0: a.into(), v1: b.into(), v2: c.into() }
            })
            .collect();
        let mut t = Duration::ZERO;
        let bvh = build_cwbvh_from_tris(&triangles, BvhBuildParams::fast_build(), &mut t);
        let tri_index = bvh.primitive_indices.clone();
        let tris = tri_index.iter().map(|&i| RtTriangle::from(&triangles[i as usize])).collect();
        let normals = tri_index.iter().map(|&i| mesh.face_normals[i as usize].into()).collect();
        ObjectBvh { bvh, tris, tri_index, normals, bounds: mesh.bounds }
    }
}

/// Per-object BVHs of a whole scene (built once per scene).
pub struct SceneBvh {
    pub objects: Vec<ObjectBvh>,
}

impl SceneBvh {
    pub fn build(meshes: &[&Mesh], progress: &dyn Progress) -> SceneBvh {
        let total: u64 = meshes.iter().map(|m| m.triangles.len() as u64).sum();
        progress.begin("BVH build", total);
        let objects = meshes
            .iter()
            .map(|m| {
                let o = ObjectBvh::build(m);
                progress.advance(m.triangles.len() as u64);
                o
            })
            .collect();
        progress.end();
        SceneBvh { objects }
    }
}

/// Reciprocals of direction components that are zero (or too small to invert in f32).
/// Finite, so the slab products of obvhs' node test stay free of `0 · ∞ = NaN`: a node's
/// quantisation scale times this stays below `f32::MAX` for scenes up to ~1e8 units across.
const ZERO_DIRECTION_RECIPROCAL: f32 = 1e30;

/// An obvhs ray whose reciprocal direction agrees with obvhs' own slab ordering.
///
/// obvhs picks each node's near and far slab planes by `direction < 0.0` but inverts the
/// direction with `signum(d) / f32::EPSILON` for `|d| <= f32::EPSILON`, and `signum(-0.0)`
/// is `-1`: a component of `-0.0` — `-Vec3::Y` is `(-0.0, -1.0, -0.0)`, and inverse
/// instance transforms of exact axis directions produce them too — got a negative
/// reciprocal with the planes ordered for a positive one, so every slab interval on that
/// axis came out empty and the ray missed everything (axis-aligned rays onto the Cornell
/// box floor, for one). Its `±2^23` stand-in for tiny components also shrank the slab
/// intervals of nearly axis-aligned rays below the true ones. Here every component gets
/// its exact reciprocal, with `±0.0` (and anything whose reciprocal overflows) mapped to
/// `±ZERO_DIRECTION_RECIPROCAL` with the sign obvhs orders the planes by (`+` unless
/// `d < 0.0`). A ray that lies exactly in a box face's plane stays ambiguous, as its
/// triangle test is.
fn make_ray(origin: Vec3A, direction: Vec3A, tmin: f32, tmax: f32) -> Ray {
    let inv = |d: f32| {
        if d < 0.0 {
            (1.0 / d).max(-ZERO_DIRECTION_RECIPROCAL)
        } else if d > 0.0 {
            (1.0 / d).min(ZERO_DIRECTION_RECIPROCAL)
        } else {
            ZERO_DIRECTION_RECIPROCAL
        }
    };
    let inv_direction = Vec3A::new(inv(direction.x), inv(direction.y), inv(direction.z));
    Ray { origin, direction, inv_direction, tmin, tmax }
}

/// The top level for one set of object transforms (one epoch).
pub struct Instances {
    top: Option<CwBvh>,
    /// Top-level primitive slot -> object id.
    slot_object: Vec<u32>,
    to_object: Vec<Affine3A>,
    /// Inverse-transpose of each object's linear part: object normals to world normals.
    normal_to_world: Vec<Mat3A>,
    /// The object-to-world transforms this top level was built for.
    transforms: Vec<Affine3A>,
}

/// A closest hit, in world space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub object: u32,
    pub triangle: u32,
    /// Distance along the ray in units of the ray direction's length.
    pub t: f32,
    pub position: Vec3,
    /// The hit point in the object's own coordinates (from the object-space ray, so it lies
    /// on the object's triangle up to the intersection's own rounding).
    pub local: Vec3,
    /// Unit geometric normal (mesh winding), world space.
    pub normal: Vec3,
    /// The same normal in the object's own coordinates.
    pub local_normal: Vec3,
}

fn world_box(a: &Affine3A, b: (Vec3, Vec3)) -> Aabb {
    let (lo, hi) = edgepoint_scene::geometry::transformed_box(a, b);
    Aabb::new(lo.into(), hi.into())
}

impl Instances {
    /// Builds the top level for `transforms` (object-to-world, one per object).
    pub fn new(bvh: &SceneBvh, transforms: &[Affine3A]) -> Instances {
        assert_eq!(bvh.objects.len(), transforms.len(), "one transform per object");
        let boxes: Vec<Aabb> = bvh.objects.iter().zip(transforms).map(|(o, t)| world_box(t, o.bounds)).collect();
        let (top, slot_object) = if boxes.is_empty() {
            (None, Vec::new())
        } else {
            let mut d = Duration::ZERO;
            let top = build_cwbvh(&boxes, BvhBuildParams::fast_build(), &mut d);
            let slots = top.primitive_indices.clone();
            (Some(top), slots)
        };
        Instances {
            top,
            slot_object,
            to_object: transforms.iter().map(|t| t.inverse()).collect(),
            normal_to_world: transforms.iter().map(|t| t.matrix3.inverse().transpose()).collect(),
            transforms: transforms.to_vec(),
        }
    }

    /// The object-to-world transforms (one per object) this top level was built for.
    #[inline]
    pub fn transforms(&self) -> &[Affine3A] {
        &self.transforms
    }

    /// Closest hit with `tmin <= t <= tmax` (t in units of `dir`'s length).
    pub fn closest_hit(&self, bvh: &SceneBvh, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        let top = self.top.as_ref()?;
        let ray = make_ray(origin.into(), dir.into(), tmin, tmax);
        let mut best: Option<(u32, u32, Vec3)> = None;
        let mut top_hit = RayHit::none();
        top.ray_traverse(ray, &mut top_hit, |r, slot| {
            let obj = self.slot_object[slot];
            let inv = &self.to_object[obj as usize];
            let o = &bvh.objects[obj as usize];
            let local = make_ray(inv.transform_point3a(r.origin), inv.transform_vector3a(r.direction), r.tmin, r.tmax);
            let mut h = RayHit::none();
            if o.bvh.ray_traverse(local, &mut h, |lr, id| o.tris[id].intersect(lr)) {
                best = Some((obj, h.primitive_id, (local.origin + local.direction * h.t).into()));
                h.t
            } else {
                f32::INFINITY
            }
        });
        let (object, slot, local) = best?;
        let t = top_hit.t;
        let o = &bvh.objects[object as usize];
        let local_normal = o.normals[slot as usize];
        let normal = (self.normal_to_world[object as usize] * local_normal).normalize_or_zero();
        Some(Hit { object, triangle: o.tri_index[slot as usize], t, position: origin + dir * t, local, normal: normal.into(), local_normal: local_normal.into() })
    }

    /// The matrix taking object `object`'s normals to world space (the inverse transpose of
    /// its linear part; the result needs normalising).
    #[inline]
    pub fn normal_to_world(&self, object: u32) -> Mat3A {
        self.normal_to_world[object as usize]
    }

    /// Any hit with `tmin <= t <= tmax`: the id of an object blocking the segment.
    pub fn occluded(&self, bvh: &SceneBvh, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<u32> {
        let top = self.top.as_ref()?;
        let ray = make_ray(origin.into(), dir.into(), tmin, tmax);
        let mut blocker = None;
        top.ray_traverse_miss(ray, |r, slot| {
            let obj = self.slot_object[slot];
            let inv = &self.to_object[obj as usize];
            let o = &bvh.objects[obj as usize];
            let local = make_ray(inv.transform_point3a(r.origin), inv.transform_vector3a(r.direction), r.tmin, r.tmax);
            if !o.bvh.ray_traverse_miss(local, |lr, id| o.tris[id].intersect(lr)) {
                blocker = Some(obj);
                r.tmin // any value < tmax stops the traversal
            } else {
                f32::INFINITY
            }
        });
        blocker
    }
}
