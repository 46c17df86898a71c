use super::*;
use crate::edges::finder::EdgeFinder;
use crate::edges::EdgeKind;
use crate::edges::TripleKey;
use edgepoint_scene::backprojection::irradiance_with_blockers;
use edgepoint_scene::builtin::shapes::{cuboid, polygon};
use edgepoint_scene::{Camera, Material, NoProgress, Object, Scene};
use std::sync::Arc;

/// ∫ x^d over [lo, hi].
fn monomial(d: i32, lo: f64, hi: f64) -> f64 {
    (hi.powi(d + 1) - lo.powi(d + 1)) / (d + 1) as f64
}

#[test]
fn gauss_legendre_is_exact_up_to_degree_2n_minus_1_and_not_beyond() {
    for n in 1..=8usize {
        let rule = gauss_legendre(n);
        let (lo, hi) = (-0.3, 1.7);
        for d in 0..=(2 * n as i32 - 1) {
            let [got] = integrate(&rule, lo, hi, |x| [x.powi(d)]);
            let want = monomial(d, lo, hi);
            assert!((got - want).abs() <= 1e-12 * want.abs().max(1.0), "n {n} degree {d}: {got} against {want}");
        }
        // Degree 2n is where the rule stops being exact (its error term is f^(2n)).
        let d = 2 * n as i32;
        let [got] = integrate(&rule, lo, hi, |x| [x.powi(d)]);
        assert!((got - monomial(d, lo, hi)).abs() > 1e-6, "n {n} integrates degree {d} exactly");
    }
}

/// A point light at height h over a plane: ∫∫ over [0, a] × [0, b] of its irradiance
/// h / (h² + x² + y²)^{3/2} is atan(a b / (h √(h² + a² + b²))) (the solid angle of the
/// rectangle's pyramid over 4 quadrants).
#[test]
fn quadrature_of_a_point_lights_irradiance_over_a_rectangle_matches_the_closed_form() {
    let rule = gauss_legendre(8);
    // (8 points per side: within 10⁻⁷ of a function with poles at distance h.)
    for (h, a, b) in [(1.0, 1.0, 1.0), (2.0, 0.5, 3.0), (0.7, 0.2, 0.4)] {
        let e = |x: f64, y: f64| h / (h * h + x * x + y * y).powf(1.5);
        let [got] = integrate(&rule, 0.0, a, |x| integrate(&rule, 0.0, b, |y| [e(x, y)]));
        let want = (a * b / (h * (h * h + a * a + b * b).sqrt())).atan();
        assert!((got - want).abs() <= 1e-7 * want, "h {h} a {a} b {b}: {got} against {want}");
    }
}

fn band() -> Band {
    Band::new(DVec3::ZERO, DVec3::new(0.0, 0.0, 2.0), DVec3::Y, 0.5).unwrap()
}

/// A step at the edge (light 0: e0 on the far side of `across`, nothing on the near one)
/// and a constant light 1 (c): the linear interpolation misses by e0 (1 − |t|)/2, so the RMS is
/// e0/√12 and the estimate e0 / √12 / (e0/2 + c), exactly, since each half is integrated on
/// its own.
#[test]
fn a_step_and_a_ramp_give_the_closed_form_estimates() {
    let b = band();
    let rule = gauss_legendre(ORDER);
    for (e0, c) in [(1.0, 0.0), (1.0, 1.0), (2.0, 19.0), (0.5, 0.25)] {
        let step = |k: usize, x: DVec3, _n: DVec3| if k == 0 { if x.dot(b.across) > 0.0 { e0 } else { 0.0 } } else { c };
        let got = washout_error(&b, 0, 2, &rule, step);
        let want = e0 / 12f64.sqrt() / (e0 / 2.0 + c);
        assert!((got - want).abs() <= 1e-12 * want, "step {e0} {c}: {got} against {want}");
        // A penumbra: 0 at t = −1 rising linearly to e0 at the edge, e0 beyond. The
        // interpolation misses by e0 (1 − |t|)/2 again; the mean of light 0 is 3 e0 / 4.
        let ramp = |k: usize, x: DVec3, _n: DVec3| {
            let t = x.dot(b.across) / b.half_width;
            if k == 0 {
                e0 * (t + 1.0).min(1.0)
            } else {
                c
            }
        };
        let got = washout_error(&b, 0, 2, &rule, ramp);
        let want = e0 / 12f64.sqrt() / (0.75 * e0 + c);
        assert!((got - want).abs() <= 1e-12 * want, "ramp {e0} {c}: {got} against {want}");
    }
    // Light 0 smooth (linear) across the band: nothing to lose.
    let linear = |k: usize, x: DVec3, _n: DVec3| if k == 0 { 1.0 + x.dot(b.across) } else { 0.0 };
    assert!(washout_error(&b, 0, 1, &rule, linear) < 1e-15);
}

const PLATE: u32 = 1;

