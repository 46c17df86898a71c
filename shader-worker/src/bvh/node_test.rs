//! The 8-child slab test of a [`Node8`] (Kay and Kajiya's slabs, Williams et al.'s sign
//! trick: per axis the near plane is picked once per ray, so no per-child min/max of the
//! two slab distances), in the instruction sets the worker chooses from at run time: AVX2
//! with FMA — all 8 children in one pass, each slab distance one fused multiply-subtract —
//! and SSE, the x86-64 baseline, in two halves of 4 (plus a scalar form elsewhere).
//! The traversal is generic over [`NodeTest`]; [`Simd`] says which one a query runs.
use super::wide::{Node8, PreparedRay, EXIT_SLACK};

/// The instruction set a traversal runs with, detected once per process ([`Simd::detect`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Simd {
    /// SSE on x86-64 (always present), scalar code elsewhere.
    Baseline,
    /// AVX2 and FMA (x86-64 only, when the CPU has both).
    Avx2,
}

impl Simd {
    /// The widest instruction set this CPU runs: AVX2 if it has AVX2 and FMA.
    pub fn detect() -> Simd {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Simd::Avx2;
            }
        }
        Simd::Baseline
    }

    /// Whether this CPU can run `self`.
    pub fn supported(self) -> bool {
        match self {
            Simd::Baseline => true,
            Simd::Avx2 => Simd::detect() == Simd::Avx2,
        }
    }
}

/// One 8-child slab test.
pub trait NodeTest {
    /// Entry distances of the 8 children and the mask of those the ray's `[tmin, tmax]`
    /// meets (`tmax` widened by [`EXIT_SLACK`]; the slab distances conservative by the
    /// ray's own slack, [`PreparedRay::new`]).
    ///
    /// # Safety
    /// The CPU must support the instructions the implementation uses, and the caller must
    /// be compiled with them enabled (inside a `#[target_feature]` function) for the
    /// intrinsics to inline.
    unsafe fn intersect(node: &Node8, r: &PreparedRay, tmax: f32) -> ([f32; 8], u32);
}

/// The baseline test: SSE on x86-64 (two halves of 4 children), scalar elsewhere.
pub struct Baseline;

/// AVX2 + FMA: the 8 children in one 8-lane pass.
#[cfg(target_arch = "x86_64")]
pub struct Avx2;

#[cfg(target_arch = "x86_64")]
impl NodeTest for Baseline {
    #[inline(always)]
    unsafe fn intersect(node: &Node8, r: &PreparedRay, tmax: f32) -> ([f32; 8], u32) {
        use std::arch::x86_64::*;
        let p = &node.planes;
        let (nx, ny, nz) = (r.near[0], r.near[1], r.near[2]);
        let mut tnear = [0f32; 8];
        let mut mask = 0u32;
        // SAFETY: SSE2 is part of the x86-64 baseline; every load reads 4 floats inside an
        // 8-float plane at offset 0 or 4 (unaligned loads, so alignment does not matter).
        unsafe {
            let (ix, iy, iz) = (_mm_set1_ps(r.inv[0]), _mm_set1_ps(r.inv[1]), _mm_set1_ps(r.inv[2]));
            let (ox, oy, oz) = (_mm_set1_ps(r.near_org_inv[0]), _mm_set1_ps(r.near_org_inv[1]), _mm_set1_ps(r.near_org_inv[2]));
            let (fx, fy, fz) = (_mm_set1_ps(r.far_org_inv[0]), _mm_set1_ps(r.far_org_inv[1]), _mm_set1_ps(r.far_org_inv[2]));
            let (t_min, t_max) = (_mm_set1_ps(r.tmin), _mm_set1_ps(tmax * EXIT_SLACK));
            for h in 0..2 {
                let ld = |k: usize| _mm_loadu_ps(p[k].as_ptr().add(4 * h));
                let slab = |k: usize, inv, oi| _mm_sub_ps(_mm_mul_ps(ld(k), inv), oi);
                let t0 = _mm_max_ps(_mm_max_ps(slab(nx, ix, ox), slab(2 + ny, iy, oy)), _mm_max_ps(slab(4 + nz, iz, oz), t_min));
                let t1 = _mm_min_ps(_mm_min_ps(slab(1 - nx, ix, fx), slab(3 - ny, iy, fy)), _mm_min_ps(slab(5 - nz, iz, fz), t_max));
                let hit = _mm_cmple_ps(t0, t1);
                _mm_storeu_ps(tnear.as_mut_ptr().add(4 * h), t0);
                mask |= (_mm_movemask_ps(hit) as u32) << (4 * h);
            }
        }
        (tnear, mask)
    }
}

