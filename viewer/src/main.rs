//! `edgepoint-viewer`: connects to an edgepoint render server (or starts a local cluster of
//! one server and N shader workers), shows the frames in a window when a display exists,
//! or writes them as PNGs plus per-frame JSON stats when it does not.
use anyhow::{bail, Context, Result};
use clap::{Parser, ValueEnum};
use edgepoint_proto::{self as pb, FrameEncoding};
use edgepoint_viewer::client::{camera_from_wire, code_name, SessionSender};
use edgepoint_viewer::frame::{decode_with, to_0rgb};
use edgepoint_viewer::headless::{FileFormat, FrameMeter, FrameStats, HeadlessWriter};
use edgepoint_viewer::tev::TevMirror;
use edgepoint_viewer::tonemap::{Look, LookControl, ToneCurve, ToneMapper};
use edgepoint_viewer::local::{LocalCluster, LocalOptions};
use edgepoint_viewer::camera_path::{parse_camera_spec, read_path, suggested_orbit, CameraSpec, OrbitArgs, PathWriter};
use edgepoint_viewer::script::{CameraPlan, Script, ScriptStep};
use edgepoint_viewer::window::{display_available, ShownFrame, ToWindow, ViewerWindow, WindowExit, WindowSetup, KEY_HELP};
use edgepoint_viewer::{scene_source_from_arg_in, ConnectOptions, Event, ReconstructionArgs, SessionClient};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tokio::sync::watch;

/// Output directory of a headless run when --out is not given.
const DEFAULT_OUT_DIR: &str = "edgepoint-frames";
/// Frames of a headless run when --frames is not given.
const DEFAULT_HEADLESS_FRAMES: u64 = 300;

/// View frames from an edgepoint render server (edge-and-point rendering, Bala et al. 2003).
///
/// Without --server, starts a local cluster: --workers shader workers and one server, as
/// child processes that end with the viewer. With a display (DISPLAY or WAYLAND_DISPLAY) and
/// without --headless, frames show in a window that the mouse and keys drive (listed below;
/// H or F1 shows them in the window); otherwise each frame is written as
/// OUT/frame_00001.png (or .exr with --format exr) with one JSON line of stats per frame in
/// OUT/stats.jsonl, 300 frames unless --frames says otherwise, and one summary line on
/// stdout at the end (per-frame lines too with --stats-stdout). Logs go to stderr, filtered
/// by RUST_LOG (default info). Ctrl-C ends the run cleanly.
///
/// Output: the renderer keeps linear RGB. PNG files and the window show it through
/// --exposure and --tonemap, then the sRGB transfer; --format exr writes the linear values
/// themselves (half floats: never tone-mapped or clipped) and --tev mirrors them to the tev
/// image viewer. Those three make the server send linear frames (half floats, LZ4) instead
/// of sRGB QOI.
#[derive(Debug, Parser)]
#[command(name = "edgepoint-viewer", version, after_help = format!("{KEY_HELP}\n\n{}", edgepoint_proto::shaders::help_text()))]
struct Args {
    /// Connect to a running edgepoint-server at URL (e.g. http://127.0.0.1:50051) instead
    /// of starting a local cluster.
    #[arg(long, value_name = "URL", conflicts_with = "local")]
    server: Option<String>,

    /// Bearer token for a server started with --token-file (also read from EDGEPOINT_TOKEN;
    /// prefer --token-file: a command line is visible to other users of the machine).
    #[arg(long, value_name = "TOKEN", env = "EDGEPOINT_TOKEN", hide_env_values = true, conflicts_with = "token_file")]
    token: Option<String>,

    /// File holding the bearer token (its first token line; `#` comments skipped).
    #[arg(long, value_name = "FILE", requires = "server")]
    token_file: Option<PathBuf>,

    /// PEM CA certificate to verify an https:// server with (default: the web PKI roots).
    #[arg(long, value_name = "FILE", requires = "server")]
    tls_ca: Option<PathBuf>,

    /// Name the server's certificate must carry (default: the host in --server).
    #[arg(long, value_name = "NAME", requires = "server")]
    tls_domain: Option<String>,

    /// Start a local cluster (shader workers + one server, as child processes) and view it.
    /// This is the default when --server is not given.
    #[arg(long)]
    local: bool,

    /// Number of shader workers in the local cluster.
    #[arg(long, value_name = "N", default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=256))]
    workers: u32,

    /// Threads per local shader worker (passed on as `--threads N`); by default each worker
    /// picks its own.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=1024))]
    worker_threads: Option<u32>,

