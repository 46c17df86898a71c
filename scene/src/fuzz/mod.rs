//! A fuzzing harness for the scene parsers that runs on stable Rust: inputs are mutations
//! ([`mutate`]) of a checked-in seed corpus (`fuzz/seeds/<target>/`), each parsed by a
//! [`targets::Target`] on a watched thread. A case is a *finding* when the parse
//!
//! - panics,
//! - takes longer than [`TIME_LIMIT`] (the inputs are at most [`mutate::MAX_LEN`] bytes, so
//!   that is a runaway loop, not a big file), or
//! - allocates out of proportion to the input: more than [`ALLOC_PER_BYTE`] bytes per input
//!   byte plus [`ALLOC_SLACK`] at its peak, measured with the counting allocator
//!   ([`crate::alloc_count`]; the binary must install it, see [`Harness::new`]).
//!
//! Every finding is written to the crash corpus (`fuzz/crashes/<target>/<kind>-<hash>.<ext>`,
//! checked in), which the tests replay along with the seeds, so a fixed bug stays fixed.
//! An input whose parse aborts the process (a failed allocation of an impossible size)
//! cannot be caught in-process; the input being parsed is kept in
//! `fuzz/crashes/<target>/.inflight.<ext>` (git-ignored) while it runs, so it survives the
//! abort, and the next run files it under `abort-<hash>`.
//!
//! Entry points: `cargo test -p edgepoint-scene --test fuzz` (a fixed number of cases per
//! target) and `edgepoint-bench fuzz --parser NAME --seconds N --json` (as long as asked).
pub mod mutate;
pub mod targets;

use crate::alloc_count;
use mutate::Rng;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};
pub use targets::{target, Target, TARGETS};

/// Longest a parse of a fuzz input may take.
pub const TIME_LIMIT: Duration = Duration::from_secs(2);
/// Bytes a parse may hold at its peak per input byte: a binary PLY face of one-byte indices
/// becomes a triangle (12 bytes), its normal, three half-edges and an edge (about 150
/// bytes) — and buffers grow by doubling.
pub const ALLOC_PER_BYTE: usize = 512;
/// Bytes any parse may hold regardless of its input (staging, the floor, small tables).
pub const ALLOC_SLACK: usize = 1 << 20;

/// What went wrong with one input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    Panic,
    Slow,
    Alloc,
    /// A previous run aborted on this input.
    Abort,
}

impl Kind {
    pub fn name(self) -> &'static str {
        match self {
            Kind::Panic => "panic",
            Kind::Slow => "slow",
            Kind::Alloc => "alloc",
            Kind::Abort => "abort",
        }
    }
}

/// A finding: the kind, what was seen, and where the input was kept.
#[derive(Debug, Clone)]
pub struct Finding {
    pub kind: Kind,
    pub detail: String,
    pub input_len: usize,
    /// The crash-corpus file holding the input (`None` when it could not be written).
    pub file: Option<PathBuf>,
}

/// Totals of a run over one target.
#[derive(Debug, Clone, Default)]
pub struct Report {
    pub target: String,
    /// Corpus inputs replayed (seeds and earlier crashes).
    pub replayed: usize,
    /// Mutated cases run.
    pub cases: u64,
    /// Cases the parser refused with an error (the expected outcome for most mutations).
    pub refused: u64,
    /// Cases it accepted.
    pub accepted: u64,
    pub seconds: f64,
    pub slowest_ms: f64,
    /// Largest peak allocation per input byte seen (beyond the slack).
    pub max_alloc_per_byte: f64,
    pub max_peak_bytes: usize,
    pub findings: Vec<Finding>,
}

/// The outcome of one parse on the watched thread.
enum Outcome {
    Done { result: Result<(), String>, peak: usize, ms: f64 },
    Panicked(String),
}

/// Runs one target's cases on a watched thread.
pub struct Harness {
    target: &'static Target,
    crash_dir: PathBuf,
    seeds: Vec<Vec<u8>>,
    crashes: Vec<(PathBuf, Vec<u8>)>,
    tx: Option<mpsc::Sender<Vec<u8>>>,
    rx: mpsc::Receiver<Outcome>,
    /// Set once a case overran the time limit: its thread is lost, no more cases run.
    stuck: bool,
    pub report: Report,
}

/// A case is running (on any thread: a parse may panic on a rayon worker).
static IN_CASE: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
static LAST_PANIC: std::sync::Mutex<Option<String>> = std::sync::Mutex::new(None);

