//! Fresnel reflectance of smooth interfaces (unpolarised light): a dielectric with a real
//! relative index of refraction, a conductor with a complex one (pbrt-v4 §9.3, Mitsuba 3's
//! `fresnel` / `fresnel_conductor`), and the hemispherical average a diffuse layer under a
//! coat sees. Directions are in the local frame (normal = +z).
use glam::Vec3;

/// Fresnel reflectance of a dielectric interface for a direction making `cos_i` with the
/// normal; `eta` is the index inside (below the normal) over outside. A negative `cos_i`
/// means the light arrives from inside, so the relative index inverts. Total internal
/// reflection gives 1.
#[inline]
pub fn dielectric(cos_i: f32, eta: f32) -> f32 {
    let (cos_i, eta) = if cos_i < 0.0 {
        (-cos_i, 1.0 / eta)
    } else {
        (cos_i, eta)
    };
    let cos_i = cos_i.min(1.0);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).max(0.0).sqrt();
    let parallel = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    let perpendicular = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    0.5 * (parallel * parallel + perpendicular * perpendicular)
}

/// A complex number, just enough for the conductor's Fresnel equations.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Complex {
    re: f32,
    im: f32,
}

impl Complex {
    fn new(re: f32, im: f32) -> Self {
        Complex { re, im }
    }
    fn add(self, o: Complex) -> Complex {
        Complex::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: Complex) -> Complex {
        Complex::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: Complex) -> Complex {
        Complex::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
    fn norm(self) -> f32 {
        self.re * self.re + self.im * self.im
    }
    fn div(self, o: Complex) -> Complex {
        let d = o.norm();
        Complex::new(
            (self.re * o.re + self.im * o.im) / d,
            (self.im * o.re - self.re * o.im) / d,
        )
    }
    /// The principal square root (non-negative real part), stable for either sign of `re`.
    fn sqrt(self) -> Complex {
        let n = self.norm().sqrt();
        if n == 0.0 {
            return Complex::new(0.0, 0.0);
        }
        let t1 = (0.5 * (n + self.re.abs())).sqrt();
        let t2 = 0.5 * self.im / t1;
        if self.re >= 0.0 {
            Complex::new(t1, t2)
        } else {
            Complex::new(t2.abs(), t1.copysign(self.im))
        }
    }
}

/// Fresnel reflectance of a conductor with complex relative index `eta + i k` for one
/// wavelength; `cos_i` is clamped to [0, 1] (light never arrives from inside a metal).
fn conductor_channel(cos_i: f32, eta: f32, k: f32) -> f32 {
    let cos_i = cos_i.clamp(0.0, 1.0);
    let n = Complex::new(eta, k);
    let ci = Complex::new(cos_i, 0.0);
    let sin2_t = Complex::new(1.0 - cos_i * cos_i, 0.0).div(n.mul(n));
    let cos_t = Complex::new(1.0, 0.0).sub(sin2_t).sqrt();
    let parallel = n.mul(ci).sub(cos_t).div(n.mul(ci).add(cos_t));
    let perpendicular = ci.sub(n.mul(cos_t)).div(ci.add(n.mul(cos_t)));
    0.5 * (parallel.norm() + perpendicular.norm()).min(2.0)
}

/// Per-channel conductor Fresnel reflectance (see [`conductor_channel`]).
#[inline]
pub fn conductor(cos_i: f32, eta: Vec3, k: Vec3) -> Vec3 {
    Vec3::new(
        conductor_channel(cos_i, eta.x, k.x),
        conductor_channel(cos_i, eta.y, k.y),
        conductor_channel(cos_i, eta.z, k.z),
    )
}

/// Cosine-weighted hemispherical average of [`dielectric`] for light arriving from the side
/// where the relative index is `eta` (Mitsuba 3's `fresnel_diffuse_reflectance`: Egan and
/// Hilgeman's fit below 1, d'Eon and Irving's above; tested against quadrature).
pub fn diffuse_reflectance(eta: f32) -> f32 {
    if eta < 1.0 {
        -1.4399 * eta * eta + 0.7099 * eta + 0.6681 + 0.0636 / eta
    } else {
        let i = 1.0 / eta;
        let (i2, i3) = (i * i, i * i * i);
        0.919317 - 3.4793 * i + 6.75335 * i2 - 7.80989 * i3 + 4.98554 * i2 * i2 - 1.36881 * i2 * i3
    }
}

/// Mirror reflection of `w` about the unit vector `n`.
#[inline]
pub fn reflect(w: Vec3, n: Vec3) -> Vec3 {
    -w + n * (2.0 * w.dot(n))
}

/// Refraction of `w` (pointing away from the surface) through a surface with unit normal
/// `n` and relative index `eta` (below `n` over above). Returns the refracted direction and
/// the index ratio it crossed (`eta` entering, `1/eta` leaving), or `None` on total
/// internal reflection.
#[inline]
pub fn refract(w: Vec3, n: Vec3, eta: f32) -> Option<(Vec3, f32)> {
    let mut cos_i = n.dot(w);
    let (mut n, mut eta) = (n, eta);
    if cos_i < 0.0 {
        eta = 1.0 / eta;
        cos_i = -cos_i;
        n = -n;
    }
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta * eta);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    Some((-w / eta + n * (cos_i / eta - cos_t), eta))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_known_values() {
        // Normal incidence: ((n-1)/(n+1))^2 from either side.
        assert!((dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        assert!((dielectric(-1.0, 1.5) - 0.04).abs() < 1e-6);
        // Grazing: total reflection; inside beyond the critical angle: total reflection.
        assert!((dielectric(0.0, 1.5) - 1.0).abs() < 1e-6);
        let critical = (1.0f32 - 1.0 / (1.5 * 1.5)).sqrt();
        assert_eq!(dielectric(-(critical - 1e-3), 1.5), 1.0);
        assert!(dielectric(-(critical + 1e-2), 1.5) < 1.0);
        // Brewster's angle: the parallel part vanishes, leaving half the perpendicular one.
        let brewster = 1.5f32.atan();
        let ci = brewster.cos();
        let ct = (1.0 - (1.0 - ci * ci) / 2.25).sqrt();
        let rs = ((ci - 1.5 * ct) / (ci + 1.5 * ct)).powi(2);
        assert!((dielectric(ci, 1.5) - 0.5 * rs).abs() < 1e-6);
        // Index 1 is no interface at all.
        assert!(dielectric(0.3, 1.0).abs() < 1e-7);
    }

    #[test]
    fn conductor_reduces_to_dielectric_without_absorption_and_matches_normal_incidence() {
        for cos in [0.05f32, 0.3, 0.7, 1.0] {
            let c = conductor(cos, Vec3::splat(1.5), Vec3::ZERO).x;
            assert!((c - dielectric(cos, 1.5)).abs() < 1e-5, "{cos}: {c}");
        }
        // Normal incidence: ((n-1)^2 + k^2) / ((n+1)^2 + k^2); gold-ish values.
        let (n, k) = (
            Vec3::new(0.143, 0.374, 1.442),
            Vec3::new(3.983, 2.385, 1.603),
        );
        let f = conductor(1.0, n, k);
        let expect = ((n - 1.0) * (n - 1.0) + k * k) / ((n + 1.0) * (n + 1.0) + k * k);
        assert!((f - expect).abs().max_element() < 1e-5, "{f} vs {expect}");
        assert!((conductor(0.0, n, k) - Vec3::ONE).abs().max_element() < 1e-5);
        for i in 0..=100 {
            let f = conductor(i as f32 / 100.0, n, k);
            assert!(f.min_element() >= 0.0 && f.max_element() <= 1.0 && f.is_finite());
        }
    }

    #[test]
    fn diffuse_reflectance_fit_matches_quadrature() {
        for eta in [1.2f32, 1.33, 1.5, 1.8, 1.0 / 1.2, 1.0 / 1.5, 1.0 / 1.8] {
            // ∫ F(cos) 2 cos d(cos) over [0, 1] by the midpoint rule in cos^2.
            let n = 20000;
            let q: f32 = (0..n)
                .map(|i| dielectric(((i as f32 + 0.5) / n as f32).sqrt(), eta))
                .sum::<f32>()
                / n as f32;
            let fit = diffuse_reflectance(eta);
            assert!((fit - q).abs() < 0.01, "eta {eta}: fit {fit} vs {q}");
        }
    }

    #[test]
    fn refraction_obeys_snell_and_reverses() {
        let w = Vec3::new(0.6, 0.0, 0.8);
        let (t, etap) = refract(w, Vec3::Z, 1.5).unwrap();
        assert_eq!(etap, 1.5);
        assert!((t.length() - 1.0).abs() < 1e-6 && t.z < 0.0);
        assert!((0.6 - 1.5 * t.x.abs()).abs() < 1e-6, "sin_i = eta sin_t");
        let (back, e2) = refract(t, Vec3::Z, 1.5).unwrap();
        assert!((back - w).length() < 1e-5 && (e2 - 1.0 / 1.5).abs() < 1e-6);
        assert!(
            refract(Vec3::new(0.9, 0.0, -(1.0f32 - 0.81).sqrt()), Vec3::Z, 1.5).is_none(),
            "TIR"
        );
    }
}