    /// Run the local shader workers under Linux's SCHED_IDLE policy as well as at a lower
    /// niceness (default true): they get only the CPU time the server and this viewer leave,
    /// and a waking frame-loop thread takes a core from them at once. `false` leaves them at
    /// the lower niceness only — for a machine where other busy programs would otherwise
    /// starve the workers.
    #[arg(long, value_name = "BOOL", default_value_t = true, action = clap::ArgAction::Set)]
    worker_idle: bool,

    /// Directory holding edgepoint-server and edgepoint-worker for the local cluster
    /// (searched first; then EDGEPOINT_BIN_DIR, this executable's directory and its parent,
    /// then PATH).
    #[arg(long, value_name = "DIR")]
    bin_dir: Option<PathBuf>,

    /// Extra argument for the local server's command line; repeat for several
    /// (e.g. --server-arg=--some-flag --server-arg=3).
    #[arg(long, value_name = "ARG", allow_hyphen_values = true)]
    server_arg: Vec<String>,

    /// RUST_LOG filter for the local server and workers (default: this process's RUST_LOG).
    #[arg(long, value_name = "FILTER")]
    cluster_log: Option<String>,

    /// Append the local server's and workers' logs to FILE instead of showing them on stderr.
    #[arg(long, value_name = "FILE")]
    cluster_log_file: Option<PathBuf>,

    /// Scene to render: a built-in name (cornell, cornell-point, chains, torus-capsule,
    /// grid-dragon, rooms, materials) or a scene file: .ply, .obj, Mitsuba 3 .xml, glTF .gltf / .glb,
    /// each also .gz (the files it references — an OBJ's mtllibs, a Mitsuba scene's meshes,
    /// a glTF's buffers and images — are sent along from its directory). A file with its
    /// own camera is seen through it; a bare model is staged on a floor under a light.
    #[arg(long, value_name = "NAME|PATH", default_value = "cornell")]
    scene: String,

    /// The shared data directory holding the models built-in scenes are made from
    /// (grid-dragon: dragon/dragon_vrip.ply). Default: $EDGEPOINT_DATA, else a shared/data
    /// directory above the working directory or this executable.
    #[arg(long, value_name = "DIR")]
    data_dir: Option<PathBuf>,

    /// Frame width in pixels [default: the scene file's film width (Mitsuba `film`; glTF:
    /// the camera's aspect ratio at 512 high), else 512].
    #[arg(long, value_name = "PIXELS", value_parser = clap::value_parser!(u32).range(1..=16384))]
    width: Option<u32>,

    /// Frame height in pixels [default: the scene file's film height, else 512].
    #[arg(long, value_name = "PIXELS", value_parser = clap::value_parser!(u32).range(1..=16384))]
    height: Option<u32>,

    /// Shader the workers run for each sample (listed below).
    #[arg(long, value_name = "NAME", default_value = "direct")]
    shader: String,

    /// A shader parameter, KEY=VALUE (e.g. shadow_rays=16 or area=exact; listed below); repeat
    /// for several. The server refuses unknown ones and values out of range.
    #[arg(long, value_name = "KEY=VALUE", value_parser = edgepoint_proto::shaders::parse_param)]
    shader_param: Vec<(String, f64)>,

    /// How one pixel's shading is spread over the workers (paper 004 §4.4): `pixels`
    /// (default: each request shades a whole pixel) or `lights:N` (each sample in N parts,
    /// 1-64, shaded by any workers at once: part i takes the lights with index i mod N, part
    /// 0 also emission, ambient and indirect light; the server adds the parts before caching).
    #[arg(long, value_name = "pixels|lights:N", default_value = "pixels")]
    split: edgepoint_proto::split::SplitMode,

    /// Encoding of the frames the server sends. Default: qoi, or linear when --format exr,
    /// --tev, --exposure or --tonemap filmic need the radiance.
    #[arg(long, value_enum)]
    encoding: Option<Encoding>,

    /// File format of the frames written to --out: png (8-bit sRGB after --exposure and
    /// --tonemap) or exr (OpenEXR, linear RGB half floats, never tone-mapped or clipped).
    #[arg(long, value_enum, default_value_t = FileFormat::Png)]
    format: FileFormat,

    /// Exposure in stops for PNG frames and the window: linear values are multiplied by
    /// 2^EV before the tone curve (the window's - and = keys change it by half a stop).
    /// EXR files and tev get the unscaled values.
    #[arg(long, value_name = "EV", default_value_t = 0.0, allow_negative_numbers = true, value_parser = parse_exposure)]
    exposure: f32,

