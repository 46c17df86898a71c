//! The `ShaderWorker` gRPC service (proto/proto/edgepoint.proto).
//!
//! Scenes are cached by content hash (LRU); concurrent loads of one hash build it once. A
//! `Shade` stream binds one loaded scene (`open`), then carries transform epochs and request
//! batches in order. Batches shade on a rayon pool (never on the async runtime) while the
//! stream keeps reading, up to [`PIPELINE`] batches at once, so a client with several
//! batches in flight keeps every core busy. A batch for an epoch never sent on the stream
//! ends the stream with FAILED_PRECONDITION: a wrong transform would be a wrong sample.
//!
//! Draining ([`DrainHandle::drain`], on SIGTERM): every stream stops reading, finishes the
//! batches it is shading, sends their samples and ends with UNAVAILABLE, so the renderer
//! re-issues whatever it still had queued here to other workers and nothing is lost.
use crate::loaded::LoadedScene;
use crate::metrics::WorkerMetrics;
use crate::shader::{shade_batch_parts, Part, RayRequest, ShaderSpec, SHADERS};
use crate::Instances;
use edgepoint_proto::shader_worker_server::ShaderWorker;
use edgepoint_proto::{self as pb, shade_in, shade_out};
use glam::{Affine3A, Vec3};
use std::collections::BTreeMap;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tokio::sync::{mpsc, watch, OnceCell, Semaphore};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

/// Batches of one stream shading at once (the rest wait in the stream's receive window).
pub const PIPELINE: usize = 3;
/// Transform epochs a stream remembers, so batches sent just before a move still shade.
pub const KEPT_EPOCHS: usize = 8;

type Loaded = Result<Arc<LoadedScene>, Status>;

/// LRU cache of loaded scenes by hash.
pub struct SceneCache {
    capacity: usize,
    entries: Mutex<Vec<(String, Arc<OnceCell<Loaded>>)>>,
}

impl SceneCache {
    pub fn new(capacity: usize) -> Self {
        SceneCache { capacity: capacity.max(1), entries: Mutex::new(Vec::new()) }
    }

    fn cell(&self, hash: &str) -> (Arc<OnceCell<Loaded>>, bool) {
        let mut e = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(i) = e.iter().position(|(h, _)| h == hash) {
            let entry = e.remove(i);
            let cell = entry.1.clone();
            e.push(entry);
            return (cell, true);
        }
        let cell = Arc::new(OnceCell::new());
        e.push((hash.to_string(), cell.clone()));
        while e.len() > self.capacity {
            e.remove(0);
        }
        (cell, false)
    }

    fn forget(&self, hash: &str) {
        let mut e = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        e.retain(|(h, _)| h != hash);
    }

    /// A loaded scene, if this worker holds it.
    pub fn get(&self, hash: &str) -> Option<Arc<LoadedScene>> {
        let e = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        e.iter().find(|(h, _)| h == hash).and_then(|(_, c)| c.get()).and_then(|r| r.as_ref().ok()).cloned()
    }

    pub fn hashes(&self) -> Vec<String> {
        let e = self.entries.lock().unwrap_or_else(|p| p.into_inner());
        e.iter().filter(|(_, c)| matches!(c.get(), Some(Ok(_)))).map(|(h, _)| h.clone()).collect()
    }
}

/// The service state.
pub struct WorkerService {
    cache: Arc<SceneCache>,
    pool: Arc<rayon::ThreadPool>,
    metrics: WorkerMetrics,
    draining: Arc<watch::Sender<bool>>,
}

/// Ends a worker's streams gracefully (see the module docs).
#[derive(Clone)]
pub struct DrainHandle(Arc<watch::Sender<bool>>);

impl DrainHandle {
    pub fn drain(&self) {
        self.0.send_replace(true);
    }
}

impl WorkerService {
    pub fn new(cache_entries: usize, threads: usize) -> Result<Self, rayon::ThreadPoolBuildError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("shade-{i}"))
            .build()?;
        Ok(WorkerService {
            cache: Arc::new(SceneCache::new(cache_entries)),
            pool: Arc::new(pool),
            metrics: WorkerMetrics::new(),
            draining: Arc::new(watch::channel(false).0),
        })
    }

    pub fn cache(&self) -> &Arc<SceneCache> {
        &self.cache
    }

    /// The worker's metrics (counted always; exported by `--metrics-listen`).
    pub fn metrics(&self) -> &WorkerMetrics {
        &self.metrics
    }

    pub fn drain_handle(&self) -> DrainHandle {
        DrainHandle(self.draining.clone())
    }
}

/// Counts a stream as open while it lives.
struct StreamGauge(prometheus::IntGauge);
impl Drop for StreamGauge {
    fn drop(&mut self) {
        self.0.dec();
    }
}

