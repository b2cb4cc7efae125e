//! Replay of recorded trials: each robot's multichannel audio and SLAM poses
//! (TUM) go through the same agent pipeline and the same agent core as a live
//! robot (`soundmap-agent run` with a WAV and a TUM file sends the same
//! observations), and the same coordinator, over gRPC on loopback, in event
//! time and as fast as the CPU allows. Recorded robots cannot move: their
//! navigator declines every command. With a truth trajectory (TUM) the run is
//! scored like a simulation.
//!
//! Time: pose and truth files are read as seconds from an origin that is the
//! simulator's epoch ([`SIM_EPOCH`]); audio sample 0 of a robot is at
//! `start` seconds of its pose file's clock (0 unless given).
//!
//! What happens when the inputs do not fit together:
//! - audio and poses whose time ranges do not overlap at all: an error;
//! - DoAs stamped outside a robot's poses (audio longer than poses, or a late
//!   first pose) or inside a gap longer than `--max-pose-gap-s`: not sent,
//!   counted, and reported (the run goes on);
//! - estimates outside every truth trajectory: kept, with empty RSE.
//!
//! Robots that run ODAS: `odas=FILE.json` instead of `audio=` replays ODAS's
//! SST output (see [`odas`]); such robots and audio robots mix freely.
//!
//! Several sources: one `--truth` per source (`FILE.tum[@A-B,C-D]`, the
//! intervals when it played, [`parse_truth`]); each estimate is scored against
//! the nearest source playing at its stamp ([`crate::report::multi`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Point3;
use soundmap_agent::agent::{self, Agent, CoreConfig};
use soundmap_agent::array::ArrayGeometry;
use soundmap_agent::audio::{self, AudioInput, AudioSource, BlockOptions, stamp_of_frame};
use soundmap_agent::navigator::DecliningNavigator;
use soundmap_agent::pipeline::{Pipeline, PipelineConfig};
use soundmap_agent::pose::tum::{PoseTimeMapping, read_tum};
use soundmap_agent::pose::{PoseBufferConfig, StampedPose};
use soundmap_proto::{Hello, RobotId, Stamp, wire};
use soundmap_server::CoordinatorConfig;

use crate::error::SimError;
use crate::report::multi::nearest_truth_among;
use crate::report::{RobotPath, RunRecord, SourceTruth, TimelineRow};
use crate::runner::fleet::Fleet;
use crate::runner::robot::{pose_covariance, slam_pose_std};
use crate::runner::rows::{point, row_of, smoothed_row};
use crate::runner::{BLOCK_LEN, SIM_EPOCH, exchange};
use crate::scenario::Scenario;

pub mod odas;
use odas::OdasHops;
pub use odas::OdasRecording;

/// One robot's recording, as given on the command line:
/// `id=ID,audio=F.wav,poses=F.tum,array=PRESET|F.toml[,start=S][,pose_std_m=M][,yaw_std_deg=D]`,
/// or `odas=F.json[,odas_hop=128][,odas_rate=16000]` instead of `audio=`.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotRecording {
    /// Robot id.
    pub id: String,
    /// Multichannel WAV (`None` when the DoAs come from ODAS).
    pub audio: Option<PathBuf>,
    /// ODAS SST output instead of audio.
    pub odas: Option<OdasRecording>,
    /// TUM trajectory of `map_from_base`.
    pub poses: PathBuf,
    /// Array preset or file.
    pub array: String,
    /// Pose-file time of audio sample 0 (s).
    pub start_s: f64,
    /// 1-σ position error of the poses (m), attached as their covariance.
    pub pose_std_m: Option<f64>,
    /// 1-σ yaw error of the poses (degrees).
    pub yaw_std_deg: Option<f64>,
    /// A robot read from a ROS 2 bag (`--rosbag`): its topics and frames;
    /// audio and poses are then converted from the bag ([`crate::rosbag`]).
    pub rosbag: Option<crate::rosbag::BagRobot>,
}

