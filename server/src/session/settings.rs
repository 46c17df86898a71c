//! Session settings and the validation of viewer input (camera, object moves, settings).
//! Anything out of range is refused with a message naming the field and the allowed range;
//! nothing the viewer sends can panic the session.
use edgepoint_proto as pb;
use edgepoint_scene::Camera;
use glam::Affine3A;

/// The settings in force in a session (paper 000 §7.2: sparseness 40–125 in the paper).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionSettings {
    /// Pixels per new sample per frame.
    pub sparseness: f64,
    /// Frame-loop rate cap.
    pub max_fps: f64,
    /// Requests per batch sent to a worker.
    pub batch_size: u32,
    /// Age (frames) at which a sample's priority saturates.
    pub max_age_frames: f64,
    pub paused: bool,
}

impl Default for SessionSettings {
    fn default() -> Self {
        SessionSettings { sparseness: 64.0, max_fps: 30.0, batch_size: 256, max_age_frames: 120.0, paused: false }
    }
}

pub const SPARSENESS_RANGE: (f64, f64) = (1.0, 1.0e6);
pub const MAX_FPS_RANGE: (f64, f64) = (0.1, 1000.0);
pub const BATCH_SIZE_RANGE: (u32, u32) = (1, 65_536);
pub const MAX_AGE_RANGE: (f64, f64) = (1.0, 1.0e7);

fn check_f64(name: &str, v: f64, (lo, hi): (f64, f64)) -> Result<Option<f64>, String> {
    // Zero means "keep the current value" (proto3 has no presence for scalars).
    if v == 0.0 {
        return Ok(None);
    }
    if !v.is_finite() || v < lo || v > hi {
        return Err(format!("settings.{name} must be in [{lo}, {hi}] (or 0 to keep), got {v}"));
    }
    Ok(Some(v))
}

impl SessionSettings {
    /// The settings with `s` applied, or why `s` is refused (then nothing of it applies).
    pub fn with(&self, s: &pb::Settings) -> Result<SessionSettings, String> {
        let mut out = *self;
        if let Some(v) = check_f64("sparseness", s.sparseness, SPARSENESS_RANGE)? {
            out.sparseness = v;
        }
        if let Some(v) = check_f64("max_fps", s.max_fps, MAX_FPS_RANGE)? {
            out.max_fps = v;
        }
        if let Some(v) = check_f64("max_age_frames", s.max_age_frames, MAX_AGE_RANGE)? {
            out.max_age_frames = v;
        }
        if s.batch_size != 0 {
            let (lo, hi) = BATCH_SIZE_RANGE;
            if s.batch_size < lo || s.batch_size > hi {
                return Err(format!("settings.batch_size must be in [{lo}, {hi}] (or 0 to keep), got {}", s.batch_size));
            }
            out.batch_size = s.batch_size;
        }
        if s.set_paused {
            out.paused = s.paused;
        }
        Ok(out)
    }

    /// New samples wanted per frame for an image of `pixels` pixels.
    pub fn frame_budget(&self, pixels: usize) -> usize {
        ((pixels as f64 / self.sparseness).ceil() as usize).max(1)
    }
}

/// A wire camera as a validated scene camera.
pub fn camera_from_wire(c: &pb::Camera) -> Result<Camera, String> {
    let get = |name: &str, v: &Option<pb::Vec3>| {
        v.as_ref().map(glam::Vec3::from).ok_or_else(|| format!("camera {name} is missing"))
    };
    let cam = Camera { eye: get("eye", &c.eye)?, target: get("target", &c.target)?, up: get("up", &c.up)?, fov_y_degrees: c.fov_y_degrees };
    cam.validate()?;
    Ok(cam)
}

pub fn camera_to_wire(c: &Camera) -> pb::Camera {
    pb::Camera { eye: Some(c.eye.into()), target: Some(c.target.into()), up: Some(c.up.into()), fov_y_degrees: c.fov_y_degrees }
}

