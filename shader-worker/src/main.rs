//! `edgepoint-worker`: the shader-worker process. Serves the `ShaderWorker` gRPC service and
//! grpc.health.v1, prints `listening <addr>` on stdout once bound, logs to stderr.
use clap::Parser;
use edgepoint_proto::shader_worker_server::ShaderWorkerServer;
use edgepoint_worker::service::WorkerService;
use std::io::Write;

#[derive(Parser, Debug)]
#[command(name = "edgepoint-worker", version, about = "edgepoint shader worker: shades batches of ray requests for the renderer over gRPC")]
struct Args {
    /// Address to listen on (port 0 picks a free port; the bound address is printed on
    /// stdout as `listening <addr>`).
    #[arg(long, default_value = "127.0.0.1:50061")]
    listen: String,
    /// Shading threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Scenes kept loaded (least recently used ones are dropped first).
    #[arg(long, default_value_t = 4)]
    scene_cache: usize,
    /// Largest gRPC message accepted or sent, in MiB (scenes travel as bytes).
    #[arg(long, default_value_t = 256)]
    max_message_mib: usize,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    let args = Args::parse();
    let threads = args.threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    if threads == 0 {
        anyhow::bail!("--threads must be at least 1");
    }
    let service = WorkerService::new(args.scene_cache, threads)?;
    let listener = tokio::net::TcpListener::bind(&args.listen)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {}: {e}", args.listen))?;
    let addr = listener.local_addr()?;
    println!("listening {addr}");
    std::io::stdout().flush()?;
    tracing::info!(%addr, threads, "edgepoint-worker serving");

    let (health, health_service) = tonic_health::server::health_reporter();
    health.set_serving::<ShaderWorkerServer<WorkerService>>().await;
    let max = args.max_message_mib.saturating_mul(1 << 20);
    tonic::transport::Server::builder()
        .http2_keepalive_interval(Some(std::time::Duration::from_secs(10)))
        .add_service(health_service)
        .add_service(ShaderWorkerServer::new(service).max_decoding_message_size(max).max_encoding_message_size(max))
        .serve_with_incoming_shutdown(edgepoint_proto::net::no_delay_incoming(listener), shutdown())
        .await?;
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
