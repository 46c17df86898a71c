//! A binary BVH ([`super::sah_build`]'s, in obvhs' type) collapsed into 8-wide nodes by the surface area heuristic: the
//! dynamic program of Ylitie, Karras and Laine, "Efficient Incoherent Ray Traversal on
//! GPUs Through Compressed Wide BVHs" (HPG 2017), §4.1, with this BVH's leaves (one
//! block of up to [`MAX_LEAF`] primitives tested at once, so a leaf costs the same for 1
//! to 4 of them). For every binary node `n` and `i` in 1..=8 it finds the cheapest way to
//! stand for `n`'s subtree with at most `i` children of a wide node — `n` itself as a
//! leaf or an inner node, or its subtree's nodes spread over the `i` slots — so which
//! binary nodes are opened is chosen by expected cost (area-weighted node and leaf
//! tests), not greedily by the largest area.
use super::huge_pages::HugeArray;
use super::wide::{leaf_code, Bvh8Build, LeafSlots, Node8, EMPTY_NODE, MAX_LEAF};
use obvhs::bvh2::Bvh2;

/// Expected cost of visiting an 8-wide node (its 8 slab tests) relative to a leaf block
/// test, per unit of the box's area. Equal costs: 2:1 either way traced the dragon's rays
/// no faster within the shared machine's noise (README, "Worker ray rate").
const NODE_COST: f32 = 1.0;
/// Expected cost of testing one leaf block per unit of its box's area.
const LEAF_COST: f32 = 1.0;

/// What a binary node stands for at one slot budget.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Choice {
    /// One slot: the node is a leaf.
    Leaf,
    /// One slot: the node is an inner wide node (its children per `split8`).
    Inner,
    /// `i` slots: no better than `i - 1` slots.
    Fewer,
    /// `i` slots: `k` for the left child's subtree, `i - k` for the right's.
    Split(u8),
}

/// The dynamic program's result: per binary node and slot budget 1..=8, its cost and
/// choice, and how an inner node spreads its children over its 8 slots.
struct Plan {
    cost: Vec<[f32; 8]>,
    choice: Vec<[Choice; 8]>,
    /// Left-subtree slots of the best spread of an inner node's subtree over 8 slots.
    split8: Vec<u8>,
}

/// The binary nodes in an order that puts every node's children before it: index order
/// backwards when every inner node's children sit after it (as the SAH build lays them
/// out: then the dynamic program reads the nodes in memory order), else a depth-first
/// order reversed (the children of inner node `n` are `first_index` and `first_index + 1`).
fn children_first(b2: &Bvh2) -> Vec<u32> {
    let n = b2.nodes.len();
    if b2.nodes.iter().enumerate().all(|(k, node)| node.is_leaf() || node.first_index as usize > k) {
        return (0..n as u32).rev().collect();
    }
    let mut order = Vec::with_capacity(n);
    // An explicit stack: the binary tree may be deep on degenerate meshes.
    let mut stack = vec![0u32];
    while let Some(k) = stack.pop() {
        order.push(k);
        let node = &b2.nodes[k as usize];
        if !node.is_leaf() {
            stack.push(node.first_index);
            stack.push(node.first_index + 1);
        }
    }
    order.reverse();
    order
}

fn plan(b2: &Bvh2, max_leaf: u32) -> Plan {
    let n = b2.nodes.len();
    let mut p = Plan { cost: vec![[0.0; 8]; n], choice: vec![[Choice::Leaf; 8]; n], split8: vec![0; n] };
    // Primitives under every node, filled as the nodes are planned, children first.
    let mut counts = vec![0u32; n];
    for k in children_first(b2) {
        let k = k as usize;
        let node = &b2.nodes[k];
        let area = node.aabb.half_area();
        if node.is_leaf() {
            // A binary leaf (≤ MAX_LEAF primitives) is always a leaf here.
            p.cost[k] = [LEAF_COST * area; 8];
            counts[k] = node.prim_count;
            continue;
        }
        let (l, r) = (node.first_index as usize, node.first_index as usize + 1);
        counts[k] = counts[l] + counts[r];
        // dist[j - 1]: the two subtrees spread over j slots (j >= 2). A subtree of c
        // primitives never uses more than c slots (its cost is flat from there), so only
        // splits within both subtrees' counts are tried: most binary nodes are small.
        let (cl, cr) = (counts[l].min(8) as usize, counts[r].min(8) as usize);
        let jmax = (cl + cr).min(8);
        let mut dist = [f32::INFINITY; 8];
        let mut dist_k = [0u8; 8];
        for j in 2..=jmax {
            for left in j.saturating_sub(cr).max(1)..=cl.min(j - 1) {
                let c = p.cost[l][left - 1] + p.cost[r][j - left - 1];
                if c < dist[j - 1] {
                    dist[j - 1] = c;
                    dist_k[j - 1] = left as u8;
                }
            }
        }
        // A leaf of c primitives is ⌈c / MAX_LEAF⌉ blocks tested one after the other.
        let leaf = if counts[k] <= max_leaf { LEAF_COST * area * counts[k].div_ceil(MAX_LEAF) as f32 } else { f32::INFINITY };
        // With more slots a spread never costs more, so the best is at the most slots.
        let inner = NODE_COST * area + dist[jmax - 1];
        p.split8[k] = dist_k[jmax - 1];
        let (mut c, mut ch) = if leaf <= inner { (leaf, Choice::Leaf) } else { (inner, Choice::Inner) };
        p.cost[k][0] = c;
        p.choice[k][0] = ch;
        for i in 2..=8 {
            if dist[i - 1] < c {
                (c, ch) = (dist[i - 1], Choice::Split(dist_k[i - 1]));
            } else {
                ch = Choice::Fewer;
            }
            p.cost[k][i - 1] = c;
            p.choice[k][i - 1] = ch;
        }
    }
    p
}

