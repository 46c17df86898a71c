//! Where a session's discontinuity edges come from each frame (paper 000 §6 and Figure 2's
//! "edge finder"; DESIGN.md step 2). The frame loop must never wait on it:
//!
//! - The edge trees and receiver hierarchies of the scene ([`SceneEdgeIndex`]) take up to
//!   seconds to build on a big mesh (the dragon: about 1.5 s). They are built on a helper
//!   thread — once per scene on the server, shared by every session that renders it — and
//!   until they are ready the frame loop finds edges by brute force (the same edges, more
//!   slowly), so frames flow from the first one.
//! - Silhouettes, sharp and boundary edges depend on the eye: the frame thread finds them
//!   every frame from the trees ([`GeometricFinder`]).
//! - Shadow edges do not depend on the eye but on the light–blocker–receiver triples the
//!   workers report and on object moves (§6.5). A new light–blocker pair on a big blocker
//!   costs far more than a frame (hundreds of milliseconds for the dragon), so the shadow
//!   store lives on its own thread ([`ShadowFinder`]): the frame loop posts the current
//!   transforms and triples when they change (latest job wins) and uses the newest shadow
//!   edges published. After a move the previous shadow edges stay up until the update
//!   lands, typically a frame later.
//!
//! - Several lights (paper 003): with a simplification tolerance above 0 the shadow thread
//!   also estimates, per shadow edge, the error of leaving it out where the other lights
//!   wash it out ([`crate::edges::simplify`]), and publishes only the edges at or above
//!   the tolerance. At 0 nothing is estimated and every edge goes to the EPI. An estimate
//!   outlives a move that leaves its edge as it was and whose boxes miss the hulls of its
//!   band and every light ([`crate::edges::simplify::SceneLights::still_holds`]): while an
//!   object is dragged only the edges near it are estimated again.
//! - Soft shadows: the shadow thread publishes every area-light shadow edge with its
//!   penumbra's extent at its ends; each frame only the part of it whose penumbra is narrow
//!   on screen goes to the EPI as a barrier ([`crate::epi::soft`]), and interpolation
//!   crosses the rest (a soft shadow's boundary is continuous). Hard edges go whole.
//!
//! - The discontinuity mesh (`--shadow-edges mesh`, issue 15 item 4): the shadow thread
//!   also keeps the mesh of every area light ([`super::mesh_shadows`]), built once and
//!   updated incrementally after each move, and its extremal and steep interior edges
//!   replace the finder's area-light shadow edges; point lights' hard edges still come
//!   from the finder. Until the mesh is built (seconds on a big scene) and while an update
//!   runs, the finder's edges or the mesh's older ones stay up.
//!
//! Both the build and the updates run on the [`crate::background`] pool, never on the
//! global pool the frame loop's per-pixel passes use.
use super::TripleKey;
use crate::edges::brute::scene_edges;
use crate::edges::finder::{GeometricFinder, SceneEdgeIndex, ShadowFinder, ViewVolume};
use crate::edges::shadow::ShadowUpdateStats;
use crate::edges::simplify::EdgeErrors;
use crate::edges::{EdgeKind, EdgeSegment};
use super::mesh_shadows::MeshShadows;
use crate::epi::raster::SegmentProjector;
use crate::epi::soft::append_barriers;
use edgepoint_scene::{NoProgress, Progress, Scene};
use glam::{Affine3A, Vec3};
use std::sync::{Arc, Condvar, Mutex, OnceLock};
use std::time::Instant;

/// The edge index of one scene, built at most once and shared by the sessions on it.
pub type EdgeIndexSlot = Arc<OnceLock<Arc<SceneEdgeIndex>>>;

/// What [`SessionEdges::find`] did this frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EdgeSourceStats {
    /// The edge trees were used (false: brute force while they build).
    pub trees: bool,
    /// Milliseconds of the shadow updates that finished since the last frame (on the
    /// shadow thread, not part of this frame's time).
    pub shadow_update_ms: f64,
    /// The last finished shadow update.
    pub shadow: ShadowUpdateStats,
    /// Shadow edges the last published result left out as washed out by other lights
    /// (paper 003; 0 with simplification off).
    pub shadow_simplified: usize,
    /// The simplification tolerance that result was chosen at.
    pub shadow_tolerance: f64,
}

