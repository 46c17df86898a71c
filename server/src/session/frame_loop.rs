//! The frame loop of one session, on its own thread (DESIGN.md "One frame in the renderer"
//! and "Threads"). It never awaits the network: inputs arrive on a channel, samples are
//! drained from the dispatcher at the start of the frame, requests leave through the
//! dispatcher's queue, and frames go out latest-frame-wins.
//!
//! Per frame: apply input (camera, object moves bumping the scene epoch, settings) → insert
//! the samples that arrived (dropping samples of objects that moved after the sample's
//! epoch) → discontinuity edges for the current camera and object transforms (§6; the
//! brute-force finder for now) → Render Cache reprojection (§4.3) → the edge-and-point image
//! and its reconstruction (§4–5), or the Render Cache's own interpolation when the session
//! asks for the baseline → prioritized sampling of the frame's budget from the
//! reconstruction's filter weights (§5.3) → ray requests → overlay, encode and publish →
//! sleep to the fps cap.
use super::feedback::ShadingFeedback;
use super::output::SessionOutput;
use super::requests::{build_batches, BatchSpec, RequestRing};
use super::split::{PartOutcome, PartSums};
use crate::rng::mix64;
use super::settings::{camera_from_wire, camera_to_wire, overlay_to_wire, resolve_move, Reconstruction, SessionSettings};
use super::{Input, SessionParams};
use super::edge_source::{EdgeSourceStats, SessionEdges};
use super::memory::{ring_capacity, MemoryGrant, SessionMemory};
use super::move_shadows::{place_solids, MoveQuery, MoveShadows, PlacedSolids};
use crate::render_cache::reshadow::{worst_change, ShadowChange, Worst, DROP_DRIFT};
use crate::edges::finder::ViewVolume;
use crate::edges::EdgeSegment;
use crate::encode::{effective_encoding, FrameEncoder};
use crate::epi::interpolate::OwnSample;
use crate::epi::{Epi, EpiCounts, Flags, InterpOptions, Overlay, STAGE_EDGES};
use crate::epi::raster::SegmentProjector;
use crate::epi::spread::BaselineHoles;
use crate::render_cache::holes::{HoleFill, ObjectFill};
use crate::render_cache::{CacheConfig, FrameCounts, LightBound, RenderCache, Sample};
use crate::render_cache::fresh::STAGE_STALE;
use crate::sampling::{aim_at_points, aim_into_starved, PixelRequest, Sampler, SamplingConfig};
use crate::stage_times::StageTimes;
use crate::visibility::{Visibility, STAGE_VISIBILITY};
use crate::workers::{Answer, Dispatcher};
use edgepoint_proto as pb;
use edgepoint_scene::camera::CameraFrame;
use edgepoint_scene::geometry::transformed_box;
use edgepoint_scene::{Camera, Scene};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tonic::Code;

/// Frames' worth of requests that may be outstanding at most: enough to cover worker latency,
/// few enough that requests are not shaded for a view long gone (back-pressure).
pub const OUTSTANDING_FRAMES: usize = 4;
/// Once the workers' rate is known, outstanding requests are also held to about this much
/// of their work: more in flight only makes every sample arrive later (Little's law), it
/// cannot make the workers faster.
pub const TARGET_SAMPLE_LATENCY: Duration = Duration::from_millis(100);

/// Requests allowed in flight: between one frame's budget and [`OUTSTANDING_FRAMES`] of
/// them (times `frames`: [`REST_FRAMES`] at rest), and no more than the workers shade at their
/// measured `rate` (samples per second; 0 = not measured yet) in [`TARGET_SAMPLE_LATENCY`]
/// plus `refill`, the time until the next frame's requests go out.
///
/// In motion `refill` is zero and `frames` one. At rest the frame loop sends requests only
/// once a rest period (`rest_fps`), so what is in flight after a frame must keep the
/// workers busy for that period and then for the round trip of the next frame's requests.
/// Without `refill` the bound cannot grow: the rate it is measured from is what the bound
/// let through (at most the bound per period, so `rate` × 100 ms equals the bound at a 10
/// fps rest pace, a fixed point at whatever it started with, and any latency pulls it
/// down), and at rest it sat at one frame's budget per frame — on `cornell` 41k samples/s
/// against the 300k/s the same workers shade for a progressive renderer.
///
/// Until the rate is measured (a session's first frames), [`OUTSTANDING_FRAMES`] of the
/// budget, at rest too: more ahead of the first samples would only delay the first image.
pub fn max_outstanding(per_frame: usize, rate: f64, refill: Duration, frames: usize) -> usize {
    let most = per_frame * OUTSTANDING_FRAMES;
    if rate <= 0.0 || !rate.is_finite() {
        return most;
    }
    ((rate * (TARGET_SAMPLE_LATENCY + refill).as_secs_f64()) as usize).clamp(per_frame, most * frames.max(1))
}

/// Frames' worth of requests a still view may have in flight or held ([`max_outstanding`]'s
/// `frames` at rest): 8 × [`OUTSTANDING_FRAMES`] budgets, half the pixels at the default
/// sparseness. It bounds the request ring, not the rate: at rest the workers' own rate does
/// ([`max_outstanding`], [`release_bound`]). With 3 (the interactive frames of a 10 fps rest
/// period), `cornell` with `gi` was held to 49k requests a 100 ms frame, less than its two
/// workers shade in a period and a round trip (520k samples/s on two cores with coherent
/// batches), and they idled for a tenth of the machine.
pub const REST_FRAMES: usize = 8;

/// Requests that may be outstanding at the workers (submitted to the dispatcher) while more
/// of a frame's requests are held back in the session: in motion no bound (a frame asks for
/// its budget, [`frame_requests`]); at rest the [`TARGET_SAMPLE_LATENCY`] of work at the
/// workers' `rate`, between one frame's budget and [`OUTSTANDING_FRAMES`] × `frames` of them.
///
/// At rest a frame picks the requests of its whole rest period ([`max_outstanding`] with the
/// refill): at 5 frames a second and 500k samples a second, 150,000 requests. Submitted at
/// once, they would overflow the dispatcher's queue (1,024 batches) and the workers would
/// idle for the end of the period; and a motion starting from rest would find them all ahead
/// of its first samples at the workers. Held in the session, they go out as answers come
/// back, and the next frame's picks (or the first motion) replace what is left.
pub fn release_bound(per_frame: usize, rate: f64, frames: usize, at_rest: bool) -> usize {
    if at_rest {
        max_outstanding(per_frame, rate, Duration::ZERO, frames)
    } else {
        usize::MAX
    }
}

/// Frames the camera and the objects must have stayed still before the session samples at
/// the workers' pace instead of its interactive budget (about a quarter of a second at 30
/// fps: an orbit or a drag never pauses that long between frames).
pub const REST_AFTER_FRAMES: u32 = 8;

