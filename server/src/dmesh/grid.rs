//! The uniform grid of paper 002 §3.1 ("a uniform spatial subdivision … each voxel contains
//! a list of the polygons it intersects"): triangles listed per voxel by their bounding
//! boxes, queried by a box. It finds the blockers in a receiver's shaft without scanning
//! the scene.
use super::geometry::Geometry;
use glam::{DVec3, IVec3};

#[derive(Debug, Clone)]
pub struct Grid {
    lo: DVec3,
    cell: DVec3,
    dims: IVec3,
    /// The triangles listed in each voxel.
    voxels: Vec<Vec<u32>>,
    /// Triangles in the scene (the size of a query's stamp array).
    tris: usize,
}

impl Grid {
    /// About `per_voxel` triangles per voxel on average, at most 128 voxels a side, over the
    /// scene's bounds (a triangle moved outside them is listed in the border voxels).
    pub fn build(g: &Geometry, per_voxel: f64) -> Grid {
        let (lo, hi) = g.bounds();
        let ext = (hi - lo).max(DVec3::splat(1e-9));
        let n = (g.tris.len() as f64 / per_voxel).max(1.0);
        let s = (ext.x * ext.y * ext.z / n).cbrt().max(ext.max_element() / 128.0);
        let dims = ((ext / s).ceil().as_ivec3()).clamp(IVec3::ONE, IVec3::splat(128));
        let cell = ext / dims.as_dvec3();
        let mut grid = Grid { lo, cell, dims, voxels: vec![Vec::new(); (dims.x * dims.y * dims.z) as usize], tris: g.tris.len() };
        grid.insert(g, 0..g.tris.len() as u32);
        grid
    }

    fn tri_range(&self, g: &Geometry, t: u32) -> (IVec3, IVec3) {
        let p = g.tri(t);
        self.range(p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]))
    }

    /// Lists triangles `tris` (at their positions in `g`).
    pub fn insert(&mut self, g: &Geometry, tris: std::ops::Range<u32>) {
        for t in tris {
            let (a, b) = self.tri_range(g, t);
            let mut cells = Vec::new();
            self.each(a, b, |v| cells.push(v));
            for v in cells {
                self.voxels[v].push(t);
            }
        }
    }

    /// Unlists triangles `tris` (at their positions in `g`, where they were inserted).
    pub fn remove(&mut self, g: &Geometry, tris: std::ops::Range<u32>) {
        for t in tris.clone() {
            let (a, b) = self.tri_range(g, t);
            let mut cells = Vec::new();
            self.each(a, b, |v| cells.push(v));
            for v in cells {
                self.voxels[v].retain(|x| !tris.contains(x));
            }
        }
    }

    fn range(&self, lo: DVec3, hi: DVec3) -> (IVec3, IVec3) {
        let f = |p: DVec3| ((p - self.lo) / self.cell).floor().as_ivec3().clamp(IVec3::ZERO, self.dims - 1);
        (f(lo), f(hi))
    }

    fn each(&self, a: IVec3, b: IVec3, mut f: impl FnMut(usize)) {
        for z in a.z..=b.z {
            for y in a.y..=b.y {
                for x in a.x..=b.x {
                    f(((z * self.dims.y + y) * self.dims.x + x) as usize);
                }
            }
        }
    }

    /// The box of voxel `(x, y, z)`, unbounded on the sides where it is a border voxel (a
    /// triangle moved outside the scene's bounds is listed there).
    fn voxel_box(&self, v: IVec3) -> (DVec3, DVec3) {
        let lo = self.lo + self.cell * v.as_dvec3();
        let hi = lo + self.cell;
        let inf = DVec3::splat(f64::INFINITY);
        (DVec3::select(v.cmpeq(IVec3::ZERO), -inf, lo), DVec3::select(v.cmpeq(self.dims - 1), inf, hi))
    }

    /// Whether triangle `t` (at its position in `g`, where it is listed) is listed in a
    /// voxel whose box `keep` accepts: what [`Self::query_where`] decides for it.
    pub fn listed_where(&self, g: &Geometry, t: u32, keep: impl Fn((DVec3, DVec3)) -> bool) -> bool {
        let (a, b) = self.tri_range(g, t);
        (a.z..=b.z).any(|z| (a.y..=b.y).any(|y| (a.x..=b.x).any(|x| keep(self.voxel_box(IVec3::new(x, y, z))))))
    }

    /// [`Self::query`] over the voxels whose box `keep` accepts (a receiver's shaft: a long
    /// thin shaft meets few of the voxels of its box).
    pub fn query_where(&self, lo: DVec3, hi: DVec3, keep: impl Fn((DVec3, DVec3)) -> bool, stamp: &mut Vec<u32>, epoch: &mut u32, mut f: impl FnMut(u32)) {
        if stamp.len() < self.tris {
            stamp.resize(self.tris, 0);
        }
        *epoch = epoch.wrapping_add(1);
        if *epoch == 0 {
            stamp.iter_mut().for_each(|s| *s = 0);
            *epoch = 1;
        }
        let (a, b) = self.range(lo, hi);
        let e = *epoch;
        for z in a.z..=b.z {
            for y in a.y..=b.y {
                for x in a.x..=b.x {
                    if !keep(self.voxel_box(IVec3::new(x, y, z))) {
                        continue;
                    }
                    for &t in &self.voxels[((z * self.dims.y + y) * self.dims.x + x) as usize] {
                        if stamp[t as usize] != e {
                            stamp[t as usize] = e;
                            f(t);
                        }
                    }
                }
            }
        }
    }

    /// Calls `f` once for every triangle listed in a voxel the box touches. `stamp` (one
    /// entry per triangle) and `epoch` dedupe across voxels without clearing.
    pub fn query(&self, lo: DVec3, hi: DVec3, stamp: &mut Vec<u32>, epoch: &mut u32, f: impl FnMut(u32)) {
        self.query_where(lo, hi, |_| true, stamp, epoch, f);
    }

    /// Bytes of the voxel lists.
    pub fn bytes(&self) -> usize {
        self.voxels.iter().map(|v| 24 + v.capacity() * 4).sum()
    }
}
