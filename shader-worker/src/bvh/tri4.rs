//! Leaf triangles four to a block in structure-of-arrays layout (vertex 0, edges 1 and 2,
//! each coordinate as 4 lanes), intersected together by Möller–Trumbore written lane-wise
//! so the compiler turns it into one SIMD test. Unused lanes are degenerate (zero edges:
//! determinant 0, never a hit).
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

    /// The nearest lane hit with `tmin <= t <= tmax`: (lane, t).
    #[inline(always)]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> Option<(usize, f32)> {
        let (t, mut mask) = self.distances(o, d, tmin, tmax);
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

    /// Whether any lane is hit with `tmin <= t <= tmax`.
    #[inline(always)]
    pub fn any(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> bool {
        self.distances(o, d, tmin, tmax).1 != 0
    }

    /// Per lane, the hit distance, and the mask of lanes hit with `tmin <= t <= tmax`:
    /// the SSE form (x86-64 always has SSE2).
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn distances(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
        use std::arch::x86_64::*;
        // SAFETY: SSE2 is part of the x86-64 baseline; `c` is 16-byte aligned (repr align).
        unsafe {
            let ld = |k: usize| _mm_load_ps(self.c[k].as_ptr());
            let (dx, dy, dz) = (_mm_set1_ps(d.x), _mm_set1_ps(d.y), _mm_set1_ps(d.z));
            let (e1x, e1y, e1z) = (ld(3), ld(4), ld(5));
            let (e2x, e2y, e2z) = (ld(6), ld(7), ld(8));
            let sub = |a, b| _mm_sub_ps(a, b);
            let mul = |a, b| _mm_mul_ps(a, b);
            let add = |a, b| _mm_add_ps(a, b);
            let px = sub(mul(dy, e2z), mul(dz, e2y));
            let py = sub(mul(dz, e2x), mul(dx, e2z));
            let pz = sub(mul(dx, e2y), mul(dy, e2x));
            let det = add(add(mul(e1x, px), mul(e1y, py)), mul(e1z, pz));
            // Unnormalised barycentrics and distance with the determinant's sign folded in:
            // no division unless some lane is hit.
            let sign = _mm_and_ps(det, _mm_set1_ps(-0.0));
            let abs_det = _mm_xor_ps(det, sign);
            let sx = sub(_mm_set1_ps(o.x), ld(0));
            let sy = sub(_mm_set1_ps(o.y), ld(1));
            let sz = sub(_mm_set1_ps(o.z), ld(2));
            let u = _mm_xor_ps(add(add(mul(sx, px), mul(sy, py)), mul(sz, pz)), sign);
            let qx = sub(mul(sy, e1z), mul(sz, e1y));
            let qy = sub(mul(sz, e1x), mul(sx, e1z));
            let qz = sub(mul(sx, e1y), mul(sy, e1x));
            let v = _mm_xor_ps(add(add(mul(dx, qx), mul(dy, qy)), mul(dz, qz)), sign);
            let tt = _mm_xor_ps(add(add(mul(e2x, qx), mul(e2y, qy)), mul(e2z, qz)), sign);
            let zero = _mm_setzero_ps();
            // Ordered comparisons: NaN fails each of them.
            let mut m = _mm_cmpgt_ps(abs_det, zero);
            m = _mm_and_ps(m, _mm_cmpge_ps(u, zero));
            m = _mm_and_ps(m, _mm_cmpge_ps(v, zero));
            m = _mm_and_ps(m, _mm_cmple_ps(add(u, v), abs_det));
            let mut out = [0f32; 4];
            if _mm_movemask_ps(m) == 0 {
                return (out, 0);
            }
            let t = _mm_div_ps(tt, abs_det);
            m = _mm_and_ps(m, _mm_cmpge_ps(t, _mm_set1_ps(tmin)));
            m = _mm_and_ps(m, _mm_cmple_ps(t, _mm_set1_ps(tmax)));
            _mm_storeu_ps(out.as_mut_ptr(), t);
            (out, _mm_movemask_ps(m) as u32)
        }
    }

    /// The same test lane by lane, for targets without SSE (and as the reference the SSE
    /// form is tested against).
    #[cfg_attr(target_arch = "x86_64", allow(dead_code))]
    #[inline(always)]
    fn distances_scalar(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
        let c = &self.c;
        let mut out = [0f32; 4];
        let mut hit = [false; 4];
        for i in 0..4 {
            let (e1x, e1y, e1z) = (c[3][i], c[4][i], c[5][i]);
            let (e2x, e2y, e2z) = (c[6][i], c[7][i], c[8][i]);
            // p = d × e2, det = e1 · p
            let px = d.y * e2z - d.z * e2y;
            let py = d.z * e2x - d.x * e2z;
            let pz = d.x * e2y - d.y * e2x;
            let det = e1x * px + e1y * py + e1z * pz;
            // Unnormalised barycentrics and distance with the determinant's sign folded in.
            let sign = if det.is_sign_negative() { -1.0 } else { 1.0 };
            let abs_det = det * sign;
            // s = o - v0, u = (s · p) · sign
            let sx = o.x - c[0][i];
            let sy = o.y - c[1][i];
            let sz = o.z - c[2][i];
            let u = (sx * px + sy * py + sz * pz) * sign;
            // q = s × e1, v = (d · q) · sign, t = (e2 · q) · sign / |det|
            let qx = sy * e1z - sz * e1y;
            let qy = sz * e1x - sx * e1z;
            let qz = sx * e1y - sy * e1x;
            let v = (d.x * qx + d.y * qy + d.z * qz) * sign;
            let t = (e2x * qx + e2y * qy + e2z * qz) * sign / abs_det;
            // NaN fails every comparison.
            hit[i] = abs_det > 0.0 && u >= 0.0 && v >= 0.0 && u + v <= abs_det && t >= tmin && t <= tmax;
            out[i] = t;
        }
        let mut mask = 0;
        for (i, h) in hit.iter().enumerate() {
            mask |= (*h as u32) << i;
        }
        (out, mask)
    }

    #[cfg(not(target_arch = "x86_64"))]
    #[inline(always)]
    fn distances(&self, o: Vec3A, d: Vec3A, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
        self.distances_scalar(o, d, tmin, tmax)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The SSE test and the lane-by-lane one agree bit for bit on random triangles and
    /// rays (the same operations in the same order), including empty lanes.
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
            let (ta, ma) = block.distances(o, d, 0.0, f32::INFINITY);
            let (tb, mb) = block.distances_scalar(o, d, 0.0, f32::INFINITY);
            assert_eq!(ma, mb);
            for lane in 0..4 {
                if ma & (1 << lane) != 0 {
                    assert_eq!(ta[lane].to_bits(), tb[lane].to_bits());
                    hits += 1;
                }
            }
            assert_eq!(ma >> tris.len(), 0, "empty lanes never hit");
        }
        assert!(hits > 8000, "{hits} hits");
    }
}