/// Still frames after which requests go out in runs of neighbouring pixels
/// (`BatchSpec::coherent`) and in batches of [`REST_BATCH_REQUESTS`]: about a second at the
/// rest pace after [`REST_AFTER_FRAMES`]. Before, a session's first frames and the first
/// frames after a motion still have regions without samples, which batches spread over the
/// image fill everywhere at once (with coherent batches from the first frame, `cornell` with
/// `gi` showed 17.7–18.7 dB at 0.25 s instead of 21.7–24, its first answers a band of rows).
const COHERENT_AFTER_FRAMES: u32 = REST_AFTER_FRAMES + 10;

/// What a pixel with its own usable sample shows `still_frames` frames after the camera last
/// moved: with the camera still (from [`REST_AFTER_FRAMES`]) the sample as shaded (the
/// Render Cache rule, [`OwnSample::Show`]); while it moves the mean with its reachable neighbours
/// like any other pixel, except near a stale point or in a complex pixel
/// ([`OwnSample::FilterAwayFromStale`]; the kernel's σ of 0.8 px, edges respected). In
/// motion most pixels hold a point shaded once, whose Monte Carlo noise (16 shadow rays in a
/// penumbra) the shown sample put on screen pixel by pixel: the frames were grainy where the
/// reference is smooth. Filtering averages about five points' worth and keeps edges
/// (`edgepoint-bench motion`, 2026-12-05): `cornell`'s orbit 45.8 → 47.4 dB, SSIM 0.983 →
/// 0.989; `cornell-point`'s 50.2 → 51.9 dB; `rooms`' 37.9 → 39.2 dB; `cornell-point`'s orbit
/// at 64², 128², 256²: 38.3 → 39.8, 45.2 → 46.8, 48.9 → 49.6 dB. Near stale points it shows
/// them as before: filtered there, a moving box's new shadow on points shaded lit came out
/// diluted. At rest the points converge (a re-picked point averages its samples) and
/// filtering them only blurs: kept for the first 80 still frames, a still 64²
/// `cornell-point` stalled at 31.5 dB where showing reaches 41.0 by frame 60 (the point
/// light's hot spot on the ceiling spread). An object's move does not count as motion here:
/// the rest of the view is still and its points converged, and filtered they mottled
/// `cornell-point`'s hot spot while `tallbox` moved.
pub fn own_sample_after(still_frames: u32) -> OwnSample {
    if still_frames < REST_AFTER_FRAMES {
        OwnSample::FilterAwayFromStale
    } else {
        OwnSample::Show
    }
}

/// Requests per batch at rest, at least (the session's `batch_size` when larger). At rest the
/// workers shade half a million samples a second on two cores: in batches of 64 that is
/// 8,000 messages, fork-joins and wake-ups a second. The worker pool still splits a batch
/// into pieces of its worker's measured 25 ms of work.
const REST_BATCH_REQUESTS: usize = 1024;

/// Samples ahead of the one being inserted whose cached point is prefetched
/// (`RenderCache::prefetch_aimed`): enough to cover a memory access at a few tens of
/// nanoseconds of work a sample.
const INSERT_PREFETCH_AHEAD: usize = 8;

/// Still frames between two updates of the noise gains (`request_next`).
const NOISE_GAIN_FRAMES: u32 = 4;

/// The pause between frame starts: the interactive one (`max_fps`) and the one to keep
/// while nothing moves (`rest_fps`, when lower). At rest a frame only adds the samples
/// that arrived since the last one, and on a machine the frame loop shares with the
/// workers (one host) every frame it does not make leaves the workers more time to shade:
/// the image converges faster at 10 frames a second than at 30.
pub fn frame_periods(s: &SessionSettings, still_frames: u32) -> (Duration, Duration) {
    let interactive = Duration::from_secs_f64(1.0 / s.max_fps);
    if still_frames >= REST_AFTER_FRAMES && s.rest_fps < s.max_fps {
        (interactive, Duration::from_secs_f64(1.0 / s.rest_fps))
    } else {
        (interactive, interactive)
    }
}

/// Requests to send this frame, given the frame's interactive budget `per_frame`, the
/// `room` left under [`max_outstanding`], and how many frames the view has been still.
///
/// In motion a frame asks for at most its budget: samples requested now are for this
/// view, and more in flight would only arrive for views already gone. At rest nothing
/// goes stale, so every free place in flight is filled: the workers, otherwise idle for
/// most of a frame at 1/64 of the pixels per frame, keep shading, and the image converges
/// at their pace (issue 14 item 3) — bounded still by [`max_outstanding`] (the request
/// ring, the memory grant and [`TARGET_SAMPLE_LATENCY`] when motion resumes).
pub fn frame_requests(per_frame: usize, room: usize, still_frames: u32) -> usize {
    if still_frames >= REST_AFTER_FRAMES {
        room
    } else {
        per_frame.min(room)
    }
}
/// Stage name of hole filling (not a column of paper Table 2).
pub const STAGE_HOLES: &str = "holes";
/// How often a waiting loop checks whether the viewer is gone.
const POLL: Duration = Duration::from_millis(50);

/// Running totals of one session, logged when it ends.
#[derive(Debug, Default, Clone, Copy)]
pub struct SessionCounters {
    pub frames: u64,
    pub samples_inserted: u64,
    /// Of those, samples averaged into the point they re-shaded (converging at rest).
    pub averaged: u64,
    pub samples_requested: u64,
    /// Samples of an object that moved after the sample's epoch: carried to the object's
    /// current place (from the hit's object-space position) and inserted as stale.
    pub carried: u64,
    /// Hits without an object-space position whose object moved since (not inserted).
    pub stale_dropped: u64,
    /// Cached points dropped, and samples not inserted, because a move since they were
    /// shaded changed their shadow from a point light (their shading is wrong now).
    pub shadow_changed: u64,
    /// Answers whose request the session no longer remembers, or with an unknown object.
    pub unmatched: u64,
    /// Samples with non-finite values (not inserted).
    pub nonfinite: u64,
    /// Batches the dispatcher refused (queue full).
    pub refused_batches: u64,
    /// Split samples dropped with some parts missing (their request forgotten).
    pub parts_forgotten: u64,
}

