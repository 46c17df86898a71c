//! The browser viewer as a person uses it (issue 16): the renderer's own page in Debian's
//! headless Chromium, driven over the DevTools protocol (tests/src/cdp.rs) with real mouse
//! events. The page connects and frames arrive and change; a left drag moves the camera the
//! server renders with; a Ctrl+left drag on the tall box picks and moves it; the overlay and
//! reconstruction switches reach the frames; a wrong token is refused with a message on the
//! page; a killed server is reported on the page. It also prints the frame latency and bytes
//! per frame at 512² over loopback (README "Remote viewing in a browser").
//!
//! Needs Chromium (Debian package `chromium`; `.ci/run` installs it). Without it the test says
//! why and passes, unless `EDGEPOINT_REQUIRE_CHROMIUM=1` (set by `.ci/run`).
use edgepoint_tests::cdp::{find_chromium, Browser};
use edgepoint_tests::wait_for;
use serde_json::Value;
use std::time::Duration;

const SIZE: u32 = 256;
const TOKEN: &str = "browser-test-token-0123456789";

/// The page's state (window.edgepoint) as JSON.
fn page(b: &mut Browser) -> Value {
    b.eval(
        "JSON.stringify({status: edgepoint.status, frames: edgepoint.frames, seq: edgepoint.lastSeq, tiles: edgepoint.lastTiles, \
         refused: edgepoint.refused, lost: edgepoint.lost, camera: edgepoint.camera, picked: edgepoint.picked, \
         header: edgepoint.header, statusText: document.getElementById('status').hidden ? '' : document.getElementById('status').textContent, \
         stats: document.getElementById('stats').textContent})",
    )
    .ok()
    .and_then(|v| v.as_str().and_then(|s| serde_json::from_str(s).ok()))
    .unwrap_or(Value::Null)
}

/// A hash of the canvas pixels, and how many are not black.
fn canvas(b: &mut Browser) -> (u64, u64) {
    let v = b
        .eval(
            "(() => { const c = document.getElementById('frame'); const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; \
             let h = 0, lit = 0; for (let i = 0; i < d.length; i += 4) { h = (Math.imul(h, 31) + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) | 0; \
             if (d[i] + d[i + 1] + d[i + 2] > 30) lit++; } return [h >>> 0, lit]; })()",
        )
        .unwrap();
    (v[0].as_u64().unwrap(), v[1].as_u64().unwrap())
}

/// The canvas's page position of frame pixel (x, y).
fn on_canvas(b: &mut Browser, x: f64, y: f64) -> (f64, f64) {
    let r = b.eval("(() => { const r = document.getElementById('frame').getBoundingClientRect(); const c = document.getElementById('frame'); return [r.left, r.top, r.width / c.width, r.height / c.height]; })()").unwrap();
    let f = |i: usize| r[i].as_f64().unwrap();
    (f(0) + x * f(2), f(1) + y * f(3))
}

fn eye(p: &Value) -> Vec<f64> {
    p["camera"]["eye"].as_array().map(|a| a.iter().map(|v| v.as_f64().unwrap()).collect()).unwrap_or_default()
}

