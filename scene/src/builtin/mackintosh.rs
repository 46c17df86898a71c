//! `mackintosh` (paper 000 Table 1 and Figures 10–11: "The Mackintosh room … has three
//! lights and is rendered with the global illumination shader"; Figure 10: "a tea-stand with
//! fine geometry and complex shadows"): a white room after Charles Rennie Mackintosh's
//! interiors, for the `gi` shader. Fine geometry casting fine shadows:
//! - a tall latticed window (a grid of small square panes) with daylight behind it: an area
//!   light outside the window throws the lattice's shadow grid across the floor and table;
//! - six high-back chairs (Argyle style): slender posts, two long back slats and a
//!   latticed top panel, stretchers between the legs;
//! - a dining table with slatted aprons, a three-tier tea-stand with lattice trays, a
//!   three-leaf lattice screen, and a sideboard with latticed doors;
//! - a hanging lamp over the table (a lattice shade and a small area light under it) and a
//!   wall light (a point light): three lights.
//!
//! About 40,000 triangles, most of them the small faces of lattices and slats. The room is
//! white (colour bleeding and lit ceilings under `gi`), the furniture dark stained oak.
use super::shapes::{cuboid, grid_plate, polygon, Parts};
use super::{object, object_at};
use crate::{Camera, Light, Material, Mesh, Object, Orbit, Scene};
use glam::{Affine3A, Mat3A, Vec3, Vec3A};

/// Room extent: x ∈ [0, W], z ∈ [0, D], y ∈ [0, H] (metres).
const W: f32 = 5.0;
const D: f32 = 4.2;
const H: f32 = 2.8;
const WALL: f32 = 0.1;
/// The window in the x = 0 wall: z and y ranges of its opening.
const WIN_Z: (f32, f32) = (1.2, 3.0);
const WIN_Y: (f32, f32) = (0.9, 2.4);
/// The table's centre (the orbit's pivot).
const TABLE: Vec3 = Vec3::new(2.8, 0.0, 2.2);

fn bx(p: &mut Parts, lo: Vec3, hi: Vec3) {
    p.add(&cuboid(lo, hi), Affine3A::IDENTITY);
}

/// A lattice panel: `grid_plate` (a square in x–z, thickness along y) mapped onto the
/// rectangle spanned by `u` and `v` from `corner`, `thickness` along `n` (the panel's
/// frame, one vector each, reads better than a struct built for every call).
#[allow(clippy::too_many_arguments)]
fn lattice(p: &mut Parts, cells: u32, bar: f32, corner: Vec3, u: Vec3, v: Vec3, n: Vec3, thickness: f32) {
    let plate = grid_plate(1.0, cells, bar, 1.0);
    // Plate coordinates: x and z in [-0.5, 0.5], y in [0, 1].
    let m = Mat3A::from_cols(Vec3A::from(u), Vec3A::from(n * thickness), Vec3A::from(v));
    let t = Affine3A { matrix3: m, translation: Vec3A::from(corner + 0.5 * u + 0.5 * v) };
    p.add(&plate, t);
}

/// The x = 0 wall with the window opening (boxes around it, none sharing a vertex).
fn window_wall(p: &mut Parts) {
    let (x0, x1) = (-WALL, 0.0);
    bx(p, Vec3::new(x0, 0.0, -WALL), Vec3::new(x1, WIN_Y.0, D + WALL));
    bx(p, Vec3::new(x0, WIN_Y.1, -WALL), Vec3::new(x1, H, D + WALL));
    bx(p, Vec3::new(x0, WIN_Y.0 + 0.001, -WALL), Vec3::new(x1, WIN_Y.1 - 0.001, WIN_Z.0));
    bx(p, Vec3::new(x0, WIN_Y.0 + 0.001, WIN_Z.1), Vec3::new(x1, WIN_Y.1 - 0.001, D + WALL));
}

/// The other three walls (closed boxes).
fn walls(p: &mut Parts) {
    bx(p, Vec3::new(W, 0.0, -WALL), Vec3::new(W + WALL, H, D + WALL));
    bx(p, Vec3::new(0.001, 0.0, -WALL), Vec3::new(W - 0.001, H, 0.0));
    bx(p, Vec3::new(0.001, 0.0, D), Vec3::new(W - 0.001, H, D + WALL));
}

