//! Scene library shared by the renderer and the shader workers.
//!
//! A [`Scene`] is a list of [`Object`]s (a welded triangle [`Mesh`] with edge–face
//! adjacency, one [`Material`] and a default object-to-world transform), a list of
//! [`Light`]s (point lights and planar convex polygonal area lights), a [`Camera`] and an
//! ambient term. Meshes are kept in object space: moving an object changes only its
//! transform, so per-object acceleration structures (BVHs, edge trees) never rebuild.
//!
//! Loaders read PLY (binary and ASCII) and OBJ (+MTL colours); built-in scenes are in
//! [`builtin`] (procedural, or made from the shared data found by [`data`]).

// Checks are written `!(x >= min)` on purpose: that is true for NaN, where `x < min` is not,
// so a NaN never passes a validation by failing every comparison (issue 12 item 9).
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod alloc_count;
pub mod backprojection;
pub mod builtin;
pub mod camera;
pub mod data;
pub mod error;
pub mod geometry;
pub mod fuzz;
pub mod light;
pub mod limits;
pub mod load;
pub mod material;
pub mod mesh;
pub mod orbit;
pub mod polyclip;
pub mod polygon_irradiance;
pub mod progress;
mod scene;

pub use camera::Camera;
pub use error::SceneError;
pub use light::Light;
pub use material::{Bsdf, Material, Texture};
pub use mesh::{Corners, Edge, Mesh, WeldStats, NO_FACE};
pub use orbit::Orbit;
pub use progress::{NoProgress, Progress};
pub use scene::{Object, Scene};

pub use glam;
