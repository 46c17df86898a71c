//! With a static camera, frames converge toward the reference as samples accumulate.
use edgepoint_scene::NoProgress;
use edgepoint_server::image_metrics::{psnr, srgb8_to_linear};
use edgepoint_server::reference::render_reference;
use edgepoint_server::workers::WorkerPool;
use edgepoint_tests::{cluster, next_frame, start_builtin};
use edgepoint_viewer::client::{camera_from_wire, SessionClient};
use glam::Vec3;
use std::collections::HashMap;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn psnr_against_the_reference_rises_as_frames_accumulate() {
    let (w, h) = (64, 64);
    let cl = tokio::task::block_in_place(|| cluster(2)).expect("cluster starts");
    let start = start_builtin("cornell-point", w, h);
    let source = start.scene.clone().unwrap();
    let (mut client, started) = SessionClient::connect(&cl.server_url(), start).await.unwrap();
    let camera = camera_from_wire(started.camera.as_ref().unwrap());

    let mut curve = Vec::new();
    for i in 1..=60 {
        let (f, _) = next_frame(&mut client, Duration::from_secs(30)).await.unwrap();
        if [2, 10, 60].contains(&i) {
            let img = edgepoint_viewer::frame::decode_frame(&f).unwrap();
            curve.push(img.pixels().map(|p| srgb8_to_linear(p.0)).collect::<Vec<Vec3>>());
        }
    }
    drop(client);

    // The converged reference, through the same workers and shader.
    let pool = WorkerPool::new(cl.worker_addrs().iter().map(|a| format!("http://{a}")).collect()).unwrap();
    let d = pool.open(source.clone(), edgepoint_proto::scene_hash(&source));
    let reference = render_reference(&d, &camera, w, h, 16, "direct", &HashMap::new(), &NoProgress).await.unwrap();
    let p: Vec<f64> = curve.iter().map(|img| psnr(img, &reference.pixels)).collect();
    eprintln!("PSNR at frames 2, 10, 60: {p:?}");
    assert!(p[1] > p[0] + 1.0, "PSNR rises from frame 2 to 10: {p:?}");
    assert!(p[2] > p[0] + 3.0, "PSNR rises from frame 2 to 60: {p:?}");
    assert!(p[2] > 20.0, "frame 60 is close to the reference: {p:?}");
}
