//! `cornell`: the Cornell box from Cornell's published measurements (converted from
//! millimetres to metres), a short and a tall box, lit by the square ceiling luminaire as a
//! polygonal area light (soft shadows). `cornell-point`: the same room lit by a point light
//! just under the ceiling centre (hard shadows).
use super::object;
use super::shapes::polygon;
use crate::{Camera, Light, Material, Mesh, NoProgress, Orbit, Scene};
use glam::{Vec2, Vec3};

const MM: f32 = 0.001;

fn mm(x: f32, y: f32, z: f32) -> Vec3 {
    Vec3::new(x, y, z) * MM
}

/// A closed prism over a floor quad `foot` (x, z in mm) of height `h` mm, wound outward.
fn prism(foot: [Vec2; 4], h: f32) -> Mesh {
    let mut p = Vec::new();
    for f in foot {
        p.push(mm(f.x, 0.0, f.y));
    }
    for f in foot {
        p.push(mm(f.x, h, f.y));
    }
    let mut t = vec![[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]];
    for i in 0..4u32 {
        let j = (i + 1) % 4;
        t.push([i, 4 + i, 4 + j]);
        t.push([i, 4 + j, j]);
    }
    let mut m = Mesh::from_triangles(p, t, &NoProgress);
    if m.signed_volume() < 0.0 {
        m.flip();
    }
    m
}

pub fn cornell(point_light: bool) -> Scene {
    let white = Material::diffuse("white", Vec3::splat(0.73));
    let red = Material::diffuse("red", Vec3::new(0.63, 0.065, 0.05));
    let green = Material::diffuse("green", Vec3::new(0.14, 0.45, 0.091));
    // Walls wound so that their normals face the inside of the room.
    let mut objects = vec![
        object(
            "floor",
            polygon(&[mm(552.8, 0.0, 0.0), mm(0.0, 0.0, 0.0), mm(0.0, 0.0, 559.2), mm(549.6, 0.0, 559.2)]),
            white.clone(),
        ),
        object(
            "ceiling",
            polygon(&[mm(556.0, 548.8, 0.0), mm(556.0, 548.8, 559.2), mm(0.0, 548.8, 559.2), mm(0.0, 548.8, 0.0)]),
            white.clone(),
        ),
        object(
            "back",
            polygon(&[mm(549.6, 0.0, 559.2), mm(0.0, 0.0, 559.2), mm(0.0, 548.8, 559.2), mm(556.0, 548.8, 559.2)]),
            white.clone(),
        ),
        object(
            "greenwall",
            polygon(&[mm(0.0, 0.0, 559.2), mm(0.0, 0.0, 0.0), mm(0.0, 548.8, 0.0), mm(0.0, 548.8, 559.2)]),
            green,
        ),
        object(
            "redwall",
            polygon(&[mm(552.8, 0.0, 0.0), mm(549.6, 0.0, 559.2), mm(556.0, 548.8, 559.2), mm(556.0, 548.8, 0.0)]),
            red,
        ),
        object(
            "shortbox",
            prism([Vec2::new(130.0, 65.0), Vec2::new(82.0, 225.0), Vec2::new(240.0, 272.0), Vec2::new(290.0, 114.0)], 165.0),
            white.clone(),
        ),
        object(
            "tallbox",
            prism([Vec2::new(423.0, 247.0), Vec2::new(265.0, 296.0), Vec2::new(314.0, 456.0), Vec2::new(472.0, 406.0)], 330.0),
            white,
        ),
    ];
    let radiance = Vec3::new(17.0, 12.0, 4.0);
    // The luminaire hangs 0.5 mm under the ceiling and faces down.
    let lum = [mm(343.0, 548.3, 227.0), mm(343.0, 548.3, 332.0), mm(213.0, 548.3, 332.0), mm(213.0, 548.3, 227.0)];
    let area = Light::Area { vertices: lum.to_vec(), radiance };
    let lights = if point_light {
        // Same power through the lower hemisphere as the area light: I = L * A.
        vec![Light::Point { position: mm(278.0, 540.0, 279.5), intensity: radiance * area.area() }]
    } else {
        objects.push(object("luminaire", polygon(&lum), Material::emissive("light", radiance)));
        vec![area]
    };
    Scene {
        name: if point_light { "cornell-point" } else { "cornell" }.to_string(),
        objects,
        lights,
        camera: Camera {
            eye: mm(278.0, 273.0, -800.0),
            target: mm(278.0, 273.0, 0.0),
            up: Vec3::Y,
            fov_y_degrees: 39.3077,
        },
        ambient: Vec3::splat(0.03),
        background: Vec3::ZERO,
        orbit: Some(ORBIT),
    }
}

/// Inside the box, 14 cm above the tall box (its top is at 0.330 m; the eye circles at
/// 0.470 m, 8 cm under the ceiling and 5 cm from the walls at the nearest), looking down at
/// the two boxes with a wide lens, so both are in view all the way round; it starts at the
/// front, looking toward the back wall like the default camera.
const ORBIT: Orbit = Orbit {
    pivot: Vec3::new(0.278, 0.12, 0.28),
    radius: 0.4134,
    elevation_degrees: 57.85,
    start_azimuth_degrees: 180.0,
    fov_y_degrees: 65.0,
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builtin::load;

    #[test]
    fn cornell_geometry() {
        let s = load("cornell").unwrap();
        for name in ["shortbox", "tallbox"] {
            let o = &s.objects[s.object_id(name).unwrap() as usize];
            assert_eq!(o.mesh.boundary_edges(), 0);
            assert!(o.mesh.signed_volume() > 0.0);
        }
        // wall normals face the room centre
        let centre = mm(278.0, 274.4, 279.6);
        for o in &s.objects[..5] {
            let n = o.mesh.face_normals[0];
            let p = o.mesh.positions[0];
            assert!((centre - p).dot(n) > 0.0, "{} faces inward", o.name);
        }
        let light_n = s.lights[0].normal().unwrap();
        assert!(light_n.y < -0.99, "luminaire faces down");
        let lum = &s.objects[s.object_id("luminaire").unwrap() as usize];
        assert!(lum.mesh.face_normals[0].y < -0.99);
    }
}
