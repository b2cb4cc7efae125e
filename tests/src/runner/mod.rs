//! Runs a scenario end to end: the room renders each robot's microphones,
//! each robot's agent pipeline hears DoAs, its SLAM pose is attached, and the
//! observations go over real gRPC (loopback) to a real coordinator, in
//! simulated time. The coordinator's estimates are recorded against the truth.
//!
//! A run is deterministic for a seed: time is simulated, and observations are
//! sent in lockstep (see [`fleet`]).

pub mod fleet;
pub mod recording;
pub mod robot;
pub mod rows;

use std::path::PathBuf;

use nalgebra::Point3;
use soundmap_agent::agent::{Agent, FromCoordinator, Reply};
use soundmap_agent::audio::stamp_of_frame;
use soundmap_agent::navigator::Navigator as AgentNavigator;
use soundmap_proto::RepositionCommand;
use soundmap_proto::Stamp;

use crate::acoustics::{
    Activity, RirConfig, Scene, ShoeboxRoom, SourceSignal, direct_path_rms, noise_std_for_snr,
};
use crate::error::SimError;
use crate::report::{RobotPath, RoomOutline, RunRecord, SourceTruth};
use crate::scenario::Scenario;
use fleet::Fleet;
use robot::SimRobot;
use soundmap_agent::link::CoordinatorEvent;

/// Start of simulated time: 2026-01-01T00:00:00Z (Unix ns). Replays of
/// recordings made by the simulator use the same origin.
pub const SIM_EPOCH: Stamp = Stamp::from_ns(1_767_225_600_000_000_000);

/// Samples rendered per block (4 hops of 128).
pub const BLOCK_LEN: usize = 512;

/// How to run a scenario.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Overrides the scenario's seed.
    pub seed: Option<u64>,
    /// Overrides whether active positioning is on.
    pub active_positioning: Option<bool>,
    /// Writes the run as a recorded trial (WAV + TUM per robot, a TUM per source:
    /// `source.tum` for source 0, `source-K.tum` for source K ≥ 1) into this
    /// directory, with `replay-command.txt` and the settings it names
    /// ([`REPLAY_CONFIG`], and [`REPLAY_PIPELINE`] when the scenario sets `[agent]`).
    pub record_dir: Option<PathBuf>,
    /// Shows a progress bar on the terminal.
    pub progress: bool,
    /// The Foxglove live view, the MCAP recording and real-time pacing.
    pub view: crate::viewer::ViewArgs,
}

/// Runs `scenario` and returns what it recorded.
pub fn run(scenario: &Scenario, options: &RunOptions) -> Result<RunRecord, SimError> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("soundmap-sim")
        .enable_all()
        .build()
        .map_err(SimError::Runtime)?;
    runtime.block_on(run_async(scenario, options))
}

/// The acoustic scene of a scenario.
pub fn scene(s: &Scenario, seed: u64) -> Result<Scene, SimError> {
    let room = ShoeboxRoom::from_rt60(s.room.min_corner(), s.room.size(), s.room.rt60_s)?;
    let sources = s
        .sources
        .iter()
        .enumerate()
        .map(|(i, src)| SourceSignal {
            waveform: src.signal.waveform(),
            rms: src.rms,
            activity: if src.active.is_empty() {
                Activity::Always
            } else {
                Activity::Intervals(src.active.iter().map(|[a, b]| (*a, *b)).collect())
            },
            ramp_s: 0.005,
            seed: seed.wrapping_add(1000 + i as u64),
        })
        .collect();
    let rir = RirConfig { length_s: s.room.rt60_s.clamp(0.1, 1.2), ..RirConfig::default() };
    Ok(Scene { room, sources, rir })
}

async fn run_async(scenario: &Scenario, options: &RunOptions) -> Result<RunRecord, SimError> {
    let mut sim = Sim::start(scenario, options).await?;
    let blocks = (scenario.duration_s * sim.fs as f64 / BLOCK_LEN as f64).ceil() as u64;
    let bar = progress_bar(options.progress, blocks, &scenario.name);
    let pacer = options.view.pacer(SIM_EPOCH);
    for b in 0..blocks {
        sim.block(b).await?;
        pacer.wait(sim.stamp_of((b + 1) * BLOCK_LEN as u64)).await;
        if let Some(bar) = &bar {
            bar.inc(1);
        }
    }
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    sim.finish(blocks).await
}