impl RobotRecording {
    /// The recordings `soundmap-sim run --record DIR` writes for `scenario`'s
    /// robots: WAV and TUM per robot, with the scenario's SLAM pose error.
    pub fn recorded(dir: &Path, scenario: &Scenario) -> Vec<RobotRecording> {
        let (pos, yaw) = slam_pose_std(&scenario.slam);
        scenario
            .robots
            .iter()
            .map(|r| RobotRecording {
                id: r.id.clone(),
                audio: Some(dir.join(format!("{}.wav", r.id))),
                odas: None,
                poses: dir.join(format!("{}.tum", r.id)),
                array: r.array.clone(),
                start_s: 0.0,
                pose_std_m: Some(pos),
                yaw_std_deg: Some(yaw.to_degrees()),
                rosbag: None,
            })
            .collect()
    }

    /// The `--robot` argument that gives this recording ([`parse_robot`] reads it back).
    pub fn to_argument(&self) -> String {
        let mut a = format!("id={}", self.id);
        if let Some(audio) = &self.audio {
            a.push_str(&format!(",audio={}", audio.display()));
        }
        if let Some(o) = &self.odas {
            a.push_str(&format!(",odas={}", o.path.display()));
            if o.hop_len != odas::DEFAULT_HOP_LEN {
                a.push_str(&format!(",odas_hop={}", o.hop_len));
            }
            if o.sample_rate_hz != odas::DEFAULT_SAMPLE_RATE_HZ {
                a.push_str(&format!(",odas_rate={}", o.sample_rate_hz));
            }
        }
        a.push_str(&format!(",poses={},array={}", self.poses.display(), self.array));
        if self.start_s != 0.0 {
            a.push_str(&format!(",start={}", self.start_s));
        }
        if let Some(p) = self.pose_std_m {
            a.push_str(&format!(",pose_std_m={p}"));
        }
        if let Some(y) = self.yaw_std_deg {
            a.push_str(&format!(",yaw_std_deg={y}"));
        }
        a
    }
}

/// Parses `key=value,…` (the `--robot` argument).
pub fn parse_robot(s: &str) -> Result<RobotRecording, String> {
    let mut kv = BTreeMap::new();
    for part in s.split(',').filter(|p| !p.is_empty()) {
        let (k, v) = part.split_once('=').ok_or_else(|| format!("{part:?}: expected key=value"))?;
        if kv.insert(k.trim().to_string(), v.trim().to_string()).is_some() {
            return Err(format!("{k}: given twice"));
        }
    }
    if crate::rosbag::is_bag_robot(&kv) {
        return crate::rosbag::robot_from_keys(kv);
    }
    let mut take = |k: &str| kv.remove(k);
    let need = |v: Option<String>, k: &str| {
        v.ok_or_else(|| format!("{k}: missing (id, audio or odas, poses and array are required)"))
    };
    let number = robot_key_number;
    let count = |v: Option<String>, k: &str| -> Result<Option<u32>, String> {
        v.map(|v| {
            v.parse::<u32>()
                .ok()
                .filter(|x| *x > 0)
                .ok_or_else(|| format!("{k}: {v:?} is not a positive integer"))
        })
        .transpose()
    };
    let (audio, odas_path) = (take("audio"), take("odas"));
    let (hop, rate) = (count(take("odas_hop"), "odas_hop")?, count(take("odas_rate"), "odas_rate")?);
    let odas = match (&audio, odas_path) {
        (Some(_), Some(_)) => return Err("audio and odas: give one of them, not both".into()),
        (None, None) => return Err("audio: missing (id, audio or odas, poses and array are required)".into()),
        (_, Some(path)) => Some(OdasRecording {
            path: path.into(),
            hop_len: hop.unwrap_or(odas::DEFAULT_HOP_LEN),
            sample_rate_hz: rate.unwrap_or(odas::DEFAULT_SAMPLE_RATE_HZ),
        }),
        (Some(_), None) if hop.is_some() || rate.is_some() => {
            return Err("odas_hop, odas_rate: only with odas=FILE.json".into());
        }
        (Some(_), None) => None,
    };
    let r = RobotRecording {
        id: need(take("id"), "id")?,
        audio: audio.map(PathBuf::from),
        odas,
        poses: need(take("poses"), "poses")?.into(),
        array: need(take("array"), "array")?,
        start_s: number(take("start"), "start")?.unwrap_or(0.0),
        pose_std_m: number(take("pose_std_m"), "pose_std_m")?,
        yaw_std_deg: number(take("yaw_std_deg"), "yaw_std_deg")?,
        rosbag: None,
    };
    if let Some(k) = kv.keys().next() {
        return Err(format!(
            "{k}: unknown key (expected id, audio, odas, odas_hop, odas_rate, poses, array, start, pose_std_m, yaw_std_deg)"
        ));
    }
    RobotId::parse(&r.id, "id").map_err(|e| e.to_string())?;
    Ok(r)
}

