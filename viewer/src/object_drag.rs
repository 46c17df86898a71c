//! Dragging a picked object with the mouse: the object moves in the plane that faces the
//! camera (normal = the view direction when it was picked) through the picked point, so
//! the point under the cursor stays under the cursor.
use edgepoint_proto as pb;
use edgepoint_scene::Camera;
use glam::{Affine3A, Vec3};

/// An object held by the mouse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Drag {
    pub object_id: u32,
    /// The picked surface point (world space).
    grab: Vec3,
    /// The drag plane's normal.
    normal: Vec3,
    /// The object's transform when it was picked.
    start: Affine3A,
}

impl Drag {
    /// A drag for a pick answer that hit something (with its transform and camera).
    pub fn new(p: &pb::Picked) -> Option<Drag> {
        if !p.hit {
            return None;
        }
        let cam = crate::client::camera_from_wire(p.camera.as_ref()?);
        cam.validate().ok()?;
        let start = pb::affine_from_wire(p.transform.as_ref()?).ok()?;
        let grab = Vec3::from(p.position.as_ref()?);
        grab.is_finite().then(|| Drag { object_id: p.object_id, grab, normal: (cam.target - cam.eye).normalize(), start })
    }

    /// The object's transform with the cursor at frame position (`x`, `y`) of a `width` x
    /// `height` frame seen through `camera`: the start transform shifted by where the ray
    /// through the cursor meets the drag plane, less the grabbed point. `None` when the ray
    /// runs along the plane or meets it behind the eye.
    pub fn transform_at(&self, camera: &Camera, width: u32, height: u32, x: f32, y: f32) -> Option<Affine3A> {
        let (o, d) = camera.frame(width, height).ray(x, y);
        let denom = d.dot(self.normal);
        if denom.abs() < 1e-6 {
            return None;
        }
        let t = (self.grab - o).dot(self.normal) / denom;
        if !(t > 0.0 && t.is_finite()) {
            return None;
        }
        let shift = o + d * t - self.grab;
        Some(Affine3A::from_translation(shift) * self.start)
    }

    /// The move to send for transform `t`.
    pub fn object_move(&self, t: &Affine3A) -> pb::ObjectMove {
        pb::ObjectMove { object_id: self.object_id, name: String::new(), transform: Some(pb::affine_to_wire(t)) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grabbed_point_follows_the_cursor_in_the_plane_facing_the_camera() {
        let cam = Camera { eye: Vec3::new(0.0, 1.0, 4.0), target: Vec3::new(0.0, 1.0, 0.0), up: Vec3::Y, fov_y_degrees: 40.0 };
        let start = Affine3A::from_translation(Vec3::new(0.2, 0.0, -0.5)) * Affine3A::from_rotation_y(0.4);
        let grab = Vec3::new(0.3, 1.1, 0.5);
        let picked = pb::Picked {
            hit: true,
            object_id: 3,
            position: Some(grab.into()),
            transform: Some(pb::affine_to_wire(&start)),
            camera: Some(crate::client::camera_to_wire(&cam)),
            ..Default::default()
        };
        let d = Drag::new(&picked).unwrap();
        let f = cam.frame(200, 100);
        let (gx, gy, _) = f.project(grab).unwrap();
        // Not moving the cursor moves nothing.
        assert!(d.transform_at(&cam, 200, 100, gx, gy).unwrap().abs_diff_eq(start, 1e-5));
        // Moving it to where a point of the plane projects moves the grabbed point there.
        for off in [Vec3::new(0.4, 0.0, 0.0), Vec3::new(-0.1, 0.3, 0.0), Vec3::new(0.0, -0.5, 0.0)] {
            let (x, y, _) = f.project(grab + off).unwrap();
            let t = d.transform_at(&cam, 200, 100, x, y).unwrap();
            let moved = t.transform_point3(start.inverse().transform_point3(grab));
            assert!((moved - (grab + off)).length() < 1e-4, "{off}: {moved}");
            assert!(t.matrix3.abs_diff_eq(start.matrix3, 1e-6), "rotation kept");
            assert_eq!(d.object_move(&t).object_id, 3);
        }
        // A camera turned so the ray runs away from the plane: no transform.
        let away = Camera { target: Vec3::new(0.0, 1.0, 8.0), ..cam };
        assert!(d.transform_at(&away, 200, 100, 100.0, 50.0).is_none());
        assert!(Drag::new(&pb::Picked { hit: false, ..picked }).is_none());
    }
}
