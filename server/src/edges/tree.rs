//! The edge tree of one mesh, in object space (paper 000 §6.4 "Accelerating silhouette
//! computation").
//!
//! "The leaves of this tree store edges; the internal nodes of the tree conservatively
//! represent the normals and positions of all the contained edges" as interval vectors: a
//! node holds the box of the normals of both faces of every edge below it and the box of
//! the edges' end points. Traversal evaluates Equation 1 at a node with interval arithmetic
//! ([`super::interval`]): `N · (E - P)` for the node's normal box `N`, position box `P` and
//! the eye `E` (a point, or a light's bounding box for area lights); when the interval has
//! one sign, every face below faces the same way for every eye in `E`, so no edge below can
//! be a silhouette and the subtree is pruned.
//!
//! Beyond the paper, each node also keeps a [`Spread`]: the interval `D` of `n · (p - c)`
//! over the faces' normals `n` and the edges' points `p` below it, for a fixed point `c` of
//! the node. Every `n · (e - p)` then lies in `N · (E - c) - D` too, and the traversal
//! prunes when either interval has one sign ([`Node::facing_tight`]). The box product pays
//! `|N| × (box of P)` even when the normals and points are strongly correlated (a flat-ish
//! patch: each normal is nearly perpendicular to the offsets of its own points); `D` keeps
//! them together. On the dragon it prunes 15 % of the nodes and 13 % of the edge tests the
//! interval test alone leaves (`edgepoint-bench edges` reports both).
//!
//! Construction is top-down. At each node the edges are split by their normal centroid on
//! the axis — and, beyond the paper, optionally by their position centroid — that minimises
//! the children's combined extent (binned: 16 candidate planes per axis, cost = Σ children
//! `count × extent`, extent = the sum of the normal box sides plus the position box sides
//! over a typical viewing distance, see [`SplitAxes`]). "Sharp edges higher": an edge whose
//! normals span more than half of the node's normal range on some axis stays at that node
//! and is tested whenever the node is reached, which keeps the children's normal boxes
//! compact on noisy scanned meshes.
//!
//! Layout: one flat array of 64-byte nodes in depth-first order (left child next to its
//! parent; the spread fits in the line because a node's stored blocks end where its left
//! child's begin, and subtree ends, needed only to take a subtree whole, sit in a side
//! array), and the edges in tree order as compact records (first end point and both
//! normals) so the leaf test streams through memory. Every subtree's edges are one
//! contiguous range, which lets a query take a whole subtree without testing it.
//! Leaf and stored edges are decided with the brute-force predicates of [`super::brute`],
//! so the tree's answers equal brute force exactly. Builds run in parallel with rayon.
use super::brute::face_side;
use super::interval::{IVec3, Interval};
use crate::prefetch::prefetch_lines as prefetch;
use edgepoint_scene::{Mesh, Progress};
use glam::{Vec3, Vec3A, Vec4};
use rayon::prelude::*;

/// One edge as the leaf test needs it: Equation 1 at the edge's first end point `p` for the
/// two face normals. `edge` indexes `Mesh::edges`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeRecord {
    pub p: Vec3,
    pub n0: Vec3,
    pub n1: Vec3,
    pub edge: u32,
}

impl EdgeRecord {
    /// Equation 1: exactly one of the two faces faces `eye` (same predicate as
    /// [`super::brute::classify`]).
    #[inline(always)]
    pub fn is_silhouette_from(&self, eye: Vec3) -> bool {
        face_side(self.n0, self.p, eye) != face_side(self.n1, self.p, eye)
    }

    /// Both faces face `eye`.
    #[inline(always)]
    pub fn both_face(&self, eye: Vec3) -> bool {
        face_side(self.n0, self.p, eye) && face_side(self.n1, self.p, eye)
    }
}

/// Marks an unused lane of a [`Block`].
pub const NO_EDGE: u32 = u32::MAX;

/// Four edges, one array per coordinate (160 bytes), so the leaf test runs on four edges at
/// a time from two and a half cache lines. Every lane computes `n · (eye - p)` with the very
/// operations of [`face_side`] (`glam::Vec3::dot`: subtract, multiply, add x + y, then + z;
/// no fused multiply-add), so the four-wide test decides exactly as the scalar one. Unused
/// lanes have `edge == NO_EDGE` and zero normals, so every facing test is false for them.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(32))]
pub struct Block {
    pub p: [[f32; 4]; 3],
    pub n0: [[f32; 4]; 3],
    pub n1: [[f32; 4]; 3],
    pub edge: [u32; 4],
}

impl Block {
    const EMPTY: Block = Block { p: [[0.0; 4]; 3], n0: [[0.0; 4]; 3], n1: [[0.0; 4]; 3], edge: [NO_EDGE; 4] };

    fn set(&mut self, k: usize, r: &EdgeRecord) {
        for a in 0..3 {
            self.p[a][k] = r.p[a];
            self.n0[a][k] = r.n0[a];
            self.n1[a][k] = r.n1[a];
        }
        self.edge[k] = r.edge;
    }

    /// Lane `k` as a record (`None` for an unused lane).
    pub fn record(&self, k: usize) -> Option<EdgeRecord> {
        (self.edge[k] != NO_EDGE).then(|| EdgeRecord {
            p: Vec3::new(self.p[0][k], self.p[1][k], self.p[2][k]),
            n0: Vec3::new(self.n0[0][k], self.n0[1][k], self.n0[2][k]),
            n1: Vec3::new(self.n1[0][k], self.n1[1][k], self.n1[2][k]),
            edge: self.edge[k],
        })
    }

    /// Bit k of the first mask is `face_side(n0, p, eye)` of lane k, of the second the same
    /// for `n1`.
    #[inline(always)]
    pub fn sides(&self, eye: Vec3) -> (u32, u32) {
        let v = |a: &[f32; 4]| Vec4::from_array(*a);
        let vx = Vec4::splat(eye.x) - v(&self.p[0]);
        let vy = Vec4::splat(eye.y) - v(&self.p[1]);
        let vz = Vec4::splat(eye.z) - v(&self.p[2]);
        let d0 = v(&self.n0[0]) * vx + v(&self.n0[1]) * vy + v(&self.n0[2]) * vz;
        let d1 = v(&self.n1[0]) * vx + v(&self.n1[1]) * vy + v(&self.n1[2]) * vz;
        (d0.cmpgt(Vec4::ZERO).bitmask(), d1.cmpgt(Vec4::ZERO).bitmask())
    }

    /// Calls `f(edge)` for every lane whose bit is set in `pick(sides)`.
    #[inline(always)]
    pub fn select(&self, eye: Vec3, pick: impl Fn(u32, u32) -> u32, mut f: impl FnMut(u32)) {
        let (a, b) = self.sides(eye);
        let mut m = pick(a, b);
        while m != 0 {
            f(self.edge[m.trailing_zeros() as usize]);
            m &= m - 1;
        }
    }

    /// The lanes in use.
    pub fn edges(&self) -> impl Iterator<Item = u32> + '_ {
        self.edge.iter().copied().filter(|&e| e != NO_EDGE)
    }
}

