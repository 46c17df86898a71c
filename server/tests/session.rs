//! End-to-end sessions in one process: real shader workers and the Renderer service on
//! 127.0.0.1:0, a viewer over gRPC.
mod common;

use common::{open, spawn_renderer, start_msg, Worker};
use edgepoint_proto as pb;
use edgepoint_proto::viewer_msg::Msg as In;
use edgepoint_server::encode::decode_frame;
use glam::{Affine3A, Vec3};

fn cornell() -> pb::SceneSource {
    pb::builtin_source("cornell")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cornell_session_streams_frames_that_fill_with_samples() {
    let w = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![w.url.clone()], 4).await;
    let mut v = open(&addr, start_msg(cornell(), 64, 48)).await.unwrap();
    let st = v.started().await;
    assert_eq!(st.scene_hash, pb::scene_hash(&cornell()));
    assert_eq!(st.workers, 1);
    assert!(st.lights >= 1 && !st.objects.is_empty());
    for (i, o) in st.objects.iter().enumerate() {
        assert_eq!(o.id as usize, i);
        assert!(o.triangles > 0 && !o.name.is_empty() && o.transform.is_some());
    }
    assert!(st.camera.is_some() && !st.session_id.is_empty());

    let (first, _) = v.frame(20).await;
    let with_samples = v.frame_with_samples(20).await;
    assert!(with_samples.sequence > first.sequence);
    let mut last = with_samples.sequence;
    for _ in 0..5 {
        let (f, rej) = v.frame(10).await;
        assert!(rej.is_empty());
        assert!(f.sequence > last, "sequence increases");
        last = f.sequence;
        assert_eq!((f.width, f.height, f.encoding), (64, 48, pb::FrameEncoding::Qoi as i32));
        let px = decode_frame(&f.data, pb::FrameEncoding::Qoi, 64, 48).unwrap();
        assert_eq!(px.len(), 64 * 48);
        // The frame's own stages in pipeline order, encode last; then the picking and the
        // requests made after the frame before was published, in after_ms, not in total_ms.
        let (own, after) = f.stages.split_at(f.stages.len() - 2);
        assert_eq!(own.last().unwrap().stage, "encode", "stages in pipeline order, encode last");
        assert_eq!([after[0].stage.as_str(), after[1].stage.as_str()], ["sampling", "requests"]);
        assert!((f.after_ms - (after[0].ms + after[1].ms)).abs() < 1e-9, "after_ms {} is the picking's time", f.after_ms);
        assert!(f.total_ms >= own.iter().map(|s| s.ms).sum::<f64>() * 0.99);
        let p = f.pixels.unwrap();
        assert_eq!(p.with_point + p.filled + p.empty, 64 * 48);
        assert!(p.cache_points > 0);
    }
    // After some frames of dense sampling most pixels show a real point, and the image is
    // not just the background. (How many frames that takes depends on how fast the worker
    // answers, so wait for it, within a deadline, rather than count frames.)
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(20);
    let f = loop {
        let (f, _) = v.frame(10).await;
        if f.pixels.unwrap().with_point > 64 * 48 / 4 {
            break f;
        }
        assert!(tokio::time::Instant::now() < deadline, "the cache never filled: {:?}", f.pixels);
    };
    let px = decode_frame(&f.data, pb::FrameEncoding::Qoi, 64, 48).unwrap();
    let distinct: std::collections::HashSet<_> = px.iter().collect();
    assert!(distinct.len() > 10, "a rendered room has many colours, got {}", distinct.len());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_inputs_are_rejected_and_frames_keep_coming() {
    let w = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![w.url.clone()], 4).await;
    let mut v = open(&addr, start_msg(cornell(), 64, 48)).await.unwrap();
    let st = v.started().await;
    let (f0, _) = v.frame(20).await;

    let nan = pb::Camera {
        eye: Some(Vec3::new(f32::NAN, 0.0, 0.0).into()),
        target: Some(Vec3::ZERO.into()),
        up: Some(Vec3::Y.into()),
        fov_y_degrees: 40.0,
    };
    v.send(In::Camera(nan)).await;
    let mut parallel = st.camera.unwrap();
    let (e, t): (Vec3, Vec3) = (parallel.eye.unwrap().into(), parallel.target.unwrap().into());
    parallel.up = Some((t - e).into());
    v.send(In::Camera(parallel)).await;
    v.send(In::Move(pb::ObjectMove { object_id: 999, name: String::new(), transform: Some(pb::affine_to_wire(&Affine3A::IDENTITY)) })).await;
    v.send(In::Settings(pb::Settings { sparseness: -5.0, ..Default::default() })).await;

    let mut rejected = Vec::new();
    let mut last = f0.sequence;
    while rejected.len() < 4 {
        let (f, r) = v.frame(10).await;
        assert!(f.sequence > last);
        last = f.sequence;
        rejected.extend(r);
    }
    assert!(rejected.iter().all(|r| r.code == tonic::Code::InvalidArgument as i32));
    assert!(rejected[0].message.contains("camera") && rejected[0].message.contains("not finite"), "{}", rejected[0].message);
    assert!(rejected[1].message.contains("parallel"), "{}", rejected[1].message);
    assert!(rejected[2].message.contains("999"), "{}", rejected[2].message);
    assert!(rejected[3].message.contains("sparseness"), "{}", rejected[3].message);
    assert_eq!(rejected.len(), 4);

    // Frames keep coming, samples keep arriving, and the epoch has not moved.
    let f = v.frame_with_samples(20).await;
    assert_eq!(f.epoch, 0);

    // A valid move bumps the epoch; the moved object's stale samples never come back.
    let mut moved = Affine3A::from_translation(Vec3::new(0.05, 0.0, 0.0));
    let obj = st.objects.last().unwrap();
    moved = pb::affine_from_wire(obj.transform.as_ref().unwrap()).unwrap() * moved;
    v.send(In::Move(pb::ObjectMove { object_id: 0, name: obj.name.clone(), transform: Some(pb::affine_to_wire(&moved)) })).await;
    let mut epoch = 0;
    for _ in 0..50 {
        let (f, r) = v.frame(10).await;
        assert!(r.is_empty(), "{r:?}");
        epoch = f.epoch;
        if epoch == 1 {
            break;
        }
    }
    assert_eq!(epoch, 1);
    let f = v.frame_with_samples(20).await;
    assert_eq!(f.epoch, 1);
    // A valid camera is taken silently.
    let mut cam = st.camera.unwrap();
    cam.fov_y_degrees = 50.0;
    v.send(In::Camera(cam)).await;
    let (_, r) = v.frame(10).await;
    let (_, r2) = v.frame(10).await;
    assert!(r.is_empty() && r2.is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_starts_fail_alone_while_another_session_runs() {
    let w = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![w.url.clone()], 8).await;
    let mut good = open(&addr, start_msg(cornell(), 64, 48)).await.unwrap();
    good.started().await;
    let (f0, _) = good.frame(20).await;

    let e = open(&addr, start_msg(cornell(), 0, 48)).await.err().expect("zero width refused");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("width") && e.message().contains('0'), "{}", e.message());

    let broken = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 zero 0\n".to_vec();
    let e = open(&addr, start_msg(pb::files_source(vec![("broken_mesh.ply".into(), broken)]), 64, 48))
        .await
        .err()
        .expect("malformed PLY refused");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("broken_mesh.ply"), "names the file: {}", e.message());

    let e = open(&addr, start_msg(pb::builtin_source("no-such-scene"), 64, 48)).await.err().unwrap();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("no-such-scene"), "{}", e.message());

    // A shader parameter out of its range is refused at start, naming it (issue 14).
    let mut bad_gi = start_msg(cornell(), 64, 48);
    if let Some(In::Start(st)) = &mut bad_gi.msg {
        st.shader = "gi".into();
        st.shader_params = [("cache_error".to_string(), 5.0)].into();
    }
    let e = open(&addr, bad_gi).await.err().expect("cache_error 5 refused");
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("cache_error"), "{}", e.message());

    let cam_first = pb::ViewerMsg { msg: Some(In::Camera(pb::Camera::default())) };
    let e = open(&addr, cam_first).await.err().unwrap();
    assert_eq!(e.code(), tonic::Code::InvalidArgument);
    assert!(e.message().contains("start"), "{}", e.message());

    // The good session never noticed.
    let mut last = f0.sequence;
    for _ in 0..3 {
        let (f, r) = good.frame(10).await;
        assert!(r.is_empty());
        assert!(f.sequence > last);
        last = f.sequence;
    }
    good.frame_with_samples(20).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn session_limit_and_missing_workers_are_refused() {
    let w = Worker::spawn();
    let (addr, handle) = spawn_renderer(vec![w.url.clone()], 1).await;
    let mut first = open(&addr, start_msg(cornell(), 32, 24)).await.unwrap();
    first.started().await;
    let e = open(&addr, start_msg(cornell(), 32, 24)).await.err().expect("over the limit");
    assert_eq!(e.code(), tonic::Code::ResourceExhausted);
    assert!(e.message().contains("max-sessions"), "{}", e.message());
    assert_eq!(handle.active_sessions(), 1);
    // Ending the first session frees its slot.
    drop(first);
    let mut freed = false;
    for _ in 0..100 {
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        if handle.active_sessions() == 0 {
            freed = true;
            break;
        }
    }
    assert!(freed, "the session slot was released");
    let mut again = open(&addr, start_msg(cornell(), 32, 24)).await.unwrap();
    again.started().await;

    let (none, _h2) = spawn_renderer(vec![], 4).await;
    let e = open(&none, start_msg(cornell(), 32, 24)).await.err().unwrap();
    assert_eq!(e.code(), tonic::Code::FailedPrecondition);

    // Shutdown ends running sessions and refuses new ones.
    handle.shutdown();
    while let Ok(Some(_)) =
        tokio::time::timeout(std::time::Duration::from_secs(5), again.rx.message()).await.expect("stream ends")
    {}
    let e = open(&addr, start_msg(cornell(), 32, 24)).await.err().unwrap();
    assert_eq!(e.code(), tonic::Code::Unavailable);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_continue_when_a_worker_disappears() {
    let mut a = Worker::spawn();
    let b = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![a.url.clone(), b.url.clone()], 4).await;
    let mut v = open(&addr, start_msg(cornell(), 64, 48)).await.unwrap();
    v.started().await;
    let mut live = 0;
    for _ in 0..200 {
        let (f, _) = v.frame(10).await;
        live = f.live_workers;
        if live == 2 && f.samples_used > 0 {
            break;
        }
    }
    assert_eq!(live, 2, "both workers connected");

    a.kill();
    // Frames keep coming, new samples keep arriving from the remaining worker, and the
    // session notices it has one live worker.
    let mut saw_one_live = false;
    let mut samples_after = 0u64;
    let mut last = 0;
    for _ in 0..300 {
        let (f, _) = v.frame(10).await;
        assert!(f.sequence > last);
        last = f.sequence;
        if f.live_workers == 1 {
            saw_one_live = true;
        }
        if saw_one_live {
            samples_after += f.samples_used as u64;
            if samples_after > 500 {
                break;
            }
        }
    }
    assert!(saw_one_live, "the dead worker's link went down");
    assert!(samples_after > 500, "samples keep arriving after the worker died ({samples_after})");
    drop(b);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn edge_and_point_frames_classify_pixels_and_switch_mode_mid_session() {
    let w = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![w.url.clone()], 4).await;
    let (width, height) = (96u32, 96u32);
    let mut v = open(&addr, start_msg(cornell(), width, height)).await.unwrap();
    v.started().await;
    let stages = |f: &pb::Frame| f.stages.iter().map(|s| s.stage.clone()).collect::<Vec<_>>();

    // Edge-and-point reconstruction by default: edges found and rasterized, pixels classified.
    let f = v.frame_with_samples(20).await;
    assert_eq!(f.reconstruction, pb::Reconstruction::EdgeAndPoint as i32);
    let p = f.pixels.unwrap();
    assert_eq!(p.empty_class + p.simple_class + p.complex_class, width * height);
    assert!(p.simple_class > 0 && p.complex_class > 0, "{p:?}");
    assert_eq!(p.with_point + p.filled + p.empty, width * height);
    let e = f.edges.unwrap();
    assert!(e.silhouette + e.sharp + e.boundary > 0 && e.fragments > 0, "{e:?}");
    let names = stages(&f);
    for s in ["input", "samples", "edges", "reproject", "rasterize", "reach", "interpolate", "antialias", "complex", "sampling", "requests", "encode"] {
        assert!(names.iter().any(|n| n == s), "stage {s} missing from {names:?}");
    }

    // Switch to the Render Cache baseline: no EPI work, no classes.
    v.send(In::Settings(pb::Settings { reconstruction: pb::Reconstruction::RenderCache as i32, ..Default::default() })).await;
    let f = first_frame_made_with(&mut v, pb::Reconstruction::RenderCache).await;
    assert!(!stages(&f).iter().any(|s| s == "reach" || s == "edges"), "{:?}", stages(&f));
    assert_eq!(f.pixels.unwrap().simple_class, 0);

    // Bad reconstruction settings are rejected; the session and its mode go on.
    v.send(In::Settings(pb::Settings { reconstruction: 9, ..Default::default() })).await;
    v.send(In::Settings(pb::Settings { sharp_cutoff_degrees: 500.0, ..Default::default() })).await;
    v.send(In::Settings(pb::Settings { overlay: 42, ..Default::default() })).await;
    let mut rejected = Vec::new();
    while rejected.len() < 3 {
        let (f, r) = v.frame(10).await;
        assert_eq!(f.reconstruction, pb::Reconstruction::RenderCache as i32);
        rejected.extend(r);
    }
    assert!(rejected.iter().all(|r| r.code == tonic::Code::InvalidArgument as i32));
    assert!(rejected[0].message.contains("reconstruction"), "{}", rejected[0].message);
    assert!(rejected[1].message.contains("sharp_cutoff"), "{}", rejected[1].message);
    assert!(rejected[2].message.contains("overlay"), "{}", rejected[2].message);

    // Back to edge-and-point without the complex filter, with the class overlay: the frame
    // shows simple pixels in the overlay's purple.
    v.send(In::Settings(pb::Settings {
        reconstruction: pb::Reconstruction::EdgeAndPoint as i32,
        complex_filter: Some(false),
        overlay: pb::Overlay::Classes as i32,
        ..Default::default()
    }))
    .await;
    let f = first_frame_made_with(&mut v, pb::Reconstruction::EdgeAndPoint).await;
    let names = stages(&f);
    assert!(names.iter().any(|s| s == "reach") && !names.iter().any(|s| s == "complex"), "{names:?}");
    assert!(names.iter().any(|s| s == "overlay"), "{names:?}");
    let px = decode_frame(&f.data, pb::FrameEncoding::Qoi, width, height).unwrap();
    let purple = edgepoint_server::image_metrics::linear_to_srgb8(edgepoint_server::epi::overlay::SIMPLE_PURPLE);
    let n = px.iter().filter(|c| **c == purple).count() as u32;
    assert_eq!(n, f.pixels.unwrap().simple_class, "one purple pixel per simple pixel");
}

