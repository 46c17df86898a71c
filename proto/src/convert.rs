//! Conversions between wire types and glam, and the canonical scene hash.
use crate::v1;
use glam::{Affine3A, Mat3A, Vec3, Vec3A};
use prost::Message;
use sha2::{Digest, Sha256};

impl From<Vec3> for v1::Vec3 {
    fn from(v: Vec3) -> Self {
        v1::Vec3 { x: v.x, y: v.y, z: v.z }
    }
}
impl From<Vec3A> for v1::Vec3 {
    fn from(v: Vec3A) -> Self {
        v1::Vec3 { x: v.x, y: v.y, z: v.z }
    }
}
impl From<v1::Vec3> for Vec3 {
    fn from(v: v1::Vec3) -> Self {
        Vec3::new(v.x, v.y, v.z)
    }
}
impl From<&v1::Vec3> for Vec3 {
    fn from(v: &v1::Vec3) -> Self {
        Vec3::new(v.x, v.y, v.z)
    }
}

/// Reads an optional wire vector, treating an absent one as zero.
pub fn vec3_or_zero(v: &Option<v1::Vec3>) -> Vec3 {
    v.as_ref().map(Vec3::from).unwrap_or(Vec3::ZERO)
}

/// Encodes an affine transform as 12 row-major values (the rows of [R|t]).
pub fn affine_to_wire(a: &Affine3A) -> v1::Affine {
    let m = a.matrix3;
    let t = a.translation;
    v1::Affine {
        rows: vec![
            m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x, //
            m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y, //
            m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z,
        ],
    }
}

/// Decodes 12 row-major values into an affine transform; rejects wrong lengths, non-finite
/// values and singular matrices with a message saying which.
pub fn affine_from_wire(w: &v1::Affine) -> Result<Affine3A, String> {
    let r = &w.rows;
    if r.len() != 12 {
        return Err(format!("transform needs 12 values (3 rows of [R|t]), got {}", r.len()));
    }
    if let Some(i) = r.iter().position(|v| !v.is_finite()) {
        return Err(format!("transform value {i} is not finite ({})", r[i]));
    }
    let m = Mat3A::from_cols(
        Vec3A::new(r[0], r[4], r[8]),
        Vec3A::new(r[1], r[5], r[9]),
        Vec3A::new(r[2], r[6], r[10]),
    );
    let det = m.determinant();
    if !(det.abs() >= 1e-12) {
        return Err(format!("transform is singular (determinant {det})"));
    }
    let a = Affine3A::from_mat3_translation(m.into(), Vec3::new(r[3], r[7], r[11]));
    edgepoint_scene::limits::check_affine(&a)?;
    Ok(a)
}

/// The wire form of an orbit.
pub fn orbit_to_wire(o: &edgepoint_scene::Orbit) -> v1::Orbit {
    v1::Orbit {
        pivot: Some(o.pivot.into()),
        radius: o.radius,
        elevation_degrees: o.elevation_degrees,
        start_azimuth_degrees: o.start_azimuth_degrees,
        fov_y_degrees: o.fov_y_degrees,
    }
}

/// A wire orbit as a validated orbit (errors name the field).
pub fn orbit_from_wire(w: &v1::Orbit) -> Result<edgepoint_scene::Orbit, String> {
    let o = edgepoint_scene::Orbit {
        pivot: w.pivot.as_ref().map(Vec3::from).ok_or("orbit pivot is missing")?,
        radius: w.radius,
        elevation_degrees: w.elevation_degrees,
        start_azimuth_degrees: w.start_azimuth_degrees,
        fov_y_degrees: w.fov_y_degrees,
    };
    o.validate()?;
    Ok(o)
}

/// `partial` over `base`: each field `partial` sets (a present vector, a non-zero field of
/// view) replaces `base`'s (the meaning of `Start.camera`). The result is validated, and a
/// set field that is not finite is named even when the rest would do.
pub fn camera_over(partial: &v1::Camera, base: &edgepoint_scene::Camera) -> Result<edgepoint_scene::Camera, String> {
    check_partial_camera(partial)?;
    let pick = |v: &Option<v1::Vec3>, b: Vec3| v.as_ref().map(Vec3::from).unwrap_or(b);
    let fov = if partial.fov_y_degrees == 0.0 { base.fov_y_degrees } else { partial.fov_y_degrees };
    let c = edgepoint_scene::Camera {
        eye: pick(&partial.eye, base.eye),
        target: pick(&partial.target, base.target),
        up: pick(&partial.up, base.up),
        fov_y_degrees: fov,
    };
    c.validate()?;
    Ok(c)
}

