//! One link: the async task that keeps one worker busy for one dispatcher (paper 000 §3: the
//! shader computes samples asynchronously; the renderer never waits for it).
//!
//! A link loads the scene on its worker (by content hash), opens a `Shade` stream, and then
//! at once pulls batches from the dispatcher's shared queue while it holds fewer than its
//! in-flight limit, and forwards every answer to the dispatcher. Before the first batch of
//! an epoch newer than anything it sent, it sends that epoch's full transform set. When the
//! stream fails the link puts its in-flight batches back on the queue for the other links,
//! waits (exponential backoff capped at [`MAX_BACKOFF`]) and starts over, scene load
//! included (the worker may have restarted and lost its cache).
use super::epochs::{EpochAction, SentEpochs};
use super::rate::InFlightLimit;
use super::{Answer, Queued, Shared};
use edgepoint_proto::shade_in::Msg as InMsg;
use edgepoint_proto::shade_out::Msg as OutMsg;
use edgepoint_proto::shader_worker_client::ShaderWorkerClient;
use edgepoint_proto::{LoadSceneRequest, SampleBatch, ShadeIn, ShadeOpen, TransformEpoch};
use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_stream::wrappers::ReceiverStream;
use tonic::transport::Channel;

/// Longest wait between reconnection attempts.
pub const MAX_BACKOFF: Duration = Duration::from_secs(1);
const FIRST_BACKOFF: Duration = Duration::from_millis(50);
/// A batch that has gone back to the queue this many times is dropped: a worker that keeps
/// failing on it (e.g. rejects its epoch) must not make it circulate forever.
pub const MAX_ATTEMPTS: u32 = 6;

struct InFlight {
    queued: Queued,
    sent_at: Instant,
    was_alone: bool,
}

/// Counts the link as live while a stream is open.
struct LiveGuard<'a>(&'a Shared);
impl Drop for LiveGuard<'_> {
    fn drop(&mut self) {
        self.0.live.fetch_sub(1, Ordering::SeqCst);
    }
}

pub(super) async fn run(shared: Arc<Shared>, channel: Channel, endpoint: String) {
    let mut backoff = FIRST_BACKOFF;
    let mut inflight: HashMap<u64, InFlight> = HashMap::new();
    let mut limit = InFlightLimit::new(shared.cfg.initial_in_flight, 2, shared.cfg.max_in_flight);
    loop {
        let started = Instant::now();
        let err = stream_once(&shared, channel.clone(), &mut inflight, &mut limit).await;
        let n = inflight.len();
        for (_, f) in inflight.drain() {
            requeue(&shared, f.queued);
        }
        // A stream that ran a while was healthy: start the next backoff series afresh.
        if started.elapsed() > Duration::from_secs(2) {
            backoff = FIRST_BACKOFF;
        }
        tracing::warn!(worker = %endpoint, requeued = n, retry_in_ms = backoff.as_millis() as u64, "worker link down: {err}");
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(MAX_BACKOFF);
    }
}

/// Puts a batch back on the shared queue, or drops it after too many attempts.
fn requeue(shared: &Shared, mut q: Queued) {
    q.attempts += 1;
    if q.attempts >= MAX_ATTEMPTS {
        tracing::warn!(batch = q.batch.batch_id, epoch = q.batch.epoch, "dropping a batch that failed {} times", q.attempts);
        shared.answer_dropped(&q);
        return;
    }
    shared.requeued_batches.fetch_add(1, Ordering::Relaxed);
    // The queue is unbounded underneath (its capacity is enforced at submit), so this only
    // fails when the dispatcher is gone, and then nobody waits for the batch.
    let _ = shared.queue_tx.send(q);
}

