//! One link: the async task that keeps one worker busy for one dispatcher (paper 000 §3: the
//! shader computes samples asynchronously; the renderer never waits for it).
//!
//! A link loads the scene on its worker (by content hash), opens a `Shade` stream, and then
//! at once pulls batches from the dispatcher's queues while it holds fewer than its
//! in-flight limit, and forwards every answer to the dispatcher. A batch larger than the
//! worker's batch size (see [`super::rate::BatchSizer`]) is split: the head goes to this
//! worker, the rest back to the dispatcher's retry queue for whichever worker is free next.
//! Before the first batch of an epoch newer than anything it sent, the link sends that
//! epoch's full transform set.
//!
//! Every call has a deadline: `LoadScene` and opening the stream have fixed ones, and a
//! stream whose worker answers nothing for a while with batches in flight (a stopped or
//! wedged process whose TCP connection stays open) counts as failed — after
//! [`stall_allowance`], a few round trips (the other workers' until this one has answered)
//! but at least `PoolOptions::stall_floor`. HTTP/2 keepalive (set on the channel) catches
//! dead connections underneath.
//!
//! When the stream fails, stalls, or the worker leaves the pool, the link puts its in-flight
//! batches back on the retry queue for the other links, and (unless it was stopped) waits —
//! exponential backoff capped at [`MAX_BACKOFF`] — and starts over, scene load included
//! (a restarted worker has lost its cache). A restarted worker is thus back within
//! `MAX_BACKOFF` plus its scene load.
use super::epochs::{EpochAction, SentEpochs};
use super::rate::{BatchSizer, InFlightLimit};
use super::{Answer, PoolMember, Queued, Shared};
use edgepoint_proto::shade_in::Msg as InMsg;
use edgepoint_proto::shade_out::Msg as OutMsg;
use edgepoint_proto::shader_worker_client::ShaderWorkerClient;
use edgepoint_proto::{LoadSceneRequest, SampleBatch, ShadeIn, ShadeOpen, TransformEpoch};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;
use tokio_stream::wrappers::ReceiverStream;

/// Longest wait between reconnection attempts.
pub const MAX_BACKOFF: Duration = Duration::from_secs(1);
const FIRST_BACKOFF: Duration = Duration::from_millis(50);
/// A batch that has gone back to the queue this many times is dropped: a worker that keeps
/// failing on it (e.g. rejects its epoch) must not make it circulate forever.
pub const MAX_ATTEMPTS: u32 = 6;
/// Messages that may wait to be sent on one stream. The in-flight limit bounds batches (and
/// each batch brings at most one epoch message), so this never fills on a healthy stream;
/// a full buffer means the worker stopped reading and the stream is given up.
const SEND_BUFFER: usize = 80;

/// What one link shows the dispatcher (status, tests) while it runs.
#[derive(Debug)]
pub struct LinkState {
    pub url: Arc<str>,
    pub live: AtomicBool,
    pub in_flight_batches: AtomicUsize,
    pub in_flight_requests: AtomicUsize,
    pub in_flight_limit: AtomicUsize,
    pub batch_size: AtomicUsize,
    pub samples: AtomicU64,
    /// Measured samples per busy second, as f64 bits (0 = not measured yet).
    pub rate_bits: AtomicU64,
    /// Streams that failed, stalled or could not be opened.
    pub failures: AtomicU64,
}

impl LinkState {
    pub fn new(url: Arc<str>) -> Self {
        LinkState {
            url,
            live: AtomicBool::new(false),
            in_flight_batches: AtomicUsize::new(0),
            in_flight_requests: AtomicUsize::new(0),
            in_flight_limit: AtomicUsize::new(0),
            batch_size: AtomicUsize::new(0),
            samples: AtomicU64::new(0),
            rate_bits: AtomicU64::new(0),
            failures: AtomicU64::new(0),
        }
    }
}

struct InFlight {
    queued: Queued,
    sent_at: Instant,
    was_alone: bool,
}

/// The batches one link has sent and not had answered, keyed by the id used on the wire
/// (the link's own counter: a split batch's parts share the session's batch id). Keeps the
/// link state and the worker's metrics in step with its contents.
struct InFlightSet<'a> {
    map: HashMap<u64, InFlight>,
    requests: usize,
    state: &'a LinkState,
    member: &'a PoolMember,
}

impl<'a> InFlightSet<'a> {
    fn new(state: &'a LinkState, member: &'a PoolMember) -> Self {
        InFlightSet { map: HashMap::new(), requests: 0, state, member }
    }

    fn len(&self) -> usize {
        self.map.len()
    }

    fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    fn account(&mut self, batches: isize, requests: isize) {
        self.requests = (self.requests as isize + requests) as usize;
        self.state.in_flight_batches.store(self.map.len(), Ordering::Relaxed);
        self.state.in_flight_requests.store(self.requests, Ordering::Relaxed);
        self.member.series.in_flight_batches.add(batches as i64);
        self.member.series.in_flight_requests.add(requests as i64);
    }

    fn insert(&mut self, wire_id: u64, f: InFlight) {
        let n = f.queued.batch.requests.len() as isize;
        self.map.insert(wire_id, f);
        self.account(1, n);
    }

    fn remove(&mut self, wire_id: u64) -> Option<InFlight> {
        let f = self.map.remove(&wire_id)?;
        self.account(-1, -(f.queued.batch.requests.len() as isize));
        Some(f)
    }

    fn oldest_sent(&self) -> Option<Instant> {
        self.map.values().map(|f| f.sent_at).min()
    }

    /// Hands every in-flight batch back to the dispatcher.
    fn requeue_all(&mut self, shared: &Shared, count_attempt: bool) -> usize {
        let ids: Vec<u64> = self.map.keys().copied().collect();
        for id in &ids {
            if let Some(f) = self.remove(*id) {
                requeue(shared, f.queued, count_attempt);
            }
        }
        ids.len()
    }
}

impl Drop for InFlightSet<'_> {
    fn drop(&mut self) {
        // Only reached with batches inside if the link task itself is aborted (the
        // dispatcher is gone, so nobody waits for them); keep the gauges right regardless.
        self.member.series.in_flight_batches.sub(self.map.len() as i64);
        self.member.series.in_flight_requests.sub(self.requests as i64);
    }
}

/// What a link learns about its worker across streams.
struct Tuning {
    limit: InFlightLimit,
    sizer: BatchSizer,
    /// Smoothed round trip of one batch, seconds.
    rtt: Option<f64>,
}

/// How long a stream may go without any answer while batches are in flight before it
/// counts as stalled: four smoothed round trips, within `[floor, cap]`; `first` before any
/// round trip was measured.
pub fn stall_allowance(rtt: Option<f64>, floor: Duration, cap: Duration, first: Duration) -> Duration {
    match rtt {
        Some(r) if r.is_finite() => Duration::from_secs_f64(4.0 * r).clamp(floor, cap.max(floor)),
        _ => first,
    }
}

/// Counts the link as live while a stream is open.
struct LiveGuard<'a> {
    shared: &'a Shared,
    member: &'a PoolMember,
    state: &'a LinkState,
}

impl<'a> LiveGuard<'a> {
    fn new(shared: &'a Shared, member: &'a PoolMember, state: &'a LinkState) -> Self {
        shared.live.fetch_add(1, Ordering::SeqCst);
        member.streams.fetch_add(1, Ordering::SeqCst);
        member.series.streams.inc();
        state.live.store(true, Ordering::SeqCst);
        LiveGuard { shared, member, state }
    }
}

