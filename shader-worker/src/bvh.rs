//! Two-level BVH (DESIGN.md "shader-worker"): one 8-wide BVH per object ([`wide`], built
//! by binned SAH and collapsed here), built once in OBJECT space, and a small top level of the
//! same kind over the instances' world boxes, rebuilt per transform epoch in microseconds. A ray is transformed into each candidate instance's object space by
//! the inverse affine with its direction NOT renormalised, so `t` stays in world units and
//! hits from different instances compare directly. Moving an object rebuilds nothing of its
//! own BVH — the property paper 000 §6.5 relies on for moving objects.
mod collapse;
mod huge_pages;
mod node_test;
mod sah_build;
mod tri4;
mod wide;

use edgepoint_scene::{Mesh, Progress};
use glam::{Affine3A, Mat3A, Vec3, Vec3A};
use obvhs::aabb::Aabb;
#[cfg(target_arch = "x86_64")]
use node_test::Avx2;
use node_test::{Baseline, NodeTest};
pub use node_test::Simd;
use huge_pages::HugeArray;
use tri4::{Tri4, TriTest};
use std::marker::PhantomData;
use wide::{leaf_blocks, Bvh8, Bvh8Build, Leaf, LeafSlots, PreparedRay};

/// One object's BVH in object space: an 8-wide tree whose leaves are one or two blocks of
/// up to 4 triangles tested together ([`tri4`]).
pub struct ObjectBvh {
    bvh: Bvh8,
    /// The leaves' blocks, a leaf's next to each other (its payload names the first and
    /// how many: [`wide::leaf_blocks`]), holding the mesh's triangle indices: a hit needs
    /// nothing else. In huge-page-advised memory when large.
    blocks: HugeArray<Tri4>,
    leaves: usize,
    triangles: usize,
    bounds: (Vec3, Vec3),
}

impl ObjectBvh {
    pub fn build(mesh: &Mesh) -> ObjectBvh {
        let start = std::time::Instant::now();
        // The triangles' boxes on the caller's rayon pool, as the binary build's subtrees
        // ([`sah_build`]).
        let b2 = sah_build::build_with(mesh.triangles.len(), |f| {
            let [a, b, c] = mesh.triangle(f).map(Vec3A::from);
            Aabb::new(a.min(b).min(c), a.max(b).max(c))
        });
        let binary = start.elapsed();
        // Leaves of up to two blocks: the surface area heuristic merges small neighbours
        // into one leaf where a node test over them would cost more (Embree's leaves hold
        // lists of blocks too).
        let Bvh8Build { bvh, blocks: slots, leaf_count, prims } = Bvh8::from_bvh2(&b2, wide::MAX_LEAF_BLOCKS);
        let collapsed = start.elapsed();
        let blocks = HugeArray::collect(slots.iter().map(|l: &LeafSlots| {
            let mut tris = [(0u32, [Vec3::ZERO; 3]); wide::MAX_LEAF as usize];
            let ids = &prims[l.first as usize..(l.first + l.count) as usize];
            for (slot, &f) in tris.iter_mut().zip(ids) {
                *slot = (f, mesh.triangle(f as usize));
            }
            Tri4::new(&tris[..ids.len()])
        }));
        // The build's phases (the rays bench times the whole): what to speed up next.
        tracing::debug!(
            triangles = prims.len(),
            binary_ms = binary.as_secs_f64() * 1e3,
            collapse_ms = (collapsed - binary).as_secs_f64() * 1e3,
            blocks_ms = (start.elapsed() - collapsed).as_secs_f64() * 1e3,
            huge_pages = blocks.mapped(),
            "object BVH built"
        );
        ObjectBvh { bvh, blocks, leaves: leaf_count, triangles: prims.len(), bounds: mesh.bounds }
    }

    /// The closest hit in this object with `ray.tmin <= t <= *t`: lowers `*t` to it and
    /// returns its (block, lane).
    ///
    /// # Safety
    /// As [`NodeTest::intersect`].
    #[inline(always)]
    unsafe fn closest<N: NodeTest + TriTest>(&self, ray: &PreparedRay, t: &mut f32) -> Option<(u32, usize)> {
        let mut leaf = ClosestInObject::<N> { object: self, ray, best: None, simd: PhantomData };
        // SAFETY: forwarded from the caller.
        unsafe { self.bvh.traverse_with::<N>(ray, t, &mut leaf) };
        leaf.best
    }

