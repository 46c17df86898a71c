//! Several lights simplified (paper 003, Drettakis, "Simplifying the Representation of
//! Radiance from Multiple Emitters": §4.1 extremal boundaries, §5.1–5.2 the L2 error of a
//! simplified representation by Gauss–Legendre quadrature, §6 several sources), applied to
//! the shadow edges the edge-and-point image draws.
//!
//! The shadow store already holds only the extremal boundaries of every light's shadows —
//! the maximal (penumbral) and minimal (umbral) boundary of each blocker's shadow from an
//! area light ([`super::umbra`]), the hard edge of a point light's — and no detail inside
//! the penumbra: that is paper 003's first pass. This module is its second: per shadow edge
//! of light `l`, whether the other lights wash it out. It takes a band on the receiver
//! across the edge, on each side as wide as `l`'s penumbra there (a small fraction of the
//! distance to the light for a point light, whose penumbra has no width), and estimates the
//! L2 error of reconstructing without the edge: `l`'s exact irradiance against its linear
//! interpolation from the band's two sides (without the edge the EPI blends the samples
//! on either side across it, as §5.2's simplified interpolant spans the light face),
//! relative to the mean total irradiance of all lights over the band. Both integrals are
//! Gauss–Legendre quadratures (§5.1), over each half of the band separately: the edge
//! splits the band, so each half is smooth in `l`'s irradiance and the rule integrates a
//! step or a kink at the edge exactly. The irradiance at the nodes is exact — Lambert's
//! formula over the backprojection ([`edgepoint_scene::backprojection`]) for an area light,
//! a shadow ray for a point or spot light — with every object of the scene as a blocker,
//! found through the receivers' face hierarchies.
//!
//! An edge whose error is below the tolerance can be left out of the EPI; the session
//! decides (`--simplify-tolerance`, 0: every edge, as before).
use super::face_bvh::{Face, FaceBvh};
use super::shadow::{daffine, ShadowStore};
use super::EdgeSegment;
use edgepoint_scene::backprojection::{LightPlane, Visible};
use edgepoint_scene::geometry::ray_triangle;
use edgepoint_scene::light::spot_falloff;
use edgepoint_scene::Light;
use glam::{Affine3A, DAffine3, DVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;

/// Quadrature points per dimension (and per half band): exact for polynomials of degree
/// 5 in each direction, 18 nodes and 6 side values per edge and light.
pub const ORDER: usize = 3;

/// A point light's band, on each side, as a fraction of the distance to the light: its
/// shadow edge is a step, whose error does not depend on the band's width; the width only
/// decides how much of the other lights' variation nearby is weighed in.
pub const POINT_BAND: f64 = 0.02;

/// `P_n(x)` and `P_n'(x)` by the three-term recurrence.
fn legendre(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    for k in 2..=n {
        let k = k as f64;
        let p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
        p0 = p1;
        p1 = p2;
    }
    if n == 0 {
        return (1.0, 0.0);
    }
    (p1, n as f64 * (x * p1 - p0) / (x * x - 1.0))
}

/// The n-point Gauss–Legendre rule on [−1, 1] as (node, weight): the roots of `P_n`, by
/// Newton's method from the Chebyshev guesses. Exact for polynomials of degree ≤ 2n − 1.
pub fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            for _ in 0..100 {
                let (p, dp) = legendre(n, x);
                let dx = p / dp;
                x -= dx;
                if dx.abs() <= 1e-16 {
                    break;
                }
            }
            let (_, dp) = legendre(n, x);
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// ∫ f over [lo, hi] by `rule`, for K integrands at once.
pub fn integrate<const K: usize>(rule: &[(f64, f64)], lo: f64, hi: f64, mut f: impl FnMut(f64) -> [f64; K]) -> [f64; K] {
    let (half, mid) = (0.5 * (hi - lo), 0.5 * (hi + lo));
    let mut sum = [0.0; K];
    for &(x, w) in rule {
        let v = f(mid + half * x);
        for k in 0..K {
            sum[k] += w * half * v[k];
        }
    }
    sum
}

/// The region of one edge's estimate: the parallelogram `a + s (b − a) + t h across`,
/// `s ∈ [0, 1]`, `t ∈ [−1, 1]`, in the receiver's tangent plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    pub a: DVec3,
    pub b: DVec3,
    /// The receiver's unit normal, on the side facing the edge's light.
    pub normal: DVec3,
    /// Unit, in the tangent plane, perpendicular to the edge.
    pub across: DVec3,
    pub half_width: f64,
}