pub(super) struct FrameLoop {
    scene: Arc<Scene>,
    names: Vec<String>,
    width: u32,
    height: u32,
    shader: String,
    shader_params: std::collections::HashMap<String, f64>,
    encoding: pb::FrameEncoding,
    camera: Camera,
    cam_frame: CameraFrame,
    settings: SessionSettings,
    epoch: u64,
    /// Per object: the epoch of its latest move (0 = never moved).
    moved_at: Vec<u64>,
    last_move_epoch: u64,
    /// Frames since the camera last changed or an object last moved (see
    /// [`frame_requests`]).
    still_frames: u32,
    /// Frames since the camera last moved (object moves do not count): what a pixel's own
    /// sample shows ([`own_sample_after`]).
    camera_still_frames: u32,
    /// Whether the cache's noise gains are of this still view (`request_next`).
    gains_ready: bool,
    /// Per object: its current object-to-world transform (for edge finding).
    transforms: Vec<glam::Affine3A>,
    /// Per object: the matrix taking its normals to world space now.
    normal_to_world: Vec<glam::Mat3A>,
    /// The lights as shadow tests see them.
    lights: Vec<LightBound>,
    /// Recent moves, newest last: a sample shaded before one of them arrives stale, or is
    /// dropped where the move changed its shadow from a point light ([`Self::shading_since`]).
    recent_moves: std::collections::VecDeque<RecentMove>,
    /// The moved objects' face hierarchies and convex solids, for exact shadow tests.
    move_shadows: MoveShadows,
    /// Per object made of convex solids that has moved: those solids where it is now (the
    /// exact area-light test; a sample shaded before a move compares its place then with it).
    placed: Vec<Option<Arc<PlacedSolids>>>,
    cache: RenderCache,
    /// The exact primary visibility of the frame: what reprojection culls against.
    visibility: Visibility,
    epi: Epi,
    /// Finds the frame's discontinuity segments (edge trees, shadow thread).
    edge_source: SessionEdges,
    /// The frame's discontinuity segments.
    edges: Vec<EdgeSegment>,
    edge_stats: EdgeSourceStats,
    holes: HoleFill,
    object_fill: ObjectFill,
    baseline_holes: BaselineHoles,
    sampler: Sampler,
    dispatcher: Dispatcher,
    ring: RequestRing,
    /// Split shading: the parts of samples received so far (one part: pass-through).
    split: PartSums,
    pub feedback: ShadingFeedback,
    times: StageTimes,
    encoder: FrameEncoder,
    /// Sample batches taken from the workers and not yet inserted.
    answers: Vec<pb::SampleBatch>,
    /// Samples inserted while the loop waited for the next frame, and the time it took
    /// (reported with the next frame).
    between: (u32, f64),
    /// The time of those inserted before the frame being made (`Frame.between_ms`).
    between_ms: f64,
    /// The stages run after the last frame was published (picking the pixels to shade and
    /// sending their requests: [`Self::request_next`]), reported with the next frame.
    after_times: StageTimes,
    /// Requests sent since the last frame was published (`Frame.samples_requested`).
    requested: u32,
    picks: Vec<PixelRequest>,
    /// Request batches built and not yet submitted (see [`release_bound`]).
    held: std::collections::VecDeque<pb::RequestBatch>,
    next_batch_id: u64,
    seed: u64,
    sequence: u64,
    start: Instant,
    out: Arc<SessionOutput>,
    inputs: flume::Receiver<Input>,
    inputs_open: bool,
    pending: Vec<Input>,
    pub counters: SessionCounters,
    /// Whether a frame has been published: until the first samples arrive, the viewer gets
    /// progress instead of black frames.
    shown: bool,
    /// The last waiting state reported to the viewer (live workers, workers, requested).
    waiting_reported: Option<(usize, usize, bool)>,
    points_per_pixel: f32,
    memory: Option<MemoryGrant>,
}

impl FrameLoop {
    pub(super) fn new(p: SessionParams, dispatcher: Dispatcher, inputs: flume::Receiver<Input>, out: Arc<SessionOutput>) -> Self {
        let pixels = p.width as usize * p.height as usize;
        let cache = RenderCache::new(CacheConfig {
            width: p.width,
            height: p.height,
            points_per_pixel: p.points_per_pixel,
            background: p.scene.background,
        });
        let settings = p.settings;
        let ring = RequestRing::new(ring_capacity(&settings, pixels));
        let objects = p.scene.objects.len();
        FrameLoop {
            names: p.scene.objects.iter().map(|o| o.name.clone()).collect(),
            width: p.width,
            height: p.height,
            shader: p.shader,
            shader_params: p.shader_params,
            encoding: effective_encoding(p.encoding),
            cam_frame: p.camera.frame(p.width, p.height),
            camera: p.camera,
            settings,
            epoch: 0,
            moved_at: vec![0; objects],
            last_move_epoch: 0,
            // A new session is at rest until the camera or an object first moves.
            still_frames: REST_AFTER_FRAMES,
            camera_still_frames: REST_AFTER_FRAMES,
            gains_ready: false,
            transforms: p.scene.objects.iter().map(|o| o.transform).collect(),
            normal_to_world: p.scene.objects.iter().map(|o| normal_matrix(&o.transform)).collect(),
            lights: p.scene.lights.iter().map(light_bound).collect(),
            recent_moves: std::collections::VecDeque::new(),
            move_shadows: MoveShadows::new(&p.scene),
            placed: vec![None; objects],
            cache,
            visibility: Visibility::new(p.width, p.height),
            epi: Epi::new(p.width, p.height),
            edge_source: SessionEdges::new(
                p.scene.clone(),
                p.edge_index.clone(),
                Box::new(super::ViewerProgress::new(out.clone(), "edge trees", &format!("session {}: edge trees", &p.id[..p.id.len().min(8)]))),
                Box::new(super::ViewerProgress::new(out.clone(), "discontinuity mesh", &format!("session {}: discontinuity mesh", &p.id[..p.id.len().min(8)]))),
            ),
            edges: Vec::new(),
            edge_stats: EdgeSourceStats::default(),
            holes: HoleFill::new(p.width, p.height),
            object_fill: ObjectFill::default(),
            baseline_holes: BaselineHoles::default(),
            sampler: Sampler::new(p.width, p.height, p.seed),
            dispatcher,
            ring,
            split: PartSums::new(p.split.parts()),
            feedback: ShadingFeedback::new(objects),
            times: StageTimes::new(),
            encoder: FrameEncoder::new(),
            answers: Vec::new(),
            between: (0, 0.0),
            between_ms: 0.0,
            after_times: StageTimes::new(),
            requested: 0,
            picks: Vec::new(),
            held: std::collections::VecDeque::new(),
            next_batch_id: 0,
            seed: mix64(p.seed ^ 0x5eed),
            sequence: 0,
            start: Instant::now(),
            out,
            inputs,
            inputs_open: true,
            pending: Vec::new(),
            counters: SessionCounters::default(),
            shown: false,
            waiting_reported: None,
            points_per_pixel: p.points_per_pixel,
            memory: p.memory,
            scene: p.scene,
        }
    }