    /// Tone curve for PNG frames and the window, after the exposure and before the sRGB
    /// transfer: clip (values above 1 clip; at exposure 0 the server's own sRGB frames) or
    /// filmic (the ACES filmic fit of Narkowicz 2016, x(2.51x+0.03)/(x(2.43x+0.59)+0.14):
    /// highlights roll off, white at 7.2). The window's T key switches them.
    #[arg(long, value_enum, default_value_t = ToneCurve::Clip)]
    tonemap: ToneCurve,

    /// Mirror every frame's linear RGB to the tev image viewer listening at HOST:PORT (tev's
    /// default is 127.0.0.1:14158; a bare HOST gets that port), as pbrt-v4's
    /// --display-server does. A tev that is absent or goes away only gets a warning: the
    /// render goes on and the mirror reconnects when tev is back.
    #[arg(long, value_name = "HOST:PORT", value_parser = edgepoint_viewer::tev::parse_addr)]
    tev: Option<String>,

    /// Stop after N frames; 0 runs until Ctrl-C (or until the window is closed). Default:
    /// 300 frames when headless (about 10 s at 30 fps, so a forgotten run cannot fill the
    /// disk with PNGs), no limit with a window.
    #[arg(long, value_name = "N")]
    frames: Option<u64>,

    /// Write every frame as DIR/frame_00001.png (.exr with --format exr) ... and per-frame
    /// stats to DIR/stats.jsonl.
    /// Headless runs write to ./edgepoint-frames when not given; with a window, only when given.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,

    /// Never open a window, even when a display exists.
    #[arg(long)]
    headless: bool,

    /// Browser viewing: start the local cluster with the server's browser viewer on ADDR
    /// (e.g. 127.0.0.1:8080; port 0 picks one) and print the page's URL instead of opening
    /// a window; runs until Ctrl-C. With --token-file the server asks for that token and the
    /// URL carries it (`#token=…`, never sent to a server by the browser). An address beyond
    /// loopback needs the server's TLS (`--server-arg --tls-cert …`) or `--server-arg --insecure`.
    /// The page picks the scene and shader; --scene, --shader and --width preselect them.
    #[arg(long, value_name = "ADDR", conflicts_with_all = ["server", "headless", "token"])]
    web: Option<String>,

    /// Camera overriding the scene's, any subset of "eye=X,Y,Z target=X,Y,Z up=X,Y,Z
    /// fov=DEG" (sent in `start`; the keys left out keep the scene camera's — for a scene
    /// file that brings a camera, the file's). With --orbit only fov is allowed (the orbit
    /// places the camera).
    #[arg(long, value_name = "KEYS", value_parser = parse_camera_spec)]
    camera: Option<CameraSpec>,

    /// Use the scene file's camera of this name instead of its first one (glTF: camera or
    /// node name; Mitsuba XML: sensor id); --camera keys still override it.
    #[arg(long, value_name = "NAME")]
    camera_name: Option<String>,

    #[command(flatten)]
    orbit: OrbitArgs,

    /// Play a camera path: FILE holds one camera per line as JSON,
    /// {"eye":[x,y,z],"target":[x,y,z],"up":[x,y,z],"fov":deg} (any subset of the keys, over
    /// the start camera; blank lines and # comments skipped). One camera per received frame;
    /// at the end of the path a headless run stops once a frame of the last camera arrives
    /// (--frames may stop it sooner) and a window keeps the last camera for the mouse and
    /// keys, unless --loop-path starts it over.
    #[arg(long, value_name = "FILE", conflicts_with = "orbit")]
    camera_path: Option<PathBuf>,

    /// Start the --camera-path over at its end, forever.
    #[arg(long, requires = "camera_path")]
    loop_path: bool,

    /// Directory the window's screenshot key (P) writes PNGs to.
    #[arg(long, value_name = "DIR", default_value = ".")]
    screenshot_dir: PathBuf,

    /// Record the camera of every received frame (as the server reports it rendered the
    /// frame) to FILE, one JSON line per frame, in the format --camera-path plays.
    #[arg(long, value_name = "FILE")]
    record_path: Option<PathBuf>,

    /// Slide the named scene object back and forth along X (25% of the scene's width,
    /// 120 frames per cycle), one move per received frame.
    #[arg(long, value_name = "NAME")]
    move_object: Option<String>,