impl Band {
    /// `None` for a zero-length edge, an edge along the normal or a width that is not
    /// positive and finite.
    pub fn new(a: DVec3, b: DVec3, normal: DVec3, half_width: f64) -> Option<Band> {
        let normal = normal.try_normalize()?;
        let across = normal.cross(b - a).try_normalize()?;
        (half_width > 0.0 && half_width.is_finite()).then_some(Band { a, b, normal, across, half_width })
    }

    pub fn point(&self, s: f64, t: f64) -> DVec3 {
        self.a + (self.b - self.a) * s + self.across * (t * self.half_width)
    }

    /// The parallelogram's four corners.
    pub fn corners(&self) -> [DVec3; 4] {
        [self.point(0.0, -1.0), self.point(1.0, -1.0), self.point(1.0, 1.0), self.point(0.0, 1.0)]
    }
}

/// Paper 003's estimate for an edge of light `light` over `band`: the RMS, over the band,
/// of `light`'s irradiance minus its linear interpolation across the band from the two
/// sides, over the band's mean total irradiance of all `lights`. `irradiance(k, x, n)` is
/// light k's irradiance at x (unit normal n). 0 where nothing differs (or no light at all
/// reaches the band and its sides), infinite where the sides are lit but the band is not.
pub fn washout_error(band: &Band, light: usize, lights: usize, rule: &[(f64, f64)], irradiance: impl FnMut(usize, DVec3, DVec3) -> f64) -> f64 {
    washout(band, light, lights, rule, None::<&mut fn(usize, DVec3, DVec3) -> f64>, irradiance)
}

/// Where an upper bound of the other lights' mean over the band (their irradiance with
/// nothing in the way) is at most this fraction of the edge's own light's mean, the other
/// lights are not evaluated: their mean lies between 0 and the bound, and taking half the
/// bound puts the estimate within half this fraction of the full one (relative). Such an
/// estimate is large anyway (a shadow with little other light: near the lone values
/// 0.38–0.58), far above useful tolerances.
pub const COMPARABLE: f64 = 0.1;

/// [`washout_error`], skipping the other lights where none is comparable ([`COMPARABLE`]):
/// `bound(k, x, n)` is an upper bound of light k's irradiance (the light with nothing in the
/// way), far cheaper than the exact value. Within `COMPARABLE / 2` (relative) of the full
/// estimate, and equal to it where the other lights are comparable. Where the own light's
/// deviation is 0 nothing else is evaluated (the estimate is 0 whatever the others give).
pub fn washout_error_bounded(
    band: &Band,
    light: usize,
    lights: usize,
    rule: &[(f64, f64)],
    irradiance: impl FnMut(usize, DVec3, DVec3) -> f64,
    bound: impl FnMut(usize, DVec3, DVec3) -> f64,
) -> f64 {
    washout(band, light, lights, rule, Some(&mut { bound }), irradiance)
}

fn washout<B: FnMut(usize, DVec3, DVec3) -> f64>(
    band: &Band,
    light: usize,
    lights: usize,
    rule: &[(f64, f64)],
    bound: Option<&mut B>,
    mut irradiance: impl FnMut(usize, DVec3, DVec3) -> f64,
) -> f64 {
    let n = band.normal;
    // ∫ f over the band by `rule` along the edge and on each half across it (the edge is at
    // t = 0: a step there is integrated exactly); `side(s)` is computed once per node s.
    fn halves<S: Copy>(rule: &[(f64, f64)], mut side: impl FnMut(f64) -> S, mut f: impl FnMut(f64, f64, S) -> [f64; 2]) -> [f64; 2] {
        integrate(rule, 0.0, 1.0, |s| {
            let v = side(s);
            let [a0, a1] = integrate(rule, -1.0, 0.0, |t| f(s, t, v));
            let [b0, b1] = integrate(rule, 0.0, 1.0, |t| f(s, t, v));
            [a0 + b0, a1 + b1]
        })
    }
    let irr = std::cell::RefCell::new(&mut irradiance);
    let e = |k: usize, x: DVec3| (irr.borrow_mut())(k, x, n);
    let [sq, own] = halves(
        rule,
        |s| (e(light, band.point(s, -1.0)), e(light, band.point(s, 1.0))),
        |s, t, (lo, hi)| {
            let v = e(light, band.point(s, t));
            let lin = lo + (hi - lo) * 0.5 * (t + 1.0);
            [(v - lin) * (v - lin), v]
        },
    );
    // The band's measure in (s, t) is 2.
    let rms = (sq / 2.0).max(0.0).sqrt();
    if rms == 0.0 {
        return 0.0;
    }
    let own_mean = own / 2.0;
    let others = |x: DVec3| (0..lights).filter(|j| *j != light).map(|j| e(j, x)).sum::<f64>();
    let full = || halves(rule, |_| (), |s, t, ()| [others(band.point(s, t)), 0.0])[0] / 2.0;
    let others_mean = match bound {
        Some(bound) if lights > 1 => {
            // The same rule over the bounds: the full estimate's mean of the others lies in
            // [0, b] (positive weights, pointwise 0 ≤ exact ≤ bound).
            let b = halves(rule, |_| (), |s, t, ()| {
                let x = band.point(s, t);
                [(0..lights).filter(|j| *j != light).map(|j| bound(j, x, n)).sum(), 0.0]
            })[0] / 2.0;
            if b <= COMPARABLE * own_mean {
                0.5 * b
            } else {
                full()
            }
        }
        _ => full(),
    };
    let mean_total = own_mean + others_mean;
    if mean_total > 0.0 {
        rms / mean_total
    } else {
        f64::INFINITY
    }
}

