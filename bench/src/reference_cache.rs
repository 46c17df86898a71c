//! On-disk cache of converged reference images: rendering one takes many seconds, and every
//! benchmark run of the same setup needs the same image. It lives in the user's cache
//! directory ([`default_dir`]), never relative to wherever the bench happens to be started.
use anyhow::{Context, Result};
use edgepoint_scene::Camera;
use edgepoint_server::reference::ReferenceImage;
use glam::Vec3;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

pub struct RefCache {
    dir: PathBuf,
}

/// Where references are cached unless `--ref-cache` says: `$XDG_CACHE_HOME/edgepoint/references`,
/// else `$HOME/.cache/edgepoint/references`, else the system's temporary directory.
pub fn default_dir() -> PathBuf {
    let non_empty = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty()).map(PathBuf::from);
    let base = non_empty("XDG_CACHE_HOME").or_else(|| non_empty("HOME").map(|h| h.join(".cache"))).unwrap_or_else(std::env::temp_dir);
    base.join("edgepoint").join("references")
}

impl RefCache {
    /// The cache in `dir`, or in [`default_dir`].
    pub fn at(dir: Option<&Path>) -> Self {
        RefCache { dir: dir.map_or_else(default_dir, Path::to_path_buf) }
    }

    /// A file name that changes whenever anything that affects the image changes.
    pub fn key(scene_hash: &str, cam: &Camera, width: u32, height: u32, spp: u32, shader: &str, params: &HashMap<String, f64>) -> String {
        Self::key_with(scene_hash, cam, width, height, spp, shader, params, "")
    }

    /// [`Self::key`] for a scene state described by `state` too (e.g. moved objects'
    /// transforms; empty for the scene's default state).
    #[allow(clippy::too_many_arguments)]
    pub fn key_with(
        scene_hash: &str,
        cam: &Camera,
        width: u32,
        height: u32,
        spp: u32,
        shader: &str,
        params: &HashMap<String, f64>,
        state: &str,
    ) -> String {
        let mut p: Vec<_> = params.iter().map(|(k, v)| format!("{k}={v}")).collect();
        p.sort();
        let mut desc = format!(
            "{scene_hash}|{:?}|{:?}|{:?}|{}|{width}x{height}|{spp}|{shader}|{}",
            cam.eye.to_array(),
            cam.target.to_array(),
            cam.up.to_array(),
            cam.fov_y_degrees,
            p.join(",")
        );
        // The shader's revision (above 1 only, so keys made before revisions existed stay
        // valid for the shaders that have not changed since).
        if let Some(r) = edgepoint_proto::shaders::shader(shader).map(|s| s.revision).filter(|&r| r > 1) {
            desc += &format!("|rev{r}");
        }
        if !state.is_empty() {
            desc += "|";
            desc += state;
        }
        let src = edgepoint_proto::SceneSource {
            source: Some(edgepoint_proto::scene_source::Source::Builtin(desc)),
        };
        format!("ref-{}-{width}x{height}-{spp}spp.f32", &edgepoint_proto::scene_hash(&src)[..16])
    }

    /// The cached image, if present and of the right size.
    pub fn load(&self, key: &str, width: u32, height: u32, spp: u32) -> Option<ReferenceImage> {
        let bytes = std::fs::read(self.dir.join(key)).ok()?;
        let n = width as usize * height as usize;
        if bytes.len() != n * 12 {
            return None;
        }
        let f = |i: usize| f32::from_le_bytes(bytes[i * 4..i * 4 + 4].try_into().unwrap());
        let pixels = (0..n).map(|p| Vec3::new(f(p * 3), f(p * 3 + 1), f(p * 3 + 2))).collect();
        Some(ReferenceImage { width, height, spp, pixels, elapsed: Duration::ZERO, rays: 0, nonfinite: 0 })
    }

    pub fn store(&self, key: &str, img: &ReferenceImage) -> Result<()> {
        std::fs::create_dir_all(&self.dir).with_context(|| format!("creating {}", self.dir.display()))?;
        let mut bytes = Vec::with_capacity(img.pixels.len() * 12);
        for p in &img.pixels {
            for v in p.to_array() {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        let path = self.dir.join(key);
        std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))
    }
}
