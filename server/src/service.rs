//! The `Renderer` gRPC service (proto `edgepoint.v1.Renderer`): one bidirectional stream per
//! viewer. The first message must be `start`; it is validated (image size, encoding,
//! camera, settings, shader), the scene is built on a blocking thread (a malformed file is
//! refused with INVALID_ARGUMENT naming the file and line), a [`Session`] starts, and the
//! server answers `started` and then streams frames. Later bad messages are answered with
//! `rejected` and change nothing. Each session is isolated: its frame loop runs on its own
//! thread, so a failing session never stops another.
//!
//! Remote viewing is guarded here: with tokens configured a session needs
//! `authorization: Bearer <token>` (else UNAUTHENTICATED); `start` must arrive within
//! [`ServiceConfig::start_timeout`] (else DEADLINE_EXCEEDED); the frame must fit the server's
//! pixel limit and, encoded at its worst, the message limit (else RESOURCE_EXHAUSTED); its
//! estimated memory must fit in what the server-wide budget has left (else
//! RESOURCE_EXHAUSTED); and at most `max_sessions` run at once (else RESOURCE_EXHAUSTED). Messages above the size limit
//! are refused by tonic itself (OUT_OF_RANGE). Every refusal is counted by reason in the
//! metrics, and every sent frame feeds the frame-time and frame-interval histograms.
use crate::metrics::{Refusal, SessionMetrics};
use crate::reference::LogProgress;
use crate::rng::mix64;
use crate::session::memory::{MemoryBudget, MemoryGrant, SessionMemory};
use crate::session::{camera_to_wire, Input, Session, SessionParams, SessionSettings, DEFAULT_POINTS_PER_PIXEL};
use crate::workers::{WorkerPool, DEFAULT_MAX_MESSAGE_BYTES};
use edgepoint_proto as pb;
use edgepoint_proto::split::SplitMode;
use edgepoint_proto::auth::check_bearer;
use edgepoint_proto::renderer_server::{Renderer, RendererServer};
use edgepoint_proto::viewer_msg::Msg as ViewerIn;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::{Duration, Instant};
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

/// Largest image side accepted.
pub const MAX_IMAGE_SIDE: u32 = 8192;
/// Shader used when `start.shader` is empty.
pub const DEFAULT_SHADER: &str = edgepoint_proto::shaders::DEFAULT_SHADER;
/// How long `start` waits for workers to list their shaders before trusting the name.
const SHADER_QUERY_TIMEOUT: Duration = Duration::from_secs(2);

/// Default largest frame, in pixels (4096 × 4096).
pub const DEFAULT_MAX_FRAME_PIXELS: u64 = 4096 * 4096;
/// Default time a viewer has to send `start` after opening its session stream.
pub const DEFAULT_START_TIMEOUT: Duration = Duration::from_secs(30);
/// Worst-case encoded bytes per pixel of any frame encoding (QOI's worst case is 4 bytes per
/// RGB pixel; raw is 3), plus room for the frame's stats.
const WORST_BYTES_PER_PIXEL: u64 = 4;
const FRAME_OVERHEAD_BYTES: u64 = 64 << 10;

/// Service options.
#[derive(Clone)]
pub struct ServiceConfig {
    /// Sessions allowed at once; more are refused with RESOURCE_EXHAUSTED.
    pub max_sessions: usize,
    /// Render Cache size per pixel.
    pub points_per_pixel: f32,
    /// Largest frame (width × height) a session may ask for; more is RESOURCE_EXHAUSTED.
    pub max_frame_pixels: u64,
    /// The message limit the server is built with ([`RendererService::into_server`]); a
    /// frame that could not fit in it encoded is refused at `start`.
    pub max_message_bytes: usize,
    /// Accepted bearer tokens; `None` accepts every viewer (loopback or `--insecure`).
    pub tokens: Option<Arc<Vec<String>>>,
    /// Time allowed between opening a session stream and its `start`.
    pub start_timeout: Duration,
    /// The memory all sessions together may take (their [`SessionMemory`] estimates); a
    /// session that would exceed it is refused with RESOURCE_EXHAUSTED.
    pub memory: Arc<MemoryBudget>,
    pub metrics: Arc<SessionMetrics>,
    /// Sessions' simplification tolerance unless their viewer sets one (paper 003; 0: off).
    pub simplify_tolerance: f64,
}

