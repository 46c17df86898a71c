//! Workers failing and joining while a session runs, against the real processes: a worker
//! killed with SIGKILL and restarted, a worker stopped with SIGSTOP and continued, a third
//! worker added through the server's workers file. In every case frames keep arriving, the
//! surviving workers keep shading, and the worker (re)joins and shades again.
//!
//! No assertion is about speed: the bounds below are generous deadlines for a loaded CI
//! machine; the measured times are printed (see `edgepoint-bench loadtest` for figures).
use edgepoint_tests::{cluster_with, frames_until, scrape_metric, start_builtin};
use edgepoint_viewer::client::SessionClient;
use std::time::{Duration, Instant};

/// Longest any single wait may take on a loaded 2-core machine.
const WAIT: Duration = Duration::from_secs(30);
/// A frame gap this long would mean the frame loop stalled, not that the machine is busy.
const STALL: Duration = Duration::from_secs(10);

async fn worker_samples(cl: &edgepoint_tests::LocalCluster, i: usize) -> f64 {
    let addr = cl.worker_metrics_addr(i).expect("worker metrics endpoint");
    scrape_metric(addr, "edgepoint_worker_samples_total").await.unwrap()
}

/// Waits until worker `i` reports more shaded samples than `than`.
async fn worker_shades(cl: &edgepoint_tests::LocalCluster, client: &mut SessionClient, last: &mut Instant, i: usize, than: f64) {
    let shaded = async {
        while worker_samples(cl, i).await <= than {
            // Keep taking frames meanwhile (the viewer side must not back up).
            frames_until(client, last, WAIT, |_, s| s.frames >= 3).await.unwrap();
        }
    };
    tokio::time::timeout(WAIT, shaded).await.unwrap_or_else(|_| panic!("worker {i} shaded nothing new within {WAIT:?}"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_worker_is_routed_around_and_rejoins_when_restarted() {
    let mut cl = tokio::task::block_in_place(|| cluster_with(2, |o| o.metrics = true)).expect("cluster starts");
    let (mut c, started) = SessionClient::connect(&cl.server_url(), start_builtin("cornell", 64, 48)).await.unwrap();
    assert_eq!(started.workers, 2);
    let mut last = Instant::now();
    frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 2).await.expect("both workers live");

    tokio::task::block_in_place(|| cl.kill_worker(0)).unwrap();
    let killed_at = Instant::now();
    let down = frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 1).await.expect("the server notices the dead worker");
    let noticed = killed_at.elapsed();
    let after = frames_until(&mut c, &mut last, WAIT, |_, s| s.frames >= 30 && s.samples > 0).await.expect("frames go on");
    assert!(after.samples > 0, "the surviving worker keeps shading");
    println!("kill -9: noticed after {noticed:?}; longest frame gap {:?}", down.max_gap.max(after.max_gap));

    tokio::task::block_in_place(|| cl.restart_worker(0)).unwrap();
    let restarted_at = Instant::now();
    let back = frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 2).await.expect("the restarted worker rejoins");
    let rejoin = restarted_at.elapsed();
    println!("restart: rejoined after {rejoin:?} ({} frames meanwhile, longest gap {:?})", back.frames, back.max_gap);
    worker_shades(&cl, &mut c, &mut last, 0, 0.0).await;
    for s in [&down, &after, &back] {
        assert!(s.max_gap < STALL, "a frame gap of {:?}", s.max_gap);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopped_worker_is_routed_around_and_resumes_when_continued() {
    let mut cl = tokio::task::block_in_place(|| cluster_with(2, |o| o.metrics = true)).expect("cluster starts");
    let (mut c, _) = SessionClient::connect(&cl.server_url(), start_builtin("cornell", 64, 48)).await.unwrap();
    let mut last = Instant::now();
    frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 2).await.expect("both workers live");
    // Both have answered (so the server knows their round trips).
    worker_shades(&cl, &mut c, &mut last, 0, 0.0).await;
    worker_shades(&cl, &mut c, &mut last, 1, 0.0).await;
    let server_metrics = cl.server_metrics_addr().expect("server metrics");

    // SIGSTOP: the process and its TCP connections stay, it answers nothing. Only the
    // server's stall deadline can tell.
    cl.stop_worker(0).unwrap();
    let stopped_at = Instant::now();
    let during = frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 1).await.expect("the stall is detected");
    println!("SIGSTOP: routed around after {:?}; longest frame gap {:?}", stopped_at.elapsed(), during.max_gap);
    let requeued = scrape_metric(server_metrics, "edgepoint_server_requeued_batches_total").await.unwrap();
    assert!(requeued > 0.0, "the stopped worker's batches were re-issued");
    let flowing = frames_until(&mut c, &mut last, WAIT, |_, s| s.frames >= 20 && s.samples > 0).await.expect("frames go on");
    assert!(flowing.samples > 0, "the other worker shades the re-issued batches");

    let before = {
        cl.continue_worker(0).unwrap();
        // The counter of the continued process (it was not restarted).
        worker_samples(&cl, 0).await
    };
    let continued_at = Instant::now();
    let back = frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 2).await.expect("the continued worker rejoins");
    println!("SIGCONT: live again after {:?}", continued_at.elapsed());
    worker_shades(&cl, &mut c, &mut last, 0, before).await;
    for s in [&during, &flowing, &back] {
        assert!(s.max_gap < STALL, "a frame gap of {:?}", s.max_gap);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_added_mid_session_takes_work() {
    let mut cl = tokio::task::block_in_place(|| {
        cluster_with(2, |o| {
            o.metrics = true;
            o.workers_file = true;
        })
    })
    .expect("cluster starts");
    let (mut c, started) = SessionClient::connect(&cl.server_url(), start_builtin("cornell", 64, 48)).await.unwrap();
    assert_eq!(started.workers, 2);
    let mut last = Instant::now();
    frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 2).await.expect("both workers live");

    let third = tokio::task::block_in_place(|| cl.add_worker()).expect("a third worker starts");
    let added_at = Instant::now();
    let joined = frames_until(&mut c, &mut last, WAIT, |f, _| f.live_workers == 3).await.expect("the third worker joins the session");
    println!("added: live after {:?} (longest frame gap {:?})", added_at.elapsed(), joined.max_gap);
    worker_shades(&cl, &mut c, &mut last, third, 0.0).await;
    let m = cl.server_metrics_addr().unwrap();
    assert_eq!(scrape_metric(m, "edgepoint_server_workers").await.unwrap(), 3.0);
    assert_eq!(scrape_metric(m, "edgepoint_server_workers_live").await.unwrap(), 3.0);
    assert!(joined.max_gap < STALL);
}
