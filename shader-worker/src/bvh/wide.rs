//! An 8-wide BVH with exact f32 child boxes in structure-of-arrays layout, and its
//! one-ray traversal. A binned SAH build makes a binary BVH with leaves of up to 4
//! primitives ([`super::sah_build`]); [`Bvh8::from_bvh2`] collapses it to 8 children per node
//! and up to 4 primitives per leaf. Why not obvhs' own `CwBvh` and traversal (the worker's
//! before): its children's boxes are 8-bit quantised and dequantised on every node visit
//! with scalar byte-to-float conversions, its leaves hold at most 3 primitives (1.45 per
//! leaf on the dragon, tested one at a time through a closure), and its conversion is a
//! good part of the build. Here a node test is one AVX2 pass over the 8 slab tests (two SSE
//! halves without AVX2; [`super::node_test`]), children are visited nearest first (closest
//! hit; one or two hit children without a sort) with far ones culled on pop once `tmax`
//! shrinks, or in node order (any hit), and a leaf is one [`super::tri4`] block (≤ 4
//! triangles in one watertight SIMD test). Which binary nodes become wide nodes and leaves
//! is chosen by [`super::collapse`].
use glam::Vec3A;
use std::mem::MaybeUninit;
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
#[cfg(test)]
use super::node_test::Baseline;
use super::huge_pages::HugeArray;
use super::node_test::NodeTest;

/// A child slot with nothing in it (its box is empty too, so it is never hit).
const EMPTY: u32 = u32::MAX;
/// A child code with this bit set is a leaf; the other bits are its payload.
pub(super) const LEAF: u32 = 1 << 31;
/// Stack entries a traversal keeps on the thread's stack: ≤ 7 deferred children per level
/// of a tree up to 32 levels deep (the dragon's is 9). A deeper tree (a degenerate mesh can
/// make the binary tree arbitrarily deep) traverses with a heap stack of its own size.
const STACK: usize = 7 * 32 + 1;

/// One node: per child, its box as six 8-lane planes (min x, max x, min y, max y, min z,
/// max z) and its code (an inner node's index, `LEAF | payload`, or [`EMPTY`]).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub struct Node8 {
    pub(super) planes: [[f32; 8]; 6],
    pub(super) child: [u32; 8],
}

/// A ray prepared for slab tests: finite reciprocals (±1e30 for zero components, the sign
/// picking the slab order like the reciprocal's own sign) and which plane is near per axis.
#[derive(Clone, Copy, Debug)]
pub struct PreparedRay {
    pub origin: Vec3A,
    pub direction: Vec3A,
    pub(super) inv: [f32; 3],
    /// `origin * inv` plus and minus the slab slack (see [`PreparedRay::new`]): a near
    /// plane's distance is `plane * inv - near_org_inv`, a far one's `plane * inv -
    /// far_org_inv`, each one multiply and one subtract (one fused operation with FMA).
    pub(super) near_org_inv: [f32; 3],
    pub(super) far_org_inv: [f32; 3],
    /// Per axis, the plane index (0 = min, 1 = max) that is near for this direction.
    pub(super) near: [usize; 3],
    /// The triangle test's frame (Woop et al. 2013, §3): `[kx, ky, kz]` with `kz` the axis
    /// along which the direction is largest, and the shear `[d[kx] / d[kz], d[ky] / d[kz],
    /// 1 / d[kz]]` that makes the ray run along +z (the quotients as products with
    /// `1 / d[kz]`).
    pub(super) axes: [usize; 3],
    pub(super) shear: [f32; 3],
    pub tmin: f32,
}