impl std::fmt::Debug for ServiceConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ServiceConfig")
            .field("max_sessions", &self.max_sessions)
            .field("points_per_pixel", &self.points_per_pixel)
            .field("max_frame_pixels", &self.max_frame_pixels)
            .field("max_message_bytes", &self.max_message_bytes)
            .field("tokens", &self.tokens.as_ref().map(|t| format!("{} token(s)", t.len())))
            .field("start_timeout", &self.start_timeout)
            .field("memory_limit", &self.memory.limit())
            .field("simplify_tolerance", &self.simplify_tolerance)
            .finish()
    }
}

impl Default for ServiceConfig {
    fn default() -> Self {
        ServiceConfig {
            max_sessions: 16,
            points_per_pixel: DEFAULT_POINTS_PER_PIXEL,
            max_frame_pixels: DEFAULT_MAX_FRAME_PIXELS,
            max_message_bytes: DEFAULT_MAX_MESSAGE_BYTES,
            tokens: None,
            start_timeout: DEFAULT_START_TIMEOUT,
            memory: MemoryBudget::unlimited(),
            metrics: Arc::new(SessionMetrics::default()),
            simplify_tolerance: 0.0,
        }
    }
}

/// The renderer service. Clone-free: wrap it with [`RendererService::into_server`] (or share
/// it in an `Arc` with [`RendererService::shared_server`] and the browser listener).
pub struct RendererService {
    pool: Arc<WorkerPool>,
    cfg: ServiceConfig,
    state: Arc<ServiceState>,
}

#[derive(Default)]
struct ServiceState {
    active: AtomicUsize,
    next: AtomicU64,
    shutting_down: AtomicBool,
    sessions: Mutex<HashMap<u64, Weak<crate::session::SessionOutput>>>,
    /// Scenes and edge indexes shared by the sessions on the same scene.
    scenes: crate::scenes::SceneLibrary,
}

