//! The browser page's messages (JSON text over the WebSocket) translated to and from the
//! gRPC session's `ViewerMsg` / `ServerMsg` (proto/proto/edgepoint.proto), so a page drives
//! exactly the session machinery a gRPC viewer does. Every malformed message is an error
//! string naming the field, never a panic; the caller answers it as a `rejected`.
//!
//! Page → server: `hello` (first: token and start), `camera`, `pick`, `move`, `settings`,
//! `shown` (the echo of a drawn frame). Server → page: `started`, `progress`, `picked`,
//! `rejected`, `refused` (the session could not open, or was refused; the socket then
//! closes), `ended`, and binary frames ([`super::tiles`]).
use edgepoint_proto as pb;
use edgepoint_proto::viewer_msg::Msg as ViewerIn;
use serde_json::{json, Value};

/// Largest image side a page may ask for (the server's pixel limit applies too).
pub const MAX_PAGE_SIDE: u32 = 4096;

/// What a page's text message asks for.
// One lives at a time, moved straight into the session's input channel: boxing the large
// variant would only add an allocation per message.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum PageMsg {
    /// For the session: camera, pick, move or settings.
    Viewer(pb::ViewerMsg),
    /// The page drew frame `seq`, stamped `t` (server milliseconds) when it was sent.
    Shown { seq: u64, t: f64 },
}

/// The first message: `{"type":"hello","token":"…","start":{"scene":"cornell","shader":"direct","width":512,"height":512}}`.
#[derive(Debug, Clone, PartialEq)]
pub struct Hello {
    pub token: Option<String>,
    pub start: pb::Start,
}

fn field<'a>(v: &'a Value, name: &str) -> Result<&'a Value, String> {
    v.get(name).ok_or_else(|| format!("`{name}` is missing"))
}

fn num(v: &Value, name: &str) -> Result<f64, String> {
    field(v, name)?.as_f64().filter(|x| x.is_finite()).ok_or_else(|| format!("`{name}` must be a finite number"))
}

fn vec3(v: &Value, name: &str) -> Result<pb::Vec3, String> {
    let a = field(v, name)?.as_array().filter(|a| a.len() == 3).ok_or_else(|| format!("`{name}` must be [x, y, z]"))?;
    let c = |i: usize| a[i].as_f64().filter(|x| x.is_finite()).map(|x| x as f32).ok_or_else(|| format!("`{name}` must hold 3 finite numbers"));
    Ok(pb::Vec3 { x: c(0)?, y: c(1)?, z: c(2)? })
}

fn text<'a>(v: &'a Value, name: &str) -> Result<&'a str, String> {
    field(v, name)?.as_str().ok_or_else(|| format!("`{name}` must be a string"))
}

/// Parses the page's first message.
pub fn parse_hello(s: &str) -> Result<Hello, String> {
    let v: Value = serde_json::from_str(s).map_err(|e| format!("the first message is not JSON: {e}"))?;
    if v.get("type").and_then(Value::as_str) != Some("hello") {
        return Err("the first message must be `hello`".into());
    }
    let token = v.get("token").and_then(Value::as_str).filter(|t| !t.is_empty()).map(str::to_string);
    let st = field(&v, "start")?;
    let scene = text(st, "scene")?;
    let shader = st.get("shader").and_then(Value::as_str).unwrap_or("").to_string();
    let side = |name: &str| -> Result<u32, String> {
        let x = num(st, name)?;
        if x.fract() != 0.0 || !(1.0..=MAX_PAGE_SIDE as f64).contains(&x) {
            return Err(format!("start.{name} must be a whole number in 1..={MAX_PAGE_SIDE}, got {x}"));
        }
        Ok(x as u32)
    };
    let start = pb::Start {
        scene: Some(pb::builtin_source(scene)),
        width: side("width")?,
        height: side("height")?,
        shader,
        // The tiles are diffed on the frame's own sRGB bytes, so the session sends them raw.
        encoding: pb::FrameEncoding::RawRgb8 as i32,
        ..Default::default()
    };
    Ok(Hello { token, start })
}

