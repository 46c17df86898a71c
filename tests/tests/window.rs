//! The interactive window as a person uses it: the real viewer with a local cluster in a
//! window on a virtual X display (Xvfb), driven by synthetic mouse and key input (xdotool).
//! What the server reports in each frame (stats.jsonl: the camera it rendered with, the
//! overlay, the scene epoch that object moves bump) shows that the input reached it.
//!
//! Needs `Xvfb` and `xdotool` (Debian packages `xvfb`, `xdotool`; `.ci/run` installs them).
//! Without them the test says why and passes, unless `EDGEPOINT_REQUIRE_XVFB=1` (set by
//! `.ci/run`), which makes their absence a failure.
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use edgepoint_tests::wait_for;
use std::time::Duration;

const SIZE: u32 = 256;

fn have(tool: &str) -> bool {
    Command::new("sh").args(["-c", &format!("command -v {tool}")]).stdout(Stdio::null()).status().is_ok_and(|s| s.success())
}

/// Kills the child (by its own pid) when dropped.
struct Kill(Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts Xvfb on a free display number; returns it and the display name.
fn start_xvfb() -> (Kill, String) {
    for n in 0..40 {
        let d = 60 + (std::process::id() as usize + n * 7) % 400;
        if Path::new(&format!("/tmp/.X{d}-lock")).exists() || Path::new(&format!("/tmp/.X11-unix/X{d}")).exists() {
            continue;
        }
        let child = Command::new("Xvfb")
            // -noreset: an X server resets when its last client disconnects, and a client
            // connecting meanwhile is refused (the readiness check below is such a client).
            .args([format!(":{d}").as_str(), "-screen", "0", "800x600x24", "-nolisten", "tcp", "-noreset"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("Xvfb starts");
        let mut k = Kill(child);
        // Its socket appears before it accepts clients: wait until a client connects.
        let up = wait_for(Duration::from_secs(10), || {
            Path::new(&format!("/tmp/.X11-unix/X{d}")).exists()
                && Command::new("xdotool").arg("getdisplaygeometry").env("DISPLAY", format!(":{d}")).output().is_ok_and(|o| o.status.success())
        });
        if up && k.0.try_wait().unwrap().is_none() {
            return (k, format!(":{d}"));
        }
    }
    panic!("no free X display for Xvfb");
}

fn xdo(display: &str, args: &[&str]) -> String {
    let o = Command::new("xdotool").args(args).env("DISPLAY", display).output().expect("xdotool runs");
    assert!(o.status.success(), "xdotool {args:?}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stats(out: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(out.join("stats.jsonl"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

fn last_stats(out: &Path) -> Option<serde_json::Value> {
    stats(out).pop()
}

fn eye(s: &serde_json::Value) -> [f64; 3] {
    let e = s["camera"]["eye"].as_array().expect("frames report their camera");
    [e[0].as_f64().unwrap(), e[1].as_f64().unwrap(), e[2].as_f64().unwrap()]
}

/// A key pressed long enough for the window's polling loop to see it.
fn press(display: &str, key: &str) {
    xdo(display, &["keydown", key]);
    std::thread::sleep(Duration::from_millis(200));
    xdo(display, &["keyup", key]);
}

/// Drags with `button` from `from` to `to` (window coordinates) in small steps.
fn drag(display: &str, wid: &str, button: &str, from: (i32, i32), to: (i32, i32), hold_first: Duration) {
    xdo(display, &["mousemove", "--window", wid, &from.0.to_string(), &from.1.to_string()]);
    std::thread::sleep(Duration::from_millis(100));
    xdo(display, &["mousedown", button]);
    std::thread::sleep(hold_first);
    for k in 1..=8 {
        let x = from.0 + (to.0 - from.0) * k / 8;
        let y = from.1 + (to.1 - from.1) * k / 8;
        xdo(display, &["mousemove", "--window", wid, &x.to_string(), &y.to_string()]);
        std::thread::sleep(Duration::from_millis(60));
    }
    std::thread::sleep(Duration::from_millis(150));
    xdo(display, &["mouseup", button]);
}

#[test]
fn the_window_orbits_moves_objects_toggles_overlays_and_saves_screenshots() {
    let required = std::env::var("EDGEPOINT_REQUIRE_XVFB").is_ok_and(|v| v == "1");
    let missing: Vec<&str> = ["Xvfb", "xdotool"].into_iter().filter(|t| !have(t)).collect();
    if !missing.is_empty() {
        assert!(!required, "EDGEPOINT_REQUIRE_XVFB=1 but {} not installed (apt-get install xvfb xdotool)", missing.join(", "));
        eprintln!("SKIPPED the window test: {} not installed (apt-get install xvfb xdotool)", missing.join(", "));
        return;
    }
    let (_xvfb, display) = start_xvfb();
    let dir: PathBuf = std::env::temp_dir().join(format!("edgepoint-window-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("frames");
    let viewer = edgepoint_viewer::local::find_binary("edgepoint-viewer").expect("viewer binary built");
    let log = std::fs::File::create(dir.join("viewer.log")).unwrap();
    let stdout = std::fs::File::create(dir.join("stdout")).unwrap();
    let child = Command::new(viewer)
        .args(["--local", "--scene", "cornell", "--workers", "1", "--worker-threads", "1", "--quiet"])
        .args(["--width", &SIZE.to_string(), "--height", &SIZE.to_string()])
        .arg("--out")
        .arg(&out)
        .arg("--screenshot-dir")
        .arg(&dir)
        .env("DISPLAY", &display)
        .env("RUST_LOG", "info")
        .stdout(stdout)
        .stderr(log)
        .spawn()
        .unwrap();
    let mut viewer = Kill(child);
    let read_log = || std::fs::read_to_string(dir.join("viewer.log")).unwrap_or_default();

    // The window opens and frames with content arrive.
    let mut wid = String::new();
    let opened = wait_for(Duration::from_secs(60), || {
        let o = Command::new("xdotool").args(["search", "--name", "edgepoint-viewer"]).env("DISPLAY", &display).output().unwrap();
        wid = String::from_utf8_lossy(&o.stdout).lines().next().unwrap_or("").to_string();
        !wid.is_empty()
    });
    assert!(opened, "no window appeared; viewer log:\n{}", read_log());
    let content = wait_for(Duration::from_secs(60), || last_stats(&out).is_some_and(|s| s["pixels"]["cache_points"].as_u64() > Some(1000)));
    assert!(content, "no frames with content; viewer log:\n{}", read_log());
    // Keys go to the window under the pointer (no window manager: focus follows it).
    xdo(&display, &["mousemove", "--window", &wid, "128", "128"]);
    let _ = Command::new("xdotool").args(["windowfocus", &wid]).env("DISPLAY", &display).status();
    let start_eye = eye(&last_stats(&out).unwrap());

    // Ctrl+left drag on the tall box moves it: the server answers the pick and applies the
    // moves (each bumps the scene epoch it reports).
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let id = scene.object_id("tallbox").unwrap() as usize;
    let (lo, hi) = scene.object_bounds(id);
    let front = glam::Vec3::new((lo.x + hi.x) * 0.5, hi.y * 0.6, lo.z + 0.05 * (hi.z - lo.z));
    let (px, py, _) = scene.camera.frame(SIZE, SIZE).project(front).unwrap();
    let (px, py) = (px as i32, py as i32);
    xdo(&display, &["keydown", "ctrl"]);
    drag(&display, &wid, "1", (px, py), (px - 40, py), Duration::from_millis(500));
    xdo(&display, &["keyup", "ctrl"]);
    assert!(wait_for(Duration::from_secs(10), || read_log().contains("picked 'tallbox'")), "no pick of the tall box at ({px}, {py}):\n{}", read_log());
    assert!(
        wait_for(Duration::from_secs(10), || last_stats(&out).is_some_and(|s| s["epoch"].as_u64() > Some(0))),
        "the server applied no object move"
    );
    assert_eq!(eye(&last_stats(&out).unwrap()), start_eye, "moving an object leaves the camera alone");

    // A left drag orbits: the server renders from another eye, at the same distance.
    drag(&display, &wid, "1", (100, 128), (170, 128), Duration::from_millis(100));
    let moved = wait_for(Duration::from_secs(10), || last_stats(&out).is_some_and(|s| eye(&s) != start_eye));
    assert!(moved, "the camera the server reports did not change after a left drag");
    let s = last_stats(&out).unwrap();
    let (e, t) = (eye(&s), s["camera"]["target"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect::<Vec<_>>());
    let d = |a: [f64; 3]| ((a[0] - t[0]).powi(2) + (a[1] - t[1]).powi(2) + (a[2] - t[2]).powi(2)).sqrt();
    assert!((d(e) - d(start_eye)).abs() < 1e-3 * d(start_eye), "an orbit keeps the distance: {} vs {}", d(e), d(start_eye));
    // R puts it back.
    press(&display, "r");
    assert!(wait_for(Duration::from_secs(10), || last_stats(&out).is_some_and(|s| eye(&s) == start_eye)), "R did not reset the camera");

    // O switches the server's overlay on.
    press(&display, "o");
    assert!(
        wait_for(Duration::from_secs(10), || last_stats(&out).is_some_and(|s| s["overlay"] == "edges")),
        "the overlay key reached no frame"
    );
    // B switches the reconstruction.
    press(&display, "b");
    assert!(
        wait_for(Duration::from_secs(10), || last_stats(&out).is_some_and(|s| s["reconstruction"] == "render-cache")),
        "the reconstruction key reached no frame"
    );

    // P writes a screenshot and prints its path.
    press(&display, "p");
    let printed = || std::fs::read_to_string(dir.join("stdout")).unwrap_or_default();
    assert!(wait_for(Duration::from_secs(10), || printed().contains("screenshot ")), "no screenshot line on stdout");
    let path = printed().lines().find_map(|l| l.strip_prefix("screenshot ")).unwrap().to_string();
    let img = image::open(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    assert_eq!((img.width(), img.height()), (SIZE, SIZE));

    // Esc closes the window and the viewer exits cleanly.
    press(&display, "Escape");
    let ended = wait_for(Duration::from_secs(20), || viewer.0.try_wait().unwrap().is_some());
    assert!(ended, "Esc did not end the viewer");
    let status = viewer.0.wait().unwrap();
    assert!(status.success(), "viewer exit status {status}; log:\n{}", read_log());
    let _ = std::fs::remove_dir_all(&dir);
}
