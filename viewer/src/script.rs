//! Scripted motion that drives a session without a person: the camera orbiting the vertical
//! axis through its target, and an object sliding back and forth along X (the moving-object
//! case of paper 000 §6.5 and paper 002). Also the camera rig the window's keys move, so keys
//! and a scripted orbit compose.
use anyhow::{anyhow, bail, Result};
use edgepoint_proto::{self as pb};
use edgepoint_scene::Camera;
use glam::{Affine3A, Vec3};

use crate::client::{camera_from_wire, camera_to_wire};

/// A camera defined by a base camera, a yaw about the vertical axis through the base
/// target, and a distance scale toward that target. Recomputing from the base each time
/// keeps long orbits free of accumulated rounding.
#[derive(Debug, Clone, Copy)]
pub struct CameraRig {
    base: Camera,
    yaw: f32,
    distance_scale: f32,
}

/// Closest and farthest dolly, as multiples of the starting distance.
const DOLLY_MIN: f32 = 0.05;
const DOLLY_MAX: f32 = 20.0;

impl CameraRig {
    /// A rig at `base` (yaw 0, original distance).
    pub fn new(base: Camera) -> Self {
        CameraRig { base, yaw: 0.0, distance_scale: 1.0 }
    }

    /// Turns the camera by `radians` about the vertical axis through the target
    /// (positive: counter-clockwise seen from above).
    pub fn orbit(&mut self, radians: f32) {
        self.yaw = (self.yaw + radians).rem_euclid(std::f32::consts::TAU);
    }

    /// Scales the eye's distance to the target by `factor` (< 1 moves closer), within
    /// 0.05x..20x the starting distance.
    pub fn dolly(&mut self, factor: f32) {
        if factor.is_finite() && factor > 0.0 {
            self.distance_scale = (self.distance_scale * factor).clamp(DOLLY_MIN, DOLLY_MAX);
        }
    }

    /// Current yaw in radians, in [0, 2π).
    pub fn yaw(&self) -> f32 {
        self.yaw
    }

    /// The camera for the current yaw and distance.
    pub fn camera(&self) -> Camera {
        let pivot = self.base.target;
        let eye = pivot + (self.base.eye - pivot) * self.distance_scale;
        Camera { eye, ..self.base }.orbit(pivot, self.yaw)
    }
}

/// An object sliding along world X: `offset(k) = A sin(2π k / period)` at the k-th
/// received frame, applied on top of the object's transform at session start.
#[derive(Debug, Clone)]
pub struct ObjectSlide {
    object_id: u32,
    name: String,
    base: Affine3A,
    amplitude: f32,
    period_frames: f32,
    frame: u64,
}

/// Frames per back-and-forth cycle.
pub const SLIDE_PERIOD_FRAMES: f32 = 120.0;
/// Slide amplitude as a fraction of the scene's X extent.
pub const SLIDE_AMPLITUDE_FRACTION: f32 = 0.25;

impl ObjectSlide {
    /// The slide of the object called `name` in `started`, with amplitude 25% of the
    /// scene's X extent and a 120-frame period. An unknown name is an error listing the
    /// scene's object names.
    pub fn new(started: &pb::Started, name: &str) -> Result<Self> {
        let obj = started.objects.iter().find(|o| o.name == name).ok_or_else(|| {
            let names: Vec<&str> = started.objects.iter().map(|o| o.name.as_str()).collect();
            anyhow!("--move-object: the scene has no object named '{name}' (objects: {})", names.join(", "))
        })?;
        let base = match &obj.transform {
            Some(t) => pb::affine_from_wire(t).map_err(|e| anyhow!("object '{name}': server sent a bad transform: {e}"))?,
            None => Affine3A::IDENTITY,
        };
        let min = pb::vec3_or_zero(&started.scene_min);
        let max = pb::vec3_or_zero(&started.scene_max);
        let extent = max.x - min.x;
        if !extent.is_finite() || extent <= 0.0 {
            bail!("--move-object: the scene's X extent is {extent} (bounds {min} .. {max}); cannot size the slide");
        }
        Ok(ObjectSlide {
            object_id: obj.id,
            name: name.to_string(),
            base,
            amplitude: SLIDE_AMPLITUDE_FRACTION * extent,
            period_frames: SLIDE_PERIOD_FRAMES,
            frame: 0,
        })
    }

