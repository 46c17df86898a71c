use super::*;
use crate::edges::finder::EdgeFinder;
use crate::edges::EdgeKind;
use crate::edges::TripleKey;
use edgepoint_scene::backprojection::irradiance_with_blockers;
use edgepoint_scene::builtin::shapes::{cuboid, polygon};
use edgepoint_scene::{Camera, Material, NoProgress, Object, Scene};
use glam::DVec2;
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

/// Other lights bounded: with a second light far below [`COMPARABLE`] of the own light's
/// mean it is never evaluated, and the estimate (with half its unoccluded mean) is within
/// COMPARABLE / 2 of the full one, e/√12 / (e/2 + c); where it is comparable the full
/// estimate, with 18 evaluations of it.
#[test]
fn other_lights_that_are_not_comparable_are_bounded_not_evaluated() {
    let b = band();
    let rules = Rules::new();
    // (the second light's level, its unoccluded level, comparable)
    for (c, free, comparable) in [(0.01, 0.02, false), (0.0, 0.04, false), (0.03, 0.045, false), (0.3, 0.4, true), (2.0, 2.0, true)] {
        let calls = std::cell::Cell::new(0usize);
        let step = |k: usize, x: DVec3, _n: DVec3| {
            if k == 0 {
                if x.dot(b.across) > 0.0 {
                    1.0
                } else {
                    0.0
                }
            } else {
                calls.set(calls.get() + 1);
                c
            }
        };
        let bound = |k: usize, _x: DVec3, _n: DVec3| if k == 0 { 1.0 } else { free };
        let full = washout_error(&b, 0, 2, &rules.full, step);
        let full_calls = calls.replace(0);
        let fast = washout_error_bounded(&b, 0, 2, &rules.full, step, bound);
        let want = 1.0 / 12f64.sqrt() / (0.5 + c);
        assert!((full - want).abs() <= 1e-12 * want, "{c}: {full} against {want}");
        assert_eq!(full_calls, 18);
        if comparable {
            assert_eq!(calls.get(), 18, "{c}");
            assert!((fast - full).abs() <= 1e-12 * full, "{c}: {fast} against {full}");
        } else {
            assert_eq!(calls.get(), 0, "{c}");
            let fast_want = 1.0 / 12f64.sqrt() / (0.5 + 0.5 * free);
            assert!((fast - fast_want).abs() <= 1e-12 * fast_want, "{c}: {fast} against {fast_want}");
            assert!((fast - full).abs() <= 0.5 * COMPARABLE * full, "{c}: {fast} against {full}");
        }
    }
    // The own light smooth: 0 without evaluating or bounding the other light.
    let calls = std::cell::Cell::new(0usize);
    let flat = |k: usize, _x: DVec3, _n: DVec3| {
        if k == 1 {
            calls.set(calls.get() + 1);
        }
        1.0
    };
    assert_eq!(washout_error_bounded(&b, 0, 2, &rules.full, flat, flat), 0.0);
    assert_eq!(calls.get(), 0);
}

