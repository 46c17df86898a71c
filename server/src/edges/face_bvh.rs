//! The receiver's face hierarchy (paper 000 §6.4 "Shadow edge computation"): "a bounding
//! volume hierarchy for the receiver faces ... extended to include a conservative normal
//! interval vector at each internal node. These normal interval vectors are used to
//! eliminate entire sub-trees of receiver polygons that are back-facing with respect to the
//! light."
//!
//! Object space, built once per mesh (median splits on the longest centroid axis, in
//! parallel). A wedge search is bound by memory latency, not arithmetic, so a node holds
//! the boxes of its two *children* in one cache line (a child is tested without touching
//! its own node, and rejected children are never fetched), their normal boxes in a second
//! array read only for closed meshes, and the faces sit in leaf order with corners and
//! normal together. The search itself is in [`super::wedge`].
use edgepoint_scene::{Mesh, Progress};
use glam::Vec3;

/// A child of a node: an internal node, a leaf (a run of faces), or nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Child {
    Node(u32),
    Leaf { start: u32, count: u32 },
    Empty,
}

/// An internal node: the corner boxes of its two children and what they are. 64 bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
pub struct FaceNode {
    pub lo: [[f32; 3]; 2],
    pub hi: [[f32; 3]; 2],
    /// Node index, or first face of a leaf.
    pub child: [u32; 2],
    /// Faces of a leaf child; 0 for a node child; `u32::MAX` for no child.
    pub count: [u32; 2],
}

impl FaceNode {
    #[inline(always)]
    pub fn child(&self, k: usize) -> Child {
        match self.count[k] {
            0 => Child::Node(self.child[k]),
            u32::MAX => Child::Empty,
            n => Child::Leaf { start: self.child[k], count: n },
        }
    }
}

/// The normal boxes of a node's two children (same index as the node).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalBoxes {
    pub lo: [[f32; 3]; 2],
    pub hi: [[f32; 3]; 2],
}

/// One face in leaf order.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct Face {
    pub v: [Vec3; 3],
    /// Unit normal (zero for a zero-area face).
    pub n: Vec3,
    /// Face index in the mesh.
    pub id: u32,
}

/// The root of a [`FaceBvh`] and its corner and normal boxes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Root {
    pub child: Child,
    pub lo: [f32; 3],
    pub hi: [f32; 3],
    pub nlo: [f32; 3],
    pub nhi: [f32; 3],
}

#[derive(Debug, Clone, Default)]
pub struct FaceBvh {
    pub nodes: Vec<FaceNode>,
    pub normals: Vec<NormalBoxes>,
    /// The root: a node or (small meshes) a leaf, with its boxes; `None` for no faces.
    pub root: Option<Root>,
    pub faces: Vec<Face>,
    /// The mesh is closed (no boundary edge): the first surface a ray from outside meets
    /// faces it, so faces turned away from the light can never bound a shadow or hide one.
    pub closed: bool,
    /// Closed and wound outward: every directed edge's reverse belongs to exactly one other
    /// face, and the signed volume is positive. A segment from a point outside the mesh or
    /// on it to a point outside that meets its inside leaves it through a face that has
    /// the segment's start behind its plane, so those faces alone hide what all hide.
    pub oriented: bool,
}

/// Whether every directed edge (a, b) of `triangles` occurs once and its reverse (b, a)
/// once (a closed mesh whose faces all wind the same way about its inside).
pub fn consistently_oriented(triangles: &[[u32; 3]]) -> bool {
    let mut directed: Vec<(u32, u32)> = triangles.iter().flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]).collect();
    directed.sort_unstable();
    if directed.windows(2).any(|w| w[0] == w[1]) {
        return false;
    }
    directed.iter().all(|&(a, b)| directed.binary_search(&(b, a)).is_ok())
}

/// Six times the signed volume enclosed by the mesh's faces (positive when wound outward).
fn signed_volume(mesh: &Mesh) -> f64 {
    (0..mesh.triangles.len())
        .map(|f| {
            let [a, b, c] = mesh.triangle(f).map(|v| v.as_dvec3());
            a.dot(b.cross(c))
        })
        .sum()
}

const LEAF: usize = 8;
const PARALLEL: usize = 1 << 14;

#[derive(Clone, Copy)]
struct Item {
    c: Vec3,
    lo: Vec3,
    hi: Vec3,
    n: Vec3,
    face: u32,
}

