//! Leaf triangles four to a block in structure-of-arrays layout (the three corners, each
//! coordinate as 4 lanes), intersected together by one 4-lane watertight test ([`TriTest`]:
//! SSE, or with fused multiply-adds where the CPU has FMA): Woop, Benthin and Wald,
//! "Watertight Ray/Triangle Intersection" (JCGT 2(1), 2013), §3. Watertight because each
//! edge's test is a function of that edge's two corners only (relative to the ray's origin,
//! in the ray's sheared frame), computed so that swapping the corners negates it exactly:
//! the two triangles sharing an edge see the same value with opposite signs, so a ray
//! through the edge is inside one of them (or on both). Möller–Trumbore, the test before,
//! measures both barycentrics from one corner, so neighbours round the shared edge
//! differently: with fused multiply-adds it let a camera ray aimed at the centre of a floor
//! of two triangles (on their shared diagonal) through both. Unused lanes have three equal
//! corners (every edge function 0, determinant 0: never a hit).
#[cfg(target_arch = "x86_64")]
use super::node_test::Avx2;
use super::node_test::Baseline;
use super::wide::PreparedRay;
use glam::Vec3;

/// Up to four triangles and their indices in the mesh (`u32::MAX` in unused lanes).
#[derive(Clone, Copy)]
#[repr(C, align(16))]
pub struct Tri4 {
    /// a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z — 4 lanes each.
    c: [[f32; 4]; 9],
    pub tri: [u32; 4],
}

impl Tri4 {
    /// A block of up to 4 triangles (`(index in the mesh, [a, b, c])`).
    pub fn new(tris: &[(u32, [Vec3; 3])]) -> Tri4 {
        assert!(tris.len() <= 4, "a Tri4 block holds at most 4 triangles");
        let mut block = Tri4 { c: [[0.0; 4]; 9], tri: [u32::MAX; 4] };
        for (lane, (tri, corners)) in tris.iter().enumerate() {
            for (k, v) in corners.iter().flat_map(|v| v.to_array()).enumerate() {
                block.c[k][lane] = v;
            }
            block.tri[lane] = *tri;
        }
        block
    }

    fn corner(&self, corner: usize, lane: usize) -> Vec3 {
        let c = &self.c;
        Vec3::new(c[3 * corner][lane], c[3 * corner + 1][lane], c[3 * corner + 2][lane])
    }

    /// The geometric normal of the triangle in `lane` (mesh winding), unnormalised:
    /// `(b - a) × (c - a)` from the same corners as the mesh's face normals, so normalised
    /// (`normalize_or_zero`) it equals `Mesh::face_normals` bit for bit; read from the block
    /// the hit just loaded rather than from a normal array that would be one more cache miss.
    #[inline]
    pub fn geometric(&self, lane: usize) -> Vec3 {
        let a = self.corner(0, lane);
        (self.corner(1, lane) - a).cross(self.corner(2, lane) - a)
    }

