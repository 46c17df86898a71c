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
    fn scene_hash_depends_on_content() {
        let a = v1::SceneSource { source: Some(v1::scene_source::Source::Builtin("cornell".into())) };
        let b = v1::SceneSource { source: Some(v1::scene_source::Source::Builtin("cornell-point".into())) };
        assert_eq!(scene_hash(&a), scene_hash(&a.clone()));
        assert_ne!(scene_hash(&a), scene_hash(&b));
        assert_eq!(scene_hash(&a).len(), 64);
    }
}
