//! The edge finder of the frame loop (paper 000 §6, Figure 2 "find edges"): per frame the
//! silhouettes, forward-facing sharp edges and boundary edges of the objects in view, from
//! their edge trees, and the shadow edges of the light–blocker–receiver triples the shader
//! workers reported, from the shadow store (recomputed only where something moved or a new
//! triple appeared).
//!
//! ```ignore
//! let mut finder = EdgeFinder::new(&scene, &progress);           // builds every tree
//! let stats = finder.frame(&transforms, camera.eye, Some(&ViewVolume::new(&camera, aspect)),
//!                          feedback.triples.keys().copied(), 85.0, &mut segments);
//! ```
use super::events::VertexRings;
use super::face_bvh::FaceBvh;
use super::geometric::{MeshEdgeTrees, SharpTree};
use super::shadow::{ShadowScene, ShadowStore, ShadowUpdateStats};
use super::simplify::{EdgeErrors, SceneLights};
use super::{EdgeCounts, EdgeKind, EdgeSegment};
use crate::edges::TripleKey;
use edgepoint_scene::{Camera, Light, Mesh, Progress, Scene};
use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use std::sync::Arc;
use std::time::Instant;

/// The camera's view volume (four side planes and the eye plane), for culling objects.
#[derive(Debug, Clone, Copy)]
pub struct ViewVolume {
    /// Inward plane normals and offsets: a point `p` is inside when `n · p >= d` for all.
    planes: [(Vec3, f32); 5],
}

impl ViewVolume {
    /// The volume seen by `camera` on an image of aspect ratio `aspect` (width / height).
    pub fn new(camera: &Camera, aspect: f32) -> ViewVolume {
        let f = camera.frame(1, 1);
        let ty = f.tan_half_y;
        let tx = ty * aspect.max(1e-6);
        // Side planes through the eye, normals pointing inside.
        let n = [
            (f.forward + f.right * tx).cross(f.up).normalize_or_zero() * -1.0,
            (f.forward - f.right * tx).cross(f.up).normalize_or_zero(),
            (f.forward + f.up * ty).cross(f.right).normalize_or_zero(),
            (f.forward - f.up * ty).cross(f.right).normalize_or_zero() * -1.0,
        ];
        let mut planes = [(f.forward, f.forward.dot(f.eye)); 5];
        for (k, nk) in n.into_iter().enumerate() {
            planes[k + 1] = (nk, nk.dot(f.eye));
        }
        ViewVolume { planes }
    }

    /// Whether the world-space box may be in view.
    pub fn may_see(&self, lo: Vec3, hi: Vec3) -> bool {
        self.planes.iter().all(|&(n, d)| {
            // The box corner farthest along n.
            let p = Vec3::select(n.cmpge(Vec3::ZERO), hi, lo);
            n.dot(p) >= d - 1e-6 * (1.0 + d.abs())
        })
    }
}

/// One frame's edge finding.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameEdgeStats {
    /// Silhouettes, sharp and boundary edges of the objects in view (ms).
    pub find_ms: f64,
    /// Shadow store update (events, intersections, clipping) (ms).
    pub shadow_ms: f64,
    /// Copying the stored shadow edges out (ms).
    pub output_ms: f64,
    pub objects_in_view: u32,
    pub objects_moved: u32,
    /// Segments handed out, per kind (paper Table 3: silhouette and shadow edges).
    pub counts: EdgeCounts,
    pub shadow: ShadowUpdateStats,
}

/// Build times and sizes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FinderBuildStats {
    pub edge_trees_ms: f64,
    pub face_bvhs_ms: f64,
    pub rings_ms: f64,
    pub edges: usize,
    pub faces: usize,
}

/// Everything per object that edge finding reads and never changes once built: the meshes,
/// their edge trees (§6.4), receiver face hierarchies and vertex rings (§6.3). Queries run
/// in object space, so moves never touch it; it is shared (behind an `Arc`) by every
/// session on the same scene and by each session's frame and shadow threads.
pub struct SceneEdgeIndex {
    meshes: Vec<Arc<Mesh>>,
    trees: Vec<MeshEdgeTrees>,
    bvhs: Vec<FaceBvh>,
    rings: Vec<Option<VertexRings>>,
    /// The scene's default object transforms and lights.
    defaults: Vec<Affine3A>,
    lights: Vec<Light>,
    pub build: FinderBuildStats,
}