/// The window's lattice: small square panes (12 × 10) in the opening.
fn window_lattice(p: &mut Parts) {
    let (dz, dy) = (WIN_Z.1 - WIN_Z.0, WIN_Y.1 - WIN_Y.0);
    lattice(p, 12, 0.012, Vec3::new(-0.07, WIN_Y.0, WIN_Z.0), Vec3::Z * dz, Vec3::Y * dy, Vec3::X, 0.04);
}

/// A high-back chair facing −z (its back at +z), seat centre at the origin's floor point.
fn chair(p: &mut Parts) {
    let (s, seat_y, top) = (0.21, 0.45, 1.36);
    bx(p, Vec3::new(-s, seat_y - 0.03, -s), Vec3::new(s, seat_y, s));
    // Front legs, and the back posts running up to the top panel.
    for x in [-s, s - 0.035] {
        bx(p, Vec3::new(x, 0.0, -s), Vec3::new(x + 0.035, seat_y - 0.03, -s + 0.035));
        bx(p, Vec3::new(x, 0.0, s - 0.035), Vec3::new(x + 0.035, top, s));
    }
    // Stretchers low between the legs, and a rail under the seat.
    for y in [0.12, 0.3] {
        bx(p, Vec3::new(-s + 0.035, y, -s + 0.005), Vec3::new(s - 0.035, y + 0.02, -s + 0.03));
        bx(p, Vec3::new(-s + 0.035, y, s - 0.03), Vec3::new(s - 0.035, y + 0.02, s - 0.005));
        bx(p, Vec3::new(-s + 0.005, y + 0.05, -s + 0.035), Vec3::new(-s + 0.03, y + 0.07, s - 0.035));
        bx(p, Vec3::new(s - 0.03, y + 0.05, -s + 0.035), Vec3::new(s - 0.005, y + 0.07, s - 0.035));
    }
    // Two long back slats between the posts, and the rails they run between.
    for x in [-0.07, 0.03] {
        bx(p, Vec3::new(x, seat_y, s - 0.025), Vec3::new(x + 0.04, top - 0.22, s - 0.01));
    }
    bx(p, Vec3::new(-s + 0.035, top - 0.24, s - 0.03), Vec3::new(s - 0.035, top - 0.22, s - 0.005));
    // The latticed top panel (a 4 × 3 grid of small square holes).
    lattice(p, 4, 0.02, Vec3::new(-s + 0.035, top - 0.22, s - 0.025), Vec3::X * (2.0 * s - 0.07), Vec3::Y * 0.2, Vec3::Z, 0.015);
}

/// The dining table, centred on the origin's floor point, long side along x.
fn table(p: &mut Parts) {
    let (hx, hz, top) = (0.8, 0.45, 0.74);
    bx(p, Vec3::new(-hx, top, -hz), Vec3::new(hx, top + 0.035, hz));
    for (x, z) in [(-hx + 0.05, -hz + 0.05), (hx - 0.1, -hz + 0.05), (-hx + 0.05, hz - 0.1), (hx - 0.1, hz - 0.1)] {
        bx(p, Vec3::new(x, 0.0, z), Vec3::new(x + 0.05, top, z + 0.05));
    }
    // Slatted aprons on the long sides: a rail, 14 vertical slats and a low stretcher.
    for z in [-hz + 0.06, hz - 0.08] {
        bx(p, Vec3::new(-hx + 0.1, top - 0.06, z), Vec3::new(hx - 0.1, top - 0.001, z + 0.02));
        bx(p, Vec3::new(-hx + 0.1, 0.1, z), Vec3::new(hx - 0.1, 0.13, z + 0.02));
        for k in 0..14 {
            let x = -hx + 0.14 + k as f32 * ((2.0 * hx - 0.28) / 13.0) - 0.01;
            bx(p, Vec3::new(x, 0.13, z + 0.004), Vec3::new(x + 0.02, top - 0.06, z + 0.016));
        }
    }
}