/// A built subtree: its boxes and what it is (node indices local to its node vector).
struct Built {
    lo: Vec3,
    hi: Vec3,
    nlo: Vec3,
    nhi: Vec3,
    child: Child,
}

impl FaceBvh {
    pub fn build(mesh: &Mesh, progress: &dyn Progress) -> FaceBvh {
        use rayon::prelude::*;
        let mut items: Vec<Item> = (0..mesh.triangles.len())
            .into_par_iter()
            .map(|f| {
                let [a, b, c] = mesh.triangle(f);
                Item { c: (a + b + c) / 3.0, lo: a.min(b).min(c), hi: a.max(b).max(c), n: mesh.face_normals[f], face: f as u32 }
            })
            .collect();
        let mut nodes = Vec::with_capacity(items.len() / 2 + 1);
        let mut normals = Vec::with_capacity(items.len() / 2 + 1);
        let root = (!items.is_empty()).then(|| {
            let b = build(&mut items, 0, &mut nodes, &mut normals, progress);
            Root { child: b.child, lo: b.lo.to_array(), hi: b.hi.to_array(), nlo: b.nlo.to_array(), nhi: b.nhi.to_array() }
        });
        let faces = items
            .par_iter()
            .map(|it| Face { v: mesh.triangle(it.face as usize), n: mesh.face_normals[it.face as usize], id: it.face })
            .collect();
        let closed = mesh.boundary_edges() == 0;
        FaceBvh { nodes, normals, root, faces, closed, oriented: closed && consistently_oriented(&mesh.triangles) && signed_volume(mesh) > 0.0 }
    }

    /// Visits the faces of every leaf whose box `overlaps` accepts (a region query: the
    /// test must be conservative, true for any box the region may meet). `face` returns
    /// false to stop the whole query early; the query then returns false too.
    pub fn visit(&self, overlaps: impl Fn(Vec3, Vec3) -> bool, mut face: impl FnMut(&Face) -> bool) -> bool {
        let Some(root) = &self.root else { return true };
        if !overlaps(Vec3::from(root.lo), Vec3::from(root.hi)) {
            return true;
        }
        let mut stack = vec![root.child];
        while let Some(c) = stack.pop() {
            match c {
                Child::Empty => {}
                Child::Leaf { start, count } => {
                    for f in &self.faces[start as usize..(start + count) as usize] {
                        if !face(f) {
                            return false;
                        }
                    }
                }
                Child::Node(i) => {
                    let n = &self.nodes[i as usize];
                    for k in 0..2 {
                        if n.count[k] != u32::MAX && overlaps(Vec3::from(n.lo[k]), Vec3::from(n.hi[k])) {
                            stack.push(n.child(k));
                        }
                    }
                }
            }
        }
        true
    }
}

/// Builds the subtree over `items` (faces `start..` in leaf order) into `nodes` (depth-first,
/// a node before its children); reports progress once per sequential chunk.
fn build(items: &mut [Item], start: usize, nodes: &mut Vec<FaceNode>, normals: &mut Vec<NormalBoxes>, progress: &dyn Progress) -> Built {
    let b = build_rec(items, start, nodes, normals, progress);
    if items.len() <= PARALLEL {
        progress.advance(items.len() as u64);
    }
    b
}

