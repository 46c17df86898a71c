//! Headless output: every frame as `DIR/frame_00001.png` (tone-mapped sRGB) or
//! `DIR/frame_00001.exr` (linear, `--format exr`) and one JSON line of stats per frame in
//! `DIR/stats.jsonl` — the per-stage milliseconds of paper 000 Table 2 and the
//! pixel classes of Table 3 as the server reports them, plus what the viewer measures
//! (arrival time, interval, fps), so a headless run can reproduce those tables.
use crate::frame::{decode_with, encoding_name, Decoded};
use crate::tonemap::{Look, ToneMapper};
use anyhow::{bail, Context, Result};
use edgepoint_proto::{self as pb, FrameEncoding};
use image::{ImageEncoder, RgbImage};
use serde::ser::{Serialize, SerializeMap, Serializer};
use std::collections::VecDeque;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Name of the stats file inside the output directory.
pub const STATS_FILE: &str = "stats.jsonl";

/// File name of the `index`-th frame written (1-based): `frame_00001.png`.
pub fn frame_file_name(index: u64) -> String {
    FileFormat::Png.file_name(index)
}

/// The file format of headless frames (`--format`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum FileFormat {
    /// 8-bit sRGB PNG, after exposure and tone mapping.
    #[default]
    Png,
    /// OpenEXR, linear RGB half floats: never tone-mapped or clipped.
    Exr,
}

impl FileFormat {
    /// `frame_00001.png` / `frame_00001.exr`.
    pub fn file_name(self, index: u64) -> String {
        let ext = match self {
            FileFormat::Png => "png",
            FileFormat::Exr => "exr",
        };
        format!("frame_{index:05}.{ext}")
    }
}

/// One frame's stats: what the server reported plus what the viewer measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FrameStats {
    /// Frames received by this viewer so far, this one included (1-based).
    pub index: u64,
    /// The PNG this frame was written to, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    pub sequence: u64,
    pub width: u32,
    pub height: u32,
    pub encoding: &'static str,
    /// Size of the encoded frame data.
    pub bytes: usize,
    /// Per-stage milliseconds, in pipeline order.
    pub stages: Stages,
    pub total_ms: f64,
    pub samples_used: u32,
    pub samples_requested: u32,
    pub outstanding: u32,
    pub pixels: PixelStats,
    /// Discontinuity edges per kind and their rasterization (paper Table 3).
    pub edges: EdgeStats,
    /// How the frame was reconstructed: `epr` or `render-cache`.
    pub reconstruction: &'static str,
    /// The overlay drawn over it (`none`, `edges`, `classes`, `samples`).
    pub overlay: &'static str,
    /// The camera the server rendered it with, as a camera path line's fields.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraStats>,
    pub epoch: u64,
    pub live_workers: u32,
    pub frames_dropped: u64,
    /// Server milliseconds spent, before this frame, inserting samples that arrived while
    /// it waited for the frame (not in `total_ms`).
    pub between_ms: f64,
    /// Server milliseconds spent after publishing the frame before this one on picking the
    /// pixels to shade next and sending their requests (not in `total_ms`).
    pub after_ms: f64,
    /// Server seconds since session start when the frame was made.
    pub sim_time: f64,
    /// Viewer seconds since the session started when the frame arrived.
    pub received_s: f64,
    /// Milliseconds since the previous frame arrived (absent for the first).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub interval_ms: Option<f64>,
    /// Viewer-side frame rate over the last frames (up to 30).
    pub fps: f64,
    /// Time the viewer spent decoding the frame.
    pub decode_ms: f64,
}

/// A frame's camera in stats lines (the fields of a camera path line).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CameraStats {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    pub fov: f32,
}

impl From<&pb::Camera> for CameraStats {
    fn from(c: &pb::Camera) -> Self {
        let c = crate::client::camera_from_wire(c);
        CameraStats { eye: c.eye.into(), target: c.target.into(), up: c.up.into(), fov: c.fov_y_degrees }
    }
}

/// Stage timings that serialize as a JSON object keeping pipeline order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stages(pub Vec<(String, f64)>);

impl Serialize for Stages {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, v)?;
        }
        m.end()
    }
}

/// The server's pixel counts (paper 000 Table 3 classes and Render Cache occupancy).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct PixelStats {
    pub with_point: u32,
    pub filled: u32,
    pub empty: u32,
    pub occluded: u32,
    pub cache_points: u32,
    pub empty_class: u32,
    pub simple_class: u32,
    pub complex_class: u32,
}

impl From<&pb::PixelCounts> for PixelStats {
    fn from(p: &pb::PixelCounts) -> Self {
        PixelStats {
            with_point: p.with_point,
            filled: p.filled,
            empty: p.empty,
            occluded: p.occluded,
            cache_points: p.cache_points,
            empty_class: p.empty_class,
            simple_class: p.simple_class,
            complex_class: p.complex_class,
        }
    }
}

