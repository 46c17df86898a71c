//! `edgepoint-bench encode`: the frame's way out of the renderer — conversion to sRGB, QOI
//! (and raw) encoding, and publishing the message — against the encoder the renderer had
//! before (kept here as the baseline: a 4096-entry table plus a walk along the rounding
//! boundaries per channel, then the `image` crate's QOI encoder), measured in the same
//! process on the same frame, so the ratios hold on a busy machine.
//!
//! The frame is one a session would send: the scene's edge-and-point reconstruction from a
//! Render Cache holding samples of the given density (or a PNG given with `--image`). One
//! thread: that thread's CPU time; all threads: wall clock on a pool of that many.
//!
//! The linear encoding (half floats, LZ4) is measured against QOI on the same frame: the
//! server's encode, the viewer's decode and tone mapping (against decoding QOI), bytes per
//! frame; and EXR writes of the decoded frame with each lossless compression (wall clock:
//! the `exr` crate compresses blocks on its own threads).
use crate::clock::{median_ms, thread_cpu_ms, wall_ms};
use crate::inprocess::{jittered_picks, reconstructed_frame, Staged};
use crate::stats::median;
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_proto::FrameEncoding;
use edgepoint_server::encode::{decode_frame, encode_srgb8, to_srgb8, FrameEncoder};
use edgepoint_server::image_metrics::srgb8_to_linear;
use edgepoint_server::srgb::reference_code;
use edgepoint_server::session::SessionOutput;
use edgepoint_proto::linear_frame;
use edgepoint_viewer::exr_file::{write_half_with, Compression};
use edgepoint_viewer::tonemap::{Look, ToneCurve, ToneMapper};
use glam::Vec3;
use prost::Message;
use serde_json::json;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct EncodeArgs {
    /// Scene the frame is reconstructed from: a built-in name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz).
    #[arg(long, default_value = "cornell")]
    pub scene: String,
    /// Square frame sizes to measure (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "512,1024")]
    pub sizes: Vec<u32>,
    /// Fraction of pixels holding a sample in the frame's Render Cache (1 = the steady state
    /// of a still camera).
    #[arg(long, default_value_t = 1.0)]
    pub density: f64,
    /// Measure this PNG frame instead of reconstructing one (`--sizes` is then ignored).
    #[arg(long, value_name = "PNG")]
    pub image: Option<PathBuf>,
    /// Timed repetitions per measurement (medians are reported).
    #[arg(long, default_value_t = 30)]
    pub iterations: usize,
    /// Thread count of the "all threads" runs (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// The encoder as of commit 0e292e1 (the baseline of the ratios).
mod baseline {
    use edgepoint_server::image_metrics::srgb_to_linear;
    use glam::Vec3;
    use rayon::prelude::*;
    use std::sync::OnceLock;

    const COARSE: usize = 4096;

    struct Tables {
        mid: [f32; 257],
        coarse: Vec<u8>,
    }

    fn tables() -> &'static Tables {
        static T: OnceLock<Tables> = OnceLock::new();
        T.get_or_init(|| {
            let mut mid = [0.0f32; 257];
            mid[0] = f32::NEG_INFINITY;
            for (k, m) in mid.iter_mut().enumerate().take(256).skip(1) {
                *m = srgb_to_linear((k as f32 - 0.5) / 255.0);
            }
            mid[256] = f32::INFINITY;
            let mut coarse = vec![0u8; COARSE + 1];
            let mut code = 0usize;
            for (i, c) in coarse.iter_mut().enumerate() {
                let x = i as f32 / COARSE as f32;
                while code < 255 && mid[code + 1] <= x {
                    code += 1;
                }
                *c = code as u8;
            }
            Tables { mid, coarse }
        })
    }

    #[inline]
    fn channel(t: &Tables, x: f32) -> u8 {
        let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
        let mut code = t.coarse[(x * COARSE as f32) as usize] as usize;
        while code < 255 && t.mid[code + 1] <= x {
            code += 1;
        }
        code as u8
    }

    /// Linear frame to interleaved sRGB bytes, rows in parallel.
    pub fn to_srgb8(linear: &[Vec3], w: usize, out: &mut Vec<u8>) {
        let t = tables();
        out.clear();
        out.resize(linear.len() * 3, 0);
        out.par_chunks_mut(w * 3).zip(linear.par_chunks(w)).for_each(|(dst, src)| {
            for (d, c) in dst.chunks_exact_mut(3).zip(src) {
                d.copy_from_slice(&[channel(t, c.x), channel(t, c.y), channel(t, c.z)]);
            }
        });
    }
}

