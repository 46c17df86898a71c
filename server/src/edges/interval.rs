//! Interval arithmetic on scalars and 3-vectors (paper 000 §6.4, footnotes 1–2: "operators
//! on interval vectors are defined using the usual interval arithmetic operations [Moore
//! 1979]; the dot product of two interval vectors is a component-wise interval
//! multiplication and an interval addition of the resulting intervals").
//!
//! The edge trees prune a subtree when the interval of `N · V` excludes zero, and then never
//! look at the edges below it, so an interval must contain every value the exact per-edge
//! test could produce. Two facts make that hold:
//!
//! - Every operation rounds its lower end down and its upper end up by one ulp after
//!   computing it in f32, so the interval contains the exact real result of the operation on
//!   any inputs inside the input intervals (round-to-nearest is off by at most half an ulp).
//! - Round-to-nearest is monotone, so the f32 evaluation of the *same expression in the same
//!   order* on point inputs inside the intervals lies between the f32 evaluations on the
//!   ends. [`IVec3::dot`] therefore sums `x`, then `y`, then `z`, exactly as
//!   `glam::Vec3::dot` does in the leaf test [`super::brute::face_side`], and the interval
//!   also contains the leaf test's own rounded value — the pruning never drops an edge the
//!   leaf test would report.
//!
//! Inputs must be finite (mesh positions, normals and the eye are).
use glam::Vec3;

/// A closed interval `[lo, hi]` of reals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    pub lo: f32,
    pub hi: f32,
}

#[inline(always)]
fn down(x: f32) -> f32 {
    x.next_down()
}

#[inline(always)]
fn up(x: f32) -> f32 {
    x.next_up()
}

impl Interval {
    #[inline(always)]
    pub const fn new(lo: f32, hi: f32) -> Interval {
        Interval { lo, hi }
    }

    /// The degenerate interval `[x, x]`.
    #[inline(always)]
    pub const fn point(x: f32) -> Interval {
        Interval { lo: x, hi: x }
    }

    #[inline(always)]
    pub fn contains(self, x: f32) -> bool {
        self.lo <= x && x <= self.hi
    }

    #[inline(always)]
    pub fn width(self) -> f32 {
        self.hi - self.lo
    }

    /// Every value is `> 0`.
    #[inline(always)]
    pub fn all_positive(self) -> bool {
        self.lo > 0.0
    }

    /// Every value is `<= 0`.
    #[inline(always)]
    pub fn all_non_positive(self) -> bool {
        self.hi <= 0.0
    }

    /// The sign test `x > 0` has the same answer for every `x` in the interval.
    #[inline(always)]
    pub fn sign_is_fixed(self) -> bool {
        self.lo > 0.0 || self.hi <= 0.0
    }

    #[inline(always)]
    pub fn hull(self, o: Interval) -> Interval {
        Interval { lo: self.lo.min(o.lo), hi: self.hi.max(o.hi) }
    }

}

impl std::ops::Add for Interval {
    type Output = Interval;
    #[inline(always)]
    fn add(self, o: Interval) -> Interval {
        Interval { lo: down(self.lo + o.lo), hi: up(self.hi + o.hi) }
    }
}

impl std::ops::Sub for Interval {
    type Output = Interval;
    #[inline(always)]
    fn sub(self, o: Interval) -> Interval {
        Interval { lo: down(self.lo - o.hi), hi: up(self.hi - o.lo) }
    }
}

impl std::ops::Mul for Interval {
    type Output = Interval;
    #[inline(always)]
    fn mul(self, o: Interval) -> Interval {
        let (a, b, c, d) = (self.lo * o.lo, self.lo * o.hi, self.hi * o.lo, self.hi * o.hi);
        Interval { lo: down(a.min(b).min(c.min(d))), hi: up(a.max(b).max(c.max(d))) }
    }
}