    /// Runs until the viewer is gone.
    pub(super) fn run(&mut self) {
        while !self.out.is_closed() {
            let t0 = Instant::now();
            self.times.clear();
            let t = Instant::now();
            self.apply_inputs();
            self.times.add("input", ms_since(t));
            if self.settings.paused {
                // Keep taking samples (they stay valid and free the workers' answers) but
                // make no frames and request nothing.
                self.insert_samples();
                self.wait_inputs(t0 + POLL, t0 + POLL);
                continue;
            }
            self.frame(t0);
            let (soon, late) = frame_periods(&self.settings, self.still_frames);
            self.wait_inputs(t0 + soon, t0 + late);
        }
    }

    fn frame(&mut self, t0: Instant) {
        let t = Instant::now();
        let (between, between_ms) = std::mem::take(&mut self.between);
        self.between_ms = between_ms;
        let samples_used = between + self.insert_samples();
        self.times.add("samples", ms_since(t));

        let (counts, epi_counts) = self.reconstruct();
        if !self.shown && self.cache.is_empty() {
            // Nothing to show yet (the workers are loading the scene, or the first samples
            // are on their way): say so instead of sending a black frame.
            self.report_waiting();
            self.request_next();
            return;
        }
        if !self.shown {
            self.shown = true;
            self.out.progress(pb::Progress {
                stage: "first samples".into(),
                done: 1,
                total: 1,
                message: format!("first frame after {:.2} s", self.start.elapsed().as_secs_f64()),
            });
        }

        if epi_counts.is_some() && self.settings.overlay != Overlay::None {
            let t = Instant::now();
            let (_, image, _) = self.cache.reconstruction_target();
            self.epi.draw_overlay(self.settings.overlay, image);
            self.times.add("overlay", ms_since(t));
        }

        let t = Instant::now();
        let data = match self.encoder.encode(self.cache.image(), self.width, self.height, self.encoding) {
            Ok(d) => d,
            Err(e) => {
                tracing::error!("frame {} not sent: {e}", self.sequence);
                return;
            }
        };
        self.times.add("encode", ms_since(t));
        self.publish(t0, data, counts, epi_counts, samples_used);
        self.request_next();
    }

    /// Picks the pixels to shade next from the frame just reconstructed (its filter weights,
    /// its points' ages, its usable samples) and sends their requests, after the frame is
    /// published so the viewer does not wait for them. The workers lose nothing by it: the
    /// in-flight bound keeps 100 ms or more of earlier requests queued at them. Timed as the
    /// stages `sampling` and `requests`, reported with the next frame (`Frame.after_ms`,
    /// outside its `total_ms`).
    fn request_next(&mut self) {
        self.after_times.clear();
        let t = Instant::now();
        let pixels = self.width as usize * self.height as usize;
        let per_frame = self.settings.frame_budget(pixels);
        // The dispatcher counts parts; the budget counts samples (pixels shaded whole).
        let parts = self.split.parts() as f64;
        let (refill, frames) = if self.still_frames >= REST_AFTER_FRAMES {
            (frame_periods(&self.settings, self.still_frames).1, REST_FRAMES)
        } else {
            (Duration::ZERO, 1)
        };
        let max_outstanding = max_outstanding(per_frame, self.workers_rate() / parts, refill, frames);
        let outstanding = self.dispatcher.outstanding_requests() as usize / parts as usize;
        let budget = frame_requests(per_frame, max_outstanding.saturating_sub(outstanding), self.still_frames);
        self.still_frames = self.still_frames.saturating_add(1);
        self.camera_still_frames = self.camera_still_frames.saturating_add(1);
        let cfg = SamplingConfig { sparseness: self.settings.sparseness, max_age_frames: self.settings.max_age_frames as f32 };
        self.picks.clear();
        if budget > 0 {
            // While the view is still, noisier points are re-shaded more often (converging at
            // rest, `render_cache/converge.rs`); in motion every point's age counts alike.
            // The gains are a pass over the image with a scattered read of each pixel's point
            // (2.6 ms of a rest frame at 512²) and a point's spread changes little in a few
            // frames, so they are remade every NOISE_GAIN_FRAMES frames.
            let at_rest = self.still_frames > REST_AFTER_FRAMES;
            if !at_rest {
                self.gains_ready = false;
            } else if !self.gains_ready || self.still_frames % NOISE_GAIN_FRAMES == 0 {
                self.gains_ready = self.cache.update_noise_gains();
            }
            let gains = (at_rest && self.gains_ready).then(|| self.cache.noise_gains());
            let ages = &self.cache.point_image().age;
            let epr = self.settings.reconstruction == Reconstruction::EdgeAndPoint;
            // Pixels whose secondary region no sample reached get picked, and shaded inside
            // that region (edge-and-point reconstruction only: the baseline has no regions).
            let starved = epr.then(|| self.epi.starved());
            self.sampler.select_gained(self.cache.filter_weights(), ages, gains, starved, &cfg, budget, &mut self.picks);
            // Re-picked points are shaded again where they are, so the cache averages their
            // samples (converging at rest); edge-and-point reconstruction uses only usable ones.
            let (epi, flags) = (&self.epi, self.epi.flags());
            aim_at_points(
                &mut self.picks,
                self.cache.point_image(),
                |x, y| !epr || flags.get(x as usize, y as usize, Flags::USABLE),
                |x, y, jittered, point| epr && epi.same_region(x as usize, y as usize, jittered, point),
            );
            if epr {
                aim_into_starved(&mut self.picks, |x, y, u, v| epi.secondary_position(x as usize, y as usize, u, v));
            }
        }
        self.after_times.add("sampling", ms_since(t));

        let t = Instant::now();
        self.send_requests();
        self.after_times.add("requests", ms_since(t));
    }

