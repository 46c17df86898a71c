//! The backprojection at a point (paper 002 §1 and §4.4, after Drettakis and Fiume's
//! backprojection): the part of a polygonal area light visible from a point, as convex
//! polygons in the light's plane, and the irradiance from it in closed form
//! ([`crate::polygon_irradiance`]). Exact up to rounding: the light polygon, clipped to the
//! point's tangent plane, minus the central projection from the point onto the light's
//! plane of every blocker triangle between them. It is the oracle the discontinuity mesh's
//! per-face backprojections are checked against, and the `direct` shader's `area=exact`.
//!
//! A blocker is first clipped to the pyramid from the point to the light (so only what can
//! block is projected, and nothing behind the point or the light is), then projected and
//! subtracted from every visible piece ([`crate::polyclip::subtract_convex`]).
use crate::polyclip::{bounds, box_overlaps, clip, convex_hull, drop_repeated, signed_area2, subtract_convex};
use crate::polygon_irradiance::polygon_irradiance;
use glam::{DVec2, DVec3, Vec3};

/// What lies within this fraction of the way from a point to the light's plane does not
/// block it: the light's own fixture (a polygon in the light's plane, as `cornell`'s
/// luminaire) must not hide the light, and the shadow rays of the sampled estimate stop as
/// far short of the light (`direct`: `dist · (1 − 1e-4)`), so both see the same blockers.
pub const LIGHT_GAP: f64 = 1e-4;

/// [`Visible::convex_shadow`] projects a solid whole only when no corner's shadow is
/// magnified more than this (a corner at least 1 % of the way from the point to the light).
pub const MAX_SOLID_MAGNIFICATION: f64 = 100.0;

/// A solid with a corner outside the band [`Visible::convex_shadow`] projects whole.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotBetween;

/// A planar convex area light with a frame in its plane: origin `o`, axes `u`, `v` with
/// `u × v = n`, the emitting normal, so the light's own winding is counter-clockwise in
/// (u, v) coordinates.
#[derive(Debug, Clone)]
pub struct LightPlane {
    pub o: DVec3,
    pub u: DVec3,
    pub v: DVec3,
    pub n: DVec3,
    /// The light's corners in (u, v) coordinates, counter-clockwise.
    pub corners: Vec<DVec2>,
}

impl LightPlane {
    /// The frame of a light polygon (its corners in its own winding); `None` for fewer than
    /// three corners or zero area (a validated [`crate::Light::Area`] has neither).
    pub fn new(vertices: &[Vec3]) -> Option<LightPlane> {
        let v: Vec<DVec3> = vertices.iter().map(|p| p.as_dvec3()).collect();
        if v.len() < 3 {
            return None;
        }
        // Newell's normal, in f64 (as `light::polygon_normal` does in f32).
        let n: DVec3 = (0..v.len()).map(|i| v[i].cross(v[(i + 1) % v.len()])).sum();
        let n = n.try_normalize()?;
        let o = v[0];
        let u = (v[1] - v[0]).reject_from(n).try_normalize()?;
        let w = n.cross(u);
        let corners = v.iter().map(|p| DVec2::new((*p - o).dot(u), (*p - o).dot(w))).collect();
        Some(LightPlane { o, u, v: w, n, corners })
    }

    #[inline]
    pub fn lift(&self, q: DVec2) -> DVec3 {
        self.o + self.u * q.x + self.v * q.y
    }

    #[inline]
    pub fn local(&self, x: DVec3) -> DVec2 {
        DVec2::new((x - self.o).dot(self.u), (x - self.o).dot(self.v))
    }

    /// Height of `x` above the light's plane, on its emitting side.
    #[inline]
    pub fn height(&self, x: DVec3) -> f64 {
        (x - self.o).dot(self.n)
    }

    pub fn area(&self) -> f64 {
        signed_area2(&self.corners) * 0.5
    }
}

/// The part of a light visible from one point, built by [`Visible::occlude`]-ing it with
/// every blocker triangle in its [`Visible::pyramid`].
#[derive(Debug, Clone)]
pub struct Visible<'a> {
    light: &'a LightPlane,
    p: DVec3,
    n: DVec3,
    /// Height of `p` over the light's plane (> 0).
    h: f64,
    /// The light clipped to `p`'s tangent plane, in 3D: the base of the pyramid.
    base: Vec<DVec3>,
    /// The normals of the pyramid's side planes (through `p` and each base edge), pointing
    /// inside.
    sides: Vec<DVec3>,
    /// The visible part: convex pieces in (u, v) coordinates, counter-clockwise.
    pieces: Vec<Vec<DVec2>>,
    /// Pieces (twice their area) smaller than this are rounding and are dropped.
    min_area2: f64,
    /// Shadow corners closer than this are one corner.
    min_length: f64,
}

