//! Split shading end to end (paper 004 §4.4): requests built as a session builds them, parts
//! shaded by real workers in this process, summed by the session's `PartSums`. A part lost
//! with a killed worker is shaded again by the other worker and the sample completes equal
//! to the unsplit shading; a split session fills its frames; a bad split is refused at start.
mod common;

use common::{open, spawn_renderer, start_msg, Worker};
use edgepoint_proto as pb;
use edgepoint_proto::viewer_msg::Msg as In;
use edgepoint_scene::NoProgress;
use edgepoint_server::rng::mix64;
use edgepoint_server::sampling::PixelRequest;
use edgepoint_server::session::split::{PartOutcome, PartSums};
use edgepoint_server::session::{build_batches, BatchSpec, RequestRing};
use edgepoint_server::workers::{Answer, WorkerPool};
use edgepoint_worker::{shade_batch, LoadedScene, RayRequest, ShaderSpec};
use glam::Vec3;
use std::collections::HashMap;
use std::time::Duration;

/// `batches` batches of `size` jittered picks over a 128² image of `scene`'s camera, as a
/// session with `parts` parts per sample requests them.
fn requests(scene: &edgepoint_scene::Scene, batches: usize, size: usize, parts: u32) -> Vec<pb::RequestBatch> {
    let cam = scene.camera.frame(128, 128);
    let mut h = 7u64;
    let picks: Vec<PixelRequest> = (0..batches * size)
        .map(|_| {
            h = mix64(h);
            let (sx, sy) = ((h >> 40) as f32 / (1 << 24) as f32 * 128.0, ((h >> 8) & 0xff_ffff) as f32 / (1 << 24) as f32 * 128.0);
            PixelRequest { x: sx as u32, y: sy as u32, sx, sy, point: u32::MAX }
        })
        .collect();
    let params = HashMap::new();
    let spec = BatchSpec { epoch: 0, shader: "direct", params: &params, batch_size: size, parts, coherent: false };
    let (mut ring, mut next, mut seed, mut out) = (RequestRing::new(picks.len()), 0, 3, Vec::new());
    build_batches(&picks, &cam, &mut ring, &spec, &mut next, &mut seed, &mut out);
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_part_lost_with_a_killed_worker_is_shaded_again_and_the_sum_is_whole() {
    let scene = edgepoint_scene::builtin::load("rooms").unwrap();
    let parts = 2;
    let batches = requests(&scene, 24, 256, parts);
    // The unsplit shading of every request, in this process, with the batches' own seeds.
    let loaded = LoadedScene::build(scene.clone(), "rooms".into(), &NoProgress);
    let inst = loaded.instances(&loaded.default_transforms());
    let spec = ShaderSpec::parse("direct", &HashMap::new()).unwrap();
    let mut want: HashMap<u64, (bool, Vec3)> = HashMap::new();
    for b in batches.iter().filter(|b| b.requests[0].part == 0) {
        let reqs: Vec<RayRequest> = b
            .requests
            .iter()
            .map(|r| RayRequest { id: r.id, pixel: [r.pixel_x, r.pixel_y], origin: pb::vec3_or_zero(&r.origin), direction: pb::vec3_or_zero(&r.direction) })
            .collect();
        for s in shade_batch(&loaded, &inst, &spec, b.seed, &reqs).samples {
            want.insert(s.id, (s.hit.is_some(), s.rgb));
        }
    }
    assert_eq!(want.len(), 24 * 256);
    // A worker killed just after it took a batch may already have sent every answer it
    // held (the answers are on the socket before the kill drops its runtime): that run
    // completes without a requeue and shows nothing of the path under test. Each run is
    // checked whole; up to ten runs are made until one kills the worker while it holds
    // batches (about one run in three did not, on two cores).
    for attempt in 0..10 {
        let stats = kill_while_shading(&batches, &want, parts).await;
        assert_eq!(stats.dropped_batches, 0);
        if stats.requeued_batches > 0 {
            return;
        }
        eprintln!("run {attempt}: the killed worker had answered all it held: {stats:?}");
    }
    panic!("in ten runs the killed worker's batches never went back to the queue");
}

/// Shades `batches` on two workers, killing the first once it holds a batch; every sample
/// completes equal to `want` (the unsplit shading). The dispatcher's counts.
async fn kill_while_shading(batches: &[pb::RequestBatch], want: &HashMap<u64, (bool, Vec3)>, parts: u32) -> edgepoint_server::workers::DispatchStats {
    let batches = batches.to_vec();
    let (mut a, b) = (Worker::spawn(), Worker::spawn());
    let pool = WorkerPool::new(vec![a.url.clone(), b.url.clone()]).unwrap();
    let source = pb::builtin_source("rooms");
    let d = pool.open(source.clone(), pb::scene_hash(&source));
    for batch in batches {
        assert!(d.submit(batch));
    }
    // Kill `a` while it holds batches (parts of samples whose other parts `b` may have).
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    loop {
        let st = d.worker_status();
        if st.iter().any(|w| w.url == a.url && w.in_flight_batches > 0) {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "worker a never took a batch: {st:?}");
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    a.kill();

    let mut sums = PartSums::new(parts);
    let mut complete = 0;
    // Until every sample is complete (the dispatcher settles a batch just before its answer
    // is queued, so "nothing outstanding" can come a moment before the last answer).
    while complete < 24 * 256 {
        let answer = tokio::time::timeout(Duration::from_secs(60), d.next_answer()).await.expect("answers keep coming").unwrap();
        let Answer::Samples { batch, .. } = answer else { panic!("a batch was given up: {answer:?}") };
        for s in &batch.samples {
            match sums.add(batch.epoch, s) {
                PartOutcome::Complete(whole, _) => {
                    let (hit, rgb) = want[&whole.id];
                    assert_eq!(whole.hit, hit);
                    let got = pb::vec3_or_zero(&whole.rgb);
                    assert!((got - rgb).abs().max_element() <= 2e-6 * rgb.max_element().max(1e-3), "sample {}: {got} vs unsplit {rgb}", whole.id);
                    complete += 1;
                }
                PartOutcome::Waiting => {}
                other => panic!("sample {} part {}: {other:?}", s.id, s.part),
            }
        }
    }
    assert_eq!(complete, 24 * 256, "every sample completes");
    assert_eq!(sums.waiting(), 0);
    drop(b);
    d.stats()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_split_session_fills_its_frames_and_bad_splits_are_refused() {
    let (w1, w2) = (Worker::spawn(), Worker::spawn());
    let (addr, _h) = spawn_renderer(vec![w1.url.clone(), w2.url.clone()], 4).await;
    let rooms = pb::builtin_source("rooms");
    let with_split = |split: pb::Split| {
        let mut m = start_msg(rooms.clone(), 64, 48);
        if let Some(In::Start(s)) = &mut m.msg {
            s.split = Some(split);
        }
        m
    };
    for (bad, what) in [(pb::Split { by: 1, parts: 65 }, "65"), (pb::Split { by: 1, parts: 0 }, "not 0"), (pb::Split { by: 4, parts: 2 }, "SplitBy")] {
        let e = open(&addr, with_split(bad)).await.err().expect("refused");
        assert_eq!(e.code(), tonic::Code::InvalidArgument);
        assert!(e.message().contains("start.split") && e.message().contains(what), "{}", e.message());
    }
    let mut v = open(&addr, with_split(pb::Split { by: pb::SplitBy::Lights as i32, parts: 3 })).await.unwrap();
    v.started().await;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    loop {
        let (f, rejected) = v.frame(20).await;
        assert!(rejected.is_empty());
        if f.pixels.unwrap().with_point > 64 * 48 / 4 {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "the split session's cache never filled: {:?}", f.pixels);
    }
}
