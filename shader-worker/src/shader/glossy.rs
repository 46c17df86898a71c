//! `glossy` (paper 000 §7: "direct with glossy reflections"): at every surface what `direct`
//! computes (sampled direct light, area lights through the BSDF, ambient), plus the
//! radiance the non-diffuse part of the BSDF reflects (or, for glass, transmits) from the
//! rest of the scene, estimated by sampling that part: K rays at the first hit, one at each
//! deeper hit, followed up to `max_depth` bounces. The non-diffuse part is the whole BSDF of
//! a conductor or a dielectric, the coat of a plastic (its base is what the ambient term
//! stands for) and nothing of a Lambertian surface. What the rays bring back leaves out the
//! light fixtures' own emission: the BSDF samples toward the area lights at the surface
//! already count it, weighted against the light samples. Split shading: the first hit's
//! lights are split as `direct`'s; the reflected scene is part 0's.
use super::direct::{add_lit, DirectParams, BSDF_STREAM};
use super::hit::{primary, Surface};
use super::{finish, RayRequest, Shaded};
use crate::bvh::Instances;
use crate::loaded::LoadedScene;
use crate::rng::Rng;
use edgepoint_scene::material::{Plastic, Scatter, Scattering};
use edgepoint_proto::split::Part;
use glam::Vec3;

/// Parameters of the `glossy` shader (ranges and defaults: the shared table).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlossyParams {
    /// `shadow_rays` and `ambient`, as `direct`'s.
    pub direct: DirectParams,
    /// Reflection rays K at the first hit (`rays`).
    pub rays: u32,
    /// Reflection bounces followed (`max_depth`).
    pub max_depth: u32,
}

/// Seed offset of the reflection rays' random stream.
const REFLECT_STREAM: u64 = 0x676c_6f73_7379_5f72;

/// The random streams of one request: light samples, BSDF samples toward lights, reflections.
struct Streams {
    light: Rng,
    bsdf: Rng,
    reflect: Rng,
}

pub(crate) fn shade(scene: &LoadedScene, inst: &Instances, p: &GlossyParams, seed: u64, r: &RayRequest, part: Part) -> Shaded {
    let s = match primary(scene, inst, r, part) {
        Ok(s) => s,
        Err(done) => return done,
    };
    let mut triples = Vec::new();
    let mut rgb = if part.shades_unsplit_terms() { s.emitted() } else { Vec3::ZERO };
    let mut rng = Streams { light: Rng::new(seed, r.id), bsdf: Rng::new(seed ^ BSDF_STREAM, r.id), reflect: Rng::new(seed ^ REFLECT_STREAM, r.id) };
    add_lit(scene, inst, &s, &p.direct, part, &mut rng.light, &mut rng.bsdf, Some(&mut triples), &mut rgb);
    // The reflected scene belongs to no single light: part 0 follows it (with every light at
    // the surfaces it meets), from the same random states the whole shading reaches here.
    if part.shades_unsplit_terms() {
        rgb += reflected(scene, inst, p, &s, p.rays, p.max_depth, &mut rng);
    }
    finish(r.id, Some(s.info()), rgb, triples)
}

/// The non-diffuse part of a BSDF (module docs), or `None` for a Lambertian surface.
pub fn specular_part(b: &Scattering) -> Option<Scattering> {
    match b {
        Scattering::Lambert(_) => None,
        // A plastic of albedo 0 is its coat alone (its sampler then always picks the coat).
        Scattering::Plastic(pl) => Some(Scattering::Plastic(Plastic::new(pl.eta, pl.ggx.map_or(0.0, |g| g.alpha), Vec3::ZERO))),
        other => Some(*other),
    }
}

/// Radiance the non-diffuse part of `s`'s BSDF brings from the scene with `k` samples and
/// `depth` bounces left.
fn reflected(scene: &LoadedScene, inst: &Instances, p: &GlossyParams, s: &Surface, k: u32, depth: u32, rng: &mut Streams) -> Vec3 {
    if depth == 0 || !s.sp.scatters {
        return Vec3::ZERO;
    }
    let Some(spec) = specular_part(&s.sp.bsdf) else { return Vec3::ZERO };
    let mut sum = Vec3::ZERO;
    for _ in 0..k {
        let u = Vec3::new(rng.reflect.next_f32(), rng.reflect.next_f32(), rng.reflect.next_f32());
        let Some(b) = spec.sample(s.sp.wo, u) else { continue };
        let wi = s.sp.frame.to_world(b.wi);
        // The sampled side must agree with the face: a shading normal can tilt a sample
        // through the surface it leaves.
        if (wi.dot(s.n) > 0.0) != (b.wi.z * s.sp.wo.z > 0.0) {
            continue;
        }
        let weight = b.weight();
        let origin = s.spawn(wi, scene.epsilon);
        let l = match inst.closest_hit(&scene.bvh, origin, wi, 0.0, f32::INFINITY) {
            None => scene.scene.background,
            Some(h) => {
                let next = Surface::new(scene, inst, h, wi);
                let mut l = Vec3::ZERO;
                add_lit(scene, inst, &next, &p.direct, Part::WHOLE, &mut rng.light, &mut rng.bsdf, None, &mut l);
                l + reflected(scene, inst, p, &next, 1, depth - 1, rng)
            }
        };
        sum += weight * l;
    }
    sum / k as f32
}