    /// Pixels per new sample per frame (the paper uses 40-125); the server's default is 64.
    #[arg(long, value_name = "RATIO", allow_negative_numbers = true, value_parser = parse_positive_f64)]
    sparseness: Option<f64>,

    /// Cap on the server's frame rate (frames per second); the server's default is 30.
    #[arg(long, value_name = "FPS", allow_negative_numbers = true, value_parser = parse_positive_f64)]
    max_fps: Option<f64>,

    /// Cap on the server's frame rate while the camera and the objects are still (after 8
    /// still frames); the server's default is 10. The frames at rest only add the samples
    /// that arrived since the last one, and a frame not made leaves the machine to the
    /// shader workers, so a still image converges faster. The first camera change or object
    /// move is answered at the --max-fps rate. Equal to --max-fps: no slowing down.
    #[arg(long, value_name = "FPS", allow_negative_numbers = true, value_parser = parse_positive_f64)]
    rest_fps: Option<f64>,

    #[command(flatten)]
    reconstruction: ReconstructionArgs,

    /// Print each frame's stats line (the JSON of stats.jsonl) on stdout as it arrives.
    #[arg(long, conflicts_with = "quiet")]
    stats_stdout: bool,

    /// Print nothing on stdout, not even the summary line at the end (stats.jsonl is still
    /// written).
    #[arg(long)]
    quiet: bool,

    /// Seconds to wait for the server to answer `start` (it builds the scene first).
    #[arg(long, value_name = "S", default_value_t = edgepoint_viewer::client::DEFAULT_START_TIMEOUT.as_secs(), value_parser = clap::value_parser!(u64).range(1..=86_400))]
    start_timeout_secs: u64,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum Encoding {
    /// QOI: lossless, fast.
    Qoi,
    /// PNG: lossless, smaller, slower to encode.
    Png,
    /// JPEG: lossy, smallest.
    Jpeg,
    /// Raw 8-bit sRGB, width*height*3 bytes.
    Raw,
    /// Linear RGB as half floats, LZ4-compressed (for EXR, tev, exposure and tone mapping).
    Linear,
}

impl From<Encoding> for FrameEncoding {
    fn from(e: Encoding) -> Self {
        match e {
            Encoding::Qoi => FrameEncoding::Qoi,
            Encoding::Png => FrameEncoding::Png,
            Encoding::Jpeg => FrameEncoding::Jpeg,
            Encoding::Raw => FrameEncoding::RawRgb8,
            Encoding::Linear => FrameEncoding::LinearHalfLz4,
        }
    }
}


fn parse_exposure(s: &str) -> Result<f32, String> {
    let v: f32 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() || v.abs() > 64.0 {
        return Err(format!("must be a number of stops in [-64, 64], got {s}"));
    }
    Ok(v)
}

impl Args {
    fn look(&self) -> Look {
        Look { exposure: self.exposure, curve: self.tonemap }
    }