/// One connection attempt and stream lifetime. Returns why it ended.
async fn stream_once(
    shared: &Arc<Shared>,
    channel: Channel,
    inflight: &mut HashMap<u64, InFlight>,
    limit: &mut InFlightLimit,
) -> String {
    let mut client = ShaderWorkerClient::new(channel)
        .max_decoding_message_size(shared.cfg.max_message_bytes)
        .max_encoding_message_size(shared.cfg.max_message_bytes);
    let t0 = Instant::now();
    let load = LoadSceneRequest { source: Some((*shared.source).clone()), expect_hash: shared.hash.clone() };
    let reply = match client.load_scene(load).await {
        Ok(r) => r.into_inner(),
        Err(s) => return format!("LoadScene failed: {}: {}", s.code(), s.message()),
    };
    if reply.scene_hash != shared.hash {
        return format!("worker built scene {} but {} was asked", reply.scene_hash, shared.hash);
    }
    tracing::debug!(hash = %shared.hash, cached = reply.cached, worker_load_ms = reply.load_ms,
        ms = t0.elapsed().as_millis() as u64, "scene loaded on worker");

    let (tx, rx) = tokio::sync::mpsc::channel::<ShadeIn>(64);
    let open = ShadeIn { msg: Some(InMsg::Open(ShadeOpen { scene_hash: shared.hash.clone() })) };
    if tx.send(open).await.is_err() {
        return "shade stream closed before opening".into();
    }
    let mut inbound = match client.shade(ReceiverStream::new(rx)).await {
        Ok(r) => r.into_inner(),
        Err(s) => return format!("Shade failed: {}: {}", s.code(), s.message()),
    };
    shared.live.fetch_add(1, Ordering::SeqCst);
    let _live = LiveGuard(shared);
    let mut sent = SentEpochs::default();

    loop {
        tokio::select! {
            // Answers first: they free in-flight slots and feed the frame loop.
            biased;
            msg = inbound.message() => match msg {
                Ok(Some(out)) => {
                    if let Some(OutMsg::Samples(b)) = out.msg {
                        answered(shared, inflight, limit, b);
                    }
                }
                Ok(None) => return "worker ended the stream".into(),
                Err(s) => return format!("stream error: {}: {}", s.code(), s.message()),
            },
            q = shared.queue_rx.recv_async(), if inflight.len() < limit.get() => {
                // The dispatcher holds a sender for as long as this task lives.
                let Ok(q) = q else { return "dispatcher gone".into() };
                match sent.action(q.batch.epoch) {
                    EpochAction::Ready => {}
                    EpochAction::SendFirst => {
                        let Some(transforms) = shared.epochs.lock().unwrap_or_else(|p| p.into_inner()).get(q.batch.epoch) else {
                            // Too old to reconstruct: nobody can shade it consistently.
                            shared.answer_dropped(&q);
                            continue;
                        };
                        let msg = ShadeIn { msg: Some(InMsg::Epoch(TransformEpoch {
                            epoch: q.batch.epoch,
                            transforms: transforms.as_ref().clone(),
                        })) };
                        if tx.send(msg).await.is_err() {
                            requeue(shared, q);
                            return "shade stream closed".into();
                        }
                        sent.record(q.batch.epoch);
                    }
                    EpochAction::Unsendable => {
                        shared.answer_dropped(&q);
                        continue;
                    }
                }
                let msg = ShadeIn { msg: Some(InMsg::Batch(q.batch.clone())) };
                let was_alone = inflight.is_empty();
                let id = q.batch.batch_id;
                if tx.send(msg).await.is_err() {
                    requeue(shared, q);
                    return "shade stream closed".into();
                }
                if let Some(prev) = inflight.insert(id, InFlight { queued: q, sent_at: Instant::now(), was_alone }) {
                    // Two outstanding batches with one id: the caller broke the contract;
                    // the older one can no longer be told apart, so it counts as dropped.
                    shared.answer_dropped(&prev.queued);
                }
            }
        }
    }
}

fn answered(shared: &Shared, inflight: &mut HashMap<u64, InFlight>, limit: &mut InFlightLimit, b: SampleBatch) {
    let Some(f) = inflight.remove(&b.batch_id) else {
        tracing::debug!(batch = b.batch_id, "answer for a batch this link does not hold");
        return;
    };
    let now = Instant::now();
    limit.observe(now.duration_since(f.sent_at), b.shade_ms, f.was_alone);
    shared.rate.lock().unwrap_or_else(|p| p.into_inner()).record(now, b.samples.len() as u64);
    shared.settle(&f.queued.batch);
    let _ = shared.answers_tx.send(Answer::Samples(b));
}
