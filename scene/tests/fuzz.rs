//! The fuzz harness inside the test suite (issue 12): for every parser target, replay the
//! seed and crash corpora, then run a fixed number of mutated cases. Any panic, parse over
//! the time limit or allocation out of proportion to the input fails the test, and its
//! input is written to `fuzz/crashes/<target>/` to be fixed and kept. Longer runs:
//! `edgepoint-bench fuzz --parser NAME --seconds N`.
use edgepoint_scene::alloc_count::CountingAlloc;
use edgepoint_scene::fuzz::{target, Harness, TARGETS};
use std::path::PathBuf;
use std::sync::Mutex;

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

/// Mutated cases per target: about 3 s in release on the development machine (~10,000/s).
const CASES: u64 = 30_000;
/// Fixed, so a run is repeatable; the bench program varies it.
const SEED: u64 = 0x5eed_f022;

/// The targets run one at a time: the allocation counters are global.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn corpus() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fuzz")
}

fn fuzz(name: &str) {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let t = target(name).unwrap_or_else(|| panic!("no fuzz target {name}"));
    let mut h = Harness::new(t, &corpus()).unwrap();
    h.replay();
    let replay_findings = h.report.findings.len();
    h.fuzz(SEED ^ name.len() as u64, CASES, None);
    let r = &h.report;
    eprintln!(
        "fuzz {name}: {} corpus inputs, {} cases ({} refused, {} accepted) in {:.1} s; slowest {:.1} ms; peak {} bytes, at most {:.1} bytes per input byte",
        r.replayed, r.cases, r.refused, r.accepted, r.seconds, r.slowest_ms, r.max_peak_bytes, r.max_alloc_per_byte
    );
    assert!(r.replayed >= 2, "the corpus was read");
    assert_eq!(r.cases, CASES, "every case ran");
    assert!(r.refused > 0 && r.accepted > 0, "mutations both break and keep inputs: {r:?}");
    let shown: Vec<String> = r
        .findings
        .iter()
        .map(|f| format!("{:?}: {} ({} bytes, kept in {:?})", f.kind, f.detail, f.input_len, f.file))
        .collect();
    assert!(r.findings.is_empty(), "{name}: {} findings ({replay_findings} on replay):\n{}", r.findings.len(), shown.join("\n"));
}

#[test]
fn fuzz_ply() {
    fuzz("ply");
}

#[test]
fn fuzz_obj() {
    fuzz("obj");
}

#[test]
fn fuzz_mtl() {
    fuzz("mtl");
}

#[test]
fn fuzz_grid_dragon() {
    fuzz("grid-dragon");
}

#[test]
fn fuzz_mitsuba() {
    fuzz("mitsuba");
}

#[test]
fn fuzz_gltf() {
    fuzz("gltf");
}

#[test]
fn fuzz_glb() {
    fuzz("glb");
}

#[test]
fn fuzz_gz() {
    fuzz("gz");
}

#[test]
fn every_target_has_a_test_and_seeds() {
    let tested = ["ply", "obj", "mtl", "grid-dragon", "mitsuba", "gltf", "glb", "gz"];
    for t in TARGETS {
        assert!(tested.contains(&t.name), "target {} has no test in tests/fuzz.rs", t.name);
        assert!(corpus().join("seeds").join(t.name).is_dir(), "target {} has no seeds", t.name);
    }
}

/// The harness itself finds what it must: a parser that panics, one that loops and one that
/// allocates from a number in its input are each reported and their input kept.
#[test]
fn the_harness_catches_panics_runaway_loops_and_allocations() {
    use edgepoint_scene::fuzz::{Kind, Target};
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    fn panics(b: &[u8]) -> Result<(), String> {
        if b.first() == Some(&b'!') {
            panic!("boom");
        }
        Err("refused".into())
    }
    // Loops until the test has seen the finding (then ends, so it does not burn a core
    // for the rest of the test run).
    static RELEASE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    fn loops(b: &[u8]) -> Result<(), String> {
        if b.first() == Some(&b'~') {
            while !RELEASE.load(std::sync::atomic::Ordering::SeqCst) {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
        }
        Ok(())
    }
    fn allocates(b: &[u8]) -> Result<(), String> {
        let n: usize = std::str::from_utf8(b).ok().and_then(|s| s.trim().parse().ok()).unwrap_or(0);
        let v = vec![1u8; n.min(64 << 20)];
        std::hint::black_box(&v);
        Ok(())
    }
    let dir = std::env::temp_dir().join(format!("edgepoint-fuzz-selftest-{}", std::process::id()));
    for (name, seed, bad) in [("panics", b"ok".to_vec(), b"!x".to_vec()), ("loops", b"ok".to_vec(), b"~".to_vec()), ("allocates", b"12".to_vec(), b"50000000".to_vec())] {
        let run = match name {
            "panics" => panics as fn(&[u8]) -> Result<(), String>,
            "loops" => loops,
            _ => allocates,
        };
        let t: &'static Target = Box::leak(Box::new(Target { name: Box::leak(name.to_string().into_boxed_str()), ext: "bin", about: "self-test", run }));
        std::fs::create_dir_all(dir.join("seeds").join(name)).unwrap();
        std::fs::write(dir.join("seeds").join(name).join("seed.bin"), &seed).unwrap();
        let mut h = Harness::new(t, &dir).unwrap();
        h.replay();
        assert!(h.report.findings.is_empty(), "{name}: the seed is fine");
        h.run_one(&bad, true);
        let f = h.report.findings.last().unwrap_or_else(|| panic!("{name}: no finding"));
        let want = match name {
            "panics" => Kind::Panic,
            "loops" => Kind::Slow,
            _ => Kind::Alloc,
        };
        assert_eq!(f.kind, want, "{name}: {f:?}");
        if name == "panics" {
            assert!(f.detail.contains("boom"), "{f:?}");
        }
        let kept = f.file.as_ref().expect("the input is kept");
        assert_eq!(std::fs::read(kept).unwrap(), bad);
        assert!(kept.starts_with(dir.join("crashes").join(name)));
        if name == "loops" {
            assert!(!h.run_one(b"ok", false), "a harness whose thread is stuck runs nothing more");
            RELEASE.store(true, std::sync::atomic::Ordering::SeqCst);
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
