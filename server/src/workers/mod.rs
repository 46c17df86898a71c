//! The shader-worker pool: asynchronous request dispatch with back-pressure (paper 000 §3:
//! "the shader asynchronously finds visible points and computes their color"; DESIGN.md
//! "Threads" and "Budget").
//!
//! A [`WorkerPool`] holds one lazily connected gRPC channel per worker address (HTTP/2
//! keepalive, connect timeout, large messages since scenes travel as bytes). For every
//! render session (or reference render, or benchmark) [`WorkerPool::open`] makes a
//! [`Dispatcher`]: one async link task per worker (see `link`), a shared multi-consumer
//! queue of request batches, and an answer queue.
//!
//! The dispatcher's methods never block and never await, so the frame-loop thread calls
//! them directly: [`Dispatcher::submit`] queues a batch (or refuses when the queue is full),
//! [`Dispatcher::set_epoch`] announces moved objects, [`Dispatcher::drain`] takes every
//! answer that arrived. Every worker pulls from the same queue while it holds fewer batches
//! than its in-flight limit, so faster workers take proportionally more. A worker that fails
//! hands its in-flight batches back to the queue, so no request is lost while another
//! worker lives; a batch that can no longer be shaded consistently (its epoch is gone) is
//! dropped and counted as answered so the outstanding count never leaks.
//!
//! Outside a session, await answers with [`Dispatcher::next_answer`] or let
//! [`Dispatcher::shade_all`] submit a whole job and collect it (the reference renderer and
//! the benchmarks do this).
mod epochs;
mod link;
mod rate;

pub use epochs::{EpochTable, RETAINED_EPOCHS, WORKER_KEEPS};
pub use link::{MAX_ATTEMPTS, MAX_BACKOFF};
pub use rate::{InFlightLimit, RateMeter};

use edgepoint_proto::shader_worker_client::ShaderWorkerClient;
use edgepoint_proto::{InfoRequest, RequestBatch, SampleBatch, SceneSource};
use glam::Affine3A;
use std::collections::HashSet;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::runtime::Handle;
use tokio::task::JoinHandle;
use tonic::transport::{Channel, Endpoint};

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
    /// Batches the shared queue of each dispatcher holds before `submit` refuses more.
    pub queue_batches: usize,
    /// In-flight batches per worker before the first measurement, and the cap.
    pub initial_in_flight: usize,
    pub max_in_flight: usize,
}