/// A 20 m floor (object 0) under a 1 m × 1 m plate 1 m up (object 1), and `lights`.
fn plate_scene(lights: Vec<Light>) -> Scene {
    let l = 10.0;
    let floor = polygon(&[Vec3::new(-l, 0.0, -l), Vec3::new(-l, 0.0, l), Vec3::new(l, 0.0, l), Vec3::new(l, 0.0, -l)]);
    let plate = cuboid(Vec3::new(-0.5, 0.98, -0.5), Vec3::new(0.5, 1.0, 0.5));
    let obj = |name: &str, mesh| Object { name: name.into(), mesh: Arc::new(mesh), material: Material::default(), transform: Affine3A::IDENTITY };
    Scene {
        name: "plate".into(),
        objects: vec![obj("floor", floor), obj("plate", plate)],
        lights,
        camera: Camera { eye: Vec3::new(0.0, 4.0, 4.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 60.0 },
        ambient: Vec3::ZERO,
        background: Vec3::ZERO,
        orbit: None,
    }
}

/// A square area light (half side `a`) at `c`, facing down.
fn square(c: Vec3, a: f32) -> Vec<Vec3> {
    [(-a, -a), (a, -a), (a, a), (-a, a)].iter().map(|&(x, z)| c + Vec3::new(x, 0.0, z)).collect()
}

/// The estimates of light 0's shadow edges of the plate on the floor.
fn errors_of_light_0(scene: &Scene) -> Vec<(EdgeSegment, f64)> {
    let mut f = EdgeFinder::new(scene, &NoProgress);
    let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    let triples = [TripleKey { light: 0, blocker: PLATE, receiver: 0 }];
    let mut out = Vec::new();
    f.frame(&t, scene.camera.eye, None, triples, 85.0, &mut out);
    let (errors, estimated) = f.errors(&mut EdgeErrors::new());
    assert_eq!(estimated, errors.len());
    assert!(errors.iter().all(|(e, _)| e.object == 0));
    errors
}

/// Where the second light of the wash-out tests hangs: far enough that its irradiance
/// varies by a few percent over the plate's shadow (so "as bright" holds at every edge), and
/// low enough that its own shadow of the plate falls 5.8 m away, outside every band.
const SIDE: Vec3 = Vec3::new(100.0, 20.0, 0.0);

/// One area light over the plate, then a second one far to the side as bright as the first
/// at the shadow's centre, then 20 times as bright: paper 003's wash-out.
#[test]
fn a_much_brighter_second_light_washes_out_the_dim_lights_shadow_and_an_equal_one_does_not() {
    let dim = Light::Area { vertices: square(Vec3::new(0.0, 2.0, 0.0), 0.25), radiance: Vec3::splat(10.0) };
    let one = errors_of_light_0(&plate_scene(vec![dim.clone()]));
    let kinds = |v: &[(EdgeSegment, f64)], k: EdgeKind| v.iter().filter(|(e, _)| e.kind == k).count();
    assert!(kinds(&one, EdgeKind::ShadowUmbral) >= 4 && kinds(&one, EdgeKind::ShadowPenumbral) >= 4, "{one:?}");
    let min = |v: &[(EdgeSegment, f64)]| v.iter().map(|e| e.1).fold(f64::INFINITY, f64::min);
    let max = |v: &[(EdgeSegment, f64)]| v.iter().map(|e| e.1).fold(0.0, f64::max);
    // Alone, every edge of a shadow loses a large part of the light it bounds: nothing is
    // dropped at any tolerance up to 0.1.
    assert!(min(&one) > 0.1, "one light: {one:?}");

    // The side light's irradiance at the shadow's centre per unit radiance, against the
    // dim light's.
    let side = square(SIDE, 2.0);
    let at = |v: &[Vec3]| irradiance_with_blockers(&LightPlane::new(v).unwrap(), Vec3::ZERO, Vec3::Y, std::iter::empty());
    let ratio = at(&square(Vec3::new(0.0, 2.0, 0.0), 0.25)) / at(&side);
    let with = |times: f32| {
        let bright = Light::Area { vertices: side.clone(), radiance: Vec3::splat(10.0 * ratio as f32 * times) };
        errors_of_light_0(&plate_scene(vec![dim.clone(), bright]))
    };
    let equal = with(1.0);
    let much = with(20.0);

    assert_eq!((equal.len(), much.len()), (one.len(), one.len()));
    assert!(min(&equal) > 0.05, "equal light: {equal:?}");
    assert!(max(&much) < 0.05, "20 times brighter: {much:?}");
    // The estimate falls as the other light grows, edge by edge.
    for ((a, b), c) in one.iter().zip(&equal).zip(&much) {
        assert!(a.1 > b.1 && b.1 > c.1, "{a:?} {b:?} {c:?}");
    }
}

/// The same with point lights (`chains` has two): a hard edge is a step.
#[test]
fn point_lights_hard_edges_wash_out_the_same_way() {
    let dim = Light::Point { position: Vec3::new(0.0, 2.0, 0.0), intensity: Vec3::splat(4.0) };
    let one = errors_of_light_0(&plate_scene(vec![dim.clone()]));
    assert!(one.len() >= 4 && one.iter().all(|(e, _)| e.kind == EdgeKind::ShadowHard));
    // Alone: a step from 0 to e, the estimate (1/√12) e / (e/2) = 0.577 (a little off as e
    // varies over the band).
    assert!(one.iter().all(|(_, x)| *x > 0.5 && *x < 0.65), "{one:?}");
    // At the origin a point light's irradiance is I h / r³ (the dim one's: I / 4).
    let (h, r) = (SIDE.y, SIDE.length());
    let per_unit = h / (r * r * r) / (1.0 / 4.0);
    let with = |times: f32| {
        let side = Light::Point { position: SIDE, intensity: Vec3::splat(4.0 * times / per_unit) };
        errors_of_light_0(&plate_scene(vec![dim.clone(), side]))
    };
    // With a light as bright at the origin: at the edges (1 m out) the dim light gives 0.72
    // of its light at the origin and the far one the same, so about 0.29 / (1/2 + 1.4) = 0.15.
    let equal = with(1.0);
    assert!(equal.iter().all(|(_, x)| *x > 0.1 && *x < 0.2), "equal: {equal:?}");
    assert!(with(20.0).iter().all(|(_, x)| *x < 0.05), "20 times brighter");
}
