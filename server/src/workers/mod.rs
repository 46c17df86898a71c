//! The shader-worker pool: asynchronous request dispatch with back-pressure (paper 000 §3:
//! "the shader asynchronously finds visible points and computes their color"; DESIGN.md
//! "Threads", "Budget" and "deploy").
//!
//! A [`WorkerPool`] knows the workers — fixed addresses, DNS names re-resolved periodically
//! (the Kubernetes headless-Service pattern) and/or a file re-read periodically, see
//! `discovery` — and holds one lazily connected gRPC channel per worker (HTTP/2 keepalive,
//! connect timeout, TLS for `https://` workers, large messages since scenes travel as bytes).
//! Workers join and leave while sessions run. For every render session (or reference
//! render, or benchmark) [`WorkerPool::open`] makes a [`Dispatcher`]: a supervisor task that
//! keeps one async link per current worker (see `link`), a shared multi-consumer queue of
//! request batches, a retry queue that links serve first, and an answer queue.
//!
//! The dispatcher's methods never block and never await, so the frame-loop thread calls
//! them directly: [`Dispatcher::submit`] queues a batch (or refuses when the queue is full),
//! [`Dispatcher::set_epoch`] announces moved objects, [`Dispatcher::drain`] takes every
//! answer that arrived. Every worker pulls from the same queues while it holds fewer batches
//! than its in-flight limit, so faster workers take proportionally more; a batch larger than
//! a worker's measured batch size is split and the rest goes to whoever is free next. A
//! worker that fails, stalls or leaves hands its in-flight batches back to the retry queue,
//! so no request is lost while another worker lives; a batch that can no longer be shaded
//! consistently (its epoch is gone) is dropped and counted as answered so the outstanding
//! count never leaks.
//!
//! Outside a session, await answers with [`Dispatcher::next_answer`] or let
//! [`Dispatcher::shade_all`] submit a whole job and collect it (the reference renderer and
//! the benchmarks do this).
mod discovery;
mod epochs;
mod link;
mod rate;

pub use discovery::{
    read_workers_file, Discovery, Member, Resolve, SystemResolver, WorkerAddr, WorkerSources, DNS_GRACE, LOOKUP_TIMEOUT,
};
pub use epochs::{EpochTable, RETAINED_EPOCHS, WORKER_KEEPS};
pub use link::{stall_allowance, LinkState, MAX_ATTEMPTS, MAX_BACKOFF};
pub use rate::{BatchSizer, InFlightLimit, RateMeter};

use crate::metrics::PoolMetrics;
use edgepoint_proto::shader_worker_client::ShaderWorkerClient;
use edgepoint_proto::{InfoRequest, RequestBatch, SampleBatch, SceneSource};
use glam::Affine3A;
use prometheus::{IntCounter, IntGauge};
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::runtime::Handle;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tonic::transport::{Channel, ClientTlsConfig, Endpoint};

/// Default gRPC message size limit: scenes travel as bytes.
pub const DEFAULT_MAX_MESSAGE_BYTES: usize = 256 << 20;

/// Connection and dispatch options.
#[derive(Debug, Clone)]
pub struct PoolOptions {
    /// Largest gRPC message sent or accepted (scene sources, sample batches).
    pub max_message_bytes: usize,
    /// TCP connect timeout per attempt.
    pub connect_timeout: Duration,
    /// HTTP/2 keepalive ping interval; a worker that stops answering pings for
    /// `keepalive_timeout` counts as failed even when its TCP connection hangs.
    pub keepalive_interval: Duration,
    pub keepalive_timeout: Duration,
    /// Deadline of `LoadScene` (a large mesh takes seconds to load and build).
    pub load_timeout: Duration,
    /// Deadline of the small calls (`Info`, opening a `Shade` stream).
    pub call_timeout: Duration,
    /// A stream with batches in flight and no answer for a few round trips, but at least
    /// `stall_floor` and at most `stall_cap`, counts as stalled; before any round trip was
    /// measured the allowance is `first_answer_timeout`.
    pub stall_floor: Duration,
    pub stall_cap: Duration,
    pub first_answer_timeout: Duration,
    /// A batch not answered within this time fails its stream, however busy the worker is.
    pub batch_deadline: Duration,
    /// Batches the shared queue of each dispatcher holds before `submit` refuses more.
    pub queue_batches: usize,
    /// In-flight batches per worker before the first measurement, and the cap.
    pub initial_in_flight: usize,
    pub max_in_flight: usize,
    /// Batches sent to a worker hold about this much of its work (see [`BatchSizer`]),
    /// between `min_batch` and `max_batch` requests; larger submitted batches are split.
    pub target_batch_time: Duration,
    pub min_batch: usize,
    pub max_batch: usize,
    /// TLS for `https://` workers (CA and name checks, and a client certificate for mutual
    /// TLS); `None` trusts the web PKI roots.
    pub tls: Option<ClientTlsConfig>,
    /// Adds the bearer token workers started with `--token-file` require to every call
    /// (`--worker-token-file`; the default adds none).
    pub worker_token: edgepoint_proto::auth::SendToken,
    /// Where the pool's metrics go (unexported unless registered with a server's registry).
    pub metrics: Arc<PoolMetrics>,
}

