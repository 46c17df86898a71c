//! Camera orbits: an eye circling a pivot at a fixed distance and elevation, looking at the
//! pivot. Every scene suggests one ([`crate::Scene::suggested_orbit`]); the built-ins choose
//! theirs so that along the full circle the eye stays inside the room and outside every
//! object with the interesting content in view, which an orbit about the default camera's
//! target at the default eye distance does not (it leaves the Cornell box after ~20°).
use crate::Camera;
use glam::Vec3;

/// An orbit: the eye at `radius` from `pivot`, `elevation_degrees` above the pivot's
/// horizontal plane, at an azimuth measured about +Y from +Z toward +X (the sense of
/// [`Camera::orbit`] with a positive angle); it looks at the pivot with +Y up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Orbit {
    pub pivot: Vec3,
    pub radius: f32,
    /// Degrees above the pivot's horizontal plane, in (-90, 90).
    pub elevation_degrees: f32,
    /// Azimuth of the orbit's first camera (degrees).
    pub start_azimuth_degrees: f32,
    /// Vertical field of view of the orbit's cameras.
    pub fov_y_degrees: f32,
}

/// Elevations closer to the poles than this make +Y almost parallel to the view direction.
pub const MAX_ELEVATION_DEGREES: f32 = 85.0;

impl Orbit {
    /// The orbit that passes through `camera`: pivot at its target, radius its eye distance,
    /// elevation and start azimuth those of its eye, same field of view (what an orbit about
    /// a camera without any knowledge of the scene looks like).
    pub fn through(camera: &Camera) -> Orbit {
        let d = camera.eye - camera.target;
        let radius = d.length();
        let horizontal = (d.x * d.x + d.z * d.z).sqrt();
        Orbit {
            pivot: camera.target,
            radius,
            elevation_degrees: d.y.atan2(horizontal).to_degrees().clamp(-MAX_ELEVATION_DEGREES, MAX_ELEVATION_DEGREES),
            start_azimuth_degrees: d.x.atan2(d.z).to_degrees(),
            fov_y_degrees: camera.fov_y_degrees,
        }
    }

    /// The eye at `azimuth_degrees` (absolute, not relative to the start).
    pub fn eye_at(&self, azimuth_degrees: f32) -> Vec3 {
        let (a, e) = (azimuth_degrees.to_radians(), self.elevation_degrees.to_radians());
        self.pivot + self.radius * Vec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos())
    }

    /// The camera at `azimuth_degrees` (absolute).
    pub fn camera_at(&self, azimuth_degrees: f32) -> Camera {
        Camera { eye: self.eye_at(azimuth_degrees), target: self.pivot, up: Vec3::Y, fov_y_degrees: self.fov_y_degrees }
    }

    /// The camera `degrees` past the start azimuth (step `k` of an orbit at `d` degrees per
    /// frame is `camera_after(k as f32 * d)`; computed from the start, so long orbits
    /// accumulate no rounding).
    pub fn camera_after(&self, degrees: f32) -> Camera {
        self.camera_at(self.start_azimuth_degrees + degrees)
    }

    /// Checks the orbit makes valid cameras: finite values, radius > 0, elevation within
    /// ±85°, field of view in (0, 180). Errors name the field.
    pub fn validate(&self) -> Result<(), String> {
        if !self.pivot.is_finite() {
            return Err(format!("orbit pivot is not finite ({})", self.pivot));
        }
        if !self.radius.is_finite() || self.radius <= 0.0 {
            return Err(format!("orbit radius must be a positive number, got {}", self.radius));
        }
        if !self.elevation_degrees.is_finite() || self.elevation_degrees.abs() > MAX_ELEVATION_DEGREES {
            return Err(format!(
                "orbit elevation must be within ±{MAX_ELEVATION_DEGREES} degrees, got {}",
                self.elevation_degrees
            ));
        }
        if !self.start_azimuth_degrees.is_finite() {
            return Err(format!("orbit start azimuth is not finite ({})", self.start_azimuth_degrees));
        }
        if !self.fov_y_degrees.is_finite() || self.fov_y_degrees <= 0.0 || self.fov_y_degrees >= 180.0 {
            return Err(format!("orbit field of view must be in (0, 180) degrees, got {}", self.fov_y_degrees));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn through_a_camera_reproduces_it_and_turns_like_camera_orbit() {
        let cam = Camera { eye: Vec3::new(1.0, 2.0, 5.0), target: Vec3::new(0.0, 0.5, 0.0), up: Vec3::Y, fov_y_degrees: 45.0 };
        let o = Orbit::through(&cam);
        o.validate().unwrap();
        let c0 = o.camera_after(0.0);
        assert!((c0.eye - cam.eye).length() < 1e-5, "{} vs {}", c0.eye, cam.eye);
        assert_eq!((c0.target, c0.fov_y_degrees), (cam.target, 45.0));
        for deg in [1.0f32, 37.0, 90.0, 181.0, 359.0, -20.0] {
            let want = cam.orbit(cam.target, deg.to_radians());
            let got = o.camera_after(deg);
            assert!((got.eye - want.eye).length() < 1e-4, "{deg}: {} vs {}", got.eye, want.eye);
            assert!(((got.eye - o.pivot).length() - o.radius).abs() < 1e-5);
            got.validate().unwrap();
        }
    }

    #[test]
    fn bad_orbits_name_the_field() {
        let good = Orbit { pivot: Vec3::ZERO, radius: 1.0, elevation_degrees: 30.0, start_azimuth_degrees: 0.0, fov_y_degrees: 50.0 };
        good.validate().unwrap();
        let cases = [
            (Orbit { pivot: Vec3::NAN, ..good }, "pivot"),
            (Orbit { radius: 0.0, ..good }, "radius"),
            (Orbit { radius: f32::INFINITY, ..good }, "radius"),
            (Orbit { elevation_degrees: 89.0, ..good }, "elevation"),
            (Orbit { start_azimuth_degrees: f32::NAN, ..good }, "azimuth"),
            (Orbit { fov_y_degrees: 180.0, ..good }, "field of view"),
        ];
        for (o, what) in cases {
            assert!(o.validate().unwrap_err().contains(what), "{o:?}");
        }
    }
}
