//! The `edgepoint-viewer` command line: help text, argument errors, headless runs against a
//! mock renderer, and the local cluster's life cycle with fake server/worker executables.
mod common;

use common::*;
use std::path::Path;
use std::process::{Command, Output, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_edgepoint-viewer");

fn viewer(args: &[&str]) -> Output {
    Command::new(BIN).args(args).env("RUST_LOG", "warn").output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn help_mentions_every_flag() {
    let o = viewer(&["--help"]);
    assert!(o.status.success());
    let help = String::from_utf8_lossy(&o.stdout);
    for flag in [
        "--server", "--local", "--workers", "--worker-threads", "--worker-idle", "--bin-dir", "--server-arg", "--cluster-log",
        "--cluster-log-file", "--scene", "--width", "--height", "--shader", "--shader-param", "--encoding",
        "--frames", "--out", "--headless", "--orbit", "--orbit-speed", "--orbit-pivot", "--orbit-radius",
        "--orbit-elevation", "--orbit-start", "--camera", "--camera-path", "--loop-path", "--record-path",
        "--screenshot-dir",
        "--move-object", "--sparseness",
        "--max-fps", "--quiet", "--stats-stdout", "--start-timeout-secs", "--split",
    ] {
        assert!(help.contains(&format!("{flag} ")) || help.contains(&format!("{flag}\n")), "--help lacks {flag}:\n{help}");
    }
    // Every option has a description: no option line stands alone without text after it.
    for enc in ["qoi", "png", "jpeg", "raw"] {
        assert!(help.contains(enc), "encoding {enc} not listed");
    }
    // The shared shader table: every shader and parameter with its range (issue 12 item 8).
    for s in edgepoint_proto::shaders::SHADERS {
        assert!(help.contains(&format!("{}:", s.name)), "--help lacks shader {}", s.name);
        for p in s.params {
            assert!(help.contains(p.name) && help.contains(p.help), "--help lacks parameter {}", p.name);
        }
    }
    assert!(help.contains("300 frames"), "--help says what a headless run without --frames does");
    // No colour codes in a redirected log (issue 12 item 16).
    assert!(!String::from_utf8_lossy(&o.stderr).contains('\x1b'));
}

#[test]
fn bad_flag_values_fail_with_a_clear_message() {
    let cases: &[(&[&str], &[&str])] = &[
        (&["--width", "abc"], &["--width", "abc"]),
        (&["--height", "0"], &["--height", "0"]),
        (&["--encoding", "bmp"], &["--encoding", "bmp", "qoi"]),
        (&["--shader-param", "shadow_rays"], &["--shader-param", "KEY=VALUE"]),
        (&["--shader-param", "shadow_rays=many"], &["shadow_rays", "must be a number"]),
        (&["--workers", "0"], &["--workers", "0"]),
        (&["--sparseness", "-3"], &["--sparseness", "positive"]),
        (&["--max-fps", "nan"], &["--max-fps"]),
        (&["--orbit-speed", "inf"], &["--orbit-speed", "finite"]),
        (&["--camera", "eye=1,2"], &["--camera", "eye needs three numbers"]),
        (&["--camera", "zoom=2"], &["--camera", "unknown key 'zoom'"]),
        (&["--orbit", "--orbit-elevation", "89"], &["--orbit-elevation", "85"]),
        (&["--orbit-radius", "2"], &["--orbit-radius", "--orbit"]),
        (&["--orbit", "--camera-path", "p.jsonl"], &["--camera-path", "--orbit"]),
        (&["--loop-path"], &["--loop-path", "--camera-path"]),
        (&["--server", "http://127.0.0.1:1", "--local"], &["--local", "--server"]),
        (&["--no-such-flag"], &["--no-such-flag"]),
    ];
    for (args, needles) in cases {
        let o = viewer(args);
        assert_eq!(o.status.code(), Some(2), "{args:?} should be a usage error");
        let e = stderr(&o);
        for n in *needles {
            assert!(e.contains(n), "{args:?}: stderr lacks '{n}':\n{e}");
        }
    }
}

#[test]
fn a_missing_scene_file_is_named_before_anything_starts() {
    // Port 1 has no server: the scene error must come first.
    let o = viewer(&["--server", "http://127.0.0.1:1", "--scene", "/no/such/dir/bunny.ply"]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("error:") && e.contains("/no/such/dir/bunny.ply"), "{e}");
}

#[test]
fn a_bare_name_that_is_a_file_is_read_as_a_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("cornell"), b"x").unwrap();
    let o = Command::new(BIN)
        .args(["--server", "http://127.0.0.1:1", "--scene", "cornell"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("needs one of the extensions .ply, .obj"), "{}", stderr(&o));
}

#[test]
fn an_unreachable_server_is_a_clear_error() {
    let o = viewer(&["--server", "http://127.0.0.1:1", "--headless", "--frames", "1"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("cannot connect to http://127.0.0.1:1"), "{}", stderr(&o));
}

#[test]
fn a_rejected_start_exits_nonzero_with_the_servers_message() {
    let mock = MockServer::start(0);
    let o = viewer(&["--server", &mock.url(), "--scene", "broken", "--headless", "--frames", "1"]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains(&format!("error: INVALID_ARGUMENT: {BROKEN_MESSAGE}")), "{e}");
}

fn stats_lines(dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("stats.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn headless_run_writes_pngs_stats_and_drives_the_script() {
    // Paced: frame k + 1 goes out once the viewer's script step after frame k has arrived,
    // so the check below sees every step even on a loaded machine (the viewer exits right
    // after its last frame, and what it still had queued then need not reach the mock).
    let mock = MockServer::start_paced(0);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("frames");
    let o = viewer(&[
        "--server", &mock.url(), "--headless", "--frames", "12", "--width", "40", "--height", "30",
        "--out", out.to_str().unwrap(), "--orbit", "--orbit-speed", "5", "--move-object", "tallbox",
        "--shader-param", "shadow_rays=16", "--sparseness", "80", "--max-fps", "200", "--encoding", "png",
        "--stats-stdout",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));

    // With --stats-stdout, stdout carries the same JSON lines as stats.jsonl, then the summary.
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stats = stats_lines(&out);
    assert_eq!(stats.len(), 12);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 13, "{stdout}");
    for (line, s) in lines.iter().zip(&stats) {
        assert_eq!(&serde_json::from_str::<serde_json::Value>(line).unwrap(), s);
    }
    assert!(lines[12].starts_with("12 frames 40x30"), "{}", lines[12]);
    for (i, s) in stats.iter().enumerate() {
        let seq = s["sequence"].as_u64().unwrap();
        assert_eq!(s["index"], i as u64 + 1);
        assert_eq!(s["encoding"], "png");
        assert_eq!(s["stages"]["reconstruct"], 2.0);
        assert_eq!(s["pixels"]["with_point"], 7);
        let file = out.join(s["file"].as_str().unwrap());
        assert_eq!(file, out.join(format!("frame_{:05}.png", i + 1)));
        let png = image::open(&file).unwrap().to_rgb8();
        assert_eq!(png, expected_image(seq, 40, 30), "{} holds frame {seq}", file.display());
    }

    let seen = mock.seen.lock().unwrap();
    let start = &seen.starts[0];
    assert_eq!((start.width, start.height, start.shader.as_str()), (40, 30, "direct"));
    assert_eq!(start.shader_params.get("shadow_rays"), Some(&16.0));
    let settings = start.settings.as_ref().unwrap();
    assert_eq!((settings.sparseness, settings.max_fps), (80.0, 200.0));
    // After each frame but the last (the run stops on it) the viewer sends the next orbit
    // camera and object move. The run ends right after its last frame, so the newest
    // messages may still be in flight: check that what arrived is exactly the scripted
    // sequence, in order, and that the script ran at all.
    let base = edgepoint_viewer::client::camera_from_wire(mock_started().camera.as_ref().unwrap());
    let base_box = glam::Vec3::new(0.5, 0.0, 0.0);
    let (mut cams, mut moves) = (0usize, 0usize);
    for m in &seen.messages {
        match m {
            edgepoint_proto::viewer_msg::Msg::Camera(c) => {
                cams += 1;
                // The first goes out right after `started`: the orbit through the mock's
                // camera (it suggests none) at its start.
                let want = base.orbit(base.target, (5.0 * (cams - 1) as f32).to_radians());
                let got = edgepoint_viewer::client::camera_from_wire(c);
                assert!((got.eye - want.eye).length() < 1e-4, "camera {cams}: {} vs {}", got.eye, want.eye);
            }
            edgepoint_proto::viewer_msg::Msg::Move(m) => {
                moves += 1;
                assert_eq!(m.object_id, 1);
                let t = edgepoint_proto::affine_from_wire(m.transform.as_ref().unwrap()).unwrap();
                // 25% of the mock scene's 2-unit X extent, 120 frames per cycle.
                let dx = 0.5 * (std::f64::consts::TAU * moves as f64 / 120.0).sin() as f32;
                assert!((glam::Vec3::from(t.translation) - (base_box + glam::Vec3::X * dx)).length() < 1e-5, "move {moves}");
            }
            other => panic!("unexpected message {other:?}"),
        }
    }
    assert!((2..=12).contains(&cams) && (1..=11).contains(&moves), "{cams} cameras, {moves} moves");
}

#[test]
fn every_encoding_round_trips_to_png() {
    let mock = MockServer::start(0);
    for enc in ["qoi", "raw", "jpeg", "png"] {
        let dir = tempfile::tempdir().unwrap();
        let o = viewer(&[
            "--server", &mock.url(), "--headless", "--quiet", "--frames", "2", "--width", "24", "--height", "16",
            "--encoding", enc, "--out", dir.path().to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{enc}: {}", stderr(&o));
        assert!(o.stdout.is_empty(), "--quiet prints no stats");
        let s = &stats_lines(dir.path())[1];
        assert_eq!(s["encoding"], enc);
        let png = image::open(dir.path().join("frame_00002.png")).unwrap().to_rgb8();
        let want = expected_image(s["sequence"].as_u64().unwrap(), 24, 16);
        let max_diff = png.pixels().zip(want.pixels()).flat_map(|(a, b)| (0..3).map(move |c| (a[c] as i32 - b[c] as i32).abs())).max().unwrap();
        assert!(max_diff <= if enc == "jpeg" { 40 } else { 0 }, "{enc}: max channel difference {max_diff}");
    }
}

#[test]
fn an_unknown_move_object_lists_the_scene_objects() {
    let mock = MockServer::start(0);
    let o = viewer(&["--server", &mock.url(), "--headless", "--frames", "1", "--move-object", "teapot"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("no object named 'teapot' (objects: floor, tallbox)"), "{}", stderr(&o));
}

#[test]
fn a_session_that_ends_early_is_an_error() {
    let mock = MockServer::start(3);
    let dir = tempfile::tempdir().unwrap();
    let o = viewer(&["--server", &mock.url(), "--headless", "--quiet", "--frames", "10", "--out", dir.path().to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("ended the session after 3 of 10 frames"), "{}", stderr(&o));
    // Issue 12 item 12: also without a frame target (it used to exit 0).
    let o = viewer(&["--server", &mock.url(), "--headless", "--quiet", "--frames", "0", "--out", dir.path().to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("ended the session after 3 frames"), "{}", stderr(&o));
}

/// Issue 12 item 16: a headless run without --frames stops at 300 (it used to write PNGs
/// until the disk filled), and stdout gets one summary line instead of a JSON line per frame.
#[test]
fn a_headless_run_without_frames_stops_and_summarises() {
    let mock = MockServer::start(0);
    let dir = tempfile::tempdir().unwrap();
    let o = viewer(&["--server", &mock.url(), "--headless", "--width", "8", "--height", "6", "--out", dir.path().to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(stats_lines(dir.path()).len(), 300);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert_eq!(stdout.lines().count(), 1, "one line: {stdout}");
    assert!(stdout.starts_with("300 frames 8x6") && stdout.contains(&dir.path().display().to_string()), "{stdout}");
    assert!(!stderr(&o).contains('\x1b'), "no colour codes in a redirected log");
}

/// Issue 12 item 12: a server that never answers `start` is given up on with a clear
/// message (it used to wait forever).
#[test]
fn a_server_that_never_answers_start_times_out() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::spawn(move || {
        let mut held = Vec::new();
        for s in listener.incoming().flatten() {
            held.push(s); // accepted, never answered
        }
    });
    let o = viewer(&["--server", &format!("http://{addr}"), "--headless", "--frames", "1", "--start-timeout-secs", "2"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("did not answer `start` within 2 s"), "{}", stderr(&o));
}

/// Issue 12 item 15: under `cargo run` the viewer builds the server and the worker with the
/// cargo that runs it (here a fake that records its arguments and fails), before anything
/// starts.
#[cfg(unix)]
#[test]
fn under_cargo_run_the_viewer_builds_its_server_and_worker() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("cargo-args");
    let fake = dir.path().join("cargo");
    std::fs::write(&fake, format!("#!/bin/sh\necho \"$PWD $@ $CARGO_TARGET_DIR\" > {}\necho '   Compiling edgepoint-server' >&2\nexit 3\n", log.display())).unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    let o = Command::new(BIN)
        .args(["--headless", "--frames", "1"])
        .env("CARGO", &fake)
        .env("CARGO_PKG_NAME", "edgepoint-viewer")
        .env("CARGO_MANIFEST_DIR", dir.path())
        .env_remove("EDGEPOINT_BIN_DIR")
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("Compiling edgepoint-server"), "cargo's progress shows: {e}");
    assert!(e.contains("build -p edgepoint-server -p edgepoint-worker") && e.contains("failed"), "{e}");
    let args = std::fs::read_to_string(&log).unwrap();
    let exe_dir = Path::new(BIN).parent().unwrap();
    let profile = exe_dir.file_name().unwrap().to_str().unwrap();
    assert!(args.starts_with(&dir.path().display().to_string()), "run in the package directory: {args}");
    assert!(args.contains("build -p edgepoint-server -p edgepoint-worker"), "{args}");
    assert_eq!(args.contains("--release"), profile == "release", "{args}");
    assert!(args.trim_end().ends_with(&exe_dir.parent().unwrap().display().to_string()), "same target dir: {args}");
}

#[test]
fn local_cluster_children_are_wired_and_reaped_on_exit() {
    let mock = MockServer::start(0);
    let bins = tempfile::tempdir().unwrap();
    fake_bin_dir(bins.path(), mock.addr);
    let out = tempfile::tempdir().unwrap();
    let o = Command::new(BIN)
        .args(["--headless", "--quiet", "--frames", "3", "--workers", "3", "--worker-threads", "2"])
        .args(["--out", out.path().to_str().unwrap(), "--server-arg=--flag-for-server"])
        .env("EDGEPOINT_BIN_DIR", bins.path())
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(stats_lines(out.path()).len(), 3);
    let workers = fake_log(bins.path(), "edgepoint-worker");
    let servers = fake_log(bins.path(), "edgepoint-server");
    assert_eq!(workers.len(), 3);
    assert_eq!(servers.len(), 1);
    for (_, args) in &workers {
        assert_eq!(args, "--listen 127.0.0.1:0 --threads 2");
    }
    // The server is told about every worker, by the address each reported.
    let server_args = &servers[0].1;
    assert!(server_args.starts_with("--listen 127.0.0.1:0 --worker http://127.0.0.1:"), "{server_args}");
    assert_eq!(server_args.matches("--worker http://").count(), 3, "{server_args}");
    assert!(server_args.ends_with("--flag-for-server"), "{server_args}");
    // Their stderr was forwarded with a name prefix.
    assert!(stderr(&o).contains("[edgepoint-worker #2] worker starting on"), "{}", stderr(&o));
    for (pid, _) in workers.iter().chain(&servers) {
        assert!(eventually(5, || !alive(*pid)), "child {pid} outlived the viewer");
    }
}

/// Starts the viewer on a fake cluster in front of the mock, running until stopped, and
/// waits for its first frame. Returns the child, the fake-bin dir and the output dir.
fn endless_viewer_on_fake_cluster(mock: &MockServer) -> (std::process::Child, tempfile::TempDir, tempfile::TempDir) {
    let bins = tempfile::tempdir().unwrap();
    fake_bin_dir(bins.path(), mock.addr);
    let out = tempfile::tempdir().unwrap();
    let child = Command::new(BIN)
        .args(["--headless", "--quiet", "--frames", "0", "--max-fps", "30", "--out", out.path().to_str().unwrap()])
        .env("EDGEPOINT_BIN_DIR", bins.path())
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stats = out.path().join("stats.jsonl");
    assert!(
        eventually(30, || std::fs::read_to_string(&stats).is_ok_and(|s| s.lines().count() >= 2)),
        "the viewer wrote no frames"
    );
    (child, bins, out)
}

#[test]
fn ctrl_c_ends_the_viewer_cleanly_and_kills_the_cluster() {
    let mock = MockServer::start(0);
    let (mut child, bins, _out) = endless_viewer_on_fake_cluster(&mock);
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = child.wait().unwrap();
    assert!(status.success(), "Ctrl-C should end cleanly, got {status}");
    for (pid, _) in fake_log(bins.path(), "edgepoint-worker").iter().chain(&fake_log(bins.path(), "edgepoint-server")) {
        assert!(eventually(5, || !alive(*pid)), "child {pid} outlived the viewer");
    }
}

#[test]
fn children_die_when_the_viewer_is_killed_hard() {
    let mock = MockServer::start(0);
    let (mut child, bins, _out) = endless_viewer_on_fake_cluster(&mock);
    let pids: Vec<i32> = fake_log(bins.path(), "edgepoint-worker")
        .iter()
        .chain(&fake_log(bins.path(), "edgepoint-server"))
        .map(|p| p.0)
        .collect();
    assert_eq!(pids.len(), 3);
    assert!(pids.iter().all(|&p| alive(p)));
    child.kill().unwrap(); // SIGKILL: no destructor runs; only PR_SET_PDEATHSIG can help.
    child.wait().unwrap();
    for pid in pids {
        assert!(eventually(5, || !alive(pid)), "child {pid} survived a SIGKILLed viewer");
    }
}

#[test]
fn camera_flags_go_in_start_and_a_recorded_orbit_plays_back_and_stops_at_its_end() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("orbit.jsonl");
    // Record six frames of an orbit (each frame reports the newest camera the mock got).
    let mock = MockServer::start_paced(0);
    let o = viewer(&[
        "--server", &mock.url(), "--headless", "--quiet", "--frames", "6", "--width", "16", "--height", "8",
        "--out", dir.path().join("a").to_str().unwrap(), "--orbit", "--orbit-speed", "10", "--camera", "fov=70",
        "--record-path", rec.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let start_cam = mock.seen.lock().unwrap().starts[0].camera.unwrap();
    assert!(start_cam.eye.is_none() && start_cam.target.is_none() && start_cam.fov_y_degrees == 70.0, "{start_cam:?}");
    let recorded = edgepoint_viewer::camera_path::read_path(&rec).unwrap();
    assert_eq!(recorded.len(), 6, "one camera per frame");
    let stats = stats_lines(&dir.path().join("a"));
    for (s, e) in stats.iter().zip(&recorded) {
        // The stats line and the recording both hold the camera the frame reports.
        assert_eq!(s["camera"]["eye"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect::<Vec<_>>(), e.spec.eye.unwrap().to_array());
        assert_eq!(e.spec.fov_y_degrees, Some(70.0), "the orbit takes --camera fov");
    }

    // Play it back: every camera is sent in order, and the run stops by itself once a frame
    // of the last camera has arrived.
    let mock = MockServer::start_paced(0);
    let out = dir.path().join("b");
    let o = viewer(&[
        "--server", &mock.url(), "--headless", "--quiet", "--width", "16", "--height", "8",
        "--out", out.to_str().unwrap(), "--camera-path", rec.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let seen = mock.seen.lock().unwrap();
    let sent: Vec<glam::Vec3> = seen
        .messages
        .iter()
        .filter_map(|m| match m {
            edgepoint_proto::viewer_msg::Msg::Camera(c) => Some(edgepoint_viewer::client::camera_from_wire(c).eye),
            _ => None,
        })
        .collect();
    let want: Vec<glam::Vec3> = recorded.iter().map(|e| e.spec.eye.unwrap()).collect();
    assert_eq!(sent, want);
    let last = stats_lines(&out).last().cloned().unwrap();
    assert_eq!(last["camera"]["eye"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect::<Vec<_>>(), want[5].to_array());

    // A path line that is bad is named with its file and line before anything starts.
    let bad = dir.path().join("bad.jsonl");
    std::fs::write(&bad, "{\"eye\":[0,1,2]}\n# fine so far\n{\"eye\":[0,1,\"x\"]}\n").unwrap();
    let o = viewer(&["--server", "http://127.0.0.1:1", "--camera-path", bad.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains(&format!("{}: line 3:", bad.display())), "{}", stderr(&o));
    // --orbit places the camera itself.
    let o = viewer(&["--server", "http://127.0.0.1:1", "--orbit", "--camera", "eye=0,1,2"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("cannot be combined with --orbit"), "{}", stderr(&o));
}
