//! Progress reporting for long work (parsing, welding, BVH and edge-tree builds).
//! The library reports; binaries draw (indicatif bars) or log.

/// Receives progress of a long operation. `begin` starts a stage of `total` units.
pub trait Progress: Sync {
    fn begin(&self, stage: &str, total: u64);
    fn advance(&self, units: u64);
    fn end(&self);
}

/// Discards progress.
pub struct NoProgress;

impl Progress for NoProgress {
    fn begin(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
    fn end(&self) {}
}
