//! The on-screen viewer window (minifb), interactive as the paper's demos: the mouse and keys
//! move the camera ([`crate::camera_control`]) and drag objects ([`crate::object_drag`],
//! picked by the server), keys switch the server's overlays and reconstruction and save
//! screenshots, and an overlay drawn into the frame ([`crate::hud`]) shows fps, samples per
//! frame and per-stage milliseconds — or the session's loading progress until frames have
//! content. minifb loads X11 / Wayland at run time, so opening fails cleanly without a
//! display and the caller falls back to headless output.
use crate::camera_control::FreeCamera;
use crate::client::{camera_to_wire, SessionSender};
use crate::hud::{wrap, Canvas, LINE};
use crate::object_drag::Drag;
use anyhow::{anyhow, Context, Result};
use edgepoint_proto as pb;
use edgepoint_scene::Camera;
use minifb::{Key, KeyRepeat, MouseButton, MouseMode, ScaleMode, Window, WindowOptions};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::time::{Duration, Instant};

/// Every binding of the window, for `--help` and the on-screen help (H or F1).
pub const KEY_HELP: &str = "\
Window controls:
  left drag            orbit about the target
  right drag           pan
  wheel                dolly toward / away from the target
  Ctrl+left drag       move the object under the cursor (middle drag too),
                       in the plane facing the camera
  W/S A/D Q/E          fly forward/back, left/right, down/up (Shift: 4x)
  arrow keys           orbit
  R                    reset the camera
  O                    next overlay: none, edges, classes, samples
  B                    reconstruction: edge-and-point / Render Cache
  Space                pause / resume the server's frames
  - / =                exposure down / up by half a stop (linear frames)
  T                    tone curve: clip / filmic
  P                    screenshot (PNG; its path is printed)
  Tab                  stats overlay on / off
  H or F1              this help
  Esc                  quit
A scripted orbit or camera path stops when the mouse or keys move the camera.";

/// Whether a display server is named in the environment (X11 `DISPLAY` or
/// `WAYLAND_DISPLAY`).
pub fn display_available() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY"].iter().any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}

/// A decoded frame ready to show, with what the overlay prints.
#[derive(Debug, Clone)]
pub struct ShownFrame {
    pub width: u32,
    pub height: u32,
    /// 0RGB pixels, row-major, top row first.
    pub pixels: Vec<u32>,
    pub sequence: u64,
    pub samples_used: u32,
    /// Viewer-side frames per second.
    pub fps: f64,
    /// Per-stage milliseconds, in pipeline order, and the frame's total.
    pub stages: Vec<(String, f64)>,
    pub total_ms: f64,
    /// The camera the server rendered it with.
    pub camera: Option<Camera>,
    pub overlay: i32,
    pub reconstruction: i32,
    /// Whether it shows anything yet (the Render Cache holds points).
    pub has_content: bool,
}

/// What the session sends the window.
#[derive(Debug, Clone)]
pub enum ToWindow {
    Frame(ShownFrame),
    Progress(pb::Progress),
    Picked(pb::Picked),
}

/// Why [`ViewerWindow::run`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WindowExit {
    /// The user closed the window or pressed Esc.
    Closed,
    /// The frame source ended (the session is over).
    FramesEnded,
    /// `stop` was set (Ctrl-C).
    Stopped,
}

/// What the window needs to drive the session.
pub struct WindowSetup {
    pub sender: SessionSender,
    /// The session's start camera (R returns to it); `None` leaves the camera alone.
    pub home: Option<Camera>,
    /// The scene's size (its suggested orbit radius): fly speed per second, dolly limit.
    pub scale: f32,
    /// Where P saves screenshots.
    pub screenshot_dir: PathBuf,
    /// Whether an orbit or camera path drives the camera until the user takes over.
    pub scripted_camera: bool,
    /// What the loading screen names.
    pub scene: String,
    /// Decoded frames sent and not yet taken (the window counts down as it takes them).
    pub frames_queued: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    /// Exposure and tone curve, which the frame receiver applies to linear frames.
    pub look: std::sync::Arc<crate::tonemap::LookControl>,
}

/// Exposure change per key press, in stops.
const EXPOSURE_STEP: f32 = 0.5;