/// A session slot; released on drop.
struct Slot(Arc<ServiceState>, Arc<SessionMetrics>);
impl Drop for Slot {
    fn drop(&mut self) {
        self.1.sessions.dec();
        self.0.active.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A cheap handle that can end every session (for graceful shutdown).
#[derive(Clone)]
pub struct ShutdownHandle(Arc<ServiceState>);

impl ShutdownHandle {
    /// Refuses new sessions (UNAVAILABLE) and ends the running ones, so their streams
    /// finish and the server can drain.
    pub fn shutdown(&self) {
        self.0.shutting_down.store(true, Ordering::SeqCst);
        let sessions = self.0.sessions.lock().unwrap_or_else(|p| p.into_inner());
        for out in sessions.values().filter_map(Weak::upgrade) {
            out.close();
        }
    }

    /// Sessions running now.
    pub fn active_sessions(&self) -> usize {
        self.0.active.load(Ordering::SeqCst)
    }
}

impl RendererService {
    pub fn new(pool: Arc<WorkerPool>, cfg: ServiceConfig) -> Self {
        RendererService { pool, cfg, state: Arc::new(ServiceState::default()) }
    }

    pub fn shutdown_handle(&self) -> ShutdownHandle {
        ShutdownHandle(self.state.clone())
    }

    /// The tonic server for this service, accepting and sending messages up to
    /// `max_message_bytes` (a `start` may carry a whole scene).
    pub fn into_server(self, max_message_bytes: usize) -> RendererServer<RendererService> {
        Arc::new(self).shared_server(max_message_bytes)
    }

    /// [`Self::into_server`] for a service also shared with the browser listener
    /// ([`crate::web`]), so both transports draw on the same sessions and limits.
    pub fn shared_server(self: Arc<Self>, max_message_bytes: usize) -> RendererServer<RendererService> {
        RendererServer::from_arc(self).max_decoding_message_size(max_message_bytes).max_encoding_message_size(max_message_bytes)
    }

    /// The service's limits (the browser listener refuses by the same ones).
    pub fn config(&self) -> &ServiceConfig {
        &self.cfg
    }

    /// Checks the viewer's bearer token when tokens are configured.
    fn authenticate(&self, md: &tonic::metadata::MetadataMap) -> Result<(), Status> {
        let Some(tokens) = &self.cfg.tokens else { return Ok(()) };
        check_bearer(md, tokens, "give the viewer --token-file FILE (or --token)")
    }

    /// Refuses frames above the pixel limit, or that could not fit in a message encoded.
    fn check_frame_size(&self, s: &pb::Start) -> Result<(), Status> {
        let pixels = s.width as u64 * s.height as u64;
        let max = self.cfg.max_frame_pixels;
        if pixels > max {
            return Err(Status::resource_exhausted(format!(
                "a {}x{} frame has {pixels} pixels, above this server's limit of {max} (--max-frame-pixels)",
                s.width, s.height
            )));
        }
        let worst = pixels * WORST_BYTES_PER_PIXEL + FRAME_OVERHEAD_BYTES;
        let limit = self.cfg.max_message_bytes as u64;
        if worst > limit {
            return Err(Status::resource_exhausted(format!(
                "a {}x{} frame may take {worst} bytes encoded, above this server's message limit of {limit} bytes (--max-message-mib)",
                s.width, s.height
            )));
        }
        Ok(())
    }

    /// Grants the session's estimated memory from the server's budget, or refuses it with
    /// RESOURCE_EXHAUSTED saying how much it needs and how much is in use.
    fn grant_memory(&self, s: &pb::Start, settings: &SessionSettings) -> Result<MemoryGrant, Status> {
        let need = SessionMemory::estimate(s.width, s.height, self.cfg.points_per_pixel, settings, rayon::current_num_threads());
        self.cfg
            .memory
            .grant(need.total(), &format!("a {}x{} session", s.width, s.height))
            .map_err(Status::resource_exhausted)
    }

    fn acquire_slot(&self) -> Result<Slot, Status> {
        let max = self.cfg.max_sessions;
        self.state
            .active
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| (n < max).then_some(n + 1))
            .map_err(|n| Status::resource_exhausted(format!("{n} sessions running, the limit is {max} (--max-sessions)")))?;
        self.cfg.metrics.sessions.inc();
        Ok(Slot(self.state.clone(), self.cfg.metrics.clone()))
    }
}

fn invalid(msg: impl Into<String>) -> Status {
    Status::invalid_argument(msg.into())
}

/// Checks the parts of `start` that need no scene; returns the resolved values.
#[derive(Debug)]
struct StartChecked {
    encoding: pb::FrameEncoding,
    shader: String,
    settings: SessionSettings,
    split: SplitMode,
}

fn check_start(s: &pb::Start) -> Result<StartChecked, Status> {
    for (name, v) in [("width", s.width), ("height", s.height)] {
        if v == 0 || v > MAX_IMAGE_SIDE {
            return Err(invalid(format!("start.{name} must be in 1..={MAX_IMAGE_SIDE}, got {v}")));
        }
    }
    let encoding = pb::FrameEncoding::try_from(s.encoding)
        .map_err(|_| invalid(format!("start.encoding {} is not a known FrameEncoding", s.encoding)))?;
    let shader = if s.shader.is_empty() { DEFAULT_SHADER.to_string() } else { s.shader.clone() };
    // The shared table: a parameter the workers would refuse is refused here, at once,
    // instead of giving a session of black frames.
    edgepoint_proto::shaders::resolve(&shader, &s.shader_params).map_err(|e| invalid(format!("start: {e}")))?;
    let settings = match &s.settings {
        Some(st) => SessionSettings::default().with(st).map_err(|e| invalid(format!("start: {e}")))?,
        None => SessionSettings::default(),
    };
    if let Some(c) = &s.camera {
        pb::check_partial_camera(c).map_err(|e| invalid(format!("start.camera: {e}")))?;
    }
    if s.scene.is_none() {
        return Err(invalid("start.scene is missing: name a built-in or send files"));
    }
    let split = SplitMode::from_wire(s.split.as_ref()).map_err(|e| invalid(format!("start.split: {e}")))?;
    Ok(StartChecked { encoding, shader, settings, split })
}

fn started_msg(id: &str, hash: &str, scene: &edgepoint_scene::Scene, camera: &edgepoint_scene::Camera, workers: usize) -> pb::ServerMsg {
    let (lo, hi) = scene.bounds();
    let objects = scene
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| pb::SceneObject {
            id: i as u32,
            name: o.name.clone(),
            triangles: o.mesh.triangles.len() as u64,
            transform: Some(pb::affine_to_wire(&o.transform)),
            bounds_min: Some(o.mesh.bounds.0.into()),
            bounds_max: Some(o.mesh.bounds.1.into()),
        })
        .collect();
    pb::ServerMsg {
        msg: Some(pb::server_msg::Msg::Started(pb::Started {
            session_id: id.to_string(),
            scene_hash: hash.to_string(),
            objects,
            camera: Some(camera_to_wire(camera)),
            workers: workers as u32,
            scene_min: Some(lo.into()),
            scene_max: Some(hi.into()),
            lights: scene.lights.len() as u32,
            orbit: Some(pb::orbit_to_wire(&scene.suggested_orbit())),
        })),
    }
}