    /// Whether anything in this object lies on `ray.tmin <= t <= tmax`; stops at the first
    /// hit found.
    ///
    /// # Safety
    /// As [`NodeTest::intersect`].
    #[inline(always)]
    unsafe fn any<N: NodeTest + TriTest>(&self, ray: &PreparedRay, tmax: f32) -> bool {
        let mut t = tmax;
        let mut leaf = AnyInObject::<N> { object: self, ray, hit: false, simd: PhantomData };
        // Children in node order, not nearest first: sorting them cost more than it saved
        // in finding a blocker sooner (shadow rays 0.78× → 0.83× Embree on the dragon).
        // SAFETY: forwarded from the caller.
        unsafe { self.bvh.traverse_unordered_with::<N>(ray, &mut t, &mut leaf) };
        leaf.hit
    }

    /// Where leaf `payload`'s first block starts (for a prefetch; not dereferenced).
    #[inline(always)]
    fn leaf_address(&self, payload: u32) -> *const u8 {
        self.blocks.as_ptr().wrapping_add(leaf_blocks(payload).0 as usize) as *const u8
    }

    /// Starts loading the blocks of leaf `payload` (a hint).
    #[inline(always)]
    fn prefetch_leaf(&self, payload: u32) {
        let (first, n) = leaf_blocks(payload);
        if let Some(block) = self.blocks.get(first as usize) {
            wide::prefetch(block);
        }
        if n == 2 {
            if let Some(block) = self.blocks.get(first as usize + 1) {
                wide::prefetch(block);
            }
        }
    }

    /// The tree's size: what build-quality changes are judged by next to the ray rate.
    pub fn shape(&self) -> BvhShape {
        BvhShape { nodes: self.bvh.node_count(), depth: self.bvh.depth(), leaves: self.leaves, blocks: self.blocks.len(), triangles: self.triangles, sah: self.bvh.sah() }
    }
}

/// The leaf test of a closest-hit query in one object. Only made inside functions that
/// guarantee `N`'s instructions (the `# Safety` of [`ObjectBvh::closest`]).
struct ClosestInObject<'a, N> {
    object: &'a ObjectBvh,
    ray: &'a PreparedRay,
    best: Option<(u32, usize)>,
    simd: PhantomData<N>,
}

impl<N: NodeTest + TriTest> Leaf for ClosestInObject<'_, N> {
    #[inline(always)]
    fn visit(&mut self, payload: u32, t: &mut f32) -> bool {
        let r = self.ray;
        let (first, n) = leaf_blocks(payload);
        for b in first..first + n {
            // SAFETY: made only where `N`'s instructions run (see the struct); leaf codes name
            // blocks of this object (built with its tree), so the index is in bounds
            // (unchecked for the reason the traversal's nodes are).
            if let Some((lane, th)) = unsafe { self.object.blocks.get_unchecked(b as usize).intersect::<N>(r, *t) } {
                *t = th;
                self.best = Some((b, lane));
            }
        }
        false
    }

    #[inline(always)]
    fn prefetch(&self, payload: u32) {
        self.object.prefetch_leaf(payload);
    }

    #[inline(always)]
    fn address(&self, payload: u32) -> *const u8 {
        self.object.leaf_address(payload)
    }
}

/// The leaf test of an any-hit query in one object (made as [`ClosestInObject`]).
struct AnyInObject<'a, N> {
    object: &'a ObjectBvh,
    ray: &'a PreparedRay,
    hit: bool,
    simd: PhantomData<N>,
}

