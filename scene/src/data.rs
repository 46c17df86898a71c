//! Finding the shared data directory (the Stanford models and friends) on the machine that
//! starts a session. Built-ins made from data (`grid-dragon`) are expanded there into a
//! description plus the data files' bytes (see [`crate::builtin`]), so the server and the
//! shader workers never need the directory themselves.
//!
//! Search order: an explicit directory (a `--data-dir` flag), then the [`DATA_ENV`]
//! environment variable, then `shared/data` and `data` in the working directory, the
//! executable's directory and every directory above them.
use crate::builtin;
use crate::load::NamedBytes;
use crate::{Progress, Scene};
use std::path::{Path, PathBuf};

/// Environment variable naming the data directory.
pub const DATA_ENV: &str = "EDGEPOINT_DATA";

/// The directories searched, in order (see the module docs).
pub fn candidates(explicit: Option<&Path>) -> Vec<PathBuf> {
    if let Some(d) = explicit {
        return vec![d.to_path_buf()];
    }
    let mut out = Vec::new();
    if let Some(d) = std::env::var_os(DATA_ENV) {
        out.push(PathBuf::from(d));
    }
    let mut starts = Vec::new();
    if let Ok(d) = std::env::current_dir() {
        starts.push(d);
    }
    if let Some(d) = std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf)) {
        starts.push(d);
    }
    for s in starts {
        for a in s.ancestors() {
            for sub in ["shared/data", "data"] {
                let c = a.join(sub);
                if !out.contains(&c) {
                    out.push(c);
                }
            }
        }
    }
    out
}

/// The path of data file `rel` (e.g. `dragon/dragon_vrip.ply`) in the first candidate
/// directory that has it. The error lists where it looked and how to point at the data.
pub fn find_file(rel: &str, explicit: Option<&Path>) -> Result<PathBuf, String> {
    let cands = candidates(explicit);
    for c in &cands {
        let p = c.join(rel);
        if p.is_file() {
            return Ok(p);
        }
    }
    let looked: Vec<String> = cands.iter().take(12).map(|c| c.display().to_string()).collect();
    Err(format!(
        "data file {rel} not found; looked in: {}{}. Point at the shared data directory with --data-dir DIR or \
         the {DATA_ENV} environment variable",
        looked.join(", "),
        if cands.len() > looked.len() { ", ..." } else { "" }
    ))
}

/// The files that make built-in `name` on the wire: `None` for a procedural built-in (send
/// its name); otherwise its description followed by its data files, read from the data
/// directory.
pub fn builtin_files(name: &str, explicit: Option<&Path>) -> Result<Option<Vec<NamedBytes>>, String> {
    let need = builtin::data_files(name);
    if need.is_empty() {
        return Ok(None);
    }
    let mut files = vec![builtin::description(name)];
    for rel in need {
        let path = find_file(rel, explicit).map_err(|e| format!("built-in scene '{name}': {e}"))?;
        let data = std::fs::read(&path).map_err(|e| format!("built-in scene '{name}': cannot read {}: {e}", path.display()))?;
        files.push(NamedBytes { name: rel.to_string(), data });
    }
    Ok(Some(files))
}

/// Builds any built-in locally, reading its data files from the data directory if it has
/// any (benchmarks and tests).
pub fn load_builtin(name: &str, explicit: Option<&Path>, progress: &dyn Progress) -> Result<Scene, String> {
    match builtin_files(name, explicit)? {
        None => builtin::load(name),
        Some(files) => crate::load::load_files(&files, progress).map_err(|e| e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_explicit_directory_is_the_only_candidate_and_misses_are_explained() {
        let dir = std::env::temp_dir().join("edgepoint-no-data-here");
        let e = find_file("dragon/dragon_vrip.ply", Some(&dir)).unwrap_err();
        assert!(e.contains("edgepoint-no-data-here") && e.contains("--data-dir") && e.contains(DATA_ENV), "{e}");
        let e = builtin_files("grid-dragon", Some(&dir)).unwrap_err();
        assert!(e.contains("grid-dragon") && e.contains("dragon_vrip.ply"), "{e}");
        assert!(builtin_files("cornell", Some(&dir)).unwrap().is_none());
    }

    #[test]
    fn candidates_include_shared_data_above_the_working_directory() {
        let c = candidates(None);
        let cwd = std::env::current_dir().unwrap();
        assert!(c.contains(&cwd.join("shared/data")));
        assert!(cwd.parent().is_none_or(|p| c.contains(&p.join("shared/data"))));
    }
}
