//! One viewer session with the renderer: the `Renderer.Session` bidirectional stream
//! (proto/proto/edgepoint.proto) as a typed client. The first message is `start`; the server
//! answers `started`, then streams frames and, for bad later messages, `rejected` notes.
//! Also turns a `--scene` argument into the wire `SceneSource` (built-in name or files).
use anyhow::bail;
use edgepoint_proto::{self as pb, renderer_client::RendererClient, server_msg, viewer_msg};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_stream::wrappers::UnboundedReceiverStream;

/// Frames of large raw images exceed tonic's 4 MiB default; nothing the server sends is
/// meant to be refused for size.
const MAX_MESSAGE_BYTES: usize = 1 << 30;

/// Why a session call failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The URL is malformed or nothing answers there.
    #[error("cannot connect to {url}: {message}")]
    Connect { url: String, message: String },
    /// The server ended the call with a gRPC status (for a bad start: INVALID_ARGUMENT
    /// naming the problem). Displays as `CODE: message`.
    #[error("{}: {message}", code_name(*.code))]
    Status { code: tonic::Code, message: String },
    /// The server broke the session protocol (e.g. no `started` first).
    #[error("protocol error: {0}")]
    Protocol(String),
    /// The session is over; nothing more can be sent.
    #[error("the session is closed")]
    Closed,
    /// The server did not answer `start` in time.
    #[error("the server did not answer `start` within {secs} s (a large scene may still be loading: raise --start-timeout-secs)")]
    StartTimeout { secs: u64 },
    /// The connection broke under the session (the server exited, or the network failed):
    /// no status came from the server.
    #[error("lost the connection to the server (it exited, or the network failed): {0}")]
    Disconnected(String),
}

impl ClientError {
    /// The gRPC status code, when the server sent one.
    pub fn code(&self) -> Option<tonic::Code> {
        match self {
            ClientError::Status { code, .. } => Some(*code),
            _ => None,
        }
    }

    fn from_status(s: tonic::Status) -> Self {
        if is_transport_failure(&s) {
            use std::error::Error;
            let mut detail = s.message().to_string();
            let mut cur = s.source();
            while let Some(c) = cur {
                let t = c.to_string();
                if !detail.contains(&t) {
                    detail.push_str(&format!(": {t}"));
                }
                cur = c.source();
            }
            return ClientError::Disconnected(detail);
        }
        ClientError::Status { code: s.code(), message: s.message().to_string() }
    }
}

/// Whether a status was made on this side from a broken connection (tonic keeps the
/// transport error as its source), rather than sent by the server: a server that dies shows
/// up as `UNKNOWN: h2 protocol error`, which says nothing to a user.
fn is_transport_failure(s: &tonic::Status) -> bool {
    use std::error::Error;
    use tonic::Code::*;
    matches!(s.code(), Unknown | Unavailable | Internal | Cancelled)
        && (s.source().is_some() || ["h2 protocol error", "transport error", "error reading a body"].iter().any(|m| s.message().contains(m)))
}

/// Default time to wait for `started` after sending `start` (the server builds the scene
/// first: a large file takes a while).
pub const DEFAULT_START_TIMEOUT: Duration = Duration::from_secs(120);

/// How to reach a server beyond its URL: a bearer token (servers started with
/// `--token-file` require one) and, for an `https://` URL, the CA to trust and the name to
/// check (default: the web PKI roots and the URL's host).
#[derive(Debug, Clone, Default)]
pub struct ConnectOptions {
    pub token: Option<String>,
    pub tls_ca: Option<PathBuf>,
    pub tls_domain: Option<String>,
    /// How long to wait for `started` ([`DEFAULT_START_TIMEOUT`] when `None`).
    pub start_timeout: Option<Duration>,
}

/// What the server sends after `started`.
#[derive(Debug, Clone)]
pub enum Event {
    /// A rendered frame with its stats.
    Frame(pb::Frame),
    /// A later message of ours was ignored (e.g. a NaN camera); the session goes on.
    Rejected(pb::Rejected),
    /// Progress of the session's long work (scene loading on the workers, edge trees, first
    /// samples): show it instead of black frames.
    Progress(pb::Progress),
    /// The answer to a `pick`: the object under a pixel.
    Picked(pb::Picked),
}

