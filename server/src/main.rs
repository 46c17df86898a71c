//! `edgepoint-server`: the renderer process. Serves the `Renderer` gRPC service (one render
//! session per viewer) and grpc.health.v1, dispatching shading work to the shader workers
//! given with `--worker`. Prints `listening <addr>` on stdout once bound.
use clap::Parser;
use edgepoint_proto::renderer_server::RendererServer;
use edgepoint_server::service::{RendererService, ServiceConfig};
use edgepoint_server::workers::{PoolOptions, WorkerPool};
use std::io::Write;
use std::sync::Arc;
use std::time::Duration;

/// The edgepoint renderer: edge-and-point rendering sessions over gRPC, shading on remote
/// shader workers.
#[derive(Parser, Debug)]
#[command(name = "edgepoint-server", version, about)]
struct Cli {
    /// Address to listen on (host:port; port 0 picks a free port). The bound address is
    /// printed on stdout as `listening <addr>`.
    #[arg(long, default_value = "127.0.0.1:50051")]
    listen: String,

    /// A shader worker to dispatch to: `http://host:port` or `host:port`. Repeat the flag
    /// for several workers. Without any, sessions are refused with FAILED_PRECONDITION.
    #[arg(long = "worker", value_name = "URL")]
    workers: Vec<String>,

    /// Most render sessions (viewers) served at once; further ones get RESOURCE_EXHAUSTED.
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=4096))]
    max_sessions: u32,

    /// Largest gRPC message in MiB, to and from viewers and workers (a scene travels as the
    /// bytes of its files in one message).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(1..=2047))]
    max_message_mib: u32,

    /// Render Cache size per session, in cached points per image pixel.
    #[arg(long, default_value_t = edgepoint_server::session::DEFAULT_POINTS_PER_PIXEL)]
    points_per_pixel: f32,
}

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    if !(cli.points_per_pixel.is_finite() && (0.25..=64.0).contains(&cli.points_per_pixel)) {
        eprintln!("error: --points-per-pixel must be in [0.25, 64], got {}", cli.points_per_pixel);
        return std::process::ExitCode::from(2);
    }
    let rt = match tokio::runtime::Builder::new_multi_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return std::process::ExitCode::FAILURE;
        }
    };
    match rt.block_on(run(cli)) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

async fn run(cli: Cli) -> anyhow::Result<()> {
    let max_message = cli.max_message_mib as usize * (1 << 20);
    let pool = WorkerPool::with_options(cli.workers.clone(), PoolOptions { max_message_bytes: max_message, ..PoolOptions::default() })?;
    if pool.is_empty() {
        tracing::warn!("no --worker given: sessions will be refused until the server is restarted with workers");
    } else {
        tracing::info!(workers = ?pool.endpoints(), "shader workers");
    }
    let service = RendererService::new(
        Arc::new(pool),
        ServiceConfig { max_sessions: cli.max_sessions as usize, points_per_pixel: cli.points_per_pixel },
    );
    let shutdown = service.shutdown_handle();

    let (health_reporter, health_service) = tonic_health::server::health_reporter();
    health_reporter.set_serving::<RendererServer<RendererService>>().await;

    let listener = tokio::net::TcpListener::bind(&cli.listen)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", cli.listen))?;
    let addr = listener.local_addr()?;
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening {addr}")?;
        out.flush()?;
    }
    tracing::info!(%addr, max_sessions = cli.max_sessions, "renderer serving");

    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let signal_task = tokio::spawn(async move {
        wait_for_signal().await;
        tracing::info!("shutting down: ending sessions");
        health_reporter.set_not_serving::<RendererServer<RendererService>>().await;
        shutdown.shutdown();
        let _ = stop_tx.send(());
    });

    let server = tonic::transport::Server::builder()
        .add_service(health_service)
        .add_service(service.into_server(max_message))
        .serve_with_incoming_shutdown(edgepoint_proto::net::no_delay_incoming(listener), async {
            let _ = stop_rx.await;
        });
    let mut server = std::pin::pin!(server);
    tokio::select! {
        r = &mut server => r?,
        _ = async {
            // After the signal, give open streams a moment to finish, then stop regardless.
            while !signal_task.is_finished() {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            tokio::time::sleep(Duration::from_secs(5)).await;
        } => tracing::warn!("connections did not drain within 5 s; exiting"),
    }
    tracing::info!("stopped");
    Ok(())
}

async fn wait_for_signal() {
    #[cfg(unix)]
    {
        let mut term = match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!("cannot watch SIGTERM ({e}); Ctrl-C only");
                let _ = tokio::signal::ctrl_c().await;
                return;
            }
        };
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {}
            _ = term.recv() => {}
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}