/// Marks a leaf in [`Node::link`].
const LEAF: u32 = 1 << 31;

/// A tree node, one cache line: normal box, position box, the node's [`Spread`]
/// `dlo..dhi`, and the first of its blocks in tree order, `start`. `link` is the right
/// child's index for an internal node (the left child is the next node, and the blocks
/// stored at the node end where the left child's begin), or [`LEAF`] plus the number of
/// blocks for a leaf (all of them stored). Where a subtree's blocks end is kept apart
/// (`EdgeTree::ends`): only taking a subtree whole needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
pub struct Node {
    pub nlo: [f32; 3],
    pub nhi: [f32; 3],
    pub plo: [f32; 3],
    pub phi: [f32; 3],
    pub dlo: f32,
    pub dhi: f32,
    pub start: u32,
    pub link: u32,
}

impl Node {
    #[inline(always)]
    pub fn is_leaf(&self) -> bool {
        self.link & LEAF != 0
    }
    /// The right child of an internal node.
    #[inline(always)]
    pub fn right(&self) -> u32 {
        self.link
    }
    #[inline(always)]
    pub fn spread(&self) -> Spread {
        Spread { lo: self.dlo, hi: self.dhi }
    }
    #[inline(always)]
    pub fn normals(&self) -> IVec3 {
        IVec3::from_arrays(&self.nlo, &self.nhi)
    }
    #[inline(always)]
    pub fn positions(&self) -> IVec3 {
        IVec3::from_arrays(&self.plo, &self.phi)
    }
    /// Equation 1 over the node: an interval holding `n · (e - p)` for every normal `n`,
    /// eye `e` in the box `[eye_lo, eye_hi]` and position `p` in the boxes — both its exact
    /// real value and the f32 value [`face_side`] computes for it.
    ///
    /// This is the hot loop of every query, so it is [`IVec3::dot_view`] done four lanes
    /// wide without rounding each operation outward: in plain round-to-nearest, evaluated in
    /// the leaf test's own order (x + y, then + z), the ends bound the leaf test's f32 value
    /// because rounding is monotone; a final widening by `8·2⁻²⁴ Σ max|n_i| max|v_i|`
    /// (more than the at most six roundings on any path, each within `2⁻²⁴` relative)
    /// makes them bound the exact value too. A child's interval lies inside its parent's.
    /// Tested against f64 and the leaf test.
    #[inline(always)]
    pub fn facing(&self, eye_lo: Vec3A, eye_hi: Vec3A) -> Interval {
        let v = |a: &[f32; 3]| Vec3A::new(a[0], a[1], a[2]);
        let (nlo, nhi) = (v(&self.nlo), v(&self.nhi));
        let vlo = eye_lo - v(&self.phi);
        let vhi = eye_hi - v(&self.plo);
        let (a, b, c, d) = (nlo * vlo, nlo * vhi, nhi * vlo, nhi * vhi);
        let mn = a.min(b).min(c.min(d));
        let mx = a.max(b).max(c.max(d));
        let mag = nlo.abs().max(nhi.abs()) * vlo.abs().max(vhi.abs());
        let slack = (mag.x + mag.y + mag.z) * (8.0 / 16_777_216.0);
        Interval { lo: (mn.x + mn.y) + mn.z - slack, hi: (mx.x + mx.y) + mx.z + slack }
    }

    /// The fixed point `c` of the node that its [`Spread`] is measured from: the centre of
    /// the position box (inside it, since f32 rounding is monotone and halving is exact).
    #[inline(always)]
    pub fn centre(&self) -> Vec3A {
        centre_of(&self.plo, &self.phi)
    }

    /// Equation 1 over the node, bounded twice (beyond the paper): the interval of
    /// [`Self::facing`] intersected with `N · (E - c) - D`, where `D` is the node's
    /// [`Spread`] (the interval of `n · (p - c)` over the faces' normals `n` and edge points
    /// `p` below it). Both hold `n · (e - p)` for every face below and eye `e` in the box, so
    /// their intersection does too; the second keeps each normal together with its own
    /// point and is far narrower on flat-ish patches, where `N · (E - P)` pays the whole
    /// position box times the normal.
    ///
    /// Conservative with respect to [`face_side`]: let `M = Σ max|n_i| max|e_i - p_i|` over
    /// the boxes (the `mag` of [`Self::facing`]). The f32 evaluation of `N · (E - c)` is
    /// within `4.01·2⁻²⁴ M` of the exact one (`c` lies in the box, so `|e_i - c_i|` is
    /// bounded by the same maximum), subtracting `D` (`|D| ≤ M`, rounded outward at build
    /// from f64) adds `2.01·2⁻²⁴ M`, the slack subtraction `3·2⁻²⁴ M`, and the leaf test's
    /// own f32 value is within `4.01·2⁻²⁴ M` of the exact one: `16·2⁻²⁴ M` covers them all.
    /// Tested against f64 and the leaf test.
    #[inline(always)]
    pub fn facing_tight(&self, eye_lo: Vec3A, eye_hi: Vec3A) -> Interval {
        let d = self.spread();
        let v = |a: &[f32; 3]| Vec3A::new(a[0], a[1], a[2]);
        let (nlo, nhi) = (v(&self.nlo), v(&self.nhi));
        let (plo, phi) = (v(&self.plo), v(&self.phi));
        let vlo = eye_lo - phi;
        let vhi = eye_hi - plo;
        let (a, b, c, e) = (nlo * vlo, nlo * vhi, nhi * vlo, nhi * vhi);
        let mn = a.min(b).min(c.min(e));
        let mx = a.max(b).max(c.max(e));
        let mag = nlo.abs().max(nhi.abs()) * vlo.abs().max(vhi.abs());
        let m = mag.x + mag.y + mag.z;
        let slack = m * (8.0 / 16_777_216.0);
        let centre = centre_of(&self.plo, &self.phi);
        let (wlo, whi) = (eye_lo - centre, eye_hi - centre);
        let (a, b, c, e) = (nlo * wlo, nlo * whi, nhi * wlo, nhi * whi);
        let mn2 = a.min(b).min(c.min(e));
        let mx2 = a.max(b).max(c.max(e));
        let slack2 = m * (16.0 / 16_777_216.0);
        let lo = ((mn.x + mn.y) + mn.z - slack).max(((mn2.x + mn2.y) + mn2.z - d.hi) - slack2);
        let hi = ((mx.x + mx.y) + mx.z + slack).min(((mx2.x + mx2.y) + mx2.z - d.lo) + slack2);
        Interval { lo, hi }
    }
}

/// The centre of the box `[lo, hi]` (the same bits at build and query).
#[inline(always)]
fn centre_of(lo: &[f32; 3], hi: &[f32; 3]) -> Vec3A {
    let v = |a: &[f32; 3]| Vec3A::new(a[0], a[1], a[2]);
    (v(lo) + v(hi)) * 0.5
}

