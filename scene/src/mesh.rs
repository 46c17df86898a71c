//! Triangle meshes with welded vertices and edge–face adjacency.
//!
//! Paper 000 §6.1–6.2 needs, for every edge, its two vertices and the normals of its one or
//! two faces (Equation 1, sharp-edge cut-off). Scanned meshes arrive as soups or pieces with
//! duplicated vertices along seams, so every mesh is welded first: vertices with bit-equal
//! positions merge, triangles that collapse (two equal corners) are dropped, unreferenced
//! vertices are removed.
use crate::progress::Progress;
use glam::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// Marks a missing second face (a boundary edge).
pub const NO_FACE: u32 = u32::MAX;

/// An undirected mesh edge. `v` is ordered as the edge runs in `faces[0]`'s winding.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    pub v: [u32; 2],
    /// The one or two adjacent faces; `faces[1] == NO_FACE` on a boundary edge.
    pub faces: [u32; 2],
    /// Unit normals of the adjacent faces; `normals[1]` is zero on a boundary edge.
    pub normals: [Vec3; 2],
}

impl Edge {
    #[inline]
    pub fn is_boundary(&self) -> bool {
        self.faces[1] == NO_FACE
    }

    /// Angle between the two face normals in degrees (0 for a flat edge, 180 for a fold);
    /// 180 for boundary edges.
    pub fn dihedral_degrees(&self) -> f32 {
        if self.is_boundary() {
            return 180.0;
        }
        self.normals[0].dot(self.normals[1]).clamp(-1.0, 1.0).acos().to_degrees()
    }
}

/// What welding did to a mesh.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WeldStats {
    pub input_vertices: usize,
    pub input_triangles: usize,
    pub vertices: usize,
    pub triangles: usize,
    /// Triangles dropped because two corners welded to one vertex.
    pub degenerate_dropped: usize,
    /// Triangles kept although their corners are collinear (zero area; normal is zero).
    pub zero_area: usize,
    pub edges: usize,
    pub boundary_edges: usize,
    /// Edges shared by more than two faces (split into pairs plus a boundary remainder).
    pub non_manifold_edges: usize,
}

/// A welded triangle mesh in object space.
#[derive(Debug, Clone)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Unit face normals from the counter-clockwise winding (zero for zero-area faces).
    pub face_normals: Vec<Vec3>,
    pub edges: Vec<Edge>,
    /// Object-space bounding box (min, max).
    pub bounds: (Vec3, Vec3),
    pub stats: WeldStats,
    /// Per-corner shading attributes, one entry per triangle (aligned with `triangles`).
    pub corners: Corners,
}

/// Shading normals and texture coordinates per triangle corner (OBJ `vn`/`vt`, glTF
/// `NORMAL`/`TEXCOORD_0`). Kept per corner rather than per welded vertex: welding merges
/// positions only, and a crease or UV seam gives one position several normals or UVs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Corners {
    /// Object-space shading normals (unit length or zero where the file gave none).
    pub normals: Option<Vec<[Vec3; 3]>>,
    pub uvs: Option<Vec<[glam::Vec2; 3]>>,
}

impl Mesh {
    /// Builds a mesh from raw positions and triangles: welds bit-equal positions, drops
    /// collapsed triangles and unused vertices, computes face normals and edge adjacency.
    /// Triangle indices must be < positions.len() (loaders check and report them).
    pub fn from_triangles(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>, progress: &dyn Progress) -> Mesh {
        Self::weld(positions, triangles, progress).0
    }

    /// [`Mesh::from_triangles`] carrying per-corner attributes (one entry per input
    /// triangle): the entries of triangles that welding drops are dropped with them, so
    /// `corners` stays aligned with `triangles`. An attribute list whose length is not the
    /// triangle count is a loader bug; it is dropped (with an error log) rather than
    /// misaligned.
    pub fn from_triangles_with_corners(
        positions: Vec<Vec3>,
        triangles: Vec<[u32; 3]>,
        corners: Corners,
        progress: &dyn Progress,
    ) -> Mesh {
        let n = triangles.len();
        let (mut mesh, kept) = Self::weld(positions, triangles, progress);
        fn keep<T: Copy>(what: &str, list: Option<Vec<T>>, n: usize, kept: &[u32]) -> Option<Vec<T>> {
            let list = list?;
            if list.len() != n {
                tracing::error!("{what}: {} corner entries for {n} triangles; dropped", list.len());
                return None;
            }
            Some(kept.iter().map(|&t| list[t as usize]).collect())
        }
        mesh.corners = Corners {
            normals: keep("shading normals", corners.normals, n, &kept),
            uvs: keep("texture coordinates", corners.uvs, n, &kept),
        };
        mesh
    }

