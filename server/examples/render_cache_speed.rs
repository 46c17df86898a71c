//! Times the Render Cache's per-frame work (paper 000 §4.3 point reprojection, depth
//! culling, interpolation) and prioritized sampling (§5.3) on a synthetic scene: a floor
//! and a box, ray-traced analytically, filling the cache with its full capacity of points
//! shaded from slightly different views; then the camera orbits and every frame reprojects,
//! interpolates, picks the sample budget and inserts that many new samples.
//!
//! `cargo run --release -p edgepoint-server --example render_cache_speed -- --help`
//! (`RAYON_NUM_THREADS=1` for the one-core figure).
use clap::Parser;
use edgepoint_scene::camera::CameraFrame;
use edgepoint_scene::Camera;
use edgepoint_server::render_cache::{CacheConfig, RenderCache, Sample, STAGE_INTERPOLATE, STAGE_REPROJECT};
use edgepoint_server::sampling::{Sampler, SamplingConfig};
use edgepoint_server::stage_times::StageTimes;
use glam::Vec3;
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(about = "Time Render Cache reprojection/interpolation and prioritized sampling on synthetic points")]
struct Args {
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 512)]
    size: u32,
    /// Cache capacity in points per pixel.
    #[arg(long, default_value_t = 2.0)]
    points_per_pixel: f32,
    /// Frames to time (after 5 warm-up frames).
    #[arg(long, default_value_t = 60)]
    frames: u32,
    /// Pixels per new sample (the per-frame budget is pixels / sparseness).
    #[arg(long, default_value_t = 64.0)]
    sparseness: f64,
    /// Camera orbit per frame in degrees.
    #[arg(long, default_value_t = 0.5)]
    orbit_degrees: f32,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// Analytic scene: floor y = 0 (|x|, |z| < 4) and an axis-aligned box; misses are sky.
fn trace(cam: &CameraFrame, sx: f32, sy: f32, pixel: [u32; 2]) -> Sample {
    let (o, d) = cam.ray(sx, sy);
    let mut best = f32::INFINITY;
    let mut hit = None;
    if d.y.abs() > 1e-6 {
        let t = -o.y / d.y;
        let p = o + d * t;
        if t > 0.0 && p.x.abs() < 4.0 && p.z.abs() < 4.0 {
            best = t;
            let checker = ((p.x.floor() + p.z.floor()) as i32).rem_euclid(2) as f32;
            hit = Some((p, Vec3::Y, Vec3::splat(0.3 + 0.5 * checker), 0u32));
        }
    }
    let (lo, hi) = (Vec3::new(-0.7, 0.0, -0.7), Vec3::new(0.7, 1.2, 0.7));
    let inv = d.recip();
    let (t0, t1) = ((lo - o) * inv, (hi - o) * inv);
    let (tmin, tmax) = (t0.min(t1).max_element(), t0.max(t1).min_element());
    if tmin > 0.0 && tmin <= tmax && tmin < best {
        let p = o + d * tmin;
        let c = (p - (lo + hi) * 0.5) / ((hi - lo) * 0.5);
        let a = c.abs();
        let n = if a.x >= a.y && a.x >= a.z {
            Vec3::X * c.x.signum()
        } else if a.y >= a.z {
            Vec3::Y * c.y.signum()
        } else {
            Vec3::Z * c.z.signum()
        };
        hit = Some((p, n, Vec3::new(0.8, 0.3, 0.2) * (0.5 + 0.5 * n.dot(Vec3::new(0.3, 0.8, 0.5)).max(0.0)), 1));
    }
    match hit {
        Some((position, normal, color, object)) => Sample { hit: true, position, normal, color, object, epoch: 0, pixel },
        None => Sample { hit: false, position: d, normal: Vec3::ZERO, color: Vec3::new(0.5, 0.7, 1.0), object: u32::MAX, epoch: 0, pixel },
    }
}