/// Parses a later message of the page.
pub fn parse_page(s: &str) -> Result<PageMsg, String> {
    let v: Value = serde_json::from_str(s).map_err(|e| format!("not JSON: {e}"))?;
    let kind = text(&v, "type")?;
    let msg = match kind {
        "shown" => {
            let seq = field(&v, "seq")?.as_u64().ok_or("`seq` must be a whole number")?;
            return Ok(PageMsg::Shown { seq, t: num(&v, "t")? });
        }
        "camera" => ViewerIn::Camera(pb::Camera {
            eye: Some(vec3(&v, "eye")?),
            target: Some(vec3(&v, "target")?),
            up: Some(vec3(&v, "up")?),
            fov_y_degrees: num(&v, "fov")? as f32,
        }),
        "pick" => ViewerIn::Pick(pb::Pick {
            id: field(&v, "id")?.as_u64().ok_or("`id` must be a whole number")?,
            x: num(&v, "x")? as f32,
            y: num(&v, "y")? as f32,
        }),
        "move" => {
            let rows = field(&v, "rows")?.as_array().filter(|a| a.len() == 12).ok_or("`rows` must hold 12 numbers")?;
            let rows = rows.iter().map(|x| x.as_f64().filter(|x| x.is_finite()).map(|x| x as f32)).collect::<Option<Vec<_>>>();
            let rows = rows.ok_or("`rows` must hold 12 finite numbers")?;
            let id = field(&v, "object")?.as_u64().and_then(|x| u32::try_from(x).ok()).ok_or("`object` must be an object id")?;
            ViewerIn::Move(pb::ObjectMove { object_id: id, name: String::new(), transform: Some(pb::Affine { rows }) })
        }
        "settings" => {
            let mut st = pb::Settings::default();
            if let Some(o) = v.get("overlay") {
                st.overlay = match o.as_str() {
                    Some("none") => pb::Overlay::None,
                    Some("edges") => pb::Overlay::Edges,
                    Some("classes") => pb::Overlay::Classes,
                    Some("samples") => pb::Overlay::Samples,
                    _ => return Err("`overlay` must be none, edges, classes or samples".into()),
                } as i32;
            }
            if let Some(r) = v.get("reconstruction") {
                st.reconstruction = match r.as_str() {
                    Some("epr") => pb::Reconstruction::EdgeAndPoint,
                    Some("render-cache") => pb::Reconstruction::RenderCache,
                    _ => return Err("`reconstruction` must be epr or render-cache".into()),
                } as i32;
            }
            if let Some(p) = v.get("paused") {
                st.paused = p.as_bool().ok_or("`paused` must be true or false")?;
                st.set_paused = true;
            }
            ViewerIn::Settings(st)
        }
        other => return Err(format!("unknown message type `{other}`")),
    };
    Ok(PageMsg::Viewer(pb::ViewerMsg { msg: Some(msg) }))
}

fn v3(v: &Option<pb::Vec3>) -> Value {
    v.as_ref().map_or(Value::Null, |v| json!([v.x, v.y, v.z]))
}

fn camera(c: &Option<pb::Camera>) -> Value {
    c.as_ref().map_or(Value::Null, |c| json!({"eye": v3(&c.eye), "target": v3(&c.target), "up": v3(&c.up), "fov": c.fov_y_degrees}))
}

fn rows(a: &Option<pb::Affine>) -> Value {
    a.as_ref().map_or(Value::Null, |a| json!(a.rows))
}

