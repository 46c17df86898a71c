//! The discontinuity mesh of area lights on receiver faces (paper 002, Loscos and
//! Drettakis 1997, §2 and §4; the complete mesh with backprojections of Drettakis and Fiume
//! that it keeps up to date).
//!
//! Per area light and receiver triangle: the visible discontinuity segments of the EV
//! surfaces with the vertex or the edge on the light ([`segments`]), of the EEE surfaces
//! with an edge on the light ([`eee`], as polylines on their conic traces) and the blockers'
//! contacts with the receiver's plane, their planar
//! arrangement as a half-edge structure with faces ([`arrangement`]), and each face's
//! backprojection ([`face`]). The scene's triangles are listed in a uniform grid
//! ([`grid`]) that finds each receiver's shaft blockers ([`receiver`]).
//!
//! An algorithm module: plain geometry, no session, no network.
use edgepoint_scene::backprojection::LightPlane;
use edgepoint_scene::{NoProgress, Progress};
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

pub mod arrangement;
pub mod eee;
pub mod face;
pub mod fast_hash;
pub mod geometry;
pub mod grid;
pub mod receiver;
pub mod segments;
pub mod solid;
pub mod umbra;
pub mod update;

use arrangement::Arrangement;
use eee::EeeSurface;
use face::FaceBackprojection;
use geometry::Geometry;
use grid::Grid;
use receiver::{LightAbove, Receiver, Shaft};
use segments::{Segment, TraceVis};

/// Triangles per voxel the grid aims at.
pub const GRID_TRIANGLES_PER_VOXEL: f64 = 4.0;

/// The mesh of one light on one receiver triangle.
#[derive(Debug, Clone)]
pub struct ReceiverMesh {
    pub receiver: Receiver,
    /// The shaft from the light (above the receiver's plane) to the receiver: every blocker
    /// and every discontinuity surface of the receiver lies in it.
    pub shaft: Shaft,
    /// Every triangle that can hide part of the light from some point of the receiver.
    pub blockers: Vec<u32>,
    /// The surfaces' traces with their intersection lists.
    pub traces: Vec<TraceVis>,
    /// The EEE surfaces with one edge on the light, with their intersection lists.
    pub eee: Vec<EeeSurface>,
    /// The visible segments (the traces after 1D visibility, then the EEE surfaces' visible
    /// polylines).
    pub segments: Vec<Segment>,
    pub arrangement: Arrangement,
    /// One per bounded face of the arrangement.
    pub faces: Vec<FaceBackprojection>,
    /// Wholly in umbra behind one flat occluder ([`umbra`]): no traces, one dark face.
    pub umbra: bool,
}

impl ReceiverMesh {
    /// The mesh of `light` on triangle `tri`; `None` when no part of the light is above the
    /// triangle's plane, the triangle is in the umbra of its own solid ([`solid`]) — it
    /// receives nothing — or it is degenerate.
    pub fn compute(g: &Geometry, grid: &Grid, light: &LightPlane, tri: u32, tol: f64, scratch: &mut Scratch) -> Option<ReceiverMesh> {
        let (receiver, above, shaft) = frame(g, light, tri, tol)?;
        let mut blockers = Vec::new();
        receiver::shaft_blockers(g, grid, light, &receiver, &shaft, &mut blockers, &mut scratch.stamp, &mut scratch.epoch);
        blockers.sort_unstable();
        Some(ReceiverMesh::from_blockers(g, light, &above, receiver, shaft, blockers))
    }

    /// The mesh from the receiver's blockers: in umbra behind one of them, or traced.
    pub fn from_blockers(g: &Geometry, light: &LightPlane, above: &LightAbove, receiver: Receiver, shaft: Shaft, blockers: Vec<u32>) -> ReceiverMesh {
        if let Some(occluder) = umbra::covering_occluder(g, &above.clipped, &g.tri(receiver.tri), &blockers, receiver.tol) {
            return ReceiverMesh::in_umbra(receiver, shaft, blockers, occluder);
        }
        let traces = segments::receiver_traces(g, light, above, &receiver, &blockers);
        let eee = eee::receiver_surfaces(g, light, above, &receiver, &blockers);
        ReceiverMesh::assemble(g, light, receiver, shaft, blockers, traces, eee, |_, _| None)
    }

