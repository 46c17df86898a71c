//! Scripted motion that drives a session without a person: the camera on an orbit or a
//! camera path ([`crate::camera_path`]), and an object sliding back and forth along X (the
//! moving-object case of paper 000 §6.5 and paper 002), one step per received frame.
use anyhow::{anyhow, bail, Result};
use edgepoint_proto::{self as pb};
use edgepoint_scene::Camera;
use glam::{Affine3A, Vec3};

use crate::camera_path::{resolve_path, suggested_orbit, OrbitArgs, PathEntry};
use crate::client::{camera_from_wire, camera_to_wire};
use edgepoint_scene::Orbit;

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
/// Slide amplitude as a fraction of the scene's X extent, at most the object's own width
/// (so a small object on a large floor stays where the camera looks).
pub const SLIDE_AMPLITUDE_FRACTION: f32 = 0.25;

impl ObjectSlide {
    /// The slide of the object called `name` in `started`, with amplitude 25% of the
    /// scene's X extent or the object's own X extent, whichever is less, and a 120-frame
    /// period. An unknown name is an error listing the
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
        let own = match (&obj.bounds_min, &obj.bounds_max) {
            (Some(lo), Some(hi)) => {
                let (lo, hi) = edgepoint_scene::geometry::transformed_box(&base, (glam::Vec3::from(lo), glam::Vec3::from(hi)));
                hi.x - lo.x
            }
            _ => f32::INFINITY,
        };
        let amplitude = if own.is_finite() && own > 0.0 { own.min(SLIDE_AMPLITUDE_FRACTION * extent) } else { SLIDE_AMPLITUDE_FRACTION * extent };
        Ok(ObjectSlide {
            object_id: obj.id,
            name: name.to_string(),
            base,
            amplitude,
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

/// Where the camera goes, frame by frame.
#[derive(Debug, Clone, Default)]
pub enum CameraPlan {
    /// Nowhere (the start camera; keys and mouse move it in a window).
    #[default]
    Still,
    /// `--orbit`: the flags over the scene's suggested orbit; `fov` from `--camera fov=`.
    Orbit { args: OrbitArgs, fov: Option<f32> },
    /// `--camera-path FILE`: its cameras over the start camera, one per received frame;
    /// at the end the path stops (or starts again with `looped`).
    Path { entries: Vec<PathEntry>, name: String, looped: bool },
}

#[derive(Debug, Clone)]
enum CameraScript {
    Still,
    Orbit { orbit: Orbit, step_degrees: f32, k: u64 },
    Path { cameras: Vec<Camera>, next: usize, looped: bool },
}

/// The scripted motion of a run: a camera orbit or path and an optional object slide,
/// advanced once per received frame.
#[derive(Debug, Clone)]
pub struct Script {
    camera: CameraScript,
    slide: Option<ObjectSlide>,
    start_camera: Option<Camera>,
}

impl Script {
    /// A script for a session that started as `started`: the camera as `plan` says, the
    /// object `move_object` sliding when given. Errors name the flag (or the path file and
    /// line) at fault.
    pub fn new(started: &pb::Started, plan: &CameraPlan, move_object: Option<&str>) -> Result<Self> {
        let start_camera = started.camera.as_ref().map(camera_from_wire).filter(|c| c.validate().is_ok());
        let camera = match plan {
            CameraPlan::Still => CameraScript::Still,
            CameraPlan::Orbit { args, fov } => {
                let orbit = args.resolve(&suggested_orbit(started)?, *fov)?;
                CameraScript::Orbit { orbit, step_degrees: args.orbit_speed, k: 0 }
            }
            CameraPlan::Path { entries, name, looped } => {
                let base = start_camera.ok_or_else(|| anyhow!("--camera-path: the server sent no usable start camera"))?;
                CameraScript::Path { cameras: resolve_path(entries, &base, name)?, next: 0, looped: *looped }
            }
        };
        let slide = move_object.map(|name| ObjectSlide::new(started, name)).transpose()?;
        Ok(Script { camera, slide, start_camera })
    }

    /// Whether anything is scripted.
    pub fn is_active(&self) -> bool {
        !matches!(self.camera, CameraScript::Still) || self.slide.is_some()
    }

    /// Whether the camera is scripted (an orbit or a path still playing).
    pub fn drives_camera(&self) -> bool {
        !matches!(self.camera, CameraScript::Still)
    }

    /// The camera the session started with (as the server reported it).
    pub fn start_camera(&self) -> Option<Camera> {
        self.start_camera
    }

    /// Hands the camera over to interactive control: the orbit or path stops.
    pub fn stop_camera(&mut self) {
        self.camera = CameraScript::Still;
    }

    fn next_camera(&mut self) -> Option<Camera> {
        match &mut self.camera {
            CameraScript::Still => None,
            CameraScript::Orbit { orbit, step_degrees, k } => {
                let c = orbit.camera_after(*k as f32 * *step_degrees);
                *k += 1;
                Some(c)
            }
            CameraScript::Path { cameras, next, looped } => {
                if *next >= cameras.len() {
                    if !*looped {
                        return None;
                    }
                    *next = 0;
                }
                *next += 1;
                Some(cameras[*next - 1])
            }
        }
    }

    /// What to send right after `started`, before any frame: the script's first camera.
    pub fn first_step(&mut self) -> ScriptStep {
        ScriptStep { camera: self.next_camera().map(|c| camera_to_wire(&c)), object_move: None }
    }

    /// Advances one received frame and says what to send.
    pub fn on_frame(&mut self) -> ScriptStep {
        let camera = self.next_camera().map(|c| camera_to_wire(&c));
        let object_move = self.slide.as_mut().map(|s| s.next_move());
        ScriptStep { camera, object_move }
    }

    /// Whether a non-looping camera path has been played to its end: every camera was sent
    /// and `frame_camera` (the camera a received frame reports it was rendered with) is the
    /// last one.
    pub fn path_finished(&self, frame_camera: Option<&pb::Camera>) -> bool {
        match &self.camera {
            CameraScript::Path { cameras, next, looped: false } => {
                *next >= cameras.len() && frame_camera.is_some_and(|c| camera_from_wire(c) == cameras[cameras.len() - 1])
            }
            _ => false,
        }
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

    fn orbit_plan(speed: f32) -> CameraPlan {
        CameraPlan::Orbit { args: OrbitArgs { orbit: true, orbit_speed: speed, ..Default::default() }, fov: None }
    }

    #[test]
    fn the_orbit_starts_at_its_first_camera_and_turns_by_the_step() {
        let mut st = started();
        let orbit = Orbit { pivot: Vec3::new(1.0, 0.5, 0.0), radius: 0.8, elevation_degrees: 20.0, start_azimuth_degrees: 45.0, fov_y_degrees: 60.0 };
        st.orbit = Some(pb::orbit_to_wire(&orbit));
        let mut s = Script::new(&st, &orbit_plan(3.0), None).unwrap();
        assert!(s.drives_camera());
        let first = camera_from_wire(&s.first_step().camera.unwrap());
        assert_eq!(first, orbit.camera_after(0.0));
        for k in 1..=200u32 {
            let cam = camera_from_wire(&s.on_frame().camera.unwrap());
            // Against the closed form: the eye on the circle at start + k * step.
            let a = (45.0 + 3.0 * k as f32).to_radians();
            let e = 20f32.to_radians();
            let want = orbit.pivot + 0.8 * Vec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos());
            assert!((cam.eye - want).length() < 1e-4, "frame {k}: {} vs {want}", cam.eye);
            assert_eq!((cam.target, cam.fov_y_degrees), (orbit.pivot, 60.0));
        }
        s.stop_camera();
        assert!(s.on_frame().camera.is_none() && !s.drives_camera());
    }

    #[test]
    fn a_path_plays_once_or_loops() {
        let st = started();
        let entries = crate::camera_path::parse_path("{\"fov\":30}\n{\"fov\":31}\n", "p").unwrap();
        let plan = CameraPlan::Path { entries: entries.clone(), name: "p".into(), looped: false };
        let mut s = Script::new(&st, &plan, None).unwrap();
        let fov = |c: Option<pb::Camera>| c.map(|c| c.fov_y_degrees);
        assert_eq!(fov(s.first_step().camera), Some(30.0));
        assert!(!s.path_finished(None));
        let last = s.on_frame().camera;
        assert_eq!(fov(last), Some(31.0));
        assert!(s.on_frame().camera.is_none(), "played once");
        let first = camera_to_wire(&camera_from_wire(started().camera.as_ref().unwrap()));
        assert!(!s.path_finished(Some(&first)), "a frame of an earlier camera");
        assert!(s.path_finished(last.as_ref()), "the frame of the last camera ends it");
        let plan = CameraPlan::Path { entries, name: "p".into(), looped: true };
        let mut s = Script::new(&st, &plan, None).unwrap();
        let got: Vec<_> = std::iter::once(s.first_step().camera).chain((0..4).map(|_| s.on_frame().camera)).map(fov).collect();
        assert_eq!(got, [Some(30.0), Some(31.0), Some(30.0), Some(31.0), Some(30.0)]);
        assert!(!s.path_finished(last.as_ref()), "a looping path never ends");
    }

    #[test]
    fn slide_composes_with_the_start_transform() {
        let st = started();
        let base = pb::affine_from_wire(st.objects[1].transform.as_ref().unwrap()).unwrap();
        let mut s = Script::new(&st, &CameraPlan::Still, Some("tallbox")).unwrap();
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
        let msg = Script::new(&started(), &CameraPlan::Still, Some("teapot")).unwrap_err().to_string();
        assert!(msg.contains("teapot") && msg.contains("floor, tallbox"), "{msg}");
    }

    #[test]
    fn orbit_without_a_camera_or_orbit_is_an_error() {
        let st = pb::Started { camera: None, ..started() };
        assert!(Script::new(&st, &orbit_plan(1.0), None).is_err());
        assert!(!Script::new(&st, &CameraPlan::Still, None).unwrap().is_active());
        let bad = pb::Started { orbit: Some(pb::Orbit { radius: -1.0, ..Default::default() }), ..started() };
        assert!(Script::new(&bad, &orbit_plan(1.0), None).unwrap_err().to_string().contains("bad orbit"));
    }
}
