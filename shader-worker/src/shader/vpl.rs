//! Virtual point lights for the `hybrid` shader's one-bounce indirect light (paper 004 §3
//! and §4.2), computed once per (scene, object transforms, parameters) on each worker.
//!
//! The paper renders an item buffer from each light's centroid and weights every polygon
//! element by its form factor from the differential light × its reflectivity × the
//! light's emission, then places light sources at the centroids of the `8p` elements of
//! highest weight. A ray tracer can do the same integral with visibility directly: for
//! each equal-area element ([`super::elements`]) and each side it reflects on, the
//! irradiance E from every light is estimated from [`ELEMENT_SAMPLES`] shadow rays (points
//! uniform on the element, stratified on an area light), and the element reflects the flux
//! Φ = ρ E A. The K candidates of largest Φ (luminance) become VPLs; the paper's weight is
//! the same quantity for a differential light (F·ρ·emission ∝ Φ), here for whole lights.
//!
//! A VPL is a Lambertian emitter of radiant intensity I = Φ/π along its normal, placed at
//! the mean of the element's sample points weighted by the light they received (the
//! centroid of its lit part: an element half under a box sends its light from the lit
//! half). It lights a point x (unlike the paper's OpenGL lights, with a shadow ray) with
//! f(x) cos θx · I cos θv / (r² + A/π). **Clamping:** the 1/r² of a point light would be
//! unbounded next to the element; r² + A/π is the on-axis form factor of a disk of the
//! element's area A, bounded by π/A. Against the unclamped term it removes the fraction
//! (A/π)/(r² + A/π) of a VPL's light: 1 % at ten element radii, 50 % at one; against the
//! exact disk it is exact on the axis and close elsewhere. So the bias is a darkening
//! within a few element radii of each VPL (inside corners), shrinking with smaller elements.
//! Keeping only K of the candidates drops the indirect light of all others: the set
//! reports the share of the candidates' flux it keeps ([`VplSet::kept_flux`]). With
//! `conserve` (the default) the kept VPLs are scaled by one factor so that together they
//! reflect the flux of every candidate — the paper sets its lights' intensities
//! "proportional to the assigned weight" — which keeps the image's indirect energy but
//! moves it toward the brightest elements (less colour bleeding from dimmer walls than
//! a full one bounce would have); without it each VPL carries its own element's flux,
//! exact one bounce (up to discretisation and clamping) once K covers every candidate.
//!
//! **Cache:** a worker keeps the sets of the last [`KEPT_SETS`] (transforms, settings)
//! keys per scene. A batch whose object transforms differ from every kept set's (an object
//! moved) builds a new set from scratch — elements re-tessellated under the new transforms,
//! fluxes re-estimated with visibility, re-ranked. The build is deterministic (fixed seeds,
//! no dependence on thread order), so every worker shading a scene under the same
//! transforms has the same VPLs, and split shading by VPL ranges adds up. It runs on
//! scoped threads of its own, not on the rayon pool: a rayon thread waiting for a build
//! could otherwise steal a batch that waits for the same build.
use super::elements::{tessellate, Element};
use crate::bvh::Instances;
use crate::loaded::{LoadedScene, PreparedLight};
use crate::rng::Rng;
use crate::surface::ShadingPoint;
use glam::{Affine3A, Vec3};
use std::f32::consts::FRAC_1_PI;
use std::ops::Range;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// Shadow rays per element and light for its received flux.
pub const ELEMENT_SAMPLES: u32 = 16;
/// VPL sets kept per scene on a worker (the newest ones).
pub const KEPT_SETS: usize = 4;
/// Seed of the elements' sample points (fixed: see the module docs).
const FLUX_SEED: u64 = 0x7670_6c5f_666c_7578;

/// What a VPL set depends on besides the scene and the transforms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VplSettings {
    /// K: VPLs kept.
    pub count: u32,
    /// Target number of elements.
    pub elements: u32,
    /// Scale the kept VPLs to the flux of every candidate.
    pub conserve: bool,
}

/// One virtual point light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vpl {
    /// On its element, lifted off the surface along `normal`.
    pub position: Vec3,
    /// Unit normal of the side it reflects on.
    pub normal: Vec3,
    /// Radiant intensity along the normal, Φ/π.
    pub intensity: Vec3,
    /// A/π of its element: the clamp of the 1/r² term.
    pub clamp_r2: f32,
    pub object: u32,
}

/// The VPLs of one (scene, transforms, settings), brightest first.
#[derive(Debug, Clone, Default)]
pub struct VplSet {
    pub vpls: Vec<Vpl>,
    pub elements: usize,
    /// Element sides that received light.
    pub candidates: usize,
    /// Reflected flux of every candidate and of the kept ones (per channel).
    pub total_flux: Vec3,
    pub kept_flux: Vec3,
    pub build_ms: f64,
}

