//! Camera control from the command line and from files, shared by the viewer and the
//! benchmarks:
//! - [`CameraSpec`]: `--camera "eye=X,Y,Z target=X,Y,Z up=X,Y,Z fov=DEG"`, any subset of the
//!   keys, each overriding the scene's camera (sent in `Start.camera`, whose unset fields
//!   keep the scene's).
//! - camera path files: one camera per line as JSON, `{"eye":[x,y,z],"target":[x,y,z],
//!   "up":[x,y,z],"fov":deg}` (any subset of the keys again, over the session's start
//!   camera; blank lines and `#` comments skipped), read with [`read_path`] (errors name the
//!   file and line) and written with [`PathWriter`].
//! - [`OrbitArgs`]: `--orbit` with pivot, radius, elevation and degrees per frame, each
//!   defaulting to the orbit the server suggests for the scene (`Started.orbit`).
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_scene::{Camera, Orbit};
use glam::Vec3;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Keys `--camera` and path lines take.
pub const CAMERA_KEYS: &str = "eye, target, up, fov";

/// Some of a camera's fields, each overriding a base camera's.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CameraSpec {
    pub eye: Option<Vec3>,
    pub target: Option<Vec3>,
    pub up: Option<Vec3>,
    pub fov_y_degrees: Option<f32>,
}

fn finite_number(key: &str, s: &str) -> Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|_| format!("{key}: '{s}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("{key}: {s} is not finite"));
    }
    Ok(v)
}

/// `X,Y,Z` as a finite vector (errors name `what`).
pub fn parse_vec3(what: &str, s: &str) -> Result<Vec3, String> {
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != 3 {
        return Err(format!("{what} needs three numbers X,Y,Z, got '{s}'"));
    }
    let mut v = [0.0f32; 3];
    for (i, p) in parts.iter().enumerate() {
        v[i] = finite_number(what, p)?;
    }
    Ok(Vec3::from(v))
}

fn check_fov(what: &str, v: f32) -> Result<f32, String> {
    if !(v.is_finite() && v > 0.0 && v < 180.0) {
        return Err(format!("{what} must be in (0, 180) degrees, got {v}"));
    }
    Ok(v)
}

/// Parses `eye=X,Y,Z target=X,Y,Z up=X,Y,Z fov=DEG` (any subset, separated by spaces; each
/// key at most once). Errors name the bad key or value. A clap value parser.
pub fn parse_camera_spec(s: &str) -> Result<CameraSpec, String> {
    let mut spec = CameraSpec::default();
    let mut any = false;
    for item in s.split_whitespace() {
        let (key, value) =
            item.split_once('=').ok_or_else(|| format!("'{item}' is not KEY=VALUE (keys: {CAMERA_KEYS})"))?;
        let seen = match key {
            "eye" => spec.eye.replace(parse_vec3("eye", value)?).is_some(),
            "target" => spec.target.replace(parse_vec3("target", value)?).is_some(),
            "up" => spec.up.replace(parse_vec3("up", value)?).is_some(),
            "fov" => spec.fov_y_degrees.replace(check_fov("fov", finite_number("fov", value)?)?).is_some(),
            _ => return Err(format!("unknown key '{key}' (keys: {CAMERA_KEYS})")),
        };
        if seen {
            return Err(format!("'{key}' is given twice"));
        }
        any = true;
    }
    if !any {
        return Err(format!("no camera keys given (keys: {CAMERA_KEYS}, e.g. \"eye=0,1,4 target=0,1,0\")"));
    }
    spec.check_alone()?;
    Ok(spec)
}

impl CameraSpec {
    /// Every field set.
    pub fn full(c: &Camera) -> Self {
        CameraSpec { eye: Some(c.eye), target: Some(c.target), up: Some(c.up), fov_y_degrees: Some(c.fov_y_degrees) }
    }

