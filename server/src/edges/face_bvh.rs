//! The receiver's face hierarchy (paper 000 §6.4 "Shadow edge computation"): "a bounding
//! volume hierarchy for the receiver faces ... extended to include a conservative normal
//! interval vector at each internal node. These normal interval vectors are used to
//! eliminate entire sub-trees of receiver polygons that are back-facing with respect to the
//! light."
//!
//! Object space, built once per mesh (median splits on the longest centroid axis, in
//! parallel); nodes are 64 bytes in depth-first order and the faces are stored in leaf
//! order. The event-wedge search over it lives in [`super::wedge`].
use edgepoint_scene::{Mesh, Progress};
use glam::Vec3;

/// A node: box of its faces' corners, box of their unit normals, faces `start..end`;
/// `right == 0` marks a leaf, otherwise the left child is the next node.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(64))]
pub struct FaceNode {
    pub lo: [f32; 3],
    pub hi: [f32; 3],
    pub nlo: [f32; 3],
    pub nhi: [f32; 3],
    pub start: u32,
    pub end: u32,
    pub right: u32,
}

impl FaceNode {
    #[inline(always)]
    pub fn is_leaf(&self) -> bool {
        self.right == 0
    }
}

#[derive(Debug, Clone, Default)]
pub struct FaceBvh {
    pub nodes: Vec<FaceNode>,
    /// Corners of the faces in leaf order.
    pub tris: Vec<[Vec3; 3]>,
    /// Unit normals (zero for zero-area faces), leaf order.
    pub normals: Vec<Vec3>,
    /// Mesh face index of each slot.
    pub faces: Vec<u32>,
    /// The mesh is closed (no boundary edge): the first surface a ray from outside meets
    /// faces it, so faces turned away from the light can never bound a shadow or hide one.
    pub closed: bool,
}

const LEAF: usize = 4;
const PARALLEL: usize = 1 << 14;

#[derive(Clone, Copy)]
struct Item {
    c: Vec3,
    lo: Vec3,
    hi: Vec3,
    n: Vec3,
    face: u32,
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
        if !items.is_empty() {
            build(&mut items, 0, &mut nodes, progress);
        }
        let faces: Vec<u32> = items.iter().map(|i| i.face).collect();
        FaceBvh {
            nodes,
            tris: faces.par_iter().map(|&f| mesh.triangle(f as usize)).collect(),
            normals: faces.iter().map(|&f| mesh.face_normals[f as usize]).collect(),
            faces,
            closed: mesh.boundary_edges() == 0,
        }
    }
}

/// Builds the subtree over `items` into `nodes`; reports progress once per sequential chunk.
fn build(items: &mut [Item], start: usize, nodes: &mut Vec<FaceNode>, progress: &dyn Progress) {
    build_rec(items, start, nodes, progress);
    if items.len() <= PARALLEL {
        progress.advance(items.len() as u64);
    }
}

fn build_rec(items: &mut [Item], start: usize, nodes: &mut Vec<FaceNode>, progress: &dyn Progress) {
    let (mut lo, mut hi, mut nlo, mut nhi, mut clo, mut chi) = (
        Vec3::splat(f32::INFINITY),
        Vec3::splat(f32::NEG_INFINITY),
        Vec3::splat(f32::INFINITY),
        Vec3::splat(f32::NEG_INFINITY),
        Vec3::splat(f32::INFINITY),
        Vec3::splat(f32::NEG_INFINITY),
    );
    for it in items.iter() {
        lo = lo.min(it.lo);
        hi = hi.max(it.hi);
        nlo = nlo.min(it.n);
        nhi = nhi.max(it.n);
        clo = clo.min(it.c);
        chi = chi.max(it.c);
    }
    let me = nodes.len();
    let n = items.len();
    nodes.push(FaceNode {
        lo: lo.to_array(),
        hi: hi.to_array(),
        nlo: nlo.to_array(),
        nhi: nhi.to_array(),
        start: start as u32,
        end: (start + n) as u32,
        right: 0,
    });
    if n <= LEAF {
        return;
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
    let (l, r) = items.split_at_mut(mid);
    if n > PARALLEL {
        let (mut lv, mut rv) = (Vec::new(), Vec::new());
        rayon::join(|| build(l, start, &mut lv, progress), || build(r, start + mid, &mut rv, progress));
        let base = nodes.len() as u32;
        for x in lv.iter_mut().filter(|x| x.right != 0) {
            x.right += base;
        }
        let rbase = base + lv.len() as u32;
        for x in rv.iter_mut().filter(|x| x.right != 0) {
            x.right += rbase;
        }
        nodes.append(&mut lv);
        nodes[me].right = rbase;
        nodes.append(&mut rv);
    } else {
        build_rec(l, start, nodes, progress);
        nodes[me].right = nodes.len() as u32;
        build_rec(r, start + mid, nodes, progress);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_scene::NoProgress;

    #[test]
    fn boxes_contain_their_faces() {
        let scene = edgepoint_scene::builtin::load("cornell").unwrap();
        for o in &scene.objects {
            let b = FaceBvh::build(&o.mesh, &NoProgress);
            assert_eq!(b.faces.len(), o.mesh.triangles.len());
            let mut seen = b.faces.clone();
            seen.sort_unstable();
            assert!(seen.iter().enumerate().all(|(i, &f)| i as u32 == f));
            for (i, n) in b.nodes.iter().enumerate() {
                for s in n.start..n.end {
                    let s = s as usize;
                    for p in b.tris[s] {
                        assert!(p.cmpge(Vec3::from(n.lo)).all() && p.cmple(Vec3::from(n.hi)).all());
                    }
                    assert!(b.normals[s].cmpge(Vec3::from(n.nlo)).all() && b.normals[s].cmple(Vec3::from(n.nhi)).all());
                }
                if !n.is_leaf() {
                    assert_eq!(b.nodes[i + 1].start, n.start);
                    assert_eq!(b.nodes[n.right as usize].end, n.end);
                }
            }
            assert_eq!(b.closed, o.mesh.boundary_edges() == 0);
        }
    }
}
