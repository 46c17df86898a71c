//! Procedural meshes for the built-in scenes: polygons, boxes, tori, capsules, spheres and a
//! plate with square holes. Closed shapes are wound outward (positive signed volume).
use crate::{Mesh, NoProgress};
use glam::{Affine3A, Vec3};
use std::f32::consts::{PI, TAU};

/// A planar polygon (fan-triangulated), wound as given.
pub fn polygon(v: &[Vec3]) -> Mesh {
    let tris = (1..v.len() as u32 - 1).map(|i| [0, i, i + 1]).collect();
    Mesh::from_triangles(v.to_vec(), tris, &NoProgress)
}

/// Raw triangles that are merged into meshes (several parts make one object).
#[derive(Debug, Clone, Default)]
pub struct Parts {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

impl Parts {
    /// Adds `m` moved by `t` (a mirroring `t` keeps the faces facing out).
    pub fn add(&mut self, m: &Mesh, t: Affine3A) -> &mut Self {
        let base = self.positions.len() as u32;
        let mirror = t.matrix3.determinant() < 0.0;
        self.positions.extend(m.positions.iter().map(|p| t.transform_point3(*p)));
        self.triangles.extend(m.triangles.iter().map(|tr| {
            let tr = tr.map(|i| i + base);
            if mirror {
                [tr[0], tr[2], tr[1]]
            } else {
                tr
            }
        }));
        self
    }
    pub fn mesh(self) -> Mesh {
        Mesh::from_triangles(self.positions, self.triangles, &NoProgress)
    }
}

fn outward(mut m: Mesh) -> Mesh {
    if m.signed_volume() < 0.0 {
        m.flip();
    }
    m
}

/// The box `[lo, hi]`.
pub fn cuboid(lo: Vec3, hi: Vec3) -> Mesh {
    let c = |i: u32| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let p: Vec<Vec3> = (0..8).map(c).collect();
    let t = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    outward(Mesh::from_triangles(p, t, &NoProgress))
}

/// A torus around the y axis: ring radius `major`, tube radius `minor`, `around` segments
/// along the ring and `tube` around the tube (`2 · around · tube` triangles).
pub fn torus(major: f32, minor: f32, around: u32, tube: u32) -> Mesh {
    let mut p = Vec::with_capacity((around * tube) as usize);
    for i in 0..around {
        let phi = TAU * i as f32 / around as f32;
        for j in 0..tube {
            let th = TAU * j as f32 / tube as f32;
            let rr = major + minor * th.cos();
            p.push(Vec3::new(rr * phi.cos(), minor * th.sin(), rr * phi.sin()));
        }
    }
    let id = |i: u32, j: u32| (i % around) * tube + (j % tube);
    let mut t = Vec::with_capacity((2 * around * tube) as usize);
    for i in 0..around {
        for j in 0..tube {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            t.push([a, b, c]);
            t.push([a, c, d]);
        }
    }
    outward(Mesh::from_triangles(p, t, &NoProgress))
}

/// A surface of revolution around the x axis through the profile `(x, radius)` from one
/// pole (radius 0) to the other, with `around` segments.
fn revolve_x(profile: &[(f32, f32)], around: u32) -> Mesh {
    let mut p = Vec::new();
    let mut rings: Vec<Vec<u32>> = Vec::new();
    for &(x, r) in profile {
        if r <= 0.0 {
            rings.push(vec![p.len() as u32]);
            p.push(Vec3::new(x, 0.0, 0.0));
        } else {
            let ring = (0..around)
                .map(|i| {
                    let a = TAU * i as f32 / around as f32;
                    p.push(Vec3::new(x, r * a.cos(), r * a.sin()));
                    p.len() as u32 - 1
                })
                .collect();
            rings.push(ring);
        }
    }
    let mut t = Vec::new();
    for w in rings.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        for i in 0..around as usize {
            let j = (i + 1) % around as usize;
            match (a.len(), b.len()) {
                (1, 1) => {}
                (1, _) => t.push([a[0], b[j], b[i]]),
                (_, 1) => t.push([a[i], a[j], b[0]]),
                _ => {
                    t.push([a[i], a[j], b[j]]);
                    t.push([a[i], b[j], b[i]]);
                }
            }
        }
    }
    outward(Mesh::from_triangles(p, t, &NoProgress))
}

/// A capsule along the x axis: a cylinder of `radius` and length `2 half_length` capped by
/// hemispheres; `around` segments, `cap` rings per hemisphere, `body` rings along the
/// cylinder.
pub fn capsule(radius: f32, half_length: f32, around: u32, cap: u32, body: u32) -> Mesh {
    let mut prof = Vec::new();
    for k in 0..=cap {
        let a = PI * 0.5 * k as f32 / cap as f32;
        prof.push((-half_length - radius * a.cos(), radius * a.sin()));
    }
    for k in 1..body {
        prof.push((-half_length + 2.0 * half_length * k as f32 / body as f32, radius));
    }
    for k in (0..=cap).rev() {
        let a = PI * 0.5 * k as f32 / cap as f32;
        prof.push((half_length + radius * a.cos(), radius * a.sin()));
    }
    revolve_x(&prof, around)
}

