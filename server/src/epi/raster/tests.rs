//! Rasterization against a direct 3D computation: each boundary line is a plane through the
//! eye; intersecting the world-space segment with it gives the crossing and its true view
//! depth, independently of the screen-space interpolation the rasterizer uses.
use super::*;
use crate::edges::EdgeKind;
use crate::epi::code::{Cell, PIXEL};
use crate::epi::testutil::Rng;
use edgepoint_scene::Camera;
use glam::Vec3;

fn camera(w: usize, h: usize) -> CameraFrame {
    Camera { eye: Vec3::new(0.2, 0.1, 0.3), target: Vec3::new(0.0, 0.0, -5.0), up: Vec3::Y, fov_y_degrees: 50.0 }.frame(w as u32, h as u32)
}

fn v64(v: Vec3) -> [f64; 3] {
    [v.x as f64, v.y as f64, v.z as f64]
}

/// Expected crossings: `must` bits are certain, `may` bits are within rounding of a bit or
/// depth boundary (either answer accepted).
struct Expected {
    must_sides: Vec<u16>,
    may_sides: Vec<u16>,
    must_centres: Vec<u16>,
    may_centres: Vec<u16>,
}

/// Intersects `e` with the plane through the eye whose points project to screen line
/// `x = value` (vertical) or `y = value`; returns (screen position along the other axis,
/// view depth).
fn cross(cam: &CameraFrame, w: usize, h: usize, e: &EdgeSegment, vertical: bool, value: f64) -> Option<(f64, f64)> {
    let (cx, cy) = (0.5 * w as f64, 0.5 * h as f64);
    let tan = cam.tan_half_y as f64;
    let aspect = w as f64 / h as f64;
    let (right, up, fwd, eye) = (v64(cam.right), v64(cam.up), v64(cam.forward), v64(cam.eye));
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    // sx = cx + (d.right) * cx / (tan * aspect * z); sy = cy - (d.up) * cy / (tan * z).
    let n: [f64; 3] = if vertical {
        let k = cx / (tan * aspect);
        std::array::from_fn(|i| right[i] * k - (value - cx) * fwd[i])
    } else {
        let k = cy / tan;
        std::array::from_fn(|i| -up[i] * k - (value - cy) * fwd[i])
    };
    let (a, b) = (v64(e.a), v64(e.b));
    let da: [f64; 3] = std::array::from_fn(|i| a[i] - eye[i]);
    let ab: [f64; 3] = std::array::from_fn(|i| b[i] - a[i]);
    let den = dot(n, ab);
    if den == 0.0 {
        return None;
    }
    let t = -dot(n, da) / den;
    if !(0.0..=1.0).contains(&t) {
        return None;
    }
    let p: [f64; 3] = std::array::from_fn(|i| da[i] + t * ab[i]);
    let z = dot(p, fwd);
    if z <= NEAR * 10.0 {
        return None;
    }
    let other = if vertical { cy - dot(p, up) * (cy / tan) / z } else { cx + dot(p, right) * (cx / (tan * aspect)) / z };
    Some((other, z))
}

