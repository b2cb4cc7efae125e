//! Coordinator benchmarks (`cargo bench -p soundmap-server --bench server`).
//!
//! - triangulation: the paper's closest point (reference) vs the full pair
//!   triangulation with covariance, GDOP, θ and gate; 8-ray LS + LM;
//! - the gRPC service over loopback with 2, 16 and 128 robot streams:
//!   observations per second and the latency from an observation's receipt
//!   to the publication of the first estimate that used it.
//!
//! Options: `--quick` (shorter runs), `--only NAME` (triangulation | service).

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Point3, Unit, Vector3};
use soundmap_proto::wire::robot_link_client::RobotLinkClient;
use soundmap_proto::wire::robot_message::Msg as Up;
use soundmap_proto::{ArrayInfo, Hello, Observation, RobotId, Stamp, TrackedDoa, wire};
use soundmap_server::clock::SystemClock;
use soundmap_server::triangulation::pair::paper_ray_to_ray;
use soundmap_server::{CoordinatorConfig, Ray, TriangulationConfig, service, triangulate};

/// Best-of-`reps` nanoseconds per call of `f` over `n` calls.
fn time_per_call(reps: usize, n: usize, mut f: impl FnMut(usize)) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let start = Instant::now();
        for i in 0..n {
            f(i);
        }
        best = best.min(start.elapsed().as_nanos() as f64 / n as f64);
    }
    best
}

fn rays_around(source: Point3<f64>, n: usize, k: usize) -> Vec<Ray> {
    (0..n)
        .map(|i| {
            let a = i as f64 * std::f64::consts::TAU / n as f64 + 0.01 * k as f64;
            let o = source + Vector3::new(3.0 * a.cos(), 3.0 * a.sin(), -0.6);
            let wobble =
                Vector3::new((k as f64 * 0.37 + i as f64).sin(), (k as f64 * 0.71).cos(), 0.3) * 0.05;
            Ray {
                origin: o,
                direction: Unit::new_normalize(source - o + wobble),
                sigma_rad: 0.05,
                origin_sigma_m: 0.01,
            }
        })
        .collect()
}

fn bench_triangulation(quick: bool) {
    let source = Point3::new(2.0, 3.0, 1.12);
    let sets: Vec<Vec<Ray>> = (0..256).map(|k| rays_around(source, 2, k)).collect();
    let sets8: Vec<Vec<Ray>> = (0..256).map(|k| rays_around(source, 8, k)).collect();
    let sets128: Vec<Vec<Ray>> = (0..64).map(|k| rays_around(source, 128, k)).collect();
    let cfg = TriangulationConfig::default();
    let n = if quick { 20_000 } else { 200_000 };
    let paper = time_per_call(5, n, |i| {
        let r = &sets[i % 256];
        black_box(paper_ray_to_ray(&r[0].origin, &r[0].direction, &r[1].origin, &r[1].direction));
    });
    let pair = time_per_call(5, n, |i| {
        black_box(triangulate(black_box(&sets[i % 256]), &cfg));
    });
    let n8 = n / 10;
    let lm8 = time_per_call(5, n8, |i| {
        black_box(triangulate(black_box(&sets8[i % 256]), &cfg));
    });
    let lm128 = time_per_call(3, n / 200, |i| {
        black_box(triangulate(black_box(&sets128[i % 64]), &cfg));
    });
    println!("## triangulation (one thread)");
    println!("| operation | ns per call |");
    println!("|---|---|");
    println!("| paper's ray-to-ray point only (reference) | {paper:.0} |");
    println!("| pair triangulation with covariance, GDOP, θ, κ, gate | {pair:.0} |");
    println!(
        "| 8 rays: IRLS least squares + Levenberg–Marquardt (Cauchy) with covariance and gate | {lm8:.0} |"
    );
    println!(
        "| 128 rays: IRLS least squares + Levenberg–Marquardt (Cauchy) with covariance and gate | {lm128:.0} |"
    );
    println!("pair / paper ratio: {:.1}×; target for the pair: < 1000 ns\n", pair / paper);
}

fn hello(i: usize) -> wire::RobotMessage {
    let h = Hello {
        robot_id: RobotId::parse(&format!("bench-{i}"), "id").expect("valid id"),
        array: ArrayInfo {
            base_from_array: Isometry3::translation(0.0, 0.0, 0.48),
            microphone_count: 16,
            preset: None,
            microphone_positions: vec![],
        },
        software_version: "bench".into(),
    };
    wire::RobotMessage { msg: Some(Up::Hello(h.to_wire())) }
}

fn observation(i: usize, n: usize, seq: u64, stamp: Stamp) -> wire::RobotMessage {
    let source = Point3::new(0.0, 0.0, 1.12);
    let a = i as f64 * std::f64::consts::TAU / n as f64;
    let base = Point3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.0);
    let d = source - (base + Vector3::new(0.0, 0.0, 0.48));
    let o = Observation {
        sequence: seq,
        stamp,
        map_from_base: Isometry3::translation(base.x, base.y, 0.0),
        pose_covariance: None,
        doas: vec![TrackedDoa {
            track_id: 1,
            direction_in_array: Unit::new_normalize(d),
            activity: 0.9,
            angular_sigma_rad: Some(0.05),
        }],
    };
    wire::RobotMessage { msg: Some(Up::Observation(o.to_wire())) }
}

/// How a robot paces its observations.
#[derive(Clone, Copy)]
enum Load {
    /// As fast as acknowledgements allow, with at most this many unacknowledged.
    Saturate(u64),
    /// At this rate (observations per second), whatever the acknowledgements do.
    Paced(f64),
}

