//! In-process scenes and shading for the `epi` and `quality` benchmarks: the worker's shader
//! called directly (no cluster, no network), a fixed set of jittered pixels shaded once, a
//! Render Cache holding exactly those samples, and the converged reference (cached on disk
//! with the `frame` benchmark's key, so either benchmark can reuse the other's).
use crate::reference_cache::RefCache;
use anyhow::{Context, Result};
use edgepoint_proto as pb;
use edgepoint_scene::camera::CameraFrame;
use edgepoint_scene::NoProgress;
use edgepoint_server::reference::{subpixel_position, LogProgress, ReferenceOptions};
use edgepoint_server::render_cache::{CacheConfig, RenderCache, Sample};
use edgepoint_server::rng::mix64;
use edgepoint_server::session::TripleKey;
use edgepoint_server::stage_times::StageTimes;
use edgepoint_scene::Progress;
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, ShaderSpec};
use glam::Vec3;
use std::collections::HashMap;
use edgepoint_viewer::headless::FileFormat;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A scene loaded for in-process shading.
pub struct Staged {
    /// The name it was given by (built-in name or path).
    pub name: String,
    pub source: pb::SceneSource,
    pub loaded: LoadedScene,
    pub shader: String,
    pub params: HashMap<String, f64>,
    pub spec: ShaderSpec,
}

impl Staged {
    /// Loads a built-in scene or a .ply / .obj file (staged on a floor under a point light
    /// when it brings no lights) and builds its BVH.
    pub fn load(arg: &str, shader: &str, params: &HashMap<String, f64>) -> Result<Staged> {
        let source = edgepoint_viewer::scene_source_from_arg(arg)?;
        let scene = pb::scene_from_source(&source, &NoProgress).map_err(|e| anyhow::anyhow!("{e}"))?;
        let spec = ShaderSpec::parse(shader, params).map_err(|e| anyhow::anyhow!("{e}"))?;
        let hash = pb::scene_hash(&source);
        let loaded = LoadedScene::build(scene, hash, &LogProgress::new(&format!("BVH of {arg}")));
        Ok(Staged { name: arg.to_string(), source, loaded, shader: shader.to_string(), params: params.clone(), spec })
    }

    pub fn camera(&self, width: u32, height: u32) -> CameraFrame {
        self.loaded.scene.camera.frame(width, height)
    }

    /// Shades the continuous image positions `picks` (pixel, position) with the scene's
    /// default transforms; returns the samples as the renderer caches them.
    pub fn shade(&self, cam: &CameraFrame, picks: &[Pick], seed: u64) -> Vec<Sample> {
        self.shade_with_triples(cam, picks, seed).0
    }

    /// [`Self::shade`], with the light–blocker–receiver triples the shading found (as the
    /// workers report them to a session: the input of its shadow edges).
    pub fn shade_with_triples(&self, cam: &CameraFrame, picks: &[Pick], seed: u64) -> (Vec<Sample>, Vec<TripleKey>) {
        let inst = self.loaded.instances(&self.loaded.default_transforms());
        let mut triples = std::collections::BTreeSet::new();
        let mut out = Vec::with_capacity(picks.len());
        for (c, chunk) in picks.chunks(1 << 16).enumerate() {
            let requests: Vec<RayRequest> = chunk
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let (origin, direction) = cam.ray(p.sx, p.sy);
                    RayRequest { id: (c << 16 | i) as u64, pixel: [p.x, p.y], origin, direction }
                })
                .collect();
            let shaded = shade_batch(&self.loaded, &inst, &self.spec, mix64(seed ^ c as u64), &requests);
            triples.extend(shaded.triples.iter().map(|&[light, blocker, receiver]| TripleKey { light, blocker, receiver }));
            for (s, r) in shaded.samples.iter().zip(&requests) {
                out.push(match s.hit {
                    Some(h) => Sample { hit: true, position: h.position, normal: Vec3::ZERO, color: s.rgb, object: h.object, epoch: 0, pixel: r.pixel },
                    None => Sample { hit: false, position: r.direction, normal: Vec3::ZERO, color: s.rgb, object: u32::MAX, epoch: 0, pixel: r.pixel },
                });
            }
        }
        (out, triples.into_iter().collect())
    }

    /// The converged reference at `spp` samples per pixel: from the cache in `dir` when an
    /// earlier run (of this or the `frame` benchmark) stored it, else rendered in-process.
    pub fn reference(&self, width: u32, height: u32, spp: u32, dir: Option<&Path>) -> Result<(Vec<Vec3>, bool)> {
        let cache = RefCache::at(dir);
        let camera = &self.loaded.scene.camera;
        let key = RefCache::key(&pb::scene_hash(&self.source), camera, width, height, spp, &self.shader, &self.params);
        if let Some(img) = cache.load(&key, width, height, spp) {
            return Ok((img.pixels, true));
        }
        let cam = self.camera(width, height);
        let seed = ReferenceOptions::default().seed;
        let inst = self.loaded.instances(&self.loaded.default_transforms());
        let total = width as u64 * height as u64;
        let progress = LogProgress::new(&format!("reference of {} at {spp} spp", self.name));
        progress.begin(&format!("reference {width}x{height} {spp} spp"), total);
        let t0 = Instant::now();
        let mut pixels = Vec::with_capacity(total as usize);
        const ROWS: u32 = 8;
        for y0 in (0..height).step_by(ROWS as usize) {
            let requests: Vec<RayRequest> = (y0..(y0 + ROWS).min(height))
                .flat_map(|y| (0..width).map(move |x| (x, y)))
                .flat_map(|(x, y)| (0..spp).map(move |s| (x, y, s)))
                .map(|(x, y, s)| {
                    let (sx, sy) = subpixel_position(x, y, s, spp, seed);
                    let (origin, direction) = cam.ray(sx, sy);
                    RayRequest { id: ((y as u64 * width as u64 + x as u64) * spp as u64) + s as u64, pixel: [x, y], origin, direction }
                })
                .collect();
            let shaded = shade_batch(&self.loaded, &inst, &self.spec, mix64(seed ^ y0 as u64), &requests);
            for px in shaded.samples.chunks(spp as usize) {
                let sum: Vec3 = px.iter().map(|s| if s.rgb.is_finite() { s.rgb } else { Vec3::ZERO }).sum();
                pixels.push(sum / spp as f32);
            }
            progress.advance((ROWS.min(height - y0) * width) as u64);
        }
        progress.end();
        tracing::info!("reference of {} rendered in {:.1} s", self.name, t0.elapsed().as_secs_f64());
        let img = edgepoint_server::reference::ReferenceImage {
            width,
            height,
            spp,
            pixels,
            elapsed: t0.elapsed(),
            rays: total * spp as u64,
            nonfinite: 0,
        };
        cache.store(&key, &img).context("storing the reference")?;
        Ok((img.pixels, false))
    }
}

