//! A top-down binned SAH build of the binary BVH the collapse starts from: Wald, "On fast
//! Construction of SAH-based Bounding Volume Hierarchies" (IEEE RT 2007), §3 — primitive
//! centroids binned into 32 equal bins per axis, the split plane between two bins with the
//! lowest surface area cost, the primitives partitioned in place. Leaves hold up to
//! [`MAX_LEAF`] primitives and are costed per block of [`MAX_LEAF`] as Embree's builder
//! does ("SAH block size"): a leaf of one to four triangles is one 4-lane test, so a split
//! that leaves a side with 5 costs two. It replaced obvhs' PLOC (a bottom-up build by
//! Morton order with one primitive per leaf): on the dragon the leaves it leaves to the
//! collapse hold more triangles (fuller blocks: fewer, and less memory to miss on) and the
//! build takes less time (README, "Worker ray rate").
use super::wide::MAX_LEAF;
use glam::Vec3A;
use obvhs::aabb::Aabb;
use obvhs::bvh2::node::Bvh2Node;
use obvhs::bvh2::Bvh2;

/// Bins per axis (Wald 2007 found 16–32 as good as a full sweep).
const BINS: usize = 32;
/// Cost of a binary node's box test relative to one leaf block's, per unit of area (as
/// the collapse's costs, which decide the final tree; these only shape the binary one).
const NODE_COST: f32 = 1.0;
const LEAF_COST: f32 = 1.0;

/// Leaf blocks `n` primitives fill.
#[inline]
fn blocks(n: usize) -> f32 {
    n.div_ceil(MAX_LEAF as usize) as f32
}

/// The area term of a box that may be empty (no primitives on that side): 0 for empty.
#[inline]
fn area(b: &Aabb) -> f32 {
    if b.min.cmple(b.max).all() { b.half_area() } else { 0.0 }
}

/// A primitive being sorted into the tree: its box and index, moved with it when the
/// range is partitioned, so binning reads memory in order (Embree's `PrimRef`) instead of
/// through an index into the boxes (a cache miss per primitive per level).
#[derive(Clone, Copy)]
struct PrimRef {
    bounds: Aabb,
    id: u32,
}

impl PrimRef {
    /// Twice the box's centre: the binning key (the factor 2 is the same for all).
    #[inline(always)]
    fn key(&self) -> Vec3A {
        self.bounds.min + self.bounds.max
    }
}

/// Bounds of the boxes of `refs` and of their keys.
fn bounds(refs: &[PrimRef]) -> (Aabb, Aabb) {
    let (mut b, mut c) = (Aabb::INVALID, Aabb::INVALID);
    for r in refs {
        b = b.union(&r.bounds);
        c.extend(r.key());
    }
    (b, c)
}

/// Per axis, the factor taking a key's offset from `cb.min` to its bin (slightly under
/// BINS / extent so the largest key lands in the last bin; 0 on a flat axis).
#[inline]
fn bin_scale(cb: &Aabb) -> Vec3A {
    let ext = cb.diagonal();
    Vec3A::select(ext.cmpgt(Vec3A::ZERO), Vec3A::splat(BINS as f32 * (1.0 - 1e-6)) / ext, Vec3A::ZERO)
}

/// The best binned split of `refs` (key bounds `cb`, box bounds `nb`): (axis, first bin
/// of the right side, its cost), or `None` when the keys coincide on every axis.
fn best_split(refs: &[PrimRef], nb: &Aabb, cb: &Aabb) -> Option<(usize, usize, f32)> {
    let ext = cb.diagonal();
    let scale = bin_scale(cb);
    let mut bin_box = [[Aabb::INVALID; BINS]; 3];
    let mut bin_count = [[0u32; BINS]; 3];
    for r in refs {
        let b = ((r.key() - cb.min) * scale).to_array();
        for a in 0..3 {
            let k = (b[a] as usize).min(BINS - 1);
            bin_box[a][k] = bin_box[a][k].union(&r.bounds);
            bin_count[a][k] += 1;
        }
    }
    let mut best: Option<(usize, usize, f32)> = None;
    for a in 0..3 {
        if ext[a] <= 0.0 {
            continue;
        }
        // right[k]: the area · blocks of bins k.. (k ≥ 1).
        let mut right = [0f32; BINS];
        let (mut rb, mut rn) = (Aabb::INVALID, 0usize);
        for k in (1..BINS).rev() {
            rb = rb.union(&bin_box[a][k]);
            rn += bin_count[a][k] as usize;
            right[k] = area(&rb) * blocks(rn);
        }
        let (mut lb, mut ln) = (Aabb::INVALID, 0usize);
        for k in 1..BINS {
            lb = lb.union(&bin_box[a][k - 1]);
            ln += bin_count[a][k - 1] as usize;
            if ln == 0 || ln == refs.len() {
                continue;
            }
            let cost = NODE_COST * area(nb) + LEAF_COST * (area(&lb) * blocks(ln) + right[k]);
            if best.is_none_or(|b| cost < b.2) {
                best = Some((a, k, cost));
            }
        }
    }
    best
}