/// The quadrature rule of the estimate: [`ORDER`] points on each half band.
#[derive(Debug, Clone, Default)]
pub struct Rules {
    pub full: Vec<(f64, f64)>,
}

impl Rules {
    pub fn new() -> Rules {
        Rules { full: gauss_legendre(ORDER) }
    }
}

/// How the estimate is made: both on in sessions; off to compare.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Estimate {
    /// Skip lights that cannot reach the band ([`reach`]: the same estimate).
    pub cull: bool,
    /// Other lights that are not comparable bounded, not evaluated ([`washout_error_bounded`]).
    pub bounded: bool,
}

impl Estimate {
    pub const FAST: Estimate = Estimate { cull: true, bounded: true };
    pub const FULL: Estimate = Estimate { cull: false, bounded: false };
}

impl Default for Estimate {
    fn default() -> Estimate {
        Estimate::FAST
    }
}

/// Rec. 709 luminance: the lights' RGB weighed into one irradiance.
fn luminance(c: Vec3) -> f64 {
    (0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z) as f64
}

/// Whether the box may meet the convex region on the inner side of every plane (normal,
/// a point of it).
fn box_meets(planes: &[(DVec3, DVec3)], lo: Vec3, hi: Vec3) -> bool {
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    planes.iter().all(|(m, p)| {
        let far = DVec3::select(m.cmpgt(DVec3::ZERO), hi, lo);
        m.dot(far - *p) >= 0.0
    })
}