impl Default for PoolOptions {
    fn default() -> Self {
        PoolOptions {
            max_message_bytes: DEFAULT_MAX_MESSAGE_BYTES,
            connect_timeout: Duration::from_secs(2),
            keepalive_interval: Duration::from_secs(2),
            keepalive_timeout: Duration::from_secs(5),
            load_timeout: Duration::from_secs(300),
            call_timeout: Duration::from_secs(10),
            stall_floor: Duration::from_secs(1),
            stall_cap: Duration::from_secs(10),
            first_answer_timeout: Duration::from_secs(30),
            batch_deadline: Duration::from_secs(60),
            queue_batches: 1024,
            initial_in_flight: 4,
            max_in_flight: 16,
            target_batch_time: Duration::from_millis(25),
            min_batch: 16,
            max_batch: 65_536,
            tls: None,
            worker_token: Default::default(),
            metrics: Arc::new(PoolMetrics::default()),
        }
    }
}

/// A worker address could not be used.
#[derive(Debug, thiserror::Error)]
pub enum PoolError {
    #[error("bad worker address '{addr}': {reason}")]
    BadAddress { addr: String, reason: String },
    #[error("WorkerPool must be created inside a tokio runtime")]
    NoRuntime,
}

/// Turns `host:port` into `http://host:port`; URLs with a scheme pass through.
pub fn normalize_endpoint(addr: &str) -> String {
    let a = addr.trim();
    if a.contains("://") {
        a.to_string()
    } else {
        format!("http://{a}")
    }
}

/// The metric series of one worker, resolved once when it joins.
pub(crate) struct WorkerSeries {
    pub streams: IntGauge,
    pub in_flight_batches: IntGauge,
    pub in_flight_requests: IntGauge,
    pub batch_size: IntGauge,
    pub in_flight_limit: IntGauge,
    pub samples: IntCounter,
    pub failures: IntCounter,
}

impl WorkerSeries {
    fn new(m: &PoolMetrics, url: &str) -> Self {
        let l = [url];
        WorkerSeries {
            streams: m.worker_streams.with_label_values(&l),
            in_flight_batches: m.worker_in_flight_batches.with_label_values(&l),
            in_flight_requests: m.worker_in_flight_requests.with_label_values(&l),
            batch_size: m.worker_batch_size.with_label_values(&l),
            in_flight_limit: m.worker_in_flight_limit.with_label_values(&l),
            samples: m.worker_samples.with_label_values(&l),
            failures: m.worker_failures.with_label_values(&l),
        }
    }
}

/// One worker of the pool: its channel (shared by every session) and live counts.
pub(crate) struct PoolMember {
    pub url: Arc<str>,
    pub channel: Channel,
    /// Open Shade streams to this worker over all dispatchers.
    pub streams: AtomicUsize,
    pub series: WorkerSeries,
}

type Members = Arc<Vec<Arc<PoolMember>>>;

/// Aborts a task when dropped.
struct AbortOnDrop(JoinHandle<()>);
impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// State the pool shares with its discovery task and its dispatchers.
struct PoolCore {
    runtime: Handle,
    opts: PoolOptions,
    members: watch::Sender<Members>,
    /// Samples per second over all dispatchers (for metrics).
    rate: Mutex<RateMeter>,
    /// The open dispatchers, for the queue and outstanding gauges.
    dispatchers: Mutex<Vec<std::sync::Weak<Shared>>>,
}

