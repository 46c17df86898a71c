//! Helpers shared by the scene crate's integration tests.
use std::path::PathBuf;

/// A file of the shared data directory (`../shared/data` next to the repository), or
/// `None` (with a note) when it is not there.
pub fn data(rel: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data").join(rel);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipping: {} not found", p.display());
        None
    }
}