/// The first frame reconstructed with `mode` within 50 frames; no rejections on the way.
async fn first_frame_made_with(v: &mut common::Viewer, mode: pb::Reconstruction) -> pb::Frame {
    first_frame_where(v, &format!("made with {mode:?}"), |f| f.reconstruction == mode as i32).await
}

/// The first frame within 50 frames for which `pred` holds; no rejections on the way.
async fn first_frame_where(v: &mut common::Viewer, what: &str, pred: impl Fn(&pb::Frame) -> bool) -> pb::Frame {
    for _ in 0..50 {
        let (f, r) = v.frame(10).await;
        assert!(r.is_empty(), "{r:?}");
        if pred(&f) {
            return f;
        }
    }
    panic!("no frame {what} within 50 frames");
}

/// Paper §6 in a live session: the edge trees take over from the brute-force finder, the
/// triples the worker reports become hard shadow edges in the frames, and moving the
/// shadow's blocker moves them (the shadow thread catches up within a deadline).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shadow_edges_from_reported_triples_reach_the_frames_and_follow_a_move() {
    let w = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![w.url.clone()], 4).await;
    let mut v = open(&addr, start_msg(pb::builtin_source("cornell-point"), 96, 96)).await.unwrap();
    v.started().await;
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(60);
    let shadowed = |f: &pb::Frame| f.edges.as_ref().is_some_and(|e| e.edge_trees && e.shadow_hard > 0 && e.shadow_pairs > 0);
    let before = loop {
        let (f, r) = v.frame(10).await;
        assert!(r.is_empty(), "{r:?}");
        if shadowed(&f) {
            break f.edges.unwrap();
        }
        assert!(tokio::time::Instant::now() < deadline, "no shadow edges from the trees: {:?}", f.edges);
    };
    assert_eq!((before.shadow_umbral, before.shadow_penumbral), (0, 0), "a point light makes hard shadows only");
    // Lift the tall box: its shadow edges change (the update comes from the shadow thread).
    let lift = Affine3A::from_translation(Vec3::new(0.0, 0.12, 0.0));
    v.send(In::Move(pb::ObjectMove { name: "tallbox".into(), transform: Some(pb::affine_to_wire(&lift)), ..Default::default() })).await;
    let deadline = tokio::time::Instant::now() + std::time::Duration::from_secs(60);
    loop {
        let (f, r) = v.frame(10).await;
        assert!(r.is_empty(), "{r:?}");
        let e = f.edges.unwrap();
        if f.epoch > 0 && e.shadow_update_ms > 0.0 && e.shadow_hard != before.shadow_hard {
            break;
        }
        assert!(tokio::time::Instant::now() < deadline, "the shadow edges never followed the move: {e:?}");
    }
}

