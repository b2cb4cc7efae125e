//! `soundmap-sim replay-mcap FILE.mcap --out DIR [--config coordinator.toml]`:
//! re-runs a coordinator on the observations of a recording (written by
//! `soundmap-coordinator --record` or `soundmap-sim … --mcap`) and writes the
//! same reports as `replay`, so settings can be tuned on a recorded mission.
//!
//! The recording's raw `soundmap.v1` topics are read back
//! (`/soundmap/robots/{id}/hello` and `…/observation`, see
//! `soundmap_server::viz::publisher`). Each robot connects with its recorded
//! hello at the first hello's log time; observations are then sent in
//! recording order over real gRPC (lockstep, as in the simulator), with the
//! coordinator clock set to each one's log time — the clock the recording
//! coordinator had when it handled it. With the same configuration the
//! replayed coordinator therefore publishes the same estimates (and, with a
//! simulated run's `FILE.coordinator.toml`, which holds the run's active
//! positioning, its planner decides on them as the run's did).
//!
//! The file is read twice, as a stream (constant memory): once for the hellos
//! and the true sources (`/soundmap/truth`, present in simulator recordings,
//! which then score the replay), once for the observations. Robots cannot
//! move in a replay: commands the replayed coordinator sends are listed in the
//! report and otherwise unanswered.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};
use nalgebra::{Isometry3, Point3};
use prost::Message;
use soundmap_agent::link::CoordinatorEvent;
use soundmap_proto::{Hello, Limits, Observation, Stamp, wire};
use soundmap_server::CoordinatorConfig;

use crate::error::SimError;
use crate::report::{RobotPath, RoomOutline, RunRecord, SourceTruth};
use crate::runner::fleet::Fleet;
use crate::runner::rows::{point, row_of, truth_for};

/// `soundmap-sim replay-mcap`.
#[derive(Debug, Clone, clap::Args)]
pub struct ReplayMcapArgs {
    /// The recording (MCAP).
    #[arg(value_name = "FILE.mcap")]
    pub file: PathBuf,
    /// Output directory for the reports.
    #[arg(long)]
    pub out: PathBuf,
    /// Coordinator configuration to replay with (TOML; default: the defaults).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// The Foxglove live view, a new recording and real-time pacing.
    #[command(flatten)]
    pub view: crate::viewer::ViewArgs,
}

/// A recorded message: its topic, log time (ns) and payload.
type Recorded = (Topic, i64, Vec<u8>);
/// The true sources at one log time (ns): position in `map`, and whether playing.
type TruthSample = (i64, Vec<(Point3<f64>, bool)>);
/// The robots' hellos with their log times (ns).
type Hellos = Vec<(i64, Hello)>;

/// What a topic of the recording carries.
#[derive(Clone, Debug)]
enum Topic {
    Hello,
    Observation(String),
    Truth,
    Other,
}

fn topic_kind(topic: &str) -> Topic {
    if topic == "/soundmap/truth" {
        return Topic::Truth;
    }
    match topic.strip_prefix("/soundmap/robots/").and_then(|r| r.rsplit_once('/')) {
        Some((_, "hello")) => Topic::Hello,
        Some((id, "observation")) => Topic::Observation(id.to_string()),
        _ => Topic::Other,
    }
}

/// The messages of an MCAP file in file order, read as a stream.
///
/// A recording cut short (the coordinator stopped without closing it, the
/// disk filled) ends in the middle of a record: its messages up to the last
/// complete record (for a chunked file, the last complete chunk) are read,
/// and [`Messages::cut_short`] says so, instead of the whole replay failing.
struct Messages {
    path: PathBuf,
    file: std::fs::File,
    reader: LinearReader,
    topics: HashMap<u16, Topic>,
    /// Messages returned so far.
    count: usize,
    /// Whether the file ended in the middle of a record.
    cut_short: bool,
}

impl Messages {
    fn open(path: &Path) -> Result<Self, SimError> {
        let file = std::fs::File::open(path).map_err(|e| SimError::file(path, e))?;
        Ok(Messages {
            path: path.to_path_buf(),
            file,
            reader: LinearReader::new(),
            topics: HashMap::new(),
            count: 0,
            cut_short: false,
        })
    }