#[inline]
fn luminance(v: Vec3) -> f32 {
    v.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// A side of an element that received light: its flux and where it came from.
struct Candidate {
    element: usize,
    /// +1: the normal's side, −1: the other.
    side: f32,
    flux: Vec3,
    position: Vec3,
}

/// Irradiance estimates of both sides of element `e` (index `ei`): (E, Σ weight × point,
/// Σ weight) per side.
fn receive(scene: &LoadedScene, inst: &Instances, e: &Element, ei: usize) -> [(Vec3, Vec3, f32); 2] {
    let mut out = [(Vec3::ZERO, Vec3::ZERO, 0.0f32); 2];
    let mut rng = Rng::new(FLUX_SEED, ei as u64);
    let k = ELEMENT_SAMPLES;
    let nx = (k as f32).sqrt().ceil() as u32;
    let ny = k.div_ceil(nx);
    for i in 0..k {
        let x = e.point(rng.next_f32(), rng.next_f32());
        for light in &scene.lights {
            // Each light: one direction, its arriving irradiance contribution (already /k).
            let (to, contrib) = match light {
                PreparedLight::Point { position, intensity, cone } => {
                    let to = *position - x;
                    let d2 = to.length_squared();
                    let wi = to / d2.sqrt();
                    let share = cone.map_or(1.0, |(axis, inner, outer)| edgepoint_scene::light::spot_falloff(axis, inner, outer, -wi));
                    if share <= 0.0 {
                        continue;
                    }
                    (to, *intensity * (share / (d2 * k as f32)))
                }
                PreparedLight::Area(a) => {
                    let u = ((i % nx) as f32 + rng.next_f32()) / nx as f32;
                    let v = ((i / nx) as f32 + rng.next_f32()) / ny as f32;
                    let to = a.sample(u, v) - x;
                    let d2 = to.length_squared();
                    let cos_l = -a.normal.dot(to) / d2.sqrt();
                    if cos_l.is_nan() || cos_l <= 0.0 {
                        continue;
                    }
                    (to, a.radiance * (cos_l * a.area / (d2 * k as f32)))
                }
            };
            let dist = to.length();
            let wi = to / dist;
            let cos_n = e.normal.dot(wi);
            let side = if cos_n > 0.0 { 0 } else { 1 };
            if cos_n.is_nan() || cos_n == 0.0 || (side == 1 && !e.two_sided) {
                continue;
            }
            let n = if side == 0 { e.normal } else { -e.normal };
            let origin = x + n * scene.epsilon;
            if inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)).is_some() {
                continue;
            }
            let got = contrib * cos_n.abs();
            if got.is_finite() {
                let w = luminance(got);
                let o = &mut out[side];
                o.0 += got;
                o.1 += x * w;
                o.2 += w;
            }
        }
    }
    out
}

/// Builds the VPL set of `scene` under `inst`'s transforms (module docs).
pub fn build(scene: &LoadedScene, inst: &Instances, settings: VplSettings) -> VplSet {
    let t0 = Instant::now();
    if settings.count == 0 {
        return VplSet::default();
    }
    let elements = tessellate(&scene.scene, inst.transforms(), settings.elements);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, 16);
    let chunk = elements.len().div_ceil(threads).max(1);
    let mut candidates: Vec<Candidate> = Vec::new();
    std::thread::scope(|sc| {
        let handles: Vec<_> = elements
            .chunks(chunk)
            .enumerate()
            .map(|(c, els)| {
                sc.spawn(move || {
                    let mut found = Vec::new();
                    for (j, e) in els.iter().enumerate() {
                        let ei = c * chunk + j;
                        for (s, (irr, wp, w)) in receive(scene, inst, e, ei).into_iter().enumerate() {
                            let flux = e.albedo * irr * e.area;
                            if luminance(flux) > 0.0 {
                                let position = if w > 0.0 { wp / w } else { e.centroid() };
                                found.push(Candidate { element: ei, side: if s == 0 { 1.0 } else { -1.0 }, flux, position });
                            }
                        }
                    }
                    found
                })
            })
            .collect();
        for h in handles {
            match h.join() {
                Ok(f) => candidates.extend(f),
                Err(p) => std::panic::resume_unwind(p),
            }
        }
    });
    let total_flux: Vec3 = candidates.iter().map(|c| c.flux).sum();
    let n_candidates = candidates.len();
    // Brightest first; ties by element and side so the order never depends on the threads.
    let key = |c: &Candidate| (-luminance(c.flux), c.element, -c.side as i32);
    let by = |a: &Candidate, b: &Candidate| key(a).partial_cmp(&key(b)).unwrap_or(std::cmp::Ordering::Equal);
    let k = (settings.count as usize).min(candidates.len());
    if k > 0 && k < candidates.len() {
        candidates.select_nth_unstable_by(k - 1, by);
    }
    candidates.truncate(k);
    candidates.sort_unstable_by(by);
    let kept_flux: Vec3 = candidates.iter().map(|c| c.flux).sum();
    // Conserving: one scale for all (luminance ratio: no colour shift), so the K VPLs
    // reflect what every lit element does.
    let scale = if settings.conserve && luminance(kept_flux) > 0.0 { luminance(total_flux) / luminance(kept_flux) } else { 1.0 };
    let vpls: Vec<Vpl> = candidates
        .iter()
        .map(|c| {
            let e = &elements[c.element];
            let normal = e.normal * c.side;
            Vpl { position: c.position + normal * scene.epsilon, normal, intensity: c.flux * (scale * FRAC_1_PI), clamp_r2: e.area * FRAC_1_PI, object: e.object }
        })
        .collect();
    VplSet { vpls, elements: elements.len(), candidates: n_candidates, total_flux, kept_flux, build_ms: t0.elapsed().as_secs_f64() * 1e3 }
}

