//! Shared helpers of the in-process integration tests: a real shader worker (from the
//! edgepoint-worker crate) on its own runtime so a test can make it vanish, the Renderer
//! service on 127.0.0.1:0, and viewer-side stream helpers.
#![allow(dead_code)]
use edgepoint_proto as pb;
use edgepoint_proto::renderer_client::RendererClient;
use edgepoint_proto::server_msg::Msg as Out;
use edgepoint_server::service::{RendererService, ServiceConfig, ShutdownHandle};
use edgepoint_server::workers::{WorkerPool, DEFAULT_MAX_MESSAGE_BYTES};
use std::sync::Arc;
use std::time::Duration;
use tokio_stream::wrappers::{ReceiverStream, TcpListenerStream};

/// A shader worker serving on 127.0.0.1 from its own runtime (on its own thread). Dropping
/// it (or calling [`Worker::kill`]) drops that runtime: every task, connection and socket of
/// the worker disappears at once, as when a worker process dies.
pub struct Worker {
    pub url: String,
    kill: Option<std::sync::mpsc::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Worker {
    pub fn spawn() -> Worker {
        let (addr_tx, addr_rx) = std::sync::mpsc::channel();
        let (kill_tx, kill_rx) = std::sync::mpsc::channel::<()>();
        let thread = std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
            rt.block_on(async {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
                addr_tx.send(listener.local_addr().unwrap()).unwrap();
                let svc = edgepoint_worker::service::WorkerService::new(4, 2).unwrap();
                let svc = edgepoint_proto::shader_worker_server::ShaderWorkerServer::new(svc)
                    .max_decoding_message_size(DEFAULT_MAX_MESSAGE_BYTES)
                    .max_encoding_message_size(DEFAULT_MAX_MESSAGE_BYTES);
                tokio::spawn(
                    tonic::transport::Server::builder()
                        .add_service(svc)
                        .serve_with_incoming(TcpListenerStream::new(listener)),
                );
            });
            // Park until killed (or the test ends), then drop the runtime with everything.
            let _ = kill_rx.recv();
            rt.shutdown_background();
        });
        let addr = addr_rx.recv().unwrap();
        Worker { url: format!("http://{addr}"), kill: Some(kill_tx), thread: Some(thread) }
    }

    pub fn kill(&mut self) {
        if let Some(k) = self.kill.take() {
            let _ = k.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.kill();
    }
}

/// The Renderer service on 127.0.0.1:0 in the current runtime.
pub async fn spawn_renderer(workers: Vec<String>, max_sessions: usize) -> (String, ShutdownHandle) {
    let pool = WorkerPool::new(workers).unwrap();
    let svc = RendererService::new(Arc::new(pool), ServiceConfig { max_sessions, ..Default::default() });
    let handle = svc.shutdown_handle();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(
        tonic::transport::Server::builder()
            .add_service(svc.into_server(DEFAULT_MAX_MESSAGE_BYTES))
            .serve_with_incoming(TcpListenerStream::new(listener)),
    );
    (format!("http://{addr}"), handle)
}

/// A viewer's side of one session.
pub struct Viewer {
    pub tx: tokio::sync::mpsc::Sender<pb::ViewerMsg>,
    pub rx: tonic::Streaming<pb::ServerMsg>,
}

pub fn start_msg(scene: pb::SceneSource, width: u32, height: u32) -> pb::ViewerMsg {
    pb::ViewerMsg {
        msg: Some(pb::viewer_msg::Msg::Start(pb::Start {
            scene: Some(scene),
            width,
            height,
            encoding: pb::FrameEncoding::Qoi as i32,
            // Dense sampling and a high frame cap keep the tests short.
            settings: Some(pb::Settings { sparseness: 8.0, max_fps: 100.0, batch_size: 64, ..Default::default() }),
            ..Default::default()
        })),
    }
}

/// Opens a session with `first` as the first message; the error is the server's status.
pub async fn open(addr: &str, first: pb::ViewerMsg) -> Result<Viewer, tonic::Status> {
    let mut client = RendererClient::connect(addr.to_string()).await.expect("renderer reachable");
    let (tx, rx) = tokio::sync::mpsc::channel(16);
    tx.send(first).await.unwrap();
    let rx = client.session(ReceiverStream::new(rx)).await?.into_inner();
    Ok(Viewer { tx, rx })
}

impl Viewer {
    /// The next message, or panics after `secs` seconds.
    pub async fn next(&mut self, secs: u64) -> Out {
        match tokio::time::timeout(Duration::from_secs(secs), self.rx.message()).await {
            Ok(Ok(Some(pb::ServerMsg { msg: Some(m) }))) => m,
            Ok(Ok(Some(_))) => panic!("empty server message"),
            Ok(Ok(None)) => panic!("server ended the session"),
            Ok(Err(s)) => panic!("session failed: {s}"),
            Err(_) => panic!("no message within {secs} s"),
        }
    }

    pub async fn started(&mut self) -> pb::Started {
        match self.next(20).await {
            Out::Started(s) => s,
            other => panic!("expected started, got {other:?}"),
        }
    }

    /// The next frame, skipping (and returning) rejections met on the way.
    pub async fn frame(&mut self, secs: u64) -> (pb::Frame, Vec<pb::Rejected>) {
        let mut rejected = Vec::new();
        loop {
            match self.next(secs).await {
                Out::Frame(f) => return (f, rejected),
                Out::Rejected(r) => rejected.push(r),
                Out::Started(_) => panic!("second started"),
                Out::Progress(_) | Out::Picked(_) => {}
            }
        }
    }

    pub async fn send(&self, m: pb::viewer_msg::Msg) {
        self.tx.send(pb::ViewerMsg { msg: Some(m) }).await.unwrap();
    }

    /// Reads frames until one has `samples_used > 0`; returns it (panics after `secs`).
    pub async fn frame_with_samples(&mut self, secs: u64) -> pb::Frame {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(secs);
        loop {
            let left = deadline.saturating_duration_since(tokio::time::Instant::now()).as_secs().max(1);
            assert!(tokio::time::Instant::now() < deadline, "no frame with new samples within {secs} s");
            let (f, _) = self.frame(left).await;
            if f.samples_used > 0 {
                return f;
            }
        }
    }
}
