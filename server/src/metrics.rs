//! Prometheus metrics of the renderer, served by `--metrics-listen` (DESIGN.md "deploy":
//! what an operator scaling workers out needs to see).
//!
//! Two groups: [`PoolMetrics`] — the worker pool (workers known and live, per worker the
//! open streams, in-flight batches and requests, batch size and in-flight limit, samples;
//! pool-wide samples/s, batch latency, re-issued and dropped batches, dispatch queue depth,
//! outstanding requests) — and [`SessionMetrics`] — the viewer sessions (running, started,
//! refused by reason, frames sent and dropped, frame-loop time and the interval between
//! frames). Every collector lives in the [`ServerMetrics`] registry, never in a global one,
//! so several servers in one test process keep separate counts.
use prometheus::{
    exponential_buckets, Gauge, Histogram, HistogramOpts, IntCounter, IntCounterVec, IntGauge, IntGaugeVec, Opts, Registry,
};
use std::sync::Arc;

/// Label naming one worker (its URL).
pub const WORKER_LABEL: &str = "worker";

fn gauge(name: &str, help: &str) -> IntGauge {
    IntGauge::new(name, help).expect("static metric name")
}

fn gauge_vec(name: &str, help: &str) -> IntGaugeVec {
    IntGaugeVec::new(Opts::new(name, help), &[WORKER_LABEL]).expect("static metric name")
}

fn counter(name: &str, help: &str) -> IntCounter {
    IntCounter::new(name, help).expect("static metric name")
}

fn histogram(name: &str, help: &str) -> Histogram {
    // 1 ms .. ~33 s in factors of two: frame times, batch latencies and stalls all fit.
    let buckets = exponential_buckets(0.001, 2.0, 16).expect("valid buckets");
    Histogram::with_opts(HistogramOpts::new(name, help).buckets(buckets)).expect("static metric name")
}

/// Registers every collector in `list` with `registry`.
fn register(registry: Option<&Registry>, list: Vec<Box<dyn prometheus::core::Collector>>) {
    if let Some(r) = registry {
        for c in list {
            r.register(c).expect("metric names are unique");
        }
    }
}

/// The worker pool's metrics. Per-worker series carry the label `worker` (the worker URL)
/// and are removed when the worker leaves the pool, so pods coming and going do not
/// accumulate series.
#[derive(Clone)]
pub struct PoolMetrics {
    pub workers: IntGauge,
    pub workers_live: IntGauge,
    pub worker_streams: IntGaugeVec,
    pub worker_in_flight_batches: IntGaugeVec,
    pub worker_in_flight_requests: IntGaugeVec,
    pub worker_batch_size: IntGaugeVec,
    pub worker_in_flight_limit: IntGaugeVec,
    pub worker_samples: IntCounterVec,
    pub worker_failures: IntCounterVec,
    pub samples_per_second: Gauge,
    pub batch_latency: Histogram,
    pub requeued_batches: IntCounter,
    pub dropped_batches: IntCounter,
    pub queued_batches: IntGauge,
    pub outstanding_requests: IntGauge,
}

impl std::fmt::Debug for PoolMetrics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PoolMetrics").field("workers", &self.workers.get()).finish_non_exhaustive()
    }
}

impl Default for PoolMetrics {
    /// Collectors that count but are not exported (pools made outside a server).
    fn default() -> Self {
        Self::new(None)
    }
}