/// Whether segment p → q meets the box (slab test).
fn segment_meets(p: DVec3, q: DVec3, lo: Vec3, hi: Vec3) -> bool {
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    let d = q - p;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for k in 0..3 {
        if d[k].abs() < 1e-300 {
            if p[k] < lo[k] || p[k] > hi[k] {
                return false;
            }
            continue;
        }
        let (a, b) = ((lo[k] - p[k]) / d[k], (hi[k] - p[k]) / d[k]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
        if t0 > t1 {
            return false;
        }
    }
    true
}

/// The width of the penumbra of a light of `diameter` centred at `c` at receiver point `m`
/// (normal `n`) across an edge cast by the blocker segment `s0`–`s1`: the diameter seen
/// through the blocker point nearest `m`, D |m − s| / |s − c|, stretched by the receiver's
/// slant (1 / cos, at most 4×); 0 where the blocker touches the receiver (contact
/// hardening, paper 000 §6). Shared by the renderer's own shadow edges
/// ([`SceneLights::penumbra_width`]) and the discontinuity mesh's ([`super::mesh_edges`]).
pub fn penumbra_width_of(diameter: f64, c: DVec3, m: DVec3, n: DVec3, s0: DVec3, s1: DVec3) -> f64 {
    let dist = (m - c).length();
    let d = s1 - s0;
    let u = if d.length_squared() > 0.0 { ((m - s0).dot(d) / d.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    let s = s0 + d * u;
    let penumbra = diameter * (m - s).length() / (s - c).length().max(1e-12);
    let slant = (n.dot(c - m) / dist.max(1e-12)).abs().max(0.25);
    penumbra / slant
}

/// The scene as the estimate needs it: its lights, and every object's faces (object space,
/// in its face hierarchy) at its current transform.
pub struct SceneLights<'a> {
    lights: &'a [Light],
    planes: Vec<Option<LightPlane>>,
    weights: Vec<f64>,
    bvhs: &'a [FaceBvh],
    to_world: Vec<DAffine3>,
    to_object: Vec<DAffine3>,
    /// Closed, consistently oriented meshes block through their exit faces alone (the same
    /// irradiance with half the faces); off only to compare.
    pub exit_faces: bool,
}

impl<'a> SceneLights<'a> {
    pub fn new(lights: &'a [Light], bvhs: &'a [FaceBvh], transforms: &[Affine3A]) -> SceneLights<'a> {
        let to_world: Vec<DAffine3> = (0..bvhs.len()).map(|o| daffine(transforms.get(o).unwrap_or(&Affine3A::IDENTITY))).collect();
        SceneLights {
            lights,
            planes: lights.iter().map(|l| if let Light::Area { vertices, .. } = l { LightPlane::new(vertices) } else { None }).collect(),
            weights: lights
                .iter()
                .map(|l| match l {
                    Light::Area { radiance, .. } => luminance(*radiance),
                    Light::Point { intensity, .. } | Light::Spot { intensity, .. } => luminance(*intensity),
                })
                .collect(),
            to_object: to_world.iter().map(|t| t.inverse()).collect(),
            to_world,
            bvhs,
            exit_faces: true,
        }
    }

    pub fn lights(&self) -> usize {
        self.lights.len()
    }

    /// Irradiance (luminance) at `x`, unit normal `n`, from light `k`, exact: every object
    /// blocks.
    pub fn irradiance(&self, k: usize, x: DVec3, n: DVec3) -> f64 {
        match &self.lights[k] {
            Light::Area { .. } => {
                let Some(plane) = &self.planes[k] else { return 0.0 };
                let Some(mut vis) = Visible::new(plane, x.as_vec3(), n.as_vec3()) else { return 0.0 };
                let (apex, base) = vis.pyramid();
                let (apex, base) = (apex, base.to_vec());
                for o in 0..self.bvhs.len() {
                    let (w, to) = (&self.to_world[o], &self.to_object[o]);
                    let p = to.transform_point3(apex);
                    let planes = pyramid_planes(p, &base.iter().map(|b| to.transform_point3(*b)).collect::<Vec<_>>());
                    // Only the faces that have the point behind their plane, where the
                    // mesh allows it ([`FaceBvh::oriented`], the light outside its box).
                    let exits = self.exit_faces && self.bvhs[o].oriented && self.light_outside(k, o);
                    let go = self.bvhs[o].visit(
                        |lo, hi| box_meets(&planes, lo, hi),
                        |f: &Face| {
                            if exits {
                                let [a, b, c] = f.v.map(|v| v.as_dvec3());
                                if (b - a).cross(c - a).dot(p - a) >= 0.0 {
                                    return true;
                                }
                            }
                            vis.occlude(f.v.map(|v| w.transform_point3(v.as_dvec3())));
                            !vis.is_empty()
                        },
                    );
                    if !go {
                        return 0.0;
                    }
                }
                vis.irradiance() * self.weights[k]
            }
            Light::Point { .. } | Light::Spot { .. } => self.point_light(k, x, n, true),
        }
    }

    /// Whether light `k` lies wholly outside object `o`'s box (then outside the object):
    /// all its points beyond one side of the box, in the object's space.
    fn light_outside(&self, k: usize, o: usize) -> bool {
        let Some(root) = &self.bvhs[o].root else { return true };
        let (lo, hi) = (DVec3::from(root.lo.map(f64::from)), DVec3::from(root.hi.map(f64::from)));
        let pts: Vec<DVec3> = self.light_points(k).iter().map(|x| self.to_object[o].transform_point3(*x)).collect();
        (0..3).any(|i| pts.iter().all(|x| x[i] < lo[i]) || pts.iter().all(|x| x[i] > hi[i]))
    }

    /// Light `k`'s irradiance at `x` (unit normal `n`) with nothing in the way: an upper
    /// bound of [`Self::irradiance`], by Lambert's formula or the point light's law alone.
    pub fn unoccluded(&self, k: usize, x: DVec3, n: DVec3) -> f64 {
        match &self.lights[k] {
            Light::Area { .. } => {
                let Some(plane) = &self.planes[k] else { return 0.0 };
                Visible::new(plane, x.as_vec3(), n.as_vec3()).map_or(0.0, |v| v.irradiance() * self.weights[k])
            }
            Light::Point { .. } | Light::Spot { .. } => self.point_light(k, x, n, false),
        }
    }

    /// A point or spot light's irradiance at `x`, through the shadow ray when `shadowed`.
    fn point_light(&self, k: usize, x: DVec3, n: DVec3, shadowed: bool) -> f64 {
        let (Light::Point { position, .. } | Light::Spot { position, .. }) = &self.lights[k] else { return 0.0 };
        let to_light = position.as_dvec3() - x;
        let r2 = to_light.length_squared();
        let cos = n.dot(to_light) / r2.sqrt();
        if cos.is_nan() || cos <= 0.0 || (shadowed && !self.sees(x, position.as_dvec3())) {
            return 0.0;
        }
        let cone = match &self.lights[k] {
            Light::Spot { direction, cos_inner, cos_outer, .. } => spot_falloff(*direction, *cos_inner, *cos_outer, (-to_light / r2.sqrt()).as_vec3()) as f64,
            _ => 1.0,
        };
        self.weights[k] * cone * cos / r2
    }

    /// Whether nothing lies on the segment from `x` to `light` (a shadow ray; hits within
    /// 10⁻⁴ of either end do not count, as for the workers' shadow rays).
    fn sees(&self, x: DVec3, light: DVec3) -> bool {
        (0..self.bvhs.len()).all(|o| {
            let to = &self.to_object[o];
            let (p, q) = (to.transform_point3(x), to.transform_point3(light));
            let (po, d) = (p.as_vec3(), (q - p).as_vec3());
            self.bvhs[o].visit(
                |lo, hi| segment_meets(p, q, lo, hi),
                |f: &Face| !ray_triangle(po, d, f.v[0], f.v[1], f.v[2]).is_some_and(|t| t > 1e-4 && t < 1.0 - 1e-4),
            )
        })
    }

    /// The unit normal (world space) of the face of `object` nearest `p`, when one lies
    /// within 10⁻⁴ of the object's size (a shadow edge lies on its receiver's faces).
    pub fn receiver_normal(&self, object: u32, p: DVec3) -> Option<DVec3> {
        let o = object as usize;
        let bvh = self.bvhs.get(o)?;
        let root = bvh.root.as_ref()?;
        let size = (Vec3::from(root.hi) - Vec3::from(root.lo)).length() as f64;
        let r = 1e-4 * size.max(1e-9);
        let q = self.to_object[o].transform_point3(p);
        let mut best: Option<(f64, Vec3)> = None;
        bvh.visit(
            |lo, hi| (lo.as_dvec3() - r).cmple(q).all() && q.cmple(hi.as_dvec3() + r).all(),
            |f: &Face| {
                if f.n != Vec3::ZERO {
                    let c = edgepoint_scene::geometry::closest_on_triangle(q.as_vec3(), f.v[0], f.v[1], f.v[2]);
                    let d = (c.as_dvec3() - q).length();
                    if d <= r && best.is_none_or(|(e, _)| d < e) {
                        best = Some((d, f.n));
                    }
                }
                true
            },
        );
        // Normals go to world space by the inverse transpose of the object's matrix.
        best.and_then(|(_, n)| (self.to_object[o].matrix3.transpose() * n.as_dvec3()).try_normalize())
    }

    /// Half the band across an edge at `m` (receiver normal `n`) of light `k` cast by the
    /// blocker segment `s0`–`s1` (one point for an EV event): the width of the penumbra
    /// there ([`Self::penumbra_width`]), and at least [`POINT_BAND`] of the distance to the
    /// light.
    pub fn half_width(&self, k: usize, m: DVec3, n: DVec3, s0: DVec3, s1: DVec3) -> f64 {
        let dist = (m - self.lights[k].center().as_dvec3()).length();
        self.penumbra_width(k, m, n, s0, s1).max(POINT_BAND * dist)
    }

    /// The width of light `k`'s penumbra at `m` (receiver normal `n`) across an edge cast by
    /// the blocker segment `s0`–`s1`: the light's diameter seen through the blocker point
    /// nearest `m`, D |m − s| / |s − c|, stretched by the receiver's slant (1 / cos, at most
    /// 4×); 0 for a point light, and falling to 0 where the blocker touches the receiver
    /// (contact hardening, paper 000 §6).
    pub fn penumbra_width(&self, k: usize, m: DVec3, n: DVec3, s0: DVec3, s1: DVec3) -> f64 {
        let light = &self.lights[k];
        let diameter = match light {
            Light::Area { vertices, .. } => vertices
                .iter()
                .flat_map(|a| vertices.iter().map(move |b| (*a - *b).length() as f64))
                .fold(0.0, f64::max),
            _ => 0.0,
        };
        penumbra_width_of(diameter, light.center().as_dvec3(), m, n, s0, s1)
    }

    /// The penumbra across shadow edge `e` of light `k` (blocker points `s0`–`s1`) at its
    /// two ends, as world vectors in the receiver's tangent plane perpendicular to the edge,
    /// [`Self::penumbra_width`] long: what the EPI projects each frame to decide where the
    /// edge is a barrier ([`crate::epi::soft`]). Zero (a barrier everywhere) for a hard
    /// edge, and where no receiver face is found under the edge or it has no length.
    pub fn penumbra(&self, e: &EdgeSegment, k: usize, s0: DVec3, s1: DVec3) -> [Vec3; 2] {
        if !matches!(e.kind, super::EdgeKind::ShadowUmbral | super::EdgeKind::ShadowPenumbral) || k >= self.lights.len() {
            return [Vec3::ZERO; 2];
        }
        let (a, b) = (e.a.as_dvec3(), e.b.as_dvec3());
        let Some(n) = self.receiver_normal(e.object, 0.5 * (a + b)) else { return [Vec3::ZERO; 2] };
        let Some(across) = n.cross(b - a).try_normalize() else { return [Vec3::ZERO; 2] };
        [a, b].map(|p| (across * self.penumbra_width(k, p, n, s0, s1)).as_vec3())
    }

    /// The estimate for shadow edge `e` of light `k` cast by blocker points `s0`–`s1` (a
    /// [`Job`]); `None` when no receiver face is found under it, it has no length or its
    /// light is not in the scene. See [`Self::band_error`] for `how`.
    pub fn edge_error(&self, (e, k, s0, s1): &Job, rules: &Rules, how: Estimate, culls: &mut Culls) -> Option<f64> {
        let k = *k as usize;
        if k >= self.lights.len() {
            return None;
        }
        let band = self.edge_band(e, k, *s0, *s1)?;
        Some(self.band_error(&band, k, rules, how, culls))
    }

    /// [`Self::edge_error`] with the band it was made over (infinite with none where none
    /// can be made).
    pub fn edge_estimate(&self, (e, k, s0, s1): &Job, rules: &Rules, how: Estimate, culls: &mut Culls) -> Estimated {
        let k = *k as usize;
        match (k < self.lights.len()).then(|| self.edge_band(e, k, *s0, *s1)).flatten() {
            Some(band) => Estimated { error: self.band_error(&band, k, rules, how, culls), band: Some(band) },
            None => Estimated { error: f64::INFINITY, band: None },
        }
    }

    /// Whether estimate `e` is still the estimate after objects moved within `boxes` (world
    /// boxes, before and after each move): every point of its band sees every light through
    /// the convex hull of the band and the light, and where no box meets any of those hulls
    /// no light's irradiance at any of the band's nodes changed — the same estimate, bit for
    /// bit, as the face walks and shadow rays meet the same faces. The boxes are grown by
    /// more than the f32 rounding of the nodes. One with no band is made again.
    pub fn still_holds(&self, e: &Estimated, boxes: &[(DVec3, DVec3)]) -> bool {
        let Some(band) = &e.band else { return false };
        if boxes.is_empty() {
            return true;
        }
        let corners = band.corners();
        (0..self.lights.len()).all(|k| {
            let light = self.light_points(k);
            let size = corners.iter().chain(&light).map(|p| p.abs().max_element()).fold(1.0, f64::max);
            let margin = 1e-5 * size;
            let shaft = crate::dmesh::receiver::Shaft::new(&light, &corners, margin);
            boxes.iter().all(|(lo, hi)| !shaft.may_meet_box((*lo - margin, *hi + margin), margin))
        })
    }

    /// The band of shadow edge `e` of light `k` (see [`Self::edge_error`]).
    pub fn edge_band(&self, e: &EdgeSegment, k: usize, s0: DVec3, s1: DVec3) -> Option<Band> {
        let (a, b) = (e.a.as_dvec3(), e.b.as_dvec3());
        let m = 0.5 * (a + b);
        let mut n = self.receiver_normal(e.object, m)?;
        // The receiver's side the edge's light shines on.
        if n.dot(self.lights[k].center().as_dvec3() - m) < 0.0 {
            n = -n;
        }
        Band::new(a, b, n, self.half_width(k, m, n, s0, s1))
    }

    /// [`washout_error`] of light `k` over `band` with exact irradiance. With `how.cull`, a
    /// light that [`Self::reaches`] says lights none of the band counts as 0 without
    /// evaluating it (the same estimate); with `how.bounded`, [`washout_error_bounded`].
    pub fn band_error(&self, band: &Band, k: usize, rules: &Rules, how: Estimate, culls: &mut Culls) -> f64 {
        let reach: Vec<bool> = (0..self.lights.len()).map(|j| !how.cull || self.reaches(j, band, culls)).collect();
        let e = |j: usize, x: DVec3, n: DVec3| if reach[j] { self.irradiance(j, x, n) } else { 0.0 };
        if how.bounded {
            let b = |j: usize, x: DVec3, n: DVec3| if reach[j] { self.unoccluded(j, x, n) } else { 0.0 };
            washout_error_bounded(band, k, self.lights.len(), &rules.full, e, b)
        } else {
            washout_error(band, k, self.lights.len(), &rules.full, e)
        }
    }
}

/// The inward planes (normal, point) of the pyramid from `apex` over the convex `base`, and
/// the base's own plane.
fn pyramid_planes(apex: DVec3, base: &[DVec3]) -> Vec<(DVec3, DVec3)> {
    let k = base.len();
    let inside = (apex + base.iter().copied().sum::<DVec3>() / k.max(1) as f64) * 0.5;
    let mut out: Vec<(DVec3, DVec3)> = (0..k)
        .map(|i| {
            let m = (base[i] - apex).cross(base[(i + 1) % k] - apex);
            (if m.dot(inside - apex) >= 0.0 { m } else { -m }, apex)
        })
        .collect();
    if k >= 3 {
        let m = (base[1] - base[0]).cross(base[2] - base[0]);
        out.push((if m.dot(inside - base[0]) >= 0.0 { m } else { -m }, base[0]));
    }
    out
}

type EdgeKey = (u32, u32, u8, [u32; 6]);

/// One shadow edge to estimate: the edge, its light, and its blocker's points (world).
pub type Job = (EdgeSegment, u32, DVec3, DVec3);

/// Every shadow edge of `store` as a [`Job`], in the store's order.
pub fn jobs(store: &ShadowStore, transforms: &[Affine3A]) -> Vec<Job> {
    let mut out = Vec::new();
    for ((l, b), ev, segs) in store.events_with_edges() {
        let tb = daffine(transforms.get(b as usize).unwrap_or(&Affine3A::IDENTITY));
        let (s0, s1) = (tb.transform_point3(ev.s[0].as_dvec3()), tb.transform_point3(ev.s[1].as_dvec3()));
        out.extend(segs.iter().map(|e| (*e, l, s0, s1)));
    }
    out
}

/// [`SceneLights::penumbra`] of every job, on the rayon pool (a receiver-face query each).
pub fn penumbrae(scene: &SceneLights, jobs: &[Job]) -> Vec<[Vec3; 2]> {
    jobs.par_iter().map(|(e, k, s0, s1)| scene.penumbra(e, *k as usize, *s0, *s1)).collect()
}

/// The estimates of `jobs` on the rayon pool (infinite where none can be made), with
/// what the culls skipped.
pub fn estimate(scene: &SceneLights, jobs: &[Job], rules: &Rules, how: Estimate) -> (Vec<f64>, Culls) {
    let (out, culls) = estimate_over_bands(scene, jobs, rules, how);
    (out.into_iter().map(|e| e.error).collect(), culls)
}

/// [`estimate`], each with the band it was made over (to carry it across a move,
/// [`SceneLights::still_holds`]).
pub fn estimate_over_bands(scene: &SceneLights, jobs: &[Job], rules: &Rules, how: Estimate) -> (Vec<Estimated>, Culls) {
    let out: Vec<(Estimated, Culls)> = jobs
        .par_iter()
        .map(|job| {
            let mut c = Culls::default();
            (scene.edge_estimate(job, rules, how, &mut c), c)
        })
        .collect();
    let mut culls = Culls::default();
    out.iter().for_each(|(_, c)| culls.add(c));
    (out.into_iter().map(|(e, _)| e).collect(), culls)
}

/// An edge's estimate with the band it was made over: whether a move leaves it as it was
/// is a question about the band alone ([`SceneLights::still_holds`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimated {
    pub error: f64,
    /// `None` where no estimate could be made (the error is infinite).
    pub band: Option<Band>,
}

