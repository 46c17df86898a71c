//! The edgepoint viewer: the slim client of the `Renderer` gRPC service (DESIGN.md,
//! "Processes and data flow"). The renderer does all the edge-and-point work; the viewer
//! sends camera / object moves / settings and shows or stores the frames it gets back.
//!
//! The modules are public so that the benchmark and the integration tests reuse them:
//! - [`local`]: start a local cluster (N workers + one server) as child processes.
//! - [`client`]: one `Renderer.Session` stream as a typed client.
//! - [`frame`]: decoding frames (raw / QOI / PNG / JPEG / linear half floats) into RGB images.
//! - [`headless`]: a PNG or EXR file per frame plus one JSON line of stats per frame.
//! - [`tonemap`]: exposure and tone curves (clip, filmic) of linear frames for display.
//! - [`exr_file`]: OpenEXR files of linear RGB (half for frames, float for references).
//! - [`tev`]: mirroring frames to the tev image viewer over its network protocol.
//! - [`reconstruction`]: the reconstruction switches (edge-and-point vs baseline, overlays).
//! - [`camera_path`]: `--camera`, camera path files (read, write), `--orbit` parameters.
//! - [`camera_control`]: the camera the window's mouse and keys move.
//! - [`script`]: scripted camera orbit or path and object slide, one step per frame.
//! - [`window`]: the interactive on-screen window (minifb) when a display exists;
//!   [`hud`] draws its text, [`object_drag`] moves picked objects.
pub mod camera_control;
pub mod camera_path;
pub mod client;
pub mod exr_file;
pub mod frame;
pub mod headless;
pub mod hud;
pub mod local;
pub mod object_drag;
pub mod reconstruction;
pub mod script;
pub mod tev;
pub mod tonemap;
pub mod window;

pub use client::{scene_source_from_arg, scene_source_from_arg_in, ClientError, ConnectOptions, Event, SessionClient, SessionSender};
pub use headless::{FrameStats, HeadlessWriter};
pub use local::{find_binary, LocalCluster, LocalOptions};
pub use reconstruction::ReconstructionArgs;
pub use camera_path::{CameraSpec, OrbitArgs};
pub use script::{CameraPlan, ObjectSlide, Script};