    /// `base` with the fields this spec sets replaced, as a full spec.
    pub fn over(&self, base: &Camera) -> CameraSpec {
        CameraSpec {
            eye: self.eye.or(Some(base.eye)),
            target: self.target.or(Some(base.target)),
            up: self.up.or(Some(base.up)),
            fov_y_degrees: self.fov_y_degrees.or(Some(base.fov_y_degrees)),
        }
    }

    /// Whether no field is set.
    pub fn is_empty(&self) -> bool {
        *self == CameraSpec::default()
    }

    /// Whether it sets where the camera is or looks (eye, target or up), not only the lens.
    pub fn places_the_camera(&self) -> bool {
        self.eye.is_some() || self.target.is_some() || self.up.is_some()
    }

    /// What can be refused without a base camera: eye equal to target, up zero or along the
    /// view direction when the fields involved are all given.
    fn check_alone(&self) -> Result<(), String> {
        if let Some(up) = self.up {
            if up.length() < 1e-9 {
                return Err("up must not be zero".into());
            }
        }
        if let (Some(e), Some(t)) = (self.eye, self.target) {
            if (t - e).length() < 1e-9 {
                return Err(format!("eye and target coincide ({e})"));
            }
            if let Some(up) = self.up {
                if (t - e).normalize().cross(up.normalize()).length() < 1e-6 {
                    return Err("up is parallel to the view direction (target - eye)".into());
                }
            }
        }
        Ok(())
    }

    /// The wire form for `Start.camera`: unset fields stay unset (the server keeps the
    /// scene's).
    pub fn to_wire(&self) -> pb::Camera {
        pb::Camera {
            eye: self.eye.map(Into::into),
            target: self.target.map(Into::into),
            up: self.up.map(Into::into),
            fov_y_degrees: self.fov_y_degrees.unwrap_or(0.0),
        }
    }

    /// `base` with the fields this sets replaced, validated (the same rule the server
    /// applies to `Start.camera`).
    pub fn apply(&self, base: &Camera) -> Result<Camera, String> {
        pb::camera_over(&self.to_wire(), base)
    }
}

/// One line of a camera path file.
#[derive(Debug, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct PathLine {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    eye: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    target: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    up: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fov: Option<f32>,
}

/// A camera of a path file with the line it came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathEntry {
    pub line: usize,
    pub spec: CameraSpec,
}

/// Camera path text (`name` for errors): one camera per line, blank lines and `#` comments
/// skipped. Errors say `NAME: line N: ...`. An empty path is an error.
pub fn parse_path(text: &str, name: &str) -> Result<Vec<PathEntry>> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let n = i + 1;
        let p: PathLine = serde_json::from_str(line).map_err(|e| {
            anyhow::anyhow!("{name}: line {n}: {e} (expected {{\"eye\":[x,y,z],\"target\":[x,y,z],\"up\":[x,y,z],\"fov\":deg}})")
        })?;
        let vec = |key: &str, v: Option<[f32; 3]>| -> Result<Option<Vec3>> {
            match v.map(Vec3::from) {
                Some(v) if !v.is_finite() => bail!("{name}: line {n}: {key} is not finite ({v})"),
                v => Ok(v),
            }
        };
        let spec = CameraSpec {
            eye: vec("eye", p.eye)?,
            target: vec("target", p.target)?,
            up: vec("up", p.up)?,
            fov_y_degrees: p.fov.map(|f| check_fov("fov", f)).transpose().map_err(|e| anyhow::anyhow!("{name}: line {n}: {e}"))?,
        };
        if spec.is_empty() {
            bail!("{name}: line {n}: no camera keys (keys: {CAMERA_KEYS})");
        }
        spec.check_alone().map_err(|e| anyhow::anyhow!("{name}: line {n}: {e}"))?;
        out.push(PathEntry { line: n, spec });
    }
    if out.is_empty() {
        bail!("{name}: the camera path has no cameras");
    }
    Ok(out)
}

/// Reads a camera path file (see [`parse_path`]).
pub fn read_path(path: &Path) -> Result<Vec<PathEntry>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read camera path {}", path.display()))?;
    parse_path(&text, &path.display().to_string())
}