impl SceneEdgeIndex {
    /// Builds every object's edge tree and face hierarchy (and vertex rings when the scene
    /// has area lights), in parallel. Long builds show progress.
    pub fn build(scene: &Scene, progress: &dyn Progress) -> SceneEdgeIndex {
        let meshes: Vec<Arc<Mesh>> = scene.objects.iter().map(|o| o.mesh.clone()).collect();
        let edges: usize = meshes.iter().map(|m| m.edges.len()).sum();
        let faces: usize = meshes.iter().map(|m| m.triangles.len()).sum();
        let t = Instant::now();
        progress.begin("edge trees", edges as u64);
        let trees: Vec<MeshEdgeTrees> = meshes.par_iter().map(|m| MeshEdgeTrees::build(m, progress)).collect();
        progress.end();
        let edge_trees_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        progress.begin("receiver hierarchies", faces as u64);
        let bvhs: Vec<FaceBvh> = meshes.par_iter().map(|m| FaceBvh::build(m, progress)).collect();
        progress.end();
        let face_bvhs_ms = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        let area = scene.lights.iter().any(|l| matches!(l, Light::Area { .. }));
        let rings = meshes.par_iter().map(|m| area.then(|| VertexRings::build(m))).collect();
        let rings_ms = t.elapsed().as_secs_f64() * 1e3;
        tracing::info!(
            "edge finder: {} objects, {edges} edges, trees {edge_trees_ms:.0} ms, face hierarchies {face_bvhs_ms:.0} ms",
            meshes.len()
        );
        SceneEdgeIndex {
            trees,
            bvhs,
            rings,
            defaults: scene.objects.iter().map(|o| o.transform).collect(),
            lights: scene.lights.clone(),
            build: FinderBuildStats { edge_trees_ms, face_bvhs_ms, rings_ms, edges, faces },
            meshes,
        }
    }

    /// Number of objects.
    pub fn objects(&self) -> usize {
        self.meshes.len()
    }

    /// The edge trees of object `o`.
    pub fn trees(&self, o: usize) -> &MeshEdgeTrees {
        &self.trees[o]
    }

    /// Object `o`'s transform in `transforms`, or its scene default.
    fn transform(&self, transforms: &[Affine3A], o: usize) -> Affine3A {
        transforms.get(o).copied().unwrap_or(self.defaults[o])
    }

    /// Which objects may be in `view` (all when `None`) at `transforms`.
    fn in_view(&self, transforms: &[Affine3A], view: Option<&ViewVolume>) -> Vec<bool> {
        (0..self.meshes.len())
            .map(|o| {
                view.is_none_or(|v| {
                    let (lo, hi) = world_box(&self.transform(transforms, o), self.meshes[o].bounds);
                    v.may_see(lo, hi)
                })
            })
            .collect()
    }
}

/// The view-dependent part of edge finding (§6.1, §6.2): silhouettes, forward-facing sharp
/// edges and boundary edges of the objects in view, from the shared trees. Owns the sharp
/// trees of its cut-off. Runs on the frame thread, every frame.
///
/// An object's edges depend only on the eye in its own coordinates, its transform and the
/// cut-off, so each object keeps the world-space edges of its last query and hands them out
/// again while those three are bit for bit the same (a still camera over still objects:
/// most frames of a session that converges). A moving eye queries the trees every frame:
/// on the scanned dragon a third of the silhouette edges change between two frames of a
/// one-degree orbit, so an older answer saves little there (README, *What is not done yet*).
/// Keeping the answer costs a frame that queries one copy of its segments (the dragon's
/// 31,000: about 1 MB, a few percent of the query).
pub struct GeometricFinder {
    index: Arc<SceneEdgeIndex>,
    sharp: Vec<SharpTree>,
    cos_cutoff: Option<f32>,
    scratch: (Vec<(u32, EdgeKind)>, Vec<u32>),
    last: Vec<Option<LastQuery>>,
    /// Objects answered from `last` / queried, over the finder's life.
    pub reused: u64,
    pub queried: u64,
}