/// The server's edge counts.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct EdgeStats {
    pub silhouette: u32,
    pub sharp: u32,
    pub boundary: u32,
    pub shadow_hard: u32,
    pub shadow_umbral: u32,
    pub shadow_penumbral: u32,
    pub fragments: u32,
    pub culled: u32,
    /// Found with the edge trees (false while they build: brute force).
    pub edge_trees: bool,
    /// Shadow-store updates finished since the previous frame (ms, on the server's shadow
    /// thread).
    pub shadow_update_ms: f64,
    pub shadow_pairs: u32,
}

impl From<&pb::EdgeCounts> for EdgeStats {
    fn from(e: &pb::EdgeCounts) -> Self {
        EdgeStats {
            silhouette: e.silhouette,
            sharp: e.sharp,
            boundary: e.boundary,
            shadow_hard: e.shadow_hard,
            shadow_umbral: e.shadow_umbral,
            shadow_penumbral: e.shadow_penumbral,
            fragments: e.fragments,
            culled: e.culled,
            edge_trees: e.edge_trees,
            shadow_update_ms: e.shadow_update_ms,
            shadow_pairs: e.shadow_pairs,
        }
    }
}

/// Arrival bookkeeping shared by the headless writer and the window title.
#[derive(Debug)]
pub struct FrameMeter {
    start: Instant,
    recent: VecDeque<Instant>,
    count: u64,
}

/// How many recent arrivals the fps figure averages over.
const FPS_WINDOW: usize = 30;

/// What [`FrameMeter::arrive`] measured for one frame.
#[derive(Debug, Clone, Copy)]
pub struct Arrival {
    pub index: u64,
    pub received_s: f64,
    pub interval_ms: Option<f64>,
    pub fps: f64,
}

impl FrameMeter {
    /// A meter whose clock starts now (call it when the session starts).
    pub fn new() -> Self {
        Self::starting_at(Instant::now())
    }

    /// A meter whose clock started at `start`.
    pub fn starting_at(start: Instant) -> Self {
        FrameMeter { start, recent: VecDeque::with_capacity(FPS_WINDOW + 1), count: 0 }
    }

    /// Records a frame that arrived at `at`.
    pub fn arrive(&mut self, at: Instant) -> Arrival {
        let interval_ms = self.recent.back().map(|&prev| at.saturating_duration_since(prev).as_secs_f64() * 1e3);
        self.recent.push_back(at);
        if self.recent.len() > FPS_WINDOW {
            self.recent.pop_front();
        }
        self.count += 1;
        let span = at.saturating_duration_since(self.recent[0]).as_secs_f64();
        let fps = if self.recent.len() >= 2 && span > 0.0 { (self.recent.len() - 1) as f64 / span } else { 0.0 };
        Arrival { index: self.count, received_s: at.saturating_duration_since(self.start).as_secs_f64(), interval_ms, fps }
    }

    /// Frames recorded so far.
    pub fn count(&self) -> u64 {
        self.count
    }
}

impl Default for FrameMeter {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameStats {
    /// Stats of frame `f` as it arrived (`a`); `file` and `decode_ms` are filled by the caller.
    pub fn new(f: &pb::Frame, a: Arrival) -> Self {
        let mut stages: Vec<(String, f64)> = Vec::with_capacity(f.stages.len());
        for s in &f.stages {
            // A repeated stage name (a stage run twice) adds up rather than making a JSON
            // object with duplicate keys.
            match stages.iter_mut().find(|(k, _)| *k == s.stage) {
                Some((_, ms)) => *ms += s.ms,
                None => stages.push((s.stage.clone(), s.ms)),
            }
        }
        FrameStats {
            index: a.index,
            file: None,
            sequence: f.sequence,
            width: f.width,
            height: f.height,
            encoding: encoding_name(f.encoding),
            bytes: f.data.len(),
            stages: Stages(stages),
            total_ms: f.total_ms,
            samples_used: f.samples_used,
            samples_requested: f.samples_requested,
            outstanding: f.outstanding,
            pixels: f.pixels.as_ref().map(PixelStats::from).unwrap_or_default(),
            edges: f.edges.as_ref().map(EdgeStats::from).unwrap_or_default(),
            reconstruction: crate::reconstruction::reconstruction_name(f.reconstruction),
            overlay: crate::reconstruction::overlay_name(f.overlay),
            camera: f.camera.as_ref().map(CameraStats::from),
            epoch: f.epoch,
            live_workers: f.live_workers,
            frames_dropped: f.frames_dropped,
            between_ms: f.between_ms,
            after_ms: f.after_ms,
            sim_time: f.sim_time,
            received_s: a.received_s,
            interval_ms: a.interval_ms,
            fps: a.fps,
            decode_ms: 0.0,
        }
    }
}

/// Writes frames as PNG or EXR files and their stats as JSON lines into one directory.
pub struct HeadlessWriter {
    dir: PathBuf,
    stats: BufWriter<File>,
    echo_stdout: bool,
    meter: FrameMeter,
    last: Option<FrameStats>,
    format: FileFormat,
    /// How [`Self::write_frame`] shows linear frames in PNGs.
    tone: ToneMapper,
}

impl HeadlessWriter {
    /// Creates `dir` (and parents) and a fresh `stats.jsonl` in it. With `echo_stdout`,
    /// every stats line is also printed on stdout (`--stats-stdout`).
    pub fn create(dir: &Path, echo_stdout: bool) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create output directory {}", dir.display()))?;
        let path = dir.join(STATS_FILE);
        let f = File::create(&path).with_context(|| format!("cannot create {}", path.display()))?;
        Ok(HeadlessWriter {
            dir: dir.to_path_buf(),
            stats: BufWriter::new(f),
            echo_stdout,
            meter: FrameMeter::new(),
            last: None,
            format: FileFormat::Png,
            tone: ToneMapper::new(Look::default()),
        })
    }