    /// Edges, reprojection and the frame's reconstruction (edge-and-point, or the Render
    /// Cache baseline) into the cache's image and filter weights. The EPI is built in
    /// baseline mode too when an overlay shows it.
    fn reconstruct(&mut self) -> (FrameCounts, Option<EpiCounts>) {
        let s = self.settings;
        let epr = s.reconstruction == Reconstruction::EdgeAndPoint;
        let build = epr || s.overlay != Overlay::None;
        if build {
            let t = Instant::now();
            let view = ViewVolume::new(&self.camera, self.width as f32 / self.height as f32);
            self.edge_stats = self.edge_source.find(
                &self.transforms,
                self.cam_frame.eye,
                &view,
                &self.feedback.triples,
                s.sharp_cutoff_degrees,
                s.simplify_tolerance,
                s.mesh_shadow_edges,
                Some(&SegmentProjector::new(&self.cam_frame, self.width as usize, self.height as usize)),
                &mut self.edges,
            );
            self.times.add(STAGE_EDGES, ms_since(t));
        }
        let t = Instant::now();
        self.visibility.update(&self.scene, &self.transforms, &self.cam_frame);
        self.times.add(STAGE_VISIBILITY, ms_since(t));
        let occluded = self.cache.reproject_points(&self.cam_frame, Some(self.visibility.cull()), &mut self.times);
        // Points shaded before a move that may have changed them give way to newer ones that
        // disagree with them.
        let t = Instant::now();
        self.cache.hide_stale_near_fresh(Some(self.visibility.objects()));
        self.times.add(STAGE_STALE, ms_since(t));
        let epi_counts = build.then(|| {
            let centre_lines = epr && s.complex_filter;
            self.epi.build(&self.edges, &self.cam_frame, self.cache.point_image(), centre_lines, &mut self.times)
        });
        let cache_points = self.cache.len() as u32;
        let counts = if epr {
            let background = self.cache.background();
            let (points, image, weights) = self.cache.reconstruction_target();
            let opts = InterpOptions { own_sample: own_sample_after(self.camera_still_frames), ..InterpOptions::default() };
            let r = self.epi.reconstruct(points, background, &opts, s.complex_filter, image, weights, &mut self.times);
            let i = r.interp;
            FrameCounts { with_point: i.with_point, filled: i.filled, empty: i.empty, occluded, cache_points }
        } else {
            let (with_point, filled, empty) = self.cache.interpolate_gaps(&mut self.times);
            FrameCounts { with_point, filled, empty, occluded, cache_points }
        };
        // Pixels no sample reached (edge-and-point reconstruction has spread colour into
        // those its regions connect to): the pyramid fill, after an edge-blind spread for
        // the baseline.
        let t = Instant::now();
        let (points, image, weights) = self.cache.reconstruction_target();
        // Within the objects the exact visibility shows first, so a surface that just came
        // into view takes its colour from itself, not from what lies beside it.
        let objects = self.visibility.objects();
        if epr {
            let (w, h) = (self.width as usize, self.height as usize);
            let (_, left) = self.object_fill.fill(w, h, self.epi.holes(), objects, image);
            self.holes.fill(points, left, image);
        } else {
            self.baseline_holes.fill(points, weights, image, &mut self.holes, Some((objects, &mut self.object_fill)));
        }
        self.times.add(STAGE_HOLES, ms_since(t));
        (counts, epi_counts)
    }

    fn publish(&mut self, t0: Instant, data: Vec<u8>, counts: FrameCounts, epi: Option<EpiCounts>, samples_used: u32) {
        let epi = epi.unwrap_or_default();
        self.sequence += 1;
        self.counters.frames += 1;
        let frame = pb::Frame {
            sequence: self.sequence,
            width: self.width,
            height: self.height,
            encoding: self.encoding as i32,
            data,
            // This frame's stages, then the picking and requests made after the frame before.
            stages: self.times.stages.iter().chain(&self.after_times.stages).map(|&(stage, ms)| pb::StageTime { stage: stage.to_string(), ms }).collect(),
            total_ms: ms_since(t0),
            samples_used,
            samples_requested: std::mem::take(&mut self.requested),
            outstanding: self.dispatcher.outstanding_requests().min(u32::MAX as u64) as u32,
            pixels: Some(pb::PixelCounts {
                with_point: counts.with_point,
                filled: counts.filled,
                empty: counts.empty,
                occluded: counts.occluded,
                cache_points: counts.cache_points,
                empty_class: epi.empty,
                simple_class: epi.simple,
                complex_class: epi.complex,
            }),
            epoch: self.epoch,
            live_workers: self.dispatcher.live_workers() as u32,
            frames_dropped: self.out.frames_dropped(),
            sim_time: self.start.elapsed().as_secs_f64(),
            edges: Some(pb::EdgeCounts {
                silhouette: epi.edges[0],
                sharp: epi.edges[1],
                boundary: epi.edges[2],
                shadow_hard: epi.edges[3],
                shadow_umbral: epi.edges[4],
                shadow_penumbral: epi.edges[5],
                fragments: epi.raster.fragments,
                culled: epi.raster.culled,
                edge_trees: self.edge_stats.trees,
                shadow_update_ms: self.edge_stats.shadow_update_ms,
                shadow_pairs: self.edge_stats.shadow.pairs as u32,
            }),
            reconstruction: self.settings.reconstruction.to_wire() as i32,
            camera: Some(camera_to_wire(&self.camera)),
            overlay: overlay_to_wire(self.settings.overlay) as i32,
            between_ms: self.between_ms,
            after_ms: self.after_times.total_ms(),
        };
        self.out.publish_frame(frame);
    }

    /// Tells the viewer what the session waits for before its first frame: the shader
    /// workers that have loaded the scene (parsed it and built their BVHs), then the first
    /// samples. Sent when it changes.
    fn report_waiting(&mut self) {
        let (live, workers) = (self.dispatcher.live_workers(), self.dispatcher.workers());
        let requested = self.counters.samples_requested > 0;
        let state = (live, workers, requested);
        if self.waiting_reported == Some(state) {
            return;
        }
        self.waiting_reported = Some(state);
        self.out.progress(pb::Progress {
            stage: "workers".into(),
            done: live as u64,
            total: workers as u64,
            message: match workers {
                0 => "no shader workers yet".to_string(),
                _ => format!("{live} of {workers} shader workers have the scene loaded (parsed, BVH built)"),
            },
        });
        if live > 0 {
            self.out.progress(pb::Progress {
                stage: "first samples".into(),
                done: 0,
                total: 1,
                message: format!("waiting for the first samples ({} requested)", self.counters.samples_requested),
            });
        }
    }