/// The measurements of one frame on one pool.
fn measure(frame: &[Vec3], w: u32, h: u32, iterations: usize, cpu: bool) -> Result<BTreeMap<&'static str, f64>> {
    let clock: fn() -> f64 = if cpu { thread_cpu_ms } else { wall_ms };
    let time = |f: &mut dyn FnMut()| -> f64 { median_ms(iterations, clock, f) };
    let mut m = BTreeMap::new();
    let mut rgb = Vec::new();
    let mut enc = FrameEncoder::new();
    m.insert("srgb_baseline", time(&mut || baseline::to_srgb8(frame, w as usize, &mut rgb)));
    m.insert("srgb", time(&mut || to_srgb8(frame, w, h, &mut rgb).expect("sizes match")));
    m.insert("qoi_image_crate", time(&mut || drop(encode_srgb8(&rgb, w, h, FrameEncoding::Qoi).expect("encodes"))));
    m.insert(
        "encode_qoi_baseline",
        time(&mut || {
            baseline::to_srgb8(frame, w as usize, &mut rgb);
            drop(encode_srgb8(&rgb, w, h, FrameEncoding::Qoi).expect("encodes"));
        }),
    );
    m.insert("encode_qoi", time(&mut || drop(enc.encode(frame, w, h, FrameEncoding::Qoi).expect("encodes"))));
    m.insert(
        "encode_raw_baseline",
        time(&mut || {
            let mut out = Vec::new();
            baseline::to_srgb8(frame, w as usize, &mut out);
            drop(out);
        }),
    );
    m.insert("encode_raw", time(&mut || drop(enc.encode(frame, w, h, FrameEncoding::RawRgb8).expect("encodes"))));
    m.insert("encode_linear", time(&mut || drop(enc.encode(frame, w, h, FrameEncoding::LinearHalfLz4).expect("encodes"))));
    // The viewer's side: decoding and showing each kind of frame.
    let lin = enc.encode(frame, w, h, FrameEncoding::LinearHalfLz4)?;
    let qoi = enc.encode(frame, w, h, FrameEncoding::Qoi)?;
    let decoded = linear_frame::decode(&lin, w, h)?;
    let tone = ToneMapper::new(Look { exposure: 1.0, curve: ToneCurve::Filmic });
    m.insert("viewer_decode_qoi", time(&mut || drop(decode_frame(&qoi, FrameEncoding::Qoi, w, h).expect("decodes"))));
    m.insert("viewer_decode_linear", time(&mut || drop(linear_frame::decode(&lin, w, h).expect("decodes"))));
    m.insert("viewer_tonemap", time(&mut || drop(tone.map(&decoded))));
    // Publishing: the frame message handed to the session's output, taken by the stream and
    // serialised as the gRPC layer does.
    let data = qoi;
    let out = SessionOutput::new();
    m.insert(
        "publish",
        time(&mut || {
            let stages = ["input", "samples", "edges", "reproject", "rasterize", "reach", "interpolate", "antialias", "sampling", "encode"];
            out.publish_frame(pb::Frame {
                sequence: 1,
                width: w,
                height: h,
                encoding: FrameEncoding::Qoi as i32,
                data: data.clone(),
                stages: stages.iter().map(|s| pb::StageTime { stage: s.to_string(), ms: 1.0 }).collect(),
                ..Default::default()
            });
            let msg = out.try_next().expect("the frame just published");
            drop(msg.encode_to_vec());
        }),
    );
    Ok(m)
}

