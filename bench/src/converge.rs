//! `edgepoint-bench converge`: converging at rest (issue 14 item 3). A still camera on a
//! still scene, two renderers on the same workers and shader, each for `--seconds` of wall
//! time, their images compared with the converged reference at fixed time points:
//!
//! - **edge-and-point**: a session as the viewer runs it (linear half-float frames, so the
//!   comparison is not limited by 8-bit quantisation); at each time point, the last frame
//!   received. Time starts when the session has started (the scene is loaded).
//! - **progressive**: every pixel, one jittered sample per pass (stratified over groups of 16
//!   passes), accumulated per pixel; at each time point, the mean of every sample received
//!   (pixels without one are black). The workers load the scene before its time starts.
//!
//! Each renderer (and the reference, when it is not cached) runs on workers started for it,
//! so both start cold: neither finds the other's irradiance records.
//!
//! The verdict says whether edge-and-point is ahead (higher PSNR) at every time point.
//!
//! Where each renderer's last image is wrong: the squared error (sRGB, as the PSNR counts it)
//! of the worst pixels and the worst rows, as shares of the whole image's, with the pixels'
//! shown and reference colours (`*_error` in the JSON; `--out` adds error maps). A plateau
//! that sits in a few pixels is reconstruction, not noise.
use crate::frame::{converged_reference, open_dispatcher, start_cluster, start_message, PaceArgs, SceneArgs};
use crate::inprocess::write_image;
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_scene::Camera;
use edgepoint_server::image_metrics::psnr;
use edgepoint_server::reference::{pixel_batches, subpixel_position, FullFrameSpec, ReferenceOptions};
use edgepoint_server::rng::mix64;
use edgepoint_server::workers::Dispatcher;
use edgepoint_viewer::client::{scene_source_from_arg_in, Event, SessionClient};
use edgepoint_viewer::headless::FileFormat;
use glam::Vec3;
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Samples per pixel of the converged reference unless `--spp` says: well above what either
/// renderer reaches in 30 s, so that the reference's own noise stays a small part of the
/// error measured.
pub const DEFAULT_CONVERGE_REFERENCE_SPP: u32 = 1024;

/// Passes of the progressive renderer whose jittered positions share one stratification.
const PROGRESSIVE_STRATA: u32 = 16;

#[derive(clap::Args, Debug)]
pub struct ConvergeArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Wall time each renderer gets, in seconds.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Seconds between time points (there are two more, at 1/4 and 1/2 of it).
    #[arg(long, default_value_t = 1.0)]
    pub interval: f64,
    /// The edge-and-point session's pace.
    #[command(flatten)]
    pub pace: PaceArgs,
    /// Write both renderers' last images and the reference into this directory (PNG, or
    /// linear float EXR with --format exr).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// File format of the images --out writes.
    #[arg(long, value_enum, default_value_t = FileFormat::Png)]
    pub format: FileFormat,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// One renderer's image at one time point.
#[derive(Debug, Clone, Copy)]
struct Point {
    psnr_db: f64,
    /// Samples shaded for the image so far, per pixel.
    samples_per_pixel: f64,
}

/// The time points of a run: `interval / 4`, `interval / 2`, then every `interval` up to
/// `seconds`.
fn time_points(seconds: f64, interval: f64) -> Vec<f64> {
    let mut t = vec![interval / 4.0, interval / 2.0];
    let mut k = 1.0;
    while k * interval <= seconds + 1e-9 {
        t.push(k * interval);
        k += 1.0;
    }
    t.retain(|&x| x <= seconds + 1e-9);
    t
}