/// A cloneable handle that sends messages into a session (e.g. from a window's key loop
/// while another task receives frames). Sending never blocks: messages are queued.
#[derive(Debug, Clone)]
pub struct SessionSender {
    tx: mpsc::UnboundedSender<pb::ViewerMsg>,
}

impl SessionSender {
    /// A sender tied to no stream: what it sends comes out of the returned receiver (for
    /// testing what a front end sends).
    pub fn detached() -> (SessionSender, mpsc::UnboundedReceiver<pb::ViewerMsg>) {
        let (tx, rx) = mpsc::unbounded_channel();
        (SessionSender { tx }, rx)
    }

    /// Sends any viewer message.
    pub fn send(&self, msg: viewer_msg::Msg) -> Result<(), ClientError> {
        self.tx.send(pb::ViewerMsg { msg: Some(msg) }).map_err(|_| ClientError::Closed)
    }

    /// Moves the camera.
    pub fn send_camera(&self, camera: pb::Camera) -> Result<(), ClientError> {
        self.send(viewer_msg::Msg::Camera(camera))
    }

    /// Moves an object (by id, or by name when `name` is set).
    pub fn send_move(&self, mv: pb::ObjectMove) -> Result<(), ClientError> {
        self.send(viewer_msg::Msg::Move(mv))
    }

    /// Changes session settings (zero fields keep their value).
    pub fn send_settings(&self, settings: pb::Settings) -> Result<(), ClientError> {
        self.send(viewer_msg::Msg::Settings(settings))
    }

    /// Asks which object is under frame position (`x`, `y`); answered by an
    /// [`Event::Picked`] with the same `id`.
    pub fn send_pick(&self, id: u64, x: f32, y: f32) -> Result<(), ClientError> {
        self.send(viewer_msg::Msg::Pick(pb::Pick { id, x, y }))
    }
}

/// An open session: send with the `send_*` methods, receive with [`Self::next_event`].
/// Dropping it ends the session (the request stream closes).
#[derive(Debug)]
pub struct SessionClient {
    sender: SessionSender,
    inbound: tonic::Streaming<pb::ServerMsg>,
}

impl SessionClient {
    /// Connects to `url` (e.g. `http://127.0.0.1:50051`), sends `start` and waits for
    /// `started`. A refused start comes back as [`ClientError::Status`] with the server's
    /// code and message (e.g. `INVALID_ARGUMENT: bunny.ply: face 12: ...`).
    pub async fn connect(url: &str, start: pb::Start) -> Result<(SessionClient, pb::Started), ClientError> {
        Self::connect_with(url, start, &ConnectOptions::default()).await
    }

