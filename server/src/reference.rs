//! Reference renders through the same workers and shader as the interactive renderer (paper
//! 000 §7.2: "a ray tracer that samples every pixel in each frame … using our shaders and
//! the same number of processors").
//!
//! - `spp = 1`: one ray through every pixel centre — the full ray-trace baseline the speedup
//!   is measured against (the result carries its wall time).
//! - `spp > 1`: stratified, jittered sub-pixel positions averaged per pixel — the converged
//!   image PSNR/SSIM are measured against.
//!
//! [`render_reference`] is `async`: await it on a tokio runtime (the dispatcher's links run
//! there). It must be the dispatcher's only consumer of answers while it runs (open a
//! dispatcher for it; do not share one with a live session).
use crate::rng::mix64;
use crate::workers::{DispatchError, Dispatcher};
use edgepoint_proto as pb;
use edgepoint_scene::camera::CameraFrame;
use edgepoint_scene::{Camera, Progress};
use glam::Vec3;
use std::collections::HashMap;
use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// A finished reference render.
#[derive(Debug, Clone)]
pub struct ReferenceImage {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    /// Linear RGB, row-major.
    pub pixels: Vec<Vec3>,
    /// From the first request to the last answer.
    pub elapsed: Duration,
    pub rays: u64,
    /// Samples dropped for non-finite values.
    pub nonfinite: u64,
}

/// Tuning of a reference render.
#[derive(Debug, Clone)]
pub struct ReferenceOptions {
    /// Requests per batch.
    pub batch_size: usize,
    /// Batches outstanding at once.
    pub window: usize,
    /// Give up when no answer arrives for this long.
    pub stall: Duration,
    /// Seed of the sub-pixel jitter and of the batches' shading seeds.
    pub seed: u64,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        ReferenceOptions { batch_size: 1024, window: 64, stall: Duration::from_secs(60), seed: 0x00c0_ffee }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    #[error("reference size {width}x{height} with {spp} spp is not renderable")]
    BadSize { width: u32, height: u32, spp: u32 },
    #[error("camera: {0}")]
    BadCamera(String),
    #[error(transparent)]
    Dispatch(#[from] DispatchError),
    #[error("{missing} pixels received no sample (first: {first_x},{first_y})")]
    Missing { missing: usize, first_x: u32, first_y: u32 },
}

/// Sub-pixel position of sample `s` of pixel (`x`, `y`): the pixel centre for one sample;
/// otherwise a jittered point in one cell of an `nx` x `ny` grid of strata. A per-pixel
/// random rotation picks which cells are used when `spp` does not fill the grid, so every
/// cell is equally likely and the average stays unbiased.
#[inline]
pub fn subpixel_position(x: u32, y: u32, s: u32, spp: u32, seed: u64) -> (f32, f32) {
    if spp <= 1 {
        return (x as f32 + 0.5, y as f32 + 0.5);
    }
    let nx = (spp as f64).sqrt().ceil() as u32;
    let ny = spp.div_ceil(nx);
    let cells = nx * ny;
    let h = mix64(seed ^ ((y as u64) << 32 | x as u64));
    let cell = ((h % cells as u64) as u32 + s) % cells;
    let j = mix64(h ^ (s as u64 + 1));
    let jx = (j >> 40) as f32 / (1u64 << 24) as f32;
    let jy = ((j >> 16) & 0xff_ffff) as f32 / (1u64 << 24) as f32;
    let (cx, cy) = (cell % nx, cell / nx);
    (x as f32 + (cx as f32 + jx) / nx as f32, y as f32 + (cy as f32 + jy) / ny as f32)
}

/// What every batch of a full-frame render shares.
pub struct FullFrameSpec<'a> {
    pub epoch: u64,
    pub shader: &'a str,
    pub params: &'a HashMap<String, f64>,
    /// Requests per batch (at least 1).
    pub batch_size: usize,
    /// The batches' shading seeds derive from it.
    pub seed: u64,
}

