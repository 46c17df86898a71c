//! The shading point of a primary hit: the material's scattering model with its base colour
//! (× texture at the interpolated UV), the local shading frame (the normal interpolated from
//! the mesh's per-corner normals, else the face normal), the direction to the viewer in that
//! frame, and whether the surface scatters toward the viewer at all.
//!
//! Sidedness follows Mitsuba: reflection-only models on a two-sided material scatter on both
//! sides (the frame flips toward the viewer); on a one-sided material a hit from behind the
//! winding normal is black. The dielectric has no sides to choose: its frame keeps the
//! winding normal as "outside" and the model handles the viewer being inside.
use crate::bvh::{Hit, Instances};
use edgepoint_scene::material::{Frame, Scatter, Scattering};
use edgepoint_scene::{Material, Mesh};
use glam::{Vec2, Vec3};

pub struct ShadingPoint {
    pub frame: Frame,
    /// Direction to the viewer, local.
    pub wo: Vec3,
    pub bsdf: Scattering,
    /// False for a one-sided surface seen from behind: it reflects nothing.
    pub scatters: bool,
    /// `Some(f)` when f is the same for every light direction on the viewer's side of the
    /// face normal (Lambert with the face normal as shading normal): the direct shader then
    /// sums the unweighted light samples and multiplies once, as before materials existed,
    /// so that path's output is unchanged to the bit.
    pub constant: Option<Vec3>,
}

/// Barycentric coordinates of `p` (on or near the triangle's plane) in triangle `[a, b, c]`,
/// clamped into the triangle so a hit rounded just outside an edge interpolates sanely.
pub fn barycentric(p: Vec3, [a, b, c]: [Vec3; 3]) -> Vec3 {
    let (e0, e1, e2) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (e0.dot(e0), e0.dot(e1), e1.dot(e1));
    let (d20, d21) = (e2.dot(e0), e2.dot(e1));
    let den = d00 * d11 - d01 * d01;
    if den.is_nan() || den == 0.0 {
        return Vec3::new(1.0, 0.0, 0.0);
    }
    let v = ((d11 * d20 - d01 * d21) / den).clamp(0.0, 1.0);
    let w = ((d00 * d21 - d01 * d20) / den).clamp(0.0, 1.0);
    let s = v + w;
    let (v, w) = if s > 1.0 { (v / s, w / s) } else { (v, w) };
    Vec3::new(1.0 - v - w, v, w)
}

/// The base colour at a hit: the material's colour times its texture at the interpolated
/// UV (a texture on a mesh without UVs is looked up at UV (0, 0): the whole surface gets one
/// texel, which is what a renderer without UVs can do).
fn base_colour(mat: &Material, mesh: &Mesh, triangle: usize, bary: Option<Vec3>) -> Vec3 {
    let Some(tex) = &mat.texture else { return mat.diffuse };
    let uv = match (&mesh.corners.uvs, bary) {
        (Some(uvs), Some(b)) if triangle < uvs.len() => {
            let t = uvs[triangle];
            t[0] * b.x + t[1] * b.y + t[2] * b.z
        }
        _ => Vec2::ZERO,
    };
    mat.diffuse * tex.sample(uv)
}

impl ShadingPoint {
    /// `d`: the unit ray direction; `front`: the ray meets the winding side.
    pub fn new(mat: &Material, mesh: &Mesh, inst: &Instances, h: &Hit, d: Vec3, front: bool) -> ShadingPoint {
        let tri = h.triangle as usize;
        let has_normals = mesh.corners.normals.as_ref().is_some_and(|n| tri < n.len());
        let needs_bary = has_normals || (mat.texture.is_some() && mesh.corners.uvs.is_some());
        let bary = needs_bary.then(|| barycentric(h.local, mesh.triangle(tri)));
        let bsdf = mat.bsdf.at(base_colour(mat, mesh, tri, bary));

        // The shading normal on the winding side: interpolated when the mesh has normals and
        // they give a usable one that agrees with the face, else the face normal.
        let mut ns = h.normal;
        if let (Some(normals), Some(b)) = (&mesh.corners.normals, bary) {
            let c = normals[tri];
            let local = c[0] * b.x + c[1] * b.y + c[2] * b.z;
            let world = (inst.normal_to_world(h.object) * local).normalize_or_zero();
            let world = if world.dot(h.normal) < 0.0 { -world } else { world };
            // Where the interpolated normal puts the viewer on the wrong side (silhouettes
            // of coarse meshes) it would turn the surface black; the face normal does not.
            if world != Vec3::ZERO && world.dot(-d).signum() == h.normal.dot(-d).signum() {
                ns = world;
            }
        }
        let reflection_only = bsdf.is_reflection_only();
        let n = if reflection_only && !front { -ns } else { ns };
        let frame = Frame::from_normal(n);
        let wo = frame.to_local(-d);
        let scatters = front || mat.two_sided || !reflection_only;
        let constant = match bsdf {
            Scattering::Lambert(l) if ns == h.normal => Some(l.albedo * std::f32::consts::FRAC_1_PI),
            _ => None,
        };
        ShadingPoint { frame, wo, bsdf, scatters, constant }
    }

    /// f(wo, wi) · |cos θi| for a world direction `wi`.
    #[inline]
    pub fn eval_cos(&self, wi: Vec3) -> Vec3 {
        let l = self.frame.to_local(wi);
        self.bsdf.eval(self.wo, l) * l.z.abs()
    }

    /// The BSDF's sampling density of world direction `wi`.
    #[inline]
    pub fn pdf(&self, wi: Vec3) -> f32 {
        self.bsdf.pdf(self.wo, self.frame.to_local(wi))
    }

    /// Has a rough (non-delta, non-Lambertian) lobe: area lights are then sampled both from
    /// the light and from the BSDF, combined by multiple importance sampling.
    #[inline]
    pub fn is_glossy(&self) -> bool {
        !matches!(self.bsdf, Scattering::Lambert(_)) && self.bsdf.has_non_delta()
    }

    #[inline]
    pub fn bsdf_has_delta(&self) -> bool {
        self.bsdf.has_delta()
    }

    #[inline]
    pub fn bsdf_has_non_delta(&self) -> bool {
        self.bsdf.has_non_delta()
    }

    /// Albedo of the Lambertian part, which the ambient term multiplies.
    #[inline]
    pub fn diffuse_albedo(&self) -> Vec3 {
        self.bsdf.diffuse_albedo(self.wo)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn barycentrics_reproduce_points() {
        let t = [Vec3::new(0.0, 0.0, 0.0), Vec3::new(2.0, 0.0, 0.0), Vec3::new(0.0, 1.0, 1.0)];
        for b in [Vec3::new(0.2, 0.3, 0.5), Vec3::new(1.0, 0.0, 0.0), Vec3::new(0.0, 0.5, 0.5)] {
            let p = t[0] * b.x + t[1] * b.y + t[2] * b.z;
            assert!((barycentric(p, t) - b).abs().max_element() < 1e-6);
        }
        // Outside the triangle: clamped onto it.
        let b = barycentric(Vec3::new(3.0, 0.0, 0.0), t);
        assert!((b - Vec3::new(0.0, 1.0, 0.0)).abs().max_element() < 1e-6, "{b}");
        assert_eq!(barycentric(Vec3::ONE, [Vec3::ZERO; 3]), Vec3::X);
    }
}
