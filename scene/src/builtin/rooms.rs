//! `rooms` (paper 000 Figure 12, Table 1: "a multi-room scene with six lights", 15,006
//! polygons): a house of 3 × 2 rooms of 4 × 4 m with doorways between neighbours, each
//! room lit by a square ceiling area light and furnished with a table, two chairs, a shelf,
//! a ball on the table and a ring on the floor.
use super::shapes::{cuboid, polygon, sphere, torus, Parts};
use super::{object, object_at};
use crate::{Camera, Light, Material, Mesh, Object, Orbit, Scene};
use glam::{Affine3A, Vec3};

const ROOM: f32 = 4.0;
const HEIGHT: f32 = 2.6;
const WALL: f32 = 0.1;
const DOOR: (f32, f32) = (1.5, 2.4);
const DOOR_TOP: f32 = 2.1;

fn b(lo: Vec3, hi: Vec3) -> Mesh {
    cuboid(lo, hi)
}

/// A wall along x from `x0` to `x1` centred on `z`, with the given door openings (x
/// ranges). The lintel over a door reaches 2 cm into the wall on either side, so no two
/// boxes share a vertex (shared vertices would weld into edges of four faces).
fn wall_x(p: &mut Parts, x0: f32, x1: f32, z: f32, doors: &[(f32, f32)]) {
    let (z0, z1) = (z - WALL * 0.5, z + WALL * 0.5);
    let mut from = x0;
    for &(d0, d1) in doors {
        p.add(&b(Vec3::new(from, 0.0, z0), Vec3::new(d0, HEIGHT, z1)), Affine3A::IDENTITY);
        p.add(&b(Vec3::new(d0 - 0.02, DOOR_TOP, z0), Vec3::new(d1 + 0.02, HEIGHT, z1)), Affine3A::IDENTITY);
        from = d1;
    }
    p.add(&b(Vec3::new(from, 0.0, z0), Vec3::new(x1, HEIGHT, z1)), Affine3A::IDENTITY);
}

