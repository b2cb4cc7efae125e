//! soundmap-agent: the robot agent.
//!
//! - `soundmap-agent localize`: localize and track sources in a recording with
//!   our SRP-PHAT pipeline; one JSON line per hop.
//! - `soundmap-agent run --config agent.toml`: the live agent: audio through the
//!   pipeline (or ODAS's tracked sources) + SLAM poses → observations streamed to
//!   the coordinator; reposition commands to the navigator.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use serde::Serialize;
use soundmap_agent::AgentError;
use soundmap_agent::array::{ArrayGeometry, presets};
use soundmap_agent::audio::{self, AudioInput, AudioSource, BlockOptions, RawFormat, RawLayout};
use soundmap_agent::config::{self, AgentConfig, DoaSource, OdasInput, PoseSource};
use soundmap_agent::link::{Link, LinkHandle};
use soundmap_agent::navigator::JsonLinesNavigator;
use soundmap_agent::odas::{self, LiveStart, OdasTiming};
use soundmap_agent::pipeline::{FrameResult, Pipeline, PipelineConfig};
use soundmap_agent::pose::{self, Attached, Attacher, PoseBuffer, PoseTimeMapping, StampedPose};
use soundmap_proto::{ArrayInfo, Hello, Observation, Stamp, TrackedDoa};
use tokio::sync::mpsc;

#[derive(Debug, Parser)]
#[command(
    name = "soundmap-agent",
    version,
    about = "soundmap robot agent: hears directions, streams them with the robot's pose"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Localize and track sound sources in a recording; writes one JSON line per hop:
    /// {"stamp_ns":…, "sources":[{"id","x","y","z","activity"}]} with (x, y, z) the unit
    /// vector toward the source in the array frame (x forward, y left, z up).
    Localize(LocalizeArgs),
    /// Run the agent: audio + poses → observations to the coordinator; commands → navigator.
    Run {
        /// The agent configuration (see deploy/agent.example.toml).
        #[arg(long)]
        config: PathBuf,
    },
}

