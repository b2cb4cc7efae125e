//! The live agent (`soundmap-agent run`): the shell around the
//! [agent core](crate::agent).
//!
//! Everything that can fail on bad configuration is prepared first (files
//! opened, sockets bound: [`LivePlan::prepare`]); then an audio thread reads
//! (and, for files with `realtime`, paces) blocks, a DSP thread runs the
//! pipeline, poses come from a TUM file (all given to the core up front) or a
//! live JSON-lines feed, and the [`Link`] task drives the core, the stream to
//! the coordinator and the navigator.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use soundmap_proto::Stamp;
use tokio::sync::mpsc;

use crate::AgentError;
use crate::agent::{self, Agent, CoreConfig};
use crate::array::ArrayGeometry;
use crate::audio::{self, AudioInput, AudioSource, BlockOptions};
use crate::config::{AgentConfig, DoaSource, OdasInput, PoseSource};
use crate::link::{Hop, Link, LinkInputs, LinkStats};
use crate::navigator::JsonLinesNavigator;
use crate::odas::{self, LiveStart, OdasTiming};
use crate::pipeline::Pipeline;
use crate::pose::{self, PoseBuffer, PoseTimeMapping, StampedPose};

/// Blocks in the pool between the audio thread and the DSP thread (the bound of their channel).
const AUDIO_BLOCKS: usize = 32;
/// Hops queued toward the link task.
const HOP_QUEUE: usize = 256;
/// Longest wait for acknowledgements once the input has ended.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(10);

/// Where hops will come from, prepared (files opened, sockets bound).
enum HopPlan {
    Own { source: Box<dyn AudioSource>, pipeline: Box<Pipeline>, file: bool, realtime: bool },
    OdasFile { frames: Vec<odas::OdasFrame>, realtime: bool },
    OdasFollow { path: std::path::PathBuf, hop_len: u32, sample_rate_hz: u32, start: LiveStart },
    OdasListen { listener: std::net::TcpListener, hop_len: u32, sample_rate_hz: u32, start: LiveStart },
}

impl HopPlan {
    /// A finished recording read as fast as possible.
    fn is_asap_file(&self) -> bool {
        matches!(
            self,
            HopPlan::Own { file: true, realtime: false, .. } | HopPlan::OdasFile { realtime: false, .. }
        )
    }
}

/// Where poses will come from.
enum PosePlan {
    /// A whole trajectory, given to the core before anything starts.
    Tum,
    Tcp(std::net::TcpListener),
    Stdin,
}

/// A live agent ready to run: its core, inputs and navigator.
pub struct LivePlan {
    config: AgentConfig,
    core: Agent,
    hops: HopPlan,
    poses: PosePlan,
    /// The poses the DSP thread reads the base's orientation from (see
    /// [`Pipeline::set_base_orientation`]): the whole trajectory of a TUM
    /// file, or the live feed's poses as they arrive.
    orientations: Orientations,
    navigator: JsonLinesNavigator,
    /// `[odas_out]`: the tracks also written as ODAS's SST JSON.
    odas_out: Option<odas::out::OdasOut>,
}

/// Poses shared with the DSP thread.
type Orientations = Arc<Mutex<PoseBuffer>>;

impl std::fmt::Debug for LivePlan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LivePlan").field("robot_id", &self.config.robot_id).finish_non_exhaustive()
    }
}

fn named(cfg: &str, what: &str, e: AgentError) -> AgentError {
    match e {
        AgentError::InvalidParameter { field, message } => {
            AgentError::Config { path: cfg.into(), field: format!("{what}.{field}"), message }
        }
        other => other,
    }
}