/// One robot streaming observations until `stop`; returns how many were acknowledged.
async fn robot(channel: tonic::transport::Channel, i: usize, n: usize, load: Load, stop: Instant) -> u64 {
    let (tx, rx) = tokio::sync::mpsc::channel(4096);
    tx.send(hello(i)).await.expect("open");
    let mut stream = RobotLinkClient::new(channel)
        .connect(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .expect("connect")
        .into_inner();
    let _welcome = stream.message().await.expect("welcome");
    let acked = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let notify = Arc::new(tokio::sync::Notify::new());
    let reader = {
        let (acked, notify) = (acked.clone(), notify.clone());
        tokio::spawn(async move {
            while let Ok(Some(m)) = stream.message().await {
                if let Some(wire::coordinator_message::Msg::ObservationAck(a)) = m.msg {
                    acked.store(a.up_to_sequence, std::sync::atomic::Ordering::Release);
                    notify.notify_one();
                }
            }
        })
    };
    let mut sent = 0u64;
    match load {
        Load::Saturate(window) => {
            while Instant::now() < stop {
                while sent >= acked.load(std::sync::atomic::Ordering::Acquire) + window {
                    notify.notified().await;
                }
                sent += 1;
                let _ = tx.send(observation(i, n, sent, Stamp::now())).await;
            }
        }
        Load::Paced(rate) => {
            let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / rate));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
            while Instant::now() < stop {
                tick.tick().await;
                sent += 1;
                let _ = tx.send(observation(i, n, sent, Stamp::now())).await;
            }
        }
    }
    // Let the last acknowledgements arrive.
    let deadline = Instant::now() + Duration::from_secs(2);
    while acked.load(std::sync::atomic::Ordering::Acquire) < sent && Instant::now() < deadline {
        let _ = tokio::time::timeout(Duration::from_millis(50), notify.notified()).await;
    }
    drop(tx);
    reader.abort();
    acked.load(std::sync::atomic::Ordering::Acquire)
}

struct ServiceFigures {
    rate: f64,
    p50: Duration,
    p99: Duration,
    max: Duration,
    samples: u64,
}

/// Drives `n` robots against the coordinator at `addr` and reads its latency metrics.
async fn drive(
    addr: std::net::SocketAddr,
    metrics: Arc<service::Metrics>,
    n: usize,
    load: Load,
    seconds: f64,
) -> ServiceFigures {
    let endpoint = format!("http://{addr}");
    // Robots share a few HTTP/2 connections: a load generator on one machine
    // cannot afford one per robot as real robots would have.
    let connections = n.clamp(1, 8);
    let mut channels = Vec::new();
    for _ in 0..connections {
        channels.push(
            tonic::transport::Endpoint::from_shared(endpoint.clone())
                .expect("uri")
                .tcp_nodelay(true)
                .connect()
                .await
                .expect("connect"),
        );
    }
    let warm = Instant::now() + Duration::from_millis(300);
    let tasks: Vec<_> =
        (0..n).map(|i| tokio::spawn(robot(channels[i % connections].clone(), i, n, load, warm))).collect();
    for t in tasks {
        t.await.expect("robot");
    }
    let _ = metrics.take_latency(true);
    let start = Instant::now();
    let stop = start + Duration::from_secs_f64(seconds);
    let tasks: Vec<_> = (0..n)
        .map(|i| tokio::spawn(robot(channels[i % connections].clone(), i + n, n, load, stop)))
        .collect();
    let mut total = 0;
    for t in tasks {
        total += t.await.expect("robot");
    }
    let h = metrics.take_latency(false);
    ServiceFigures {
        rate: total as f64 / seconds,
        p50: h.quantile(0.5),
        p99: h.quantile(0.99),
        max: h.max(),
        samples: h.count(),
    }
}

fn bench_service(quick: bool) {
    // The coordinator and the load generator run on separate runtimes (as they
    // would in separate processes); the coordinator task has its own thread.
    let runtime = |name: &str| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name(name)
            .enable_all()
            .build()
            .expect("runtime")
    };
    let (server_rt, client_rt) = (runtime("coordinator-rt"), runtime("load-rt"));
    let seconds = if quick { 1.0 } else { 4.0 };
    println!(
        "## coordinator service over loopback (coordinator: 2 worker threads + its task's thread; load generator: 2 threads in the same process)"
    );
    println!(
        "| robot streams | load | observations/s acknowledged | p50 latency | p99 latency | max | samples |"
    );
    println!("|---|---|---|---|---|---|---|");
    for n in [2, 16, 128] {
        for (name, load) in [
            ("50,000/s offered", Load::Paced(50_000.0 / n as f64)),
            ("saturating (16 in flight per robot)", Load::Saturate(16)),
        ] {
            let running = server_rt.block_on(async {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("bind");
                let mut config = CoordinatorConfig::default();
                config.liveness.tick_ms = 0;
                service::start(config, Arc::new(SystemClock), listener).await.expect("start")
            });
            let f = client_rt.block_on(drive(running.local_addr, running.metrics.clone(), n, load, seconds));
            server_rt.block_on(running.shutdown()).expect("shutdown");
            println!(
                "| {n} | {name} | {:.0} | {:?} | {:?} | {:?} | {} |",
                f.rate, f.p50, f.p99, f.max, f.samples
            );
        }
    }
    println!(
        "latency: receipt of an observation by its stream handler → publication of the first estimate using it"
    );
    println!("targets: ≥ 50,000 observations/s with 128 robots, p99 < 5 ms\n");
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let only = args.iter().position(|a| a == "--only").and_then(|i| args.get(i + 1)).cloned();
    let run = |name: &str| only.as_deref().is_none_or(|o| o == name);
    if run("triangulation") {
        bench_triangulation(quick);
    }
    if run("service") {
        bench_service(quick);
    }
}