/// One true source trajectory, as given on the command line:
/// `FILE.tum[@START-END,START-END…]` (seconds on the pose files' clock). The
/// intervals say when the source played (`[start, end)` each); without them it
/// always did. A path holding `@` ends with a bare `@` (always on).
#[derive(Clone, Debug, PartialEq)]
pub struct TruthTrack {
    /// TUM trajectory of the source (orientation ignored).
    pub path: PathBuf,
    /// When it played; empty: always.
    pub active: Vec<(f64, f64)>,
}

impl TruthTrack {
    /// A source that always played.
    pub fn always(path: impl Into<PathBuf>) -> Self {
        TruthTrack { path: path.into(), active: Vec::new() }
    }
}

/// Parses `FILE[@A-B,C-D…]` (the `--truth` argument).
pub fn parse_truth(s: &str) -> Result<TruthTrack, String> {
    let Some((path, spec)) = s.rsplit_once('@') else { return Ok(TruthTrack::always(s)) };
    if path.is_empty() {
        return Err(format!("{s:?}: no file before '@'"));
    }
    let mut active: Vec<(f64, f64)> = Vec::new();
    for part in spec.split(',').filter(|p| !p.trim().is_empty()) {
        let bad = || format!("{part:?}: expected START-END in seconds, e.g. {path}@0-12,20-30");
        let (a, b) = part.split_once('-').ok_or_else(bad)?;
        let a: f64 = a.trim().parse().map_err(|_| bad())?;
        let b: f64 = b.trim().parse().map_err(|_| bad())?;
        if !(a.is_finite() && b.is_finite() && a >= 0.0 && a < b) {
            return Err(format!("{part:?}: need 0 ≤ START < END"));
        }
        if active.last().is_some_and(|(_, end)| a < *end) {
            return Err(format!("{part:?}: intervals must be sorted and disjoint"));
        }
        active.push((a, b));
    }
    Ok(TruthTrack { path: path.into(), active })
}

/// The `@A-B,C-D` suffix of a `--truth` argument for these intervals ("" for always).
pub fn format_intervals(active: &[(f64, f64)]) -> String {
    if active.is_empty() {
        return String::new();
    }
    let parts: Vec<String> = active.iter().map(|(a, b)| format!("{a}-{b}")).collect();
    format!("@{}", parts.join(","))
}