/// Reciprocals of a direction's components for slab tests: finite, so `0 · ∞ = NaN` cannot
/// appear; `±0.0` and reciprocals too large for f32 become ±1e30 with the sign `d < 0.0`
/// gives (so `-0.0` is treated as `+0.0`, consistently for the plane order and the
/// product). A node's extent times 1e30 stays finite for scenes up to ~1e8 units across.
/// One vector divide for the three (three scalar ones before: a camera ray that misses the
/// mesh costs little more than its setup).
#[inline]
fn slab_reciprocals(d: Vec3A) -> Vec3A {
    const ZERO_DIRECTION_RECIPROCAL: f32 = 1e30;
    // ±0.0 → +0.0, whose reciprocal is +∞; then clamped. A NaN component (a broken ray)
    // still gets a finite reciprocal, ±1e30 (`max` / `min` keep the number over a NaN).
    let d = Vec3A::select(d.cmpeq(Vec3A::ZERO), Vec3A::ZERO, d);
    let r = Vec3A::ONE / d;
    Vec3A::splat(ZERO_DIRECTION_RECIPROCAL).min(r.max(Vec3A::splat(-ZERO_DIRECTION_RECIPROCAL)))
}

impl PreparedRay {
    /// The ray from `origin` along `direction` from `tmin` on, for boxes whose coordinates
    /// are at most `extent` in absolute value.
    ///
    /// The slab distances are conservative (Ize, "Robust BVH Ray Traversal", 2013, does it
    /// with a relative widening of the exit distance): per axis the near distance is moved
    /// down and the far one up by `delta = 8 ε (extent + |o|) |inv|`, folded into the
    /// origin term so the node test does no extra work per child. The computed distance
    /// `plane * inv - origin * inv` is off from `(plane - o) / d` by at most about
    /// `2.5 ε (extent + |o|) |inv|` (the reciprocal's, the origin product's and the
    /// subtraction's roundings; one more product rounding without FMA), so with `delta`
    /// over that every computed near distance is at most the true one and every far one at
    /// least the true one: a ray that meets a box meets its computed box, also when the box
    /// is flat or the ray grazes an edge, with `min` and `max` exact. A widening in space of
    /// `8 ε (extent + |o|)` (1e-6 of the scene's size) costs no measurable extra visits. Not
    /// a relative widening of the far distance alone, which was the same speed: near and far
    /// round apart when `plane * inv` and `origin * inv` nearly cancel, and flat boxes were
    /// missed (`bvh_oracle` on the Cornell box's walls).
    #[inline]
    pub fn new(origin: Vec3A, direction: Vec3A, tmin: f32, extent: f32) -> PreparedRay {
        let inv_v = slab_reciprocals(direction);
        let org_inv = origin * inv_v;
        let delta = (Vec3A::splat(extent) + origin.abs()) * inv_v.abs() * (8.0 * f32::EPSILON);
        let inv = inv_v.to_array();
        let d = direction.to_array();
        let a = direction.abs();
        let kz = if a.x >= a.y && a.x >= a.z { 0 } else if a.y >= a.z { 1 } else { 2 };
        // Swapped for a negative d[kz] so the frame keeps the triangles' winding.
        let (kx, ky) = if d[kz] < 0.0 { ((kz + 2) % 3, (kz + 1) % 3) } else { ((kz + 1) % 3, (kz + 2) % 3) };
        PreparedRay {
            origin,
            direction,
            inv,
            near_org_inv: (org_inv + delta).to_array(),
            far_org_inv: (org_inv - delta).to_array(),
            near: [(inv[0] < 0.0) as usize, (inv[1] < 0.0) as usize, (inv[2] < 0.0) as usize],
            axes: [kx, ky, kz],
            // 1 / d[kz] is the slab reciprocal already taken, so the shear costs no divide
            // (clamped only for a direction shorter than 1e-30; the shear is still the same
            // for every triangle the ray meets, which is all watertightness needs).
            shear: [d[kx] * inv[kz], d[ky] * inv[kz], inv[kz]],
            // Never below +0.0: the AVX2 node test takes maxima as integers, exact only
            // when the largest entry distance is at least +0.0 (no query looks behind its
            // origin; every caller passes 0 or more). NaN becomes 0 too.
            tmin: if tmin > 0.0 { tmin } else { 0.0 },
        }
    }
}