    /// A receiver hidden from the whole light by `occluder`: the triangle is one face that
    /// sees nothing.
    fn in_umbra(receiver: Receiver, shaft: Shaft, blockers: Vec<u32>, occluder: Vec<u32>) -> ReceiverMesh {
        let arrangement = arrangement::build(&receiver.corners, &[], receiver.tol);
        let faces = (0..arrangement.faces.len()).map(|f| FaceBackprojection { point: arrangement.interior_point(f), pieces: Vec::new(), occluders: occluder.clone(), irradiance: 0.0 }).collect();
        ReceiverMesh { receiver, shaft, blockers, traces: Vec::new(), eee: Vec::new(), segments: Vec::new(), arrangement, faces, umbra: true }
    }

    /// The segments, arrangement and face backprojections from the traces; `reuse` may give
    /// a face's backprojection from before a move (by its interior point and area).
    #[allow(clippy::too_many_arguments)] // the receiver's parts as a mesh holds them, moved in
    pub fn assemble(
        g: &Geometry,
        light: &LightPlane,
        receiver: Receiver,
        shaft: Shaft,
        blockers: Vec<u32>,
        traces: Vec<TraceVis>,
        eee: Vec<EeeSurface>,
        mut reuse: impl FnMut(DVec2, f64) -> Option<FaceBackprojection>,
    ) -> ReceiverMesh {
        let (segments, arrangement) = arrange(g, &receiver, &blockers, &traces, &eee);
        let points = interior_points(&arrangement);
        let faces = face_backprojections(g, light, &receiver, &blockers, &arrangement, &points, &mut reuse);
        ReceiverMesh { receiver, shaft, blockers, traces, eee, segments, arrangement, faces, umbra: false }
    }

    /// Irradiance per unit radiance at receiver point `q` (receiver frame), from the
    /// pointwise backprojection there with the receiver's blockers.
    pub fn irradiance(&self, g: &Geometry, light: &LightPlane, q: DVec2) -> f64 {
        let mut hit = Vec::new();
        face::visible_at(g, light, &self.receiver, &self.blockers, q, &mut hit).map_or(0.0, |v| v.irradiance())
    }

    pub fn bytes(&self) -> usize {
        std::mem::size_of::<ReceiverMesh>()
            + self.blockers.len() * 4
            + self.traces.iter().map(|t| t.bytes()).sum::<usize>()
            + self.eee.iter().map(|t| t.bytes()).sum::<usize>()
            + self.segments.len() * std::mem::size_of::<Segment>()
            + self.arrangement.bytes()
            + self.faces.iter().map(|f| f.bytes()).sum::<usize>()
    }
}

/// 1D visibility on every trace and EEE surface, and the arrangement of the visible
/// segments and the blockers' contacts.
pub fn arrange(g: &Geometry, receiver: &Receiver, blockers: &[u32], traces: &[TraceVis], eee: &[EeeSurface]) -> (Vec<Segment>, Arrangement) {
    let segments = visible_segments(g, receiver, blockers, traces, eee);
    let arrangement = arrangement::build(&receiver.corners, &segments, receiver.tol);
    (segments, arrangement)
}

/// The visible segments of `traces` and of the `eee` surfaces (1D visibility), in their
/// order, then the contacts of `blockers` with the receiver's plane.
pub fn visible_segments(g: &Geometry, receiver: &Receiver, blockers: &[u32], traces: &[TraceVis], eee: &[EeeSurface]) -> Vec<Segment> {
    let mut segments = Vec::new();
    for t in traces {
        t.visible(receiver, &mut segments);
    }
    for s in eee {
        s.visible(g, receiver, &mut segments);
    }
    segments::contacts(g, receiver, blockers, &mut segments);
    segments
}

/// A point inside each bounded face of `arrangement` ([`Arrangement::interior_point`]).
pub fn interior_points(arrangement: &Arrangement) -> Vec<DVec2> {
    (0..arrangement.faces.len()).map(|f| arrangement.interior_point(f)).collect()
}

/// One backprojection per bounded face of `arrangement` (at its point in `points`), from
/// `reuse` (an old face's, by interior point and area) or computed.
pub fn face_backprojections(
    g: &Geometry,
    light: &LightPlane,
    receiver: &Receiver,
    blockers: &[u32],
    arrangement: &Arrangement,
    points: &[DVec2],
    reuse: &mut impl FnMut(DVec2, f64) -> Option<FaceBackprojection>,
) -> Vec<FaceBackprojection> {
    // The blockers' runs once for the faces to compute (none when every face is kept), in
    // list order: the visible part is occluded triangle by triangle, and slivers below the
    // clipping's area threshold come out differently in another order. A face the update
    // keeps was occluded in the old list's order; the full computation's must be the same
    // up to the moved triangles, which the curve order of a long list is not (its keys
    // follow the list's box): on `chains` one receiver a move then differed in a sliver.
    let mut runs = None;
    (0..arrangement.faces.len())
        .map(|f| {
            let point = points[f];
            reuse(point, arrangement.faces[f].area2).unwrap_or_else(|| {
                let runs = runs.get_or_insert_with(|| segments::Runs::new(g, blockers, false));
                FaceBackprojection::compute(g, light, receiver, runs, point)
            })
        })
        .collect()
}

