//! A small counter-based random number generator: the numbers of a request depend only on
//! (batch seed, request id), so shading is reproducible whatever the thread schedule.

#[inline]
fn mix64(mut x: u64) -> u64 {
    // splitmix64 finaliser
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64, id: u64) -> Rng {
        Rng(mix64(seed ^ mix64(id.wrapping_add(0x9e37_79b9_7f4a_7c15))))
    }
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        mix64(self.0)
    }
    /// Skips the next `n` numbers in O(1) (the generator is a counter): a split-shading part
    /// passes over the light samples of the lights another part shades, so the numbers it
    /// does use are the ones the unsplit shading would have used.
    #[inline]
    pub fn skip(&mut self, n: u64) {
        self.0 = self.0.wrapping_add(n.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    }
    /// Uniform in [0, 1).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_and_reproducible() {
        let mut a = Rng::new(1, 2);
        let mut b = Rng::new(1, 2);
        let mut c = Rng::new(1, 3);
        let xs: Vec<f32> = (0..10000).map(|_| a.next_f32()).collect();
        assert!(xs.iter().all(|x| (0.0..1.0).contains(x)));
        let mean = xs.iter().sum::<f32>() / xs.len() as f32;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
        assert_eq!(xs[0], b.next_f32());
        assert_ne!(xs[0], c.next_f32());
    }

    #[test]
    fn skip_equals_drawing() {
        let (mut a, mut b) = (Rng::new(5, 9), Rng::new(5, 9));
        for n in [0u64, 1, 7, 33] {
            for _ in 0..n {
                a.next_u64();
            }
            b.skip(n);
            assert_eq!(a.next_u64(), b.next_u64());
        }
    }
}
