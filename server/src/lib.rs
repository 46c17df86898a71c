//! edgepoint renderer library. Folders follow the per-frame pipeline (DESIGN.md):
//!
//! - [`cli`] — the `edgepoint-server` command line (shared with the deploy tests).
//! - [`edges`] — paper 000 §6: discontinuity edges (brute-force finder; the oracle).
//! - [`epi`] — paper 000 §4–§5: the edge-and-point image (edge rasterization, pixel
//!   classification, reachability, edge-respecting interpolation, anti-aliasing, complex
//!   filter) (no networking).
//! - [`render_cache`] — paper 000 §4.3: cached 3D point samples, reprojection, depth-based
//!   occlusion culling, gap-filling interpolation (no networking).
//! - [`visibility`] — primary visibility: the scene's triangles rasterized at pixel centres,
//!   the exact depth that culls hidden cached points in motion (no networking).
//! - [`sampling`] — paper 000 §5.3 "Prioritized sampling": priorities from filter weight and
//!   age, dithered selection of the frame's sample budget (no networking).
//! - [`image_metrics`] — PSNR / SSIM against reference images.
//! - [`metrics`] — Prometheus metrics of the pool and the sessions (`--metrics-listen`).
//! - [`prefetch`] — the software prefetch hint of loops that know their next random reads.
//! - [`stage_times`] — per-stage frame timing (paper Table 2 columns).
//! - [`workers`] — the shader-worker pool: discovery (fixed, DNS, file), asynchronous request
//!   dispatch with back-pressure, adaptive batch sizes, failure handling.
//! - [`session`] — one render session per viewer: the frame loop thread.
//! - [`encode`] — frame encodings (raw, QOI, PNG, JPEG).
//! - [`srgb`] — exactly rounded linear to 8-bit sRGB by table.
//! - [`reference`] — reference renders (1 spp and converged) through the workers.
//! - [`service`] — the `Renderer` gRPC service.
//! - [`web`] — the browser viewer: its page and WebSocket live connection (`--web-listen`).

pub mod cli;
pub mod background;
pub mod dmesh;
pub mod edges;
pub mod encode;
pub mod epi;
pub mod image_metrics;
pub mod metrics;
pub mod prefetch;
pub mod reference;
pub mod render_cache;
pub mod rng;
pub mod sampling;
pub mod srgb;
pub mod scenes;
pub mod service;
pub mod session;
pub mod stage_times;
pub mod visibility;
pub mod web;
pub mod workers;
