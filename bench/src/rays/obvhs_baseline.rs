//! The worker's two-level traversal as it was on main at 2f309e2 (before the ray-rate
//! work), kept verbatim in its ray path as the same-process baseline of
//! `edgepoint-bench rays`: obvhs `CwBvh` (fast build) per object, `RtTriangle` leaves, a
//! `CwBvh` top level whose callback transforms the ray into object space and traverses
//! the object's BVH through obvhs' closure API. One object, one instance, as in the bench.
use super::Tracer;
use edgepoint_scene::Mesh;
use glam::{Affine3A, Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::builder::{build_cwbvh, build_cwbvh_from_tris};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::rt_triangle::RtTriangle;
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use std::time::Duration;

pub struct BaselineBvh {
    object: CwBvh,
    tris: Vec<RtTriangle>,
    tri_index: Vec<u32>,
    top: CwBvh,
    to_object: Affine3A,
}

impl BaselineBvh {
    pub fn build(mesh: &Mesh, transform: Affine3A) -> BaselineBvh {
        let triangles: Vec<Triangle> = (0..mesh.triangles.len())
            .map(|f| {
                let [a, b, c] = mesh.triangle(f);
                Triangle { v0: a.into(), v1: b.into(), v2: c.into() }
            })
            .collect();
        let mut t = Duration::ZERO;
        let object = build_cwbvh_from_tris(&triangles, BvhBuildParams::fast_build(), &mut t);
        let tri_index = object.primitive_indices.clone();
        let tris = tri_index.iter().map(|&i| RtTriangle::from(&triangles[i as usize])).collect();
        let (lo, hi) = edgepoint_scene::geometry::transformed_box(&transform, mesh.bounds);
        let top = build_cwbvh(&[Aabb::new(lo.into(), hi.into())], BvhBuildParams::fast_build(), &mut t);
        BaselineBvh { object, tris, tri_index, top, to_object: transform.inverse() }
    }
}

const ZERO_DIRECTION_RECIPROCAL: f32 = 1e30;

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

impl Tracer for BaselineBvh {
    fn closest(&self, o: Vec3, d: Vec3, tmax: f32) -> Option<(f32, u32)> {
        let ray = make_ray(o.into(), d.into(), 0.0, tmax);
        let mut best = None;
        let mut top_hit = RayHit::none();
        self.top.ray_traverse(ray, &mut top_hit, |r, _slot| {
            let inv = &self.to_object;
            let local = make_ray(inv.transform_point3a(r.origin), inv.transform_vector3a(r.direction), r.tmin, r.tmax);
            let mut h = RayHit::none();
            if self.object.ray_traverse(local, &mut h, |lr, id| self.tris[id].intersect(lr)) {
                best = Some(h.primitive_id);
                h.t
            } else {
                f32::INFINITY
            }
        });
        best.map(|slot| (top_hit.t, self.tri_index[slot as usize]))
    }

    fn occluded(&self, o: Vec3, d: Vec3, tmax: f32) -> bool {
        let ray = make_ray(o.into(), d.into(), 0.0, tmax);
        let mut blocked = false;
        self.top.ray_traverse_miss(ray, |r, _slot| {
            let inv = &self.to_object;
            let local = make_ray(inv.transform_point3a(r.origin), inv.transform_vector3a(r.direction), r.tmin, r.tmax);
            if !self.object.ray_traverse_miss(local, |lr, id| self.tris[id].intersect(lr)) {
                blocked = true;
                r.tmin
            } else {
                f32::INFINITY
            }
        });
        blocked
    }
}