/// Keeps panic messages of fuzz cases off stderr (they are reported as findings) and
/// passes every other panic to the hook that was installed before.
fn install_panic_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if IN_CASE.load(std::sync::atomic::Ordering::SeqCst) {
                let loc = info.location().map(|l| format!(" at {}:{}", l.file(), l.line())).unwrap_or_default();
                let msg = info
                    .payload()
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| info.payload().downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "non-string panic".into());
                *LAST_PANIC.lock().unwrap_or_else(|p| p.into_inner()) = Some(format!("{msg}{loc}"));
            } else {
                previous(info);
            }
        }));
    });
}

/// A short content hash for crash file names.
fn hash(data: &[u8]) -> u64 {
    data.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3))
}

fn read_dir_files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out: Vec<(PathBuf, Vec<u8>)> = match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .filter_map(|e| e.ok())
            .map(|e| e.path())
            .filter(|p| p.is_file() && p.file_name().is_some_and(|n| !n.to_string_lossy().starts_with('.')))
            .filter_map(|p| std::fs::read(&p).ok().map(|d| (p, d)))
            .collect(),
        Err(_) => Vec::new(),
    };
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

/// The corpus directory (holding `seeds/` and `crashes/`): `explicit` if given, else a
/// `scene/fuzz` directory in or above the working directory or the executable.
pub fn find_corpus(explicit: Option<&Path>) -> Result<PathBuf, String> {
    if let Some(d) = explicit {
        return if d.join("seeds").is_dir() {
            Ok(d.to_path_buf())
        } else {
            Err(format!("{} has no seeds/ directory", d.display()))
        };
    }
    let mut starts = Vec::new();
    starts.extend(std::env::current_dir().ok());
    starts.extend(std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf)));
    for s in &starts {
        for a in s.ancestors() {
            for c in [a.join("scene/fuzz"), a.join("fuzz")] {
                if c.join("seeds").is_dir() {
                    return Ok(c);
                }
            }
        }
    }
    Err("cannot find the fuzz corpus (a scene/fuzz directory with seeds/) above the working directory or the \
         executable; give it with --corpus DIR"
        .into())
}

impl Harness {
    /// A harness for `target` over the corpus in `corpus` (`seeds/<target>/`,
    /// `crashes/<target>/`). Fails when the binary did not install the counting allocator
    /// (allocations could not be judged) or the target has no seeds.
    pub fn new(target: &'static Target, corpus: &Path) -> Result<Harness, String> {
        if !alloc_count::installed() {
            return Err("the fuzz harness needs the counting allocator: \
                 #[global_allocator] static A: edgepoint_scene::alloc_count::CountingAlloc = CountingAlloc;"
                .into());
        }
        install_panic_hook();
        let seed_dir = corpus.join("seeds").join(target.name);
        let seeds: Vec<Vec<u8>> = read_dir_files(&seed_dir).into_iter().map(|(_, d)| d).collect();
        if seeds.is_empty() {
            return Err(format!("no seeds for target {} in {}", target.name, seed_dir.display()));
        }
        let crash_dir = corpus.join("crashes").join(target.name);
        let (tx, rx) = spawn_runner(target);
        let mut h = Harness {
            target,
            crash_dir,
            seeds,
            crashes: Vec::new(),
            tx: Some(tx),
            rx,
            stuck: false,
            report: Report { target: target.name.to_string(), ..Default::default() },
        };
        // An input that aborted an earlier run: file it as a crash.
        let inflight = h.inflight_path();
        if let Ok(data) = std::fs::read(&inflight) {
            let _ = std::fs::remove_file(&inflight);
            let file = h.save(Kind::Abort, &data);
            h.report.findings.push(Finding {
                kind: Kind::Abort,
                detail: "an earlier run aborted while parsing this input".into(),
                input_len: data.len(),
                file,
            });
        }
        h.crashes = read_dir_files(&h.crash_dir).into_iter().filter(|(p, _)| p != &inflight).collect();
        Ok(h)
    }

    fn inflight_path(&self) -> PathBuf {
        self.crash_dir.join(format!(".inflight.{}", self.target.ext))
    }

    /// Writes a finding's input into the crash corpus.
    fn save(&self, kind: Kind, data: &[u8]) -> Option<PathBuf> {
        let p = self.crash_dir.join(format!("{}-{:016x}.{}", kind.name(), hash(data), self.target.ext));
        std::fs::create_dir_all(&self.crash_dir).ok()?;
        std::fs::write(&p, data).ok()?;
        Some(p)
    }

