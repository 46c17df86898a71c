//! A scene ready to shade: the scene, its per-object BVHs and its lights prepared for
//! sampling. Built once per scene hash and shared by every stream that shades it.
use crate::bvh::{Instances, SceneBvh};
use crate::shader::irradiance_cache::IrradianceCache;
use crate::shader::vpl::VplCache;
use edgepoint_scene::backprojection::LightPlane;
use edgepoint_scene::{Light, Progress, Scene};
use glam::{Affine3A, Vec3};
use std::sync::Arc;
use std::time::Instant;

/// A polygonal area light prepared for uniform area sampling (fan triangles + their CDF).
#[derive(Debug, Clone)]
pub struct AreaLight {
    pub vertices: Vec<Vec3>,
    pub tris: Vec<[Vec3; 3]>,
    /// Cumulative area fraction per fan triangle (last = 1).
    pub cdf: Vec<f32>,
    pub area: f32,
    pub normal: Vec3,
    pub centroid: Vec3,
    pub radiance: Vec3,
    /// The light's plane and corners in f64 for exact visibility (`direct` `area=exact`);
    /// `None` only for a degenerate polygon, which validation refuses.
    pub plane: Option<LightPlane>,
}

impl AreaLight {
    /// The point of the polygon at (u, v) in [0,1)^2; uniform in area for uniform (u, v),
    /// and strata of the square map to compact strata of the polygon.
    #[inline]
    pub fn sample(&self, u: f32, v: f32) -> Vec3 {
        let i = self.cdf.iter().position(|&c| u < c).unwrap_or(self.cdf.len() - 1);
        let lo = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let uu = ((u - lo) / (self.cdf[i] - lo)).clamp(0.0, 1.0);
        let s = uu.sqrt();
        let [a, b, c] = self.tris[i];
        a * (1.0 - s) + b * (s * (1.0 - v)) + c * (s * v)
    }
}

#[derive(Debug, Clone)]
pub enum PreparedLight {
    /// A point light; a spot light is one with a `cone` (unit axis, cos inner, cos outer).
    Point { position: Vec3, intensity: Vec3, cone: Option<(Vec3, f32, f32)> },
    Area(AreaLight),
}

impl PreparedLight {
    pub fn new(l: &Light) -> PreparedLight {
        match l {
            Light::Point { position, intensity } => PreparedLight::Point { position: *position, intensity: *intensity, cone: None },
            Light::Spot { position, direction, intensity, cos_inner, cos_outer } => PreparedLight::Point {
                position: *position,
                intensity: *intensity,
                cone: Some((*direction, *cos_inner, *cos_outer)),
            },
            Light::Area { vertices, radiance } => {
                let tris: Vec<[Vec3; 3]> = (1..vertices.len() - 1).map(|i| [vertices[0], vertices[i], vertices[i + 1]]).collect();
                let areas: Vec<f32> = tris.iter().map(|t| (t[1] - t[0]).cross(t[2] - t[0]).length() * 0.5).collect();
                let area: f32 = areas.iter().sum();
                let mut acc = 0.0;
                let cdf = areas
                    .iter()
                    .map(|a| {
                        acc += a / area;
                        acc
                    })
                    .collect();
                PreparedLight::Area(AreaLight {
                    vertices: vertices.clone(),
                    tris,
                    cdf,
                    area,
                    normal: l.normal().unwrap_or(Vec3::Y),
                    centroid: l.center(),
                    radiance: *radiance,
                    plane: LightPlane::new(vertices),
                })
            }
        }
    }
}

/// A loaded scene on a worker.
pub struct LoadedScene {
    pub scene: Arc<Scene>,
    pub bvh: SceneBvh,
    pub hash: String,
    pub lights: Vec<PreparedLight>,
    /// Offset of secondary-ray origins along the normal, relative to the scene size.
    pub epsilon: f32,
    /// Milliseconds spent building the BVHs.
    pub build_ms: f64,
    /// The `gi` shader's irradiance records for this scene on this worker.
    pub irradiance: IrradianceCache,
    /// The `hybrid` shader's virtual point lights for this scene on this worker.
    pub vpls: VplCache,
}

impl LoadedScene {
    /// Builds the per-object BVHs (object space) and prepares the lights.
    pub fn build(scene: Scene, hash: String, progress: &dyn Progress) -> LoadedScene {
        let t = Instant::now();
        let meshes: Vec<_> = scene.objects.iter().map(|o| o.mesh.as_ref()).collect();
        let bvh = SceneBvh::build(&meshes, progress);
        let (lo, hi) = scene.bounds();
        let epsilon = ((hi - lo).length() * 1e-5).max(1e-6);
        let lights = scene.lights.iter().map(PreparedLight::new).collect();
        let irradiance = IrradianceCache::new((lo, hi));
        LoadedScene { scene: Arc::new(scene), bvh, hash, lights, epsilon, build_ms: t.elapsed().as_secs_f64() * 1e3, irradiance, vpls: VplCache::default() }
    }

    /// The top level for one epoch's object transforms (one per object).
    pub fn instances(&self, transforms: &[Affine3A]) -> Instances {
        Instances::new(&self.bvh, transforms)
    }

    /// The scene's default transforms (epoch 0).
    pub fn default_transforms(&self) -> Vec<Affine3A> {
        self.scene.objects.iter().map(|o| o.transform).collect()
    }
}
