//! The BSDF-sampled half of the direct shader's area-light estimate: directions drawn from
//! the material that hit an area light. Two uses:
//! - delta lobes (mirrors, smooth glass and plastic coats) can only see an area light this
//!   way: one ray in the mirror direction, weighted by the lobe's reflectance;
//! - rough lobes: as many BSDF samples as light samples, combined with them by the power
//!   heuristic (Veach 1997 §9.2), so a small bright light in a glossy surface does not come
//!   out as the light sampler's fireflies, nor a broad light in a sharp lobe as the BSDF
//!   sampler's.
//!
//! These rays report no light–blocker–receiver triples: the light samples already do, and
//! the edge finder's view of which shadows exist must not depend on the material.
use crate::bvh::Instances;
use crate::loaded::{AreaLight, LoadedScene, PreparedLight};
use crate::rng::Rng;
use crate::surface::ShadingPoint;
use edgepoint_proto::split::Part;
use edgepoint_scene::material::Scatter;
use glam::Vec3;

/// Power heuristic (β = 2) weight of a strategy with density `a` against one with `b`, equal
/// sample counts.
#[inline]
pub fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 && (a2 + b2).is_finite() {
        a2 / (a2 + b2)
    } else if a.is_infinite() {
        1.0
    } else {
        0.0
    }
}

/// Density per unit solid angle of uniform area sampling of `a`, seen from distance² `d2`
/// at cosine `cos_l` with the light's normal.
#[inline]
pub fn light_pdf(a: &AreaLight, d2: f32, cos_l: f32) -> f32 {
    d2 / (cos_l * a.area)
}

/// Where the ray `origin + t dir` meets the emitting side of area light `a`: (t, cos at the
/// light). Möller–Trumbore on the light's fan triangles.
pub(crate) fn hit_area_light(a: &AreaLight, origin: Vec3, dir: Vec3) -> Option<(f32, f32)> {
    let cos_l = -a.normal.dot(dir);
    if cos_l.is_nan() || cos_l <= 0.0 {
        return None;
    }
    for [p0, p1, p2] in &a.tris {
        let (e1, e2) = (*p1 - *p0, *p2 - *p0);
        let pv = dir.cross(e2);
        let det = e1.dot(pv);
        if det.abs() < 1e-12 {
            continue;
        }
        let inv = 1.0 / det;
        let tv = origin - *p0;
        let u = tv.dot(pv) * inv;
        if !(0.0..=1.0).contains(&u) {
            continue;
        }
        let qv = tv.cross(e1);
        let v = dir.dot(qv) * inv;
        if v < 0.0 || u + v > 1.0 {
            continue;
        }
        let t = e2.dot(qv) * inv;
        if t > 0.0 {
            return Some((t, cos_l));
        }
    }
    None
}

/// The closest area light along a ray, unoccluded, if `part` shades it: (light, its
/// radiance-carrying distance² and cosine). The shadow ray stops short of the light as the
/// light samples' do, so a luminaire object lying on the light does not block it; it is
/// cast only for the part that owns the light (split shading counts each light once).
fn visible_light<'a>(scene: &'a LoadedScene, inst: &Instances, origin: Vec3, dir: Vec3, part: Part) -> Option<(&'a AreaLight, f32, f32)> {
    let (i, a, t, cos_l) = nearest_area_light_index(scene, origin, dir)?;
    if !part.owns(i) {
        return None;
    }
    if inst.occluded(&scene.bvh, origin, dir, 0.0, t * (1.0 - 1e-4)).is_some() {
        return None;
    }
    Some((a, t * t, cos_l))
}

/// The nearest area light's emitting side along a ray, occlusion not tested: (light,
/// distance, cosine at the light).
pub(crate) fn nearest_area_light(scene: &LoadedScene, origin: Vec3, dir: Vec3) -> Option<(&AreaLight, f32, f32)> {
    nearest_area_light_index(scene, origin, dir).map(|(_, a, t, c)| (a, t, c))
}