    /// A warning when the file was cut short, naming what was read.
    fn cut_short(&self) -> Option<String> {
        self.cut_short.then(|| {
            format!(
                "{}: the recording ends in the middle of a record (cut short while it was written?): \
                 replaying the {} complete messages before it",
                self.path.display(),
                self.count
            )
        })
    }

    /// The next message: (its topic, log time in ns, payload).
    fn next(&mut self) -> Option<Result<Recorded, SimError>> {
        let path = &self.path;
        let bad = |e: mcap::McapError| {
            SimError::Replay(format!("{}: not a readable MCAP file: {e}", path.display()))
        };
        while let Some(event) = self.reader.next_event() {
            match event {
                Err(mcap::McapError::UnexpectedEof) => {
                    self.cut_short = true;
                    return None;
                }
                Err(e) => return Some(Err(bad(e))),
                Ok(LinearReadEvent::ReadRequest(n)) => match self.file.read(self.reader.insert(n)) {
                    Ok(read) => self.reader.notify_read(read),
                    Err(e) => return Some(Err(SimError::file(path, e))),
                },
                Ok(LinearReadEvent::Record { data, opcode }) => match mcap::parse_record(opcode, data) {
                    Err(e) => return Some(Err(bad(e))),
                    Ok(Record::Channel(c)) => {
                        self.topics.insert(c.id, topic_kind(&c.topic));
                    }
                    Ok(Record::Message { header, data }) => {
                        let topic = self.topics.get(&header.channel_id).cloned().unwrap_or(Topic::Other);
                        self.count += 1;
                        return Some(Ok((topic, header.log_time as i64, data.into_owned())));
                    }
                    Ok(_) => {}
                },
            }
        }
        None
    }
}

/// The hellos (first of each robot, in order) and true sources of a recording.
fn read_header(path: &Path) -> Result<(Hellos, Vec<SourceTruth>), SimError> {
    let mut hellos: Hellos = Vec::new();
    let mut truth: Vec<TruthSample> = Vec::new();
    let mut messages = Messages::open(path)?;
    while let Some(m) = messages.next() {
        let (topic, t, data) = m?;
        let data = data.as_slice();
        match topic {
            Topic::Hello => {
                let w = wire::Hello::decode(data).map_err(|e| decode_error(path, "hello", e))?;
                let h = Hello::from_wire(&w, &Limits::at(Stamp::from_ns(t)))
                    .map_err(|e| SimError::Replay(format!("{}: recorded hello: {e}", path.display())))?;
                if !hellos.iter().any(|(_, o)| o.robot_id == h.robot_id) {
                    hellos.push((t, h));
                }
            }
            Topic::Truth => {
                truth.push((t, parse_truth(data).ok_or_else(|| decode_error(path, "truth", "bad JSON"))?))
            }
            _ => {}
        }
    }
    if hellos.is_empty() && messages.cut_short {
        return Err(SimError::Replay(format!(
            "{}: the recording ends in the middle of a record (cut short while it was written?) \
             before any complete /soundmap/robots/*/hello message: nothing to replay",
            path.display()
        )));
    }
    if hellos.is_empty() {
        return Err(SimError::Replay(format!(
            "{}: no /soundmap/robots/*/hello messages: not a soundmap recording",
            path.display()
        )));
    }
    let t0 = Stamp::from_ns(hellos[0].0);
    Ok((hellos, truth_tracks(t0, &truth)))
}

fn decode_error(path: &Path, what: &str, e: impl std::fmt::Display) -> SimError {
    SimError::Replay(format!("{}: recorded {what} does not decode: {e}", path.display()))
}

fn parse_truth(data: &[u8]) -> Option<Vec<(Point3<f64>, bool)>> {
    let v: serde_json::Value = serde_json::from_slice(data).ok()?;
    v["sources"]
        .as_array()?
        .iter()
        .map(|s| {
            Some((Point3::new(s["x"].as_f64()?, s["y"].as_f64()?, s["z"].as_f64()?), s["active"].as_bool()?))
        })
        .collect()
}