    /// Writes `format` files (EXR needs linear frames; a frame that is not is an error).
    pub fn with_format(mut self, format: FileFormat) -> Self {
        self.format = format;
        self
    }

    /// Shows linear frames with `look` in the PNGs [`Self::write_frame`] writes.
    pub fn with_look(mut self, look: Look) -> Self {
        self.tone.set_look(look);
        self
    }

    /// One line saying what the run wrote: frames, time, frame rate, the last frame's server
    /// figures, and where the files are.
    pub fn summary(&self) -> String {
        summary_line(self.meter.count(), self.last.as_ref(), Some(&self.dir))
    }

    /// The output directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.meter.count()
    }

    /// Decodes `f`, writes it as the next file and appends its stats line. A frame that
    /// does not decode is an error naming it (nothing is written for it).
    pub fn write_frame(&mut self, f: &pb::Frame, received: Instant) -> Result<FrameStats> {
        let t0 = Instant::now();
        let d = decode_with(f, &self.tone)?;
        let decode_ms = t0.elapsed().as_secs_f64() * 1e3;
        self.write_decoded(f, &d, received, decode_ms)
    }

    /// [`Self::write_frame`] for a frame the caller already decoded (taking `decode_ms`), so
    /// a window and the writer share one decode.
    pub fn write_decoded(&mut self, f: &pb::Frame, d: &Decoded, received: Instant, decode_ms: f64) -> Result<FrameStats> {
        if self.format == FileFormat::Exr && d.linear.is_none() {
            bail!("frame {} is {}, not linear: EXR files need linear frames", f.sequence, encoding_name(f.encoding));
        }
        let a = self.meter.arrive(received);
        let name = self.format.file_name(a.index);
        let path = self.dir.join(&name);
        if let (FileFormat::Exr, Some(lin)) = (self.format, &d.linear) {
            crate::exr_file::write_half(&path, lin)?;
        } else {
            self.write_png(f, &d.image, &name, &path)?;
        }
        self.finish_frame(f, a, name, decode_ms)
    }

    fn write_png(&self, f: &pb::Frame, img: &RgbImage, name: &str, path: &Path) -> Result<()> {
        let png = if f.encoding == FrameEncoding::Png as i32 {
            // Already a PNG (and it decoded): keep the server's bytes.
            f.data.clone()
        } else {
            let mut buf = Vec::with_capacity(img.as_raw().len() / 2);
            // Fast compression: ~1 ms at 512x512 instead of ~40 ms (STACK.md).
            image::codecs::png::PngEncoder::new_with_quality(
                &mut buf,
                image::codecs::png::CompressionType::Fast,
                image::codecs::png::FilterType::Adaptive,
            )
            .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
            .with_context(|| format!("encoding {name}"))?;
            buf
        };
        std::fs::write(path, &png).with_context(|| format!("cannot write {}", path.display()))
    }

    fn finish_frame(&mut self, f: &pb::Frame, a: Arrival, name: String, decode_ms: f64) -> Result<FrameStats> {
        let mut stats = FrameStats::new(f, a);
        stats.file = Some(name);
        stats.decode_ms = decode_ms;
        let line = serde_json::to_string(&stats)?;
        writeln!(self.stats, "{line}").with_context(|| format!("cannot write {}", self.dir.join(STATS_FILE).display()))?;
        // Flushed per frame so the file is complete whenever the run is interrupted.
        self.stats.flush()?;
        if self.echo_stdout {
            let mut out = std::io::stdout().lock();
            // A closed stdout (piped into `head`) must not end the run.
            let _ = writeln!(out, "{line}");
        }
        self.last = Some(stats.clone());
        Ok(stats)
    }
}