/// Orbit speed of the arrow keys.
const KEY_ORBIT_DEGREES_PER_SECOND: f32 = 90.0;
/// Flying speed in scene sizes per second (Shift: 4x).
const FLY_SPEED: f32 = 1.0;
/// A notice (screenshot saved, pick answer) stays this long.
const NOTICE: Duration = Duration::from_secs(4);

/// An open window.
pub struct ViewerWindow {
    window: Window,
    title: String,
}

/// The object drag in progress.
enum Grab {
    None,
    /// Waiting for the server's answer to pick `id`.
    Waiting(u64),
    Holding(Drag),
}

/// A mouse drag for the camera.
#[derive(Clone, Copy, PartialEq)]
enum CamDrag {
    Orbit,
    Pan,
}

/// Where the frame shows inside the window (minifb's aspect-preserving stretch, centred).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewRect {
    pub x: f32,
    pub y: f32,
    pub w: f32,
    pub h: f32,
}

impl ViewRect {
    /// The rectangle a `fw` x `fh` frame fills in a `ww` x `wh` window.
    pub fn fit(ww: usize, wh: usize, fw: u32, fh: u32) -> ViewRect {
        let (ww, wh, fw, fh) = (ww.max(1) as f32, wh.max(1) as f32, fw.max(1) as f32, fh.max(1) as f32);
        if fw / fh > ww / wh {
            let h = (ww * fh / fw).floor().max(1.0);
            ViewRect { x: 0.0, y: ((wh - h) / 2.0).floor(), w: ww, h }
        } else {
            let w = (wh * fw / fh).floor().max(1.0);
            ViewRect { x: ((ww - w) / 2.0).floor(), y: 0.0, w, h: wh }
        }
    }

    /// The frame position (continuous pixels) under window position (mx, my).
    pub fn to_frame(&self, mx: f32, my: f32, fw: u32, fh: u32) -> (f32, f32) {
        ((mx - self.x + 0.5) * fw as f32 / self.w, (my - self.y + 0.5) * fh as f32 / self.h)
    }
}

/// Saves a 0RGB frame as a PNG.
pub fn save_png(path: &Path, pixels: &[u32], width: u32, height: u32) -> Result<()> {
    let rgb: Vec<u8> = pixels.iter().flat_map(|p| [(p >> 16) as u8, (p >> 8) as u8, *p as u8]).collect();
    image::save_buffer(path, &rgb, width, height, image::ExtendedColorType::Rgb8).with_context(|| format!("cannot write {}", path.display()))
}

fn next_overlay(current: i32) -> pb::Overlay {
    match pb::Overlay::try_from(current) {
        Ok(pb::Overlay::Edges) => pb::Overlay::Classes,
        Ok(pb::Overlay::Classes) => pb::Overlay::Samples,
        Ok(pb::Overlay::Samples) => pb::Overlay::None,
        _ => pb::Overlay::Edges,
    }
}

fn other_reconstruction(current: i32) -> pb::Reconstruction {
    if current == pb::Reconstruction::RenderCache as i32 {
        pb::Reconstruction::EdgeAndPoint
    } else {
        pb::Reconstruction::RenderCache
    }
}

impl ViewerWindow {
    /// Opens a `width` x `height` window (resizable, aspect kept when scaled).
    pub fn open(title: &str, width: u32, height: u32) -> Result<Self> {
        let opts = WindowOptions { resize: true, scale_mode: ScaleMode::AspectRatioStretch, ..WindowOptions::default() };
        let mut window = Window::new(title, width.max(1) as usize, height.max(1) as usize, opts)
            .map_err(|e| anyhow!("cannot open a window: {e}"))?;
        window.set_target_fps(60);
        Ok(ViewerWindow { window, title: title.to_string() })
    }

