//! Magnitude limits on coordinates. f32 holds values up to 3.4e38, but rendering multiplies
//! coordinates together (cross products of triangle edges with ray origins, squared
//! distances, the staged light's intensity), so a coordinate of 1e30 overflows to infinity
//! or NaN long before any f32 check would notice. Inputs are held to limits whose products
//! stay finite, and the checks name the value and the limit instead of a NaN symptom.
use glam::Vec3;

/// Largest |coordinate| of a model's vertices (PLY, OBJ, built-in data files). Staging puts
/// the camera and the light a few model sizes away, which stays below
/// [`MAX_WORLD_COORDINATE`].
pub const MAX_COORDINATE: f32 = 1.0e12;

/// Largest |coordinate| of a world-space position: camera eye and target, light positions
/// and vertices, object translations.
pub const MAX_WORLD_COORDINATE: f32 = 1.0e13;

/// Largest |entry| of an object transform's linear part (a scale of a million).
pub const MAX_TRANSFORM_SCALE: f32 = 1.0e6;

/// Checks that `v` is finite and within `±limit` on every axis; the error names `what`.
/// Written so that NaN fails: every comparison must hold, none may merely not fail.
pub fn check_vec(what: &str, v: Vec3, limit: f32) -> Result<(), String> {
    if !v.is_finite() {
        return Err(format!("{what} is not finite ({v})"));
    }
    let m = v.abs().max_element();
    if !(m <= limit) {
        return Err(format!("{what} ({v}) has a coordinate beyond ±{limit:e}, the largest edgepoint accepts"));
    }
    Ok(())
}

/// [`check_vec`] for a scalar in f64 (a parsed file value before it becomes f32).
pub fn check_coordinate(value: f64, limit: f32) -> Result<(), String> {
    if !value.is_finite() {
        return Err(format!("coordinate {value} is not finite"));
    }
    // Compared as the f32 it becomes (1e12 in f64 rounds to the same f32 as the limit).
    if !((value as f32).abs() <= limit) {
        return Err(format!(
            "coordinate {value:e} is beyond ±{limit:e}, the largest edgepoint accepts (scale the model down)"
        ));
    }
    Ok(())
}

/// Checks an object-to-world transform: finite, translation within
/// [`MAX_WORLD_COORDINATE`], linear part within [`MAX_TRANSFORM_SCALE`].
pub fn check_affine(a: &glam::Affine3A) -> Result<(), String> {
    let m = a.matrix3;
    for (i, col) in [m.x_axis, m.y_axis, m.z_axis].into_iter().enumerate() {
        let col = Vec3::from(col);
        if !col.is_finite() {
            return Err(format!("transform column {i} is not finite ({col})"));
        }
        if !(col.abs().max_element() <= MAX_TRANSFORM_SCALE) {
            return Err(format!("transform column {i} ({col}) has an entry beyond ±{MAX_TRANSFORM_SCALE:e}"));
        }
    }
    check_vec("transform translation", Vec3::from(a.translation), MAX_WORLD_COORDINATE)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_and_huge_values_fail_with_their_value() {
        assert!(check_vec("eye", Vec3::new(1.0, 2.0, 3.0), MAX_WORLD_COORDINATE).is_ok());
        let e = check_vec("camera eye", Vec3::new(1e30, 0.0, 0.0), MAX_WORLD_COORDINATE).unwrap_err();
        assert!(e.contains("camera eye") && e.contains("1e13"), "{e}");
        assert!(check_vec("x", Vec3::NAN, 1.0).unwrap_err().contains("not finite"));
        assert!(check_coordinate(3e38, MAX_COORDINATE).unwrap_err().contains("3e38"));
        assert!(check_coordinate(f64::NAN, MAX_COORDINATE).is_err());
        assert!(check_coordinate(-1e12, MAX_COORDINATE).is_ok());
        // The products rendering forms from the largest allowed values stay finite.
        let w = MAX_WORLD_COORDINATE * 2.0;
        let m = MAX_COORDINATE * 2.0;
        assert!((w * m * m).is_finite() && (w * w).is_finite());
    }
}
