//! Reproducible random numbers and viewpoints for the edge finder's tests and benchmarks
//! (paper 000 §6.4 measures silhouettes "from random viewpoints"; the tests compare the
//! trees with brute force from the same ones). Splitmix64: tiny, fast, well mixed.
use glam::Vec3;

/// A deterministic random number generator.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut x = self.0;
        x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        x ^ (x >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [0, n).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    /// A uniformly distributed unit vector.
    pub fn direction(&mut self) -> Vec3 {
        let z = self.unit() * 2.0 - 1.0;
        let t = self.unit() * std::f32::consts::TAU;
        let s = (1.0 - z * z).sqrt();
        Vec3::new(s * t.cos(), z, s * t.sin())
    }
}

/// `n` eyes around the box `bounds`: uniform directions from its centre, at distances
/// uniform between `near` and `far` times its bounding radius.
pub fn viewpoints(bounds: (Vec3, Vec3), n: usize, seed: u64, near: f32, far: f32) -> Vec<Vec3> {
    let (lo, hi) = bounds;
    let (c, r) = ((lo + hi) * 0.5, (hi - lo).length() * 0.5);
    let mut g = Rng::new(seed);
    (0..n).map(|_| c + g.direction() * r * (near + (far - near) * g.unit())).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viewpoints_are_reproducible_and_in_range() {
        let b = (Vec3::ZERO, Vec3::splat(2.0));
        let v = viewpoints(b, 500, 3, 1.5, 4.0);
        assert_eq!(v, viewpoints(b, 500, 3, 1.5, 4.0));
        let r = 3f32.sqrt();
        for p in &v {
            let d = (*p - Vec3::ONE).length() / r;
            assert!((1.5 - 1e-4..=4.0 + 1e-4).contains(&d));
        }
        let mean = v.iter().copied().sum::<Vec3>() / v.len() as f32 - Vec3::ONE;
        assert!(mean.length() < 0.5, "directions spread evenly");
    }
}