/// What can be checked of a partial camera without its base: every set field is finite and
/// a set field of view is in (0, 180).
pub fn check_partial_camera(c: &v1::Camera) -> Result<(), String> {
    for (name, v) in [("eye", &c.eye), ("target", &c.target), ("up", &c.up)] {
        if let Some(v) = v {
            let v = Vec3::from(v);
            if !v.is_finite() {
                return Err(format!("camera {name} is not finite ({v})"));
            }
        }
    }
    let f = c.fov_y_degrees;
    if f != 0.0 && !(f.is_finite() && f > 0.0 && f < 180.0) {
        return Err(format!("camera field of view must be in (0, 180) degrees, got {f}"));
    }
    Ok(())
}

/// The content hash of a scene source: hex SHA-256 of its canonical protobuf encoding.
/// Server and workers both compute it, so a worker can be asked for a scene by hash.
pub fn scene_hash(src: &v1::SceneSource) -> String {
    let bytes = src.encode_to_vec();
    let digest = Sha256::digest(&bytes);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn affine_round_trips() {
        let a = Affine3A::from_scale_rotation_translation(
            Vec3::new(1.0, 2.0, 0.5),
            glam::Quat::from_rotation_y(0.7),
            Vec3::new(3.0, -1.0, 2.0),
        );
        let b = affine_from_wire(&affine_to_wire(&a)).unwrap();
        assert!(a.abs_diff_eq(b, 1e-6));
        let p = Vec3::new(0.3, 0.2, -0.9);
        assert!((a.transform_point3(p) - b.transform_point3(p)).length() < 1e-5);
    }

    #[test]
    fn bad_affines_are_rejected() {
        assert!(affine_from_wire(&v1::Affine { rows: vec![1.0; 11] }).is_err());
        let mut rows = affine_to_wire(&Affine3A::IDENTITY).rows;
        rows[5] = f32::NAN;
        assert!(affine_from_wire(&v1::Affine { rows }).unwrap_err().contains("not finite"));
        assert!(affine_from_wire(&v1::Affine { rows: vec![0.0; 12] }).unwrap_err().contains("singular"));
        let mut rows = affine_to_wire(&Affine3A::IDENTITY).rows;
        rows[3] = 3e38;
        assert!(affine_from_wire(&v1::Affine { rows }).unwrap_err().contains("translation"));
        let mut rows = affine_to_wire(&Affine3A::IDENTITY).rows;
        rows[0] = 1e30;
        assert!(affine_from_wire(&v1::Affine { rows }).unwrap_err().contains("beyond"));
    }

    #[test]
    fn orbits_round_trip_and_bad_ones_are_named() {
        let o = edgepoint_scene::Orbit {
            pivot: Vec3::new(1.0, 2.0, 3.0),
            radius: 0.5,
            elevation_degrees: 30.0,
            start_azimuth_degrees: 270.0,
            fov_y_degrees: 60.0,
        };
        assert_eq!(orbit_from_wire(&orbit_to_wire(&o)).unwrap(), o);
        let mut w = orbit_to_wire(&o);
        w.radius = -1.0;
        assert!(orbit_from_wire(&w).unwrap_err().contains("radius"));
        w.pivot = None;
        assert!(orbit_from_wire(&w).unwrap_err().contains("pivot"));
    }

    #[test]
    fn a_partial_camera_keeps_the_base_fields_it_leaves_unset() {
        let base = edgepoint_scene::Camera { eye: Vec3::new(0.0, 1.0, 5.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 40.0 };
        assert_eq!(camera_over(&v1::Camera::default(), &base).unwrap(), base);
        let p = v1::Camera { eye: Some(Vec3::new(3.0, 1.0, 0.0).into()), fov_y_degrees: 70.0, ..Default::default() };
        let c = camera_over(&p, &base).unwrap();
        assert_eq!((c.eye, c.target, c.up, c.fov_y_degrees), (Vec3::new(3.0, 1.0, 0.0), Vec3::ZERO, Vec3::Y, 70.0));
        // A set field that is bad is named; so is a degenerate result.
        let nan = v1::Camera { target: Some(Vec3::new(f32::NAN, 0.0, 0.0).into()), ..Default::default() };
        assert!(camera_over(&nan, &base).unwrap_err().contains("target is not finite"));
        assert!(check_partial_camera(&v1::Camera { fov_y_degrees: 180.0, ..Default::default() }).unwrap_err().contains("field of view"));
        let onto_eye = v1::Camera { target: Some(base.eye.into()), ..Default::default() };
        assert!(camera_over(&onto_eye, &base).unwrap_err().contains("coincide"));
    }

    #[test]
    fn scene_hash_depends_on_content() {
        let a = v1::SceneSource { source: Some(v1::scene_source::Source::Builtin("cornell".into())) };
        let b = v1::SceneSource { source: Some(v1::scene_source::Source::Builtin("cornell-point".into())) };
        assert_eq!(scene_hash(&a), scene_hash(&a.clone()));
        assert_ne!(scene_hash(&a), scene_hash(&b));
        assert_eq!(scene_hash(&a).len(), 64);
    }
}
