//! Issue 12 item 3: a session's memory is accounted by adding up each structure's own
//! `bytes_for`. These tests hold every `bytes_for` to what a counting allocator sees its
//! constructor (and first frames) allocate, and the whole estimate to what a running
//! session allocates — so a buffer added to a structure without its `bytes_for`, or to the
//! session beside them, fails here. (Own test binary: the counters are global.)
mod common;

use edgepoint_scene::alloc_count::{self, CountingAlloc, Usage};
use edgepoint_scene::Camera;
use edgepoint_server::epi::spread::BaselineHoles;
use edgepoint_server::epi::{Epi, InterpOptions};
use edgepoint_server::render_cache::holes::{HoleFill, ObjectFill};
use edgepoint_server::render_cache::{CacheConfig, RenderCache, Sample};
use edgepoint_server::sampling::Sampler;
use edgepoint_server::session::memory::SessionMemory;
use edgepoint_server::session::{RequestRing, SessionSettings};
use edgepoint_server::stage_times::StageTimes;
use edgepoint_server::visibility::Visibility;
use glam::Vec3;
use std::sync::Mutex;

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

/// One measurement at a time (the counters see every thread).
static ONE: Mutex<()> = Mutex::new(());

/// A measurement that nothing else in this binary disturbs: the global rayon pool exists
/// already (its threads and queues are built on first use, which is not the measured
/// structure's memory), and threads of an earlier test (the session test's worker pool and
/// runtimes wind down after it returns) have stopped freeing.
fn measure<R>(f: impl FnOnce() -> R) -> (R, Usage) {
    rayon::broadcast(|_| ());
    assert!(alloc_count::settle(std::time::Duration::from_secs(10)), "the allocator never went quiet");
    alloc_count::measure(f)
}

const SIZES: &[(u32, u32)] = &[(64, 48), (333, 257), (512, 512), (1000, 100)];

fn close(what: &str, measured: isize, estimate: usize, rel: f64) {
    let (m, e) = (measured as f64, estimate as f64);
    assert!((m - e).abs() <= e * rel + 4096.0, "{what}: allocated {measured} bytes, bytes_for says {estimate}");
}

fn camera() -> Camera {
    Camera { eye: Vec3::new(0.0, 1.0, 4.0), target: Vec3::ZERO, up: Vec3::Y, fov_y_degrees: 40.0 }
}

/// A cache holding samples on a plane in front of the camera, one per pixel in `1/every`.
fn filled_cache(w: u32, h: u32, every: u32) -> RenderCache {
    let mut c = RenderCache::new(CacheConfig::new(w, h));
    let cam = camera().frame(w, h);
    for y in 0..h {
        for x in (y % every..w).step_by(every as usize) {
            let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            let t = (-1.0 - o.z) / d.z;
            c.insert(&Sample { hit: true, position: o + d * t.abs(), normal: Vec3::Z, color: Vec3::splat(0.5), object: 0, epoch: 0, pixel: [x, y] });
        }
    }
    c
}

#[test]
fn render_cache_bytes_for_matches_new_and_a_frame() {
    let _one = ONE.lock().unwrap_or_else(|p| p.into_inner());
    let threads = rayon::current_num_threads();
    for &(w, h) in SIZES {
        for ppp in [0.5f32, 2.0, 4.0] {
            let (cache, u) = measure(|| {
                let mut c = RenderCache::new(CacheConfig { points_per_pixel: ppp, ..CacheConfig::new(w, h) });
                let mut times = StageTimes::new();
                c.reproject_points(&camera().frame(w, h), None, &mut times);
                drop(times);
                c
            });
            close(&format!("RenderCache {w}x{h} ppp {ppp}"), u.live, RenderCache::bytes_for(w, h, ppp, threads), 0.01);
            drop(cache);
        }
    }
}

#[test]
fn epi_bytes_for_bounds_what_a_frame_allocates() {
    let _one = ONE.lock().unwrap_or_else(|p| p.into_inner());
    // The EPI's tables are process-wide and built on first use: build them first.
    let mut warm = filled_cache(8, 8, 1);
    warm.reproject_points(&camera().frame(8, 8), None, &mut StageTimes::new());
    Epi::new(8, 8).build(&[], &camera().frame(8, 8), warm.point_image(), true, &mut StageTimes::new());
    for &(w, h) in SIZES {
        let mut cache = filled_cache(w, h, 3);
        let mut times = StageTimes::new();
        cache.reproject_points(&camera().frame(w, h), None, &mut times);
        let (epi, u) = measure(|| {
            let mut epi = Epi::new(w, h);
            let mut t = StageTimes::new();
            let bg = cache.background();
            epi.build(&[], &camera().frame(w, h), cache.point_image(), true, &mut t);
            let (points, image, weights) = cache.reconstruction_target();
            epi.reconstruct(points, bg, &InterpOptions::default(), true, image, weights, &mut t);
            drop(t);
            epi
        });
        let bound = Epi::bytes_for(w, h);
        // Content-sized parts at their worst (every pixel simple, every pixel spread to):
        // two colours and two queue entries per pixel. This frame has no edges.
        let content = (24 + 8) * (w * h) as usize;
        assert!(u.live as usize <= bound, "EPI {w}x{h}: allocated {} > bytes_for {bound}", u.live);
        close(&format!("EPI {w}x{h} image-sized part"), u.live, bound - content, 0.02);
        drop(epi);
    }
}