/// The world boxes, before and after, of every object whose transform differs between
/// `before` and `after` (object-space boxes from the face hierarchies' roots), for
/// [`SceneLights::still_holds`].
pub fn moved_boxes(bvhs: &[FaceBvh], before: &[Affine3A], after: &[Affine3A]) -> Vec<(DVec3, DVec3)> {
    let at = |t: &[Affine3A], o: usize| *t.get(o).unwrap_or(&Affine3A::IDENTITY);
    (0..bvhs.len())
        .filter(|o| at(before, *o) != at(after, *o))
        .filter_map(|o| bvhs[o].root.map(|r| (o, (Vec3::from(r.lo), Vec3::from(r.hi)))))
        .flat_map(|(o, b)| [at(before, o), at(after, o)].map(|t| {
            let (lo, hi) = super::finder::world_box(&t, b);
            (lo.as_dvec3(), hi.as_dvec3())
        }))
        .collect()
}

fn key(light: u32, e: &EdgeSegment) -> EdgeKey {
    let [a, b] = [e.a, e.b].map(|p| p.to_array().map(f32::to_bits));
    (light, e.object, e.kind as u8, [a[0], a[1], a[2], b[0], b[1], b[2]])
}

/// The estimate of every stored shadow edge, kept from update to update: an edge already
/// estimated under the same lights is not estimated again, and after a move only if the
/// moved objects can reach its band ([`SceneLights::still_holds`]; other lights: all made
/// again).
#[derive(Default)]
pub struct EdgeErrors {
    /// How the estimates are made ([`Estimate::FAST`] by default; others only to compare).
    pub how: Estimate,
    /// What the culls skipped, summed over every estimate made.
    pub culls: Culls,
    /// Estimates kept across moves, and dropped because a move reached their band.
    pub carried: usize,
    pub dropped: usize,
    lights: Vec<Light>,
    transforms: Vec<Affine3A>,
    known: HashMap<EdgeKey, Estimated>,
    rules: Rules,
}