#[tonic::async_trait]
impl Renderer for RendererService {
    type SessionStream = ReceiverStream<Result<pb::ServerMsg, Status>>;

    async fn session(&self, request: Request<Streaming<pb::ViewerMsg>>) -> Result<Response<Self::SessionStream>, Status> {
        let peer = request.remote_addr();
        let (md, _, inbound) = request.into_parts();
        self.serve_session(&md, peer, inbound).await.map(Response::new)
    }
}

/// What a session's viewer sends, from any transport: the gRPC request stream, or the
/// browser's WebSocket messages translated by [`crate::web`].
pub type ViewerStream = std::pin::Pin<Box<dyn tokio_stream::Stream<Item = Result<pb::ViewerMsg, Status>> + Send>>;

impl RendererService {
    /// Opens one session for a viewer whatever its transport (gRPC or the browser's
    /// WebSocket): the token in `md`, then every check of `start`, the shared session
    /// machinery, and the refusal metrics. Answers the stream of messages to the viewer.
    pub async fn serve_session(
        &self,
        md: &tonic::metadata::MetadataMap,
        peer: Option<std::net::SocketAddr>,
        inbound: impl tokio_stream::Stream<Item = Result<pb::ViewerMsg, Status>> + Send + 'static,
    ) -> Result<ReceiverStream<Result<pb::ServerMsg, Status>>, Status> {
        let r = self.open_session(md, peer, Box::pin(inbound)).await;
        match &r {
            Ok(_) => self.cfg.metrics.started.inc(),
            Err(s) => {
                self.cfg.metrics.refuse(Refusal::of(s.code()));
                tracing::info!(code = ?s.code(), "session refused: {}", s.message());
            }
        }
        r
    }
}