    /// Welds and builds the mesh; also returns the input index of every kept triangle.
    fn weld(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>, progress: &dyn Progress) -> (Mesh, Vec<u32>) {
        let input_vertices = positions.len();
        let input_triangles = triangles.len();

        // 1. Weld: map each input vertex to the first vertex with the same bits.
        progress.begin("weld vertices", input_vertices as u64);
        let mut remap = Vec::with_capacity(positions.len());
        let mut first: HashMap<[u32; 3], u32> = HashMap::with_capacity(positions.len());
        let key = |p: Vec3| {
            // +0.0 and -0.0 are the same position.
            let k = |v: f32| if v == 0.0 { 0u32 } else { v.to_bits() };
            [k(p.x), k(p.y), k(p.z)]
        };
        for (i, p) in positions.iter().enumerate() {
            let id = *first.entry(key(*p)).or_insert(i as u32);
            remap.push(id);
            if i % 65536 == 0 {
                progress.advance(65536.min(input_vertices - i) as u64);
            }
        }
        progress.end();

        // 2. Drop collapsed triangles, then compact the vertices actually used.
        let mut degenerate_dropped = 0;
        let mut used = vec![u32::MAX; positions.len()];
        let mut out_pos = Vec::new();
        let mut out_tri = Vec::with_capacity(triangles.len());
        let mut kept = Vec::with_capacity(triangles.len());
        for (i, t) in triangles.iter().enumerate() {
            let w = [remap[t[0] as usize], remap[t[1] as usize], remap[t[2] as usize]];
            if w[0] == w[1] || w[1] == w[2] || w[0] == w[2] {
                degenerate_dropped += 1;
                continue;
            }
            let mut c = [0u32; 3];
            for k in 0..3 {
                let slot = &mut used[w[k] as usize];
                if *slot == u32::MAX {
                    *slot = out_pos.len() as u32;
                    out_pos.push(positions[w[k] as usize]);
                }
                c[k] = *slot;
            }
            out_tri.push(c);
            kept.push(i as u32);
        }
        drop(positions);

        let mut mesh = Mesh {
            positions: out_pos,
            triangles: out_tri,
            face_normals: Vec::new(),
            edges: Vec::new(),
            bounds: (Vec3::ZERO, Vec3::ZERO),
            stats: WeldStats { input_vertices, input_triangles, degenerate_dropped, ..Default::default() },
            corners: Corners::default(),
        };
        mesh.rebuild_derived(progress);
        (mesh, kept)
    }

    /// Recomputes face normals, bounds and edge adjacency from positions and triangles.
    fn rebuild_derived(&mut self, progress: &dyn Progress) {
        let pos = &self.positions;
        self.face_normals = self
            .triangles
            .par_iter()
            .map(|t| {
                let (a, b, c) = (pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]);
                (b - a).cross(c - a).normalize_or_zero()
            })
            .collect();
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for p in pos {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        self.bounds = if pos.is_empty() { (Vec3::ZERO, Vec3::ZERO) } else { (lo, hi) };
        self.stats.zero_area = self.face_normals.iter().filter(|n| **n == Vec3::ZERO).count();
        self.build_edges(progress);
        self.stats.vertices = self.positions.len();
        self.stats.triangles = self.triangles.len();
        self.stats.edges = self.edges.len();
        self.stats.boundary_edges = self.edges.iter().filter(|e| e.is_boundary()).count();
    }

