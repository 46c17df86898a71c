//! Remote viewing, safely: bearer tokens (missing or wrong ones refused with UNAUTHENTICATED),
//! TLS on the viewer port and between server and workers (certificates made here by a test
//! CA), the refusal to serve a non-loopback address unprotected, and the limits — sessions
//! per server, frame size, message size, time to `start` — each refused with a clear status
//! while the server goes on serving.
use edgepoint_proto as pb;
use edgepoint_tests::{attack, cluster_with, frames_until, garbage, metric, scrape, start_builtin, Spawned};
use edgepoint_viewer::client::{ConnectOptions, SessionClient};
use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, DnType, IsCa, KeyPair};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tonic::Code;

const WAIT: Duration = Duration::from_secs(30);
const TOKEN: &str = "test-token-5d41402abc4b2a76b9719d911017c592";

/// A scratch directory removed on drop.
struct Scratch(PathBuf);
impl Scratch {
    fn new(tag: &str) -> Scratch {
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let d = std::env::temp_dir().join(format!("edgepoint-secure-{tag}-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        Scratch(d)
    }
    fn write(&self, name: &str, data: impl AsRef<[u8]>) -> PathBuf {
        let p = self.0.join(name);
        std::fs::write(&p, data).unwrap();
        p
    }
    fn path(&self, name: &str) -> String {
        self.0.join(name).display().to_string()
    }
}
impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A test CA and a certificate it issued for `localhost` and 127.0.0.1: ca.pem, cert.pem,
/// key.pem in `dir`; and a client certificate it issued for the renderer (mutual TLS):
/// client.pem, client-key.pem.
fn pki(dir: &Scratch) {
    let mut ca = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    ca.distinguished_name.push(DnType::CommonName, "edgepoint test CA");
    let ca = CertifiedIssuer::self_signed(ca, KeyPair::generate().unwrap()).unwrap();
    let key = KeyPair::generate().unwrap();
    let leaf = CertificateParams::new(vec!["localhost".to_string(), "127.0.0.1".to_string()]).unwrap().signed_by(&key, &ca).unwrap();
    dir.write("ca.pem", ca.pem());
    dir.write("cert.pem", leaf.pem());
    dir.write("key.pem", key.serialize_pem());
    let ckey = KeyPair::generate().unwrap();
    let client = CertificateParams::new(vec!["edgepoint-renderer".to_string()]).unwrap().signed_by(&ckey, &ca).unwrap();
    dir.write("client.pem", client.pem());
    dir.write("client-key.pem", ckey.serialize_pem());
}

fn with_token(token: &str) -> ConnectOptions {
    ConnectOptions { token: Some(token.to_string()), ..Default::default() }
}

async fn refused(url: &str, start: pb::Start, opts: &ConnectOptions) -> (Code, String) {
    match SessionClient::connect_with(url, start, opts).await {
        Ok(_) => panic!("the session was accepted"),
        Err(e) => {
            println!("refused: {e}");
            (e.code().unwrap_or(Code::Unknown), e.to_string())
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_and_limits_are_enforced_with_clear_statuses() {
    let dir = Scratch::new("limits");
    let tokens = dir.write("tokens", format!("# viewers\n{TOKEN}\n"));
    let cl = tokio::task::block_in_place(|| {
        cluster_with(1, |o| {
            o.metrics = true;
            o.server_args = [
                "--token-file",
                &tokens.display().to_string(),
                "--max-sessions",
                "2",
                "--max-frame-pixels",
                "5000",
                "--max-message-mib",
                "1",
                "--start-timeout-secs",
                "1",
            ]
            .map(String::from)
            .to_vec();
        })
    })
    .expect("cluster starts");
    let url = cl.server_url();
    let small = || start_builtin("cornell", 64, 48);

    let (code, msg) = refused(&url, small(), &ConnectOptions::default()).await;
    assert_eq!(code, Code::Unauthenticated, "{msg}");
    assert!(msg.contains("--token-file"), "the refusal says what to do: {msg}");
    let (code, msg) = refused(&url, small(), &with_token("wrong-token-0000000000000000")).await;
    assert_eq!(code, Code::Unauthenticated, "{msg}");
    assert!(msg.contains("invalid bearer token"), "{msg}");

    let (mut a, _) = SessionClient::connect_with(&url, small(), &with_token(TOKEN)).await.expect("the right token is accepted");
    let mut last = Instant::now();
    frames_until(&mut a, &mut last, WAIT, |_, s| s.samples > 0).await.unwrap();

    let (code, msg) = refused(&url, start_builtin("cornell", 100, 100), &with_token(TOKEN)).await;
    assert_eq!(code, Code::ResourceExhausted, "{msg}");
    assert!(msg.contains("--max-frame-pixels") && msg.contains("10000"), "{msg}");

    // A scene file larger than the 1 MiB message limit.
    let mut big = small();
    big.scene = Some(pb::files_source(vec![("big.ply".into(), vec![b'x'; 2 << 20])]));
    let (code, msg) = refused(&url, big, &with_token(TOKEN)).await;
    assert!(matches!(code, Code::OutOfRange | Code::ResourceExhausted), "{code:?}: {msg}");
    assert!(msg.to_lowercase().contains("too large") || msg.contains("limit"), "{msg}");

    // A stream that never sends `start` is ended after --start-timeout-secs.
    let channel = tonic::transport::Endpoint::from_shared(url.clone()).unwrap().connect().await.unwrap();
    let mut raw = pb::renderer_client::RendererClient::new(channel);
    let mut req = tonic::Request::new(tokio_stream::pending::<pb::ViewerMsg>());
    req.metadata_mut().insert("authorization", format!("Bearer {TOKEN}").parse().unwrap());
    let status = tokio::time::timeout(WAIT, raw.session(req)).await.expect("answered").expect_err("refused");
    assert_eq!(status.code(), Code::DeadlineExceeded, "{status:?}");
    assert!(status.message().contains("start"), "{}", status.message());

    let (mut b, _) = SessionClient::connect_with(&url, small(), &with_token(TOKEN)).await.expect("a second session fits");
    let (code, msg) = refused(&url, small(), &with_token(TOKEN)).await;
    assert_eq!(code, Code::ResourceExhausted, "{msg}");
    assert!(msg.contains("--max-sessions"), "{msg}");

    // Everything refused, nothing broken: both sessions still get frames.
    frames_until(&mut a, &mut last, WAIT, |_, s| s.frames >= 5).await.unwrap();
    let mut t = Instant::now();
    frames_until(&mut b, &mut t, WAIT, |_, s| s.frames >= 5).await.unwrap();
    let m = scrape(cl.server_metrics_addr().unwrap()).await.unwrap();
    assert_eq!(metric(&m, "edgepoint_server_sessions_refused_total{reason=\"unauthenticated\"}"), Some(2.0), "{m}");
    assert!(metric(&m, "edgepoint_server_sessions_refused_total{reason=\"limit\"}").unwrap() >= 2.0, "{m}");
    assert_eq!(metric(&m, "edgepoint_server_sessions"), Some(2.0));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_protects_the_viewer_port() {
    let dir = Scratch::new("tls");
    pki(&dir);
    let other = Scratch::new("other-ca");
    pki(&other);
    let tokens = dir.write("tokens", TOKEN);
    let cl = tokio::task::block_in_place(|| {
        cluster_with(1, |o| {
            o.server_args = vec![
                "--tls-cert".into(),
                dir.path("cert.pem"),
                "--tls-key".into(),
                dir.path("key.pem"),
                "--token-file".into(),
                tokens.display().to_string(),
            ];
        })
    })
    .expect("cluster starts");
    let port = cl.server_addr().port();
    let https = format!("https://localhost:{port}");
    let good = ConnectOptions { token: Some(TOKEN.into()), tls_ca: Some(dir.0.join("ca.pem")), ..Default::default() };
    let (mut c, _) = SessionClient::connect_with(&https, start_builtin("cornell", 64, 48), &good).await.expect("TLS session");
    let mut last = Instant::now();
    frames_until(&mut c, &mut last, WAIT, |_, s| s.samples > 0).await.unwrap();

    // Plaintext to the TLS port, and TLS with a CA that did not issue the certificate.
    let plain = SessionClient::connect_with(&format!("http://127.0.0.1:{port}"), start_builtin("cornell", 64, 48), &with_token(TOKEN)).await;
    println!("plaintext to TLS: {:?}", plain.as_ref().err());
    assert!(plain.is_err(), "plaintext must not reach a TLS server");
    let wrong_ca = ConnectOptions { tls_ca: Some(other.0.join("ca.pem")), ..good.clone() };
    let e = SessionClient::connect_with(&https, start_builtin("cornell", 64, 48), &wrong_ca).await.expect_err("an unknown CA is refused");
    println!("unknown CA: {e}");
    assert!(e.to_string().to_lowercase().contains("certificate") || e.to_string().contains("cannot connect"), "{e}");

    // Garbage and a truncated TLS ClientHello on the TLS port change nothing.
    let addr = cl.server_addr();
    attack(addr, &garbage(4096, 3)).await;
    attack(addr, &[0x16, 0x03, 0x01, 0x02, 0x00, 0x01, 0x00, 0x01, 0xfc, 0x03, 0x03]).await;
    attack(addr, b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n").await;

    // The viewer binary, as a user runs it against a remote server.
    let out = dir.0.join("frames");
    let viewer = edgepoint_viewer::local::find_binary("edgepoint-viewer").unwrap();
    let ca = dir.path("ca.pem");
    let tok = tokens.display().to_string();
    let out_arg = out.display().to_string();
    let status = tokio::task::block_in_place(|| {
        std::process::Command::new(viewer)
            .args(["--server", &https, "--tls-ca", &ca, "--token-file", &tok, "--headless", "--quiet", "--frames", "3"])
            .args(["--width", "48", "--height", "32", "--out", &out_arg])
            .env("RUST_LOG", "warn")
            .status()
            .unwrap()
    });
    assert!(status.success(), "viewer over TLS: {status}");
    assert!(Path::new(&out).join("stats.jsonl").exists());
    frames_until(&mut c, &mut last, WAIT, |_, s| s.frames >= 3).await.expect("the first session went on");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_between_the_server_and_its_workers() {
    let dir = Scratch::new("worker-tls");
    pki(&dir);
    let (cert, key, ca) = (dir.path("cert.pem"), dir.path("key.pem"), dir.path("ca.pem"));
    let worker = tokio::task::block_in_place(|| {
        Spawned::start("edgepoint-worker", &["--listen", "127.0.0.1:0", "--threads", "1", "--tls-cert", &cert, "--tls-key", &key])
    })
    .unwrap();
    let waddr = worker.addr.unwrap_or_else(|| panic!("worker did not start: {}", worker.stderr()));
    let wurl = format!("https://localhost:{}", waddr.port());
    let server = tokio::task::block_in_place(|| {
        Spawned::start("edgepoint-server", &["--listen", "127.0.0.1:0", "--worker", &wurl, "--worker-tls-ca", &ca])
    })
    .unwrap();
    let saddr = server.addr.unwrap_or_else(|| panic!("server did not start: {}", server.stderr()));
    let (mut c, _) = SessionClient::connect(&format!("http://{saddr}"), start_builtin("cornell", 64, 48)).await.expect("session");
    let mut last = Instant::now();
    let seen = frames_until(&mut c, &mut last, WAIT, |f, s| f.live_workers == 1 && s.samples > 0).await.expect("the TLS worker shades");
    assert!(seen.samples > 0);
}

/// Issue 12 item 5: a worker with tokens refuses calls without one, and a renderer given the
/// token shades through it; a worker requiring mutual TLS serves only a renderer presenting
/// a certificate of its CA, even on a non-loopback address.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn workers_authenticate_their_renderer() {
    use edgepoint_proto::shader_worker_client::ShaderWorkerClient;
    let dir = Scratch::new("worker-auth");
    pki(&dir);
    let tokens = dir.write("worker-tokens", format!("# renderers\n{TOKEN}\n"));
    let tokens = tokens.display().to_string();
    let worker = tokio::task::block_in_place(|| Spawned::start("edgepoint-worker", &["--listen", "127.0.0.1:0", "--threads", "1", "--token-file", &tokens])).unwrap();
    let waddr = worker.addr.unwrap_or_else(|| panic!("worker did not start: {}", worker.stderr()));
    let mut anonymous = ShaderWorkerClient::connect(format!("http://{waddr}")).await.unwrap();
    let e = anonymous.info(pb::InfoRequest {}).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated);
    assert!(e.message().contains("--worker-token-file"), "{}", e.message());
    let e = anonymous.load_scene(pb::LoadSceneRequest { source: Some(pb::builtin_source("cornell")), expect_hash: String::new() }).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "no scene loads without the token");
    let server = tokio::task::block_in_place(|| {
        Spawned::start("edgepoint-server", &["--listen", "127.0.0.1:0", "--worker", &format!("http://{waddr}"), "--worker-token-file", &tokens])
    })
    .unwrap();
    let saddr = server.addr.unwrap_or_else(|| panic!("server did not start: {}", server.stderr()));
    let (mut c, _) = SessionClient::connect(&format!("http://{saddr}"), start_builtin("cornell", 64, 48)).await.expect("session");
    let mut last = Instant::now();
    frames_until(&mut c, &mut last, WAIT, |_, s| s.samples > 0).await.expect("the renderer with the token gets samples");

    // Mutual TLS on all addresses.
    let (cert, key, ca) = (dir.path("cert.pem"), dir.path("key.pem"), dir.path("ca.pem"));
    let mtls = tokio::task::block_in_place(|| {
        Spawned::start("edgepoint-worker", &["--listen", "0.0.0.0:0", "--threads", "1", "--tls-cert", &cert, "--tls-key", &key, "--tls-client-ca", &ca])
    })
    .unwrap();
    let maddr = mtls.addr.unwrap_or_else(|| panic!("an mTLS worker may listen beyond loopback: {}", mtls.stderr()));
    let murl = format!("https://localhost:{}", maddr.port());
    let no_cert = edgepoint_proto::net::client_tls(Some(Path::new(&ca)), None).unwrap();
    let channel = tonic::transport::Endpoint::from_shared(murl.clone()).unwrap().tls_config(no_cert).unwrap();
    let refused = match channel.connect().await {
        Ok(ch) => ShaderWorkerClient::new(ch).info(pb::InfoRequest {}).await.is_err(),
        Err(_) => true,
    };
    assert!(refused, "a client without a certificate is refused");
    let server = tokio::task::block_in_place(|| {
        Spawned::start(
            "edgepoint-server",
            &[
                "--listen", "127.0.0.1:0", "--worker", &murl, "--worker-tls-ca", &ca,
                "--worker-tls-cert", &dir.path("client.pem"), "--worker-tls-key", &dir.path("client-key.pem"),
            ],
        )
    })
    .unwrap();
    let saddr = server.addr.unwrap_or_else(|| panic!("server did not start: {}", server.stderr()));
    let (mut c, _) = SessionClient::connect(&format!("http://{saddr}"), start_builtin("cornell", 64, 48)).await.expect("session");
    let mut last = Instant::now();
    frames_until(&mut c, &mut last, WAIT, |_, s| s.samples > 0).await.expect("the renderer with its certificate gets samples");
}

#[test]
fn non_loopback_addresses_need_tls_and_tokens_or_insecure() {
    let dir = Scratch::new("exposure");
    pki(&dir);
    let tokens = dir.write("tokens", TOKEN);
    let mut open = Spawned::start("edgepoint-server", &["--listen", "0.0.0.0:0"]).unwrap();
    assert!(open.addr.is_none(), "the server must not serve 0.0.0.0 unprotected");
    let st = open.wait_exit(Duration::from_secs(20)).expect("it exits");
    assert!(!st.success());
    let err = open.stderr();
    assert!(err.contains("--tls-cert") && err.contains("--token-file") && err.contains("--insecure"), "{err}");

    let mut tls_only =
        Spawned::start("edgepoint-server", &["--listen", "0.0.0.0:0", "--tls-cert", &dir.path("cert.pem"), "--tls-key", &dir.path("key.pem")]).unwrap();
    assert!(tls_only.addr.is_none());
    tls_only.wait_exit(Duration::from_secs(20)).expect("it exits");
    assert!(tls_only.stderr().contains("--token-file") && !tls_only.stderr().contains("--tls-cert FILE"), "{}", tls_only.stderr());

    let protected = Spawned::start(
        "edgepoint-server",
        &["--listen", "0.0.0.0:0", "--tls-cert", &dir.path("cert.pem"), "--tls-key", &dir.path("key.pem"), "--token-file", &tokens.display().to_string()],
    )
    .unwrap();
    assert!(protected.addr.is_some(), "TLS and tokens: allowed ({})", protected.stderr());
    let insecure = Spawned::start("edgepoint-server", &["--listen", "0.0.0.0:0", "--insecure"]).unwrap();
    assert!(insecure.addr.is_some(), "--insecure: allowed ({})", insecure.stderr());

    let mut worker = Spawned::start("edgepoint-worker", &["--listen", "0.0.0.0:0"]).unwrap();
    assert!(worker.addr.is_none());
    worker.wait_exit(Duration::from_secs(20)).expect("it exits");
    assert!(worker.stderr().contains("--tls-cert") && worker.stderr().contains("--token-file"), "{}", worker.stderr());
    // Issue 12 item 5: beyond loopback a worker must authenticate its renderer; neither
    // --insecure nor TLS alone is enough.
    let tokens_arg = tokens.display().to_string();
    for args in [
        vec!["--listen", "0.0.0.0:0", "--insecure"],
        vec!["--listen", "0.0.0.0:0", "--tls-cert", &dir.path("cert.pem"), "--tls-key", &dir.path("key.pem")],
    ] {
        let mut w = Spawned::start("edgepoint-worker", &args).unwrap();
        assert!(w.addr.is_none(), "{args:?} must be refused");
        w.wait_exit(Duration::from_secs(20)).expect("it exits");
        assert!(w.stderr().contains("authentication of the renderer") && w.stderr().contains("--token-file"), "{args:?}: {}", w.stderr());
    }
    let worker = Spawned::start("edgepoint-worker", &["--listen", "0.0.0.0:0", "--insecure", "--token-file", &tokens_arg]).unwrap();
    assert!(worker.addr.is_some(), "plaintext with a token on a trusted network: {}", worker.stderr());
    // Issue 12 item 11: plain-HTTP metrics beyond loopback need --metrics-public.
    let mut m = Spawned::start("edgepoint-worker", &["--listen", "127.0.0.1:0", "--metrics-listen", "0.0.0.0:0"]).unwrap();
    assert!(m.addr.is_none());
    m.wait_exit(Duration::from_secs(20)).expect("it exits");
    assert!(m.stderr().contains("--metrics-public"), "{}", m.stderr());
    let m = Spawned::start("edgepoint-server", &["--listen", "127.0.0.1:0", "--metrics-listen", "0.0.0.0:0", "--metrics-public"]).unwrap();
    assert!(m.addr.is_some() && m.metrics.is_some(), "{}", m.stderr());

    let bad_token_file = dir.write("short", "tooshort\n");
    let mut s = Spawned::start("edgepoint-server", &["--token-file", &bad_token_file.display().to_string()]).unwrap();
    assert!(s.addr.is_none());
    s.wait_exit(Duration::from_secs(20)).expect("it exits");
    assert!(s.stderr().contains("short") && s.stderr().contains("line 1"), "a bad token file is named: {}", s.stderr());
}
