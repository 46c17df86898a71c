//! The camera the window's mouse and keys move (pure math, no window): orbit about the
//! target (left drag, arrows), pan in the view plane (right drag), dolly toward the target
//! (wheel), fly as in pbrt-v4's interactive mode (W/S along the view, A/D sideways, Q/E
//! down/up) at a speed scaled to the scene and independent of the frame rate, and reset.
use edgepoint_scene::Camera;
use glam::{Mat3, Vec3};

/// Closest the view direction comes to straight up or down (degrees), so +Y stays usable
/// as the up vector.
const MIN_POLE_DEGREES: f32 = 5.0;
/// Dolly: the eye–target distance is multiplied by this per wheel notch toward the target.
pub const DOLLY_PER_NOTCH: f32 = 0.85;

/// An interactively moved camera with +Y up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FreeCamera {
    home: Camera,
    cam: Camera,
    /// The scene's size for speeds and limits (e.g. its suggested orbit radius).
    scale: f32,
}

impl FreeCamera {
    /// Starts at `home` (R returns there); `scale` is the scene's size (> 0): flying moves
    /// one `scale` per second, the dolly stops at 1 % of it from the target.
    pub fn new(home: Camera, scale: f32) -> Self {
        let home = Camera { up: Vec3::Y, ..home };
        let scale = if scale.is_finite() && scale > 0.0 { scale } else { (home.target - home.eye).length().max(1e-3) };
        FreeCamera { home, cam: home, scale }
    }

    pub fn camera(&self) -> Camera {
        self.cam
    }

    pub fn scale(&self) -> f32 {
        self.scale
    }

    /// Back to the starting camera.
    pub fn reset(&mut self) {
        self.cam = self.home;
    }

    /// Takes over `c` (e.g. where a scripted orbit left the camera) keeping +Y up.
    pub fn set(&mut self, c: Camera) {
        if c.validate().is_ok() {
            self.cam = Camera { up: Vec3::Y, ..c };
            if self.cam.validate().is_err() {
                self.cam = c;
            }
        }
    }

    fn accept(&mut self, c: Camera) {
        if c.validate().is_ok() {
            self.cam = c;
        }
    }

    /// Turns the eye about the target: `yaw` radians about +Y (positive: counter-clockwise
    /// seen from above), `pitch` radians up over the target (the view never comes closer
    /// than 5° to straight down or up).
    pub fn orbit(&mut self, yaw: f32, pitch: f32) {
        let c = self.cam;
        let offset = c.eye - c.target;
        let r = offset.length();
        let elev = (offset.y / r).clamp(-1.0, 1.0).asin();
        let limit = (90.0 - MIN_POLE_DEGREES).to_radians();
        let new_elev = (elev + pitch).clamp(-limit, limit);
        let az = offset.x.atan2(offset.z) + yaw;
        let dir = Vec3::new(new_elev.cos() * az.sin(), new_elev.sin(), new_elev.cos() * az.cos());
        self.accept(Camera { eye: c.target + dir * r, up: Vec3::Y, ..c });
    }

    /// Moves eye and target together in the view plane so that the point at the target's
    /// depth follows a drag of (`dx`, `dy`) pixels on a frame `height` pixels high.
    pub fn pan(&mut self, dx: f32, dy: f32, height: u32) {
        let c = self.cam;
        let f = c.frame(height.max(1), height.max(1));
        let dist = (c.target - c.eye).length();
        let per_pixel = 2.0 * dist * f.tan_half_y / height.max(1) as f32;
        let shift = (-dx * f.right + dy * f.up) * per_pixel;
        self.accept(Camera { eye: c.eye + shift, target: c.target + shift, ..c });
    }

    /// Moves the eye toward the target by `notches` wheel notches (negative: away), never
    /// closer than 1 % of the scene's size.
    pub fn dolly(&mut self, notches: f32) {
        let c = self.cam;
        let offset = c.eye - c.target;
        let dist = offset.length();
        let new = (dist * DOLLY_PER_NOTCH.powf(notches)).max(0.01 * self.scale);
        self.accept(Camera { eye: c.target + offset * (new / dist), ..c });
    }

    /// Flies for `seconds`: `forward` along the view direction, `right` sideways, `up`
    /// along +Y (each -1, 0 or 1), at `speed` scene sizes per second; eye and target move
    /// together.
    pub fn fly(&mut self, forward: f32, right: f32, up: f32, seconds: f32, speed: f32) {
        let c = self.cam;
        let f = c.frame(1, 1);
        let d = (f.forward * forward + f.right * right + Vec3::Y * up) * (speed * self.scale * seconds);
        if d.is_finite() {
            self.accept(Camera { eye: c.eye + d, target: c.target + d, ..c });
        }
    }