fn build_rec(items: &mut [Item], start: usize, nodes: &mut Vec<FaceNode>, normals: &mut Vec<NormalBoxes>, progress: &dyn Progress) -> Built {
    let inf = Vec3::splat(f32::INFINITY);
    let (mut lo, mut hi, mut nlo, mut nhi, mut clo, mut chi) = (inf, -inf, inf, -inf, inf, -inf);
    for it in items.iter() {
        lo = lo.min(it.lo);
        hi = hi.max(it.hi);
        nlo = nlo.min(it.n);
        nhi = nhi.max(it.n);
        clo = clo.min(it.c);
        chi = chi.max(it.c);
    }
    let n = items.len();
    if n <= LEAF {
        return Built { lo, hi, nlo, nhi, child: Child::Leaf { start: start as u32, count: n as u32 } };
    }
    let ext = chi - clo;
    let axis = if ext.x >= ext.y && ext.x >= ext.z {
        0
    } else if ext.y >= ext.z {
        1
    } else {
        2
    };
    let mid = n / 2;
    items.select_nth_unstable_by(mid, |a, b| a.c[axis].total_cmp(&b.c[axis]));
    let me = nodes.len();
    let empty = FaceNode { lo: [[0.0; 3]; 2], hi: [[0.0; 3]; 2], child: [0; 2], count: [u32::MAX; 2] };
    nodes.push(empty);
    normals.push(NormalBoxes { lo: [[0.0; 3]; 2], hi: [[0.0; 3]; 2] });
    let (l, r) = items.split_at_mut(mid);
    let (bl, br) = if n > PARALLEL {
        let (mut lv, mut ln, mut rv, mut rn) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let (mut bl, mut br) = rayon::join(
            || build(l, start, &mut lv, &mut ln, progress),
            || build(r, start + mid, &mut rv, &mut rn, progress),
        );
        let shift = |v: &mut Vec<FaceNode>, b: &mut Built, by: u32| {
            for x in v.iter_mut() {
                for k in 0..2 {
                    if x.count[k] == 0 {
                        x.child[k] += by;
                    }
                }
            }
            if let Child::Node(i) = &mut b.child {
                *i += by;
            }
        };
        let base = nodes.len() as u32;
        shift(&mut lv, &mut bl, base);
        nodes.append(&mut lv);
        normals.append(&mut ln);
        let rbase = nodes.len() as u32;
        shift(&mut rv, &mut br, rbase);
        nodes.append(&mut rv);
        normals.append(&mut rn);
        (bl, br)
    } else {
        let bl = build_rec(l, start, nodes, normals, progress);
        let br = build_rec(r, start + mid, nodes, normals, progress);
        (bl, br)
    };
    for (k, c) in [bl, br].into_iter().enumerate() {
        let node = &mut nodes[me];
        node.lo[k] = c.lo.to_array();
        node.hi[k] = c.hi.to_array();
        (node.child[k], node.count[k]) = match c.child {
            Child::Node(i) => (i, 0),
            Child::Leaf { start, count } => (start, count),
            Child::Empty => (0, u32::MAX),
        };
        normals[me].lo[k] = c.nlo.to_array();
        normals[me].hi[k] = c.nhi.to_array();
    }
    Built { lo, hi, nlo, nhi, child: Child::Node(me as u32) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_scene::NoProgress;

    /// Checks the boxes of `c` (and below) contain its faces; returns the faces seen.
    fn check(b: &FaceBvh, c: Child, lo: [f32; 3], hi: [f32; 3], nlo: [f32; 3], nhi: [f32; 3], seen: &mut Vec<u32>) {
        let inside = |p: Vec3, lo: [f32; 3], hi: [f32; 3]| p.cmpge(Vec3::from(lo)).all() && p.cmple(Vec3::from(hi)).all();
        match c {
            Child::Empty => {}
            Child::Leaf { start, count } => {
                for f in &b.faces[start as usize..(start + count) as usize] {
                    assert!(f.v.iter().all(|&p| inside(p, lo, hi)));
                    assert!(inside(f.n, nlo, nhi));
                    seen.push(f.id);
                }
            }
            Child::Node(i) => {
                let (n, nb) = (&b.nodes[i as usize], &b.normals[i as usize]);
                for k in 0..2 {
                    // Child boxes nest in the parent's.
                    if n.child(k) != Child::Empty {
                        assert!(inside(Vec3::from(n.lo[k]), lo, hi) && inside(Vec3::from(n.hi[k]), lo, hi));
                    }
                    check(b, n.child(k), n.lo[k], n.hi[k], nb.lo[k], nb.hi[k], seen);
                }
            }
        }
    }

    #[test]
    fn boxes_contain_their_faces() {
        let mut meshes: Vec<Mesh> =
            edgepoint_scene::builtin::load("cornell").unwrap().objects.iter().map(|o| (*o.mesh).clone()).collect();
        meshes.push((*edgepoint_scene::builtin::load("torus-capsule").unwrap().objects[2].mesh).clone());
        for m in &meshes {
            let b = FaceBvh::build(m, &NoProgress);
            let r = b.root.unwrap();
            let mut seen = Vec::new();
            check(&b, r.child, r.lo, r.hi, r.nlo, r.nhi, &mut seen);
            seen.sort_unstable();
            assert!(seen.iter().enumerate().all(|(i, &f)| i as u32 == f) && seen.len() == m.triangles.len());
            assert_eq!(b.closed, m.boundary_edges() == 0);
        }
    }
}