#[derive(Debug, Args)]
struct LocalizeArgs {
    /// Array preset name or array .toml file.
    #[arg(long)]
    array: String,
    /// FILE.wav, a raw PCM file, or - for raw PCM on standard input.
    #[arg(long)]
    input: PathBuf,
    /// Raw sample format: s16le, s24le (packed 3 bytes) or s32le.
    #[arg(long)]
    format: Option<RawFormat>,
    /// Raw input: channels per frame in the stream.
    #[arg(long)]
    channels: Option<usize>,
    /// Raw input: sample rate, Hz.
    #[arg(long)]
    rate: Option<u32>,
    /// Input channel of each microphone, in microphone order (e.g. 3,0,1,2).
    #[arg(long, value_delimiter = ',')]
    channel_map: Vec<usize>,
    /// Unix ns of input sample 0 (default 0).
    #[arg(long, default_value_t = 0)]
    start_ns: i64,
    /// Output file (default: standard output).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write this hop's SRP peaks: "potentials":[{"x","y","z","energy"}].
    #[arg(long)]
    potentials: bool,
    /// Also write tentative (unconfirmed) tracks.
    #[arg(long)]
    all_tracks: bool,
    /// Pipeline settings: a TOML file with the fields of agent.toml's [pipeline]
    /// (default: the pipeline defaults at the input's sample rate).
    #[arg(long)]
    pipeline: Option<PathBuf>,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .init();
    let result = match cli.command {
        Command::Localize(args) => localize(&args),
        Command::Run { config } => run(&config),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

// ------------------------------------------------------------------ localize

#[derive(Serialize)]
struct SourceLine {
    id: u64,
    x: f64,
    y: f64,
    z: f64,
    activity: f64,
}

#[derive(Serialize)]
struct PotentialLine {
    x: f64,
    y: f64,
    z: f64,
    energy: f64,
}

#[derive(Serialize)]
struct HopLine {
    stamp_ns: i64,
    sources: Vec<SourceLine>,
    #[serde(skip_serializing_if = "Option::is_none")]
    potentials: Option<Vec<PotentialLine>>,
}

fn localize(args: &LocalizeArgs) -> Result<()> {
    let array = ArrayGeometry::load(&args.array)?;
    let raw_args = [args.format.is_some(), args.channels.is_some(), args.rate.is_some()];
    let is_wav = args.input.extension().is_some_and(|e| e.eq_ignore_ascii_case("wav"));
    let input = if is_wav {
        if raw_args.iter().any(|&b| b) {
            bail!(
                "{}: --format, --channels and --rate are for raw input (a WAV header gives them)",
                args.input.display()
            );
        }
        AudioInput::Wav { path: args.input.clone() }
    } else {
        let (Some(format), Some(channels), Some(sample_rate_hz)) = (args.format, args.channels, args.rate)
        else {
            bail!("{}: raw input needs --format, --channels and --rate", args.input.display());
        };
        let layout = RawLayout { format, channels, sample_rate_hz };
        if args.input == Path::new("-") {
            AudioInput::Stdin { layout }
        } else {
            AudioInput::Raw { path: args.input.clone(), layout }
        }
    };
    let pipeline_config = match &args.pipeline {
        Some(p) => config::load_pipeline(p)?,
        None => PipelineConfig { sample_rate_hz: input_rate(&input)?, ..PipelineConfig::default() },
    };
    let mut pipeline =
        Pipeline::new(&array, &pipeline_config).map_err(|e| pipeline_error(e, args.pipeline.as_deref()))?;
    let options = BlockOptions {
        hop_len: pipeline.hop_len(),
        channels: array.channels(),
        sample_rate_hz: pipeline.sample_rate_hz(),
        channel_map: (!args.channel_map.is_empty()).then(|| args.channel_map.clone()),
        start: Stamp::from_ns(args.start_ns),
    };
    let mut source = audio::open(&input, &options)?;
    let mut out: Box<dyn Write> = match &args.out {
        Some(p) => Box::new(std::io::BufWriter::new(
            std::fs::File::create(p).with_context(|| format!("{}: cannot create", p.display()))?,
        )),
        None => Box::new(std::io::BufWriter::new(std::io::stdout().lock())),
    };
    let mut block = vec![0.0f32; source.hop_len() * source.channels()];
    while let Some(stamp) = source.next_block(&mut block)? {
        let r = pipeline.process_hop(stamp, &block);
        let line = hop_line(r, args.potentials, args.all_tracks);
        serde_json::to_writer(&mut out, &line)?;
        out.write_all(b"\n")?;
    }
    out.flush()?;
    Ok(())
}

fn hop_line(r: &FrameResult, potentials: bool, all_tracks: bool) -> HopLine {
    HopLine {
        stamp_ns: r.stamp.as_ns(),
        sources: r
            .tracks
            .iter()
            .filter(|t| all_tracks || t.confirmed)
            .map(|t| SourceLine {
                id: t.track_id,
                x: t.direction.x,
                y: t.direction.y,
                z: t.direction.z,
                activity: t.activity,
            })
            .collect(),
        potentials: potentials.then(|| {
            r.potentials
                .iter()
                .map(|p| PotentialLine {
                    x: p.direction.x,
                    y: p.direction.y,
                    z: p.direction.z,
                    energy: p.energy,
                })
                .collect()
        }),
    }
}

/// The sample rate of an input (WAV header, or the raw layout).
fn input_rate(input: &AudioInput) -> Result<u32> {
    Ok(match input {
        AudioInput::Wav { path } => {
            hound::WavReader::open(path)
                .map_err(|e| AgentError::Audio {
                    path: path.clone(),
                    message: format!("not a supported WAV file: {e}"),
                })?
                .spec()
                .sample_rate
        }
        AudioInput::Raw { layout, .. } | AudioInput::Stdin { layout } | AudioInput::Live { layout, .. } => {
            layout.sample_rate_hz
        }
    })
}

/// Names the pipeline settings' origin in a pipeline construction error.
fn pipeline_error(e: AgentError, file: Option<&Path>) -> anyhow::Error {
    let origin = file.map_or("pipeline".to_owned(), |f| f.display().to_string());
    match e {
        AgentError::InvalidParameter { field, message } => {
            anyhow::anyhow!("{origin}: pipeline.{field}: {message}")
        }
        other => other.into(),
    }
}

// ------------------------------------------------------------------ run

/// Confirmed tracks of one hop (or of one ODAS object), stamped.
#[derive(Debug)]
struct DoaFrame {
    stamp: Stamp,
    doas: Vec<TrackedDoa>,
}

/// Observations are sent while tracks exist, plus one empty observation when
/// they end (so the coordinator learns the robot hears nothing); silent hops
/// send nothing (heartbeats keep the link alive).
#[derive(Debug, Default)]
struct SilenceFilter {
    previous_empty: bool,
}

impl SilenceFilter {
    fn new() -> Self {
        SilenceFilter { previous_empty: true }
    }

    /// Whether a frame with these DoAs is sent.
    fn keep(&mut self, doas: &[TrackedDoa]) -> bool {
        let keep = !(doas.is_empty() && self.previous_empty);
        self.previous_empty = doas.is_empty();
        keep
    }
}

/// Where DoA frames will come from, prepared (files opened, sockets bound) before anything starts.
enum DoaPlan {
    Own { source: Box<dyn AudioSource>, pipeline: Box<Pipeline>, realtime: bool },
    OdasFile(Vec<odas::OdasFrame>),
    OdasListen { listener: std::net::TcpListener, hop_len: u32, sample_rate_hz: u32, start: LiveStart },
}

enum PosePlan {
    Tum(Vec<StampedPose>),
    Tcp(std::net::TcpListener),
    Stdin,
}

fn run(config_path: &Path) -> Result<()> {
    let config = AgentConfig::load(config_path)?;
    let cfg_name = config.path.display().to_string();
    let array = ArrayGeometry::load(&config.array).with_context(|| format!("{cfg_name}: array"))?;
    let hello = Hello {
        robot_id: config.robot_id.clone(),
        array: ArrayInfo {
            base_from_array: array.base_from_array,
            microphone_count: array.channels() as u32,
            preset: presets::NAMES.contains(&config.array.as_str()).then(|| array.name.clone()),
            microphone_positions: array.positions().collect(),
        },
        software_version: format!("soundmap-agent {}", env!("CARGO_PKG_VERSION")),
    };
    let audio_start = Stamp::now();
    let doa_plan = match &config.doa {
        DoaSource::Own { audio, pipeline } => {
            let pipeline = Pipeline::new(&array, pipeline).map_err(|e| match e {
                AgentError::InvalidParameter { field, message } => {
                    anyhow::anyhow!("{cfg_name}: pipeline.{field}: {message}")
                }
                other => other.into(),
            })?;
            let options = BlockOptions {
                hop_len: pipeline.hop_len(),
                channels: array.channels(),
                sample_rate_hz: pipeline.sample_rate_hz(),
                channel_map: audio.channel_map.clone(),
                start: audio.start.unwrap_or(audio_start),
            };
            let source = audio::open(&audio.input, &options).with_context(|| format!("{cfg_name}: audio"))?;
            let file = matches!(audio.input, AudioInput::Wav { .. } | AudioInput::Raw { .. });
            DoaPlan::Own { source, pipeline: Box::new(pipeline), realtime: file && audio.realtime }
        }
        DoaSource::Odas(o) => match &o.input {
            OdasInput::File(path) => {
                let timing = OdasTiming {
                    hop_len: o.hop_len,
                    sample_rate_hz: o.sample_rate_hz,
                    start: o.start.unwrap_or(audio_start),
                };
                DoaPlan::OdasFile(odas::read_sst_file(path, &timing)?)
            }
            OdasInput::Listen(addr) => DoaPlan::OdasListen {
                listener: bind(*addr, &format!("{cfg_name}: doa.listen"))?,
                hop_len: o.hop_len,
                sample_rate_hz: o.sample_rate_hz,
                start: o.start.map_or(LiveStart::AtFirstFrame, LiveStart::Fixed),
            },
        },
    };
    let pose_plan = match &config.pose.source {
        PoseSource::Tum { path, start_s } => {
            let origin = match &config.doa {
                DoaSource::Own { audio, .. } => audio.start.unwrap_or(audio_start),
                DoaSource::Odas(o) => o.start.unwrap_or(audio_start),
            };
            let mapping = start_s.map_or(PoseTimeMapping::UNIX, |s| PoseTimeMapping::new(s, origin));
            PosePlan::Tum(pose::read_tum(path, mapping)?)
        }
        PoseSource::JsonlTcp(addr) => PosePlan::Tcp(bind(*addr, &format!("{cfg_name}: pose.listen"))?),
        PoseSource::JsonlStdin => PosePlan::Stdin,
    };
    let navigator = JsonLinesNavigator::open(&config.navigator.path, config.navigator.arrival_tolerance_m)?;
    let runtime = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
    let result = runtime.block_on(run_agent(config, hello, doa_plan, pose_plan, navigator));
    // A read of standard input blocked in tokio's blocking pool must not hold the exit.
    runtime.shutdown_timeout(Duration::from_millis(200));
    result
}

fn bind(addr: std::net::SocketAddr, what: &str) -> Result<std::net::TcpListener> {
    let l = std::net::TcpListener::bind(addr).with_context(|| format!("{what}: cannot listen on {addr}"))?;
    l.set_nonblocking(true)?;
    Ok(l)
}

async fn run_agent(
    config: AgentConfig,
    hello: Hello,
    doa_plan: DoaPlan,
    pose_plan: PosePlan,
    navigator: JsonLinesNavigator,
) -> Result<()> {
    let stop = Arc::new(AtomicBool::new(false));
    let (frames_tx, mut frames_rx) = mpsc::channel::<DoaFrame>(256);
    let mut dsp_threads = None;
    match doa_plan {
        DoaPlan::Own { source, pipeline, realtime } => {
            dsp_threads = Some(spawn_dsp(source, pipeline, realtime, frames_tx, stop.clone()));
        }
        DoaPlan::OdasFile(frames) => {
            tokio::spawn(async move {
                let (wall0, stamp0) = (Instant::now(), frames.first().map_or(Stamp::ZERO, |f| f.stamp));
                let mut silence = SilenceFilter::new();
                for f in frames {
                    tokio::time::sleep_until((wall0 + since(stamp0, f.stamp)).into()).await;
                    if !silence.keep(&f.doas) {
                        continue;
                    }
                    if frames_tx.send(DoaFrame { stamp: f.stamp, doas: f.doas }).await.is_err() {
                        return;
                    }
                }
            });
        }
        DoaPlan::OdasListen { listener, hop_len, sample_rate_hz, start } => {
            let listener = tokio::net::TcpListener::from_std(listener)?;
            let (odas_tx, mut odas_rx) = mpsc::channel(256);
            tokio::spawn(async move {
                if let Err(e) = odas::serve_tcp(listener, hop_len, sample_rate_hz, start, odas_tx).await {
                    tracing::error!("{e}");
                }
            });
            tokio::spawn(async move {
                let mut silence = SilenceFilter::new();
                while let Some(f) = odas_rx.recv().await {
                    if !silence.keep(&f.doas) {
                        continue;
                    }
                    if frames_tx.send(DoaFrame { stamp: f.stamp, doas: f.doas }).await.is_err() {
                        return;
                    }
                }
            });
        }
    }

    let cfg_name = config.path.display().to_string();
    let (poses_tx, mut poses_rx) = mpsc::channel::<StampedPose>(1024);
    let mut buffer_config = config.pose.buffer;
    let mut replay = None;
    match pose_plan {
        PosePlan::Tum(poses) => {
            buffer_config.capacity = buffer_config.capacity.max(poses.len());
            replay = Some(poses);
        }
        PosePlan::Tcp(listener) => {
            let listener = tokio::net::TcpListener::from_std(listener)?;
            tokio::spawn(pose::jsonl::serve_tcp(listener, poses_tx));
        }
        PosePlan::Stdin => {
            tokio::spawn(async move {
                let stdin = tokio::io::BufReader::new(tokio::io::stdin());
                if let Err(e) = pose::jsonl::read_feed(stdin, "pose feed -", &poses_tx).await {
                    tracing::error!("{e}");
                }
            });
        }
    }
    let mut attacher: Attacher<Vec<TrackedDoa>> = Attacher::new(
        PoseBuffer::new(format!("{cfg_name}: pose"), buffer_config)?,
        config.pose.max_wait_s,
        4096,
    );
    if let Some(poses) = replay {
        for p in poses {
            attacher.push_pose(p)?;
        }
        attacher.finish_poses();
    }

    let (link, link_task) = Link::spawn(config.link.clone(), hello, Box::new(navigator));
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    let mut out = Vec::new();
    let mut dropped_no_pose = 0u64;
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    let mut frames_open = true;
    let mut poses_open = true;
    let mut interrupted = false;
    while frames_open {
        tokio::select! {
            f = frames_rx.recv() => match f {
                Some(f) => attacher.push_frame(f.stamp, f.doas, &mut out),
                None => frames_open = false,
            },
            p = poses_rx.recv(), if poses_open => match p {
                Some(p) => {
                    if let Err(e) = attacher.push_pose(p) {
                        tracing::warn!("{e}");
                    }
                }
                None => poses_open = false,
            },
            _ = tick.tick() => {}
            _ = &mut ctrl_c => {
                tracing::info!("interrupted");
                interrupted = true;
                break;
            }
        }
        attacher.poll(Stamp::now(), &mut out);
        dropped_no_pose += deliver(&link, &mut out);
    }
    stop.store(true, Ordering::SeqCst);
    // Frames still waiting for poses get them or their chance ends.
    let until = Instant::now() + Duration::from_secs_f64(config.pose.max_wait_s);
    while attacher.pending() > 0 && Instant::now() < until && !interrupted {
        tokio::select! {
            Some(p) = poses_rx.recv(), if poses_open => {
                if let Err(e) = attacher.push_pose(p) {
                    tracing::warn!("{e}");
                }
            }
            _ = tick.tick() => {}
        }
        attacher.poll(Stamp::now(), &mut out);
        dropped_no_pose += deliver(&link, &mut out);
    }
    attacher.finish_poses();
    attacher.poll(Stamp::now(), &mut out);
    dropped_no_pose += deliver(&link, &mut out);

    if !interrupted && !link.flush(Duration::from_secs(10)).await {
        tracing::warn!("some observations were not acknowledged before shutdown");
    }
    let s = link.stats();
    tracing::info!(
        "sent {} observations ({} resent, {} acknowledged, {} dropped by the link, {} without a pose), \
         {} stream errors, {} commands",
        s.sent,
        s.resent,
        s.acked,
        s.dropped,
        dropped_no_pose,
        s.stream_errors,
        s.commands
    );
    link.shutdown();
    let _ = link_task.await;
    if let Some((reader, dsp)) = dsp_threads {
        dsp.join().map_err(|_| anyhow::anyhow!("the DSP thread panicked"))?;
        reader.join().map_err(|_| anyhow::anyhow!("the audio thread panicked"))??;
    }
    Ok(())
}

/// Sends ready observations to the link; returns how many frames had no pose.
fn deliver(link: &LinkHandle, out: &mut Vec<Attached<Vec<TrackedDoa>>>) -> u64 {
    let mut dropped = 0;
    for a in out.drain(..) {
        match a {
            Attached::Ready { pose, payload } => {
                link.observe_pose(pose.clone());
                link.send(Observation {
                    sequence: 0,
                    stamp: pose.stamp,
                    map_from_base: pose.map_from_base,
                    pose_covariance: pose.covariance,
                    doas: payload,
                });
            }
            Attached::Dropped { stamp, reason, .. } => {
                dropped += 1;
                tracing::warn!("DoA frame at {stamp} dropped: {reason}");
            }
        }
    }
    dropped
}

fn since(earlier: Stamp, later: Stamp) -> Duration {
    Duration::from_nanos((later - earlier).max(0) as u64)
}

/// Blocks in the pool between the audio thread and the DSP thread (the bound of their channel).
const AUDIO_BLOCKS: usize = 32;

/// The audio thread reads (and, for files, paces) blocks; the DSP thread runs the
/// pipeline and sends frames with confirmed tracks to the async side. Blocks
/// circulate through a fixed pool, so nothing is allocated per block.
fn spawn_dsp(
    mut source: Box<dyn AudioSource>,
    mut pipeline: Box<Pipeline>,
    realtime: bool,
    out: mpsc::Sender<DoaFrame>,
    stop: Arc<AtomicBool>,
) -> (std::thread::JoinHandle<Result<(), AgentError>>, std::thread::JoinHandle<()>) {
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
            let mut silence = SilenceFilter::new();
            let sigma_floor = pipeline.doa_sigma_floor_rad();
            while let Ok((stamp, block)) = full_rx.recv() {
                let r = pipeline.process_hop(stamp, &block);
                let doas: Vec<TrackedDoa> = r.confirmed_doas(sigma_floor);
                let frame_stamp = r.stamp;
                let _ = free_tx.send(block);
                if !silence.keep(&doas) {
                    continue;
                }
                if out.blocking_send(DoaFrame { stamp: frame_stamp, doas }).is_err() {
                    break;
                }
            }
        })
        .expect("spawn the DSP thread");
    (reader, dsp)
}
