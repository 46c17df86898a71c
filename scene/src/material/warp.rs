//! Maps from the unit square to directions and disks, with their densities.
use glam::{Vec2, Vec3};
use std::f32::consts::{FRAC_1_PI, FRAC_PI_2, FRAC_PI_4};

/// Concentric (Shirley–Chiu) map of the square onto the unit disk: strata stay compact and
/// the map has no fold, so stratified numbers stay stratified.
#[inline]
pub fn square_to_disk(u: Vec2) -> Vec2 {
    let o = u * 2.0 - Vec2::ONE;
    if o.x == 0.0 && o.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if o.x.abs() > o.y.abs() {
        (o.x, FRAC_PI_4 * (o.y / o.x))
    } else {
        (o.y, FRAC_PI_2 - FRAC_PI_4 * (o.x / o.y))
    };
    Vec2::new(r * theta.cos(), r * theta.sin())
}

/// Polar map of the square onto the unit disk (radius from `u.x`, angle from `u.y`): the
/// visible-normal sampler warps its second coordinate, which needs this parametrisation.
#[inline]
pub fn square_to_disk_polar(u: Vec2) -> Vec2 {
    let r = u.x.sqrt();
    let (s, c) = (std::f32::consts::TAU * u.y).sin_cos();
    Vec2::new(r * c, r * s)
}

/// Cosine-weighted direction on the upper hemisphere (Malley's method).
#[inline]
pub fn square_to_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = square_to_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// Density of [`square_to_cosine_hemisphere`] per unit solid angle.
#[inline]
pub fn cosine_hemisphere_pdf(w: Vec3) -> f32 {
    if w.z > 0.0 {
        w.z * FRAC_1_PI
    } else {
        0.0
    }
}
