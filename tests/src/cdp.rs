//! A small Chrome DevTools Protocol client for the browser tests (tests/tests/browser.rs):
//! starts Debian's headless Chromium with a private profile, connects to its page target's
//! WebSocket, and sends commands (`Page.navigate`, `Runtime.evaluate`,
//! `Input.dispatchMouseEvent`), skipping the events in between.
use anyhow::{bail, Context, Result};
use serde_json::{json, Value};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::{self, Message, WebSocket};

/// Where Debian's `chromium` package puts the browser.
pub const CHROMIUM: &str = "/usr/bin/chromium";

/// The browser (killed by its pid and its profile removed on drop) and one page of it.
pub struct Browser {
    ws: WebSocket<TcpStream>,
    next_id: u64,
    // Dropped last: the page's socket closes before the browser goes.
    _process: Process,
}

/// The Chromium process and its profile directory, from the moment it is spawned, so a
/// start that fails half-way leaves nothing running.
struct Process {
    child: Child,
    profile: PathBuf,
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.profile);
    }
}

/// The browser's executable: `$EDGEPOINT_CHROMIUM`, else [`CHROMIUM`] when present.
pub fn find_chromium() -> Option<PathBuf> {
    let p = std::env::var_os("EDGEPOINT_CHROMIUM").map(PathBuf::from).unwrap_or_else(|| PathBuf::from(CHROMIUM));
    p.is_file().then_some(p)
}

fn http_get(port: u16, path: &str) -> Result<String> {
    use std::io::{Read, Write};
    let mut s = TcpStream::connect(("127.0.0.1", port))?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    write!(s, "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n")?;
    // Chromium keeps the connection open whatever the request says: read the head, then
    // exactly Content-Length bytes.
    let mut buf = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        let n = s.read(&mut chunk)?;
        if n == 0 {
            break;
        }
        buf.extend_from_slice(&chunk[..n]);
        let text = String::from_utf8_lossy(&buf);
        if let Some((head, body)) = text.split_once("\r\n\r\n") {
            let len = head.lines().find_map(|l| l.split_once(':').filter(|(k, _)| k.eq_ignore_ascii_case("content-length")).and_then(|(_, v)| v.trim().parse::<usize>().ok()));
            if len.is_some_and(|n| body.len() >= n) {
                return Ok(body.to_string());
            }
        }
    }
    Ok(String::from_utf8_lossy(&buf).split_once("\r\n\r\n").map(|(_, b)| b.to_string()).unwrap_or_default())
}

impl Browser {
    /// Starts headless Chromium on a free DevTools port and attaches to its first page.
    pub fn start(exe: &Path) -> Result<Browser> {
        let profile = std::env::temp_dir().join(format!("edgepoint-chromium-{}-{}", std::process::id(), crate::unique_suffix()));
        std::fs::create_dir_all(&profile)?;
        let child = Command::new(exe)
            .args(["--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run"])
            .args(["--no-default-browser-check", "--disable-extensions", "--remote-debugging-port=0", "--remote-allow-origins=*"])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg("about:blank")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .with_context(|| format!("starting {}", exe.display()))?;
        let process = Process { child, profile: profile.clone() };
        // Chromium writes the port it bound into the profile's DevToolsActivePort.
        let port_file = profile.join("DevToolsActivePort");
        let deadline = Instant::now() + Duration::from_secs(30);
        let port: u16 = loop {
            if let Some(p) = std::fs::read_to_string(&port_file).ok().and_then(|t| t.lines().next().and_then(|l| l.trim().parse().ok())) {
                break p;
            }
            if Instant::now() > deadline {
                bail!("{} wrote no DevToolsActivePort within 30 s", exe.display());
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        let page_ws = loop {
            let list: Value = serde_json::from_str(&http_get(port, "/json/list").unwrap_or_default()).unwrap_or(Value::Null);
            let page = list.as_array().and_then(|l| l.iter().find(|t| t["type"] == "page")).and_then(|t| t["webSocketDebuggerUrl"].as_str());
            if let Some(u) = page {
                break u.to_string();
            }
            if Instant::now() > deadline {
                bail!("Chromium lists no page target");
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        let stream = TcpStream::connect(("127.0.0.1", port))?;
        stream.set_read_timeout(Some(Duration::from_secs(60)))?;
        let (ws, _) = tungstenite::client(page_ws.as_str(), stream).context("DevTools WebSocket handshake")?;
        let mut b = Browser { ws, next_id: 1, _process: process };
        b.call("Page.enable", json!({}))?;
        b.call("Runtime.enable", json!({}))?;
        Ok(b)
    }

    /// Sends a command and waits for its answer (events in between are skipped).
    pub fn call(&mut self, method: &str, params: Value) -> Result<Value> {
        let id = self.next_id;
        self.next_id += 1;
        self.ws.send(Message::text(json!({"id": id, "method": method, "params": params}).to_string()))?;
        loop {
            let m = self.ws.read().with_context(|| format!("waiting for the answer to {method}"))?;
            let Message::Text(t) = m else { continue };
            let v: Value = serde_json::from_str(&t)?;
            if v["id"].as_u64() == Some(id) {
                if let Some(e) = v.get("error") {
                    bail!("{method}: {e}");
                }
                return Ok(v["result"].clone());
            }
        }
    }

    pub fn navigate(&mut self, url: &str) -> Result<()> {
        let r = self.call("Page.navigate", json!({"url": url}))?;
        if let Some(e) = r.get("errorText") {
            bail!("navigating to {url}: {e}");
        }
        Ok(())
    }

    /// Evaluates `expr` in the page; its value (JSON-serialisable) or the exception.
    pub fn eval(&mut self, expr: &str) -> Result<Value> {
        let r = self.call("Runtime.evaluate", json!({"expression": expr, "returnByValue": true, "awaitPromise": true}))?;
        if let Some(e) = r.get("exceptionDetails") {
            bail!("{expr}: {e}");
        }
        Ok(r["result"]["value"].clone())
    }

    /// A mouse event at page coordinates; `buttons` as the DOM's bit mask, `modifiers` as
    /// CDP's (2 = Ctrl).
    pub fn mouse(&mut self, kind: &str, x: f64, y: f64, button: &str, buttons: u32, modifiers: u32) -> Result<()> {
        let mut p = json!({"type": kind, "x": x, "y": y, "button": button, "buttons": buttons, "modifiers": modifiers});
        if kind != "mouseMoved" {
            p["clickCount"] = json!(1);
        }
        self.call("Input.dispatchMouseEvent", p).map(|_| ())
    }

    /// Presses `button` at `from`, moves to `to` in steps, releases.
    pub fn drag(&mut self, button: &str, from: (f64, f64), to: (f64, f64), modifiers: u32, pause: Duration) -> Result<()> {
        let mask = match button {
            "left" => 1,
            "right" => 2,
            _ => 4,
        };
        self.mouse("mouseMoved", from.0, from.1, "none", 0, modifiers)?;
        self.mouse("mousePressed", from.0, from.1, button, mask, modifiers)?;
        std::thread::sleep(pause);
        for k in 1..=10 {
            let f = k as f64 / 10.0;
            self.mouse("mouseMoved", from.0 + (to.0 - from.0) * f, from.1 + (to.1 - from.1) * f, button, mask, modifiers)?;
            std::thread::sleep(Duration::from_millis(40));
        }
        self.mouse("mouseReleased", to.0, to.1, button, 0, modifiers)
    }
}
