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

/// Bins per axis (Wald 2007 found 16–32 as good as a full sweep) for a range of more than
/// 16 primitives; ranges of 9–16 bin into 16, smaller ones into 8: with fewer keys than
/// bins most bins are empty, and clearing and sweeping 3 × 32 of them cost more than
/// binning the few primitives (most of the binary tree's nodes are such small ranges).
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
/// through an index into the boxes (a cache miss per primitive per level). On x86-64 the
/// index rides in the boxes' unused fourth lanes (its low and high 16 bits as small whole
/// floats: never denormal, so no slow arithmetic on them), making a record 32 bytes
/// instead of 48: the binning and the partition stream through the records at every level,
/// the top levels from memory. Nothing reads a box's fourth lane (glam's `Vec3A` leaves it
/// unspecified), so the nodes' boxes built from these carry the lanes' leftovers harmlessly.
#[derive(Clone, Copy)]
struct PrimRef {
    bounds: Aabb,
    #[cfg(not(target_arch = "x86_64"))]
    id: u32,
}

impl PrimRef {
    #[inline(always)]
    fn new(bounds: Aabb, id: u32) -> PrimRef {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::*;
            // SAFETY: SSE is part of x86-64; Vec3A is an __m128 there.
            unsafe {
                // (z, w, v.w, w) from the high halves, then (x, y) and (z, w): SSE only.
                let with_w = |v: Vec3A, w: u32| {
                    let v: __m128 = v.into();
                    Vec3A::from(_mm_shuffle_ps::<0x44>(v, _mm_unpackhi_ps(v, _mm_set1_ps(w as f32))))
                };
                PrimRef { bounds: Aabb::new(with_w(bounds.min, id & 0xffff), with_w(bounds.max, id >> 16)) }
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        PrimRef { bounds, id }
    }

    #[inline(always)]
    fn id(&self) -> u32 {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::*;
            // SAFETY: SSE is part of x86-64; Vec3A is an __m128 there.
            unsafe {
                let w = |v: Vec3A| _mm_cvtss_f32(_mm_shuffle_ps::<0xff>(v.into(), v.into())) as u32;
                w(self.bounds.min) | w(self.bounds.max) << 16
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        self.id
    }

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

/// The number of bins for a range of `n` primitives (see [`BINS`]).
#[inline]
fn bins_for(n: usize) -> usize {
    n.next_power_of_two().clamp(8, BINS)
}

/// Per axis, the factor taking a key's offset from `cb.min` to one of `bins` bins (slightly
/// under bins / extent so the largest key lands in the last bin; 0 on a flat axis).
#[inline]
fn bin_scale(cb: &Aabb, bins: usize) -> Vec3A {
    let ext = cb.diagonal();
    Vec3A::select(ext.cmpgt(Vec3A::ZERO), Vec3A::splat(bins as f32 * (1.0 - 1e-6)) / ext, Vec3A::ZERO)
}

/// Per axis, a key's offset from `min` in bins (`scale` from [`bin_scale`]): binning and
/// partitioning compare the same numbers, so a primitive goes to the side its bin is on.
#[inline(always)]
fn bin_offset(key: Vec3A, min: Vec3A, scale: Vec3A) -> Vec3A {
    (key - min) * scale
}

/// Per axis, the bin of [`bin_offset`] `x` among `bins`: truncated and clamped to
/// 0..bins − 1, NaN to 0 (what `(x as usize).min(bins − 1)` gives), the three axes in one
/// SSE conversion instead of three saturating scalar ones (the binning's main cost).
#[inline(always)]
fn bin_index(x: Vec3A, bins: usize) -> [i32; 4] {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // SAFETY: SSE and SSE2 are part of x86_64; __m128i and [i32; 4] are 16 plain bytes.
        unsafe {
            // `maxps` returns its second operand (0) when the first is NaN.
            let c = _mm_min_ps(_mm_max_ps(x.into(), _mm_setzero_ps()), _mm_set1_ps((bins - 1) as f32));
            std::mem::transmute::<__m128i, [i32; 4]>(_mm_cvttps_epi32(c))
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let a = x.to_array();
        [0, 1, 2, 0].map(|i| (a[i] as usize).min(bins - 1) as i32)
    }
}

/// The best split of `refs` (key bounds `cb`, box bounds `nb`) between [`bins_for`] bins:
/// (axis, first bin of the right side, its cost), or `None` when the keys coincide on
/// every axis.
fn best_split(refs: &[PrimRef], nb: &Aabb, cb: &Aabb) -> Option<(usize, usize, f32)> {
    match bins_for(refs.len()) {
        8 => best_split_in::<8>(refs, nb, cb),
        16 => best_split_in::<16>(refs, nb, cb),
        _ => best_split_in::<BINS>(refs, nb, cb),
    }
}

/// [`best_split`] with `B` bins per axis (a constant, so the bins live in fixed arrays).
fn best_split_in<const B: usize>(refs: &[PrimRef], nb: &Aabb, cb: &Aabb) -> Option<(usize, usize, f32)> {
    let ext = cb.diagonal();
    let scale = bin_scale(cb, B);
    let mut bin_box = [[Aabb::INVALID; B]; 3];
    let mut bin_count = [[0u32; B]; 3];
    for r in refs {
        let b = bin_index(bin_offset(r.key(), cb.min, scale), B);
        for a in 0..3 {
            // B is a power of two and b[a] < B: the mask only drops the bounds check.
            let k = b[a] as usize & (B - 1);
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
        let mut right = [0f32; B];
        let (mut rb, mut rn) = (Aabb::INVALID, 0usize);
        for k in (1..B).rev() {
            rb = rb.union(&bin_box[a][k]);
            rn += bin_count[a][k] as usize;
            right[k] = area(&rb) * blocks(rn);
        }
        let (mut lb, mut ln) = (Aabb::INVALID, 0usize);
        for k in 1..B {
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

/// Moves the primitives `left` accepts to the front of `range`, keeping the bounds of each
/// side's boxes and keys: (how many went left, [left boxes, left keys, right boxes, right
/// keys]). Without a branch on the side (Lomuto's scheme with a moving hole, as in
/// Bergdoll's branchless partitions): each primitive is written to the end of the left part
/// and the first right one moved behind the right part, the left count advanced by the
/// side; the sides' bounds are unions with the box or with the empty box, picked by a mask.
/// A primitive's side is a coin toss to the branch predictor: the partition before, which
/// branched on it, is the one this replaced (README, "Worker ray rate").
#[inline(always)]
fn partition(range: &mut [PrimRef], left: impl Fn(&PrimRef) -> bool) -> (usize, [Aabb; 4]) {
    let n = range.len();
    let [mut lb, mut lc, mut rb, mut rc] = [Aabb::INVALID; 4];
    if n == 0 {
        return (0, [lb, lc, rb, rc]);
    }
    let mut add = |r: &PrimRef, is_left: bool| {
        // (this side's share, the other side's): the box itself and the empty box, whose
        // union with anything is that thing, exactly.
        let m = glam::BVec3A::splat(is_left);
        let split = |b: &Aabb| {
            let none = Aabb::INVALID;
            let this = Aabb::new(Vec3A::select(m, b.min, none.min), Vec3A::select(m, b.max, none.max));
            let other = Aabb::new(Vec3A::select(m, none.min, b.min), Vec3A::select(m, none.max, b.max));
            (this, other)
        };
        let key = r.key();
        let ((lbox, rbox), (lkey, rkey)) = (split(&r.bounds), split(&Aabb::new(key, key)));
        lb = lb.union(&lbox);
        rb = rb.union(&rbox);
        lc = lc.union(&lkey);
        rc = rc.union(&rkey);
    };
    let p = range.as_mut_ptr();
    // SAFETY: every index read or written is below n; the hole is the one position whose
    // value has been taken out (first the first primitive, held in `first`), so no
    // primitive is lost or duplicated when it is overwritten; `ptr::copy` allows a position
    // onto itself. PrimRef is Copy, so nothing is dropped twice.
    let count = unsafe {
        let first = std::ptr::read(p);
        let mut l = 0usize;
        // Invariant at step k: [0, l) left, [l, k − 1) right, k − 1 the hole.
        for k in 1..n {
            let r = std::ptr::read(p.add(k));
            let is_left = left(&r);
            std::ptr::copy(p.add(l), p.add(k - 1), 1);
            std::ptr::write(p.add(l), r);
            l += is_left as usize;
            add(&r, is_left);
        }
        // The hole is at n − 1: the first primitive goes where the left part ends.
        let is_left = left(&first);
        std::ptr::copy(p.add(l), p.add(n - 1), 1);
        std::ptr::write(p.add(l), first);
        add(&first, is_left);
        l + is_left as usize
    };
    (count, [lb, lc, rb, rc])
}

/// Ranges of at least this many primitives are split off as tasks of their own when the
/// build runs on more than one thread (below it a task is not worth its bookkeeping).
const MIN_TASK: usize = 4096;

/// The binary BVH over `boxes`: leaves of 1..=[`MAX_LEAF`] primitives
/// (`primitive_indices[first_index..first_index + prim_count]`), the two children of an
/// inner node at `first_index` and `first_index + 1`, node 0 the root. On a rayon pool of
/// more than one thread the top of the tree is built first, down to ranges of about
/// 1 / (8 · threads) of the primitives, and those subtrees in parallel, each into nodes of
/// its own appended after; the splits, so the tree, are the same on any number of threads.
pub fn build(boxes: &[Aabb]) -> Bvh2 {
    build_with(boxes.len(), |i| boxes[i])
}

/// [`build`] over the boxes `box_of(0..n)`, taken straight into the build's records (an
/// object's triangles need no array of boxes of their own: 28 MB written and read once
/// fewer on the dragon).
pub fn build_with(n: usize, box_of: impl Fn(usize) -> Aabb + Sync) -> Bvh2 {
    use rayon::prelude::*;
    let mut b2 = Bvh2::default();
    if n == 0 {
        return b2;
    }
    let mut refs: Vec<PrimRef> = (0..n).into_par_iter().map(|id| PrimRef::new(box_of(id), id as u32)).collect();
    let (root, root_keys) = bounds(&refs);
    // A full binary tree over n primitives has at most 2n − 1 nodes: reserved once, the
    // vector never moves (the pages past its use are never touched, so never mapped in).
    b2.nodes.reserve(2 * n - 1);
    b2.nodes.push(Bvh2Node { aabb: root, ..Default::default() });
    let threads = rayon::current_num_threads();
    let defer_below = if threads > 1 { (n / (8 * threads)).max(MIN_TASK) } else { 0 };
    let mut tasks = grow(&mut b2.nodes, &mut refs, vec![(0usize, 0usize, n, root_keys)], defer_below);
    if !tasks.is_empty() {
        // Disjoint ranges of `refs`, one per task, in order.
        tasks.sort_unstable_by_key(|t| t.1);
        let mut rest: &mut [PrimRef] = &mut refs;
        let mut at = 0;
        let mut jobs = Vec::with_capacity(tasks.len());
        for &(node, begin, end, cb) in &tasks {
            let (_, tail) = std::mem::take(&mut rest).split_at_mut(begin - at);
            let (range, tail) = tail.split_at_mut(end - begin);
            rest = tail;
            at = end;
            jobs.push((node, begin, range, cb));
        }
        let root_boxes: Vec<Aabb> = tasks.iter().map(|t| b2.nodes[t.0].aabb).collect();
        let built: Vec<(usize, usize, Vec<Bvh2Node>)> = jobs
            .into_par_iter()
            .zip(root_boxes)
            .map(|((node, begin, range, cb), aabb)| {
                let mut nodes = vec![Bvh2Node { aabb, ..Default::default() }];
                let len = range.len();
                grow(&mut nodes, range, vec![(0, 0, len, cb)], 0);
                (node, begin, nodes)
            })
            .collect();
        // Each subtree's root takes its placeholder's slot, the rest goes after the nodes
        // so far: local node i ≥ 1 lands at base + i − 1; leaves' ranges shift by `begin`.
        for (node, begin, local) in built {
            let base = b2.nodes.len();
            let place = |mut n: Bvh2Node| {
                n.first_index = if n.prim_count > 0 { n.first_index + begin as u32 } else { (base + n.first_index as usize - 1) as u32 };
                n
            };
            b2.nodes[node] = place(local[0]);
            b2.nodes.extend(local[1..].iter().map(|n| place(*n)));
        }
    }
    b2.primitive_indices = refs.iter().map(|r| r.id()).collect();
    b2
}

/// Builds the subtrees `todo` holds — (node in `nodes`, its range of `refs`, the range's key
/// bounds), the node's box already set — into `nodes`, leaves' ranges as indices into `refs`;
/// a range of more than one and at most `defer_below` primitives is left unsplit and
/// returned instead (0: none).
fn grow(nodes: &mut Vec<Bvh2Node>, refs: &mut [PrimRef], mut todo: Vec<(usize, usize, usize, Aabb)>, defer_below: usize) -> Vec<(usize, usize, usize, Aabb)> {
    let mut deferred = Vec::new();
    // An explicit stack since a degenerate mesh may make the tree deep.
    while let Some((node, begin, end, cb)) = todo.pop() {
        let n = end - begin;
        if n > 1 && n <= defer_below {
            deferred.push((node, begin, end, cb));
            continue;
        }
        let nb = nodes[node].aabb;
        let range = &mut refs[begin..end];
        // A range that fits one leaf block is a leaf without binning: a split would cost
        // NODE_COST · area(nb) plus its sides' non-negative terms, never less than the leaf's
        // LEAF_COST · area(nb) · 1 (NODE_COST ≥ LEAF_COST, asserted below). Every leaf comes
        // from such a range, so this skips as many bin sweeps as there are leaves.
        const { assert!(NODE_COST >= LEAF_COST) };
        if n <= MAX_LEAF as usize {
            nodes[node].prim_count = n as u32;
            nodes[node].first_index = begin as u32;
            continue;
        }
        // The children's box and key bounds, gathered by the partition when it runs (one
        // pass over the range fewer per level than measuring them after).
        let mut sides = None;
        let mid = match best_split(range, &nb, &cb) {
            Some((axis, k, _)) => {
                // Partition by bin, left bins first (the same arithmetic as the binning):
                // for k in 1..bins, [`bin_index`] < k exactly when the offset is not ≥ k
                // (NaN, bin 0, included), compared on all axes at once and the split
                // axis's bit taken (no lane extraction or float-to-integer conversion).
                let scale = bin_scale(&cb, bins_for(n));
                let kf = Vec3A::splat(k as f32);
                let left = |r: &PrimRef| bin_offset(r.key(), cb.min, scale).cmpge(kf).bitmask() >> axis & 1 == 0;
                let (i, [lb, lc, rb, rc]) = partition(range, left);
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
        let first = nodes.len();
        nodes[node].first_index = first as u32;
        for (side, (lo, hi)) in [(begin, begin + mid), (begin + mid, end)].into_iter().enumerate() {
            let (b, c) = match sides {
                Some(s) => s[side],
                None => bounds(&refs[lo..hi]),
            };
            nodes.push(Bvh2Node { aabb: b, ..Default::default() });
            todo.push((nodes.len() - 1, lo, hi, c));
        }
    }
    deferred
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random boxes, coincident boxes and a single box: every primitive is in exactly one
    /// leaf of 1..=MAX_LEAF primitives, every node's box is the union of its children's
    /// (leaves: of their primitives'), and each inner node has two children.
    #[test]
    fn tree_covers_every_primitive_once_with_exact_boxes() {
        let random = random_boxes(99, 2000, Vec3A::splat(10.0));
        let same = vec![Aabb::new(Vec3A::ZERO, Vec3A::ONE); 37];
        let one = vec![Aabb::new(Vec3A::ONE, Vec3A::splat(2.0))];
        // Enough boxes for the two-thread build to split off subtrees (> MIN_TASK).
        let many = random_boxes(98, 12 * MIN_TASK, Vec3A::splat(100.0));
        let two = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        for (boxes, threads) in [(&random, 1), (&same, 1), (&one, 1), (&random, 2), (&many, 2)] {
            let b2 = if threads == 1 { build(boxes) } else { two.install(|| build(boxes)) };
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
            if boxes.len() >= 2000 {
                assert!(leaves * 2 < boxes.len(), "random boxes share leaves: {leaves} leaves");
            }
        }
    }

    /// [`bin_index`] is the saturating cast it replaced, `(x as usize).min(bins − 1)`, lane
    /// by lane, on in-range, boundary, out-of-range and non-finite offsets; and the
    /// partition's test (offset not ≥ k) puts on the left exactly the bins below k.
    #[test]
    fn bin_index_is_the_clamped_cast_and_agrees_with_the_partition() {
        let mut xs = vec![0.0, -0.0, 0.5, 1.0, 7.0, 7.999999, 8.0, 15.5, 16.0, 31.99998, 32.0, 1e9, -1.0, -1e9, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MIN_POSITIVE];
        let mut z = 5u64;
        for _ in 0..300 {
            z = z.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            xs.push((z >> 40) as f32 / (1u64 << 24) as f32 * 40.0 - 4.0);
        }
        for bins in [8, 16, BINS] {
            for w in xs.windows(3) {
                let got = bin_index(Vec3A::new(w[0], w[1], w[2]), bins);
                for a in 0..3 {
                    let want = (w[a] as usize).min(bins - 1);
                    assert_eq!(got[a] as usize, want, "offset {} of {bins} bins", w[a]);
                    for k in 1..bins {
                        let left = Vec3A::new(w[0], w[1], w[2]).cmpge(Vec3A::splat(k as f32)).bitmask() >> a & 1 == 0;
                        assert_eq!(left, want < k, "offset {} split at {k}", w[a]);
                    }
                }
            }
        }
    }

    /// The branchless partition against its definition: on random sides (all left, all
    /// right, mixed; 0 to 40 primitives) the left part holds exactly the primitives the test
    /// accepts, every primitive is still there once, and each side's bounds are the unions
    /// of its boxes and keys.
    #[test]
    fn partition_keeps_every_primitive_and_the_sides_bounds() {
        let boxes = random_boxes(5, 40, Vec3A::splat(10.0));
        let mut z = 77u64;
        for n in 0..=40usize {
            for rule in 0..4 {
                z = z.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let pattern = z;
                let is_left = |id: u32| match rule {
                    0 => true,
                    1 => false,
                    _ => pattern >> (id % 64) & 1 == 1,
                };
                let mut refs: Vec<PrimRef> = boxes[..n].iter().enumerate().map(|(id, b)| PrimRef::new(*b, id as u32)).collect();
                let (count, [lb, lc, rb, rc]) = partition(&mut refs, |r| is_left(r.id()));
                assert_eq!(count, (0..n as u32).filter(|&id| is_left(id)).count());
                assert!(refs[..count].iter().all(|r| is_left(r.id())) && refs[count..].iter().all(|r| !is_left(r.id())));
                let mut ids: Vec<u32> = refs.iter().map(|r| r.id()).collect();
                ids.sort_unstable();
                assert_eq!(ids, (0..n as u32).collect::<Vec<_>>());
                for (side, (b, c)) in [(&refs[..count], (lb, lc)), (&refs[count..], (rb, rc))] {
                    let (want_b, want_c) = bounds(side);
                    assert_eq!((b.min, b.max, c.min, c.max), (want_b.min, want_b.max, want_c.min, want_c.max));
                }
            }
        }
    }

    /// A range of at most MAX_LEAF primitives, made a leaf without binning, is one no split
    /// would beat: the binned split's cost is never below the leaf's, on random ranges of
    /// 2..=MAX_LEAF boxes of every size and on coincident ones.
    #[test]
    fn small_ranges_never_split_cheaper_than_a_leaf() {
        let boxes = random_boxes(11, 4000, Vec3A::new(3.0, 0.5, 2.0));
        let mut ranges: Vec<&[Aabb]> = (2..=MAX_LEAF as usize).flat_map(|n| boxes.chunks_exact(n).take(300)).collect();
        let same = [Aabb::new(Vec3A::ZERO, Vec3A::ONE); 4];
        ranges.push(&same);
        for range in ranges {
            let refs: Vec<PrimRef> = range.iter().enumerate().map(|(id, b)| PrimRef::new(*b, id as u32)).collect();
            let (nb, cb) = bounds(&refs);
            let leaf_cost = LEAF_COST * area(&nb) * blocks(refs.len());
            if let Some((_, _, cost)) = best_split(&refs, &nb, &cb) {
                assert!(leaf_cost <= cost, "{} boxes: leaf {leaf_cost}, split {cost}", refs.len());
            }
        }
    }

    /// `n` unit-or-smaller boxes at uniform corners in [0, spread] (a fixed pseudo-random
    /// sequence per seed).
    fn random_boxes(seed: u64, n: usize, spread: Vec3A) -> Vec<Aabb> {
        let mut z = seed;
        let mut next = || {
            z = z.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (z >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..n)
            .map(|_| {
                let c = Vec3A::new(next(), next(), next()) * spread;
                Aabb::new(c, c + Vec3A::new(next(), next(), next()))
            })
            .collect()
    }

    /// The tree as the nodes' boxes and leaves' primitives in depth-first order, left child
    /// first: equal for two builds that made the same splits, wherever their nodes sit.
    fn shape(b2: &Bvh2) -> Vec<([f32; 6], Vec<u32>)> {
        let mut out = Vec::new();
        let mut stack = vec![0usize];
        while let Some(k) = stack.pop() {
            let n = &b2.nodes[k];
            let (lo, hi) = (n.aabb.min.to_array(), n.aabb.max.to_array());
            let prims = b2.primitive_indices[n.first_index as usize..(n.first_index + n.prim_count) as usize].to_vec();
            if n.prim_count == 0 {
                stack.extend([n.first_index as usize + 1, n.first_index as usize]);
            }
            out.push(([lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]], prims));
        }
        out
    }

    /// The build on two threads (subtrees built apart and appended) makes the very tree the
    /// one-thread build does, on boxes enough to be split into tasks.
    #[test]
    fn two_threads_build_the_same_tree() {
        // Flattened in y, so the splits are not all alike.
        let boxes = random_boxes(7, 20 * MIN_TASK, Vec3A::new(100.0, 10.0, 100.0));
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| build(&boxes));
        let two = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap().install(|| build(&boxes));
        assert_eq!(one.nodes.len(), two.nodes.len());
        assert!(shape(&one) == shape(&two), "the two-thread tree differs");
        // The node order does differ (the subtrees were appended), so the test compared
        // trees rather than arrays.
        assert!(one.nodes.iter().zip(&two.nodes).any(|(a, b)| a.first_index != b.first_index));
    }
}