    /// Applies every input received so far, in order. Bad ones are answered with a
    /// `Rejected` and change nothing.
    fn apply_inputs(&mut self) {
        if self.inputs_open {
            loop {
                match self.inputs.try_recv() {
                    Ok(i) => self.pending.push(i),
                    Err(flume::TryRecvError::Empty) => break,
                    Err(flume::TryRecvError::Disconnected) => {
                        self.inputs_open = false;
                        break;
                    }
                }
            }
        }
        let pending = std::mem::take(&mut self.pending);
        for input in &pending {
            match input {
                Input::Camera(c) => match camera_from_wire(c) {
                    Ok(cam) => {
                        if cam != self.camera {
                            self.still_frames = 0;
                            self.camera_still_frames = 0;
                        }
                        self.camera = cam;
                        self.cam_frame = cam.frame(self.width, self.height);
                    }
                    Err(e) => self.out.reject(Code::InvalidArgument, format!("camera ignored: {e}")),
                },
                Input::Move(m) => match resolve_move(m, &self.names) {
                    Ok((id, t)) => self.move_object(id, t),
                    Err(e) => self.out.reject(Code::InvalidArgument, format!("object move ignored: {e}")),
                },
                Input::Settings(s) => match self.settings.with(s) {
                    Ok(_) if pb::FrameEncoding::try_from(s.encoding).is_err() => self.out.reject(
                        Code::InvalidArgument,
                        format!("settings ignored: settings.encoding {} is not a known FrameEncoding (0 to keep)", s.encoding),
                    ),
                    Ok(new) => match self.regrant(&new) {
                        Ok(()) => {
                            self.settings = new;
                            // A viewer switches to linear frames when it starts needing them
                            // (exposure keys, tev); `UNSPECIFIED` keeps the current encoding.
                            match pb::FrameEncoding::try_from(s.encoding) {
                                Ok(pb::FrameEncoding::Unspecified) | Err(_) => {}
                                Ok(e) => self.encoding = e,
                            }
                            let pixels = self.width as usize * self.height as usize;
                            self.ring.reserve(ring_capacity(&new, pixels));
                        }
                        Err(e) => self.out.reject(Code::ResourceExhausted, format!("settings ignored: {e}")),
                    },
                    Err(e) => self.out.reject(Code::InvalidArgument, format!("settings ignored: {e}")),
                },
                Input::Pick(p) => match super::pick::answer(&self.scene, &self.transforms, &self.camera, &self.cam_frame, p) {
                    Ok(answer) => self.out.picked(answer),
                    Err(e) => self.out.reject(Code::InvalidArgument, format!("pick ignored: {e}")),
                },
            }
        }
        // Hand the (now empty) buffer back so its capacity is reused.
        self.pending = pending;
        self.pending.clear();
    }

    /// Resizes the session's memory grant for `settings` (sampling more pixels per frame
    /// needs a larger request ring); an error leaves the grant as it was.
    fn regrant(&mut self, settings: &SessionSettings) -> Result<(), String> {
        let Some(grant) = &mut self.memory else { return Ok(()) };
        let need = SessionMemory::estimate(self.width, self.height, self.points_per_pixel, settings, rayon::current_num_threads());
        grant.resize(need.total(), "the session with these settings")
    }

    fn move_object(&mut self, id: u32, t: glam::Affine3A) {
        self.epoch += 1;
        self.still_frames = 0;
        if !self.dispatcher.set_epoch(self.epoch, vec![(id, t)]) {
            // The session is the dispatcher's only writer, so epochs always increase.
            tracing::error!(epoch = self.epoch, "dispatcher refused a new epoch");
        }
        self.moved_at[id as usize] = self.epoch;
        let from = std::mem::replace(&mut self.transforms[id as usize], t);
        self.normal_to_world[id as usize] = normal_matrix(&t);
        self.last_move_epoch = self.epoch;
        // The object's points go with it (their shading is aged: it was computed in the old
        // place). Of the points it can shadow, in its old place or its new one, those whose
        // shadow from a point light it changed (its segment blocked in one place only) are
        // dropped (wrong now); from an area light and an object of convex solids, each
        // point's light shifted by the share hidden in one place only, and a point is kept
        // stale while its shifts add up to little, dropped beyond (`reshadow`). Prioritized
        // sampling re-shades them first (DESIGN.md "Motion"). Objects without an exact test
        // age them instead. The others are as right as before.
        self.cache.move_object(id, &from, &t);
        let bounds = self.scene.objects[id as usize].mesh.bounds;
        let (a, b) = (transformed_box(&from, bounds), transformed_box(&t, bounds));
        let region = (a.0.min(b.0), a.1.max(b.1));
        self.move_shadows.prepare(&self.scene, id);
        let exact = self.move_shadows.get(id);
        let mesh = &self.scene.objects[id as usize].mesh;
        // The object's solids where it was (kept from its last move) and where it is now.
        let solids = exact.and_then(|e| e.solids.as_ref()).map(|s| {
            let before = self.placed[id as usize].clone().unwrap_or_else(|| Arc::new(place_solids(mesh, s, &from)));
            (before, Arc::new(place_solids(mesh, s, &t)))
        });
        self.placed[id as usize] = solids.as_ref().map(|s| s.1.clone());
        let placed_from = solids.as_ref().map(|s| s.0.clone());
        let query = MoveQuery::placed(exact, &from, &t, solids, &self.lights, self.move_shadows.areas());
        self.counters.shadow_changed += self.cache.reshadow(region, &self.lights, &query).dropped as u64;
        if self.recent_moves.len() >= RECENT_MOVES {
            self.recent_moves.pop_front();
        }
        self.recent_moves.push_back(RecentMove { epoch: self.epoch, object: id, from, region, placed_from });
    }

    /// Drains answers from the workers into the cache (with those already taken); returns
    /// samples inserted.
    fn insert_samples(&mut self) -> u32 {
        self.dispatcher.drain(&mut self.answers);
        let mut inserted = 0u32;
        let objects = self.moved_at.len() as u32;
        let lights = self.scene.lights.len();
        let split = self.split.parts() > 1;
        for b in &self.answers {
            self.feedback.record(b, lights);
            for (k, s) in b.samples.iter().enumerate() {
                if let Some(info) = b.samples.get(k + INSERT_PREFETCH_AHEAD).and_then(|a| self.ring.get(a.id)) {
                    self.cache.prefetch_aimed(info.point);
                }
                // A split sample enters the cache once all its parts are in, summed.
                let whole;
                let s = if split {
                    match self.split.add(b.epoch, s) {
                        PartOutcome::Complete(w, _) => {
                            whole = w;
                            &whole
                        }
                        PartOutcome::Waiting => continue,
                        PartOutcome::Duplicate | PartOutcome::Mismatch => {
                            self.counters.unmatched += 1;
                            continue;
                        }
                    }
                } else {
                    s
                };
                let Some(info) = self.ring.get(s.id) else {
                    self.counters.unmatched += 1;
                    continue;
                };
                let mut position = pb::vec3_or_zero(&s.position);
                let mut normal = glam::Vec3::ZERO;
                let mut stale = false;
                let object = if s.hit {
                    let o = s.object_id;
                    if o >= objects {
                        self.counters.unmatched += 1;
                        continue;
                    }
                    // Shaded before a move that changed its shadow from a point light: wrong
                    // now, never shown; that may have changed it: right place, stale shading.
                    // (A sample of a moved object itself is stale anyway, below.)
                    if b.epoch < self.last_move_epoch && self.moved_at[o as usize] <= b.epoch {
                        match self.shading_since(b.epoch, position) {
                            ShadowChange::Changed => {
                                self.counters.shadow_changed += 1;
                                continue;
                            }
                            ShadowChange::Shifted(f) if f >= DROP_DRIFT => {
                                self.counters.shadow_changed += 1;
                                continue;
                            }
                            ShadowChange::Unknown | ShadowChange::Shifted(_) => stale = true,
                            ShadowChange::Unchanged => {}
                        }
                    }
                    // The object moved after the sample was requested: the hit is carried to
                    // the object's current place (DESIGN.md "Motion"), its shading aged.
                    if self.moved_at[o as usize] > b.epoch {
                        if s.local_position.is_none() {
                            self.counters.stale_dropped += 1;
                            continue;
                        }
                        position = self.transforms[o as usize].transform_point3(pb::vec3_or_zero(&s.local_position));
                        stale = true;
                        self.counters.carried += 1;
                    }
                    // The side of the surface the sample was shaded from, as the object is now.
                    normal = (self.normal_to_world[o as usize] * pb::vec3_or_zero(&s.local_normal)).normalize_or_zero();
                    o
                } else {
                    // A background miss is a direction (DESIGN.md "Motion"); reprojection
                    // culls it wherever the scene's surfaces cover its pixel.
                    position = info.dir;
                    u32::MAX
                };
                let sample = Sample {
                    hit: s.hit,
                    position,
                    normal,
                    color: pb::vec3_or_zero(&s.rgb),
                    object,
                    epoch: b.epoch,
                    pixel: info.pixel,
                };
                if !(sample.position.is_finite() && sample.color.is_finite()) {
                    self.counters.nonfinite += 1;
                    continue;
                }
                if self.cache.insert_aimed(&sample, stale, info.point) {
                    inserted += 1;
                }
            }
        }
        if split {
            // Parts of requests the ring forgot (or whose other part was given up) never
            // complete: drop their partial sums.
            let ring = &self.ring;
            self.counters.parts_forgotten += self.split.forget(|id| ring.get(id).is_some()) as u64;
        }
        self.answers.clear();
        self.counters.samples_inserted += inserted as u64;
        self.counters.averaged = self.cache.averaged();
        inserted
    }