impl LivePlan {
    /// Loads the array, opens the inputs, binds the sockets and builds the core.
    /// Errors name the configuration file and field.
    pub fn prepare(config: AgentConfig) -> Result<Self, AgentError> {
        let cfg_name = config.path.display().to_string();
        let array = ArrayGeometry::load(&config.array).map_err(|e| AgentError::Config {
            path: config.path.clone(),
            field: "array".into(),
            message: e.to_string(),
        })?;
        let robot_id = config.robot_id.clone();
        let version = format!("soundmap-agent {}", env!("CARGO_PKG_VERSION"));
        let mut hello = agent::hello(robot_id, &array, version);
        hello.base_limits = config.navigator.base_limits;
        if let DoaSource::Own { pipeline, .. } = &config.doa {
            // The robot declares how many tracks it sends and its signature bands.
            hello = pipeline.declare_tracks(hello).map_err(|e| named(&cfg_name, "pipeline", e))?;
        }
        let audio_start = Stamp::now();
        // `origin`: the time of the first sample (or of ODAS's hop 1), see the clock rule in `odas`.
        let (hops, origin, sigma_floor_deg) = plan_hops(&config, &array, audio_start, &cfg_name)?;
        let mut core_config = CoreConfig {
            pose_buffer: config.pose.buffer,
            max_pose_wait_s: config.pose.max_wait_s,
            buffer_capacity: config.link.buffer_capacity,
            doa_sigma_floor_rad: sigma_floor_deg.to_radians(),
            ..CoreConfig::default()
        };
        let (poses, trajectory) = match &config.pose.source {
            PoseSource::Tum { path, start_s } => {
                let mapping = start_s.map_or(PoseTimeMapping::UNIX, |s| PoseTimeMapping::new(s, origin));
                (PosePlan::Tum, pose::read_tum(path, mapping)?)
            }
            PoseSource::JsonlTcp(addr) => {
                (PosePlan::Tcp(bind(*addr, &format!("{cfg_name}: pose.listen"))?), vec![])
            }
            PoseSource::JsonlStdin => (PosePlan::Stdin, vec![]),
        };
        core_config.pose_buffer.capacity = core_config.pose_buffer.capacity.max(trajectory.len());
        let mut orientations = PoseBuffer::new(format!("{cfg_name}: pose"), core_config.pose_buffer)?;
        let mut core = Agent::new(hello, core_config, &format!("{cfg_name}: pose"))?;
        if matches!(poses, PosePlan::Tum) {
            for p in &trajectory {
                orientations.push(p.clone())?;
            }
            core.handle_trajectory(Stamp::now(), trajectory)?;
        }
        let orientations = Arc::new(Mutex::new(orientations));
        let navigator =
            JsonLinesNavigator::open(&config.navigator.path, config.navigator.arrival_tolerance_m)?;
        let odas_out = config.odas_out.as_ref().map(odas::out::OdasOut::open).transpose()?;
        Ok(LivePlan { config, core, hops, poses, orientations, navigator, odas_out })
    }

    /// Runs the agent until its input ends (and everything is acknowledged) or
    /// Ctrl-C; returns the link's counters.
    pub fn run(self) -> Result<LinkStats, AgentError> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .map_err(|source| AgentError::Io { path: "<tokio runtime>".into(), source })?;
        let result = runtime.block_on(self.run_async());
        // A read of standard input blocked in tokio's blocking pool must not hold the exit.
        runtime.shutdown_timeout(Duration::from_millis(200));
        result
    }

    async fn run_async(self) -> Result<LinkStats, AgentError> {
        let stop = Arc::new(AtomicBool::new(false));
        let (hops_tx, mut hops_rx) = mpsc::channel::<Hop>(HOP_QUEUE);
        let lossless = self.hops.is_asap_file();
        let threads = start_hops(self.hops, hops_tx, stop.clone(), self.orientations.clone())?;
        let mut odas_out = None;
        if let Some(out) = self.odas_out {
            let (rx, task) = tee_odas_out(hops_rx, out);
            (hops_rx, odas_out) = (rx, Some(task));
        }
        let poses_rx = start_poses(self.poses)?.map(|rx| share_poses(rx, self.orientations));
        let inputs = LinkInputs { hops: hops_rx, poses: poses_rx, lossless };
        let (link, task) =
            Link::spawn(self.config.link.clone(), self.core, Box::new(self.navigator), inputs, DRAIN_TIMEOUT);
        let stats = tokio::select! {
            r = task => r.map_err(|e| AgentError::Link(format!("the link task failed: {e}")))?,
            _ = tokio::signal::ctrl_c() => {
                tracing::info!("interrupted");
                link.shutdown();
                link.stats()
            }
        };
        stop.store(true, Ordering::SeqCst);
        if let Some(task) = odas_out {
            // Every hop's object is written once the input has ended.
            let _ = tokio::time::timeout(Duration::from_secs(2), task).await;
        }
        tracing::info!(
            "sent {} observations ({} resent, {} acknowledged, {} dropped by the link, {} hops without a pose), \
             {} stream errors, {} commands",
            stats.sent,
            stats.resent,
            stats.acked,
            stats.dropped,
            stats.hops_without_pose,
            stats.stream_errors,
            stats.commands
        );
        if let Some((reader, dsp)) = threads {
            dsp.join().map_err(|_| AgentError::Link("the DSP thread panicked".into()))?;
            reader.join().map_err(|_| AgentError::Link("the audio thread panicked".into()))??;
        }
        Ok(stats)
    }
}

