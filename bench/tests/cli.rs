//! The benchmark program's command line: every subcommand explains itself, and a bad motion
//! path is refused with the valid choices. (Its integration tests also make `cargo test`
//! build the binary, which the motion tests of `tests/` run.)
use std::process::Command;

fn bench(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_edgepoint-bench")).args(args).env("RUST_LOG", "warn").output().expect("edgepoint-bench runs")
}

#[test]
fn every_subcommand_has_help() {
    for sub in ["frame", "throughput", "loadtest", "load", "edges", "reference", "epi", "quality", "motion"] {
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