    /// What the moves since `epoch` did to the shadows at `p`, a point on an object that has
    /// not moved since: [`ShadowChange::Changed`] where an object that moved blocks a point
    /// light's segment in its place at `epoch` and not now, or now and not then (exact, with
    /// the object's triangles); [`ShadowChange::Shifted`] by the share of an area light its
    /// convex solids hide in one of those places only; [`ShadowChange::Unknown`] for an
    /// object without an exact test, or when the moves since `epoch` are no longer all
    /// remembered.
    fn shading_since(&self, epoch: u64, p: glam::Vec3) -> ShadowChange {
        if self.recent_moves.front().is_none_or(|m| m.epoch > epoch + 1) && epoch < self.last_move_epoch {
            return ShadowChange::Unknown;
        }
        let since = || self.recent_moves.iter().filter(|m| m.epoch > epoch);
        let mut worst = Worst::default();
        for (k, m) in since().enumerate() {
            // Each object once, at its first move since `epoch`: its place then was `from`.
            if since().take(k).any(|e| e.object == m.object) {
                continue;
            }
            let o = m.object as usize;
            let solids = m.placed_from.clone().zip(self.placed[o].clone());
            let query = MoveQuery::placed(self.move_shadows.get(m.object), &m.from, &self.transforms[o], solids, &self.lights, self.move_shadows.areas());
            // A segment that misses every box the object swept since then cannot have
            // changed (both its places are in them): no exact test needed.
            let swept = (0..self.lights.len()).filter(|&l| since().filter(|e| e.object == m.object).any(|e| self.lights[l].may_shadow(p, e.region)));
            if worst.add(worst_change(p, swept, &query)) {
                break;
            }
        }
        worst.answer()
    }

    /// Builds ray batches for the picked pixels and submits them, or as many as
    /// [`release_bound`] lets out now (the rest are held and go out as answers come back,
    /// [`Self::release_held`]). Batches still held from the last frame are dropped: this
    /// frame's picks replace them.
    fn send_requests(&mut self) {
        self.held.clear();
        let converging = self.still_frames > COHERENT_AFTER_FRAMES;
        let batch_size = self.settings.batch_size as usize;
        let spec = BatchSpec {
            epoch: self.epoch,
            shader: &self.shader,
            params: &self.shader_params,
            batch_size: if converging { batch_size.max(REST_BATCH_REQUESTS) } else { batch_size },
            parts: self.split.parts(),
            coherent: converging,
        };
        let mut batches = Vec::new();
        build_batches(&self.picks, &self.cam_frame, &mut self.ring, &spec, &mut self.next_batch_id, &mut self.seed, &mut batches);
        self.held.extend(batches);
        self.release_held();
    }

    /// Samples a second the workers can shade: the rate received is only what was let
    /// through, and a bound taken from it alone grows by a rest period's share a frame (at 2.5
    /// rest frames a second `cornell` with `gi` took 20 s to reach the workers' pace); the
    /// rate of the workers' busy time is what they do when they have work.
    fn workers_rate(&self) -> f64 {
        self.dispatcher.samples_per_second().max(self.dispatcher.samples_per_busy_second())
    }

    /// Submits held batches while the requests outstanding stay under [`release_bound`].
    fn release_held(&mut self) {
        if self.settings.paused {
            self.held.clear();
            return;
        }
        let parts = self.split.parts() as usize;
        let at_rest = self.still_frames >= REST_AFTER_FRAMES;
        let pixels = self.width as usize * self.height as usize;
        let bound = release_bound(self.settings.frame_budget(pixels), self.workers_rate() / parts as f64, REST_FRAMES, at_rest);
        let mut sent = 0u32;
        while let Some(b) = self.held.pop_front() {
            if (self.dispatcher.outstanding_requests() as usize) / parts >= bound {
                self.held.push_front(b);
                break;
            }
            let n = b.requests.len() as u32;
            match self.dispatcher.try_submit(b) {
                Ok(()) => sent += n,
                Err(b) => {
                    // Queue full: retried when the next answer frees room, or replaced by
                    // the next frame's (re-prioritised) selection.
                    self.counters.refused_batches += 1;
                    self.held.push_front(b);
                    break;
                }
            }
        }
        self.counters.samples_requested += sent as u64;
        self.requested += sent;
    }