impl<'a> Visible<'a> {
    /// The whole light above `p`'s tangent plane (normal `n`), before any blocker; `None`
    /// when `p` is behind the light's emitting side or the light is wholly below the
    /// tangent plane (no light at all reaches `p`).
    pub fn new(light: &'a LightPlane, p: Vec3, n: Vec3) -> Option<Visible<'a>> {
        let (p, n) = (p.as_dvec3(), n.as_dvec3().try_normalize()?);
        let h = light.height(p);
        if !(h > 0.0) {
            return None;
        }
        let above = clip(&light.corners, |q| n.dot(light.lift(q) - p));
        let min_area2 = 1e-12 * signed_area2(&light.corners);
        if signed_area2(&above) <= min_area2 {
            return None;
        }
        let base: Vec<DVec3> = above.iter().map(|q| light.lift(*q)).collect();
        let k = base.len();
        let centre = base.iter().fold(DVec3::ZERO, |s, b| s + *b) / k as f64;
        let sides = (0..k)
            .map(|i| {
                // (c_i − p) × (c_{i+1} − p) points into the pyramid for a base wound
                // counter-clockwise about the normal facing p.
                let m = (base[i] - p).cross(base[(i + 1) % k] - p);
                if m.dot(centre - p) >= 0.0 {
                    m
                } else {
                    -m
                }
            })
            .collect();
        // 1e-9 of the light's size: far above f64 rounding of the projected corners, far below
        // any feature of the scene's f32 geometry.
        let min_length = 1e-9 * signed_area2(&light.corners).sqrt();
        Some(Visible { light, p, n, h, base, sides, pieces: vec![above], min_area2, min_length })
    }

    /// The pyramid from the point to the visible light: its apex and then its base's
    /// corners. Only triangles meeting it can block (a gatherer may pass more).
    pub fn pyramid(&self) -> (DVec3, &[DVec3]) {
        (self.p, &self.base)
    }

    /// Whether anything of the light is left.
    pub fn is_empty(&self) -> bool {
        self.pieces.is_empty()
    }

    /// Whether triangle `t` lies wholly outside one side of the pyramid, or wholly beyond
    /// either end (the light's plane, the point): it would be clipped away whole, so
    /// [`Self::occlude`] passes it over without the clipping (most triangles that reach it
    /// only met the pyramid's box), and it hides nothing.
    pub fn passes_over(&self, t: &[DVec3; 3]) -> bool {
        let (p, light, h) = (self.p, self.light, self.h);
        self.sides.iter().any(|m| t.iter().all(|x| m.dot(*x - p) < 0.0)) || t.iter().all(|x| light.height(*x) - LIGHT_GAP * h < 0.0) || t.iter().all(|x| (1.0 - 1e-9) * h - light.height(*x) < 0.0)
    }

    /// Whether the box `(lo, hi)` lies wholly outside one side of the pyramid, or wholly
    /// beyond either end: then so does every triangle inside it ([`Self::passes_over`]
    /// holds for each, tested on the box's corner that is innermost for that plane).
    pub fn passes_over_box(&self, (lo, hi): (DVec3, DVec3)) -> bool {
        let (p, light, h) = (self.p, self.light, self.h);
        // The corner of the box farthest along `m`.
        let far = |m: DVec3| DVec3::select(m.cmpge(DVec3::ZERO), hi, lo);
        let corners = [lo, hi].into_iter().flat_map(|a| [DVec3::new(a.x, lo.y, lo.z), DVec3::new(a.x, hi.y, lo.z), DVec3::new(a.x, lo.y, hi.z), DVec3::new(a.x, hi.y, hi.z)]);
        self.sides.iter().any(|m| m.dot(far(*m) - p) < 0.0)
            || corners.clone().all(|x| light.height(x) - LIGHT_GAP * h < 0.0)
            || corners.clone().all(|x| (1.0 - 1e-9) * h - light.height(x) < 0.0)
    }

    /// Removes what triangle `t` hides of the light. Returns whether it hid anything.
    pub fn occlude(&mut self, t: [DVec3; 3]) -> bool {
        if self.pieces.is_empty() {
            return false;
        }
        let Some(shadow) = self.project(&t) else { return false };
        self.subtract(&shadow)
    }

    /// The shadow on the light's plane of a convex solid with corners `corners`: the convex
    /// hull of their central projections from the point. It is the union of its triangles'
    /// shadows — a convex body's central projection is convex, the hull of its corners'
    /// projections — when every corner lies between the point and the light, where
    /// [`Self::project`] clips nothing off a triangle but what falls outside the light.
    /// `Err(NotBetween)` when a corner does not, or lies so near the point's height that
    /// the projection would magnify it over [`MAX_SOLID_MAGNIFICATION`] times (its
    /// coordinates would swamp the light's in the subtraction): occlude the solid triangle
    /// by triangle then. `Ok(None)` when the shadow has no area.
    pub fn convex_shadow(&self, corners: impl IntoIterator<Item = DVec3>) -> Result<Option<Vec<DVec2>>, NotBetween> {
        let (p, light, h) = (self.p, self.light, self.h);
        let mut q = Vec::new();
        for x in corners {
            let height = light.height(x);
            let s = 1.0 - height / h;
            if !(height - LIGHT_GAP * h > 0.0 && s * MAX_SOLID_MAGNIFICATION >= 1.0) {
                return Err(NotBetween);
            }
            q.push(light.local(p + (x - p) / s));
        }
        Ok(self.hull_shadow(q))
    }

    /// The shadow on the light's plane of a convex closed solid with triangles `tris` that
    /// does not hold the point: the hull of its triangles' shadows ([`Self::project`]: each
    /// clipped to the pyramid and between the point and the light). The lines from the point
    /// that meet the solid form a convex cone, and every one enters the solid through a
    /// triangle, so the union of the triangles' shadows is that cone's trace on the light's
    /// plane, convex: its hull. Unlike [`Self::convex_shadow`] the solid may reach below the
    /// point's height (a box standing on the floor the point lies on). `None` when nothing of
    /// it has area.
    pub fn solid_shadow(&self, tris: impl IntoIterator<Item = [DVec3; 3]>) -> Option<Vec<DVec2>> {
        let mut q = Vec::new();
        for t in tris {
            if let Some(s) = self.project(&t) {
                q.extend(s);
            }
        }
        self.hull_shadow(q)
    }

    /// The convex hull of shadow points `q` as a shadow polygon (corners closer than the
    /// shortest edge dropped), `None` when it has no area.
    fn hull_shadow(&self, q: Vec<DVec2>) -> Option<Vec<DVec2>> {
        let mut q = convex_hull(q);
        drop_repeated(&mut q, self.min_length);
        (q.len() >= 3 && signed_area2(&q) > self.min_area2).then_some(q)
    }

    /// Removes the convex counter-clockwise polygon `shadow` (on the light's plane, in its
    /// (u, v) coordinates, no repeated corners) from the visible part: what
    /// [`Self::occlude`] does with a triangle's shadow. Returns whether it hid anything.
    pub fn subtract(&mut self, shadow: &[DVec2]) -> bool {
        let mut out = Vec::with_capacity(self.pieces.len() + 4);
        let mut changed = false;
        let shadow_box = bounds(shadow);
        for piece in self.pieces.drain(..) {
            if box_overlaps(&piece, shadow_box) {
                let before = out.len();
                subtract_convex(&piece, shadow, self.min_area2, &mut out);
                // Unchanged when the piece came back whole (one piece of the same area).
                changed |= !(out.len() == before + 1 && (signed_area2(&out[before]) - signed_area2(&piece)).abs() <= self.min_area2);
            } else {
                out.push(piece);
            }
        }
        self.pieces = out;
        changed
    }

    /// The central projection from the point onto the light's plane of the part of `t`
    /// inside the pyramid, counter-clockwise in (u, v); `None` if nothing of `t` is inside
    /// or its shadow has no area (seen edge on).
    fn project(&self, t: &[DVec3; 3]) -> Option<Vec<DVec2>> {
        let p = self.p;
        let (light, h) = (self.light, self.h);
        if self.passes_over(t) {
            return None;
        }
        let mut poly = t.to_vec();
        for m in &self.sides {
            poly = clip(&poly, |x| m.dot(x - p));
            if poly.is_empty() {
                return None;
            }
        }
        // Between (just short of) the light's plane and (just short of) the point: s =
        // 1 − height/h is the fraction of the way from p to the light, and the projection
        // divides by it.
        poly = clip(&poly, |x| light.height(x) - LIGHT_GAP * h);
        poly = clip(&poly, |x| (1.0 - 1e-9) * h - light.height(x));
        if poly.is_empty() {
            return None;
        }
        let mut q: Vec<DVec2> = poly
            .iter()
            .map(|x| {
                let s = 1.0 - light.height(*x) / h;
                light.local(p + (*x - p) / s)
            })
            .collect();
        drop_repeated(&mut q, self.min_length);
        let a2 = signed_area2(&q);
        if q.len() < 3 || a2.abs() <= self.min_area2 {
            return None;
        }
        if a2 < 0.0 {
            q.reverse();
        }
        Some(q)
    }

    /// The visible pieces in 3D, in the light's plane (counter-clockwise about its normal).
    pub fn pieces(&self) -> Vec<Vec<DVec3>> {
        self.pieces.iter().map(|q| q.iter().map(|x| self.light.lift(*x)).collect()).collect()
    }

    /// Area of the visible part of the light.
    pub fn area(&self) -> f64 {
        self.pieces.iter().map(|q| signed_area2(q) * 0.5).sum()
    }

    /// Irradiance per unit radiance at the point from the visible part (Lambert's formula
    /// over each piece; the shared cuts between pieces cancel).
    pub fn irradiance(&self) -> f64 {
        let e: f64 = self.pieces().iter().map(|q| polygon_irradiance(self.p, self.n, q)).sum();
        e.max(0.0)
    }
}

/// Irradiance per unit radiance at `p` (unit normal `n`) from `light` with `blockers` (any
/// triangles; those outside the point–light pyramid cost a clip each): the brute-force form
/// tests use.
pub fn irradiance_with_blockers(light: &LightPlane, p: Vec3, n: Vec3, blockers: impl IntoIterator<Item = [Vec3; 3]>) -> f64 {
    let Some(mut vis) = Visible::new(light, p, n) else { return 0.0 };
    for t in blockers {
        vis.occlude(t.map(|x| x.as_dvec3()));
        if vis.is_empty() {
            return 0.0;
        }
    }
    vis.irradiance()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fuzz::mutate::Rng;
    use crate::geometry::ray_triangle;

    fn unit(r: &mut Rng) -> f64 {
        (r.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A box passed over means every triangle in it is: random boxes around and beside
    /// the pyramid from random points under a ceiling light, 40 random triangles in each
    /// (corners on the box's faces and inside). Some boxes are passed over and some not.
    #[test]
    fn a_box_passed_over_passes_its_triangles_over() {
        let mut r = Rng::new(77);
        let light = LightPlane::new(&ceiling(0.5, 2.0)).unwrap();
        let (mut over, mut not) = (0, 0);
        for _ in 0..3000 {
            let mut v = |s: f64| DVec3::new(unit(&mut r) * 2.0 - 1.0, unit(&mut r) * 2.0 - 1.0, unit(&mut r) * 2.0 - 1.0) * s;
            let p = v(1.5) * DVec3::new(1.0, 0.3, 1.0);
            let Some(vis) = Visible::new(&light, p.as_vec3(), Vec3::Y) else { continue };
            let (offset, half) = (v(0.5), v(0.2).abs());
            let along = unit(&mut r) * 1.2 - 0.1;
            let c = p.lerp(DVec3::new(0.0, 2.0, 0.0), along) + offset;
            let (lo, hi) = (c - half, c + half);
            if !vis.passes_over_box((lo, hi)) {
                not += 1;
                continue;
            }
            over += 1;
            for _ in 0..40 {
                let mut corner = || {
                    let mut x = lo + (hi - lo) * DVec3::new(unit(&mut r), unit(&mut r), unit(&mut r));
                    // Half the corners on a face of the box (its extremes reached).
                    let axis = (unit(&mut r) * 6.0) as usize;
                    if axis < 3 {
                        x[axis] = if unit(&mut r) < 0.5 { lo[axis] } else { hi[axis] };
                    }
                    x
                };
                let t = [corner(), corner(), corner()];
                assert!(vis.passes_over(&t), "box {lo} .. {hi} passed over but not triangle {t:?} (point {p})");
            }
        }
        assert!(over > 300 && not > 300, "{over} boxes passed over, {not} not");
    }

    /// A square light of side 2a at height `y`, facing down.
    fn ceiling(a: f32, y: f32) -> Vec<Vec3> {
        vec![Vec3::new(-a, y, -a), Vec3::new(a, y, -a), Vec3::new(a, y, a), Vec3::new(-a, y, a)]
    }

    fn quad(lo: Vec3, hi: Vec3) -> [[Vec3; 3]; 2] {
        // A horizontal rectangle at height lo.y.
        let (a, b, c, d) = (lo, Vec3::new(hi.x, lo.y, lo.z), Vec3::new(hi.x, lo.y, hi.z), Vec3::new(lo.x, lo.y, hi.z));
        [[a, b, c], [a, c, d]]
    }

    /// Monte Carlo: uniform points on the light, each ray tested against every blocker.
    /// Returns (mean, standard error) of ∫ cos cos / r² dA.
    fn monte_carlo(light: &[Vec3], p: Vec3, n: Vec3, blockers: &[[Vec3; 3]], rays: usize, r: &mut Rng) -> (f64, f64) {
        let lp = LightPlane::new(light).unwrap();
        let area = lp.area();
        // Uniform on a convex polygon: a fan triangle by area, then uniform in it.
        let fan: Vec<f64> = (1..light.len() - 1).map(|i| signed_area2(&[lp.corners[0], lp.corners[i], lp.corners[i + 1]]) * 0.5).collect();
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..rays {
            let mut pick = unit(r) * area;
            let mut i = 0;
            while i + 1 < fan.len() && pick > fan[i] {
                pick -= fan[i];
                i += 1;
            }
            let (mut a, mut b) = (unit(r), unit(r));
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let (c0, c1, c2) = (lp.corners[0], lp.corners[i + 1], lp.corners[i + 2]);
            let y = lp.lift(c0 + (c1 - c0) * a + (c2 - c0) * b);
            let pd = p.as_dvec3();
            let d = y - pd;
            let r2 = d.length_squared();
            let w = d / r2.sqrt();
            let (cx, cl) = (n.as_dvec3().dot(w), -lp.n.dot(w));
            let mut f = 0.0;
            if cx > 0.0 && cl > 0.0 {
                let dir = d.as_vec3();
                let blocked = blockers.iter().any(|t| ray_triangle(p, dir, t[0], t[1], t[2]).is_some_and(|t| t < 1.0 - 1e-6));
                if !blocked {
                    f = cx * cl / r2 * area;
                }
            }
            s += f;
            s2 += f * f;
        }
        let m = s / rays as f64;
        (m, ((s2 / rays as f64 - m * m) / rays as f64).sqrt())
    }

    #[test]
    fn unoccluded_light_is_lamberts_formula_and_a_blocker_over_the_point_is_darkness() {
        let light = ceiling(0.5, 2.0);
        let lp = LightPlane::new(&light).unwrap();
        assert!(lp.n.y < -0.99 && (lp.area() - 1.0).abs() < 1e-12);
        let p = Vec3::ZERO;
        let free = irradiance_with_blockers(&lp, p, Vec3::Y, []);
        let (a, h) = (0.5f64, 2.0f64);
        let r = (a * a + h * h).sqrt();
        assert!((free - 4.0 * (a / r) * (a / r).atan()).abs() < 1e-9, "{free}");
        // The light's own fixture, in its plane, hides nothing (as for the shadow rays).
        let fixture = [[light[0], light[1], light[2]], [light[0], light[2], light[3]]];
        assert_eq!(irradiance_with_blockers(&lp, p, Vec3::Y, fixture), free);
        // A plate bigger than the light's shadow pyramid at mid height: full umbra.
        let plate = quad(Vec3::new(-1.0, 1.0, -1.0), Vec3::new(1.0, 1.0, 1.0));
        assert_eq!(irradiance_with_blockers(&lp, p, Vec3::Y, plate), 0.0);
        // Behind the light, or facing away, or below the receiver plane: nothing.
        assert_eq!(irradiance_with_blockers(&lp, Vec3::new(0.0, 3.0, 0.0), Vec3::NEG_Y, []), 0.0);
        assert_eq!(irradiance_with_blockers(&lp, p, Vec3::NEG_Y, []), 0.0);
        // A blocker beside the pyramid, above the light or below the point: no effect.
        for far in [quad(Vec3::new(2.0, 1.0, -1.0), Vec3::new(3.0, 1.0, 1.0)), quad(Vec3::new(-1.0, 2.5, -1.0), Vec3::new(1.0, 2.5, 1.0)), quad(Vec3::new(-1.0, -0.5, -1.0), Vec3::new(1.0, -0.5, 1.0))] {
            assert!((irradiance_with_blockers(&lp, p, Vec3::Y, far) - free).abs() < 1e-12);
        }
    }

    /// A half-plane blocker's edge under the light's middle: the visible part is exactly the
    /// other half of the light (the shadow of a straight edge through the pyramid's axis),
    /// and a point's irradiance equals that of the half-light polygon by Lambert's formula.
    #[test]
    fn half_plane_blocker_leaves_exactly_half_the_light() {
        let light = ceiling(0.5, 2.0);
        let lp = LightPlane::new(&light).unwrap();
        let p = Vec3::new(0.0, 0.0, 0.0);
        // Blocker covering x < 0 at height 1: hides light x < 0 (the point is at x = 0).
        let plate = quad(Vec3::new(-5.0, 1.0, -5.0), Vec3::new(0.0, 1.0, 5.0));
        let mut vis = Visible::new(&lp, p, Vec3::Y).unwrap();
        for t in plate {
            vis.occlude(t.map(|x| x.as_dvec3()));
        }
        assert!((vis.area() - 0.5).abs() < 1e-9, "{}", vis.area());
        let half = [DVec3::new(0.0, 2.0, -0.5), DVec3::new(0.5, 2.0, -0.5), DVec3::new(0.5, 2.0, 0.5), DVec3::new(0.0, 2.0, 0.5)];
        let want = polygon_irradiance(DVec3::ZERO, DVec3::Y, &half);
        assert!((vis.irradiance() - want).abs() < 1e-12, "{} vs {want}", vis.irradiance());
    }

    /// Either side of a shadow boundary: points just outside the penumbra see the whole light
    /// (the irradiance of the unoccluded light), points just inside the umbra see none, and
    /// points in between see some; checked by rays to the light's corners too.
    #[test]
    fn whole_light_and_none_on_either_side_of_the_penumbra() {
        let light = ceiling(0.5, 2.0);
        let lp = LightPlane::new(&light).unwrap();
        // A plate over x ∈ [-3, 0] at height 1: umbra where x < -0.5, penumbra -0.5..0.5
        // on the floor (similar triangles: the light's x ∈ [-0.5, 0.5] through the edge x = 0).
        let plate = quad(Vec3::new(-3.0, 1.0, -3.0), Vec3::new(0.0, 1.0, 3.0));
        for (x, lit) in [(-0.52, Some(false)), (-0.3, None), (0.0, None), (0.3, None), (0.52, Some(true))] {
            let p = Vec3::new(x, 0.0, 0.0);
            let e = irradiance_with_blockers(&lp, p, Vec3::Y, plate);
            let free = irradiance_with_blockers(&lp, p, Vec3::Y, []);
            let corners_seen = light.iter().filter(|c| plate.iter().all(|t| ray_triangle(p, **c - p, t[0], t[1], t[2]).is_none())).count();
            match lit {
                Some(true) => assert!((e - free).abs() < 1e-12 && corners_seen == 4, "x {x}: {e} vs {free}"),
                Some(false) => assert!(e == 0.0 && corners_seen == 0, "x {x}: {e}"),
                None => assert!(e > 1e-6 && e < free - 1e-6, "x {x}: {e} in (0, {free})"),
            }
        }
    }

    /// A closed mesh as the blocker (a UV sphere: triangles sharing edges and corners, the
    /// common case in scenes): at points across its penumbra on the floor, the exact value
    /// equals Monte Carlo within its noise, and the visible area falls monotonically into the
    /// umbra as the point moves under the sphere.
    #[test]
    fn a_sphere_of_shared_edges_agrees_with_monte_carlo() {
        let (stacks, slices) = (8, 16);
        let at = |i: u32, j: u32| {
            let (th, ph) = (std::f32::consts::PI * i as f32 / stacks as f32, std::f32::consts::TAU * j as f32 / slices as f32);
            Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()) * 0.6 + Vec3::new(0.0, 1.0, 0.0)
        };
        let mut sphere = Vec::new();
        for i in 0..stacks {
            for j in 0..slices {
                let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
                sphere.push([a, b, d]);
                sphere.push([a, d, c]);
            }
        }
        let light = ceiling(0.5, 2.5);
        let lp = LightPlane::new(&light).unwrap();
        let mut r = Rng::new(3);
        let mut last = f64::INFINITY;
        for k in 0..8 {
            let p = Vec3::new(2.0 - 0.25 * k as f32, 0.0, 0.1);
            let mut vis = Visible::new(&lp, p, Vec3::Y).unwrap();
            for t in &sphere {
                vis.occlude(t.map(|x| x.as_dvec3()));
            }
            let (e, area) = (vis.irradiance(), vis.area());
            let (mc, se) = monte_carlo(&light, p, Vec3::Y, &sphere, 100_000, &mut r);
            assert!((e - mc).abs() <= 4.5 * se + 1e-6, "x {}: exact {e} vs Monte Carlo {mc} ± {se}", p.x);
            assert!(area <= last + 1e-12, "x {}: visible area {area} after {last}", p.x);
            last = area;
        }
        assert!(last < 1e-9, "the last point is in the umbra ({last})");
    }

    /// Random lights, points, normals and blocker triangles: the exact irradiance equals a
    /// many-ray Monte Carlo estimate within 4.5 standard errors (plus 1e-4 relative for the
    /// f32 rays), and the visible area never exceeds the light's.
    #[test]
    fn random_occluders_agree_with_monte_carlo() {
        let mut r = Rng::new(15);
        let mut partial = 0;
        for case in 0..24 {
            let mut v3 = |s: f64, c: DVec3| (c + DVec3::new(unit(&mut r) - 0.5, unit(&mut r) - 0.5, unit(&mut r) - 0.5) * s).as_vec3();
            // A light: a random convex pentagon-ish polygon in a tilted plane above.
            let centre = v3(1.0, DVec3::new(0.0, 3.0, 0.0));
            let tilt = v3(0.6, DVec3::ZERO);
            let nl = (Vec3::NEG_Y + tilt).normalize();
            let u = nl.any_orthonormal_vector();
            let w = nl.cross(u);
            let k = 3 + case % 4;
            let light: Vec<Vec3> = (0..k)
                .map(|i| {
                    let a = std::f32::consts::TAU * i as f32 / k as f32;
                    // Counter-clockwise about nl: u × w = nl.
                    centre + (u * a.cos() + w * a.sin()) * 0.8
                })
                .collect();
            let p = v3(1.0, DVec3::ZERO);
            let n = (Vec3::Y + v3(0.8, DVec3::ZERO)).normalize();
            let blockers: Vec<[Vec3; 3]> = (0..1 + case % 6)
                .map(|_| {
                    let c = v3(1.2, DVec3::new(0.0, 1.5, 0.0));
                    [v3(1.0, c.as_dvec3()), v3(1.0, c.as_dvec3()), v3(1.0, c.as_dvec3())]
                })
                .collect();
            let lp = LightPlane::new(&light).unwrap();
            let mut vis = Visible::new(&lp, p, n);
            if let Some(v) = vis.as_mut() {
                for t in &blockers {
                    v.occlude(t.map(|x| x.as_dvec3()));
                }
                assert!(v.area() <= lp.area() * (1.0 + 1e-9));
            }
            let exact = vis.as_ref().map_or(0.0, |v| v.irradiance());
            let free = irradiance_with_blockers(&lp, p, n, []);
            let (mc, se) = monte_carlo(&light, p, n, &blockers, 200_000, &mut r);
            assert!((exact - mc).abs() <= 4.5 * se + 1e-4 * free + 1e-9, "case {case}: exact {exact} vs Monte Carlo {mc} ± {se} (unoccluded {free})");
            partial += (exact > 0.02 * free && exact < 0.98 * free) as u32;
        }
        assert!(partial >= 6, "the random cases include penumbrae ({partial})");
    }

    /// A convex solid's shadow subtracted whole (the hull of its corners' shadows) leaves the
    /// visible part its triangles leave one by one: random boxes turned every way and UV
    /// spheres between random points and random lights, the irradiance within 10⁻¹² of the
    /// unoccluded light's and the area within 10⁻¹² of the light's; a solid reaching below the
    /// point's height, or too near it, is `NotBetween`.
    #[test]
    fn a_convex_solids_hull_shadow_equals_its_triangles_shadows() {
        let mut r = Rng::new(17);
        let (mut compared, mut partial, mut refused) = (0, 0, 0);
        for case in 0..400 {
            let c = DVec3::new(unit(&mut r) - 0.5, 0.7 + 1.2 * unit(&mut r), unit(&mut r) - 0.5);
            let rot = glam::DQuat::from_axis_angle(DVec3::new(unit(&mut r) - 0.5, unit(&mut r) - 0.5, unit(&mut r) - 0.5).normalize_or(DVec3::Y), 6.0 * unit(&mut r));
            let (corners, tris): (Vec<DVec3>, Vec<[usize; 3]>) = if case % 2 == 0 {
                let half = DVec3::new(0.05 + 0.3 * unit(&mut r), 0.05 + 0.3 * unit(&mut r), 0.05 + 0.3 * unit(&mut r));
                let v = (0..8).map(|i| c + rot * (half * DVec3::new(if i & 1 == 0 { -1.0 } else { 1.0 }, if i & 2 == 0 { -1.0 } else { 1.0 }, if i & 4 == 0 { -1.0 } else { 1.0 }))).collect();
                let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
                (v, quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect())
            } else {
                let (stacks, slices, rad) = (6, 10, 0.1 + 0.3 * unit(&mut r));
                let at = |i: usize, j: usize| {
                    let (th, ph) = (std::f64::consts::PI * i as f64 / stacks as f64, std::f64::consts::TAU * j as f64 / slices as f64);
                    c + rot * (DVec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin()) * rad)
                };
                let mut v = vec![at(0, 0)];
                for i in 1..stacks {
                    v.extend((0..slices).map(|j| at(i, j)));
                }
                v.push(at(stacks, 0));
                let id = |i: usize, j: usize| if i == 0 { 0 } else if i == stacks { v.len() - 1 } else { 1 + (i - 1) * slices + j % slices };
                let mut t = Vec::new();
                for i in 0..stacks {
                    for j in 0..slices {
                        let (a, b, c2, d) = (id(i, j), id(i, j + 1), id(i + 1, j), id(i + 1, j + 1));
                        if a != b {
                            t.push([a, b, d]);
                        }
                        if c2 != d {
                            t.push([a, d, c2]);
                        }
                    }
                }
                (v, t)
            };
            let y = 2.6 + unit(&mut r);
            let k = 3 + (unit(&mut r) * 3.0) as usize;
            let light: Vec<Vec3> = (0..k)
                .map(|i| {
                    let a = std::f64::consts::TAU * (i as f64 + 0.3 * unit(&mut r)) / k as f64;
                    Vec3::new((0.6 * a.cos()) as f32, y as f32, (0.6 * a.sin()) as f32)
                })
                .collect();
            let lp = LightPlane::new(&light).unwrap();
            let p = Vec3::new((1.6 * (unit(&mut r) - 0.5)) as f32, 0.0, (1.6 * (unit(&mut r) - 0.5)) as f32);
            let n = Vec3::new((0.4 * (unit(&mut r) - 0.5)) as f32, 1.0, (0.4 * (unit(&mut r) - 0.5)) as f32).normalize();
            let Some(mut each) = Visible::new(&lp, p, n) else { continue };
            let mut whole = each.clone();
            for t in &tris {
                each.occlude(t.map(|i| corners[i]));
            }
            let shadow = whole.convex_shadow(corners.iter().copied()).expect("between the point and the light");
            if let Some(s) = shadow {
                whole.subtract(&s);
            }
            let free = Visible::new(&lp, p, n).unwrap().irradiance();
            assert!((whole.irradiance() - each.irradiance()).abs() <= 1e-12 * free, "case {case}: whole {} vs each {}", whole.irradiance(), each.irradiance());
            assert!((whole.area() - each.area()).abs() <= 1e-12 * lp.area(), "case {case}: area whole {} vs each {}", whole.area(), each.area());
            compared += 1;
            partial += (each.irradiance() > 0.01 * free && each.irradiance() < 0.99 * free) as u32;
            // A corner within 1 % of the way from the point: refused.
            let low = corners.iter().copied().chain([DVec3::new(c.x, 0.005 * y, c.z)]);
            assert_eq!(whole.convex_shadow(low), Err(NotBetween));
            refused += 1;
        }
        assert!(compared > 300 && partial > 60 && refused == compared, "{compared} compared, {partial} in penumbra, {refused} refused");
    }
}