#[test]
fn small_structures_bytes_for_match_their_constructors() {
    let _one = ONE.lock().unwrap_or_else(|p| p.into_inner());
    for &(w, h) in SIZES {
        let (x, u) = measure(|| HoleFill::new(w, h));
        close(&format!("HoleFill {w}x{h}"), u.live, HoleFill::bytes_for(w, h), 0.0);
        drop(x);
        let (x, u) = measure(|| Sampler::new(w, h, 1));
        close(&format!("Sampler {w}x{h}"), u.live, Sampler::bytes_for(w, h), 0.0);
        drop(x);
        let cap = (w * h / 8) as usize;
        let (x, u) = measure(|| RequestRing::new(cap));
        close(&format!("RequestRing {cap}"), u.live, RequestRing::bytes_for(cap), 0.0);
        drop(x);
        // The baseline's hole fill on a frame where most pixels are holes.
        let mut cache = filled_cache(w, h, 50);
        let mut times = StageTimes::new();
        cache.reproject_points(&camera().frame(w, h), None, &mut times);
        let mut pyramid = HoleFill::new(w, h);
        let (x, u) = measure(|| {
            let mut b = BaselineHoles::default();
            let (points, image, weights) = cache.reconstruction_target();
            b.fill(points, weights, image, &mut pyramid, None);
            b
        });
        assert!(u.live as usize <= BaselineHoles::bytes_for(w as usize, h as usize), "BaselineHoles {w}x{h}: {}", u.live);
        drop(x);
        let (x, u) = measure(|| Visibility::new(w, h));
        close(&format!("Visibility {w}x{h}"), u.live, Visibility::bytes_for(w, h), 0.0);
        drop(x);
        // The object-aware fill on a frame where every pixel is a hole but one.
        let words = (w as usize).div_ceil(64);
        // Every pixel a hole (the bits past the row's end stay clear, as the EPI leaves them).
        let mut holes = vec![0u64; words * h as usize];
        for y in 0..h as usize {
            for x in 0..w as usize {
                holes[y * words + x / 64] |= 1 << (x % 64);
            }
        }
        holes[0] &= !1;
        let objects = vec![0u32; (w * h) as usize];
        let mut image = vec![Vec3::ONE; (w * h) as usize];
        let (x, u) = measure(|| {
            let mut f = ObjectFill::default();
            f.fill(w as usize, h as usize, &holes, &objects, &mut image);
            f
        });
        assert!(u.live as usize <= ObjectFill::bytes_for(w, h), "ObjectFill {w}x{h}: {} > {}", u.live, ObjectFill::bytes_for(w, h));
        assert_eq!(x.bytes(), ObjectFill::bytes_for(w, h), "ObjectFill {w}x{h} holds what bytes_for says");
        drop(x);
    }
}

/// The whole estimate against a running session (its frame loop, frames encoded and
/// published, no workers): it must cover what the session allocates, and not by much more
/// than its stated worst cases for content-sized buffers.
#[test]
fn a_running_session_stays_within_its_estimate() {
    use edgepoint_proto as pb;
    use edgepoint_server::session::{EdgeIndexSlot, Session, SessionParams};
    use edgepoint_server::workers::WorkerPool;
    use std::sync::Arc;
    let _one = ONE.lock().unwrap_or_else(|p| p.into_inner());
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().unwrap();
    let scene = Arc::new(edgepoint_scene::builtin::load("cornell").unwrap());
    let (w, h) = (480u32, 360u32);
    let settings = SessionSettings { max_fps: 1000.0, ..Default::default() };
    let estimate = SessionMemory::estimate(w, h, 2.0, &settings, rayon::current_num_threads()).total();
    // A real worker (in this process, started before the measurement): sessions publish
    // frames only once samples arrive. Its own allocations during the run (a cornell BVH,
    // request and answer buffers) are small beside the session's and are counted too.
    let worker = common::Worker::spawn();
    let (frames, u) = measure(|| {
        rt.block_on(async {
            let pool = WorkerPool::new(vec![worker.url.clone()]).unwrap();
            let source = pb::builtin_source("cornell");
            let hash = pb::scene_hash(&source);
            let params = SessionParams {
                id: "memory-test".into(),
                camera: scene.camera,
                scene: scene.clone(),
                width: w,
                height: h,
                shader: "direct".into(),
                shader_params: Default::default(),
                encoding: pb::FrameEncoding::Qoi,
                settings,
                points_per_pixel: 2.0,
                seed: 1,
                edge_index: EdgeIndexSlot::default(),
                memory: None,
                split: Default::default(),
            };
            let session = Session::start(params, pool.open(source, hash), None).unwrap();
            let out = session.output();
            let mut frames = 0;
            while frames < 20 {
                match tokio::time::timeout(std::time::Duration::from_secs(60), out.next()).await {
                    Ok(Some(pb::ServerMsg { msg: Some(pb::server_msg::Msg::Frame(_)) })) => frames += 1,
                    Ok(Some(_)) => {}
                    _ => break,
                }
            }
            session.join();
            frames
        })
    });
    assert_eq!(frames, 20, "the session made frames");
    let peak = u.peak as u64;
    eprintln!("{w}x{h} session: peak allocated {peak} bytes, estimate {estimate}");
    assert!(peak <= estimate, "a {w}x{h} session allocated {peak} bytes at its peak, above its estimate {estimate}");
    assert!(peak * 10 >= estimate * 7, "the estimate {estimate} is far above the {peak} bytes a session allocated");
}