fn vec3(v: &Option<pb::Vec3>, what: &str, id: u64) -> Result<Vec3, Status> {
    let v: Vec3 = v.as_ref().map(Vec3::from).ok_or_else(|| Status::invalid_argument(format!("request {id}: no {what}")))?;
    if !v.is_finite() {
        return Err(Status::invalid_argument(format!("request {id}: {what} is not finite ({v})")));
    }
    Ok(v)
}

/// A batch's rays and, when any request is a part of a split sample, every request's part
/// (empty otherwise: the common case costs nothing).
fn requests_from_wire(b: &pb::RequestBatch) -> Result<(Vec<RayRequest>, Vec<Part>), Status> {
    let reqs = b
        .requests
        .iter()
        .map(|r| {
            let direction = vec3(&r.direction, "direction", r.id)?;
            if direction.length_squared() == 0.0 {
                return Err(Status::invalid_argument(format!("request {}: zero direction", r.id)));
            }
            Ok(RayRequest { id: r.id, pixel: [r.pixel_x, r.pixel_y], origin: vec3(&r.origin, "origin", r.id)?, direction })
        })
        .collect::<Result<Vec<_>, Status>>()?;
    if b.requests.iter().all(|r| r.parts <= 1 && r.part == 0) {
        return Ok((reqs, Vec::new()));
    }
    let parts = b
        .requests
        .iter()
        .map(|r| Part::from_wire(r.part, r.parts).map_err(|m| Status::invalid_argument(format!("request {}: {m}", r.id))))
        .collect::<Result<Vec<_>, Status>>()?;
    Ok((reqs, parts))
}

fn samples_to_wire(b: &pb::RequestBatch, out: crate::ShadeOutput, shade_ms: f64) -> pb::SampleBatch {
    pb::SampleBatch {
        batch_id: b.batch_id,
        epoch: b.epoch,
        samples: out
            .samples
            .into_iter()
            .map(|s| match s.hit {
                Some(h) => pb::Sample {
                    part: 0,
                    id: s.id,
                    hit: true,
                    position: Some(h.position.into()),
                    normal: Some(h.normal.into()),
                    object_id: h.object,
                    distance: h.distance,
                    rgb: Some(s.rgb.into()),
                    triangle: h.triangle,
                    local_position: Some(h.local_position.into()),
                    local_normal: Some(h.local_normal.into()),
                },
                None => pb::Sample { id: s.id, hit: false, rgb: Some(s.rgb.into()), object_id: u32::MAX, ..Default::default() },
            })
            .zip(&b.requests)
            // Samples come in request order: each echoes its request's part.
            .map(|(s, r)| pb::Sample { part: r.part, ..s })
            .collect(),
        triples: out.triples.into_iter().map(|[light, blocker, receiver]| pb::Triple { light, blocker, receiver }).collect(),
        visible_objects: out.visible,
        shade_ms,
        nonfinite: out.nonfinite,
        packed_samples: Vec::new(),
    }
}

/// Per-stream transform state: the instances of the last few epochs.
struct StreamEpochs {
    transforms: Vec<Affine3A>,
    latest: u64,
    by_epoch: BTreeMap<u64, Arc<Instances>>,
}

impl StreamEpochs {
    fn new(scene: &LoadedScene) -> Self {
        let transforms = scene.default_transforms();
        let mut by_epoch = BTreeMap::new();
        by_epoch.insert(0, Arc::new(scene.instances(&transforms)));
        StreamEpochs { transforms, latest: 0, by_epoch }
    }

    fn apply(&mut self, scene: &LoadedScene, e: &pb::TransformEpoch) -> Result<(), Status> {
        if e.epoch <= self.latest && !(e.epoch == 0 && self.latest == 0) {
            return Err(Status::failed_precondition(format!(
                "epoch {} after epoch {}: epochs must increase on a stream",
                e.epoch, self.latest
            )));
        }
        let mut t = self.transforms.clone();
        for ot in &e.transforms {
            let slot = t.get_mut(ot.object_id as usize).ok_or_else(|| {
                Status::invalid_argument(format!(
                    "epoch {}: object {} does not exist (the scene has {} objects)",
                    e.epoch,
                    ot.object_id,
                    self.transforms.len()
                ))
            })?;
            let w = ot.transform.as_ref().ok_or_else(|| Status::invalid_argument(format!("epoch {}: object {} has no transform", e.epoch, ot.object_id)))?;
            *slot = edgepoint_proto::affine_from_wire(w)
                .map_err(|m| Status::invalid_argument(format!("epoch {}: object {}: {m}", e.epoch, ot.object_id)))?;
        }
        self.by_epoch.insert(e.epoch, Arc::new(scene.instances(&t)));
        self.transforms = t;
        self.latest = e.epoch;
        while self.by_epoch.len() > KEPT_EPOCHS {
            let first = *self.by_epoch.keys().next().expect("non-empty");
            self.by_epoch.remove(&first);
        }
        Ok(())
    }
}