/// Arguments of `soundmap-sim replay`.
#[derive(Clone, Debug, clap::Args)]
pub struct ReplayArgs {
    /// A robot's recording: `id=ID,audio=F.wav,poses=F.tum,array=PRESET|F.toml[,start=S][,pose_std_m=M,yaw_std_deg=D]`.
    #[arg(long = "robot", required = true, value_parser = parse_robot)]
    pub robots: Vec<RobotRecording>,
    /// A true source trajectory (TUM), repeatable, one per source in order:
    /// `FILE.tum[@START-END,START-END...]` with the intervals (s) when it played
    /// (always without them), e.g. --truth s0.tum --truth s1.tum@0-12,20-30.
    /// Each estimate is scored against the nearest source playing at its stamp;
    /// without any, no RSE is computed.
    #[arg(long = "truth", value_parser = parse_truth)]
    pub truths: Vec<TruthTrack>,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Coordinator configuration (TOML).
    #[arg(long)]
    pub coordinator_config: Option<PathBuf>,
    /// Agent pipeline configuration (TOML, the `pipeline` table of agent.toml).
    #[arg(long)]
    pub pipeline: Option<PathBuf>,
    /// DoAs in a gap between poses longer than this are not sent (s).
    #[arg(long, default_value_t = 0.5)]
    pub max_pose_gap_s: f64,
    /// A ROS 2 bag (rosbag2 folder or its .mcap file) holding every robot's
    /// audio and tf; each --robot then reads
    /// `id=NAME,audio_topic=TOPIC,array=PRESET[,info_topic=TOPIC][,base_frame=base_link][,map_frame=map]`,
    /// and --truth files stamp in the bag's clock (Unix seconds).
    #[arg(long, value_name = "BAG")]
    pub rosbag: Option<PathBuf>,
    /// The Foxglove live view, the MCAP recording and real-time pacing.
    #[command(flatten)]
    pub view: crate::viewer::ViewArgs,
}

/// Where a replayed robot's hops come from.
enum Hops {
    /// Audio through the agent's pipeline.
    Audio { pipeline: Box<Pipeline>, audio: Box<dyn AudioSource>, hop: Vec<f32> },
    /// ODAS's SST output.
    Odas(OdasHops),
}

/// A robot being replayed.
struct Replayed {
    id: RobotId,
    array: ArrayGeometry,
    hops: Hops,
    core: Agent,
    navigator: DecliningNavigator,
    /// Stamp of the next hop's first sample; `None` once the audio is exhausted.
    next: Option<Stamp>,
    start: Stamp,
    samples_done: u64,
}

impl Replayed {
    /// Runs the pipeline on the next hop, hands it to the core and exchanges
    /// with the coordinator; returns the coordinator's clock for the hop: the
    /// end of the simulator-sized block holding it.
    async fn hop(&mut self, fleet: &mut Fleet, i: usize) -> Result<Stamp, SimError> {
        let first = self.next.expect("a hop is left");
        let (now, stamp, doas) = match &mut self.hops {
            Hops::Audio { pipeline, hop, .. } => {
                pipeline.follow_poses(self.core.poses(), first);
                let result = pipeline.process_hop(first, hop);
                let (stamp, doas) = (result.stamp, result.confirmed_doas());
                let block = BLOCK_LEN as u64;
                let block_end = (self.samples_done / block + 1) * block;
                self.samples_done += pipeline.hop_len() as u64;
                (stamp_of_frame(self.start, block_end, pipeline.sample_rate_hz()), stamp, doas)
            }
            Hops::Odas(o) => {
                let (frame, now) = o.take().expect("a hop is left");
                (now, frame.stamp, frame.doas)
            }
        };
        fleet.set_time(now);
        self.core.handle_hop(now, stamp, doas);
        exchange(fleet, &mut self.core, &mut self.navigator, i, now).await?;
        Ok(now)
    }

    fn advance(&mut self) -> Result<(), SimError> {
        self.next = match &mut self.hops {
            Hops::Audio { audio, hop, .. } => audio.next_block(hop)?,
            Hops::Odas(o) => o.next_stamp(),
        };
        Ok(())
    }
}

