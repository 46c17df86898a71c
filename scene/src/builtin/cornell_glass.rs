//! `cornell-glass` (paper 004 Fig. 10, the `hybrid` shader's scene): the Cornell box of
//! [`super::cornell`] with a glass sphere on the floor and the top of the short box made a
//! mirror ("A glass sphere is added into the scene and the top of the small box is made
//! reflective"). The sphere is smooth glass (index 1.5) with exact per-corner normals; the
//! mirror is a polished silver plate lying 1 mm above the short box's top.
use super::cornell::cornell;
use super::object_at;
use super::shapes::{polygon, sphere};
use crate::{Bsdf, Material, Mesh, Scene};
use glam::{Affine3A, Vec3};

/// The glass sphere: radius and centre (on the floor, in front of the tall box).
pub const SPHERE_RADIUS: f32 = 0.09;
pub const SPHERE_CENTRE: Vec3 = Vec3::new(0.41, SPHERE_RADIUS + 1e-3, 0.13);

fn smooth_sphere(radius: f32) -> Mesh {
    let mut m = sphere(radius, 64, 32);
    let normals = m.triangles.iter().map(|t| t.map(|i| m.positions[i as usize].normalize_or_zero())).collect();
    m.corners.normals = Some(normals);
    m
}

pub fn cornell_glass() -> Scene {
    let mut s = cornell(false);
    s.name = "cornell-glass".into();
    let silver = (Vec3::new(0.155, 0.117, 0.138), Vec3::new(4.828, 3.122, 2.147));
    // The short box's top face, 1 mm up, wound to face up.
    let top = [
        Vec3::new(0.130, 0.166, 0.065),
        Vec3::new(0.082, 0.166, 0.225),
        Vec3::new(0.240, 0.166, 0.272),
        Vec3::new(0.290, 0.166, 0.114),
    ];
    let mut plate = polygon(&top);
    if plate.face_normals[0].y < 0.0 {
        plate.flip();
    }
    let mirror = Material { bsdf: Bsdf::Conductor { eta: silver.0, k: silver.1, roughness: 0.0 }, ..Material::diffuse("mirror", Vec3::ONE) };
    let glass = Material { bsdf: Bsdf::Dielectric { ior: 1.5, roughness: 0.0 }, ..Material::diffuse("glass", Vec3::ONE) };
    s.objects.push(object_at("mirror", plate, mirror, Affine3A::IDENTITY));
    s.objects.push(object_at("glass", smooth_sphere(SPHERE_RADIUS), glass, Affine3A::from_translation(SPHERE_CENTRE)));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sphere_rests_on_the_floor_clear_of_the_boxes_and_the_mirror_faces_up() {
        let s = cornell_glass();
        s.validate().unwrap();
        let glass = s.object_id("glass").unwrap() as usize;
        let (lo, _) = s.object_bounds(glass);
        assert!(lo.y > 0.0 && lo.y < 0.002, "{lo}");
        // Clear of both boxes: the centre's distance (in the floor plane) to every edge of
        // each box's footprint exceeds the radius, and the centre is outside the footprint.
        let c = glam::Vec2::new(SPHERE_CENTRE.x, SPHERE_CENTRE.z);
        for name in ["shortbox", "tallbox"] {
            let o = &s.objects[s.object_id(name).unwrap() as usize];
            let foot: Vec<glam::Vec2> = o.mesh.positions.iter().filter(|p| p.y < 1e-6).map(|p| glam::Vec2::new(p.x, p.z)).collect();
            assert_eq!(foot.len(), 4);
            let inside = (0..4).all(|i| (foot[(i + 1) % 4] - foot[i]).perp_dot(c - foot[i]) > 0.0) || (0..4).all(|i| (foot[(i + 1) % 4] - foot[i]).perp_dot(c - foot[i]) < 0.0);
            assert!(!inside, "{name}");
            for i in 0..4 {
                for j in 0..4 {
                    let (a, b) = (foot[i], foot[j]);
                    let t = ((c - a).dot(b - a) / (b - a).length_squared().max(1e-12)).clamp(0.0, 1.0);
                    assert!((a + (b - a) * t).distance(c) > SPHERE_RADIUS, "{name}");
                }
            }
        }
        let m = &s.objects[s.object_id("mirror").unwrap() as usize];
        assert!(m.mesh.face_normals.iter().all(|n| n.y > 0.99));
        assert!(matches!(s.objects[glass].material.bsdf, Bsdf::Dielectric { .. }));
    }
}