    /// The frames' encoding: linear whenever an output needs the radiance.
    fn frame_encoding(&self) -> Result<FrameEncoding> {
        let need = if self.format == FileFormat::Exr {
            Some("--format exr")
        } else if self.tev.is_some() {
            Some("--tev")
        } else if !self.look().is_identity() {
            Some("--exposure / --tonemap filmic")
        } else {
            None
        };
        match (self.encoding, need) {
            (None, None) => Ok(FrameEncoding::Qoi),
            (None, Some(_)) | (Some(Encoding::Linear), _) => Ok(FrameEncoding::LinearHalfLz4),
            (Some(e), None) => Ok(e.into()),
            (Some(e), Some(what)) => bail!("{what} needs linear frames: drop --encoding {e:?} (or give --encoding linear)"),
        }
    }
}

/// `--web`: prints the page's URL (with the scene, shader and size preselected, and the
/// token in the fragment) and keeps the cluster up until Ctrl-C.
fn serve_web(cluster: &LocalCluster, args: &Args, rt: &tokio::runtime::Runtime, mut stop: watch::Receiver<bool>) -> Result<()> {
    let Some(base) = cluster.web_url() else { bail!("the server did not print its browser viewer's URL (`web <url>`)") };
    let token = match &args.token_file {
        Some(p) => edgepoint_proto::auth::read_token_file(p).map_err(anyhow::Error::msg)?.into_iter().next(),
        None => None,
    };
    let url = web_page_url(base, &args.scene, &args.shader, args.width, token.as_deref());
    {
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        writeln!(out, "{url}")?;
        out.flush()?;
    }
    tracing::info!("browser viewer at {url} (Ctrl-C stops the cluster)");
    rt.block_on(async {
        let _ = stop.wait_for(|s| *s).await;
    });
    Ok(())
}

/// The page URL with `?scene=&shader=&size=` preselections and `#token=`. Query values
/// are built-in names and numbers (a scene file cannot be picked in the page: it is left out).
fn web_page_url(base: &str, scene: &str, shader: &str, width: Option<u32>, token: Option<&str>) -> String {
    let mut q = Vec::new();
    if edgepoint_scene::builtin::BUILTINS.iter().any(|b| b.0 == scene) {
        q.push(format!("scene={scene}"));
    }
    if edgepoint_proto::shaders::shader(shader).is_some() {
        q.push(format!("shader={shader}"));
    }
    if let Some(w) = width {
        q.push(format!("size={w}"));
    }
    let mut url = base.to_string();
    if !q.is_empty() {
        url.push('?');
        url.push_str(&q.join("&"));
    }
    if let Some(t) = token {
        // Tokens are printable ASCII without spaces; escape what a fragment would misread.
        url.push_str("#token=");
        for b in t.bytes() {
            match b {
                b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => url.push(b as char),
                _ => url.push_str(&format!("%{b:02X}")),
            }
        }
    }
    url
}

fn parse_positive_f64(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() || v <= 0.0 {
        return Err(format!("must be a positive number, got {s}"));
    }
    Ok(v)
}

fn main() -> ExitCode {
    let args = Args::parse();
    edgepoint_proto::logging::init("info");
    match run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Everything that owns resources lives in here, so the local cluster is dropped (its
/// children killed) before the process exits, whatever the outcome.
fn run(args: Args) -> Result<()> {
    // Read the scene and the camera path before starting anything: a wrong path fails at once.
    let scene = scene_source_from_arg_in(&args.scene, args.data_dir.as_deref())?;
    // The file's film size and named camera, read from its bytes (its meshes are not
    // loaded here: the server and workers do that).
    let view = edgepoint_viewer::client::scene_file_view(&scene, args.camera_name.as_deref())?;
    let (width, height) = (
        args.width.or(view.film.map(|f| f.0)).unwrap_or(512),
        args.height.or(view.film.map(|f| f.1)).unwrap_or(512),
    );
    let camera = match (&args.camera_name, view.camera) {
        (Some(_), Some(named)) => Some(args.camera.unwrap_or_default().over(&named)),
        _ => args.camera,
    };
    let plan = camera_plan(&args)?;
    let encoding = args.frame_encoding()?;
    let mut recorder = args.record_path.as_deref().map(PathWriter::create).transpose()?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")?;

    // Ctrl-C only sets a flag: the run loops notice it and return normally, so the
    // cluster's Drop runs. The children sit in their own process group, so a terminal's
    // Ctrl-C reaches only us.
    let (stop_tx, stop_rx) = watch::channel(false);
    let stop_flag = Arc::new(AtomicBool::new(false));
    {
        let stop_flag = stop_flag.clone();
        rt.spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                tracing::info!("Ctrl-C: stopping");
                stop_flag.store(true, Ordering::Relaxed);
                let _ = stop_tx.send(true);
            }
        });
    }

    let cluster = match &args.server {
        Some(_) => None,
        None => {
            let mut server_args = args.server_arg.clone();
            if let (Some(_), Some(f)) = (&args.web, &args.token_file) {
                server_args.extend(["--token-file".to_string(), f.display().to_string()]);
            }
            let opts = LocalOptions {
                workers: args.workers as usize,
                worker_threads: args.worker_threads.map(|t| t as usize),
                worker_idle: args.worker_idle,
                server_args,
                web: args.web.clone(),
                bin_dir: args.bin_dir.clone(),
                log_level: args.cluster_log.clone(),
                log_file: args.cluster_log_file.clone(),
                ..LocalOptions::default()
            };
            // Under `cargo run`, build the server and worker first (cargo rebuilds what is stale).
            edgepoint_viewer::local::build_under_cargo(args.bin_dir.as_deref())?;
            Some(LocalCluster::start(opts).context("starting the local cluster")?)
        }
    };
    if stop_flag.load(Ordering::Relaxed) {
        return Ok(());
    }
    if let (Some(_), Some(c)) = (&args.web, &cluster) {
        return serve_web(c, &args, &rt, stop_rx);
    }
    let url = match (&args.server, &cluster) {
        (Some(u), _) => u.clone(),
        (None, Some(c)) => c.server_url(),
        (None, None) => unreachable!("a cluster is started whenever --server is absent"),
    };