/// On random scenes and bands the bounded estimate stays within COMPARABLE / 2 of the full
/// one, and the unoccluded irradiance bounds the exact one at every node.
#[test]
fn bounded_estimates_stay_within_half_the_comparable_fraction() {
    let rules = Rules::new();
    let mut bounded = 0;
    for_random_bands(5, 60, 10, |lights, band, k, r| {
        let fast = lights.band_error(band, k, &rules, Estimate::FAST, &mut Culls::default());
        let full = lights.band_error(band, k, &rules, Estimate::FULL, &mut Culls::default());
        assert!(fast == full || (fast - full).abs() <= 0.5 * COMPARABLE * full + 1e-12, "{fast} against {full} ({band:?})");
        bounded += usize::from(fast != full && (fast - full).abs() > 1e-9 * full);
        for _ in 0..5 {
            let x = band.point(r.f64(), 2.0 * r.f64() - 1.0);
            for j in 0..lights.lights() {
                let (e, u) = (lights.irradiance(j, x, band.normal), lights.unoccluded(j, x, band.normal));
                assert!(e <= u * (1.0 + 1e-9) + 1e-15, "light {j} at {x}: {e} over its bound {u}");
            }
        }
    });
    assert!(bounded >= 5, "only {bounded} estimates used the bound");
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

/// Two 4 m rooms side by side (a floor, a 10 cm wall at x = 4 with a random doorway or none,
/// placed by its object's transform), random boxes, and random lights: area lights facing
/// down, up or tilted, point lights, in either room.
fn two_rooms(r: &mut crate::rng::Rng) -> Scene {
    let obj = |name: &str, mesh, transform| Object { name: name.into(), mesh: Arc::new(mesh), material: Material::default(), transform };
    let floor = polygon(&[Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 4.0), Vec3::new(8.0, 0.0, 4.0), Vec3::new(8.0, 0.0, 0.0)]);
    let mut objects = vec![obj("floor", floor, Affine3A::IDENTITY)];
    // The wall in its own frame (centred on x = 0), moved to x = 4: with a doorway, three
    // boxes (two sides and a lintel overlapping them), else one.
    let mut wall = edgepoint_scene::builtin::shapes::Parts::default();
    if r.chance(0.6) {
        let z0 = r.range(0.3, 2.5);
        let z1 = z0 + r.range(0.4, 1.2);
        let top = r.range(1.5, 2.3);
        wall.add(&cuboid(Vec3::new(-0.05, 0.0, 0.0), Vec3::new(0.05, 2.6, z0)), Affine3A::IDENTITY);
        wall.add(&cuboid(Vec3::new(-0.05, 0.0, z1), Vec3::new(0.05, 2.6, 4.0)), Affine3A::IDENTITY);
        wall.add(&cuboid(Vec3::new(-0.05, top, z0 - 0.02), Vec3::new(0.05, 2.6, z1 + 0.02)), Affine3A::IDENTITY);
    } else {
        wall.add(&cuboid(Vec3::new(-0.05, 0.0, 0.0), Vec3::new(0.05, 2.6, 4.0)), Affine3A::IDENTITY);
    }
    objects.push(obj("wall", wall.mesh(), Affine3A::from_translation(Vec3::new(4.0, 0.0, 0.0))));
    for i in 0..r.below(4) {
        let c = Vec3::new(r.range(0.3, 7.7), r.range(0.2, 1.5), r.range(0.3, 3.7));
        let h = r.vec3(0.05, 0.4);
        let turn = Affine3A::from_translation(c) * Affine3A::from_rotation_y(r.range(0.0, 3.0));
        objects.push(obj(&format!("box{i}"), cuboid(-h, h), turn));
    }
    let mut lights = Vec::new();
    for _ in 0..2 + r.below(3) {
        let c = Vec3::new(r.range(0.5, 7.5), r.range(1.8, 2.5), r.range(0.5, 3.5));
        if r.chance(0.3) {
            lights.push(Light::Point { position: c, intensity: Vec3::splat(r.range(1.0, 5.0)) });
        } else {
            // Mostly facing down; sometimes up (the floor is behind it) or tilted.
            let n = match r.below(3) {
                0 => Vec3::Y,
                1 => (Vec3::NEG_Y + r.vec3(-0.8, 0.8)).normalize(),
                _ => Vec3::NEG_Y,
            };
            let u = n.any_orthonormal_vector();
            let w = n.cross(u);
            let a = r.range(0.1, 0.5);
            let vertices = [(-a, -a), (a, -a), (a, a), (-a, a)].iter().map(|&(x, y)| c + u * x + w * y).collect();
            lights.push(Light::Area { vertices, radiance: Vec3::splat(r.range(2.0, 10.0)) });
        }
    }
    Scene {
        name: "two-rooms".into(),
        objects,
        lights,
        camera: Camera { eye: Vec3::new(1.0, 1.6, 1.0), target: Vec3::new(6.0, 0.5, 2.0), up: Vec3::Y, fov_y_degrees: 60.0 },
        ambient: Vec3::ZERO,
        background: Vec3::ZERO,
        orbit: None,
    }
}

/// A random band: on the floor, on either face of the wall, or anywhere with any normal.
fn random_band(r: &mut crate::rng::Rng) -> Band {
    let (a, normal, along) = match r.below(4) {
        0 | 1 => (DVec3::new(r.f64() * 8.0, 0.0, r.f64() * 4.0), DVec3::Y, DVec3::new(r.f64() - 0.5, 0.0, r.f64() - 0.5)),
        2 => {
            let x = if r.chance(0.5) { 3.95 } else { 4.05 };
            (DVec3::new(x, r.f64() * 2.5, r.f64() * 4.0), DVec3::new(if x < 4.0 { -1.0 } else { 1.0 }, 0.0, 0.0), DVec3::new(0.0, r.f64() - 0.5, r.f64() - 0.5))
        }
        _ => {
            let n = r.direction().as_dvec3();
            (DVec3::new(r.f64() * 8.0, r.f64() * 2.5, r.f64() * 4.0), n, n.any_orthonormal_vector())
        }
    };
    let b = a + along.normalize_or(DVec3::X) * (0.05 + r.f64());
    Band::new(a, b, normal, 0.02 + 0.5 * r.f64()).unwrap()
}

