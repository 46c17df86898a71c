//! Closed solids, to cull receivers wholly in umbra before any work (issue 15's "cull
//! receivers wholly in umbra"; paper 002 §2 computes the mesh on the faces that can see the
//! source). A triangle of a closed, consistently wound component faces out of its solid; when
//! every corner of the light lies behind its outward plane and the light is outside the
//! component's box, every line from a point of the triangle to the light starts into the
//! solid and must leave it through another of its triangles before reaching the light: the
//! triangle receives nothing, like one facing away from a one-sided light.
//!
//! Components are the triangles joined across edges that have exactly two triangles; one is
//! closed when every edge of it has two triangles walking it in opposite directions (a
//! manifold, consistently wound surface) and it encloses a volume. A self-intersecting
//! surface is taken for a solid too (the scenes' meshes are not).
use super::geometry::{edge_key, EdgeKey, Geometry};
use glam::DVec3;
use std::collections::HashMap;

/// Not in a closed component.
pub const OPEN: u32 = u32::MAX;

#[derive(Debug, Clone, Default)]
pub struct Solids {
    /// Per triangle: its closed component, or [`OPEN`].
    pub component: Vec<u32>,
    /// Per triangle: whether its winding normal `(b − a) × (c − a)` points out of its solid
    /// (meaningless for [`OPEN`]).
    pub outward: Vec<bool>,
    /// Per closed component: its box.
    pub boxes: Vec<(DVec3, DVec3)>,
}

fn find(p: &mut [u32], mut x: u32) -> u32 {
    while p[x as usize] != x {
        p[x as usize] = p[p[x as usize] as usize];
        x = p[x as usize];
    }
    x
}

impl Solids {
    pub fn new(pos: &[DVec3], tris: &[[u32; 3]], edge_tris: &super::fast_hash::FastMap<EdgeKey, Vec<u32>>) -> Solids {
        let n = tris.len();
        // +1 for each triangle walking the edge from its smaller id, −1 the other way.
        let mut walk: HashMap<EdgeKey, i32> = HashMap::with_capacity(edge_tris.len());
        for t in tris {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *walk.entry(edge_key(a, b)).or_default() += if a < b { 1 } else { -1 };
            }
        }
        let mut parent: Vec<u32> = (0..n as u32).collect();
        let mut open = vec![false; n];
        for (key, ts) in edge_tris {
            if ts.len() == 2 && walk[key] == 0 {
                let (a, b) = (find(&mut parent, ts[0]), find(&mut parent, ts[1]));
                parent[a as usize] = b;
            } else {
                ts.iter().for_each(|t| open[*t as usize] = true);
            }
        }
        let root: Vec<u32> = (0..n as u32).map(|t| find(&mut parent, t)).collect();
        for t in 0..n {
            if open[t] {
                open[root[t] as usize] = true;
            }
        }
        // Signed volume per component (about its first corner, for precision) and the size
        // it is judged against.
        let mut volume: HashMap<u32, (DVec3, f64, f64)> = HashMap::new();
        for (t, tri) in tris.iter().enumerate() {
            if open[root[t] as usize] {
                continue;
            }
            let [a, b, c] = tri.map(|v| pos[v as usize]);
            let e = volume.entry(root[t]).or_insert((a, 0.0, 0.0));
            let (a, b, c) = (a - e.0, b - e.0, c - e.0);
            e.1 += a.dot(b.cross(c)) / 6.0;
            e.2 += a.length() * b.length() * c.length() / 6.0;
        }
        let mut id: HashMap<u32, u32> = HashMap::new();
        let mut component = vec![OPEN; n];
        let mut outward = vec![false; n];
        for t in 0..n {
            let Some(&(_, v, size)) = volume.get(&root[t]) else { continue };
            if v.abs() <= 1e-9 * size {
                continue; // flat: encloses nothing
            }
            let next = id.len() as u32;
            component[t] = *id.entry(root[t]).or_insert(next);
            outward[t] = v > 0.0;
        }
        let mut s = Solids { component, outward, boxes: vec![(DVec3::INFINITY, DVec3::NEG_INFINITY); id.len()] };
        s.update_boxes(pos, tris, 0..n as u32);
        s
    }

    /// Recomputes the boxes of the components of triangles `range` (an object that moved;
    /// components do not span objects).
    pub fn update_boxes(&mut self, pos: &[DVec3], tris: &[[u32; 3]], range: std::ops::Range<u32>) {
        for t in range.clone() {
            if let Some(b) = self.boxes.get_mut(self.component[t as usize] as usize) {
                *b = (DVec3::INFINITY, DVec3::NEG_INFINITY);
            }
        }
        for t in range {
            if let Some(b) = self.boxes.get_mut(self.component[t as usize] as usize) {
                for v in tris[t as usize] {
                    *b = (b.0.min(pos[v as usize]), b.1.max(pos[v as usize]));
                }
            }
        }
    }
}

/// Whether triangle `t` is wholly in the umbra of its own solid from the light with
/// corners `light` (see the module's doc).
pub fn in_own_umbra(g: &Geometry, t: u32, light: &[DVec3], tol: f64) -> bool {
    let s = &g.solids;
    let c = s.component[t as usize];
    if c == OPEN {
        return false;
    }
    let [a, b, p] = g.tri(t);
    let Some(n) = (b - a).cross(p - a).try_normalize() else { return false };
    let n = if s.outward[t as usize] { n } else { -n };
    if light.iter().any(|y| n.dot(*y - a) > tol) {
        return false;
    }
    let (lo, hi) = s.boxes[c as usize];
    let (llo, lhi) = light.iter().fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(lo, hi), y| (lo.min(*y), hi.max(*y)));
    llo.cmpgt(hi + tol).any() || lhi.cmplt(lo - tol).any()
}

/// Whether triangle `t` (corners `tri`) of a closed solid faces away from `p`, a point outside
/// the solid's box: then it hides nothing from `p` that another triangle of the solid does
/// not hide first — a line from `p` that meets the solid enters it through a face turned
/// toward `p` before it can leave through this one — and an occlusion test may pass it over.
pub fn faces_away(g: &Geometry, t: u32, tri: [DVec3; 3], p: DVec3) -> bool {
    let s = &g.solids;
    let c = s.component[t as usize];
    if c == OPEN {
        return false;
    }
    let (lo, hi) = s.boxes[c as usize];
    if p.cmpge(lo).all() && p.cmple(hi).all() {
        return false;
    }
    let [a, b, q] = tri;
    let n = (b - a).cross(q - a);
    let n = if s.outward[t as usize] { n } else { -n };
    n.dot(p - a) < 0.0
}
