//! `SessionClient` against an in-process mock renderer: the start handshake, a refused
//! start, frames, rejections of bad later messages, and the end of a session.
mod common;

use common::*;
use edgepoint_proto as pb;
use edgepoint_viewer::{ClientError, Event, SessionClient};

fn start(scene: &str) -> pb::Start {
    pb::Start { scene: Some(pb::builtin_source(scene)), width: 16, height: 8, ..Default::default() }
}

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

#[test]
fn connect_returns_started_then_frames() {
    let mock = MockServer::start(0);
    rt().block_on(async {
        let (mut c, started) = SessionClient::connect(&mock.url(), start("cornell")).await.unwrap();
        assert_eq!(started.session_id, "mock-1");
        assert_eq!(started.objects.len(), 2);
        let mut last = 0;
        for _ in 0..3 {
            match c.next_event().await.unwrap().unwrap() {
                Event::Frame(f) => {
                    assert!(f.sequence > last);
                    last = f.sequence;
                    let img = edgepoint_viewer::frame::decode_frame(&f).unwrap();
                    assert_eq!(img, expected_image(f.sequence, 16, 8));
                }
                Event::Rejected(r) => panic!("unexpected rejection {r:?}"),
                Event::Progress(_) | Event::Picked(_) => {}
            }
        }
    });
    assert_eq!(mock.seen.lock().unwrap().starts[0].scene, Some(pb::builtin_source("cornell")));
}

#[test]
fn a_refused_start_carries_the_grpc_code_and_message() {
    let mock = MockServer::start(0);
    let err = rt().block_on(SessionClient::connect(&mock.url(), start("broken"))).unwrap_err();
    assert_eq!(err.code(), Some(tonic::Code::InvalidArgument));
    assert_eq!(err.to_string(), format!("INVALID_ARGUMENT: {BROKEN_MESSAGE}"));
    let zero = pb::Start { width: 0, ..start("cornell") };
    let err = rt().block_on(SessionClient::connect(&mock.url(), zero)).unwrap_err();
    assert!(matches!(err, ClientError::Status { code: tonic::Code::InvalidArgument, .. }), "{err}");
}

#[test]
fn a_bad_camera_is_rejected_and_the_session_goes_on() {
    let mock = MockServer::start(0);
    rt().block_on(async {
        let (mut c, started) = SessionClient::connect(&mock.url(), start("cornell")).await.unwrap();
        let mut cam = started.camera.unwrap();
        cam.eye.as_mut().unwrap().x = f32::NAN;
        c.send_camera(cam).unwrap();
        let mut rejected = None;
        let mut frames_after = 0;
        while frames_after < 2 {
            match c.next_event().await.unwrap().unwrap() {
                Event::Rejected(r) => rejected = Some(r),
                Event::Frame(_) if rejected.is_some() => frames_after += 1,
                Event::Frame(_) | Event::Progress(_) | Event::Picked(_) => {}
            }
        }
        let r = rejected.unwrap();
        assert_eq!((r.code, r.message.as_str()), (3, "camera eye is not finite"));
        c.send_settings(pb::Settings { sparseness: 100.0, ..Default::default() }).unwrap();
        c.sender().send_move(pb::ObjectMove { object_id: 1, ..Default::default() }).unwrap();
        // Let the mock read them.
        while mock.seen.lock().unwrap().messages.len() < 3 {
            c.next_event().await.unwrap().unwrap();
        }
        let _ = c.next_event().await;
    });
    let seen = mock.seen.lock().unwrap();
    assert!(seen.messages.iter().any(|m| matches!(m, pb::viewer_msg::Msg::Settings(s) if s.sparseness == 100.0)));
}

#[test]
fn a_finished_session_ends_the_event_stream() {
    let mock = MockServer::start(2);
    rt().block_on(async {
        let (mut c, _) = SessionClient::connect(&mock.url(), start("cornell")).await.unwrap();
        let mut frames = 0;
        while let Some(ev) = c.next_event().await {
            assert!(matches!(ev.unwrap(), Event::Frame(_)));
            frames += 1;
        }
        assert_eq!(frames, 2);
    });
}

#[test]
fn connection_failures_name_the_url() {
    let err = rt().block_on(SessionClient::connect("http://127.0.0.1:1", start("cornell"))).unwrap_err();
    assert!(matches!(err, ClientError::Connect { .. }), "{err}");
    assert!(err.to_string().starts_with("cannot connect to http://127.0.0.1:1"), "{err}");
    let err = rt().block_on(SessionClient::connect("not a url", start("cornell"))).unwrap_err();
    assert!(err.to_string().contains("invalid URL"), "{err}");
}
