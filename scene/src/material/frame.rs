//! The local shading frame every scattering model works in: z is the surface normal, x and
//! y span the tangent plane, so `cos θ = w.z`.
use glam::Vec3;

/// An orthonormal basis around a unit normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    pub s: Vec3,
    pub t: Vec3,
    pub n: Vec3,
}

impl Frame {
    /// A basis around unit `n` without trigonometry or a branch on a near-zero component
    /// (Duff et al. 2017, "Building an Orthonormal Basis, Revisited"): continuous except at
    /// `n.z = -0`, so grazing normals get a well-conditioned tangent.
    #[inline]
    pub fn from_normal(n: Vec3) -> Frame {
        let sign = 1f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Frame { s, t, n }
    }

    #[inline]
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    #[inline]
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        self.s * v.x + self.t * v.y + self.n * v.z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_orthonormal_and_round_trip() {
        let mut seed = 1u32;
        let mut r = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
        };
        let mut normals: Vec<Vec3> = (0..1000)
            .map(|_| Vec3::new(r(), r(), r()).normalize())
            .collect();
        normals.extend([
            Vec3::Z,
            -Vec3::Z,
            Vec3::X,
            Vec3::new(0.0, 0.0, -0.0) + Vec3::new(1e-7, 0.0, -1.0).normalize(),
        ]);
        for n in normals {
            let f = Frame::from_normal(n);
            for (a, b) in [(f.s, f.t), (f.t, f.n), (f.s, f.n)] {
                assert!(a.dot(b).abs() < 1e-5, "{n}");
            }
            for v in [f.s, f.t, f.n] {
                assert!((v.length() - 1.0).abs() < 1e-5, "{n}");
            }
            let w = Vec3::new(0.3, -0.5, 0.8);
            assert!((f.to_world(f.to_local(w)) - w).length() < 1e-5);
            assert!((f.to_local(n) - Vec3::Z).length() < 1e-5);
        }
    }
}
