//! `edgepoint-bench`: measurements of the whole system, printed as a table or as JSON
//! (`--json`). Every speed figure comes with a baseline measured in the same process
//! (a full ray trace, the shader called in-process, one worker), because the machines are
//! noisy and only ratios travel.
//!
//! Subcommands:
//! - `frame`: a headless session for N frames (server + workers + this process as the
//!   viewer): per-stage medians, fps, samples per frame, sparseness ratio, PSNR/SSIM of the
//!   last frame against a converged reference rendered through the same workers, and the
//!   speedup over a 1-sample-per-pixel full ray trace with the same workers.
//! - `throughput`: samples/s of 1..K workers at batch size B, their scaling, and the gRPC
//!   overhead against calling the shader in-process with the same thread count.
//! - `loadtest`: K workers at full rate (samples/s, p50/p99 batch latency, scaling 1..K),
//!   S concurrent sessions (fps per session, dropped frames, server memory), and a worker
//!   killed/restarted and stopped/continued mid-session (longest frame gaps, rejoin time).
//! - `load`: scene load (parse + weld + adjacency) and BVH build times.
//! - `edges`: edge-tree build and silhouette times against brute force, shadow-edge times.
//! - `reference`: render the 1-spp and converged references of a scene to PNG files.
//! - `epi`: per-stage times of the edge-and-point image (rasterize, reach, interpolate,
//!   anti-alias, complex) at 512² and 1024², one thread and all, and bytes per pixel.
//! - `sampling`: the frame loop's work after publishing — picking the next frame's pixels,
//!   aiming them at cached points, building the request batches — against one priority pass.
//! - `encode`: the frame's conversion to sRGB, QOI / raw encoding and publishing, against
//!   the encoder before (kept in the bench as the baseline), one thread and all.
//! - `materials`: ns per `eval` / `sample` / `pdf` call of each scattering model, and the
//!   `direct` shader's samples/s against the shader before materials, in the same process.
//! - `fuzz`: the scene-parser fuzz harness for as long as asked (findings go to the crash
//!   corpus the tests replay).
//! - `quality`: PSNR / SSIM of edge-and-point reconstruction vs the Render Cache's
//!   interpolation from the same samples, at several sample densities.
//! - `converge`: converging at rest — PSNR against the converged reference over wall time,
//!   an edge-and-point session beside a progressive full-frame renderer on the same workers.
//! - `motion`: quality in motion — every frame of a scripted path (orbit, dolly, object
//!   slide, camera path file) against the converged reference of its exact state: PSNR,
//!   SSIM, outlier pixels, the moved object's coverage, frames to fill newly exposed
//!   regions; edge-and-point and Render Cache side by side.
//! - `rays`: the worker's ray rate (Mrays/s, 1 and 2 threads) on a mesh's primary, shadow
//!   and incoherent rays and its BVH build time, against the traversal before (and Embree
//!   libraries named with `--embree`) in the same process, and the Embree figures.
//! - `split`: split shading by lights against splitting by pixels on the same workers:
//!   complete samples/s and request-to-sample latency under light and saturated load.
//! - `simplify`: several lights (paper 003): a session with every shadow edge against one
//!   leaving out those other lights wash out: shadow edges, samples per frame, PSNR.
//! - `speedup`: per scene and shader, an edge-and-point session's median frame time against
//!   a full 1-spp frame shaded by the same workers (paper 000 Table 2's speedup).
//! - `exact-area`: the `direct` shader's exact area lights against its sampled ones on one
//!   thread: samples/s and the sampled images' noise.

mod clock;
mod converge;
mod dmesh;
mod edges;
mod encode;
mod sampling;
mod epi;
mod exact_area;
mod frame;
mod fuzz;
mod inprocess;
mod load;
mod materials;
mod motion;
mod loadtest;
mod quality;
mod rays;
mod requests;
mod reference_cache;
mod simplify;
mod simplify_estimates;
mod speedup;
mod split;
mod stats;
mod throughput;

use clap::{Parser, Subcommand};

/// Counts allocations for `fuzz` (off, one relaxed load per allocation, otherwise).
#[global_allocator]
static ALLOC: edgepoint_scene::alloc_count::CountingAlloc = edgepoint_scene::alloc_count::CountingAlloc;

