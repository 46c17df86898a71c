//! Dispatcher tests against a scripted worker that follows the ShaderWorker contract exactly
//! (scene by hash, epochs only increase, a batch of an epoch never sent ends the stream with
//! FAILED_PRECONDITION) and can be told to fail. It answers each request with values that
//! reveal what the worker held: rgb = (batch epoch, number of transforms in force, the
//! x translation of object 0), so the tests can check that every batch was shaded under
//! the transforms of its own epoch.
use edgepoint_proto as pb;
use edgepoint_proto::shade_in::Msg as In;
use edgepoint_proto::shader_worker_server::{ShaderWorker, ShaderWorkerServer};
use edgepoint_server::workers::{Answer, DispatchError, PoolOptions, Resolve, WorkerPool, WorkerSources};
use glam::{Affine3A, Vec3};
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio_stream::wrappers::{ReceiverStream, TcpListenerStream};
use tonic::{Request, Response, Status, Streaming};

#[derive(Default)]
struct Script {
    /// Batches to answer (over all streams) before failing one stream; negative = never.
    fail_after: AtomicI64,
    loads: AtomicUsize,
    batches: AtomicUsize,
    delay_ms: u64,
    /// Extra shading time per request, in microseconds.
    per_request_us: u64,
    /// While set, batches are read but never answered (the stream and connection stay up,
    /// as with a wedged process).
    hang: AtomicBool,
    /// Smallest batch seen.
    min_batch: AtomicUsize,
}

struct ScriptedWorker {
    hash: String,
    script: Arc<Script>,
}

#[tonic::async_trait]
impl ShaderWorker for ScriptedWorker {
    async fn load_scene(&self, r: Request<pb::LoadSceneRequest>) -> Result<Response<pb::LoadSceneReply>, Status> {
        self.script.loads.fetch_add(1, Ordering::SeqCst);
        let src = r.into_inner().source.ok_or_else(|| Status::invalid_argument("no source"))?;
        let hash = pb::scene_hash(&src);
        if hash != self.hash {
            return Err(Status::invalid_argument("unexpected scene"));
        }
        Ok(Response::new(pb::LoadSceneReply { scene_hash: hash, objects: 2, triangles: 2, cached: true, load_ms: 0.0 }))
    }

    type ShadeStream = ReceiverStream<Result<pb::ShadeOut, Status>>;

