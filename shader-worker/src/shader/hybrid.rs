//! `hybrid` (paper 004, Udeshi & Hansen 1999): the three effects of its interactive
//! renderer, done by ray tracing on the worker.
//!
//! - **Soft shadows** (§2, §4.1): every area light sampled with `shadow_rays` stratified
//!   shadow rays (the paper's "light samples", 9–25 per light), point lights with one.
//! - **One-bounce indirect light** (§3, §4.2): the `vpls` virtual point lights that reflect
//!   the most energy ([`super::vpl`], built once per scene, transforms and parameters), each
//!   with a shadow ray (the paper's OpenGL lights had no visibility, its Fig. 8).
//! - **Specular reflection and refraction** (§1.3, §4.3): a Whitted ray tree at every delta
//!   lobe (mirror, smooth glass, the smooth coat of plastic), both the reflected and the
//!   refracted ray of glass with their Fresnel weights, `max_depth` bounces deep; the
//!   surfaces it reaches are shaded like the camera's (lights, VPLs, deeper specular rays),
//!   and the area lights it meets are seen with their radiance. A branch whose throughput
//!   falls below [`BRANCH_CUTOFF`] is dropped (the light it could bring is below that
//!   fraction of what it would see); with the weights of a branch's children summing to at
//!   most its own, at most max_depth / cutoff branches live, and a glass sphere's tree is
//!   a few rays.
//!
//! Rough lobes (rough metal, rough glass, rough plastic coats) are lit by the lights (light
//! samples and as many BSDF samples, power heuristic, as `direct`) and by the VPLs; they
//! do not reflect the rest of the scene (the `glossy` and `gi` shaders trace that).
//! No ambient term: the VPLs are the indirect light.
//!
//! **Parts**, for split shading (paper 004 §4.4): [`shade_part`] shades only a [`Part`] —
//! lights and VPLs by index range at every vertex of the ray tree, and the rest (emission
//! seen by the camera, the background met by specular rays) in one part. Each light has a
//! random stream of its own per tree vertex (the first vertex's first light uses the
//! request's own stream, as `direct`'s does), the BSDF samples are the same in every part,
//! and the tree does not depend on the part, so the parts of a split add up to the whole
//! sample up to float summation order. Triples come from the first hit's light samples of
//! the part's lights.
use super::hit::{primary, Surface};
use super::lights::{add_direct_light_in, LightQuery};
use super::vpl::{add_vpl_light, vpl_range, Vpl, VplSet, VplSettings};
use super::{finish, RayRequest, SampleOut, Shaded};
use crate::bsdf_rays::{hit_area_light, light_pdf, power_heuristic};
use crate::bvh::Instances;
use crate::loaded::{LoadedScene, PreparedLight};
use crate::rng::Rng;
use crate::surface::ShadingPoint;
use edgepoint_scene::material::{Scatter, Scattering};
use glam::Vec3;
use std::ops::Range;

/// Parameters of the `hybrid` shader (ranges and defaults: the shared table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HybridParams {
    /// Light samples per area light at every diffusely shaded surface (`shadow_rays`).
    pub shadow_rays: u32,
    /// Virtual point lights K (`vpls`).
    pub vpls: u32,
    /// Target count of equal-area elements the VPLs are chosen from (`elements`).
    pub elements: u32,
    /// Specular bounces traced (`max_depth`).
    pub max_depth: u32,
    /// The K VPLs carry the flux of every candidate (`conserve`).
    pub conserve: bool,
}

impl HybridParams {
    /// What the VPL set depends on.
    pub fn vpl_settings(&self) -> VplSettings {
        VplSettings { count: self.vpls, elements: self.elements, conserve: self.conserve }
    }
}

/// A ray-tree branch carrying less throughput than this (largest channel) is dropped.
pub const BRANCH_CUTOFF: f32 = 1e-4;

/// Seed offsets of the per-vertex, per-light streams and of the BSDF samples.
const LIGHT_STREAM: u64 = 0x6879_6272_6964_5f6c;
const BSDF_STREAM: u64 = 0x6879_6272_6964_5f62;

/// A share of one sample's shading (module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Part {
    /// Lights shaded: those a split session's part owns (interleaved by index, as in the
    /// other shaders, so a part reports the triples of its own lights only).
    pub lights: edgepoint_proto::split::Part,
    /// VPLs shaded (indices into the set, brightest first).
    pub vpls: Range<usize>,
    /// Emission seen by the camera and background met by specular rays.
    pub rest: bool,
}

