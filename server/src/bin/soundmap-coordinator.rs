//! `soundmap-coordinator`: the coordinator service.
//!
//! ```text
//! soundmap-coordinator [--config FILE] [--listen ADDR] [--estimates-jsonl FILE] [--metrics ADDR]
//!                      [--foxglove ADDR] [--record FILE.mcap]
//! ```

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use clap::Parser;
use soundmap_server::clock::SystemClock;
use soundmap_server::{CoordinatorConfig, service};

/// Triangulates sound sources from the bearings robots stream to it.
#[derive(Debug, Parser)]
#[command(name = "soundmap-coordinator", version)]
struct Args {
    /// Configuration file (TOML). Every key is optional; unknown keys are errors.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Address to listen on (overrides `listen` in the config), e.g. 0.0.0.0:50051.
    #[arg(long, value_name = "ADDR")]
    listen: Option<std::net::SocketAddr>,
    /// Append estimates to this JSON-lines file (overrides `output.estimates_jsonl`).
    #[arg(long, value_name = "FILE")]
    estimates_jsonl: Option<PathBuf>,
    /// Append every accepted observation to this JSON-lines file (overrides `output.observations_jsonl`).
    #[arg(long, value_name = "FILE")]
    observations_jsonl: Option<PathBuf>,
    /// Keep state that survives a restart (sources, robots, operator settings)
    /// in DIR (overrides `state.dir`; the systemd unit gives its StateDirectory).
    #[arg(long, value_name = "DIR")]
    state_dir: Option<PathBuf>,
    /// Serve the Foxglove live view (WebSocket, `foxglove.websocket.v1`) on ADDR
    /// (overrides `foxglove.listen`), e.g. 127.0.0.1:8765.
    #[arg(long, value_name = "ADDR")]
    foxglove: Option<std::net::SocketAddr>,
    /// Record the live view's channels and the raw soundmap.v1 messages to this
    /// MCAP file (overrides `record.mcap`; the file is replaced).
    #[arg(long, value_name = "FILE.mcap")]
    record: Option<PathBuf>,
    /// Serve Prometheus metrics at http://ADDR/metrics (overrides `metrics.listen`), e.g. 127.0.0.1:9464.
    #[arg(long, value_name = "ADDR")]
    metrics: Option<std::net::SocketAddr>,
    /// Check the configuration and exit: every key, the TLS files, that the
    /// output files are writable and that the listen address can be bound.
    #[arg(long)]
    check: bool,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let args = Args::parse();
    let mut config = match &args.config {
        Some(path) => CoordinatorConfig::from_file(path)?,
        None => CoordinatorConfig::default(),
    };
    if let Some(listen) = args.listen {
        config.listen = listen;
    }
    if let Some(path) = args.estimates_jsonl {
        config.output.estimates_jsonl = Some(path);
    }
    if let Some(path) = args.observations_jsonl {
        config.output.observations_jsonl = Some(path);
    }
    if let Some(dir) = args.state_dir {
        config.state.dir = Some(dir);
    }
    if let Some(addr) = args.foxglove {
        config.foxglove.listen = Some(addr);
    }
    if let Some(path) = args.record {
        config.record.mcap = Some(path);
    }
    if let Some(addr) = args.metrics {
        config.metrics.listen = Some(addr);
    }
    if args.check {
        check_environment(&config)?;
        println!("configuration OK");
        return Ok(());
    }
    let listener = tokio::net::TcpListener::bind(config.listen)
        .await
        .with_context(|| format!("cannot listen on {}", config.listen))?;
    let running = service::start(config, Arc::new(SystemClock), listener).await?;
    tracing::info!("soundmap-coordinator {} listening on {}", env!("CARGO_PKG_VERSION"), running.local_addr);
    shutdown_signal().await?;
    tracing::info!("shutting down");
    running.shutdown().await?;
    Ok(())
}

/// What `--check` verifies beyond the file's keys: the TLS files parse, every
/// output file can be appended to (created and removed again when it does
/// not exist yet), and the listen address can be bound now.
fn check_environment(config: &CoordinatorConfig) -> anyhow::Result<()> {
    soundmap_server::tls::server_config(&config.tls)?;
    for (key, path) in [
        ("output.estimates_jsonl", &config.output.estimates_jsonl),
        ("output.observations_jsonl", &config.output.observations_jsonl),
    ] {
        if let Some(path) = path {
            check_writable(path).with_context(|| format!("{key}: {} is not writable", path.display()))?;
        }
    }
    std::net::TcpListener::bind(config.listen)
        .with_context(|| format!("listen: cannot bind {}", config.listen))?;
    Ok(())
}

fn check_writable(path: &std::path::Path) -> std::io::Result<()> {
    let mut options = std::fs::OpenOptions::new();
    if path.exists() {
        options.append(true).open(path).map(drop)
    } else {
        options.append(true).create_new(true).open(path)?;
        std::fs::remove_file(path)
    }
}

async fn shutdown_signal() -> anyhow::Result<()> {
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    tokio::select! {
        r = tokio::signal::ctrl_c() => r?,
        _ = term.recv() => {}
    }
    Ok(())
}