fn expected(cam: &CameraFrame, w: usize, h: usize, edges: &[EdgeSegment], depth: &ConservativeDepth) -> Expected {
    let mut ex = Expected {
        must_sides: vec![0; (w + 1) * (h + 1)],
        may_sides: vec![0; (w + 1) * (h + 1)],
        must_centres: vec![0; w * h],
        may_centres: vec![0; w * h],
    };
    const EPS: f64 = 1e-6;
    for e in edges {
        for (vertical, centre) in [(true, false), (false, false), (true, true), (false, true)] {
            let (count, limit) = if vertical { (w + 1, h) } else { (h + 1, w) };
            for line in 0..count - usize::from(centre) {
                let value = line as f64 + if centre { 0.5 } else { 0.0 };
                let Some((along, z)) = cross(cam, w, h, e, vertical, value) else { continue };
                if !(along >= -EPS && along < limit as f64 + EPS) {
                    continue;
                }
                let cell = along.floor().clamp(0.0, limit as f64 - 1.0);
                let f = along - cell;
                let bit = ((f * 8.0) as u32).min(7);
                let near_bit_edge = (f * 8.0 - (f * 8.0).round()).abs() < EPS * 8.0 || along < EPS || along > limit as f64 - EPS;
                // Nearest vertex (both neighbours for centre lines across them).
                let (vx, vy) = if vertical { (value, along) } else { (along, value) };
                let mut d = depth.at(vx.round() as i64, vy.round() as i64);
                if centre && vertical {
                    d = depth.at(value.floor() as i64, vy.round() as i64).max(depth.at(value.floor() as i64 + 1, vy.round() as i64));
                }
                let near_depth_edge = ((z - d as f64) / z).abs() < 1e-6 || (along - along.floor() - 0.5).abs() < EPS;
                let kept = z <= d as f64;
                let (x, y) = if vertical { (line, cell as usize) } else { (cell as usize, line) };
                let b = if vertical { 1u16 << bit } else { 1u16 << (8 + bit) };
                let (must, may) = if centre {
                    (&mut ex.must_centres[y * w + x], &mut ex.may_centres[y * w + x])
                } else {
                    (&mut ex.must_sides[y * (w + 1) + x], &mut ex.may_sides[y * (w + 1) + x])
                };
                if near_bit_edge || near_depth_edge {
                    // Either this bit, its neighbour, or nothing.
                    *may |= b | (b << 1) | (b >> 1);
                } else if kept {
                    *must |= b;
                }
            }
        }
    }
    ex
}

fn random_edges(rng: &mut Rng, n: usize) -> Vec<EdgeSegment> {
    (0..n)
        .map(|_| {
            let p = |rng: &mut Rng| Vec3::new(rng.unit() * 8.0 - 4.0, rng.unit() * 8.0 - 4.0, rng.unit() * -9.0 + 1.5);
            let a = p(rng);
            // Mostly short segments, some long ones, some crossing the eye plane.
            let b = if rng.chance(0.7) { a + (p(rng) - Vec3::new(0.0, 0.0, -3.0)) * 0.1 } else { p(rng) };
            EdgeSegment { a, b, kind: EdgeKind::Silhouette, object: 0 }
        })
        .collect()
}

#[test]
fn crossings_and_culling_match_plane_intersections_in_3d() {
    let mut rng = Rng(11);
    for (w, h, centres) in [(37, 29, true), (64, 48, false), (130, 17, true), (3, 70, true)] {
        let cam = camera(w, h);
        let mut depth = ConservativeDepth::new(w, h);
        for d in depth.depth.iter_mut() {
            *d = if rng.chance(0.3) { f32::INFINITY } else { 1.0 + 8.0 * rng.unit() };
        }
        let edges = random_edges(&mut rng, 300);
        let mut out = Boundaries::new(w, h);
        if centres {
            out.centres = vec![0; w * h];
        }
        let mut r = Rasterizer::new();
        let counts = r.rasterize(&edges, &cam, &depth, &mut out);
        let ex = expected(&cam, w, h, &edges, &depth);
        let check = |got: &[u16], must: &[u16], may: &[u16], what: &str| {
            for i in 0..got.len() {
                assert_eq!(got[i] & must[i], must[i], "{what} {i} of {w}x{h}: missing {:016b}", must[i] & !got[i]);
                assert_eq!(got[i] & !(must[i] | may[i]), 0, "{what} {i} of {w}x{h}: extra {:016b}", got[i] & !(must[i] | may[i]));
            }
        };
        check(&out.sides, &ex.must_sides, &ex.may_sides, "side vertex");
        if centres {
            check(&out.centres, &ex.must_centres, &ex.may_centres, "centre");
        }
        assert!(counts.fragments > 100 && counts.culled > 50, "{counts:?}");
        assert!(counts.on_screen < counts.segments);
        // Rasterizing again gives the same result (buffers are cleared).
        let before = out.sides.clone();
        r.rasterize(&edges, &cam, &depth, &mut out);
        assert_eq!(before, out.sides);
    }
}