impl Default for PoolOptions {
    fn default() -> Self {
        PoolOptions {
            max_message_bytes: DEFAULT_MAX_MESSAGE_BYTES,
            connect_timeout: Duration::from_secs(2),
            keepalive_interval: Duration::from_secs(5),
            keepalive_timeout: Duration::from_secs(10),
            queue_batches: 1024,
            initial_in_flight: 4,
            max_in_flight: 16,
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

struct Worker {
    url: String,
    channel: Channel,
}

/// The configured shader workers. Cheap to share (`Arc`); sessions share its channels.
pub struct WorkerPool {
    workers: Vec<Worker>,
    runtime: Handle,
    opts: PoolOptions,
}

impl WorkerPool {
    /// A pool over `endpoints` (`http://host:port` or `host:port`) with default options.
    /// Must be called inside a tokio runtime: links are spawned on it. Nothing connects
    /// until a dispatcher is opened.
    pub fn new(endpoints: Vec<String>) -> Result<Self, PoolError> {
        Self::with_options(endpoints, PoolOptions::default())
    }

    pub fn with_options(endpoints: Vec<String>, opts: PoolOptions) -> Result<Self, PoolError> {
        let runtime = Handle::try_current().map_err(|_| PoolError::NoRuntime)?;
        let mut workers = Vec::with_capacity(endpoints.len());
        for addr in endpoints {
            let url = normalize_endpoint(&addr);
            let ep = Endpoint::from_shared(url.clone())
                .map_err(|e| PoolError::BadAddress { addr: addr.clone(), reason: e.to_string() })?;
            if ep.uri().host().is_none() || ep.uri().port_u16().is_none() {
                return Err(PoolError::BadAddress { addr, reason: "needs host and port".into() });
            }
            let ep = ep
                .connect_timeout(opts.connect_timeout)
                .http2_keep_alive_interval(opts.keepalive_interval)
                .keep_alive_timeout(opts.keepalive_timeout)
                .keep_alive_while_idle(true)
                .tcp_nodelay(true)
                .http2_adaptive_window(true);
            let channel = {
                let _g = runtime.enter();
                ep.connect_lazy()
            };
            workers.push(Worker { url, channel });
        }
        Ok(WorkerPool { workers, runtime, opts })
    }

    pub fn len(&self) -> usize {
        self.workers.len()
    }

    pub fn is_empty(&self) -> bool {
        self.workers.is_empty()
    }

    pub fn endpoints(&self) -> Vec<String> {
        self.workers.iter().map(|w| w.url.clone()).collect()
    }

    pub fn options(&self) -> &PoolOptions {
        &self.opts
    }

    /// The shaders the workers offer (union over the workers that answer `Info` within
    /// `timeout`), or `None` when no worker answered.
    pub async fn shaders(&self, timeout: Duration) -> Option<Vec<String>> {
        let mut set = tokio::task::JoinSet::new();
        for w in &self.workers {
            let mut client = ShaderWorkerClient::new(w.channel.clone());
            set.spawn_on(async move { tokio::time::timeout(timeout, client.info(InfoRequest {})).await }, &self.runtime);
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

    /// Starts one link per worker for the scene `source` whose content hash is `hash`
    /// (`edgepoint_proto::scene_hash(&source)`). The dispatcher starts at epoch 0 (every
    /// object at its scene default). Dropping the dispatcher stops the links.
    pub fn open(&self, source: SceneSource, hash: String) -> Dispatcher {
        let (queue_tx, queue_rx) = flume::unbounded();
        let (answers_tx, answers_rx) = flume::unbounded();
        let shared = Arc::new(Shared {
            source: Arc::new(source),
            hash,
            cfg: self.opts.clone(),
            queue_tx,
            queue_rx,
            answers_tx,
            answers_rx,
            epochs: Mutex::new(EpochTable::default()),
            outstanding_requests: AtomicU64::new(0),
            outstanding_batches: AtomicU64::new(0),
            live: AtomicUsize::new(0),
            rate: Mutex::new(RateMeter::new(Duration::from_secs(2))),
            requeued_batches: AtomicU64::new(0),
            dropped_batches: AtomicU64::new(0),
            answered_batches: AtomicU64::new(0),
        });
        let tasks = self
            .workers
            .iter()
            .map(|w| self.runtime.spawn(link::run(shared.clone(), w.channel.clone(), w.url.clone())))
            .collect();
        Dispatcher { shared, tasks, workers: self.workers.len() }
    }
}

/// A queued batch and how often it went back to the queue.
pub(crate) struct Queued {
    pub batch: RequestBatch,
    pub attempts: u32,
}

/// What comes back for a submitted batch.
#[derive(Debug)]
pub enum Answer {
    /// The worker's samples.
    Samples(SampleBatch),
    /// The batch was given up: its epoch can no longer be sent to any worker stream, or it
    /// failed [`MAX_ATTEMPTS`] times. It no longer counts as outstanding.
    Dropped { batch_id: u64, epoch: u64 },
}

/// State shared between a dispatcher and its links.
pub(crate) struct Shared {
    pub source: Arc<SceneSource>,
    pub hash: String,
    pub cfg: PoolOptions,
    pub queue_tx: flume::Sender<Queued>,
    pub queue_rx: flume::Receiver<Queued>,
    pub answers_tx: flume::Sender<Answer>,
    pub answers_rx: flume::Receiver<Answer>,
    pub epochs: Mutex<EpochTable>,
    pub outstanding_requests: AtomicU64,
    pub outstanding_batches: AtomicU64,
    pub live: AtomicUsize,
    pub rate: Mutex<RateMeter>,
    pub requeued_batches: AtomicU64,
    pub dropped_batches: AtomicU64,
    pub answered_batches: AtomicU64,
}

impl Shared {
    /// A batch left the system (answered or dropped).
    pub fn settle(&self, b: &RequestBatch) {
        self.outstanding_requests.fetch_sub(b.requests.len() as u64, Ordering::SeqCst);
        self.outstanding_batches.fetch_sub(1, Ordering::SeqCst);
        self.answered_batches.fetch_add(1, Ordering::Relaxed);
    }

    pub fn answer_dropped(&self, q: &Queued) {
        self.dropped_batches.fetch_add(1, Ordering::Relaxed);
        self.settle(&q.batch);
        let _ = self.answers_tx.send(Answer::Dropped { batch_id: q.batch.batch_id, epoch: q.batch.epoch });
    }
}

/// Counters of one dispatcher since it opened.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DispatchStats {
    /// Batches answered or dropped.
    pub settled_batches: u64,
    /// Batches given up (see [`Answer::Dropped`]).
    pub dropped_batches: u64,
    /// Batches handed back to the queue by a failing worker link.
    pub requeued_batches: u64,
    /// Samples received.
    pub samples: u64,
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
    tasks: Vec<JoinHandle<()>>,
    workers: usize,
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

    /// [`Dispatcher::submit`] that hands a refused batch back.
    pub fn try_submit(&self, batch: RequestBatch) -> Result<(), RequestBatch> {
        if self.shared.queue_rx.len() >= self.shared.cfg.queue_batches {
            return Err(batch);
        }
        if !self.shared.epochs.lock().unwrap_or_else(|p| p.into_inner()).is_retained(batch.epoch) {
            return Err(batch);
        }
        self.shared.outstanding_requests.fetch_add(batch.requests.len() as u64, Ordering::SeqCst);
        self.shared.outstanding_batches.fetch_add(1, Ordering::SeqCst);
        // Unbounded underneath (capacity is checked above), so this cannot block; it fails
        // only if every receiver is gone, which the dispatcher itself prevents.
        if let Err(e) = self.shared.queue_tx.send(Queued { batch, attempts: 0 }) {
            let q = e.into_inner();
            self.shared.outstanding_requests.fetch_sub(q.batch.requests.len() as u64, Ordering::SeqCst);
            self.shared.outstanding_batches.fetch_sub(1, Ordering::SeqCst);
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
            if let Answer::Samples(b) = a {
                out.push(b);
            }
        }
        out.len() - before
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

    pub fn outstanding_batches(&self) -> u64 {
        self.shared.outstanding_batches.load(Ordering::SeqCst)
    }

    /// Batches waiting in the queue for a worker.
    pub fn queued_batches(&self) -> usize {
        self.shared.queue_rx.len()
    }

    /// Workers with an open shade stream for this scene right now.
    pub fn live_workers(&self) -> usize {
        self.shared.live.load(Ordering::SeqCst)
    }

    /// Workers configured.
    pub fn workers(&self) -> usize {
        self.workers
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
    /// the queue refuses), hands every answer to `on_batch` as it arrives, and returns when
    /// all are answered. Fails if a batch is dropped (its epoch was superseded meanwhile) or
    /// nothing arrives for `stall` (e.g. every worker is down). The caller must be this
    /// dispatcher's only consumer of answers while it runs.
    pub async fn shade_all<I, F>(&self, batches: I, window: usize, stall: Duration, mut on_batch: F) -> Result<(), DispatchError>
    where
        I: IntoIterator<Item = RequestBatch>,
        F: FnMut(SampleBatch),
    {
        let mut batches = batches.into_iter();
        let mut pending: HashSet<u64> = HashSet::new();
        let mut held: Option<RequestBatch> = None;
        let window = window.max(1);
        loop {
            while pending.len() < window {
                let Some(b) = held.take().or_else(|| batches.next()) else { break };
                let (id, epoch) = (b.batch_id, b.epoch);
                if !self.shared.epochs.lock().unwrap_or_else(|p| p.into_inner()).is_retained(epoch) {
                    return Err(DispatchError::BadEpoch { batch_id: id, epoch, current: self.epoch() });
                }
                match self.try_submit(b) {
                    Ok(()) => {
                        pending.insert(id);
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
                Ok(Some(Answer::Samples(b))) => {
                    if pending.remove(&b.batch_id) {
                        on_batch(b);
                    }
                }
                Ok(Some(Answer::Dropped { batch_id, epoch })) => {
                    if pending.contains(&batch_id) {
                        return Err(DispatchError::Dropped { batch_id, epoch });
                    }
                }
                Ok(None) | Err(_) => {
                    return Err(DispatchError::Stalled {
                        stall,
                        pending: pending.len(),
                        live: self.live_workers(),
                        workers: self.workers,
                    })
                }
            }
        }
    }
}

impl Drop for Dispatcher {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}