impl Part {
    /// Everything: the unsplit shader.
    pub fn whole() -> Part {
        Part { lights: edgepoint_proto::split::Part::WHOLE, vpls: 0..usize::MAX, rest: true }
    }
}

struct Ctx<'a> {
    scene: &'a LoadedScene,
    inst: &'a Instances,
    p: &'a HybridParams,
    vpls: &'a [Vpl],
    part: &'a Part,
    seed: u64,
    id: u64,
}

pub(crate) fn shade(scene: &LoadedScene, inst: &Instances, p: &HybridParams, set: &VplSet, seed: u64, r: &RayRequest) -> Shaded {
    shade_part(scene, inst, p, set, seed, r, &Part::whole())
}

/// One request's share `part` of the `hybrid` shading (module docs); [`Part::whole`] is
/// the whole sample.
pub fn shade_part(scene: &LoadedScene, inst: &Instances, p: &HybridParams, set: &VplSet, seed: u64, r: &RayRequest, part: &Part) -> (SampleOut, Vec<[u32; 3]>, bool) {
    let s = match primary(scene, inst, r, edgepoint_proto::split::Part::WHOLE) {
        Ok(s) => s,
        Err((sample, t, bad)) if !part.rest && !bad => return (SampleOut { rgb: Vec3::ZERO, ..sample }, t, bad),
        Err(done) => return done,
    };
    let ctx = Ctx { scene, inst, p, vpls: vpl_range(set, &part.vpls), part, seed, id: r.id };
    let mut triples = Vec::new();
    let mut rgb = if part.rest { s.emitted() } else { Vec3::ZERO };
    let mut vertex = 0u64;
    rgb += radiance(&ctx, &s, p.max_depth, Vec3::ONE, &mut vertex, Some(&mut triples));
    finish(r.id, Some(s.info()), rgb, triples)
}

/// The stream of light `li` at tree vertex `vertex`: the first vertex's first light uses
/// the request's own stream (so on a scene of one light and no VPLs the shader's direct
/// light is `direct`'s, bit for bit).
fn light_rng(ctx: &Ctx, vertex: u64, li: usize) -> Rng {
    let key = if vertex == 0 && li == 0 { 0 } else { Rng::new(LIGHT_STREAM ^ vertex, li as u64).next_u64() };
    Rng::new(ctx.seed ^ key, ctx.id)
}

/// Radiance leaving `s` toward the viewer (without its own emission) with `depth` specular
/// bounces left; `beta` the throughput from the camera to here, `vertex` the tree vertex
/// counter (depth-first order, the same in every part).
fn radiance(ctx: &Ctx, s: &Surface, depth: u32, beta: Vec3, vertex: &mut u64, mut triples: Option<&mut Vec<[u32; 3]>>) -> Vec3 {
    let (scene, inst) = (ctx.scene, ctx.inst);
    let v = *vertex;
    *vertex += 1;
    let mut l = Vec3::ZERO;
    // Lights, one at a time (each with its own stream).
    let lights = ctx.part.lights;
    let q = LightQuery { sp: &s.sp, receiver: s.h.object, origin: s.origin, n: s.n, k: ctx.p.shadow_rays, bsdf_per_light_sample: 1.0, exact: false, part: edgepoint_proto::split::Part::WHOLE };
    for li in (0..scene.lights.len()).filter(|&li| lights.owns(li)) {
        add_direct_light_in(scene, inst, &q, li..li + 1, &mut light_rng(ctx, v, li), triples.as_deref_mut(), &mut l);
    }
    let mut bsdf_rng = Rng::new(ctx.seed ^ BSDF_STREAM ^ v.wrapping_mul(0x9e37_79b9_7f4a_7c15), ctx.id);
    if s.sp.scatters && s.sp.is_glossy() {
        l += lights_via_bsdf(ctx, &s.sp, s.origin, s.n, lights, &mut bsdf_rng);
    }
    add_vpl_light(scene, inst, &s.sp, s.origin, s.n, ctx.vpls, &mut l);
    if depth == 0 || !s.sp.scatters || !s.sp.bsdf_has_delta() {
        return l;
    }
    for (wi, weight) in delta_branches(s) {
        let b = beta * weight;
        if !b.is_finite() || b.max_element() < BRANCH_CUTOFF {
            continue;
        }
        let origin = s.spawn(wi, scene.epsilon);
        let hit = inst.closest_hit(&scene.bvh, origin, wi, 0.0, f32::INFINITY);
        // An area light in front of the next surface is seen (a luminaire object lying
        // on it is met at the same distance, hence the allowance).
        if let Some((li, a, t)) = nearest_light(scene, origin, wi) {
            if lights.owns(li) && hit.is_none_or(|h| t <= h.t * (1.0 + 1e-3) + scene.epsilon) {
                l += weight * a.radiance;
            }
        }
        match hit {
            None if ctx.part.rest => l += weight * scene.scene.background,
            None => {}
            Some(h) => {
                let next = Surface::new(scene, inst, h, wi);
                l += weight * radiance(ctx, &next, depth - 1, b, vertex, None);
            }
        }
    }
    l
}

