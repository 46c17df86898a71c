//! The scene as the discontinuity mesh sees it (paper 002 §2: the "polygons of the
//! environment" whose edges and vertices generate discontinuity surfaces): world-space
//! triangles in f64 with welded vertex ids, and the adjacency the generators need — the
//! triangles around each edge (is it a silhouette from a light vertex?) and the neighbours
//! of each vertex (is a plane through it tangent to its object?).
use super::fast_hash::FastMap;
use super::solid::Solids;
use edgepoint_scene::Scene;
use glam::DVec3;

/// An undirected edge by its two vertex ids, smaller first.
pub type EdgeKey = (u32, u32);

pub fn edge_key(a: u32, b: u32) -> EdgeKey {
    if a < b {
        (a, b)
    } else {
        (b, a)
    }
}

#[derive(Debug, Clone, Default)]
pub struct Geometry {
    /// World-space vertex positions; ids are global over all objects.
    pub pos: Vec<DVec3>,
    /// Triangles as vertex ids.
    pub tris: Vec<[u32; 3]>,
    /// The object each triangle belongs to.
    pub object: Vec<u32>,
    /// The first vertex id and the first triangle id of each object (so a moved object's
    /// vertices and triangles are contiguous ranges).
    pub vertex_start: Vec<u32>,
    pub tri_start: Vec<u32>,
    /// Triangles around each edge.
    pub edge_tris: FastMap<EdgeKey, Vec<u32>>,
    /// Neighbour vertices of each vertex (over its triangles), sorted, no repeats.
    pub neighbours: Vec<Vec<u32>>,
    /// The closed components and their boxes (receivers in their own umbra).
    pub solids: Solids,
}

impl Geometry {
    /// The scene's objects at their default transforms.
    pub fn from_scene(scene: &Scene) -> Geometry {
        Geometry::from_scene_at(scene, &[])
    }

    /// The scene's objects placed by `transforms` (one per object; an object without one
    /// keeps its default), as a session has them.
    pub fn from_scene_at(scene: &Scene, transforms: &[glam::Affine3A]) -> Geometry {
        let objects: Vec<(Vec<DVec3>, Vec<[u32; 3]>)> = scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let t = transforms.get(i).unwrap_or(&o.transform);
                (o.mesh.positions.iter().map(|p| t.transform_point3(*p).as_dvec3()).collect(), o.mesh.triangles.clone())
            })
            .collect();
        Geometry::from_objects(&objects)
    }

    /// A triangle soup given per object (tests, and objects moved by [`Geometry::moved`]).
    pub fn from_objects(objects: &[(Vec<DVec3>, Vec<[u32; 3]>)]) -> Geometry {
        let mut pos = Vec::new();
        let mut tris = Vec::new();
        let mut object = Vec::new();
        let (mut vertex_start, mut tri_start) = (Vec::new(), Vec::new());
        for (oi, (p, t)) in objects.iter().enumerate() {
            let base = pos.len() as u32;
            vertex_start.push(base);
            tri_start.push(tris.len() as u32);
            pos.extend_from_slice(p);
            tris.extend(t.iter().map(|t| [t[0] + base, t[1] + base, t[2] + base]));
            object.extend(std::iter::repeat_n(oi as u32, t.len()));
        }
        Geometry::from_parts(pos, tris, object, vertex_start, tri_start)
    }

    fn from_parts(pos: Vec<DVec3>, tris: Vec<[u32; 3]>, object: Vec<u32>, vertex_start: Vec<u32>, tri_start: Vec<u32>) -> Geometry {
        let mut edge_tris: FastMap<EdgeKey, Vec<u32>> = FastMap::with_capacity_and_hasher(tris.len() * 3 / 2, Default::default());
        let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); pos.len()];
        for (ti, t) in tris.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                edge_tris.entry(edge_key(a, b)).or_default().push(ti as u32);
                neighbours[a as usize].push(b);
                neighbours[b as usize].push(a);
            }
        }
        for n in &mut neighbours {
            n.sort_unstable();
            n.dedup();
        }
        let solids = Solids::new(&pos, &tris, &edge_tris);
        Geometry { pos, tris, object, vertex_start, tri_start, edge_tris, neighbours, solids }
    }

    /// The corners of triangle `t`.
    #[inline]
    pub fn tri(&self, t: u32) -> [DVec3; 3] {
        let v = self.tris[t as usize];
        [self.pos[v[0] as usize], self.pos[v[1] as usize], self.pos[v[2] as usize]]
    }

    /// The vertex range of object `o`.
    pub fn object_vertices(&self, o: u32) -> std::ops::Range<u32> {
        let end = self.vertex_start.get(o as usize + 1).copied().unwrap_or(self.pos.len() as u32);
        self.vertex_start[o as usize]..end
    }

    /// The triangle range of object `o`.
    pub fn object_tris(&self, o: u32) -> std::ops::Range<u32> {
        let end = self.tri_start.get(o as usize + 1).copied().unwrap_or(self.tris.len() as u32);
        self.tri_start[o as usize]..end
    }

    /// The same scene with object `o`'s vertices mapped by `f` (ids, triangles and adjacency
    /// unchanged: a rigid move keeps the topology; no mirroring, which would turn its solids
    /// inside out).
    pub fn moved(&self, o: u32, f: impl Fn(DVec3) -> DVec3) -> Geometry {
        let mut g = self.clone();
        for v in self.object_vertices(o) {
            g.pos[v as usize] = f(self.pos[v as usize]);
        }
        g.solids.update_boxes(&g.pos, &g.tris, g.object_tris(o));
        g
    }

    /// Object `o` turned by `rot` about the centre of its box, then moved by `d` (the
    /// benchmark's and the tests' rigid moves).
    pub fn moved_rigidly(&self, o: u32, rot: glam::DQuat, d: DVec3) -> Geometry {
        let (lo, hi) = self.object_bounds(o);
        let c = (lo + hi) * 0.5;
        self.moved(o, |p| c + d + rot * (p - c))
    }

    /// Axis-aligned bounds of object `o`.
    pub fn object_bounds(&self, o: u32) -> (DVec3, DVec3) {
        bounds_of(self.object_vertices(o).map(|v| self.pos[v as usize]))
    }

    /// Axis-aligned bounds of triangle `t`.
    pub fn tri_bounds(&self, t: u32) -> (DVec3, DVec3) {
        bounds_of(self.tri(t).into_iter())
    }

    /// Axis-aligned bounds of the whole scene.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        bounds_of(self.pos.iter().copied())
    }

    /// Bytes held by the geometry and its adjacency (for the benchmark's memory figure).
    pub fn bytes(&self) -> usize {
        self.pos.len() * 24 + self.tris.len() * 16 + self.edge_tris.len() * 48 + self.neighbours.iter().map(|n| 24 + n.len() * 4).sum::<usize>()
    }
}

/// Whether two axis-aligned boxes meet (touching counts).
pub fn boxes_meet(a: (DVec3, DVec3), b: (DVec3, DVec3)) -> bool {
    !(a.0.cmpgt(b.1).any() || a.1.cmplt(b.0).any())
}

/// The box around some boxes (inverted, infinite for none).
pub fn union_of(boxes: impl Iterator<Item = (DVec3, DVec3)>) -> (DVec3, DVec3) {
    boxes.fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), b| (lo.min(b.0), hi.max(b.1)))
}

/// Axis-aligned bounds of some points (inverted, infinite ones for none).
fn bounds_of(points: impl Iterator<Item = DVec3>) -> (DVec3, DVec3) {
    points.fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| (lo.min(p), hi.max(p)))
}
