//! Discontinuity edges (paper 000 §6): the 3D segments the edge-and-point image rasterizes.
//!
//! - [`brute`] — the brute-force finder that tests every mesh edge with Equation 1 (§6.1),
//!   the sharp-edge cut-off (§6.2) and boundary edges. It is the oracle the edge trees
//!   (§6.4) are tested against, and it feeds the EPI wherever the trees are not used.
//!
//! Everything here is plain geometry in object or world space: no networking, no image.
use glam::{Affine3A, Vec3};

pub mod brute;
pub mod clip1d;
pub mod events;
pub mod face_bvh;
pub mod finder;
pub mod geometric;
pub mod interval;
pub mod mesh_edges;
pub mod sample;
pub mod shadow;
pub mod simplify;
pub mod tree;
pub mod umbra;
pub mod wedge;

/// A shadow ray from `receiver` toward `light` was blocked by `blocker` (the shaders'
/// light–blocker–receiver triples, paper 000 §6.5): which pairs need shadow edges.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TripleKey {
    pub light: u32,
    pub blocker: u32,
    pub receiver: u32,
}

/// Default sharp-edge cut-off (paper §6.2: "In our scenes, the cutoff angle is 85°"): an edge
/// whose face normals differ by at least this angle is sharp.
pub const DEFAULT_SHARP_CUTOFF_DEGREES: f32 = 85.0;

/// Why a segment is a discontinuity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EdgeKind {
    /// One adjacent face faces the eye, the other faces away (Equation 1).
    Silhouette,
    /// Both faces face the eye and their normals differ by at least the cut-off (§6.2).
    Sharp,
    /// An edge with one face: a discontinuity wherever it is visible.
    Boundary,
    /// A shadow edge from a point light (umbral and penumbral events coincide).
    ShadowHard,
    /// A shadow edge bounding the umbra of an area light.
    ShadowUmbral,
    /// A shadow edge bounding the penumbra of an area light.
    ShadowPenumbral,
}

impl EdgeKind {
    pub const ALL: [EdgeKind; 6] = [
        EdgeKind::Silhouette,
        EdgeKind::Sharp,
        EdgeKind::Boundary,
        EdgeKind::ShadowHard,
        EdgeKind::ShadowUmbral,
        EdgeKind::ShadowPenumbral,
    ];

    pub fn name(self) -> &'static str {
        match self {
            EdgeKind::Silhouette => "silhouette",
            EdgeKind::Sharp => "sharp",
            EdgeKind::Boundary => "boundary",
            EdgeKind::ShadowHard => "shadow_hard",
            EdgeKind::ShadowUmbral => "shadow_umbral",
            EdgeKind::ShadowPenumbral => "shadow_penumbral",
        }
    }

    /// Geometric (view-dependent) edges as opposed to shadow edges (view-independent).
    pub fn is_geometric(self) -> bool {
        matches!(self, EdgeKind::Silhouette | EdgeKind::Sharp | EdgeKind::Boundary)
    }
}

/// A world-space discontinuity segment from `a` to `b`, lying on object `object`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeSegment {
    pub a: Vec3,
    pub b: Vec3,
    pub kind: EdgeKind,
    /// The object the segment lies on (the receiver for shadow edges).
    pub object: u32,
}

/// The eye (or a point light) in an object's own coordinates: queries run in object space,
/// so moving an object never rebuilds its per-mesh structures (§6.5).
pub fn point_in_object_space(world_to_object: &Affine3A, p: Vec3) -> Vec3 {
    world_to_object.transform_point3(p)
}

/// Counts of found segments per kind (paper Table 3 reports silhouettes and shadow edges).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EdgeCounts {
    pub silhouette: u32,
    pub sharp: u32,
    pub boundary: u32,
    pub shadow: u32,
}

impl EdgeCounts {
    pub fn of(segments: &[EdgeSegment]) -> Self {
        let mut c = EdgeCounts::default();
        for s in segments {
            match s.kind {
                EdgeKind::Silhouette => c.silhouette += 1,
                EdgeKind::Sharp => c.sharp += 1,
                EdgeKind::Boundary => c.boundary += 1,
                EdgeKind::ShadowHard | EdgeKind::ShadowUmbral | EdgeKind::ShadowPenumbral => c.shadow += 1,
            }
        }
        c
    }
}