impl PoolCore {
    fn channel(&self, m: &Member) -> Result<Channel, PoolError> {
        let opts = &self.opts;
        let bad = |reason: String| PoolError::BadAddress { addr: m.url.clone(), reason };
        let mut ep = Endpoint::from_shared(m.url.clone()).map_err(|e| bad(e.to_string()))?;
        if ep.uri().host().is_none() || ep.uri().port_u16().is_none() {
            return Err(bad("needs host and port".into()));
        }
        if m.url.starts_with("https://") {
            let mut tls = opts.tls.clone().unwrap_or_else(|| ClientTlsConfig::new().with_webpki_roots());
            if let Some(d) = &m.tls_domain {
                tls = tls.domain_name(d.clone());
            }
            ep = ep.tls_config(tls).map_err(|e| bad(format!("TLS: {e}")))?;
        }
        let ep = ep
            .connect_timeout(opts.connect_timeout)
            .http2_keep_alive_interval(opts.keepalive_interval)
            .keep_alive_timeout(opts.keepalive_timeout)
            .keep_alive_while_idle(true)
            .tcp_nodelay(true)
            .http2_adaptive_window(true);
        let _g = self.runtime.enter();
        Ok(ep.connect_lazy())
    }

    /// Makes the pool's members `list`: keeps the channels of workers that stay, opens
    /// channels for new ones, forgets departed ones (their links stop, handing their
    /// batches to the others). Returns how many joined and left.
    fn set_members(&self, list: &[Member]) -> (usize, usize) {
        let current = self.members.borrow().clone();
        let mut keep: BTreeMap<&str, Arc<PoolMember>> = current.iter().map(|m| (&*m.url, m.clone())).collect();
        let mut next = Vec::with_capacity(list.len());
        let mut joined = 0;
        for m in list {
            if let Some(existing) = keep.remove(m.url.as_str()) {
                next.push(existing);
                continue;
            }
            match self.channel(m) {
                Ok(channel) => {
                    joined += 1;
                    tracing::info!(worker = %m.url, "worker joined the pool");
                    next.push(Arc::new(PoolMember {
                        url: m.url.as_str().into(),
                        channel,
                        streams: AtomicUsize::new(0),
                        series: WorkerSeries::new(&self.opts.metrics, &m.url),
                    }));
                }
                Err(e) => tracing::warn!("{e}; not added"),
            }
        }
        let left = keep.len();
        for url in keep.keys() {
            tracing::info!(worker = %url, "worker left the pool");
            self.opts.metrics.forget_worker(url);
        }
        if joined > 0 || left > 0 {
            self.opts.metrics.workers.set(next.len() as i64);
            self.members.send_replace(Arc::new(next));
        }
        (joined, left)
    }
}

/// The shader workers. Cheap to share (`Arc`); sessions share its channels. Dropping the
/// pool stops discovery; dispatchers already open keep the workers they have.
pub struct WorkerPool {
    core: Arc<PoolCore>,
    _discovery: Option<AbortOnDrop>,
}

impl WorkerPool {
    /// A pool over fixed `endpoints` (`http://host:port` or `host:port`) with default
    /// options. Must be called inside a tokio runtime: links are spawned on it. Nothing
    /// connects until a dispatcher is opened.
    pub fn new(endpoints: Vec<String>) -> Result<Self, PoolError> {
        Self::with_options(endpoints, PoolOptions::default())
    }

    /// A pool over fixed `endpoints`.
    pub fn with_options(endpoints: Vec<String>, opts: PoolOptions) -> Result<Self, PoolError> {
        let core = Self::core(opts)?;
        let mut list = Vec::with_capacity(endpoints.len());
        for addr in &endpoints {
            let a = WorkerAddr::parse(addr).map_err(|reason| PoolError::BadAddress { addr: addr.clone(), reason })?;
            list.push(Member { url: a.url(), tls_domain: None });
        }
        list.sort();
        list.dedup();
        for m in &list {
            core.channel(m)?;
        }
        core.set_members(&list);
        Ok(WorkerPool { core, _discovery: None })
    }

    /// A pool that follows `sources`: resolves them once now, then again every
    /// `sources.interval` on a background task while the pool lives.
    pub async fn discover(sources: WorkerSources, opts: PoolOptions) -> Result<Self, PoolError> {
        Self::discover_with(sources, opts, Arc::new(SystemResolver)).await
    }

    /// [`WorkerPool::discover`] with a chosen resolver.
    pub async fn discover_with(sources: WorkerSources, opts: PoolOptions, resolver: Arc<dyn Resolve>) -> Result<Self, PoolError> {
        let core = Self::core(opts)?;
        let mut discovery = Discovery::new(&sources, resolver)?;
        core.set_members(&discovery.poll().await);
        let task = if sources.is_dynamic() {
            let core = core.clone();
            let interval = sources.interval.max(Duration::from_millis(50));
            Some(AbortOnDrop(core.runtime.spawn({
                let core = core.clone();
                async move {
                    loop {
                        tokio::time::sleep(interval).await;
                        let list = discovery.poll().await;
                        let (joined, left) = core.set_members(&list);
                        if joined + left > 0 {
                            tracing::info!(workers = list.len(), joined, left, "worker pool changed");
                        }
                    }
                }
            })))
        } else {
            None
        };
        Ok(WorkerPool { core, _discovery: task })
    }

