//! The `direct` shader as it was before materials (commit e30fa8d: Lambertian BRDF of the
//! base colour, face normals, every surface two-sided), kept verbatim for two jobs: the
//! oracle the Lambertian path is tested against bit for bit (`lambert_oracle` tests), and
//! the speed baseline of `edgepoint-bench materials`. Not used for shading.
use crate::bvh::Instances;
use crate::loaded::{LoadedScene, PreparedLight};
use crate::rng::Rng;
use crate::shader::{merge, push_unique, DirectParams, HitInfo, RayRequest, SampleOut, ShadeOutput};
use glam::Vec3;
use rayon::prelude::*;
use std::f32::consts::FRAC_1_PI;

/// [`crate::shade_batch`] with the pre-materials `direct` shader.
pub fn shade_batch_before_materials(scene: &LoadedScene, inst: &Instances, params: &DirectParams, seed: u64, requests: &[RayRequest]) -> ShadeOutput {
    merge(requests.par_iter().map(|r| shade_direct_before_materials(scene, inst, params, seed, r)).collect())
}

pub(crate) fn shade_direct_before_materials(
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
    let albedo = mat.diffuse;
    let eps = scene.epsilon;
    let origin = h.position + n * eps;
    let mut rng = Rng::new(seed, r.id);
    for (li, light) in scene.lights.iter().enumerate() {
        let li = li as u32;
        match light {
            // No spot cones: this shader predates them, and no built-in scene has one.
            PreparedLight::Point { position, intensity, .. } => {
                let to = *position - origin;
                let d2 = to.length_squared();
                let dist = d2.sqrt();
                let wi = to / dist;
                let cos = n.dot(wi);
                if cos <= 0.0 {
                    continue;
                }
                match inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)) {
                    Some(b) => push_unique(&mut triples, [li, b, h.object]),
                    None => rgb += albedo * FRAC_1_PI * *intensity * (cos / d2),
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
                let mut sum = Vec3::ZERO;
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
                        None => sum += a.radiance * (cos_x * cos_l / d2),
                    }
                }
                rgb += albedo * FRAC_1_PI * sum * (a.area / k as f32);
            }
        }
    }
    rgb += albedo * s.ambient * p.ambient;
    let bad = !rgb.is_finite();
    if bad {
        rgb = Vec3::ZERO;
    }
    let local_normal = if front { h.local_normal } else { -h.local_normal }.normalize_or_zero();
    let hit = HitInfo { position: h.position, local_position: h.local, local_normal, normal: n, object: h.object, triangle: h.triangle, distance: h.t };
    (SampleOut { id: r.id, hit: Some(hit), rgb }, triples, bad)
}
