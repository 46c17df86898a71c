//! `edgepoint-server`: the renderer process. Serves the `Renderer` gRPC service (one render
//! session per viewer) and grpc.health.v1, dispatching shading work to the shader workers
//! it is given or discovers (see `edgepoint_server::cli`), and with `--web-listen` the
//! browser viewer (`edgepoint_server::web`). Prints `metrics <addr>` (with `--metrics-listen`),
//! `web <url>` (with `--web-listen`) and then `listening <addr>` on stdout once bound.
use clap::Parser;
use edgepoint_proto::net::{check_exposure, client_tls, server_tls, Protection};
use edgepoint_proto::renderer_server::RendererServer;
use edgepoint_server::cli::ServerArgs;
use edgepoint_server::metrics::ServerMetrics;
use edgepoint_server::service::{RendererService, ServiceConfig};
use edgepoint_server::workers::{PoolOptions, WorkerPool, WorkerSources};
use std::io::Write;
use std::sync::Arc;
use std::time::Duration;

/// Concurrent HTTP/2 streams one connection may open (a viewer needs one per session).
const MAX_STREAMS_PER_CONNECTION: u32 = 64;

fn main() -> std::process::ExitCode {
    edgepoint_proto::logging::init("info");
    edgepoint_proto::heap::keep_freed_memory();
    let cli = ServerArgs::parse();
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

async fn run(cli: ServerArgs) -> anyhow::Result<()> {
    let max_message = cli.max_message_mib as usize * (1 << 20);
    let tokens = match &cli.token_file {
        Some(p) => Some(Arc::new(edgepoint_proto::auth::read_token_file(p).map_err(anyhow::Error::msg)?)),
        None => None,
    };
    let tls = match (&cli.tls_cert, &cli.tls_key) {
        (Some(c), Some(k)) => Some(server_tls(c, k).map_err(anyhow::Error::msg)?),
        _ => None,
    };
    let web_tls = match (&cli.web_listen, &cli.tls_cert, &cli.tls_key) {
        (Some(_), Some(c), Some(k)) => Some(edgepoint_proto::net::rustls_server_config(c, k).map_err(anyhow::Error::msg)?),
        _ => None,
    };
    let mut worker_tls = if cli.worker_tls_ca.is_some() || cli.worker_tls_domain.is_some() || cli.worker_tls_cert.is_some() {
        Some(client_tls(cli.worker_tls_ca.as_deref(), cli.worker_tls_domain.as_deref()).map_err(anyhow::Error::msg)?)
    } else {
        None
    };
    if let (Some(c), Some(k)) = (&cli.worker_tls_cert, &cli.worker_tls_key) {
        let t = worker_tls.take().expect("set above when --worker-tls-cert is given");
        worker_tls = Some(edgepoint_proto::net::client_identity(t, c, k).map_err(anyhow::Error::msg)?);
    }
    let worker_token = match &cli.worker_token_file {
        Some(p) => {
            let t = edgepoint_proto::auth::read_token_file(p).map_err(anyhow::Error::msg)?;
            Some(edgepoint_proto::auth::SendToken::new(t.first().map(String::as_str)).map_err(anyhow::Error::msg)?)
        }
        None => None,
    };

    // Bind first, so that the exposure check sees the address actually bound.
    let listener = tokio::net::TcpListener::bind(&cli.listen)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", cli.listen))?;
    let addr = listener.local_addr()?;
    check_exposure(addr, Protection { tls: tls.is_some(), token: Some(tokens.is_some()), insecure: cli.insecure })
        .map_err(anyhow::Error::msg)?;
    if cli.insecure && !edgepoint_proto::net::is_loopback(addr.ip()) && (tls.is_none() || tokens.is_none()) {
        tracing::warn!(%addr, tls = tls.is_some(), tokens = tokens.is_some(), "--insecure: serving a non-loopback address without full protection");
    }

    let metrics = Arc::new(ServerMetrics::new());
    let sources = WorkerSources {
        urls: cli.workers.clone(),
        dns: cli.worker_dns.clone(),
        file: cli.workers_file.clone(),
        interval: Duration::from_millis(cli.discovery_interval_ms),
    };
    let opts = PoolOptions {
        max_message_bytes: max_message,
        tls: worker_tls,
        target_batch_time: Duration::from_millis(cli.target_batch_ms),
        stall_floor: Duration::from_millis(cli.worker_stall_ms),
        stall_cap: Duration::from_millis(cli.worker_stall_ms).max(Duration::from_secs(10)),
        metrics: metrics.pool.clone(),
        worker_token: worker_token.unwrap_or_default(),
        ..PoolOptions::default()
    };
    let pool = Arc::new(WorkerPool::discover(sources.clone(), opts).await?);
    if !sources.is_dynamic() && pool.is_empty() {
        tracing::warn!("no workers given (--worker, --worker-dns or --workers-file): sessions will be refused");
    } else {
        tracing::info!(workers = ?pool.endpoints(), dns = ?sources.dns, file = ?sources.file, "shader workers");
    }

    if let Some(m) = &cli.metrics_listen {
        let (pool, metrics) = (pool.clone(), metrics.clone());
        edgepoint_proto::metrics_http::start(
            m,
            cli.metrics_public,
            Arc::new(move || {
                pool.refresh_metrics();
                metrics.encode()
            }),
        )
        .await?;
    }

    let memory_limit = match cli.max_memory_mib {
        Some(m) => m << 20,
        None => edgepoint_server::session::memory::default_budget_bytes(),
    };
    tracing::info!(max_memory_mib = memory_limit >> 20, "session memory budget (--max-memory-mib)");
    let service = Arc::new(RendererService::new(
        pool,
        ServiceConfig {
            max_sessions: cli.max_sessions as usize,
            points_per_pixel: cli.points_per_pixel,
            max_frame_pixels: cli.max_frame_pixels,
            max_message_bytes: max_message,
            tokens: tokens.clone(),
            start_timeout: Duration::from_secs(cli.start_timeout_secs),
            memory: edgepoint_server::session::memory::MemoryBudget::new(memory_limit),
            metrics: metrics.sessions.clone(),
            simplify_tolerance: cli.simplify_tolerance,
        },
    ));
    let shutdown = service.shutdown_handle();
    if let Some(w) = &cli.web_listen {
        let opts = edgepoint_server::web::WebOptions { tls: web_tls, insecure: cli.insecure };
        edgepoint_server::web::start(w, service.clone(), opts).await?;
    }

    let (health_reporter, health_service) = tonic_health::server::health_reporter();
    health_reporter.set_serving::<RendererServer<RendererService>>().await;

    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening {addr}")?;
        out.flush()?;
    }
    tracing::info!(%addr, max_sessions = cli.max_sessions, tls = tls.is_some(), tokens = tokens.as_ref().map_or(0, |t| t.len()), "renderer serving");

    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let signal_task = tokio::spawn(async move {
        wait_for_signal().await;
        tracing::info!("shutting down: ending sessions");
        health_reporter.set_not_serving::<RendererServer<RendererService>>().await;
        shutdown.shutdown();
        let _ = stop_tx.send(());
    });

    let mut builder = tonic::transport::Server::builder()
        .max_concurrent_streams(Some(MAX_STREAMS_PER_CONNECTION))
        .http2_keepalive_interval(Some(Duration::from_secs(10)))
        .http2_keepalive_timeout(Some(Duration::from_secs(20)));
    if let Some(tls) = tls {
        builder = builder.tls_config(tls).map_err(|e| anyhow::anyhow!("TLS configuration: {e}"))?;
    }
    let server = builder
        .add_service(health_service)
        .add_service(service.shared_server(max_message))
        .serve_with_incoming_shutdown(edgepoint_proto::net::guarded_incoming(listener), async {
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