/// The robots of a scenario.
fn build_robots(scenario: &Scenario, seed: u64) -> Result<Vec<SimRobot>, SimError> {
    let fs = scenario.agent.sample_rate_hz;
    let hop = scenario.agent.hop_len;
    if hop == 0 || !BLOCK_LEN.is_multiple_of(hop) {
        return Err(SimError::Scenario {
            path: scenario.name.clone(),
            field: "agent.hop_len".into(),
            message: format!("{hop} must divide the simulator's block of {BLOCK_LEN} samples"),
        });
    }
    let hop_s = hop as f64 / fs as f64;
    let scene = scene(scenario, seed)?;
    let reference = direct_path_rms(scenario.sources[0].rms, scenario.noise.reference_distance_m);
    let sensor_std = noise_std_for_snr(reference, scenario.noise.sensor_snr_db);
    let diffuse_std = scenario.noise.diffuse_snr_db.map(|snr| noise_std_for_snr(reference, snr));
    let (agent, slam) = (&scenario.agent, &scenario.slam);
    scenario
        .robots
        .iter()
        .enumerate()
        .map(|(i, spec)| {
            let (n, h) = (sensor_std, diffuse_std);
            SimRobot::new(i, spec, &scene, agent, slam, n, h, seed, BLOCK_LEN, hop_s, SIM_EPOCH)
        })
        .collect()
}

/// A scenario being run.
struct Sim<'a> {
    scenario: &'a Scenario,
    options: &'a RunOptions,
    seed: u64,
    /// The run's active positioning and free space, as the coordinator got
    /// them, for the settings a replay of its recording is given.
    positioning: ReplayPositioning,
    fs: u32,
    hop: usize,
    robots: Vec<SimRobot>,
    fleet: Fleet,
    recorders: Option<Vec<recording::RobotRecorder>>,
    rows: rows::RowMaker,
    paths: Vec<RobotPath>,
    /// Per source, its true position at each hop (recordings only).
    source_truth: Vec<Vec<(i64, Point3<f64>)>>,
    commands: Vec<(f64, String, String)>,
    /// The live view and recording, told the true sources (when on).
    viz: (crate::viewer::TruthFeed, Vec<crate::report::SourceTruth>),
}