#[cfg(target_arch = "x86_64")]
impl NodeTest for Avx2 {
    #[inline(always)]
    unsafe fn intersect(node: &Node8, r: &PreparedRay, tmax: f32) -> ([f32; 8], u32) {
        use std::arch::x86_64::*;
        let p = &node.planes;
        let (nx, ny, nz) = (r.near[0], r.near[1], r.near[2]);
        let mut tnear = [0f32; 8];
        // SAFETY: the caller guarantees AVX2 and FMA; each plane is 32 bytes at a 32-byte
        // multiple inside a 64-byte aligned node, so the aligned loads are aligned.
        unsafe {
            let (ix, iy, iz) = (_mm256_set1_ps(r.inv[0]), _mm256_set1_ps(r.inv[1]), _mm256_set1_ps(r.inv[2]));
            let (ox, oy, oz) = (_mm256_set1_ps(r.near_org_inv[0]), _mm256_set1_ps(r.near_org_inv[1]), _mm256_set1_ps(r.near_org_inv[2]));
            let (fx, fy, fz) = (_mm256_set1_ps(r.far_org_inv[0]), _mm256_set1_ps(r.far_org_inv[1]), _mm256_set1_ps(r.far_org_inv[2]));
            let ld = |k: usize| _mm256_load_ps(p[k].as_ptr());
            // plane · inv − origin · inv with one rounding (the SSE form's two are covered
            // by the same slack: `PreparedRay::new`).
            //
            // The maxima, minima and the comparison are taken on the floats' bits as signed
            // integers (as Embree's traversal does): one cycle each instead of four, on the
            // chain from a node's load to the next node's address. Signed integer order is
            // float order on non-negative floats and puts every negative float below them
            // (no NaN reaches here: the reciprocals are finite, empty children's planes are
            // ±∞). The entry distance's maximum includes `tmin >= +0.0`, so it is the
            // float maximum exactly; an exit distance's minimum may pick the wrong one of
            // two negative floats, but then it is negative either way and below every entry
            // distance, as the float minimum would be: the same children are hit, with the
            // same entry distances. (A -0.0 exit distance, which only `tmax = -0.0` could
            // give since the slack keeps a box's far planes positive at its entry, would
            // count as a miss.)
            let slab = |k: usize, inv, oi| _mm256_castps_si256(_mm256_fmsub_ps(ld(k), inv, oi));
            let t0 = _mm256_max_epi32(_mm256_max_epi32(slab(nx, ix, ox), slab(2 + ny, iy, oy)), _mm256_max_epi32(slab(4 + nz, iz, oz), _mm256_castps_si256(_mm256_set1_ps(r.tmin))));
            let t1 = _mm256_min_epi32(_mm256_min_epi32(slab(1 - nx, ix, fx), slab(3 - ny, iy, fy)), _mm256_min_epi32(slab(5 - nz, iz, fz), _mm256_castps_si256(_mm256_set1_ps(tmax * EXIT_SLACK))));
            let miss = _mm256_cmpgt_epi32(t0, t1);
            _mm256_storeu_si256(tnear.as_mut_ptr() as *mut __m256i, t0);
            (tnear, !(_mm256_movemask_ps(_mm256_castsi256_ps(miss)) as u32) & 0xff)
        }
    }
}

/// `a.max(b)` without `f32::max`'s NaN rule (no NaN reaches the slab test).
#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b { a } else { b }
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b { a } else { b }
}