impl Staged {
    /// Pixels within `radius` pixels of a hard shadow boundary: where the visibility of some
    /// point light from the surface seen through the pixel centre changes between
    /// neighbouring pixels (ray cast in-process). `None` when the scene has no point light.
    /// Used to tell how much of an image's error lies at shadow boundaries, which the EPI
    /// cannot respect before shadow edges exist.
    pub fn shadow_boundaries(&self, cam: &CameraFrame, radius: usize) -> Option<Vec<bool>> {
        let lights: Vec<Vec3> = self
            .loaded
            .scene
            .lights
            .iter()
            .filter_map(|l| match l {
                edgepoint_scene::Light::Point { position, .. } => Some(*position),
                _ => None,
            })
            .take(32)
            .collect();
        if lights.is_empty() {
            return None;
        }
        let (w, h) = (cam.width as usize, cam.height as usize);
        let inst = self.loaded.instances(&self.loaded.default_transforms());
        let eps = self.loaded.epsilon;
        use rayon::prelude::*;
        // Per pixel: bit l set when point light l is visible; u64::MAX for a miss.
        let vis: Vec<u64> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (o, d) = cam.ray((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
                let Some(hit) = inst.closest_hit(&self.loaded.bvh, o, d, 0.0, f32::INFINITY) else { return u64::MAX };
                let n = if hit.normal.dot(d) < 0.0 { hit.normal } else { -hit.normal };
                let origin = hit.position + n * eps;
                lights.iter().enumerate().fold(0u64, |acc, (l, &pos)| {
                    let to = pos - origin;
                    let dist = to.length();
                    let seen = n.dot(to) > 0.0 && inst.occluded(&self.loaded.bvh, origin, to / dist, 0.0, dist * (1.0 - 1e-4)).is_none();
                    acc | (u64::from(seen) << l)
                })
            })
            .collect();
        let r = radius as i64;
        Some(
            (0..w * h)
                .into_par_iter()
                .map(|i| {
                    let (x, y) = ((i % w) as i64, (i / w) as i64);
                    let here = vis[i];
                    (-r..=r).any(|dy| {
                        (-r..=r).any(|dx| {
                            let (nx, ny) = (x + dx, y + dy);
                            if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                                return false;
                            }
                            let other = vis[ny as usize * w + nx as usize];
                            here != u64::MAX && other != u64::MAX && other != here
                        })
                    })
                })
                .collect(),
        )
    }
}

/// One pixel to shade and the position inside it.
#[derive(Debug, Clone, Copy)]
pub struct Pick {
    pub x: u32,
    pub y: u32,
    pub sx: f32,
    pub sy: f32,
    /// Uniform in [0, 1): the pixel belongs to every sample set of a density above this.
    pub rank: f32,
}

