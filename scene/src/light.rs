//! Lights: point lights, spot lights (a point light with a cone) and planar convex
//! polygonal area lights (paper 000 §6.3). Shadows of a spot light are those of a point
//! light at its position; only its shading has the cone.
use crate::limits::{check_vec, MAX_WORLD_COORDINATE};
use glam::Vec3;

#[derive(Debug, Clone, PartialEq)]
pub enum Light {
    /// An isotropic point light; `intensity` is radiant intensity (irradiance at 1 unit
    /// distance facing the light), linear RGB.
    Point { position: Vec3, intensity: Vec3 },
    /// A one-sided planar convex polygon emitting `radiance` uniformly from the side its
    /// normal (counter-clockwise winding) faces.
    Area { vertices: Vec<Vec3>, radiance: Vec3 },
    /// A point light shining into a cone around `direction` (unit): full `intensity`
    /// within `cos_inner` of the axis, falling smoothly to nothing at `cos_outer`
    /// ([`spot_falloff`]; glTF `KHR_lights_punctual` spot, Mitsuba `spot`).
    Spot { position: Vec3, direction: Vec3, intensity: Vec3, cos_inner: f32, cos_outer: f32 },
}

/// The fraction of a spot light's intensity sent along unit direction `to_point` (from the
/// light): 1 inside the inner cone, 0 outside the outer one, and between them the smooth
/// square of the linear ramp in cos θ that glTF's `KHR_lights_punctual` recommends.
pub fn spot_falloff(direction: Vec3, cos_inner: f32, cos_outer: f32, to_point: Vec3) -> f32 {
    let c = direction.dot(to_point);
    let t = ((c - cos_outer) / (cos_inner - cos_outer).max(1e-4)).clamp(0.0, 1.0);
    t * t
}

impl Light {
    /// Unit normal of an area light (counter-clockwise winding); `None` for point lights.
    pub fn normal(&self) -> Option<Vec3> {
        match self {
            Light::Point { .. } | Light::Spot { .. } => None,
            Light::Area { vertices, .. } => Some(polygon_normal(vertices).normalize_or_zero()),
        }
    }

    /// Area of an area light (0 for point lights).
    pub fn area(&self) -> f32 {
        match self {
            Light::Point { .. } | Light::Spot { .. } => 0.0,
            Light::Area { vertices, .. } => polygon_normal(vertices).length(),
        }
    }

    /// Centroid (the position for point lights).
    pub fn center(&self) -> Vec3 {
        match self {
            Light::Point { position, .. } | Light::Spot { position, .. } => *position,
            Light::Area { vertices, .. } => {
                vertices.iter().copied().sum::<Vec3>() / vertices.len().max(1) as f32
            }
        }
    }