    /// [`SessionClient::connect`] with a token and TLS settings. A token the server does not
    /// accept comes back as [`ClientError::Status`] with code UNAUTHENTICATED.
    pub async fn connect_with(url: &str, start: pb::Start, opts: &ConnectOptions) -> Result<(SessionClient, pb::Started), ClientError> {
        let connect_err = |message: String| ClientError::Connect { url: url.to_string(), message };
        let mut endpoint = tonic::transport::Endpoint::from_shared(url.to_string())
            .map_err(|e| connect_err(format!("invalid URL ({})", error_chain(&e))))?
            .connect_timeout(Duration::from_secs(10))
            .tcp_nodelay(true);
        let https = url.trim_start().to_ascii_lowercase().starts_with("https://");
        if https {
            let tls = edgepoint_proto::net::client_tls(opts.tls_ca.as_deref(), opts.tls_domain.as_deref()).map_err(connect_err)?;
            endpoint = endpoint.tls_config(tls).map_err(|e| connect_err(format!("TLS: {}", error_chain(&e))))?;
        } else if opts.tls_ca.is_some() || opts.tls_domain.is_some() {
            return Err(connect_err("TLS options (--tls-ca, --tls-domain) need an https:// server URL".into()));
        }
        let auth = match &opts.token {
            Some(t) => {
                edgepoint_proto::auth::check_token(t).map_err(|e| connect_err(format!("bad token: {e}")))?;
                let loopback = endpoint.uri().host().is_some_and(|h| {
                    let h = h.trim_start_matches('[').trim_end_matches(']');
                    h == "localhost" || h.parse().is_ok_and(edgepoint_proto::net::is_loopback)
                });
                if !https && !loopback {
                    tracing::warn!(%url, "sending the token without TLS: anyone on the path can read it (use an https:// URL)");
                }
                let value = edgepoint_proto::auth::bearer(t)
                    .parse::<tonic::metadata::MetadataValue<tonic::metadata::Ascii>>()
                    .map_err(|_| connect_err("the token is not a valid header value".into()))?;
                Some(value)
            }
            None => None,
        };
        let channel = endpoint.connect().await.map_err(|e| connect_err(error_chain(&e)))?;
        let mut client = RendererClient::new(channel)
            .max_decoding_message_size(MAX_MESSAGE_BYTES)
            .max_encoding_message_size(MAX_MESSAGE_BYTES);
        let (tx, rx) = mpsc::unbounded_channel();
        let sender = SessionSender { tx };
        sender.send(viewer_msg::Msg::Start(start))?;
        let mut request = tonic::Request::new(UnboundedReceiverStream::new(rx));
        if let Some(v) = auth {
            request.metadata_mut().insert(edgepoint_proto::auth::AUTHORIZATION, v);
        }
        let wait = opts.start_timeout.unwrap_or(DEFAULT_START_TIMEOUT);
        let answer = async {
            let response = client.session(request).await.map_err(ClientError::from_status)?;
            let mut inbound = response.into_inner();
            let started = match inbound.message().await {
                Ok(Some(pb::ServerMsg { msg: Some(server_msg::Msg::Started(s)) })) => s,
                Ok(Some(other)) => {
                    return Err(ClientError::Protocol(format!("expected `started` first, got {}", msg_kind(&other))))
                }
                Ok(None) => return Err(ClientError::Protocol("the server closed the session before `started`".into())),
                Err(status) => return Err(ClientError::from_status(status)),
            };
            Ok((inbound, started))
        };
        let (inbound, started) =
            tokio::time::timeout(wait, answer).await.map_err(|_| ClientError::StartTimeout { secs: wait.as_secs() })??;
        Ok((SessionClient { sender, inbound }, started))
    }

    /// A handle for sending from elsewhere (another task or thread).
    pub fn sender(&self) -> SessionSender {
        self.sender.clone()
    }

    /// Moves the camera.
    pub fn send_camera(&self, camera: pb::Camera) -> Result<(), ClientError> {
        self.sender.send_camera(camera)
    }

    /// Moves an object.
    pub fn send_move(&self, mv: pb::ObjectMove) -> Result<(), ClientError> {
        self.sender.send_move(mv)
    }

    /// Changes session settings.
    pub fn send_settings(&self, settings: pb::Settings) -> Result<(), ClientError> {
        self.sender.send_settings(settings)
    }

    /// The next frame or rejection; `None` when the server ended the session normally,
    /// `Some(Err(..))` when it ended it with an error status.
    pub async fn next_event(&mut self) -> Option<Result<Event, ClientError>> {
        loop {
            return match self.inbound.message().await {
                Ok(Some(m)) => match m.msg {
                    Some(server_msg::Msg::Frame(f)) => Some(Ok(Event::Frame(f))),
                    Some(server_msg::Msg::Rejected(r)) => Some(Ok(Event::Rejected(r))),
                    Some(server_msg::Msg::Progress(p)) => Some(Ok(Event::Progress(p))),
                    Some(server_msg::Msg::Picked(p)) => Some(Ok(Event::Picked(p))),
                    Some(server_msg::Msg::Started(_)) => {
                        Some(Err(ClientError::Protocol("a second `started` in one session".into())))
                    }
                    // A message kind newer than this viewer: skip it.
                    None => continue,
                },
                Ok(None) => None,
                Err(status) => Some(Err(ClientError::from_status(status))),
            };
        }
    }
}

fn msg_kind(m: &pb::ServerMsg) -> &'static str {
    match &m.msg {
        Some(server_msg::Msg::Started(_)) => "started",
        Some(server_msg::Msg::Frame(_)) => "frame",
        Some(server_msg::Msg::Rejected(_)) => "rejected",
        Some(server_msg::Msg::Progress(_)) => "progress",
        Some(server_msg::Msg::Picked(_)) => "picked",
        None => "an empty message",
    }
}

/// The error and its sources, joined (tonic's transport errors say little on their own).
fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        let t = c.to_string();
        if !s.contains(&t) {
            s.push_str(": ");
            s.push_str(&t);
        }
        cur = c.source();
    }
    s
}