fn unit(h: u64) -> f32 {
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// The jittered pixels of density `density`: pixel `i` is in the set when its hashed rank
/// is below `density`, so the sets of lower densities are subsets of the higher ones.
pub fn jittered_picks(width: u32, height: u32, density: f64, seed: u64) -> Vec<Pick> {
    let mut out = Vec::new();
    for y in 0..height {
        for x in 0..width {
            let h = mix64(seed ^ ((y as u64) << 32 | x as u64));
            let rank = unit(h);
            if (rank as f64) < density {
                let j = mix64(h);
                out.push(Pick { x, y, sx: x as f32 + unit(j).min(0.999_99), sy: y as f32 + unit(j << 24).min(0.999_99), rank });
            }
        }
    }
    out
}

/// A Render Cache holding exactly `samples` (of the same camera), reprojected once.
pub fn cache_with(width: u32, height: u32, cam: &CameraFrame, samples: &[Sample], background: Vec3) -> RenderCache {
    let mut cache = RenderCache::new(CacheConfig { width, height, points_per_pixel: 2.0, background });
    for s in samples {
        cache.insert(s);
    }
    cache.reproject_points(cam, None, &mut StageTimes::new());
    cache
}

/// A frame as a session reconstructs it: the scene's brute-force edges, a Render Cache
/// holding `samples`, the edge-and-point reconstruction (with the complex filter). The
/// cache's image and filter weights are the frame's.
pub fn reconstructed_frame(staged: &Staged, cam: &CameraFrame, samples: &[Sample]) -> RenderCache {
    let (w, h) = (cam.width, cam.height);
    let scene = &staged.loaded.scene;
    let transforms: Vec<glam::Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
    let mut edges = Vec::new();
    edgepoint_server::edges::brute::scene_edges(scene, &transforms, cam.eye, edgepoint_server::edges::DEFAULT_SHARP_CUTOFF_DEGREES, &mut edges);
    let mut cache = cache_with(w, h, cam, samples, scene.background);
    let mut epi = edgepoint_server::epi::Epi::new(w, h);
    let mut times = StageTimes::new();
    epi.build(&edges, cam, cache.point_image(), true, &mut times);
    let background = cache.background();
    let (points, image, weights) = cache.reconstruction_target();
    epi.reconstruct(points, background, &Default::default(), true, image, weights, &mut times);
    cache
}

/// Writes a linear-RGB image as an sRGB PNG.
/// Writes linear pixels as `stem.png` (8-bit sRGB, clipped) or `stem.exr` (linear RGB
/// float, as rendered: references are ground truth, so no bit is dropped); returns the path.
pub fn write_image(stem: &Path, format: FileFormat, w: u32, h: u32, linear: &[Vec3]) -> Result<PathBuf> {
    // Appended, not `with_extension`: stems like `epr_05.0` hold a dot.
    let with = |ext: &str| {
        let mut p = stem.as_os_str().to_owned();
        p.push(ext);
        PathBuf::from(p)
    };
    match format {
        FileFormat::Png => {
            let path = with(".png");
            write_png(&path, w, h, linear)?;
            Ok(path)
        }
        FileFormat::Exr => {
            let path = with(".exr");
            edgepoint_viewer::exr_file::write_f32(&path, w, h, linear)?;
            Ok(path)
        }
    }
}

pub fn write_png(path: &Path, w: u32, h: u32, linear: &[Vec3]) -> Result<()> {
    let mut bytes = Vec::with_capacity(linear.len() * 3);
    for c in linear {
        bytes.extend_from_slice(&edgepoint_server::image_metrics::linear_to_srgb8(*c));
    }
    image::save_buffer(path, &bytes, w, h, image::ExtendedColorType::Rgb8).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod write_image_tests {
    use super::*;

    #[test]
    fn images_keep_dotted_stems_and_exr_keeps_the_linear_values() {
        let dir = tempfile::tempdir().unwrap();
        let px = vec![Vec3::new(0.25, 3.5, 1e-4), Vec3::new(12.0, 0.0, 0.5)];
        let png = write_image(&dir.path().join("epr_05.0"), FileFormat::Png, 2, 1, &px).unwrap();
        assert_eq!(png.file_name().unwrap(), "epr_05.0.png");
        assert_eq!(image::open(&png).unwrap().to_rgb8().get_pixel(0, 0).0[1], 255, "PNG clips");
        let exr = write_image(&dir.path().join("epr_05.0"), FileFormat::Exr, 2, 1, &px).unwrap();
        assert_eq!(exr.file_name().unwrap(), "epr_05.0.exr");
        let (w, h, v) = edgepoint_viewer::exr_file::read_rgb(&exr).unwrap();
        assert_eq!((w, h), (2, 1));
        assert_eq!(v, vec![0.25, 3.5, 1e-4, 12.0, 0.0, 0.5], "EXR keeps every f32, past 1 too");
    }
}