    /// Shows what arrives on `from_session` until the window closes, the source ends or
    /// `stop` is set, and turns the mouse and keys into session messages. `take_over` runs
    /// once, when the user first moves a scripted camera.
    pub fn run(mut self, from_session: Receiver<ToWindow>, stop: &AtomicBool, setup: WindowSetup, mut take_over: impl FnMut()) -> WindowExit {
        let mut ui = Ui::new(setup);
        let mut last_tick = Instant::now();
        let mut last_title = Instant::now() - Duration::from_secs(1);
        let mut buffer: Vec<u32> = Vec::new();
        loop {
            if stop.load(Ordering::Relaxed) {
                return WindowExit::Stopped;
            }
            if !self.window.is_open() || self.window.is_key_down(Key::Escape) {
                return WindowExit::Closed;
            }
            let mut ended = false;
            loop {
                match from_session.try_recv() {
                    Ok(m) => ui.receive(m),
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => {
                        ended = true;
                        break;
                    }
                }
            }
            if ended {
                return WindowExit::FramesEnded;
            }
            let dt = last_tick.elapsed().as_secs_f32().min(0.1);
            last_tick = Instant::now();
            if ui.input(&self.window, dt) && !ui.taken_over {
                ui.taken_over = true;
                if ui.scripted {
                    take_over();
                    tracing::info!("interactive control: the scripted camera stops");
                }
            }
            let (w, h) = ui.compose(&mut buffer);
            if self.window.update_with_buffer(&buffer, w, h).is_err() {
                self.window.update();
            }
            if last_title.elapsed() >= Duration::from_millis(500) {
                if let Some(f) = &ui.frame {
                    self.window.set_title(&format!("{} - {:.1} fps - {} samples/frame", self.title, f.fps, f.samples_used));
                }
                last_title = Instant::now();
            }
        }
    }
}

/// The window's state between frames.
struct Ui {
    setup: WindowSetup,
    camera: Option<FreeCamera>,
    frame: Option<ShownFrame>,
    progress: BTreeMap<String, pb::Progress>,
    grab: Grab,
    next_pick: u64,
    cam_drag: Option<(CamDrag, (f32, f32))>,
    show_stats: bool,
    show_help: bool,
    paused: bool,
    notices: Vec<(String, Instant)>,
    scripted: bool,
    taken_over: bool,
    screenshots: u32,
    /// The last mouse position (window pixels) and the frame rectangle it maps through.
    rect: ViewRect,
}

impl Ui {
    fn new(setup: WindowSetup) -> Self {
        Ui {
            camera: setup.home.map(|c| FreeCamera::new(c, setup.scale)),
            scripted: setup.scripted_camera,
            setup,
            frame: None,
            progress: BTreeMap::new(),
            grab: Grab::None,
            next_pick: 1,
            cam_drag: None,
            show_stats: true,
            show_help: false,
            paused: false,
            notices: Vec::new(),
            taken_over: false,
            screenshots: 0,
            rect: ViewRect { x: 0.0, y: 0.0, w: 1.0, h: 1.0 },
        }
    }

    fn notice(&mut self, text: String) {
        self.notices.push((text, Instant::now()));
    }

    fn receive(&mut self, m: ToWindow) {
        match m {
            ToWindow::Frame(f) => {
                self.setup.frames_queued.fetch_sub(1, Ordering::Relaxed);
                // A scripted camera moves on its own: interactive moves continue from it.
                if let (false, Some(cam), Some(c)) = (self.taken_over, self.camera.as_mut(), f.camera) {
                    cam.set(c);
                }
                self.frame = Some(f);
            }
            ToWindow::Progress(p) => {
                self.progress.insert(p.stage.clone(), p);
            }
            ToWindow::Picked(p) => {
                if !matches!(self.grab, Grab::Waiting(id) if id == p.id) {
                    return; // released before the answer came
                }
                if p.hit {
                    let pos = glam::Vec3::from(p.position.unwrap_or_default());
                    tracing::info!(object = %p.name, id = p.object_id, "picked '{}' at {pos}", p.name);
                    self.notice(format!("moving {}", p.name));
                } else {
                    tracing::info!("picked nothing");
                }
                self.grab = Drag::new(&p).map_or(Grab::None, Grab::Holding);
            }
        }
    }

    fn frame_size(&self) -> (u32, u32) {
        self.frame.as_ref().map_or((1, 1), |f| (f.width, f.height))
    }

    fn send_settings(&self, s: pb::Settings) {
        let _ = self.setup.sender.send_settings(s);
    }