/// The binary BVH over `boxes`: leaves of 1..=[`MAX_LEAF`] primitives
/// (`primitive_indices[first_index..first_index + prim_count]`), the two children of an
/// inner node at `first_index` and `first_index + 1`, node 0 the root.
pub fn build(boxes: &[Aabb]) -> Bvh2 {
    let mut b2 = Bvh2::default();
    if boxes.is_empty() {
        return b2;
    }
    let mut refs: Vec<PrimRef> = boxes.iter().enumerate().map(|(id, b)| PrimRef { bounds: *b, id: id as u32 }).collect();
    let (root, root_keys) = bounds(&refs);
    b2.nodes.reserve(boxes.len() / 2);
    b2.nodes.push(Bvh2Node { aabb: root, ..Default::default() });
    // (node, its primitives' range in `refs`, their key bounds); an explicit stack since a
    // degenerate mesh may make the tree deep.
    let mut todo = vec![(0usize, 0usize, boxes.len(), root_keys)];
    while let Some((node, begin, end, cb)) = todo.pop() {
        let n = end - begin;
        let nb = b2.nodes[node].aabb;
        let range = &mut refs[begin..end];
        let split = if n > 1 { best_split(range, &nb, &cb) } else { None };
        let leaf_cost = LEAF_COST * area(&nb) * blocks(n);
        // The children's box and key bounds, gathered by the partition when it runs (one
        // pass over the range fewer per level than measuring them after).
        let mut sides = None;
        let mid = match split {
            _ if n <= MAX_LEAF as usize && split.is_none_or(|s| leaf_cost <= s.2) => {
                b2.nodes[node].prim_count = n as u32;
                b2.nodes[node].first_index = begin as u32;
                continue;
            }
            Some((axis, k, _)) => {
                // Partition by bin, left bins first (the same arithmetic as the binning).
                let scale = bin_scale(&cb)[axis];
                let left = |r: &PrimRef| (((r.key()[axis] - cb.min[axis]) * scale) as usize).min(BINS - 1) < k;
                let (mut i, mut j) = (0usize, n);
                let [mut lb, mut lc, mut rb, mut rc] = [Aabb::INVALID; 4];
                while i < j {
                    let r = range[i];
                    if left(&r) {
                        lb = lb.union(&r.bounds);
                        lc.extend(r.key());
                        i += 1;
                    } else {
                        rb = rb.union(&r.bounds);
                        rc.extend(r.key());
                        j -= 1;
                        range.swap(i, j);
                    }
                }
                // Both sides hold a primitive (the split has some on each side, binned
                // the same way); halves if rounding ever disagreed.
                if i == 0 || i == n {
                    n / 2
                } else {
                    sides = Some([(lb, lc), (rb, rc)]);
                    i
                }
            }
            // Every key at one point: halves in index order.
            None => n / 2,
        };
        let first = b2.nodes.len();
        b2.nodes[node].first_index = first as u32;
        for (side, (lo, hi)) in [(begin, begin + mid), (begin + mid, end)].into_iter().enumerate() {
            let (b, c) = match sides {
                Some(s) => s[side],
                None => bounds(&refs[lo..hi]),
            };
            b2.nodes.push(Bvh2Node { aabb: b, ..Default::default() });
            todo.push((b2.nodes.len() - 1, lo, hi, c));
        }
    }
    b2.primitive_indices = refs.iter().map(|r| r.id).collect();
    b2
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random boxes, coincident boxes and a single box: every primitive is in exactly one
    /// leaf of 1..=MAX_LEAF primitives, every node's box is the union of its children's
    /// (leaves: of their primitives'), and each inner node has two children.
    #[test]
    fn tree_covers_every_primitive_once_with_exact_boxes() {
        let mut z = 99u64;
        let mut next = || {
            z = z.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (z >> 40) as f32 / (1u64 << 24) as f32
        };
        let random: Vec<Aabb> = (0..2000)
            .map(|_| {
                let c = Vec3A::new(next(), next(), next()) * 10.0;
                Aabb::new(c, c + Vec3A::new(next(), next(), next()))
            })
            .collect();
        let same = vec![Aabb::new(Vec3A::ZERO, Vec3A::ONE); 37];
        let one = vec![Aabb::new(Vec3A::ONE, Vec3A::splat(2.0))];
        for boxes in [random, same, one] {
            let b2 = build(&boxes);
            let mut seen = vec![0u32; boxes.len()];
            let mut stack = vec![0usize];
            let mut leaves = 0;
            while let Some(k) = stack.pop() {
                let node = &b2.nodes[k];
                let expect = if node.prim_count > 0 {
                    assert!(node.prim_count <= MAX_LEAF);
                    leaves += 1;
                    let ps = &b2.primitive_indices[node.first_index as usize..(node.first_index + node.prim_count) as usize];
                    let mut b = Aabb::INVALID;
                    for &p in ps {
                        seen[p as usize] += 1;
                        b = b.union(&boxes[p as usize]);
                    }
                    b
                } else {
                    let (l, r) = (node.first_index as usize, node.first_index as usize + 1);
                    stack.extend([l, r]);
                    b2.nodes[l].aabb.union(&b2.nodes[r].aabb)
                };
                assert_eq!((node.aabb.min, node.aabb.max), (expect.min, expect.max));
            }
            assert!(seen.iter().all(|&c| c == 1));
            assert_eq!(b2.nodes.len(), 2 * leaves - 1, "a full binary tree");
            if boxes.len() == 2000 {
                assert!(leaves * 2 < boxes.len(), "random boxes share leaves: {leaves} leaves");
            }
        }
    }
}