/// [`nearest_area_light`] with the light's index in the scene's light list.
fn nearest_area_light_index(scene: &LoadedScene, origin: Vec3, dir: Vec3) -> Option<(usize, &AreaLight, f32, f32)> {
    let mut best: Option<(usize, &AreaLight, f32, f32)> = None;
    for (i, l) in scene.lights.iter().enumerate() {
        if let PreparedLight::Area(a) = l {
            if let Some((t, cos_l)) = hit_area_light(a, origin, dir) {
                if best.is_none_or(|b| t < b.2) {
                    best = Some((i, a, t, cos_l));
                }
            }
        }
    }
    best
}

/// Radiance reaching the viewer from area lights through BSDF-sampled directions.
/// `n`: the face normal on the viewer's side (rays below it would enter the surface);
/// `samples`: the light samples per area light (as many BSDF samples are drawn for rough
/// lobes, for the power heuristic's equal counts); `part`: only the lights it owns count
/// (every part draws the same directions, so the parts' sum is the whole estimate).
#[allow(clippy::too_many_arguments)]
pub fn area_light_via_bsdf(scene: &LoadedScene, inst: &Instances, sp: &ShadingPoint, origin: Vec3, n: Vec3, samples: u32, part: Part, rng: &mut Rng) -> Vec3 {
    let mut rgb = Vec3::ZERO;
    if sp.bsdf.has_delta() {
        // u.x = 0 picks every model's reflection lobe; its expected contribution is
        // value · |cos| (the weight times the probability of picking it).
        if let Some(s) = sp.bsdf.sample(sp.wo, Vec3::new(0.0, 0.5, 0.5)) {
            let wi = sp.frame.to_world(s.wi);
            if s.delta && wi.dot(n) > 0.0 {
                if let Some((a, _, _)) = visible_light(scene, inst, origin, wi, part) {
                    rgb += s.value * s.wi.z.abs() * a.radiance;
                }
            }
        }
    }
    if sp.is_glossy() {
        let mut sum = Vec3::ZERO;
        for _ in 0..samples {
            let u = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let Some(s) = sp.bsdf.sample(sp.wo, u) else { continue };
            let wi = sp.frame.to_world(s.wi);
            if s.delta || wi.dot(n) <= 0.0 {
                continue;
            }
            if let Some((a, d2, cos_l)) = visible_light(scene, inst, origin, wi, part) {
                let w = power_heuristic(s.pdf, light_pdf(a, d2, cos_l));
                sum += s.weight() * a.radiance * w;
            }
        }
        rgb += sum / samples as f32;
    }
    rgb
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heuristic_weights_sum_to_one_and_handle_extremes() {
        for (a, b) in [(1.0f32, 2.0f32), (0.3, 0.3), (5.0, 0.01)] {
            assert!((power_heuristic(a, b) + power_heuristic(b, a) - 1.0).abs() < 1e-6);
        }
        assert_eq!(power_heuristic(0.0, 0.0), 0.0);
        assert_eq!(power_heuristic(f32::INFINITY, 1.0), 1.0);
        assert_eq!(power_heuristic(1.0, f32::INFINITY), 0.0);
    }

    #[test]
    fn rays_find_the_emitting_side_of_a_light() {
        let light = crate::loaded::PreparedLight::new(&edgepoint_scene::Light::Area {
            vertices: vec![Vec3::new(-1.0, 2.0, -1.0), Vec3::new(1.0, 2.0, -1.0), Vec3::new(1.0, 2.0, 1.0), Vec3::new(-1.0, 2.0, 1.0)],
            radiance: Vec3::ONE,
        });
        let crate::loaded::PreparedLight::Area(a) = light else { unreachable!() };
        assert!(a.normal.y < 0.0);
        let (t, cos) = hit_area_light(&a, Vec3::ZERO, Vec3::new(0.5, 2.0, 0.0).normalize()).unwrap();
        assert!((t - Vec3::new(0.5, 2.0, 0.0).length()).abs() < 1e-5 && (cos - 2.0 / 4.25f32.sqrt()).abs() < 1e-5);
        assert!(hit_area_light(&a, Vec3::ZERO, Vec3::new(2.0, 2.0, 0.0).normalize()).is_none(), "misses the square");
        assert!(hit_area_light(&a, Vec3::new(0.0, 3.0, 0.0), -Vec3::Y).is_none(), "the back does not emit");
    }
}