/// One object's last answer and what it depended on.
struct LastQuery {
    eye: Vec3,
    to_world: Affine3A,
    segments: Vec<EdgeSegment>,
}

impl GeometricFinder {
    pub fn new(index: Arc<SceneEdgeIndex>) -> GeometricFinder {
        let n = index.objects();
        GeometricFinder {
            index,
            sharp: vec![SharpTree::default(); n],
            cos_cutoff: None,
            scratch: Default::default(),
            last: (0..n).map(|_| None).collect(),
            reused: 0,
            queried: 0,
        }
    }

    pub fn index(&self) -> &Arc<SceneEdgeIndex> {
        &self.index
    }

    /// Appends the silhouettes, forward-facing sharp edges (cut-off `sharp_cutoff_degrees`)
    /// and boundary edges of every object in `view` (all when `None`) seen from world-space
    /// `eye`, with objects at `transforms` (missing entries: the scene's default). Returns
    /// (milliseconds, objects in view).
    pub fn edges(
        &mut self,
        transforms: &[Affine3A],
        eye: Vec3,
        view: Option<&ViewVolume>,
        sharp_cutoff_degrees: f32,
        out: &mut Vec<EdgeSegment>,
    ) -> (f64, u32) {
        let t = Instant::now();
        let index = &*self.index;
        let cos = sharp_cutoff_degrees.to_radians().cos();
        if self.cos_cutoff != Some(cos) {
            self.sharp.par_iter_mut().enumerate().for_each(|(o, sharp)| {
                index.trees[o].prepare_sharp(&index.meshes[o], cos, sharp);
            });
            self.cos_cutoff = Some(cos);
            self.last.iter_mut().for_each(|l| *l = None);
        }
        let in_view = index.in_view(transforms, view);
        let mut seen = 0;
        let (found, scratch) = &mut self.scratch;
        for (o, &visible) in in_view.iter().enumerate() {
            if !visible {
                continue;
            }
            seen += 1;
            let to_world = index.transform(transforms, o);
            let eye_obj = to_world.inverse().transform_point3(eye);
            let same = |l: &LastQuery| l.eye.to_array().map(f32::to_bits) == eye_obj.to_array().map(f32::to_bits) && l.to_world == to_world;
            if let Some(l) = self.last[o].as_ref().filter(|l| same(l)) {
                out.extend_from_slice(&l.segments);
                self.reused += 1;
                continue;
            }
            found.clear();
            index.trees[o].query(&self.sharp[o], eye_obj, found, scratch);
            let m = &index.meshes[o];
            let mut segments = self.last[o].take().map(|l| l.segments).unwrap_or_default();
            segments.clear();
            segments.extend(found.iter().map(|&(i, kind)| {
                let e = &m.edges[i as usize];
                EdgeSegment {
                    a: to_world.transform_point3(m.positions[e.v[0] as usize]),
                    b: to_world.transform_point3(m.positions[e.v[1] as usize]),
                    kind,
                    object: o as u32,
                }
            }));
            out.extend_from_slice(&segments);
            self.last[o] = Some(LastQuery { eye: eye_obj, to_world, segments });
            self.queried += 1;
        }
        (t.elapsed().as_secs_f64() * 1e3, seen)
    }
}

/// The view-independent part (§6.3, §6.5): the shadow store, brought up to date with the
/// triples and the moves. Its updates can take long (a new light–blocker pair on a big
/// blocker), so a session runs it on its own thread, beside the frame loop.
pub struct ShadowFinder {
    index: Arc<SceneEdgeIndex>,
    lights: Vec<Light>,
    /// Transforms of the last update (moves are found by comparing).
    transforms: Vec<Affine3A>,
    light_moved: Vec<bool>,
    /// Objects moved since the last update.
    moved: Vec<bool>,
    store: ShadowStore,
}