impl<N: NodeTest + TriTest> Leaf for AnyInObject<'_, N> {
    #[inline(always)]
    fn visit(&mut self, payload: u32, t: &mut f32) -> bool {
        let r = self.ray;
        let (first, n) = leaf_blocks(payload);
        let blocks = &self.object.blocks;
        // SAFETY: made only where `N`'s instructions run (see `ClosestInObject`).
        // (The blocks unchecked as in `ClosestInObject::visit`.)
        self.hit = unsafe { blocks.get_unchecked(first as usize).any::<N>(r, *t) || (n == 2 && blocks.get_unchecked(first as usize + 1).any::<N>(r, *t)) };
        self.hit
    }

    #[inline(always)]
    fn prefetch(&self, payload: u32) {
        self.object.prefetch_leaf(payload);
    }

    #[inline(always)]
    fn address(&self, payload: u32) -> *const u8 {
        self.object.leaf_address(payload)
    }
}

/// The top-level leaf test of a closest-hit query: each instance of the leaf, its ray in
/// object space (made as [`ClosestInObject`]).
struct ClosestInstance<'a, N> {
    instances: &'a Instances,
    bvh: &'a SceneBvh,
    ray: &'a PreparedRay,
    best: Option<(u32, u32, usize, Vec3A, Vec3A)>,
    simd: PhantomData<N>,
}

impl<N: NodeTest + TriTest> Leaf for ClosestInstance<'_, N> {
    #[inline(always)]
    fn visit(&mut self, leaf: u32, t: &mut f32) -> bool {
        let l = &self.instances.top_leaves[leaf as usize];
        for s in l.first..l.first + l.count {
            let obj = self.instances.slot_object[s as usize];
            let local = self.instances.local_ray(obj, self.ray);
            // SAFETY: made only where `N`'s instructions run (see `ClosestInObject`).
            if let Some((block, lane)) = unsafe { self.bvh.objects[obj as usize].closest::<N>(&local, t) } {
                self.best = Some((obj, block, lane, local.origin, local.direction));
            }
        }
        false
    }
}

/// The top-level leaf test of an any-hit query (made as [`ClosestInObject`]).
struct AnyInstance<'a, N> {
    instances: &'a Instances,
    bvh: &'a SceneBvh,
    ray: &'a PreparedRay,
    blocker: Option<u32>,
    simd: PhantomData<N>,
}

impl<N: NodeTest + TriTest> Leaf for AnyInstance<'_, N> {
    #[inline(always)]
    fn visit(&mut self, leaf: u32, t: &mut f32) -> bool {
        let l = &self.instances.top_leaves[leaf as usize];
        for s in l.first..l.first + l.count {
            let obj = self.instances.slot_object[s as usize];
            // SAFETY: made only where `N`'s instructions run (see `ClosestInObject`).
            if unsafe { self.bvh.objects[obj as usize].any::<N>(&self.instances.local_ray(obj, self.ray), *t) } {
                self.blocker = Some(obj);
                return true;
            }
        }
        false
    }
}

/// Node, level, leaf and triangle counts of one object's BVH.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BvhShape {
    pub nodes: usize,
    /// Levels of 8-wide nodes.
    pub depth: usize,
    pub leaves: usize,
    /// Triangle blocks of the leaves (a leaf holds one or two).
    pub blocks: usize,
    pub triangles: usize,
    /// [`wide::Bvh8::sah`]: expected node and block tests per ray through the root box.
    pub sah: f64,
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
    /// With exactly one object, queries skip the top level (one node test and a leaf
    /// visit per ray) and trace that object's BVH directly.
    single: bool,
    /// The instruction set queries run with.
    simd: Simd,
    /// The largest absolute coordinate of any box a ray is tested against, world or object
    /// space (the slab tests' slack scales with it: [`PreparedRay::new`]).
    extent: f32,
}

/// A closest hit before it is turned into a [`Hit`]: object, leaf block, lane, t and the
/// object-space ray.
struct Found {
    object: u32,
    block: u32,
    lane: usize,
    t: f32,
    origin: Vec3A,
    direction: Vec3A,
}