impl Drop for LiveGuard<'_> {
    fn drop(&mut self) {
        self.state.live.store(false, Ordering::SeqCst);
        self.member.series.streams.dec();
        self.member.streams.fetch_sub(1, Ordering::SeqCst);
        self.shared.live.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Why a stream ended.
enum End {
    /// The worker left the pool or the dispatcher is closing.
    Stopped,
    Failed(String),
}

/// Runs the link until `stop` turns true (or its sender is dropped).
pub(super) async fn run(shared: Arc<Shared>, member: Arc<PoolMember>, state: Arc<LinkState>, mut stop: watch::Receiver<bool>) {
    let cfg = &shared.cfg;
    let mut tuning = Tuning {
        limit: InFlightLimit::new(cfg.initial_in_flight, 2, cfg.max_in_flight),
        sizer: BatchSizer::new(cfg.target_batch_time, cfg.min_batch, cfg.max_batch),
        rtt: None,
    };
    let mut inflight = InFlightSet::new(&state, &member);
    let mut backoff = FIRST_BACKOFF;
    let mut failed_attempts = 0u32;
    loop {
        let started = Instant::now();
        let end = tokio::select! {
            e = stream_once(&shared, &member, &state, &mut inflight, &mut tuning) => End::Failed(e),
            _ = stopped(&mut stop) => End::Stopped,
        };
        match end {
            End::Stopped => {
                let n = inflight.requeue_all(&shared, false);
                tracing::info!(worker = %member.url, requeued = n, "worker link stopped");
                return;
            }
            End::Failed(err) => {
                let n = inflight.requeue_all(&shared, true);
                state.failures.fetch_add(1, Ordering::Relaxed);
                member.series.failures.inc();
                // A stream that ran a while was healthy: start the next backoff series afresh.
                if started.elapsed() > Duration::from_secs(2) {
                    backoff = FIRST_BACKOFF;
                    failed_attempts = 0;
                }
                failed_attempts += 1;
                let retry_in_ms = backoff.as_millis() as u64;
                // The first failure of a series is news; the retries that follow are not.
                if failed_attempts == 1 || failed_attempts.is_multiple_of(60) {
                    tracing::warn!(worker = %member.url, requeued = n, retry_in_ms, failed_attempts, "worker link down: {err}");
                } else {
                    tracing::debug!(worker = %member.url, requeued = n, retry_in_ms, failed_attempts, "worker link still down: {err}");
                }
            }
        }
        tokio::select! {
            _ = tokio::time::sleep(backoff) => {}
            _ = stopped(&mut stop) => {
                tracing::info!(worker = %member.url, "worker link stopped");
                return;
            }
        }
        backoff = (backoff * 2).min(MAX_BACKOFF);
    }
}

/// Resolves once the link must stop.
async fn stopped(stop: &mut watch::Receiver<bool>) {
    // A dropped sender also means stop.
    let _ = stop.wait_for(|s| *s).await;
}

/// Puts a batch back on the retry queue (ahead of new work), or drops it after too many
/// failed attempts. A batch whose worker merely left the pool is not charged an attempt.
fn requeue(shared: &Shared, mut q: Queued, count_attempt: bool) {
    if count_attempt {
        q.attempts += 1;
        if q.attempts >= MAX_ATTEMPTS {
            tracing::warn!(batch = q.batch.batch_id, epoch = q.batch.epoch, "dropping a batch that failed {} times", q.attempts);
            shared.answer_dropped(&q);
            return;
        }
    }
    shared.requeued_batches.fetch_add(1, Ordering::Relaxed);
    shared.metrics.requeued_batches.inc();
    shared.push_retry(q);
}

/// Splits off everything past `max` requests of `q` into a new queued part.
fn split(q: &mut Queued, max: usize) -> Option<Queued> {
    if q.batch.requests.len() <= max {
        return None;
    }
    let rest = q.batch.requests.split_off(max);
    let mut batch = edgepoint_proto::RequestBatch { requests: rest, ..Default::default() };
    batch.batch_id = q.batch.batch_id;
    batch.epoch = q.batch.epoch;
    batch.shader = q.batch.shader.clone();
    batch.params = q.batch.params.clone();
    // Shading randomness depends on (seed, request id) only, so the parts shade exactly as
    // the whole batch would have.
    batch.seed = q.batch.seed;
    Some(Queued { batch, attempts: q.attempts, submitted_at: q.submitted_at })
}

/// One connection attempt and stream lifetime. Returns why it ended.
async fn stream_once(
    shared: &Arc<Shared>,
    member: &PoolMember,
    state: &LinkState,
    inflight: &mut InFlightSet<'_>,
    tuning: &mut Tuning,
) -> String {
    let cfg = &shared.cfg;
    let mut client = ShaderWorkerClient::with_interceptor(member.channel.clone(), cfg.worker_token.clone())
        .max_decoding_message_size(cfg.max_message_bytes)
        .max_encoding_message_size(cfg.max_message_bytes);
    let t0 = Instant::now();
    let mut load = tonic::Request::new(LoadSceneRequest { source: Some((*shared.source).clone()), expect_hash: shared.hash.clone() });
    load.set_timeout(cfg.load_timeout);
    let reply = match tokio::time::timeout(cfg.load_timeout + Duration::from_secs(1), client.load_scene(load)).await {
        Ok(Ok(r)) => r.into_inner(),
        Ok(Err(s)) => return format!("LoadScene failed: {}: {}", s.code(), s.message()),
        Err(_) => return format!("LoadScene got no answer within {:?}", cfg.load_timeout),
    };
    if reply.scene_hash != shared.hash {
        return format!("worker built scene {} but {} was asked", reply.scene_hash, shared.hash);
    }
    tracing::debug!(worker = %member.url, hash = %shared.hash, cached = reply.cached, worker_load_ms = reply.load_ms,
        ms = t0.elapsed().as_millis() as u64, "scene loaded on worker");

    let (tx, rx) = tokio::sync::mpsc::channel::<ShadeIn>(SEND_BUFFER);
    let open = ShadeIn { msg: Some(InMsg::Open(ShadeOpen { scene_hash: shared.hash.clone() })) };
    if tx.try_send(open).is_err() {
        return "shade stream closed before opening".into();
    }
    let mut inbound = match tokio::time::timeout(cfg.call_timeout, client.shade(ReceiverStream::new(rx))).await {
        Ok(Ok(r)) => r.into_inner(),
        Ok(Err(s)) => return format!("Shade failed: {}: {}", s.code(), s.message()),
        Err(_) => return format!("Shade got no answer within {:?}", cfg.call_timeout),
    };
    let _live = LiveGuard::new(shared, member, state);
    tracing::debug!(worker = %member.url, "shade stream open");
    let mut sent = SentEpochs::default();
    let mut wire_id = 0u64;
    // When the worker last showed progress: its last answer, or when the link went from
    // idle to busy. The busy mark measures the time the worker had work, for its rate.
    let mut progress_at = Instant::now();
    let mut busy_mark = Instant::now();
    let publish = |tuning: &Tuning| {
        let size = tuning.sizer.next_size();
        state.in_flight_limit.store(tuning.limit.get(), Ordering::Relaxed);
        state.batch_size.store(size, Ordering::Relaxed);
        state.rate_bits.store(tuning.sizer.rate().unwrap_or(0.0).to_bits(), Ordering::Relaxed);
        member.series.in_flight_limit.set(tuning.limit.get() as i64);
        member.series.batch_size.set(size as i64);
    };
    publish(tuning);

    loop {
        let room = inflight.len() < tuning.limit.get();
        let deadline = if inflight.is_empty() {
            None
        } else {
            // Before this worker answered anything, the other workers' round trip (doubled:
            // this one may be slower) is a better guess than the first-answer timeout.
            let rtt = tuning.rtt.or_else(|| shared.rtt().map(|r| 2.0 * r));
            let stall = progress_at + stall_allowance(rtt, cfg.stall_floor, cfg.stall_cap, cfg.first_answer_timeout);
            let hard = inflight.oldest_sent().map(|t| t + cfg.batch_deadline).unwrap_or(stall);
            Some(stall.min(hard))
        };
        let taken = tokio::select! {
            // Answers first: they free in-flight slots and feed the frame loop.
            biased;
            msg = inbound.message() => {
                match msg {
                    Ok(Some(out)) => {
                        if let Some(OutMsg::Samples(b)) = out.msg {
                            let now = Instant::now();
                            answered(shared, member, state, inflight, tuning, b, now.duration_since(busy_mark));
                            progress_at = now;
                            busy_mark = now;
                            publish(tuning);
                        }
                    }
                    Ok(None) => return "worker ended the stream".into(),
                    Err(s) => return format!("stream error: {}: {}", s.code(), s.message()),
                }
                None
            }
            _ = tokio::time::sleep_until(deadline.unwrap_or_else(|| Instant::now() + Duration::from_secs(3600)).into()), if deadline.is_some() => {
                let idle = progress_at.elapsed();
                return format!(
                    "no answer for {} ms with {} batches in flight: worker stalled",
                    idle.as_millis(),
                    inflight.len()
                );
            }
            q = shared.retry_rx.recv_async(), if room => q.ok(),
            q = shared.queue_rx.recv_async(), if room => q.ok(),
        };
        let Some(mut q) = taken else { continue };
        match sent.action(q.batch.epoch) {
            EpochAction::Ready => {}
            EpochAction::SendFirst => {
                let Some(transforms) = shared.epochs.lock().unwrap_or_else(|p| p.into_inner()).get(q.batch.epoch) else {
                    // Too old to reconstruct: nobody can shade it consistently.
                    shared.answer_dropped(&q);
                    continue;
                };
                let msg = ShadeIn {
                    msg: Some(InMsg::Epoch(TransformEpoch { epoch: q.batch.epoch, transforms: transforms.as_ref().clone() })),
                };
                if tx.try_send(msg).is_err() {
                    requeue(shared, q, true);
                    return "the worker stopped reading its stream".into();
                }
                sent.record(q.batch.epoch);
            }
            EpochAction::Unsendable => {
                shared.answer_dropped(&q);
                continue;
            }
        }
        if let Some(rest) = split(&mut q, tuning.sizer.next_size()) {
            shared.outstanding_batches.fetch_add(1, Ordering::SeqCst);
            shared.push_retry(rest);
        }
        wire_id += 1;
        let wire = to_wire(&q.batch, wire_id);
        let was_alone = inflight.is_empty();
        if tx.try_send(ShadeIn { msg: Some(InMsg::Batch(wire)) }).is_err() {
            requeue(shared, q, true);
            return "the worker stopped reading its stream".into();
        }
        let now = Instant::now();
        if was_alone {
            progress_at = now;
            busy_mark = now;
        }
        inflight.insert(wire_id, InFlight { queued: q, sent_at: now, was_alone });
    }
}

/// The batch as it goes to the worker: under its per-link id, its requests packed
/// (`edgepoint_proto::packed`: the worker answers with packed samples, which the renderer
/// reads at a fraction of the protobuf decoding's cost).
fn to_wire(b: &edgepoint_proto::RequestBatch, wire_id: u64) -> edgepoint_proto::RequestBatch {
    let mut wire = edgepoint_proto::RequestBatch {
        batch_id: wire_id,
        epoch: b.epoch,
        shader: b.shader.clone(),
        params: b.params.clone(),
        requests: Vec::new(),
        seed: b.seed,
        packed_requests: Vec::new(),
    };
    edgepoint_proto::packed::pack_requests(&b.requests, &mut wire.packed_requests);
    wire
}

fn answered(
    shared: &Shared,
    member: &PoolMember,
    state: &LinkState,
    inflight: &mut InFlightSet<'_>,
    tuning: &mut Tuning,
    mut b: SampleBatch,
    busy: Duration,
) {
    if let Err(e) = edgepoint_proto::packed::unpack_sample_batch(&mut b) {
        // Counted below as an answer with the wrong number of samples.
        tracing::warn!(worker = %member.url, batch = b.batch_id, "unreadable answer: {e}");
        b.packed_samples = Vec::new();
    }
    let Some(f) = inflight.remove(b.batch_id) else {
        tracing::debug!(worker = %member.url, batch = b.batch_id, "answer for a batch this link does not hold");
        return;
    };
    let now = Instant::now();
    let rtt = now.duration_since(f.sent_at);
    let requests = f.queued.batch.requests.len();
    if b.samples.len() != requests {
        tracing::warn!(worker = %member.url, got = b.samples.len(), asked = requests, "worker answered a batch with the wrong number of samples");
    }
    tuning.limit.observe(rtt, b.shade_ms, f.was_alone);
    tuning.sizer.observe(b.samples.len() as u64, busy);
    tuning.rtt = Some(match tuning.rtt {
        Some(r) => 0.8 * r + 0.2 * rtt.as_secs_f64(),
        None => rtt.as_secs_f64(),
    });
    shared.observe_rtt(rtt);
    let n = b.samples.len() as u64;
    state.samples.fetch_add(n, Ordering::Relaxed);
    member.series.samples.inc_by(n);
    shared.record_samples(now, n);
    let latency = now.duration_since(f.queued.submitted_at);
    shared.metrics.batch_latency.observe(latency.as_secs_f64());
    b.batch_id = f.queued.batch.batch_id;
    shared.settle(&f.queued.batch);
    let _ = shared.answers_tx.send(Answer::Samples { batch: b, requests, latency, worker: member.url.clone() });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stall_allowance_is_a_few_round_trips_within_bounds() {
        let (floor, cap, first) = (Duration::from_secs(1), Duration::from_secs(10), Duration::from_secs(30));
        assert_eq!(stall_allowance(None, floor, cap, first), first);
        assert_eq!(stall_allowance(Some(0.010), floor, cap, first), floor);
        assert_eq!(stall_allowance(Some(0.5), floor, cap, first), Duration::from_secs(2));
        assert_eq!(stall_allowance(Some(100.0), floor, cap, first), cap);
        assert_eq!(stall_allowance(Some(f64::NAN), floor, cap, first), first);
    }

    #[test]
    fn split_keeps_the_head_and_hands_back_the_rest() {
        let reqs = (0..10).map(|i| edgepoint_proto::ShadeRequest { id: i, ..Default::default() }).collect();
        let batch = edgepoint_proto::RequestBatch { batch_id: 7, epoch: 3, shader: "direct".into(), requests: reqs, seed: 99, ..Default::default() };
        let mut q = Queued { batch, attempts: 2, submitted_at: Instant::now() };
        assert!(split(&mut q, 10).is_none());
        let rest = split(&mut q, 4).unwrap();
        assert_eq!(q.batch.requests.iter().map(|r| r.id).collect::<Vec<_>>(), [0, 1, 2, 3]);
        assert_eq!(rest.batch.requests.iter().map(|r| r.id).collect::<Vec<_>>(), [4, 5, 6, 7, 8, 9]);
        assert_eq!((rest.batch.batch_id, rest.batch.epoch, rest.batch.seed, rest.attempts), (7, 3, 99, 2));
        assert_eq!(rest.batch.shader, "direct");
    }
}