impl RendererService {
    async fn open_session(
        &self,
        md: &tonic::metadata::MetadataMap,
        peer: Option<std::net::SocketAddr>,
        mut inbound: ViewerStream,
    ) -> Result<ReceiverStream<Result<pb::ServerMsg, Status>>, Status> {
        use tokio_stream::StreamExt;
        self.authenticate(md)?;
        if self.state.shutting_down.load(Ordering::SeqCst) {
            return Err(Status::unavailable("the renderer is shutting down"));
        }
        let first = tokio::time::timeout(self.cfg.start_timeout, inbound.next()).await.map_err(|_| {
            Status::deadline_exceeded(format!("no `start` message within {:?} of opening the session", self.cfg.start_timeout))
        })?;
        let start = match first.transpose()? {
            Some(pb::ViewerMsg { msg: Some(ViewerIn::Start(s)) }) => s,
            Some(other) => {
                let what = match other.msg {
                    Some(ViewerIn::Camera(_)) => "camera",
                    Some(ViewerIn::Move(_)) => "move",
                    Some(ViewerIn::Settings(_)) => "settings",
                    Some(ViewerIn::Pick(_)) => "pick",
                    _ => "an empty message",
                };
                return Err(invalid(format!("the first message must be `start`, got {what}")));
            }
            None => return Err(invalid("the stream ended before `start`")),
        };
        if self.pool.is_empty() {
            return Err(Status::failed_precondition(
                "no shader workers available (give the server --worker URL, --worker-dns HOST:PORT or --workers-file FILE, and check that they run)",
            ));
        }
        let mut checked = check_start(&start)?;
        // The server's default simplification (--simplify-tolerance) unless the viewer chose.
        if start.settings.as_ref().is_none_or(|s| s.simplify_tolerance.is_none()) {
            checked.settings.simplify_tolerance = self.cfg.simplify_tolerance;
        }
        self.check_frame_size(&start)?;
        if let Some(shaders) = self.pool.shaders(SHADER_QUERY_TIMEOUT).await {
            if !shaders.contains(&checked.shader) {
                return Err(invalid(format!("unknown shader '{}' (the workers offer: {})", checked.shader, shaders.join(", "))));
            }
        }
        let memory = self.grant_memory(&start, &checked.settings)?;
        let slot = self.acquire_slot()?;

        let source = start.scene.clone().expect("checked in check_start");
        let hash = pb::scene_hash(&source);
        let what = pb::describe_source(&source);
        tracing::info!(?peer, scene = %what, width = start.width, height = start.height,
            memory_mib = memory.bytes() >> 20, budget_used_mib = self.cfg.memory.used() >> 20, "session starting");
        let shared = match self.state.scenes.get(&hash) {
            Some(shared) => shared,
            None => {
                let src = source.clone();
                let scene = tokio::task::spawn_blocking(move || pb::scene_from_source(&src, &LogProgress::new("scene")))
                    .await
                    .map_err(|e| Status::internal(format!("scene build task failed: {e}")))?
                    .map_err(|e| invalid(e.to_string()))?;
                self.state.scenes.insert(&hash, scene)
            }
        };
        let scene = shared.scene;
        let camera = match &start.camera {
            Some(c) => pb::camera_over(c, &scene.camera).map_err(|e| invalid(format!("start.camera: {e}")))?,
            None => scene.camera,
        };

        let n = self.state.next.fetch_add(1, Ordering::Relaxed);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0);
        let seed = mix64(nanos ^ n.rotate_left(32));
        let id = format!("{seed:016x}");
        let started = started_msg(&id, &hash, &scene, &camera, self.pool.len());

        let dispatcher = self.pool.open(source, hash);
        let params = SessionParams {
            id: id.clone(),
            scene,
            width: start.width,
            height: start.height,
            camera,
            shader: checked.shader,
            shader_params: start.shader_params.clone(),
            encoding: checked.encoding,
            settings: checked.settings,
            points_per_pixel: self.cfg.points_per_pixel,
            seed,
            edge_index: shared.edge_index,
            memory: Some(memory),
            split: checked.split,
        };
        let state = self.state.clone();
        let on_end: Box<dyn FnOnce() + Send> = Box::new(move || {
            state.sessions.lock().unwrap_or_else(|p| p.into_inner()).remove(&n);
            drop(slot);
        });
        let session = Session::start(params, dispatcher, Some(on_end))
            .map_err(|e| Status::resource_exhausted(format!("cannot start a session thread: {e}")))?;
        let output = session.output();
        self.state.sessions.lock().unwrap_or_else(|p| p.into_inner()).insert(n, Arc::downgrade(&output));