impl ShadowFinder {
    pub fn new(index: Arc<SceneEdgeIndex>) -> ShadowFinder {
        let n = index.objects();
        ShadowFinder {
            lights: index.lights.clone(),
            transforms: index.defaults.clone(),
            light_moved: vec![false; index.lights.len()],
            moved: vec![false; n],
            store: ShadowStore::new(),
            index,
        }
    }

    /// Replaces light `i` (its shadow events are recomputed at the next update).
    pub fn set_light(&mut self, i: usize, light: Light) {
        if let Some(l) = self.lights.get_mut(i) {
            *l = light;
            self.light_moved[i] = true;
        }
    }

    /// Takes the current object transforms (`transforms[o]`, missing entries: the scene's
    /// default); objects whose transform changed since the last call are moved for the
    /// next [`Self::update`]. Returns how many moved.
    pub fn set_transforms(&mut self, transforms: &[Affine3A]) -> u32 {
        let mut moved = 0;
        for o in 0..self.index.objects() {
            let t = self.index.transform(transforms, o);
            if t != self.transforms[o] {
                self.transforms[o] = t;
                self.moved[o] = true;
                moved += 1;
            }
        }
        moved
    }

    /// The transforms the store is (or will be, after [`Self::update`]) computed for.
    pub fn transforms(&self) -> &[Affine3A] {
        &self.transforms
    }

    /// Brings the shadow store up to date with `triples` (the whole current set) and the
    /// moves since the last update. Returns what it did and its milliseconds.
    pub fn update(&mut self, triples: impl IntoIterator<Item = TripleKey>) -> (ShadowUpdateStats, f64) {
        let t = Instant::now();
        let index = &*self.index;
        let scene = ShadowScene {
            meshes: &index.meshes,
            trees: &index.trees,
            rings: &index.rings,
            bvhs: &index.bvhs,
            lights: &self.lights,
            transforms: &self.transforms,
        };
        let stats = self.store.update(&scene, triples, &self.moved, &self.light_moved);
        self.light_moved.iter_mut().for_each(|m| *m = false);
        self.moved.iter_mut().for_each(|m| *m = false);
        (stats, t.elapsed().as_secs_f64() * 1e3)
    }

    /// Appends the stored shadow edges on receivers in `view` (all when `None`).
    pub fn append(&self, view: Option<&ViewVolume>, out: &mut Vec<EdgeSegment>) {
        let in_view = self.index.in_view(&self.transforms, view);
        self.store.append(out, |o| in_view.get(o as usize).copied().unwrap_or(false));
    }

    /// The shadow store (for inspection and benchmarks).
    pub fn store(&self) -> &ShadowStore {
        &self.store
    }

    /// Every stored shadow edge with paper 003's estimate of the error of leaving it out
    /// ([`super::simplify`]), at the lights and transforms of the last update; `errors`
    /// keeps the estimates of edges that did not change. Also returns how many edges were
    /// estimated now.
    pub fn errors(&self, errors: &mut EdgeErrors) -> (Vec<(EdgeSegment, f64)>, usize) {
        errors.update(&self.store, &self.lights, &self.index.bvhs, &self.transforms)
    }

    /// Every stored shadow edge (in the order of [`Self::append`] without a view) with its
    /// penumbra at its two ends ([`SceneLights::penumbra`]: zero for hard edges), at the
    /// transforms of the last update.
    pub fn with_penumbrae(&self) -> Vec<(EdgeSegment, [Vec3; 2])> {
        let (scene, transforms) = self.scene_lights();
        let jobs = super::simplify::jobs(&self.store, transforms);
        let penumbrae = super::simplify::penumbrae(&scene, &jobs);
        jobs.into_iter().zip(penumbrae).map(|((e, ..), p)| (e, p)).collect()
    }

    /// The scene as paper 003's estimate sees it, and the transforms, of the last update.
    pub fn scene_lights(&self) -> (SceneLights<'_>, &[Affine3A]) {
        (SceneLights::new(&self.lights, &self.index.bvhs, &self.transforms), &self.transforms)
    }

