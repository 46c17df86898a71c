//! Output for rendering engineers through the real binaries: linear EXR frames written
//! headless, mirrored to a fake tev that parses the protocol's packets, tone-mapped PNGs;
//! and the tone curve `clip` at exposure 0 against the renderer's own sRGB table.
use edgepoint_tests::run_viewer_headless;
use edgepoint_viewer::tev::{read_packet, Packet, CHANNELS};
use edgepoint_viewer::tonemap::{Look, ToneCurve, ToneMapper};
use half::f16;
use std::net::TcpListener;
use std::process::Command;
use std::sync::mpsc;
use std::time::Duration;

fn viewer() -> std::path::PathBuf {
    edgepoint_viewer::local::find_binary("edgepoint-viewer").expect("viewer binary built")
}

fn temp(tag: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("edgepoint-output-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A stand-in for tev: accepts connections one after another and sends every packet it
/// parses to the test, then `None` when a connection ends.
fn fake_tev() -> (String, mpsc::Receiver<Option<Packet>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(mut s) = conn else { return };
            while let Ok(Some(p)) = read_packet(&mut s) {
                if tx.send(Some(p)).is_err() {
                    return;
                }
            }
            if tx.send(None).is_err() {
                return;
            }
        }
    });
    (addr, rx)
}

#[test]
fn headless_exr_frames_are_linear_and_tev_gets_the_same_values() {
    let out = temp("exr");
    let (tev, packets) = fake_tev();
    let (w, h) = (64u32, 48u32);
    let status = run_viewer_headless(&["--frames", "4", "--width", "64", "--height", "48", "--format", "exr", "--tev", &tev], &out);
    assert!(status.success(), "viewer exit status {status}");
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = stats.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 4);
    let mut last = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        assert_eq!(l["encoding"], "linear-half-lz4", "EXR output asks for linear frames");
        let name = format!("frame_{:05}.exr", i + 1);
        assert_eq!(l["file"], name.as_str());
        let (rw, rh, px) = edgepoint_viewer::exr_file::read_rgb(&out.join(&name)).unwrap();
        assert_eq!((rw, rh), (w, h));
        assert!(px.iter().all(|v| v.is_finite() && *v >= 0.0));
        assert!(px.iter().any(|v| *v > 0.0), "{name} is not black");
        assert!(px.iter().all(|v| f16::from_f32(*v).to_f32() == *v), "{name} holds half floats");
        last = px;
    }
    // Every frame went to tev as one 64x48 tile (the last one at least: the mirror sends
    // the newest frame and the one waiting when the viewer ends).
    // The viewer has exited, so its connection ends after the last packet it sent.
    let mut got = Vec::new();
    while let Some(p) = packets.recv_timeout(Duration::from_secs(30)).expect("the viewer connected to tev and closed the connection") {
        got.push(p);
    }
    let Some(Packet::CreateImage { name, width, height, channels, grab_focus }) = got.first() else { panic!("{got:?}") };
    assert_eq!((name.as_str(), *width, *height, *grab_focus), ("edgepoint cornell", 64, 48, true));
    assert_eq!(channels, &CHANNELS);
    let updates: Vec<&Packet> = got.iter().filter(|p| matches!(p, Packet::UpdateImage { .. })).collect();
    assert!(!updates.is_empty() && updates.len() <= 4, "{} updates", updates.len());
    let Packet::UpdateImage { name, x, y, width, height, values, .. } = updates[updates.len() - 1] else { unreachable!() };
    assert_eq!((name.as_str(), *x, *y, *width, *height), ("edgepoint cornell", 0, 0, 64, 48));
    let tev_pixels: Vec<f32> = (0..(w * h) as usize).flat_map(|i| [values[0][i], values[1][i], values[2][i]]).collect();
    assert_eq!(tev_pixels, last, "tev shows the last EXR frame's linear values");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn exposure_and_filmic_write_tone_mapped_pngs_and_bad_combinations_fail_clearly() {
    let out = temp("filmic");
    let status = run_viewer_headless(&["--frames", "2", "--width", "48", "--height", "32", "--exposure", "1", "--tonemap", "filmic"], &out);
    assert!(status.success());
    let stats = std::fs::read_to_string(out.join("stats.jsonl")).unwrap();
    assert!(stats.lines().all(|l| l.contains(r#""encoding":"linear-half-lz4""#)), "{stats}");
    let img = image::open(out.join("frame_00002.png")).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (48, 32));
    let _ = std::fs::remove_dir_all(&out);

    for (args, says) in [
        (&["--format", "exr", "--encoding", "qoi"][..], "--format exr needs linear frames"),
        (&["--exposure", "nan"][..], "--exposure"),
        (&["--tev", "host:port"][..], "not a port number"),
    ] {
        let o = Command::new(viewer()).args(["--local", "--headless", "--frames", "1"]).args(args).env("RUST_LOG", "warn").output().unwrap();
        assert!(!o.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
    }
}

/// Oracle: the renderer's sRGB table (the codes of its QOI frames). At exposure 0, `clip`
/// gives the same code for every half float and for a spread of f32 values.
#[test]
fn clip_at_exposure_zero_is_the_renderers_srgb_bit_for_bit() {
    let id = Look::default();
    let table = ToneMapper::new(id);
    for h in 0..=u16::MAX {
        let x = f16::from_bits(h).to_f32();
        let want = edgepoint_server::srgb::encode(x);
        assert_eq!(table.code(h), want, "half {h:#06x} = {x}");
        assert_eq!(id.srgb8(x), want);
    }
    let mut s = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..2_000_000 {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        // Every exponent from tiny to past 1, any mantissa.
        let x = f32::from_bits(0x3000_0000 + (s as u32 % 0x1000_0000));
        assert_eq!(id.srgb8(x), edgepoint_server::srgb::encode(x), "{x:e}");
    }
    // Filmic and exposure differ from it, as they should.
    assert_ne!(Look { exposure: 0.0, curve: ToneCurve::Filmic }.srgb8(0.5), id.srgb8(0.5));
    assert_eq!(Look { exposure: 1.0, curve: ToneCurve::Clip }.srgb8(0.25), id.srgb8(0.5));
}