        // Viewer → frame loop. Rejections for malformed messages go straight to the output.
        let inputs = session.inputs();
        let out_in = output.clone();
        tokio::spawn(async move {
            loop {
                // Stop reading when the session ends, so the request stream is released
                // and the connection can drain (graceful shutdown).
                let msg = tokio::select! {
                    m = inbound.next() => m.transpose(),
                    _ = out_in.done() => break,
                };
                match msg {
                    Ok(Some(pb::ViewerMsg { msg })) => {
                        let input = match msg {
                            Some(ViewerIn::Camera(c)) => Input::Camera(c),
                            Some(ViewerIn::Move(m)) => Input::Move(m),
                            Some(ViewerIn::Settings(s)) => Input::Settings(s),
                            Some(ViewerIn::Pick(p)) => Input::Pick(p),
                            Some(ViewerIn::Start(_)) => {
                                out_in.reject(tonic::Code::InvalidArgument, "`start` ignored: the session is already started");
                                continue;
                            }
                            None => {
                                out_in.reject(tonic::Code::InvalidArgument, "empty viewer message ignored");
                                continue;
                            }
                        };
                        if inputs.send_async(input).await.is_err() {
                            break; // the frame loop is gone
                        }
                    }
                    // The viewer half-closed or its stream failed: no more input. Frames go
                    // on until the viewer drops the response stream.
                    Ok(None) => break,
                    Err(s) => {
                        tracing::debug!("viewer input stream ended: {s}");
                        break;
                    }
                }
            }
        });

        // Frame loop → viewer, one message in flight: a slow viewer makes the frame loop
        // replace frames rather than queue them.
        let (tx, rx) = tokio::sync::mpsc::channel(1);
        let metrics = self.cfg.metrics.clone();
        tokio::spawn(async move {
            let session = session; // dropped (closing the frame loop) when this task ends
            if tx.send(Ok(started)).await.is_err() {
                return;
            }
            let mut frames = FrameMeter::default();
            loop {
                tokio::select! {
                    m = output.next() => match m {
                        Some(m) => {
                            if let Some(pb::server_msg::Msg::Frame(f)) = &m.msg {
                                frames.sent(f, &metrics);
                            }
                            if tx.send(Ok(m)).await.is_err() {
                                break;
                            }
                        }
                        None => break,
                    },
                    _ = tx.closed() => break,
                }
            }
            tracing::info!(session = %session.id(), "viewer stream closed");
            drop(session);
        });
        Ok(ReceiverStream::new(rx))
    }
}

/// Feeds one session's sent frames into the metrics.
#[derive(Default)]
struct FrameMeter {
    last: Option<Instant>,
    dropped: u64,
}

