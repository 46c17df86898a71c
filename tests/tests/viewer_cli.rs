//! The viewer binary as a user runs it: `--local` headless, frames and stats on disk.
use std::process::Command;

#[test]
fn headless_local_run_writes_frames_and_stats() {
    let viewer = edgepoint_viewer::local::find_binary("edgepoint-viewer").expect("viewer binary built");
    let out = std::env::temp_dir().join(format!("edgepoint-viewer-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let status = Command::new(viewer)
        .args(["--local", "--headless", "--frames", "6", "--width", "64", "--height", "48", "--quiet", "--orbit"])
        .arg("--out")
        .arg(&out)
        .env("RUST_LOG", "warn")
        .status()
        .expect("viewer runs");
    assert!(status.success(), "viewer exit status {status}");
    let pngs = std::fs::read_dir(&out).unwrap().filter(|e| {
        e.as_ref().unwrap().path().extension().map(|x| x == "png").unwrap_or(false)
    });
    assert_eq!(pngs.count(), 6);
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = stats.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 6);
    for l in &lines {
        assert!(l["stages"].is_object(), "stats line has per-stage times: {l}");
        assert_eq!(l["width"], 64);
    }
    let img = image::open(out.join(edgepoint_viewer::headless::frame_file_name(1))).unwrap();
    assert_eq!((img.width(), img.height()), (64, 48));
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn viewer_with_a_missing_scene_file_fails_clearly() {
    let viewer = edgepoint_viewer::local::find_binary("edgepoint-viewer").expect("viewer binary built");
    let out = Command::new(viewer)
        .args(["--local", "--headless", "--frames", "1", "--scene", "/nonexistent/model.ply"])
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/model.ply"), "error names the path: {err}");
}
