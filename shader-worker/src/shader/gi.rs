//! `gi` (paper 000 §7: "direct with global illumination"): a path tracer. At every vertex,
//! next-event estimation samples every light ([`super::lights`]: `shadow_rays` per area
//! light at the first hit, one deeper); the path goes on by sampling the BSDF, and the area
//! lights that next ray meets count with the power heuristic against the light samples
//! (Veach 1997 §9.2, with the sample counts), or fully after a delta lobe; a Lambertian
//! vertex takes its light samples alone (its next ray does not count lights). Escaped rays
//! bring the background. Russian roulette from the fourth vertex (survival probability the
//! path throughput's largest channel, at most 0.95); `max_depth` vertices at most.
//!
//! With `cache` on, a Lambertian first hit takes its diffuse indirect term, albedo/π × E,
//! from the worker's [`super::irradiance_cache`]: E interpolated from records, or gathered
//! into a new record from `cache_rays` hemisphere paths when no record is valid there; a
//! record that has served a quarter as many lookups as it holds rays gathers `cache_rays` more (the
//! lookup that finds it so pays for them), up to `cache_max_rays`, so a still view's
//! records lose their noise as its samples accumulate.
//! Only first hits use the cache (the paper's shader caches what the camera sees; deeper
//! vertices are path-traced).
//!
//! Split shading: a part samples its own lights at the first hit; the rest of the path
//! (and the irradiance cache) is part 0's.
use super::hit::{primary, Surface};
use super::irradiance_cache::{gather, CacheSettings, Gathered, Ticket};
use super::lights::{add_direct_light, LightQuery};
use super::{finish, RayRequest, Shaded};
use crate::bsdf_rays::{light_pdf, nearest_area_light, power_heuristic};
use crate::bvh::Instances;
use crate::loaded::LoadedScene;
use crate::rng::Rng;
use edgepoint_scene::material::{Frame, Scatter, Scattering};
use edgepoint_proto::split::Part;
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// Parameters of the `gi` shader (ranges and defaults: the shared table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GiParams {
    /// Light samples per area light at the first hit (`shadow_rays`).
    pub shadow_rays: u32,
    /// Path vertices shaded at most (`max_depth`).
    pub max_depth: u32,
    /// Irradiance cache on (`cache`).
    pub cache: bool,
    /// Ward's accuracy a (`cache_error`).
    pub cache_error: f32,
    /// Hemisphere rays per record (`cache_rays`).
    pub cache_rays: u32,
    /// Rays a record grows to by refinement (`cache_max_rays`).
    pub cache_max_rays: u32,
}

impl GiParams {
    /// What the cache's records depend on.
    pub fn cache_settings(&self) -> CacheSettings {
        CacheSettings { error: self.cache_error, rays: self.cache_rays, max_depth: self.max_depth, max_rays: self.cache_max_rays }
    }
}

/// Seed offset of the path's random stream (BSDF samples, roulette, hemisphere rays); the
/// light samples use the request's own stream, as `direct`'s do.
const PATH_STREAM: u64 = 0x7061_7468_5f67_6921;

/// What a path needs besides its own state.
struct Ctx<'a> {
    scene: &'a LoadedScene,
    inst: &'a Instances,
    p: &'a GiParams,
}

pub(crate) fn shade(scene: &LoadedScene, inst: &Instances, p: &GiParams, cache: Option<Ticket>, seed: u64, r: &RayRequest, part: Part) -> Shaded {
    let s = match primary(scene, inst, r, part) {
        Ok(s) => s,
        Err(done) => return done,
    };
    let ctx = Ctx { scene, inst, p };
    let mut triples = Vec::new();
    let mut light_rng = Rng::new(seed, r.id);
    let mut path_rng = Rng::new(seed ^ PATH_STREAM, r.id);
    let info = s.info();
    let mut rgb = if part.shades_unsplit_terms() { s.emitted() } else { Vec3::ZERO };
    rgb += scattered(&ctx, s, 0, part, cache, Some(&mut triples), &mut light_rng, &mut path_rng);
    finish(r.id, Some(info), rgb, triples)
}