/// Adds the light of `vpls` at a shading point: `origin` the point lifted off its surface,
/// `n` its face normal on the viewer's side. Nothing for a surface without a non-delta lobe.
pub(crate) fn add_vpl_light(scene: &LoadedScene, inst: &Instances, sp: &ShadingPoint, origin: Vec3, n: Vec3, vpls: &[Vpl], rgb: &mut Vec3) {
    if !(sp.scatters && sp.bsdf_has_non_delta()) {
        return;
    }
    let mut sum = Vec3::ZERO;
    for v in vpls {
        let to = v.position - origin;
        let d2 = to.length_squared();
        let dist = d2.sqrt();
        let wi = to / dist;
        let cos_x = n.dot(wi);
        let cos_v = -v.normal.dot(wi);
        if !(cos_x > 0.0 && cos_v > 0.0) {
            continue;
        }
        if inst.occluded(&scene.bvh, origin, wi, 0.0, dist * (1.0 - 1e-4)).is_some() {
            continue;
        }
        let g = cos_v / (d2 + v.clamp_r2);
        sum += match sp.constant {
            Some(f) => f * v.intensity * (cos_x * g),
            None => sp.eval_cos(wi) * v.intensity * g,
        };
    }
    *rgb += sum;
}

/// The VPLs with index in `range`, clipped to the set.
pub fn vpl_range<'a>(set: &'a VplSet, range: &Range<usize>) -> &'a [Vpl] {
    let end = range.end.min(set.vpls.len());
    &set.vpls[range.start.min(end)..end]
}

type Key = (Vec<Affine3A>, VplSettings);
/// A set, built once by whichever batch asks first.
type Cell = Arc<OnceLock<Arc<VplSet>>>;

/// A scene's VPL sets on a worker (module docs).
#[derive(Default)]
pub struct VplCache {
    sets: Mutex<Vec<(Key, Cell)>>,
    builds: std::sync::atomic::AtomicU64,
}

impl VplCache {
    /// The set for `inst`'s transforms and `settings`, built on first use.
    pub fn get(&self, scene: &LoadedScene, inst: &Instances, settings: VplSettings) -> Arc<VplSet> {
        let cell = {
            let mut sets = self.sets.lock().unwrap_or_else(|p| p.into_inner());
            match sets.iter().position(|(k, _)| k.1 == settings && k.0.as_slice() == inst.transforms()) {
                Some(i) => {
                    let entry = sets.remove(i);
                    let cell = entry.1.clone();
                    sets.push(entry);
                    cell
                }
                None => {
                    let cell = Arc::new(OnceLock::new());
                    sets.push(((inst.transforms().to_vec(), settings), cell.clone()));
                    while sets.len() > KEPT_SETS {
                        sets.remove(0);
                    }
                    cell
                }
            }
        };
        cell.get_or_init(|| {
            self.builds.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let set = build(scene, inst, settings);
            tracing::info!(
                scene = %scene.hash,
                elements = set.elements,
                candidates = set.candidates,
                vpls = set.vpls.len(),
                kept_flux_share = luminance(set.kept_flux) / luminance(set.total_flux).max(f32::MIN_POSITIVE),
                ms = set.build_ms,
                "hybrid: virtual point lights built"
            );
            Arc::new(set)
        })
        .clone()
    }

    /// Sets built so far.
    pub fn builds(&self) -> u64 {
        self.builds.load(std::sync::atomic::Ordering::Relaxed)
    }
}