fn plan_hops(
    config: &AgentConfig,
    array: &ArrayGeometry,
    audio_start: Stamp,
    cfg_name: &str,
) -> Result<(HopPlan, Stamp, f64), AgentError> {
    Ok(match &config.doa {
        DoaSource::Own { audio, pipeline } => {
            let p = Pipeline::new(array, pipeline).map_err(|e| named(cfg_name, "pipeline", e))?;
            let options = BlockOptions {
                hop_len: p.hop_len(),
                channels: array.channels(),
                sample_rate_hz: p.sample_rate_hz(),
                channel_map: audio.channel_map.clone(),
                start: audio.start.unwrap_or(audio_start),
            };
            let mut start = options.start;
            let mut source = audio::open(&audio.input, &options)?;
            let file = matches!(audio.input, AudioInput::Wav { .. } | AudioInput::Raw { .. });
            if let (None, false, Some(frames)) = (audio.start, audio.realtime, source.frames_total()) {
                // asap: the file ends when the agent starts, so no stamp runs ahead of the clock.
                let length_ns = audio::stamp_of_frame(Stamp::ZERO, frames, p.sample_rate_hz()).as_ns();
                start = audio_start.plus_ns(-length_ns);
                source = audio::open(&audio.input, &BlockOptions { start, ..options })?;
            }
            let floor = p.doa_sigma_floor_rad().to_degrees();
            (
                HopPlan::Own { source, pipeline: Box::new(p), file, realtime: file && audio.realtime },
                start,
                floor,
            )
        }
        DoaSource::Odas(o) => {
            let floor = CoreConfig::default().doa_sigma_floor_rad.to_degrees();
            match &o.input {
                OdasInput::File { path, follow: false } => {
                    let mut timing = OdasTiming {
                        hop_len: o.hop_len,
                        sample_rate_hz: o.sample_rate_hz,
                        start: o.start.unwrap_or(audio_start),
                    };
                    let mut frames = odas::read_sst_file(path, &timing)?;
                    if o.start.is_none() && !o.realtime {
                        // asap: the recording ends when the agent starts (the clock rule).
                        let end = frames.last().map_or(0, |f| timing.stamp(f.time_stamp + 1) - timing.start);
                        timing.start = audio_start.plus_ns(-end);
                        for f in &mut frames {
                            f.stamp = timing.stamp(f.time_stamp);
                        }
                    }
                    (HopPlan::OdasFile { frames, realtime: o.realtime }, timing.start, floor)
                }
                OdasInput::File { path, follow: true } => (
                    HopPlan::OdasFollow {
                        path: path.clone(),
                        hop_len: o.hop_len,
                        sample_rate_hz: o.sample_rate_hz,
                        start: o.start.map_or(LiveStart::AtFirstFrame, LiveStart::Fixed),
                    },
                    o.start.unwrap_or(audio_start),
                    floor,
                ),
                OdasInput::Listen(addr) => (
                    HopPlan::OdasListen {
                        listener: bind(*addr, &format!("{cfg_name}: doa.listen"))?,
                        hop_len: o.hop_len,
                        sample_rate_hz: o.sample_rate_hz,
                        start: o.start.map_or(LiveStart::AtFirstFrame, LiveStart::Fixed),
                    },
                    o.start.unwrap_or(audio_start),
                    floor,
                ),
            }
        }
    })
}