impl FrameMeter {
    fn sent(&mut self, f: &pb::Frame, m: &SessionMetrics) {
        let now = Instant::now();
        m.frames.inc();
        if f.total_ms.is_finite() && f.total_ms >= 0.0 {
            m.frame_seconds.observe(f.total_ms / 1e3);
        }
        if let Some(last) = self.last.replace(now) {
            m.frame_interval_seconds.observe(now.duration_since(last).as_secs_f64());
        }
        // `frames_dropped` is the session's running count.
        m.frames_dropped.inc_by(f.frames_dropped.saturating_sub(self.dropped));
        self.dropped = self.dropped.max(f.frames_dropped);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn start() -> pb::Start {
        pb::Start { scene: Some(pb::builtin_source("cornell")), width: 64, height: 48, ..Default::default() }
    }

    #[test]
    fn start_checks_name_the_bad_value() {
        let c = check_start(&start()).unwrap();
        assert_eq!((c.encoding, c.shader.as_str()), (pb::FrameEncoding::Unspecified, "direct"));
        let e = check_start(&pb::Start { width: 0, ..start() }).unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument);
        assert!(e.message().contains("width") && e.message().contains("got 0"), "{}", e.message());
        let e = check_start(&pb::Start { height: 9000, ..start() }).unwrap_err();
        assert!(e.message().contains("height") && e.message().contains("9000"));
        assert!(check_start(&pb::Start { encoding: 42, ..start() }).unwrap_err().message().contains("42"));
        assert!(check_start(&pb::Start { scene: None, ..start() }).unwrap_err().message().contains("scene"));
        // A partial camera is fine (the scene's fills the rest); a bad field is named.
        let fov_only = pb::Camera { fov_y_degrees: 40.0, ..Default::default() };
        assert!(check_start(&pb::Start { camera: Some(fov_only), ..start() }).is_ok());
        let bad_cam = pb::Camera { eye: Some(glam::Vec3::new(0.0, f32::INFINITY, 0.0).into()), ..Default::default() };
        let e = check_start(&pb::Start { camera: Some(bad_cam), ..start() }).unwrap_err();
        assert!(e.message().contains("start.camera: camera eye is not finite"), "{}", e.message());
        let bad_settings = pb::Settings { sparseness: -2.0, ..Default::default() };
        assert!(check_start(&pb::Start { settings: Some(bad_settings), ..start() }).unwrap_err().message().contains("sparseness"));
        let params = HashMap::from([("ambient".to_string(), f64::NAN)]);
        assert!(check_start(&pb::Start { shader_params: params, ..start() }).unwrap_err().message().contains("ambient"));
        // Issue 12 item 8: an unknown parameter is refused at start, listing the valid ones.
        let params = HashMap::from([("bogus".to_string(), 1.0)]);
        let e = check_start(&pb::Start { shader_params: params, ..start() }).unwrap_err();
        assert_eq!(e.code(), tonic::Code::InvalidArgument);
        assert!(e.message().contains("'bogus'") && e.message().contains("shadow_rays") && e.message().contains("ambient"), "{}", e.message());
        let params = HashMap::from([("shadow_rays".to_string(), 0.0)]);
        assert!(check_start(&pb::Start { shader_params: params, ..start() }).unwrap_err().message().contains("shadow_rays"));
        let e = check_start(&pb::Start { shader: "phong".into(), ..start() }).unwrap_err();
        assert!(e.message().contains("unknown shader 'phong'") && e.message().contains("direct, glossy, gi"), "{}", e.message());
        // Issue 14: the new shaders' parameters are checked too.
        assert!(check_start(&pb::Start { shader: "gi".into(), ..start() }).is_ok());
        let split = |by, parts| Some(pb::Split { by, parts });
        assert_eq!(check_start(&pb::Start { split: split(1, 3), ..start() }).unwrap().split, SplitMode::Lights(3));
        assert!(check_start(&pb::Start { split: split(1, 65), ..start() }).unwrap_err().message().contains("start.split"));
        assert!(check_start(&pb::Start { split: split(1, 0), ..start() }).unwrap_err().message().contains("not 0"));
        assert!(check_start(&pb::Start { split: split(9, 2), ..start() }).unwrap_err().message().contains("SplitBy"));
        let params = HashMap::from([("max_depth".to_string(), 0.0)]);
        assert!(check_start(&pb::Start { shader: "glossy".into(), shader_params: params, ..start() }).unwrap_err().message().contains("max_depth"));
    }

    fn service(cfg: ServiceConfig) -> RendererService {
        let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
        let pool = rt.block_on(async { WorkerPool::new(vec![]).unwrap() });
        RendererService::new(Arc::new(pool), cfg)
    }

