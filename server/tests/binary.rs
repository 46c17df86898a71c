//! The `edgepoint-server` binary: CLI contract (`listening <addr>` on stdout, health
//! service, `--worker host:port`), a session through it, graceful exit on SIGTERM.
mod common;

use common::{open, start_msg, Worker};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

fn server_bin() -> &'static str {
    env!("CARGO_BIN_EXE_edgepoint-server")
}

#[test]
fn help_documents_every_flag() {
    let out = Command::new(server_bin()).arg("--help").output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = help.lines().collect();
    for flag in ["--listen", "--worker", "--max-sessions", "--max-message-mib", "--points-per-pixel"] {
        let i = lines.iter().position(|l| l.trim_start().starts_with(flag)).unwrap_or_else(|| panic!("{flag} missing"));
        // clap puts the doc on the same line (short help) or the next one (long help).
        let doc = format!("{} {}", lines[i], lines.get(i + 1).unwrap_or(&""));
        assert!(doc.split_whitespace().count() > 5, "{flag} undocumented: {doc}");
    }
    let bad = Command::new(server_bin()).args(["--worker", "http://", "--listen", "127.0.0.1:0"]).output().unwrap();
    assert!(!bad.status.success(), "a bad worker address is an error");
    assert!(String::from_utf8_lossy(&bad.stderr).contains("worker address"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serves_sessions_and_health_and_exits_on_sigterm() {
    let w = Worker::spawn();
    let host_port = w.url.trim_start_matches("http://").to_string();
    let mut child = Command::new(server_bin())
        .args(["--listen", "127.0.0.1:0", "--worker", &host_port, "--max-sessions", "2"])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let line = tokio::task::spawn_blocking(move || {
        let mut l = String::new();
        BufReader::new(stdout).read_line(&mut l).unwrap();
        l
    })
    .await
    .unwrap();
    let addr = line.trim().strip_prefix("listening ").unwrap_or_else(|| panic!("bad first line {line:?}")).to_string();
    let url = format!("http://{addr}");

    let channel = tonic::transport::Channel::from_shared(url.clone()).unwrap().connect().await.unwrap();
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel);
    let r = health
        .check(tonic_health::pb::HealthCheckRequest { service: "edgepoint.v1.Renderer".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.status, tonic_health::pb::health_check_response::ServingStatus::Serving as i32);

    let mut v = open(&url, start_msg(edgepoint_proto::builtin_source("cornell"), 32, 24)).await.unwrap();
    v.started().await;
    v.frame_with_samples(20).await;

    let pid = child.id().to_string();
    assert!(Command::new("kill").args(["-TERM", &pid]).status().unwrap().success());
    // The session stream ends and the process exits cleanly.
    while let Ok(Some(_)) =
        tokio::time::timeout(Duration::from_secs(10), v.rx.message()).await.expect("stream ends after SIGTERM")
    {}
    // A liveness bound, not a speed check: a process that never exits fails here instead of
    // hanging the suite.
    let status = tokio::time::timeout(Duration::from_secs(60), tokio::task::spawn_blocking(move || child.wait().unwrap()))
        .await
        .expect("the server exits after SIGTERM")
        .unwrap();
    assert!(status.success(), "exit status {status:?}");
}