/// The JSON text of a session message other than a frame (`None` for a frame).
pub fn server_json(m: &pb::ServerMsg) -> Option<Value> {
    use pb::server_msg::Msg;
    Some(match m.msg.as_ref()? {
        Msg::Started(s) => json!({
            "type": "started",
            "session": s.session_id,
            "objects": s.objects.iter().map(|o| json!({"id": o.id, "name": o.name, "transform": rows(&o.transform)})).collect::<Vec<_>>(),
            "camera": camera(&s.camera),
            "scene_min": v3(&s.scene_min),
            "scene_max": v3(&s.scene_max),
            "workers": s.workers,
            "lights": s.lights,
        }),
        Msg::Progress(p) => json!({"type": "progress", "stage": p.stage, "done": p.done, "total": p.total, "message": p.message}),
        Msg::Picked(p) => json!({
            "type": "picked", "id": p.id, "hit": p.hit, "object": p.object_id, "name": p.name,
            "position": v3(&p.position), "transform": rows(&p.transform), "camera": camera(&p.camera),
        }),
        Msg::Rejected(r) => json!({"type": "rejected", "code": tonic::Code::from(r.code).description(), "message": r.message}),
        Msg::Frame(_) => return None,
    })
}

/// The header of a frame's binary message: what the stats overlay shows.
pub fn frame_header(f: &pb::Frame, tiles: &[u32], sent_ms: f64, latency_ms: Option<f64>) -> Value {
    json!({
        "seq": f.sequence,
        "width": f.width,
        "height": f.height,
        "tiles": tiles,
        "t": sent_ms,
        "latency_ms": latency_ms,
        "total_ms": f.total_ms,
        "stages": f.stages.iter().map(|s| json!([s.stage, s.ms])).collect::<Vec<_>>(),
        "samples_used": f.samples_used,
        "samples_requested": f.samples_requested,
        "frames_dropped": f.frames_dropped,
        "between_ms": f.between_ms,
        "after_ms": f.after_ms,
        "live_workers": f.live_workers,
        "camera": camera(&f.camera),
        "epoch": f.epoch,
        "overlay": match pb::Overlay::try_from(f.overlay) {
            Ok(pb::Overlay::Edges) => "edges",
            Ok(pb::Overlay::Classes) => "classes",
            Ok(pb::Overlay::Samples) => "samples",
            _ => "none",
        },
        "reconstruction": match pb::Reconstruction::try_from(f.reconstruction) {
            Ok(pb::Reconstruction::RenderCache) => "render-cache",
            _ => "epr",
        },
    })
}

/// A refusal the page shows before the socket closes: the gRPC code's name and the reason.
pub fn refused(code: tonic::Code, message: &str) -> Value {
    json!({"type": "refused", "code": code_name(code), "message": message})
}