    /// The nearest lane hit with `ray.tmin <= t <= tmax`: (lane, t), tested with `K`.
    ///
    /// # Safety
    /// As [`TriTest::distances`].
    #[inline(always)]
    pub unsafe fn intersect<K: TriTest>(&self, ray: &PreparedRay, tmax: f32) -> Option<(usize, f32)> {
        // SAFETY: forwarded from the caller.
        let (t, mut mask) = unsafe { K::distances(self, ray, tmax) };
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

    /// Whether any lane is hit with `ray.tmin <= t <= tmax`, tested with `K`.
    ///
    /// # Safety
    /// As [`TriTest::distances`].
    #[inline(always)]
    pub unsafe fn any<K: TriTest>(&self, ray: &PreparedRay, tmax: f32) -> bool {
        // SAFETY: forwarded from the caller.
        unsafe { K::distances(self, ray, tmax).1 != 0 }
    }

    /// The test lane by lane with separate multiplies and adds: the reference the SSE form
    /// equals bit for bit, and the form on targets without SSE. `fused` computes the shear
    /// and the distance's dot product with one rounding per multiply-add (`mul_add`), as
    /// the FMA form does, which it equals bit for bit then. The edge functions are never
    /// fused: `x·y − z·w` fused is not negated exactly by swapping the corners.
    #[cfg_attr(target_arch = "x86_64", allow(dead_code))]
    #[inline(always)]
    fn distances_scalar(&self, ray: &PreparedRay, tmax: f32, fused: bool) -> ([f32; 4], u32) {
        let fma = |a: f32, b: f32, c: f32| if fused { a.mul_add(b, c) } else { a * b + c };
        let [kx, ky, kz] = ray.axes;
        let o = ray.origin.to_array();
        let [sx, sy, sz] = ray.shear;
        let c = &self.c;
        let mut out = [0f32; 4];
        let mut mask = 0;
        for i in 0..4 {
            // Corner j in the ray's frame: origin at the ray's, sheared so the ray runs
            // along +z (z not yet scaled).
            let corner = |j: usize| {
                let z = c[3 * j + kz][i] - o[kz];
                (fma(-sx, z, c[3 * j + kx][i] - o[kx]), fma(-sy, z, c[3 * j + ky][i] - o[ky]), z)
            };
            let (a, b, cc) = (corner(0), corner(1), corner(2));
            // Edge functions (twice the signed areas seen along the ray), unfused.
            let u = cc.0 * b.1 - cc.1 * b.0;
            let v = a.0 * cc.1 - a.1 * cc.0;
            let w = b.0 * a.1 - b.1 * a.0;
            let det = u + v + w;
            let sign = if det.is_sign_negative() { -1.0 } else { 1.0 };
            let abs_det = det * sign;
            // t · det = u·a.z + v·b.z + w·c.z (z scaled by 1 / d[kz]).
            let tt = fma(w, sz * cc.2, fma(v, sz * b.2, u * (sz * a.2))) * sign;
            // NaN fails every comparison; the distance is tested before dividing by |det|.
            if abs_det > 0.0 && u * sign >= 0.0 && v * sign >= 0.0 && w * sign >= 0.0 && tt >= abs_det * ray.tmin && tt <= abs_det * tmax {
                mask |= 1 << i;
                // Clamped: the range was tested on t · |det|, so the quotient may round an
                // ulp outside it.
                out[i] = (tt / abs_det).max(ray.tmin).min(tmax);
            }
        }
        (out, mask)
    }
}

/// One 4-lane watertight triangle test (the module's; the determinant's sign folded into
/// the edge functions and the distance, and the distance range tested before dividing, as
/// Embree does): per lane the hit distance, and the mask of lanes hit with
/// `ray.tmin <= t <= tmax`. Both faces count.
pub trait TriTest {
    /// # Safety
    /// The CPU must support the instructions the implementation uses, and the caller must
    /// be compiled with them enabled (inside a `#[target_feature]` function).
    unsafe fn distances(block: &Tri4, ray: &PreparedRay, tmax: f32) -> ([f32; 4], u32);
}

/// The SSE form (x86-64 always has SSE2), or the FMA form: the same operations, the shear
/// and the distance's multiply-adds fused in the FMA form.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn distances_sse<const FUSED: bool>(block: &Tri4, ray: &PreparedRay, tmax: f32) -> ([f32; 4], u32) {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of the x86-64 baseline, FMA guaranteed by the caller when
    // FUSED; `c` is 16-byte aligned (repr align).
    unsafe {
        let ld = |k: usize| _mm_load_ps(block.c[k].as_ptr());
        let fma = |a, b, c| if FUSED { _mm_fmadd_ps(a, b, c) } else { _mm_add_ps(_mm_mul_ps(a, b), c) };
        // c − a·b
        let fnma = |a, b, c| if FUSED { _mm_fnmadd_ps(a, b, c) } else { _mm_sub_ps(c, _mm_mul_ps(a, b)) };
        let [kx, ky, kz] = ray.axes;
        let o = ray.origin.to_array();
        let (ox, oy, oz) = (_mm_set1_ps(o[kx]), _mm_set1_ps(o[ky]), _mm_set1_ps(o[kz]));
        let (sx, sy, sz) = (_mm_set1_ps(ray.shear[0]), _mm_set1_ps(ray.shear[1]), _mm_set1_ps(ray.shear[2]));
        let corner = |j: usize| {
            let z = _mm_sub_ps(ld(3 * j + kz), oz);
            (fnma(sx, z, _mm_sub_ps(ld(3 * j + kx), ox)), fnma(sy, z, _mm_sub_ps(ld(3 * j + ky), oy)), z)
        };
        let (a, b, c) = (corner(0), corner(1), corner(2));
        // Never fused (see `distances_scalar`).
        let edge = |p: (__m128, __m128, __m128), q: (__m128, __m128, __m128)| _mm_sub_ps(_mm_mul_ps(p.0, q.1), _mm_mul_ps(p.1, q.0));
        let u = edge(c, b);
        let v = edge(a, c);
        let w = edge(b, a);
        let det = _mm_add_ps(_mm_add_ps(u, v), w);
        let sign = _mm_and_ps(det, _mm_set1_ps(-0.0));
        let abs_det = _mm_xor_ps(det, sign);
        let zero = _mm_setzero_ps();
        // Inside: the three edge functions of the determinant's sign, i.e. all ≥ 0 or all
        // ≤ 0 (their sum is the determinant, so it cannot have the other sign; all zero is
        // the zero determinant, excluded) — two compares on their minimum and maximum
        // instead of three on sign-flipped copies. Ordered comparisons: a NaN edge
        // function makes the determinant NaN, which fails `abs_det > 0`.
        let lo = _mm_min_ps(_mm_min_ps(u, v), w);
        let hi = _mm_max_ps(_mm_max_ps(u, v), w);
        let inside = _mm_or_ps(_mm_cmpge_ps(lo, zero), _mm_cmple_ps(hi, zero));
        let mut m = _mm_and_ps(_mm_cmpgt_ps(abs_det, zero), inside);
        // Most blocks a ray visits are missed by every lane: stop before the distance (as
        // Embree's leaf test does).
        if _mm_movemask_ps(m) == 0 {
            return ([0f32; 4], 0);
        }
        let tt = _mm_xor_ps(fma(w, _mm_mul_ps(sz, c.2), fma(v, _mm_mul_ps(sz, b.2), _mm_mul_ps(u, _mm_mul_ps(sz, a.2)))), sign);
        m = _mm_and_ps(m, _mm_cmpge_ps(tt, _mm_mul_ps(abs_det, _mm_set1_ps(ray.tmin))));
        m = _mm_and_ps(m, _mm_cmple_ps(tt, _mm_mul_ps(abs_det, _mm_set1_ps(tmax))));
        let mut out = [0f32; 4];
        let mask = _mm_movemask_ps(m) as u32;
        // Divide only when some lane is hit (a minority of the blocks a ray visits).
        if mask != 0 {
            // Clamped as in the scalar form.
            let t = _mm_min_ps(_mm_max_ps(_mm_div_ps(tt, abs_det), _mm_set1_ps(ray.tmin)), _mm_set1_ps(tmax));
            _mm_storeu_ps(out.as_mut_ptr(), t);
        }
        (out, mask)
    }
}

