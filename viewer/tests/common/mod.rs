//! Test doubles for the viewer's integration tests: an in-process `Renderer` service that
//! speaks the session protocol with synthetic frames (so the viewer is tested without the
//! real server), and fake `edgepoint-worker` / `edgepoint-server` executables (shell
//! scripts) for the local-cluster launcher.
#![allow(dead_code)]
use edgepoint_proto::{self as pb, renderer_server::{Renderer, RendererServer}, server_msg, viewer_msg, FrameEncoding};
use glam::{Affine3A, Vec3};
use image::RgbImage;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_stream::wrappers::{ReceiverStream, TcpListenerStream};
use tonic::{Request, Response, Status, Streaming};

/// The start message a broken scene name provokes, as a real server would phrase it.
pub const BROKEN_MESSAGE: &str = "broken.ply: face 12: vertex index 99 out of range (the file has 40 vertices)";

/// Everything the mock saw from viewers.
#[derive(Default, Debug)]
pub struct Seen {
    pub starts: Vec<pb::Start>,
    pub messages: Vec<viewer_msg::Msg>,
}

/// The synthetic frame `seq` at `w` x `h`: red ramps along x, green along y, blue is the
/// sequence number, so a test can check exactly which frame a PNG holds.
pub fn expected_image(seq: u64, w: u32, h: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 255 / w.max(1)) as u8, (y * 255 / h.max(1)) as u8, (seq % 256) as u8]))
}

fn encode(img: &RgbImage, enc: i32) -> Vec<u8> {
    let format = match FrameEncoding::try_from(enc).unwrap_or(FrameEncoding::Qoi) {
        FrameEncoding::RawRgb8 => return img.as_raw().clone(),
        FrameEncoding::Png => image::ImageFormat::Png,
        FrameEncoding::Jpeg => image::ImageFormat::Jpeg,
        _ => image::ImageFormat::Qoi,
    };
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, format).unwrap();
    buf.into_inner()
}

/// What `started` says about the mock scene: two objects, a camera looking at (0, 1, 0).
pub fn mock_started() -> pb::Started {
    let cam = edgepoint_scene::Camera {
        eye: Vec3::new(0.0, 1.0, 4.0),
        target: Vec3::new(0.0, 1.0, 0.0),
        up: Vec3::Y,
        fov_y_degrees: 40.0,
    };
    pb::Started {
        session_id: "mock-1".into(),
        scene_hash: "00".repeat(32),
        objects: vec![
            pb::SceneObject { id: 0, name: "floor".into(), transform: Some(pb::affine_to_wire(&Affine3A::IDENTITY)), ..Default::default() },
            pb::SceneObject {
                id: 1,
                name: "tallbox".into(),
                transform: Some(pb::affine_to_wire(&Affine3A::from_translation(Vec3::new(0.5, 0.0, 0.0)))),
                ..Default::default()
            },
        ],
        camera: Some(edgepoint_viewer::client::camera_to_wire(&cam)),
        workers: 2,
        scene_min: Some(Vec3::new(-1.0, 0.0, -1.0).into()),
        scene_max: Some(Vec3::new(1.0, 2.0, 1.0).into()),
        lights: 1,
        orbit: None,
    }
}

struct Mock {
    seen: Arc<Mutex<Seen>>,
    /// Frames per session before the mock ends the stream normally (0 = unlimited).
    frame_limit: u64,
    /// Send each frame after the first only once a viewer message has arrived since the
    /// previous one (or 2 s have passed): a scripted viewer's messages then all reach the
    /// mock before the run ends, however loaded the machine.
    paced: bool,
}

#[tonic::async_trait]
impl Renderer for Mock {
    type SessionStream = ReceiverStream<Result<pb::ServerMsg, Status>>;