    /// The same slide with another period (frames per cycle, > 0).
    pub fn with_period(mut self, frames: f32) -> Self {
        if frames.is_finite() && frames > 0.0 {
            self.period_frames = frames;
        }
        self
    }

    /// The object's id and name.
    pub fn object(&self) -> (u32, &str) {
        (self.object_id, &self.name)
    }

    /// Slide amplitude in scene units.
    pub fn amplitude(&self) -> f32 {
        self.amplitude
    }

    /// X offset at step `k`.
    pub fn offset_at(&self, k: u64) -> f32 {
        let phase = (k as f64 / self.period_frames as f64).fract() * std::f64::consts::TAU;
        self.amplitude * phase.sin() as f32
    }

    /// The object's transform at step `k`: the start transform, then the X offset.
    pub fn transform_at(&self, k: u64) -> Affine3A {
        Affine3A::from_translation(Vec3::X * self.offset_at(k)) * self.base
    }

    /// Advances one step and returns the move to send.
    pub fn next_move(&mut self) -> pb::ObjectMove {
        self.frame += 1;
        pb::ObjectMove {
            object_id: self.object_id,
            name: String::new(),
            transform: Some(pb::affine_to_wire(&self.transform_at(self.frame))),
        }
    }
}

/// What to send after a received frame.
#[derive(Debug, Clone, Default)]
pub struct ScriptStep {
    pub camera: Option<pb::Camera>,
    pub object_move: Option<pb::ObjectMove>,
}

/// The scripted motion of a run: an optional orbit and an optional object slide, advanced
/// once per received frame.
#[derive(Debug, Clone)]
pub struct Script {
    rig: Option<CameraRig>,
    orbit_step: Option<f32>,
    slide: Option<ObjectSlide>,
}

impl Script {
    /// A script for a session that started as `started`: orbit at `orbit_degrees_per_frame`
    /// when given, slide the object `move_object` when given.
    pub fn new(started: &pb::Started, orbit_degrees_per_frame: Option<f32>, move_object: Option<&str>) -> Result<Self> {
        let rig = match &started.camera {
            Some(c) => {
                let cam = camera_from_wire(c);
                match cam.validate() {
                    Ok(()) => Some(CameraRig::new(cam)),
                    Err(e) if orbit_degrees_per_frame.is_some() => bail!("--orbit: the server's camera is unusable: {e}"),
                    Err(_) => None,
                }
            }
            None if orbit_degrees_per_frame.is_some() => bail!("--orbit: the server's `started` carries no camera"),
            None => None,
        };
        if let Some(d) = orbit_degrees_per_frame {
            if !d.is_finite() {
                bail!("--orbit-speed must be a finite number of degrees, got {d}");
            }
        }
        let slide = move_object.map(|name| ObjectSlide::new(started, name)).transpose()?;
        Ok(Script { rig, orbit_step: orbit_degrees_per_frame.map(f32::to_radians), slide })
    }

    /// Whether anything is scripted.
    pub fn is_active(&self) -> bool {
        self.orbit_step.is_some() || self.slide.is_some()
    }

    /// The camera rig (absent when the server sent no usable camera).
    pub fn rig(&self) -> Option<&CameraRig> {
        self.rig.as_ref()
    }

    /// The rig, for interactive moves (keys) that compose with the scripted orbit.
    pub fn rig_mut(&mut self) -> Option<&mut CameraRig> {
        self.rig.as_mut()
    }

