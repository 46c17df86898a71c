//! One render session per viewer (DESIGN.md "Processes and data flow", "Threads"): the frame
//! loop of paper 000 Figure 2 on its own thread, fed by viewer input through a channel and
//! by worker samples through a [`Dispatcher`], publishing frames latest-frame-wins.
//!
//! ```text
//!  viewer msgs ──Input──▶ [frame loop thread] ──Frame/Rejected──▶ SessionOutput ──▶ viewer
//!                          ▲ drain      │ submit
//!                          └─Dispatcher─┘ (async links to the workers)
//! ```
//!
//! [`Session::start`] spawns the thread; the session ends when [`Session::close`] is called
//! or the `Session` is dropped (the service does this when the viewer disconnects). The
//! thread then exits, dropping the dispatcher, which stops its worker links.
mod edge_source;
mod feedback;
mod frame_loop;
pub mod mesh_shadows;
pub mod move_shadows;
pub mod memory;
mod output;
mod progress;
pub mod pick;
pub mod requests;
mod settings;
pub mod split;

pub use edge_source::{EdgeIndexSlot, EdgeSourceStats, SessionEdges, TripleSet};
pub use feedback::{ObjectSeen, ShadingFeedback, TripleKey, TripleSeen};
pub use frame_loop::{max_outstanding, SessionCounters, OUTSTANDING_FRAMES, TARGET_SAMPLE_LATENCY};
pub use output::{SessionOutput, MAX_QUEUED_REJECTIONS};
pub use progress::ViewerProgress;
pub use requests::{build_batches, BatchSpec, RequestInfo, RequestRing};
pub use settings::{
    camera_from_wire, camera_to_wire, resolve_move, Reconstruction, SessionSettings, BATCH_SIZE_RANGE, MAX_AGE_RANGE,
    MAX_FPS_RANGE, SHARP_CUTOFF_RANGE, SIMPLIFY_TOLERANCE_RANGE, SPARSENESS_RANGE,
};

use crate::workers::Dispatcher;
use edgepoint_proto as pb;
use edgepoint_scene::{Camera, Scene};
use std::collections::HashMap;
use std::sync::Arc;

/// Inputs waiting for the frame loop before the viewer's stream is back-pressured.
pub const INPUT_QUEUE: usize = 1024;

/// A viewer message after `start`.
#[derive(Debug, Clone)]
pub enum Input {
    Camera(pb::Camera),
    Move(pb::ObjectMove),
    Settings(pb::Settings),
    /// Which object is under a pixel: answered with a `Picked` ([`pick`]).
    Pick(pb::Pick),
}

/// Everything a session is made from (validated by the caller, except settings ranges
/// which [`SessionSettings::with`] checks).
pub struct SessionParams {
    pub id: String,
    pub scene: Arc<Scene>,
    pub width: u32,
    pub height: u32,
    pub camera: Camera,
    pub shader: String,
    pub shader_params: HashMap<String, f64>,
    pub encoding: pb::FrameEncoding,
    pub settings: SessionSettings,
    /// Render Cache size as a multiple of the pixel count.
    pub points_per_pixel: f32,
    /// Seed of the sampler's dithering and the batches' shading seeds.
    pub seed: u64,
    /// The scene's edge index, shared with the other sessions on the same scene (built by
    /// the first session that needs it).
    pub edge_index: EdgeIndexSlot,
    /// The session's share of the server's memory budget (`None`: unlimited); a settings
    /// change that needs more than it can grow to is refused.
    pub memory: Option<memory::MemoryGrant>,
    /// How each pixel's shading is spread over the workers (by pixels: whole samples).
    pub split: edgepoint_proto::split::SplitMode,
}

/// Default Render Cache size per pixel (DESIGN.md: "a small multiple of the pixel count").
pub const DEFAULT_POINTS_PER_PIXEL: f32 = 2.0;

/// A running session. Dropping it ends the session.
pub struct Session {
    id: String,
    inputs: flume::Sender<Input>,
    output: Arc<SessionOutput>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Runs when the frame-loop thread ends, even by a panic: tells the viewer side the
/// session is over and releases whatever the caller attached (a session slot).
struct EndGuard {
    out: Arc<SessionOutput>,
    on_end: Option<Box<dyn FnOnce() + Send>>,
}

impl Drop for EndGuard {
    fn drop(&mut self) {
        self.out.end();
        if let Some(f) = self.on_end.take() {
            f();
        }
    }
}

impl Session {
    /// Starts the frame loop on its own thread. `on_end` runs when the thread finishes.
    pub fn start(params: SessionParams, dispatcher: Dispatcher, on_end: Option<Box<dyn FnOnce() + Send>>) -> std::io::Result<Session> {
        let (tx, rx) = flume::bounded(INPUT_QUEUE);
        let output = Arc::new(SessionOutput::new());
        let out = output.clone();
        let id = params.id.clone();
        let thread = std::thread::Builder::new().name(format!("session-{}", short(&id))).spawn(move || {
            let guard = EndGuard { out: out.clone(), on_end };
            let id = params.id.clone();
            let (w, h) = (params.width, params.height);
            let mut fl = frame_loop::FrameLoop::new(params, dispatcher, rx, out);
            tracing::info!(session = %id, width = w, height = h, "frame loop started");
            fl.run();
            let c = fl.counters;
            tracing::info!(session = %id, frames = c.frames, samples_inserted = c.samples_inserted, averaged = c.averaged,
                samples_requested = c.samples_requested, carried = c.carried, stale_dropped = c.stale_dropped, shadow_changed = c.shadow_changed,
                unmatched = c.unmatched, parts_forgotten = c.parts_forgotten, nonfinite = c.nonfinite, refused_batches = c.refused_batches,
                triples = fl.feedback.triples.len(), "session ended");
            drop(fl);
            drop(guard);
        })?;
        Ok(Session { id, inputs: tx, output, thread: Some(thread) })
    }

    pub fn id(&self) -> &str {
        &self.id
    }

    /// Where the frame loop's inputs go (bounded: an async sender awaits room).
    pub fn inputs(&self) -> flume::Sender<Input> {
        self.inputs.clone()
    }

    /// What the frame loop produces for the viewer.
    pub fn output(&self) -> Arc<SessionOutput> {
        self.output.clone()
    }

    /// Asks the frame loop to stop (it checks at least every 50 ms).
    pub fn close(&self) {
        self.output.close();
    }

    /// Stops the session and waits for its thread (blocking: not for async contexts).
    pub fn join(mut self) {
        self.close();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        self.close();
    }
}

fn short(id: &str) -> &str {
    &id[..id.len().min(8)]
}
