//! Shaders, one module each behind one interface: a [`ShaderSpec`] parsed from the shared
//! table ([`edgepoint_proto::shaders`]) and [`shade_batch`], which shades a batch of primary
//! rays in parallel and reports, besides the samples, the light–blocker–receiver triples of
//! the first hits' shadow rays (paper 000 §6.5) and how many non-finite results it replaced.
//!
//! - [`direct`]: direct light with ambient (paper 000 §7's first shader);
//! - [`glossy`]: `direct` plus glossy and mirror reflection by BSDF sampling;
//! - [`gi`]: path tracing with next-event estimation and MIS, Russian roulette, and the
//!   per-worker [`irradiance_cache`] for the diffuse indirect term;
//! - [`hybrid`]: paper 004's soft shadows, one-bounce indirect light from virtual point
//!   lights ([`vpl`] over equal-area [`elements`]) and ray-traced specular reflection and
//!   refraction.
//!
//! Shared pieces: [`hit::Surface`] (a hit made ready to shade), the light-sampling estimator
//! ([`lights`]) and the NaN / infinity filter in [`finish`], so no shader can let a
//! non-finite value leave the worker.
//!
//! Split shading (paper 004 §4.4): a request can carry a [`Part`] of its pixel's shading;
//! each shader samples only the part's lights ([`Part::owns`]) and leaves the terms of no
//! light (emission, ambient, indirect and reflected light) to part 0, skipping the random
//! numbers of what it does not shade ([`shade_batch_parts`]).
pub mod direct;
pub mod elements;
mod exact_area;
pub mod gi;
pub mod glossy;
pub mod hybrid;
pub mod irradiance_cache;
pub mod vpl;
mod hit;
mod lights;

pub use direct::DirectParams;
pub use gi::GiParams;
pub use glossy::GlossyParams;
pub use hybrid::HybridParams;

use crate::bvh::Instances;
use crate::loaded::LoadedScene;
pub use edgepoint_proto::split::Part;
use glam::Vec3;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};

/// Names of the shaders this worker offers: every row of the shared table
/// ([`edgepoint_proto::shaders::SHADERS`]).
pub const SHADERS: &[&str] = &["direct", "glossy", "gi", "hybrid"];

/// A parsed shader with its parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum ShaderSpec {
    Direct(DirectParams),
    Glossy(GlossyParams),
    Gi(GiParams),
    Hybrid(HybridParams),
}

