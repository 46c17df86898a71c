//! Which lights can reach an estimate's band at all (paper 003 §6, several sources: the
//! error estimate sums every light over the band, and in a scene of many rooms most lights
//! light none of it). Exact culls, each conservative by a margin above the rounding of the
//! band's nodes (which the estimate hands to the backprojection in f32): a light is skipped
//! only when its irradiance is 0 at every point of the band, so the estimate is the one
//! with every light (tested against it).
//!
//! 1. **Facing**: every point of the light at or below the band's plane (the band is flat:
//!    one plane for all its points), so the light clipped to any node's tangent plane is
//!    empty (a point light: the cosine is not positive).
//! 2. **Behind**: every corner of the band behind an area light's emitting side.
//! 3. **Shaft blocked**: between the band B and the light L (both convex) lies a plane P
//!    with B strictly on one side and L on the other; the segments from B to L meet P in
//!    the convex hull C of the crossings of the segments between their corners (a polytope
//!    meets a plane in the hull of its edges' crossings, and the edges of conv(B ∪ L) that
//!    cross P join a corner of B to one of L). If C, grown by a margin, lies inside the
//!    union of the scene's triangles in P, every segment from the band to the light is
//!    blocked — e.g. a wall between two rooms. The planes tried are those of the triangles
//!    the segments from the band's centre and corners to the light's centre hit. Area
//!    lights only: for a point light the 18 shadow rays cost less than the test.
use super::{Band, SceneLights};
use edgepoint_scene::geometry::ray_triangle;
pub use edgepoint_scene::polyclip::convex_hull;
use edgepoint_scene::polyclip::{signed_area2, subtract_convex};
use edgepoint_scene::Light;
use glam::{DVec2, DVec3};

/// Why a light was culled, counted by the benchmark.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Culls {
    pub facing: u64,
    pub behind: u64,
    pub blocked: u64,
    /// Pairs (band, light) looked at.
    pub pairs: u64,
}

impl Culls {
    pub fn add(&mut self, o: &Culls) {
        self.facing += o.facing;
        self.behind += o.behind;
        self.blocked += o.blocked;
        self.pairs += o.pairs;
    }
}

/// Planes at most this many tried per (band, light).
const MAX_PLANES: usize = 8;
/// Crossings must lie this far inside the segments (fraction of the way): the shadow rays
/// ignore hits within 10⁻⁴ of either end and the backprojection what lies within 10⁻⁴ of
/// the light's plane.
const SEGMENT_MARGIN: f64 = 1e-3;