    /// Sleeps until `late`, collecting inputs — or, from `soon` on, until a camera change or
    /// an object move is pending: a session pacing itself down at rest still answers the
    /// first motion at the interactive rate. Returns early only for that or when the viewer
    /// is gone.
    fn wait_inputs(&mut self, soon: Instant, late: Instant) {
        /// What ended one wait.
        enum Woke {
            Input(Input),
            InputsClosed,
            Answer(Answer),
            Timeout,
        }
        loop {
            if self.out.is_closed() {
                return;
            }
            let now = Instant::now();
            let motion = self.pending.iter().any(|i| matches!(i, Input::Camera(_) | Input::Move(_)));
            if now >= late || (motion && now >= soon) {
                return;
            }
            let step = if motion { soon } else { late }.min(now + POLL);
            // Samples that arrive while the loop waits (most of a frame at rest, paced down to
            // `rest_fps`) are inserted at once rather than at the start of the next frame:
            // the same insertions in the same order (nothing reads or changes the cache in
            // between), off the frame's critical path.
            let mut select = flume::Selector::new();
            if self.inputs_open {
                select = select.recv(&self.inputs, |r| r.map_or(Woke::InputsClosed, Woke::Input));
            }
            let woke = select.recv(self.dispatcher.answers(), |r| r.map_or(Woke::Timeout, Woke::Answer)).wait_deadline(step).unwrap_or(Woke::Timeout);
            match woke {
                Woke::Input(i) => self.pending.push(i),
                Woke::InputsClosed => self.inputs_open = false,
                Woke::Answer(a) => {
                    if let Answer::Samples { batch, .. } = a {
                        self.answers.push(batch);
                    }
                    let t = Instant::now();
                    self.between.0 += self.insert_samples();
                    self.between.1 += ms_since(t);
                    if !motion {
                        self.release_held();
                    }
                }
                Woke::Timeout => {}
            }
        }
    }
}

/// The matrix taking an object's normals to world space under `t`.
fn normal_matrix(t: &glam::Affine3A) -> glam::Mat3A {
    t.matrix3.inverse().transpose()
}

/// Moves remembered for samples that arrive after them.
const RECENT_MOVES: usize = 64;

/// One object move as samples shaded before it need it.
#[derive(Debug, Clone)]
struct RecentMove {
    epoch: u64,
    object: u32,
    /// The object's transform before the move.
    from: glam::Affine3A,
    /// The world box it swept (old and new place).
    region: (glam::Vec3, glam::Vec3),
    /// Its convex solids placed before the move, if it is made of them.
    placed_from: Option<Arc<PlacedSolids>>,
}

/// A light as the shadow tests see it: every emitting point within a sphere.
fn light_bound(l: &edgepoint_scene::Light) -> LightBound {
    let center = l.center();
    let radius = match l {
        edgepoint_scene::Light::Point { .. } | edgepoint_scene::Light::Spot { .. } => 0.0,
        edgepoint_scene::Light::Area { vertices, .. } => vertices.iter().map(|v| (*v - center).length()).fold(0.0, f32::max),
    };
    LightBound { center, radius }
}


fn ms_since(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outstanding_follows_the_measured_rate_within_bounds() {
        let z = Duration::ZERO;
        assert_eq!(max_outstanding(1000, 0.0, z, 1), 4000, "unmeasured: four frames");
        assert_eq!(max_outstanding(1000, 25_000.0, z, 1), 2500, "100 ms of work at 25k samples/s");
        assert_eq!(max_outstanding(1000, 1_000.0, z, 1), 1000, "never below one frame");
        assert_eq!(max_outstanding(1000, 1e9, z, 1), 4000, "never above four frames");
        assert_eq!(max_outstanding(1000, f64::NAN, z, 1), 4000);
    }

    #[test]
    fn at_rest_the_bound_covers_the_rest_period_and_grows_to_the_workers_rate() {
        let rest = Duration::from_millis(100);
        assert_eq!(max_outstanding(1000, 25_000.0, rest, 3), 5000, "200 ms of work at 25k samples/s");
        assert_eq!(max_outstanding(1000, 1e9, rest, 3), 12_000, "never above four frames per interactive period");
        assert_eq!(max_outstanding(1000, 1e9, rest, 0), 4000, "frames count at least one");
        assert_eq!(max_outstanding(1000, 0.0, rest, 3), 4000, "unmeasured: four frames, at rest too");
        // Requests go out once per rest period, the measured rate is what the bound let
        // through; when the workers answer within the period, the bound doubles each period
        // until it reaches what the workers can shade (here 300k/s, 60k in 200 ms).
        let (capacity, per_frame) = (300_000.0f64, 4096usize);
        let mut bound = per_frame;
        for _ in 0..20 {
            let rate = (bound as f64 / rest.as_secs_f64()).min(capacity);
            bound = max_outstanding(per_frame, rate, rest, 4);
        }
        assert_eq!(bound, 60_000, "the workers' rate times 200 ms");
        // Without the rest period in the bound (as in motion) it stays where it started.
        let mut stuck = per_frame;
        for _ in 0..20 {
            stuck = max_outstanding(per_frame, stuck as f64 / rest.as_secs_f64(), Duration::ZERO, 4);
        }
        assert_eq!(stuck, per_frame);
    }

    #[test]
    fn at_rest_only_the_workers_latency_worth_goes_out_and_motion_sends_everything() {
        let per_frame = 4096;
        assert_eq!(release_bound(per_frame, 0.0, REST_FRAMES, true), per_frame * OUTSTANDING_FRAMES, "rate unknown");
        assert_eq!(release_bound(per_frame, 500_000.0, REST_FRAMES, true), 50_000, "100 ms of work");
        assert_eq!(release_bound(per_frame, 1e9, REST_FRAMES, true), per_frame * OUTSTANDING_FRAMES * REST_FRAMES);
        assert_eq!(release_bound(per_frame, 1_000.0, REST_FRAMES, true), per_frame, "never below a frame's budget");
        assert_eq!(release_bound(per_frame, 500_000.0, REST_FRAMES, false), usize::MAX, "in motion a frame's budget goes at once");
    }

    #[test]
    fn a_still_view_fills_the_room_in_flight_and_motion_keeps_the_budget() {
        for still in 0..REST_AFTER_FRAMES {
            assert_eq!(frame_requests(1000, 3500, still), 1000, "in motion: one frame's budget");
            assert_eq!(frame_requests(1000, 300, still), 300, "in motion: no more than the room");
        }
        assert_eq!(frame_requests(1000, 3500, REST_AFTER_FRAMES), 3500, "at rest: all the room");
        assert_eq!(frame_requests(1000, 0, u32::MAX), 0, "at rest, full: nothing");
    }

    #[test]
    fn a_still_view_paces_down_to_the_rest_rate_but_never_above_the_cap() {
        let s = SessionSettings { max_fps: 30.0, rest_fps: 10.0, ..Default::default() };
        let (fast, slow) = (Duration::from_secs_f64(1.0 / 30.0), Duration::from_secs_f64(0.1));
        assert_eq!(frame_periods(&s, 0), (fast, fast));
        assert_eq!(frame_periods(&s, REST_AFTER_FRAMES - 1), (fast, fast));
        assert_eq!(frame_periods(&s, REST_AFTER_FRAMES), (fast, slow));
        let capped = SessionSettings { max_fps: 5.0, rest_fps: 10.0, ..Default::default() };
        let five = Duration::from_secs_f64(0.2);
        assert_eq!(frame_periods(&capped, u32::MAX), (five, five), "rest_fps above max_fps changes nothing");
    }
}