impl Plan {
    /// The binary nodes that stand for `n`'s subtree in at most `i` slots.
    fn roots(&self, b2: &Bvh2, n: usize, mut i: usize, out: &mut Vec<usize>) {
        loop {
            match self.choice[n][i - 1] {
                Choice::Leaf | Choice::Inner => return out.push(n),
                Choice::Fewer => i -= 1,
                Choice::Split(k) => {
                    let first = b2.nodes[n].first_index as usize;
                    self.roots(b2, first, k as usize, out);
                    return self.roots(b2, first + 1, i - k as usize, out);
                }
            }
        }
    }

    /// Whether binary node `n` becomes a leaf when it fills one slot.
    fn is_leaf(&self, b2: &Bvh2, n: usize) -> bool {
        b2.nodes[n].is_leaf() || self.choice[n][0] == Choice::Leaf
    }
}

/// Appends the primitives under `n` to `prims`, left to right.
fn gather(b2: &Bvh2, n: usize, prims: &mut Vec<u32>) {
    let leaf_prims = |node: &obvhs::bvh2::node::Bvh2Node| &b2.primitive_indices[node.first_index as usize..(node.first_index + node.prim_count) as usize];
    // Almost every wide leaf is one binary leaf: no stack for it.
    if b2.nodes[n].is_leaf() {
        return prims.extend_from_slice(leaf_prims(&b2.nodes[n]));
    }
    let mut stack = vec![n];
    while let Some(n) = stack.pop() {
        let node = &b2.nodes[n];
        if node.is_leaf() {
            prims.extend_from_slice(leaf_prims(node));
        } else {
            stack.push(node.first_index as usize + 1);
            stack.push(node.first_index as usize);
        }
    }
}

/// Collapses `b2` (non-empty) into `out`, whose node 0 is the root, with leaves of up to
/// `max_leaf` primitives (a multiple of [`MAX_LEAF`]: whole blocks).
pub(super) fn collapse(b2: &Bvh2, out: &mut Bvh8Build, max_leaf: u32) {
    let p = plan(b2, max_leaf);
    let mut nodes = vec![EMPTY_NODE];
    // The root as a wide node even when the plan would make it one leaf (a mesh of up to
    // four triangles): traversal starts at an inner node.
    let mut roots = Vec::with_capacity(8);
    if b2.nodes[0].is_leaf() {
        roots.push(0);
    } else {
        let first = b2.nodes[0].first_index as usize;
        let k = p.split8[0] as usize;
        p.roots(b2, first, k, &mut roots);
        p.roots(b2, first + 1, 8 - k, &mut roots);
    }
    // (wide node index, its binary roots, its level), filled depth first.
    let mut todo = vec![(0usize, roots, 1usize)];
    while let Some((at, kids, depth)) = todo.pop() {
        out.bvh.depth = out.bvh.depth.max(depth);
        let mut node: Node8 = EMPTY_NODE;
        for (i, &k) in kids.iter().enumerate() {
            let b = b2.nodes[k].aabb;
            let (lo, hi) = (b.min.to_array(), b.max.to_array());
            for a in 0..3 {
                node.planes[2 * a][i] = lo[a];
                node.planes[2 * a + 1][i] = hi[a];
            }
            if p.is_leaf(b2, k) {
                let (first, first_block) = (out.prims.len() as u32, out.blocks.len() as u32);
                gather(b2, k, &mut out.prims);
                let end = out.prims.len() as u32;
                // The leaf's primitives in runs of MAX_LEAF, one block each; its code names
                // the first block and how many.
                out.blocks.extend((first..end).step_by(MAX_LEAF as usize).map(|s| LeafSlots { first: s, count: (end - s).min(MAX_LEAF) }));
                node.child[i] = leaf_code(first_block, out.blocks.len() as u32 - first_block);
                out.leaf_count += 1;
            } else {
                let child = nodes.len();
                node.child[i] = child as u32;
                nodes.push(EMPTY_NODE);
                let first = b2.nodes[k].first_index as usize;
                let split = p.split8[k] as usize;
                let mut grand = Vec::with_capacity(8);
                p.roots(b2, first, split, &mut grand);
                p.roots(b2, first + 1, 8 - split, &mut grand);
                todo.push((child, grand, depth + 1));
            }
        }
        nodes[at] = node;
    }
    out.bvh.nodes = HugeArray::collect(nodes.into_iter());
}
