//! Garbage on every port: random bytes, truncated and malformed HTTP/2, HTTP/1 where HTTP/2
//! is expected, oversized frame headers, and idle connections that never speak — sent to the
//! server's gRPC and metrics ports and a worker's gRPC and metrics ports while a session
//! runs. Afterwards the session still receives frames, a new session starts and shades,
//! and every metrics endpoint still answers.
use edgepoint_tests::{attack, cluster_with, frames_until, garbage, scrape, start_builtin};
use edgepoint_viewer::client::SessionClient;
use std::time::{Duration, Instant};

const WAIT: Duration = Duration::from_secs(30);
const PREFACE: &[u8] = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n";

/// An HTTP/2 frame header: 24-bit length, type, flags, stream id.
fn frame_header(len: u32, kind: u8, flags: u8, stream: u32) -> Vec<u8> {
    let mut h = len.to_be_bytes()[1..].to_vec();
    h.extend([kind, flags]);
    h.extend(stream.to_be_bytes());
    h
}

/// Every hostile payload, by name.
fn payloads() -> Vec<(&'static str, Vec<u8>)> {
    let settings_empty = frame_header(0, 0x4, 0, 0);
    let mut truncated_settings = PREFACE.to_vec();
    truncated_settings.extend(frame_header(18, 0x4, 0, 0));
    truncated_settings.extend([0, 3, 0, 0]); // 4 of the promised 18 bytes
    let mut truncated_headers = PREFACE.to_vec();
    truncated_headers.extend(&settings_empty);
    truncated_headers.extend(frame_header(200, 0x1, 0x4, 1));
    truncated_headers.extend(garbage(20, 7));
    let mut bad_hpack = PREFACE.to_vec();
    bad_hpack.extend(&settings_empty);
    bad_hpack.extend(frame_header(16, 0x1, 0x5, 1));
    bad_hpack.extend([0xff; 16]);
    let mut huge_data = PREFACE.to_vec();
    huge_data.extend(&settings_empty);
    huge_data.extend(frame_header(0xff_ffff, 0x0, 0, 1));
    huge_data.extend(garbage(1000, 9));
    let mut grpc_no_body = PREFACE.to_vec();
    grpc_no_body.extend(&settings_empty);
    // A HEADERS frame whose HPACK is a single literal that claims 100 bytes and has 3.
    grpc_no_body.extend(frame_header(5, 0x1, 0x4, 1));
    grpc_no_body.extend([0x40, 0x64, b'a', b'b', b'c']);
    vec![
        ("random bytes", garbage(4096, 1)),
        ("truncated preface", PREFACE[..10].to_vec()),
        ("truncated SETTINGS", truncated_settings),
        ("truncated HEADERS", truncated_headers),
        ("malformed HPACK", bad_hpack),
        ("oversized DATA frame", huge_data),
        ("truncated HPACK literal", grpc_no_body),
        ("HTTP/1 request", b"GET / HTTP/1.1\r\nHost: x\r\n\r\n".to_vec()),
        ("HTTP/1 with a huge header", [b"GET /metrics HTTP/1.1\r\nX: ".to_vec(), vec![b'a'; 200_000], b"\r\n\r\n".to_vec()].concat()),
        ("nothing", Vec::new()),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_on_every_port_leaves_everything_serving() {
    let mut cl = tokio::task::block_in_place(|| cluster_with(1, |o| o.metrics = true)).expect("cluster starts");
    let (mut c, _) = SessionClient::connect(&cl.server_url(), start_builtin("cornell", 64, 48)).await.unwrap();
    let mut last = Instant::now();
    frames_until(&mut c, &mut last, WAIT, |_, s| s.frames >= 5).await.unwrap();

    let ports = [
        ("server gRPC", cl.server_addr()),
        ("server metrics", cl.server_metrics_addr().unwrap()),
        ("worker gRPC", cl.worker_addrs()[0]),
        ("worker metrics", cl.worker_metrics_addr(0).unwrap()),
    ];
    // Idle connections that never send a byte, held open through everything below.
    let mut idle = Vec::new();
    for (_, addr) in &ports {
        for _ in 0..8 {
            idle.push(tokio::net::TcpStream::connect(addr).await.unwrap());
        }
    }
    for (port, addr) in &ports {
        let mut attacks = tokio::task::JoinSet::new();
        for (name, payload) in payloads() {
            let addr = *addr;
            attacks.spawn(async move {
                attack(addr, &payload).await;
                name
            });
        }
        while let Some(r) = attacks.join_next().await {
            r.unwrap_or_else(|e| panic!("attack on {port} panicked: {e}"));
        }
        // The session is unaffected between attacks on different ports.
        frames_until(&mut c, &mut last, WAIT, |_, s| s.frames >= 3).await.unwrap_or_else(|e| panic!("after garbage on the {port} port: {e:#}"));
    }

    assert!(cl.worker_alive(0), "the worker survived");
    let seen = frames_until(&mut c, &mut last, WAIT, |_, s| s.frames >= 10 && s.samples > 0).await.expect("the session goes on");
    assert!(seen.samples > 0, "and the worker still shades for it");
    let (mut fresh, _) = SessionClient::connect(&cl.server_url(), start_builtin("cornell-point", 48, 32)).await.expect("a new session starts");
    let mut t = Instant::now();
    frames_until(&mut fresh, &mut t, WAIT, |_, s| s.samples > 0).await.expect("and shades");
    for (port, addr) in &ports[1..] {
        if port.ends_with("metrics") {
            scrape(*addr).await.unwrap_or_else(|e| panic!("{port} stopped answering: {e:#}"));
        }
    }
    drop(idle);
}

/// Issue 12 item 10: a connection that never speaks, or stops halfway through the HTTP/2
/// preface, is closed by the server and the worker after their handshake time instead of
/// being held forever. (30 s is only the liveness guard; they close after 10 s.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_and_half_open_connections_are_closed() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let cl = tokio::task::block_in_place(|| cluster_with(1, |_| {})).expect("cluster starts");
    let mut pending = Vec::new();
    for (port, addr) in [("server", cl.server_addr()), ("worker", cl.worker_addrs()[0])] {
        let silent = tokio::net::TcpStream::connect(addr).await.unwrap();
        let mut half = tokio::net::TcpStream::connect(addr).await.unwrap();
        half.write_all(&PREFACE[..12]).await.unwrap();
        pending.push((port, "silent", silent));
        pending.push((port, "half a preface", half));
    }
    let t0 = Instant::now();
    for (port, what, mut s) in pending {
        let mut buf = [0u8; 256];
        let closed = tokio::time::timeout(Duration::from_secs(30), async {
            loop {
                match s.read(&mut buf).await {
                    // The server's own SETTINGS frame may come first; then the close.
                    Ok(n) if n > 0 => continue,
                    _ => break,
                }
            }
        })
        .await;
        assert!(closed.is_ok(), "the {port} kept a {what} connection open for 30 s");
    }
    eprintln!("closed after {:.1} s", t0.elapsed().as_secs_f64());
}
