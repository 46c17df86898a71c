//! Session settings and the validation of viewer input (camera, object moves, settings).
//! Anything out of range is refused with a message naming the field and the allowed range;
//! nothing the viewer sends can panic the session.
use crate::epi::Overlay;
use edgepoint_proto as pb;
use edgepoint_scene::Camera;
use glam::Affine3A;

/// How frames are reconstructed from the cached points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reconstruction {
    /// The edge-and-point image (paper 000 §4–5).
    EdgeAndPoint,
    /// The baseline: the Render Cache's gap-filling interpolation, edges ignored.
    RenderCache,
}

impl Reconstruction {
    pub fn to_wire(self) -> pb::Reconstruction {
        match self {
            Reconstruction::EdgeAndPoint => pb::Reconstruction::EdgeAndPoint,
            Reconstruction::RenderCache => pb::Reconstruction::RenderCache,
        }
    }
}

/// The wire name of an overlay (frames say which one they carry).
pub fn overlay_to_wire(o: Overlay) -> pb::Overlay {
    match o {
        Overlay::None => pb::Overlay::None,
        Overlay::Edges => pb::Overlay::Edges,
        Overlay::Classes => pb::Overlay::Classes,
        Overlay::Samples => pb::Overlay::Samples,
    }
}

/// The settings in force in a session (paper 000 §7.2: sparseness 40–125 in the paper).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionSettings {
    /// Pixels per new sample per frame.
    pub sparseness: f64,
    /// Frame-loop rate cap.
    pub max_fps: f64,
    /// Frame-loop rate cap while the camera and the objects are still (see
    /// `frame_loop::frame_periods`).
    pub rest_fps: f64,
    /// Requests per batch sent to a worker.
    pub batch_size: u32,
    /// Age (frames) at which a sample's priority saturates.
    pub max_age_frames: f64,
    pub paused: bool,
    pub reconstruction: Reconstruction,
    /// Refine complex pixels with the subpixel filter (paper §5.4).
    pub complex_filter: bool,
    pub overlay: Overlay,
    /// Dihedral angle (degrees) at or above which a forward-facing edge is sharp (§6.2).
    pub sharp_cutoff_degrees: f32,
    /// Shadow edges whose estimated error of leaving them out is below this are left out
    /// of the EPI (paper 003, [`crate::edges::simplify`]); 0: off.
    pub simplify_tolerance: f64,
    /// Area-light shadow edges from the discontinuity mesh ([`crate::edges::mesh_edges`])
    /// instead of the triples' edge finder.
    pub mesh_shadow_edges: bool,
}

impl Default for SessionSettings {
    fn default() -> Self {
        SessionSettings {
            sparseness: 64.0,
            max_fps: 30.0,
            rest_fps: 10.0,
            batch_size: 256,
            max_age_frames: 120.0,
            paused: false,
            reconstruction: Reconstruction::EdgeAndPoint,
            complex_filter: true,
            overlay: Overlay::None,
            sharp_cutoff_degrees: crate::edges::DEFAULT_SHARP_CUTOFF_DEGREES,
            simplify_tolerance: 0.0,
            mesh_shadow_edges: false,
        }
    }
}