/// EXR writes of the frame's half floats with each lossless compression: median wall-clock
/// ms and file bytes.
fn measure_exr(frame: &[Vec3], w: u32, h: u32, iterations: usize) -> Result<serde_json::Value> {
    let lin = linear_frame::LinearFrame::from_linear(frame, w, h);
    let dir = std::env::temp_dir().join(format!("edgepoint-bench-exr-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let path = dir.join("frame.exr");
    let mut out = serde_json::Map::new();
    for (name, c) in [("uncompressed", Compression::Uncompressed), ("rle", Compression::RLE), ("zip16", Compression::ZIP16), ("piz", Compression::PIZ)] {
        let mut v = Vec::with_capacity(iterations);
        for i in 0..iterations.min(10) + 1 {
            let t0 = wall_ms();
            write_half_with(&path, &lin, c)?;
            if i > 0 {
                v.push(wall_ms() - t0);
            }
        }
        let bytes = std::fs::metadata(&path)?.len();
        out.insert(name.into(), json!({ "write_ms": median(&v), "bytes": bytes }));
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(out.into())
}

pub fn run(args: EncodeArgs) -> Result<()> {
    if args.iterations == 0 {
        bail!("--iterations must be at least 1");
    }
    if let Some(s) = args.sizes.iter().find(|&&s| !(8..=8192).contains(&s)) {
        bail!("--sizes {s}: frame sizes must be in [8, 8192]");
    }
    if !(args.density > 0.0 && args.density <= 1.0) {
        bail!("--density {} is not in (0, 1]", args.density);
    }
    let frames: Vec<(String, u32, u32, Vec<Vec3>)> = match &args.image {
        Some(path) => {
            let img = image::open(path).with_context(|| format!("reading {}", path.display()))?.into_rgb8();
            let frame = img.pixels().map(|p| srgb8_to_linear(p.0)).collect();
            vec![(path.display().to_string(), img.width(), img.height(), frame)]
        }
        None => {
            let staged = Staged::load(&args.scene, "direct", &HashMap::new())?;
            let mut v = Vec::new();
            for &size in &args.sizes {
                let cam = staged.camera(size, size);
                let picks = jittered_picks(size, size, args.density, 0x0e91);
                let samples = staged.shade(&cam, &picks, 1);
                let cache = reconstructed_frame(&staged, &cam, &samples);
                v.push((args.scene.clone(), size, size, cache.image().to_vec()));
            }
            v
        }
    };
    let all = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let pools = [(1usize, rayon::ThreadPoolBuilder::new().num_threads(1).build()?), (all, rayon::ThreadPoolBuilder::new().num_threads(all).build()?)];
    let mut runs = Vec::new();
    let mut table = String::new();
    use std::fmt::Write;
    writeln!(table, "frame encoding, median of {} runs (ms; 1 thread: thread CPU time, more: wall clock)", args.iterations)?;
    writeln!(
        table,
        "  {:>24} {:>3} | {:>9} {:>6} {:>7} | {:>9} {:>6} {:>7} | {:>9} {:>6} | {:>7} {:>9}",
        "frame", "thr", "qoi base", "qoi", "ratio", "raw base", "raw", "ratio", "srgb base", "srgb", "publish", "QOI bytes"
    )?;
    for (name, w, h, frame) in &frames {
        // The QOI frame decodes to the sRGB bytes, byte for byte; where those differ from
        // the baseline's, the new ones are the correctly rounded codes (the baseline's
        // boundaries were computed in f32).
        let mut rgb = Vec::new();
        to_srgb8(frame, *w, *h, &mut rgb)?;
        let mut before = Vec::new();
        baseline::to_srgb8(frame, *w as usize, &mut before);
        let ours = FrameEncoder::new().encode(frame, *w, *h, FrameEncoding::Qoi)?;
        let linear = FrameEncoder::new().encode(frame, *w, *h, FrameEncoding::LinearHalfLz4)?;
        if linear_frame::decode(&linear, *w, *h)? != linear_frame::LinearFrame::from_linear(frame, *w, *h) {
            bail!("{name}: the linear frame does not decode to the frame's half floats");
        }
        let exr = measure_exr(frame, *w, *h, args.iterations)?;
        let theirs = encode_srgb8(&rgb, *w, *h, FrameEncoding::Qoi)?;
        if decode_frame(&ours, FrameEncoding::Qoi, *w, *h)?.concat() != rgb {
            bail!("{name}: the QOI frame does not decode to the frame's sRGB bytes");
        }
        let channels: Vec<f32> = frame.iter().flat_map(|c| c.to_array()).collect();
        let mut differ = 0usize;
        for (i, (a, b)) in rgb.iter().zip(&before).enumerate() {
            if a != b {
                differ += 1;
                if *a != reference_code(channels[i]) {
                    bail!("{name}: channel {i} ({:e}) encodes to {a}, not the correctly rounded {}", channels[i], reference_code(channels[i]));
                }
            }
        }
        for (threads, pool) in &pools {
            let m = pool.install(|| measure(frame, *w, *h, args.iterations, *threads == 1))?;
            let ratio = |a: &str, b: &str| m[a] / m[b];
            writeln!(
                table,
                "  {:>24} {:>3} | {:>9.3} {:>6.3} {:>6.2}x | {:>9.3} {:>6.3} {:>6.2}x | {:>9.3} {:>6.3} | {:>7.3} {:>9}",
                format!("{name} {w}x{h}"),
                threads,
                m["encode_qoi_baseline"],
                m["encode_qoi"],
                ratio("encode_qoi_baseline", "encode_qoi"),
                m["encode_raw_baseline"],
                m["encode_raw"],
                ratio("encode_raw_baseline", "encode_raw"),
                m["srgb_baseline"],
                m["srgb"],
                m["publish"],
                ours.len(),
            )?;
            writeln!(
                table,
                "  {:>28} | linear {:>6.3} ms ({:.2}x QOI), {} bytes ({:.2}x QOI); viewer: decode {:.3} + tone map {:.3} ms vs QOI decode {:.3}",
                "",
                m["encode_linear"],
                ratio("encode_linear", "encode_qoi"),
                linear.len(),
                linear.len() as f64 / ours.len() as f64,
                m["viewer_decode_linear"],
                m["viewer_tonemap"],
                m["viewer_decode_qoi"],
            )?;
            if *threads == 1 {
                writeln!(table, "  {:>28} | EXR half writes (ms, bytes): {exr}", "")?;
            }
            runs.push(json!({
                "frame": name, "width": w, "height": h, "threads": threads,
                "clock": if *threads == 1 { "thread CPU time" } else { "wall clock" },
                "median_ms": m,
                "speedup_qoi": ratio("encode_qoi_baseline", "encode_qoi"),
                "speedup_raw": ratio("encode_raw_baseline", "encode_raw"),
                "speedup_srgb": ratio("srgb_baseline", "srgb"),
                "encode_qoi_plus_publish_ms": m["encode_qoi"] + m["publish"],
                "qoi_bytes": ours.len(),
                "qoi_bytes_image_crate": theirs.len(),
                "linear_bytes": linear.len(),
                "linear_over_qoi_bytes": linear.len() as f64 / ours.len() as f64,
                "linear_over_qoi_encode_time": ratio("encode_linear", "encode_qoi"),
                "viewer_linear_over_qoi_time": (m["viewer_decode_linear"] + m["viewer_tonemap"]) / m["viewer_decode_qoi"],
                "exr_half": exr.clone(),
                "channels_rounded_differently_from_baseline": differ,
            }));
        }
    }
    writeln!(table, "  qoi/raw base = the encoder before (table walk per channel + the image crate's QOI); srgb = conversion alone")?;
    writeln!(table, "  publish = the frame message handed to the session output, taken and serialised as gRPC does")?;
    crate::emit(args.json, &json!({ "scene": args.scene, "density": args.density, "iterations": args.iterations, "runs": runs }), &table);
    Ok(())
}