    /// Checks the light is usable: finite values, an area light with at least three
    /// vertices forming a non-degenerate planar convex polygon.
    pub fn validate(&self) -> Result<(), String> {
        match self {
            Light::Point { position, intensity } => {
                check_vec("point light position", *position, MAX_WORLD_COORDINATE)?;
                if !intensity.is_finite() {
                    return Err(format!("point light intensity is not finite ({intensity})"));
                }
            }
            Light::Spot { position, direction, intensity, cos_inner, cos_outer } => {
                check_vec("spot light position", *position, MAX_WORLD_COORDINATE)?;
                if !intensity.is_finite() {
                    return Err(format!("spot light intensity is not finite ({intensity})"));
                }
                if !((direction.length() - 1.0).abs() <= 1e-3) {
                    return Err(format!("spot light direction is not a unit vector ({direction})"));
                }
                if !(*cos_outer >= -1.0 && cos_inner <= &1.0 && cos_outer <= cos_inner) {
                    return Err(format!("spot light cone cosines must satisfy -1 <= outer ({cos_outer}) <= inner ({cos_inner}) <= 1"));
                }
            }
            Light::Area { vertices, radiance } => {
                if vertices.len() < 3 {
                    return Err(format!("area light needs >= 3 vertices, has {}", vertices.len()));
                }
                if !radiance.is_finite() {
                    return Err(format!("area light radiance is not finite ({radiance})"));
                }
                for (i, v) in vertices.iter().enumerate() {
                    check_vec(&format!("area light vertex {i}"), *v, MAX_WORLD_COORDINATE)?;
                }
                let n = polygon_normal(vertices);
                if !(n.length() >= 1e-12) {
                    return Err("area light polygon has zero area".into());
                }
                let n = n.normalize();
                let c = self.center();
                let size = vertices.iter().map(|v| (*v - c).length()).fold(0.0, f32::max);
                for v in vertices {
                    if (*v - c).dot(n).abs() > 1e-4 * size.max(1e-6) {
                        return Err("area light polygon is not planar".into());
                    }
                }
                let k = vertices.len();
                for i in 0..k {
                    let (a, b, d) = (vertices[i], vertices[(i + 1) % k], vertices[(i + 2) % k]);
                    if (b - a).cross(d - b).dot(n) < -1e-9 * size * size {
                        return Err("area light polygon is not convex".into());
                    }
                }
            }
        }
        Ok(())
    }
}

/// Newell's method: the polygon's normal scaled by its area (counter-clockwise winding).
pub fn polygon_normal(v: &[Vec3]) -> Vec3 {
    let mut n = Vec3::ZERO;
    for i in 0..v.len() {
        let a = v[i];
        let b = v[(i + 1) % v.len()];
        n += a.cross(b);
    }
    n * 0.5
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_light_geometry() {
        let l = Light::Area {
            vertices: vec![
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(0.0, 1.0, 2.0),
                Vec3::new(2.0, 1.0, 2.0),
                Vec3::new(2.0, 1.0, 0.0),
            ],
            radiance: Vec3::ONE,
        };
        assert!((l.area() - 4.0).abs() < 1e-6);
        assert!((l.normal().unwrap() - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-6);
        assert_eq!(l.center(), Vec3::new(1.0, 1.0, 1.0));
        l.validate().unwrap();
    }

    #[test]
    fn spot_cone_falls_off_between_its_angles() {
        let (inner, outer) = (10f32.to_radians().cos(), 30f32.to_radians().cos());
        let at = |deg: f32| spot_falloff(Vec3::Y, inner, outer, Vec3::new(deg.to_radians().sin(), deg.to_radians().cos(), 0.0));
        assert_eq!(at(0.0), 1.0);
        assert_eq!(at(9.0), 1.0);
        assert_eq!(at(31.0), 0.0);
        assert_eq!(at(180.0), 0.0);
        let mid = at(20.0);
        let lin = (20f32.to_radians().cos() - outer) / (inner - outer);
        assert!((mid - lin * lin).abs() < 1e-6 && mid > 0.0 && mid < 1.0);
        let s = Light::Spot { position: Vec3::ZERO, direction: Vec3::Y, intensity: Vec3::ONE, cos_inner: inner, cos_outer: outer };
        s.validate().unwrap();
        assert_eq!(s.center(), Vec3::ZERO);
        let bad = Light::Spot { position: Vec3::ZERO, direction: Vec3::Y, intensity: Vec3::ONE, cos_inner: outer, cos_outer: inner };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn invalid_lights_are_rejected() {
        let flat = Light::Area { vertices: vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0], radiance: Vec3::ONE };
        assert!(flat.validate().is_err());
        let nan = Light::Point { position: Vec3::NAN, intensity: Vec3::ONE };
        assert!(nan.validate().is_err());
        let far = Light::Point { position: Vec3::new(0.0, 3e20, 0.0), intensity: Vec3::ONE };
        let e = far.validate().unwrap_err();
        assert!(e.contains("point light position") && e.contains("beyond"), "{e}");
    }
}