    /// Runs one input; records a finding if it is one. Returns `false` once the harness can
    /// run no more (a case overran the time limit and its thread is lost).
    pub fn run_one(&mut self, input: &[u8], keep: bool) -> bool {
        if self.stuck {
            return false;
        }
        let inflight = self.inflight_path();
        let wrote_inflight = keep && std::fs::create_dir_all(&self.crash_dir).is_ok() && std::fs::write(&inflight, input).is_ok();
        let Some(tx) = &self.tx else { return false };
        if tx.send(input.to_vec()).is_err() {
            return false;
        }
        let finding = match self.rx.recv_timeout(TIME_LIMIT) {
            Ok(Outcome::Done { result, peak, ms }) => {
                self.report.slowest_ms = self.report.slowest_ms.max(ms);
                self.report.max_peak_bytes = self.report.max_peak_bytes.max(peak);
                let per_byte = peak.saturating_sub(ALLOC_SLACK) as f64 / input.len().max(1) as f64;
                self.report.max_alloc_per_byte = self.report.max_alloc_per_byte.max(per_byte);
                match result {
                    Ok(()) => self.report.accepted += 1,
                    Err(_) => self.report.refused += 1,
                }
                let budget = ALLOC_SLACK + ALLOC_PER_BYTE * input.len();
                (peak > budget).then(|| {
                    (Kind::Alloc, format!("peak allocation {peak} bytes for a {}-byte input (budget {budget})", input.len()))
                })
            }
            Ok(Outcome::Panicked(msg)) => Some((Kind::Panic, msg)),
            Err(_) => {
                // The thread is still parsing: lose it (it ends with the process).
                self.stuck = true;
                self.tx = None;
                Some((Kind::Slow, format!("no result within {:?}", TIME_LIMIT)))
            }
        };
        if wrote_inflight {
            let _ = std::fs::remove_file(&inflight);
        }
        if let Some((kind, detail)) = finding {
            let file = if keep { self.save(kind, input) } else { None };
            self.report.findings.push(Finding { kind, detail, input_len: input.len(), file });
        }
        !self.stuck
    }

    /// Replays every seed and every crash-corpus input (none of them may be a finding).
    pub fn replay(&mut self) {
        let inputs: Vec<Vec<u8>> = self.seeds.iter().cloned().chain(self.crashes.iter().map(|(_, d)| d.clone())).collect();
        for input in inputs {
            self.report.replayed += 1;
            if !self.run_one(&input, false) {
                break;
            }
        }
    }

    /// Runs mutated cases until `cases` have run or `until` has passed, whichever first.
    /// Cases are drawn from `seed` alone, so a run can be repeated.
    pub fn fuzz(&mut self, seed: u64, cases: u64, until: Option<Instant>) {
        let t0 = Instant::now();
        let mut rng = Rng::new(seed);
        let pool: Vec<Vec<u8>> = self.seeds.iter().cloned().chain(self.crashes.iter().map(|(_, d)| d.clone())).collect();
        while self.report.cases < cases && until.is_none_or(|u| Instant::now() < u) {
            let base = rng.pick(&pool).clone();
            let other = rng.pick(&pool).clone();
            let input = mutate::mutate(&mut rng, &base, &other);
            self.report.cases += 1;
            if !self.run_one(&input, true) {
                break;
            }
        }
        self.report.seconds += t0.elapsed().as_secs_f64();
    }
}

impl Drop for Harness {
    fn drop(&mut self) {
        self.tx = None;
    }
}

/// The watched thread: parses the inputs it is sent, measuring time and allocation.
fn spawn_runner(target: &'static Target) -> (mpsc::Sender<Vec<u8>>, mpsc::Receiver<Outcome>) {
    let (tx, rx) = mpsc::channel::<Vec<u8>>();
    let (otx, orx) = mpsc::channel();
    std::thread::Builder::new()
        .name(format!("fuzz-{}", target.name))
        .spawn(move || {
            while let Ok(input) = rx.recv() {
                let t = Instant::now();
                IN_CASE.store(true, std::sync::atomic::Ordering::SeqCst);
                let (r, usage) = alloc_count::measure(|| std::panic::catch_unwind(|| (target.run)(&input)));
                IN_CASE.store(false, std::sync::atomic::Ordering::SeqCst);
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let out = match r {
                    Ok(result) => Outcome::Done { result, peak: usage.peak, ms },
                    Err(_) => Outcome::Panicked(
                        LAST_PANIC.lock().unwrap_or_else(|p| p.into_inner()).take().unwrap_or_else(|| "panic".into()),
                    ),
                };
                if otx.send(out).is_err() {
                    break;
                }
            }
        })
        .expect("spawning the fuzz thread");
    (tx, orx)
}