/// A session's edge finding: brute force until the index is ready, then the trees on the
/// frame thread and the shadow store on its own thread.
pub struct SessionEdges {
    scene: Arc<Scene>,
    /// Delivers the index once built.
    ready: flume::Receiver<Arc<SceneEdgeIndex>>,
    running: Option<Running>,
    /// Reports the discontinuity mesh's build, given to the shadow thread when it starts.
    mesh_progress: Option<Box<dyn Progress + Send>>,
}

struct Running {
    geometric: GeometricFinder,
    shadows: ShadowThread,
    /// The newest shadow edges taken from the shadow thread.
    current: Arc<ShadowResult>,
    /// What was last posted, to post again only on change.
    posted_transforms: Vec<Affine3A>,
    posted_triples: usize,
    posted_tolerance: f64,
    posted_mesh: bool,
}

impl SessionEdges {
    /// Starts building (or waiting for another session's build of) the scene's edge index on
    /// a helper thread. `progress` reports the build; `mesh_progress` the discontinuity
    /// mesh's, and its first estimates (paper 003), if the session asks for the mesh.
    pub fn new(scene: Arc<Scene>, slot: EdgeIndexSlot, progress: Box<dyn Progress + Send>, mesh_progress: Box<dyn Progress + Send>) -> SessionEdges {
        let (tx, rx) = flume::bounded(1);
        let s = scene.clone();
        let spawned = std::thread::Builder::new().name("edge-index".into()).spawn(move || {
            let t = Instant::now();
            let index = slot
                .get_or_init(|| crate::background::pool().install(|| Arc::new(SceneEdgeIndex::build(&s, &*progress))))
                .clone();
            tracing::debug!(ms = t.elapsed().as_secs_f64() * 1e3, "edge index ready");
            // The session may be gone already: nothing to do then.
            let _ = tx.send(index);
        });
        if let Err(e) = spawned {
            // Without the thread the session keeps the brute-force finder: slower, same edges.
            tracing::error!("cannot start the edge-index thread ({e}); edges are found by brute force");
        }
        SessionEdges { scene, ready: rx, running: None, mesh_progress: Some(mesh_progress) }
    }

    /// Whether the edge trees are in use.
    pub fn trees_ready(&self) -> bool {
        self.running.is_some()
    }

    /// This frame's edges into `out` (cleared first): the geometric edges seen from `eye`
    /// with the objects at `transforms`, and the newest shadow edges of `triples` — those
    /// other lights do not wash out below `simplify_tolerance` (0: all of them), the soft
    /// ones cut to where their penumbra is narrow in the frame's projection `screen`
    /// ([`crate::epi::soft`]; `None`: every edge whole).
    #[allow(clippy::too_many_arguments)]
    pub fn find(
        &mut self,
        transforms: &[Affine3A],
        eye: Vec3,
        view: &ViewVolume,
        triples: &dyn TripleSet,
        sharp_cutoff_degrees: f32,
        simplify_tolerance: f64,
        mesh_shadow_edges: bool,
        screen: Option<&SegmentProjector>,
        out: &mut Vec<EdgeSegment>,
    ) -> EdgeSourceStats {
        out.clear();
        if self.running.is_none() {
            if let Ok(index) = self.ready.try_recv() {
                let mesh_progress = self.mesh_progress.take().unwrap_or_else(|| Box::new(NoProgress));
                self.running = Running::start(index, self.scene.clone(), mesh_progress);
            }
        }
        let Some(r) = &mut self.running else {
            scene_edges(&self.scene, transforms, eye, sharp_cutoff_degrees, out);
            return EdgeSourceStats::default();
        };
        r.geometric.edges(transforms, eye, Some(view), sharp_cutoff_degrees, out);
        if r.posted_transforms != transforms || r.posted_triples != triples.len() || r.posted_tolerance != simplify_tolerance || r.posted_mesh != mesh_shadow_edges {
            r.posted_transforms.clear();
            r.posted_transforms.extend_from_slice(transforms);
            r.posted_triples = triples.len();
            r.posted_tolerance = simplify_tolerance;
            r.posted_mesh = mesh_shadow_edges;
            r.shadows.post(ShadowJob { transforms: transforms.to_vec(), triples: triples.keys(), simplify_tolerance, mesh: mesh_shadow_edges });
        }
        let mut stats = EdgeSourceStats { trees: true, ..Default::default() };
        if let Some((result, ms)) = r.shadows.take() {
            r.current = result;
            stats.shadow_update_ms = ms;
        }
        stats.shadow = r.current.stats;
        stats.shadow_simplified = r.current.simplified;
        stats.shadow_tolerance = r.current.tolerance;
        append_barriers(&r.current.segments, screen, out);
        stats
    }
}