impl Replayed {
    /// Opens one robot's recording: its audio, its poses (given whole to a new
    /// agent core), and its path for the map plot.
    fn open(
        r: &RobotRecording,
        pipeline_config: &PipelineConfig,
        max_pose_gap_s: f64,
    ) -> Result<(Replayed, RobotPath), SimError> {
        let array = ArrayGeometry::load(&r.array)?;
        let start = SIM_EPOCH.plus_secs(r.start_s);
        let hops = match (&r.audio, &r.odas) {
            (_, Some(o)) => Hops::Odas(OdasHops::open(o, start)?),
            (Some(path), None) => {
                let pipeline = Pipeline::new(&array, pipeline_config)?;
                let options = BlockOptions {
                    hop_len: pipeline.hop_len(),
                    channels: array.channels(),
                    sample_rate_hz: pipeline.sample_rate_hz(),
                    channel_map: None,
                    start,
                };
                let audio = audio::open(&AudioInput::Wav { path: path.clone() }, &options)?;
                let hop = vec![0.0; array.channels() * pipeline.hop_len()];
                Hops::Audio { pipeline: Box::new(pipeline), audio, hop }
            }
            (None, None) => return Err(SimError::Replay(format!("robot {}: neither audio nor odas", r.id))),
        };
        let list = read_tum(&r.poses, PoseTimeMapping::new(0.0, SIM_EPOCH))?;
        if list.is_empty() {
            return Err(SimError::Replay(format!("{}: no poses", r.poses.display())));
        }
        let poses = PoseBufferConfig {
            capacity: list.len().max(2),
            max_gap_s: max_pose_gap_s,
            ..PoseBufferConfig::default()
        };
        let (first, last) = (list[0].stamp, list[list.len() - 1].stamp);
        if first > start.plus_secs(24.0 * 3600.0) || last < start {
            return Err(SimError::Replay(format!(
                "{}: poses cover {:.3}–{:.3} s but the audio of {} starts at {:.3} s: the time ranges do not overlap",
                r.poses.display(),
                first.seconds_since(SIM_EPOCH),
                last.seconds_since(SIM_EPOCH),
                r.id,
                r.start_s
            )));
        }
        let path = RobotPath {
            id: r.id.clone(),
            samples: list
                .iter()
                .step_by((list.len() / 2000).max(1))
                .map(|p| {
                    let t = p.map_from_base.translation.vector;
                    (p.stamp.seconds_since(SIM_EPOCH), t.x, t.y, p.map_from_base.rotation.euler_angles().2)
                })
                .collect(),
            goals: vec![],
        };
        let covariance = match (r.pose_std_m, r.yaw_std_deg) {
            (None, None) => None,
            (p, y) => Some(pose_covariance(p.unwrap_or(0.0), y.unwrap_or(0.0).to_radians())),
        };
        let id = RobotId::parse(&r.id, "id")?;
        let version = concat!("soundmap-sim replay ", env!("CARGO_PKG_VERSION"));
        let (doa_sigma_floor_rad, hello) = match &hops {
            // The hello declares the tracks and signature bands the pipeline reports, as live.
            Hops::Audio { pipeline, .. } => (
                pipeline.doa_sigma_floor_rad(),
                pipeline_config.declare_tracks(agent::hello(id.clone(), &array, version.into()))?,
            ),
            // As the live agent with `[doa] source = "odas"`.
            Hops::Odas(_) => {
                (CoreConfig::default().doa_sigma_floor_rad, agent::hello(id.clone(), &array, version.into()))
            }
        };
        let core_config = CoreConfig { pose_buffer: poses, doa_sigma_floor_rad, ..CoreConfig::default() };
        let mut core = Agent::new(hello, core_config, &r.poses.display().to_string())?;
        let trajectory = list.into_iter().map(|p| StampedPose { covariance, ..p }).collect();
        core.handle_trajectory(start, trajectory)?;
        let robot = Replayed {
            id,
            array,
            hops,
            core,
            navigator: DecliningNavigator::new("replay: a recorded robot cannot move"),
            next: None,
            start,
            samples_done: 0,
        };
        Ok((robot, path))
    }
}