pub fn run(args: ConvergeArgs) -> Result<()> {
    let a = &args.scene;
    if !(args.seconds > 0.0 && args.seconds.is_finite() && args.interval > 0.0 && args.interval.is_finite()) {
        bail!("--seconds and --interval must be positive");
    }
    let points = time_points(args.seconds, args.interval);
    let source = scene_source_from_arg_in(&a.scene, a.data_dir.as_deref())?;
    let scene = pb::scene_from_source(&source, &edgepoint_scene::NoProgress).map_err(|e| anyhow::anyhow!("{}: {e}", a.scene))?;
    let camera = match a.camera {
        Some(c) => c.apply(&scene.camera).map_err(|e| anyhow::anyhow!("--camera: {e}"))?,
        None => scene.camera,
    };
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
    // Each render gets workers of its own: a worker keeps what it learnt of a scene (the
    // `gi` shader's irradiance records), so workers shared with an earlier render would
    // start the later one warm — with `cache_rays=1024` the progressive renderer, run first,
    // spent its first 10 s making the records the session then found made.
    rt.block_on(async {
        let spp = a.reference_spp.unwrap_or(DEFAULT_CONVERGE_REFERENCE_SPP);
        let (reference, reference_cached) = {
            let cluster = start_cluster(a)?;
            let dispatcher = open_dispatcher(&cluster, &source)?;
            converged_reference(&dispatcher, a, &source, &camera, spp).await?
        };
        let reference = reference.pixels;

        tracing::info!("converge: progressive full frames for {} s", args.seconds);
        let (progressive, progressive_image, passes) = {
            let cluster = start_cluster(a)?;
            let dispatcher = open_dispatcher(&cluster, &source)?;
            progressive_run(&dispatcher, a, &camera, &points, &reference).await?
        };

        tracing::info!("converge: edge-and-point session for {} s", args.seconds);
        let cluster = start_cluster(a)?;
        let (epr, epr_image, frames, requested) = session_run(&cluster, &args, &source, &points, &reference).await?;
        drop(cluster);

        let behind: Vec<f64> = points.iter().zip(epr.iter().zip(&progressive)).filter(|(_, (e, p))| e.psnr_db <= p.psnr_db).map(|(&t, _)| t).collect();
        let verdict = if behind.is_empty() {
            "edge-and-point ahead at every time point".to_string()
        } else {
            format!("edge-and-point not ahead at {} of {} time points (first at {} s)", behind.len(), points.len(), behind[0])
        };
        if let Some(dir) = &args.out {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            write_image(&dir.join("converge_edge_and_point"), args.format, a.width, a.height, &epr_image)?;
            write_image(&dir.join("converge_progressive"), args.format, a.width, a.height, &progressive_image)?;
            write_image(&dir.join(format!("reference_{spp}spp")), args.format, a.width, a.height, &reference)?;
            write_error_map(&dir.join("converge_edge_and_point_error.png"), a.width, a.height, &epr_image, &reference)?;
            write_error_map(&dir.join("converge_progressive_error.png"), a.width, a.height, &progressive_image, &reference)?;
        }
        let series = |v: &[Point]| {
            json!({
                "psnr_db": v.iter().map(|p| p.psnr_db).collect::<Vec<_>>(),
                "samples_per_pixel": v.iter().map(|p| p.samples_per_pixel).collect::<Vec<_>>(),
            })
        };
        let out = json!({
            "scene": a.scene,
            "width": a.width,
            "height": a.height,
            "workers": a.workers,
            "worker_threads": a.worker_threads,
            "shader": a.shader,
            "shader_params": a.shader_params.iter().cloned().collect::<HashMap<_, _>>(),
            "reference_params": crate::frame::reference_params(a),
            "seconds": args.seconds,
            "reference_spp": spp,
            "reference_cached": reference_cached,
            "time_points_s": points,
            "edge_and_point": series(&epr),
            "edge_and_point_frames": frames,
            "edge_and_point_requested_per_pixel": requested as f64 / (a.width as f64 * a.height as f64),
            "progressive": series(&progressive),
            "progressive_passes": passes,
            "edge_and_point_error": hotspots(&epr_image, &reference, a.width as usize),
            "progressive_error": hotspots(&progressive_image, &reference, a.width as usize),
            "ahead_at_every_time_point": behind.is_empty(),
            "behind_at_s": behind,
            "verdict": verdict,
        });
        let mut table = format!(
            "converge: {} {}x{}, shader {}, {} workers, {} s each; PSNR (dB) against {spp} spp{}\n  {:>7}  {:>15} {:>9}  {:>12} {:>9}\n",
            a.scene, a.width, a.height, a.shader, a.workers, args.seconds,
            if reference_cached { " (cached)" } else { "" },
            "t (s)", "edge-and-point", "spp", "progressive", "spp"
        );
        for (k, t) in points.iter().enumerate() {
            table += &format!(
                "  {t:>7.2}  {:>15.2} {:>9.2}  {:>12.2} {:>9.2}\n",
                epr[k].psnr_db, epr[k].samples_per_pixel, progressive[k].psnr_db, progressive[k].samples_per_pixel
            );
        }
        table += &format!("  {frames} frames, {passes:.2} progressive passes; {verdict}\n");
        crate::emit(args.json, &out, &table);
        Ok(())
    })
}