/// The interval `D` of `n · (p - c)` over the edges below a node (both face normals `n` of
/// each, at the point `p` the leaf test uses, the edge's first end point) for the node's
/// [`Node::centre`] `c`: computed in f64 at build and rounded outward to f32 (the f64
/// rounding, below `2⁻⁵⁰ M`, is inside the slack of [`Node::facing_tight`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Spread {
    pub lo: f32,
    pub hi: f32,
}

impl Spread {
    /// The spread of the edges in `blocks` about `c`.
    pub fn of(blocks: &[Block], c: Vec3A) -> Spread {
        let c = [c.x as f64, c.y as f64, c.z as f64];
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for b in blocks {
            for k in 0..4 {
                if b.edge[k] == NO_EDGE {
                    continue;
                }
                let d: [f64; 3] = std::array::from_fn(|a| b.p[a][k] as f64 - c[a]);
                for n in [&b.n0, &b.n1] {
                    let x = n[0][k] as f64 * d[0] + n[1][k] as f64 * d[1] + n[2][k] as f64 * d[2];
                    lo = lo.min(x);
                    hi = hi.max(x);
                }
            }
        }
        if lo > hi {
            return Spread::default();
        }
        // Outward to f32 (`as` rounds to nearest).
        let (l, h) = (lo as f32, hi as f32);
        Spread { lo: if l as f64 > lo { l.next_down() } else { l }, hi: if (h as f64) < hi { h.next_up() } else { h } }
    }
}

/// Which axes a node may be split on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SplitAxes {
    /// The paper's rule: the three normal axes only.
    Normals,
    /// Normal axes and position axes. A node's extent is the sum of its normal box sides
    /// plus the sum of its position box sides divided by `view_distance` (object units):
    /// the interval `N · (E - P)` of a node at distance `d` from the eye is about
    /// `d · |N| + |P|` wide, so both boxes matter, the position box relatively less from
    /// afar. Normal-only trees leave every node spread over the whole object, and for an
    /// eye at a few object sizes most nodes then straddle zero.
    NormalsAndPositions { view_distance: f32 },
}

/// Build parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeParams {
    /// A node with at most this many edges is a leaf.
    pub leaf_size: usize,
    /// An edge whose normal span on some axis exceeds this fraction of the node's normal
    /// range stays at the node (the paper: one half). `None` disables the rule.
    pub stay_fraction: Option<f32>,
    pub split: SplitAxes,
}

impl TreeParams {
    /// The defaults for a mesh with bounding box `bounds`: leaves of 8, the paper's
    /// one-half rule, and normal + position splits with a viewing distance of twice the
    /// bounding-box diagonal (chosen by `edgepoint-bench edges`, which reports the others).
    pub fn for_bounds(bounds: (Vec3, Vec3)) -> TreeParams {
        let diag = (bounds.1 - bounds.0).length().max(1e-6);
        TreeParams {
            leaf_size: 8,
            stay_fraction: Some(0.5),
            split: SplitAxes::NormalsAndPositions { view_distance: 2.0 * diag },
        }
    }
}

/// An edge tree over a subset of one mesh's edges.
#[derive(Debug, Clone, Default)]
pub struct EdgeTree {
    pub nodes: Vec<Node>,
    /// Where each node's subtree's blocks end (same index as `nodes`).
    pub ends: Vec<u32>,
    /// Edges in tree order, four to a block; every node's stored edges start a new block.
    pub blocks: Vec<Block>,
    /// Number of edges (lanes in use).
    pub len: usize,
    /// Parallel queries: the nodes above `frontier`, each tested for its stored edges only,
    /// and the subtrees traversed in parallel.
    upper: Vec<u32>,
    frontier: Vec<u32>,
    /// Trees with at least this many edges answer queries in parallel.
    pub parallel_from: usize,
}

/// Trees with more edges than this answer queries in parallel.
const PARALLEL_QUERY_EDGES: usize = 200_000;

/// Past this depth nodes split their edge list in halves, so a tree is at most this deep
/// plus 32 levels (traversal stacks are sized from it).
const MAX_DEPTH: usize = 60;
const STACK: usize = MAX_DEPTH + 40;
/// Nodes with more edges than this build their two children in parallel.
const PARALLEL_ITEMS: usize = 1 << 14;
const BINS: usize = 16;

/// Build-time edge: the boxes of its normals and of its end points (four-lane vectors, so
/// the binning's min/max run four wide).
#[derive(Debug, Clone, Copy)]
struct Item {
    nlo: Vec3A,
    nhi: Vec3A,
    plo: Vec3A,
    phi: Vec3A,
    edge: u32,
}