/// Per source, its path and the intervals in which it was reported active.
fn truth_tracks(t0: Stamp, samples: &[TruthSample]) -> Vec<SourceTruth> {
    let n = samples.iter().map(|(_, s)| s.len()).max().unwrap_or(0);
    (0..n)
        .map(|k| {
            let mut truth = SourceTruth { path: Vec::new(), active: Vec::new() };
            let mut open: Option<f64> = None;
            for (t, s) in samples {
                let Some((p, active)) = s.get(k) else { continue };
                let t_s = Stamp::from_ns(*t).seconds_since(t0);
                truth.path.push((t_s, *p));
                match (open, active) {
                    (None, true) => open = Some(t_s),
                    (Some(a), false) => {
                        truth.active.push((a, t_s));
                        open = None;
                    }
                    _ => {}
                }
            }
            match open {
                // Active throughout: the empty interval list means "always".
                Some(a) if truth.active.is_empty() && truth.path.first().is_some_and(|(t, _)| *t >= a) => {}
                Some(a) => truth.active.push((a, f64::INFINITY)),
                None if truth.active.is_empty() => truth.active.push((0.0, 0.0)),
                None => {}
            }
            truth
        })
        .collect()
}

/// Re-runs the coordinator on the recording and returns what it published.
pub fn replay_mcap(args: &ReplayMcapArgs) -> Result<RunRecord, SimError> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(SimError::Runtime)?;
    runtime.block_on(replay_async(args))
}

/// Per robot: where its array was last (for scoring), and its path.
struct Robot {
    base_from_array: Isometry3<f64>,
    array_in_map: Option<Point3<f64>>,
    path: RobotPath,
}

impl Robot {
    /// Notes where `obs` puts the array, and a path sample every 0.4 s.
    fn saw(&mut self, t_s: f64, obs: &Observation) {
        self.array_in_map = Some(obs.map_from_base * self.base_from_array * Point3::origin());
        if self.path.samples.last().is_none_or(|(t, ..)| t_s - t >= 0.4) {
            let (_, _, yaw) = obs.map_from_base.rotation.euler_angles();
            let b = obs.map_from_base.translation.vector;
            self.path.samples.push((t_s, b.x, b.y, yaw));
        }
    }
}

