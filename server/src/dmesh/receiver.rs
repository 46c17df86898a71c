//! One receiver face and one area light: the receiver's plane and 2D frame, the part of the
//! light above that plane (the same for every point of the face, so it is clipped once),
//! and the blockers that can stand between them (paper 002 §2: the shaft between source
//! and receiver bounds every surface and every backprojection of the face).
use super::geometry::Geometry;
use super::grid::Grid;
use edgepoint_scene::backprojection::LightPlane;
use glam::{DVec2, DVec3};

/// Relative tolerance of the mesh: lengths below `EPS × scene size` are one point.
pub const EPS: f64 = 1e-9;

#[derive(Debug, Clone)]
pub struct Receiver {
    pub tri: u32,
    /// Frame: origin, in-plane axes and the normal facing the light.
    pub o: DVec3,
    pub e1: DVec3,
    pub e2: DVec3,
    pub n: DVec3,
    /// The triangle's corners in the frame, counter-clockwise.
    pub corners: [DVec2; 3],
    /// Length tolerance (scene scale × [`EPS`]).
    pub tol: f64,
}

impl Receiver {
    /// The frame of triangle `t`, its normal turned toward the light's centre (receivers
    /// are two-sided); `None` for a degenerate triangle.
    pub fn new(g: &Geometry, t: u32, light_centre: DVec3, tol: f64) -> Option<Receiver> {
        let [a, b, c] = g.tri(t);
        let mut n = (b - a).cross(c - a).try_normalize()?;
        if n.dot(light_centre - a) < 0.0 {
            n = -n;
        }
        let e1 = (b - a).try_normalize()?;
        let e2 = n.cross(e1);
        let to2 = |p: DVec3| DVec2::new((p - a).dot(e1), (p - a).dot(e2));
        let mut corners = [to2(a), to2(b), to2(c)];
        if (corners[1] - corners[0]).perp_dot(corners[2] - corners[0]) < 0.0 {
            corners.swap(1, 2);
        }
        Some(Receiver { tri: t, o: a, e1, e2, n, corners, tol })
    }

    #[inline]
    pub fn height(&self, p: DVec3) -> f64 {
        (p - self.o).dot(self.n)
    }

    #[inline]
    pub fn to2(&self, p: DVec3) -> DVec2 {
        DVec2::new((p - self.o).dot(self.e1), (p - self.o).dot(self.e2))
    }

    #[inline]
    pub fn to3(&self, q: DVec2) -> DVec3 {
        self.o + self.e1 * q.x + self.e2 * q.y
    }

    /// The part of segment `a b` inside the triangle (Liang–Barsky against its three
    /// sides), as parameters along it.
    pub fn clip_segment(&self, a: DVec2, b: DVec2) -> Option<(f64, f64)> {
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        let d = b - a;
        for k in 0..3 {
            let (p, q) = (self.corners[k], self.corners[(k + 1) % 3]);
            let e = q - p;
            // Inside: e × (x − p) ≥ 0 for a counter-clockwise triangle.
            let fa = e.perp_dot(a - p);
            let fd = e.perp_dot(d);
            if fd.abs() < 1e-300 {
                if fa < -self.tol * e.length() {
                    return None;
                }
                continue;
            }
            let t = -fa / fd;
            if fd > 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
        (t1 - t0 > 0.0).then_some((t0, t1))
    }

    /// The point where segment `p q` crosses the plane at height `h` over the receiver, if
    /// it does.
    pub fn crossing(&self, p: DVec3, q: DVec3, h: f64) -> Option<DVec3> {
        let (hp, hq) = (self.height(p) - h, self.height(q) - h);
        ((hp > 0.0) != (hq > 0.0)).then(|| p + (q - p) * (hp / (hp - hq)))
    }

    /// The two points where triangle `tri` passes through the receiver's plane, if it does
    /// (the sides' sign changes come in pairs).
    pub fn plane_crossing(&self, tri: &[DVec3; 3]) -> Option<[DVec3; 2]> {
        let mut q = (0..3).filter_map(|k| self.crossing(tri[k], tri[(k + 1) % 3], 0.0));
        Some([q.next()?, q.next()?])
    }

    /// Whether `q` lies inside the triangle (closed).
    pub fn contains(&self, q: DVec2) -> bool {
        (0..3).all(|k| {
            let (p, r) = (self.corners[k], self.corners[(k + 1) % 3]);
            (r - p).perp_dot(q - p) >= -self.tol * (r - p).length()
        })
    }
}

/// The part of segment `a b` where an affine function with values `ha`, `hb` at its ends
/// is positive.
pub fn part_above(a: DVec3, b: DVec3, ha: f64, hb: f64) -> Option<(DVec3, DVec3)> {
    match (ha > 0.0, hb > 0.0) {
        (true, true) => Some((a, b)),
        (false, false) => None,
        (true, false) => Some((a, a + (b - a) * (ha / (ha - hb)))),
        (false, true) => Some((a + (b - a) * (ha / (ha - hb)), b)),
    }
}

/// The light as seen from one receiver plane: its corners in 3D, which of them are above the
/// plane (they generate surfaces), and each edge's part above the plane.
#[derive(Debug, Clone)]
pub struct LightAbove {
    pub corners: Vec<DVec3>,
    /// `Some(p)` for a corner strictly above the receiver's plane.
    pub vertices: Vec<Option<DVec3>>,
    /// Edge i (corner i to i + 1): its part strictly above the plane, if any.
    pub edges: Vec<Option<(DVec3, DVec3)>>,
    /// The light clipped to the plane (3D), for the shaft.
    pub clipped: Vec<DVec3>,
}

impl LightAbove {
    pub fn new(light: &LightPlane, r: &Receiver) -> Option<LightAbove> {
        let corners: Vec<DVec3> = light.corners.iter().map(|q| light.lift(*q)).collect();
        let h: Vec<f64> = corners.iter().map(|p| r.height(*p)).collect();
        let k = corners.len();
        let vertices: Vec<Option<DVec3>> = (0..k).map(|i| (h[i] > r.tol).then_some(corners[i])).collect();
        let edges = (0..k)
            .map(|i| {
                let j = (i + 1) % k;
                part_above(corners[i], corners[j], h[i] - r.tol, h[j] - r.tol)
            })
            .collect();
        let clipped = edgepoint_scene::polyclip::clip(&corners, |p| r.height(p) - r.tol);
        if clipped.len() < 3 {
            return None;
        }
        Some(LightAbove { corners, vertices, edges, clipped })
    }
}

/// The shaft between the light (above the receiver's plane) and the receiver (Haines and
/// Wallace's shaft culling): its box, and the planes of the convex hull of the two polygons
/// (through an edge of one and a corner of the other with every corner of both on one side).
/// Every line from the light to the receiver lies inside.
#[derive(Debug, Clone)]
pub struct Shaft {
    pub lo: DVec3,
    pub hi: DVec3,
    /// `(n, d)`: inside where `n · x <= d`.
    pub planes: Vec<(DVec3, f64)>,
}

impl Shaft {
    pub fn new(light: &[DVec3], receiver: &[DVec3], tol: f64) -> Shaft {
        let pts: Vec<DVec3> = light.iter().chain(receiver.iter()).copied().collect();
        let (lo, hi) = pts.iter().fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        let mut planes = Vec::new();
        for (poly, other) in [(light, receiver), (receiver, light)] {
            let k = poly.len();
            for i in 0..k {
                let (a, b) = (poly[i], poly[(i + 1) % k]);
                for c in other {
                    let Some(n) = (b - a).cross(*c - a).try_normalize() else { continue };
                    let d = n.dot(a);
                    let (mut pos, mut neg) = (false, false);
                    for p in &pts {
                        let s = n.dot(*p) - d;
                        pos |= s > tol;
                        neg |= s < -tol;
                    }
                    match (pos, neg) {
                        (false, true) => planes.push((n, d)),
                        (true, false) => planes.push((-n, -d)),
                        _ => {}
                    }
                }
            }
        }
        Shaft { lo: lo - tol, hi: hi + tol, planes }
    }

