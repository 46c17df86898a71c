//! Prometheus metrics of a shader worker, served by `--metrics-listen`: samples and batches
//! shaded, shading time per batch, batches shading now and waiting for a slot, open streams,
//! scenes loaded, stream errors, non-finite samples, resident memory. Samples per second is
//! `rate(edgepoint_worker_samples_total[1m])`.
use prometheus::{exponential_buckets, Histogram, HistogramOpts, IntCounter, IntGauge, Registry};

/// One worker's metrics, in its own registry.
#[derive(Clone)]
pub struct WorkerMetrics {
    pub registry: Registry,
    pub samples: IntCounter,
    pub batches: IntCounter,
    pub batch_seconds: Histogram,
    pub shading: IntGauge,
    pub waiting: IntGauge,
    pub streams: IntGauge,
    pub scenes: IntGauge,
    pub scene_loads: IntCounter,
    pub stream_errors: IntCounter,
    pub nonfinite: IntCounter,
    resident: IntGauge,
}

impl Default for WorkerMetrics {
    fn default() -> Self {
        Self::new()
    }
}

impl WorkerMetrics {
    pub fn new() -> Self {
        let registry = Registry::new();
        let g = |n: &str, h: &str| {
            let m = IntGauge::new(n, h).expect("static metric name");
            registry.register(Box::new(m.clone())).expect("unique");
            m
        };
        let c = |n: &str, h: &str| {
            let m = IntCounter::new(n, h).expect("static metric name");
            registry.register(Box::new(m.clone())).expect("unique");
            m
        };
        let batch_seconds = Histogram::with_opts(
            HistogramOpts::new("edgepoint_worker_batch_seconds", "Wall time spent shading one batch.")
                .buckets(exponential_buckets(0.0005, 2.0, 16).expect("valid buckets")),
        )
        .expect("static metric name");
        registry.register(Box::new(batch_seconds.clone())).expect("unique");
        WorkerMetrics {
            samples: c("edgepoint_worker_samples_total", "Samples shaded."),
            batches: c("edgepoint_worker_batches_total", "Batches shaded."),
            shading: g("edgepoint_worker_shading_batches", "Batches being shaded now."),
            waiting: g("edgepoint_worker_waiting_batches", "Batches read from a stream and waiting for a shading slot (queue depth)."),
            streams: g("edgepoint_worker_streams", "Open Shade streams (one per renderer session)."),
            scenes: g("edgepoint_worker_scenes", "Scenes loaded in the cache."),
            scene_loads: c("edgepoint_worker_scene_loads_total", "Scenes built (cache misses)."),
            stream_errors: c("edgepoint_worker_stream_errors_total", "Shade streams ended with an error status."),
            nonfinite: c("edgepoint_worker_nonfinite_samples_total", "Samples whose shading was NaN or infinite (clamped)."),
            resident: edgepoint_proto::metrics_http::resident_gauge(&registry),
            batch_seconds,
            registry,
        }
    }

    /// The Prometheus text exposition, process memory read now.
    pub fn encode(&self) -> String {
        edgepoint_proto::metrics_http::encode(&self.registry, &self.resident)
    }
}