/// `scenes` random [`two_rooms`] with `bands` random bands each: `f(lights, band, k, rng)`
/// for a random light k of the scene.
fn for_random_bands(seed: u64, scenes: usize, bands: usize, mut f: impl FnMut(&mut SceneLights, &Band, usize, &mut crate::rng::Rng)) {
    let mut r = crate::rng::Rng::new(seed);
    for _ in 0..scenes {
        let scene = two_rooms(&mut r);
        let bvhs: Vec<FaceBvh> = scene.objects.iter().map(|o| FaceBvh::build(&o.mesh, &NoProgress)).collect();
        let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let mut lights = SceneLights::new(&scene.lights, &bvhs, &t);
        for _ in 0..bands {
            let band = random_band(&mut r);
            let k = r.below(scene.lights.len());
            f(&mut lights, &band, k, &mut r);
        }
    }
}

/// The culls are exact: with them every estimate is the one made with every light (random
/// scenes, bands and lights), and at random points of a band a culled light's irradiance
/// is 0. Every kind of cull happens.
#[test]
fn culled_estimates_equal_the_unculled_ones() {
    let rules = Rules::new();
    let cull_only = Estimate { cull: true, bounded: false };
    let mut total = Culls::default();
    let mut partly = 0;
    for_random_bands(31, 30, 12, |lights, band, k, r| {
        let mut c = Culls::default();
        let with = lights.band_error(band, k, &rules, cull_only, &mut c);
        let without = lights.band_error(band, k, &rules, Estimate::FULL, &mut Culls::default());
        let same = with == without || (with - without).abs() <= 1e-9 * without.abs();
        assert!(same, "culled {with} against {without} ({c:?}, light {k}, {band:?})");
        if c.facing + c.behind + c.blocked > 0 && c.facing + c.behind + c.blocked < c.pairs {
            partly += 1;
        }
        total.add(&c);
        // Each culled light lights no point of the band.
        for j in 0..lights.lights() {
            if !lights.reaches(j, band, &mut Culls::default()) {
                for _ in 0..20 {
                    let x = band.point(r.f64(), 2.0 * r.f64() - 1.0);
                    let e = lights.irradiance(j, x, band.normal);
                    assert!(e <= 1e-9 * lights.weights[j], "light {j} culled but gives {e} at {x} ({band:?})");
                }
            }
        }
    });
    assert!(total.facing >= 10 && total.behind >= 10 && total.blocked >= 10, "{total:?}");
    assert!(partly >= 10, "bands with some lights culled and others not: {partly}");
}

/// The hull of a square's corners, a point on one of its sides and random points inside is
/// the square, counter-clockwise.
#[test]
fn convex_hull_of_a_square_and_points_inside() {
    let mut p = vec![DVec2::new(0.0, 0.0), DVec2::new(2.0, 0.0), DVec2::new(2.0, 2.0), DVec2::new(0.0, 2.0)];
    let mut r = crate::rng::Rng::new(3);
    for _ in 0..50 {
        p.push(DVec2::new(2.0 * r.f64(), 2.0 * r.f64()));
    }
    p.push(DVec2::new(1.0, 0.0));
    let h = convex_hull(p);
    assert_eq!(h.len(), 4, "{h:?}");
    assert!((edgepoint_scene::polyclip::signed_area2(&h) - 8.0).abs() < 1e-12, "{h:?}");
}

/// Closed meshes wound outward block through their exit faces alone: the irradiance of every
/// light at random points of random bands (on the floor, the wall, anywhere: some inside a
/// box) is the one with every face, and the exit faces are used (the boxes and the wall).
#[test]
fn exit_faces_of_closed_meshes_hide_what_all_faces_hide() {
    let mut shadowed = 0;
    for_random_bands(41, 30, 10, |lights, band, _k, r| {
        assert!(lights.bvhs.iter().skip(1).all(|b| b.oriented), "the wall and the boxes are closed and wound outward");
        for _ in 0..10 {
            let x = band.point(r.f64(), 2.0 * r.f64() - 1.0);
            for j in 0..lights.lights() {
                lights.exit_faces = true;
                let fast = lights.irradiance(j, x, band.normal);
                lights.exit_faces = false;
                let all = lights.irradiance(j, x, band.normal);
                assert!((fast - all).abs() <= 1e-9 * lights.weights[j], "light {j} at {x}: {fast} against {all}");
                shadowed += usize::from(all < lights.unoccluded(j, x, band.normal) * (1.0 - 1e-6));
            }
        }
    });
    assert!(shadowed >= 100, "only {shadowed} shadowed points");
}