#[cfg(target_arch = "x86_64")]
impl TriTest for Baseline {
    #[inline(always)]
    unsafe fn distances(block: &Tri4, ray: &PreparedRay, tmax: f32) -> ([f32; 4], u32) {
        // SAFETY: SSE only.
        unsafe { distances_sse::<false>(block, ray, tmax) }
    }
}

#[cfg(target_arch = "x86_64")]
impl TriTest for Avx2 {
    #[inline(always)]
    unsafe fn distances(block: &Tri4, ray: &PreparedRay, tmax: f32) -> ([f32; 4], u32) {
        // SAFETY: the caller guarantees FMA.
        unsafe { distances_sse::<true>(block, ray, tmax) }
    }
}

#[cfg(not(target_arch = "x86_64"))]
impl TriTest for Baseline {
    #[inline(always)]
    unsafe fn distances(block: &Tri4, ray: &PreparedRay, tmax: f32) -> ([f32; 4], u32) {
        block.distances_scalar(ray, tmax, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3A;

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
            let ray = PreparedRay::new(o, Vec3A::from((a + b + c) / 3.0 + v() * 0.3) - o, 0.0, 2.0);
            // A finite tmax on some rays so the distance test is exercised too.
            let tmax = if n % 3 == 0 { 1.0 } else { f32::INFINITY };
            // (name, the SIMD test's distances and mask, the lane-by-lane ones)
            let mut forms: Vec<(&str, Distances, Distances)> = Vec::new();
            // SAFETY: SSE is baseline on x86-64; FMA is only run when detected.
            #[cfg(target_arch = "x86_64")]
            unsafe {
                forms.push(("sse", Baseline::distances(&block, &ray, tmax), block.distances_scalar(&ray, tmax, false)));
                if crate::bvh::Simd::Avx2.supported() {
                    forms.push(("fma", Avx2::distances(&block, &ray, tmax), block.distances_scalar(&ray, tmax, true)));
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
