//! Listener plumbing shared by the gRPC servers.
use tokio_stream::wrappers::TcpListenerStream;
use tokio_stream::{Stream, StreamExt};

/// The listener's accepted connections with Nagle's algorithm off. tonic cannot set
/// TCP_NODELAY on sockets handed to `serve_with_incoming`, and with Nagle on, small messages
/// (sample batches, rejections) wait for delayed ACKs — tens of milliseconds each, which
/// measured as a 4x loss of worker throughput on loopback.
pub fn no_delay_incoming(listener: tokio::net::TcpListener) -> impl Stream<Item = std::io::Result<tokio::net::TcpStream>> {
    TcpListenerStream::new(listener).map(|s| {
        if let Ok(s) = &s {
            let _ = s.set_nodelay(true);
        }
        s
    })
}
