//! edgepoint shader worker: loads scenes, builds a two-level BVH ([`bvh`]), shades batches of
//! ray requests ([`shader`]: `direct`, `glossy`, `gi`, `hybrid`) and serves them over gRPC ([`service`]), with its command line in
//! [`cli`] and its Prometheus metrics in [`metrics`].
pub mod baseline;
pub mod bsdf_rays;
pub mod bvh;
pub mod cli;
#[cfg(test)]
mod lambert_oracle;
pub mod loaded;
pub mod metrics;
pub mod ray_oracle;
mod rng;
pub mod service;
pub mod shader;
pub mod surface;
pub mod triples;

pub use bvh::{BvhShape, Hit, Instances, SceneBvh, Simd};
pub use loaded::LoadedScene;
pub use triples::sample_triples;
pub use shader::{shade_batch, shade_batch_parts, Part, DirectParams, GiParams, GlossyParams, HybridParams, HitInfo, RayRequest, SampleOut, ShadeOutput, ShaderSpec, SHADERS};