fn main() {
    let args = Args::parse();
    let n = args.size;
    let base = Camera { eye: Vec3::new(3.0, 2.5, 4.0), target: Vec3::new(0.0, 0.4, 0.0), up: Vec3::Y, fov_y_degrees: 45.0 };
    let mut cache = RenderCache::new(CacheConfig { width: n, height: n, points_per_pixel: args.points_per_pixel, background: Vec3::ZERO });
    let mut rng = edgepoint_server::rng::Rng::new(1);

    // Fill the whole pool from views around the start (a cache after some interaction).
    let t_fill = Instant::now();
    let mut filled = 0usize;
    let mut view = 0;
    while filled < cache.capacity() {
        let cam = base.orbit(Vec3::ZERO, (view as f32 - 4.0) * 0.02).frame(n, n);
        view += 1;
        for y in 0..n {
            for x in 0..n {
                if filled >= cache.capacity() {
                    break;
                }
                let s = trace(&cam, x as f32 + rng.unit(), y as f32 + rng.unit(), [x, y]);
                filled += usize::from(cache.insert(&s));
            }
        }
    }
    let fill_ms = t_fill.elapsed().as_secs_f64() * 1e3;

    let cfg = SamplingConfig { sparseness: args.sparseness, max_age_frames: 120.0 };
    let budget = cfg.budget((n * n) as usize);
    let mut sampler = Sampler::new(n, n, 7);
    let mut picks = Vec::with_capacity(budget);
    let mut times = StageTimes::new();
    // Per stage: (sum, min) over the timed frames. The minimum is robust against the
    // process being descheduled on a busy machine.
    let mut sums: Vec<(&'static str, f64, f64)> = Vec::new();
    let mut last_counts = None;
    let warmup = 5;
    for f in 0..warmup + args.frames {
        times.clear();
        let cam = base.orbit(Vec3::ZERO, (f as f32 * args.orbit_degrees).to_radians()).frame(n, n);
        let counts = cache.reproject_and_interpolate(&cam, &mut times);
        times.time("sampling", || {
            sampler.select(cache.filter_weights(), &cache.point_image().age, &cfg, budget, &mut picks);
        });
        // Shading is the workers' job; trace outside the timed region, time only the inserts.
        let samples: Vec<Sample> = picks.iter().map(|p| trace(&cam, p.sx, p.sy, [p.x, p.y])).collect();
        times.time("insert", || {
            for s in &samples {
                cache.insert(s);
            }
        });
        if f >= warmup {
            for &(name, ms) in &times.stages {
                match sums.iter_mut().find(|(s, _, _)| *s == name) {
                    Some((_, t, m)) => {
                        *t += ms;
                        *m = m.min(ms);
                    }
                    None => sums.push((name, ms, ms)),
                }
            }
            last_counts = Some((counts, picks.len()));
        }
    }
    let frames = args.frames.max(1) as f64;
    let threads = rayon::current_num_threads();
    let (counts, picked) = last_counts.expect("at least one timed frame");
    let per = |name: &str| sums.iter().find(|(s, _, _)| *s == name).map_or(0.0, |(_, t, _)| t / frames);
    let min = |name: &str| sums.iter().find(|(s, _, _)| *s == name).map_or(0.0, |(_, _, m)| *m);
    let total: f64 = sums.iter().map(|(_, t, _)| t / frames).sum();
    let total_min: f64 = sums.iter().map(|(_, _, m)| m).sum();
    if args.json {
        println!(
            "{{\"size\":{n},\"points\":{},\"threads\":{threads},\"frames\":{},\"budget\":{budget},\"picked\":{picked},\"mean_ms\":{{\"{STAGE_REPROJECT}\":{:.3},\"{STAGE_INTERPOLATE}\":{:.3},\"sampling\":{:.3},\"insert\":{:.3},\"total\":{:.3}}},\"min_ms\":{{\"{STAGE_REPROJECT}\":{:.3},\"{STAGE_INTERPOLATE}\":{:.3},\"sampling\":{:.3},\"insert\":{:.3},\"total\":{:.3}}},\"with_point\":{},\"filled\":{},\"empty\":{},\"occluded\":{}}}",
            cache.len(),
            args.frames,
            per(STAGE_REPROJECT),
            per(STAGE_INTERPOLATE),
            per("sampling"),
            per("insert"),
            total,
            min(STAGE_REPROJECT),
            min(STAGE_INTERPOLATE),
            min("sampling"),
            min("insert"),
            total_min,
            counts.with_point,
            counts.filled,
            counts.empty,
            counts.occluded
        );
    } else {
        println!("{n}x{n}, {} cached points, {threads} rayon threads, fill {fill_ms:.0} ms", cache.len());
        println!("per frame over {} frames (orbit {} deg/frame):   mean       min", args.frames, args.orbit_degrees);
        for (name, t, m) in &sums {
            println!("  {name:<12} {:8.3} ms {m:8.3} ms", t / frames);
        }
        println!("  {:<12} {total:8.3} ms {total_min:8.3} ms", "total");
        println!(
            "last frame: {} with point, {} filled, {} empty, {} occluded; {picked} of {budget} budget picked",
            counts.with_point, counts.filled, counts.empty, counts.occluded
        );
    }
}
