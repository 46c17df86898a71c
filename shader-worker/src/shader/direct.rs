//! `direct` (paper 000 §7: "direct illumination with ambient"): point lights with one
//! shadow ray, planar polygonal area lights with N stratified shadow rays (soft shadows) or,
//! with `area=exact`, on Lambertian surfaces by their exact visible part ([`super::exact_area`]), the
//! material's BSDF ([`crate::surface`]: shading normals, textures, sidedness), emission of
//! light fixtures seen from the front, and an ambient term times the diffuse albedo. Rough
//! lobes also sample the BSDF toward area lights (multiple importance sampling) and delta
//! lobes see area lights only that way ([`crate::bsdf_rays`]); point lights reach every
//! non-delta lobe. Transmission receives no direct light (a light behind a glass surface is
//! behind the object the surface belongs to). Split shading: a part samples its own lights
//! ([`Part::owns`]); emission and ambient belong to part 0.
use super::hit::{primary, Surface};
use super::lights::{add_direct_light, LightQuery};
use super::{finish, RayRequest, Shaded};
use crate::bsdf_rays::area_light_via_bsdf;
use crate::bvh::Instances;
use crate::loaded::LoadedScene;
use crate::rng::Rng;
use edgepoint_proto::split::Part;
use glam::Vec3;
use std::collections::HashMap;

/// Parameters of the `direct` shader (ranges and defaults: the shared table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectParams {
    /// Shadow rays per area light per sample (`shadow_rays`).
    pub shadow_rays: u32,
    /// Scale of the scene's ambient term (`ambient`).
    pub ambient: f32,
    /// Area lights on Lambertian surfaces by their exact visible part and Lambert's formula
    /// (`area=exact`, [`super::exact_area`]) instead of `shadow_rays` rays.
    pub exact_area: bool,
}

impl Default for DirectParams {
    fn default() -> Self {
        match super::ShaderSpec::parse("direct", &HashMap::new()) {
            Ok(super::ShaderSpec::Direct(p)) => p,
            other => unreachable!("the table's defaults are valid (tested): {other:?}"),
        }
    }
}

/// Seed offset of the BSDF samples' random stream: separate from the light samples' stream,
/// so the light samples (and the triples they find) do not depend on the material.
pub(crate) const BSDF_STREAM: u64 = 0x6273_6466_5f72_6179;

pub(crate) fn shade(scene: &LoadedScene, inst: &Instances, p: &DirectParams, seed: u64, r: &RayRequest, part: Part) -> Shaded {
    let s = match primary(scene, inst, r, part) {
        Ok(s) => s,
        Err(done) => return done,
    };
    let mut triples = Vec::new();
    let mut rgb = if part.shades_unsplit_terms() { s.emitted() } else { Vec3::ZERO };
    let mut rng = Rng::new(seed, r.id);
    let mut bsdf_rng = Rng::new(seed ^ BSDF_STREAM, r.id);
    add_lit(scene, inst, &s, p, part, &mut rng, &mut bsdf_rng, Some(&mut triples), &mut rgb);
    finish(r.id, Some(s.info()), rgb, triples)
}

/// What `direct` adds at a surface: sampled direct light, area lights through the BSDF
/// (delta and rough lobes), and the ambient term; of a split sample, `part`'s lights (and
/// the ambient term in part 0). `glossy` adds the same at every bounce.
#[allow(clippy::too_many_arguments)]
pub(crate) fn add_lit(scene: &LoadedScene, inst: &Instances, s: &Surface, p: &DirectParams, part: Part, rng: &mut Rng, bsdf_rng: &mut Rng, triples: Option<&mut Vec<[u32; 3]>>, rgb: &mut Vec3) {
    let q = LightQuery { sp: &s.sp, receiver: s.h.object, origin: s.origin, n: s.n, k: p.shadow_rays, bsdf_per_light_sample: 1.0, exact: p.exact_area, part };
    add_direct_light(scene, inst, &q, rng, triples, rgb);
    if s.sp.scatters {
        if s.sp.bsdf_has_delta() || s.sp.is_glossy() {
            *rgb += area_light_via_bsdf(scene, inst, &s.sp, s.origin, s.n, p.shadow_rays, part, bsdf_rng);
        }
        if part.shades_unsplit_terms() {
            *rgb += s.sp.diffuse_albedo() * scene.scene.ambient * p.ambient;
        }
    }
}