/// The canonical upper-case name of a gRPC status code (`INVALID_ARGUMENT`).
pub fn code_name(code: tonic::Code) -> &'static str {
    use tonic::Code::*;
    match code {
        Ok => "OK",
        Cancelled => "CANCELLED",
        Unknown => "UNKNOWN",
        InvalidArgument => "INVALID_ARGUMENT",
        DeadlineExceeded => "DEADLINE_EXCEEDED",
        NotFound => "NOT_FOUND",
        AlreadyExists => "ALREADY_EXISTS",
        PermissionDenied => "PERMISSION_DENIED",
        ResourceExhausted => "RESOURCE_EXHAUSTED",
        FailedPrecondition => "FAILED_PRECONDITION",
        Aborted => "ABORTED",
        OutOfRange => "OUT_OF_RANGE",
        Unimplemented => "UNIMPLEMENTED",
        Internal => "INTERNAL",
        Unavailable => "UNAVAILABLE",
        DataLoss => "DATA_LOSS",
        Unauthenticated => "UNAUTHENTICATED",
    }
}

/// The wire camera for a scene camera.
pub fn camera_to_wire(c: &edgepoint_scene::Camera) -> pb::Camera {
    pb::Camera {
        eye: Some(c.eye.into()),
        target: Some(c.target.into()),
        up: Some(c.up.into()),
        fov_y_degrees: c.fov_y_degrees,
    }
}

/// The scene camera for a wire camera (absent vectors read as zero; the result may need
/// [`edgepoint_scene::Camera::validate`]).
pub fn camera_from_wire(c: &pb::Camera) -> edgepoint_scene::Camera {
    edgepoint_scene::Camera {
        eye: pb::vec3_or_zero(&c.eye),
        target: pb::vec3_or_zero(&c.target),
        up: pb::vec3_or_zero(&c.up),
        fov_y_degrees: c.fov_y_degrees,
    }
}

/// Turns a `--scene` argument into a scene source. A bare name (no path separator, no
/// extension, and no file of that name) is a built-in scene (`cornell`); anything else is
/// a file path (`.ply`, `.obj`, `.xml`, `.gltf`, `.glb`, each also `.gz`), sent together
/// with the files it references ([`edgepoint_scene::load::gather`]). Errors name the path;
/// a missing referenced file is a warning naming the line that references it.
/// Built-ins made from shared data (`grid-dragon`) are sent as their description plus the
/// data files, found as [`edgepoint_scene::data`] describes.
pub fn scene_source_from_arg(arg: &str) -> anyhow::Result<pb::SceneSource> {
    scene_source_from_arg_in(arg, None)
}

/// [`scene_source_from_arg`] with the shared data directory given (`--data-dir`).
pub fn scene_source_from_arg_in(arg: &str, data_dir: Option<&Path>) -> anyhow::Result<pb::SceneSource> {
    if arg.trim().is_empty() {
        bail!("empty scene: give a built-in name (e.g. cornell) or a .ply / .obj file path");
    }
    let path = Path::new(arg);
    let has_separator = arg.contains('/') || arg.contains(std::path::MAIN_SEPARATOR);
    if !has_separator && path.extension().is_none() && !path.is_file() {
        return match edgepoint_scene::data::builtin_files(arg, data_dir).map_err(anyhow::Error::msg)? {
            None => Ok(pb::builtin_source(arg)),
            Some(files) => Ok(pb::files_source(files.into_iter().map(|f| (f.name, f.data)).collect())),
        };
    }
    let file_name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let inner = file_name.strip_suffix(".gz").unwrap_or(&file_name);
    let ext = Path::new(inner).extension().map(|e| e.to_string_lossy().into_owned());
    match ext.as_deref() {
        // The scene file and every file it references (an OBJ's mtllibs, a Mitsuba scene's
        // meshes and textures, a glTF's buffers and images), read by the scene crate's one
        // gathering rule: only files inside the scene file's directory are sent (never
        // `/etc/passwd` or `../..`); one that may not be read, or is missing, is a warning.
        Some("ply" | "obj" | "xml" | "gltf" | "glb") => {
            let files = edgepoint_scene::load::gather(path).map_err(|e| anyhow::anyhow!("scene file {e}"))?;
            Ok(pb::files_source(files.into_iter().map(|f| (f.name, f.data)).collect()))
        }
        Some(other) => bail!(
            "{}: unsupported scene file type '.{other}' (supported: {SCENE_FILE_TYPES})",
            path.display()
        ),
        None => bail!(
            "{}: a scene file needs one of the extensions {SCENE_FILE_TYPES} (built-in scenes are named without one: {})",
            path.display(),
            builtin_names()
        ),
    }
}