/// The receiver's frame, the light above its plane and the shaft.
pub fn frame(g: &Geometry, light: &LightPlane, tri: u32, tol: f64) -> Option<(Receiver, LightAbove, Shaft)> {
    let centre = light.corners.iter().map(|q| light.lift(*q)).sum::<DVec3>() / light.corners.len() as f64;
    let receiver = Receiver::new(g, tri, centre, tol)?;
    let above = LightAbove::new(light, &receiver)?;
    let [a, b, c] = g.tri(tri);
    // Wholly behind the (one-sided) light, or in the umbra of its own solid: nothing
    // reaches it.
    if [a, b, c].iter().all(|p| light.height(*p) <= tol) || solid::in_own_umbra(g, tri, &above.corners, tol) {
        return None;
    }
    let shaft = Shaft::new(&above.clipped, &[a, b, c], tol);
    Some((receiver, above, shaft))
}

/// Units of work counted before each report to a [`Progress`] from parallel loops (a
/// report takes a lock; a receiver can take a microsecond).
pub const PROGRESS_STEP: u64 = 1024;

/// Counts units of work done on any thread and reports them to a [`Progress`] every
/// [`PROGRESS_STEP`] (what is left under a step is reported by the stage's end).
pub struct ProgressSteps<'a> {
    progress: &'a dyn Progress,
    done: AtomicU64,
}

impl<'a> ProgressSteps<'a> {
    pub fn new(progress: &'a dyn Progress) -> Self {
        ProgressSteps { progress, done: AtomicU64::new(0) }
    }

    /// One unit done.
    pub fn one(&self) {
        if (self.done.fetch_add(1, Ordering::Relaxed) + 1).is_multiple_of(PROGRESS_STEP) {
            self.progress.advance(PROGRESS_STEP);
        }
    }
}

/// Per-thread scratch of the grid queries.
#[derive(Debug, Default)]
pub struct Scratch {
    stamp: Vec<u32>,
    epoch: u32,
}

/// The whole mesh: per light, the receivers it reaches.
#[derive(Debug, Clone)]
pub struct DiscontinuityMesh {
    pub lights: Vec<LightPlane>,
    /// `meshes[l][t]`: the mesh of light `l` on triangle `t`, if the light reaches it.
    pub meshes: Vec<Vec<Option<Box<ReceiverMesh>>>>,
    pub tol: f64,
    /// The receivers meshed, when not every triangle ([`DiscontinuityMesh::compute_for`]).
    pub only: Option<Vec<bool>>,
}

/// The area lights of a scene as light planes (point and spot lights have no mesh).
pub fn area_lights(scene: &edgepoint_scene::Scene) -> Vec<LightPlane> {
    area_lights_indexed(scene).into_iter().map(|(_, l)| l).collect()
}

/// [`area_lights`], each with its index among the scene's lights (a light with no plane,
/// all its corners on a line, is left out of both).
pub fn area_lights_indexed(scene: &edgepoint_scene::Scene) -> Vec<(u32, LightPlane)> {
    scene
        .lights
        .iter()
        .enumerate()
        .filter_map(|(i, l)| match l {
            edgepoint_scene::Light::Area { vertices, .. } => LightPlane::new(vertices).map(|p| (i as u32, p)),
            _ => None,
        })
        .collect()
}

/// Square area lights of side `side` standing in for a scene's point and spot lights (the
/// benchmark's stand-ins for scenes lit only by points: `chains`, `grid-dragon`), each
/// centred on the point and facing the centre of the scene's bounds.
pub fn point_lights_as_squares(scene: &edgepoint_scene::Scene, side: f64) -> Vec<LightPlane> {
    let (lo, hi) = scene.bounds();
    let centre = ((lo + hi) * 0.5).as_dvec3();
    scene
        .lights
        .iter()
        .filter_map(|l| match l {
            edgepoint_scene::Light::Point { position, .. } | edgepoint_scene::Light::Spot { position, .. } => {
                let p = position.as_dvec3();
                let n = (centre - p).try_normalize()?;
                let u = n.any_orthonormal_vector() * (0.5 * side);
                let w = n.cross(u);
                // Counter-clockwise about n (u × w = n): the light emits toward the centre.
                let corners = [p - u - w, p + u - w, p + u + w, p - u + w].map(|c| c.as_vec3());
                LightPlane::new(&corners)
            }
            _ => None,
        })
        .collect()
}

