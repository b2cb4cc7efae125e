//! `soundmap-load`: load and attack generator for the coordinator, loopback
//! only, bounded in time and count. Each command starts its own
//! `soundmap-coordinator` (the binary beside this one, or `--coordinator`),
//! drives it over real gRPC, samples its resident memory every second and
//! ends with one JSON summary line.
//!
//! ```text
//! soundmap-load soak   [--robots 128] [--rate 125] [--seconds 60]   robots × rate held, lost acks, latency, RSS
//! soundmap-load stamps [--robots 8] [--rate 2000] [--seconds 30]    the identical-stamp flood: RSS
//! soundmap-load ids    [--count 40000] [--channels 16]               throw-away robot ids: RSS, GetState size
//! soundmap-load idle   [--connections 1500] [--from 127.0.0.2]       idle TCP connections vs a robot connecting
//! ```
//!
//! Latency is from an observation's send to the estimate published for it
//! reaching a `WatchEstimates` client: the estimate's stamp is its newest
//! observation's stamp, which the robots take from the wall clock when sending.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::{Parser, Subcommand};
use prost::Message;
use soundmap_proto::wire;
use soundmap_proto::wire::monitoring_client::MonitoringClient;
use soundmap_server::loadgen::{self, RobotLog, RobotSpec, StampMode, rss_bytes, run_robot, wall_clock};

#[derive(Debug, Parser)]
#[command(
    name = "soundmap-load",
    version,
    about = "Load and attack generator for soundmap-coordinator (loopback)"
)]
struct Args {
    /// The coordinator binary (default: `soundmap-coordinator` beside this one).
    #[arg(long, value_name = "PATH", global = true)]
    coordinator: Option<PathBuf>,
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Robots streaming at a rate: acks lost, latency, RSS over time.
    Soak {
        #[arg(long, default_value_t = 128)]
        robots: usize,
        #[arg(long, default_value_t = 125.0)]
        rate: f64,
        #[arg(long, default_value_t = 60)]
        seconds: u64,
    },
    /// Robots sending the same stamp over and over.
    Stamps {
        #[arg(long, default_value_t = 8)]
        robots: usize,
        #[arg(long, default_value_t = 2000.0)]
        rate: f64,
        #[arg(long, default_value_t = 30)]
        seconds: u64,
    },
    /// Hellos of throw-away robot ids, one stream each.
    Ids {
        #[arg(long, default_value_t = 40_000)]
        count: usize,
        #[arg(long, default_value_t = 16)]
        channels: usize,
    },
    /// Idle TCP connections from one address, then a robot from another.
    Idle {
        #[arg(long, default_value_t = 1500)]
        connections: usize,
        #[arg(long, default_value = "127.0.0.2")]
        from: std::net::IpAddr,
    },
}

/// A coordinator child process on a free loopback port.
struct Coordinator {
    child: Child,
    addr: SocketAddr,
    _dir: PathBuf,
}