impl EdgeErrors {
    pub fn new() -> EdgeErrors {
        EdgeErrors { rules: Rules::new(), ..Default::default() }
    }

    /// Brings the known estimates to `lights` and `transforms`: other lights forget them
    /// all; moved objects forget those whose band they can reach.
    fn sync(&mut self, lights: &[Light], bvhs: &[FaceBvh], transforms: &[Affine3A]) {
        if self.lights != lights {
            self.known.clear();
            self.lights = lights.to_vec();
        } else if self.transforms != transforms {
            let boxes = moved_boxes(bvhs, &self.transforms, transforms);
            let scene = SceneLights::new(lights, bvhs, transforms);
            let before = self.known.len();
            self.known.retain(|_, e| scene.still_holds(e, &boxes));
            self.carried += self.known.len();
            self.dropped += before - self.known.len();
        }
        self.transforms = transforms.to_vec();
    }

    /// Every shadow edge of `store` with its error as far as known — kept across moves — and
    /// NaN where not estimated yet, estimating nothing (in the store's order).
    pub fn known(&mut self, store: &ShadowStore, lights: &[Light], bvhs: &[FaceBvh], transforms: &[Affine3A]) -> Vec<(EdgeSegment, f64)> {
        self.sync(lights, bvhs, transforms);
        jobs(store, transforms).into_iter().map(|(e, l, _, _)| (e, self.known.get(&key(l, &e)).map_or(f64::NAN, |x| x.error))).collect()
    }