/// The tea-stand (paper 000 Figure 10): four slender posts and three square lattice trays.
fn tea_stand(p: &mut Parts) {
    let s = 0.2;
    for (x, z) in [(-s, -s), (s - 0.02, -s), (-s, s - 0.02), (s - 0.02, s - 0.02)] {
        bx(p, Vec3::new(x, 0.0, z), Vec3::new(x + 0.02, 1.2, z + 0.02));
    }
    for y in [0.3, 0.65, 1.0] {
        lattice(p, 9, 0.008, Vec3::new(-s + 0.02, y, -s + 0.02), Vec3::X * (2.0 * s - 0.04), Vec3::Z * (2.0 * s - 0.04), Vec3::Y, 0.012);
        // A rim around each tray.
        bx(p, Vec3::new(-s + 0.02, y, -s + 0.005), Vec3::new(s - 0.02, y + 0.05, -s + 0.015));
        bx(p, Vec3::new(-s + 0.02, y, s - 0.015), Vec3::new(s - 0.02, y + 0.05, s - 0.005));
    }
    // Finials.
    for (x, z) in [(-s, -s), (s - 0.02, -s), (-s, s - 0.02), (s - 0.02, s - 0.02)] {
        bx(p, Vec3::new(x - 0.01, 1.2, z - 0.01), Vec3::new(x + 0.03, 1.24, z + 0.03));
    }
}

/// One leaf of the screen: a frame around a fine lattice, in the x–y plane.
fn screen_leaf(p: &mut Parts, w: f32, h: f32) {
    let f = 0.03;
    bx(p, Vec3::new(0.0, 0.0, 0.0), Vec3::new(f, h, f));
    bx(p, Vec3::new(w - f, 0.0, 0.0), Vec3::new(w, h, f));
    bx(p, Vec3::new(f, h - f, 0.0), Vec3::new(w - f, h, f));
    bx(p, Vec3::new(f, 0.15, 0.0), Vec3::new(w - f, 0.15 + f, f));
    lattice(p, 10, 0.01, Vec3::new(f, 0.15 + f, 0.008), Vec3::X * (w - 2.0 * f), Vec3::Y * (h - 0.15 - 2.0 * f), Vec3::Z, 0.014);
}

/// A sideboard with two latticed doors, its back at +z, centred on the origin's floor point.
fn sideboard(p: &mut Parts) {
    let (hx, d, h) = (0.8, 0.4, 0.9);
    bx(p, Vec3::new(-hx, 0.1, -d + 0.02), Vec3::new(hx, h, 0.0));
    bx(p, Vec3::new(-hx - 0.02, h, -d - 0.02), Vec3::new(hx + 0.02, h + 0.03, 0.01));
    for x in [-hx, hx - 0.04] {
        bx(p, Vec3::new(x, 0.0, -d), Vec3::new(x + 0.04, 0.1, -d + 0.04));
    }
    for x0 in [-hx + 0.03, 0.01] {
        lattice(p, 6, 0.012, Vec3::new(x0, 0.15, -d), Vec3::X * (hx - 0.04), Vec3::Y * (h - 0.2), Vec3::Z, 0.018);
    }
}

/// The hanging lamp's shade: four lattice sides of a square lantern and a cord, around the
/// origin (the light's centre) — open below, where the light hangs.
fn lamp_shade(p: &mut Parts) {
    let (s, h) = (0.2, 0.3);
    let sides = [
        (Vec3::new(-s, 0.0, -s), Vec3::X * 2.0 * s, Vec3::Z),
        (Vec3::new(-s, 0.0, s - 0.01), Vec3::X * 2.0 * s, Vec3::Z),
        (Vec3::new(-s, 0.0, -s + 0.01), Vec3::Z * (2.0 * s - 0.02), Vec3::X),
        (Vec3::new(s - 0.01, 0.0, -s + 0.01), Vec3::Z * (2.0 * s - 0.02), Vec3::X),
    ];
    for (corner, u, n) in sides {
        lattice(p, 5, 0.012, corner, u, Vec3::Y * h, n, 0.01);
    }
    bx(p, Vec3::new(-s, h, -s), Vec3::new(s, h + 0.02, s));
    bx(p, Vec3::new(-0.006, h + 0.02, -0.006), Vec3::new(0.006, H - 1.7, 0.006));
}

