//! An 8-wide BVH with exact f32 child boxes in structure-of-arrays layout, and its
//! one-ray traversal. obvhs builds the tree (PLOC + a little reinsertion, a binary BVH
//! with one primitive per leaf); [`Bvh8::from_bvh2`] collapses it to 8 children per node
//! and up to 4 primitives per leaf. Why not obvhs' own `CwBvh` and traversal (the worker's
//! before): its children's boxes are 8-bit quantised and dequantised on every node visit
//! with scalar byte-to-float conversions, its leaves hold at most 3 primitives (1.45 per
//! leaf on the dragon, tested one at a time through a closure), and its conversion is a
//! good part of the build. Here a node test is two SSE halves of 4 slab tests, children are
//! visited nearest first (closest hit) with far ones culled on pop once `tmax` shrinks, and
//! a leaf is one [`super::tri4`] block (≤ 4 triangles in one SIMD test; 2.9 per leaf on the
//! dragon).
use glam::Vec3A;
use std::mem::MaybeUninit;
use obvhs::aabb::Aabb;
use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
use obvhs::bvh2::Bvh2;
use obvhs::ploc::PlocBuilder;
use obvhs::BvhBuildParams;

/// A child slot with nothing in it (its box is empty too, so it is never hit).
const EMPTY: u32 = u32::MAX;
/// A child code with this bit set is a leaf; the other bits are its payload.
const LEAF: u32 = 1 << 31;
/// Stack entries a traversal keeps on the thread's stack: ≤ 7 deferred children per level
/// of a tree up to 32 levels deep (the dragon's is 9). A deeper tree (a degenerate mesh can
/// make PLOC's binary tree arbitrarily deep) traverses with a heap stack of its own size.
const STACK: usize = 7 * 32 + 1;

/// One node: per child, its box as six 8-lane planes (min x, max x, min y, max y, min z,
/// max z) and its code (an inner node's index, `LEAF | payload`, or [`EMPTY`]).
#[derive(Clone, Copy)]
#[repr(C, align(64))]
pub struct Node8 {
    planes: [[f32; 8]; 6],
    child: [u32; 8],
}

/// A ray prepared for slab tests: finite reciprocals (±1e30 for zero components, the sign
/// picking the slab order like the reciprocal's own sign) and which plane is near per axis.
#[derive(Clone, Copy, Debug)]
pub struct PreparedRay {
    pub origin: Vec3A,
    pub direction: Vec3A,
    inv: [f32; 3],
    /// `origin * inv`, so a slab distance is one multiply and one subtract.
    org_inv: [f32; 3],
    /// Per axis, the plane index (0 = min, 1 = max) that is near for this direction.
    near: [usize; 3],
    pub tmin: f32,
}

/// Reciprocal of a direction component for slab tests: finite, so `0 · ∞ = NaN` cannot
/// appear; `±0.0` and reciprocals too large for f32 become ±1e30 with the sign `d < 0.0`
/// gives (so `-0.0` is treated as `+0.0`, consistently for the plane order and the
/// product). A node's extent times 1e30 stays finite for scenes up to ~1e8 units across.
#[inline]
fn slab_reciprocal(d: f32) -> f32 {
    const ZERO_DIRECTION_RECIPROCAL: f32 = 1e30;
    if d < 0.0 {
        (1.0 / d).max(-ZERO_DIRECTION_RECIPROCAL)
    } else if d > 0.0 {
        (1.0 / d).min(ZERO_DIRECTION_RECIPROCAL)
    } else {
        ZERO_DIRECTION_RECIPROCAL
    }
}

impl PreparedRay {
    #[inline]
    pub fn new(origin: Vec3A, direction: Vec3A, tmin: f32) -> PreparedRay {
        let inv = [slab_reciprocal(direction.x), slab_reciprocal(direction.y), slab_reciprocal(direction.z)];
        let o = origin.to_array();
        PreparedRay {
            origin,
            direction,
            inv,
            org_inv: [o[0] * inv[0], o[1] * inv[1], o[2] * inv[2]],
            near: [(inv[0] < 0.0) as usize, (inv[1] < 0.0) as usize, (inv[2] < 0.0) as usize],
            tmin,
        }
    }
}

/// Slab distances are computed in f32 and may round a hair inside the true box; widening
/// the exit distance by a few ulps keeps a ray that grazes a box (hitting a triangle on its
/// face) from missing it (Ize, "Robust BVH Ray Traversal", 2013).
const EXIT_SLACK: f32 = 1.0 + 4.0 * f32::EPSILON;

