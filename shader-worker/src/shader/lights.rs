//! Light sampling at one shading point (next-event estimation), shared by every shader:
//! point and spot lights with one shadow ray, planar polygonal area lights with `k`
//! stratified shadow rays (soft shadows). Rough lobes weight the light samples by the power
//! heuristic against the BSDF samples the caller draws toward the same lights
//! ([`crate::bsdf_rays`] in `direct` and `glossy`, the path's next ray in `gi`); a Lambertian
//! surface takes the light samples alone; delta lobes get nothing here.
//! Every blocked shadow ray reports a light–blocker–receiver triple when the caller collects
//! them (first hits only: the edge finder's receivers are what the camera sees).
use super::push_unique;
use edgepoint_proto::split::Part;
use crate::bsdf_rays::{light_pdf, power_heuristic};
use crate::bvh::Instances;
use crate::loaded::{LoadedScene, PreparedLight};
use crate::rng::Rng;
use crate::surface::ShadingPoint;
use glam::Vec3;
use std::ops::Range;

/// One shading point's light-sampling job.
pub(crate) struct LightQuery<'a> {
    pub sp: &'a ShadingPoint,
    /// The object shaded (the receiver of triples).
    pub receiver: u32,
    /// Shadow rays leave from here (the hit lifted off the surface).
    pub origin: Vec3,
    /// Unit face normal on the viewer's side.
    pub n: Vec3,
    /// Shadow rays per area light.
    pub k: u32,
    /// BSDF samples the caller draws toward the lights per light sample: 1 when it draws
    /// as many as `k` (the `direct` shader), 1/k for a path's single next ray.
    pub bsdf_per_light_sample: f32,
    /// Area lights on Lambertian surfaces exactly ([`super::exact_area`]) instead of by `k`
    /// rays (`direct` `area=exact`); other lobes still sample them.
    pub exact: bool,
    /// Which lights to sample (split shading): the others are passed over, their random
    /// numbers skipped, so every part draws what the whole shading would have drawn.
    pub part: Part,
}

/// Adds the sampled direct light at `q` to `rgb` (in the order the `direct` shader always
/// summed it, so its output is unchanged to the bit), recording triples if `triples` is given.
pub(crate) fn add_direct_light(scene: &LoadedScene, inst: &Instances, q: &LightQuery, rng: &mut Rng, triples: Option<&mut Vec<[u32; 3]>>, rgb: &mut Vec3) {
    add_direct_light_in(scene, inst, q, 0..scene.lights.len(), rng, triples, rgb);
}

/// [`add_direct_light`] for the lights whose index lies in `lights` only: a share of the
/// shading (the `hybrid` shader samples one light at a time with its own random stream, so
/// any subset of lights can be shaded apart and summed).
pub(crate) fn add_direct_light_in(scene: &LoadedScene, inst: &Instances, q: &LightQuery, lights: Range<usize>, rng: &mut Rng, mut triples: Option<&mut Vec<[u32; 3]>>, rgb: &mut Vec3) {
    let sp = q.sp;
    let (n, origin) = (q.n, q.origin);
    // Light samples reach the non-delta part; a pure mirror or smooth glass gets nothing from
    // them (its shadow rays are still cast: the triples describe geometry, not materials).
    let lit = sp.scatters && sp.bsdf_has_non_delta();
    let glossy = sp.is_glossy();
    let mut blocked = |b: u32, li: u32| {
        if let Some(t) = triples.as_deref_mut() {
            push_unique(t, [li, b, q.receiver]);
        }
    };
    for (li, light) in scene.lights.iter().enumerate().take(lights.end).skip(lights.start) {
        let owned = q.part.owns(li);
        let li = li as u32;
        match light {
            PreparedLight::Point { .. } if !owned => {}
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
                    Some(b) => blocked(b, li),
                    None if !lit => {}
                    None => match sp.constant {
                        Some(f) => *rgb += f * intensity * (cos / d2),
                        None => *rgb += sp.eval_cos(wi) * intensity / d2,
                    },
                }
            }
            PreparedLight::Area(a) => {
                // A point behind the emitting side, or a light wholly below the point's
                // tangent plane, receives nothing: no rays needed.
                if a.normal.dot(origin - a.centroid) <= 0.0 || a.vertices.iter().all(|v| n.dot(*v - origin) <= 0.0) {
                    continue;
                }
                let k = q.k;
                // Exact visibility needs a BSDF constant over the hemisphere (irradiance
                // times albedo/π); it draws no random numbers.
                let exact = q.exact && sp.constant.is_some();
                if !owned {
                    // Another part samples this light: one rotation and two numbers a ray.
                    if !exact {
                        rng.skip(1 + 2 * k as u64);
                    }
                    continue;
                }
                if exact {
                    let e = super::exact_area::irradiance(scene, inst, a, origin, n, |b| blocked(b, li));
                    if let (true, Some(f)) = (lit, sp.constant) {
                        *rgb += f * a.radiance * e;
                    }
                    continue;
                }
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
                    let p = a.sample(u, v);
                    let to = p - origin;
                    let d2 = to.length_squared();
                    let dist = d2.sqrt();
                    let wi = to / dist;
                    let cos_x = n.dot(wi);
                    let cos_l = -a.normal.dot(wi);
                    if cos_x <= 0.0 || cos_l <= 0.0 {
                        continue;
                    }
                    match inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)) {
                        Some(b) => blocked(b, li),
                        None if !lit => {}
                        None if sp.constant.is_some() => sum += a.radiance * (cos_x * cos_l / d2),
                        None => {
                            let w = if glossy { power_heuristic(light_pdf(a, d2, cos_l), sp.pdf(wi) * q.bsdf_per_light_sample) } else { 1.0 };
                            weighted += sp.eval_cos(wi) * a.radiance * (w * cos_l / d2);
                        }
                    }
                }
                if let Some(f) = sp.constant {
                    *rgb += f * sum * (a.area / k as f32);
                }
                *rgb += weighted * (a.area / k as f32);
            }
        }
    }
}