impl<'a> Sim<'a> {
    async fn start(scenario: &'a Scenario, options: &'a RunOptions) -> Result<Sim<'a>, SimError> {
        let seed = options.seed.unwrap_or(scenario.seed);
        let active = options.active_positioning.unwrap_or(scenario.active_positioning.enabled);
        let fs = scenario.agent.sample_rate_hz;
        let robots = build_robots(scenario, seed)?;
        let mut config = scenario.coordinator.clone();
        // The room's ceiling is known here, as a deployment knows its rooms;
        // a scenario's own `[coordinator.doa] ceiling_height_m` wins.
        config.doa.ceiling_height_m = Some(ceiling_height_m(scenario));
        configure_positioning(&mut config, scenario, active);
        let positioning = ReplayPositioning {
            active_positioning: config.active_positioning.clone(),
            free_space: config.planner.free_space.clone(),
        };
        options.view.apply(&mut config);
        let hellos: Vec<_> = robots.iter().map(SimRobot::hello).collect();
        let fleet = Fleet::start(config, &hellos, SIM_EPOCH).await?;
        let fleet_viz = fleet.viz();
        let recorders = match &options.record_dir {
            Some(dir) => {
                std::fs::create_dir_all(dir).map_err(|e| SimError::file(dir, e))?;
                Some(
                    robots
                        .iter()
                        .map(|r| recording::RobotRecorder::create(dir, r.id.as_str(), r.array.channels(), fs))
                        .collect::<Result<Vec<_>, _>>()?,
                )
            }
            None => None,
        };
        let rows = rows::RowMaker::new(scenario, &robots);
        let paths = robots
            .iter()
            .map(|r| RobotPath { id: r.id.to_string(), samples: vec![], goals: vec![] })
            .collect();
        Ok(Sim {
            scenario,
            options,
            seed,
            positioning,
            fs,
            hop: scenario.agent.hop_len,
            robots,
            fleet,
            recorders,
            rows,
            paths,
            source_truth: vec![Vec::new(); scenario.sources.len()],
            commands: Vec::new(),
            viz: (
                crate::viewer::TruthFeed::new(fleet_viz, SIM_EPOCH),
                scenario.sources.iter().map(rows::source_truth).collect(),
            ),
        })
    }

    fn stamp_of(&self, sample: u64) -> Stamp {
        stamp_of_frame(SIM_EPOCH, sample, self.fs)
    }

    /// Block `b`: the robots move hop by hop (SLAM poses to their cores), the
    /// room renders, the pipelines hear, and the cores' observations go out.
    async fn block(&mut self, b: u64) -> Result<(), SimError> {
        let first = b * BLOCK_LEN as u64;
        self.move_robots(first)?;
        let end_s = (first + BLOCK_LEN as u64) as f64 / self.fs as f64;
        let sources: Vec<Point3<f64>> = self.scenario.sources.iter().map(|s| s.position_at(end_s)).collect();
        let fs = self.fs;
        let stamp_of = move |sample: u64| stamp_of_frame(SIM_EPOCH, sample, fs);
        hear_all(&mut self.robots, &sources, first, &stamp_of, self.recorders.as_mut())?;
        self.viz.0.at(self.stamp_of(first + BLOCK_LEN as u64), &self.viz.1);
        let now = self.stamp_of(first + BLOCK_LEN as u64);
        self.deliver(now).await?;
        if b.is_multiple_of(12) {
            for (r, path) in self.robots.iter().zip(self.paths.iter_mut()) {
                let p = r.pose();
                path.samples.push((end_s, p.x_m, p.y_m, p.yaw_rad));
            }
        }
        Ok(())
    }

    fn move_robots(&mut self, first: u64) -> Result<(), SimError> {
        for h in 0..BLOCK_LEN / self.hop {
            let sample = first + (h * self.hop) as u64;
            for r in self.robots.iter_mut() {
                r.step(sample as f64 / self.fs as f64)?;
            }
            if self.options.record_dir.is_some() {
                let t = self.stamp_of(sample);
                for (src, truth) in self.scenario.sources.iter().zip(self.source_truth.iter_mut()) {
                    truth.push((t - SIM_EPOCH, src.position_at(t.seconds_since(SIM_EPOCH))));
                }
            }
        }
        for (i, r) in self.robots.iter_mut().enumerate() {
            let poses = r.take_published_poses();
            if let Some(rec) = self.recorders.as_mut() {
                for p in &poses {
                    rec[i].pose(p.stamp, SIM_EPOCH, &p.map_from_base)?;
                }
            }
        }
        Ok(())
    }

    /// Hands the block's hops to the cores (robot by robot within a hop) and
    /// exchanges with the coordinator in lockstep; then the navigators report.
    async fn deliver(&mut self, now: Stamp) -> Result<(), SimError> {
        self.fleet.set_time(now);
        for h in 0..BLOCK_LEN / self.hop {
            for i in 0..self.robots.len() {
                let r = &mut self.robots[i];
                let hop = r.hops[h].clone();
                r.core.handle_hop(now, hop.stamp, hop.doas);
                let seen = exchange(&mut self.fleet, &mut r.core, &mut r.navigator, i, now).await?;
                for (stamp, cmd) in &seen.commands {
                    let t_s = stamp.seconds_since(SIM_EPOCH);
                    self.commands.push((t_s, r.id.to_string(), cmd.detail.clone()));
                    if seen.accepted.contains(&cmd.command_id) {
                        let g = cmd.goal_map_from_base.translation.vector;
                        self.paths[i].goals.push((t_s, g.x, g.y));
                    }
                }
                for e in self.fleet.drain_estimates()? {
                    self.rows.push(&e, &self.robots);
                }
            }
        }
        for (i, r) in self.robots.iter_mut().enumerate() {
            r.exchange_with_navigator(now);
            send_replies(&mut self.fleet, &mut r.core, i).await?;
        }
        Ok(())
    }

    async fn finish(self, blocks: u64) -> Result<RunRecord, SimError> {
        let stream_errors = self.fleet.stream_errors();
        self.fleet.shutdown().await?;
        if stream_errors > 0 {
            return Err(SimError::Coordinator(format!(
                "the coordinator refused {stream_errors} message(s) of the agents"
            )));
        }
        let scenario = self.scenario;
        if let (Some(dir), Some(recs)) = (&self.options.record_dir, self.recorders) {
            for r in recs {
                r.finish()?;
            }
            for (k, truth) in self.source_truth.iter().enumerate() {
                recording::write_source_tum(&dir.join(recording::source_tum_name(k)), truth)?;
            }
            write_replay_command(dir, scenario)?;
        }
        if let Some(mcap) = &self.options.view.mcap {
            write_replay_config_to(&mcap_replay_config(mcap), scenario, Some(&self.positioning))?;
        }
        let duration_s = blocks as f64 * BLOCK_LEN as f64 / self.fs as f64;
        let a = &scenario.active_positioning;
        Ok(RunRecord {
            name: scenario.name.clone(),
            duration_s,
            active_positioning: self.positioning.active_positioning.enabled,
            theta_band_deg: (a.theta_min_deg, a.theta_max_deg),
            rows: self.rows.finish(),
            robot_ids: self.robots.iter().map(|r| r.id.to_string()).collect(),
            robots: self.paths,
            sources: scenario
                .sources
                .iter()
                .map(|src| SourceTruth {
                    path: (0..=(duration_s * 10.0) as usize)
                        .map(|k| {
                            let t = k as f64 / 10.0;
                            (t, src.position_at(t))
                        })
                        .collect(),
                    active: src.active_intervals(),
                })
                .collect(),
            room: Some(RoomOutline {
                floor: scenario.room.floor(),
                obstacles: scenario.room.obstacles.clone(),
            }),
            seed: Some(self.seed),
            commands: self.commands,
        })
    }
}