impl Item {
    #[inline(always)]
    fn centroid(&self, axis: usize) -> f32 {
        if axis < 3 {
            (self.nlo[axis] + self.nhi[axis]) * 0.5
        } else {
            (self.plo[axis - 3] + self.phi[axis - 3]) * 0.5
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Bounds {
    nlo: Vec3A,
    nhi: Vec3A,
    plo: Vec3A,
    phi: Vec3A,
}

impl Bounds {
    const EMPTY: Bounds = Bounds {
        nlo: Vec3A::splat(f32::INFINITY),
        nhi: Vec3A::splat(f32::NEG_INFINITY),
        plo: Vec3A::splat(f32::INFINITY),
        phi: Vec3A::splat(f32::NEG_INFINITY),
    };
    #[inline(always)]
    fn grow(&mut self, it: &Item) {
        self.nlo = self.nlo.min(it.nlo);
        self.nhi = self.nhi.max(it.nhi);
        self.plo = self.plo.min(it.plo);
        self.phi = self.phi.max(it.phi);
    }
    #[inline(always)]
    fn merge(&mut self, o: &Bounds) {
        self.nlo = self.nlo.min(o.nlo);
        self.nhi = self.nhi.max(o.nhi);
        self.plo = self.plo.min(o.plo);
        self.phi = self.phi.max(o.phi);
    }
    /// Combined extent (see [`SplitAxes`]); `inv_d == 0` counts normals only.
    #[inline(always)]
    fn extent(&self, inv_d: f32) -> f32 {
        let n = self.nhi - self.nlo;
        let p = self.phi - self.plo;
        (n.x + n.y + n.z) + (p.x + p.y + p.z) * inv_d
    }
}

/// Node bounds plus the bounds of the split keys (normal and position centroids).
#[derive(Debug, Clone, Copy)]
struct Summary {
    b: Bounds,
    clo: [f32; 6],
    chi: [f32; 6],
}

impl Summary {
    const EMPTY: Summary = Summary { b: Bounds::EMPTY, clo: [f32::INFINITY; 6], chi: [f32::NEG_INFINITY; 6] };
    #[inline(always)]
    fn grow(&mut self, it: &Item) {
        self.b.grow(it);
        for a in 0..6 {
            let c = it.centroid(a);
            self.clo[a] = self.clo[a].min(c);
            self.chi[a] = self.chi[a].max(c);
        }
    }
    fn merge(mut self, o: Summary) -> Summary {
        self.b.merge(&o.b);
        for a in 0..6 {
            self.clo[a] = self.clo[a].min(o.clo[a]);
            self.chi[a] = self.chi[a].max(o.chi[a]);
        }
        self
    }
}

fn summarize(items: &[Item]) -> Summary {
    if items.len() > PARALLEL_ITEMS {
        items
            .par_chunks(PARALLEL_ITEMS / 2)
            .map(|c| {
                let mut s = Summary::EMPTY;
                c.iter().for_each(|it| s.grow(it));
                s
            })
            .reduce(|| Summary::EMPTY, Summary::merge)
    } else {
        let mut s = Summary::EMPTY;
        items.iter().for_each(|it| s.grow(it));
        s
    }
}

#[derive(Clone, Copy)]
struct Bin {
    b: Bounds,
    count: u32,
}

type Bins = [[Bin; BINS]; 6];

const EMPTY_BINS: Bins = [[Bin { b: Bounds::EMPTY, count: 0 }; BINS]; 6];

struct Ctx<'a> {
    params: TreeParams,
    inv_d: f32,
    axes: std::ops::Range<usize>,
    progress: &'a dyn Progress,
}

fn bin_of(c: f32, lo: f32, scale: f32) -> usize {
    (((c - lo) * scale) as usize).min(BINS - 1)
}

/// The best (axis, bin boundary) to split the items that do not stay (`stays`) at, or `None`
/// when no candidate separates them (all keys equal); and how many stay.
fn choose_split(items: &[Item], s: &Summary, stays: &(impl Fn(&Item) -> bool + Sync), ctx: &Ctx) -> (Option<(usize, usize)>, usize) {
    let scales: [f32; 6] = std::array::from_fn(|a| {
        let w = s.chi[a] - s.clo[a];
        if w > 0.0 && w.is_finite() {
            BINS as f32 / w * (1.0 - 1e-6)
        } else {
            0.0
        }
    });
    // Candidate axes: the three whose keys spread widest, in the units of the cost (position
    // spread over the viewing distance). Splitting along a narrow axis rarely wins, and
    // binning half the axes halves the build.
    let mut axes: Vec<usize> = ctx.axes.clone().filter(|&a| scales[a] > 0.0).collect();
    let spread = |a: usize| (s.chi[a] - s.clo[a]) * if a < 3 { 1.0 } else { ctx.inv_d };
    axes.sort_by(|&x, &y| spread(y).total_cmp(&spread(x)));
    axes.truncate(3);
    let axes = &axes;
    let fill = |bins: &mut Bins, stayed: &mut usize, chunk: &[Item]| {
        for it in chunk {
            if stays(it) {
                *stayed += 1;
                continue;
            }
            for &a in axes {
                if scales[a] > 0.0 {
                    let k = bin_of(it.centroid(a), s.clo[a], scales[a]);
                    bins[a][k].b.grow(it);
                    bins[a][k].count += 1;
                }
            }
        }
    };
    let (bins, stayed): (Bins, usize) = if items.len() > PARALLEL_ITEMS {
        items
            .par_chunks(PARALLEL_ITEMS / 2)
            .map(|c| {
                let (mut b, mut n) = (EMPTY_BINS, 0);
                fill(&mut b, &mut n, c);
                (b, n)
            })
            .reduce(
                || (EMPTY_BINS, 0),
                |(mut x, nx), (y, ny)| {
                    for a in 0..6 {
                        for k in 0..BINS {
                            x[a][k].b.merge(&y[a][k].b);
                            x[a][k].count += y[a][k].count;
                        }
                    }
                    (x, nx + ny)
                },
            )
    } else {
        let (mut b, mut n) = (EMPTY_BINS, 0);
        fill(&mut b, &mut n, items);
        (b, n)
    };
    let mut best: Option<(f32, usize, usize)> = None;
    for &a in axes {
        // Suffix extents, then sweep the prefix.
        let mut right = [(Bounds::EMPTY, 0u32); BINS];
        let mut acc = (Bounds::EMPTY, 0u32);
        for k in (1..BINS).rev() {
            acc.0.merge(&bins[a][k].b);
            acc.1 += bins[a][k].count;
            right[k] = acc;
        }
        let mut left = (Bounds::EMPTY, 0u32);
        for k in 1..BINS {
            left.0.merge(&bins[a][k - 1].b);
            left.1 += bins[a][k - 1].count;
            let r = right[k];
            if left.1 == 0 || r.1 == 0 {
                continue;
            }
            let cost = left.1 as f32 * left.0.extent(ctx.inv_d) + r.1 as f32 * r.0.extent(ctx.inv_d);
            if best.is_none_or(|b| cost < b.0) {
                best = Some((cost, a, k));
            }
        }
    }
    (best.map(|(_, a, k)| (a, k)), stayed)
}

impl EdgeTree {
    /// Builds the tree over `edges` (indices into `mesh.edges`). `progress` advances by one
    /// unit per edge placed.
    pub fn build(mesh: &Mesh, edges: &[u32], params: TreeParams, progress: &dyn Progress) -> EdgeTree {
        let pos = &mesh.positions;
        let mut items: Vec<Item> = edges
            .par_iter()
            .map(|&i| {
                let e = &mesh.edges[i as usize];
                let (a, b) = (pos[e.v[0] as usize], pos[e.v[1] as usize]);
                let (n0, n1) = (e.normals[0], e.normals[1]);
                let (n0, n1, a, b) = (Vec3A::from(n0), Vec3A::from(n1), Vec3A::from(a), Vec3A::from(b));
                Item { nlo: n0.min(n1), nhi: n0.max(n1), plo: a.min(b), phi: a.max(b), edge: i }
            })
            .collect();
        let inv_d = match params.split {
            SplitAxes::Normals => 0.0,
            SplitAxes::NormalsAndPositions { view_distance } => 1.0 / view_distance.max(1e-30),
        };
        let axes = match params.split {
            SplitAxes::Normals => 0..3,
            SplitAxes::NormalsAndPositions { .. } => 0..6,
        };
        let ctx = Ctx { params, inv_d, axes, progress };
        let mut nodes = Vec::with_capacity(items.len() / params.leaf_size.max(1) * 2 + 1);
        if !items.is_empty() {
            let sum = summarize(&items);
            build_node(&mut items, 0, 0, &mut nodes, &ctx, sum);
        }
        let record = |it: &Item| {
            let e = &mesh.edges[it.edge as usize];
            EdgeRecord { p: pos[e.v[0] as usize], n0: e.normals[0], n1: e.normals[1], edge: it.edge }
        };
        let blocks = to_blocks(&mut nodes, &items, record);
        let ends = nodes.iter().map(|n| n.end).collect();
        let nodes: Vec<Node> = nodes.par_iter().with_min_len(256).map(|n| n.finish(&blocks)).collect();
        let (upper, frontier) = split_for_parallel(&nodes);
        EdgeTree { nodes, ends, blocks, len: items.len(), upper, frontier, parallel_from: PARALLEL_QUERY_EDGES }
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Depth-first traversal: `enter(node)` decides what to do at a node ([`Visit`]);
    /// `blocks(blocks, whole)` receives the blocks stored at every node tested
    /// (`whole == false`: each edge needs the leaf test) and all blocks of every subtree
    /// taken (`whole == true`).
    #[inline]
    pub fn traverse(&self, enter: impl FnMut(&Node) -> Visit, blocks: impl FnMut(&[Block], bool)) {
        if !self.nodes.is_empty() {
            self.traverse_from(0, enter, blocks);
        }
    }

    /// The traversal loop. Blocks are memory-bound (the leaf test itself is a few
    /// instructions), so their processing is software-pipelined: a node that passes has its
    /// first blocks prefetched and its range queued, and ranges are handed to `blocks`
    /// [`PIPELINE`] nodes later, by which time their cache lines have arrived.
    #[inline]
    fn traverse_from(&self, root: u32, mut enter: impl FnMut(&Node) -> Visit, mut blocks: impl FnMut(&[Block], bool)) {
        let mut stack = [0u32; STACK];
        stack[0] = root;
        let mut sp = 1;
        let mut queue = [(0u32, 0u32, false); PIPELINE];
        let (mut head, mut len) = (0usize, 0usize);
        let mut defer = |s: u32, e: u32, whole: bool, blocks: &mut dyn FnMut(&[Block], bool)| {
            for b in &self.blocks[s as usize..(s as usize + 2).min(e as usize)] {
                prefetch(b);
            }
            if len == PIPELINE {
                let (qs, qe, qw) = queue[head];
                blocks(&self.blocks[qs as usize..qe as usize], qw);
                queue[head] = (s, e, whole);
                head = (head + 1) % PIPELINE;
            } else {
                queue[(head + len) % PIPELINE] = (s, e, whole);
                len += 1;
            }
        };
        while sp > 0 {
            sp -= 1;
            let at = stack[sp];
            let node = &self.nodes[at as usize];
            match enter(node) {
                Visit::Skip => continue,
                Visit::TakeAll => {
                    defer(node.start, self.ends[at as usize], true, &mut blocks);
                    continue;
                }
                Visit::Test => {}
            }
            let stored_end = if node.is_leaf() {
                node.start + (node.link & !LEAF)
            } else {
                prefetch(&self.nodes[node.right() as usize]);
                stack[sp] = node.right();
                stack[sp + 1] = at + 1;
                sp += 2;
                self.nodes[at as usize + 1].start
            };
            if stored_end > node.start {
                defer(node.start, stored_end, false, &mut blocks);
            }
        }
        for k in 0..len {
            let (qs, qe, qw) = queue[(head + k) % PIPELINE];
            blocks(&self.blocks[qs as usize..qe as usize], qw);
        }
    }

    /// Runs a query over the whole tree, in parallel over subtrees for big trees (at least
    /// [`Self::parallel_from`] edges). `enter` and `blocks` are as in [`Self::traverse`];
    /// `blocks` writes its findings to the vector it is given; all of them end up in `out`
    /// (in no particular order).
    pub fn query<T: Send>(
        &self,
        out: &mut Vec<T>,
        enter: impl Fn(&Node) -> Visit + Sync,
        blocks: impl Fn(&[Block], bool, &mut Vec<T>) + Sync,
    ) {
        if self.nodes.is_empty() {
            return;
        }
        if self.len < self.parallel_from || self.frontier.is_empty() {
            self.traverse_from(0, &enter, |b, w| blocks(b, w, out));
            return;
        }
        // Above the frontier only the stored edges are tested (and nothing is taken whole):
        // the subtrees below are queried on their own. Every node's bound is conservative on
        // its own, so testing a frontier subtree whose ancestor would have been pruned costs
        // time, never correctness (and rarely happens: the box intervals nest).
        for &u in &self.upper {
            let stored = self.stored(u);
            if !stored.is_empty() && enter(&self.nodes[u as usize]) != Visit::Skip {
                blocks(&self.blocks[stored], false, out);
            }
        }
        let parts: Vec<Vec<T>> = self
            .frontier
            .par_iter()
            .map(|&f| {
                let mut v = Vec::new();
                self.traverse_from(f, &enter, |b, w| blocks(b, w, &mut v));
                v
            })
            .collect();
        for mut p in parts {
            out.append(&mut p);
        }
    }

    /// Silhouette edges seen from `eye` (object space): Equation 1 with pruning. Appends
    /// `Mesh::edges` indices (in no particular order).
    pub fn silhouettes(&self, eye: Vec3, out: &mut Vec<u32>) {
        let e = Vec3A::from(eye);
        self.query(
            out,
            |n| if n.facing_tight(e, e).sign_is_fixed() { Visit::Skip } else { Visit::Test },
            |blocks, _, out| {
                for b in blocks {
                    b.select(eye, |a, b| a ^ b, |i| out.push(i));
                }
            },
        );
    }

    /// Edges whose two faces both face `eye` (the forward-facing test of §6.2). Subtrees
    /// whose faces all face `eye` are taken whole; subtrees whose faces all face away are
    /// pruned.
    pub fn both_facing(&self, eye: Vec3, out: &mut Vec<u32>) {
        let e = Vec3A::from(eye);
        self.query(
            out,
            |n| {
                let f = n.facing_tight(e, e);
                if f.all_non_positive() {
                    Visit::Skip
                } else if f.all_positive() {
                    Visit::TakeAll
                } else {
                    Visit::Test
                }
            },
            |blocks, whole, out| {
                for b in blocks {
                    if whole {
                        out.extend(b.edges());
                    } else {
                        b.select(eye, |a, b| a & b, |i| out.push(i));
                    }
                }
            },
        );
    }

    /// The blocks stored at node `at` (all of a leaf's).
    #[inline(always)]
    pub fn stored(&self, at: u32) -> std::ops::Range<usize> {
        let n = &self.nodes[at as usize];
        let end = if n.is_leaf() { n.start + (n.link & !LEAF) } else { self.nodes[at as usize + 1].start };
        n.start as usize..end as usize
    }

    /// All blocks of the subtree at node `at`.
    pub fn subtree(&self, at: u32) -> std::ops::Range<usize> {
        self.nodes[at as usize].start as usize..self.ends[at as usize] as usize
    }

    /// Statistics of the tree's shape.
    pub fn stats(&self) -> TreeStats {
        let leaves = self.nodes.iter().filter(|n| n.is_leaf()).count();
        let stored_internal: usize = (0..self.nodes.len() as u32)
            .filter(|&i| !self.nodes[i as usize].is_leaf())
            .map(|i| self.blocks[self.stored(i)].iter().map(|b| b.edges().count()).sum::<usize>())
            .sum();
        let mut depth = 0;
        let mut d = vec![0u32; self.nodes.len()];
        for (i, n) in self.nodes.iter().enumerate() {
            depth = depth.max(d[i]);
            if !n.is_leaf() {
                d[i + 1] = d[i] + 1;
                d[n.right() as usize] = d[i] + 1;
            }
        }
        TreeStats {
            edges: self.len,
            nodes: self.nodes.len(),
            leaves,
            stored_at_internal_nodes: stored_internal,
            depth: depth as usize,
            bytes: self.nodes.len() * (std::mem::size_of::<Node>() + 4) + self.blocks.len() * std::mem::size_of::<Block>(),
        }
    }
}

/// What a traversal does at a node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Visit {
    /// Nothing below can match: prune.
    Skip,
    /// Test this node's stored edges and descend.
    Test,
    /// Everything below matches: take the whole subtree's edge range.
    TakeAll,
}

/// Node ranges queued before their blocks are processed (see [`EdgeTree::traverse`]).
const PIPELINE: usize = 8;

/// Lays the edges out in blocks: every node's stored edges start a new block. Rewrites the
/// nodes' edge ranges (item indices) into block ranges.
fn to_blocks(nodes: &mut [BuildNode], items: &[Item], record: impl Fn(&Item) -> EdgeRecord + Sync) -> Vec<Block> {
    // Nodes are in depth-first order and so are their stored item ranges.
    let mut first_block = Vec::with_capacity(nodes.len());
    let mut nblocks = 0u32;
    for n in nodes.iter() {
        first_block.push(nblocks);
        nblocks += n.stored.div_ceil(4);
    }
    let mut blocks = vec![Block::EMPTY; nblocks as usize];
    // Fill the blocks of each node from its stored items, in parallel over chunks of nodes.
    {
        let mut rest: &mut [Block] = &mut blocks;
        let mut jobs = Vec::with_capacity(nodes.len());
        for n in nodes.iter() {
            let (mine, tail) = rest.split_at_mut(n.stored.div_ceil(4) as usize);
            jobs.push((mine, n.start as usize, n.stored as usize));
            rest = tail;
        }
        jobs.into_par_iter().with_min_len(1024).for_each(|(mine, start, stored)| {
            for (k, it) in items[start..start + stored].iter().enumerate() {
                mine[k / 4].set(k % 4, &record(it));
            }
        });
    }
    // Block ranges: a leaf ends after its own blocks, an internal node where its right
    // subtree ends (children come after their parent, so walk backwards).
    let mut end = vec![0u32; nodes.len()];
    for i in (0..nodes.len()).rev() {
        let n = &nodes[i];
        end[i] = if n.is_leaf() { first_block[i] + n.stored.div_ceil(4) } else { end[n.right as usize] };
    }
    for (i, n) in nodes.iter_mut().enumerate() {
        n.stored = n.stored.div_ceil(4);
        n.start = first_block[i];
        n.end = end[i];
    }
    blocks
}

/// The nodes above depth `d` and the nodes at depth `d` (or leaves above it), with `d` the
/// first depth holding at least 16 nodes: parallel queries test the former for their
/// stored edges and traverse the latter in parallel.
fn split_for_parallel(nodes: &[Node]) -> (Vec<u32>, Vec<u32>) {
    if nodes.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let mut level = vec![0u32];
    let mut upper = Vec::new();
    while level.len() < 16 {
        let mut next = Vec::new();
        let mut leaves = Vec::new();
        for &i in &level {
            let n = &nodes[i as usize];
            if n.is_leaf() {
                leaves.push(i);
            } else {
                upper.push(i);
                next.push(i + 1);
                next.push(n.right());
            }
        }
        if next.is_empty() {
            break;
        }
        next.extend(leaves);
        level = next;
    }
    (upper, level)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TreeStats {
    pub edges: usize,
    pub nodes: usize,
    pub leaves: usize,
    /// Edges stored at internal nodes ("sharp edges higher").
    pub stored_at_internal_nodes: usize,
    pub depth: usize,
    pub bytes: usize,
}

/// A node while the tree is built: its edges (later blocks) `start..end` in tree order, of
/// which the first `stored` are stored at the node; `right == 0` marks a leaf.
#[derive(Debug, Clone, Copy)]
struct BuildNode {
    nlo: [f32; 3],
    nhi: [f32; 3],
    plo: [f32; 3],
    phi: [f32; 3],
    start: u32,
    stored: u32,
    end: u32,
    right: u32,
}

impl BuildNode {
    fn is_leaf(&self) -> bool {
        self.right == 0
    }

    /// The final node, once `start..end` are block ranges, with its spread.
    fn finish(&self, blocks: &[Block]) -> Node {
        let d = Spread::of(&blocks[self.start as usize..self.end as usize], centre_of(&self.plo, &self.phi));
        assert!(self.stored < LEAF, "too many blocks at one leaf");
        Node {
            nlo: self.nlo,
            nhi: self.nhi,
            plo: self.plo,
            phi: self.phi,
            dlo: d.lo,
            dhi: d.hi,
            start: self.start,
            link: if self.is_leaf() { LEAF | self.stored } else { self.right },
        }
    }
}

fn node_from(b: &Bounds, start: usize, stored: usize, end: usize) -> BuildNode {
    BuildNode {
        nlo: b.nlo.to_array(),
        nhi: b.nhi.to_array(),
        plo: b.plo.to_array(),
        phi: b.phi.to_array(),
        start: start as u32,
        stored: stored as u32,
        end: end as u32,
        right: 0,
    }
}

/// Builds the subtree over `items` (which sit at `start..` of the tree order) and appends
/// its nodes to `nodes` in depth-first order, the subtree's root first. Progress is
/// reported per sequential chunk (nodes of at most [`PARALLEL_ITEMS`] edges) and for edges
/// stored at the big nodes above them, so reporting costs nothing measurable.
fn build_node(items: &mut [Item], start: usize, depth: usize, nodes: &mut Vec<BuildNode>, ctx: &Ctx, sum: Summary) {
    let n = items.len();
    let big = n > PARALLEL_ITEMS;
    build_rec(items, start, depth, nodes, ctx, sum);
    if !big {
        ctx.progress.advance(n as u64);
    }
}

/// Three-way partition: class 0 first, then 1, then 2; returns the counts of classes 0 and
/// 1 and the summaries of classes 1 and 2 (one pass).
fn partition3(items: &mut [Item], class: impl Fn(&Item) -> u8) -> (usize, usize, Summary, Summary) {
    let (mut lo, mut mid, mut hi) = (0usize, 0usize, items.len());
    let (mut s1, mut s2) = (Summary::EMPTY, Summary::EMPTY);
    while mid < hi {
        match class(&items[mid]) {
            0 => {
                items.swap(lo, mid);
                lo += 1;
                mid += 1;
            }
            1 => {
                s1.grow(&items[mid]);
                mid += 1;
            }
            _ => {
                hi -= 1;
                s2.grow(&items[mid]);
                items.swap(mid, hi);
            }
        }
    }
    (lo, mid - lo, s1, s2)
}

/// One node: `sum` summarises `items`. Two passes over the items per node: binning (which
/// also counts the edges that stay) and a three-way partition (stay / left / right) that
/// also summarises the two children.
fn build_rec(items: &mut [Item], start: usize, depth: usize, nodes: &mut Vec<BuildNode>, ctx: &Ctx, sum: Summary) {
    let n = items.len();
    let big = n > PARALLEL_ITEMS;
    let me = nodes.len();
    let leaf = ctx.params.leaf_size.max(1);
    if n <= leaf {
        nodes.push(node_from(&sum.b, start, n, start + n));
        return;
    }
    // Sharp edges higher: an edge spanning more than `stay_fraction` of the node's normal
    // range on some axis stays here.
    let w = (sum.b.nhi - sum.b.nlo) * ctx.params.stay_fraction.unwrap_or(f32::INFINITY);
    let stays = |it: &Item| ctx.params.stay_fraction.is_some() && (it.nhi - it.nlo).cmpgt(w).any();
    let (split, stored) = if depth >= MAX_DEPTH { (None, 0) } else { choose_split(items, &sum, &stays, ctx) };
    if n - stored <= leaf || depth >= MAX_DEPTH && n <= 4 * leaf {
        // What is left fits a leaf: store it all here.
        nodes.push(node_from(&sum.b, start, n, start + n));
        if big {
            ctx.progress.advance(n as u64);
        }
        return;
    }
    let (stored, nl, ls, rs) = match split {
        Some((axis, k)) => {
            let scale = BINS as f32 / (sum.chi[axis] - sum.clo[axis]) * (1.0 - 1e-6);
            let lo = sum.clo[axis];
            partition3(items, |it| {
                if stays(it) {
                    0
                } else if bin_of(it.centroid(axis), lo, scale) < k {
                    1
                } else {
                    2
                }
            })
        }
        None => {
            // No key separates the rest (or too deep): stays first, then halves by index.
            let (st, _, _, _) = partition3(items, |it| if stays(it) { 0 } else { 1 });
            let half = (n - st) / 2;
            let (l, r) = items[st..].split_at(half);
            (st, half, summarize(l), summarize(r))
        }
    };
    let (stored, nl, ls, rs) = if nl == 0 || nl == n - stored {
        // A degenerate split (possible when keys collide at a bin edge): halve by index.
        let half = (n - stored) / 2;
        let (l, r) = items[stored..].split_at(half);
        (stored, half, summarize(l), summarize(r))
    } else {
        (stored, nl, ls, rs)
    };
    if big {
        ctx.progress.advance(stored as u64);
    }
    nodes.push(node_from(&sum.b, start, stored, start + n));
    let (left, right) = items[stored..].split_at_mut(nl);
    let (lstart, rstart) = (start + stored, start + stored + nl);
    if big {
        let (mut lv, mut rv) = (Vec::new(), Vec::new());
        rayon::join(
            || build_node(left, lstart, depth + 1, &mut lv, ctx, ls),
            || build_node(right, rstart, depth + 1, &mut rv, ctx, rs),
        );
        let base = nodes.len() as u32;
        let shift = |v: &mut Vec<BuildNode>, by: u32| {
            for x in v.iter_mut() {
                if x.right != 0 {
                    x.right += by;
                }
            }
        };
        shift(&mut lv, base);
        let rbase = base + lv.len() as u32;
        shift(&mut rv, rbase);
        nodes.append(&mut lv);
        nodes[me].right = rbase;
        nodes.append(&mut rv);
    } else {
        build_rec(left, lstart, depth + 1, nodes, ctx, ls);
        nodes[me].right = nodes.len() as u32;
        build_rec(right, rstart, depth + 1, nodes, ctx, rs);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edges::brute;
    use edgepoint_scene::NoProgress;

    /// A bumpy closed sphere (UV grid), noisy like a scan.
    fn bumpy_sphere(nu: u32, nv: u32, noise: f32) -> Mesh {
        let mut p = vec![Vec3::Y, -Vec3::Y];
        let mut h = 12345u32;
        let mut rnd = || {
            h ^= h << 13;
            h ^= h >> 17;
            h ^= h << 5;
            (h as f32 / u32::MAX as f32) - 0.5
        };
        for j in 1..nv {
            let th = std::f32::consts::PI * j as f32 / nv as f32;
            for i in 0..nu {
                let ph = 2.0 * std::f32::consts::PI * i as f32 / nu as f32;
                let r = 1.0 + noise * rnd();
                p.push(Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()) * r);
            }
        }
        let id = |i: u32, j: u32| 2 + (j - 1) * nu + (i % nu);
        let mut t = Vec::new();
        for i in 0..nu {
            t.push([0, id(i + 1, 1), id(i, 1)]);
            t.push([1, id(i, nv - 1), id(i + 1, nv - 1)]);
            for j in 1..nv - 1 {
                t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        let mut m = Mesh::from_triangles(p, t, &NoProgress);
        if m.signed_volume() < 0.0 {
            m.flip();
        }
        m
    }

    fn all_interior(m: &Mesh) -> Vec<u32> {
        (0..m.edges.len() as u32)
            .filter(|&i| {
                let e = &m.edges[i as usize];
                !e.is_boundary() && e.normals[0] != Vec3::ZERO && e.normals[1] != Vec3::ZERO
            })
            .collect()
    }

    fn eyes(n: usize, radius: f32) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let t = i as f32 * 2.399_963;
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
                let r = (1.0 - z * z).sqrt();
                Vec3::new(r * t.cos(), z, r * t.sin()) * radius * (0.3 + (i % 7) as f32 * 0.4)
            })
            .collect()
    }

    #[test]
    fn silhouettes_equal_brute_force_for_every_build_variant() {
        let m = bumpy_sphere(60, 40, 0.05);
        let edges = all_interior(&m);
        let variants = [
            TreeParams { leaf_size: 8, stay_fraction: Some(0.5), split: SplitAxes::Normals },
            TreeParams { leaf_size: 1, stay_fraction: None, split: SplitAxes::Normals },
            TreeParams::for_bounds(m.bounds),
            TreeParams { leaf_size: 3, stay_fraction: Some(0.25), split: SplitAxes::NormalsAndPositions { view_distance: 0.1 } },
        ];
        for (v, params) in variants.into_iter().enumerate() {
            let mut t = EdgeTree::build(&m, &edges, params, &NoProgress);
            // Half the variants answer in parallel over subtrees.
            if v % 2 == 1 {
                t.parallel_from = 0;
            }
            assert_eq!(t.len, edges.len());
            // Every edge exactly once, every subtree range nested in its parent's.
            let mut seen: Vec<u32> = t.blocks.iter().flat_map(|b| b.edges()).collect();
            seen.sort_unstable();
            assert_eq!(seen, edges);
            for (i, n) in t.nodes.iter().enumerate() {
                if !n.is_leaf() {
                    let (l, r) = (i as u32 + 1, n.right());
                    assert_eq!(t.subtree(l).start, t.stored(i as u32).end);
                    assert_eq!(t.subtree(l).end, t.subtree(r).start);
                    assert_eq!(t.subtree(r).end, t.subtree(i as u32).end);
                } else {
                    assert_eq!(t.stored(i as u32), t.subtree(i as u32));
                }
                // The spread holds every face's `n · (p - c)` below the node.
                let c = n.centre();
                for b in &t.blocks[t.subtree(i as u32)] {
                    for r in (0..4).filter_map(|k| b.record(k)) {
                        for nn in [r.n0, r.n1] {
                            let x = (0..3).map(|a| nn[a] as f64 * (r.p[a] as f64 - c[a] as f64)).sum::<f64>();
                            assert!(n.dlo as f64 <= x && x <= n.dhi as f64, "node {i}: {x} outside {}..{}", n.dlo, n.dhi);
                        }
                    }
                }
            }
            for eye in eyes(200, 3.0) {
                let mut want = Vec::new();
                brute::mesh_silhouettes(&m, eye, &mut want);
                let mut got = Vec::new();
                t.silhouettes(eye, &mut got);
                got.sort_unstable();
                assert_eq!(got, want, "eye {eye} params {params:?}");
            }
        }
    }

    /// A flat-ish patch of `k` edges: points near a random plane (offset far from the origin
    /// or not, of very different sizes), normals near the plane's; the node over them with
    /// its spread, as the build makes them.
    fn patch(g: &mut crate::rng::Rng, k: usize) -> (Node, Vec<Block>, Vec<EdgeRecord>) {
        let scale = 10f32.powi(g.below(7) as i32 - 3);
        let origin = if g.chance(0.5) { g.vec3(-100.0, 100.0) * scale } else { Vec3::ZERO };
        let axis = g.direction();
        let (u, v) = axis.any_orthonormal_pair();
        let (bend, noise) = (0.3 * g.unit() * g.unit(), 0.05 * g.unit());
        let mut recs = Vec::new();
        let mut b = Bounds::EMPTY;
        for i in 0..k {
            let (s, t) = (g.range(-1.0, 1.0), g.range(-1.0, 1.0));
            let p = origin + (u * s + v * t + axis * (g.range(-1.0, 1.0) * noise)) * scale;
            let q = p + (u * g.range(-0.2, 0.2) + v * g.range(-0.2, 0.2)) * scale;
            let n0 = (axis + g.direction() * bend).normalize();
            let n1 = if g.chance(0.2) { n0 } else { (axis + g.direction() * bend).normalize() };
            let (n0a, n1a, pa, qa) = (Vec3A::from(n0), Vec3A::from(n1), Vec3A::from(p), Vec3A::from(q));
            b.grow(&Item { nlo: n0a.min(n1a), nhi: n0a.max(n1a), plo: pa.min(qa), phi: pa.max(qa), edge: i as u32 });
            recs.push(EdgeRecord { p, n0, n1, edge: i as u32 });
        }
        let mut blocks = vec![Block::EMPTY; k.div_ceil(4)];
        for (i, r) in recs.iter().enumerate() {
            blocks[i / 4].set(i % 4, r);
        }
        let node = node_from(&b, 0, blocks.len(), blocks.len()).finish(&blocks);
        (node, blocks, recs)
    }

    /// The spread bound against f64 and the leaf test: for random flat-ish patches and eyes
    /// (many exactly in the plane of one of the faces, where the leaf test's sign hangs on
    /// its rounding), the interval holds the exact value and the leaf test's f32 value of
    /// every face, point eyes and eye boxes; a fixed sign agrees with [`face_side`].
    #[test]
    fn facing_tight_contains_exact_and_leaf_values() {
        let mut g = crate::rng::Rng::new(0x511E_77E5);
        let (mut pruned, mut pruned_interval_only, mut cases) = (0, 0, 0);
        for _ in 0..20_000 {
            let k = 1 + g.below(12);
            let (node, blocks, recs) = patch(&mut g, k);
            assert_eq!(blocks.iter().flat_map(|b| b.edges()).count(), k);
            let size = (Vec3::from(node.phi) - Vec3::from(node.plo)).length().max(1e-30);
            let centre = Vec3::from(node.centre());
            for _ in 0..6 {
                // Eyes near and far, a third exactly in the plane of one face.
                let mut eye = centre + g.direction() * size * 10f32.powi(g.below(5) as i32 - 1);
                if g.chance(0.33) {
                    let r = &recs[g.below(k)];
                    let n = if g.chance(0.5) { r.n0 } else { r.n1 };
                    let (a, _) = n.any_orthonormal_pair();
                    eye = r.p + a * size * g.range(0.1, 30.0);
                }
                let box_eye = g.chance(0.25);
                let (elo, ehi) = if box_eye {
                    let h = Vec3::new(g.unit(), g.unit(), g.unit()) * size * 0.5;
                    (eye - h, eye + h)
                } else {
                    (eye, eye)
                };
                let iv = node.facing_tight(elo.into(), ehi.into());
                cases += 1;
                pruned += iv.sign_is_fixed() as usize;
                pruned_interval_only += node.facing(elo.into(), ehi.into()).sign_is_fixed() as usize;
                for _ in 0..if box_eye { 4 } else { 1 } {
                    let e = if box_eye {
                        Vec3::new(g.range(elo.x, ehi.x), g.range(elo.y, ehi.y), g.range(elo.z, ehi.z)).clamp(elo, ehi)
                    } else {
                        eye
                    };
                    for r in &recs {
                        for n in [r.n0, r.n1] {
                            let exact = (0..3).map(|a| n[a] as f64 * (e[a] as f64 - r.p[a] as f64)).sum::<f64>();
                            let leaf = n.dot(e - r.p);
                            assert!(iv.lo as f64 <= exact && exact <= iv.hi as f64, "{iv:?} ∌ exact {exact}");
                            assert!(iv.contains(leaf), "{iv:?} ∌ leaf {leaf}");
                            if iv.all_positive() {
                                assert!(face_side(n, r.p, e));
                            }
                            if iv.all_non_positive() {
                                assert!(!face_side(n, r.p, e));
                            }
                        }
                    }
                }
            }
        }
        // Both outcomes exercised, and the spread bound prunes what the box product cannot.
        assert!(pruned > cases / 10 && pruned < cases * 9 / 10, "{pruned} of {cases}");
        assert!(pruned > pruned_interval_only + cases / 20, "{pruned} vs {pruned_interval_only} of {cases}");
    }

    #[test]
    fn both_facing_equals_brute_force() {
        let m = bumpy_sphere(40, 30, 0.2);
        let edges = all_interior(&m);
        let mut t = EdgeTree::build(&m, &edges, TreeParams::for_bounds(m.bounds), &NoProgress);
        for (k, eye) in eyes(100, 3.0).into_iter().enumerate() {
            t.parallel_from = if k % 2 == 0 { usize::MAX } else { 0 };
            let mut want: Vec<u32> = edges
                .iter()
                .copied()
                .filter(|&i| {
                    let e = &m.edges[i as usize];
                    let p = m.positions[e.v[0] as usize];
                    brute::face_side(e.normals[0], p, eye) && brute::face_side(e.normals[1], p, eye)
                })
                .collect();
            want.sort_unstable();
            let mut got = Vec::new();
            t.both_facing(eye, &mut got);
            got.sort_unstable();
            assert_eq!(got, want);
        }
    }

    #[test]
    fn empty_and_tiny_trees() {
        let m = bumpy_sphere(8, 6, 0.0);
        let t = EdgeTree::build(&m, &[], TreeParams::for_bounds(m.bounds), &NoProgress);
        let mut out = Vec::new();
        t.silhouettes(Vec3::splat(3.0), &mut out);
        assert!(out.is_empty() && t.is_empty());
        let t = EdgeTree::build(&m, &[0, 1], TreeParams::for_bounds(m.bounds), &NoProgress);
        assert_eq!(t.nodes.len(), 1);
    }
}