/// The path's cameras over `base` (the session's start camera); a line that makes an
/// unusable camera is an error naming the file and line.
pub fn resolve_path(entries: &[PathEntry], base: &Camera, name: &str) -> Result<Vec<Camera>> {
    entries
        .iter()
        .map(|e| e.spec.apply(base).map_err(|m| anyhow::anyhow!("{name}: line {}: {m}", e.line)))
        .collect()
}

/// One path line for a camera (every key).
pub fn path_line(c: &Camera) -> String {
    let l = PathLine { eye: Some(c.eye.into()), target: Some(c.target.into()), up: Some(c.up.into()), fov: Some(c.fov_y_degrees) };
    serde_json::to_string(&l).expect("plain numbers serialize")
}

/// Writes a camera path file line by line, flushed per camera so the file is complete
/// whenever the run stops.
pub struct PathWriter {
    path: PathBuf,
    out: BufWriter<File>,
    written: usize,
}

impl PathWriter {
    pub fn create(path: &Path) -> Result<Self> {
        let f = File::create(path).with_context(|| format!("cannot create camera path {}", path.display()))?;
        Ok(PathWriter { path: path.to_path_buf(), out: BufWriter::new(f), written: 0 })
    }

    pub fn push(&mut self, c: &Camera) -> Result<()> {
        writeln!(self.out, "{}", path_line(c)).and_then(|_| self.out.flush()).with_context(|| format!("cannot write {}", self.path.display()))?;
        self.written += 1;
        Ok(())
    }

    /// Cameras written so far.
    pub fn written(&self) -> usize {
        self.written
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Writes `cameras` as a path file.
pub fn write_path(path: &Path, cameras: &[Camera]) -> Result<()> {
    let mut w = PathWriter::create(path)?;
    for c in cameras {
        w.push(c)?;
    }
    Ok(())
}

/// `--orbit` and its parameters; unset ones come from the scene's suggested orbit.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct OrbitArgs {
    /// Orbit the camera, one step per received frame, along the scene's suggested orbit
    /// (built-ins: inside the room and outside every object all the way round; a loaded
    /// model: about its framing target), changed by the --orbit-* flags. The orbit looks at
    /// its pivot; --camera fov=DEG sets its field of view.
    #[arg(long)]
    pub orbit: bool,

    /// Point the orbit circles and looks at (default: the scene's).
    #[arg(long, value_name = "X,Y,Z", requires = "orbit", value_parser = |s: &str| parse_vec3("--orbit-pivot", s))]
    pub orbit_pivot: Option<Vec3>,

    /// Distance from the eye to the pivot (default: the scene's).
    #[arg(long, value_name = "R", requires = "orbit", value_parser = parse_positive_f32)]
    pub orbit_radius: Option<f32>,

    /// Degrees of the eye above the pivot's horizontal plane, within ±85 (default: the scene's).
    #[arg(long, value_name = "DEGREES", requires = "orbit", allow_negative_numbers = true, value_parser = parse_elevation)]
    pub orbit_elevation: Option<f32>,

    /// Azimuth of the first camera in degrees about +Y from +Z toward +X (default: the scene's).
    #[arg(long, value_name = "DEGREES", requires = "orbit", allow_negative_numbers = true, value_parser = parse_finite_f32)]
    pub orbit_start: Option<f32>,

    /// Orbit step in degrees per received frame (negative turns the other way).
    #[arg(long, value_name = "DEGREES", default_value_t = 1.0, allow_negative_numbers = true, value_parser = parse_finite_f32)]
    pub orbit_speed: f32,
}

fn parse_finite_f32(s: &str) -> Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("must be a finite number, got {s}"));
    }
    Ok(v)
}

fn parse_positive_f32(s: &str) -> Result<f32, String> {
    let v = parse_finite_f32(s)?;
    if v <= 0.0 {
        return Err(format!("must be a positive number, got {s}"));
    }
    Ok(v)
}