/// The triples a session has seen (its feedback map), without copying them every frame.
pub trait TripleSet {
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    fn keys(&self) -> Vec<TripleKey>;
}

impl<V> TripleSet for std::collections::HashMap<TripleKey, V> {
    fn len(&self) -> usize {
        std::collections::HashMap::len(self)
    }
    fn keys(&self) -> Vec<TripleKey> {
        std::collections::HashMap::keys(self).copied().collect()
    }
}

impl Running {
    fn start(index: Arc<SceneEdgeIndex>, scene: Arc<Scene>, mesh_progress: Box<dyn Progress + Send>) -> Option<Running> {
        let shadows = ShadowThread::spawn(ShadowFinder::new(index.clone()), scene, mesh_progress)?;
        Some(Running {
            geometric: GeometricFinder::new(index),
            shadows,
            current: Arc::new(ShadowResult::default()),
            posted_transforms: Vec::new(),
            posted_triples: usize::MAX,
            posted_tolerance: 0.0,
            posted_mesh: false,
        })
    }
}

/// The state the shadow store is asked to reach.
struct ShadowJob {
    transforms: Vec<Affine3A>,
    triples: Vec<TripleKey>,
    simplify_tolerance: f64,
    /// Area-light shadow edges from the discontinuity mesh.
    mesh: bool,
}

/// What the shadow thread publishes: the stored shadow edges that go to the EPI, world
/// space, each with its penumbra at its ends (zero for hard edges), and how many the
/// simplification left out.
#[derive(Default)]
struct ShadowResult {
    segments: Vec<(EdgeSegment, [Vec3; 2])>,
    stats: ShadowUpdateStats,
    simplified: usize,
    tolerance: f64,
}

/// The shadow edges that go to the EPI (appended to `out`): every one at tolerance 0
/// (simplification off: today's edges exactly), else those whose estimated error of
/// leaving them out ([`crate::edges::simplify`]) is not below the tolerance. Returns how
/// many were left out.
pub fn chosen_shadow_edges<T: Copy>(errors: &[(T, f64)], tolerance: f64, out: &mut Vec<T>) -> usize {
    let before = out.len();
    if tolerance > 0.0 {
        out.extend(errors.iter().filter(|(_, e)| e.is_nan() || *e >= tolerance).map(|(s, _)| *s));
    } else {
        out.extend(errors.iter().map(|(s, _)| *s));
    }
    errors.len() - (out.len() - before)
}

/// Mesh shadow edges estimated between two looks for a newer job (about a second's work
/// on `rooms`).
const MESH_ESTIMATE_CHUNK: usize = 2048;

/// The finder's shadow edges with the area lights' replaced by the mesh's (those the
/// mesh's estimates leave out at `tolerance` left out): point lights' hard edges stay.
/// Returns how many of the mesh's were left out.
fn with_mesh_edges(segments: &mut Vec<(EdgeSegment, [Vec3; 2])>, mesh: &MeshShadows, tolerance: f64) -> usize {
    segments.retain(|(e, _)| !matches!(e.kind, EdgeKind::ShadowUmbral | EdgeKind::ShadowPenumbral));
    mesh.published(tolerance, segments)
}

/// Between the frame loop and the shadow thread: the newest job (an older one not yet
/// started is replaced) and the newest result with the time the updates took.
#[derive(Default)]
struct Mailbox {
    job: Option<ShadowJob>,
    result: Option<(Arc<ShadowResult>, f64)>,
    closed: bool,
}