/// Squared error of each pixel in sRGB, summed over the channels (what [`psnr`] averages).
fn pixel_errors(image: &[Vec3], reference: &[Vec3]) -> Vec<f64> {
    image.iter().zip(reference).map(|(c, r)| edgepoint_server::image_metrics::srgb_squared_error(*c, *r)).collect()
}

/// Where `image` is wrong: the shares of the squared error in the worst 1 % of the pixels,
/// the ten worst pixels (position, shown and reference colour) and the five worst rows.
fn hotspots(image: &[Vec3], reference: &[Vec3], width: usize) -> serde_json::Value {
    let err = pixel_errors(image, reference);
    let total: f64 = err.iter().sum();
    if total <= 0.0 || width == 0 {
        return json!({ "squared_error": total });
    }
    let mut order: Vec<usize> = (0..err.len()).collect();
    order.sort_by(|&a, &b| err[b].total_cmp(&err[a]));
    let top1: f64 = order[..err.len().div_ceil(100)].iter().map(|&i| err[i]).sum();
    let colour = |c: Vec3| [c.x, c.y, c.z];
    let pixels: Vec<_> = order[..10.min(order.len())]
        .iter()
        .map(|&i| json!({ "x": i % width, "y": i / width, "share": err[i] / total, "shown": colour(image[i]), "reference": colour(reference[i]) }))
        .collect();
    let mut rows: Vec<(usize, f64)> = err.chunks(width).map(|r| r.iter().sum()).enumerate().collect();
    rows.sort_by(|a, b| b.1.total_cmp(&a.1));
    let rows: Vec<_> = rows[..5.min(rows.len())].iter().map(|&(y, e)| json!({ "y": y, "share": e / total })).collect();
    json!({ "squared_error": total, "share_in_worst_1_percent_of_pixels": top1 / total, "worst_pixels": pixels, "worst_rows": rows })
}

/// A grey map of the square root of each pixel's squared error, scaled to its largest.
fn write_error_map(path: &std::path::Path, w: u32, h: u32, image: &[Vec3], reference: &[Vec3]) -> Result<()> {
    let err = pixel_errors(image, reference);
    let max = err.iter().cloned().fold(0.0, f64::max).sqrt().max(1e-12);
    let bytes: Vec<u8> = err.iter().map(|e| (255.0 * e.sqrt() / max).round() as u8).collect();
    image::save_buffer(path, &bytes, w, h, image::ExtendedColorType::L8).with_context(|| format!("writing {}", path.display()))
}

/// PSNR of `image` against `reference`, logged as progress.
fn measure(who: &str, t: f64, image: &[Vec3], reference: &[Vec3], samples_per_pixel: f64) -> Point {
    let p = Point { psnr_db: psnr(image, reference), samples_per_pixel };
    tracing::info!("converge: t={t:.2} s {who} {:.2} dB ({samples_per_pixel:.2} samples/pixel)", p.psnr_db);
    p
}

