//! Per-stage frame timing, the columns of paper 000 Table 2 (edge finding, edge
//! rasterization, point reprojection, reachability, interpolation, anti-aliasing, complex
//! filter, total). Stages keep the order in which they first ran in a frame, so a stats
//! line reads in pipeline order.
use std::time::Instant;

/// Milliseconds per named stage of one frame, in pipeline order.
#[derive(Debug, Clone)]
pub struct StageTimes {
    /// `(stage name, milliseconds)` in the order the stages first ran.
    pub stages: Vec<(&'static str, f64)>,
    /// The clock [`Self::time`] reads, in milliseconds (wall clock unless given).
    clock: Option<fn() -> f64>,
}

impl Default for StageTimes {
    fn default() -> Self {
        Self::new()
    }
}

impl StageTimes {
    pub fn new() -> Self {
        Self { stages: Vec::with_capacity(16), clock: None }
    }

    /// Times read from `clock` (milliseconds from any origin) instead of the wall clock, e.g.
    /// the thread's CPU time in a benchmark on a busy machine.
    pub fn with_clock(clock: fn() -> f64) -> Self {
        Self { stages: Vec::with_capacity(16), clock: Some(clock) }
    }

    /// Runs `f`, adds its time (wall clock, or the given clock) to `stage` and returns its
    /// result.
    pub fn time<R>(&mut self, stage: &'static str, f: impl FnOnce() -> R) -> R {
        if let Some(clock) = self.clock {
            let t0 = clock();
            let r = f();
            self.add(stage, clock() - t0);
            return r;
        }
        let t0 = Instant::now();
        let r = f();
        self.add(stage, t0.elapsed().as_secs_f64() * 1e3);
        r
    }

    /// Adds `ms` to `stage` (a stage that runs several times a frame accumulates).
    pub fn add(&mut self, stage: &'static str, ms: f64) {
        match self.stages.iter_mut().find(|(name, _)| *name == stage) {
            Some((_, t)) => *t += ms,
            None => self.stages.push((stage, ms)),
        }
    }

    /// Sum over all stages.
    pub fn total_ms(&self) -> f64 {
        self.stages.iter().map(|(_, t)| t).sum()
    }

    pub fn get(&self, stage: &str) -> Option<f64> {
        self.stages.iter().find(|(name, _)| *name == stage).map(|(_, t)| *t)
    }

    /// Forgets all stages (keeps the allocation for the next frame).
    pub fn clear(&mut self) {
        self.stages.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_accumulate_in_first_run_order() {
        let mut t = StageTimes::new();
        t.add("reproject", 1.5);
        t.add("interpolate", 2.0);
        t.add("reproject", 0.5);
        assert_eq!(t.stages, vec![("reproject", 2.0), ("interpolate", 2.0)]);
        assert_eq!(t.get("reproject"), Some(2.0));
        assert_eq!(t.get("sampling"), None);
        assert_eq!(t.total_ms(), 4.0);
        let v = t.time("sampling", || 7);
        assert_eq!(v, 7);
        assert!(t.get("sampling").unwrap() >= 0.0);
        assert_eq!(t.stages.last().unwrap().0, "sampling");
        t.clear();
        assert!(t.stages.is_empty());
        assert_eq!(t.total_ms(), 0.0);
    }
}