pub const SPARSENESS_RANGE: (f64, f64) = (1.0, 1.0e6);
pub const MAX_FPS_RANGE: (f64, f64) = (0.1, 1000.0);
pub const BATCH_SIZE_RANGE: (u32, u32) = (1, 65_536);
pub const MAX_AGE_RANGE: (f64, f64) = (1.0, 1.0e7);
/// Simplification tolerances accepted (0: off; a relative error, so 1 already drops
/// nearly every shadow edge).
pub const SIMPLIFY_TOLERANCE_RANGE: (f64, f64) = (0.0, 100.0);
/// Sharp-edge cut-off angles accepted (degrees; 0 on the wire keeps the current value).
pub const SHARP_CUTOFF_RANGE: (f64, f64) = (0.0, 180.0);

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
        if let Some(v) = check_f64("rest_fps", s.rest_fps, MAX_FPS_RANGE)? {
            out.rest_fps = v;
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
        if let Some(v) = s.simplify_tolerance {
            let (lo, hi) = SIMPLIFY_TOLERANCE_RANGE;
            if !v.is_finite() || v < lo || v > hi {
                return Err(format!("settings.simplify_tolerance must be in [{lo}, {hi}] (0 = off), got {v}"));
            }
            out.simplify_tolerance = v;
        }
        match pb::ShadowEdges::try_from(s.shadow_edges) {
            Ok(pb::ShadowEdges::Unspecified) => {}
            Ok(pb::ShadowEdges::Triples) => out.mesh_shadow_edges = false,
            Ok(pb::ShadowEdges::Mesh) => out.mesh_shadow_edges = true,
            Err(_) => return Err(format!("settings.shadow_edges {} is not a known ShadowEdges (0 to keep)", s.shadow_edges)),
        }
        if s.set_paused {
            out.paused = s.paused;
        }
        match pb::Reconstruction::try_from(s.reconstruction) {
            Ok(pb::Reconstruction::Unspecified) => {}
            Ok(pb::Reconstruction::EdgeAndPoint) => out.reconstruction = Reconstruction::EdgeAndPoint,
            Ok(pb::Reconstruction::RenderCache) => out.reconstruction = Reconstruction::RenderCache,
            Err(_) => {
                return Err(format!(
                    "settings.reconstruction {} is not a reconstruction mode (1 = edge-and-point, 2 = render cache, 0 to keep)",
                    s.reconstruction
                ))
            }
        }
        match pb::Overlay::try_from(s.overlay) {
            Ok(pb::Overlay::Unspecified) => {}
            Ok(pb::Overlay::None) => out.overlay = Overlay::None,
            Ok(pb::Overlay::Edges) => out.overlay = Overlay::Edges,
            Ok(pb::Overlay::Classes) => out.overlay = Overlay::Classes,
            Ok(pb::Overlay::Samples) => out.overlay = Overlay::Samples,
            Err(_) => {
                return Err(format!(
                    "settings.overlay {} is not an overlay (1 = none, 2 = edges, 3 = classes, 4 = samples, 0 to keep)",
                    s.overlay
                ))
            }
        }
        if let Some(on) = s.complex_filter {
            out.complex_filter = on;
        }
        if s.sharp_cutoff_degrees != 0.0 {
            let (lo, hi) = SHARP_CUTOFF_RANGE;
            let v = s.sharp_cutoff_degrees;
            if !v.is_finite() || v <= lo || v > hi {
                return Err(format!("settings.sharp_cutoff_degrees must be in ({lo}, {hi}] (or 0 to keep), got {v}"));
            }
            out.sharp_cutoff_degrees = v as f32;
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
        assert_eq!((t.sparseness, t.batch_size, t.max_fps, t.rest_fps), (100.0, 64, 30.0, 10.0));
        assert_eq!(t.with(&pb::Settings { rest_fps: 2.5, ..Default::default() }).unwrap().rest_fps, 2.5);
        let p = t.with(&pb::Settings { paused: true, set_paused: true, ..Default::default() }).unwrap();
        assert!(p.paused);
        assert!(p.with(&pb::Settings { paused: false, ..Default::default() }).unwrap().paused, "needs set_paused");
        for bad in [
            pb::Settings { sparseness: -1.0, ..Default::default() },
            pb::Settings { sparseness: f64::NAN, ..Default::default() },
            pb::Settings { max_fps: 1e9, ..Default::default() },
            pb::Settings { rest_fps: -1.0, ..Default::default() },
            pb::Settings { rest_fps: f64::INFINITY, ..Default::default() },
            pb::Settings { max_age_frames: f64::INFINITY, ..Default::default() },
            pb::Settings { batch_size: 1_000_000, ..Default::default() },
        ] {
            let e = s.with(&bad).unwrap_err();
            assert!(e.starts_with("settings."), "{e}");
        }
        assert!(s.with(&pb::Settings { sparseness: 10.0, max_fps: -3.0, ..Default::default() }).is_err(), "all or nothing");
        // Reconstruction settings: enums with "unspecified keeps", an optional flag, a range.
        let r = s
            .with(&pb::Settings {
                reconstruction: pb::Reconstruction::RenderCache as i32,
                overlay: pb::Overlay::Classes as i32,
                complex_filter: Some(false),
                sharp_cutoff_degrees: 30.0,
                ..Default::default()
            })
            .unwrap();
        assert_eq!((r.reconstruction, r.overlay, r.complex_filter, r.sharp_cutoff_degrees), (Reconstruction::RenderCache, Overlay::Classes, false, 30.0));
        assert_eq!(r.with(&pb::Settings::default()).unwrap(), r, "unspecified keeps");
        let simp = r.with(&pb::Settings { simplify_tolerance: Some(0.05), ..Default::default() }).unwrap();
        assert_eq!(simp.simplify_tolerance, 0.05);
        assert_eq!(simp.with(&pb::Settings::default()).unwrap().simplify_tolerance, 0.05, "unset keeps");
        assert_eq!(simp.with(&pb::Settings { simplify_tolerance: Some(0.0), ..Default::default() }).unwrap().simplify_tolerance, 0.0, "0 turns it off");
        let mesh = r.with(&pb::Settings { shadow_edges: pb::ShadowEdges::Mesh as i32, ..Default::default() }).unwrap();
        assert!(mesh.mesh_shadow_edges && !r.mesh_shadow_edges);
        assert!(mesh.with(&pb::Settings::default()).unwrap().mesh_shadow_edges, "unspecified keeps");
        assert!(!mesh.with(&pb::Settings { shadow_edges: pb::ShadowEdges::Triples as i32, ..Default::default() }).unwrap().mesh_shadow_edges);
        let back = r.with(&pb::Settings { reconstruction: 1, overlay: 1, complex_filter: Some(true), ..Default::default() }).unwrap();
        assert_eq!((back.reconstruction, back.overlay, back.complex_filter), (Reconstruction::EdgeAndPoint, Overlay::None, true));
        for bad in [
            pb::Settings { reconstruction: 7, ..Default::default() },
            pb::Settings { overlay: -1, ..Default::default() },
            pb::Settings { sharp_cutoff_degrees: 181.0, ..Default::default() },
            pb::Settings { sharp_cutoff_degrees: -5.0, ..Default::default() },
            pb::Settings { sharp_cutoff_degrees: f64::NAN, ..Default::default() },
            pb::Settings { simplify_tolerance: Some(-0.1), ..Default::default() },
            pb::Settings { simplify_tolerance: Some(f64::NAN), ..Default::default() },
            pb::Settings { simplify_tolerance: Some(1e3), ..Default::default() },
            pb::Settings { shadow_edges: 3, ..Default::default() },
        ] {
            let e = s.with(&bad).unwrap_err();
            assert!(e.starts_with("settings."), "{e}");
        }
        assert_eq!(s.reconstruction, Reconstruction::EdgeAndPoint, "edge-and-point by default");
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