    /// Reads the mouse and keys; sends what they ask for. Returns whether the camera moved.
    fn input(&mut self, w: &Window, dt: f32) -> bool {
        let (ww, wh) = w.get_size();
        let (fw, fh) = self.frame_size();
        self.rect = ViewRect::fit(ww, wh, fw, fh);
        let Some(mut cam) = self.camera else { return false };
        let before = cam;
        let down = |keys: &[Key]| keys.iter().any(|k| w.is_key_down(*k));
        let ctrl = down(&[Key::LeftCtrl, Key::RightCtrl]);
        let mouse = w.get_mouse_pos(MouseMode::Pass);
        let (left, right, middle) = (w.get_mouse_down(MouseButton::Left), w.get_mouse_down(MouseButton::Right), w.get_mouse_down(MouseButton::Middle));

        // Object drag: Ctrl+left or middle.
        let grabbing = middle || (left && ctrl);
        match (&self.grab, grabbing, mouse) {
            (Grab::None, true, Some((mx, my))) if self.cam_drag.is_none() && self.frame.is_some() => {
                let (x, y) = self.rect.to_frame(mx, my, fw, fh);
                if (0.0..=fw as f32).contains(&x) && (0.0..=fh as f32).contains(&y) {
                    let id = self.next_pick;
                    self.next_pick += 1;
                    let _ = self.setup.sender.send_pick(id, x, y);
                    self.grab = Grab::Waiting(id);
                }
            }
            (Grab::Holding(d), true, Some((mx, my))) => {
                let (x, y) = self.rect.to_frame(mx, my, fw, fh);
                if let Some(t) = d.transform_at(&cam.camera(), fw, fh, x, y) {
                    let _ = self.setup.sender.send_move(d.object_move(&t));
                }
            }
            (_, false, _) => self.grab = Grab::None,
            _ => {}
        }

        // Camera drags: left orbits, right pans.
        let wanted = if left && !ctrl && matches!(self.grab, Grab::None) {
            Some(CamDrag::Orbit)
        } else if right {
            Some(CamDrag::Pan)
        } else {
            None
        };
        match (wanted, self.cam_drag, mouse) {
            (Some(kind), Some((was, (px, py))), Some((mx, my))) if kind == was => {
                let (dx, dy) = ((mx - px) * fw as f32 / self.rect.w, (my - py) * fh as f32 / self.rect.h);
                match kind {
                    CamDrag::Orbit => cam.orbit(-dx / fw as f32 * std::f32::consts::TAU, dy / fh as f32 * std::f32::consts::PI),
                    CamDrag::Pan => cam.pan(dx, dy, fh),
                }
                self.cam_drag = Some((kind, (mx, my)));
            }
            (Some(kind), _, Some(m)) => self.cam_drag = Some((kind, m)),
            _ => self.cam_drag = None,
        }
        if let Some((_, wy)) = w.get_scroll_wheel() {
            cam.dolly(wy);
        }

        // Held keys: fly and orbit, per second.
        let speed = FLY_SPEED * if down(&[Key::LeftShift, Key::RightShift]) { 4.0 } else { 1.0 };
        let axis = |plus: Key, minus: Key| (w.is_key_down(plus) as i32 - w.is_key_down(minus) as i32) as f32;
        let (f, r, u) = (axis(Key::W, Key::S), axis(Key::D, Key::A), axis(Key::E, Key::Q));
        if !ctrl && (f, r, u) != (0.0, 0.0, 0.0) {
            cam.fly(f, r, u, dt, speed);
        }
        let turn = KEY_ORBIT_DEGREES_PER_SECOND.to_radians() * dt;
        let (yaw, pitch) = (axis(Key::Left, Key::Right), axis(Key::Up, Key::Down));
        if (yaw, pitch) != (0.0, 0.0) {
            cam.orbit(yaw * turn, pitch * turn);
        }

        for k in w.get_keys_pressed(KeyRepeat::No) {
            match k {
                Key::R => cam.reset(),
                Key::O => {
                    let o = next_overlay(self.frame.as_ref().map_or(0, |f| f.overlay));
                    self.send_settings(pb::Settings { overlay: o as i32, ..Default::default() });
                    self.notice(format!("overlay: {}", crate::reconstruction::overlay_name(o as i32)));
                }
                Key::B => {
                    let r = other_reconstruction(self.frame.as_ref().map_or(0, |f| f.reconstruction));
                    self.send_settings(pb::Settings { reconstruction: r as i32, ..Default::default() });
                    self.notice(format!("reconstruction: {}", crate::reconstruction::reconstruction_name(r as i32)));
                }
                Key::Space => {
                    self.paused = !self.paused;
                    self.send_settings(pb::Settings { paused: self.paused, set_paused: true, ..Default::default() });
                    self.notice(if self.paused { "paused".into() } else { "resumed".into() });
                }
                Key::Minus | Key::NumPadMinus => self.change_look(|l| l.exposure -= EXPOSURE_STEP),
                Key::Equal | Key::NumPadPlus => self.change_look(|l| l.exposure += EXPOSURE_STEP),
                Key::T => self.change_look(|l| l.curve = l.curve.toggled()),
                Key::P => self.screenshot(),
                Key::Tab => self.show_stats = !self.show_stats,
                Key::H | Key::F1 => self.show_help = !self.show_help,
                _ => {}
            }
        }

        self.camera = Some(cam);
        if cam != before {
            let _ = self.setup.sender.send_camera(camera_to_wire(&cam.camera()));
            return true;
        }
        false
    }

