//! `edgepoint-bench quality`: image quality of edge-and-point reconstruction against the
//! Render Cache's interpolation from the same samples (paper 000 Fig. 11), as PSNR and SSIM
//! against the converged reference.
//!
//! One fixed set of jittered pixels is shaded once per scene (in-process, deterministic); the
//! sample set of each density is the pixels whose hashed rank is below it (so the 1 % set is
//! part of the 5 % set, which is part of the 20 % set). Each set goes into a Render Cache,
//! is reprojected once, and is reconstructed both ways.
use crate::inprocess::{cache_with, jittered_picks, write_image, write_png, Staged};
use anyhow::{bail, Result};
use edgepoint_server::edges::finder::EdgeFinder;
use edgepoint_server::edges::EdgeCounts;
use edgepoint_server::epi::{Epi, InterpOptions, OwnSample, Overlay};
use edgepoint_server::reference::LogProgress;
use edgepoint_server::image_metrics::{psnr, ssim};
use edgepoint_server::epi::spread::BaselineHoles;
use edgepoint_server::render_cache::holes::HoleFill;
use edgepoint_server::stage_times::StageTimes;
use glam::{Affine3A, Vec3};
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct QualityArgs {
    /// Scene (repeatable): a built-in name or a scene file (.ply, .obj, Mitsuba .xml, .gltf, .glb; also .gz) (a bare model is staged on a
    /// floor under a point light).
    #[arg(long)]
    pub scene: Vec<String>,
    /// The four scenes of the issue: cornell-point (hard shadows), cornell (soft shadows), and
    /// the bunny and the dragon from --data-dir on a floor under a point light.
    #[arg(long)]
    pub all: bool,
    /// Directory of the shared models (bunny/bun_zipper.ply, dragon/dragon_vrip.ply).
    /// Default: $EDGEPOINT_DATA, else a shared/data directory in or above the working
    /// directory or this executable.
    #[arg(long = "data-dir", visible_alias = "data", value_name = "DIR")]
    pub data: Option<PathBuf>,
    #[arg(long, default_value_t = 512)]
    pub width: u32,
    #[arg(long, default_value_t = 512)]
    pub height: u32,
    /// Fractions of pixels holding a sample (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "0.01,0.05,0.2")]
    pub densities: Vec<f64>,
    /// Samples per pixel of the converged reference.
    #[arg(long, default_value_t = 64)]
    pub reference_spp: u32,
    /// Directory caching converged references (shared with `frame`). Default:
    /// $XDG_CACHE_HOME/edgepoint/references (else ~/.cache/edgepoint/references).
    #[arg(long, value_name = "DIR")]
    pub ref_cache: Option<PathBuf>,
    /// Seed of the pixel set and its jitter.
    #[arg(long, default_value_t = 0x5a3e)]
    pub seed: u64,
    /// Shader parameter KEY=VALUE (repeatable), e.g. shadow_rays=16.
    #[arg(long = "shader-param", value_parser = crate::frame::parse_param)]
    pub shader_params: Vec<(String, f64)>,
    /// Write the reference, both reconstructions and the EPI class overlay of every density
    /// as files into DIR/<scene>/ (PNG, or EXR for the images of radiance with --format exr).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// File format of the reference and the reconstructions --out writes: png (8-bit sRGB,
    /// clipped) or exr (linear RGB float, never tone-mapped or clipped). The class and
    /// sample overlays are always PNG.
    #[arg(long, value_enum, default_value_t = edgepoint_viewer::headless::FileFormat::Png)]
    pub format: edgepoint_viewer::headless::FileFormat,
    /// Tuning: interpolation kernel sigma in pixels.
    #[arg(long, default_value_t = edgepoint_server::epi::DEFAULT_SIGMA)]
    pub sigma: f32,
    /// Tuning: filter a pixel's own sample with its neighbours instead of showing it.
    #[arg(long)]
    pub filter_own: bool,
    /// Tuning: pixels that reach no sample take the unconstrained window mean (edge-blind)
    /// instead of spreading colour from their region.
    #[arg(long)]
    pub fallback: bool,
    /// Leave the pixels no sample reaches at the background in both reconstructions (the
    /// renderer spreads colour into them from their neighbours — within their region for
    /// edge-and-point, ignoring edges for the baseline — then fills the rest from coarser
    /// sample averages).
    #[arg(long)]
    pub no_hole_fill: bool,
    /// Ablation: run edge-and-point reconstruction with no edges at all (what remains of its
    /// gain is not the edges' doing).
    #[arg(long)]
    pub no_edges: bool,
    /// Ablation: geometric edges only (silhouettes, sharp, boundary), no shadow edges.
    #[arg(long)]
    pub no_shadow_edges: bool,
    /// Turn the complex filter off.
    #[arg(long)]
    pub no_complex_filter: bool,
    /// Diagnosis: print how the EPI saw pixel X,Y and its 3 × 3 neighbours (flags, code,
    /// region, crossing masks, point, reconstructed colour and the reference) for every
    /// scene and density
    #[arg(long, value_name = "X,Y", value_parser = parse_pixel)]
    pub explain: Option<(usize, usize)>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: QualityArgs) -> Result<()> {
    let mut scenes = args.scene.clone();
    if args.all {
        for s in ["cornell-point", "cornell"] {
            scenes.push(s.to_string());
        }
        for m in ["bunny/bun_zipper.ply", "dragon/dragon_vrip.ply"] {
            let path = edgepoint_scene::data::find_file(m, args.data.as_deref()).map_err(anyhow::Error::msg)?;
            scenes.push(path.display().to_string());
        }
    }
    if scenes.is_empty() {
        bail!("name a scene with --scene (repeatable) or use --all");
    }
    if let Some(d) = args.densities.iter().find(|d| !(**d > 0.0 && **d <= 1.0)) {
        bail!("--densities: {d} is not in (0, 1]");
    }
    let params: HashMap<String, f64> = args.shader_params.iter().cloned().collect();
    let options = InterpOptions {
        sigma: args.sigma,
        own_sample: if args.filter_own { OwnSample::Filter } else { OwnSample::Show },
        fallback: args.fallback,
    };
    let (w, h) = (args.width, args.height);
    let mut results = Vec::new();
    let mut table = String::new();
    use std::fmt::Write;
    writeln!(table, "quality at {w}x{h} vs {} spp reference (PSNR dB / SSIM)", args.reference_spp)?;
    writeln!(
        table,
        "  {:<16} {:>7} {:>8} | {:>16} {:>16} | {:>7} | {:>6} {:>6} {:>6} {:>7} {:>7}",
        "scene", "density", "samples", "render cache", "edge-and-point", "dPSNR", "simple", "cmplx", "ambig", "spread", "holes"
    )?;
    let mut notes = String::new();
    for name in &scenes {
        let staged = Staged::load(name, "direct", &params)?;
        let tag = std::path::Path::new(name).file_stem().map_or(name.clone(), |s| s.to_string_lossy().into_owned());
        let (reference, cached) = staged.reference(w, h, args.reference_spp, args.ref_cache.as_deref())?;
        tracing::info!("{name}: reference {}", if cached { "from the cache" } else { "rendered" });
        let cam = staged.camera(w, h);
        let top = args.densities.iter().cloned().fold(0.0, f64::max);
        let picks = jittered_picks(w, h, top, args.seed);
        let (shaded, triples) = staged.shade_with_triples(&cam, &picks, args.seed);
        let transforms: Vec<Affine3A> = staged.loaded.scene.objects.iter().map(|o| o.transform).collect();
        // The edges a session has once its edge trees are built and the shadow store has
        // taken the triples this shading reported (paper §6): silhouettes, sharp and
        // boundary edges, and the shadow edges on the receivers the triples name.
        let mut edges = Vec::new();
        if !args.no_edges {
            let mut finder = EdgeFinder::new(&staged.loaded.scene, &LogProgress::new(&format!("edge trees of {tag}")));
            let triples = if args.no_shadow_edges { Vec::new() } else { triples };
            finder.frame(&transforms, cam.eye, None, triples, edgepoint_server::edges::DEFAULT_SHARP_CUTOFF_DEGREES, &mut edges);
            // As a session draws them: soft-shadow edges only where their penumbra is
            // narrow on screen (edgepoint_server::epi::soft).
            edges.retain(|e| e.kind.is_geometric());
            let screen = edgepoint_server::epi::raster::SegmentProjector::new(&cam, w as usize, h as usize);
            edgepoint_server::epi::soft::append_barriers(&finder.shadow_penumbrae(), Some(&screen), &mut edges);
        }
        let edge_counts = EdgeCounts::of(&edges);
        let background = staged.loaded.scene.background;
        let dir = args.out.as_ref().map(|d| d.join(&tag));
        if let Some(d) = &dir {
            std::fs::create_dir_all(d)?;
            write_image(&d.join("reference"), args.format, w, h, &reference)?;
        }
        // Hard shadow boundaries (point lights): the error there is reported apart, to show
        // what the shadow edges do (compare with --no-shadow-edges).
        let shadow = staged.shadow_boundaries(&cam, 2);
        let mut epi = Epi::new(w, h);
        let mut fill = HoleFill::new(w, h);
        let mut baseline_holes = BaselineHoles::default();
        for &density in &args.densities {
            let samples: Vec<_> = picks.iter().zip(&shaded).filter(|(p, _)| (p.rank as f64) < density).map(|(_, s)| *s).collect();
            let mut cache = cache_with(w, h, &cam, &samples, background);
            let mut t = StageTimes::new();
            // Both reconstructions as the renderer runs them, holes filled the same way.
            cache.interpolate_gaps(&mut t);
            let (points, image, weights) = cache.reconstruction_target();
            if !args.no_hole_fill {
                baseline_holes.fill(points, weights, image, &mut fill, None);
            }
            let baseline = cache.image().to_vec();
            let counts = epi.build(&edges, &cam, cache.point_image(), !args.no_complex_filter, &mut t);
            let (points, image, weights) = cache.reconstruction_target();
            let rec = epi.reconstruct(points, background, &options, !args.no_complex_filter, image, weights, &mut t);
            if !args.no_hole_fill {
                fill.fill(points, epi.holes(), image);
            }
            let epr = cache.image().to_vec();
            if let Some((x, y)) = args.explain {
                if x < w as usize && y < h as usize {
                    let r = reference[y * w as usize + x];
                    eprintln!("{tag} at {:.1}% density, pixel ({x},{y}), reference ({:.3},{:.3},{:.3}):\n{}", density * 100.0, r.x, r.y, r.z, epi.explain(x, y, 1, cache.point_image(), &epr));
                } else {
                    eprintln!("--explain {x},{y} is outside the {w}x{h} image");
                }
            }
            let (pb, pe) = (psnr(&baseline, &reference), psnr(&epr, &reference));
            let (sb, se) = (ssim(&baseline, &reference, w, h), ssim(&epr, &reference, w, h));
            // PSNR away from hard shadow boundaries, and the share of the squared error at them.
            let off_shadow = shadow.as_ref().map(|mask| {
                let keep = |img: &[Vec3]| img.iter().zip(mask).filter(|(_, m)| !**m).map(|(c, _)| *c).collect::<Vec<Vec3>>();
                let r = keep(&reference);
                let (b, e) = (psnr(&keep(&baseline), &r), psnr(&keep(&epr), &r));
                let share = |img: &[Vec3]| {
                    let err = |c: Vec3, r: Vec3| (0..3).map(|k| {
                        let d = edgepoint_server::image_metrics::linear_to_srgb(c[k]) as f64 - edgepoint_server::image_metrics::linear_to_srgb(r[k]) as f64;
                        d * d
                    }).sum::<f64>();
                    let (mut at, mut all) = (0.0, 0.0);
                    for ((c, r), m) in img.iter().zip(&reference).zip(mask) {
                        let e = err(*c, *r);
                        all += e;
                        if *m {
                            at += e;
                        }
                    }
                    if all > 0.0 { at / all } else { 0.0 }
                };
                json!({
                    "pixels_near_shadow_boundaries": mask.iter().filter(|m| **m).count(),
                    "render_cache_psnr_db": b, "edge_and_point_psnr_db": e, "psnr_gain_db": e - b,
                    "render_cache_error_share_at_shadow_boundaries": share(&baseline),
                    "edge_and_point_error_share_at_shadow_boundaries": share(&epr),
                })
            });
            writeln!(
                table,
                "  {:<16} {:>6.1}% {:>8} | {:>7.2} / {:.4} {:>7.2} / {:.4} | {:>+7.2} | {:>6} {:>6} {:>6} {:>7} {:>7}",
                tag,
                density * 100.0,
                samples.len(),
                pb,
                sb,
                pe,
                se,
                pe - pb,
                counts.simple,
                counts.complex,
                counts.ambiguous_samples,
                rec.spread,
                rec.interp.empty
            )?;
            if let Some(o) = &off_shadow {
                writeln!(
                    notes,
                    "  {:<16} {:>6.1}%: off hard shadow boundaries {:.2} vs {:.2} dB ({:+.2}); share of the squared error at them: {:.0}% / {:.0}%",
                    tag,
                    density * 100.0,
                    o["render_cache_psnr_db"].as_f64().unwrap_or(0.0),
                    o["edge_and_point_psnr_db"].as_f64().unwrap_or(0.0),
                    o["psnr_gain_db"].as_f64().unwrap_or(0.0),
                    100.0 * o["render_cache_error_share_at_shadow_boundaries"].as_f64().unwrap_or(0.0),
                    100.0 * o["edge_and_point_error_share_at_shadow_boundaries"].as_f64().unwrap_or(0.0),
                )?;
            }
            results.push(json!({
                "scene": name, "density": density, "samples": samples.len(),
                "render_cache": { "psnr_db": pb, "ssim": sb },
                "edge_and_point": { "psnr_db": pe, "ssim": se },
                "psnr_gain_db": pe - pb,
                "pixel_classes": { "empty": counts.empty, "simple": counts.simple, "complex": counts.complex },
                "off_hard_shadow_boundaries": off_shadow,
                "samples_usable": counts.usable_samples, "samples_ambiguous": counts.ambiguous_samples,
                "pixels_unreached_fallback": rec.interp.fallback, "pixels_spread": rec.spread,
                "pixels_without_reachable_sample": rec.interp.empty,
                "edges": edges.len(), "fragments": counts.raster.fragments, "culled": counts.raster.culled,
                "edge_kinds": { "silhouette": edge_counts.silhouette, "sharp": edge_counts.sharp, "boundary": edge_counts.boundary, "shadow": edge_counts.shadow },
            }));
            if let Some(d) = &dir {
                let pct = format!("{:04.1}", density * 100.0);
                write_image(&d.join(format!("render_cache_{pct}")), args.format, w, h, &baseline)?;
                write_image(&d.join(format!("epr_{pct}")), args.format, w, h, &epr)?;
                let mut classes = epr.clone();
                epi.draw_overlay(Overlay::Classes, &mut classes);
                write_png(&d.join(format!("classes_{pct}.png")), w, h, &classes)?;
                let mut samples_img: Vec<Vec3> = epr.clone();
                epi.draw_overlay(Overlay::Samples, &mut samples_img);
                write_png(&d.join(format!("samples_{pct}.png")), w, h, &samples_img)?;
            }
        }
    }
    table.push_str(&notes);
    let out = json!({
        "width": w, "height": h, "reference_spp": args.reference_spp, "seed": args.seed,
        "options": { "sigma": options.sigma, "own_sample": format!("{:?}", options.own_sample), "fallback": options.fallback, "complex_filter": !args.no_complex_filter, "hole_fill": !args.no_hole_fill },
        "results": results,
    });
    crate::emit(args.json, &out, &table);
    Ok(())
}

fn parse_pixel(s: &str) -> Result<(usize, usize), String> {
    let (x, y) = s.split_once(',').ok_or_else(|| format!("'{s}' is not X,Y"))?;
    let p = |v: &str| v.trim().parse::<usize>().map_err(|_| format!("'{v}' in '{s}' is not a pixel coordinate"));
    Ok((p(x)?, p(y)?))
}