/// A closest hit as the traversal finds it, what Embree's `rtcIntersect1` returns: the ids,
/// `t` and the unnormalised geometric normal; [`Hit`] (what [`Instances::closest_hit`]
/// gives) adds the position and the unit normals, two square roots and divides a caller
/// that needs no normal (the rays bench's tracer) should not pay for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    pub object: u32,
    pub triangle: u32,
    /// Distance along the ray in units of the ray direction's length.
    pub t: f32,
    /// The geometric normal (mesh winding) in the object's own coordinates, unnormalised:
    /// `(b - a) × (c - a)` of the triangle's corners.
    pub local_geometric: Vec3,
    origin: Vec3A,
    direction: Vec3A,
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
        let Bvh8Build { bvh: top, blocks: top_leaves, prims: slot_object, .. } = Bvh8::from_bvh2(&wide::build_bvh2(&boxes), 1);
        let largest = |lo: Vec3A, hi: Vec3A| lo.abs().max(hi.abs()).max_element();
        let world = boxes.iter().map(|b| largest(b.min, b.max));
        let local = bvh.objects.iter().map(|o| largest(o.bounds.0.into(), o.bounds.1.into()));
        let extent = world.chain(local).fold(0.0f32, f32::max);
        Instances {
            top,
            top_leaves,
            slot_object,
            to_object: transforms.iter().map(|t| t.inverse()).collect(),
            normal_to_world: transforms.iter().map(|t| t.matrix3.inverse().transpose()).collect(),
            transforms: transforms.to_vec(),
            single: transforms.len() == 1,
            simd: Simd::detect(),
            extent,
        }
    }

    /// The same top level running its queries with `simd` instead of the widest the CPU
    /// has (the baseline when the CPU lacks `simd`): for tests and benchmarks comparing
    /// the instruction sets.
    pub fn with_simd(mut self, simd: Simd) -> Instances {
        self.simd = if simd.supported() { simd } else { Simd::Baseline };
        self
    }

    /// The instruction set queries run with.
    pub fn simd(&self) -> Simd {
        self.simd
    }

    /// `ray` in object `obj`'s space (direction not renormalised: t stays in world units).
    #[inline(always)]
    fn local_ray(&self, obj: u32, ray: &PreparedRay) -> PreparedRay {
        let inv = &self.to_object[obj as usize];
        PreparedRay::new(inv.transform_point3a(ray.origin), inv.transform_vector3a(ray.direction), ray.tmin, self.extent)
    }

    /// The ray a query starts with: already in the object's space when there is one object
    /// (the top level is skipped), else in world space: preparing a ray takes three divides,
    /// so the one-object path does not prepare the world ray first.
    #[inline(always)]
    fn start_ray(&self, origin: Vec3, dir: Vec3, tmin: f32) -> PreparedRay {
        if self.single {
            let inv = &self.to_object[0];
            PreparedRay::new(inv.transform_point3a(origin.into()), inv.transform_vector3a(dir.into()), tmin, self.extent)
        } else {
            PreparedRay::new(origin.into(), dir.into(), tmin, self.extent)
        }
    }

    /// The object-to-world transforms (one per object) this top level was built for.
    #[inline]
    pub fn transforms(&self) -> &[Affine3A] {
        &self.transforms
    }

    /// Closest hit with `tmin <= t <= tmax` (t in units of `dir`'s length).
    pub fn closest_hit(&self, bvh: &SceneBvh, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<Hit> {
        let RayHit { object, triangle, t, local_geometric, origin: lo, direction: ld } = self.closest(bvh, origin, dir, tmin, tmax)?;
        // Normalised as `Tri4::normal` does: equal to `Mesh::face_normals` bit for bit.
        let local_normal = local_geometric.normalize_or_zero();
        let normal = (self.normal_to_world[object as usize] * Vec3A::from(local_normal)).normalize_or_zero();
        Some(Hit { object, triangle, t, position: origin + dir * t, local: (lo + ld * t).into(), normal: normal.into(), local_normal })
    }

    /// The closest hit with `tmin <= t <= tmax` without its position and unit normals
    /// ([`RayHit`]).
    #[inline]
    pub fn closest(&self, bvh: &SceneBvh, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<RayHit> {
        let ray = self.start_ray(origin, dir, tmin);
        let found = match self.simd {
            // SAFETY: `simd` is only `Avx2` when the CPU has AVX2 and FMA (`Simd::detect`,
            // `with_simd`).
            #[cfg(target_arch = "x86_64")]
            Simd::Avx2 => unsafe { self.closest_avx2(bvh, &ray, tmax) },
            // SAFETY: the baseline runs on every CPU of the target.
            _ => unsafe { self.closest_with::<Baseline>(bvh, &ray, tmax) },
        };
        let Found { object, block: b, lane, t, origin, direction } = found?;
        let block = &bvh.objects[object as usize].blocks[b as usize];
        Some(RayHit { object, triangle: block.tri[lane], t, local_geometric: block.geometric(lane), origin, direction })
    }

    /// [`Self::closest_with`] compiled for AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn closest_avx2(&self, bvh: &SceneBvh, ray: &PreparedRay, tmax: f32) -> Option<Found> {
        // SAFETY: this function's callers guarantee AVX2 and FMA.
        unsafe { self.closest_with::<Avx2>(bvh, ray, tmax) }
    }

    /// The closest hit with node test `N`; `ray` from [`Self::start_ray`].
    ///
    /// # Safety
    /// As [`NodeTest::intersect`].
    #[inline(always)]
    unsafe fn closest_with<N: NodeTest + TriTest>(&self, bvh: &SceneBvh, ray: &PreparedRay, tmax: f32) -> Option<Found> {
        let mut t = tmax;
        // SAFETY: forwarded from the caller.
        let best = unsafe {
            if self.single {
                bvh.objects[0].closest::<N>(ray, &mut t).map(|(block, lane)| (0, block, lane, ray.origin, ray.direction))
            } else {
                let mut leaf = ClosestInstance::<N> { instances: self, bvh, ray, best: None, simd: PhantomData };
                self.top.traverse_with::<N>(ray, &mut t, &mut leaf);
                leaf.best
            }
        };
        best.map(|(object, block, lane, origin, direction)| Found { object, block, lane, t, origin, direction })
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
                        |payload| {
                            let (first, n) = leaf_blocks(payload);
                            for block in &o.blocks[first as usize..(first + n) as usize] {
                                for &t in block.tri.iter().filter(|t| **t != u32::MAX) {
                                    f(obj, t);
                                }
                            }
                        },
                    );
                }
            },
        );
    }

    /// Any hit with `tmin <= t <= tmax`: the id of an object blocking the segment. Stops
    /// at the first hit found (inside an object, children in node order: see
    /// [`ObjectBvh::any`]).
    pub fn occluded(&self, bvh: &SceneBvh, origin: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<u32> {
        let ray = self.start_ray(origin, dir, tmin);
        match self.simd {
            // SAFETY: as in `closest_hit`.
            #[cfg(target_arch = "x86_64")]
            Simd::Avx2 => unsafe { self.occluded_avx2(bvh, &ray, tmax) },
            // SAFETY: the baseline runs on every CPU of the target.
            _ => unsafe { self.occluded_with::<Baseline>(bvh, &ray, tmax) },
        }
    }

    /// [`Self::occluded_with`] compiled for AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn occluded_avx2(&self, bvh: &SceneBvh, ray: &PreparedRay, tmax: f32) -> Option<u32> {
        // SAFETY: this function's callers guarantee AVX2 and FMA.
        unsafe { self.occluded_with::<Avx2>(bvh, ray, tmax) }
    }

    /// The blocking object with node test `N`; `ray` from [`Self::start_ray`].
    ///
    /// # Safety
    /// As [`NodeTest::intersect`].
    #[inline(always)]
    unsafe fn occluded_with<N: NodeTest + TriTest>(&self, bvh: &SceneBvh, ray: &PreparedRay, tmax: f32) -> Option<u32> {
        // SAFETY: forwarded from the caller.
        unsafe {
            if self.single {
                return bvh.objects[0].any::<N>(ray, tmax).then_some(0);
            }
            let mut t = tmax;
            let mut leaf = AnyInstance::<N> { instances: self, bvh, ray, blocker: None, simd: PhantomData };
            self.top.traverse_with::<N>(ray, &mut t, &mut leaf);
            leaf.blocker
        }
    }
}
