//! One page's live connection: the WebSocket loop between a browser and a render session
//! (issue 16 items 1 and 3). The page's `hello` carries its token and `start`; both go
//! through [`RendererService::serve_session`], the gRPC stream's own entry, so every check,
//! limit and refusal is the same. Then page messages become session inputs, and session
//! messages go to the page: JSON text, and frames as changed tiles ([`super::tiles`]).
//!
//! Pace: at most [`FRAMES_IN_FLIGHT`] frames are on their way to the page at once; each is
//! released when the page echoes it drawn (`shown`). While the link or the page is behind,
//! the loop does not read the session's output, so the frame loop replaces its pending frame
//! (latest frame wins, never a queue of stale frames). The echo also measures the end-to-end
//! latency: from the frame leaving the frame loop to the page having drawn it, plus the
//! echo's trip back (one loopback hop).
use super::protocol::{self, PageMsg};
use super::tiles::{frame_message, TileDiff};
use super::MAX_PAGE_MESSAGE;
use crate::service::RendererService;
use edgepoint_proto as pb;
use futures_util::{SinkExt, StreamExt};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tokio_tungstenite::tungstenite::protocol::{frame::coding::CloseCode, CloseFrame, Role, WebSocketConfig};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::WebSocketStream;
use tonic::{Code, Status};

/// Frames sent and not yet echoed drawn; more wait (replaced by newer ones) in the session.
pub const FRAMES_IN_FLIGHT: usize = 2;
/// Pings keep an idle (paused) page's connection alive: browsers answer them by themselves.
const PING_EVERY: Duration = Duration::from_secs(10);

/// From the page's reader to the writer loop.
enum Ctl {
    Shown { t: f64 },
    Text(String),
    /// The page closed, or broke a rule: the reason, and a refusal to show when it is ours.
    Closed(Option<(Code, String)>),
}

/// Serves one upgraded connection until the page or the session ends.
pub async fn run<S>(io: S, peer: SocketAddr, service: Arc<RendererService>)
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let mut cfg = WebSocketConfig::default();
    cfg.max_message_size = Some(MAX_PAGE_MESSAGE);
    cfg.max_frame_size = Some(MAX_PAGE_MESSAGE);
    let ws = WebSocketStream::from_raw_socket(io, Role::Server, Some(cfg)).await;
    let (mut sink, mut stream) = ws.split();

    // The first message: token and start, within the service's start timeout.
    let limit = service.config().start_timeout;
    let hello = match tokio::time::timeout(limit, next_text(&mut stream)).await {
        Err(_) => Err((Code::DeadlineExceeded, format!("no `hello` message within {limit:?} of connecting"))),
        Ok(Err(e)) => Err(e),
        Ok(Ok(t)) => protocol::parse_hello(&t).map_err(|e| (Code::InvalidArgument, e)),
    };
    let hello = match hello {
        Ok(h) => h,
        Err((code, msg)) => return refuse(&mut sink, peer, code, &msg).await,
    };
    let mut md = tonic::metadata::MetadataMap::new();
    if let Some(t) = &hello.token {
        match edgepoint_proto::auth::bearer(t).parse() {
            Ok(v) => {
                md.insert(edgepoint_proto::auth::AUTHORIZATION, v);
            }
            Err(_) => return refuse(&mut sink, peer, Code::Unauthenticated, "the token holds characters a token may not").await,
        }
    }
    let (in_tx, in_rx) = mpsc::channel::<Result<pb::ViewerMsg, Status>>(16);
    let start = pb::ViewerMsg { msg: Some(pb::viewer_msg::Msg::Start(hello.start)) };
    // The receiver is held just below, so this cannot fail.
    let _ = in_tx.send(Ok(start)).await;
    let out = match service.serve_session(&md, Some(peer), ReceiverStream::new(in_rx)).await {
        Ok(out) => out,
        Err(s) => {
            let hint = if s.code() == Code::Unauthenticated { ": open the URL the server printed, with its #token=…" } else { "" };
            return refuse(&mut sink, peer, s.code(), &format!("{}{hint}", s.message())).await;
        }
    };

    // Page → session (and acks / malformed-message rejections → the writer).
    let (ctl_tx, mut ctl_rx) = mpsc::channel::<Ctl>(64);
    let reader = tokio::spawn(async move {
        loop {
            let text = match next_text(&mut stream).await {
                Ok(t) => t,
                Err((Code::Cancelled, _)) => break ctl_tx.send(Ctl::Closed(None)).await,
                Err(e) => break ctl_tx.send(Ctl::Closed(Some(e))).await,
            };
            let sent = match protocol::parse_page(&text) {
                Ok(PageMsg::Shown { t, .. }) => ctl_tx.send(Ctl::Shown { t }).await,
                Ok(PageMsg::Viewer(m)) => {
                    if in_tx.send(Ok(m)).await.is_err() {
                        break Ok(()); // the session ended
                    }
                    Ok(())
                }
                Err(e) => {
                    let j = serde_json::json!({"type": "rejected", "code": "INVALID_ARGUMENT", "message": format!("ignored: {e}")});
                    ctl_tx.send(Ctl::Text(j.to_string())).await
                }
            };
            if sent.is_err() {
                break Ok(());
            }
        }
    });

    let t0 = Instant::now();
    let mut out = out;
    let mut diff = TileDiff::default();
    let (mut in_flight, mut latency) = (0usize, None::<f64>);
    let mut ping = tokio::time::interval(PING_EVERY);
    ping.tick().await;
    let end: Result<(), (Code, String)> = loop {
        tokio::select! {
            biased;
            ctl = ctl_rx.recv() => match ctl {
                Some(Ctl::Shown { t }) => {
                    in_flight = in_flight.saturating_sub(1);
                    let now = t0.elapsed().as_secs_f64() * 1e3;
                    if t.is_finite() && t <= now {
                        latency = Some(now - t);
                    }
                }
                Some(Ctl::Text(t)) => {
                    if sink.send(Message::text(t)).await.is_err() {
                        break Ok(());
                    }
                }
                Some(Ctl::Closed(why)) => break why.map_or(Ok(()), Err),
                None => break Ok(()),
            },
            m = out.next(), if in_flight < FRAMES_IN_FLIGHT => match m {
                Some(Ok(m)) => {
                    let msg = match &m.msg {
                        Some(pb::server_msg::Msg::Frame(f)) => match frame_bytes(&mut diff, f, t0, latency) {
                            Ok(b) => {
                                in_flight += 1;
                                Message::binary(b)
                            }
                            Err(e) => break Err((Code::Internal, e)),
                        },
                        _ => match protocol::server_json(&m) {
                            Some(j) => Message::text(j.to_string()),
                            None => continue,
                        },
                    };
                    if sink.send(msg).await.is_err() {
                        break Ok(());
                    }
                }
                Some(Err(s)) => break Err((s.code(), s.message().to_string())),
                None => {
                    let j = serde_json::json!({"type": "ended", "message": "the session ended (the renderer is shutting down or ended it)"});
                    let _ = sink.send(Message::text(j.to_string())).await;
                    break Ok(());
                }
            },
            _ = ping.tick() => {
                if sink.send(Message::Ping(Vec::new().into())).await.is_err() {
                    break Ok(());
                }
            }
        }
    };
    reader.abort();
    // Dropping `out` ends the session (its frame loop stops, its slot and memory return).
    drop(out);
    match end {
        Ok(()) => {
            let _ = sink.close().await;
            tracing::info!(%peer, "web viewer closed");
        }
        Err((code, msg)) => refuse(&mut sink, peer, code, &msg).await,
    }
}