fn mesh(f: impl Fn(&mut Parts)) -> Mesh {
    let mut p = Parts::default();
    f(&mut p);
    p.mesh()
}

pub fn mackintosh() -> Scene {
    let mut objects: Vec<Object> = Vec::new();
    let white = Material::diffuse("white plaster", Vec3::new(0.82, 0.81, 0.78));
    let oak = Material::diffuse("stained oak", Vec3::new(0.16, 0.11, 0.07));
    objects.push(object(
        "floor",
        polygon(&[Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, D), Vec3::new(W, 0.0, D), Vec3::new(W, 0.0, 0.0)]),
        Material::diffuse("floor boards", Vec3::new(0.45, 0.33, 0.22)),
    ));
    objects.push(object(
        "ceiling",
        polygon(&[Vec3::new(0.0, H, 0.0), Vec3::new(W, H, 0.0), Vec3::new(W, H, D), Vec3::new(0.0, H, D)]),
        white.clone(),
    ));
    objects.push(object("window wall", mesh(window_wall), white.clone()));
    objects.push(object("walls", mesh(walls), white.clone()));
    objects.push(object("window lattice", mesh(window_lattice), Material::diffuse("painted wood", Vec3::splat(0.85))));
    objects.push(object_at("table", mesh(table), oak.clone(), Affine3A::from_translation(TABLE)));
    // Six chairs around the table, backs away from it: two on each long side, one at each end.
    let chair_m = mesh(chair);
    let seats = [(-0.4, 0.78, 0.0), (0.4, 0.78, 0.0), (-0.4, -0.78, 1.0), (0.4, -0.78, 1.0), (-1.2, 0.0, 1.5), (1.2, 0.0, 0.5)];
    for (k, (x, z, turn)) in seats.iter().enumerate() {
        let t = Affine3A::from_translation(TABLE + Vec3::new(*x, 0.0, *z)) * Affine3A::from_rotation_y(turn * std::f32::consts::PI);
        objects.push(object_at(&format!("chair{k}"), chair_m.clone(), oak.clone(), t));
    }
    objects.push(object_at("tea-stand", mesh(tea_stand), oak.clone(), Affine3A::from_translation(Vec3::new(0.55, 0.0, 0.5))));
    // The screen: three leaves standing in a zigzag along the x = W wall.
    let mut screen = Parts::default();
    let leaf = mesh(|p| screen_leaf(p, 0.45, 1.7));
    for k in 0..3 {
        let turn = if k % 2 == 0 { 1.4 } else { 1.75 };
        screen.add(&leaf, Affine3A::from_translation(Vec3::new(4.65 + 0.06 * (k % 2) as f32, 0.0, 0.35 + 0.44 * k as f32)) * Affine3A::from_rotation_y(turn));
    }
    objects.push(object("screen", screen.mesh(), oak.clone()));
    objects.push(object_at("sideboard", mesh(sideboard), oak.clone(), Affine3A::from_translation(Vec3::new(1.6, 0.0, D - 0.02))));

    let mut lights = Vec::new();
    // Daylight behind the window: a panel outside facing +x, larger than the opening.
    let x = -0.6;
    let (z0, z1, y0, y1) = (WIN_Z.0 - 0.3, WIN_Z.1 + 0.3, WIN_Y.0 - 0.2, WIN_Y.1 + 0.3);
    let sky = [Vec3::new(x, y0, z0), Vec3::new(x, y1, z0), Vec3::new(x, y1, z1), Vec3::new(x, y0, z1)];
    let daylight = Vec3::new(5.5, 6.0, 7.0);
    objects.push(object("daylight", polygon(&sky), Material::emissive("sky", daylight)));
    lights.push(Light::Area { vertices: sky.to_vec(), radiance: daylight });
    // The hanging lamp: a small panel facing down inside the lattice shade.
    let lamp_y = 1.7;
    let h = 0.1;
    let c = TABLE;
    let y = lamp_y + 0.05;
    let panel = [Vec3::new(c.x - h, y, c.z - h), Vec3::new(c.x + h, y, c.z - h), Vec3::new(c.x + h, y, c.z + h), Vec3::new(c.x - h, y, c.z + h)];
    let warm = Vec3::new(40.0, 32.0, 22.0);
    objects.push(object("lamp", polygon(&panel), Material::emissive("lamp", warm)));
    lights.push(Light::Area { vertices: panel.to_vec(), radiance: warm });
    objects.push(object_at("lamp shade", mesh(lamp_shade), oak, Affine3A::from_translation(Vec3::new(c.x, lamp_y, c.z))));
    // A wall light by the sideboard.
    lights.push(Light::Point { position: Vec3::new(3.4, 1.9, D - 0.15), intensity: Vec3::new(1.6, 1.4, 1.1) });

    Scene {
        name: "mackintosh".into(),
        objects,
        lights,
        camera: Camera { eye: Vec3::new(4.6, 1.55, 3.85), target: Vec3::new(1.3, 0.85, 1.7), up: Vec3::Y, fov_y_degrees: 55.0 },
        ambient: Vec3::splat(0.02),
        background: Vec3::ZERO,
        // Around the table, above the chairs' backs and under the lamp.
        orbit: Some(Orbit { pivot: TABLE + Vec3::new(0.0, 0.8, 0.0), radius: 1.8, elevation_degrees: 25.0, start_azimuth_degrees: 60.0, fov_y_degrees: 55.0 }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::transformed_box;

    #[test]
    fn three_lights_and_tens_of_thousands_of_small_faces() {
        let s = mackintosh();
        s.validate().unwrap();
        assert_eq!(s.lights.len(), 3);
        let tris = s.triangle_count();
        assert!((20_000..80_000).contains(&tris), "{tris} triangles");
        // Fine geometry: the median face is small against the room (a few cm²).
        let mut areas: Vec<f32> = s
            .objects
            .iter()
            .flat_map(|o| {
                let m = &o.mesh;
                let t = o.transform;
                m.triangles.iter().map(move |tr| {
                    let [a, b, c] = tr.map(|i| t.transform_point3(m.positions[i as usize]));
                    0.5 * (b - a).cross(c - a).length()
                })
            })
            .collect();
        areas.sort_by(f32::total_cmp);
        assert!(areas[areas.len() / 2] < 4e-4, "median face {} m²", areas[areas.len() / 2]);
        // The daylight faces into the room through the window; the lamp faces down.
        assert!(s.lights[0].normal().unwrap().x > 0.99);
        assert!(s.lights[1].normal().unwrap().y < -0.99);
        for name in ["walls", "window wall"] {
            assert_eq!(s.objects[s.object_id(name).unwrap() as usize].mesh.boundary_edges(), 0, "{name} closed");
        }
    }

    #[test]
    fn the_orbit_stays_in_the_room_and_out_of_the_furniture() {
        let s = mackintosh();
        let orbit = s.orbit.unwrap();
        let shell = ["floor", "ceiling", "walls", "window wall", "daylight"];
        for k in 0..72 {
            let eye = orbit.camera_at(k as f32 * 5.0).eye;
            assert!(eye.x > 0.1 && eye.x < W - 0.1 && eye.z > 0.1 && eye.z < D - 0.1 && eye.y > 0.1 && eye.y < H - 0.1, "{eye}");
            for o in s.objects.iter().filter(|o| !shell.contains(&o.name.as_str())) {
                let (lo, hi) = transformed_box(&o.transform, o.mesh.bounds);
                let inside = eye.cmpgt(lo - 0.05).all() && eye.cmplt(hi + 0.05).all();
                assert!(!inside, "eye {eye} at {}° is inside {}", k * 5, o.name);
            }
        }
        let cam = s.camera;
        for o in s.objects.iter().filter(|o| !shell.contains(&o.name.as_str())) {
            let (lo, hi) = transformed_box(&o.transform, o.mesh.bounds);
            assert!(!(cam.eye.cmpgt(lo).all() && cam.eye.cmplt(hi).all()), "camera inside {}", o.name);
        }
    }
}