    fn core(opts: PoolOptions) -> Result<Arc<PoolCore>, PoolError> {
        let runtime = Handle::try_current().map_err(|_| PoolError::NoRuntime)?;
        let (members, _) = watch::channel(Arc::new(Vec::new()));
        Ok(Arc::new(PoolCore {
            runtime,
            opts,
            members,
            rate: Mutex::new(RateMeter::new(Duration::from_secs(2))),
            dispatchers: Mutex::new(Vec::new()),
        }))
    }

    fn members(&self) -> Members {
        self.core.members.borrow().clone()
    }

    /// Workers in the pool right now.
    pub fn len(&self) -> usize {
        self.members().len()
    }

    pub fn is_empty(&self) -> bool {
        self.members().is_empty()
    }

    /// The workers' URLs right now, sorted.
    pub fn endpoints(&self) -> Vec<String> {
        self.members().iter().map(|w| w.url.to_string()).collect()
    }

    /// Workers with at least one open Shade stream (over all dispatchers).
    pub fn live(&self) -> usize {
        self.members().iter().filter(|m| m.streams.load(Ordering::SeqCst) > 0).count()
    }

    pub fn options(&self) -> &PoolOptions {
        &self.core.opts
    }

    /// Brings the gauges that are computed rather than counted up to date (call before
    /// exporting metrics): workers known and live, the pool-wide sample rate, and the
    /// queued batches and outstanding requests summed over the open dispatchers.
    pub fn refresh_metrics(&self) {
        let m = &self.core.opts.metrics;
        let (mut queued, mut outstanding) = (0usize, 0u64);
        {
            let mut ds = self.core.dispatchers.lock().unwrap_or_else(|p| p.into_inner());
            ds.retain(|w| match w.upgrade() {
                Some(sh) => {
                    queued += sh.queue_rx.len() + sh.retry_rx.len();
                    outstanding += sh.outstanding_requests.load(Ordering::SeqCst);
                    true
                }
                None => false,
            });
        }
        m.queued_batches.set(queued as i64);
        m.outstanding_requests.set(outstanding as i64);
        m.workers.set(self.len() as i64);
        m.workers_live.set(self.live() as i64);
        m.samples_per_second.set(self.core.rate.lock().unwrap_or_else(|p| p.into_inner()).per_second(Instant::now()));
    }

    /// The shaders the workers offer (union over the workers that answer `Info` within
    /// `timeout`), or `None` when no worker answered.
    pub async fn shaders(&self, timeout: Duration) -> Option<Vec<String>> {
        let mut set = tokio::task::JoinSet::new();
        for w in self.members().iter() {
            let mut client = ShaderWorkerClient::with_interceptor(w.channel.clone(), self.core.opts.worker_token.clone());
            let mut req = tonic::Request::new(InfoRequest {});
            req.set_timeout(timeout);
            set.spawn_on(async move { tokio::time::timeout(timeout, client.info(req)).await }, &self.core.runtime);
        }
        let mut out: Option<Vec<String>> = None;
        while let Some(r) = set.join_next().await {
            if let Ok(Ok(Ok(reply))) = r {
                let all = out.get_or_insert_with(Vec::new);
                for s in reply.into_inner().shaders {
                    if !all.contains(&s) {
                        all.push(s);
                    }
                }
            }
        }
        out
    }

    /// Starts dispatch for the scene `source` whose content hash is `hash`
    /// (`edgepoint_proto::scene_hash(&source)`): one link per worker, following the pool as
    /// workers join and leave. The dispatcher starts at epoch 0 (every object at its scene
    /// default). Dropping the dispatcher stops its links.
    pub fn open(&self, source: SceneSource, hash: String) -> Dispatcher {
        let (queue_tx, queue_rx) = flume::unbounded();
        let (retry_tx, retry_rx) = flume::unbounded();
        let (answers_tx, answers_rx) = flume::unbounded();
        let shared = Arc::new(Shared {
            source: Arc::new(source),
            hash,
            cfg: self.core.opts.clone(),
            metrics: self.core.opts.metrics.clone(),
            queue_tx,
            queue_rx,
            retry_tx,
            retry_rx,
            answers_tx,
            answers_rx,
            epochs: Mutex::new(EpochTable::default()),
            outstanding_requests: AtomicU64::new(0),
            outstanding_batches: AtomicU64::new(0),
            live: AtomicUsize::new(0),
            members: AtomicUsize::new(0),
            rate: Mutex::new(RateMeter::new(Duration::from_secs(2))),
            rtt_bits: AtomicU64::new(0),
            pool: self.core.clone(),
            links: Mutex::new(Vec::new()),
            requeued_batches: AtomicU64::new(0),
            dropped_batches: AtomicU64::new(0),
            answered_batches: AtomicU64::new(0),
        });
        {
            let mut ds = self.core.dispatchers.lock().unwrap_or_else(|p| p.into_inner());
            ds.retain(|w| w.strong_count() > 0);
            ds.push(Arc::downgrade(&shared));
        }
        let members = self.core.members.subscribe();
        let supervisor = AbortOnDrop(self.core.runtime.spawn(supervise(shared.clone(), members)));
        Dispatcher { shared, _supervisor: supervisor }
    }
}