fn bind(addr: std::net::SocketAddr, what: &str) -> Result<std::net::TcpListener, AgentError> {
    let io = |source| AgentError::Io { path: format!("{what}: cannot listen on {addr}").into(), source };
    let l = std::net::TcpListener::bind(addr).map_err(io)?;
    l.set_nonblocking(true).map_err(io)?;
    Ok(l)
}

type Threads = (std::thread::JoinHandle<Result<(), AgentError>>, std::thread::JoinHandle<()>);

/// Starts whatever produces hops; returns the audio and DSP threads when there are some.
fn start_hops(
    plan: HopPlan,
    out: mpsc::Sender<Hop>,
    stop: Arc<AtomicBool>,
    orientations: Orientations,
) -> Result<Option<Threads>, AgentError> {
    match plan {
        HopPlan::Own { source, pipeline, realtime, .. } => {
            return Ok(Some(spawn_dsp(source, pipeline, realtime, out, stop, orientations)));
        }
        HopPlan::OdasFile { frames, realtime } => {
            tokio::spawn(async move {
                let (wall0, stamp0) = (Instant::now(), frames.first().map_or(Stamp::ZERO, |f| f.stamp));
                for f in frames {
                    if realtime {
                        tokio::time::sleep_until((wall0 + since(stamp0, f.stamp)).into()).await;
                    }
                    if out.send(Hop { stamp: f.stamp, doas: f.doas }).await.is_err() {
                        return;
                    }
                }
                tracing::info!("end of the ODAS file");
            });
        }
        HopPlan::OdasFollow { path, hop_len, sample_rate_hz, start } => {
            let (odas_tx, odas_rx) = mpsc::channel(HOP_QUEUE);
            tokio::spawn(async move {
                if let Err(e) = odas::follow_file(path, hop_len, sample_rate_hz, start, odas_tx).await {
                    tracing::error!("{e}");
                }
            });
            forward_odas(odas_rx, out);
        }
        HopPlan::OdasListen { listener, hop_len, sample_rate_hz, start } => {
            let listener = tokio::net::TcpListener::from_std(listener)
                .map_err(|source| AgentError::Io { path: "doa.listen".into(), source })?;
            let (odas_tx, odas_rx) = mpsc::channel(HOP_QUEUE);
            tokio::spawn(async move {
                if let Err(e) = odas::serve_tcp(listener, hop_len, sample_rate_hz, start, odas_tx).await {
                    tracing::error!("{e}");
                }
            });
            forward_odas(odas_rx, out);
        }
    }
    Ok(None)
}

/// Passes a live ODAS bridge's frames on to the link as hops.
fn forward_odas(mut frames: mpsc::Receiver<odas::OdasFrame>, out: mpsc::Sender<Hop>) {
    tokio::spawn(async move {
        while let Some(f) = frames.recv().await {
            if out.send(Hop { stamp: f.stamp, doas: f.doas }).await.is_err() {
                return;
            }
        }
    });
}

/// Passes the hops on to the link, writing each hop's tracks to `[odas_out]` on the way.
/// Returns the link's hops and the writer's task.
fn tee_odas_out(
    mut hops: mpsc::Receiver<Hop>,
    out: odas::out::OdasOut,
) -> (mpsc::Receiver<Hop>, tokio::task::JoinHandle<()>) {
    let (tx, rx) = mpsc::channel::<Hop>(HOP_QUEUE);
    let (out_tx, out_rx) = mpsc::channel(HOP_QUEUE);
    let task = tokio::spawn(out.run(out_rx));
    tokio::spawn(async move {
        while let Some(h) = hops.recv().await {
            // The writer never waits on its socket, so this only waits for file writes.
            let _ = out_tx.send(h.doas.clone()).await;
            if tx.send(h).await.is_err() {
                return;
            }
        }
    });
    (rx, task)
}