/// The node test compares entry distances with `tmax` widened by this factor: a triangle
/// whose computed distance equals the closest hit's up to its rounding (a neighbour across a
/// shared edge) is not culled for a last-ulp difference. (The slab distances themselves are
/// made conservative in [`PreparedRay::new`].)
pub(super) const EXIT_SLACK: f32 = 1.0 + 4.0 * f32::EPSILON;

/// What a traversal does at a leaf: tests the primitives of leaf `payload`, lowers
/// `*tmax` to a closer hit and returns `true` to stop the traversal (an any-hit query that
/// found one). A trait with an always-inlined method rather than a closure because a
/// closure is compiled without the `#[target_feature]`s of the function it is called from
/// unless LLVM inlines it, and it did not: the AVX2 traversal called `_mm_fmadd_ps` as a
/// function and ran at 0.83× the SSE one.
pub trait Leaf {
    fn visit(&mut self, payload: u32, tmax: &mut f32) -> bool;

    /// Starts loading what [`Self::visit`] of `payload` will read (a hint; nothing by
    /// default).
    #[inline(always)]
    fn prefetch(&self, _payload: u32) {}

    /// Where the data of leaf `payload` starts (null by default: nothing to prefetch), for
    /// the traversal's branch-free prefetch of a child it is about to visit.
    #[inline(always)]
    fn address(&self, _payload: u32) -> *const u8 {
        std::ptr::null()
    }
}

impl<F: FnMut(u32, &mut f32) -> bool> Leaf for F {
    #[inline(always)]
    fn visit(&mut self, payload: u32, tmax: &mut f32) -> bool {
        self(payload, tmax)
    }
}