    /// Every stored shadow edge with its estimate as far as `errors` knows it (NaN where not
    /// estimated yet), estimating nothing.
    pub fn known_errors(&self, errors: &mut EdgeErrors) -> Vec<(EdgeSegment, f64)> {
        errors.known(&self.store, &self.lights, &self.index.bvhs, &self.transforms)
    }

}

/// Both parts on one thread, for tests, benchmarks and single-threaded callers.
pub struct EdgeFinder {
    geometric: GeometricFinder,
    shadows: ShadowFinder,
    pub build: FinderBuildStats,
}

impl EdgeFinder {
    /// Builds every object's edge tree and face hierarchy (see [`SceneEdgeIndex::build`]).
    pub fn new(scene: &Scene, progress: &dyn Progress) -> EdgeFinder {
        EdgeFinder::from_index(Arc::new(SceneEdgeIndex::build(scene, progress)))
    }

    pub fn from_index(index: Arc<SceneEdgeIndex>) -> EdgeFinder {
        EdgeFinder { build: index.build, geometric: GeometricFinder::new(index.clone()), shadows: ShadowFinder::new(index) }
    }

    /// Replaces light `i` (its shadow events are recomputed at the next frame).
    pub fn set_light(&mut self, i: usize, light: Light) {
        self.shadows.set_light(i, light);
    }

    /// [`ShadowFinder::with_penumbrae`]: every stored shadow edge with its penumbra.
    pub fn shadow_penumbrae(&self) -> Vec<(EdgeSegment, [Vec3; 2])> {
        self.shadows.with_penumbrae()
    }

    /// The edge trees of object `o`.
    pub fn trees(&self, o: usize) -> &MeshEdgeTrees {
        self.geometric.index.trees(o)
    }

    /// One frame: appends to `out` the silhouettes, forward-facing sharp edges (cut-off
    /// `sharp_cutoff_degrees`) and boundary edges of every object in `view` (all objects
    /// when `None`) seen from world-space `eye`, and the shadow edges of `triples` (the
    /// whole current set) on receivers in view. `transforms[o]` is object `o`'s current
    /// object-to-world transform (missing entries: the scene's default); objects whose
    /// transform changed since the last frame count as moved.
    ///
    /// The same as [`Self::set_transforms`], [`Self::geometric_edges`] and
    /// [`Self::shadow_edges`] in a row (call those to run the parts on their own).
    pub fn frame(
        &mut self,
        transforms: &[Affine3A],
        eye: Vec3,
        view: Option<&ViewVolume>,
        triples: impl IntoIterator<Item = TripleKey>,
        sharp_cutoff_degrees: f32,
        out: &mut Vec<EdgeSegment>,
    ) -> FrameEdgeStats {
        let first = out.len();
        let objects_moved = self.set_transforms(transforms);
        let (find_ms, objects_in_view) = self.geometric_edges(eye, view, sharp_cutoff_degrees, out);
        let (shadow, shadow_ms, output_ms) = self.shadow_edges(triples, view, out);
        FrameEdgeStats {
            find_ms,
            shadow_ms,
            output_ms,
            objects_in_view,
            objects_moved,
            counts: EdgeCounts::of(&out[first..]),
            shadow,
        }
    }

    /// Takes this frame's object transforms (`transforms[o]`, missing entries: the scene's
    /// default); objects whose transform changed since the last call are moved for the next
    /// [`Self::shadow_edges`]. Returns how many moved.
    pub fn set_transforms(&mut self, transforms: &[Affine3A]) -> u32 {
        self.shadows.set_transforms(transforms)
    }

    /// Appends the silhouettes, forward-facing sharp edges and boundary edges of every object
    /// in `view` seen from world-space `eye`, at the transforms of the last
    /// [`Self::set_transforms`]. Returns (milliseconds, objects in view).
    pub fn geometric_edges(&mut self, eye: Vec3, view: Option<&ViewVolume>, sharp_cutoff_degrees: f32, out: &mut Vec<EdgeSegment>) -> (f64, u32) {
        self.geometric.edges(&self.shadows.transforms, eye, view, sharp_cutoff_degrees, out)
    }