    /// Every shadow edge of `store` with its error (infinite where none can be estimated:
    /// such an edge always stays), in the store's order, and how many were estimated now.
    pub fn update(&mut self, store: &ShadowStore, lights: &[Light], bvhs: &[FaceBvh], transforms: &[Affine3A]) -> (Vec<(EdgeSegment, f64)>, usize) {
        self.sync(lights, bvhs, transforms);
        let scene = SceneLights::new(lights, bvhs, transforms);
        let all = jobs(store, transforms);
        let todo: Vec<Job> = all.iter().filter(|(e, l, _, _)| !self.known.contains_key(&key(*l, e))).copied().collect();
        let (errs, culls) = estimate_over_bands(&scene, &todo, &self.rules, self.how);
        self.culls.add(&culls);
        let fresh: Vec<(EdgeKey, Estimated)> = todo.iter().zip(errs).map(|((e, l, _, _), err)| (key(*l, e), err)).collect();
        let estimated = fresh.len();
        self.known.extend(fresh);
        // Edges no longer stored are forgotten.
        if self.known.len() > all.len() {
            let live: std::collections::HashSet<EdgeKey> = all.iter().map(|(e, l, _, _)| key(*l, e)).collect();
            self.known.retain(|k, _| live.contains(k));
        }
        let out = all.into_iter().map(|(e, l, _, _)| (e, self.known.get(&key(l, &e)).map_or(f64::INFINITY, |x| x.error))).collect();
        (out, estimated)
    }
}

mod reach;
pub use reach::{convex_hull, Culls};

#[cfg(test)]
mod tests;