#[test]
fn the_page_shows_frames_follows_the_mouse_and_reports_refusals_and_lost_connections() {
    let required = std::env::var("EDGEPOINT_REQUIRE_CHROMIUM").is_ok_and(|v| v == "1");
    let Some(chromium) = find_chromium() else {
        assert!(!required, "EDGEPOINT_REQUIRE_CHROMIUM=1 but Chromium is not installed (apt-get install chromium)");
        eprintln!("SKIPPED the browser test: Chromium is not installed (apt-get install chromium)");
        return;
    };
    let dir = std::env::temp_dir().join(format!("edgepoint-browser-test-{}", edgepoint_tests::unique_suffix()));
    std::fs::create_dir_all(&dir).unwrap();
    let token_file = dir.join("token");
    std::fs::write(&token_file, format!("{TOKEN}\n")).unwrap();
    let cluster = edgepoint_tests::cluster_with(1, |o| {
        o.web = Some("127.0.0.1:0".into());
        o.server_args = vec!["--token-file".into(), token_file.display().to_string()];
    })
    .expect("local cluster with the browser viewer");
    let base = cluster.web_url().expect("the server printed its page URL").to_string();
    let mut b = Browser::start(&chromium).expect("Chromium starts with DevTools");

    // The page connects and frames with content arrive, then change as samples come in.
    b.navigate(&format!("{base}?scene=cornell&shader=direct&size={SIZE}#token={TOKEN}")).unwrap();
    let live = wait_for(Duration::from_secs(90), || page(&mut b)["frames"].as_u64() >= Some(3));
    assert!(live, "no frames on the page: {}", page(&mut b));
    let first = canvas(&mut b);
    assert!(wait_for(Duration::from_secs(30), || canvas(&mut b).1 > (SIZE * SIZE / 4) as u64), "the frame stays dark: {:?}", canvas(&mut b));
    let seq0 = page(&mut b)["seq"].as_u64().unwrap();
    assert!(
        wait_for(Duration::from_secs(30), || page(&mut b)["seq"].as_u64() > Some(seq0 + 2) && canvas(&mut b).0 != first.0),
        "frames stopped arriving or never changed"
    );
    let p = page(&mut b);
    assert_eq!(p["status"], "live");
    let stats = p["stats"].as_str().unwrap();
    for what in ["fps", "samples/frame", "bytes/frame", "latency", "ms:"] {
        assert!(stats.contains(what), "the stats overlay lacks {what}: {stats}");
    }

    // A left drag orbits: the server renders from another eye at the same distance.
    let eye0 = eye(&page(&mut b));
    let target: Vec<f64> = page(&mut b)["camera"]["target"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let (from, to) = (on_canvas(&mut b, 80.0, 128.0), on_canvas(&mut b, 160.0, 128.0));
    b.drag("left", from, to, 0, Duration::from_millis(50)).unwrap();
    assert!(wait_for(Duration::from_secs(20), || { let e = eye(&page(&mut b)); !e.is_empty() && e != eye0 }), "the camera did not move after a drag");
    let d = |e: &[f64]| e.iter().zip(&target).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
    let e1 = eye(&page(&mut b));
    assert!((d(&e1) - d(&eye0)).abs() < 1e-3 * d(&eye0), "an orbit keeps the distance: {} vs {}", d(&e1), d(&eye0));
    b.eval("document.getElementById('reset').click()").unwrap();
    assert!(wait_for(Duration::from_secs(20), || eye(&page(&mut b)) == eye0), "reset did not bring the camera back");

    // Ctrl+left drag on the tall box: the server picks it and applies the moves (the frames'
    // scene epoch rises), the camera stays.
    let scene = edgepoint_scene::builtin::load("cornell").unwrap();
    let id = scene.object_id("tallbox").unwrap() as usize;
    let (lo, hi) = scene.object_bounds(id);
    let front = glam::Vec3::new((lo.x + hi.x) * 0.5, hi.y * 0.6, lo.z + 0.05 * (hi.z - lo.z));
    let (px, py, _) = scene.camera.frame(SIZE, SIZE).project(front).unwrap();
    let (from, to) = (on_canvas(&mut b, px as f64, py as f64), on_canvas(&mut b, px as f64 - 40.0, py as f64));
    b.drag("left", from, to, 2, Duration::from_millis(400)).unwrap();
    assert!(wait_for(Duration::from_secs(20), || page(&mut b)["picked"]["name"] == "tallbox"), "no pick of the tall box: {}", page(&mut b)["picked"]);
    assert!(wait_for(Duration::from_secs(20), || page(&mut b)["header"]["epoch"].as_u64() > Some(0)), "the server applied no object move");
    assert_eq!(eye(&page(&mut b)), eye0, "moving an object leaves the camera alone");

    // The switches reach the server's frames.
    b.eval("(() => { const s = document.getElementById('overlay'); s.value = 'classes'; s.dispatchEvent(new Event('change')); })()").unwrap();
    assert!(wait_for(Duration::from_secs(20), || page(&mut b)["header"]["overlay"] == "classes"), "the overlay switch reached no frame");
    b.eval("(() => { const s = document.getElementById('reconstruction'); s.value = 'render-cache'; s.dispatchEvent(new Event('change')); })()").unwrap();
    assert!(wait_for(Duration::from_secs(20), || page(&mut b)["header"]["reconstruction"] == "render-cache"), "the reconstruction switch reached no frame");

    // Figures at 512² over loopback: bytes per frame and end-to-end latency, at rest and
    // while the camera orbits (a turn each display frame, as a held drag gives, swinging
    // between the scene camera and 0.15 rad beside it so the eye stays inside the box).
    b.navigate(&format!("{base}?scene=cornell&shader=direct&size=512&m=1#token={TOKEN}")).unwrap();
    assert!(wait_for(Duration::from_secs(90), || page(&mut b)["frames"].as_u64() >= Some(5)), "no 512² frames: {}", page(&mut b));
    let secs: f64 = std::env::var("EDGEPOINT_BROWSER_MEASURE_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(8.0);
    let mut figures = serde_json::Map::new();
    for (phase, setup) in [("rest", ""), ("orbit", "let k = 0; window.__spin = setInterval(() => edgepoint.orbitBy(((k++ / 15) | 0) % 2 ? -0.01 : 0.01, 0), 16);")] {
        b.eval(&format!("{setup} edgepoint.bytes = []; edgepoint.lat = []; edgepoint.f0 = edgepoint.frames; edgepoint.t0 = performance.now(); \
            window.__lat = setInterval(() => {{ if (edgepoint.latency != null) edgepoint.lat.push(edgepoint.latency); }}, 50); \
            edgepoint.flog = []; window.__flog = setInterval(() => {{ const h = edgepoint.header; if (h && h.seq !== window.__fseq) {{ window.__fseq = h.seq; \
            edgepoint.flog.push([h.seq, h.tiles.length, h.camera.eye[0], h.total_ms, h.samples_used, h.frames_dropped]); }} }}, 5); 0")).unwrap();
        std::thread::sleep(Duration::from_secs_f64(secs));
        let v = b.eval("(() => { clearInterval(window.__lat); clearInterval(window.__spin); clearInterval(window.__flog); const s = (a) => a.slice().sort((x, y) => x - y); \
            const q = (a, f) => a.length ? s(a)[Math.min(a.length - 1, Math.floor(f * a.length))] : null; \
            return {frames: edgepoint.frames - edgepoint.f0, fps: (edgepoint.frames - edgepoint.f0) * 1000 / (performance.now() - edgepoint.t0), \
            bytes_mean: edgepoint.bytes.reduce((a, b) => a + b, 0) / Math.max(1, edgepoint.bytes.length), bytes_median: q(edgepoint.bytes, 0.5), \
            latency_median_ms: q(edgepoint.lat, 0.5), latency_p95_ms: q(edgepoint.lat, 0.95), \
            tiles_changed_mean: edgepoint.flog.reduce((a, f) => a + f[1], 0) / Math.max(1, edgepoint.flog.length), tiles_per_frame: Math.ceil(512 / 32) ** 2, \
            frame_loop_ms_median: q(edgepoint.flog.map((f) => f[3]), 0.5)}; })()").unwrap();
        if std::env::var_os("EDGEPOINT_BROWSER_FRAME_LOG").is_some() {
            eprintln!("{phase} [seq, tiles, eye.x, ms]: {}", b.eval("JSON.stringify(edgepoint.flog.slice(0, 60))").unwrap());
        }
        figures.insert(phase.into(), v);
    }
    figures.insert("raw_rgb_frame_bytes".into(), (512u64 * 512 * 3).into());
    println!("browser 512x512 loopback: {}", Value::Object(figures.clone()));
    assert!(figures["orbit"]["frames"].as_u64() > Some(0), "no frames while orbiting");

    // A wrong token is refused, and the page says so.
    b.navigate(&format!("{base}?scene=cornell&size={SIZE}&m=2#token=wrong-token-0123456789")).unwrap();
    assert!(wait_for(Duration::from_secs(20), || page(&mut b)["status"] == "refused"), "a wrong token was not refused: {}", page(&mut b));
    let p = page(&mut b);
    assert!(p["refused"].as_str().unwrap().contains("UNAUTHENTICATED"), "{}", p["refused"]);
    assert!(p["statusText"].as_str().unwrap().contains("refused"), "the page shows no refusal: {}", p["statusText"]);
    assert_eq!(p["frames"], 0);

    // A dropped connection (the server killed) is reported on the page.
    b.navigate(&format!("{base}?scene=cornell&size={SIZE}&m=3#token={TOKEN}")).unwrap();
    assert!(wait_for(Duration::from_secs(60), || page(&mut b)["frames"].as_u64() >= Some(2)), "no frames before the kill: {}", page(&mut b));
    let pid = cluster.server_pid().expect("the server runs");
    // SAFETY: kill(2) on the server child this test's cluster started.
    assert_eq!(unsafe { libc::kill(pid as i32, libc::SIGKILL) }, 0);
    assert!(wait_for(Duration::from_secs(20), || page(&mut b)["status"] == "lost"), "the page did not notice the lost server: {}", page(&mut b));
    let shown = page(&mut b)["statusText"].as_str().unwrap_or("").to_string();
    assert!(shown.contains("Connection to the renderer lost"), "the page shows: {shown}");
    drop(b);
    let _ = std::fs::remove_dir_all(&dir);
}