/// A viewer switches its frames to the linear encoding mid-session (what the window does
/// when an exposure key is pressed) and back; an unknown encoding is rejected and changes
/// nothing.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_switch_to_linear_half_floats_and_back() {
    let w = Worker::spawn();
    let (addr, _h) = spawn_renderer(vec![w.url.clone()], 4).await;
    let (width, height) = (40u32, 30u32);
    let mut v = open(&addr, start_msg(cornell(), width, height)).await.unwrap();
    v.started().await;
    let f = v.frame_with_samples(20).await;
    assert_eq!(f.encoding, pb::FrameEncoding::Qoi as i32);

    let linear = pb::Settings { encoding: pb::FrameEncoding::LinearHalfLz4 as i32, ..Default::default() };
    v.send(In::Settings(linear)).await;
    let f = first_frame_encoded(&mut v, pb::FrameEncoding::LinearHalfLz4).await;
    let lin = pb::linear_frame::decode(&f.data, width, height).unwrap().to_f32();
    assert!(lin.iter().all(|x| x.is_finite() && *x >= 0.0));
    assert!(lin.iter().any(|x| *x > 0.01), "a lit room is not black");
    // The sRGB view of the linear frame decodes through the same path as every encoding.
    assert_eq!(decode_frame(&f.data, pb::FrameEncoding::LinearHalfLz4, width, height).unwrap().len(), 1200);

    v.send(In::Settings(pb::Settings { encoding: 77, ..Default::default() })).await;
    let mut rejected = Vec::new();
    while rejected.is_empty() {
        let (f, r) = v.frame(10).await;
        assert_eq!(f.encoding, pb::FrameEncoding::LinearHalfLz4 as i32, "a rejected switch changes nothing");
        rejected.extend(r);
    }
    assert!(rejected[0].message.contains("encoding 77"), "{}", rejected[0].message);

    v.send(In::Settings(pb::Settings { encoding: pb::FrameEncoding::Qoi as i32, ..Default::default() })).await;
    let f = first_frame_encoded(&mut v, pb::FrameEncoding::Qoi).await;
    assert_eq!(decode_frame(&f.data, pb::FrameEncoding::Qoi, width, height).unwrap().len(), 1200);
}

async fn first_frame_encoded(v: &mut common::Viewer, encoding: pb::FrameEncoding) -> pb::Frame {
    first_frame_where(v, &format!("encoded as {encoding:?}"), |f| f.encoding == encoding as i32).await
}