/// The mesh's length tolerance for a scene: [`receiver::EPS`] of its size.
pub fn tolerance(g: &Geometry) -> f64 {
    let (lo, hi) = g.bounds();
    receiver::EPS * (hi - lo).length().max(1e-30)
}

impl DiscontinuityMesh {
    /// The full computation over every light and every triangle, in parallel over
    /// receivers.
    pub fn compute(g: &Geometry, grid: &Grid, lights: &[LightPlane]) -> DiscontinuityMesh {
        DiscontinuityMesh::compute_with_tolerance(g, grid, lights, tolerance(g))
    }

    /// The full computation with a given length tolerance. A mesh keeps the tolerance it
    /// was made with through its updates (it is part of what the mesh is: where ends snap,
    /// where a trace stops above the receiver's plane), whereas [`tolerance`] follows the
    /// scene's bounds, which a moved object can widen; a full recomputation to compare an
    /// updated mesh with takes the mesh's `tol`.
    pub fn compute_with_tolerance(g: &Geometry, grid: &Grid, lights: &[LightPlane], tol: f64) -> DiscontinuityMesh {
        DiscontinuityMesh::compute_for(g, grid, lights, tol, None)
    }

    /// The mesh on the receivers `only` marks (every triangle for `None`; every triangle
    /// still blocks): for scenes too large to mesh whole in a test or a short benchmark run.
    /// Updates keep to the same receivers.
    pub fn compute_for(g: &Geometry, grid: &Grid, lights: &[LightPlane], tol: f64, only: Option<Vec<bool>>) -> DiscontinuityMesh {
        DiscontinuityMesh::compute_reporting(g, grid, lights, tol, only, &NoProgress)
    }

    /// [`Self::compute_for`], reporting the (light, triangle) pairs done to `progress` (a
    /// session's mesh of `rooms` takes seconds), in steps of [`PROGRESS_STEP`].
    pub fn compute_reporting(g: &Geometry, grid: &Grid, lights: &[LightPlane], tol: f64, only: Option<Vec<bool>>, progress: &dyn Progress) -> DiscontinuityMesh {
        progress.begin("light-triangle pairs", (lights.len() * g.tris.len()) as u64);
        let step = ProgressSteps::new(progress);
        let meshes = lights
            .iter()
            .map(|light| {
                (0..g.tris.len() as u32)
                    .into_par_iter()
                    .map_init(Scratch::default, |s, t| {
                        step.one();
                        if only.as_ref().is_some_and(|o| !o[t as usize]) {
                            return None;
                        }
                        ReceiverMesh::compute(g, grid, light, t, tol, s).map(Box::new)
                    })
                    .collect()
            })
            .collect();
        progress.end();
        DiscontinuityMesh { lights: lights.to_vec(), meshes, tol, only }
    }

    /// Whether triangle `t` is one of the receivers meshed.
    pub fn meshes_receiver(&self, t: u32) -> bool {
        self.only.as_ref().is_none_or(|o| o[t as usize])
    }

    /// Every receiver mesh of every light.
    pub fn receivers(&self) -> impl Iterator<Item = &ReceiverMesh> {
        self.meshes.iter().flatten().flatten().map(|m| &**m)
    }

    /// (light, triangle) of every receiver with a mesh, lights first.
    pub fn receiver_ids(&self) -> Vec<(u32, u32)> {
        self.meshes.iter().enumerate().flat_map(|(l, ms)| ms.iter().enumerate().filter(|(_, m)| m.is_some()).map(move |(t, _)| (l as u32, t as u32))).collect()
    }

    pub fn segment_count(&self) -> usize {
        self.receivers().map(|m| m.segments.len()).sum()
    }

    pub fn face_count(&self) -> usize {
        self.receivers().map(|m| m.faces.len()).sum()
    }

    pub fn bytes(&self) -> usize {
        self.receivers().map(|m| m.bytes()).sum()
    }
}

#[cfg(test)]
pub(crate) mod tests;
