//! 16 concurrent sessions against one server for a bounded time: every session keeps
//! receiving frames, and the server's memory stays flat (its resident size, read from
//! /proc, is no higher in the last third of the run than in the middle third, within a
//! margin for allocator noise). Then the sessions are closed and 16 new ones opened, twice:
//! sessions that come and go leave nothing behind.
//!
//! The run takes about [`SOAK`] plus set-up; fps is printed, not asserted.
use edgepoint_tests::{cluster_with, frames_until, rss_kib, start_builtin, Seen};
use edgepoint_viewer::client::SessionClient;
use std::time::{Duration, Instant};

const SESSIONS: usize = 16;
const SOAK: Duration = Duration::from_secs(24);
const WAIT: Duration = Duration::from_secs(60);

/// Runs `n` sessions for `d`; each must see frames in every quarter of the run.
async fn sessions(url: &str, n: usize, d: Duration) -> Vec<Seen> {
    let mut tasks = Vec::new();
    for i in 0..n {
        let url = url.to_string();
        tasks.push(tokio::spawn(async move {
            let scene = if i % 2 == 0 { "cornell" } else { "cornell-point" };
            let (mut c, _) = SessionClient::connect(&url, start_builtin(scene, 64, 48)).await.expect("session starts");
            let t0 = Instant::now();
            let mut last = Instant::now();
            let mut total = Seen::default();
            for q in 1..=4u32 {
                let until = t0 + d * q / 4;
                let part = frames_until(&mut c, &mut last, WAIT, |_, _| Instant::now() >= until)
                    .await
                    .unwrap_or_else(|e| panic!("session {i}, quarter {q}: {e:#}"));
                assert!(part.frames > 0, "session {i} got no frame in quarter {q}");
                total.frames += part.frames;
                total.samples += part.samples;
                total.max_gap = total.max_gap.max(part.max_gap);
                total.last = part.last;
            }
            total
        }));
    }
    let mut out = Vec::new();
    for t in tasks {
        out.push(t.await.expect("session task"));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sixteen_sessions_keep_getting_frames_with_flat_memory() {
    let cl = tokio::task::block_in_place(|| cluster_with(2, |_| {})).expect("cluster starts");
    let pid = cl.server_pid().unwrap();
    let url = cl.server_url();
    let Some(idle) = rss_kib(pid) else {
        eprintln!("no /proc on this system: skipping the memory soak");
        return;
    };

    let sampler = tokio::spawn(async move {
        let t0 = Instant::now();
        let mut rss = Vec::new();
        while t0.elapsed() < SOAK + Duration::from_secs(5) {
            if let Some(k) = rss_kib(pid) {
                rss.push((t0.elapsed(), k));
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        rss
    });
    let seen = sessions(&url, SESSIONS, SOAK).await;
    let rss = sampler.await.unwrap();

    let secs = SOAK.as_secs_f64();
    let fps: Vec<f64> = seen.iter().map(|s| s.frames as f64 / secs).collect();
    let dropped: u64 = seen.iter().filter_map(|s| s.last.as_ref()).map(|f| f.frames_dropped).sum();
    let peak = rss.iter().map(|r| r.1).max().unwrap_or(0);
    let mean_in = |lo: f64, hi: f64| {
        let v: Vec<u64> = rss.iter().filter(|r| r.0.as_secs_f64() >= lo * secs && r.0.as_secs_f64() < hi * secs).map(|r| r.1).collect();
        v.iter().sum::<u64>() as f64 / v.len().max(1) as f64
    };
    let (middle, last) = (mean_in(1.0 / 3.0, 2.0 / 3.0), mean_in(2.0 / 3.0, 1.0));
    println!(
        "{SESSIONS} sessions, {secs:.0} s: fps per session {:.1}..{:.1} (mean {:.1}), frames dropped {dropped}, longest gap {:?}; server RSS idle {idle} KiB, middle third {middle:.0} KiB, last third {last:.0} KiB, peak {peak} KiB",
        fps.iter().cloned().fold(f64::INFINITY, f64::min),
        fps.iter().cloned().fold(0.0, f64::max),
        fps.iter().sum::<f64>() / fps.len() as f64,
        seen.iter().map(|s| s.max_gap).max().unwrap(),
    );
    assert!(seen.iter().all(|s| s.samples > 0), "every session's cache was filled by the workers");
    assert!(last <= middle * 1.10 + 8192.0, "server memory grew under steady load: {middle:.0} KiB -> {last:.0} KiB");

    // Churn: sessions closing and opening must not leave memory behind.
    for round in 0..2 {
        sessions(&url, SESSIONS, Duration::from_secs(3)).await;
        // Frame loops end within a poll period of their viewer leaving.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let after = rss_kib(pid).unwrap();
        println!("churn round {round}: server RSS {after} KiB");
        assert!(after as f64 <= peak as f64 * 1.25 + 16384.0, "server memory after churn round {round}: {after} KiB (peak under load {peak} KiB)");
    }
}