/// Passes the live poses on to the link, keeping a copy for the DSP thread.
fn share_poses(
    mut rx: mpsc::Receiver<StampedPose>,
    orientations: Orientations,
) -> mpsc::Receiver<StampedPose> {
    let (tx, out) = mpsc::channel::<StampedPose>(1024);
    tokio::spawn(async move {
        while let Some(p) = rx.recv().await {
            // Out-of-order poses are the core's to report; the copy skips them.
            let _ = orientations.lock().unwrap_or_else(|e| e.into_inner()).push(p.clone());
            if tx.send(p).await.is_err() {
                return;
            }
        }
    });
    out
}

/// Starts the live pose feed, if any.
fn start_poses(plan: PosePlan) -> Result<Option<mpsc::Receiver<StampedPose>>, AgentError> {
    let (tx, rx) = mpsc::channel::<StampedPose>(1024);
    match plan {
        PosePlan::Tum => return Ok(None),
        PosePlan::Tcp(listener) => {
            let listener = tokio::net::TcpListener::from_std(listener)
                .map_err(|source| AgentError::Io { path: "pose.listen".into(), source })?;
            tokio::spawn(pose::jsonl::serve_tcp(listener, tx));
        }
        PosePlan::Stdin => {
            tokio::spawn(async move {
                let stdin = tokio::io::BufReader::new(tokio::io::stdin());
                if let Err(e) = pose::jsonl::read_feed(stdin, "pose feed -", &tx).await {
                    tracing::error!("{e}");
                }
            });
        }
    }
    Ok(Some(rx))
}

fn since(earlier: Stamp, later: Stamp) -> Duration {
    Duration::from_nanos((later - earlier).max(0) as u64)
}

/// The audio thread reads (and, for files, paces) blocks; the DSP thread runs the
/// pipeline and sends every hop's confirmed tracks to the link. Blocks circulate
/// through a fixed pool, so nothing is allocated per block.
fn spawn_dsp(
    mut source: Box<dyn AudioSource>,
    mut pipeline: Box<Pipeline>,
    realtime: bool,
    out: mpsc::Sender<Hop>,
    stop: Arc<AtomicBool>,
    orientations: Orientations,
) -> Threads {
    let n = source.hop_len() * source.channels();
    let (full_tx, full_rx) = std::sync::mpsc::sync_channel::<(Stamp, Vec<f32>)>(AUDIO_BLOCKS);
    let (free_tx, free_rx) = std::sync::mpsc::sync_channel::<Vec<f32>>(AUDIO_BLOCKS);
    for _ in 0..AUDIO_BLOCKS {
        let _ = free_tx.send(vec![0.0; n]);
    }
    let reader = std::thread::Builder::new()
        .name("audio".into())
        .spawn(move || {
            let mut pace: Option<(Instant, Stamp)> = None;
            while !stop.load(Ordering::SeqCst) {
                let Ok(mut block) = free_rx.recv() else { break };
                let Some(stamp) = source.next_block(&mut block).inspect_err(|e| tracing::error!("{e}"))?
                else {
                    tracing::info!("{}: end of audio", source.name());
                    break;
                };
                if realtime {
                    let (wall0, stamp0) = *pace.get_or_insert((Instant::now(), stamp));
                    let due = wall0 + since(stamp0, stamp);
                    std::thread::sleep(due.saturating_duration_since(Instant::now()));
                }
                if full_tx.send((stamp, block)).is_err() {
                    break;
                }
            }
            Ok(())
        })
        .expect("spawn the audio thread");
    let dsp = std::thread::Builder::new()
        .name("dsp".into())
        .spawn(move || {
            while let Ok((stamp, block)) = full_rx.recv() {
                pipeline.follow_poses(&orientations.lock().unwrap_or_else(|e| e.into_inner()), stamp);
                let r = pipeline.process_hop(stamp, &block);
                let hop = Hop { stamp: r.stamp, doas: r.confirmed_doas() };
                let _ = free_tx.send(block);
                if out.blocking_send(hop).is_err() {
                    break;
                }
            }
        })
        .expect("spawn the DSP thread");
    (reader, dsp)
}
