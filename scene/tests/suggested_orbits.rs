//! Every built-in's suggested orbit, sampled every degree along the full circle: the eye
//! stays inside the room (inside the scene's bounds horizontally and above the floor; under
//! the ceiling where there is one), keeps a clearance from every triangle of every object
//! and is inside no closed object (brute force over all triangles, checked against each
//! object's bounding box first), and the scene's main content projects into the frame.
//! Loaded bare models orbit their framing target.
use edgepoint_scene::geometry::{closest_on_triangle, ray_triangle};
use edgepoint_scene::{builtin, data, Camera, Object, Orbit, Scene};
use glam::Vec3;

/// Clearance from every triangle, as a fraction of the orbit radius. Samples 1° apart are
/// closer than half of it to each other, so the eye keeps a clearance between samples too.
const CLEARANCE: f32 = 0.05;

fn world_triangles(o: &Object) -> impl Iterator<Item = [Vec3; 3]> + '_ {
    o.mesh.triangles.iter().map(|t| t.map(|i| o.transform.transform_point3(o.mesh.positions[i as usize])))
}

/// Distance from `p` to the object's triangles and whether `p` is inside it (odd number of
/// crossings along a skewed ray), or `None` when `p` is farther than `clearance` from its
/// bounding box (then it is outside and clear of it).
fn near_object(s: &Scene, i: usize, p: Vec3, clearance: f32) -> Option<(f32, bool)> {
    let (lo, hi) = s.object_bounds(i);
    let gap = (lo - p).max(p - hi).max(Vec3::ZERO).length();
    if gap >= clearance {
        return None;
    }
    let dir = Vec3::new(0.3127, 0.8129, 0.4913);
    let (mut dist, mut hits) = (f32::INFINITY, 0u32);
    for [a, b, c] in world_triangles(&s.objects[i]) {
        dist = dist.min((closest_on_triangle(p, a, b, c) - p).length());
        hits += ray_triangle(p, dir, a, b, c).is_some() as u32;
    }
    Some((dist, hits % 2 == 1))
}

/// Checks the orbit of `s`; `enclosed`: the scene has a ceiling the eye must stay under;
/// `content`: objects whose bounding-box centre must project into a square frame.
fn check_orbit(s: &Scene, enclosed: bool, content: &[&str]) {
    let orbit: Orbit = s.suggested_orbit();
    orbit.validate().unwrap();
    let (lo, hi) = s.bounds();
    let clearance = CLEARANCE * orbit.radius;
    for deg in 0..360 {
        let cam = orbit.camera_after(deg as f32);
        cam.validate().unwrap();
        let e = cam.eye;
        let inside = e.x > lo.x && e.x < hi.x && e.z > lo.z && e.z < hi.z && e.y > lo.y && (!enclosed || e.y < hi.y);
        assert!(inside, "{}: at {deg}° the eye {e} leaves the room {lo} .. {hi}", s.name);
        for (i, o) in s.objects.iter().enumerate() {
            if let Some((dist, inside)) = near_object(s, i, e, clearance) {
                assert!(!inside, "{}: at {deg}° the eye {e} is inside {}", s.name, o.name);
                assert!(dist >= clearance, "{}: at {deg}° the eye {e} is {dist} from {} (clearance {clearance})", s.name, o.name);
            }
        }
        let frame = cam.frame(256, 256);
        for name in content {
            let id = s.object_id(name).unwrap_or_else(|| panic!("{}: no object {name}", s.name)) as usize;
            let (a, b) = s.object_bounds(id);
            let (x, y, _) = frame.project((a + b) * 0.5).unwrap_or_else(|| panic!("{}: at {deg}° {name} is behind the eye", s.name));
            assert!((0.0..256.0).contains(&x) && (0.0..256.0).contains(&y), "{}: at {deg}° {name} is out of view ({x}, {y})", s.name);
        }
    }
}

#[test]
fn procedural_builtins_orbit_inside_their_rooms_and_outside_every_object() {
    for (name, enclosed, content) in [
        ("cornell", true, &["shortbox", "tallbox"][..]),
        ("cornell-point", true, &["shortbox", "tallbox"][..]),
        ("cornell-glass", true, &["glass", "mirror"][..]),
        ("chains", false, &["chain1-link3", "chain2-link4", "chain0-link4", "chain3-link3"][..]),
        ("torus-capsule", false, &["torus", "capsule"][..]),
        ("rooms", true, &["table0", "ball0"][..]),
        ("materials", false, &["lambert", "roughglass"][..]),
    ] {
        let s = builtin::load(name).unwrap();
        assert!(s.orbit.is_some(), "{name} suggests no orbit of its own");
        check_orbit(&s, enclosed, content);
    }
}

#[test]
fn grid_dragon_orbits_over_its_floor_and_under_nothing() {
    // The dragon is shared data (../shared/data); CI lays it beside the checkout.
    let s = data::load_builtin("grid-dragon", None, &edgepoint_scene::NoProgress)
        .unwrap_or_else(|e| panic!("grid-dragon needs the shared dragon: {e}"));
    check_orbit(&s, false, &["dragon"]);
}

#[test]
fn a_staged_model_orbits_its_framing_target() {
    let ply = b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
element face 4\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
    let s = edgepoint_scene::load::load_files(&[edgepoint_scene::load::NamedBytes { name: "tet.ply".into(), data: ply.to_vec() }], &edgepoint_scene::NoProgress)
        .unwrap();
    let o = s.suggested_orbit();
    assert_eq!(o.pivot, s.camera.target);
    let c: Camera = o.camera_after(0.0);
    assert!((c.eye - s.camera.eye).length() < 1e-4 * o.radius, "{} vs {}", c.eye, s.camera.eye);
    check_orbit(&s, false, &["tet"]);
}

#[test]
fn glossy_bunny_orbits_over_its_floor_and_outside_the_bunny() {
    let s = data::load_builtin("glossy-bunny", None, &edgepoint_scene::NoProgress)
        .unwrap_or_else(|e| panic!("glossy-bunny needs the shared bunny: {e}"));
    s.validate().unwrap();
    check_orbit(&s, false, &["bunny"]);
}