/// A timeline row for estimate `e`, scored against the nearest true source
/// playing at its stamp among those whose trajectory covers it.
fn score(e: &wire::SourceEstimate, robots: &[Replayed], truths: &[SourceTruth]) -> TimelineRow {
    let at = Stamp::from_ns(e.stamp_ns);
    let t_s = at.seconds_since(SIM_EPOCH);
    let covering: Vec<usize> = (0..truths.len())
        .filter(|k| {
            let p = &truths[*k].path;
            p.first().is_some_and(|(t0, _)| *t0 <= t_s) && p.last().is_some_and(|(t1, _)| t_s <= *t1)
        })
        .collect();
    let truth_at = nearest_truth_among(truths, &covering, t_s, point(&e.position_in_map_m))
        .and_then(|k| Some((k, truths[k].position_at(t_s)?)));
    let arrays_at = |at: Stamp| -> Vec<Point3<f64>> {
        robots
            .iter()
            .map(|r| {
                r.core.poses().lookup(at).ok().map_or_else(Point3::origin, |p| {
                    p.map_from_base * r.array.base_from_array * Point3::origin()
                })
            })
            .collect()
    };
    let arrays = arrays_at(at);
    let mut row = row_of(e, SIM_EPOCH, truth_at, if truth_at.is_some() { &arrays } else { &[] });
    if let Some(s) = &e.smoothed {
        let at = Stamp::from_ns(s.stamp_ns);
        let truth = truth_at.and_then(|(k, _)| truths[k].position_at(at.seconds_since(SIM_EPOCH)));
        let arrays = if truth.is_some() { arrays_at(at) } else { Vec::new() };
        row.smoothed = smoothed_row(s, SIM_EPOCH, truth, &arrays);
    }
    row
}

/// A true source's trajectory and intervals, read from its TUM file.
fn load_truth(track: &TruthTrack) -> Result<SourceTruth, SimError> {
    let poses = read_tum(&track.path, PoseTimeMapping::new(0.0, SIM_EPOCH))?;
    if poses.is_empty() {
        return Err(SimError::Replay(format!("{}: no poses", track.path.display())));
    }
    let path = poses
        .iter()
        .map(|p| (p.stamp.seconds_since(SIM_EPOCH), p.map_from_base.translation.vector.into()))
        .collect();
    Ok(SourceTruth { path, active: track.active.clone() })
}