    /// Turns the view in place (the target swings about the eye): `yaw` about +Y.
    pub fn look(&mut self, yaw: f32) {
        let c = self.cam;
        let r = Mat3::from_rotation_y(yaw);
        self.accept(Camera { target: c.eye + r * (c.target - c.eye), ..c });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn home() -> Camera {
        Camera { eye: Vec3::new(0.0, 1.0, 4.0), target: Vec3::new(0.0, 1.0, 0.0), up: Vec3::Y, fov_y_degrees: 40.0 }
    }

    #[test]
    fn orbit_keeps_the_distance_turns_by_the_angle_and_stops_short_of_the_poles() {
        let mut c = FreeCamera::new(home(), 1.0);
        c.orbit(0.3, 0.0);
        let got = c.camera();
        let want = home().orbit(home().target, 0.3);
        assert!((got.eye - want.eye).length() < 1e-5, "{} vs {}", got.eye, want.eye);
        c.orbit(0.0, 0.2);
        let off = c.camera().eye - c.camera().target;
        assert!((off.length() - 4.0).abs() < 1e-4);
        assert!(((off.y / 4.0).asin() - 0.2).abs() < 1e-4);
        c.orbit(0.0, 10.0);
        let off = c.camera().eye - c.camera().target;
        assert!(((off.y / off.length()).asin().to_degrees() - 85.0).abs() < 1e-3, "clamped at 85°");
        c.camera().validate().unwrap();
        c.reset();
        assert_eq!(c.camera(), home());
    }

    #[test]
    fn pan_moves_the_target_plane_with_the_cursor() {
        let mut c = FreeCamera::new(home(), 1.0);
        let f0 = home().frame(100, 100);
        c.pan(10.0, 0.0, 100);
        // The old target now projects 10 pixels to the right of the centre.
        let (x, y, _) = c.camera().frame(100, 100).project(home().target).unwrap();
        assert!((x - 60.0).abs() < 1e-3 && (y - 50.0).abs() < 1e-3, "{x},{y}");
        assert!((c.camera().eye - c.camera().target).abs_diff_eq(home().eye - home().target, 1e-5));
        let _ = f0;
        c.pan(0.0, -20.0, 100);
        let (_, y, _) = c.camera().frame(100, 100).project(home().target).unwrap();
        assert!((y - 30.0).abs() < 1e-3, "dragging up moves the scene up: {y}");
    }

    #[test]
    fn dolly_and_fly_scale_with_the_scene_and_time_not_the_call_count() {
        let mut c = FreeCamera::new(home(), 0.5);
        c.dolly(2.0);
        assert!(((c.camera().eye - c.camera().target).length() - 4.0 * 0.85 * 0.85).abs() < 1e-4);
        c.dolly(1000.0);
        assert!(((c.camera().eye - c.camera().target).length() - 0.005).abs() < 1e-5, "stops at 1% of the scale");
        // 0.2 s of W at one scene size per second moves 0.1 here, in one step or in twenty.
        let (mut a, mut b) = (FreeCamera::new(home(), 0.5), FreeCamera::new(home(), 0.5));
        a.fly(1.0, 0.0, 0.0, 0.2, 1.0);
        for _ in 0..20 {
            b.fly(1.0, 0.0, 0.0, 0.01, 1.0);
        }
        for c in [a, b] {
            assert!((c.camera().eye - Vec3::new(0.0, 1.0, 3.9)).length() < 1e-5, "{}", c.camera().eye);
            assert!((c.camera().target - Vec3::new(0.0, 1.0, -0.1)).length() < 1e-5);
        }
        a.fly(0.0, 1.0, 1.0, 1.0, 2.0);
        assert!((a.camera().eye - Vec3::new(1.0, 2.0, 3.9)).length() < 1e-5, "D moves right, E up: {}", a.camera().eye);
    }

    #[test]
    fn bad_moves_leave_the_camera_usable() {
        let mut c = FreeCamera::new(home(), 1.0);
        c.fly(f32::NAN, 0.0, 0.0, 1.0, 1.0);
        c.pan(f32::INFINITY, 0.0, 10);
        c.orbit(f32::NAN, 0.0);
        c.camera().validate().unwrap();
    }
}
