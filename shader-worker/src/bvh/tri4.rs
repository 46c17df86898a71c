//! Leaf triangles four to a block in structure-of-arrays layout (vertex 0, edges 1 and 2,
//! each coordinate as 4 lanes), intersected together by one 4-lane Möller–Trumbore test
//! ([`TriTest`]: SSE, or with fused multiply-adds where the CPU has FMA). Unused lanes
//! are degenerate (zero edges: determinant 0, never a hit).
#[cfg(target_arch = "x86_64")]
use super::node_test::Avx2;
use super::node_test::Baseline;
use glam::{Vec3, Vec3A};

/// Up to four triangles and their indices in the mesh (`u32::MAX` in unused lanes).
#[derive(Clone, Copy)]
#[repr(C, align(16))]
pub struct Tri4 {
    /// v0.x, v0.y, v0.z, e1.x, e1.y, e1.z, e2.x, e2.y, e2.z — 4 lanes each.
    c: [[f32; 4]; 9],
    pub tri: [u32; 4],
}

impl Tri4 {
    /// A block of up to 4 triangles (`(index in the mesh, [a, b, c])`).
    pub fn new(tris: &[(u32, [Vec3; 3])]) -> Tri4 {
        assert!(tris.len() <= 4, "a Tri4 block holds at most 4 triangles");
        let mut block = Tri4 { c: [[0.0; 4]; 9], tri: [u32::MAX; 4] };
        for (lane, (tri, [a, b, c])) in tris.iter().enumerate() {
            let (e1, e2) = (*b - *a, *c - *a);
            for (k, v) in [a.x, a.y, a.z, e1.x, e1.y, e1.z, e2.x, e2.y, e2.z].into_iter().enumerate() {
                block.c[k][lane] = v;
            }
            block.tri[lane] = *tri;
        }
        block
    }

    /// The unit geometric normal of the triangle in `lane` (mesh winding), computed exactly
    /// as the mesh computes its face normals (`(b - a) × (c - a)`, normalised) from the
    /// same edges, so it equals `Mesh::face_normals` bit for bit; read from the block the
    /// hit just loaded rather than from a normal array that would be one more cache miss.
    #[inline]
    pub fn normal(&self, lane: usize) -> Vec3 {
        let c = &self.c;
        let e1 = Vec3::new(c[3][lane], c[4][lane], c[5][lane]);
        let e2 = Vec3::new(c[6][lane], c[7][lane], c[8][lane]);
        e1.cross(e2).normalize_or_zero()
    }

