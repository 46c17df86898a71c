//! End-to-end sessions against real processes: a server and shader workers on 127.0.0.1.
use edgepoint_proto as pb;
use edgepoint_tests::{cluster, next_frame, start_builtin};
use edgepoint_viewer::client::SessionClient;
use std::time::Duration;

const FRAME_WAIT: Duration = Duration::from_secs(30);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_arrive_with_increasing_sequence_and_samples() {
    let cl = tokio::task::block_in_place(|| cluster(2)).expect("cluster starts");
    let (mut client, started) =
        SessionClient::connect(&cl.server_url(), start_builtin("cornell", 96, 72)).await.expect("session starts");
    assert_eq!(started.workers, 2);
    assert!(started.objects.iter().any(|o| o.name == "tallbox"));
    let mut last_seq = None;
    let mut samples = 0u64;
    for _ in 0..20 {
        let (f, _) = next_frame(&mut client, FRAME_WAIT).await.unwrap();
        assert_eq!((f.width, f.height), (96, 72));
        assert!(!f.data.is_empty());
        let img = edgepoint_viewer::frame::decode_frame(&f).expect("frame decodes");
        assert_eq!((img.width(), img.height()), (96, 72));
        if let Some(prev) = last_seq {
            assert!(f.sequence > prev, "sequence {} after {}", f.sequence, prev);
        }
        last_seq = Some(f.sequence);
        samples += f.samples_used as u64;
        assert!(!f.stages.is_empty(), "per-stage times are reported");
    }
    assert!(samples > 0, "workers delivered samples into the cache");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killing_a_worker_does_not_stop_frames() {
    let mut cl = tokio::task::block_in_place(|| cluster(2)).expect("cluster starts");
    let (mut client, _) =
        SessionClient::connect(&cl.server_url(), start_builtin("cornell", 64, 48)).await.expect("session starts");
    for _ in 0..5 {
        next_frame(&mut client, FRAME_WAIT).await.unwrap();
    }
    cl.kill_worker(0).expect("kill -9 worker 0");
    // Frames keep coming, and the surviving worker keeps filling the cache.
    let mut samples_after = 0u64;
    let mut live_seen = u32::MAX;
    for _ in 0..40 {
        let (f, _) = next_frame(&mut client, FRAME_WAIT).await.expect("frames continue after a worker dies");
        samples_after += f.samples_used as u64;
        live_seen = live_seen.min(f.live_workers);
    }
    assert!(samples_after > 0, "the remaining worker still shades");
    assert_eq!(live_seen, 1, "the server notices the dead worker");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_clear_errors_and_other_sessions_go_on() {
    let cl = tokio::task::block_in_place(|| cluster(1)).expect("cluster starts");
    let url = cl.server_url();
    let (mut good, _) = SessionClient::connect(&url, start_builtin("cornell-point", 64, 48)).await.unwrap();
    next_frame(&mut good, FRAME_WAIT).await.unwrap();

    // A malformed PLY: the header promises 3 vertices and 1 face, the body is cut short.
    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 oops\n".to_vec();
    let mut bad = start_builtin("cornell", 64, 48);
    bad.scene = Some(edgepoint_proto::files_source(vec![("broken.ply".into(), ply)]));
    let err = SessionClient::connect(&url, bad).await.expect_err("malformed scene is refused");
    assert_eq!(err.code(), Some(tonic::Code::InvalidArgument), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("broken.ply") && msg.contains("11"), "message names the file and line: {msg}");

    // Zero image size.
    let err = SessionClient::connect(&url, start_builtin("cornell", 0, 48)).await.expect_err("zero width is refused");
    assert_eq!(err.code(), Some(tonic::Code::InvalidArgument), "{err}");
    assert!(err.to_string().contains("width"), "{err}");

    // Unknown built-in.
    let err = SessionClient::connect(&url, start_builtin("no-such-scene", 64, 48)).await.err().unwrap();
    assert_eq!(err.code(), Some(tonic::Code::InvalidArgument), "{err}");

    // A NaN camera mid-session is rejected, and that session keeps producing frames.
    let nan = pb::Camera {
        eye: Some(pb::Vec3 { x: f32::NAN, y: 0.0, z: 0.0 }),
        target: Some(pb::Vec3 { x: 0.0, y: 0.0, z: 1.0 }),
        up: Some(pb::Vec3 { x: 0.0, y: 1.0, z: 0.0 }),
        fov_y_degrees: 40.0,
    };
    good.send_camera(nan).unwrap();
    let mut rejected = Vec::new();
    for _ in 0..15 {
        let (_, r) = next_frame(&mut good, FRAME_WAIT).await.expect("the session survives a bad camera");
        rejected.extend(r);
    }
    assert_eq!(rejected.len(), 1, "exactly one rejection: {rejected:?}");
    assert_eq!(rejected[0].code, tonic::Code::InvalidArgument as i32);
    assert!(rejected[0].message.contains("not finite"), "{}", rejected[0].message);

    // A zero field of view is rejected too.
    let zero_fov = pb::Camera {
        eye: Some(pb::Vec3 { x: 0.0, y: 0.0, z: 0.0 }),
        target: Some(pb::Vec3 { x: 0.0, y: 0.0, z: 1.0 }),
        up: Some(pb::Vec3 { x: 0.0, y: 1.0, z: 0.0 }),
        fov_y_degrees: 0.0,
    };
    good.send_camera(zero_fov).unwrap();
    let mut rejected = Vec::new();
    for _ in 0..10 {
        rejected.extend(next_frame(&mut good, FRAME_WAIT).await.unwrap().1);
    }
    assert_eq!(rejected.len(), 1);

    // The server still starts new sessions.
    let (mut again, _) = SessionClient::connect(&url, start_builtin("cornell", 32, 32)).await.unwrap();
    next_frame(&mut again, FRAME_WAIT).await.unwrap();
}
