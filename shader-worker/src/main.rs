//! `edgepoint-worker`: the shader-worker process. Serves the `ShaderWorker` gRPC service and
//! grpc.health.v1, prints `metrics <addr>` (with `--metrics-listen`) and then
//! `listening <addr>` on stdout once bound, logs to stderr. See `edgepoint_worker::cli`.
use clap::Parser;
use edgepoint_proto::auth::{read_token_file, RequireToken};
use edgepoint_proto::net::{check_worker_exposure, server_mutual_tls, server_tls};
use edgepoint_proto::shader_worker_server::ShaderWorkerServer;
use edgepoint_worker::cli::WorkerArgs;
use edgepoint_worker::service::WorkerService;
use std::io::Write;
use std::sync::Arc;
use std::time::Duration;

/// After SIGTERM, how long streams get to drain before the process exits regardless.
const DRAIN_GRACE: Duration = Duration::from_secs(10);

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    edgepoint_proto::logging::init("info");
    edgepoint_proto::heap::keep_freed_memory();
    let args = WorkerArgs::parse();
    let threads = args.threads.map(|t| t as usize).unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    let tls = match (&args.tls_cert, &args.tls_key, &args.tls_client_ca) {
        (Some(c), Some(k), Some(ca)) => Some(server_mutual_tls(c, k, ca).map_err(anyhow::Error::msg)?),
        (Some(c), Some(k), None) => Some(server_tls(c, k).map_err(anyhow::Error::msg)?),
        _ => None,
    };
    let tokens = match &args.token_file {
        Some(p) => Some(Arc::new(read_token_file(p).map_err(anyhow::Error::msg)?)),
        None => None,
    };
    let service = WorkerService::new(args.scene_cache as usize, threads)?;
    let listener = tokio::net::TcpListener::bind(&args.listen)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", args.listen))?;
    let addr = listener.local_addr()?;
    let authenticated = tokens.is_some() || args.tls_client_ca.is_some();
    check_worker_exposure(addr, tls.is_some(), authenticated, args.insecure).map_err(anyhow::Error::msg)?;

    if let Some(m) = &args.metrics_listen {
        let (metrics, cache) = (service.metrics().clone(), service.cache().clone());
        edgepoint_proto::metrics_http::start(
            m,
            args.metrics_public,
            Arc::new(move || {
                metrics.scenes.set(cache.hashes().len() as i64);
                metrics.encode()
            }),
        )
        .await?;
    }
    println!("listening {addr}");
    std::io::stdout().flush()?;
    tracing::info!(%addr, threads, tls = tls.is_some(), mutual_tls = args.tls_client_ca.is_some(),
        tokens = tokens.as_ref().map_or(0, |t| t.len()), "edgepoint-worker serving");

    let (health, health_service) = tonic_health::server::health_reporter();
    health.set_serving::<ShaderWorkerServer<WorkerService>>().await;
    let max = (args.max_message_mib as usize).saturating_mul(1 << 20);
    let drain = service.drain_handle();
    let (stopping_tx, stopping_rx) = tokio::sync::oneshot::channel::<()>();
    let signal = async move {
        shutdown().await;
        tracing::info!("shutting down: finishing the batches in progress");
        health.set_not_serving::<ShaderWorkerServer<WorkerService>>().await;
        drain.drain();
        let _ = stopping_tx.send(());
    };
    let mut builder = tonic::transport::Server::builder()
        .http2_keepalive_interval(Some(Duration::from_secs(10)))
        .http2_keepalive_timeout(Some(Duration::from_secs(20)));
    if let Some(tls) = tls {
        builder = builder.tls_config(tls).map_err(|e| anyhow::anyhow!("TLS configuration: {e}"))?;
    }
    let server = builder
        .add_service(health_service)
        .add_service(tonic::service::interceptor::InterceptedService::new(
            ShaderWorkerServer::new(service).max_decoding_message_size(max).max_encoding_message_size(max),
            RequireToken::new(tokens, "start the renderer with --worker-token-file FILE holding one of this worker's tokens"),
        ))
        .serve_with_incoming_shutdown(edgepoint_proto::net::guarded_incoming(listener), signal);
    tokio::select! {
        r = server => r?,
        _ = async {
            let _ = stopping_rx.await;
            tokio::time::sleep(DRAIN_GRACE).await;
        } => tracing::warn!("streams did not drain within {DRAIN_GRACE:?}; exiting"),
    }
    tracing::info!("edgepoint-worker stopped");
    Ok(())
}

async fn shutdown() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).expect("SIGTERM handler");
        tokio::select! { _ = ctrl_c => {}, _ = term.recv() => {} }
    }
    #[cfg(not(unix))]
    let _ = ctrl_c.await;
}
