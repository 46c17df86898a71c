//! The `Renderer` gRPC service (proto `edgepoint.v1.Renderer`): one bidirectional stream per
//! viewer. The first message must be `start`; it is validated (image size, encoding,
//! camera, settings, shader), the scene is built on a blocking thread (a malformed file is
//! refused with INVALID_ARGUMENT naming the file and line), a [`Session`] starts, and the
//! server answers `started` and then streams frames. Later bad messages are answered with
//! `rejected` and change nothing. Each session is isolated: its frame loop runs on its own
//! thread, so a failing session never stops another.
use crate::reference::LogProgress;
use crate::session::{camera_from_wire, camera_to_wire, splitmix64, Input, Session, SessionParams, SessionSettings, DEFAULT_POINTS_PER_PIXEL};
use crate::workers::WorkerPool;
use edgepoint_proto as pb;
use edgepoint_proto::renderer_server::{Renderer, RendererServer};
use edgepoint_proto::viewer_msg::Msg as ViewerIn;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

/// Largest image side accepted.
pub const MAX_IMAGE_SIDE: u32 = 8192;
/// Shader used when `start.shader` is empty.
pub const DEFAULT_SHADER: &str = "direct";
/// How long `start` waits for workers to list their shaders before trusting the name.
const SHADER_QUERY_TIMEOUT: Duration = Duration::from_secs(2);

/// Service options.
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    /// Sessions allowed at once; more are refused with RESOURCE_EXHAUSTED.
    pub max_sessions: usize,
    /// Render Cache size per pixel.
    pub points_per_pixel: f32,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        ServiceConfig { max_sessions: 16, points_per_pixel: DEFAULT_POINTS_PER_PIXEL }
    }
}

/// The renderer service. Clone-free: wrap it with [`RendererService::into_server`].
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
}

/// A session slot; released on drop.
struct Slot(Arc<ServiceState>);
impl Drop for Slot {
    fn drop(&mut self) {
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
        RendererServer::new(self).max_decoding_message_size(max_message_bytes).max_encoding_message_size(max_message_bytes)
    }

    fn acquire_slot(&self) -> Result<Slot, Status> {
        let max = self.cfg.max_sessions;
        self.state
            .active
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| (n < max).then_some(n + 1))
            .map_err(|n| Status::resource_exhausted(format!("{n} sessions running, the limit is {max} (--max-sessions)")))?;
        Ok(Slot(self.state.clone()))
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
    for (k, v) in &s.shader_params {
        if !v.is_finite() {
            return Err(invalid(format!("start.shader_params[{k}] is not finite ({v})")));
        }
    }
    let settings = match &s.settings {
        Some(st) => SessionSettings::default().with(st).map_err(|e| invalid(format!("start: {e}")))?,
        None => SessionSettings::default(),
    };
    if let Some(c) = &s.camera {
        camera_from_wire(c).map_err(|e| invalid(format!("start.camera: {e}")))?;
    }
    if s.scene.is_none() {
        return Err(invalid("start.scene is missing: name a built-in or send files"));
    }
    Ok(StartChecked { encoding, shader, settings })
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
        })),
    }
}

#[tonic::async_trait]
impl Renderer for RendererService {
    type SessionStream = ReceiverStream<Result<pb::ServerMsg, Status>>;

    async fn session(&self, request: Request<Streaming<pb::ViewerMsg>>) -> Result<Response<Self::SessionStream>, Status> {
        let peer = request.remote_addr();
        let mut inbound = request.into_inner();
        if self.state.shutting_down.load(Ordering::SeqCst) {
            return Err(Status::unavailable("the renderer is shutting down"));
        }
        let start = match inbound.message().await? {
            Some(pb::ViewerMsg { msg: Some(ViewerIn::Start(s)) }) => s,
            Some(other) => {
                let what = match other.msg {
                    Some(ViewerIn::Camera(_)) => "camera",
                    Some(ViewerIn::Move(_)) => "move",
                    Some(ViewerIn::Settings(_)) => "settings",
                    _ => "an empty message",
                };
                return Err(invalid(format!("the first message must be `start`, got {what}")));
            }
            None => return Err(invalid("the stream ended before `start`")),
        };
        if self.pool.is_empty() {
            return Err(Status::failed_precondition("no shader workers configured (start the server with --worker URL)"));
        }
        let checked = check_start(&start)?;
        if let Some(shaders) = self.pool.shaders(SHADER_QUERY_TIMEOUT).await {
            if !shaders.contains(&checked.shader) {
                return Err(invalid(format!("unknown shader '{}' (the workers offer: {})", checked.shader, shaders.join(", "))));
            }
        }
        let slot = self.acquire_slot()?;

        let source = start.scene.clone().expect("checked in check_start");
        let hash = pb::scene_hash(&source);
        let what = pb::describe_source(&source);
        tracing::info!(?peer, scene = %what, width = start.width, height = start.height, "session starting");
        let src = source.clone();
        let scene = tokio::task::spawn_blocking(move || pb::scene_from_source(&src, &LogProgress::new("scene")))
            .await
            .map_err(|e| Status::internal(format!("scene build task failed: {e}")))?
            .map_err(|e| invalid(e.to_string()))?;
        let scene = Arc::new(scene);
        let camera = match &start.camera {
            Some(c) => camera_from_wire(c).map_err(|e| invalid(format!("start.camera: {e}")))?,
            None => scene.camera,
        };

        let n = self.state.next.fetch_add(1, Ordering::Relaxed);
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0);
        let seed = splitmix64(nanos ^ n.rotate_left(32));
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
                    m = inbound.message() => m,
                    _ = out_in.done() => break,
                };
                match msg {
                    Ok(Some(pb::ViewerMsg { msg })) => {
                        let input = match msg {
                            Some(ViewerIn::Camera(c)) => Input::Camera(c),
                            Some(ViewerIn::Move(m)) => Input::Move(m),
                            Some(ViewerIn::Settings(s)) => Input::Settings(s),
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
        tokio::spawn(async move {
            let session = session; // dropped (closing the frame loop) when this task ends
            if tx.send(Ok(started)).await.is_err() {
                return;
            }
            loop {
                tokio::select! {
                    m = output.next() => match m {
                        Some(m) => {
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
        Ok(Response::new(ReceiverStream::new(rx)))
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
        let bad_cam = pb::Camera { fov_y_degrees: 40.0, ..Default::default() };
        assert!(check_start(&pb::Start { camera: Some(bad_cam), ..start() }).unwrap_err().message().contains("camera"));
        let bad_settings = pb::Settings { sparseness: -2.0, ..Default::default() };
        assert!(check_start(&pb::Start { settings: Some(bad_settings), ..start() }).unwrap_err().message().contains("sparseness"));
        let params = HashMap::from([("ambient".to_string(), f64::NAN)]);
        assert!(check_start(&pb::Start { shader_params: params, ..start() }).unwrap_err().message().contains("ambient"));
    }
}