/// A running link and the switch that stops it. Dropping the handle aborts the link (the
/// dispatcher is gone); [`LinkHandle::stop`] lets it hand its batches back first.
struct LinkHandle {
    stop: watch::Sender<bool>,
    task: Option<JoinHandle<()>>,
}

impl LinkHandle {
    fn stop(mut self) {
        let _ = self.stop.send(true);
        // Detached: the link ends by itself once it has requeued its batches.
        self.task.take();
    }
}

impl Drop for LinkHandle {
    fn drop(&mut self) {
        if let Some(t) = self.task.take() {
            t.abort();
        }
    }
}

/// Keeps one link per pool member for one dispatcher. A departed worker's link is stopped
/// gracefully (its batches go back to the retry queue); dropping this task's future (the
/// dispatcher is gone) aborts every link.
async fn supervise(shared: Arc<Shared>, mut members: watch::Receiver<Members>) {
    let mut links: HashMap<Arc<str>, LinkHandle> = HashMap::new();
    loop {
        let current = members.borrow_and_update().clone();
        let gone: Vec<Arc<str>> = links.keys().filter(|url| !current.iter().any(|m| &m.url == *url)).cloned().collect();
        for url in gone {
            if let Some(h) = links.remove(&url) {
                h.stop();
            }
        }
        for m in current.iter() {
            if links.contains_key(&m.url) {
                continue;
            }
            let state = Arc::new(LinkState::new(m.url.clone()));
            let (stop, stop_rx) = watch::channel(false);
            let task = tokio::spawn(link::run(shared.clone(), m.clone(), state.clone(), stop_rx));
            links.insert(m.url.clone(), LinkHandle { stop, task: Some(task) });
            shared.links.lock().unwrap_or_else(|p| p.into_inner()).push(state);
        }
        shared.links.lock().unwrap_or_else(|p| p.into_inner()).retain(|s| current.iter().any(|m| m.url == s.url));
        shared.members.store(current.len(), Ordering::SeqCst);
        if members.changed().await.is_err() {
            // The pool is gone: keep serving with the workers we have.
            std::future::pending::<()>().await;
        }
    }
}

/// A queued batch, how often it went back to the queue, and when it was submitted.
pub(crate) struct Queued {
    pub batch: RequestBatch,
    pub attempts: u32,
    pub submitted_at: Instant,
}

/// What comes back for a submitted batch. A batch that was split among workers comes back
/// in several parts, each with the submitted batch id; `requests` says how many of the
/// batch's requests a part settles.
#[derive(Debug)]
pub enum Answer {
    /// A worker's samples.
    Samples {
        batch: SampleBatch,
        /// Requests of the submitted batch this answer settles.
        requests: usize,
        /// From submission to this answer: queueing, network and shading.
        latency: Duration,
        /// The URL of the worker that shaded it.
        worker: Arc<str>,
    },
    /// (Part of) the batch was given up: its epoch can no longer be sent to any worker
    /// stream, or it failed [`MAX_ATTEMPTS`] times. It no longer counts as outstanding.
    Dropped { batch_id: u64, epoch: u64, requests: usize },
}

