//! The benchmark program's command line: every subcommand explains itself, and a bad motion
//! path is refused with the valid choices; the fuzz program, where `quality` looks for data
//! and where the benches keep their caches (issue 12). (Its integration tests also make `cargo test`
//! build the binary, which the motion tests of `tests/` run.)
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_edgepoint-bench");

fn bench(args: &[&str]) -> std::process::Output {
    Command::new(BIN).args(args).env("RUST_LOG", "warn").output().expect("edgepoint-bench runs")
}

#[test]
fn every_subcommand_has_help() {
    for sub in ["frame", "throughput", "loadtest", "load", "edges", "reference", "epi", "quality", "motion", "encode", "fuzz", "exact-area"] {
        let out = bench(&[sub, "--help"]);
        assert!(out.status.success(), "{sub} --help failed");
        assert!(String::from_utf8_lossy(&out.stdout).contains("--json"), "{sub} --help names --json");
    }
    let help = String::from_utf8_lossy(&bench(&["motion", "--help"]).stdout).to_string();
    for flag in ["--path", "--degrees-per-frame", "--modes", "--frames", "--camera"] {
        assert!(help.contains(flag), "motion --help explains {flag}");
    }
}

#[test]
fn bad_motion_arguments_are_refused_before_any_work() {
    let out = bench(&["motion", "--modes", "bogus"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("epr, render-cache"), "{}", String::from_utf8_lossy(&out.stderr));
    let out = bench(&["motion", "--frames", "0"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--frames"));
}

#[test]
fn fuzz_runs_as_long_as_asked_and_reports_json() {
    // Bounded by cases, not by seconds: how many cases a second holds depends on the
    // machine's load (a loaded CI run once managed one).
    let o = Command::new(BIN).args(["fuzz", "--parser", "mtl", "--seconds", "600", "--cases", "300", "--seed", "7", "--json"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let p = &v["parsers"][0];
    assert_eq!(p["parser"], "mtl");
    assert_eq!(p["seed"], 7);
    assert_eq!(p["cases"].as_u64(), Some(300), "{p}");
    assert_eq!(p["findings"].as_array().unwrap().len(), 0, "{p}");
    let o = Command::new(BIN).args(["fuzz", "--parser", "fbx", "--seconds", "1"]).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown parser 'fbx'"));
}

#[test]
fn quality_finds_data_at_run_time_and_caches_references_in_the_cache_directory() {
    let help = Command::new(BIN).args(["quality", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(!help.contains(env!("CARGO_MANIFEST_DIR")), "no build-time path as a default: {help}");
    let o = Command::new(BIN).args(["quality", "--all", "--data-dir", "/no/such/data"]).output().unwrap();
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("/no/such/data") && e.contains("bun_zipper.ply"), "{e}");

    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("xdg-cache");
    let o = Command::new(BIN)
        .args(["quality", "--scene", "cornell-point", "--width", "24", "--height", "16", "--reference-spp", "1", "--densities", "0.5", "--json"])
        .current_dir(dir.path())
        .env("XDG_CACHE_HOME", &cache)
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let refs: Vec<_> = std::fs::read_dir(cache.join("edgepoint/references")).unwrap().collect();
    assert_eq!(refs.len(), 1, "the reference is cached under $XDG_CACHE_HOME");
    let left: Vec<String> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert_eq!(left, ["xdg-cache"], "nothing written into the working directory");
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(log.contains("INFO") && !log.contains('\x1b'), "a piped log has no colour codes: {log:?}");
}