impl PoolMetrics {
    pub fn new(registry: Option<&Registry>) -> Self {
        let m = PoolMetrics {
            workers: gauge("edgepoint_server_workers", "Shader workers in the pool (configured or discovered)."),
            workers_live: gauge("edgepoint_server_workers_live", "Workers with at least one open Shade stream."),
            worker_streams: gauge_vec("edgepoint_server_worker_streams", "Open Shade streams per worker (one per session)."),
            worker_in_flight_batches: gauge_vec("edgepoint_server_worker_in_flight_batches", "Batches sent to a worker and not yet answered."),
            worker_in_flight_requests: gauge_vec("edgepoint_server_worker_in_flight_requests", "Requests sent to a worker and not yet answered."),
            worker_batch_size: gauge_vec("edgepoint_server_worker_batch_size", "Largest batch currently sent to a worker (adapts to its measured rate)."),
            worker_in_flight_limit: gauge_vec("edgepoint_server_worker_in_flight_limit", "Batches a worker may hold at once (adapts to its latency)."),
            worker_samples: IntCounterVec::new(Opts::new("edgepoint_server_worker_samples_total", "Samples received from a worker."), &[WORKER_LABEL])
                .expect("static metric name"),
            worker_failures: IntCounterVec::new(
                Opts::new("edgepoint_server_worker_failures_total", "Shade streams to a worker that ended in an error or a stall."),
                &[WORKER_LABEL],
            )
            .expect("static metric name"),
            samples_per_second: Gauge::new("edgepoint_server_samples_per_second", "Samples received per second over the last 2 s, all workers.")
                .expect("static metric name"),
            batch_latency: histogram("edgepoint_server_batch_latency_seconds", "Time from submitting a batch to its answer (queue + network + shading)."),
            requeued_batches: counter("edgepoint_server_requeued_batches_total", "Batches re-issued to other workers after their worker failed, stalled or left."),
            dropped_batches: counter("edgepoint_server_dropped_batches_total", "Batches given up (their epoch could no longer be shaded, or they failed too often)."),
            queued_batches: gauge("edgepoint_server_dispatch_queue_batches", "Batches waiting in the sessions' dispatch queues for a worker."),
            outstanding_requests: gauge("edgepoint_server_outstanding_requests", "Requests submitted by sessions and not yet answered."),
        };
        register(
            registry,
            vec![
                Box::new(m.workers.clone()),
                Box::new(m.workers_live.clone()),
                Box::new(m.worker_streams.clone()),
                Box::new(m.worker_in_flight_batches.clone()),
                Box::new(m.worker_in_flight_requests.clone()),
                Box::new(m.worker_batch_size.clone()),
                Box::new(m.worker_in_flight_limit.clone()),
                Box::new(m.worker_samples.clone()),
                Box::new(m.worker_failures.clone()),
                Box::new(m.samples_per_second.clone()),
                Box::new(m.batch_latency.clone()),
                Box::new(m.requeued_batches.clone()),
                Box::new(m.dropped_batches.clone()),
                Box::new(m.queued_batches.clone()),
                Box::new(m.outstanding_requests.clone()),
            ],
        );
        m
    }

    /// Drops every per-worker series of `url` (the worker left the pool).
    pub fn forget_worker(&self, url: &str) {
        for v in [
            &self.worker_streams,
            &self.worker_in_flight_batches,
            &self.worker_in_flight_requests,
            &self.worker_batch_size,
            &self.worker_in_flight_limit,
        ] {
            let _ = v.remove_label_values(&[url]);
        }
        let _ = self.worker_samples.remove_label_values(&[url]);
        let _ = self.worker_failures.remove_label_values(&[url]);
    }
}

/// Why a session was refused (the `reason` label of `edgepoint_server_sessions_refused_total`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    Unauthenticated,
    Limit,
    Invalid,
    Unavailable,
}

impl Refusal {
    pub fn label(self) -> &'static str {
        match self {
            Refusal::Unauthenticated => "unauthenticated",
            Refusal::Limit => "limit",
            Refusal::Invalid => "invalid",
            Refusal::Unavailable => "unavailable",
        }
    }

    /// The refusal a gRPC status stands for.
    pub fn of(code: tonic::Code) -> Refusal {
        match code {
            tonic::Code::Unauthenticated | tonic::Code::PermissionDenied => Refusal::Unauthenticated,
            tonic::Code::ResourceExhausted | tonic::Code::OutOfRange => Refusal::Limit,
            tonic::Code::Unavailable | tonic::Code::FailedPrecondition | tonic::Code::DeadlineExceeded => Refusal::Unavailable,
            _ => Refusal::Invalid,
        }
    }
}

/// The viewer sessions' metrics.
#[derive(Clone)]
pub struct SessionMetrics {
    pub sessions: IntGauge,
    pub started: IntCounter,
    pub refused: IntCounterVec,
    pub frames: IntCounter,
    pub frames_dropped: IntCounter,
    pub frame_seconds: Histogram,
    pub frame_interval_seconds: Histogram,
}