/// The end-of-run line: `120 frames 512x512 in 4.1 s (29.3 fps); last frame: 4096 samples,
/// 18.2 ms on the server; frames and stats.jsonl in edgepoint-frames`.
pub fn summary_line(frames: u64, last: Option<&FrameStats>, dir: Option<&Path>) -> String {
    let mut s = format!("{frames} frames");
    if let Some(l) = last {
        let rate = if l.received_s > 0.0 && frames > 1 { (frames - 1) as f64 / l.received_s } else { 0.0 };
        s.push_str(&format!(
            " {}x{} in {:.1} s ({rate:.1} fps); last frame: {} samples, {:.1} ms on the server",
            l.width, l.height, l.received_s, l.samples_used, l.total_ms
        ));
    }
    if let Some(d) = dir {
        s.push_str(&format!("; frames and {STATS_FILE} in {}", d.display()));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn qoi_frame(seq: u64, w: u32, h: u32, shade: u8) -> pb::Frame {
        let img = image::RgbImage::from_pixel(w, h, image::Rgb([shade, 10, 200]));
        let mut buf = std::io::Cursor::new(Vec::new());
        img.write_to(&mut buf, image::ImageFormat::Qoi).unwrap();
        pb::Frame {
            sequence: seq,
            width: w,
            height: h,
            encoding: FrameEncoding::Qoi as i32,
            data: buf.into_inner(),
            stages: vec![
                pb::StageTime { stage: "reproject".into(), ms: 1.5 },
                pb::StageTime { stage: "edges".into(), ms: 0.25 },
                pb::StageTime { stage: "reproject".into(), ms: 0.5 },
            ],
            total_ms: 2.25,
            samples_used: 40,
            samples_requested: 64,
            pixels: Some(pb::PixelCounts { with_point: 5, simple_class: 7, ..Default::default() }),
            edges: Some(pb::EdgeCounts { silhouette: 11, culled: 3, ..Default::default() }),
            reconstruction: pb::Reconstruction::EdgeAndPoint as i32,
            live_workers: 2,
            ..Default::default()
        }
    }

    #[test]
    fn writes_pngs_and_ordered_stats_lines() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("nested/out");
        let mut w = HeadlessWriter::create(&out, false).unwrap();
        let t = Instant::now();
        w.write_frame(&qoi_frame(7, 6, 4, 100), t).unwrap();
        let s = w.write_frame(&qoi_frame(9, 6, 4, 50), t + Duration::from_millis(50)).unwrap();
        assert_eq!(s.index, 2);
        assert!((s.fps - 20.0).abs() < 1e-6, "two frames 50 ms apart: {}", s.fps);
        assert_eq!(w.frames_written(), 2);

        let png = image::open(out.join("frame_00002.png")).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (6, 4));
        assert_eq!(png.get_pixel(3, 2).0, [50, 10, 200]);

        let text = std::fs::read_to_string(out.join(STATS_FILE)).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 2);
        // Stages keep pipeline order and a repeated stage adds up.
        assert!(lines[0].contains(r#""stages":{"reproject":2.0,"edges":0.25}"#), "{}", lines[0]);
        let v: serde_json::Value = serde_json::from_str(lines[1]).unwrap();
        assert_eq!(v["sequence"], 9);
        assert_eq!(v["file"], "frame_00002.png");
        assert_eq!(v["encoding"], "qoi");
        assert_eq!(v["samples_requested"], 64);
        assert_eq!(v["pixels"]["simple_class"], 7);
        assert_eq!((v["edges"]["silhouette"].as_u64(), v["edges"]["culled"].as_u64()), (Some(11), Some(3)));
        assert_eq!(v["reconstruction"], "epr");
        assert_eq!(v["live_workers"], 2);
        assert!((v["interval_ms"].as_f64().unwrap() - 50.0).abs() < 1e-6);
    }

    #[test]
    fn the_summary_names_frames_rate_and_place() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = HeadlessWriter::create(dir.path(), false).unwrap();
        let t = Instant::now();
        for i in 0..3 {
            w.write_frame(&qoi_frame(i, 6, 4, 10), t + Duration::from_millis(100 * i)).unwrap();
        }
        let s = w.summary();
        assert!(s.starts_with("3 frames 6x4 in ") && s.contains("samples") && s.contains(&dir.path().display().to_string()), "{s}");
        assert!(!s.contains('\n'));
    }

    #[test]
    fn a_bad_frame_is_an_error_and_writes_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = HeadlessWriter::create(dir.path(), false).unwrap();
        let mut f = qoi_frame(1, 4, 4, 0);
        f.data.truncate(5);
        assert!(w.write_frame(&f, Instant::now()).is_err());
        assert_eq!(w.frames_written(), 0);
        assert!(!dir.path().join("frame_00001.png").exists());
    }
}