#[derive(Parser, Debug)]
#[command(name = "edgepoint-bench", version, about = "Benchmarks for edgepoint (JSON output with --json)")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Headless session for N frames: per-stage ms, fps, samples/frame, PSNR vs converged reference.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Frame(frame::FrameArgs),
    /// Worker sample throughput for 1..K workers, scaling, and gRPC overhead vs in-process shading.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Throughput(throughput::ThroughputArgs),
    /// Load test: workers at full rate, concurrent sessions, failover of a worker mid-session.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Loadtest(loadtest::LoadtestArgs),
    /// Scene load, weld and BVH build times.
    Load(load::LoadArgs),
    /// Edge trees and shadow edges: build time, silhouette time vs brute force, shadow-edge time.
    Edges(edges::EdgesArgs),
    /// Render the 1-spp and converged reference images of a scene through local workers.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Reference(frame::ReferenceArgs),
    /// Edge-and-point image stage times (1 thread / all threads) and bytes per pixel.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Epi(epi::EpiArgs),
    /// PSNR/SSIM of edge-and-point vs Render Cache reconstruction from the same samples.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Quality(quality::QualityArgs),
    /// Quality in motion: a session along an orbit, dolly, object slide or camera path,
    /// every frame against the converged reference of its exact state.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Motion(motion::MotionArgs),
    /// Converging at rest: PSNR against the converged reference over wall time, edge-and-point
    /// beside a progressive full-frame renderer (one sample per pixel per pass) on the same workers.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Converge(converge::ConvergeArgs),
    /// Scattering models' ns per eval/sample/pdf call, and the direct shader's samples/s
    /// against the shader before materials, in this process.
    Materials(materials::MaterialsArgs),
    /// Frame encoding (sRGB, QOI, raw) and publishing against the previous encoder.
    Encode(encode::EncodeArgs),
    /// The next frame's picks (priorities, budget, dither), aiming and request batches on a real frame's priorities.
    Sampling(sampling::SamplingArgs),
    /// Fuzz the scene parsers: mutated seed inputs; panics, slow parses and out-of-proportion
    /// allocations are findings, kept in the crash corpus.
    Fuzz(fuzz::FuzzArgs),
    /// The worker's ray rate on a mesh (primary, shadow, incoherent rays; 1 and 2 threads) and
    /// BVH build time, against the traversal before and Embree (`--embree LIB`).
    Rays(rays::RaysArgs),
    /// Split shading (paper 004 §4.4) against splitting by pixels on the same workers:
    /// complete samples per second and request-to-complete-sample latency, light and saturated load.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Split(split::SplitArgs),
    /// Speedup of an edge-and-point frame over a full 1-spp frame with the same shader and
    /// workers, per scene and shader (paper 000 Table 2).
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Speedup(speedup::SpeedupArgs),
    /// The direct shader's exact area lights (area=exact) against its sampled soft shadows:
    /// samples/s on one thread and the sampled images' noise against the exact one.
    ExactArea(exact_area::ExactAreaArgs),
    /// Several lights simplified (paper 003): two sessions, every shadow edge and then those
    /// other lights do not wash out below --tolerance: shadow edges, samples per frame, PSNR.
    #[command(after_help = edgepoint_proto::shaders::help_text())]
    Simplify(simplify::SimplifyArgs),
    /// The discontinuity mesh of the scene's area lights (paper 002): full computation
    /// time, segments and faces, memory of the grid and the mesh.
    Dmesh(dmesh::DmeshArgs),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    // Fuzz inputs make the loaders warn by the thousand: only errors, unless RUST_LOG says.
    edgepoint_proto::logging::init(if matches!(cli.cmd, Cmd::Fuzz(_)) { "error" } else { "warn" });
    match cli.cmd {
        Cmd::Frame(a) => frame::run(a),
        Cmd::Throughput(a) => throughput::run(a),
        Cmd::Loadtest(a) => loadtest::run(a),
        Cmd::Load(a) => load::run(a),
        Cmd::Reference(a) => frame::run_reference(a),
        Cmd::Epi(a) => epi::run(a),
        Cmd::Quality(a) => quality::run(a),
        Cmd::Encode(a) => encode::run(a),
        Cmd::Sampling(a) => sampling::run(a),
        Cmd::Materials(a) => materials::run(a),
        Cmd::Edges(a) => edges::run(a),
        Cmd::Motion(a) => motion::run(a),
        Cmd::Converge(a) => converge::run(a),
        Cmd::Fuzz(a) => fuzz::run(a),
        Cmd::Rays(a) => rays::run(a),
        Cmd::Split(a) => split::run(a),
        Cmd::Speedup(a) => speedup::run(a),
        Cmd::ExactArea(a) => exact_area::run(a),
        Cmd::Simplify(a) => simplify::run(a),
        Cmd::Dmesh(a) => dmesh::run(a),
    }
}

/// Prints `value` as pretty JSON when `json` is set, else the human `table` text.
pub fn emit(json: bool, value: &serde_json::Value, table: &str) {
    if json {
        println!("{}", serde_json::to_string_pretty(value).expect("json"));
    } else {
        print!("{table}");
    }
}