impl Drop for Coordinator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Coordinator {
    /// Starts it with `extra` TOML and, when given, a descriptor soft limit.
    async fn start(binary: &std::path::Path, extra: &str, nofile: Option<u32>) -> anyhow::Result<Self> {
        let addr = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?;
        let dir = std::env::temp_dir().join(format!("soundmap-load-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        let config = dir.join("coordinator.toml");
        std::fs::write(&config, format!("listen = \"{addr}\"\n{extra}"))?;
        let ulimit = nofile.map(|n| format!("ulimit -n {n} && ")).unwrap_or_default();
        let child = Command::new("sh")
            .arg("-c")
            .arg(format!("{ulimit}exec \"$0\" --config \"$1\""))
            .arg(binary)
            .arg(&config)
            .env("RUST_LOG", std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into()))
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| format!("starting {}", binary.display()))?;
        for _ in 0..100 {
            if tokio::net::TcpStream::connect(addr).await.is_ok() {
                return Ok(Coordinator { child, addr, _dir: dir });
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        anyhow::bail!("the coordinator did not listen on {addr} within 5 s")
    }

    fn rss_mb(&self) -> f64 {
        rss_bytes(self.child.id()).unwrap_or(0) as f64 / 1048576.0
    }
}

fn quantile(sorted: &[u64], q: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    sorted[((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1]
}

/// Runs `n` robots at `rate` with `stamps` for `seconds`, printing RSS every second.
async fn fleet(
    c: &Coordinator,
    n: usize,
    rate: f64,
    stamps: StampMode,
    seconds: u64,
) -> (Vec<RobotLog>, Vec<f64>) {
    let until = Instant::now() + Duration::from_secs(seconds);
    let logs: Vec<Arc<Mutex<RobotLog>>> = (0..n).map(|_| Arc::default()).collect();
    let tasks: Vec<_> = logs
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let spec = RobotSpec::on_ring("load", i, n, 3.0);
            tokio::spawn(run_robot(c.addr, spec, rate, stamps, until, l.clone()))
        })
        .collect();
    let mut rss = Vec::new();
    let started = Instant::now();
    while Instant::now() < until {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let sent: u64 = logs.iter().map(|l| l.lock().unwrap().sent).sum();
        let mb = c.rss_mb();
        rss.push(mb);
        println!("t={:>3.0} s  rss={mb:6.1} MB  sent={sent}", started.elapsed().as_secs_f64());
    }
    for t in tasks {
        let _ = t.await;
    }
    (logs.iter().map(|l| l.lock().unwrap().clone()).collect(), rss)
}

async fn soak(c: &Coordinator, robots: usize, rate: f64, seconds: u64) -> anyhow::Result<serde_json::Value> {
    let mut watch = MonitoringClient::new(loadgen::channel(c.addr).await?)
        .watch_estimates(wire::WatchEstimatesRequest {})
        .await?
        .into_inner();
    let latencies = Arc::new(Mutex::new(Vec::<u64>::new()));
    let lat = latencies.clone();
    let watcher = tokio::spawn(async move {
        while let Ok(Some(e)) = watch.message().await {
            let us = (wall_clock().as_ns() - e.stamp_ns).max(0) as u64 / 1000;
            lat.lock().unwrap().push(us);
        }
    });
    let (logs, rss) = fleet(c, robots, rate, StampMode::Now, seconds).await;
    watcher.abort();
    let sent: u64 = logs.iter().map(|l| l.sent).sum();
    let acked: u64 = logs.iter().map(|l| l.acked_count()).sum();
    let reconnects: u64 = logs.iter().map(|l| l.connections.saturating_sub(1)).sum();
    let mut lat = latencies.lock().unwrap().clone();
    lat.sort_unstable();
    let third = rss.len() / 3;
    Ok(serde_json::json!({
        "command": "soak", "robots": robots, "rate_hz": rate, "seconds": seconds,
        "sent": sent, "acked": acked, "lost_acks": sent - acked.min(sent), "reconnects": reconnects,
        "held_hz_per_robot": acked as f64 / (robots as f64 * seconds as f64),
        "estimates": lat.len(),
        "latency_p50_ms": quantile(&lat, 0.5) as f64 / 1000.0,
        "latency_p99_ms": quantile(&lat, 0.99) as f64 / 1000.0,
        "rss_mb_first_third_max": rss[..third].iter().cloned().fold(0.0, f64::max),
        "rss_mb_last_third_max": rss[rss.len() - third..].iter().cloned().fold(0.0, f64::max),
        "rss_mb_end": rss.last().copied().unwrap_or(0.0),
    }))
}

async fn ids(c: &Coordinator, count: usize, channels: usize) -> anyhow::Result<serde_json::Value> {
    let started = Instant::now();
    let next = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let welcomed = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let mut tasks = Vec::new();
    for _ in 0..channels {
        let ch = loadgen::channel(c.addr).await?;
        let (next, welcomed) = (next.clone(), welcomed.clone());
        tasks.push(tokio::spawn(async move {
            loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if i >= count {
                    return;
                }
                let Ok(hello) = loadgen::hello(&format!("throwaway-{i}")) else { return };
                let stream = tokio_stream::iter([hello]);
                let mut client = wire::robot_link_client::RobotLinkClient::new(ch.clone());
                if let Ok(r) = client.connect(stream).await {
                    let mut inbound = r.into_inner();
                    if let Ok(Some(_)) = inbound.message().await {
                        welcomed.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                }
            }
        }));
    }
    for t in tasks {
        t.await?;
    }
    let took = started.elapsed().as_secs_f64();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let state =
        MonitoringClient::new(loadgen::channel(c.addr).await?).get_state(wire::GetStateRequest {}).await?;
    let state = state.into_inner();
    Ok(serde_json::json!({
        "command": "ids", "count": count, "welcomed": welcomed.load(std::sync::atomic::Ordering::Relaxed),
        "seconds": took, "rss_mb": c.rss_mb(),
        "get_state_bytes": state.encoded_len(), "get_state_robots": state.robots.len(),
    }))
}

async fn idle(
    c: &Coordinator,
    connections: usize,
    from: std::net::IpAddr,
) -> anyhow::Result<serde_json::Value> {
    let mut held = Vec::with_capacity(connections);
    let mut failed = 0;
    for _ in 0..connections {
        let socket = tokio::net::TcpSocket::new_v4()?;
        socket.bind(SocketAddr::new(from, 0))?;
        match tokio::time::timeout(Duration::from_secs(2), socket.connect(c.addr)).await {
            Ok(Ok(s)) => held.push(s),
            _ => failed += 1,
        }
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    // Not ended by the coordinator (its HTTP/2 greeting, or nothing yet): it holds it.
    let open = held
        .iter()
        .filter(|s| match s.try_read(&mut [0u8; 64]) {
            Ok(n) => n > 0,
            Err(e) => e.kind() == std::io::ErrorKind::WouldBlock,
        })
        .count();
    let started = Instant::now();
    let log = Arc::new(Mutex::new(RobotLog::default()));
    let spec = RobotSpec::on_ring("legit", 0, 1, 3.0);
    let until = Instant::now() + Duration::from_millis(300);
    let robot = tokio::spawn(run_robot(c.addr, spec, 50.0, StampMode::Now, until, log.clone()));
    let connected = loop {
        if log.lock().unwrap().connections > 0 {
            break Some(started.elapsed());
        }
        if started.elapsed() > Duration::from_secs(10) {
            break None;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    };
    let _ = robot.await;
    let t = Instant::now();
    let state =
        MonitoringClient::new(loadgen::channel(c.addr).await?).get_state(wire::GetStateRequest {}).await;
    Ok(serde_json::json!({
        "command": "idle", "connections": connections, "connect_failed": failed, "held_open_by_coordinator": open,
        "robot_welcome_ms": connected.map(|d| d.as_secs_f64() * 1e3),
        "get_state_ok": state.is_ok(), "get_state_ms": t.elapsed().as_secs_f64() * 1e3,
        "rss_mb": c.rss_mb(),
    }))
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let binary = match args.coordinator {
        Some(p) => p,
        None => std::env::current_exe()?.with_file_name("soundmap-coordinator"),
    };
    let summary = match args.command {
        Cmd::Soak { robots, rate, seconds } => {
            let extra = format!("[server]\nmax_connections_per_peer = {}\n", robots + 64);
            let c = Coordinator::start(&binary, &extra, None).await?;
            soak(&c, robots, rate, seconds).await?
        }
        Cmd::Stamps { robots, rate, seconds } => {
            let c = Coordinator::start(&binary, "", None).await?;
            let (logs, rss) = fleet(&c, robots, rate, StampMode::Fixed(wall_clock()), seconds).await;
            let sent: u64 = logs.iter().map(|l| l.sent).sum();
            let rejected: u64 = logs.iter().map(|l| l.errors).sum();
            serde_json::json!({
                "command": "stamps", "robots": robots, "rate_hz": rate, "seconds": seconds,
                "sent": sent, "rejected_in_band": rejected,
                "rss_mb_max": rss.iter().cloned().fold(0.0, f64::max), "rss_mb_end": c.rss_mb(),
            })
        }
        Cmd::Ids { count, channels } => {
            let c = Coordinator::start(&binary, "", None).await?;
            ids(&c, count, channels).await?
        }
        Cmd::Idle { connections, from } => {
            // The coordinator at the default soft limit of 1,024 descriptors.
            let c = Coordinator::start(&binary, "", Some(1024)).await?;
            idle(&c, connections, from).await?
        }
    };
    println!("{summary}");
    Ok(())
}