/// Resolves an object move against the scene's object names: (object id, new transform).
pub fn resolve_move(m: &pb::ObjectMove, names: &[String]) -> Result<(u32, Affine3A), String> {
    let id = if !m.name.is_empty() {
        names
            .iter()
            .position(|n| *n == m.name)
            .ok_or_else(|| format!("no object named '{}' (the scene has {} objects)", m.name, names.len()))? as u32
    } else if (m.object_id as usize) < names.len() {
        m.object_id
    } else {
        return Err(format!("no object with id {} (ids are 0..{})", m.object_id, names.len()));
    };
    let t = m.transform.as_ref().ok_or_else(|| format!("move of object {id}: transform is missing"))?;
    let t = pb::affine_from_wire(t).map_err(|e| format!("move of object {id}: {e}"))?;
    Ok((id, t))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_apply_keep_and_refuse() {
        let s = SessionSettings::default();
        let keep = s.with(&pb::Settings::default()).unwrap();
        assert_eq!(keep, s, "all-zero settings keep everything");
        let t = s.with(&pb::Settings { sparseness: 100.0, batch_size: 64, ..Default::default() }).unwrap();
        assert_eq!((t.sparseness, t.batch_size, t.max_fps), (100.0, 64, 30.0));
        let p = t.with(&pb::Settings { paused: true, set_paused: true, ..Default::default() }).unwrap();
        assert!(p.paused);
        assert!(p.with(&pb::Settings { paused: false, ..Default::default() }).unwrap().paused, "needs set_paused");
        for bad in [
            pb::Settings { sparseness: -1.0, ..Default::default() },
            pb::Settings { sparseness: f64::NAN, ..Default::default() },
            pb::Settings { max_fps: 1e9, ..Default::default() },
            pb::Settings { max_age_frames: f64::INFINITY, ..Default::default() },
            pb::Settings { batch_size: 1_000_000, ..Default::default() },
        ] {
            let e = s.with(&bad).unwrap_err();
            assert!(e.starts_with("settings."), "{e}");
        }
        assert!(s.with(&pb::Settings { sparseness: 10.0, max_fps: -3.0, ..Default::default() }).is_err(), "all or nothing");
        assert_eq!(s.frame_budget(64 * 48), 48);
        assert_eq!(SessionSettings { sparseness: 1e6, ..s }.frame_budget(10), 1);
    }

    #[test]
    fn cameras_are_validated() {
        let good = pb::Camera {
            eye: Some(glam::Vec3::new(0.0, 1.0, 3.0).into()),
            target: Some(glam::Vec3::ZERO.into()),
            up: Some(glam::Vec3::Y.into()),
            fov_y_degrees: 40.0,
        };
        let cam = camera_from_wire(&good).unwrap();
        assert_eq!(camera_to_wire(&cam), good);
        let mut nan = good;
        nan.eye = Some(glam::Vec3::new(f32::NAN, 0.0, 0.0).into());
        assert!(camera_from_wire(&nan).unwrap_err().contains("not finite"));
        let mut parallel = good;
        parallel.up = Some(glam::Vec3::new(0.0, -1.0, -3.0).into());
        assert!(camera_from_wire(&parallel).is_err());
        let mut fov = good;
        fov.fov_y_degrees = 180.0;
        assert!(camera_from_wire(&fov).unwrap_err().contains("field of view"));
        let mut missing = good;
        missing.target = None;
        assert!(camera_from_wire(&missing).unwrap_err().contains("target is missing"));
    }

    #[test]
    fn moves_resolve_by_id_or_name() {
        let names = vec!["floor".to_string(), "box".to_string()];
        let t = Some(pb::affine_to_wire(&Affine3A::from_translation(glam::Vec3::X)));
        let (id, a) = resolve_move(&pb::ObjectMove { object_id: 1, name: String::new(), transform: t.clone() }, &names).unwrap();
        assert_eq!(id, 1);
        assert!(a.abs_diff_eq(Affine3A::from_translation(glam::Vec3::X), 1e-6));
        let (id, _) = resolve_move(&pb::ObjectMove { object_id: 0, name: "box".into(), transform: t.clone() }, &names).unwrap();
        assert_eq!(id, 1);
        assert!(resolve_move(&pb::ObjectMove { object_id: 2, name: String::new(), transform: t.clone() }, &names).unwrap_err().contains("id 2"));
        assert!(resolve_move(&pb::ObjectMove { object_id: 0, name: "lamp".into(), transform: t }, &names).unwrap_err().contains("'lamp'"));
        assert!(resolve_move(&pb::ObjectMove { object_id: 0, name: String::new(), transform: None }, &names).unwrap_err().contains("missing"));
        let singular = Some(pb::Affine { rows: vec![0.0; 12] });
        assert!(resolve_move(&pb::ObjectMove { object_id: 0, name: String::new(), transform: singular }, &names).unwrap_err().contains("singular"));
    }
}