/// The binary message of frame `f`: its changed tiles and its stats.
fn frame_bytes(diff: &mut TileDiff, f: &pb::Frame, t0: Instant, latency: Option<f64>) -> Result<Vec<u8>, String> {
    if f.encoding != pb::FrameEncoding::RawRgb8 as i32 {
        return Err(format!("the session sent encoding {} instead of raw RGB", f.encoding));
    }
    let u = diff.update(&f.data, f.width, f.height)?;
    let header = protocol::frame_header(f, &u.tiles, t0.elapsed().as_secs_f64() * 1e3, latency);
    Ok(frame_message(&header, &u.deflated))
}

/// The next text message, answering pings on the way. `Cancelled`: the page closed.
async fn next_text<S>(stream: &mut S) -> Result<String, (Code, String)>
where
    S: futures_util::Stream<Item = Result<Message, tokio_tungstenite::tungstenite::Error>> + Unpin,
{
    use tokio_tungstenite::tungstenite::error::{CapacityError, Error};
    loop {
        match stream.next().await {
            Some(Ok(Message::Text(t))) => return Ok(t.to_string()),
            Some(Ok(Message::Binary(_))) => return Err((Code::InvalidArgument, "the page sends JSON text messages only".into())),
            Some(Ok(Message::Close(_))) | None => return Err((Code::Cancelled, "closed".into())),
            Some(Ok(_)) => continue, // ping, pong: tungstenite answers pings itself
            Some(Err(Error::Capacity(CapacityError::MessageTooLong { size, max_size }))) => {
                return Err((Code::OutOfRange, format!("a page message of {size} bytes is above the limit of {max_size} bytes")))
            }
            Some(Err(e)) => return Err((Code::Cancelled, e.to_string())),
        }
    }
}

/// Tells the page why (a `refused` message it shows), then closes with the reason too.
async fn refuse<S>(sink: &mut S, peer: SocketAddr, code: Code, msg: &str)
where
    S: futures_util::Sink<Message> + Unpin,
{
    tracing::info!(%peer, ?code, "web viewer refused: {msg}");
    let _ = sink.send(Message::text(protocol::refused(code, msg).to_string())).await;
    // A close reason is at most 123 bytes; the full text went in the message above.
    let mut reason: String = format!("{}: {msg}", protocol::code_name(code));
    while reason.len() > 120 {
        reason.pop();
    }
    let close = CloseFrame { code: if code == Code::OutOfRange { CloseCode::Size } else { CloseCode::Policy }, reason: reason.into() };
    let _ = sink.send(Message::Close(Some(close))).await;
    let _ = sink.close().await;
}