    async fn session(&self, req: Request<Streaming<pb::ViewerMsg>>) -> Result<Response<Self::SessionStream>, Status> {
        let mut inbound = req.into_inner();
        let start = match inbound.message().await?.and_then(|m| m.msg) {
            Some(viewer_msg::Msg::Start(s)) => s,
            _ => return Err(Status::invalid_argument("the first message must be `start`")),
        };
        if let Some(pb::scene_source::Source::Builtin(name)) = start.scene.as_ref().and_then(|s| s.source.clone()) {
            if name == "broken" {
                return Err(Status::invalid_argument(BROKEN_MESSAGE));
            }
        }
        if start.width == 0 || start.height == 0 {
            return Err(Status::invalid_argument("image size must be positive"));
        }
        self.seen.lock().unwrap().starts.push(start.clone());
        let (tx, rx) = mpsc::channel(2);
        let limit = self.frame_limit;
        let (paced, arrived) = (self.paced, Arc::new(tokio::sync::Notify::new()));
        // Frames report the newest camera the viewer sent, as the real server does.
        let scene_cam = edgepoint_viewer::client::camera_from_wire(mock_started().camera.as_ref().unwrap());
        let first = match &start.camera {
            Some(c) => pb::camera_over(c, &scene_cam).map_err(Status::invalid_argument)?,
            None => scene_cam,
        };
        let camera = Arc::new(Mutex::new(Some(edgepoint_viewer::client::camera_to_wire(&first))));
        let camera_in = camera.clone();
        let arrived_in = arrived.clone();
        let frames_tx = tx.clone();
        tokio::spawn(async move {
            let started = pb::ServerMsg { msg: Some(server_msg::Msg::Started(mock_started())) };
            if frames_tx.send(Ok(started)).await.is_err() {
                return;
            }
            let mut seq = 0u64;
            while limit == 0 || seq < limit {
                if paced && seq > 0 {
                    let _ = tokio::time::timeout(Duration::from_secs(2), arrived.notified()).await;
                }
                seq += 1;
                let img = expected_image(seq, start.width, start.height);
                let encoding = if start.encoding == 0 { FrameEncoding::Qoi as i32 } else { start.encoding };
                let frame = pb::Frame {
                    sequence: seq,
                    width: start.width,
                    height: start.height,
                    encoding,
                    data: encode(&img, encoding),
                    stages: vec![
                        pb::StageTime { stage: "reproject".into(), ms: 1.0 },
                        pb::StageTime { stage: "reconstruct".into(), ms: 2.0 },
                    ],
                    total_ms: 3.0,
                    samples_used: 10,
                    samples_requested: 12,
                    live_workers: 2,
                    pixels: Some(pb::PixelCounts { with_point: 7, ..Default::default() }),
                    camera: *camera.lock().unwrap(),
                    ..Default::default()
                };
                if frames_tx.send(Ok(pb::ServerMsg { msg: Some(server_msg::Msg::Frame(frame)) })).await.is_err() {
                    return;
                }
                tokio::time::sleep(Duration::from_millis(2)).await;
            }
        });
        let seen = self.seen.clone();
        // Weak: the response stream must end when the frame task does, even while the
        // viewer keeps its side open.
        let tx = tx.downgrade();
        tokio::spawn(async move {
            while let Ok(Some(m)) = inbound.message().await {
                let Some(msg) = m.msg else { continue };
                if let viewer_msg::Msg::Camera(c) = &msg {
                    *camera_in.lock().unwrap() = Some(*c);
                    if c.eye.as_ref().is_some_and(|e| !e.x.is_finite()) {
                        let r = pb::Rejected { code: 3, message: "camera eye is not finite".into() };
                        if let Some(tx) = tx.upgrade() {
                            let _ = tx.send(Ok(pb::ServerMsg { msg: Some(server_msg::Msg::Rejected(r)) })).await;
                        }
                    }
                }
                seen.lock().unwrap().messages.push(msg);
                arrived_in.notify_one();
            }
        });
        Ok(Response::new(ReceiverStream::new(rx)))
    }
}

/// A mock renderer on 127.0.0.1:<free port>, served by its own runtime.
pub struct MockServer {
    pub addr: SocketAddr,
    pub seen: Arc<Mutex<Seen>>,
    _rt: tokio::runtime::Runtime,
}

impl MockServer {
    pub fn start(frame_limit: u64) -> MockServer {
        Self::start_with(frame_limit, false)
    }

    /// A mock that sends each frame after the first only once the viewer has sent
    /// something since the previous one (see `Mock::paced`).
    pub fn start_paced(frame_limit: u64) -> MockServer {
        Self::start_with(frame_limit, true)
    }

    fn start_with(frame_limit: u64, paced: bool) -> MockServer {
        let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().unwrap();
        let seen = Arc::new(Mutex::new(Seen::default()));
        let listener = rt.block_on(tokio::net::TcpListener::bind("127.0.0.1:0")).unwrap();
        let addr = listener.local_addr().unwrap();
        let svc = RendererServer::new(Mock { seen: seen.clone(), frame_limit, paced });
        rt.spawn(async move {
            tonic::transport::Server::builder()
                .add_service(svc)
                .serve_with_incoming(TcpListenerStream::new(listener))
                .await
                .unwrap();
        });
        MockServer { addr, seen, _rt: rt }
    }

    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }
}

/// Writes an executable shell script.
pub fn write_script(path: &Path, body: &str) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::write(path, format!("#!/bin/sh\n{body}")).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// A directory with fake `edgepoint-worker` and `edgepoint-server` scripts. Each appends
/// "PID ARGS..." to `DIR/<name>.log` and prints a `listening` line: a worker echoes its
/// `--listen` address (or a made-up port for `:0`), the server prints `server_addr`.
pub fn fake_bin_dir(dir: &Path, server_addr: SocketAddr) -> PathBuf {
    let log = |n: &str| dir.join(format!("{n}.log")).display().to_string();
    write_script(
        &dir.join("edgepoint-worker"),
        &format!(
            r#"echo "$$ $*" >> '{log}'
addr="$2"
case "$addr" in *:0) addr="127.0.0.1:$((20000 + $$ % 20000))";; esac
echo "worker starting on $addr" >&2
echo "listening $addr"
exec sleep 600
"#,
            log = log("edgepoint-worker")
        ),
    );
    write_script(
        &dir.join("edgepoint-server"),
        &format!(
            r#"echo "$$ $*" >> '{log}'
echo "listening {server_addr}"
exec sleep 600
"#,
            log = log("edgepoint-server")
        ),
    );
    dir.to_path_buf()
}

/// The (pid, args) lines a fake binary logged.
pub fn fake_log(dir: &Path, name: &str) -> Vec<(i32, String)> {
    let text = std::fs::read_to_string(dir.join(format!("{name}.log"))).unwrap_or_default();
    text.lines()
        .map(|l| {
            let (pid, args) = l.split_once(' ').unwrap_or((l, ""));
            (pid.parse().unwrap(), args.to_string())
        })
        .collect()
}

/// Whether process `pid` exists (zombies count as gone: they have exited).
pub fn alive(pid: i32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => {
            // The state field follows the parenthesised command name.
            let state = stat.rsplit_once(')').and_then(|(_, r)| r.trim_start().chars().next());
            !matches!(state, Some('Z') | Some('X'))
        }
        Err(_) => false,
    }
}

/// Polls `cond` every 20 ms for up to `secs` seconds.
pub fn eventually(secs: u64, mut cond: impl FnMut() -> bool) -> bool {
    let deadline = std::time::Instant::now() + Duration::from_secs(secs);
    while std::time::Instant::now() < deadline {
        if cond() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    cond()
}