impl ShaderSpec {
    /// Parses a shader name ("" means `direct`) and its parameters against the shared
    /// table; unknown names, unknown keys and out-of-range values are errors that list what
    /// is valid.
    pub fn parse(name: &str, params: &HashMap<String, f64>) -> Result<ShaderSpec, String> {
        let p = edgepoint_proto::shaders::resolve(name, params)?;
        let whole = |k: &str| p[k] as u32;
        // `glossy` shares `direct`'s light sampling but not its `area` parameter.
        let direct = || DirectParams { shadow_rays: whole("shadow_rays"), ambient: p["ambient"] as f32, exact_area: p.get("area") == Some(&1.0) };
        match edgepoint_proto::shaders::shader(name).map(|s| s.name) {
            Some("direct") => Ok(ShaderSpec::Direct(direct())),
            Some("glossy") => Ok(ShaderSpec::Glossy(GlossyParams { direct: direct(), rays: whole("rays"), max_depth: whole("max_depth") })),
            Some("gi") => Ok(ShaderSpec::Gi(GiParams {
                shadow_rays: whole("shadow_rays"),
                max_depth: whole("max_depth"),
                cache: whole("cache") == 1,
                cache_error: p["cache_error"] as f32,
                cache_rays: whole("cache_rays"),
                cache_max_rays: whole("cache_max_rays"),
            })),
            Some("hybrid") => Ok(ShaderSpec::Hybrid(HybridParams {
                shadow_rays: whole("shadow_rays"),
                vpls: whole("vpls"),
                elements: whole("elements"),
                max_depth: whole("max_depth"),
                conserve: whole("conserve") == 1,
            })),
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

/// One request's result: the sample, the triples its first hit's shadow rays found, and
/// whether its radiance had to be replaced because it was not finite.
pub(crate) type Shaded = (SampleOut, Vec<[u32; 3]>, bool);

/// Shades `requests` in parallel (rayon, on the current pool) with transforms `inst`.
/// Deterministic for a given `seed` (the random numbers of a request depend only on
/// (seed, request id)), except `gi` with its irradiance cache on: which records exist
/// depends on the order threads create them. `hybrid` first builds its virtual point
/// lights if this scene, transforms and parameters have none yet.
pub fn shade_batch(scene: &LoadedScene, inst: &Instances, spec: &ShaderSpec, seed: u64, requests: &[RayRequest]) -> ShadeOutput {
    shade_batch_parts(scene, inst, spec, seed, requests, &[])
}

/// [`shade_batch`] of split shading (paper 004 §4.4): request `i` shades only `parts[i]` of
/// its pixel's shading (`parts` empty: every request whole; else one part per request).
/// Every part of a request, shaded with the same seed, draws the random numbers the whole
/// shading would draw, so the parts' radiance adds up to the whole shading's up to float
/// summation order, and the parts' triples to its triples.
pub fn shade_batch_parts(scene: &LoadedScene, inst: &Instances, spec: &ShaderSpec, seed: u64, requests: &[RayRequest], parts: &[Part]) -> ShadeOutput {
    assert!(parts.is_empty() || parts.len() == requests.len(), "one part per request (or none)");
    let part = |i: usize| parts.get(i).copied().unwrap_or(Part::WHOLE);
    let per: Vec<Shaded> = match spec {
        ShaderSpec::Direct(p) => requests.par_iter().enumerate().map(|(i, r)| direct::shade(scene, inst, p, seed, r, part(i))).collect(),
        ShaderSpec::Glossy(p) => requests.par_iter().enumerate().map(|(i, r)| glossy::shade(scene, inst, p, seed, r, part(i))).collect(),
        ShaderSpec::Gi(p) => {
            let cache = p.cache.then(|| scene.irradiance.sync(&scene.scene, inst.transforms(), p.cache_settings()));
            requests.par_iter().enumerate().map(|(i, r)| gi::shade(scene, inst, p, cache, seed, r, part(i))).collect()
        }
        ShaderSpec::Hybrid(p) => {
            let vpls = scene.vpls.get(scene, inst, p.vpl_settings());
            // A split part of `hybrid` shades its lights (interleaved, as in the other
            // shaders) and a contiguous share of the virtual point lights, brightest first
            // (each light and VPL has its own random stream, so any share adds up).
            let share = |part: Part| hybrid::Part { lights: part, vpls: part.range(vpls.vpls.len()), rest: part.shades_unsplit_terms() };
            requests
                .par_iter()
                .enumerate()
                .map(|(i, r)| {
                    let part = part(i);
                    if part.is_whole() {
                        hybrid::shade(scene, inst, p, &vpls, seed, r)
                    } else {
                        hybrid::shade_part(scene, inst, p, &vpls, seed, r, &share(part))
                    }
                })
                .collect()
        }
    };
    merge(per)
}

/// One batch's output from its per-request results (sample, triples, non-finite flag):
/// triples and visible objects deduplicated and sorted.
pub(crate) fn merge(per: Vec<Shaded>) -> ShadeOutput {
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

/// The sample of a request with radiance `rgb`: a non-finite `rgb` becomes black and is
/// flagged (counted in the batch and the worker's metrics), so none leaves the worker.
pub(crate) fn finish(id: u64, hit: Option<HitInfo>, rgb: Vec3, triples: Vec<[u32; 3]>) -> Shaded {
    let bad = !rgb.is_finite();
    let rgb = if bad { Vec3::ZERO } else { rgb };
    (SampleOut { id, hit, rgb }, triples, bad)
}

pub(crate) fn push_unique(v: &mut Vec<[u32; 3]>, t: [u32; 3]) {
    if !v.contains(&t) {
        v.push(t);
    }
}