    /// Whether the box `(lo, hi)` may meet the shaft (no plane has all its corners outside).
    pub fn may_meet_box(&self, (lo, hi): (DVec3, DVec3), tol: f64) -> bool {
        if lo.cmpgt(self.hi).any() || hi.cmplt(self.lo).any() {
            return false;
        }
        let corners = (0..8).map(|k| DVec3::new(if k & 1 == 0 { lo.x } else { hi.x }, if k & 2 == 0 { lo.y } else { hi.y }, if k & 4 == 0 { lo.z } else { hi.z }));
        !self.planes.iter().any(|(n, d)| corners.clone().all(|x| n.dot(x) > *d + tol))
    }

    /// Whether triangle `p` may meet the shaft (no plane has it wholly outside).
    pub fn may_meet(&self, p: &[DVec3; 3], tol: f64) -> bool {
        let (tlo, thi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        if tlo.cmpgt(self.hi).any() || thi.cmplt(self.lo).any() {
            return false;
        }
        !self.planes.iter().any(|(n, d)| p.iter().all(|x| n.dot(*x) > *d + tol))
    }
}

/// The triangles that can block some line from the light (above the plane) to the receiver:
/// meeting the shaft, with a corner above the receiver's plane and one in front of the light,
/// not the receiver. Every occluder of every point of the face is among them.
#[allow(clippy::too_many_arguments)] // the grid query's scratch (out, stamp, epoch) is the caller's, reused across receivers
pub fn shaft_blockers(g: &Geometry, grid: &Grid, light: &LightPlane, r: &Receiver, shaft: &Shaft, out: &mut Vec<u32>, stamp: &mut Vec<u32>, epoch: &mut u32) {
    out.clear();
    // Only the voxels the shaft may meet, not every voxel of its box: a triangle listed in
    // none of them lies wholly outside the shaft (beyond its tolerance) and blocks nothing.
    grid.query_where(shaft.lo, shaft.hi, |b| shaft.may_meet_box(b, r.tol), stamp, epoch, |t| {
        if is_blocker(g, light, r, shaft, t) {
            out.push(t);
        }
    });
}

/// Whether [`shaft_blockers`] lists triangle `t` (at its place in `g`, listed in `grid`):
/// [`is_blocker`], in a voxel the shaft may meet.
pub fn is_listed_blocker(g: &Geometry, grid: &Grid, light: &LightPlane, r: &Receiver, shaft: &Shaft, t: u32) -> bool {
    is_blocker(g, light, r, shaft, t) && grid.listed_where(g, t, |b| shaft.may_meet_box(b, r.tol))
}

/// Whether triangle `t` can block a line from the light to the receiver.
pub fn is_blocker(g: &Geometry, light: &LightPlane, r: &Receiver, shaft: &Shaft, t: u32) -> bool {
    if t == r.tri {
        return false;
    }
    let p = g.tri(t);
    shaft.may_meet(&p, r.tol) && p.iter().any(|x| r.height(*x) > r.tol) && p.iter().any(|x| light.height(*x) > r.tol)
}