/// The camera (the one called `camera_name`, else the first) and film size a scene file
/// of `source` brings, read from its main file only; nothing for a built-in.
pub fn scene_file_view(source: &pb::SceneSource, camera_name: Option<&str>) -> anyhow::Result<edgepoint_scene::load::FileView> {
    use edgepoint_proto::scene_source::Source;
    let Some(Source::Files(f)) = &source.source else {
        if let Some(n) = camera_name {
            bail!("--camera-name {n}: built-in scenes have one camera and no camera names");
        }
        return Ok(Default::default());
    };
    let main: Vec<edgepoint_scene::load::NamedBytes> =
        f.files.iter().take(1).map(|nf| edgepoint_scene::load::NamedBytes { name: nf.name.clone(), data: nf.data.clone() }).collect();
    edgepoint_scene::load::file_view(&main, camera_name).map_err(|e| anyhow::anyhow!("{e}"))
}

/// The scene file types `--scene` takes.
pub const SCENE_FILE_TYPES: &str = ".ply, .obj, .xml (Mitsuba 3), .gltf, .glb, each also .gz";

fn builtin_names() -> String {
    edgepoint_scene::builtin::BUILTINS.iter().map(|b| b.0).collect::<Vec<_>>().join(", ")
}


#[cfg(test)]
mod tests {
    use super::*;
    use edgepoint_proto::scene_source::Source;

    fn files_of(src: &pb::SceneSource) -> Vec<(String, Vec<u8>)> {
        match &src.source {
            Some(Source::Files(f)) => f.files.iter().map(|f| (f.name.clone(), f.data.clone())).collect(),
            other => panic!("expected files, got {other:?}"),
        }
    }

    #[test]
    fn data_builtins_are_sent_with_their_data_or_explained() {
        // From the viewer crate the worktree's shared/data is found above the working
        // directory.
        let src = scene_source_from_arg("grid-dragon").unwrap();
        let files = files_of(&src);
        assert_eq!(files[0].0, "grid-dragon.builtin");
        assert_eq!(files[1].0, "dragon/dragon_vrip.ply");
        assert!(files[1].1.len() > 10_000_000);
        let nowhere = std::env::temp_dir().join("edgepoint-no-data-here");
        let e = format!("{:#}", scene_source_from_arg_in("grid-dragon", Some(&nowhere)).unwrap_err());
        assert!(e.contains("dragon_vrip.ply") && e.contains("--data-dir"), "{e}");
    }

    #[test]
    fn bare_names_are_builtins() {
        for name in ["cornell", "cornell-point", "no-such-scene"] {
            let src = scene_source_from_arg(name).unwrap();
            assert_eq!(src.source, Some(Source::Builtin(name.to_string())));
        }
    }