/// The progressive full-frame renderer: passes of one jittered sample per pixel until
/// `points` are all measured. Returns the series, the last image and the passes shaded.
async fn progressive_run(dispatcher: &Dispatcher, a: &SceneArgs, camera: &Camera, points: &[f64], reference: &[Vec3]) -> Result<(Vec<Point>, Vec<Vec3>, f64)> {
    let params: HashMap<String, f64> = a.shader_params.iter().cloned().collect();
    let cam = camera.frame(a.width, a.height);
    let opts = ReferenceOptions::default();
    let n = a.width as usize * a.height as usize;
    // The workers load the scene and build their BVHs before the clock starts.
    let warm = FullFrameSpec { epoch: dispatcher.epoch(), shader: &a.shader, params: &params, batch_size: 1, seed: 1 };
    let one = camera.frame(1, 1);
    dispatcher.shade_all(pixel_batches(&one, 1, &warm, |x, y, _| (x as f32 + 0.5, y as f32 + 0.5)), 1, opts.stall, |_| {}).await?;

    let (mut sum, mut count) = (vec![Vec3::ZERO; n], vec![0u32; n]);
    let mut image = vec![Vec3::ZERO; n];
    let mut shaded = 0u64;
    let mut series = Vec::with_capacity(points.len());
    let t0 = Instant::now();
    let mut pass = 0u32;
    while series.len() < points.len() {
        let spec = FullFrameSpec {
            epoch: dispatcher.epoch(),
            shader: &a.shader,
            params: &params,
            batch_size: opts.batch_size,
            seed: mix64(opts.seed ^ u64::from(pass)),
        };
        let (stratum, strata_seed) = (pass % PROGRESSIVE_STRATA, mix64(opts.seed ^ 0x5eed ^ u64::from(pass / PROGRESSIVE_STRATA)));
        let batches = pixel_batches(&cam, 1, &spec, move |x, y, _| subpixel_position(x, y, stratum, PROGRESSIVE_STRATA, strata_seed));
        dispatcher
            .shade_all(batches, opts.window, opts.stall, |b| {
                // The image at a time point holds what arrived before it.
                let t = t0.elapsed().as_secs_f64();
                while series.len() < points.len() && points[series.len()] <= t {
                    mean_image(&sum, &count, &mut image);
                    series.push(measure("progressive", points[series.len()], &image, reference, shaded as f64 / n as f64));
                }
                for s in &b.samples {
                    let c = pb::vec3_or_zero(&s.rgb);
                    if let Some(i) = usize::try_from(s.id).ok().filter(|&i| i < n && c.is_finite()) {
                        sum[i] += c;
                        count[i] += 1;
                        shaded += 1;
                    }
                }
            })
            .await
            .context("progressive pass")?;
        pass += 1;
    }
    mean_image(&sum, &count, &mut image);
    Ok((series, image, shaded as f64 / n as f64))
}

/// Per pixel the mean of its samples, black without one.
fn mean_image(sum: &[Vec3], count: &[u32], out: &mut [Vec3]) {
    for ((o, &s), &c) in out.iter_mut().zip(sum).zip(count) {
        *o = if c > 0 { s / c as f32 } else { Vec3::ZERO };
    }
}