/// `a.max(b)` without `f32::max`'s NaN rule (one `maxps`); no NaN reaches the slab test.
#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

impl Node8 {
    /// Entry distances of the 8 children and the mask of those the ray's `[tmin, tmax]`
    /// meets: the SSE form (x86-64 always has SSE2), two halves of 4 children.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn intersect(&self, r: &PreparedRay, tmax: f32) -> ([f32; 8], u32) {
        use std::arch::x86_64::*;
        let p = &self.planes;
        let (nx, ny, nz) = (r.near[0], r.near[1], r.near[2]);
        let mut tnear = [0f32; 8];
        let mut mask = 0u32;
        // SAFETY: SSE2 is part of the x86-64 baseline; every load reads 4 floats inside an
        // 8-float plane at offset 0 or 4 (unaligned loads, so alignment does not matter).
        unsafe {
            let (ix, iy, iz) = (_mm_set1_ps(r.inv[0]), _mm_set1_ps(r.inv[1]), _mm_set1_ps(r.inv[2]));
            let (ox, oy, oz) = (_mm_set1_ps(r.org_inv[0]), _mm_set1_ps(r.org_inv[1]), _mm_set1_ps(r.org_inv[2]));
            let (t_min, t_max) = (_mm_set1_ps(r.tmin), _mm_set1_ps(tmax));
            let slack = _mm_set1_ps(EXIT_SLACK);
            for h in 0..2 {
                let ld = |k: usize| _mm_loadu_ps(p[k].as_ptr().add(4 * h));
                let slab = |k: usize, inv, oi| _mm_sub_ps(_mm_mul_ps(ld(k), inv), oi);
                let t0 = _mm_max_ps(_mm_max_ps(slab(nx, ix, ox), slab(2 + ny, iy, oy)), _mm_max_ps(slab(4 + nz, iz, oz), t_min));
                let t1 = _mm_min_ps(_mm_min_ps(slab(1 - nx, ix, ox), slab(3 - ny, iy, oy)), _mm_min_ps(slab(5 - nz, iz, oz), t_max));
                let hit = _mm_cmple_ps(t0, _mm_mul_ps(t1, slack));
                _mm_storeu_ps(tnear.as_mut_ptr().add(4 * h), t0);
                mask |= (_mm_movemask_ps(hit) as u32) << (4 * h);
            }
        }
        (tnear, mask)
    }

    /// The same test child by child, for targets without SSE.
    #[cfg(not(target_arch = "x86_64"))]
    #[inline(always)]
    fn intersect(&self, r: &PreparedRay, tmax: f32) -> ([f32; 8], u32) {
        let p = &self.planes;
        let (nx, ny, nz) = (r.near[0], r.near[1], r.near[2]);
        let (xn, xf) = (&p[nx], &p[1 - nx]);
        let (yn, yf) = (&p[2 + ny], &p[3 - ny]);
        let (zn, zf) = (&p[4 + nz], &p[5 - nz]);
        let mut tnear = [0f32; 8];
        let mut mask = 0u32;
        for i in 0..8 {
            let tx0 = xn[i] * r.inv[0] - r.org_inv[0];
            let ty0 = yn[i] * r.inv[1] - r.org_inv[1];
            let tz0 = zn[i] * r.inv[2] - r.org_inv[2];
            let tx1 = xf[i] * r.inv[0] - r.org_inv[0];
            let ty1 = yf[i] * r.inv[1] - r.org_inv[1];
            let tz1 = zf[i] * r.inv[2] - r.org_inv[2];
            let t0 = max(max(tx0, ty0), max(tz0, r.tmin));
            let t1 = min(min(tx1, ty1), min(tz1, tmax)) * EXIT_SLACK;
            tnear[i] = t0;
            mask |= ((t0 <= t1) as u32) << i;
        }
        (tnear, mask)
    }
}

/// An 8-wide BVH over some primitives; what a leaf payload means is up to the owner.
pub struct Bvh8 {
    nodes: Vec<Node8>,
    /// Levels of nodes (1 for a root whose children are all leaves).
    depth: usize,
}

/// A leaf's primitives: `Bvh8Build::prims[first..first + count]`.
pub struct LeafSlots {
    pub first: u32,
    pub count: u32,
}