struct ShadowThread {
    shared: Arc<(Mutex<Mailbox>, Condvar)>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ShadowThread {
    fn spawn(mut finder: ShadowFinder, scene: Arc<Scene>, mesh_progress: Box<dyn Progress + Send>) -> Option<ShadowThread> {
        let shared: Arc<(Mutex<Mailbox>, Condvar)> = Arc::default();
        // The mesh's first estimates are reported as one stage over however many calls
        // they take (a newer job pauses them; a minute on `rooms`); those after moves are a
        // few each, made and paused as the object goes on moving: not reported.
        let (mut first_estimates, mut first_begun) = (true, false);
        let mut errors = EdgeErrors::new();
        // The mesh, once a job asks for it; `Err(())` once a build found no area light.
        let mut mesh: Option<Result<MeshShadows, ()>> = None;
        // Per scene light, whether it is an area light (the mesh's); a triple's index out of
        // range is the finder's to refuse.
        let area_light: Vec<bool> = scene.lights.iter().map(|l| matches!(l, edgepoint_scene::Light::Area { .. })).collect();
        let s = shared.clone();
        let thread = std::thread::Builder::new()
            .name("shadow-edges".into())
            .spawn(move || loop {
                let job = {
                    let (lock, cv) = &*s;
                    let mut m = lock.lock().unwrap_or_else(|p| p.into_inner());
                    loop {
                        if m.closed {
                            return;
                        }
                        if let Some(j) = m.job.take() {
                            break j;
                        }
                        m = cv.wait(m).unwrap_or_else(|p| p.into_inner());
                    }
                };
                let publish_now = |result: ShadowResult, ms: f64| {
                    let mut m = s.0.lock().unwrap_or_else(|p| p.into_inner());
                    // Updates the frame loop has not taken yet add up: it reports their time.
                    let earlier = m.result.take().map_or(0.0, |r| r.1);
                    m.result = Some((Arc::new(result), earlier + ms));
                };
                // With the mesh built, its edges replace the finder's area-light ones (its
                // older ones stay up while it is brought to a move), and the finder is given
                // only the point lights' triples: its area-light edges would be thrown away.
                // Before that, the finder's area-light edges show meanwhile.
                let meshing = job.mesh && matches!(mesh, Some(Ok(_)));
                let triples: Vec<TripleKey> = if meshing { job.triples.into_iter().filter(|k| !area_light.get(k.light as usize).copied().unwrap_or(false)).collect() } else { job.triples };
                // The finder's edges last published, with how many it left out and at what
                // tolerance, for the mesh's to join below.
                let (mut finder_edges, mut finder_simplified, mut finder_tolerance) = (Vec::new(), 0, 0.0);
                let mut publish = |mut result: ShadowResult, ms: f64| {
                    if job.mesh {
                        finder_edges.clone_from(&result.segments);
                        (finder_simplified, finder_tolerance) = (result.simplified, result.tolerance);
                    }
                    if let (true, Some(Ok(m))) = (meshing, &mesh) {
                        result.simplified += with_mesh_edges(&mut result.segments, m, result.tolerance);
                    }
                    publish_now(result, ms);
                };
                let (stats, ms) = crate::background::pool().install(|| {
                    finder.set_transforms(&job.transforms);
                    finder.update(triples)
                });
                let tolerance = job.simplify_tolerance;
                if tolerance > 0.0 {
                    // The estimates of new edges can take longer than the update (seconds
                    // on `rooms`): the edges go out first, those whose estimates outlived the
                    // move decided by them and the others all, so shadows show meanwhile.
                    let with_penumbrae = crate::background::pool().install(|| finder.with_penumbrae());
                    let known = crate::background::pool().install(|| finder.known_errors(&mut errors));
                    if known.iter().any(|(_, e)| e.is_nan()) {
                        debug_assert_eq!(with_penumbrae.len(), known.len());
                        let all: Vec<_> = with_penumbrae.iter().copied().zip(&known).map(|(s, (_, e))| (s, *e)).collect();
                        let mut segments = Vec::with_capacity(all.len());
                        let simplified = chosen_shadow_edges(&all, tolerance, &mut segments);
                        publish(ShadowResult { segments, stats, simplified, tolerance }, ms);
                    }
                    let t = Instant::now();
                    let (all, estimated) = crate::background::pool().install(|| finder.errors(&mut errors));
                    // Both in the store's order.
                    debug_assert_eq!(with_penumbrae.len(), all.len());
                    let all: Vec<_> = with_penumbrae.into_iter().zip(&all).map(|(s, (_, e))| (s, *e)).collect();
                    let mut segments = Vec::with_capacity(all.len());
                    let simplified = chosen_shadow_edges(&all, tolerance, &mut segments);
                    let est_ms = t.elapsed().as_secs_f64() * 1e3;
                    tracing::debug!(edges = all.len(), estimated, left_out = simplified, ms = est_ms, "shadow edges simplified (paper 003)");
                    publish(ShadowResult { segments, stats, simplified, tolerance }, est_ms);
                } else {
                    let segments = crate::background::pool().install(|| finder.with_penumbrae());
                    publish(ShadowResult { segments, stats, simplified: 0, tolerance }, ms);
                }
                // The finder's last publication with the mesh's edges at `tolerance`.
                let with_mesh = |m: &MeshShadows, tolerance: f64| {
                    let mut segments = finder_edges.clone();
                    let simplified = finder_simplified + with_mesh_edges(&mut segments, m, tolerance);
                    ShadowResult { segments, stats, simplified, tolerance }
                };
                if job.mesh && !matches!(&mesh, Some(Err(()))) && !matches!(&mesh, Some(Ok(m)) if m.at(&job.transforms)) {
                    // Built or brought to the job's transforms, then published again.
                    let t = Instant::now();
                    crate::background::pool().install(|| match &mut mesh {
                        Some(Ok(m)) => {
                            m.sync(&job.transforms);
                            // The estimates the move cannot have changed stay: the edges go
                            // out simplified at once, but for those estimated again below.
                            if tolerance > 0.0 {
                                let dropped = m.check_estimates(&finder.scene_lights().0);
                                tracing::debug!(dropped, "mesh shadow edge estimates checked after a move");
                            }
                        }
                        _ => mesh = Some(MeshShadows::build(&scene, &job.transforms, &*mesh_progress).ok_or(())),
                    });
                    if let Some(Ok(m)) = &mesh {
                        publish_now(with_mesh(m, finder_tolerance), t.elapsed().as_secs_f64() * 1e3);
                    }
                }
                // Paper 003 on the mesh's edges: those not estimated yet (all at first; after
                // a move the new ones and those whose band it reached) are estimated, and went
                // out above meanwhile; then only those at or above the tolerance. A newer job
                // (an object moved, the tolerance changed) stops them between chunks; they go
                // on from there.
                if let (true, true, Some(Ok(m))) = (job.mesh, tolerance > 0.0, &mut mesh) {
                    if m.estimates_missing() {
                        let t = Instant::now();
                        let newer = || s.0.lock().unwrap_or_else(|p| p.into_inner()).job.is_some();
                        if first_estimates && !first_begun {
                            mesh_progress.begin("estimates of the shadow edges (paper 003)", m.estimates_to_make() as u64);
                            first_begun = true;
                        }
                        let progress: &dyn Progress = if first_estimates { &*mesh_progress } else { &NoProgress };
                        let estimated = crate::background::pool().install(|| m.estimate(&finder.scene_lights().0, MESH_ESTIMATE_CHUNK, newer, progress));
                        if first_estimates && !m.estimates_missing() {
                            mesh_progress.end();
                            first_estimates = false;
                        }
                        let ms = t.elapsed().as_secs_f64() * 1e3;
                        // Published also when paused: the edges estimated so far are
                        // decided, the others go.
                        let result = with_mesh(m, finder_tolerance);
                        let left_out = result.simplified - finder_simplified;
                        if m.estimates_missing() {
                            tracing::debug!(estimated, left_out, ms, "mesh shadow edge estimates paused for a newer job");
                        } else {
                            tracing::debug!(estimated, left_out, ms, "mesh shadow edges simplified (paper 003)");
                        }
                        publish_now(result, ms);
                    }
                }
            })
            .map_err(|e| tracing::error!("cannot start the shadow-edge thread ({e}); no shadow edges in this session"))
            .ok()?;
        Some(ShadowThread { shared, thread: Some(thread) })
    }

    fn post(&self, job: ShadowJob) {
        let (lock, cv) = &*self.shared;
        lock.lock().unwrap_or_else(|p| p.into_inner()).job = Some(job);
        cv.notify_one();
    }

    fn take(&self) -> Option<(Arc<ShadowResult>, f64)> {
        self.shared.0.lock().unwrap_or_else(|p| p.into_inner()).result.take()
    }
}

impl Drop for ShadowThread {
    fn drop(&mut self) {
        let (lock, cv) = &*self.shared;
        lock.lock().unwrap_or_else(|p| p.into_inner()).closed = true;
        cv.notify_one();
        // An update in progress finishes first (it cannot be interrupted); the session's
        // thread is ending anyway, so waiting here keeps the thread count bounded.
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edges::EdgeKind;
    use std::collections::HashMap;
    use std::time::Duration;

    fn view(scene: &Scene) -> ViewVolume {
        ViewVolume::new(&scene.camera, 1.0)
    }

    /// Frames until the trees are in use and a shadow update has landed, with a deadline.
    fn run_until(
        edges: &mut SessionEdges,
        scene: &Scene,
        t: &[Affine3A],
        triples: &HashMap<TripleKey, ()>,
        done: impl Fn(&EdgeSourceStats, &[EdgeSegment]) -> bool,
    ) -> Vec<EdgeSegment> {
        run_until_at(edges, scene, t, triples, 0.0, done).0
    }

    /// [`run_until`] with a simplification tolerance; also returns the last stats.
    fn run_until_at(
        edges: &mut SessionEdges,
        scene: &Scene,
        t: &[Affine3A],
        triples: &HashMap<TripleKey, ()>,
        tolerance: f64,
        done: impl Fn(&EdgeSourceStats, &[EdgeSegment]) -> bool,
    ) -> (Vec<EdgeSegment>, EdgeSourceStats) {
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut out = Vec::new();
        loop {
            let st = edges.find(t, scene.camera.eye, &view(scene), triples, 85.0, tolerance, false, None, &mut out);
            if done(&st, &out) {
                return (out, st);
            }
            assert!(Instant::now() < deadline, "edge source did not get there in time");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    fn sorted_keys(v: &[EdgeSegment]) -> Vec<(u32, EdgeKind, [i64; 6])> {
        let q = |x: f32| (x * 1e5).round() as i64;
        let mut k: Vec<_> = v.iter().map(|s| (s.object, s.kind, [q(s.a.x), q(s.a.y), q(s.a.z), q(s.b.x), q(s.b.y), q(s.b.z)])).collect();
        k.sort_unstable();
        k
    }

    #[test]
    fn brute_force_first_then_trees_and_shadows_equal_to_a_direct_finder() {
        let scene = Arc::new(edgepoint_scene::builtin::load("cornell-point").unwrap());
        let slot: EdgeIndexSlot = Arc::default();
        let mut edges = SessionEdges::new(scene.clone(), slot.clone(), Box::new(NoProgress), Box::new(NoProgress));
        let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let id = |n: &str| scene.object_id(n).unwrap();
        let mut triples: HashMap<TripleKey, ()> = HashMap::new();
        for b in ["tallbox", "shortbox"] {
            for r in ["floor", "back", "redwall"] {
                triples.insert(TripleKey { light: 0, blocker: id(b), receiver: id(r) }, ());
            }
        }
        // Whatever finder is in use, the geometric edges are the brute-force ones.
        let mut first = Vec::new();
        edges.find(&t, scene.camera.eye, &view(&scene), &triples, 85.0, 0.0, false, None, &mut first);
        let mut brute = Vec::new();
        scene_edges(&scene, &t, scene.camera.eye, 85.0, &mut brute);
        let geo = |v: &[EdgeSegment]| sorted_keys(&v.iter().copied().filter(|s| s.kind.is_geometric()).collect::<Vec<_>>());
        assert_eq!(geo(&first), sorted_keys(&brute));

        let got = run_until(&mut edges, &scene, &t, &triples, |st, out| st.trees && out.iter().any(|s| !s.kind.is_geometric()));
        assert!(slot.get().is_some(), "the index went into the shared slot");
        // The same frame from a finder run directly.
        let mut direct = crate::edges::finder::EdgeFinder::from_index(slot.get().unwrap().clone());
        let mut want = Vec::new();
        direct.frame(&t, scene.camera.eye, Some(&view(&scene)), triples.keys().copied(), 85.0, &mut want);
        let all = |v: &[EdgeSegment]| sorted_keys(v);
        // Shadow edges of the thread are not filtered by the view (the rasterizer clips).
        let mut direct_all = crate::edges::finder::EdgeFinder::from_index(slot.get().unwrap().clone());
        let mut want_all = Vec::new();
        direct_all.frame(&t, scene.camera.eye, None, triples.keys().copied(), 85.0, &mut want_all);
        let shadows = |v: &[EdgeSegment]| sorted_keys(&v.iter().copied().filter(|s| !s.kind.is_geometric()).collect::<Vec<_>>());
        assert_eq!(geo(&got), geo(&want));
        assert_eq!(shadows(&got), shadows(&want_all));
        assert!(!all(&got).is_empty());

        // A move: the shadow thread catches up and matches a finder run at the new place.
        let mut moved = t.clone();
        let tall = id("tallbox") as usize;
        moved[tall] = Affine3A::from_translation(Vec3::new(-0.05, 0.0, 0.03)) * t[tall];
        let want_moved = {
            let mut f = crate::edges::finder::EdgeFinder::from_index(slot.get().unwrap().clone());
            let mut w = Vec::new();
            f.frame(&moved, scene.camera.eye, None, triples.keys().copied(), 85.0, &mut w);
            shadows(&w)
        };
        let got_moved = run_until(&mut edges, &scene, &moved, &triples, |_, out| shadows(out) == want_moved);
        assert_eq!(shadows(&got_moved), want_moved);

        // Simplification on (paper 003): with cornell's one light every shadow edge bounds
        // light no other light replaces, so a tolerance of 0.1 keeps them all; an absurd
        // one (10: more than the whole light) leaves out every edge it could estimate, and
        // back at 0 every edge is there again.
        let n = want_moved.len();
        let (kept, st) = run_until_at(&mut edges, &scene, &moved, &triples, 0.1, |st, _| st.shadow_tolerance == 0.1);
        assert_eq!((shadows(&kept), st.shadow_simplified), (want_moved.clone(), 0));
        let (few, st) = run_until_at(&mut edges, &scene, &moved, &triples, 10.0, |st, _| st.shadow_tolerance == 10.0);
        assert_eq!(shadows(&few).len() + st.shadow_simplified, n);
        assert!(st.shadow_simplified > n / 2, "{} of {n} left out", st.shadow_simplified);
        let back = run_until(&mut edges, &scene, &moved, &triples, |st, _| st.shadow_tolerance == 0.0);
        assert_eq!(shadows(&back), want_moved);
    }

    /// `--shadow-edges mesh`: the shadow thread publishes the discontinuity mesh's edges
    /// (with no triples at all), and after a move the mesh brought there incrementally.
    #[test]
    fn the_mesh_gives_the_area_light_shadow_edges_and_follows_a_move() {
        let scene = Arc::new(edgepoint_scene::builtin::load("cornell").unwrap());
        let mut edges = SessionEdges::new(scene.clone(), Arc::default(), Box::new(NoProgress), Box::new(NoProgress));
        let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let none: HashMap<TripleKey, ()> = HashMap::new();
        let shadows = |v: &[EdgeSegment]| sorted_keys(&v.iter().copied().filter(|s| !s.kind.is_geometric()).collect::<Vec<_>>());
        let mut direct = MeshShadows::build(&scene, &t, &NoProgress).expect("cornell has an area light");
        let published = |m: &MeshShadows, tolerance: f64| {
            let mut v = Vec::new();
            let left_out = m.published(tolerance, &mut v);
            (shadows(&v.iter().map(|e| e.0).collect::<Vec<_>>()), left_out)
        };
        let (want, _) = published(&direct, 0.0);
        assert!(!want.is_empty());
        let until = |edges: &mut SessionEdges, t: &[Affine3A], tolerance: f64, want: &[(u32, EdgeKind, [i64; 6])], left_out: usize| {
            let deadline = Instant::now() + Duration::from_secs(60);
            let mut out = Vec::new();
            loop {
                let st = edges.find(t, scene.camera.eye, &view(&scene), &none, 85.0, tolerance, true, None, &mut out);
                if shadows(&out) == want && st.shadow_simplified == left_out {
                    return;
                }
                assert!(Instant::now() < deadline, "mesh edges did not arrive: {} of {}", shadows(&out).len(), want.len());
                std::thread::sleep(Duration::from_millis(5));
            }
        };
        until(&mut edges, &t, 0.0, &want, 0);
        let mut moved = t.clone();
        let short = scene.object_id("shortbox").unwrap() as usize;
        moved[short] = Affine3A::from_translation(Vec3::new(0.04, 0.0, -0.03)) * t[short];
        assert!(direct.sync(&moved));
        let (want_moved, _) = published(&direct, 0.0);
        assert_ne!(want_moved, want, "the short box's shadow moved");
        // Only the receivers whose mesh the move replaced made their edges again: the same
        // edges as a mesh built there (also after a second move, of the other box).
        assert_eq!(published(&MeshShadows::build(&scene, &moved, &NoProgress).unwrap(), 0.0).0, want_moved);
        let mut twice = moved.clone();
        let tall = scene.object_id("tallbox").unwrap() as usize;
        twice[tall] = Affine3A::from_translation(Vec3::new(-0.03, 0.0, 0.05)) * t[tall];
        let mut other = MeshShadows::build(&scene, &moved, &NoProgress).unwrap();
        assert!(other.sync(&twice));
        assert_eq!(published(&other, 0.0).0, published(&MeshShadows::build(&scene, &twice, &NoProgress).unwrap(), 0.0).0);
        until(&mut edges, &moved, 0.0, &want_moved, 0);

        // Simplification (paper 003) on the mesh's edges: the session publishes those whose
        // estimate is at or above the tolerance, as the mesh estimated directly says. With
        // cornell's one light an absurd tolerance (10: more than the whole light) leaves out
        // most; back at 0 every edge is there again.
        let mut finder = ShadowFinder::new(Arc::new(SceneEdgeIndex::build(&scene, &NoProgress)));
        finder.set_transforms(&moved);
        // In chunks, stopped after the first: the rest go on from there, and meanwhile those
        // not estimated are published.
        assert!(direct.estimates_missing());
        let asked = std::cell::Cell::new(0);
        let first = direct.estimate(&finder.scene_lights().0, 16, || {
            asked.set(asked.get() + 1);
            asked.get() > 1
        }, &NoProgress);
        assert_eq!(first, 16.min(want_moved.len()));
        assert!(direct.estimates_missing(), "cornell has more than 16 mesh edges");
        let (part, part_left_out) = published(&direct, 10.0);
        assert!(part_left_out <= 16 && part.len() + part_left_out == want_moved.len(), "{part_left_out} left out");
        assert_eq!(first + direct.estimate(&finder.scene_lights().0, 16, || false, &NoProgress), want_moved.len());
        assert!(!direct.estimates_missing());
        let (few, left_out) = published(&direct, 10.0);
        assert_eq!(few.len() + left_out, want_moved.len());
        assert!(left_out > want_moved.len() / 2, "{left_out} of {} left out", want_moved.len());
        until(&mut edges, &moved, 10.0, &few, left_out);
        until(&mut edges, &moved, 0.0, &want_moved, 0);

        // Estimates outlive a move that cannot reach their band: after the tall box moves,
        // those kept and those made again equal the estimates all made afresh there.
        assert!(direct.sync(&twice));
        assert!(direct.estimates_missing());
        finder.set_transforms(&twice);
        let dropped = direct.check_estimates(&finder.scene_lights().0);
        let again = direct.estimate(&finder.scene_lights().0, 16, || false, &NoProgress);
        let kept = direct.keyed_estimates();
        direct.forget_estimates();
        let all = direct.estimate(&finder.scene_lights().0, 4096, || false, &NoProgress);
        assert_eq!(kept, direct.keyed_estimates());
        assert!(dropped > 0 && again < all, "{dropped} dropped, {again} of {all} estimated again");
    }

    /// Tolerance 0 is off: every edge goes to the EPI, whatever its estimate (even 0).
    #[test]
    fn tolerance_zero_leaves_the_shadow_edges_unchanged() {
        let seg = |x: f32, k: EdgeKind| EdgeSegment { a: Vec3::new(x, 0.0, 0.0), b: Vec3::new(x, 0.0, 1.0), kind: k, object: 3 };
        let errors = vec![
            (seg(0.0, EdgeKind::ShadowUmbral), 0.0),
            (seg(1.0, EdgeKind::ShadowPenumbral), 1e-9),
            (seg(2.0, EdgeKind::ShadowHard), 0.3),
            (seg(3.0, EdgeKind::ShadowHard), f64::INFINITY),
        ];
        let mut out = vec![seg(9.0, EdgeKind::Silhouette)];
        assert_eq!(chosen_shadow_edges(&errors, 0.0, &mut out), 0);
        assert_eq!(out[1..], errors.iter().map(|e| e.0).collect::<Vec<_>>()[..]);
        let mut out = Vec::new();
        assert_eq!(chosen_shadow_edges(&errors, 0.3, &mut out), 2);
        assert_eq!(out, vec![errors[2].0, errors[3].0]);
    }

    #[test]
    fn a_second_session_reuses_the_index() {
        let scene = Arc::new(edgepoint_scene::builtin::load("cornell").unwrap());
        let slot: EdgeIndexSlot = Arc::default();
        let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let none: HashMap<TripleKey, ()> = HashMap::new();
        let mut a = SessionEdges::new(scene.clone(), slot.clone(), Box::new(NoProgress), Box::new(NoProgress));
        run_until(&mut a, &scene, &t, &none, |st, _| st.trees);
        let first = slot.get().unwrap().clone();
        let mut b = SessionEdges::new(scene.clone(), slot.clone(), Box::new(NoProgress), Box::new(NoProgress));
        run_until(&mut b, &scene, &t, &none, |st, _| st.trees);
        assert!(Arc::ptr_eq(&first, slot.get().unwrap()));
    }
}
