//! Shaders. `direct` (paper 000 §7: "direct illumination with ambient"): point lights with one
//! shadow ray, planar polygonal area lights with N stratified shadow rays (soft shadows), the
//! material's BSDF ([`crate::surface`]: shading normals, textures, sidedness), emission of
//! light fixtures seen from the front, and an ambient term times the diffuse albedo. Rough
//! lobes also sample the BSDF toward area lights (multiple importance sampling) and delta
//! lobes see area lights only that way ([`crate::bsdf_rays`]); point lights reach every
//! non-delta lobe. Transmission receives no direct light (a light behind a glass surface is
//! behind the object the surface belongs to).
//! Every blocked shadow ray reports a light–blocker–receiver triple (paper 000 §6.5 "Finding
//! light-blocker-receiver triples"): the renderer's edge finder learns from them which
//! shadows exist without testing every light–blocker pair.
use crate::bsdf_rays::{area_light_via_bsdf, light_pdf, power_heuristic};
use crate::bvh::Instances;
use crate::loaded::{LoadedScene, PreparedLight};
use crate::rng::Rng;
use crate::surface::ShadingPoint;
use glam::Vec3;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};

/// Names of the shaders this worker offers: every row of the shared table
/// ([`edgepoint_proto::shaders::SHADERS`]).
pub const SHADERS: &[&str] = &["direct"];

/// A parsed shader with its parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum ShaderSpec {
    Direct(DirectParams),
}

/// Parameters of the `direct` shader (ranges and defaults: the shared table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirectParams {
    /// Shadow rays per area light per sample (`shadow_rays`).
    pub shadow_rays: u32,
    /// Scale of the scene's ambient term (`ambient`).
    pub ambient: f32,
}

impl Default for DirectParams {
    fn default() -> Self {
        match ShaderSpec::parse("direct", &HashMap::new()) {
            Ok(ShaderSpec::Direct(p)) => p,
            Err(e) => unreachable!("the table's defaults are valid (tested): {e}"),
        }
    }
}

impl ShaderSpec {
    /// Parses a shader name ("" means `direct`) and its parameters against the shared
    /// table; unknown names, unknown keys and out-of-range values are errors that list what
    /// is valid.
    pub fn parse(name: &str, params: &HashMap<String, f64>) -> Result<ShaderSpec, String> {
        let p = edgepoint_proto::shaders::resolve(name, params)?;
        match edgepoint_proto::shaders::shader(name).map(|s| s.name) {
            Some("direct") => Ok(ShaderSpec::Direct(DirectParams { shadow_rays: p["shadow_rays"] as u32, ambient: p["ambient"] as f32 })),
            _ => Err(format!("shader '{name}' is in the table but not built into this worker (it offers: {})", SHADERS.join(", "))),
        }
    }
}

/// One ray to shade.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayRequest {
    pub id: u64,
    pub pixel: [u32; 2],
    pub origin: Vec3,
    /// Need not be normalised; must be finite and non-zero.
    pub direction: Vec3,
}

/// The first hit of a primary ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HitInfo {
    pub position: Vec3,
    /// The hit in the object's own coordinates.
    pub local_position: Vec3,
    /// The unit normal in the object's own coordinates, facing the incoming ray.
    pub local_normal: Vec3,
    /// Unit normal facing the incoming ray.
    pub normal: Vec3,
    pub object: u32,
    pub triangle: u32,
    /// Distance along the normalised ray direction.
    pub distance: f32,
}

/// One shaded sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleOut {
    pub id: u64,
    pub hit: Option<HitInfo>,
    /// Linear radiance.
    pub rgb: Vec3,
}

/// The result of shading a batch.
#[derive(Debug, Clone, Default)]
pub struct ShadeOutput {
    pub samples: Vec<SampleOut>,
    /// Distinct (light, blocker object, receiver object) triples found by blocked shadow rays.
    pub triples: Vec<[u32; 3]>,
    /// Distinct objects hit by the batch's primary rays.
    pub visible: Vec<u32>,
    /// Samples whose shading was not finite (replaced by black).
    pub nonfinite: u32,
}

/// Shades `requests` in parallel (rayon, on the current pool) with transforms `inst`.
/// Deterministic for a given `seed`: the random numbers of a request depend only on
/// (seed, request id).
pub fn shade_batch(scene: &LoadedScene, inst: &Instances, spec: &ShaderSpec, seed: u64, requests: &[RayRequest]) -> ShadeOutput {
    let ShaderSpec::Direct(params) = spec;
    let per: Vec<(SampleOut, Vec<[u32; 3]>, bool)> =
        requests.par_iter().map(|r| shade_direct(scene, inst, params, seed, r)).collect();
    merge(per)
}

/// One batch's output from its per-request results (sample, triples, non-finite flag):
/// triples and visible objects deduplicated and sorted.
pub(crate) fn merge(per: Vec<(SampleOut, Vec<[u32; 3]>, bool)>) -> ShadeOutput {
    let mut triples = HashSet::new();
    let mut visible = HashSet::new();
    let mut nonfinite = 0;
    let mut samples = Vec::with_capacity(per.len());
    for (s, t, bad) in per {
        triples.extend(t);
        if let Some(h) = &s.hit {
            visible.insert(h.object);
        }
        nonfinite += bad as u32;
        samples.push(s);
    }
    let mut triples: Vec<_> = triples.into_iter().collect();
    triples.sort_unstable();
    let mut visible: Vec<_> = visible.into_iter().collect();
    visible.sort_unstable();
    ShadeOutput { samples, triples, visible, nonfinite }
}

/// Seed offset of the BSDF samples' random stream: separate from the light samples' stream,
/// so the light samples (and the triples they find) do not depend on the material.
const BSDF_STREAM: u64 = 0x6273_6466_5f72_6179;