/// The delta lobes of `s` as (world direction, weight = coefficient × |cos|): a mirror's or
/// a smooth coat's reflection, glass's reflection and refraction (one of them under total
/// internal reflection).
fn delta_branches(s: &Surface) -> Vec<(Vec3, Vec3)> {
    let sp = &s.sp;
    let mut out: Vec<(Vec3, Vec3)> = Vec::with_capacity(2);
    // u.x = 0 picks every model's reflection lobe; just under 1 picks glass's refraction
    // (or its reflection again under total internal reflection, skipped as a repeat).
    let picks: &[f32] = if matches!(sp.bsdf, Scattering::Dielectric(_)) { &[0.0, 1.0 - f32::EPSILON] } else { &[0.0] };
    let mut sides = Vec::with_capacity(2);
    for &ux in picks {
        let Some(b) = sp.bsdf.sample(sp.wo, Vec3::new(ux, 0.5, 0.5)) else { continue };
        let reflects = b.wi.z * sp.wo.z > 0.0;
        if !b.delta || sides.contains(&reflects) {
            continue;
        }
        sides.push(reflects);
        let wi = sp.frame.to_world(b.wi);
        // The face must agree with the lobe's side (a shading normal can tilt a reflection
        // below the surface it leaves).
        if (wi.dot(s.n) > 0.0) != reflects {
            continue;
        }
        out.push((wi, b.value * b.wi.z.abs()));
    }
    out
}

/// The nearest area light's emitting side along a ray (occlusion not tested): (its index,
/// the light, distance).
fn nearest_light(scene: &LoadedScene, origin: Vec3, dir: Vec3) -> Option<(usize, &crate::loaded::AreaLight, f32)> {
    let mut best: Option<(usize, &crate::loaded::AreaLight, f32)> = None;
    for (li, l) in scene.lights.iter().enumerate() {
        if let PreparedLight::Area(a) = l {
            if let Some((t, _)) = hit_area_light(a, origin, dir) {
                if best.is_none_or(|b| t < b.2) {
                    best = Some((li, a, t));
                }
            }
        }
    }
    best
}

/// The BSDF-sampled half of a rough lobe's area-light estimate (as `direct`'s: as many
/// samples as light samples, power heuristic), counting only the lights `lights` owns.
fn lights_via_bsdf(ctx: &Ctx, sp: &ShadingPoint, origin: Vec3, n: Vec3, lights: edgepoint_proto::split::Part, rng: &mut Rng) -> Vec3 {
    let (scene, inst) = (ctx.scene, ctx.inst);
    let k = ctx.p.shadow_rays;
    let mut sum = Vec3::ZERO;
    for _ in 0..k {
        let u = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let Some(b) = sp.bsdf.sample(sp.wo, u) else { continue };
        let wi = sp.frame.to_world(b.wi);
        if b.delta || wi.dot(n) <= 0.0 {
            continue;
        }
        let Some((li, a, t)) = nearest_light(scene, origin, wi) else { continue };
        if !lights.owns(li) || inst.occluded(&scene.bvh, origin, wi, 0.0, t * (1.0 - 1e-4)).is_some() {
            continue;
        }
        let cos_l = -a.normal.dot(wi);
        let w = power_heuristic(b.pdf, light_pdf(a, t * t, cos_l));
        sum += b.weight() * a.radiance * w;
    }
    sum / k as f32
}