    let settings = (args.sparseness.is_some() || args.max_fps.is_some() || args.rest_fps.is_some() || args.reconstruction.is_set()).then(|| {
        let mut s = pb::Settings {
            sparseness: args.sparseness.unwrap_or(0.0),
            max_fps: args.max_fps.unwrap_or(0.0),
            rest_fps: args.rest_fps.unwrap_or(0.0),
            ..Default::default()
        };
        args.reconstruction.apply(&mut s);
        s
    });
    let start = pb::Start {
        scene: Some(scene),
        width,
        height,
        shader: args.shader.clone(),
        shader_params: args.shader_param.iter().cloned().collect(),
        encoding: encoding as i32,
        settings,
        camera: camera.map(|c| c.to_wire()),
        split: args.split.to_wire(),
    };
    let token = match (&args.token, &args.token_file) {
        (Some(t), _) => Some(t.trim().to_string()),
        (None, Some(p)) => {
            let tokens = edgepoint_proto::auth::read_token_file(p).map_err(anyhow::Error::msg)?;
            tokens.into_iter().next()
        }
        (None, None) => None,
    };
    if token.is_some() && args.server.is_none() {
        tracing::warn!("the token is not used: the local cluster takes none (give --server URL to use it)");
    }
    let connect = ConnectOptions {
        token,
        tls_ca: args.tls_ca.clone(),
        tls_domain: args.tls_domain.clone(),
        start_timeout: Some(std::time::Duration::from_secs(args.start_timeout_secs)),
    };
    tracing::info!(%url, scene = %args.scene, width, height, "starting session");
    let connected = rt.block_on(async {
        let mut stop = stop_rx.clone();
        tokio::select! {
            r = SessionClient::connect_with(&url, start, &connect) => Some(r),
            _ = stop.wait_for(|s| *s) => None,
        }
    });
    let Some(connected) = connected else { return Ok(()) };
    // No context here: the message is the server's own (`INVALID_ARGUMENT: bunny.ply: ...`).
    let (client, started) = connected?;
    let names: Vec<&str> = started.objects.iter().map(|o| o.name.as_str()).collect();
    tracing::info!(
        session = %started.session_id,
        workers = started.workers,
        lights = started.lights,
        objects = %names.join(", "),
        "session started"
    );
    let mut script = Script::new(&started, &plan, args.move_object.as_deref())?;
    // The scripted camera's first position goes out before any frame is taken.
    send_step(&client.sender(), script.first_step());

    let want_window = !args.headless && display_available();
    let window = if want_window {
        match ViewerWindow::open("edgepoint-viewer", width, height) {
            Ok(w) => Some(w),
            Err(e) => {
                tracing::warn!("{e:#}; running headless");
                None
            }
        }
    } else {
        None
    };
    let tev = args.tev.as_deref().map(|addr| TevMirror::start(addr, &tev_image_name(&args.scene)));
    let linear = encoding == FrameEncoding::LinearHalfLz4;
    let result = match window {
        Some(w) => run_window(&rt, w, client, &started, script, recorder, &args, stop_flag, tev, linear),
        None => {
            let out = args.out.clone().unwrap_or_else(|| PathBuf::from(DEFAULT_OUT_DIR));
            rt.block_on(run_headless(client, script, &mut recorder, &args, out, stop_rx, tev.as_ref()))
        }
    };
    drop(cluster);
    result
}

/// The name frames have in tev: `edgepoint <scene>` (the file name of a scene file).
fn tev_image_name(scene: &str) -> String {
    let short = std::path::Path::new(scene).file_name().map_or(scene.into(), |n| n.to_string_lossy());
    format!("edgepoint {short}")
}

/// What the camera flags ask for. `--orbit` with a --camera that places the camera is an
/// error (the orbit places it); the path file is read here, so its errors come first.
fn camera_plan(args: &Args) -> Result<CameraPlan> {
    let fov = args.camera.and_then(|c| c.fov_y_degrees);
    if args.orbit.orbit {
        if args.camera.is_some_and(|c| c.places_the_camera()) {
            bail!("--camera eye/target/up cannot be combined with --orbit (the orbit places the camera: use --orbit-pivot, --orbit-radius, --orbit-elevation, --orbit-start; --camera fov=DEG sets its lens)");
        }
        return Ok(CameraPlan::Orbit { args: args.orbit.clone(), fov });
    }
    if let Some(p) = &args.camera_path {
        return Ok(CameraPlan::Path { entries: read_path(p)?, name: p.display().to_string(), looped: args.loop_path });
    }
    Ok(CameraPlan::Still)
}