    /// Brings the shadow store up to date with `triples` (the whole current set) and the
    /// moves since the last call, and appends the shadow edges on receivers in `view`.
    /// Returns (what the update did, its milliseconds, milliseconds copying edges out).
    pub fn shadow_edges(
        &mut self,
        triples: impl IntoIterator<Item = TripleKey>,
        view: Option<&ViewVolume>,
        out: &mut Vec<EdgeSegment>,
    ) -> (ShadowUpdateStats, f64, f64) {
        let (stats, shadow_ms) = self.shadows.update(triples);
        let t = Instant::now();
        self.shadows.append(view, out);
        (stats, shadow_ms, t.elapsed().as_secs_f64() * 1e3)
    }

    /// The shadow store (for inspection and benchmarks).
    pub fn store(&self) -> &ShadowStore {
        self.shadows.store()
    }

    /// See [`ShadowFinder::scene_lights`].
    pub fn scene_lights(&self) -> (SceneLights<'_>, &[Affine3A]) {
        self.shadows.scene_lights()
    }

    /// See [`ShadowFinder::errors`].
    pub fn errors(&self, errors: &mut EdgeErrors) -> (Vec<(EdgeSegment, f64)>, usize) {
        self.shadows.errors(errors)
    }

    /// [`ShadowFinder::known_errors`].
    pub fn known_errors(&self, errors: &mut EdgeErrors) -> Vec<(EdgeSegment, f64)> {
        self.shadows.known_errors(errors)
    }
}