    async fn shade(&self, r: Request<Streaming<pb::ShadeIn>>) -> Result<Response<Self::ShadeStream>, Status> {
        let mut inb = r.into_inner();
        let (tx, rx) = tokio::sync::mpsc::channel(64);
        let hash = self.hash.clone();
        let script = self.script.clone();
        tokio::spawn(async move {
            match inb.message().await {
                Ok(Some(pb::ShadeIn { msg: Some(In::Open(o)) })) if o.scene_hash == hash => {}
                _ => {
                    let _ = tx.send(Err(Status::not_found("open an unknown scene"))).await;
                    return;
                }
            }
            let mut epochs: BTreeMap<u64, Vec<pb::ObjectTransform>> = BTreeMap::new();
            while let Ok(Some(m)) = inb.message().await {
                match m.msg {
                    Some(In::Epoch(e)) => {
                        if epochs.keys().next_back().is_some_and(|&last| e.epoch <= last) {
                            let _ = tx.send(Err(Status::failed_precondition("epochs must increase"))).await;
                            return;
                        }
                        epochs.insert(e.epoch, e.transforms);
                        while epochs.len() > 8 {
                            epochs.pop_first();
                        }
                    }
                    Some(In::Batch(mut b)) => {
                        // The renderer sends packed requests; this worker answers with
                        // unpacked samples, which the renderer reads as well.
                        pb::packed::unpack_request_batch(&mut b).expect("well-formed packed requests");
                        let Some(t) = epochs.get(&b.epoch) else {
                            let _ = tx.send(Err(Status::failed_precondition(format!("epoch {} never sent", b.epoch)))).await;
                            return;
                        };
                        if script.fail_after.fetch_sub(1, Ordering::SeqCst) == 0 {
                            let _ = tx.send(Err(Status::unavailable("scripted failure"))).await;
                            return;
                        }
                        if script.hang.load(Ordering::SeqCst) {
                            continue;
                        }
                        script.min_batch.fetch_min(b.requests.len(), Ordering::SeqCst);
                        let delay = Duration::from_millis(script.delay_ms) + Duration::from_micros(script.per_request_us * b.requests.len() as u64);
                        if !delay.is_zero() {
                            tokio::time::sleep(delay).await;
                        }
                        script.batches.fetch_add(1, Ordering::SeqCst);
                        let x0 = t
                            .iter()
                            .find(|o| o.object_id == 0)
                            .and_then(|o| o.transform.as_ref())
                            .map(|a| pb::affine_from_wire(a).unwrap().translation.x)
                            .unwrap_or(0.0);
                        let samples = b
                            .requests
                            .iter()
                            .map(|q| pb::Sample {
                                id: q.id,
                                hit: true,
                                position: q.origin,
                                normal: Some(Vec3::Z.into()),
                                object_id: 0,
                                distance: 1.0,
                                rgb: Some(Vec3::new(b.epoch as f32, t.len() as f32, x0).into()),
                                triangle: 0,
                                local_position: q.origin,
                                local_normal: Some(Vec3::Z.into()),
                                part: q.part,
                            })
                            .collect();
                        let out = pb::SampleBatch { batch_id: b.batch_id, epoch: b.epoch, samples, shade_ms: 0.1, ..Default::default() };
                        if tx.send(Ok(pb::ShadeOut { msg: Some(pb::shade_out::Msg::Samples(out)) })).await.is_err() {
                            return;
                        }
                    }
                    _ => {}
                }
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }

    async fn info(&self, _: Request<pb::InfoRequest>) -> Result<Response<pb::InfoReply>, Status> {
        Ok(Response::new(pb::InfoReply { shaders: vec!["direct".into()], threads: 1, ..Default::default() }))
    }
}

async fn spawn_worker(hash: &str, script: Arc<Script>) -> String {
    spawn_worker_on(hash, script, "127.0.0.1:0").await
}

async fn spawn_worker_on(hash: &str, script: Arc<Script>, addr: &str) -> String {
    let listener = tokio::net::TcpListener::bind(addr).await.unwrap();
    let addr = listener.local_addr().unwrap();
    let svc = ShaderWorkerServer::new(ScriptedWorker { hash: hash.to_string(), script });
    tokio::spawn(tonic::transport::Server::builder().add_service(svc).serve_with_incoming(TcpListenerStream::new(listener)));
    addr.to_string() // host:port, no scheme: the pool must accept it
}

fn source() -> (pb::SceneSource, String) {
    let s = pb::builtin_source("cornell");
    let h = pb::scene_hash(&s);
    (s, h)
}

fn batch(id: u64, epoch: u64, n: u64) -> pb::RequestBatch {
    pb::RequestBatch {
        batch_id: id,
        epoch,
        shader: "direct".into(),
        requests: (0..n)
            .map(|i| pb::ShadeRequest {
                id: id * 1000 + i,
                pixel_x: i as u32,
                pixel_y: 0,
                origin: Some(Vec3::new(i as f32, 0.0, 0.0).into()),
                direction: Some(Vec3::NEG_Z.into()),
                ..Default::default()
            })
            .collect(),
        ..Default::default()
    }
}

fn script(fail_after: i64, delay_ms: u64) -> Arc<Script> {
    Arc::new(Script { fail_after: AtomicI64::new(fail_after), delay_ms, min_batch: AtomicUsize::new(usize::MAX), ..Default::default() })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_batch_is_answered_once_across_workers() {
    let (src, hash) = source();
    let (a, b) = (script(-1, 1), script(-1, 1));
    let urls = vec![spawn_worker(&hash, a.clone()).await, format!("http://{}", spawn_worker(&hash, b.clone()).await)];
    let pool = WorkerPool::new(urls).unwrap();
    let d = pool.open(src, hash);
    let mut seen = HashMap::new();
    d.shade_all((0..200).map(|i| batch(i, 0, 8)), 32, Duration::from_secs(10), |sb| {
        assert_eq!(sb.samples.len(), 8);
        for s in &sb.samples {
            assert_eq!(s.id / 1000, sb.batch_id, "sample ids stay with their batch");
        }
        *seen.entry(sb.batch_id).or_insert(0) += 1;
    })
    .await
    .unwrap();
    assert_eq!(seen.len(), 200);
    assert!(seen.values().all(|&n| n == 1));
    assert_eq!(d.outstanding_requests(), 0);
    assert_eq!(d.outstanding_batches(), 0);
    assert_eq!(d.live_workers(), 2);
    let (na, nb) = (a.batches.load(Ordering::SeqCst), b.batches.load(Ordering::SeqCst));
    assert_eq!(na + nb, 200);
    assert!(na > 0 && nb > 0, "both workers took work ({na}, {nb})");
    assert!(d.samples_per_second() > 0.0);
    assert_eq!(d.stats().samples, 1600);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failing_worker_hands_its_batches_to_the_other() {
    let (src, hash) = source();
    // Worker A fails its stream on its 5th batch (with others in flight behind it).
    let (a, b) = (script(4, 2), script(-1, 2));
    let urls = vec![spawn_worker(&hash, a.clone()).await, spawn_worker(&hash, b.clone()).await];
    let pool = WorkerPool::new(urls).unwrap();
    let d = pool.open(src, hash);
    let mut seen = HashMap::new();
    d.shade_all((0..120).map(|i| batch(i, 0, 4)), 24, Duration::from_secs(10), |sb| {
        *seen.entry(sb.batch_id).or_insert(0) += 1;
    })
    .await
    .unwrap();
    assert_eq!(seen.len(), 120, "no batch lost");
    assert!(seen.values().all(|&n| n == 1), "no batch answered twice");
    assert!(d.stats().requeued_batches > 0, "the failed link's batches went back to the queue");
    assert_eq!(d.outstanding_requests(), 0);
    assert!(a.loads.load(Ordering::SeqCst) >= 2, "the failed link reconnected and reloaded the scene");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn batches_are_shaded_under_their_own_epoch() {
    let (src, hash) = source();
    let w = script(-1, 0);
    let pool = WorkerPool::new(vec![spawn_worker(&hash, w).await]).unwrap();
    let d = pool.open(src, hash);
    assert!(d.set_epoch(1, vec![(0, Affine3A::from_translation(Vec3::new(2.0, 0.0, 0.0)))]));
    assert!(d.set_epoch(2, vec![(1, Affine3A::from_translation(Vec3::Y))]));
    assert!(!d.set_epoch(2, vec![]), "epochs only increase");
    // Epochs in increasing order on one stream: each batch sees its own full transform set.
    let mut got = HashMap::new();
    let batches = vec![batch(1, 0, 2), batch(2, 1, 2), batch(3, 2, 2)];
    d.shade_all(batches, 1, Duration::from_secs(10), |sb| {
        got.insert(sb.batch_id, pb::vec3_or_zero(&sb.samples[0].rgb));
    })
    .await
    .unwrap();
    assert_eq!(got[&1], Vec3::new(0.0, 0.0, 0.0));
    assert_eq!(got[&2], Vec3::new(1.0, 1.0, 2.0), "object 0 moved at epoch 1");
    assert_eq!(got[&3], Vec3::new(2.0, 2.0, 2.0), "epoch 2 keeps object 0's move and adds object 1's");
    // Epoch 1 was sent on this stream and is still held: usable.
    d.shade_all([batch(4, 1, 1)], 1, Duration::from_secs(10), |_| {}).await.unwrap();

    // A future epoch is refused at submit.
    assert!(!d.submit(batch(5, 9, 1)));
    assert_eq!(d.outstanding_requests(), 0);
    assert!(matches!(
        d.shade_all([batch(5, 9, 1)], 1, Duration::from_secs(1), |_| {}).await,
        Err(DispatchError::BadEpoch { epoch: 9, .. })
    ));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unsendable_old_epoch_is_dropped_and_counted_answered() {
    let (src, hash) = source();
    let pool = WorkerPool::new(vec![spawn_worker(&hash, script(-1, 0)).await]).unwrap();
    let d = pool.open(src, hash);
    d.set_epoch(1, vec![(0, Affine3A::IDENTITY)]);
    // The link's stream starts at epoch 1, so epoch 0 can no longer be sent on it.
    d.shade_all([batch(1, 1, 3)], 1, Duration::from_secs(10), |_| {}).await.unwrap();
    assert!(d.submit(batch(2, 0, 3)));
    let ans = tokio::time::timeout(Duration::from_secs(10), d.next_answer()).await.unwrap().unwrap();
    assert!(matches!(ans, Answer::Dropped { batch_id: 2, epoch: 0, .. }), "{ans:?}");
    assert_eq!(d.outstanding_requests(), 0, "a dropped batch does not leak outstanding requests");
    assert_eq!(d.stats().dropped_batches, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn queue_refuses_when_full_and_unreachable_workers_stall_cleanly() {
    let (src, hash) = source();
    // Nothing listens on this port (bound then released): the link keeps retrying.
    let dead = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().to_string()
    };
    let pool = WorkerPool::with_options(vec![dead], PoolOptions { queue_batches: 3, ..Default::default() }).unwrap();
    let d = pool.open(src, hash);
    assert!(d.submit(batch(1, 0, 2)) && d.submit(batch(2, 0, 2)) && d.submit(batch(3, 0, 2)));
    assert!(!d.submit(batch(4, 0, 2)), "queue full");
    assert_eq!(d.outstanding_requests(), 6);
    assert_eq!(d.live_workers(), 0);
    let mut out = Vec::new();
    assert_eq!(d.drain(&mut out), 0);
    drop(d);
    let d = pool.open(pb::builtin_source("cornell"), "x".into());
    let r = d.shade_all([batch(1, 0, 1)], 1, Duration::from_millis(300), |_| {}).await;
    assert!(matches!(r, Err(DispatchError::Stalled { live: 0, workers: 1, .. })), "{r:?}");
    assert!(WorkerPool::new(vec!["not a url at all".into()]).is_err());
    assert!(WorkerPool::new(vec!["http://".into()]).is_err());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_worker_gets_smaller_batches_and_every_request_is_answered_once() {
    let (src, hash) = source();
    let fast = Arc::new(Script { per_request_us: 100, ..Arc::try_unwrap(script(-1, 0)).ok().unwrap() });
    let slow = Arc::new(Script { per_request_us: 2000, ..Arc::try_unwrap(script(-1, 0)).ok().unwrap() });
    let urls = vec![spawn_worker(&hash, fast.clone()).await, spawn_worker(&hash, slow.clone()).await];
    let opts = PoolOptions { target_batch_time: Duration::from_millis(20), min_batch: 4, ..Default::default() };
    let pool = WorkerPool::with_options(urls, opts).unwrap();
    let d = pool.open(src, hash);
    let mut seen: HashMap<u64, usize> = HashMap::new();
    d.shade_all((0..200).map(|i| batch(i, 0, 64)), 8, Duration::from_secs(20), |sb| {
        for s in &sb.samples {
            assert_eq!(s.id / 1000, sb.batch_id, "parts keep their batch id");
            *seen.entry(s.id).or_insert(0) += 1;
        }
    })
    .await
    .unwrap();
    assert_eq!(seen.len(), 200 * 64, "every request of every batch answered");
    assert!(seen.values().all(|&n| n == 1), "no request answered twice");
    assert_eq!((d.outstanding_requests(), d.outstanding_batches()), (0, 0));
    // 2 ms per request at 20 ms per batch: about 10 requests per batch for the slow worker.
    let small = slow.min_batch.load(Ordering::SeqCst);
    assert!(small < 64, "the slow worker got split batches (smallest {small})");
    let status = d.worker_status();
    let slow_status = status.iter().find(|w| w.samples_per_busy_second > 0.0 && w.samples_per_busy_second < 2000.0).expect("slow worker measured");
    assert!(slow_status.batch_size < 64, "{status:?}");
    let fast_status = status.iter().find(|w| w.url != slow_status.url).unwrap();
    assert!(fast_status.samples > slow_status.samples, "the fast worker shaded more: {status:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_worker_hands_its_batches_to_the_other() {
    let (src, hash) = source();
    let (a, b) = (script(-1, 1), script(-1, 1));
    let urls = vec![spawn_worker(&hash, a.clone()).await, spawn_worker(&hash, b.clone()).await];
    let opts = PoolOptions { stall_floor: Duration::from_millis(300), first_answer_timeout: Duration::from_secs(2), ..Default::default() };
    let pool = WorkerPool::with_options(urls, opts).unwrap();
    let d = pool.open(src, hash);
    // Warm up both links, then wedge A: its connection stays up, it just never answers.
    d.shade_all((0..20).map(|i| batch(i, 0, 4)), 8, Duration::from_secs(10), |_| {}).await.unwrap();
    a.hang.store(true, Ordering::SeqCst);
    let mut seen = HashMap::new();
    d.shade_all((100..200).map(|i| batch(i, 0, 4)), 16, Duration::from_secs(20), |sb| {
        *seen.entry(sb.batch_id).or_insert(0) += 1;
    })
    .await
    .unwrap();
    assert_eq!(seen.len(), 100, "every batch answered despite the wedged worker");
    assert!(seen.values().all(|&n| n == 1));
    assert!(d.stats().requeued_batches > 0, "the wedged worker's batches were re-issued");
    let failures: u64 = d.worker_status().iter().map(|w| w.failures).sum();
    assert!(failures > 0, "the stall counts as a failure");
}

/// Answers a name from a table the test edits.
#[derive(Default)]
struct Dns(std::sync::Mutex<Vec<std::net::IpAddr>>);
impl Resolve for Dns {
    fn lookup<'a>(
        &'a self,
        _host: &'a str,
        _port: u16,
    ) -> std::pin::Pin<Box<dyn std::future::Future<Output = std::io::Result<Vec<std::net::IpAddr>>> + Send + 'a>> {
        let ips = self.0.lock().unwrap().clone();
        Box::pin(async move { Ok(ips) })
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn workers_found_by_dns_join_and_leave_while_dispatching() {
    let (src, hash) = source();
    // Two workers on one port at two loopback addresses: one DNS name, two records.
    let (a, b) = (script(-1, 1), script(-1, 1));
    let first = spawn_worker_on(&hash, a.clone(), "127.0.0.1:0").await;
    let port: u16 = first.rsplit(':').next().unwrap().parse().unwrap();
    let Ok(l) = std::net::TcpListener::bind(("127.0.0.2", port)) else {
        eprintln!("127.0.0.2:{port} is not available here; skipping");
        return;
    };
    drop(l);
    spawn_worker_on(&hash, b.clone(), &format!("127.0.0.2:{port}")).await;
    let dns = Arc::new(Dns::default());
    *dns.0.lock().unwrap() = vec!["127.0.0.1".parse().unwrap()];
    let sources = WorkerSources { dns: vec![format!("workers.test:{port}")], interval: Duration::from_millis(100), ..Default::default() };
    let pool = WorkerPool::discover_with(sources, PoolOptions::default(), dns.clone()).await.unwrap();
    assert_eq!(pool.endpoints(), [format!("http://127.0.0.1:{port}")]);
    let d = pool.open(src, hash);
    let mut seen = HashMap::new();
    let mut next = 0u64;
    let mut run = |n: u64| {
        let ids = next..next + n;
        next += n;
        ids.map(|i| batch(i, 0, 4)).collect::<Vec<_>>()
    };
    d.shade_all(run(30), 8, Duration::from_secs(10), |sb| *seen.entry(sb.batch_id).or_insert(0) += 1).await.unwrap();
    assert_eq!(b.batches.load(Ordering::SeqCst), 0, "B is not in the pool yet");
    // Scale up: B appears in DNS and takes work.
    dns.0.lock().unwrap().push("127.0.0.2".parse().unwrap());
    tokio::time::timeout(Duration::from_secs(20), async {
        while d.live_workers() < 2 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("B did not join");
    assert_eq!(d.workers(), 2);
    d.shade_all(run(100), 16, Duration::from_secs(10), |sb| *seen.entry(sb.batch_id).or_insert(0) += 1).await.unwrap();
    assert!(b.batches.load(Ordering::SeqCst) > 0, "the new worker shades");
    // Scale down while batches are in flight: A leaves, its batches go to B.
    let before_a = a.batches.load(Ordering::SeqCst);
    *dns.0.lock().unwrap() = vec!["127.0.0.2".parse().unwrap()];
    d.shade_all(run(100), 16, Duration::from_secs(10), |sb| *seen.entry(sb.batch_id).or_insert(0) += 1).await.unwrap();
    tokio::time::timeout(Duration::from_secs(30), async {
        while d.workers() > 1 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await
    .expect("A did not leave");
    let a_after_leave = a.batches.load(Ordering::SeqCst);
    d.shade_all(run(50), 16, Duration::from_secs(10), |sb| *seen.entry(sb.batch_id).or_insert(0) += 1).await.unwrap();
    assert_eq!(a.batches.load(Ordering::SeqCst), a_after_leave, "a departed worker gets nothing");
    assert!(a_after_leave >= before_a);
    assert_eq!(seen.len(), 280);
    assert!(seen.values().all(|&n| n == 1), "no batch lost or doubled across joins and leaves");
    assert_eq!(pool.endpoints(), [format!("http://127.0.0.2:{port}")]);
}
