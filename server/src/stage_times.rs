//! Per-stage frame timing, the columns of paper 000 Table 2 (edge finding, edge
//! rasterization, point reprojection, reachability, interpolation, anti-aliasing, complex
//! filter, total). Stages keep the order in which they first ran in a frame, so a stats
//! line reads in pipeline order.
use std::time::Instant;

/// Milliseconds per named stage of one frame, in pipeline order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StageTimes {
    /// `(stage name, milliseconds)` in the order the stages first ran.
    pub stages: Vec<(&'static str, f64)>,
}

impl StageTimes {
    pub fn new() -> Self {
        Self { stages: Vec::with_capacity(16) }
    }

    /// Runs `f`, adds its wall-clock time to `stage` and returns its result.
    pub fn time<R>(&mut self, stage: &'static str, f: impl FnOnce() -> R) -> R {
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