/// The edge-and-point session at rest: at each time point, the last frame received (black
/// before the first). Returns the series, the last image, the frames received and the
/// requests the session issued (its samples are those of them it used).
async fn session_run(
    cluster: &edgepoint_viewer::local::LocalCluster,
    args: &ConvergeArgs,
    source: &pb::SceneSource,
    points: &[f64],
    reference: &[Vec3],
) -> Result<(Vec<Point>, Vec<Vec3>, u64, u64)> {
    let a = &args.scene;
    let n = a.width as usize * a.height as usize;
    let mut start = start_message(source, (a.width, a.height), (&a.shader, &a.shader_params), a.camera.as_ref(), args.pace.settings());
    start.encoding = pb::FrameEncoding::LinearHalfLz4 as i32;
    let (mut client, _started) = SessionClient::connect(&cluster.server_url(), start).await?;
    let t0 = Instant::now();
    let end = t0 + Duration::from_secs_f64(args.seconds);
    let mut last: Option<pb::Frame> = None;
    let (mut frames, mut samples, mut requested) = (0u64, 0u64, 0u64);
    let mut series = Vec::with_capacity(points.len());
    let shown = |f: Option<&pb::Frame>| -> Result<Vec<Vec3>> {
        Ok(match f {
            Some(f) => {
                let lin = pb::linear_frame::decode(&f.data, f.width, f.height).with_context(|| format!("frame {}", f.sequence))?;
                lin.to_f32().chunks_exact(3).map(|c| Vec3::new(c[0], c[1], c[2])).collect()
            }
            None => vec![Vec3::ZERO; n],
        })
    };
    loop {
        let now = Instant::now();
        if now >= end {
            break;
        }
        let ev = match tokio::time::timeout(end - now, client.next_event()).await {
            Err(_) => break,
            Ok(ev) => ev,
        };
        match ev {
            None => bail!("the session ended after {frames} frames"),
            Some(Err(e)) => return Err(e.into()),
            Some(Ok(Event::Rejected(r))) => bail!("server rejected a message: {}", r.message),
            Some(Ok(Event::Progress(_) | Event::Picked(_))) => {}
            Some(Ok(Event::Frame(f))) => {
                let t = t0.elapsed().as_secs_f64();
                while series.len() < points.len() && points[series.len()] <= t {
                    let image = shown(last.as_ref())?;
                    series.push(measure("edge-and-point", points[series.len()], &image, reference, samples as f64 / n as f64));
                }
                frames += 1;
                samples += u64::from(f.samples_used);
                requested += u64::from(f.samples_requested);
                last = Some(f);
            }
        }
    }
    let image = shown(last.as_ref())?;
    while series.len() < points.len() {
        series.push(measure("edge-and-point", points[series.len()], &image, reference, samples as f64 / n as f64));
    }
    Ok((series, image, frames, requested))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_points_start_early_and_end_at_the_run_s_length() {
        assert_eq!(time_points(3.0, 1.0), vec![0.25, 0.5, 1.0, 2.0, 3.0]);
        assert_eq!(time_points(0.4, 1.0), vec![0.25]);
        assert_eq!(time_points(30.0, 5.0), vec![1.25, 2.5, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0]);
    }

    #[test]
    fn hotspots_name_the_worst_pixels_and_rows_with_their_shares() {
        // A 4 x 3 image, exact but for pixel (1, 2) (error 3 x 0.25) and pixel (3, 0)
        // (error 0.25 in one channel).
        let reference = vec![Vec3::ZERO; 12];
        let mut image = reference.clone();
        image[2 * 4 + 1] = Vec3::splat(edgepoint_server::image_metrics::srgb_to_linear(0.5));
        image[3] = Vec3::new(edgepoint_server::image_metrics::srgb_to_linear(0.5), 0.0, 0.0);
        let h = hotspots(&image, &reference, 4);
        assert!((h["squared_error"].as_f64().unwrap() - 1.0).abs() < 1e-6, "{h}");
        assert_eq!((h["worst_pixels"][0]["x"].as_u64(), h["worst_pixels"][0]["y"].as_u64()), (Some(1), Some(2)));
        assert!((h["worst_pixels"][0]["share"].as_f64().unwrap() - 0.75).abs() < 1e-6, "{h}");
        assert!((h["worst_pixels"][1]["share"].as_f64().unwrap() - 0.25).abs() < 1e-6, "{h}");
        // 1 % of 12 pixels rounds up to the worst one.
        assert!((h["share_in_worst_1_percent_of_pixels"].as_f64().unwrap() - 0.75).abs() < 1e-6, "{h}");
        assert_eq!(h["worst_rows"][0]["y"].as_u64(), Some(2));
        assert_eq!(h["worst_rows"][1]["y"].as_u64(), Some(0));
        assert_eq!(hotspots(&reference, &reference, 4)["squared_error"].as_f64(), Some(0.0));
    }

    #[test]
    fn the_mean_image_is_black_where_nothing_arrived() {
        let mut out = vec![Vec3::ONE; 2];
        mean_image(&[Vec3::splat(3.0), Vec3::ZERO], &[2, 0], &mut out);
        assert_eq!(out, vec![Vec3::splat(1.5), Vec3::ZERO]);
    }
}