/// `UNAUTHENTICATED`, `RESOURCE_EXHAUSTED`…: the names the README's tables use.
pub fn code_name(code: tonic::Code) -> String {
    format!("{code:?}").chars().fold(String::new(), |mut s, c| {
        if c.is_uppercase() && !s.is_empty() {
            s.push('_');
        }
        s.push(c.to_ascii_uppercase());
        s
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hello_becomes_a_raw_start_and_bad_ones_name_the_field() {
        let h = parse_hello(r#"{"type":"hello","token":"abc","start":{"scene":"cornell","shader":"gi","width":512,"height":256}}"#).unwrap();
        assert_eq!(h.token.as_deref(), Some("abc"));
        assert_eq!((h.start.width, h.start.height, h.start.shader.as_str()), (512, 256, "gi"));
        assert_eq!(h.start.encoding, pb::FrameEncoding::RawRgb8 as i32);
        assert_eq!(h.start.scene, Some(pb::builtin_source("cornell")));
        let h = parse_hello(r#"{"type":"hello","start":{"scene":"rooms","width":8,"height":8}}"#).unwrap();
        assert_eq!(h.token, None);
        for (bad, why) in [
            ("nope", "not JSON"),
            (r#"{"type":"camera"}"#, "must be `hello`"),
            (r#"{"type":"hello"}"#, "`start` is missing"),
            (r#"{"type":"hello","start":{"scene":"cornell","width":0,"height":8}}"#, "start.width"),
            (r#"{"type":"hello","start":{"scene":"cornell","width":8,"height":8.5}}"#, "start.height"),
            (r#"{"type":"hello","start":{"scene":"cornell","width":8,"height":99999}}"#, "4096"),
            (r#"{"type":"hello","start":{"scene":3,"width":8,"height":8}}"#, "`scene` must be a string"),
        ] {
            let e = parse_hello(bad).unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
    }

    #[test]
    fn page_messages_become_viewer_messages() {
        let m = parse_page(r#"{"type":"camera","eye":[0,1,4],"target":[0,1,0],"up":[0,1,0],"fov":40}"#).unwrap();
        let PageMsg::Viewer(pb::ViewerMsg { msg: Some(ViewerIn::Camera(c)) }) = m else { panic!("{m:?}") };
        assert_eq!((c.eye.unwrap().z, c.fov_y_degrees), (4.0, 40.0));
        let m = parse_page(r#"{"type":"pick","id":7,"x":10.5,"y":3}"#).unwrap();
        assert_eq!(m, PageMsg::Viewer(pb::ViewerMsg { msg: Some(ViewerIn::Pick(pb::Pick { id: 7, x: 10.5, y: 3.0 })) }));
        let m = parse_page(r#"{"type":"move","object":2,"rows":[1,0,0,0.5,0,1,0,0,0,0,1,0]}"#).unwrap();
        let PageMsg::Viewer(pb::ViewerMsg { msg: Some(ViewerIn::Move(mv)) }) = m else { panic!() };
        assert_eq!((mv.object_id, mv.transform.unwrap().rows[3]), (2, 0.5));
        let m = parse_page(r#"{"type":"settings","overlay":"classes","reconstruction":"render-cache","paused":true}"#).unwrap();
        let PageMsg::Viewer(pb::ViewerMsg { msg: Some(ViewerIn::Settings(s)) }) = m else { panic!() };
        assert_eq!((s.overlay, s.reconstruction, s.paused, s.set_paused), (pb::Overlay::Classes as i32, pb::Reconstruction::RenderCache as i32, true, true));
        assert_eq!(s.encoding, 0, "a page never switches the raw encoding its tiles need");
        assert_eq!(parse_page(r#"{"type":"shown","seq":3,"t":12.5}"#).unwrap(), PageMsg::Shown { seq: 3, t: 12.5 });
        for (bad, why) in [
            (r#"{"type":"camera","eye":[0,1],"target":[0,1,0],"up":[0,1,0],"fov":40}"#, "`eye` must be [x, y, z]"),
            (r#"{"type":"camera","eye":[0,1,"a"],"target":[0,1,0],"up":[0,1,0],"fov":40}"#, "`eye` must hold 3 finite"),
            (r#"{"type":"move","object":2,"rows":[1]}"#, "`rows` must hold 12"),
            (r#"{"type":"move","object":-1,"rows":[1,0,0,0,0,1,0,0,0,0,1,0]}"#, "`object`"),
            (r#"{"type":"settings","overlay":"x"}"#, "`overlay`"),
            (r#"{"type":"fly"}"#, "unknown message type `fly`"),
            (r#"{"seq":1}"#, "`type` is missing"),
        ] {
            let e = parse_page(bad).unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
    }

    #[test]
    fn session_messages_become_json() {
        let m = pb::ServerMsg { msg: Some(pb::server_msg::Msg::Rejected(pb::Rejected { code: 3, message: "bad camera".into() })) };
        let j = server_json(&m).unwrap();
        assert_eq!((j["type"].as_str(), j["message"].as_str()), (Some("rejected"), Some("bad camera")));
        let m = pb::ServerMsg { msg: Some(pb::server_msg::Msg::Frame(pb::Frame::default())) };
        assert!(server_json(&m).is_none());
        assert_eq!(code_name(tonic::Code::ResourceExhausted), "RESOURCE_EXHAUSTED");
        assert_eq!(refused(tonic::Code::Unauthenticated, "x")["code"], "UNAUTHENTICATED");
    }
}
