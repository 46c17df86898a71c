//! `edgepoint-bench fuzz`: the scene-parser fuzz harness ([`edgepoint_scene::fuzz`]) for as
//! long as asked. The test suite runs a fixed number of cases per parser; this runs until
//! `--seconds` or `--cases`, with a seed from the clock unless given, and writes every
//! finding into the crash corpus (`scene/fuzz/crashes/<parser>/`) for the tests to replay.
use anyhow::{bail, Result};
use edgepoint_scene::fuzz::{find_corpus, target, Harness, TARGETS};
use serde_json::json;
use std::path::PathBuf;
use std::time::{Duration, Instant};

fn parser_help() -> String {
    let names: Vec<String> = TARGETS.iter().map(|t| format!("{} ({})", t.name, t.about)).collect();
    format!("Parser to fuzz, or `all` (each gets --seconds): {}", names.join("; "))
}

#[derive(clap::Args, Debug)]
pub struct FuzzArgs {
    #[arg(long, value_name = "NAME", default_value = "all", help = parser_help())]
    pub parser: String,
    /// Seconds to fuzz each parser.
    #[arg(long, value_name = "S", default_value_t = 60.0)]
    pub seconds: f64,
    /// Stop each parser after this many cases (whichever of --seconds and --cases comes first).
    #[arg(long, value_name = "N")]
    pub cases: Option<u64>,
    /// Seed of the mutations (default: from the clock; the report says which was used).
    #[arg(long, value_name = "N")]
    pub seed: Option<u64>,
    /// The corpus directory (holding seeds/ and crashes/); default: scene/fuzz found in or
    /// above the working directory or this executable.
    #[arg(long, value_name = "DIR")]
    pub corpus: Option<PathBuf>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: FuzzArgs) -> Result<()> {
    if !(a.seconds.is_finite() && a.seconds > 0.0) {
        bail!("--seconds must be a positive number, got {}", a.seconds);
    }
    let targets: Vec<_> = if a.parser == "all" {
        TARGETS.iter().collect()
    } else {
        match target(&a.parser) {
            Some(t) => vec![t],
            None => bail!("unknown parser '{}' (parsers: all, {})", a.parser, TARGETS.iter().map(|t| t.name).collect::<Vec<_>>().join(", ")),
        }
    };
    let corpus = find_corpus(a.corpus.as_deref()).map_err(anyhow::Error::msg)?;
    let seed = a.seed.unwrap_or_else(|| {
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(1)
    });
    let mut reports = Vec::new();
    let mut table = String::new();
    let mut findings = 0;
    for t in targets {
        let mut h = Harness::new(t, &corpus).map_err(anyhow::Error::msg)?;
        eprintln!("fuzzing {} for {} s (seed {seed})", t.name, a.seconds);
        h.replay();
        let until = Instant::now() + Duration::from_secs_f64(a.seconds);
        h.fuzz(seed, a.cases.unwrap_or(u64::MAX), Some(until));
        let r = &h.report;
        findings += r.findings.len();
        table.push_str(&format!(
            "{:<12} {:>9} cases in {:>6.1} s ({:>8.0}/s), {} refused, {} accepted; slowest {:.1} ms; peak {} bytes; {} findings\n",
            r.target,
            r.cases,
            r.seconds,
            r.cases as f64 / r.seconds.max(1e-9),
            r.refused,
            r.accepted,
            r.slowest_ms,
            r.max_peak_bytes,
            r.findings.len()
        ));
        for f in &r.findings {
            table.push_str(&format!("  {:?}: {} ({} bytes) -> {:?}\n", f.kind, f.detail, f.input_len, f.file));
        }
        reports.push(json!({
            "parser": r.target,
            "seed": seed,
            "corpus_inputs_replayed": r.replayed,
            "cases": r.cases,
            "seconds": r.seconds,
            "cases_per_second": r.cases as f64 / r.seconds.max(1e-9),
            "refused": r.refused,
            "accepted": r.accepted,
            "slowest_ms": r.slowest_ms,
            "max_peak_bytes": r.max_peak_bytes,
            "max_alloc_per_input_byte": r.max_alloc_per_byte,
            "findings": r.findings.iter().map(|f| json!({
                "kind": f.kind.name(),
                "detail": f.detail,
                "input_bytes": f.input_len,
                "file": f.file.as_ref().map(|p| p.display().to_string()),
            })).collect::<Vec<_>>(),
        }));
    }
    crate::emit(a.json, &json!({ "corpus": corpus.display().to_string(), "parsers": reports }), &table);
    if findings > 0 {
        bail!("{findings} finding(s); their inputs are in the crash corpus");
    }
    Ok(())
}
