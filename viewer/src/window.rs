//! The on-screen viewer window (minifb): shows each frame as it arrives, with fps and
//! samples per frame in the title; Left/Right or A/D orbit, W/S or Up/Down dolly, Esc
//! quits. minifb loads X11 / Wayland at run time, so opening fails cleanly without a
//! display and the caller falls back to headless output.
use anyhow::{anyhow, Result};
use minifb::{Key, ScaleMode, Window, WindowOptions};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, TryRecvError};
use std::time::{Duration, Instant};

/// Whether a display server is named in the environment (X11 `DISPLAY` or
/// `WAYLAND_DISPLAY`).
pub fn display_available() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY"].iter().any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}

/// A decoded frame ready to show.
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
}

/// A camera move asked for with the keyboard since the last loop iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputMove {
    /// Radians to orbit about the vertical axis through the target.
    pub yaw: f32,
    /// Factor to scale the eye–target distance by (1 = no change).
    pub dolly: f32,
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

/// Orbit speed with a key held.
const ORBIT_DEGREES_PER_SECOND: f32 = 90.0;
/// Dolly speed with a key held: the distance halves (W) or doubles (S) per second.
const DOLLY_HALVINGS_PER_SECOND: f32 = 1.0;

/// An open window.
pub struct ViewerWindow {
    window: Window,
    title: String,
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

    /// Shows frames from `frames` until the window closes, the source ends or `stop` is
    /// set. Held keys are turned into camera moves given to `on_input` once per loop.
    pub fn run(
        mut self,
        frames: Receiver<ShownFrame>,
        stop: &AtomicBool,
        mut on_input: impl FnMut(InputMove),
    ) -> WindowExit {
        let mut last_tick = Instant::now();
        let mut last_title = Instant::now() - Duration::from_secs(1);
        let mut ended = false;
        loop {
            if stop.load(Ordering::Relaxed) {
                return WindowExit::Stopped;
            }
            if !self.window.is_open() || self.window.is_key_down(Key::Escape) {
                return WindowExit::Closed;
            }
            // Only the newest frame is worth showing.
            let mut newest = None;
            loop {
                match frames.try_recv() {
                    Ok(f) => newest = Some(f),
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => {
                        ended = true;
                        break;
                    }
                }
            }
            let shown = match &newest {
                Some(f) => self.window.update_with_buffer(&f.pixels, f.width as usize, f.height as usize).is_ok(),
                None => false,
            };
            if !shown {
                self.window.update();
            }
            if let Some(f) = &newest {
                if last_title.elapsed() >= Duration::from_millis(250) {
                    self.window.set_title(&format!(
                        "{} — {}x{} — {:.1} fps — {} samples/frame",
                        self.title, f.width, f.height, f.fps, f.samples_used
                    ));
                    last_title = Instant::now();
                }
            }
            if ended && newest.is_none() {
                return WindowExit::FramesEnded;
            }
            let dt = last_tick.elapsed().as_secs_f32().min(0.1);
            last_tick = Instant::now();
            let m = self.input(dt);
            if m.yaw != 0.0 || m.dolly != 1.0 {
                on_input(m);
            }
        }
    }

    fn input(&self, dt: f32) -> InputMove {
        let down = |keys: &[Key]| keys.iter().any(|k| self.window.is_key_down(*k));
        let mut yaw = 0.0;
        if down(&[Key::Left, Key::A]) {
            yaw -= ORBIT_DEGREES_PER_SECOND.to_radians() * dt;
        }
        if down(&[Key::Right, Key::D]) {
            yaw += ORBIT_DEGREES_PER_SECOND.to_radians() * dt;
        }
        let mut halvings = 0.0;
        if down(&[Key::W, Key::Up]) {
            halvings += DOLLY_HALVINGS_PER_SECOND * dt;
        }
        if down(&[Key::S, Key::Down]) {
            halvings -= DOLLY_HALVINGS_PER_SECOND * dt;
        }
        InputMove { yaw, dolly: 0.5f32.powf(halvings) }
    }
}
