//! The edgepoint gRPC contract: generated message and service types plus small conversions
//! shared by every process (vectors, transforms, cameras, the scene content hash).
#![allow(clippy::all)]

pub mod v1 {
    tonic::include_proto!("edgepoint.v1");
}

pub use v1::*;

mod convert;
pub use convert::*;

/// The encoded file-descriptor set, for reflection or tooling.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/edgepoint_descriptor.bin"));

mod source;
pub use source::*;

pub mod auth;
pub mod heap;
pub mod linear_frame;
pub mod logging;
pub mod metrics_http;
pub mod net;
pub mod packed;
pub mod shaders;
pub mod split;