/// Asks the CPU to start loading every cache line of `*value` into L1 (a hint: no effect
/// on results; nothing on targets without a prefetch instruction here).
#[inline(always)]
pub(super) fn prefetch<T>(value: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = value as *const T as *const i8;
        let size = std::mem::size_of::<T>();
        let mut at = 0;
        while at < size {
            // SAFETY: SSE is part of the x86-64 baseline; a prefetch never faults, and the
            // address is inside `*value`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(at)) };
            at += 64;
        }
        // The last line, which a value not aligned to 64 bytes may reach past the steps.
        // SAFETY: as above (size > 0 for the types prefetched here).
        if size > 0 {
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(size - 1)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = value;
}

/// An 8-wide BVH over some primitives; what a leaf payload means is up to the owner.
pub struct Bvh8 {
    /// Node 0 is the root (in huge-page-advised memory when large: [`super::huge_pages`]).
    pub(super) nodes: HugeArray<Node8>,
    /// Levels of nodes (1 for a root whose children are all leaves).
    pub(super) depth: usize,
}

/// A leaf block's primitives: `Bvh8Build::prims[first..first + count]`.
pub struct LeafSlots {
    pub first: u32,
    pub count: u32,
}

/// A built [`Bvh8`] with its leaves' blocks (numbered as the leaf codes number them:
/// [`leaf_blocks`]; with one block per leaf, leaf payload `i` is `blocks[i]`), how many
/// leaves hold them, and the original primitive indices in leaf order.
pub struct Bvh8Build {
    pub bvh: Bvh8,
    pub blocks: Vec<LeafSlots>,
    pub leaf_count: usize,
    pub prims: Vec<u32>,
}

/// Most primitives in one leaf block: one 4-lane triangle test (see `tri4`).
pub const MAX_LEAF: u32 = 4;
/// Most blocks in one leaf (see [`leaf_code`]).
pub const MAX_LEAF_BLOCKS: u32 = 2;
/// The bit of a leaf's code that says it holds [`MAX_LEAF_BLOCKS`] blocks instead of one.
const TWO_BLOCKS: u32 = 1 << 30;

/// The child code of a leaf of `blocks` (1 or 2) consecutive blocks from block `first`:
/// blocks are numbered in leaf order, so with one block per leaf the first block is the
/// leaf's own index (the top level's leaves, which index their slots by it).
pub fn leaf_code(first: u32, blocks: u32) -> u32 {
    assert!(first < TWO_BLOCKS && (1..=MAX_LEAF_BLOCKS).contains(&blocks), "leaf of {blocks} blocks from block {first}");
    LEAF | first | if blocks == 2 { TWO_BLOCKS } else { 0 }
}

/// A leaf payload (its code without [`LEAF`]) as (first block, blocks).
#[inline(always)]
pub fn leaf_blocks(payload: u32) -> (u32, u32) {
    (payload & !TWO_BLOCKS, 1 + (payload >> 30 & 1))
}

impl Bvh8 {
    /// Collapses a binary BVH (obvhs' type, leaves of at most [`MAX_LEAF`] primitives) into
    /// 8-wide nodes with leaves of at most `max_blocks` blocks of [`MAX_LEAF`] primitives
    /// (1 or [`MAX_LEAF_BLOCKS`]), by surface area heuristic ([`super::collapse`]). Child
    /// boxes are the binary nodes' exact f32 boxes; a leaf's code is [`leaf_code`] of its
    /// blocks, numbered in the order of `blocks`.
    pub fn from_bvh2(b2: &Bvh2, max_blocks: u32) -> Bvh8Build {
        let mut out = Bvh8Build { bvh: Bvh8 { nodes: HugeArray::collect(std::iter::empty()), depth: 0 }, blocks: Vec::new(), leaf_count: 0, prims: Vec::new() };
        if b2.nodes.is_empty() {
            return out;
        }
        super::collapse::collapse(b2, &mut out, max_blocks.clamp(1, MAX_LEAF_BLOCKS) * MAX_LEAF);
        out
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    pub fn depth(&self) -> usize {
        self.depth
    }

    /// The tree's surface area heuristic cost as Embree's BVH statistics state it (one per
    /// inner node and one per leaf block, each weighted by its box's area over the root's):
    /// the expected node and block tests of a random ray through the root box, so the
    /// worker's trees and Embree's (`verbose=2` in its device config) compare by one number.
    pub fn sah(&self) -> f64 {
        if self.nodes.is_empty() {
            return 0.0;
        }
        let area = |(lo, hi): (Vec3A, Vec3A)| {
            let d = (hi - lo).max(Vec3A::ZERO);
            (d.x * d.y + d.y * d.z + d.z * d.x) as f64
        };
        let child_box = |node: &Node8, i: usize| {
            let p = &node.planes;
            (Vec3A::new(p[0][i], p[2][i], p[4][i]), Vec3A::new(p[1][i], p[3][i], p[5][i]))
        };
        let root = &self.nodes[0];
        let (mut lo, mut hi) = (Vec3A::INFINITY, Vec3A::NEG_INFINITY);
        for i in (0..8).filter(|&i| root.child[i] != EMPTY) {
            let (a, b) = child_box(root, i);
            (lo, hi) = (lo.min(a), hi.max(b));
        }
        let whole = area((lo, hi)).max(f64::MIN_POSITIVE);
        let mut sum = 1.0;
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n as usize];
            for i in (0..8).filter(|&i| node.child[i] != EMPTY) {
                let (c, share) = (node.child[i], area(child_box(node, i)) / whole);
                if c & LEAF != 0 {
                    sum += leaf_blocks(c & !LEAF).1 as f64 * share;
                } else {
                    sum += share;
                    stack.push(c);
                }
            }
        }
        sum
    }

    /// Visits the leaves the ray meets within `[tmin, *tmax]`, nearest box first, with the
    /// baseline node test (see [`Self::traverse_with`]).
    #[cfg(test)]
    pub fn traverse(&self, ray: &PreparedRay, tmax: &mut f32, leaf: &mut impl Leaf) {
        // SAFETY: the baseline test runs on every CPU of the target.
        unsafe { self.traverse_with::<Baseline>(ray, tmax, leaf) }
    }

    /// Visits the leaves the ray meets within `[tmin, *tmax]`, nearest box first, testing
    /// nodes with `N`. `leaf(payload, tmax)` tests the leaf's primitives, lowers `*tmax` to
    /// a closer hit and returns `true` to stop the traversal (an any-hit query that found
    /// one).
    ///
    /// # Safety
    /// As [`NodeTest::intersect`]: the CPU runs `N`'s instructions and the caller is
    /// compiled with them.
    #[inline(always)]
    pub unsafe fn traverse_with<N: NodeTest>(&self, ray: &PreparedRay, tmax: &mut f32, leaf: &mut impl Leaf) {
        // SAFETY: forwarded from the caller.
        unsafe { self.traverse_stack::<N, true>(ray, tmax, leaf) }
    }

    /// [`Self::traverse_with`] visiting the children a ray meets in node order rather
    /// than nearest first: for any-hit queries, where an order only pays if it finds a
    /// blocker sooner than the sorting costs.
    ///
    /// # Safety
    /// As [`Self::traverse_with`].
    #[inline(always)]
    pub unsafe fn traverse_unordered_with<N: NodeTest>(&self, ray: &PreparedRay, tmax: &mut f32, leaf: &mut impl Leaf) {
        // SAFETY: forwarded from the caller.
        unsafe { self.traverse_stack::<N, false>(ray, tmax, leaf) }
    }

    /// Picks the thread's stack or, for a tree deeper than it holds, a heap one.
    #[inline(always)]
    unsafe fn traverse_stack<N: NodeTest, const ORDERED: bool>(&self, ray: &PreparedRay, tmax: &mut f32, leaf: &mut impl Leaf) {
        if self.nodes.is_empty() {
            return;
        }
        let need = 7 * self.depth + 1;
        // SAFETY: forwarded from the caller.
        unsafe {
            if need <= STACK {
                self.traverse_on::<N, ORDERED>(&mut [MaybeUninit::uninit(); STACK], ray, tmax, leaf)
            } else {
                self.traverse_on::<N, ORDERED>(&mut vec![MaybeUninit::uninit(); need], ray, tmax, leaf)
            }
        }
    }

    /// Visits every leaf whose box, and every ancestor's box, `overlaps(lo, hi)` accepts (a
    /// region query: the gatherer of blockers for exact area lights passes a convex volume's
    /// conservative box test).
    pub fn visit_overlapping(&self, overlaps: impl Fn(Vec3A, Vec3A) -> bool, mut leaf: impl FnMut(u32)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = Vec::with_capacity(7 * self.depth + 1);
        stack.push(0u32);
        while let Some(n) = stack.pop() {
            let node = &self.nodes[n as usize];
            for i in 0..8 {
                let c = node.child[i];
                if c == EMPTY {
                    continue;
                }
                let p = &node.planes;
                let (lo, hi) = (Vec3A::new(p[0][i], p[2][i], p[4][i]), Vec3A::new(p[1][i], p[3][i], p[5][i]));
                if !overlaps(lo, hi) {
                    continue;
                }
                if c & LEAF != 0 {
                    leaf(c & !LEAF);
                } else {
                    stack.push(c);
                }
            }
        }
    }

    /// Starts loading child `code` (an inner node or a leaf's first block) without a
    /// branch on which it is: issued before the loop's branch on the child's kind, which
    /// mispredicts often, the loads start even when the pipeline is flushed (Embree's
    /// traversal prefetches the next node so; perf put a sixth of the loop's samples on
    /// the first load of a node and a sixth on a leaf's). Four lines: a whole node, a
    /// block and the start of a second.
    #[inline(always)]
    fn prefetch_child(&self, leaf: &impl Leaf, code: u32) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            let node = self.nodes.as_ptr().wrapping_add(code as usize) as usize;
            let block = leaf.address(code & !LEAF) as usize;
            // All ones for a leaf (LEAF is the top bit), else zero.
            let is_leaf = ((code as i32) >> 31) as isize as usize;
            let p = ((block & is_leaf) | (node & !is_leaf)) as *const i8;
            // SAFETY: a prefetch never faults, whatever the address.
            unsafe {
                _mm_prefetch::<_MM_HINT_T0>(p);
                _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(64));
                _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(128));
                _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(192));
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (leaf, code);
    }

    /// [`Self::traverse_with`] with `stack` holding at least `7 * depth + 1` entries.
    #[inline(always)]
    unsafe fn traverse_on<N: NodeTest, const ORDERED: bool>(&self, stack: &mut [MaybeUninit<(u32, f32)>], ray: &PreparedRay, tmax: &mut f32, leaf: &mut impl Leaf) {
        let mut sp = 0usize;
        let mut cur = 0u32;
        loop {
            if cur & LEAF != 0 {
                if leaf.visit(cur & !LEAF, tmax) {
                    return;
                }
            } else {
                // SAFETY: inner child codes index `nodes` (the collapse made both), and the
                // root, node 0, exists (checked in `traverse_stack`). Unchecked: the bound
                // would hold one more register in the traversal's loop, which spills as it is.
                let node = unsafe { self.nodes.get_unchecked(cur as usize) };
                // SAFETY: forwarded from the caller.
                let (tnear, mut mask) = unsafe { N::intersect(node, ray, *tmax) };
                if mask != 0 {
                    // One or two children hit (the common case in a tree of tight boxes)
                    // skip the general sort, as in Embree's traversal.
                    let i = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    if mask == 0 {
                        cur = node.child[i];
                        if ORDERED {
                            self.prefetch_child(leaf, cur);
                        }
                        continue;
                    }
                    // Two or more, closest hit: start loading every child hit now, so the
                    // misses on the ones visited after the first overlap each other and
                    // the sort (perf put half the closest-hit loop's samples on first
                    // loads). Not for any-hit rays, which stop at the first blocker: there
                    // it measured no faster (README, "Worker ray rate").
                    let mut m = if ORDERED { mask | 1 << i } else { 0 };
                    while m != 0 {
                        let c = node.child[m.trailing_zeros() as usize];
                        m &= m - 1;
                        if c & LEAF != 0 {
                            leaf.prefetch(c & !LEAF);
                        } else {
                            // SAFETY: inner child codes index `nodes` (the collapse).
                            prefetch(unsafe { self.nodes.get_unchecked(c as usize) });
                        }
                    }
                    if !ORDERED {
                        // Descend into the first, defer the others as they come.
                        cur = node.child[i];
                        while mask != 0 {
                            let j = mask.trailing_zeros() as usize;
                            mask &= mask - 1;
                            stack[sp].write((node.child[j], tnear[j]));
                            sp += 1;
                        }
                        continue;
                    }
                    let j = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    if mask == 0 {
                        let (near, far) = if tnear[j] < tnear[i] { (j, i) } else { (i, j) };
                        stack[sp].write((node.child[far], tnear[far]));
                        sp += 1;
                        cur = node.child[near];
                        continue;
                    }
                    // Three or more: insertion-sort far to near, push all but the nearest,
                    // descend into the nearest.
                    let mut order = [(0u32, 0f32); 8];
                    order[0] = (node.child[i], tnear[i]);
                    let mut k = 1;
                    mask |= 1 << j;
                    while mask != 0 {
                        let i = mask.trailing_zeros() as usize;
                        mask &= mask - 1;
                        let t = tnear[i];
                        let mut j = k;
                        while j > 0 && order[j - 1].1 < t {
                            order[j] = order[j - 1];
                            j -= 1;
                        }
                        order[j] = (node.child[i], t);
                        k += 1;
                    }
                    for (slot, entry) in stack[sp..sp + k - 1].iter_mut().zip(&order[..k - 1]) {
                        slot.write(*entry);
                    }
                    sp += k - 1;
                    cur = order[k - 1].0;
                    continue;
                }
            }
            // Pop the nearest deferred child still in front of the closest hit so far.
            loop {
                if sp == 0 {
                    return;
                }
                sp -= 1;
                // SAFETY: entries below `sp` were written by the push above.
                let (c, t) = unsafe { stack[sp].assume_init() };
                if t <= *tmax {
                    cur = c;
                    break;
                }
            }
        }
    }
}