    #[test]
    fn tokens_are_checked_and_refusals_explain_themselves() {
        let svc = service(ServiceConfig { tokens: Some(Arc::new(vec!["old-token-0123456789".into(), "new-token-0123456789".into()])), ..Default::default() });
        let md = |v: Option<&str>| {
            let mut m = tonic::metadata::MetadataMap::new();
            if let Some(v) = v {
                m.insert(edgepoint_proto::auth::AUTHORIZATION, v.parse().unwrap());
            }
            m
        };
        assert!(svc.authenticate(&md(Some("Bearer new-token-0123456789"))).is_ok());
        assert!(svc.authenticate(&md(Some("bearer old-token-0123456789"))).is_ok(), "rotation: both accepted");
        for (v, why) in [(None, "requires a bearer token"), (Some("Bearer nope-0123456789012"), "invalid"), (Some("Basic abc"), "Bearer <token>")] {
            let e = svc.authenticate(&md(v)).unwrap_err();
            assert_eq!(e.code(), tonic::Code::Unauthenticated);
            assert!(e.message().contains(why), "{v:?}: {}", e.message());
        }
        let open = service(ServiceConfig::default());
        assert!(open.authenticate(&md(None)).is_ok(), "no tokens configured: open");
    }

    #[test]
    fn frames_must_fit_the_pixel_and_message_limits() {
        let svc = service(ServiceConfig { max_frame_pixels: 1000, max_message_bytes: 1 << 20, ..Default::default() });
        assert!(svc.check_frame_size(&pb::Start { width: 40, height: 25, ..start() }).is_ok());
        let e = svc.check_frame_size(&pb::Start { width: 40, height: 26, ..start() }).unwrap_err();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted);
        assert!(e.message().contains("--max-frame-pixels") && e.message().contains("1040"), "{}", e.message());
        let small = service(ServiceConfig { max_message_bytes: 200 << 10, ..Default::default() });
        let e = small.check_frame_size(&pb::Start { width: 256, height: 256, ..start() }).unwrap_err();
        assert!(e.message().contains("--max-message-mib"), "{}", e.message());
    }

    /// Issue 12 item 3: sessions draw their estimated memory from the server's budget; one
    /// that does not fit is refused with RESOURCE_EXHAUSTED naming the flag, and a finished
    /// session gives its share back.
    #[test]
    fn sessions_draw_from_the_memory_budget() {
        let s = SessionSettings::default();
        let one = SessionMemory::estimate(512, 512, DEFAULT_POINTS_PER_PIXEL, &s, rayon::current_num_threads()).total();
        let svc = service(ServiceConfig { memory: MemoryBudget::new(one * 5 / 2), ..Default::default() });
        let st = pb::Start { width: 512, height: 512, ..start() };
        let a = svc.grant_memory(&st, &s).unwrap();
        let b = svc.grant_memory(&st, &s).unwrap();
        let e = svc.grant_memory(&st, &s).unwrap_err();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted);
        assert!(e.message().contains("512x512") && e.message().contains("--max-memory-mib"), "{}", e.message());
        let e = svc.grant_memory(&pb::Start { width: 4096, height: 4096, ..start() }, &s).unwrap_err();
        assert_eq!(e.code(), tonic::Code::ResourceExhausted);
        drop(a);
        let c = svc.grant_memory(&st, &s).expect("room again once a session ends");
        assert_eq!(svc.cfg.memory.used(), 2 * one);
        drop((b, c));
        assert_eq!(svc.cfg.memory.used(), 0);
    }

    #[test]
    fn frame_meter_counts_drops_as_deltas() {
        let m = SessionMetrics::default();
        let mut meter = FrameMeter::default();
        for (dropped, ms) in [(0, 5.0), (3, 6.0), (3, f64::NAN), (7, 4.0)] {
            meter.sent(&pb::Frame { frames_dropped: dropped, total_ms: ms, ..Default::default() }, &m);
        }
        assert_eq!(m.frames.get(), 4);
        assert_eq!(m.frames_dropped.get(), 7);
        assert_eq!(m.frame_seconds.get_sample_count(), 3, "a NaN frame time is not observed");
        assert_eq!(m.frame_interval_seconds.get_sample_count(), 3);
    }
}