/// Appends the camera frame `f` was rendered with to the recorded path.
fn record(recorder: &mut Option<PathWriter>, f: &pb::Frame) -> Result<()> {
    if let (Some(w), Some(c)) = (recorder.as_mut(), f.camera.as_ref()) {
        w.push(&camera_from_wire(c))?;
    }
    Ok(())
}

/// Sends what the script asks for after a frame; a send can only fail once the session is
/// ending, and the receive side reports why.
fn send_step(sender: &SessionSender, step: ScriptStep) {
    if let Some(c) = step.camera {
        let _ = sender.send_camera(c);
    }
    if let Some(m) = step.object_move {
        let _ = sender.send_move(m);
    }
}

fn log_progress(p: &pb::Progress) {
    if p.total > 0 {
        tracing::info!("{}: {}/{} {}", p.stage, p.done, p.total, p.message);
    } else {
        tracing::info!("{}: {}", p.stage, p.message);
    }
}

fn log_rejected(r: &pb::Rejected) {
    let code = code_name(tonic::Code::from_i32(r.code));
    tracing::warn!("the server rejected a message: {code}: {}", r.message);
}

/// The server ended the stream: the viewer never asked for that (it stops by closing its
/// side), so it is an error whatever the frame target.
fn server_ended_session(count: u64, target: u64) -> Result<()> {
    if target > 0 {
        bail!("the server ended the session after {count} of {target} frames");
    }
    bail!("the server ended the session after {count} frames");
}

async fn run_headless(
    mut client: SessionClient,
    mut script: Script,
    recorder: &mut Option<PathWriter>,
    args: &Args,
    out: PathBuf,
    mut stop: watch::Receiver<bool>,
    tev: Option<&TevMirror>,
) -> Result<()> {
    let mut writer = HeadlessWriter::create(&out, args.stats_stdout)?.with_format(args.format);
    let tone = ToneMapper::new(args.look());
    let target = args.frames.unwrap_or(DEFAULT_HEADLESS_FRAMES);
    tracing::info!("writing frames and stats.jsonl to {}", out.display());
    let sender = client.sender();
    loop {
        let ev = tokio::select! {
            ev = client.next_event() => ev,
            _ = stop.wait_for(|s| *s) => break,
        };
        let received = Instant::now();
        match ev {
            None => {
                server_ended_session(writer.frames_written(), target)?;
            }
            Some(Err(e)) => return Err(e.into()),
            Some(Ok(Event::Rejected(r))) => log_rejected(&r),
            Some(Ok(Event::Progress(p))) => log_progress(&p),
            // Nothing here asks for picks.
            Some(Ok(Event::Picked(_))) => {}
            Some(Ok(Event::Frame(f))) => {
                let t0 = Instant::now();
                let decoded = decode_with(&f, &tone)?;
                let decode_ms = t0.elapsed().as_secs_f64() * 1e3;
                if let (Some(m), Some(lin)) = (tev, &decoded.linear) {
                    m.offer(lin.clone());
                }
                writer.write_decoded(&f, &decoded, received, decode_ms)?;
                record(recorder, &f)?;
                if target > 0 && writer.frames_written() >= target {
                    break;
                }
                if script.path_finished(f.camera.as_ref()) {
                    tracing::info!("the camera path has been played");
                    break;
                }
                send_step(&sender, script.on_frame());
            }
        }
    }
    if !args.quiet {
        println!("{}", writer.summary());
    }
    Ok(())
}