/// World box of an object-space box.
pub fn world_box(t: &Affine3A, b: (Vec3, Vec3)) -> (Vec3, Vec3) {
    edgepoint_scene::geometry::transformed_box(t, b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::edges::brute;
    use edgepoint_scene::NoProgress;

    fn key(s: &EdgeSegment) -> (u32, EdgeKind, [i64; 6]) {
        let q = |x: f32| (x * 1e5).round() as i64;
        (s.object, s.kind, [q(s.a.x), q(s.a.y), q(s.a.z), q(s.b.x), q(s.b.y), q(s.b.z)])
    }

    #[test]
    fn geometric_edges_equal_brute_force_in_a_moved_scene() {
        let scene = edgepoint_scene::builtin::load("cornell").unwrap();
        let mut f = EdgeFinder::new(&scene, &NoProgress);
        let mut t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let tall = scene.object_id("tallbox").unwrap() as usize;
        for step in 0..5 {
            t[tall] = Affine3A::from_rotation_y(0.3 * step as f32) * scene.objects[tall].transform;
            let eye = scene.camera.eye + Vec3::new(0.1 * step as f32, 0.0, 0.0);
            let mut got = Vec::new();
            let st = f.frame(&t, eye, None, std::iter::empty(), 85.0, &mut got);
            let mut want = Vec::new();
            brute::scene_edges(&scene, &t, eye, 85.0, &mut want);
            let (mut g, mut w): (Vec<_>, Vec<_>) = (got.iter().map(key).collect(), want.iter().map(key).collect());
            g.sort_unstable();
            w.sort_unstable();
            assert_eq!(g, w);
            assert_eq!(st.counts.shadow, 0);
            assert_eq!(st.objects_moved, (step > 0) as u32);
        }
    }

    /// An object's last answer is handed out again exactly while its eye, transform and the
    /// cut-off are unchanged, and every frame still equals brute force.
    #[test]
    fn unchanged_objects_reuse_their_last_edges() {
        let scene = edgepoint_scene::builtin::load("cornell").unwrap();
        let mut f = EdgeFinder::new(&scene, &NoProgress);
        let n = scene.objects.len() as u64;
        let tall = scene.object_id("tallbox").unwrap() as usize;
        let mut t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let eye_a = scene.camera.eye;
        let eye_b = eye_a + Vec3::new(0.05, -0.02, 0.0);
        // (eye, move the tall box, cut-off, objects expected to be queried again)
        let steps = [(eye_a, false, 85.0, n), (eye_a, false, 85.0, 0), (eye_a, true, 85.0, 1), (eye_a, false, 85.0, 0), (eye_b, false, 85.0, n), (eye_b, false, 30.0, n), (eye_b, false, 30.0, 0)];
        for (k, &(eye, mv, cutoff, queried)) in steps.iter().enumerate() {
            if mv {
                t[tall] = Affine3A::from_translation(Vec3::new(0.02, 0.0, 0.01)) * t[tall];
            }
            let before = f.geometric.queried;
            let mut got = Vec::new();
            f.frame(&t, eye, None, std::iter::empty(), cutoff, &mut got);
            assert_eq!(f.geometric.queried - before, queried, "step {k}");
            let mut want = Vec::new();
            brute::scene_edges(&scene, &t, eye, cutoff, &mut want);
            let (mut g, mut w): (Vec<_>, Vec<_>) = (got.iter().map(key).collect(), want.iter().map(key).collect());
            g.sort_unstable();
            w.sort_unstable();
            assert_eq!(g, w, "step {k}");
        }
        assert_eq!(f.geometric.reused, 4 * n - 1);
    }

    /// Moving a light recomputes its pairs: the result equals a finder built with the light
    /// there from the start.
    #[test]
    fn a_moved_light_gives_the_shadows_of_its_new_place() {
        let scene = edgepoint_scene::builtin::load("cornell-point").unwrap();
        let t: Vec<Affine3A> = scene.objects.iter().map(|o| o.transform).collect();
        let id = |n: &str| scene.object_id(n).unwrap();
        let triples: Vec<TripleKey> = ["tallbox", "shortbox"]
            .iter()
            .flat_map(|b| ["floor", "back", "redwall", "greenwall"].map(|r| TripleKey { light: 0, blocker: id(b), receiver: id(r) }))
            .collect();
        let shadows = |f: &mut EdgeFinder| {
            let mut out = Vec::new();
            f.frame(&t, scene.camera.eye, None, triples.iter().copied(), 85.0, &mut out);
            let mut k: Vec<_> = out.iter().filter(|s| !s.kind.is_geometric()).map(key).collect();
            k.sort_unstable();
            k
        };
        let mut live = EdgeFinder::new(&scene, &NoProgress);
        let before = shadows(&mut live);
        let moved = Light::Point { position: Vec3::new(0.15, 0.5, 0.2), intensity: Vec3::ONE };
        live.set_light(0, moved.clone());
        let after = shadows(&mut live);
        let mut moved_scene = scene.clone();
        moved_scene.lights[0] = moved;
        let fresh = shadows(&mut EdgeFinder::new(&moved_scene, &NoProgress));
        assert!(!before.is_empty() && before != after);
        assert_eq!(after, fresh);
    }

    #[test]
    fn the_view_volume_culls_objects_behind_and_beside_the_camera() {
        let cam = Camera { eye: Vec3::ZERO, target: -Vec3::Z, up: Vec3::Y, fov_y_degrees: 60.0 };
        let v = ViewVolume::new(&cam, 1.0);
        let unit = |c: Vec3| v.may_see(c - Vec3::splat(0.1), c + Vec3::splat(0.1));
        assert!(unit(Vec3::new(0.0, 0.0, -5.0)));
        assert!(!unit(Vec3::new(0.0, 0.0, 5.0)), "behind");
        assert!(!unit(Vec3::new(10.0, 0.0, -5.0)), "right");
        assert!(!unit(Vec3::new(-10.0, 0.0, -5.0)), "left");
        assert!(!unit(Vec3::new(0.0, 10.0, -5.0)), "above");
        assert!(!unit(Vec3::new(0.0, -10.0, -5.0)), "below");
        // Straddling the edge of the view counts as visible.
        assert!(unit(Vec3::new(2.85, 0.0, -5.0)));
        // A wide image sees farther sideways.
        let w = ViewVolume::new(&cam, 3.0);
        assert!(w.may_see(Vec3::new(5.0, -0.1, -5.1), Vec3::new(5.2, 0.1, -4.9)));
    }
}
