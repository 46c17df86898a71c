//! Pinhole camera: eye, target, up, vertical field of view (DESIGN.md conventions: right-
//! handed, Y up, the camera looks down -Z in its own frame, image origin top-left, pixel
//! centres at +0.5).
use glam::{Mat3, Vec3};

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    pub fov_y_degrees: f32,
}

/// A camera prepared for one image size: orthonormal basis and scale factors, so that
/// generating or projecting millions of points costs a few multiply-adds each.
#[derive(Debug, Clone, Copy)]
pub struct CameraFrame {
    pub eye: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub forward: Vec3,
    pub width: u32,
    pub height: u32,
    /// tan(fov_y / 2)
    pub tan_half_y: f32,
    pub aspect: f32,
}

impl Camera {
    /// Checks that the camera can make an image: finite values within
    /// [`MAX_WORLD_COORDINATE`](crate::limits::MAX_WORLD_COORDINATE), eye != target, up not
    /// parallel to the view direction, 0 < fov < 180. Every test is written so that a NaN
    /// fails it (an overflowing camera must not pass through NaN comparisons).
    pub fn validate(&self) -> Result<(), String> {
        use crate::limits::{check_vec, MAX_WORLD_COORDINATE};
        for (name, v) in [("eye", self.eye), ("target", self.target), ("up", self.up)] {
            check_vec(&format!("camera {name}"), v, MAX_WORLD_COORDINATE)?;
        }
        if !(self.fov_y_degrees > 0.0 && self.fov_y_degrees < 180.0) {
            return Err(format!(
                "camera field of view must be in (0, 180) degrees, got {}",
                self.fov_y_degrees
            ));
        }
        let fwd = self.target - self.eye;
        if !(fwd.length() >= 1e-9) {
            return Err("camera eye and target coincide (zero view direction)".into());
        }
        if !(self.up.length() >= 1e-9) {
            return Err("camera up vector is zero".into());
        }
        if !(fwd.normalize().cross(self.up.normalize()).length() >= 1e-6) {
            return Err("camera up vector is parallel to the view direction".into());
        }
        Ok(())
    }

    /// The orthonormal frame for an image of `width` x `height` pixels.
    pub fn frame(&self, width: u32, height: u32) -> CameraFrame {
        let forward = (self.target - self.eye).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        CameraFrame {
            eye: self.eye,
            right,
            up,
            forward,
            width,
            height,
            tan_half_y: (self.fov_y_degrees.to_radians() * 0.5).tan(),
            aspect: width as f32 / height.max(1) as f32,
        }
    }

    /// The camera rotated about the vertical axis through `pivot` by `angle` radians.
    pub fn orbit(&self, pivot: Vec3, angle: f32) -> Camera {
        let r = Mat3::from_rotation_y(angle);
        Camera {
            eye: pivot + r * (self.eye - pivot),
            target: pivot + r * (self.target - pivot),
            up: r * self.up,
            fov_y_degrees: self.fov_y_degrees,
        }
    }
}

impl CameraFrame {
    /// Ray through continuous image position (`sx`, `sy`) in pixels (pixel (i, j) covers
    /// [i, i+1) x [j, j+1); its centre is (i+0.5, j+0.5)). Direction is normalised.
    #[inline]
    pub fn ray(&self, sx: f32, sy: f32) -> (Vec3, Vec3) {
        let nx = (2.0 * sx / self.width as f32 - 1.0) * self.tan_half_y * self.aspect;
        let ny = (1.0 - 2.0 * sy / self.height as f32) * self.tan_half_y;
        let d = self.forward + nx * self.right + ny * self.up;
        (self.eye, d.normalize())
    }

    /// Projects a world point: (sx, sy, view depth) with sx, sy in continuous pixel
    /// coordinates, or `None` behind (or too near) the eye.
    #[inline]
    pub fn project(&self, p: Vec3) -> Option<(f32, f32, f32)> {
        let d = p - self.eye;
        let z = d.dot(self.forward);
        if z <= 1e-6 {
            return None;
        }
        let x = d.dot(self.right) / (z * self.tan_half_y * self.aspect);
        let y = d.dot(self.up) / (z * self.tan_half_y);
        Some(((x + 1.0) * 0.5 * self.width as f32, (1.0 - y) * 0.5 * self.height as f32, z))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera { eye: Vec3::new(1.0, 2.0, 5.0), target: Vec3::new(0.0, 0.5, 0.0), up: Vec3::Y, fov_y_degrees: 45.0 }
    }

    #[test]
    fn ray_and_project_are_inverse() {
        let f = cam().frame(640, 480);
        for &(sx, sy) in &[(0.5, 0.5), (320.0, 240.0), (639.5, 10.25), (100.0, 479.0)] {
            let (o, d) = f.ray(sx, sy);
            let p = o + d * 3.7;
            let (px, py, z) = f.project(p).unwrap();
            assert!((px - sx).abs() < 1e-3 && (py - sy).abs() < 1e-3, "{px},{py} vs {sx},{sy}");
            assert!(z > 0.0);
        }
        assert!(f.project(Vec3::new(1.0, 2.0, 10.0)).is_none(), "point behind the eye");
    }

    #[test]
    fn image_orientation_follows_conventions() {
        let f = cam().frame(100, 100);
        let (_, d) = f.ray(50.0, 0.0);
        assert!(d.dot(f.up) > 0.0, "top of the image looks up");
        let (_, d) = f.ray(100.0, 50.0);
        assert!(d.dot(f.right) > 0.0, "right of the image looks right");
    }

    #[test]
    fn invalid_cameras_are_rejected() {
        let mut c = cam();
        c.fov_y_degrees = 0.0;
        assert!(c.validate().is_err());
        let mut c = cam();
        c.eye.x = f32::NAN;
        assert!(c.validate().unwrap_err().contains("not finite"));
        let mut c = cam();
        c.target = c.eye;
        assert!(c.validate().is_err());
        let mut c = cam();
        c.up = c.target - c.eye;
        assert!(c.validate().unwrap_err().contains("parallel"));
        cam().validate().unwrap();
        // Overflowing coordinates: eye - target is infinite, every derived value NaN.
        let mut c = cam();
        (c.eye.x, c.target.x) = (3e38, -3e38);
        assert!(c.validate().unwrap_err().contains("beyond"), "{:?}", c.validate());
        // Huge but finite: the message names the coordinate, not the up vector.
        let mut c = cam();
        c.eye = Vec3::splat(1e30);
        let e = c.validate().unwrap_err();
        assert!(e.contains("camera eye") && e.contains("beyond"), "{e}");
        let mut c = cam();
        c.up = Vec3::new(0.0, 1e-30, 0.0);
        assert!(c.validate().unwrap_err().contains("zero"));
    }

    #[test]
    fn orbit_keeps_distance_to_pivot() {
        let c = cam();
        let o = c.orbit(Vec3::ZERO, 1.0);
        assert!(((o.eye.length()) - c.eye.length()).abs() < 1e-5);
        o.validate().unwrap();
    }
}