/// A built [`Bvh8`] with its leaves (leaf payload `i` is `leaves[i]`) and the original
/// primitive indices in leaf order.
pub struct Bvh8Build {
    pub bvh: Bvh8,
    pub leaves: Vec<LeafSlots>,
    pub prims: Vec<u32>,
}

/// Most primitives in one leaf: one 4-lane triangle block (see `tri4`).
pub const MAX_LEAF: u32 = 4;

impl Bvh8 {
    /// Collapses obvhs' binary BVH into 8-wide nodes: a subtree of at most [`MAX_LEAF`]
    /// primitives becomes one leaf (one SIMD block is as cheap as one triangle, so a full
    /// block beats a deeper tree), and a node opens its largest-area inner children until
    /// it has 8 (the usual BVH2-to-BVH8 collapse). Child boxes are obvhs' exact f32 boxes.
    pub fn from_bvh2(b2: &Bvh2) -> Bvh8Build {
        let mut out = Bvh8Build { bvh: Bvh8 { nodes: Vec::new(), depth: 0 }, leaves: Vec::new(), prims: Vec::new() };
        if b2.nodes.is_empty() {
            return out;
        }
        let counts = subtree_counts(b2);
        out.bvh.nodes.push(EMPTY_NODE);
        collapse(b2, &counts, &[0], 0, 1, &mut out);
        out
    }

    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Visits the leaves the ray meets within `[tmin, *tmax]`, nearest box first.
    /// `leaf(payload, tmax)` tests the leaf's primitives, lowers `*tmax` to a closer hit and
    /// returns `true` to stop the traversal (an any-hit query that found one).
    #[inline(always)]
    pub fn traverse(&self, ray: &PreparedRay, tmax: &mut f32, leaf: impl FnMut(u32, &mut f32) -> bool) {
        if self.nodes.is_empty() {
            return;
        }
        let need = 7 * self.depth + 1;
        if need <= STACK {
            self.traverse_on(&mut [MaybeUninit::uninit(); STACK], ray, tmax, leaf)
        } else {
            self.traverse_on(&mut vec![MaybeUninit::uninit(); need], ray, tmax, leaf)
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

    /// [`Self::traverse`] with `stack` holding at least `7 * depth + 1` entries.
    #[inline(always)]
    fn traverse_on(&self, stack: &mut [MaybeUninit<(u32, f32)>], ray: &PreparedRay, tmax: &mut f32, mut leaf: impl FnMut(u32, &mut f32) -> bool) {
        let mut sp = 0usize;
        let mut cur = 0u32;
        loop {
            if cur & LEAF != 0 {
                if leaf(cur & !LEAF, tmax) {
                    return;
                }
            } else {
                let node = &self.nodes[cur as usize];
                let (tnear, mut mask) = node.intersect(ray, *tmax);
                if mask != 0 {
                    // Gather the hit children, sort them far to near, push all but the
                    // nearest, descend into the nearest.
                    let mut order = [(0u32, 0f32); 8];
                    let mut k = 0;
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

const EMPTY_NODE: Node8 = Node8 {
    planes: [[f32::INFINITY; 8], [f32::NEG_INFINITY; 8], [f32::INFINITY; 8], [f32::NEG_INFINITY; 8], [f32::INFINITY; 8], [f32::NEG_INFINITY; 8]],
    child: [EMPTY; 8],
};

/// Primitives under every node of `b2` (the children of inner node `n` are `first_index`
/// and `first_index + 1`).
fn subtree_counts(b2: &Bvh2) -> Vec<u32> {
    fn count(b2: &Bvh2, n: usize, c: &mut [u32]) -> u32 {
        let node = &b2.nodes[n];
        c[n] = if node.is_leaf() {
            node.prim_count
        } else {
            count(b2, node.first_index as usize, c) + count(b2, node.first_index as usize + 1, c)
        };
        c[n]
    }
    let mut c = vec![0u32; b2.nodes.len()];
    count(b2, 0, &mut c);
    c
}

/// obvhs' binary BVH over `boxes`, one primitive per leaf: PLOC with its `fast_build`
/// settings and a little reinsertion (what its `CwBvh` builder does before converting).
pub fn build_bvh2(boxes: &[Aabb]) -> Bvh2 {
    let p = BvhBuildParams::fast_build();
    let mut b2 = PlocBuilder::with_capacity(boxes.len()).build(
        p.ploc_search_distance,
        boxes,
        (0..boxes.len() as u32).collect(),
        p.sort_precision,
        p.search_depth_threshold,
    );
    ReinsertionOptimizer::default().run(&mut b2, p.reinsertion_batch_ratio, None);
    b2
}

/// Appends the primitives under `n` to `prims`, left to right.
fn gather(b2: &Bvh2, n: usize, prims: &mut Vec<u32>) {
    let node = &b2.nodes[n];
    if node.is_leaf() {
        prims.extend_from_slice(&b2.primitive_indices[node.first_index as usize..(node.first_index + node.prim_count) as usize]);
    } else {
        gather(b2, node.first_index as usize, prims);
        gather(b2, node.first_index as usize + 1, prims);
    }
}

/// Fills node `at` with the subtrees `roots` of `b2`, opened up to 8 children.
fn collapse(b2: &Bvh2, counts: &[u32], roots: &[usize], at: usize, depth: usize, out: &mut Bvh8Build) {
    out.bvh.depth = out.bvh.depth.max(depth);
    let mut kids: Vec<usize> = roots.to_vec();
    // Open the largest inner child that is not to become a leaf, while there is room.
    while kids.len() < 8 {
        let open = kids
            .iter()
            .enumerate()
            .filter(|(_, &k)| counts[k] > MAX_LEAF && !b2.nodes[k].is_leaf())
            .max_by(|a, b| b2.nodes[*a.1].aabb.half_area().total_cmp(&b2.nodes[*b.1].aabb.half_area()));
        let Some((i, &k)) = open else { break };
        let first = b2.nodes[k].first_index as usize;
        kids[i] = first;
        kids.push(first + 1);
    }
    let mut node = EMPTY_NODE;
    let mut inner = Vec::new();
    for (i, &k) in kids.iter().enumerate() {
        let b = b2.nodes[k].aabb;
        let (lo, hi) = (b.min.to_array(), b.max.to_array());
        for a in 0..3 {
            node.planes[2 * a][i] = lo[a];
            node.planes[2 * a + 1][i] = hi[a];
        }
        if counts[k] <= MAX_LEAF || b2.nodes[k].is_leaf() {
            let first = out.prims.len() as u32;
            gather(b2, k, &mut out.prims);
            node.child[i] = LEAF | out.leaves.len() as u32;
            out.leaves.push(LeafSlots { first, count: out.prims.len() as u32 - first });
        } else {
            node.child[i] = out.bvh.nodes.len() as u32;
            out.bvh.nodes.push(EMPTY_NODE);
            inner.push((i, k));
        }
    }
    out.bvh.nodes[at] = node;
    for (i, k) in inner {
        let first = b2.nodes[k].first_index as usize;
        collapse(b2, counts, &[first, first + 1], node.child[i] as usize, depth + 1, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Boxes nested inside each other around one point (all on the same Morton code) and a
    /// ray through that point: every leaf is visited, whatever depth PLOC's tree takes, on
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
            let b = Bvh8::from_bvh2(&build_bvh2(&boxes));
            let mut seen = vec![0u32; n];
            let ray = PreparedRay::new(Vec3A::new(0.0, 0.0, -100.0), Vec3A::Z, 0.0);
            let mut tmax = f32::INFINITY;
            b.bvh.traverse(&ray, &mut tmax, |leaf, _| {
                let l = &b.leaves[leaf as usize];
                for &p in &b.prims[l.first as usize..(l.first + l.count) as usize] {
                    seen[p as usize] += 1;
                }
                false
            });
            eprintln!("{n} nested boxes: depth {}", b.bvh.depth());
            assert!(seen.iter().all(|&c| c == 1), "n {n}: depth {}, {} boxes seen", b.bvh.depth(), seen.iter().filter(|&&c| c == 1).count());
            // A ray beside every box meets none.
            let mut visited = 0;
            let beside = PreparedRay::new(Vec3A::new(1000.0, 0.0, -100.0), Vec3A::Z, 0.0);
            let mut far = f32::INFINITY;
            b.bvh.traverse(&beside, &mut far, |_, _| {
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
        let b = Bvh8::from_bvh2(&build_bvh2(&boxes));
        for _ in 0..50 {
            let qlo = Vec3A::new(next(), next(), next()) * 10.0;
            let qhi = qlo + Vec3A::splat(1.0 + 3.0 * next());
            let overlap = |lo: Vec3A, hi: Vec3A| lo.cmple(qhi).all() && qlo.cmple(hi).all();
            let mut found = vec![false; boxes.len()];
            b.bvh.visit_overlapping(overlap, |leaf| {
                let l = &b.leaves[leaf as usize];
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