/// Radiance scattered toward the viewer at `s`, vertex `depth` of a path (the camera's hit
/// is vertex 0), without `s`'s own emission. `cache` and `triples` apply to vertex 0 only,
/// and so does `part`: a split sample's part samples its own lights at vertex 0 and part 0
/// alone goes on along the path (with every light at the deeper vertices).
#[allow(clippy::too_many_arguments)]
fn scattered<'a>(ctx: &Ctx<'a>, mut s: Surface<'a>, mut depth: u32, part: Part, cache: Option<Ticket>, mut triples: Option<&mut Vec<[u32; 3]>>, light_rng: &mut Rng, rng: &mut Rng) -> Vec3 {
    let (scene, inst, p) = (ctx.scene, ctx.inst, ctx.p);
    let mut l = Vec3::ZERO;
    let mut beta = Vec3::ONE;
    loop {
        let k = if depth == 0 { p.shadow_rays } else { 1 };
        let mut direct = Vec3::ZERO;
        let vertex_part = if depth == 0 { part } else { Part::WHOLE };
        let q = LightQuery { sp: &s.sp, receiver: s.h.object, origin: s.origin, n: s.n, k, bsdf_per_light_sample: 1.0 / k as f32, exact: false, part: vertex_part };
        add_direct_light(scene, inst, &q, light_rng, triples.take(), &mut direct);
        l += beta * direct;
        if !s.sp.scatters || !vertex_part.shades_unsplit_terms() {
            break;
        }
        if let (0, Some(ticket), Scattering::Lambert(lam)) = (depth, cache, &s.sp.bsdf) {
            if p.max_depth > 1 {
                l += beta * lam.albedo * FRAC_1_PI * cached_irradiance(ctx, &s, &ticket, rng);
                break;
            }
        }
        let u = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
        let Some(b) = s.sp.bsdf.sample(s.sp.wo, u) else { break };
        let wi = s.sp.frame.to_world(b.wi);
        if (wi.dot(s.n) > 0.0) != (b.wi.z * s.sp.wo.z > 0.0) {
            break;
        }
        beta *= b.weight();
        if !(beta.is_finite() && beta.max_element() > 0.0) {
            break;
        }
        let origin = s.spawn(wi, scene.epsilon);
        let hit = inst.closest_hit(&scene.bvh, origin, wi, 0.0, f32::INFINITY);
        // The BSDF half of the light estimate (a Lambertian vertex took its light samples
        // with full weight). A light lying on a luminaire object is met at the object's
        // distance, so the comparison allows for rounding.
        if b.delta || s.sp.is_glossy() {
            if let Some((a, t, cos_l)) = nearest_area_light(scene, origin, wi) {
                if hit.is_none_or(|h| t <= h.t * (1.0 + 1e-3) + scene.epsilon) {
                    let w = if b.delta { 1.0 } else { power_heuristic(b.pdf, k as f32 * light_pdf(a, t * t, cos_l)) };
                    l += beta * a.radiance * w;
                }
            }
        }
        let Some(h) = hit else {
            l += beta * scene.scene.background;
            break;
        };
        depth += 1;
        if depth >= p.max_depth {
            break;
        }
        if depth >= 3 {
            let survive = beta.max_element().min(0.95);
            if rng.next_f32() >= survive {
                break;
            }
            beta /= survive;
        }
        s = Surface::new(scene, inst, h, wi);
    }
    l
}

/// Radiance arriving along a hemisphere ray of an irradiance record, without the lights'
/// own emission (next-event estimation at the record's point counts that), and the
/// distance to what it hit.
fn indirect_along(ctx: &Ctx, origin: Vec3, dir: Vec3, light_rng: &mut Rng, rng: &mut Rng) -> (Vec3, f32) {
    match ctx.inst.closest_hit(&ctx.scene.bvh, origin, dir, 0.0, f32::INFINITY) {
        None => (ctx.scene.scene.background, f32::INFINITY),
        Some(h) => {
            let t = h.t;
            let s = Surface::new(ctx.scene, ctx.inst, h, dir);
            (scattered(ctx, s, 1, Part::WHOLE, None, None, light_rng, rng), t)
        }
    }
}

/// Irradiance of the diffuse indirect term at a Lambertian first hit: from the cache, or
/// gathered into a new record. A lookup that asks for its best record's refinement
/// (`irradiance_cache`: once a record has served a quarter as many lookups as it holds rays) pays for
/// it: one more gather of `cache_rays` rays at that record, merged into it.
fn cached_irradiance(ctx: &Ctx, s: &Surface, ticket: &Ticket, rng: &mut Rng) -> Vec3 {
    let cache = &ctx.scene.irradiance;
    let n = s.sp.frame.n;
    if let Some((e, refine)) = cache.lookup_counted(ticket, s.h.position, n) {
        if let Some(req) = refine {
            // The rays start where the record's own did: its point lifted along the face.
            let origin = req.p + req.ng * ctx.scene.epsilon;
            let g = gather_at(ctx, &Frame::from_normal(req.n), origin, req.ng, rng);
            cache.refine(ticket, &req, &g);
        }
        return e;
    }
    let g = gather_at(ctx, &s.sp.frame, s.origin, s.n, rng);
    cache.insert(ticket, s.h.position, n, s.h.object, &g, s.n);
    g.e
}

/// `cache_rays` hemisphere paths around `frame.n` from `origin` (`ng`: the face's normal).
fn gather_at(ctx: &Ctx, frame: &Frame, origin: Vec3, ng: Vec3, rng: &mut Rng) -> Gathered {
    let mut light_rng = Rng::new(rng.next_u64(), 0);
    let mut path_rng = Rng::new(rng.next_u64(), 1);
    gather(frame, ctx.p.cache_rays, rng, |dir| {
        if dir.dot(ng) <= 0.0 {
            // Below the face (a tilted shading normal): nothing arrives through the surface.
            return (Vec3::ZERO, f32::INFINITY);
        }
        indirect_along(ctx, origin, dir, &mut light_rng, &mut path_rng)
    })
}