/// The coordinator configuration a recording is replayed with (in the recording's directory).
pub const REPLAY_CONFIG: &str = "coordinator.toml";

/// The ceiling height the simulated coordinator's floor-image model is told
/// (m): the scenario's own `[coordinator.doa] ceiling_height_m`, else the room's.
pub fn ceiling_height_m(scenario: &Scenario) -> f64 {
    scenario.coordinator.doa.ceiling_height_m.unwrap_or(scenario.room.size_m[2])
}

/// Writes [`REPLAY_CONFIG`] into `dir`: the scenario's own `[coordinator]`
/// settings and the ones the simulator adds (the room's ceiling, unless the
/// scenario sets it), for replays; returns its path.
pub fn write_replay_config(dir: &std::path::Path, scenario: &Scenario) -> Result<PathBuf, SimError> {
    write_replay_config_to(&dir.join(REPLAY_CONFIG), scenario, None)
}

/// The active positioning a run's coordinator had, as [`configure_positioning`]
/// set it (on or off, the θ band, the room and obstacles as free space).
#[derive(Clone, Debug)]
struct ReplayPositioning {
    active_positioning: soundmap_server::config::ActivePositioningConfig,
    free_space: soundmap_server::planner::free_space::FreeSpaceConfig,
}

/// Writes the coordinator configuration of [`write_replay_config`] to `path`;
/// with `positioning`, also the run's active positioning, so that a replay
/// of the observations (`replay-mcap`) plans as the run did: its goals are
/// then the decisions the run's planner would take on those estimates,
/// though the replayed robots do not move.
fn write_replay_config_to(
    path: &std::path::Path,
    scenario: &Scenario,
    positioning: Option<&ReplayPositioning>,
) -> Result<PathBuf, SimError> {
    let mut table = scenario.overrides.coordinator.clone();
    let doa = sub_table(&mut table, "doa");
    doa.insert("ceiling_height_m".into(), toml::Value::Float(ceiling_height_m(scenario)));
    let Some(ReplayPositioning { active_positioning: a, free_space }) = positioning else {
        return write_table(
            path,
            "the scenario's [coordinator] settings and the simulated room's ceiling",
            &table,
        );
    };
    let table_of = sub_table(&mut table, "active_positioning");
    table_of.insert("enabled".into(), toml::Value::Boolean(a.enabled));
    table_of.insert("theta_min_deg".into(), toml::Value::Float(a.theta_min_deg));
    table_of.insert("theta_max_deg".into(), toml::Value::Float(a.theta_max_deg));
    let polygon = |vertices: &[[f64; 2]]| {
        toml::Value::Array(
            vertices
                .iter()
                .map(|v| toml::Value::Array(vec![toml::Value::Float(v[0]), toml::Value::Float(v[1])]))
                .collect(),
        )
    };
    let free = sub_table(sub_table(&mut table, "planner"), "free_space");
    free.insert("room".into(), polygon(&free_space.room));
    let obstacles = free_space.obstacles.iter().map(|o| polygon(o)).collect();
    free.insert("obstacles".into(), toml::Value::Array(obstacles));
    write_table(
        path,
        "the scenario's [coordinator] settings, the simulated room's ceiling and the run's active positioning",
        &table,
    )
}

