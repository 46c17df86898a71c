//! Measured throughput and the per-worker in-flight limit (DESIGN.md "Budget": work is
//! shared among workers in proportion to their measured rate).
//!
//! Every link pulls from one shared queue, so a fast worker already takes more batches than
//! a slow one; what is left to choose is how many batches each worker holds at once. Too
//! few and a fast worker idles for a network round trip between batches; too many and a slow
//! worker hoards batches another worker could shade sooner. [`InFlightLimit`] covers the
//! round trip (measured on batches that were alone in flight, so the worker's own queueing
//! does not inflate it) plus two batches of shading work.
//!
//! [`BatchSizer`] sets how many requests one batch to a worker holds: enough work for
//! about a target time at that worker's measured rate. A slow worker (an expensive shader,
//! a small machine) gets small batches, so no request waits long behind it; a fast one gets
//! whole batches as the session built them.
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Samples per second over a sliding window.
#[derive(Debug)]
pub struct RateMeter {
    window: Duration,
    events: VecDeque<(Instant, u64)>,
    total: u64,
}

impl RateMeter {
    pub fn new(window: Duration) -> Self {
        RateMeter { window, events: VecDeque::with_capacity(256), total: 0 }
    }

    pub fn record(&mut self, now: Instant, samples: u64) {
        self.total += samples;
        self.events.push_back((now, samples));
        self.expire(now);
    }

    fn expire(&mut self, now: Instant) {
        while let Some(&(t, _)) = self.events.front() {
            if now.duration_since(t) > self.window || self.events.len() > 4096 {
                self.events.pop_front();
            } else {
                break;
            }
        }
    }

    /// Recent rate: samples in the window divided by the window length (0 when idle).
    pub fn per_second(&mut self, now: Instant) -> f64 {
        self.expire(now);
        let n: u64 = self.events.iter().map(|e| e.1).sum();
        n as f64 / self.window.as_secs_f64()
    }

    pub fn total(&self) -> u64 {
        self.total
    }
}

/// How many batches one worker may hold at once.
#[derive(Debug, Clone)]
pub struct InFlightLimit {
    limit: usize,
    min: usize,
    max: usize,
    /// Round trip minus shading time, from batches sent with nothing else in flight.
    overhead_ms: Option<f64>,
    /// Mean shading time per batch reported by the worker.
    shade_ms: Option<f64>,
}

impl InFlightLimit {
    pub fn new(initial: usize, min: usize, max: usize) -> Self {
        let min = min.max(1);
        let max = max.max(min);
        InFlightLimit { limit: initial.clamp(min, max), min, max, overhead_ms: None, shade_ms: None }
    }

    pub fn get(&self) -> usize {
        self.limit
    }

    /// Records one answered batch: its round trip, the worker's shading time, and whether it
    /// was the only batch in flight when sent.
    pub fn observe(&mut self, rtt: Duration, shade_ms: f64, was_alone: bool) {
        let rtt_ms = rtt.as_secs_f64() * 1e3;
        let shade_ms = if shade_ms.is_finite() && shade_ms > 0.0 { shade_ms.min(rtt_ms) } else { 0.0 };
        self.shade_ms = Some(match self.shade_ms {
            Some(s) => 0.9 * s + 0.1 * shade_ms,
            None => shade_ms,
        });
        if was_alone {
            let o = (rtt_ms - shade_ms).max(0.0);
            self.overhead_ms = Some(match self.overhead_ms {
                Some(p) => 0.7 * p + 0.3 * o,
                None => o,
            });
        }
        if let (Some(o), Some(s)) = (self.overhead_ms, self.shade_ms) {
            let cover = if s > 1e-3 { (o / s).ceil() } else { self.max as f64 };
            self.limit = (2.0 + cover).clamp(self.min as f64, self.max as f64) as usize;
        }
    }
}

/// Requests per batch for one worker, from its measured throughput.
///
/// The rate is samples per *busy* second (time with at least one batch in flight), so a
/// worker that idles for lack of work is not mistaken for a slow one. Samples and busy time
/// are decayed separately and divided, which weights each answer by the time it covered.
#[derive(Debug, Clone)]
pub struct BatchSizer {
    target: Duration,
    min: usize,
    max: usize,
    samples: f64,
    busy_s: f64,
}

/// Decay per observation of [`BatchSizer`]'s sums (about the last 20 answers count).
const SIZER_DECAY: f64 = 0.95;

