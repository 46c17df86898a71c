//! Frames in motion, through the real binaries (`edgepoint-bench motion` runs a local
//! server and workers, drives a session along a path one step per frame and measures every
//! frame against the converged reference of its exact camera and object state). Quality
//! bounds only, no wall-clock bounds: the frame rate is capped low, so the samples a frame
//! gets depend on the sampling, not on how busy the machine is.
use serde_json::Value;
use std::process::Command;

/// One cluster at a time: the two cores shade for one session, so a frame's samples do not
/// depend on which other test happens to run beside it.
static ONE: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs `edgepoint-bench motion` at `size`² with `args` (plus test-sized defaults) and
/// returns its JSON.
fn motion(size: u32, args: &[&str]) -> Value {
    let _one = ONE.lock().unwrap_or_else(|p| p.into_inner());
    let bench = edgepoint_viewer::local::find_binary("edgepoint-bench").expect("edgepoint-bench is built with the workspace's tests");
    let refs = std::env::temp_dir().join(format!("edgepoint-motion-refs-{}", std::process::id()));
    let out = Command::new(bench)
        .arg("motion")
        .args(args)
        .args(["--width", &size.to_string(), "--height", &size.to_string(), "--frames", "30", "--max-fps", "8", "--reference-spp", "8", "--modes", "epr"])
        .args(["--worker-threads", "1", "--json", "--ref-cache"])
        .arg(&refs)
        .env("RUST_LOG", "warn")
        .output()
        .expect("edgepoint-bench runs");
    let _ = std::fs::remove_dir_all(&refs);
    assert!(out.status.success(), "edgepoint-bench motion {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

fn frames(v: &Value) -> &Vec<Value> {
    v["modes"]["epr"]["frames"].as_array().expect("per-frame measures")
}

#[test]
fn an_orbiting_camera_shows_no_speckles_or_see_through_surfaces() {
    // At the 512²: at smaller sizes the strip entering at the frame's border each
    // frame (not sampled yet) and edge pixels weigh more, so the bound would measure those.
    let v = motion(512, &["--scene", "cornell-point", "--path", "orbit", "--degrees-per-frame", "1"]);
    let f = frames(&v);
    assert_eq!(f.len(), 30);
    for fr in f.iter().skip(5) {
        let o = fr["outlier_fraction"].as_f64().unwrap();
        assert!(o <= 0.002, "frame {}: {:.3} % of the pixels are off by more than 0.25 (speckles, see-through)", fr["frame"], 100.0 * o);
    }
    // Newly exposed surfaces (the orbit uncovers them every frame) fill within a few frames.
    let fill = &v["modes"]["epr"]["newly_exposed_fill_frames_max"];
    assert!(fill.as_f64().is_some_and(|m| m <= 3.0), "newly exposed regions took {fill} frames to fill");
    // The first frame shown has samples everywhere it can: coarse but complete.
    assert!(f[0]["samples_used"].as_u64().unwrap() > 0, "no frame is sent before the first samples");
    assert!(f[0]["outlier_fraction"].as_f64().unwrap() < 0.2, "frame 1 is coarse but complete: {}", f[0]);
}

#[test]
fn a_moving_object_keeps_showing_where_it_is() {
    for (scene, object) in [("torus-capsule", "torus"), ("cornell-point", "tallbox")] {
        let v = motion(256, &["--scene", scene, "--path", &format!("move-object:{object}")]);
        let f = frames(&v);
        assert_eq!(f.len(), 30);
        for fr in f.iter().skip(3) {
            let c = fr["moved_object_coverage"].as_f64().expect("the object is in view");
            assert!(c >= 0.98, "{scene}: frame {}: the moving {object} shows right on only {:.1} % of its pixels", fr["frame"], 100.0 * c);
        }
    }
}
