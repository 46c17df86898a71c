use super::*;
use crate::edges::face_bvh::FaceBvh;
use crate::edges::simplify::SceneLights;
use crate::edges::EdgeKind;
use edgepoint_scene::builtin::shapes::polygon;
use edgepoint_scene::{Camera, Light, NoProgress};
use glam::{Affine3A, DVec3};

/// A square area light of half side `A` at height `H` over the origin, facing down; the
/// floor y = 0 (object 0) as the receiver.
const A: f64 = 0.25;
const H: f64 = 2.0;

fn floor() -> Vec<FaceBvh> {
    let l = 10.0;
    vec![FaceBvh::build(&polygon(&[Vec3::new(-l, 0.0, -l), Vec3::new(-l, 0.0, l), Vec3::new(l, 0.0, l), Vec3::new(l, 0.0, -l)]), &NoProgress)]
}

fn light() -> Vec<Light> {
    let a = A as f32;
    let c = Vec3::new(0.0, H as f32, 0.0);
    let vertices = [(-a, -a), (a, -a), (a, a), (-a, a)].iter().map(|&(x, z)| c + Vec3::new(x, 0.0, z)).collect();
    vec![Light::Area { vertices, radiance: Vec3::ONE }]
}

/// The closed form of the penumbra's width on the floor at `m` across an edge cast by the
/// blocker point `s`: the light's diameter 2√2 A seen through `s`, D |m − s| / |s − c|, over
/// the cosine at `m` toward the light's centre c (a vertical normal).
fn closed_width(m: DVec3, s: DVec3) -> f64 {
    let c = DVec3::new(0.0, H, 0.0);
    let d = 2.0 * std::f64::consts::SQRT_2 * A;
    d * (m - s).length() / (s - c).length() / (H / (c - m).length())
}

/// Looking straight down at the floor from height `z` (the image plane parallel to it): a
/// floor length L shows as L f / z pixels, f = (height / 2) / tan(fov / 2).
fn looking_down(z: f32) -> (SegmentProjector, f64) {
    let (w, h) = (640, 480);
    let cam = Camera { eye: Vec3::new(0.0, z, 0.0), target: Vec3::ZERO, up: Vec3::Z, fov_y_degrees: 50.0 };
    let f = 0.5 * h as f64 / (25.0f64).to_radians().tan();
    (SegmentProjector::new(&cam.frame(w, h), w as usize, h as usize), f / z as f64)
}

fn edge(a: DVec3, b: DVec3, kind: EdgeKind) -> EdgeSegment {
    EdgeSegment { a: a.as_vec3(), b: b.as_vec3(), kind, object: 0 }
}

/// A blocker edge parallel to the floor at height `h` straight over the shadow edge from
/// (−0.3, 0, 0.4) to (0.3, 0, 0.4): the penumbra's width against its closed form at both
/// ends, then narrow (below 2 px: a barrier, whole) seen from close by a short blocker,
/// wide (not a barrier) from a tall one, and narrow again from far enough.
#[test]
fn a_wide_penumbra_is_not_a_barrier_and_a_narrow_one_is() {
    let (bvhs, lights) = (floor(), light());
    let scene = SceneLights::new(&lights, &bvhs, &[Affine3A::IDENTITY]);
    let (a, b) = (DVec3::new(-0.3, 0.0, 0.4), DVec3::new(0.3, 0.0, 0.4));
    let widths = |h: f64| {
        let (s0, s1) = (a + DVec3::Y * h, b + DVec3::Y * h);
        let e = edge(a, b, EdgeKind::ShadowUmbral);
        let p = scene.penumbra(&e, 0, s0, s1);
        for (end, s, v) in [(a, s0, p[0]), (b, s1, p[1])] {
            let want = closed_width(end, s);
            assert!((v.length() as f64 - want).abs() <= 1e-4 * want, "{} vs {want}", v.length());
            assert!(v.y.abs() as f64 <= 1e-6 * want && v.x.abs() as f64 <= 1e-6 * want, "across the edge in the floor: {v}");
        }
        (e, p, closed_width(a, s0).max(closed_width(b, s1)), closed_width(a, s0).min(closed_width(b, s1)))
    };
    let (prj, px) = looking_down(3.0);
    // Heights giving 1 px and 5 px at the wider end.
    for (target, barrier) in [(1.0, true), (5.0, false)] {
        let h = bisect(|h| widths(h).2 * px - target, 0.01, 1.5);
        let (e, p, wide, narrow) = widths(h);
        assert!((wide * px - target).abs() < 1e-6 && narrow * px > 0.9 * target);
        let got = barrier_part(&e, &p, &prj, NARROW_PIXELS);
        assert_eq!(got, barrier.then_some(e), "{target} px");
        // Either kind of soft edge alike.
        let pen = EdgeSegment { kind: EdgeKind::ShadowPenumbral, ..e };
        assert_eq!(barrier_part(&pen, &p, &prj, NARROW_PIXELS).is_some(), barrier);
        if !barrier {
            // 5 px from 3 m is below 2 px from 9 m (the width shrinks as 1 / z).
            let (far, far_px) = looking_down(9.0);
            assert!(wide * far_px < NARROW_PIXELS);
            assert_eq!(barrier_part(&e, &p, &far, NARROW_PIXELS), Some(e));
        }
    }
}