impl BatchSizer {
    /// Batches of about `target` of work, between `min` and `max` requests.
    pub fn new(target: Duration, min: usize, max: usize) -> Self {
        let min = min.max(1);
        BatchSizer { target, min, max: max.max(min), samples: 0.0, busy_s: 0.0 }
    }

    /// `samples` were answered after `busy` of busy time since the previous answer.
    pub fn observe(&mut self, samples: u64, busy: Duration) {
        self.samples = SIZER_DECAY * self.samples + samples as f64;
        self.busy_s = SIZER_DECAY * self.busy_s + busy.as_secs_f64();
    }

    /// Measured samples per busy second, once something was measured.
    pub fn rate(&self) -> Option<f64> {
        (self.busy_s > 1e-6 && self.samples > 0.0).then(|| self.samples / self.busy_s)
    }

    /// Largest batch to send this worker; `max` until its rate is known.
    pub fn size(&self) -> usize {
        match self.rate() {
            Some(r) => ((r * self.target.as_secs_f64()).round() as usize).clamp(self.min, self.max),
            None => self.max,
        }
    }

    /// The batch the link sends this worker next: [`Self::size`] once its rate is known,
    /// `min` before. A worker answers a batch whole, and a cold worker's first batches are
    /// its slowest (a `gi` worker makes an irradiance record for nearly every request of a
    /// batch spread over the image): with whole batches a session's first image waited for
    /// them — on `cornell` with `gi`, nothing at 0.25 s; with small first batches, 21–31 dB.
    pub fn next_size(&self) -> usize {
        if self.rate().is_some() {
            self.size()
        } else {
            self.min
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rate_counts_only_the_window() {
        let t0 = Instant::now();
        let mut r = RateMeter::new(Duration::from_secs(1));
        r.record(t0, 500);
        r.record(t0 + Duration::from_millis(500), 500);
        assert!((r.per_second(t0 + Duration::from_millis(600)) - 1000.0).abs() < 1e-9);
        assert!((r.per_second(t0 + Duration::from_millis(1200)) - 500.0).abs() < 1e-9);
        assert_eq!(r.per_second(t0 + Duration::from_secs(3)), 0.0);
        assert_eq!(r.total(), 1000);
    }

    #[test]
    fn limit_covers_latency_with_work() {
        let mut l = InFlightLimit::new(4, 2, 16);
        assert_eq!(l.get(), 4);
        // 10 ms of network per batch, 2 ms of shading: five batches cover the trip.
        l.observe(Duration::from_millis(12), 2.0, true);
        assert_eq!(l.get(), 2 + 5);
        // Queueing at the worker (not alone) must not inflate the overhead estimate.
        for _ in 0..50 {
            l.observe(Duration::from_millis(40), 2.0, false);
        }
        assert_eq!(l.get(), 7);
        // A slow worker (shading dominates) holds few batches.
        let mut slow = InFlightLimit::new(4, 2, 16);
        slow.observe(Duration::from_millis(101), 100.0, true);
        assert_eq!(slow.get(), 3);
        let mut lan = InFlightLimit::new(4, 2, 16);
        lan.observe(Duration::from_millis(500), 0.0, true);
        assert_eq!(lan.get(), 16, "clamped to the maximum");
    }

    #[test]
    fn batch_size_follows_the_busy_rate() {
        let mut s = BatchSizer::new(Duration::from_millis(20), 16, 4096);
        assert_eq!(s.size(), 4096, "unmeasured: no splitting");
        assert_eq!(s.next_size(), 16, "unmeasured: the link sends the smallest batches");
        // 1000 samples per busy second: 20 ms of work is 20 requests.
        for _ in 0..50 {
            s.observe(100, Duration::from_millis(100));
        }
        assert!((s.rate().unwrap() - 1000.0).abs() < 1e-6);
        assert_eq!(s.size(), 20);
        assert_eq!(s.next_size(), 20, "measured: the link follows the rate");
        // The worker gets 100x faster: the size follows within a few dozen answers.
        for _ in 0..200 {
            s.observe(1000, Duration::from_millis(10));
        }
        assert!((1990..=2000).contains(&s.size()), "{}", s.size());
        // Clamped at both ends.
        let mut slow = BatchSizer::new(Duration::from_millis(20), 16, 4096);
        slow.observe(1, Duration::from_secs(10));
        assert_eq!(slow.size(), 16);
        let mut fast = BatchSizer::new(Duration::from_millis(20), 16, 256);
        fast.observe(1_000_000, Duration::from_millis(1));
        assert_eq!(fast.size(), 256);
    }
}