/// State shared between a dispatcher and its links.
pub(crate) struct Shared {
    pub source: Arc<SceneSource>,
    pub hash: String,
    pub cfg: PoolOptions,
    pub metrics: Arc<PoolMetrics>,
    pub queue_tx: flume::Sender<Queued>,
    pub queue_rx: flume::Receiver<Queued>,
    /// Batches handed back by failed links and the rest of split batches: links take these
    /// before new work.
    pub retry_tx: flume::Sender<Queued>,
    pub retry_rx: flume::Receiver<Queued>,
    pub answers_tx: flume::Sender<Answer>,
    pub answers_rx: flume::Receiver<Answer>,
    pub epochs: Mutex<EpochTable>,
    pub outstanding_requests: AtomicU64,
    /// Batches (and parts of split batches) not yet answered or dropped.
    pub outstanding_batches: AtomicU64,
    pub live: AtomicUsize,
    pub members: AtomicUsize,
    pub rate: Mutex<RateMeter>,
    /// Smoothed batch round trip over all links, seconds as f64 bits (0 = none yet): the
    /// prior for a link that has not measured its own.
    rtt_bits: AtomicU64,
    pool: Arc<PoolCore>,
    pub links: Mutex<Vec<Arc<LinkState>>>,
    pub requeued_batches: AtomicU64,
    pub dropped_batches: AtomicU64,
    pub answered_batches: AtomicU64,
}

impl Shared {
    /// A batch (or part) left the system (answered or dropped).
    pub fn settle(&self, b: &RequestBatch) {
        let n = b.requests.len() as u64;
        self.outstanding_requests.fetch_sub(n, Ordering::SeqCst);
        self.outstanding_batches.fetch_sub(1, Ordering::SeqCst);
        self.answered_batches.fetch_add(1, Ordering::Relaxed);
    }

    pub fn answer_dropped(&self, q: &Queued) {
        self.dropped_batches.fetch_add(1, Ordering::Relaxed);
        self.metrics.dropped_batches.inc();
        self.settle(&q.batch);
        let _ = self.answers_tx.send(Answer::Dropped { batch_id: q.batch.batch_id, epoch: q.batch.epoch, requests: q.batch.requests.len() });
    }

    /// Queues a batch ahead of new work.
    pub fn push_retry(&self, q: Queued) {
        // Unbounded, and the dispatcher holds a receiver for as long as links run.
        let _ = self.retry_tx.send(q);
    }

    /// Folds one batch round trip into the dispatcher-wide estimate.
    pub fn observe_rtt(&self, rtt: Duration) {
        let old = f64::from_bits(self.rtt_bits.load(Ordering::Relaxed));
        let new = if old > 0.0 { 0.8 * old + 0.2 * rtt.as_secs_f64() } else { rtt.as_secs_f64() };
        self.rtt_bits.store(new.to_bits(), Ordering::Relaxed);
    }

    /// The dispatcher-wide smoothed round trip, once any link measured one.
    pub fn rtt(&self) -> Option<f64> {
        let r = f64::from_bits(self.rtt_bits.load(Ordering::Relaxed));
        (r > 0.0).then_some(r)
    }

    pub fn record_samples(&self, now: Instant, n: u64) {
        self.rate.lock().unwrap_or_else(|p| p.into_inner()).record(now, n);
        self.pool.rate.lock().unwrap_or_else(|p| p.into_inner()).record(now, n);
    }
}

/// Counters of one dispatcher since it opened.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DispatchStats {
    /// Batches (or parts of split batches) answered or dropped.
    pub settled_batches: u64,
    /// Batches given up (see [`Answer::Dropped`]).
    pub dropped_batches: u64,
    /// Batches handed back to the queue by a failing, stalled or departed worker link.
    pub requeued_batches: u64,
    /// Samples received.
    pub samples: u64,
}

/// One worker as one dispatcher sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerStatus {
    pub url: String,
    /// A Shade stream is open.
    pub live: bool,
    pub in_flight_batches: usize,
    pub in_flight_requests: usize,
    pub in_flight_limit: usize,
    /// Largest batch currently sent to it.
    pub batch_size: usize,
    /// Measured samples per busy second (0 until measured).
    pub samples_per_busy_second: f64,
    /// Samples it delivered to this dispatcher.
    pub samples: u64,
    /// Streams that failed, stalled or could not be opened.
    pub failures: u64,
}

/// Why [`Dispatcher::shade_all`] failed.
#[derive(Debug, thiserror::Error)]
pub enum DispatchError {
    #[error("no answer for {stall:?} with {pending} batches pending ({live} of {workers} workers live)")]
    Stalled { stall: Duration, pending: usize, live: usize, workers: usize },
    #[error("batch {batch_id} of epoch {epoch} was dropped: its epoch is no longer shadeable")]
    Dropped { batch_id: u64, epoch: u64 },
    #[error("batch {batch_id} names epoch {epoch}, which the dispatcher does not hold (current {current})")]
    BadEpoch { batch_id: u64, epoch: u64, current: u64 },
}

/// One scene's request dispatch over the pool's workers. See the module docs.
pub struct Dispatcher {
    shared: Arc<Shared>,
    _supervisor: AbortOnDrop,
}

impl Dispatcher {
    pub fn scene_hash(&self) -> &str {
        &self.shared.hash
    }