/// A wall along z (see [`wall_x`]; doors are z ranges).
fn wall_z(p: &mut Parts, z0: f32, z1: f32, x: f32, doors: &[(f32, f32)]) {
    let swap = Affine3A::from_cols_array(&[0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let mut q = Parts::default();
    wall_x(&mut q, z0, z1, x, doors);
    p.add(&q.mesh(), swap);
}

fn table(p: &mut Parts) {
    p.add(&b(Vec3::new(-0.6, 0.72, -0.4), Vec3::new(0.6, 0.77, 0.4)), Affine3A::IDENTITY);
    for (x, z) in [(-0.55, -0.35), (0.5, -0.35), (-0.55, 0.3), (0.5, 0.3)] {
        p.add(&b(Vec3::new(x, 0.0, z), Vec3::new(x + 0.05, 0.72, z + 0.05)), Affine3A::IDENTITY);
    }
}

fn chair(p: &mut Parts) {
    p.add(&b(Vec3::new(-0.22, 0.42, -0.22), Vec3::new(0.22, 0.46, 0.22)), Affine3A::IDENTITY);
    p.add(&b(Vec3::new(-0.22, 0.46, 0.18), Vec3::new(0.22, 0.95, 0.22)), Affine3A::IDENTITY);
    for (x, z) in [(-0.22, -0.22), (0.18, -0.22), (-0.22, 0.18), (0.18, 0.18)] {
        p.add(&b(Vec3::new(x, 0.0, z), Vec3::new(x + 0.04, 0.42, z + 0.04)), Affine3A::IDENTITY);
    }
}

fn shelf(p: &mut Parts) {
    // Two sides, four boards.
    p.add(&b(Vec3::new(-0.5, 0.0, -0.15), Vec3::new(-0.47, 1.8, 0.15)), Affine3A::IDENTITY);
    p.add(&b(Vec3::new(0.47, 0.0, -0.15), Vec3::new(0.5, 1.8, 0.15)), Affine3A::IDENTITY);
    for k in 0..4 {
        let y = 0.1 + 0.55 * k as f32;
        p.add(&b(Vec3::new(-0.47, y, -0.15), Vec3::new(0.47, y + 0.03, 0.15)), Affine3A::IDENTITY);
    }
}

pub fn rooms() -> Scene {
    let (nx, nz) = (3usize, 2usize);
    let (w, d) = (ROOM * nx as f32, ROOM * nz as f32);
    let mut objects: Vec<Object> = Vec::new();
    objects.push(object(
        "floor",
        polygon(&[Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, d), Vec3::new(w, 0.0, d), Vec3::new(w, 0.0, 0.0)]),
        Material::diffuse("floor", Vec3::new(0.55, 0.45, 0.35)),
    ));
    objects.push(object(
        "ceiling",
        polygon(&[Vec3::new(0.0, HEIGHT, 0.0), Vec3::new(w, HEIGHT, 0.0), Vec3::new(w, HEIGHT, d), Vec3::new(0.0, HEIGHT, d)]),
        Material::diffuse("ceiling", Vec3::splat(0.8)),
    ));
    // Walls: the lines x = k·ROOM run the full depth (a little past the outer walls, so
    // the corners close without shared vertices); the lines z = k·ROOM run between them,
    // touching their sides. Inner walls have a door in every room they bound.
    let mut walls = Parts::default();
    for k in 0..=nx {
        let inner = k > 0 && k < nx;
        let doors: Vec<(f32, f32)> =
            if inner { (0..nz).map(|r| (ROOM * r as f32 + DOOR.0, ROOM * r as f32 + DOOR.1)).collect() } else { Vec::new() };
        wall_z(&mut walls, -WALL * 0.6, d + WALL * 0.6, ROOM * k as f32, &doors);
    }
    for j in 0..=nz {
        let inner = j > 0 && j < nz;
        for r in 0..nx {
            let (x0, x1) = (ROOM * r as f32 + WALL * 0.5, ROOM * (r + 1) as f32 - WALL * 0.5);
            let doors = if inner { vec![(ROOM * r as f32 + DOOR.0, ROOM * r as f32 + DOOR.1)] } else { Vec::new() };
            wall_x(&mut walls, x0, x1, ROOM * j as f32, &doors);
        }
    }
    objects.push(object("walls", walls.mesh(), Material::diffuse("plaster", Vec3::new(0.78, 0.76, 0.7))));

    let tints = [
        Vec3::new(1.0, 0.92, 0.8),
        Vec3::new(0.9, 0.95, 1.0),
        Vec3::new(1.0, 1.0, 0.9),
        Vec3::new(0.95, 0.9, 1.0),
        Vec3::new(1.0, 0.85, 0.85),
        Vec3::new(0.9, 1.0, 0.92),
    ];
    let wood = Material::diffuse("wood", Vec3::new(0.45, 0.3, 0.18));
    let cloth = Material::diffuse("cloth", Vec3::new(0.3, 0.4, 0.55));
    let (mut t, mut c, mut s) = (Parts::default(), Parts::default(), Parts::default());
    table(&mut t);
    chair(&mut c);
    shelf(&mut s);
    let (table_m, chair_m, shelf_m) = (t.mesh(), c.mesh(), s.mesh());
    let ball = sphere(0.16, 32, 16);
    let ring = torus(0.3, 0.07, 40, 20);
    let mut lights = Vec::new();
    for j in 0..nz {
        for i in 0..nx {
            let k = j * nx + i;
            let o = Vec3::new(ROOM * i as f32, 0.0, ROOM * j as f32);
            let at = |x: f32, z: f32, turn: f32| Affine3A::from_translation(o + Vec3::new(x, 0.0, z)) * Affine3A::from_rotation_y(turn);
            let jitter = (k as f32 * 0.37).sin() * 0.3;
            objects.push(object_at(&format!("table{k}"), table_m.clone(), wood.clone(), at(2.0 + jitter, 2.2, 0.1 * k as f32)));
            objects.push(object_at(&format!("chair{k}a"), chair_m.clone(), cloth.clone(), at(1.5 + jitter, 1.4, 3.0)));
            objects.push(object_at(&format!("chair{k}b"), chair_m.clone(), cloth.clone(), at(2.6 + jitter, 3.0, 0.2)));
            objects.push(object_at(&format!("shelf{k}"), shelf_m.clone(), wood.clone(), at(0.4, 3.2, std::f32::consts::FRAC_PI_2)));
            objects.push(object_at(
                &format!("ball{k}"),
                ball.clone(),
                Material::diffuse("ball", tints[k] * Vec3::new(0.7, 0.3, 0.2)),
                Affine3A::from_translation(o + Vec3::new(2.1 + jitter, 0.77 + 0.16 + 0.001, 2.3)),
            ));
            objects.push(object_at(
                &format!("ring{k}"),
                ring.clone(),
                Material::diffuse("ring", Vec3::new(0.6, 0.6, 0.2)),
                Affine3A::from_translation(o + Vec3::new(3.0, 0.071, 0.9)),
            ));
            // The lamp: a square panel just under the ceiling, facing down.
            let (cx, cz, h) = (o.x + 2.0, o.z + 2.0, 0.4);
            let y = HEIGHT - 0.005;
            let v = [Vec3::new(cx - h, y, cz - h), Vec3::new(cx + h, y, cz - h), Vec3::new(cx + h, y, cz + h), Vec3::new(cx - h, y, cz + h)];
            let radiance = tints[k] * 9.0;
            objects.push(object(&format!("lamp{k}"), polygon(&v), Material::emissive("lamp", radiance)));
            lights.push(Light::Area { vertices: v.to_vec(), radiance });
        }
    }
    Scene {
        name: "rooms".into(),
        objects,
        lights,
        camera: Camera { eye: Vec3::new(0.6, 1.6, 0.6), target: Vec3::new(6.0, 0.9, 2.2), up: Vec3::Y, fov_y_degrees: 60.0 },
        ambient: Vec3::splat(0.04),
        background: Vec3::ZERO,
        // In the first room, 1.9 m up (over the shelf, under the lamp), 1.4 m around its
        // table; it starts looking along +x at the table and through the doorway beyond.
        orbit: Some(Orbit {
            pivot: Vec3::new(2.0, 0.6, 2.2),
            radius: 1.9105,
            elevation_degrees: 42.88,
            start_azimuth_degrees: 270.0,
            fov_y_degrees: 60.0,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn six_lit_rooms_of_about_15000_polygons() {
        let s = rooms();
        s.validate().unwrap();
        assert_eq!(s.lights.len(), 6);
        let tris = s.triangle_count();
        assert!((13_000..20_000).contains(&tris), "{tris} triangles");
        for l in &s.lights {
            assert!(l.normal().unwrap().y < -0.99, "lamps face down");
        }
        // Every lamp is inside its room, under the ceiling.
        for (k, l) in s.lights.iter().enumerate() {
            let c = l.center();
            let (i, j) = (k % 3, k / 3);
            assert!(c.x > ROOM * i as f32 && c.x < ROOM * (i + 1) as f32 && c.z > ROOM * j as f32 && c.z < ROOM * (j + 1) as f32);
            assert!(c.y < HEIGHT);
        }
        // The walls are closed boxes.
        let walls = &s.objects[s.object_id("walls").unwrap() as usize];
        assert_eq!(walls.mesh.boundary_edges(), 0);
    }
}