fn bisect(f: impl Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    assert!(f(lo) < 0.0 && f(hi) > 0.0);
    for _ in 0..200 {
        let m = 0.5 * (lo + hi);
        if f(m) < 0.0 {
            lo = m;
        } else {
            hi = m;
        }
    }
    0.5 * (lo + hi)
}

/// Contact hardening: a blocker edge rising from the floor at the shadow edge's start, its
/// penumbra growing from 0. The barrier is the part from the contact to about where the
/// closed form's projected width reaches 2 px (found by bisection): never beyond it, and
/// ending where the closed form is at least 1.5 px (the cut takes the width as linear
/// along the edge between its ends; it grows faster, the blocker rising toward the light,
/// so the cut comes early).
#[test]
fn near_a_contact_only_the_narrow_part_is_a_barrier() {
    let (bvhs, lights) = (floor(), light());
    let scene = SceneLights::new(&lights, &bvhs, &[Affine3A::IDENTITY]);
    let (prj, px) = looking_down(3.0);
    for (rise, z) in [(0.3, 0.4), (0.6, 0.4), (0.4, -0.7)] {
        let (a, b) = (DVec3::new(-0.3, 0.0, z), DVec3::new(0.3, 0.0, z));
        let (s0, s1) = (a, b + DVec3::Y * rise);
        for (e, from_a) in [(edge(a, b, EdgeKind::ShadowPenumbral), true), (edge(b, a, EdgeKind::ShadowUmbral), false)] {
            let (p0, p1) = if from_a { (s0, s1) } else { (s1, s0) };
            let p = scene.penumbra(&e, 0, p0, p1);
            // The closed form along the edge from the contact, the blocker's nearest point.
            let at = |t: f64| {
                let m = a + (b - a) * t;
                let d = s1 - s0;
                let s = s0 + d * ((m - s0).dot(d) / d.length_squared()).clamp(0.0, 1.0);
                closed_width(m, s) * px - NARROW_PIXELS
            };
            let want = bisect(at, 0.0, 1.0);
            let got = barrier_part(&e, &p, &prj, NARROW_PIXELS).expect("the contact's end is narrow");
            let contact = if from_a { got.a } else { got.b };
            let cut = if from_a { got.b } else { got.a };
            assert!((contact.as_dvec3() - a).length() < 1e-6, "the barrier starts at the contact");
            let t = (cut.as_dvec3().x - a.x) / (b.x - a.x);
            let at_cut = at(t) + NARROW_PIXELS;
            assert!(t <= want + 1e-4 && at_cut >= 1.5, "rise {rise}: cut at {t} ({at_cut} px), closed form {want}");
            assert!(want > 0.05 && want < 0.95, "the cut is inside the edge: {want}");
        }
    }
}

/// Hard shadow edges (a point light's) and geometric edges are barriers whole, whatever the
/// view; without a projection every shadow edge goes whole.
#[test]
fn hard_and_geometric_edges_stay_whole() {
    let (bvhs, lights) = (floor(), light());
    let scene = SceneLights::new(&lights, &bvhs, &[Affine3A::IDENTITY]);
    let (prj, _) = looking_down(3.0);
    let (a, b) = (DVec3::new(-0.3, 0.0, 0.4), DVec3::new(0.3, 0.0, 0.4));
    let (s0, s1) = (a + DVec3::Y, b + DVec3::Y);
    let wide = edge(a, b, EdgeKind::ShadowUmbral);
    let pw = scene.penumbra(&wide, 0, s0, s1);
    assert_eq!(barrier_part(&wide, &pw, &prj, NARROW_PIXELS), None);
    let mut all = vec![(wide, pw)];
    for kind in [EdgeKind::ShadowHard, EdgeKind::Silhouette, EdgeKind::Sharp, EdgeKind::Boundary] {
        let e = edge(a, b, kind);
        let p = scene.penumbra(&e, 0, s0, s1);
        assert_eq!(p, [Vec3::ZERO; 2], "{kind:?}");
        assert_eq!(barrier_part(&e, &p, &prj, NARROW_PIXELS), Some(e));
        all.push((e, p));
    }
    let mut out = Vec::new();
    append_barriers(&all, Some(&prj), &mut out);
    assert_eq!(out, all[1..].iter().map(|(e, _)| *e).collect::<Vec<_>>());
    out.clear();
    append_barriers(&all, None, &mut out);
    assert_eq!(out, all.iter().map(|(e, _)| *e).collect::<Vec<_>>());
}