#[test]
fn a_long_straight_edge_makes_a_chain_of_simple_pixels() {
    let (w, h) = (40, 30);
    let cam = camera(w, h);
    let depth = ConservativeDepth::new(w, h);
    // A segment far beyond the screen on both sides, in front of the camera.
    let p = |sx: f32, sy: f32| {
        let (o, d) = cam.ray(sx, sy);
        o + d * 4.0
    };
    let edges = [EdgeSegment { a: p(-30.0, -3.3), b: p(70.0, 40.1), kind: EdgeKind::Sharp, object: 1 }];
    let mut out = Boundaries::new(w, h);
    Rasterizer::new().rasterize(&edges, &cam, &depth, &mut out);
    let (mut simple, mut complex) = (0, 0);
    for y in 0..h {
        for x in 0..w {
            let c = PIXEL.classify(out.mask(x, y));
            if PIXEL.is_simple(c) {
                simple += 1;
            } else if c != crate::epi::code::EMPTY {
                complex += 1;
            }
        }
    }
    assert!(simple > 40, "{simple} simple pixels");
    // A straight line crosses every pixel it enters through two different sides, except
    // where it passes within rounding of a pixel corner.
    assert!(complex <= 2, "{complex} complex pixels");
    let _ = Cell { segments: 8, regions: 4 };
}

#[test]
fn fine_positions_are_the_crossings_and_end_bits_the_pixels_holding_segment_ends() {
    let (w, h) = (40, 30);
    let cam = camera(w, h);
    let depth = ConservativeDepth::new(w, h);
    let prj = SegmentProjector::new(&cam, w, h);
    let mut rng = Rng(5);
    let at = |sx: f32, sy: f32, z: f32| {
        let (o, d) = cam.ray(sx, sy);
        o + d * z
    };
    let (mut checked, mut ends_seen) = (0, 0);
    for trial in 0..60 {
        // One segment at a time (a side holds at most one crossing), ends on and off screen.
        let mut end = || at(rng.range(-10.0, w as f32 + 10.0), rng.range(-10.0, h as f32 + 10.0), rng.range(2.0, 6.0));
        let e = EdgeSegment { a: end(), b: end(), kind: EdgeKind::Sharp, object: 1 };
        let mut out = Boundaries::new(w, h);
        Rasterizer::new().rasterize(&[e], &cam, &depth, &mut out);
        for y in 0..=h {
            for x in 0..=w {
                let (v, f) = (out.sides[y * (w + 1) + x], out.fine[y * (w + 1) + x]);
                // (vertical line x: position along y; horizontal line y: along x)
                for (vertical, bits, byte, line, cell) in [(true, v & 0xFF, f & 0xFF, x, y), (false, v >> 8, f >> 8, y, x)] {
                    if bits == 0 {
                        continue;
                    }
                    assert_eq!(bits.count_ones(), 1, "trial {trial}: ({x}, {y})");
                    let q = bits.trailing_zeros() << 8 | u32::from(byte);
                    let (pos, _) = cross(&cam, w, h, &e, vertical, line as f64).expect("a recorded crossing is a crossing");
                    let exact = pos - cell as f64;
                    assert!((fine_fraction(q) as f64 - exact).abs() <= 2f64.powi(-12) + 1e-6, "trial {trial}: ({x}, {y}) vertical {vertical}: {} against {exact}", fine_fraction(q));
                    checked += 1;
                }
            }
        }
        // The end bits: exactly the pixels holding an on-screen end.
        let mut want = vec![0u64; out.ends.len()];
        for p in [e.a, e.b] {
            let [sx, sy] = prj.pixel(p).expect("in front");
            if sx >= 0.0 && sy >= 0.0 && sx < w as f64 && sy < h as f64 {
                want[sy as usize * w.div_ceil(64) + sx as usize / 64] |= 1 << (sx as usize % 64);
                ends_seen += 1;
            }
        }
        assert_eq!(out.ends, want, "trial {trial}");
    }
    assert!(checked > 60 * 20 && ends_seen > 30, "{checked} crossings, {ends_seen} ends");
}