/// A box is closed and wound outward; with one face turned over, or one face missing, or
/// turned inside out, it is not.
#[test]
fn orientation_of_closed_meshes() {
    let m = cuboid(Vec3::ZERO, Vec3::ONE);
    assert!(crate::edges::face_bvh::consistently_oriented(&m.triangles));
    assert!(FaceBvh::build(&m, &NoProgress).oriented);
    let mut flipped = m.triangles.clone();
    flipped[3].swap(1, 2);
    assert!(!crate::edges::face_bvh::consistently_oriented(&flipped));
    assert!(!crate::edges::face_bvh::consistently_oriented(&m.triangles[1..]));
    let mut inside_out = m.clone();
    inside_out.triangles.iter_mut().for_each(|t| t.swap(1, 2));
    assert!(crate::edges::face_bvh::consistently_oriented(&inside_out.triangles));
    let parts = edgepoint_scene::builtin::shapes::Parts { positions: inside_out.positions.clone(), triangles: inside_out.triangles.clone() };
    assert!(!FaceBvh::build(&parts.mesh(), &NoProgress).oriented, "inside out");
}

/// An estimate kept across a move ([`SceneLights::still_holds`]) is the estimate made
/// afresh there, bit for bit: on `cornell`, after the short box moves, the kept ones and
/// those made again equal a new [`EdgeErrors`]'s, and both kinds occur.
#[test]
fn estimates_kept_across_a_move_equal_estimates_made_afresh() {
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    let id = |n: &str| scene.object_id(n).unwrap();
    let triples: Vec<TripleKey> = ["tallbox", "shortbox"]
        .iter()
        .flat_map(|b| ["floor", "back", "redwall", "greenwall", "tallbox", "shortbox"].map(|r| TripleKey { light: 0, blocker: id(b), receiver: id(r) }))
        .filter(|k| k.blocker != k.receiver)
        .collect();
    let mut f = EdgeFinder::new(&scene, &NoProgress);
    let mut out = Vec::new();
    let mut kept = EdgeErrors::new();
    f.frame(&t, scene.camera.eye, None, triples.iter().copied(), 85.0, &mut out);
    let (before, estimated) = f.errors(&mut kept);
    assert_eq!(estimated, before.len());
    for (k, d) in [(0, Vec3::new(0.04, 0.0, -0.03)), (1, Vec3::new(-0.02, 0.0, 0.05))] {
        let mut moved = t.clone();
        let o = id(["shortbox", "tallbox"][k]) as usize;
        moved[o] = Affine3A::from_translation(d) * t[o];
        f.frame(&moved, scene.camera.eye, None, triples.iter().copied(), 85.0, &mut out);
        let (carried, dropped) = (kept.carried, kept.dropped);
        // Before estimating: the kept ones known, NaN for exactly those estimated next.
        let known = f.known_errors(&mut kept);
        let (after, again) = f.errors(&mut kept);
        assert_eq!(known.iter().filter(|(_, x)| x.is_nan()).count(), again);
        assert!(known.iter().zip(&after).all(|((a, x), (b, y))| a == b && (x.is_nan() || x.to_bits() == y.to_bits())));
        let (fresh, all) = f.errors(&mut EdgeErrors::new());
        let bits = |v: &[(EdgeSegment, f64)]| v.iter().map(|(e, x)| (e.a.to_array().map(f32::to_bits), e.b.to_array().map(f32::to_bits), x.to_bits())).collect::<Vec<_>>();
        assert_eq!(bits(&after), bits(&fresh), "move {k}");
        assert_eq!(all, fresh.len());
        assert!(kept.carried > carried && kept.dropped > dropped, "move {k}: {} kept, {} dropped", kept.carried - carried, kept.dropped - dropped);
        assert!(again < all, "move {k}: {again} of {all} estimated again");
        // Back where they were (the next move starts from `t`): every edge of `t` again.
        f.frame(&t, scene.camera.eye, None, triples.iter().copied(), 85.0, &mut out);
        let (back, _) = f.errors(&mut kept);
        assert_eq!(bits(&back), bits(&before));
    }
}