/// A vector of three intervals: a box of points or of normals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IVec3 {
    pub x: Interval,
    pub y: Interval,
    pub z: Interval,
}

impl IVec3 {
    /// The box `[lo, hi]` (per axis).
    #[inline(always)]
    pub fn from_bounds(lo: Vec3, hi: Vec3) -> IVec3 {
        IVec3 { x: Interval::new(lo.x, hi.x), y: Interval::new(lo.y, hi.y), z: Interval::new(lo.z, hi.z) }
    }

    #[inline(always)]
    pub fn from_arrays(lo: &[f32; 3], hi: &[f32; 3]) -> IVec3 {
        IVec3 { x: Interval::new(lo[0], hi[0]), y: Interval::new(lo[1], hi[1]), z: Interval::new(lo[2], hi[2]) }
    }

    /// The degenerate box holding the one point `p`.
    #[inline(always)]
    pub fn point(p: Vec3) -> IVec3 {
        IVec3::from_bounds(p, p)
    }

    /// The smallest box holding all `points` (empty input gives an empty box, lo > hi).
    pub fn bounding(points: &[Vec3]) -> IVec3 {
        let lo = points.iter().fold(Vec3::splat(f32::INFINITY), |a, p| a.min(*p));
        let hi = points.iter().fold(Vec3::splat(f32::NEG_INFINITY), |a, p| a.max(*p));
        IVec3::from_bounds(lo, hi)
    }

    #[inline(always)]
    pub fn lo(&self) -> Vec3 {
        Vec3::new(self.x.lo, self.y.lo, self.z.lo)
    }

    #[inline(always)]
    pub fn hi(&self) -> Vec3 {
        Vec3::new(self.x.hi, self.y.hi, self.z.hi)
    }

    #[inline(always)]
    pub fn sub(&self, o: &IVec3) -> IVec3 {
        IVec3 { x: self.x - o.x, y: self.y - o.y, z: self.z - o.z }
    }

    /// `self · o`, summed x, y, z in that order (as `glam::Vec3::dot`).
    #[inline(always)]
    pub fn dot(&self, o: &IVec3) -> Interval {
        (self.x * o.x + self.y * o.y) + self.z * o.z
    }