pub(super) const EMPTY_NODE: Node8 = Node8 {
    planes: [[f32::INFINITY; 8], [f32::NEG_INFINITY; 8], [f32::INFINITY; 8], [f32::NEG_INFINITY; 8], [f32::INFINITY; 8], [f32::NEG_INFINITY; 8]],
    child: [EMPTY; 8],
};

/// The binary BVH over `boxes` the collapse starts from: a binned SAH build with leaves of
/// up to [`MAX_LEAF`] primitives ([`super::sah_build`]).
pub fn build_bvh2(boxes: &[Aabb]) -> Bvh2 {
    super::sah_build::build(boxes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Boxes nested inside each other around one point (all on the same Morton code) and a
    /// ray through that point: every leaf is visited, whatever depth the binary tree takes, on
    /// the fixed stack or the heap one.
    #[test]
    fn every_box_around_the_ray_is_visited_at_any_depth() {
        for n in [1usize, 5, 64, 3000] {
            let boxes: Vec<Aabb> = (0..n)
                .map(|k| {
                    let h = 1.0 + k as f32 * 0.01;
                    Aabb::new(Vec3A::splat(-h), Vec3A::new(h, h * (1.0 + (k % 7) as f32), h))
                })
                .collect();
            let b = Bvh8::from_bvh2(&build_bvh2(&boxes), 1);
            let mut seen = vec![0u32; n];
            let ray = PreparedRay::new(Vec3A::new(0.0, 0.0, -100.0), Vec3A::Z, 0.0, 1000.0);
            let mut tmax = f32::INFINITY;
            b.bvh.traverse(&ray, &mut tmax, &mut |leaf, _: &mut f32| {
                let l = &b.blocks[leaf as usize];
                for &p in &b.prims[l.first as usize..(l.first + l.count) as usize] {
                    seen[p as usize] += 1;
                }
                false
            });
            eprintln!("{n} nested boxes: depth {}", b.bvh.depth());
            assert!(seen.iter().all(|&c| c == 1), "n {n}: depth {}, {} boxes seen", b.bvh.depth(), seen.iter().filter(|&&c| c == 1).count());
            // A ray beside every box meets none.
            let mut visited = 0;
            let beside = PreparedRay::new(Vec3A::new(1000.0, 0.0, -100.0), Vec3A::Z, 0.0, 1000.0);
            let mut far = f32::INFINITY;
            b.bvh.traverse(&beside, &mut far, &mut |_, _: &mut f32| {
                visited += 1;
                false
            });
            assert_eq!(visited, 0);
        }
    }

    /// The region query against brute force: random boxes and query boxes, the leaves
    /// visited hold exactly the primitives whose boxes overlap the query (a leaf may hold
    /// others beside them).
    #[test]
    fn region_query_finds_every_overlapping_box() {
        let mut z = 12345u64;
        let mut next = || {
            z = z.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (z >> 40) as f32 / (1u64 << 24) as f32
        };
        let boxes: Vec<Aabb> = (0..500)
            .map(|_| {
                let c = Vec3A::new(next(), next(), next()) * 10.0;
                Aabb::new(c, c + Vec3A::new(next(), next(), next()))
            })
            .collect();
        let b = Bvh8::from_bvh2(&build_bvh2(&boxes), 1);
        for _ in 0..50 {
            let qlo = Vec3A::new(next(), next(), next()) * 10.0;
            let qhi = qlo + Vec3A::splat(1.0 + 3.0 * next());
            let overlap = |lo: Vec3A, hi: Vec3A| lo.cmple(qhi).all() && qlo.cmple(hi).all();
            let mut found = vec![false; boxes.len()];
            b.bvh.visit_overlapping(overlap, |leaf| {
                let l = &b.blocks[leaf as usize];
                for &p in &b.prims[l.first as usize..(l.first + l.count) as usize] {
                    found[p as usize] = true;
                }
            });
            for (i, bx) in boxes.iter().enumerate() {
                if overlap(bx.min, bx.max) {
                    assert!(found[i], "box {i} overlaps the query but was not visited");
                }
            }
            assert!(found.iter().filter(|f| **f).count() < boxes.len(), "the query prunes");
        }
    }
}