// The window needs the session, its start, the script, the recorder, the flags and the
// outputs.
#[allow(clippy::too_many_arguments)]
fn run_window(
    rt: &tokio::runtime::Runtime,
    window: ViewerWindow,
    mut client: SessionClient,
    started: &pb::Started,
    script: Script,
    mut recorder: Option<PathWriter>,
    args: &Args,
    stop: Arc<AtomicBool>,
    tev: Option<TevMirror>,
    linear: bool,
) -> Result<()> {
    let mut writer = match &args.out {
        Some(dir) => Some(HeadlessWriter::create(dir, args.stats_stdout)?.with_format(args.format)),
        None => None,
    };
    let look = Arc::new(LookControl::new(args.look(), linear));
    let sender = client.sender();
    // Unbounded, so a pick answer or progress is never lost; decoded frames are skipped
    // while two wait (the window shows only the newest).
    let (to_window, from_session) = std::sync::mpsc::channel::<ToWindow>();
    let queued = Arc::new(AtomicUsize::new(0));
    let setup = WindowSetup {
        sender: sender.clone(),
        home: script.start_camera(),
        scale: suggested_orbit(started).map(|o| o.radius).unwrap_or(1.0),
        screenshot_dir: args.screenshot_dir.clone(),
        scripted_camera: script.drives_camera(),
        scene: args.scene.clone(),
        frames_queued: queued.clone(),
        look: look.clone(),
    };
    let script = Arc::new(Mutex::new(script));
    let target = args.frames.unwrap_or(0);
    let receiver = {
        let script = script.clone();
        let queued = queued.clone();
        rt.spawn(async move {
            let mut meter = FrameMeter::new();
            let mut tone = ToneMapper::new(look.get());
            while let Some(ev) = client.next_event().await {
                let received = Instant::now();
                match ev? {
                    Event::Rejected(r) => log_rejected(&r),
                    Event::Progress(p) => {
                        log_progress(&p);
                        let _ = to_window.send(ToWindow::Progress(p));
                    }
                    Event::Picked(p) => {
                        let _ = to_window.send(ToWindow::Picked(p));
                    }
                    Event::Frame(f) => {
                        let t0 = Instant::now();
                        tone.set_look(look.get());
                        let decoded = decode_with(&f, &tone)?;
                        let decode_ms = t0.elapsed().as_secs_f64() * 1e3;
                        if let (Some(m), Some(lin)) = (&tev, &decoded.linear) {
                            m.offer(lin.clone());
                        }
                        let img = &decoded.image;
                        record(&mut recorder, &f)?;
                        let stats = match writer.as_mut() {
                            Some(w) => w.write_decoded(&f, &decoded, received, decode_ms)?,
                            None => FrameStats::new(&f, meter.arrive(received)),
                        };
                        if queued.load(Ordering::Relaxed) < 2 {
                            let mut pixels = Vec::with_capacity(img.len() / 3);
                            to_0rgb(img, &mut pixels);
                            queued.fetch_add(1, Ordering::Relaxed);
                            let _ = to_window.send(ToWindow::Frame(ShownFrame {
                                width: f.width,
                                height: f.height,
                                pixels,
                                sequence: f.sequence,
                                samples_used: f.samples_used,
                                fps: stats.fps,
                                stages: stats.stages.0.clone(),
                                total_ms: f.total_ms,
                                camera: f.camera.as_ref().map(camera_from_wire),
                                overlay: f.overlay,
                                reconstruction: f.reconstruction,
                                has_content: f.pixels.as_ref().is_some_and(|p| p.cache_points > 0),
                            }));
                        }
                        let count = writer.as_ref().map_or(meter.count(), |w| w.frames_written());
                        if target > 0 && count >= target {
                            return Ok(());
                        }
                        let step = script.lock().unwrap_or_else(|e| e.into_inner()).on_frame();
                        send_step(&sender, step);
                    }
                }
            }
            let count = writer.as_ref().map_or(meter.count(), |w| w.frames_written());
            server_ended_session(count, target)
        })
    };
    let exit = window.run(from_session, &stop, setup, || script.lock().unwrap_or_else(|e| e.into_inner()).stop_camera());
    match exit {
        WindowExit::FramesEnded => rt.block_on(receiver).context("the frame receiver panicked")?,
        WindowExit::Closed | WindowExit::Stopped => {
            receiver.abort();
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_web_url_preselects_and_carries_the_token_in_the_fragment() {
        let u = web_page_url("http://127.0.0.1:8080/", "cornell", "direct", Some(256), Some("abc+def/0123456789"));
        assert_eq!(u, "http://127.0.0.1:8080/?scene=cornell&shader=direct&size=256#token=abc%2Bdef%2F0123456789");
        assert_eq!(web_page_url("http://h:1/", "model.ply", "nope", None, None), "http://h:1/", "files and unknown shaders are left out");
        Args::try_parse_from(["edgepoint-viewer", "--web", "127.0.0.1:0"]).unwrap();
        assert!(Args::try_parse_from(["edgepoint-viewer", "--web", "127.0.0.1:0", "--server", "http://x:1"]).is_err());
    }
}