fn parse_elevation(s: &str) -> Result<f32, String> {
    let v = parse_finite_f32(s)?;
    let max = edgepoint_scene::orbit::MAX_ELEVATION_DEGREES;
    if v.abs() > max {
        return Err(format!("must be within ±{max} degrees, got {s}"));
    }
    Ok(v)
}

impl OrbitArgs {
    /// The orbit to fly: `suggested` (the scene's) with the flags given replacing its
    /// fields, and `fov` (from `--camera fov=`) replacing its field of view.
    pub fn resolve(&self, suggested: &Orbit, fov: Option<f32>) -> Result<Orbit> {
        let o = Orbit {
            pivot: self.orbit_pivot.unwrap_or(suggested.pivot),
            radius: self.orbit_radius.unwrap_or(suggested.radius),
            elevation_degrees: self.orbit_elevation.unwrap_or(suggested.elevation_degrees),
            start_azimuth_degrees: self.orbit_start.unwrap_or(suggested.start_azimuth_degrees),
            fov_y_degrees: fov.unwrap_or(suggested.fov_y_degrees),
        };
        o.validate().map_err(|e| anyhow::anyhow!("--orbit: {e}"))?;
        Ok(o)
    }
}

/// The orbit a session's `started` suggests, or, from an older server without one, the
/// orbit through its camera.
pub fn suggested_orbit(started: &pb::Started) -> Result<Orbit> {
    if let Some(o) = &started.orbit {
        return pb::orbit_from_wire(o).map_err(|e| anyhow::anyhow!("the server suggested a bad orbit: {e}"));
    }
    let cam = started.camera.as_ref().context("the server's `started` carries no camera and no orbit")?;
    let cam = crate::client::camera_from_wire(cam);
    cam.validate().map_err(|e| anyhow::anyhow!("the server's camera is unusable: {e}"))?;
    Ok(Orbit::through(&cam))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base() -> Camera {
        Camera { eye: Vec3::new(0.0, 1.0, 4.0), target: Vec3::new(0.0, 1.0, 0.0), up: Vec3::Y, fov_y_degrees: 40.0 }
    }

    #[test]
    fn camera_specs_parse_any_subset_and_override_the_base() {
        let s = parse_camera_spec("eye=1,2,3 target=0,0.5,0 up=0,1,0 fov=55").unwrap();
        assert_eq!(s, CameraSpec::full(&Camera { eye: Vec3::new(1.0, 2.0, 3.0), target: Vec3::new(0.0, 0.5, 0.0), up: Vec3::Y, fov_y_degrees: 55.0 }));
        let s = parse_camera_spec("  fov=70 ").unwrap();
        assert_eq!(s, CameraSpec { fov_y_degrees: Some(70.0), ..Default::default() });
        let c = s.apply(&base()).unwrap();
        assert_eq!((c.eye, c.fov_y_degrees), (base().eye, 70.0));
        let w = s.to_wire();
        assert!(w.eye.is_none() && w.target.is_none() && w.up.is_none() && w.fov_y_degrees == 70.0);
        let c = parse_camera_spec("eye=-2,1,0").unwrap().apply(&base()).unwrap();
        assert_eq!((c.eye, c.target), (Vec3::new(-2.0, 1.0, 0.0), base().target));
        // A spec that is fine alone but degenerate over the base.
        let e = parse_camera_spec("target=0,1,4").unwrap().apply(&base()).unwrap_err();
        assert!(e.contains("coincide"), "{e}");
    }

    #[test]
    fn bad_camera_specs_name_the_key_or_value() {
        for (s, needle) in [
            ("", "no camera keys"),
            ("eye=1,2", "eye needs three numbers"),
            ("eye=1,2,x", "eye: 'x' is not a number"),
            ("target=1,inf,0", "target: inf is not finite"),
            ("fov=0", "fov must be in (0, 180)"),
            ("fov=nan", "fov: nan is not finite"),
            ("position=1,2,3", "unknown key 'position'"),
            ("eye", "'eye' is not KEY=VALUE"),
            ("fov=30 fov=40", "'fov' is given twice"),
            ("eye=1,1,1 target=1,1,1", "eye and target coincide"),
            ("eye=0,0,0 target=0,1,0 up=0,2,0", "parallel"),
            ("up=0,0,0", "up must not be zero"),
        ] {
            let e = parse_camera_spec(s).unwrap_err();
            assert!(e.contains(needle), "{s:?}: {e}");
        }
    }

    #[test]
    fn paths_round_trip_and_errors_name_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("path.jsonl");
        let cams: Vec<Camera> = (0..5).map(|k| base().orbit(base().target, k as f32 * 0.1)).collect();
        write_path(&file, &cams).unwrap();
        let entries = read_path(&file).unwrap();
        assert_eq!(entries.len(), 5);
        let back = resolve_path(&entries, &base(), "path.jsonl").unwrap();
        assert_eq!(back, cams, "f32 values round-trip through JSON exactly");

        let text = "# a comment\n\n{\"eye\":[0,2,5]}\n{\"fov\":30}\n";
        let e = parse_path(text, "p").unwrap();
        assert_eq!((e[0].line, e[1].line), (3, 4));
        let r = resolve_path(&e, &base(), "p").unwrap();
        assert_eq!((r[0].eye, r[0].target, r[1].fov_y_degrees, r[1].eye), (Vec3::new(0.0, 2.0, 5.0), base().target, 30.0, base().eye));

        for (text, needle) in [
            ("{\"eye\":[0,1,2]}\n{\"eye\":[0,1]}\n", "p: line 2:"),
            ("\n\n{\"eye\":[0,1,2],\"zoom\":3}\n", "p: line 3: unknown field `zoom`"),
            ("{\"fov\":200}\n", "p: line 1: fov must be in (0, 180)"),
            ("{}\n", "p: line 1: no camera keys"),
            ("{\"eye\":[0,1,2],\"target\":[0,1,2]}\n", "p: line 1: eye and target coincide"),
            ("not json\n", "p: line 1:"),
            ("# only a comment\n", "has no cameras"),
        ] {
            let e = parse_path(text, "p").unwrap_err().to_string();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
        // Degenerate only over the base: named with its line at resolve time.
        let e = parse_path("{\"eye\":[0,1,2]}\n{\"target\":[0,1,4]}\n", "p").unwrap();
        assert!(resolve_path(&e, &base(), "p").unwrap_err().to_string().contains("p: line 2: camera eye and target coincide"));
        assert!(read_path(&dir.path().join("missing")).unwrap_err().to_string().contains("missing"));
    }

    #[test]
    fn orbit_flags_replace_the_suggested_orbit_field_by_field() {
        let suggested = Orbit { pivot: Vec3::new(1.0, 0.5, 1.0), radius: 2.0, elevation_degrees: 30.0, start_azimuth_degrees: 90.0, fov_y_degrees: 50.0 };
        let none = OrbitArgs { orbit: true, orbit_speed: 1.0, ..Default::default() };
        assert_eq!(none.resolve(&suggested, None).unwrap(), suggested);
        let some = OrbitArgs { orbit_radius: Some(3.0), orbit_elevation: Some(-10.0), ..none.clone() };
        let o = some.resolve(&suggested, Some(70.0)).unwrap();
        assert_eq!((o.pivot, o.radius, o.elevation_degrees, o.start_azimuth_degrees, o.fov_y_degrees), (suggested.pivot, 3.0, -10.0, 90.0, 70.0));
        assert!(parse_elevation("86").unwrap_err().contains("85"));
        assert!(parse_positive_f32("0").is_err() && parse_positive_f32("-1").is_err());
        // From a server that suggests none: the orbit through its camera.
        let st = pb::Started { camera: Some(crate::client::camera_to_wire(&base())), ..Default::default() };
        let o = suggested_orbit(&st).unwrap();
        assert!((o.camera_after(0.0).eye - base().eye).length() < 1e-5);
        let st = pb::Started { orbit: Some(pb::orbit_to_wire(&suggested)), ..st };
        assert_eq!(suggested_orbit(&st).unwrap(), suggested);
    }
}