    /// Edge adjacency by sorting half-edges on their undirected key.
    fn build_edges(&mut self, progress: &dyn Progress) {
        progress.begin("edge adjacency", self.triangles.len() as u64);
        // (min vertex, max vertex, face, directed-as-in-face start vertex)
        let mut half: Vec<(u64, u32, u32)> = Vec::with_capacity(self.triangles.len() * 3);
        for (f, t) in self.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let key = ((a.min(b) as u64) << 32) | a.max(b) as u64;
                half.push((key, f as u32, a));
            }
        }
        half.par_sort_unstable_by_key(|h| (h.0, h.1));
        progress.advance(self.triangles.len() as u64 / 2);

        let normals = &self.face_normals;
        let mut edges = Vec::with_capacity(half.len() / 2 + 16);
        let mut non_manifold = 0;
        let mut i = 0;
        while i < half.len() {
            let mut j = i + 1;
            while j < half.len() && half[j].0 == half[i].0 {
                j += 1;
            }
            if j - i > 2 {
                non_manifold += 1;
            }
            let (lo, hi) = ((half[i].0 >> 32) as u32, half[i].0 as u32);
            // Pair the faces of this edge two by two; an odd one out is a boundary edge.
            let mut k = i;
            while k < j {
                let (f0, start) = (half[k].1, half[k].2);
                let v = if start == lo { [lo, hi] } else { [hi, lo] };
                let (f1, n1) = if k + 1 < j {
                    (half[k + 1].1, normals[half[k + 1].1 as usize])
                } else {
                    (NO_FACE, Vec3::ZERO)
                };
                edges.push(Edge { v, faces: [f0, f1], normals: [normals[f0 as usize], n1] });
                k += 2;
            }
            i = j;
        }
        self.stats.non_manifold_edges = non_manifold;
        self.edges = edges;
        progress.advance(self.triangles.len() as u64 - self.triangles.len() as u64 / 2);
        progress.end();
    }

    /// Signed volume (positive for a closed mesh wound counter-clockwise from outside).
    pub fn signed_volume(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let (a, b, c) = (self.positions[t[0] as usize], self.positions[t[1] as usize], self.positions[t[2] as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Reverses the winding of every triangle (and so every normal).
    pub fn flip(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
        // Corner attributes follow their corners.
        if let Some(n) = &mut self.corners.normals {
            n.iter_mut().for_each(|c| c.swap(1, 2));
        }
        if let Some(uv) = &mut self.corners.uvs {
            uv.iter_mut().for_each(|c| c.swap(1, 2));
        }
        self.rebuild_derived(&crate::NoProgress);
    }

    /// Number of boundary edges (edges with one face).
    pub fn boundary_edges(&self) -> usize {
        self.stats.boundary_edges
    }

    /// The three corners of triangle `f`.
    #[inline]
    pub fn triangle(&self, f: usize) -> [Vec3; 3] {
        let t = self.triangles[f];
        [self.positions[t[0] as usize], self.positions[t[1] as usize], self.positions[t[2] as usize]]
    }

    /// Total surface area.
    pub fn area(&self) -> f32 {
        (0..self.triangles.len())
            .map(|f| {
                let [a, b, c] = self.triangle(f);
                (b - a).cross(c - a).length() * 0.5
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NoProgress;

    /// A unit cube given as a triangle soup (every triangle has its own vertices).
    fn cube_soup() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let c = |i: u32| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32);
        // Faces wound counter-clockwise from outside.
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let mut p = Vec::new();
        let mut t = Vec::new();
        for q in quads {
            for tri in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
                let base = p.len() as u32;
                p.extend(tri.iter().map(|&i| c(i)));
                t.push([base, base + 1, base + 2]);
            }
        }
        (p, t)
    }

    #[test]
    fn welding_a_soup_gives_a_closed_cube() {
        let (p, t) = cube_soup();
        let m = Mesh::from_triangles(p, t, &NoProgress);
        assert_eq!(m.positions.len(), 8);
        assert_eq!(m.triangles.len(), 12);
        assert_eq!(m.edges.len(), 18);
        assert_eq!(m.boundary_edges(), 0);
        assert!((m.signed_volume() - 1.0).abs() < 1e-6, "outward winding");
        // 12 cube edges are sharp (90°), 6 face diagonals are flat.
        let sharp = m.edges.iter().filter(|e| e.dihedral_degrees() > 85.0).count();
        assert_eq!(sharp, 12);
        for e in &m.edges {
            let n0 = m.face_normals[e.faces[0] as usize];
            assert_eq!(n0, e.normals[0]);
            // v is ordered as in faces[0]
            let tri = m.triangles[e.faces[0] as usize];
            let k = tri.iter().position(|&v| v == e.v[0]).unwrap();
            assert_eq!(tri[(k + 1) % 3], e.v[1]);
        }
    }

    #[test]
    fn collapsed_triangles_are_dropped_and_boundaries_counted() {
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::X, Vec3::new(1.0, 1.0, 0.0)];
        // triangle 1 collapses (corners 1 and 3 weld), triangle 2 is a real neighbour
        let t = vec![[0, 1, 2], [1, 3, 2], [1, 4, 2]];
        let m = Mesh::from_triangles(p, t, &NoProgress);
        assert_eq!(m.stats.degenerate_dropped, 1);
        assert_eq!(m.triangles.len(), 2);
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.edges.len(), 5);
        assert_eq!(m.boundary_edges(), 4);
    }

    /// Corner attributes stay with their triangles through welding: the oracle is the
    /// un-welded soup, where every triangle carries its own attributes by construction.
    #[test]
    fn corners_stay_aligned_through_welding() {
        use glam::Vec2;
        let mut rng = 0x9e3779b97f4a7c15u64;
        let mut next = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        for case in 0..50 {
            // A small grid of positions (so welding merges many) and random triangles over
            // it, some collapsing.
            let grid: Vec<Vec3> = (0..9).map(|i| Vec3::new((i % 3) as f32, (i / 3) as f32, (i % 2) as f32)).collect();
            let n = 5 + case % 20;
            let mut positions = Vec::new();
            let mut triangles = Vec::new();
            let mut normals = Vec::new();
            let mut uvs = Vec::new();
            for t in 0..n {
                let base = positions.len() as u32;
                let mut tri = [Vec3::ZERO; 3];
                for c in &mut tri {
                    *c = grid[(next() % 9) as usize];
                }
                positions.extend(tri);
                triangles.push([base, base + 1, base + 2]);
                // Attributes encode the triangle's corner positions and its input index.
                normals.push(tri.map(|p| p + Vec3::new(t as f32 + 1.0, 0.0, 0.0)));
                uvs.push(tri.map(|p| Vec2::new(p.x + 10.0 * t as f32, p.y)));
            }
            let m = Mesh::from_triangles_with_corners(
                positions.clone(),
                triangles.clone(),
                Corners { normals: Some(normals.clone()), uvs: Some(uvs.clone()) },
                &NoProgress,
            );
            let (mn, mu) = (m.corners.normals.as_ref().unwrap(), m.corners.uvs.as_ref().unwrap());
            assert_eq!((mn.len(), mu.len()), (m.triangles.len(), m.triangles.len()));
            // Oracle: the input triangles that do not collapse, in order.
            let kept: Vec<usize> = (0..n).filter(|&t| {
                let [a, b, c] = [positions[3 * t], positions[3 * t + 1], positions[3 * t + 2]];
                a != b && b != c && a != c
            }).collect();
            assert_eq!(kept.len(), m.triangles.len(), "case {case}");
            for (f, &t) in kept.iter().enumerate() {
                let tri = m.triangle(f);
                for k in 0..3 {
                    assert_eq!(tri[k], positions[3 * t + k]);
                    assert_eq!(mn[f][k], normals[t][k], "case {case} face {f} corner {k}");
                    assert_eq!(mu[f][k], uvs[t][k]);
                }
            }
        }
        // A list of the wrong length is dropped, not misaligned.
        let m = Mesh::from_triangles_with_corners(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            vec![[0, 1, 2]],
            Corners { normals: Some(vec![]), uvs: None },
            &NoProgress,
        );
        assert_eq!(m.corners, Corners::default());
    }

    #[test]
    fn non_manifold_edges_are_split() {
        // three triangles sharing the edge (0,1)
        let p = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z, Vec3::new(0.5, -1.0, 0.0)];
        let t = vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]];
        let m = Mesh::from_triangles(p, t, &NoProgress);
        assert_eq!(m.stats.non_manifold_edges, 1);
        let on01 = m.edges.iter().filter(|e| (e.v[0].min(e.v[1]), e.v[0].max(e.v[1])) == (0, 1)).count();
        assert_eq!(on01, 2, "one pair plus one boundary remainder");
    }
}