    /// `self · (e - p)` for every normal in `self`, eye in `e` and position in `p`: Equation 1
    /// at a tree node (footnote 2: "the interval vector for V is computed using the position
    /// interval vector of the node").
    #[inline(always)]
    pub fn dot_view(&self, e: &IVec3, p: &IVec3) -> Interval {
        self.dot(&e.sub(p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random values, intervals and points inside them (reproducible).
    struct Rng(crate::rng::Rng);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0.next_u64()
        }
        fn unit(&mut self) -> f32 {
            self.0.unit()
        }
        /// Values of very different magnitudes and both signs, sometimes exactly equal ends.
        fn value(&mut self) -> f32 {
            let m = self.unit() * 2.0 - 1.0;
            let e = (self.next() % 13) as i32 - 6;
            m * 10f32.powi(e)
        }
        fn interval(&mut self) -> Interval {
            let (a, b) = (self.value(), self.value());
            if self.next().is_multiple_of(5) {
                Interval::point(a)
            } else {
                Interval::new(a.min(b), a.max(b))
            }
        }
        fn inside(&mut self, i: Interval) -> f32 {
            match self.next() % 4 {
                0 => i.lo,
                1 => i.hi,
                _ => {
                    let t = self.unit();
                    (i.lo as f64 + (i.hi as f64 - i.lo as f64) * t as f64).clamp(i.lo as f64, i.hi as f64) as f32
                }
            }
        }
    }

    fn contains_exact(i: Interval, x: f64) -> bool {
        i.lo as f64 <= x && x <= i.hi as f64
    }

    #[test]
    fn scalar_operations_contain_the_exact_result() {
        let mut r = Rng(crate::rng::Rng::new(0x9E3779B97F4A7C15));
        for _ in 0..200_000 {
            let (a, b) = (r.interval(), r.interval());
            let (x, y) = (r.inside(a), r.inside(b));
            let (xd, yd) = (x as f64, y as f64);
            // f64 holds the exact sum/difference/product of two f32 values only up to
            // rounding; the product of two f32 is exact in f64, sums are exact unless the
            // exponents are more than 29 apart, where the f32 widening is far larger.
            assert!(contains_exact(a + b, xd + yd), "{a:?}+{b:?} ∌ {x}+{y}");
            assert!(contains_exact(a - b, xd - yd), "{a:?}-{b:?} ∌ {x}-{y}");
            assert!(contains_exact(a * b, xd * yd), "{a:?}*{b:?} ∌ {x}*{y}");
            // ... and the f32 evaluation of the same operation.
            assert!((a + b).contains(x + y) && (a - b).contains(x - y) && (a * b).contains(x * y));
        }
    }

    /// The node test against the leaf test: for random normal and position boxes and eyes,
    /// the interval of `N · (e - P)` contains the exact (f64) value and the f32 value the
    /// leaf test [`crate::edges::brute::face_side`] computes, for points inside the boxes.
    #[test]
    fn dot_view_contains_exact_and_leaf_values() {
        let mut r = Rng(crate::rng::Rng::new(0x2545F4914F6CDD1D));
        let mut sign_fixed = 0;
        for _ in 0..100_000 {
            let n = IVec3 { x: r.interval(), y: r.interval(), z: r.interval() };
            let p = IVec3 { x: r.interval(), y: r.interval(), z: r.interval() };
            let e = Vec3::new(r.value(), r.value(), r.value());
            let iv = n.dot_view(&IVec3::point(e), &p);
            if iv.sign_is_fixed() {
                sign_fixed += 1;
            }
            for _ in 0..8 {
                let nn = Vec3::new(r.inside(n.x), r.inside(n.y), r.inside(n.z));
                let pp = Vec3::new(r.inside(p.x), r.inside(p.y), r.inside(p.z));
                let exact = nn.x as f64 * (e.x as f64 - pp.x as f64)
                    + nn.y as f64 * (e.y as f64 - pp.y as f64)
                    + nn.z as f64 * (e.z as f64 - pp.z as f64);
                let leaf = nn.dot(e - pp);
                assert!(contains_exact(iv, exact), "{iv:?} ∌ exact {exact}");
                assert!(iv.contains(leaf), "{iv:?} ∌ leaf {leaf}");
                // Pruning decisions: a fixed sign on the node means the same sign at the leaf.
                if iv.all_positive() {
                    assert!(crate::edges::brute::face_side(nn, pp, e));
                }
                if iv.all_non_positive() {
                    assert!(!crate::edges::brute::face_side(nn, pp, e));
                }
            }
        }
        // The test exercised both outcomes.
        assert!(sign_fixed > 10_000 && sign_fixed < 90_000, "{sign_fixed}");
    }

    #[test]
    fn eye_boxes_contain_every_eye() {
        // An interval eye (a light's bounding box) against point eyes inside it.
        let mut r = Rng(crate::rng::Rng::new(77));
        for _ in 0..50_000 {
            let n = IVec3 { x: r.interval(), y: r.interval(), z: r.interval() };
            let p = IVec3 { x: r.interval(), y: r.interval(), z: r.interval() };
            let eb = IVec3 { x: r.interval(), y: r.interval(), z: r.interval() };
            let iv = n.dot_view(&eb, &p);
            let e = Vec3::new(r.inside(eb.x), r.inside(eb.y), r.inside(eb.z));
            let nn = Vec3::new(r.inside(n.x), r.inside(n.y), r.inside(n.z));
            let pp = Vec3::new(r.inside(p.x), r.inside(p.y), r.inside(p.z));
            assert!(iv.contains(nn.dot(e - pp)));
        }
    }
}
