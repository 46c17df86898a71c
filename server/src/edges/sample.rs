//! Reproducible random viewpoints for the edge finder's tests and benchmarks (paper 000
//! §6.4 measures silhouettes "from random viewpoints"; the tests compare the trees with
//! brute force from the same ones).
use crate::rng::Rng;
use glam::Vec3;

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