    /// Queues a batch; false when the queue is full or the batch's epoch is not one the
    /// dispatcher holds (current or recent). Batch ids must be unique among the batches
    /// outstanding; the answer carries the same id. Never blocks.
    pub fn submit(&self, batch: RequestBatch) -> bool {
        self.try_submit(batch).is_ok()
    }

    /// [`Dispatcher::submit`] that hands a refused batch back (by value: a refusal is the
    /// rare path, and the caller owns the batch again without an allocation).
    #[allow(clippy::result_large_err)]
    pub fn try_submit(&self, batch: RequestBatch) -> Result<(), RequestBatch> {
        let sh = &self.shared;
        if sh.queue_rx.len() >= sh.cfg.queue_batches {
            return Err(batch);
        }
        if !sh.epochs.lock().unwrap_or_else(|p| p.into_inner()).is_retained(batch.epoch) {
            return Err(batch);
        }
        let n = batch.requests.len() as u64;
        sh.outstanding_requests.fetch_add(n, Ordering::SeqCst);
        sh.outstanding_batches.fetch_add(1, Ordering::SeqCst);
        // Unbounded underneath (capacity is checked above), so this cannot block; it fails
        // only if every receiver is gone, which the dispatcher itself prevents.
        if let Err(e) = sh.queue_tx.send(Queued { batch, attempts: 0, submitted_at: Instant::now() }) {
            let q = e.into_inner();
            sh.outstanding_requests.fetch_sub(n, Ordering::SeqCst);
            sh.outstanding_batches.fetch_sub(1, Ordering::SeqCst);
            return Err(q.batch);
        }
        Ok(())
    }

    /// Starts scene epoch `epoch`: the objects in `moved` take these object-to-world
    /// transforms (others keep theirs). Batches of this epoch shade the moved scene. Epochs
    /// must increase; returns false (and ignores the call) otherwise.
    pub fn set_epoch(&self, epoch: u64, moved: Vec<(u32, Affine3A)>) -> bool {
        self.shared.epochs.lock().unwrap_or_else(|p| p.into_inner()).advance(epoch, &moved)
    }

    /// The latest epoch set.
    pub fn epoch(&self) -> u64 {
        self.shared.epochs.lock().unwrap_or_else(|p| p.into_inner()).current()
    }

    /// Appends every sample batch that has arrived to `out` (dropped batches are only
    /// counted, see [`Dispatcher::stats`]). Returns how many batches were appended.
    pub fn drain(&self, out: &mut Vec<SampleBatch>) -> usize {
        let before = out.len();
        for a in self.shared.answers_rx.try_iter() {
            if let Answer::Samples { batch, .. } = a {
                out.push(batch);
            }
        }
        out.len() - before
    }

    /// The answers as they come (samples or dropped batches), for a loop that waits on them
    /// beside other channels; [`Dispatcher::drain`] takes those ready.
    pub fn answers(&self) -> &flume::Receiver<Answer> {
        &self.shared.answers_rx
    }

    /// Waits for the next answer (samples or a dropped batch). For async users; a session's
    /// frame loop uses [`Dispatcher::drain`]. The dispatcher keeps a sender, so this only
    /// returns `None` if the dispatcher is being torn down.
    pub async fn next_answer(&self) -> Option<Answer> {
        self.shared.answers_rx.recv_async().await.ok()
    }

    /// Requests submitted and not yet answered or dropped.
    pub fn outstanding_requests(&self) -> u64 {
        self.shared.outstanding_requests.load(Ordering::SeqCst)
    }

    /// Batches, and parts of split batches, not yet answered or dropped.
    pub fn outstanding_batches(&self) -> u64 {
        self.shared.outstanding_batches.load(Ordering::SeqCst)
    }

    /// Batches waiting for a worker (new and handed-back ones).
    pub fn queued_batches(&self) -> usize {
        self.shared.queue_rx.len() + self.shared.retry_rx.len()
    }

    /// Workers with an open shade stream for this scene right now.
    pub fn live_workers(&self) -> usize {
        self.shared.live.load(Ordering::SeqCst)
    }

    /// Workers in the pool right now (live or not).
    pub fn workers(&self) -> usize {
        self.shared.members.load(Ordering::SeqCst)
    }