    #[test]
    fn ply_paths_are_read_from_disk() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("thing.PLY");
        std::fs::write(&p, b"ply\nformat ascii 1.0\nend_header\n").unwrap();
        let src = scene_source_from_arg(p.to_str().unwrap()).unwrap();
        assert_eq!(files_of(&src), vec![("thing.PLY".to_string(), b"ply\nformat ascii 1.0\nend_header\n".to_vec())]);
    }

    #[test]
    fn obj_paths_bring_their_mtllibs() {
        let dir = tempfile::tempdir().unwrap();
        let obj = b"# box\nmtllib a.mtl  b.mtl\nv 0 0 0\nmtllib a.mtl\nf 1 1 1\n".to_vec();
        std::fs::write(dir.path().join("box.obj"), &obj).unwrap();
        std::fs::write(dir.path().join("a.mtl"), b"newmtl red\nKd 1 0 0\n").unwrap();
        std::fs::write(dir.path().join("b.mtl"), b"newmtl blue\nKd 0 0 1\n").unwrap();
        let src = scene_source_from_arg(dir.path().join("box.obj").to_str().unwrap()).unwrap();
        let files = files_of(&src);
        let names: Vec<&str> = files.iter().map(|f| f.0.as_str()).collect();
        assert_eq!(names, ["box.obj", "a.mtl", "b.mtl"], "main file first, each mtllib once");
        assert_eq!(files[0].1, obj);
        assert_eq!(files[2].1, b"newmtl blue\nKd 0 0 1\n");
    }

    #[test]
    fn missing_files_are_named() {
        let err = scene_source_from_arg("/no/such/dir/bunny.ply").unwrap_err();
        let msg = format!("{err:#}");
        assert!(msg.contains("/no/such/dir/bunny.ply"), "{msg}");

        // A missing mtllib is a warning, as in the loader: the OBJ goes alone.
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("m.obj"), b"v 0 0 0\n\nmtllib gone.mtl\n").unwrap();
        let src = scene_source_from_arg(dir.path().join("m.obj").to_str().unwrap()).unwrap();
        assert_eq!(files_of(&src).len(), 1);

        // A relative path with a separator is a file even without an extension.
        let msg = format!("{:#}", scene_source_from_arg("scenes/cornell").unwrap_err());
        assert!(msg.contains("scenes/cornell") && msg.contains(".ply"), "{msg}");
    }

    /// Issue 12 item 6: an OBJ naming a library outside its directory (absolute, `..`, or a
    /// link out) does not make the viewer send that file.
    #[test]
    fn mtllibs_outside_the_objs_directory_are_not_sent() {
        let dir = tempfile::tempdir().unwrap();
        let scene = dir.path().join("scene");
        std::fs::create_dir_all(&scene).unwrap();
        std::fs::write(dir.path().join("secret.mtl"), b"newmtl secret\n").unwrap();
        std::fs::write(scene.join("ok.mtl"), b"newmtl ok\n").unwrap();
        #[cfg(unix)]
        std::os::unix::fs::symlink(dir.path().join("secret.mtl"), scene.join("link.mtl")).unwrap();
        let obj = b"mtllib /etc/passwd ../secret.mtl link.mtl ok.mtl\nv 0 0 0\n";
        std::fs::write(scene.join("m.obj"), obj).unwrap();
        let src = scene_source_from_arg(scene.join("m.obj").to_str().unwrap()).unwrap();
        let names: Vec<String> = files_of(&src).into_iter().map(|f| f.0).collect();
        assert_eq!(names, ["m.obj", "ok.mtl"]);
    }

    #[test]
    fn unsupported_extensions_are_refused() {
        let msg = format!("{:#}", scene_source_from_arg("model.fbx").unwrap_err());
        assert!(msg.contains("model.fbx") && msg.contains(".gltf"), "{msg}");
    }

    #[test]
    fn status_errors_display_code_and_message() {
        let e = ClientError::from_status(tonic::Status::invalid_argument("bunny.ply: face 12: index 99 out of range"));
        assert_eq!(e.to_string(), "INVALID_ARGUMENT: bunny.ply: face 12: index 99 out of range");
        assert_eq!(e.code(), Some(tonic::Code::InvalidArgument));
        // Issue 12 item 12: a broken connection is said to be one.
        let broken = tonic::Status::from_error(Box::new(std::io::Error::new(std::io::ErrorKind::ConnectionReset, "connection reset by peer")));
        let e = ClientError::from_status(broken);
        assert!(e.to_string().starts_with("lost the connection to the server") && e.to_string().contains("reset"), "{e}");
        let h2 = ClientError::from_status(tonic::Status::unknown("h2 protocol error: error reading a body from connection"));
        assert!(matches!(h2, ClientError::Disconnected(_)), "{h2}");
        let sent = ClientError::from_status(tonic::Status::unavailable("the renderer is shutting down"));
        assert_eq!(sent.to_string(), "UNAVAILABLE: the renderer is shutting down", "a status the server sent stays as it is");
    }

    #[test]
    fn cameras_round_trip_through_the_wire() {
        let c = edgepoint_scene::Camera {
            eye: glam::Vec3::new(1.0, 2.0, 3.0),
            target: glam::Vec3::new(0.0, 0.5, -1.0),
            up: glam::Vec3::Y,
            fov_y_degrees: 39.3,
        };
        assert_eq!(camera_from_wire(&camera_to_wire(&c)), c);
    }
}
