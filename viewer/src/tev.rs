//! `--tev HOST:PORT`: mirrors every frame's linear RGB to the tev image viewer over its
//! network protocol (the one pbrt-v4's `--display-server` speaks).
//!
//! The protocol, as tev's `Ipc.h` / `Ipc.cpp` define it: TCP, one-way (tev never answers);
//! each packet is a little-endian `u32` total length (these four bytes included), a type
//! byte and the payload; strings are NUL-terminated, booleans one byte, integers and floats
//! little-endian. We send
//! - `CreateImage` (4): grab focus, image name, width, height (i32), channel count (i32),
//!   channel names — once per connection and whenever the frame size changes (tev replaces
//!   an image of the same name);
//! - `UpdateImage` v3 (6): grab focus, image name, channel count, channel names, tile x, y,
//!   width, height (i32), per-channel offset and stride (i64, in floats), then the f32
//!   values — one packet per 128 × 128 tile (pbrt-v4's tile size) carrying R, G and B
//!   interleaved (offsets 0, 1, 2, stride 3).
//!
//! The render never waits for tev: frames are handed to a background thread through a slot
//! that holds only the newest one (an older one not yet sent is dropped). When tev is not
//! there the thread warns once and tries again at most once a second; when tev goes away
//! (or restarts) a failed write drops the connection and the next frame reconnects and
//! creates the image again.
use edgepoint_proto::linear_frame::LinearFrame;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// tev's default port.
pub const DEFAULT_PORT: u16 = 14158;
/// Side of the square tiles frames are sent in.
pub const TILE: u32 = 128;
/// Packet types (tev's `IpcPacket::EType`).
pub const CREATE_IMAGE: u8 = 4;
pub const UPDATE_IMAGE_V3: u8 = 6;
/// The channels a frame is sent as.
pub const CHANNELS: [&str; 3] = ["R", "G", "B"];
/// How long to wait before trying an unreachable tev again.
const RETRY: Duration = Duration::from_secs(1);
/// A stuck tev cannot hold the sending thread longer than this per write.
const WRITE_TIMEOUT: Duration = Duration::from_secs(3);

/// Appends a `CreateImage` packet.
pub fn create_image_packet(out: &mut Vec<u8>, name: &str, width: u32, height: u32, grab_focus: bool) {
    let start = begin(out, CREATE_IMAGE);
    out.push(grab_focus as u8);
    put_str(out, name);
    for v in [width as i32, height as i32, CHANNELS.len() as i32] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for c in CHANNELS {
        put_str(out, c);
    }
    finish(out, start);
}