async fn replay_async(args: &ReplayMcapArgs) -> Result<RunRecord, SimError> {
    let mut config = match &args.config {
        Some(p) => CoordinatorConfig::from_file(p)?,
        None => CoordinatorConfig::default(),
    };
    args.view.apply(&mut config);
    // Recorded observations arrive as fast as they are read, not at the rate
    // the robots sent them: the per-stream rate bound must not drop them.
    config.server.max_observation_rate_hz = 100_000.0;
    if args.view.mcap.as_deref() == Some(args.file.as_path()) {
        return Err(SimError::Replay(format!(
            "--mcap {}: would overwrite the recording replayed",
            args.file.display()
        )));
    }
    let (hellos, truths) = read_header(&args.file)?;
    let t0 = Stamp::from_ns(hellos[0].0);
    let index: HashMap<String, usize> =
        hellos.iter().enumerate().map(|(i, (_, h))| (h.robot_id.to_string(), i)).collect();
    let mut robots: Vec<Robot> = hellos
        .iter()
        .map(|(_, h)| Robot {
            base_from_array: h.array.base_from_array,
            array_in_map: None,
            path: RobotPath { id: h.robot_id.to_string(), samples: vec![], goals: vec![] },
        })
        .collect();
    let room = (!config.planner.free_space.room.is_empty()).then(|| RoomOutline {
        floor: config.planner.free_space.room.clone(),
        obstacles: config.planner.free_space.obstacles.clone(),
    });
    let (active, band) = (
        config.active_positioning.enabled,
        (config.active_positioning.theta_min_deg, config.active_positioning.theta_max_deg),
    );
    let hello_list: Vec<Hello> = hellos.iter().map(|(_, h)| h.clone()).collect();
    let mut fleet = Fleet::start(config, &hello_list, t0).await?;
    let pacer = args.view.pacer(t0);
    let mut truth_feed = crate::viewer::TruthFeed::new(fleet.viz(), t0);
    let mut rows = Vec::new();
    let mut commands = Vec::new();
    let mut end = t0;
    let path = &args.file;
    let mut messages = Messages::open(path)?;
    while let Some(m) = messages.next() {
        let (Topic::Observation(id), t, data) = m? else { continue };
        let Some(&i) = index.get(&id) else {
            return Err(SimError::Replay(format!(
                "{}: observation of robot {id} before its hello",
                path.display()
            )));
        };
        let w =
            wire::Observation::decode(data.as_slice()).map_err(|e| decode_error(path, "observation", e))?;
        let now = Stamp::from_ns(t);
        let obs = Observation::from_wire(&w, &Limits::at(now)).map_err(|e| {
            SimError::Replay(format!("{}: recorded observation of {id}: {e}", path.display()))
        })?;
        let t_s = now.seconds_since(t0);
        robots[i].saw(t_s, &obs);
        pacer.wait(now).await;
        fleet.set_time(now);
        for e in fleet.observe(i, obs).await? {
            if let CoordinatorEvent::Reposition(c) = e {
                commands.push((t_s, robots[i].path.id.clone(), c.detail.clone()));
                let g = c.goal_map_from_base.translation.vector;
                robots[i].path.goals.push((t_s, g.x, g.y));
            }
        }
        truth_feed.at(now, &truths);
        end = end.max(now);
        let arrays: Vec<Point3<f64>> =
            robots.iter().map(|r| r.array_in_map.unwrap_or_else(Point3::origin)).collect();
        for e in fleet.drain_estimates()? {
            let t_s = Stamp::from_ns(e.stamp_ns).seconds_since(t0);
            let truth = truth_for(&truths, t_s, point(&e.position_in_map_m));
            rows.push(row_of(&e, t0, truth, if truth.is_some() { &arrays } else { &[] }));
        }
    }
    if let Some(warning) = messages.cut_short() {
        eprintln!("replay-mcap: {warning}");
    }
    let refused = fleet.stream_errors();
    if refused > 0 {
        eprintln!("replay-mcap: the coordinator refused {refused} recorded message(s) (see its log)");
    }
    fleet.shutdown().await?;
    let sources = truths.into_iter().filter(|t| !t.path.is_empty()).collect();
    Ok(RunRecord {
        name: "replay-mcap".into(),
        duration_s: end.seconds_since(t0),
        active_positioning: active,
        theta_band_deg: band,
        rows,
        robot_ids: robots.iter().map(|r| r.path.id.clone()).collect(),
        robots: robots.into_iter().map(|r| r.path).collect(),
        sources,
        room,
        seed: None,
        commands,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_are_recognised() {
        assert!(matches!(topic_kind("/soundmap/robots/r1/hello"), Topic::Hello));
        assert!(
            matches!(topic_kind("/soundmap/robots/a/b/observation"), Topic::Observation(id) if id == "a/b")
        );
        assert!(matches!(topic_kind("/soundmap/truth"), Topic::Truth));
        assert!(matches!(topic_kind("/tf"), Topic::Other));
    }

    #[test]
    fn truth_intervals_follow_the_active_flags() {
        let t0 = Stamp::from_ns(0);
        let p = Point3::origin();
        let s = |t_s: f64, a: bool| ((t_s * 1e9) as i64, vec![(p, a)]);
        let tracks = truth_tracks(t0, &[s(0.0, true), s(1.0, true), s(2.0, false), s(3.0, true)]);
        assert_eq!(tracks[0].active, vec![(0.0, 2.0), (3.0, f64::INFINITY)]);
        let always = truth_tracks(t0, &[s(0.0, true), s(1.0, true)]);
        assert!(always[0].active.is_empty());
        let never = truth_tracks(t0, &[s(0.0, false)]);
        assert!(!never[0].active_at(0.0));
    }
}