impl SceneLights<'_> {
    /// The light's corners (an area light) or its position.
    pub(super) fn light_points(&self, k: usize) -> Vec<DVec3> {
        match &self.lights[k] {
            Light::Area { vertices, .. } => vertices.iter().map(|v| v.as_dvec3()).collect(),
            Light::Point { position, .. } | Light::Spot { position, .. } => vec![position.as_dvec3()],
        }
    }

    /// Whether light `k` may light some point of `band`; `false` only when it lights none
    /// (see the module's doc). Counts the reason in `culls`.
    pub fn reaches(&self, k: usize, band: &Band, culls: &mut Culls) -> bool {
        culls.pairs += 1;
        let corners = band.corners();
        let light = self.light_points(k);
        // The margin: well above f32 rounding of coordinates of this size.
        let size = corners.iter().chain(&light).map(|p| p.abs().max_element()).fold(1.0, f64::max);
        let margin = 1e-5 * size;
        let n = band.normal;
        if corners.iter().all(|c| light.iter().all(|y| n.dot(*y - *c) < -margin)) {
            culls.facing += 1;
            return false;
        }
        if let Some(plane) = &self.planes[k] {
            if corners.iter().all(|c| plane.height(*c) < -margin) {
                culls.behind += 1;
                return false;
            }
        }
        // A point light's shadow ray per node costs less than the shaft test.
        if self.planes[k].is_some() && self.shaft_blocked(&corners, &light, size) {
            culls.blocked += 1;
            return false;
        }
        true
    }

    fn shaft_blocked(&self, band: &[DVec3; 4], light: &[DVec3], size: f64) -> bool {
        let target = light.iter().copied().sum::<DVec3>() / light.len() as f64;
        let centre = band.iter().copied().sum::<DVec3>() / 4.0;
        let mut planes: Vec<(DVec3, f64)> = Vec::new();
        for from in std::iter::once(centre).chain(band.iter().copied()) {
            self.hit_planes(from, target, &mut planes);
        }
        planes.iter().take(MAX_PLANES).any(|&(m, d)| self.plane_blocks(m, d, band, light, size))
    }

    /// The planes (unit normal, offset) of the triangles the segment p → q crosses,
    /// appended to `out` unless already there.
    fn hit_planes(&self, p: DVec3, q: DVec3, out: &mut Vec<(DVec3, f64)>) {
        for o in 0..self.bvhs.len() {
            let (to, w) = (&self.to_object[o], &self.to_world[o]);
            let (po, qo) = (to.transform_point3(p), to.transform_point3(q));
            let (o32, d32) = (po.as_vec3(), (qo - po).as_vec3());
            self.bvhs[o].visit(
                |lo, hi| super::segment_meets(po, qo, lo, hi),
                |f| {
                    if ray_triangle(o32, d32, f.v[0], f.v[1], f.v[2]).is_some_and(|t| t > 0.0 && t < 1.0) {
                        let v = f.v.map(|x| w.transform_point3(x.as_dvec3()));
                        if let Some(m) = (v[1] - v[0]).cross(v[2] - v[0]).try_normalize() {
                            let d = m.dot(v[0]);
                            let same = |(n, e): &(DVec3, f64)| (n.dot(m).abs() > 1.0 - 1e-12) && (e - d * n.dot(m).signum()).abs() < 1e-9 * (1.0 + d.abs());
                            if out.len() < MAX_PLANES && !out.iter().any(same) {
                                out.push((m, d));
                            }
                        }
                    }
                    true
                },
            );
        }
    }

    /// Whether the scene's triangles in the plane `m·x = d` block every segment from the
    /// band to the light (module doc, item 3).
    fn plane_blocks(&self, m: DVec3, d: f64, band: &[DVec3; 4], light: &[DVec3], size: f64) -> bool {
        let margin = 1e-5 * size;
        let db: Vec<f64> = band.iter().map(|x| m.dot(*x) - d).collect();
        let dl: Vec<f64> = light.iter().map(|y| m.dot(*y) - d).collect();
        let sign = if db[0] > 0.0 { 1.0 } else { -1.0 };
        // Strictly apart: the band on one side, the light on the other.
        if !(db.iter().all(|x| x * sign > margin) && dl.iter().all(|y| -y * sign > margin)) {
            return false;
        }
        // The fraction of the way from the band at which a segment crosses, d_x / (d_x − d_y),
        // grows with d_x and with −d_y: its extremes are at the corners.
        let (bmin, bmax) = db.iter().fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x.abs()), b.max(x.abs())));
        let (lmin, lmax) = dl.iter().fold((f64::INFINITY, 0.0f64), |(a, b), y| (a.min(y.abs()), b.max(y.abs())));
        if bmin / (bmin + lmax) < SEGMENT_MARGIN || bmax / (bmax + lmin) > 1.0 - SEGMENT_MARGIN {
            return false;
        }
        // Triangles within `flat` of the plane count as in it; one tilted by that much meets
        // a segment at most `flat · longest / (bmin + lmin)` away from the plane's crossing,
        // and the hull is grown by more than that.
        let flat = 1e-7 * size;
        let longest = band.iter().flat_map(|x| light.iter().map(move |y| (*y - *x).length())).fold(0.0, f64::max);
        let grow = 1e-5 * size + 2.0 * flat * longest / (bmin + lmin);
        let u = m.any_orthonormal_vector();
        let v = m.cross(u);
        let local = |x: DVec3| DVec2::new(x.dot(u), x.dot(v));
        let mut pts = Vec::with_capacity(band.len() * light.len() * 4);
        let mut lo3 = DVec3::splat(f64::INFINITY);
        let mut hi3 = DVec3::splat(f64::NEG_INFINITY);
        for (x, dx) in band.iter().zip(&db) {
            for (y, dy) in light.iter().zip(&dl) {
                let c = *x + (*y - *x) * (dx / (dx - dy));
                lo3 = lo3.min(c);
                hi3 = hi3.max(c);
                let c = local(c);
                for s in [DVec2::new(-grow, -grow), DVec2::new(grow, -grow), DVec2::new(grow, grow), DVec2::new(-grow, grow)] {
                    pts.push(c + s);
                }
            }
        }
        let hull = convex_hull(pts);
        if hull.len() < 3 {
            return false;
        }
        let (lo3, hi3) = (lo3 - DVec3::splat(2.0 * grow), hi3 + DVec3::splat(2.0 * grow));
        // Slivers this thin are the rounding at the shared sides of the plane's triangles.
        let min_area2 = 1e-12 * signed_area2(&hull);
        let mut rest = vec![hull];
        let mut next = Vec::new();
        for o in 0..self.bvhs.len() {
            let (to, w) = (&self.to_object[o], &self.to_world[o]);
            // The query box in object space: the box of the world box's corners.
            let (mut olo, mut ohi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
            for i in 0..8 {
                let c = DVec3::new(if i & 1 == 0 { lo3.x } else { hi3.x }, if i & 2 == 0 { lo3.y } else { hi3.y }, if i & 4 == 0 { lo3.z } else { hi3.z });
                let c = to.transform_point3(c);
                olo = olo.min(c);
                ohi = ohi.max(c);
            }
            let go = self.bvhs[o].visit(
                |lo, hi| lo.as_dvec3().cmple(ohi).all() && olo.cmple(hi.as_dvec3()).all(),
                |f| {
                    let t = f.v.map(|x| w.transform_point3(x.as_dvec3()));
                    if t.iter().all(|x| (m.dot(*x) - d).abs() <= flat) {
                        let mut tri: Vec<DVec2> = t.iter().map(|x| local(*x)).collect();
                        let a2 = signed_area2(&tri);
                        if a2 != 0.0 {
                            if a2 < 0.0 {
                                tri.reverse();
                            }
                            next.clear();
                            for piece in rest.drain(..) {
                                subtract_convex(&piece, &tri, min_area2, &mut next);
                            }
                            std::mem::swap(&mut rest, &mut next);
                        }
                    }
                    !rest.is_empty()
                },
            );
            if !go {
                return true;
            }
        }
        rest.is_empty()
    }
}