impl Default for SessionMetrics {
    fn default() -> Self {
        Self::new(None)
    }
}

impl SessionMetrics {
    pub fn new(registry: Option<&Registry>) -> Self {
        let m = SessionMetrics {
            sessions: gauge("edgepoint_server_sessions", "Viewer sessions running."),
            started: counter("edgepoint_server_sessions_started_total", "Viewer sessions started."),
            refused: IntCounterVec::new(
                Opts::new("edgepoint_server_sessions_refused_total", "Session starts refused, by reason."),
                &["reason"],
            )
            .expect("static metric name"),
            frames: counter("edgepoint_server_frames_total", "Frames sent to viewers."),
            frames_dropped: counter(
                "edgepoint_server_frames_dropped_total",
                "Frames replaced by a newer one before the viewer took them (a slow viewer link).",
            ),
            frame_seconds: histogram("edgepoint_server_frame_seconds", "Frame-loop time per frame (paper Table 2 total)."),
            frame_interval_seconds: histogram("edgepoint_server_frame_interval_seconds", "Time between consecutive frames sent on one session."),
        };
        register(
            registry,
            vec![
                Box::new(m.sessions.clone()),
                Box::new(m.started.clone()),
                Box::new(m.refused.clone()),
                Box::new(m.frames.clone()),
                Box::new(m.frames_dropped.clone()),
                Box::new(m.frame_seconds.clone()),
                Box::new(m.frame_interval_seconds.clone()),
            ],
        );
        m
    }

    pub fn refuse(&self, why: Refusal) {
        self.refused.with_label_values(&[why.label()]).inc();
    }
}

/// Every metric of one server process, in its own registry.
pub struct ServerMetrics {
    pub registry: Registry,
    pub pool: Arc<PoolMetrics>,
    pub sessions: Arc<SessionMetrics>,
    resident: IntGauge,
}

impl Default for ServerMetrics {
    fn default() -> Self {
        Self::new()
    }
}

impl ServerMetrics {
    pub fn new() -> Self {
        let registry = Registry::new();
        let pool = Arc::new(PoolMetrics::new(Some(&registry)));
        let sessions = Arc::new(SessionMetrics::new(Some(&registry)));
        let resident = edgepoint_proto::metrics_http::resident_gauge(&registry);
        ServerMetrics { registry, pool, sessions, resident }
    }

    /// The Prometheus text exposition of every metric, process memory read now.
    pub fn encode(&self) -> String {
        edgepoint_proto::metrics_http::encode(&self.registry, &self.resident)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_export_with_their_labels_and_forget_departed_workers() {
        let m = ServerMetrics::new();
        m.pool.workers.set(2);
        m.pool.worker_in_flight_batches.with_label_values(&["http://a:1"]).set(3);
        m.pool.worker_samples.with_label_values(&["http://a:1"]).inc_by(500);
        m.pool.batch_latency.observe(0.012);
        m.sessions.refuse(Refusal::of(tonic::Code::Unauthenticated));
        m.sessions.frames.inc();
        let text = m.encode();
        for needle in [
            "edgepoint_server_workers 2",
            "edgepoint_server_worker_in_flight_batches{worker=\"http://a:1\"} 3",
            "edgepoint_server_worker_samples_total{worker=\"http://a:1\"} 500",
            "edgepoint_server_batch_latency_seconds_count 1",
            "edgepoint_server_sessions_refused_total{reason=\"unauthenticated\"} 1",
            "edgepoint_server_frames_total 1",
        ] {
            assert!(text.contains(needle), "missing `{needle}` in:\n{text}");
        }
        if cfg!(target_os = "linux") {
            assert!(text.contains("process_resident_memory_bytes"), "{text}");
        }
        m.pool.forget_worker("http://a:1");
        assert!(!m.encode().contains("http://a:1"));
        // Unregistered metrics count but export nothing.
        let loose = PoolMetrics::default();
        loose.requeued_batches.inc();
        assert_eq!(loose.requeued_batches.get(), 1);
    }
}