type OutStream = Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::ShadeOut, Status>> + Send>>;

#[tonic::async_trait]
impl ShaderWorker for WorkerService {
    async fn load_scene(&self, req: Request<pb::LoadSceneRequest>) -> Result<Response<pb::LoadSceneReply>, Status> {
        let req = req.into_inner();
        let source = req.source.ok_or_else(|| Status::invalid_argument("LoadScene needs a scene source"))?;
        let hash = edgepoint_proto::scene_hash(&source);
        if !req.expect_hash.is_empty() && req.expect_hash != hash {
            return Err(Status::invalid_argument(format!(
                "scene source hashes to {hash}, not the expected {}",
                req.expect_hash
            )));
        }
        let (cell, was_cached) = self.cache.cell(&hash);
        let t = Instant::now();
        let h2 = hash.clone();
        let loads = self.metrics.scene_loads.clone();
        let loaded = cell
            .get_or_init(|| async move {
                loads.inc();
                let what = edgepoint_proto::describe_source(&source);
                tracing::info!(scene = %what, hash = %h2, "loading scene");
                let built = tokio::task::spawn_blocking(move || {
                    let progress = crate::service::LogProgress::new(&what);
                    let scene = edgepoint_proto::scene_from_source(&source, &progress)
                        .map_err(|e| Status::invalid_argument(e.to_string()))?;
                    Ok(Arc::new(LoadedScene::build(scene, h2, &progress)))
                })
                .await;
                match built {
                    Ok(r) => r,
                    Err(e) => Err(Status::internal(format!("scene build failed: {e}"))),
                }
            })
            .await
            .clone();
        match loaded {
            Ok(s) => Ok(Response::new(pb::LoadSceneReply {
                scene_hash: hash,
                objects: s.scene.objects.len() as u32,
                triangles: s.scene.triangle_count(),
                cached: was_cached,
                load_ms: if was_cached { 0.0 } else { t.elapsed().as_secs_f64() * 1e3 },
            })),
            Err(status) => {
                self.cache.forget(&hash);
                Err(status)
            }
        }
    }

    type ShadeStream = OutStream;