/// The table under `key` in `table`, created if missing (a non-table value
/// there is replaced: the scenario's own settings were validated as tables).
fn sub_table<'a>(table: &'a mut toml::Table, key: &str) -> &'a mut toml::Table {
    let entry = table.entry(key).or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if !entry.is_table() {
        *entry = toml::Value::Table(toml::Table::new());
    }
    entry.as_table_mut().expect("a table was just put there")
}

/// Where a run recorded to `mcap` (`--mcap FILE.mcap`) writes the coordinator
/// configuration to replay it with (`replay-mcap --config`): beside it, as
/// `FILE.coordinator.toml`.
pub fn mcap_replay_config(mcap: &std::path::Path) -> PathBuf {
    mcap.with_extension(REPLAY_CONFIG)
}

/// Writes [`REPLAY_PIPELINE`] into `dir` when the scenario sets the agents'
/// pipeline (`[agent]`), for replays; returns its path.
pub fn write_replay_pipeline(
    dir: &std::path::Path,
    scenario: &Scenario,
) -> Result<Option<PathBuf>, SimError> {
    let table = &scenario.overrides.agent;
    if table.is_empty() {
        return Ok(None);
    }
    write_table(&dir.join(REPLAY_PIPELINE), "the scenario's [agent] settings (the agents' pipeline)", table)
        .map(Some)
}

/// The agents' pipeline settings a recording is replayed with, when the
/// scenario sets any (in the recording's directory).
pub const REPLAY_PIPELINE: &str = "pipeline.toml";

fn write_table(path: &std::path::Path, what: &str, table: &toml::Table) -> Result<PathBuf, SimError> {
    let path = path.to_path_buf();
    let body = toml::to_string(table).map_err(|e| SimError::file(&path, std::io::Error::other(e)))?;
    std::fs::write(&path, format!("# {what}\n{body}")).map_err(|e| SimError::file(&path, e))?;
    Ok(path)
}

/// Writes `replay-command.txt`, the `soundmap-sim replay` call that replays the
/// recording, and the coordinator configuration it names.
fn write_replay_command(dir: &std::path::Path, scenario: &Scenario) -> Result<(), SimError> {
    let mut cmd = String::from("soundmap-sim replay");
    for r in crate::replay::RobotRecording::recorded(dir, scenario) {
        cmd.push_str(&format!(" \\\n  --robot {}", r.to_argument()));
    }
    for (k, src) in scenario.sources.iter().enumerate() {
        let intervals = crate::replay::format_intervals(&src.active_intervals());
        cmd.push_str(&format!(
            " \\\n  --truth {}/{}{intervals}",
            dir.display(),
            recording::source_tum_name(k)
        ));
    }
    let config = write_replay_config(dir, scenario)?;
    cmd.push_str(&format!(" \\\n  --coordinator-config {}", config.display()));
    if let Some(pipeline) = write_replay_pipeline(dir, scenario)? {
        cmd.push_str(&format!(" \\\n  --pipeline {}", pipeline.display()));
    }
    cmd.push_str(" \\\n  --out OUT\n");
    let path = dir.join("replay-command.txt");
    std::fs::write(&path, cmd).map_err(|e| SimError::file(path, e))
}