/// The same test child by child, for targets without SSE.
#[cfg(not(target_arch = "x86_64"))]
impl NodeTest for Baseline {
    #[inline(always)]
    unsafe fn intersect(node: &Node8, r: &PreparedRay, tmax: f32) -> ([f32; 8], u32) {
        let p = &node.planes;
        let (nx, ny, nz) = (r.near[0], r.near[1], r.near[2]);
        let (xn, xf) = (&p[nx], &p[1 - nx]);
        let (yn, yf) = (&p[2 + ny], &p[3 - ny]);
        let (zn, zf) = (&p[4 + nz], &p[5 - nz]);
        let mut tnear = [0f32; 8];
        let mut mask = 0u32;
        for i in 0..8 {
            let tx0 = xn[i] * r.inv[0] - r.near_org_inv[0];
            let ty0 = yn[i] * r.inv[1] - r.near_org_inv[1];
            let tz0 = zn[i] * r.inv[2] - r.near_org_inv[2];
            let tx1 = xf[i] * r.inv[0] - r.far_org_inv[0];
            let ty1 = yf[i] * r.inv[1] - r.far_org_inv[1];
            let tz1 = zf[i] * r.inv[2] - r.far_org_inv[2];
            let t0 = max(max(tx0, ty0), max(tz0, r.tmin));
            let t1 = min(min(tx1, ty1), min(tz1, tmax * EXIT_SLACK));
            tnear[i] = t0;
            mask |= ((t0 <= t1) as u32) << i;
        }
        (tnear, mask)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Vec3, Vec3A};

    /// The slab tests are conservative, as [`PreparedRay::new`] argues: against the exact
    /// ray–box interval (f64, from the same f32 origin and direction), every box the ray
    /// meets within `[tmin, tmax]` is in the mask, in every form the CPU runs. The boxes
    /// are the hard cases: flat on one or two axes, far from the coordinates' origin
    /// relative to their size (so `plane * inv` and `origin * inv` nearly cancel), met by
    /// rays aimed at their edges and corners from near and far.
    #[test]
    fn every_box_the_ray_meets_is_in_the_mask() {
        let mut s = 0x9e3779b97f4a7c15u64;
        let mut f = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let (mut met, mut checked) = (0usize, 0usize);
        for n in 0..40_000 {
            let extent = [1.0f32, 600.0, 1e5][n % 3];
            let mut node = Node8 { planes: [[0.0; 8]; 6], child: [0; 8] };
            let mut corner = [Vec3A::ZERO; 8];
            for c in 0..8 {
                let mut lo = [0f32; 3];
                let mut hi = [0f32; 3];
                for a in 0..3 {
                    let centre = (f() * 2.0 - 1.0) * extent * 0.9;
                    let half = if (c + a + n) % 4 == 0 { 0.0 } else { f() * extent * 1e-3 };
                    (lo[a], hi[a]) = (centre - half, centre + half);
                    node.planes[2 * a][c] = lo[a];
                    node.planes[2 * a + 1][c] = hi[a];
                }
                let pick = |a: usize, bit: usize| if c >> bit & 1 == 0 { lo[a] } else { hi[a] };
                corner[c] = Vec3A::new(pick(0, 0), pick(1, 1), pick(2, 2));
            }
            // Aim at a corner of one child (on its edges and faces when flat), or near it.
            let target = corner[n % 8] + if n % 5 == 0 { Vec3A::new(f(), f(), f()) * extent * 1e-4 } else { Vec3A::ZERO };
            let mut d = Vec3A::new(f() * 2.0 - 1.0, f() * 2.0 - 1.0, f() * 2.0 - 1.0);
            if n % 7 == 0 {
                d = d * Vec3A::new(1.0, 0.0, 1.0) + Vec3A::new(0.0, 1e-6, 0.0);
            }
            let distance = [1e-3f32, 1.0, 50.0][n % 3] * extent;
            let o = target - d.normalize() * distance;
            let ray = PreparedRay::new(o, d, 0.0, extent);
            let tmax = if n % 11 == 0 { distance * 0.5 } else { f32::INFINITY };
            let mut masks = vec![unsafe { Baseline::intersect(&node, &ray, tmax) }.1];
            #[cfg(target_arch = "x86_64")]
            if Simd::Avx2.supported() {
                // SAFETY: AVX2 and FMA were detected (the intrinsics are called, not inlined,
                // outside a target-feature function: the same arithmetic).
                masks.push(unsafe { Avx2::intersect(&node, &ray, tmax) }.1);
            }
            let (od, dd) = (Vec3::from(o).as_dvec3(), Vec3::from(d).as_dvec3());
            for c in 0..8 {
                let (mut near, mut far) = (0f64, tmax as f64);
                for a in 0..3 {
                    let (lo, hi) = (node.planes[2 * a][c] as f64, node.planes[2 * a + 1][c] as f64);
                    let (t0, t1) = ((lo - od[a]) / dd[a], (hi - od[a]) / dd[a]);
                    near = near.max(t0.min(t1));
                    far = far.min(t0.max(t1));
                }
                if near <= far {
                    met += 1;
                    for m in &masks {
                        assert!(m >> c & 1 == 1, "case {n}: child {c} met on [{near}, {far}] but not in mask {m:08b}; origin {o}, direction {d}");
                    }
                }
                checked += 1;
            }
        }
        eprintln!("{met} of {checked} children met");
        assert!(met > 5000, "too few boxes met to test anything: {met} of {checked}");
    }