/// The request batches of `spp` rays through every pixel of `cam`'s image, in scan order,
/// ray `s` of pixel (x, y) through the continuous image position `position(x, y, s)`;
/// request id = pixel index × spp + s. Made lazily as a dispatcher's window opens, so
/// memory stays bounded at any size.
pub fn pixel_batches<'a>(
    cam: &CameraFrame,
    spp: u32,
    spec: &'a FullFrameSpec<'a>,
    position: impl Fn(u32, u32, u32) -> (f32, f32) + 'a,
) -> impl Iterator<Item = pb::RequestBatch> + 'a {
    let cam = *cam;
    let (width, spp) = (cam.width as u64, spp.max(1) as u64);
    let total = width * cam.height as u64 * spp;
    let batch_size = spec.batch_size.max(1) as u64;
    (0..total.div_ceil(batch_size)).map(move |b| {
        let lo = b * batch_size;
        let hi = (lo + batch_size).min(total);
        let requests = (lo..hi)
            .map(|r| {
                let p = r / spp;
                let (x, y) = ((p % width) as u32, (p / width) as u32);
                let (sx, sy) = position(x, y, (r % spp) as u32);
                let (o, d) = cam.ray(sx, sy);
                pb::ShadeRequest { id: r, pixel_x: x, pixel_y: y, origin: Some(o.into()), direction: Some(d.into()), ..Default::default() }
            })
            .collect();
        pb::RequestBatch {
            batch_id: b,
            epoch: spec.epoch,
            shader: spec.shader.to_string(),
            params: spec.params.clone(),
            requests,
            seed: mix64(spec.seed ^ b.wrapping_mul(0x9e37_79b9)),
            // Packed by the worker link on the way out.
            packed_requests: Vec::new(),
        }
    })
}

/// Renders `width` x `height` with `spp` rays per pixel at the dispatcher's current epoch.
/// See the module docs.
#[allow(clippy::too_many_arguments)]
pub async fn render_reference(
    dispatcher: &Dispatcher,
    camera: &Camera,
    width: u32,
    height: u32,
    spp: u32,
    shader: &str,
    params: &HashMap<String, f64>,
    progress: &dyn Progress,
) -> Result<ReferenceImage, ReferenceError> {
    render_reference_with(dispatcher, camera, width, height, spp, shader, params, progress, &ReferenceOptions::default()).await
}

#[allow(clippy::too_many_arguments)]
pub async fn render_reference_with(
    dispatcher: &Dispatcher,
    camera: &Camera,
    width: u32,
    height: u32,
    spp: u32,
    shader: &str,
    params: &HashMap<String, f64>,
    progress: &dyn Progress,
    opts: &ReferenceOptions,
) -> Result<ReferenceImage, ReferenceError> {
    let pixels = width as u64 * height as u64;
    if width == 0 || height == 0 || spp == 0 || pixels.checked_mul(spp as u64).is_none_or(|r| r > (1u64 << 40)) {
        return Err(ReferenceError::BadSize { width, height, spp });
    }
    camera.validate().map_err(ReferenceError::BadCamera)?;
    let cam = camera.frame(width, height);
    let total = pixels * spp as u64;
    let seed = opts.seed;
    let spec = FullFrameSpec { epoch: dispatcher.epoch(), shader, params, batch_size: opts.batch_size, seed };
    let batches = pixel_batches(&cam, spp, &spec, move |x, y, s| subpixel_position(x, y, s, spp, seed));

    let mut sum = vec![Vec3::ZERO; pixels as usize];
    let mut count = vec![0u32; pixels as usize];
    let mut nonfinite = 0u64;
    progress.begin(&format!("reference {width}x{height} {spp} spp"), total);
    let t0 = Instant::now();
    let result = dispatcher
        .shade_all(batches, opts.window, opts.stall, |b| {
            for s in &b.samples {
                let p = (s.id / spp as u64) as usize;
                if p >= sum.len() {
                    continue;
                }
                let c = pb::vec3_or_zero(&s.rgb);
                if c.is_finite() {
                    sum[p] += c;
                    count[p] += 1;
                } else {
                    nonfinite += 1;
                }
            }
            progress.advance(b.samples.len() as u64);
        })
        .await;
    let elapsed = t0.elapsed();
    progress.end();
    result?;
    let mut missing = count.iter().enumerate().filter(|(_, &c)| c == 0).map(|(i, _)| i);
    if let Some(first) = missing.next() {
        return Err(ReferenceError::Missing {
            missing: 1 + missing.count(),
            first_x: (first % width as usize) as u32,
            first_y: (first / width as usize) as u32,
        });
    }
    let pixels = sum.iter().zip(&count).map(|(&s, &c)| s / c as f32).collect();
    Ok(ReferenceImage { width, height, spp, pixels, elapsed, rays: total, nonfinite })
}