    /// The nearest lane hit with `tmin <= t <= tmax`: (lane, t), tested with `K`.
    ///
    /// # Safety
    /// As [`TriTest::distances`].
    #[inline(always)]
    pub unsafe fn intersect<K: TriTest>(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(usize, f32)> {
        // SAFETY: forwarded from the caller.
        let (t, mut mask) = unsafe { K::distances(self, o, d, tmin, tmax) };
        let mut best: Option<(usize, f32)> = None;
        while mask != 0 {
            let lane = mask.trailing_zeros() as usize;
            mask &= mask - 1;
            if best.is_none_or(|b| t[lane] < b.1) {
                best = Some((lane, t[lane]));
            }
        }
        best
    }

    /// Whether any lane is hit with `tmin <= t <= tmax`, tested with `K`.
    ///
    /// # Safety
    /// As [`TriTest::distances`].
    #[inline(always)]
    pub unsafe fn any<K: TriTest>(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> bool {
        // SAFETY: forwarded from the caller.
        unsafe { K::distances(self, o, d, tmin, tmax).1 != 0 }
    }

    /// The test lane by lane with separate multiplies and adds: the reference the SSE form
    /// equals bit for bit, and the form on targets without SSE. `fused` computes each
    /// `a * b + c` with one rounding (`mul_add`), as the FMA form does, which it equals bit
    /// for bit then.
    #[cfg_attr(target_arch = "x86_64", allow(dead_code))]
    #[inline(always)]
    fn distances_scalar(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32, fused: bool) -> ([f32; 4], u32) {
        // a * b + c, fused or not.
        let fma = |a: f32, b: f32, c: f32| if fused { a.mul_add(b, c) } else { a * b + c };
        // a * b - c * e, the product c * e rounded first in both forms.
        let cross = |a: f32, b: f32, c: f32, e: f32| fma(a, b, -(c * e));
        let dot = |a: [f32; 3], b: [f32; 3]| fma(a[2], b[2], fma(a[1], b[1], a[0] * b[0]));
        let c = &self.c;
        let mut out = [0f32; 4];
        let mut mask = 0;
        for i in 0..4 {
            let e1 = [c[3][i], c[4][i], c[5][i]];
            let e2 = [c[6][i], c[7][i], c[8][i]];
            // p = d × e2, det = e1 · p
            let p = [cross(d.y, e2[2], d.z, e2[1]), cross(d.z, e2[0], d.x, e2[2]), cross(d.x, e2[1], d.y, e2[0])];
            let det = dot(e1, p);
            // Unnormalised barycentrics and distance with the determinant's sign folded in.
            let sign = if det.is_sign_negative() { -1.0 } else { 1.0 };
            let abs_det = det * sign;
            // s = o - v0, u = (s · p) · sign
            let s = [o.x - c[0][i], o.y - c[1][i], o.z - c[2][i]];
            let u = dot(s, p) * sign;
            // q = s × e1, v = (d · q) · sign, t · |det| = (e2 · q) · sign
            let q = [cross(s[1], e1[2], s[2], e1[1]), cross(s[2], e1[0], s[0], e1[2]), cross(s[0], e1[1], s[1], e1[0])];
            let v = dot([d.x, d.y, d.z], q) * sign;
            let tt = dot(e2, q) * sign;
            // NaN fails every comparison; the distance is tested before dividing by |det|.
            if abs_det > 0.0 && u >= 0.0 && v >= 0.0 && u + v <= abs_det && tt >= abs_det * tmin && tt <= abs_det * tmax {
                mask |= 1 << i;
                // Clamped: the range was tested on t · |det|, so the quotient may round an
                // ulp outside it.
                out[i] = (tt / abs_det).max(tmin).min(tmax);
            }
        }
        (out, mask)
    }
}

/// One 4-lane triangle test (Möller and Trumbore, "Fast, Minimum Storage Ray/Triangle
/// Intersection", 1997, with the determinant's sign folded into the unnormalised
/// barycentrics and distance, and the distance range tested before dividing, as Embree
/// does): per lane the hit distance, and the mask of lanes hit with `tmin <= t <= tmax`.
pub trait TriTest {
    /// # Safety
    /// The CPU must support the instructions the implementation uses, and the caller must
    /// be compiled with them enabled (inside a `#[target_feature]` function).
    unsafe fn distances(block: &Tri4, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32);
}

/// The SSE form (x86-64 always has SSE2), or the FMA form: the same operations, each
/// `a * b + c` fused in the FMA form.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn distances_sse<const FUSED: bool>(block: &Tri4, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of the x86-64 baseline, FMA guaranteed by the caller when
    // FUSED; `c` is 16-byte aligned (repr align).
    unsafe {
        let ld = |k: usize| _mm_load_ps(block.c[k].as_ptr());
        let fma = |a, b, c| if FUSED { _mm_fmadd_ps(a, b, c) } else { _mm_add_ps(_mm_mul_ps(a, b), c) };
        let cross = |a, b, c, e| if FUSED { _mm_fmsub_ps(a, b, _mm_mul_ps(c, e)) } else { _mm_sub_ps(_mm_mul_ps(a, b), _mm_mul_ps(c, e)) };
        let dot = |a: [__m128; 3], b: [__m128; 3]| fma(a[2], b[2], fma(a[1], b[1], _mm_mul_ps(a[0], b[0])));
        let dv = [_mm_set1_ps(d.x), _mm_set1_ps(d.y), _mm_set1_ps(d.z)];
        let e1 = [ld(3), ld(4), ld(5)];
        let e2 = [ld(6), ld(7), ld(8)];
        let p = [cross(dv[1], e2[2], dv[2], e2[1]), cross(dv[2], e2[0], dv[0], e2[2]), cross(dv[0], e2[1], dv[1], e2[0])];
        let det = dot(e1, p);
        let sign = _mm_and_ps(det, _mm_set1_ps(-0.0));
        let abs_det = _mm_xor_ps(det, sign);
        let s = [_mm_sub_ps(_mm_set1_ps(o.x), ld(0)), _mm_sub_ps(_mm_set1_ps(o.y), ld(1)), _mm_sub_ps(_mm_set1_ps(o.z), ld(2))];
        let u = _mm_xor_ps(dot(s, p), sign);
        let q = [cross(s[1], e1[2], s[2], e1[1]), cross(s[2], e1[0], s[0], e1[2]), cross(s[0], e1[1], s[1], e1[0])];
        let v = _mm_xor_ps(dot(dv, q), sign);
        let tt = _mm_xor_ps(dot(e2, q), sign);
        let zero = _mm_setzero_ps();
        // Ordered comparisons: NaN fails each of them.
        let mut m = _mm_cmpgt_ps(abs_det, zero);
        m = _mm_and_ps(m, _mm_cmpge_ps(u, zero));
        m = _mm_and_ps(m, _mm_cmpge_ps(v, zero));
        m = _mm_and_ps(m, _mm_cmple_ps(_mm_add_ps(u, v), abs_det));
        m = _mm_and_ps(m, _mm_cmpge_ps(tt, _mm_mul_ps(abs_det, _mm_set1_ps(tmin))));
        m = _mm_and_ps(m, _mm_cmple_ps(tt, _mm_mul_ps(abs_det, _mm_set1_ps(tmax))));
        let mut out = [0f32; 4];
        let mask = _mm_movemask_ps(m) as u32;
        // Divide only when some lane is hit (a minority of the blocks a ray visits).
        if mask != 0 {
            // Clamped as in the scalar form.
            let t = _mm_min_ps(_mm_max_ps(_mm_div_ps(tt, abs_det), _mm_set1_ps(tmin)), _mm_set1_ps(tmax));
            _mm_storeu_ps(out.as_mut_ptr(), t);
        }
        (out, mask)
    }
}

#[cfg(target_arch = "x86_64")]
impl TriTest for Baseline {
    #[inline(always)]
    unsafe fn distances(block: &Tri4, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
        // SAFETY: SSE only.
        unsafe { distances_sse::<false>(block, o, d, tmin, tmax) }
    }
}

#[cfg(target_arch = "x86_64")]
impl TriTest for Avx2 {
    #[inline(always)]
    unsafe fn distances(block: &Tri4, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
        // SAFETY: the caller guarantees FMA.
        unsafe { distances_sse::<true>(block, o, d, tmin, tmax) }
    }
}

#[cfg(not(target_arch = "x86_64"))]
impl TriTest for Baseline {
    #[inline(always)]
    unsafe fn distances(block: &Tri4, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
        block.distances_scalar(o, d, tmin, tmax, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Distances = ([f32; 4], u32);

    /// The SSE test and the lane-by-lane one agree bit for bit on random triangles and
    /// rays (the same operations in the same order), including empty lanes; so do the FMA
    /// test and the lane-by-lane one with fused multiply-adds, where the CPU has FMA.
    #[test]
    fn simd_and_scalar_agree() {
        let mut s = 12345u64;
        let mut f = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let mut hits = 0;
        for n in 0..20_000 {
            let mut v = || Vec3::new(f(), f(), f());
            let tris: Vec<(u32, [Vec3; 3])> = (0..1 + n % 4).map(|k| (k as u32, [v(), v(), v()])).collect();
            let block = Tri4::new(&tris);
            let o = Vec3A::from(v() * 2.0);
            // Aim near the first triangle so most rays hit something.
            let [a, b, c] = tris[0].1;
            let d = Vec3A::from((a + b + c) / 3.0 + v() * 0.3) - o;
            // A finite tmax on some rays so the distance test is exercised too.
            let tmax = if n % 3 == 0 { 1.0 } else { f32::INFINITY };
            // (name, the SIMD test's distances and mask, the lane-by-lane ones)
            let mut forms: Vec<(&str, Distances, Distances)> = Vec::new();
            // SAFETY: SSE is baseline on x86-64; FMA is only run when detected.
            #[cfg(target_arch = "x86_64")]
            unsafe {
                forms.push(("sse", Baseline::distances(&block, o, d, 0.0, tmax), block.distances_scalar(o, d, 0.0, tmax, false)));
                if crate::bvh::Simd::Avx2.supported() {
                    forms.push(("fma", Avx2::distances(&block, o, d, 0.0, tmax), block.distances_scalar(o, d, 0.0, tmax, true)));
                }
            }
            for (name, (ta, ma), (tb, mb)) in forms {
                assert_eq!(ma, mb, "{name}");
                for lane in 0..4 {
                    if ma & (1 << lane) != 0 {
                        assert_eq!(ta[lane].to_bits(), tb[lane].to_bits(), "{name}");
                        assert!(ta[lane] <= tmax, "{name}");
                        hits += 1;
                    }
                }
                assert_eq!(ma >> tris.len(), 0, "empty lanes never hit");
            }
        }
        assert!(hits > 8000, "{hits} hits");
    }
}