    /// The centre of child `c`'s box on axis `a`.
    #[cfg(target_arch = "x86_64")]
    fn centre(node: &Node8, a: usize, c: usize) -> f32 {
        (node.planes[2 * a][c] + node.planes[2 * a + 1][c]) * 0.5
    }

    /// The AVX2 test's integer maxima, minima and comparison give the float test's answer:
    /// the same mask and, for every child hit, the same entry distance bit for bit, against
    /// the same fused arithmetic with float `max`, `min` and `<=` — on boxes in front of
    /// the origin, behind it and around it, empty children (±∞ planes), tiny and infinite
    /// `tmax`, and `tmin` of 0 and above.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_integer_order_equals_float_order() {
        if !Simd::Avx2.supported() {
            return;
        }
        let mut s = 0x2545f4914f6cdd1du64;
        let mut f = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let (mut hit, mut missed) = (0usize, 0usize);
        for n in 0..50_000 {
            let mut node = super::super::wide::EMPTY_NODE;
            let children = 1 + n % 8;
            for c in 0..children {
                for a in 0..3 {
                    let (x, y) = (f() * 4.0, f() * 4.0);
                    node.planes[2 * a][c] = x.min(y);
                    node.planes[2 * a + 1][c] = if n % 13 == 0 { x.min(y) } else { x.max(y) };
                }
                node.child[c] = c as u32;
            }
            let o = Vec3A::new(f(), f(), f()) * 3.0;
            // Half the rays aimed at a child's centre (hits), half anywhere.
            let k = n % children;
            let centre = Vec3A::new(centre(&node, 0, k), centre(&node, 1, k), centre(&node, 2, k));
            let aim = if n % 2 == 0 { centre - o } else { Vec3A::ZERO };
            let d = (aim + Vec3A::new(f(), f(), f())) * if n % 9 == 0 { Vec3A::new(1.0, 0.0, 1.0) } else { Vec3A::ONE };
            let tmin = [0.0f32, 0.0, 1e-4, 0.5][n % 4];
            let ray = PreparedRay::new(o, d, tmin, 4.0);
            let tmax = [f32::INFINITY, 1.0, 0.25, 1e-3, 0.0][n % 5];
            // SAFETY: AVX2 and FMA were detected.
            let (tnear, mask) = unsafe { Avx2::intersect(&node, &ray, tmax) };
            let (nx, ny, nz) = (ray.near[0], ray.near[1], ray.near[2]);
            let p = &node.planes;
            for c in 0..8 {
                let slab = |k: usize, a: usize, oi: f32| p[k][c].mul_add(ray.inv[a], -oi);
                let t0 = slab(nx, 0, ray.near_org_inv[0]).max(slab(2 + ny, 1, ray.near_org_inv[1])).max(slab(4 + nz, 2, ray.near_org_inv[2]).max(ray.tmin));
                let t1 = slab(1 - nx, 0, ray.far_org_inv[0]).min(slab(3 - ny, 1, ray.far_org_inv[1])).min(slab(5 - nz, 2, ray.far_org_inv[2]).min(tmax * EXIT_SLACK));
                let want = t0 <= t1;
                assert_eq!(mask >> c & 1 == 1, want, "case {n} child {c}: [{t0}, {t1}]");
                if want {
                    assert_eq!(tnear[c].to_bits(), t0.to_bits(), "case {n} child {c}");
                    hit += 1;
                } else {
                    missed += 1;
                }
            }
        }
        assert!(hit > 20_000 && missed > 20_000, "{hit} hit, {missed} missed");
    }
}