    /// Each current worker as this dispatcher sees it, by URL.
    pub fn worker_status(&self) -> Vec<WorkerStatus> {
        let links = self.shared.links.lock().unwrap_or_else(|p| p.into_inner());
        let mut out: Vec<WorkerStatus> = links
            .iter()
            .map(|s| WorkerStatus {
                url: s.url.to_string(),
                live: s.live.load(Ordering::SeqCst),
                in_flight_batches: s.in_flight_batches.load(Ordering::Relaxed),
                in_flight_requests: s.in_flight_requests.load(Ordering::Relaxed),
                in_flight_limit: s.in_flight_limit.load(Ordering::Relaxed),
                batch_size: s.batch_size.load(Ordering::Relaxed),
                samples_per_busy_second: f64::from_bits(s.rate_bits.load(Ordering::Relaxed)),
                samples: s.samples.load(Ordering::Relaxed),
                failures: s.failures.load(Ordering::Relaxed),
            })
            .collect();
        out.sort_by(|a, b| a.url.cmp(&b.url));
        out
    }

    /// What the live workers can shade: the sum of their samples per busy second (a link
    /// is busy while it has batches in flight; 0 until measured). Unlike
    /// [`Self::samples_per_second`] it does not fall when the workers are kept short of work.
    pub fn samples_per_busy_second(&self) -> f64 {
        let links = self.shared.links.lock().unwrap_or_else(|p| p.into_inner());
        links.iter().filter(|s| s.live.load(Ordering::Relaxed)).map(|s| f64::from_bits(s.rate_bits.load(Ordering::Relaxed))).filter(|r| r.is_finite() && *r > 0.0).sum()
    }

    /// Samples received per second over the last two seconds.
    pub fn samples_per_second(&self) -> f64 {
        self.shared.rate.lock().unwrap_or_else(|p| p.into_inner()).per_second(Instant::now())
    }

    pub fn stats(&self) -> DispatchStats {
        DispatchStats {
            settled_batches: self.shared.answered_batches.load(Ordering::Relaxed),
            dropped_batches: self.shared.dropped_batches.load(Ordering::Relaxed),
            requeued_batches: self.shared.requeued_batches.load(Ordering::Relaxed),
            samples: self.shared.rate.lock().unwrap_or_else(|p| p.into_inner()).total(),
        }
    }

    /// Shades a whole job: submits `batches` (keeping at most `window` outstanding, fewer if
    /// the queue refuses), hands every answer to `on_batch` as it arrives (a batch split
    /// among workers arrives in parts), and returns when all are answered. Fails if a batch
    /// is dropped (its epoch was superseded meanwhile) or nothing arrives for `stall` (e.g.
    /// every worker is down). The caller must be this dispatcher's only consumer of answers
    /// while it runs.
    pub async fn shade_all<I, F>(&self, batches: I, window: usize, stall: Duration, mut on_batch: F) -> Result<(), DispatchError>
    where
        I: IntoIterator<Item = RequestBatch>,
        F: FnMut(SampleBatch),
    {
        let mut batches = batches.into_iter();
        // Requests still unanswered per pending batch id.
        let mut pending: HashMap<u64, usize> = HashMap::new();
        let mut held: Option<RequestBatch> = None;
        let window = window.max(1);
        loop {
            while pending.len() < window {
                let Some(b) = held.take().or_else(|| batches.next()) else { break };
                let (id, epoch, n) = (b.batch_id, b.epoch, b.requests.len());
                if !self.shared.epochs.lock().unwrap_or_else(|p| p.into_inner()).is_retained(epoch) {
                    return Err(DispatchError::BadEpoch { batch_id: id, epoch, current: self.epoch() });
                }
                if n == 0 {
                    continue; // nothing to shade, nothing will answer
                }
                match self.try_submit(b) {
                    Ok(()) => {
                        pending.insert(id, n);
                    }
                    Err(b) => {
                        // Queue full (shared with nobody else, so our own batches fill it):
                        // wait for answers before offering it again.
                        held = Some(b);
                        break;
                    }
                }
            }
            if pending.is_empty() && held.is_none() {
                return Ok(());
            }
            match tokio::time::timeout(stall, self.next_answer()).await {
                Ok(Some(Answer::Samples { batch, requests, .. })) => {
                    if let Some(left) = pending.get_mut(&batch.batch_id) {
                        *left = left.saturating_sub(requests);
                        if *left == 0 {
                            pending.remove(&batch.batch_id);
                        }
                        on_batch(batch);
                    }
                }
                Ok(Some(Answer::Dropped { batch_id, epoch, .. })) => {
                    if pending.contains_key(&batch_id) {
                        return Err(DispatchError::Dropped { batch_id, epoch });
                    }
                }
                Ok(None) | Err(_) => {
                    return Err(DispatchError::Stalled {
                        stall,
                        pending: pending.len(),
                        live: self.live_workers(),
                        workers: self.workers(),
                    })
                }
            }
        }
    }
}
