//! Helpers for the multi-process integration tests in `tests/tests/`.
//!
//! The tests spawn the real `edgepoint-server`, `edgepoint-worker` and `edgepoint-viewer`
//! binaries. `cargo test --workspace` builds them first (each binary's package has
//! integration tests of its own, so cargo builds its executables before running any test);
//! [`edgepoint_viewer::local::find_binary`] finds them next to the test executable.
use anyhow::{bail, Context, Result};
use edgepoint_proto as pb;
use edgepoint_viewer::client::{Event, SessionClient};
use std::time::{Duration, Instant};

pub use edgepoint_viewer::local::{LocalCluster, LocalOptions};

/// Starts a local cluster of `workers` shader workers and one server, with quiet logs.
pub fn cluster(workers: usize) -> Result<LocalCluster> {
    LocalCluster::start(LocalOptions {
        workers,
        worker_threads: Some(1),
        log_level: Some("warn".into()),
        ..Default::default()
    })
}

/// A `Start` for a built-in scene at a small size with QOI frames.
pub fn start_builtin(scene: &str, width: u32, height: u32) -> pb::Start {
    pb::Start {
        scene: Some(edgepoint_proto::builtin_source(scene)),
        width,
        height,
        shader: "direct".into(),
        encoding: pb::FrameEncoding::Qoi as i32,
        ..Default::default()
    }
}

/// Receives the next frame (skipping `rejected` notes, which are returned separately),
/// failing after `timeout`.
pub async fn next_frame(client: &mut SessionClient, timeout: Duration) -> Result<(pb::Frame, Vec<pb::Rejected>)> {
    let deadline = Instant::now() + timeout;
    let mut rejected = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            bail!("no frame within {timeout:?}");
        }
        match tokio::time::timeout(left, client.next_event()).await {
            Err(_) => bail!("no frame within {timeout:?}"),
            Ok(None) => bail!("session ended"),
            Ok(Some(Err(e))) => return Err(e).context("session failed"),
            Ok(Some(Ok(Event::Frame(f)))) => return Ok((f, rejected)),
            Ok(Some(Ok(Event::Rejected(r)))) => rejected.push(r),
        }
    }
}