/// Renders and localizes one block for every robot, two at a time in parallel.
fn hear_all(
    robots: &mut [SimRobot],
    sources: &[Point3<f64>],
    first: u64,
    stamp_of: &(impl Fn(u64) -> Stamp + Sync),
    recorders: Option<&mut Vec<recording::RobotRecorder>>,
) -> Result<(), SimError> {
    let end_s_pose = |r: &SimRobot| r.pose().map_from_base();
    let mics: Vec<_> = robots.iter().map(|r| r.microphones_in_map(&end_s_pose(r))).collect();
    let mut audio: Vec<Vec<f32>> = vec![Vec::new(); robots.len()];
    let record = recorders.is_some();
    std::thread::scope(|scope| {
        let handles: Vec<_> = robots
            .iter_mut()
            .zip(&mics)
            .zip(audio.iter_mut())
            .map(|((r, m), a)| {
                scope.spawn(move || {
                    r.hear(m, sources, first, stamp_of, |hop| {
                        if record {
                            a.extend_from_slice(hop)
                        }
                    })
                })
            })
            .collect();
        handles.into_iter().try_for_each(|h| h.join().expect("robot thread panicked"))
    })?;
    if let Some(recs) = recorders {
        for (rec, a) in recs.iter_mut().zip(&audio) {
            rec.audio(a)?;
        }
    }
    Ok(())
}

/// What one [`exchange`] saw: the commands received (with the stamp of the
/// observation that caused them) and the ids of those the navigator accepted.
#[derive(Debug, Default)]
pub(crate) struct Exchanged {
    pub commands: Vec<(Stamp, RepositionCommand)>,
    pub accepted: Vec<u64>,
}

/// Sends robot `i`'s observations in lockstep (each acknowledged before the
/// next), hands the coordinator's messages to its core, lets its navigator
/// answer, and sends the replies: the one way the simulator and the replay
/// drive an agent core against the coordinator.
pub(crate) async fn exchange(
    fleet: &mut Fleet,
    core: &mut Agent,
    navigator: &mut dyn AgentNavigator,
    i: usize,
    now: Stamp,
) -> Result<Exchanged, SimError> {
    let mut seen = Exchanged::default();
    while let Some(obs) = core.poll_observation() {
        let (stamp, seq) = (obs.stamp, obs.sequence);
        let events = fleet.observe(i, obs).await?;
        core.handle_coordinator(now, FromCoordinator::Ack { up_to_sequence: seq });
        for event in events {
            match &event {
                CoordinatorEvent::Reposition(cmd) => seen.commands.push((stamp, cmd.clone())),
                CoordinatorEvent::StreamError(e) => {
                    return Err(SimError::Coordinator(format!(
                        "robot {} got a stream error: {}: {}",
                        core.robot_id(),
                        e.field,
                        e.message
                    )));
                }
                _ => {}
            }
            core.handle_coordinator(now, FromCoordinator::Event(event));
        }
        core.exchange_with(navigator, now);
        seen.accepted.extend(send_replies(fleet, core, i).await?);
    }
    Ok(seen)
}

/// Sends robot `i`'s command replies; returns the ids of the commands it accepted.
pub(crate) async fn send_replies(
    fleet: &mut Fleet,
    core: &mut Agent,
    i: usize,
) -> Result<Vec<u64>, SimError> {
    let mut accepted = Vec::new();
    while let Some(reply) = core.poll_reply() {
        match reply {
            Reply::Ack(a) => {
                if a.accepted {
                    accepted.push(a.command_id);
                }
                fleet.command_ack(i, &a).await?;
            }
            Reply::Progress(p) => fleet.command_progress(i, &p).await?,
        }
    }
    Ok(accepted)
}

/// Applies the scenario's active-positioning settings to the coordinator's
/// config: on or off, the θ band, and the room and obstacles as free space.
fn configure_positioning(config: &mut soundmap_server::CoordinatorConfig, scenario: &Scenario, active: bool) {
    let a = &scenario.active_positioning;
    config.active_positioning.enabled = active;
    config.active_positioning.theta_min_deg = a.theta_min_deg;
    config.active_positioning.theta_max_deg = a.theta_max_deg;
    if config.planner.free_space.room.is_empty() {
        config.planner.free_space.room = scenario.room.floor();
    }
    config.planner.free_space.obstacles.extend(scenario.room.obstacles.iter().cloned());
}

fn progress_bar(show: bool, blocks: u64, name: &str) -> Option<indicatif::ProgressBar> {
    if !show {
        return None;
    }
    let bar = indicatif::ProgressBar::new(blocks);
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("{prefix} [{bar:40}] {percent:>3}% {elapsed}/{duration}")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_prefix(name.to_string());
    Some(bar)
}
