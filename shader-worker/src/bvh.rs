//! Two-level BVH (DESIGN.md "shader-worker"): one 8-wide BVH per object ([`wide`], built
//! by obvhs and collapsed here), built once in OBJECT space, and a small top level of the
//! same kind over the instances' world boxes, rebuilt per transform epoch in microseconds. A ray is transformed into each candidate instance's object space by
//! the inverse affine with its direction NOT renormalised, so `t` stays in world units and
//! hits from different instances compare directly. Moving an object rebuilds nothing of its
//! own BVH — the property paper 000 §6.5 relies on for moving objects.
mod tri4;
mod wide;

use edgepoint_scene::{Mesh, Progress};
use glam::{Affine3A, Mat3A, Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::triangle::Triangle;
use tri4::Tri4;
use wide::{Bvh8, Bvh8Build, LeafSlots, PreparedRay};

/// One object's BVH in object space: an 8-wide tree whose leaves are blocks of up to 4
/// triangles tested together ([`tri4`]).
pub struct ObjectBvh {
    bvh: Bvh8,
    /// One block per leaf (the leaf payload indexes it), holding the mesh's triangle
    /// indices: a hit needs nothing else.
    blocks: Vec<Tri4>,
    triangles: usize,
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
        let boxes: Vec<Aabb> = triangles.iter().map(|t| t.aabb()).collect();
        let Bvh8Build { bvh, leaves, prims } = Bvh8::from_bvh2(&wide::build_bvh2(&boxes));
        let blocks = leaves
            .iter()
            .map(|l: &LeafSlots| {
                let tris: Vec<(u32, [Vec3; 3])> = prims[l.first as usize..(l.first + l.count) as usize].iter().map(|&f| (f, mesh.triangle(f as usize))).collect();
                Tri4::new(&tris)
            })
            .collect();
        ObjectBvh { bvh, blocks, triangles: prims.len(), bounds: mesh.bounds }
    }

    /// The tree's size: what build-quality changes are judged by next to the ray rate.
    pub fn shape(&self) -> BvhShape {
        BvhShape { nodes: self.bvh.node_count(), depth: self.bvh.depth(), leaves: self.blocks.len(), triangles: self.triangles }
    }
}

/// Node, level, leaf and triangle counts of one object's BVH.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BvhShape {
    pub nodes: usize,
    /// Levels of 8-wide nodes.
    pub depth: usize,
    pub leaves: usize,
    pub triangles: usize,
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

/// A pyramid (an apex and a convex planar base) as a convex region tested against boxes:
/// the point–light pyramid whose triangles can hide part of an area light from the apex
/// (the `direct` shader's `area=exact`). The test is conservative (a box is rejected only
/// when it lies outside the pyramid's bounding box or wholly outside one face plane, with a
/// little slack), so nothing that could block is missed; the exact clip comes after.
pub struct Pyramid {
    /// Face planes as (normal, offset): inside where `normal · x >= offset`.
    planes: Vec<(Vec3A, f32)>,
    lo: Vec3A,
    hi: Vec3A,
}