fn shade_direct(
    scene: &LoadedScene,
    inst: &Instances,
    p: &DirectParams,
    seed: u64,
    r: &RayRequest,
) -> (SampleOut, Vec<[u32; 3]>, bool) {
    let s = &scene.scene;
    let len = r.direction.length();
    let mut triples = Vec::new();
    if !(len.is_finite() && len > 0.0 && r.origin.is_finite()) {
        return (SampleOut { id: r.id, hit: None, rgb: Vec3::ZERO }, triples, true);
    }
    let d = r.direction / len;
    let Some(h) = inst.closest_hit(&scene.bvh, r.origin, d, 0.0, f32::INFINITY) else {
        return (SampleOut { id: r.id, hit: None, rgb: s.background }, triples, false);
    };
    let obj = &s.objects[h.object as usize];
    let mat = &obj.material;
    let front = h.normal.dot(d) < 0.0;
    let n = if front { h.normal } else { -h.normal };
    let mut rgb = Vec3::ZERO;
    if front {
        rgb += mat.emission;
    }
    let sp = ShadingPoint::new(mat, &obj.mesh, inst, &h, d, front);
    // Light samples reach the non-delta part; a pure mirror or smooth glass gets nothing from
    // them (its shadow rays are still cast: the triples describe geometry, not materials).
    let lit = sp.scatters && sp.bsdf_has_non_delta();
    let glossy = sp.is_glossy();
    let eps = scene.epsilon;
    let origin = h.position + n * eps;
    let mut rng = Rng::new(seed, r.id);
    for (li, light) in scene.lights.iter().enumerate() {
        let li = li as u32;
        match light {
            PreparedLight::Point { position, intensity, cone } => {
                let to = *position - origin;
                let d2 = to.length_squared();
                let dist = d2.sqrt();
                let wi = to / dist;
                let cos = n.dot(wi);
                // A spot light sends only its cone's share this way.
                let share = cone.map_or(1.0, |(axis, inner, outer)| edgepoint_scene::light::spot_falloff(axis, inner, outer, -wi));
                if cos <= 0.0 || share <= 0.0 {
                    continue;
                }
                let intensity = *intensity * share;
                match inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)) {
                    Some(b) => push_unique(&mut triples, [li, b, h.object]),
                    None if !lit => {}
                    None => match sp.constant {
                        Some(f) => rgb += f * intensity * (cos / d2),
                        None => rgb += sp.eval_cos(wi) * intensity / d2,
                    },
                }
            }
            PreparedLight::Area(a) => {
                // A point behind the emitting side, or a light wholly below the point's
                // tangent plane, receives nothing: no rays needed.
                if a.normal.dot(origin - a.centroid) <= 0.0 || a.vertices.iter().all(|v| n.dot(*v - origin) <= 0.0) {
                    continue;
                }
                let k = p.shadow_rays;
                let nx = (k as f32).sqrt().ceil() as u32;
                let ny = k.div_ceil(nx);
                let cells = nx * ny;
                let rot = (rng.next_u64() % cells as u64) as u32;
                // `sum`: unweighted radiance × geometry, for a BSDF constant over the
                // hemisphere (multiplied once below, as before materials); `weighted`: the
                // BSDF applied per sample, with the MIS weight for rough lobes.
                let (mut sum, mut weighted) = (Vec3::ZERO, Vec3::ZERO);
                for i in 0..k {
                    let c = (i + rot) % cells;
                    let u = ((c % nx) as f32 + rng.next_f32()) / nx as f32;
                    let v = ((c / nx) as f32 + rng.next_f32()) / ny as f32;
                    let q = a.sample(u, v);
                    let to = q - origin;
                    let d2 = to.length_squared();
                    let dist = d2.sqrt();
                    let wi = to / dist;
                    let cos_x = n.dot(wi);
                    let cos_l = -a.normal.dot(wi);
                    if cos_x <= 0.0 || cos_l <= 0.0 {
                        continue;
                    }
                    match inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)) {
                        Some(b) => push_unique(&mut triples, [li, b, h.object]),
                        None if !lit => {}
                        None if sp.constant.is_some() => sum += a.radiance * (cos_x * cos_l / d2),
                        None => {
                            let w = if glossy { power_heuristic(light_pdf(a, d2, cos_l), sp.pdf(wi)) } else { 1.0 };
                            weighted += sp.eval_cos(wi) * a.radiance * (w * cos_l / d2);
                        }
                    }
                }
                if let Some(f) = sp.constant {
                    rgb += f * sum * (a.area / k as f32);
                }
                rgb += weighted * (a.area / k as f32);
            }
        }
    }
    if sp.scatters {
        if sp.bsdf_has_delta() || glossy {
            let mut bsdf_rng = Rng::new(seed ^ BSDF_STREAM, r.id);
            rgb += area_light_via_bsdf(scene, inst, &sp, origin, n, p.shadow_rays, &mut bsdf_rng);
        }
        rgb += sp.diffuse_albedo() * s.ambient * p.ambient;
    }
    let bad = !rgb.is_finite();
    if bad {
        rgb = Vec3::ZERO;
    }
    let local_normal = if front { h.local_normal } else { -h.local_normal }.normalize_or_zero();
    let hit = HitInfo { position: h.position, local_position: h.local, local_normal, normal: n, object: h.object, triangle: h.triangle, distance: h.t };
    (SampleOut { id: r.id, hit: Some(hit), rgb }, triples, bad)
}

pub(crate) fn push_unique(v: &mut Vec<[u32; 3]>, t: [u32; 3]) {
    if !v.contains(&t) {
        v.push(t);
    }
}