/// Appends an `UpdateImage` v3 packet with the tile `(x, y, w, h)` of `frame`.
pub fn update_image_packet(out: &mut Vec<u8>, name: &str, frame: &LinearFrame, values: &[f32], (x, y, w, h): (u32, u32, u32, u32)) {
    let start = begin(out, UPDATE_IMAGE_V3);
    out.push(0);
    put_str(out, name);
    out.extend_from_slice(&(CHANNELS.len() as i32).to_le_bytes());
    for c in CHANNELS {
        put_str(out, c);
    }
    for v in [x as i32, y as i32, w as i32, h as i32] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for c in 0..CHANNELS.len() as i64 {
        out.extend_from_slice(&c.to_le_bytes());
    }
    for _ in CHANNELS {
        out.extend_from_slice(&(CHANNELS.len() as i64).to_le_bytes());
    }
    let fw = frame.width as usize;
    for row in y as usize..(y + h) as usize {
        let from = (row * fw + x as usize) * 3;
        for v in &values[from..from + w as usize * 3] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    finish(out, start);
}

fn begin(out: &mut Vec<u8>, kind: u8) -> usize {
    let start = out.len();
    out.extend_from_slice(&[0, 0, 0, 0, kind]);
    start
}

fn finish(out: &mut [u8], start: usize) {
    let len = (out.len() - start) as u32;
    out[start..start + 4].copy_from_slice(&len.to_le_bytes());
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    // A NUL inside would end the string early on tev's side.
    out.extend(s.bytes().filter(|&b| b != 0));
    out.push(0);
}

/// The tiles a frame is sent in, row by row.
pub fn tiles(width: u32, height: u32) -> impl Iterator<Item = (u32, u32, u32, u32)> {
    (0..height.div_ceil(TILE)).flat_map(move |ty| {
        (0..width.div_ceil(TILE)).map(move |tx| {
            let (x, y) = (tx * TILE, ty * TILE);
            (x, y, TILE.min(width - x), TILE.min(height - y))
        })
    })
}

/// Every packet of one frame: a `CreateImage` first when `create` is set, then its tiles.
pub fn frame_packets(name: &str, frame: &LinearFrame, create: bool, grab_focus: bool) -> Vec<u8> {
    let values = frame.to_f32();
    let mut out = Vec::with_capacity(values.len() * 4 + 4096);
    if create {
        create_image_packet(&mut out, name, frame.width, frame.height, grab_focus);
    }
    for t in tiles(frame.width, frame.height) {
        update_image_packet(&mut out, name, frame, &values, t);
    }
    out
}

/// The newest frame not yet sent, and whether the mirror is closing.
struct Slot {
    frame: Option<Arc<LinearFrame>>,
    closing: bool,
}

/// A running mirror to one tev instance.
pub struct TevMirror {
    shared: Arc<(Mutex<Slot>, Condvar)>,
    thread: Option<JoinHandle<()>>,
}

impl TevMirror {
    /// Starts mirroring to `addr` (`HOST:PORT`) under the image name `name`. Nothing is
    /// connected yet: the first frame connects.
    pub fn start(addr: &str, name: &str) -> Self {
        let shared = Arc::new((Mutex::new(Slot { frame: None, closing: false }), Condvar::new()));
        let (s, addr, name) = (shared.clone(), addr.to_string(), name.to_string());
        let thread = std::thread::Builder::new()
            .name("tev".into())
            .spawn(move || Sender::new(addr, name).run(&s))
            .expect("spawning the tev thread");
        TevMirror { shared, thread: Some(thread) }
    }

    /// Hands a frame over; never blocks on the network (an older frame not yet sent is
    /// replaced).
    pub fn offer(&self, frame: Arc<LinearFrame>) {
        let (m, cv) = &*self.shared;
        m.lock().unwrap_or_else(|e| e.into_inner()).frame = Some(frame);
        cv.notify_one();
    }
}

impl Drop for TevMirror {
    /// Sends the frame still waiting (if tev is there), then ends the thread.
    fn drop(&mut self) {
        let (m, cv) = &*self.shared;
        m.lock().unwrap_or_else(|e| e.into_inner()).closing = true;
        cv.notify_one();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The background thread's connection state.
struct Sender {
    addr: String,
    name: String,
    stream: Option<TcpStream>,
    /// The size tev has an image of on the current connection.
    created: Option<(u32, u32)>,
    last_attempt: Option<Instant>,
    warned: bool,
    focused: bool,
}

impl Sender {
    fn new(addr: String, name: String) -> Self {
        Sender { addr, name, stream: None, created: None, last_attempt: None, warned: false, focused: false }
    }

    fn run(mut self, shared: &(Mutex<Slot>, Condvar)) {
        let (m, cv) = shared;
        loop {
            let (frame, closing) = {
                let mut slot = m.lock().unwrap_or_else(|e| e.into_inner());
                while slot.frame.is_none() && !slot.closing {
                    slot = cv.wait(slot).unwrap_or_else(|e| e.into_inner());
                }
                (slot.frame.take(), slot.closing)
            };
            if let Some(f) = frame {
                self.send(&f);
            }
            if closing {
                return;
            }
        }
    }

    fn connect(&mut self) -> bool {
        if self.stream.is_some() {
            return true;
        }
        if self.last_attempt.is_some_and(|t| t.elapsed() < RETRY) {
            return false;
        }
        self.last_attempt = Some(Instant::now());
        match open(&self.addr) {
            Ok(s) => {
                tracing::info!("tev: connected to {}; mirroring frames as image \"{}\"", self.addr, self.name);
                self.stream = Some(s);
                self.created = None;
                self.warned = false;
                true
            }
            Err(e) => {
                if !self.warned {
                    tracing::warn!("tev: cannot reach {}: {e}; frames are not mirrored until it answers (retrying every second)", self.addr);
                    self.warned = true;
                }
                false
            }
        }
    }

    fn send(&mut self, frame: &LinearFrame) {
        if !self.connect() {
            return;
        }
        let size = (frame.width, frame.height);
        let create = self.created != Some(size);
        let bytes = frame_packets(&self.name, frame, create, !self.focused);
        let stream = self.stream.as_mut().expect("connected above");
        match stream.write_all(&bytes) {
            Ok(()) => {
                self.created = Some(size);
                self.focused = true;
            }
            Err(e) => {
                tracing::warn!("tev: connection to {} lost ({e}); reconnecting with the next frame", self.addr);
                self.stream = None;
                self.created = None;
                // Reconnect at once (tev may have restarted), then at most once a second.
                self.last_attempt = None;
                self.warned = true;
            }
        }
    }
}

fn open(addr: &str) -> std::io::Result<TcpStream> {
    let addrs: Vec<SocketAddr> = addr.to_socket_addrs()?.collect();
    let mut last = std::io::Error::new(std::io::ErrorKind::NotFound, format!("{addr} resolves to no address"));
    for a in addrs {
        match TcpStream::connect_timeout(&a, Duration::from_secs(1)) {
            Ok(s) => {
                s.set_write_timeout(Some(WRITE_TIMEOUT))?;
                s.set_nodelay(true)?;
                return Ok(s);
            }
            Err(e) => last = e,
        }
    }
    Err(last)
}

/// Checks a `--tev` value: `HOST:PORT` (a bare host gets tev's default port).
pub fn parse_addr(s: &str) -> Result<String, String> {
    let s = s.trim();
    if s.is_empty() {
        return Err("expected HOST:PORT (tev listens on 127.0.0.1:14158 by default)".into());
    }
    match s.rsplit_once(':') {
        Some((host, port)) if !host.is_empty() && !host.ends_with(':') => {
            port.parse::<u16>().map_err(|_| format!("'{port}' is not a port number"))?;
            Ok(s.to_string())
        }
        _ => Ok(format!("{s}:{DEFAULT_PORT}")),
    }
}

/// A packet as tev reads it (the types sent here), for tests and tools that stand in for tev.
#[derive(Debug, Clone, PartialEq)]
pub enum Packet {
    CreateImage { grab_focus: bool, name: String, width: i32, height: i32, channels: Vec<String> },
    UpdateImage {
        grab_focus: bool,
        name: String,
        channels: Vec<String>,
        x: i32,
        y: i32,
        width: i32,
        height: i32,
        /// Per channel, the tile's values row by row (offsets and strides applied).
        values: Vec<Vec<f32>>,
    },
    Other { kind: u8 },
}

/// The largest packet [`read_packet`] accepts (a 4096² RGB tile is 201 MB; ours are 197 KB).
pub const MAX_PACKET: u32 = 1 << 28;

/// Reads one packet; `Ok(None)` at a clean end of the stream. Every count is checked
/// against the bytes of the packet.
pub fn read_packet(r: &mut impl Read) -> std::io::Result<Option<Packet>> {
    let mut len = [0u8; 4];
    match r.read_exact(&mut len) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
        Err(e) => return Err(e),
    }
    let len = u32::from_le_bytes(len);
    if !(5..=MAX_PACKET).contains(&len) {
        return Err(bad(format!("packet length {len}")));
    }
    let mut body = Vec::new();
    r.take(len as u64 - 4).read_to_end(&mut body)?;
    if body.len() != len as usize - 4 {
        return Err(bad("packet cut short".into()));
    }
    parse_body(&body).map(Some)
}

fn bad(msg: String) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, msg)
}

struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> std::io::Result<&[u8]> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len()).ok_or_else(|| bad("packet too short".into()))?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u8(&mut self) -> std::io::Result<u8> {
        Ok(self.take(1)?[0])
    }
    fn i32(&mut self) -> std::io::Result<i32> {
        Ok(i32::from_le_bytes(self.take(4)?.try_into().expect("4 bytes")))
    }
    fn i64(&mut self) -> std::io::Result<i64> {
        Ok(i64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    fn string(&mut self) -> std::io::Result<String> {
        let rest = &self.b[self.at..];
        let n = rest.iter().position(|&c| c == 0).ok_or_else(|| bad("unterminated string".into()))?;
        let s = String::from_utf8_lossy(&rest[..n]).into_owned();
        self.at += n + 1;
        Ok(s)
    }
    fn count(&mut self) -> std::io::Result<usize> {
        let n = self.i32()?;
        // Each counted item takes at least one byte of what is left.
        if n < 0 || n as usize > self.b.len() - self.at {
            return Err(bad(format!("count {n}")));
        }
        Ok(n as usize)
    }
}

fn parse_body(b: &[u8]) -> std::io::Result<Packet> {
    let mut c = Cursor { b, at: 0 };
    let kind = c.u8()?;
    match kind {
        CREATE_IMAGE => {
            let grab_focus = c.u8()? == 1;
            let name = c.string()?;
            let (width, height) = (c.i32()?, c.i32()?);
            let n = c.count()?;
            let channels = (0..n).map(|_| c.string()).collect::<Result<_, _>>()?;
            Ok(Packet::CreateImage { grab_focus, name, width, height, channels })
        }
        UPDATE_IMAGE_V3 => {
            let grab_focus = c.u8()? == 1;
            let name = c.string()?;
            let n = c.count()?;
            let channels: Vec<String> = (0..n).map(|_| c.string()).collect::<Result<_, _>>()?;
            let (x, y, width, height) = (c.i32()?, c.i32()?, c.i32()?, c.i32()?);
            let offsets = (0..n).map(|_| c.i64()).collect::<Result<Vec<_>, _>>()?;
            let strides = (0..n).map(|_| c.i64()).collect::<Result<Vec<_>, _>>()?;
            let data = &b[c.at..];
            let floats = data.len() / 4;
            let pixels = (width.max(0) as usize).saturating_mul(height.max(0) as usize);
            let mut values = Vec::with_capacity(n);
            for (&o, &s) in offsets.iter().zip(&strides) {
                let last = (pixels as i64 - 1).checked_mul(s).and_then(|v| v.checked_add(o));
                if pixels == 0 || o < 0 || s < 0 || last.is_none_or(|l| l as u64 >= floats as u64) {
                    return Err(bad(format!("tile of {pixels} pixels, offset {o}, stride {s} overruns {floats} values")));
                }
                let at = |i: usize| {
                    let k = (o as usize + i * s as usize) * 4;
                    f32::from_le_bytes(data[k..k + 4].try_into().expect("4 bytes"))
                };
                values.push((0..pixels).map(at).collect());
            }
            Ok(Packet::UpdateImage { grab_focus, name, channels, x, y, width, height, values })
        }
        kind => Ok(Packet::Other { kind }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use std::net::TcpListener;

    fn frame(w: u32, h: u32, k: f32) -> LinearFrame {
        let px: Vec<Vec3> = (0..w * h).map(|i| Vec3::new(i as f32 * 0.01 * k, 2.5 * k, (i % 7) as f32 * 10.0)).collect();
        LinearFrame::from_linear(&px, w, h)
    }

    /// Reassembles the image tev would hold from update packets.
    fn apply(img: &mut [f32], width: i32, p: &Packet) {
        let Packet::UpdateImage { x, y, width: tw, height: th, values, channels, .. } = p else { panic!("{p:?}") };
        assert_eq!(channels, &CHANNELS);
        for ty in 0..*th {
            for tx in 0..*tw {
                for c in 0..3 {
                    img[(((y + ty) * width + x + tx) * 3 + c) as usize] = values[c as usize][(ty * tw + tx) as usize];
                }
            }
        }
    }

    /// Reads packets until the image named `name` is fully updated; returns whether a
    /// CreateImage came first, the size it announced and the image.
    fn receive_frame(s: &mut TcpStream, w: i32, h: i32) -> (bool, Vec<f32>) {
        let mut img = vec![f32::NAN; (w * h * 3) as usize];
        let mut created = false;
        let mut covered = 0;
        while covered < w * h {
            match read_packet(s).unwrap().expect("a packet") {
                Packet::CreateImage { name, width, height, channels, .. } => {
                    assert_eq!((name.as_str(), width, height), ("edgepoint test", w, h));
                    assert_eq!(channels, CHANNELS);
                    created = true;
                }
                p @ Packet::UpdateImage { .. } => {
                    if let Packet::UpdateImage { name, width, height, .. } = &p {
                        assert_eq!(name, "edgepoint test");
                        covered += width * height;
                    }
                    apply(&mut img, w, &p);
                }
                p => panic!("unexpected {p:?}"),
            }
        }
        (created, img)
    }

    #[test]
    fn a_fake_tev_receives_the_frames_linear_values_and_survives_a_restart() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let mirror = TevMirror::start(&addr, "edgepoint test");
        let (w, h) = (300, 130); // tiles of 128, 128, 44 by 128, 2
        let f1 = Arc::new(frame(w, h, 1.0));
        mirror.offer(f1.clone());
        let (mut s, _) = listener.accept().unwrap();
        let (created, img) = receive_frame(&mut s, w as i32, h as i32);
        assert!(created);
        assert_eq!(img, f1.to_f32(), "tev holds the frame's linear values");
        // The next frame of the same size updates without creating the image again.
        let f2 = Arc::new(frame(w, h, 3.0));
        mirror.offer(f2.clone());
        let (created, img) = receive_frame(&mut s, w as i32, h as i32);
        assert!(!created);
        assert_eq!(img, f2.to_f32());
        // tev restarts: the connection drops; a later frame reconnects and creates the
        // image again (frames offered while the write fails are lost, as they should be).
        drop(s);
        let deadline = Instant::now() + Duration::from_secs(20);
        listener.set_nonblocking(true).unwrap();
        let mut s = loop {
            mirror.offer(f2.clone());
            if let Ok((s, _)) = listener.accept() {
                break s;
            }
            assert!(Instant::now() < deadline, "the mirror never reconnected");
            std::thread::sleep(Duration::from_millis(20));
        };
        s.set_nonblocking(false).unwrap();
        let (created, img) = receive_frame(&mut s, w as i32, h as i32);
        assert!(created, "a new connection creates the image first");
        assert_eq!(img, f2.to_f32());
        drop(mirror);
    }

    #[test]
    fn an_absent_tev_never_blocks_the_frames() {
        // A port nobody listens on: bind one, note it, close it.
        let port = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let mirror = TevMirror::start(&format!("127.0.0.1:{port}"), "edgepoint test");
        let f = Arc::new(frame(64, 64, 1.0));
        for _ in 0..100 {
            mirror.offer(f.clone());
        }
        drop(mirror);
    }

    #[test]
    fn packets_are_checked_when_read() {
        let f = frame(5, 3, 1.0);
        let bytes = frame_packets("n", &f, true, true);
        let mut r = &bytes[..];
        assert!(matches!(read_packet(&mut r).unwrap(), Some(Packet::CreateImage { grab_focus: true, .. })));
        assert!(matches!(read_packet(&mut r).unwrap(), Some(Packet::UpdateImage { width: 5, height: 3, .. })));
        assert_eq!(read_packet(&mut r).unwrap(), None);
        // Every truncation and corruption is an error or a packet, never a panic.
        for cut in 0..bytes.len() {
            let _ = read_packet(&mut &bytes[..cut]);
        }
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x5a;
            let mut r = &b[..];
            while let Ok(Some(_)) = read_packet(&mut r) {}
        }
        assert_eq!(parse_addr("localhost").unwrap(), "localhost:14158");
        assert_eq!(parse_addr("127.0.0.1:9000").unwrap(), "127.0.0.1:9000");
        assert!(parse_addr("host:port").is_err());
        assert!(parse_addr("").is_err());
    }
}