impl Pyramid {
    pub fn new(apex: Vec3, base: &[Vec3]) -> Pyramid {
        let pts: Vec<Vec3A> = std::iter::once(apex).chain(base.iter().copied()).map(Vec3A::from).collect();
        let (lo, hi) = pts.iter().fold((Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        let slack = (hi - lo).max_element() * 1e-4;
        let centre = pts.iter().copied().sum::<Vec3A>() / pts.len() as f32;
        let k = base.len();
        let a = Vec3A::from(apex);
        let mut faces: Vec<[Vec3A; 3]> = (0..k).map(|i| [a, pts[1 + i], pts[1 + (i + 1) % k]]).collect();
        if k >= 3 {
            faces.push([pts[1], pts[2], pts[3]]);
        }
        let planes = faces
            .iter()
            .filter_map(|[p, q, r]| {
                // A face too thin to orient (the apex on the base plane, a repeated corner)
                // is left out: the test only gets more conservative.
                let n = (*q - *p).cross(*r - *p).try_normalize()?;
                let n = if n.dot(centre - *p) >= 0.0 { n } else { -n };
                Some((n, n.dot(*p) - slack))
            })
            .collect();
        Pyramid { planes, lo: lo - slack, hi: hi + slack }
    }

    /// The same pyramid in another space (`t` affine: an object's world-to-object map).
    pub fn transformed(apex: Vec3, base: &[Vec3], t: &Affine3A) -> Pyramid {
        let base: Vec<Vec3> = base.iter().map(|p| t.transform_point3(*p)).collect();
        Pyramid::new(t.transform_point3(apex), &base)
    }

    /// Whether box [`lo`, `hi`] may meet the pyramid.
    #[inline]
    pub fn may_overlap(&self, lo: Vec3A, hi: Vec3A) -> bool {
        lo.cmple(self.hi).all() && self.lo.cmple(hi).all() && self.planes.iter().all(|(n, d)| n.dot(Vec3A::select(n.cmpge(Vec3A::ZERO), hi, lo)) >= *d)
    }
}

/// The top level for one set of object transforms (one epoch).
pub struct Instances {
    top: Bvh8,
    /// Per top-level leaf, its range of top-level primitive slots.
    top_leaves: Vec<LeafSlots>,
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
        let Bvh8Build { bvh: top, leaves: top_leaves, prims: slot_object } = Bvh8::from_bvh2(&wide::build_bvh2(&boxes));
        Instances {
            top,
            top_leaves,
            slot_object,
            to_object: transforms.iter().map(|t| t.inverse()).collect(),
            normal_to_world: transforms.iter().map(|t| t.matrix3.inverse().transpose()).collect(),
            transforms: transforms.to_vec(),
        }
    }

    /// Calls `f(object id, its BVH, the ray in its space)` for each instance of top-level
    /// leaf `leaf` until `f` returns `true` (and then returns `true`). The object-space
    /// ray's direction is not renormalised: t stays in world units.
    #[inline(always)]
    fn leaf_instances<'a>(&self, bvh: &'a SceneBvh, leaf: u32, ray: &PreparedRay, mut f: impl FnMut(u32, &'a ObjectBvh, &PreparedRay) -> bool) -> bool {
        let l = &self.top_leaves[leaf as usize];
        (l.first..l.first + l.count).any(|s| {
            let obj = self.slot_object[s as usize];
            let inv = &self.to_object[obj as usize];
            let local = PreparedRay::new(inv.transform_point3a(ray.origin), inv.transform_vector3a(ray.direction), ray.tmin);
            f(obj, &bvh.objects[obj as usize], &local)
        })
    }

    /// The object-to-world transforms (one per object) this top level was built for.
    #[inline]
    pub fn transforms(&self) -> &[Affine3A] {
        &self.transforms
    }

    /// Closest hit with `tmin <= t <= tmax` (t in units of `dir`'s length).
    pub fn closest_hit(&self, bvh: &SceneBvh, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        let ray = PreparedRay::new(origin.into(), dir.into(), tmin);
        let mut t = tmax;
        let mut best: Option<(u32, u32, usize, Vec3A, Vec3A)> = None;
        self.top.traverse(&ray, &mut t, |leaf, t| {
            self.leaf_instances(bvh, leaf, &ray, |obj, o, local| {
                o.bvh.traverse(local, t, |b, t| {
                    let block = &o.blocks[b as usize];
                    if let Some((lane, th)) = block.intersect(local.origin, local.direction, local.tmin, *t) {
                        *t = th;
                        best = Some((obj, b, lane, local.origin, local.direction));
                    }
                    false
                });
                false
            })
        });
        let (object, b, lane, lo, ld) = best?;
        let block = &bvh.objects[object as usize].blocks[b as usize];
        let local_normal = block.normal(lane);
        let normal = (self.normal_to_world[object as usize] * Vec3A::from(local_normal)).normalize_or_zero();
        Some(Hit {
            object,
            triangle: block.tri[lane],
            t,
            position: origin + dir * t,
            local: (lo + ld * t).into(),
            normal: normal.into(),
            local_normal,
        })
    }

    /// The matrix taking object `object`'s normals to world space (the inverse transpose of
    /// its linear part; the result needs normalising).
    #[inline]
    pub fn normal_to_world(&self, object: u32) -> Mat3A {
        self.normal_to_world[object as usize]
    }

    /// Calls `f(object, triangle index in its mesh)` for every triangle whose leaf box may
    /// meet the pyramid from `apex` to the convex planar `base` (world space): a superset of
    /// the triangles inside it, each once.
    pub fn triangles_near_pyramid(&self, bvh: &SceneBvh, apex: Vec3, base: &[Vec3], mut f: impl FnMut(u32, u32)) {
        let world = Pyramid::new(apex, base);
        self.top.visit_overlapping(
            |lo, hi| world.may_overlap(lo, hi),
            |leaf| {
                let l = &self.top_leaves[leaf as usize];
                for s in l.first..l.first + l.count {
                    let obj = self.slot_object[s as usize];
                    let o = &bvh.objects[obj as usize];
                    let local = Pyramid::transformed(apex, base, &self.to_object[obj as usize]);
                    o.bvh.visit_overlapping(
                        |lo, hi| local.may_overlap(lo, hi),
                        |b| {
                            for &t in o.blocks[b as usize].tri.iter().filter(|t| **t != u32::MAX) {
                                f(obj, t);
                            }
                        },
                    );
                }
            },
        );
    }

    /// Any hit with `tmin <= t <= tmax`: the id of an object blocking the segment. Stops
    /// at the first hit found (children still visited nearest first: near blockers are the
    /// likely ones).
    pub fn occluded(&self, bvh: &SceneBvh, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<u32> {
        let ray = PreparedRay::new(origin.into(), dir.into(), tmin);
        let mut t = tmax;
        let mut blocker = None;
        self.top.traverse(&ray, &mut t, |leaf, t| {
            self.leaf_instances(bvh, leaf, &ray, |obj, o, local| {
                let mut hit = false;
                o.bvh.traverse(local, t, |b, t| {
                    hit = o.blocks[b as usize].any(local.origin, local.direction, local.tmin, *t);
                    hit
                });
                if hit {
                    blocker = Some(obj);
                }
                hit
            })
        });
        blocker
    }
}