    async fn shade(&self, req: Request<Streaming<pb::ShadeIn>>) -> Result<Response<Self::ShadeStream>, Status> {
        let mut inbound = req.into_inner();
        let (tx, rx) = mpsc::channel::<Result<pb::ShadeOut, Status>>(PIPELINE + 1);
        let cache = self.cache.clone();
        let pool = self.pool.clone();
        let metrics = self.metrics.clone();
        let mut drain = self.draining.subscribe();
        tokio::spawn(async move {
            metrics.streams.inc();
            let _open = StreamGauge(metrics.streams.clone());
            let scene = match inbound.message().await {
                Ok(Some(pb::ShadeIn { msg: Some(shade_in::Msg::Open(o)) })) => match cache.get(&o.scene_hash) {
                    Some(s) => s,
                    None => {
                        let _ = tx
                            .send(Err(Status::not_found(format!(
                                "scene {} is not loaded on this worker; call LoadScene first",
                                o.scene_hash
                            ))))
                            .await;
                        return;
                    }
                },
                Ok(Some(_)) => {
                    let _ = tx.send(Err(Status::failed_precondition("the first Shade message must be `open`"))).await;
                    return;
                }
                Ok(None) | Err(_) => return,
            };
            let mut epochs = StreamEpochs::new(&scene);
            let permits = Arc::new(Semaphore::new(PIPELINE));
            loop {
                let msg = tokio::select! {
                    m = inbound.message() => match m {
                        Ok(Some(m)) => m,
                        Ok(None) | Err(_) => break,
                    },
                    _ = async { drain.wait_for(|d| *d).await.map(|_| ()) } => {
                        // Finish the batches shading (each holds its permit until its
                        // samples are queued for sending), then end the stream.
                        let _ = permits.acquire_many(PIPELINE as u32).await;
                        metrics.stream_errors.inc();
                        let _ = tx.send(Err(Status::unavailable("the worker is shutting down; re-issue the rest elsewhere"))).await;
                        break;
                    }
                };
                let fail = |s: Status| {
                    let tx = tx.clone();
                    let errors = metrics.stream_errors.clone();
                    async move {
                        errors.inc();
                        let _ = tx.send(Err(s)).await;
                    }
                };
                match msg.msg {
                    Some(shade_in::Msg::Epoch(e)) => {
                        if let Err(s) = epochs.apply(&scene, &e) {
                            fail(s).await;
                            break;
                        }
                    }
                    Some(shade_in::Msg::Batch(mut b)) => {
                        // Packed requests are answered with packed samples (`edgepoint_proto::packed`).
                        let packed = !b.packed_requests.is_empty();
                        if let Err(e) = edgepoint_proto::packed::unpack_request_batch(&mut b) {
                            fail(Status::invalid_argument(format!("batch {}: {e}", b.batch_id))).await;
                            break;
                        }
                        let Some(inst) = epochs.by_epoch.get(&b.epoch).cloned() else {
                            fail(Status::failed_precondition(format!(
                                "batch {} names epoch {}, which was never sent on this stream (known: {:?})",
                                b.batch_id,
                                b.epoch,
                                epochs.by_epoch.keys().collect::<Vec<_>>()
                            )))
                            .await;
                            break;
                        };
                        let spec = match ShaderSpec::parse(&b.shader, &b.params) {
                            Ok(s) => s,
                            Err(m) => {
                                fail(Status::invalid_argument(m)).await;
                                break;
                            }
                        };
                        let (reqs, parts) = match requests_from_wire(&b) {
                            Ok(r) => r,
                            Err(s) => {
                                fail(s).await;
                                break;
                            }
                        };
                        metrics.waiting.inc();
                        let permit = permits.clone().acquire_owned().await;
                        metrics.waiting.dec();
                        let Ok(permit) = permit else { break };
                        let (scene, pool, tx, m) = (scene.clone(), pool.clone(), tx.clone(), metrics.clone());
                        tokio::spawn(async move {
                            let t = Instant::now();
                            m.shading.inc();
                            let out = tokio::task::spawn_blocking(move || {
                                let out = pool.install(|| shade_batch_parts(&scene, &inst, &spec, b.seed, &reqs, &parts));
                                let mut batch = samples_to_wire(&b, out, t.elapsed().as_secs_f64() * 1e3);
                                let n = batch.samples.len();
                                if packed {
                                    edgepoint_proto::packed::pack_samples(&batch.samples, &mut batch.packed_samples);
                                    batch.samples = Vec::new();
                                }
                                (batch, n)
                            })
                            .await;
                            m.shading.dec();
                            let msg = match out {
                                Ok((batch, n)) => {
                                    m.batches.inc();
                                    m.samples.inc_by(n as u64);
                                    m.nonfinite.inc_by(batch.nonfinite as u64);
                                    m.batch_seconds.observe(batch.shade_ms / 1e3);
                                    Ok(pb::ShadeOut { msg: Some(shade_out::Msg::Samples(batch)) })
                                }
                                Err(e) => Err(Status::internal(format!("shading failed: {e}"))),
                            };
                            let _ = tx.send(msg).await;
                            // Held until the samples are queued, so a draining stream sends
                            // them before it ends.
                            drop(permit);
                        });
                    }
                    Some(shade_in::Msg::Open(_)) => {
                        fail(Status::failed_precondition("`open` may only be the first Shade message")).await;
                        break;
                    }
                    None => {
                        fail(Status::invalid_argument("empty Shade message")).await;
                        break;
                    }
                }
            }
        });
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn info(&self, _: Request<pb::InfoRequest>) -> Result<Response<pb::InfoReply>, Status> {
        Ok(Response::new(pb::InfoReply {
            shaders: SHADERS.iter().map(|s| s.to_string()).collect(),
            threads: self.pool.current_num_threads() as u32,
            cached_scenes: self.cache.hashes(),
            version: env!("CARGO_PKG_VERSION").to_string(),
        }))
    }
}

/// Progress of scene loads as periodic log lines (workers run without a terminal).
pub struct LogProgress {
    what: String,
    state: Mutex<(String, u64, u64, Instant)>,
}

impl LogProgress {
    pub fn new(what: &str) -> Self {
        LogProgress { what: what.to_string(), state: Mutex::new((String::new(), 0, 0, Instant::now())) }
    }
}

impl edgepoint_scene::Progress for LogProgress {
    fn begin(&self, stage: &str, total: u64) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        *s = (stage.to_string(), total, 0, Instant::now());
        tracing::info!(scene = %self.what, "{stage}: 0/{total}");
    }
    fn advance(&self, units: u64) {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        s.2 += units;
        if s.3.elapsed().as_secs_f32() > 1.0 {
            s.3 = Instant::now();
            tracing::info!(scene = %self.what, "{}: {}/{}", s.0, s.2, s.1);
        }
    }
    fn end(&self) {
        let s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        tracing::info!(scene = %self.what, "{}: done", s.0);
    }
}