    /// Advances one received frame and says what to send.
    pub fn on_frame(&mut self) -> ScriptStep {
        let mut step = ScriptStep::default();
        if let (Some(rig), Some(d)) = (self.rig.as_mut(), self.orbit_step) {
            rig.orbit(d);
            step.camera = Some(camera_to_wire(&rig.camera()));
        }
        if let Some(s) = self.slide.as_mut() {
            step.object_move = Some(s.next_move());
        }
        step
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn started() -> pb::Started {
        let cam = Camera { eye: Vec3::new(0.0, 1.0, 4.0), target: Vec3::new(0.0, 1.0, 0.0), up: Vec3::Y, fov_y_degrees: 40.0 };
        let t = Affine3A::from_translation(Vec3::new(0.3, 0.0, -0.2)) * Affine3A::from_rotation_y(0.5);
        pb::Started {
            objects: vec![
                pb::SceneObject { id: 0, name: "floor".into(), transform: Some(pb::affine_to_wire(&Affine3A::IDENTITY)), ..Default::default() },
                pb::SceneObject { id: 4, name: "tallbox".into(), transform: Some(pb::affine_to_wire(&t)), ..Default::default() },
            ],
            camera: Some(camera_to_wire(&cam)),
            scene_min: Some(Vec3::new(-1.0, 0.0, -1.0).into()),
            scene_max: Some(Vec3::new(3.0, 2.0, 1.0).into()),
            ..Default::default()
        }
    }

    #[test]
    fn orbit_keeps_distance_and_height_and_turns_by_the_step() {
        let st = started();
        let mut s = Script::new(&st, Some(3.0), None).unwrap();
        let base = camera_from_wire(st.camera.as_ref().unwrap());
        let mut prev = base;
        for k in 1..=200u32 {
            let cam = camera_from_wire(&s.on_frame().camera.unwrap());
            let r0 = base.eye - base.target;
            let r = cam.eye - cam.target;
            assert!((r.length() - r0.length()).abs() < 1e-4, "distance kept");
            assert!((cam.eye.y - base.eye.y).abs() < 1e-5 && cam.target == base.target, "height, pivot kept");
            // Angle between successive horizontal offsets is the step.
            let (a, b) = ((prev.eye - prev.target).normalize(), r.normalize());
            assert!((a.dot(b).clamp(-1.0, 1.0).acos().to_degrees() - 3.0).abs() < 0.05, "frame {k}");
            // Against the brute-force closed form: rotate the base by k * step.
            let want = base.orbit(base.target, (3.0 * k as f32).to_radians());
            assert!((want.eye - cam.eye).length() < 1e-4, "frame {k}: {} vs {}", want.eye, cam.eye);
            prev = cam;
        }
    }

    #[test]
    fn slide_composes_with_the_start_transform() {
        let st = started();
        let base = pb::affine_from_wire(st.objects[1].transform.as_ref().unwrap()).unwrap();
        let mut s = Script::new(&st, None, Some("tallbox")).unwrap();
        assert!(s.is_active());
        let amp = 0.25 * 4.0;
        let mut max_off: f32 = 0.0;
        for k in 1..=120u64 {
            let mv = s.on_frame().object_move.unwrap();
            assert_eq!(mv.object_id, 4);
            let t = pb::affine_from_wire(mv.transform.as_ref().unwrap()).unwrap();
            // Same rotation, translation shifted along X only.
            assert!(t.matrix3.abs_diff_eq(base.matrix3, 1e-6));
            let d = t.translation - base.translation;
            assert!(d.y.abs() < 1e-6 && d.z.abs() < 1e-6);
            let want = amp * (std::f64::consts::TAU * k as f64 / 120.0).sin() as f32;
            assert!((d.x - want).abs() < 1e-5, "frame {k}: {} vs {want}", d.x);
            max_off = max_off.max(d.x.abs());
        }
        assert!((max_off - amp).abs() < 1e-3, "reaches the amplitude");
    }

    #[test]
    fn unknown_object_lists_the_names() {
        let msg = Script::new(&started(), None, Some("teapot")).unwrap_err().to_string();
        assert!(msg.contains("teapot") && msg.contains("floor, tallbox"), "{msg}");
    }

    #[test]
    fn orbit_without_a_camera_is_an_error() {
        let st = pb::Started { camera: None, ..started() };
        assert!(Script::new(&st, Some(1.0), None).is_err());
        assert!(!Script::new(&st, None, None).unwrap().is_active());
    }

    #[test]
    fn dolly_scales_the_distance_within_limits() {
        let st = started();
        let mut rig = CameraRig::new(camera_from_wire(st.camera.as_ref().unwrap()));
        rig.dolly(0.5);
        assert!((rig.camera().eye - Vec3::new(0.0, 1.0, 2.0)).length() < 1e-6);
        for _ in 0..100 {
            rig.dolly(0.5);
        }
        let d = (rig.camera().eye - rig.camera().target).length();
        assert!((d - 4.0 * DOLLY_MIN).abs() < 1e-5, "{d}");
        rig.orbit(std::f32::consts::FRAC_PI_2);
        assert!(rig.camera().validate().is_ok());
    }
}