/// Progress for long work: an indicatif bar when stderr is a terminal, otherwise a tracing
/// `info` line at most every two seconds (and at the end).
pub struct LogProgress {
    label: String,
    bar: Option<indicatif::ProgressBar>,
    state: Mutex<LogState>,
}

struct LogState {
    stage: String,
    total: u64,
    done: u64,
    started: Instant,
    last_log: Instant,
}

impl LogProgress {
    pub fn new(label: &str) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = indicatif::ProgressBar::hidden();
            b.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            b.set_style(
                indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} ({eta})")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        let now = Instant::now();
        LogProgress {
            label: label.to_string(),
            bar,
            state: Mutex::new(LogState { stage: String::new(), total: 0, done: 0, started: now, last_log: now }),
        }
    }
}

impl Progress for LogProgress {
    fn begin(&self, stage: &str, total: u64) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let now = Instant::now();
        *s = LogState { stage: stage.to_string(), total, done: 0, started: now, last_log: now };
        if let Some(b) = &self.bar {
            b.reset();
            b.set_length(total);
            b.set_message(format!("{}: {stage}", self.label));
        }
    }

    fn advance(&self, units: u64) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        s.done += units;
        match &self.bar {
            Some(b) => b.set_position(s.done),
            None => {
                if s.last_log.elapsed() >= Duration::from_secs(2) {
                    s.last_log = Instant::now();
                    let pct = if s.total > 0 { 100.0 * s.done as f64 / s.total as f64 } else { 0.0 };
                    tracing::info!("{}: {} {:.0}% ({}/{})", self.label, s.stage, pct, s.done, s.total);
                }
            }
        }
    }

    fn end(&self) {
        let s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
        tracing::info!("{}: {} done ({} units in {:.2} s)", self.label, s.stage, s.done, s.started.elapsed().as_secs_f64());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_spp_uses_pixel_centres() {
        assert_eq!(subpixel_position(3, 7, 0, 1, 99), (3.5, 7.5));
    }

    #[test]
    fn strata_are_covered_once_and_stay_inside_the_pixel() {
        for spp in [4u32, 9, 16] {
            let n = (spp as f64).sqrt() as u32;
            for (x, y) in [(0u32, 0u32), (5, 2), (100, 63)] {
                let mut seen = vec![0; spp as usize];
                for s in 0..spp {
                    let (sx, sy) = subpixel_position(x, y, s, spp, 7);
                    assert!(sx >= x as f32 && sx < x as f32 + 1.0 && sy >= y as f32 && sy < y as f32 + 1.0);
                    let cx = ((sx - x as f32) * n as f32) as usize;
                    let cy = ((sy - y as f32) * n as f32) as usize;
                    seen[cy * n as usize + cx] += 1;
                }
                assert!(seen.iter().all(|&c| c == 1), "spp {spp}: one sample per stratum, got {seen:?}");
            }
        }
    }

    #[test]
    fn partial_grids_are_unbiased_over_pixels() {
        // 5 spp on a 3x2 grid: over many pixels every cell is used equally often and the mean
        // sub-pixel position is the pixel centre.
        let spp = 5;
        let (mut mx, mut my, mut n) = (0.0f64, 0.0f64, 0.0f64);
        let mut cells = [0u32; 6];
        for p in 0..20_000u32 {
            // Small coordinates keep f32 exact enough to recover the stratum; the seed
            // varies the per-pixel rotation as distinct pixels would.
            let (x, y) = (p % 3, p % 2);
            let mut used = std::collections::HashSet::new();
            for s in 0..spp {
                let (sx, sy) = subpixel_position(x, y, s, spp, p as u64);
                let (fx, fy) = (sx - x as f32, sy - y as f32);
                mx += fx as f64;
                my += fy as f64;
                n += 1.0;
                let c = (fy * 2.0) as usize * 3 + (fx * 3.0) as usize;
                assert!(used.insert(c), "a stratum used twice in one pixel");
                cells[c] += 1;
            }
        }
        assert!((mx / n - 0.5).abs() < 0.01 && (my / n - 0.5).abs() < 0.01, "mean {} {}", mx / n, my / n);
        let mean = cells.iter().sum::<u32>() as f64 / 6.0;
        assert!(cells.iter().all(|&c| (c as f64 - mean).abs() < 0.05 * mean), "{cells:?}");
    }
}