/// Replays the recordings and returns what the coordinator published.
pub fn replay(args: &ReplayArgs) -> Result<RunRecord, SimError> {
    if args.rosbag.is_some() {
        return replay(&crate::rosbag::convert(args)?);
    }
    if let Some(r) = args.robots.iter().find(|r| r.rosbag.is_some()) {
        return Err(SimError::Replay(format!("robot {}: audio_topic= reads a bag: give --rosbag BAG", r.id)));
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(SimError::Runtime)?;
    runtime.block_on(replay_async(args))
}

async fn replay_async(args: &ReplayArgs) -> Result<RunRecord, SimError> {
    let pipeline_config = match &args.pipeline {
        Some(p) => soundmap_agent::config::load_pipeline(p)?,
        None => PipelineConfig::default(),
    };
    let mut coordinator = match &args.coordinator_config {
        Some(p) => CoordinatorConfig::from_file(p)?,
        None => CoordinatorConfig::default(),
    };
    args.view.apply(&mut coordinator);
    let mut robots = Vec::new();
    let mut paths = Vec::new();
    for r in &args.robots {
        if robots.iter().any(|o: &Replayed| o.id.as_str() == r.id) {
            return Err(SimError::Replay(format!("robot {} given twice", r.id)));
        }
        let (mut robot, path) = Replayed::open(r, &pipeline_config, args.max_pose_gap_s)?;
        paths.push(path);
        robot.advance()?;
        robots.push(robot);
    }
    let truths = args.truths.iter().map(load_truth).collect::<Result<Vec<_>, _>>()?;
    let hellos: Vec<Hello> = robots.iter().map(|r| r.core.hello().clone()).collect();
    let t_start = robots.iter().map(|r| r.start).min().unwrap_or(SIM_EPOCH);
    let mut fleet = Fleet::start(coordinator, &hellos, t_start).await?;
    let (mut truth_feed, pacer) =
        (crate::viewer::TruthFeed::new(fleet.viz(), SIM_EPOCH), args.view.pacer(t_start));
    let mut rows = Vec::new();
    let mut end = t_start;
    // Hops in stamp order (ties: robot order), as a live fleet would send them.
    while let Some(i) =
        (0..robots.len()).filter(|&i| robots[i].next.is_some()).min_by_key(|&i| (robots[i].next, i))
    {
        let now = robots[i].hop(&mut fleet, i).await?;
        truth_feed.at(now, &truths);
        end = end.max(now);
        pacer.wait(now).await;
        for e in fleet.drain_estimates()? {
            rows.push(score(&e, &robots, &truths));
        }
        robots[i].advance()?;
    }
    fleet.shutdown().await?;
    for r in &robots {
        let skipped = r.core.stats().hops_without_pose;
        if skipped > 0 {
            eprintln!(
                "replay: robot {}: {skipped} hop(s) had no pose at their DoA stamp (outside the pose file or in a gap) and were not sent",
                r.id
            );
        }
    }
    // The record keeps at most ~4000 samples per source path (for the map).
    let sources = truths
        .into_iter()
        .map(|t| SourceTruth {
            path: t.path.iter().step_by((t.path.len() / 4000).max(1)).copied().collect(),
            active: t.active,
        })
        .collect();
    Ok(RunRecord {
        name: "replay".into(),
        duration_s: end.seconds_since(t_start),
        active_positioning: false,
        theta_band_deg: (40.0, 140.0),
        rows,
        robot_ids: robots.iter().map(|r| r.id.to_string()).collect(),
        robots: paths,
        sources,
        room: None,
        seed: None,
        commands: vec![],
    })
}

/// A `--robot` key's value as a finite number, if given (errors name the key).
pub(crate) fn robot_key_number(v: Option<String>, k: &str) -> Result<Option<f64>, String> {
    v.map(|v| {
        v.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| format!("{k}: {v:?} is not a number"))
    })
    .transpose()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robot_argument() {
        let r = parse_robot("id=r1,audio=a.wav,poses=p.tum,array=respeaker-4,start=1.5").unwrap();
        assert_eq!((r.id.as_str(), r.start_s, r.array.as_str()), ("r1", 1.5, "respeaker-4"));
        assert!(parse_robot("id=r1,audio=a.wav,poses=p.tum").unwrap_err().contains("array"));
        assert!(
            parse_robot("id=r1,audio=a.wav,poses=p.tum,array=x,colour=red").unwrap_err().contains("colour")
        );
        assert!(
            parse_robot("id=r1,audio=a.wav,poses=p.tum,array=x,start=soon").unwrap_err().contains("start")
        );
        assert!(parse_robot("id=r 1,audio=a.wav,poses=p.tum,array=x").is_err());
    }

    #[test]
    fn truth_argument() {
        assert_eq!(parse_truth("rec/source.tum").unwrap(), TruthTrack::always("rec/source.tum"));
        let t = parse_truth("s2.tum@0-12,20-30.5").unwrap();
        assert_eq!((t.path, t.active), (PathBuf::from("s2.tum"), vec![(0.0, 12.0), (20.0, 30.5)]));
        assert_eq!(parse_truth("odd@name.tum@").unwrap(), TruthTrack::always("odd@name.tum"));
        assert!(parse_truth("s.tum@12-3").unwrap_err().contains("START < END"));
        assert!(parse_truth("s.tum@0-5,4-8").unwrap_err().contains("disjoint"));
        assert!(parse_truth("s.tum@soon").unwrap_err().contains("START-END"));
        assert!(parse_truth("@0-1").is_err());
        assert_eq!(format_intervals(&[(0.5, 20.0), (25.0, 30.0)]), "@0.5-20,25-30");
        assert_eq!(format_intervals(&[]), "");
        let round = parse_truth(&format!("x.tum{}", format_intervals(&[(0.5, 12.0)]))).unwrap();
        assert_eq!(round.active, vec![(0.5, 12.0)]);
    }
}