/// A UV sphere of `radius` at the origin.
pub fn sphere(radius: f32, around: u32, rings: u32) -> Mesh {
    let prof: Vec<(f32, f32)> = (0..=rings)
        .map(|k| {
            let a = PI * k as f32 / rings as f32;
            (-radius * a.cos(), radius * a.sin())
        })
        .collect();
    revolve_x(&prof, around)
}

/// A square plate in the x–z plane, `size` wide and `thickness` thick (from y = 0 up),
/// with `n × n` square holes separated by bars `bar` wide (a closed solid: top and bottom
/// faces, outer walls and hole walls).
pub fn grid_plate(size: f32, n: u32, bar: f32, thickness: f32) -> Mesh {
    let hole = (size - bar * (n + 1) as f32) / n as f32;
    assert!(hole > 0.0, "bars too wide for the plate");
    // Breakpoints: bar, hole, bar, ..., bar (2n + 1 intervals).
    let mut xs = vec![0.0f32];
    for k in 0..2 * n + 1 {
        let w = if k % 2 == 0 { bar } else { hole };
        xs.push(xs[k as usize] + w);
    }
    let m = xs.len() - 1;
    let solid = |i: isize, j: isize| -> bool {
        i >= 0 && j >= 0 && (i as usize) < m && (j as usize) < m && (i % 2 == 0 || j % 2 == 0)
    };
    let h = size * 0.5;
    let at = |i: usize, j: usize, y: f32| Vec3::new(xs[i] - h, y, xs[j] - h);
    let mut p = Vec::new();
    let mut t = Vec::new();
    let mut quad = |q: [Vec3; 4]| {
        let b = p.len() as u32;
        p.extend(q);
        t.push([b, b + 1, b + 2]);
        t.push([b, b + 2, b + 3]);
    };
    for i in 0..m {
        for j in 0..m {
            if !solid(i as isize, j as isize) {
                continue;
            }
            // Top (facing +y) and bottom (facing -y).
            quad([at(i, j, thickness), at(i, j + 1, thickness), at(i + 1, j + 1, thickness), at(i + 1, j, thickness)]);
            quad([at(i, j, 0.0), at(i + 1, j, 0.0), at(i + 1, j + 1, 0.0), at(i, j + 1, 0.0)]);
            // Walls towards empty neighbours.
            let (ii, jj) = (i as isize, j as isize);
            if !solid(ii - 1, jj) {
                quad([at(i, j, 0.0), at(i, j + 1, 0.0), at(i, j + 1, thickness), at(i, j, thickness)]);
            }
            if !solid(ii + 1, jj) {
                quad([at(i + 1, j, 0.0), at(i + 1, j, thickness), at(i + 1, j + 1, thickness), at(i + 1, j + 1, 0.0)]);
            }
            if !solid(ii, jj - 1) {
                quad([at(i, j, 0.0), at(i, j, thickness), at(i + 1, j, thickness), at(i + 1, j, 0.0)]);
            }
            if !solid(ii, jj + 1) {
                quad([at(i, j + 1, 0.0), at(i + 1, j + 1, 0.0), at(i + 1, j + 1, thickness), at(i, j + 1, thickness)]);
            }
        }
    }
    outward(Mesh::from_triangles(p, t, &NoProgress))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn closed(m: &Mesh) {
        assert_eq!(m.boundary_edges(), 0);
        assert_eq!(m.stats.non_manifold_edges, 0);
        assert_eq!(m.stats.zero_area, 0);
        assert!(m.signed_volume() > 0.0);
        // Every face normal points away from the inside: consistent winding is implied by
        // a closed manifold with positive volume and every edge used once each way.
        for e in &m.edges {
            let (f0, f1) = (m.triangles[e.faces[0] as usize], m.triangles[e.faces[1] as usize]);
            let dir = |t: [u32; 3], a: u32, b: u32| (0..3).any(|k| t[k] == a && t[(k + 1) % 3] == b);
            assert!(dir(f0, e.v[0], e.v[1]) && dir(f1, e.v[1], e.v[0]), "inconsistent winding");
        }
    }

    #[test]
    fn shapes_are_closed_and_outward() {
        let t = torus(1.0, 0.25, 48, 24);
        closed(&t);
        assert_eq!(t.triangles.len(), 2 * 48 * 24);
        let v = 2.0 * PI * PI * 1.0 * 0.25 * 0.25;
        assert!((t.signed_volume() - v).abs() < 0.02 * v);
        let c = capsule(0.5, 1.0, 32, 8, 6);
        closed(&c);
        let v = PI * 0.25 * 2.0 + 4.0 / 3.0 * PI * 0.125;
        assert!((c.signed_volume() - v).abs() < 0.03 * v);
        closed(&sphere(1.0, 24, 12));
        closed(&cuboid(Vec3::ZERO, Vec3::new(1.0, 2.0, 3.0)));
        let g = grid_plate(1.0, 4, 0.05, 0.02);
        closed(&g);
        let holes = 4.0 * 4.0 * ((1.0 - 0.05 * 5.0) / 4.0f32).powi(2);
        assert!((g.signed_volume() - (1.0 - holes) * 0.02).abs() < 1e-4);
    }
}