    /// Exposure and tone curve apply to linear frames: the first change asks the server for
    /// them (frames already on their way still show as they were rendered).
    fn change_look(&mut self, change: impl FnOnce(&mut crate::tonemap::Look)) {
        let (look, switch) = self.setup.look.adjust(change);
        if switch {
            self.send_settings(pb::Settings { encoding: pb::FrameEncoding::LinearHalfLz4 as i32, ..Default::default() });
        }
        self.notice(format!("display: {}", look.describe()));
    }

    fn screenshot(&mut self) {
        let Some(f) = &self.frame else {
            self.notice("no frame to save yet".into());
            return;
        };
        self.screenshots += 1;
        let stamp = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
        let path = self.setup.screenshot_dir.join(format!("edgepoint-{stamp}-{:06}-{}.png", f.sequence, self.screenshots));
        match save_png(&path, &f.pixels, f.width, f.height) {
            Ok(()) => {
                // The path on stdout, for scripts; the notice for the person.
                println!("screenshot {}", path.display());
                tracing::info!("screenshot saved to {}", path.display());
                self.notice(format!("saved {}", path.display()));
            }
            Err(e) => {
                tracing::warn!("{e:#}");
                self.notice(format!("screenshot failed: {e:#}"));
            }
        }
    }

    /// Draws the frame (or the loading screen) and the overlays into `buf`; returns its size.
    fn compose(&mut self, buf: &mut Vec<u32>) -> (usize, usize) {
        const WHITE: u32 = 0xffffff;
        const DIM: u32 = 0xb0b0b0;
        let (w, h) = match &self.frame {
            Some(f) => (f.width as usize, f.height as usize),
            None => (512, 512),
        };
        buf.clear();
        match &self.frame {
            Some(f) if f.has_content => buf.extend_from_slice(&f.pixels),
            _ => buf.resize(w * h, 0x101418),
        }
        let mut c = Canvas { pixels: buf, width: w, height: h };
        let cols = (w / crate::hud::GLYPH).saturating_sub(2).max(8);
        if !self.frame.as_ref().is_some_and(|f| f.has_content) {
            let mut lines = vec![format!("loading {}", self.setup.scene)];
            for p in self.progress.values() {
                let count = if p.total > 0 { format!(" {}/{}", p.done, p.total) } else { String::new() };
                lines.push(format!("{}:{count} {}", p.stage, p.message));
            }
            match &self.frame {
                Some(f) => lines.push(format!("frame {}: waiting for the first samples", f.sequence)),
                None => lines.push("waiting for the first frame".into()),
            }
            let lines: Vec<String> = lines.iter().flat_map(|l| wrap(std::slice::from_ref(l), cols)).collect();
            let y = c.panel(8, 8, &lines, WHITE) + 12;
            // One bar per stage with a known total.
            for (i, p) in self.progress.values().filter(|p| p.total > 0).enumerate() {
                let bw = w.saturating_sub(24);
                let yy = y + i * 8;
                c.fill(12, yy, bw, 4, 0x303840);
                c.fill(12, yy, (bw as u64 * p.done.min(p.total) / p.total) as usize, 4, 0x40c070);
            }
        } else if self.show_stats {
            let f = self.frame.as_ref().expect("checked above");
            let mut lines = vec![format!("{:.1} fps  {} samples/frame  {:.1} ms/frame  #{}", f.fps, f.samples_used, f.total_ms, f.sequence)];
            let stages: Vec<String> = f.stages.iter().map(|(s, ms)| format!("{s} {ms:.2}")).collect();
            lines.extend(wrap(&stages, cols));
            lines.push(format!(
                "{}  overlay {}{}  H: help",
                crate::reconstruction::reconstruction_name(f.reconstruction),
                crate::reconstruction::overlay_name(f.overlay),
                if self.paused { "  PAUSED" } else { "" }
            ));
            // Long work that goes on while frames show (the discontinuity mesh's build and
            // estimates: a minute on `rooms`), one line per stage until it is done.
            for p in self.progress.values().filter(|p| p.total > 0 && p.done < p.total) {
                lines.extend(wrap(&[format!("{}: {}/{} {}", p.stage, p.done, p.total, p.message)], cols));
            }
            c.panel(4, 4, &lines, WHITE);
        }
        if self.show_help {
            let lines: Vec<String> = KEY_HELP.lines().map(str::to_string).collect();
            let top = h.saturating_sub(lines.len() * LINE + 10) / 2;
            c.panel(4, top, &lines, DIM);
        }
        self.notices.retain(|(_, t)| t.elapsed() < NOTICE);
        let notices: Vec<String> = self.notices.iter().flat_map(|(n, _)| wrap(std::slice::from_ref(n), cols)).collect();
        if !notices.is_empty() {
            c.panel(4, h.saturating_sub(notices.len() * LINE + 10), &notices, WHITE);
        }
        (w, h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_view_rect_maps_window_positions_to_frame_pixels() {
        // Same aspect: identity up to the scale.
        let r = ViewRect::fit(1024, 512, 512, 256);
        assert_eq!(r, ViewRect { x: 0.0, y: 0.0, w: 1024.0, h: 512.0 });
        assert_eq!(r.to_frame(511.5, 255.5, 512, 256), (256.0, 128.0));
        // A wide window: pillarboxed, centred.
        let r = ViewRect::fit(800, 400, 256, 256);
        assert_eq!(r, ViewRect { x: 200.0, y: 0.0, w: 400.0, h: 400.0 });
        let (x, y) = r.to_frame(399.5, 199.5, 256, 256);
        assert!((x - 128.0).abs() < 1e-4 && (y - 128.0).abs() < 1e-4);
        // A tall window: letterboxed.
        let r = ViewRect::fit(300, 900, 300, 300);
        assert_eq!((r.y, r.h), (300.0, 300.0));
    }

    #[test]
    fn overlay_and_reconstruction_keys_cycle() {
        let mut o = pb::Overlay::None as i32;
        let mut seen = vec![];
        for _ in 0..4 {
            o = next_overlay(o) as i32;
            seen.push(crate::reconstruction::overlay_name(o));
        }
        assert_eq!(seen, ["edges", "classes", "samples", "none"]);
        assert_eq!(next_overlay(0), pb::Overlay::Edges, "unknown: start at edges");
        assert_eq!(other_reconstruction(pb::Reconstruction::EdgeAndPoint as i32), pb::Reconstruction::RenderCache);
        assert_eq!(other_reconstruction(pb::Reconstruction::RenderCache as i32), pb::Reconstruction::EdgeAndPoint);
    }

    #[test]
    fn screenshots_are_pngs_of_the_frame() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("s.png");
        save_png(&p, &[0x102030, 0xff0000], 2, 1).unwrap();
        let img = image::open(&p).unwrap().to_rgb8();
        assert_eq!((img.get_pixel(0, 0).0, img.get_pixel(1, 0).0), ([0x10, 0x20, 0x30], [0xff, 0, 0]));
    }

    fn ui() -> Ui {
        ui_with(SessionSender::detached().0, false)
    }

    fn ui_with(sender: SessionSender, linear: bool) -> Ui {
        Ui::new(WindowSetup {
            sender,
            home: None,
            scale: 1.0,
            screenshot_dir: PathBuf::from("."),
            scripted_camera: false,
            scene: "cornell".into(),
            frames_queued: Default::default(),
            look: std::sync::Arc::new(crate::tonemap::LookControl::new(Default::default(), linear)),
        })
    }

    /// The exposure keys change the shared look; the first change of a session with sRGB
    /// frames asks for linear frames, once; a session that has them is never asked.
    #[test]
    fn exposure_keys_ask_for_linear_frames_once() {
        use crate::tonemap::ToneCurve;
        let (sender, mut rx) = SessionSender::detached();
        let mut ui = ui_with(sender, false);
        ui.change_look(|l| l.exposure += EXPOSURE_STEP);
        ui.change_look(|l| l.curve = l.curve.toggled());
        let look = ui.setup.look.get();
        assert_eq!((look.exposure, look.curve), (0.5, ToneCurve::Filmic));
        let msg = rx.try_recv().unwrap().msg.unwrap();
        let pb::viewer_msg::Msg::Settings(s) = msg else { panic!("{msg:?}") };
        assert_eq!(s.encoding, pb::FrameEncoding::LinearHalfLz4 as i32);
        assert!(rx.try_recv().is_err(), "asked once");
        let (sender, mut rx) = SessionSender::detached();
        let mut ui = ui_with(sender, true);
        ui.change_look(|l| l.exposure -= EXPOSURE_STEP);
        assert!(rx.try_recv().is_err());
    }

    fn frame(has_content: bool) -> ShownFrame {
        ShownFrame {
            width: 200,
            height: 150,
            pixels: vec![0x808080; 200 * 150],
            sequence: 3,
            samples_used: 10,
            fps: 30.0,
            stages: vec![("edges".into(), 1.0)],
            total_ms: 5.0,
            camera: None,
            overlay: 1,
            reconstruction: 1,
            has_content,
        }
    }

    #[test]
    fn the_stats_overlay_and_the_loading_screen_are_drawn_into_the_frame() {
        let mut u = ui();
        let mut buf = Vec::new();
        assert_eq!(u.compose(&mut buf), (512, 512), "before any frame: the loading screen");
        assert!(buf.contains(&0xffffff), "loading text drawn");
        u.receive(ToWindow::Progress(pb::Progress { stage: "workers".into(), done: 1, total: 2, message: "scene loaded".into() }));
        u.receive(ToWindow::Frame(frame(false)));
        assert_eq!(u.compose(&mut buf), (200, 150));
        assert!(buf.contains(&0x40c070), "a progress bar for the stage with a total");
        u.receive(ToWindow::Frame(frame(true)));
        u.compose(&mut buf);
        // The stats panel darkens the top-left corner and writes over it; the rest is the frame.
        assert!(buf[..200 * 12].contains(&0xffffff) && buf[5 * 200 + 5] != 0x808080);
        assert_eq!(buf[149 * 200 + 199], 0x808080);
        // A stage still going shows as one more line of the panel, until it is done.
        let panel_rows = |buf: &[u32]| (0..150).filter(|y| buf[y * 200 + 5] != 0x808080).count();
        let before = panel_rows(&buf);
        u.receive(ToWindow::Progress(pb::Progress { stage: "discontinuity mesh".into(), done: 10, total: 100, message: "light-triangle pairs".into() }));
        u.compose(&mut buf);
        assert_eq!(panel_rows(&buf), before + crate::hud::LINE, "one line more");
        u.receive(ToWindow::Progress(pb::Progress { stage: "discontinuity mesh".into(), done: 100, total: 100, message: "light-triangle pairs done".into() }));
        u.receive(ToWindow::Progress(pb::Progress { stage: "workers".into(), done: 2, total: 2, message: "scene loaded".into() }));
        u.compose(&mut buf);
        assert_eq!(panel_rows(&buf), before - crate::hud::LINE, "the workers' line gone too, once done");
        u.show_stats = false;
        u.compose(&mut buf);
        assert!(buf.iter().all(|&p| p == 0x808080), "Tab hides it");
    }

    #[test]
    fn every_key_of_the_window_is_in_the_help() {
        for k in ["left drag", "right drag", "wheel", "Ctrl+left drag", "W/S", "A/D", "Q/E", "R ", "O ", "B ", "P ", "Space", "Tab", "H or F1", "Esc"] {
            assert!(KEY_HELP.contains(k), "{k}");
        }
    }
}
