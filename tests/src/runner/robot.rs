//! A simulated robot: its base moves (preset waypoints or commanded goals),
//! its array hears the room, its agent pipeline turns the audio into tracked
//! DoAs, and SLAM reports a noisy pose after every hop.
//!
//! What the robot tells the coordinator comes from the same agent core as a
//! live robot's ([`soundmap_agent::agent::Agent`]): hops and SLAM poses go in,
//! observations (pose interpolated at the DoA stamp, silence filtered,
//! sequenced) and command replies come out. Its navigator is the simulated
//! drive, behind the agent's [`Navigator`](AgentNavigator) trait.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Matrix6, Point3};
use soundmap_agent::agent::{self, Agent, CoreConfig};
use soundmap_agent::array::ArrayGeometry;
use soundmap_agent::link::Hop;
use soundmap_agent::navigator::Navigator as AgentNavigator;
use soundmap_agent::pipeline::{Pipeline, PipelineConfig};
use soundmap_agent::pose::{PoseBufferConfig, StampedPose};
use soundmap_proto::{
    BaseLimits, CommandAck, CommandProgress, CommandState, Hello, RepositionCommand, RobotId, Stamp,
};

use crate::acoustics::{ArrayConfig, ArrayRenderer, DiffuseNoiseConfig, Scene};
use crate::error::SimError;
use crate::kinematics::{
    DiffDriveRobot, DriveLimits, FollowerConfig, NavProgress, Navigator, NavigatorConfig, Pose2, Twist,
    Waypoint, WaypointFollower,
};
use crate::scenario::{RobotSpec, SlamSpec};
use crate::slam_noise::{Drift, SlamNoise, SlamNoiseConfig};

/// What moves the base.
#[derive(Debug)]
enum Driver {
    /// Preset waypoints.
    Trajectory(WaypointFollower),
    /// Goals from the coordinator.
    Commanded(Navigator),
}

/// The simulated drive as the agent core's navigator: goals from the
/// coordinator go to the commanded navigator (a robot on a preset trajectory
/// refuses them); progress is reported on a new state or every 0.25 m.
#[derive(Debug)]
pub struct SimNavigator {
    driver: Driver,
    epoch: Stamp,
    last_progress: Option<(u64, CommandState, f64)>,
    pending: Vec<CommandProgress>,
}

impl SimNavigator {
    fn report(&mut self, p: NavProgress) {
        self.last_progress = Some((p.goal_id, p.state, p.distance_remaining_m));
        self.pending.push(CommandProgress {
            command_id: p.goal_id,
            state: p.state,
            distance_remaining_m: Some(p.distance_remaining_m).filter(|d| d.is_finite()),
            detail: String::new(),
        });
    }
}

impl AgentNavigator for SimNavigator {
    fn submit(&mut self, c: &RepositionCommand, _now: Stamp) -> CommandAck {
        let answer = |r: Result<(), String>| CommandAck {
            command_id: c.command_id,
            accepted: r.is_ok(),
            reason: r.err().unwrap_or_default(),
        };
        let deadline_s = (c.deadline.as_ns() != 0).then(|| c.deadline.seconds_since(self.epoch));
        match &mut self.driver {
            Driver::Trajectory(_) => answer(Err("this robot follows a preset trajectory".into())),
            Driver::Commanded(nav) => match nav.set_goal(c.command_id, &c.goal_map_from_base, deadline_s) {
                Ok(replaced) => {
                    if let Some(p) = replaced {
                        self.report(p);
                    }
                    answer(Ok(()))
                }
                Err(e) => answer(Err(e.to_string())),
            },
        }
    }

    fn cancel(&mut self, command_id: u64, _reason: &str, _now: Stamp) {
        if let Driver::Commanded(nav) = &mut self.driver
            && nav.progress().is_some_and(|p| p.goal_id == command_id && p.state == CommandState::Executing)
            && let Some(p) = nav.cancel()
        {
            self.report(p);
        }
    }

    fn poll_progress(&mut self, _now: Stamp, out: &mut Vec<CommandProgress>) {
        if let Driver::Commanded(nav) = &self.driver
            && let Some(p) = nav.progress()
        {
            let due = match self.last_progress {
                Some((id, state, d)) => {
                    id != p.goal_id || state != p.state || (d - p.distance_remaining_m).abs() >= 0.25
                }
                None => true,
            };
            if due {
                self.report(p);
            }
        }
        out.append(&mut self.pending);
    }
}

/// A simulated robot.
#[derive(Debug)]
pub struct SimRobot {
    /// Its id.
    pub id: RobotId,
    /// Its array.
    pub array: ArrayGeometry,
    pipeline: Pipeline,
    renderer: ArrayRenderer,
    drive: DiffDriveRobot,
    /// The simulated drive, as the core's navigator.
    pub navigator: SimNavigator,
    /// The agent core: what the robot sends.
    pub core: Agent,
    slam: SlamNoise,
    pose_covariance: Matrix6<f64>,
    epoch: Stamp,
    /// True base poses at hop boundaries: (time since start (s), pose).
    history: VecDeque<(f64, Pose2)>,
    /// Planar audio of the current block.
    block: Vec<f32>,
    /// One interleaved hop.
    hop: Vec<f32>,
    /// Results of the current block's hops.
    pub hops: Vec<Hop>,
    /// SLAM poses published since the last [`SimRobot::take_published_poses`].
    published: Vec<StampedPose>,
}

/// Total 1-σ pose error of a SLAM model: white and drift parts combined (m, rad).
pub fn slam_pose_std(spec: &SlamSpec) -> (f64, f64) {
    let pos = spec.position_white_std_m.hypot(spec.drift_position_std_m);
    let yaw = spec.yaw_white_std_deg.hypot(spec.drift_yaw_std_deg).to_radians();
    (pos, yaw)
}

/// The pose covariance an agent attaches: diagonal over (x, y, z, rx, ry, rz),
/// from per-axis position σ (m, horizontal) and yaw σ (rad).
pub fn pose_covariance(position_std_m: f64, yaw_std_rad: f64) -> Matrix6<f64> {
    let p = position_std_m * position_std_m;
    Matrix6::from_diagonal(&nalgebra::Vector6::new(p, p, 1e-6, 1e-6, 1e-6, yaw_std_rad * yaw_std_rad))
}

impl SimRobot {
    /// Builds robot `index` of a scenario.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        index: usize,
        spec: &RobotSpec,
        scene: &Scene,
        pipeline_config: &PipelineConfig,
        slam: &SlamSpec,
        sensor_noise_std: f64,
        diffuse_noise_std: Option<f64>,
        seed: u64,
        block_len: usize,
        hop_s: f64,
        epoch: Stamp,
    ) -> Result<Self, SimError> {
        let array = ArrayGeometry::load(&spec.array)?;
        let pipeline = Pipeline::new(&array, pipeline_config)?;
        let robot_seed = seed ^ (0x9E37_79B9_7F4A_7C15u64.wrapping_mul(index as u64 + 1));
        let mut cfg = ArrayConfig::new(array.channels(), robot_seed);
        cfg.block_len = block_len;
        cfg.sensor_noise_std = sensor_noise_std;
        cfg.diffuse_noise = diffuse_noise_std.map(DiffuseNoiseConfig::with_std);
        let renderer = scene.renderer(cfg)?;
        let limits = DriveLimits {
            max_speed_m_per_s: spec.max_speed_m_per_s,
            max_turn_rate_rad_per_s: spec.max_turn_rate_deg_per_s.to_radians(),
            ..DriveLimits::default()
        };
        let start = Pose2::new(spec.start[0], spec.start[1], spec.start[2].to_radians());
        let drive = DiffDriveRobot::new(start, limits, hop_s)?;
        let driver = if spec.waypoints.is_empty() {
            Driver::Commanded(Navigator::new(NavigatorConfig::default()))
        } else {
            let w = spec
                .waypoints
                .iter()
                .map(|w| match w.t_s {
                    Some(t) => Waypoint::timed(w.x_m, w.y_m, t),
                    None => Waypoint::at(w.x_m, w.y_m),
                })
                .collect();
            Driver::Trajectory(WaypointFollower::new(w, FollowerConfig::default()))
        };
        let slam_config = SlamNoiseConfig {
            position_white_std_m: slam.position_white_std_m,
            yaw_white_std_rad: slam.yaw_white_std_deg.to_radians(),
            drift: Drift::GaussMarkov {
                position_std_m: slam.drift_position_std_m,
                yaw_std_rad: slam.drift_yaw_std_deg.to_radians(),
                time_constant_s: slam.drift_time_constant_s,
            },
            ..SlamNoiseConfig::perfect()
        };
        let (pos_std, yaw_std) = slam_pose_std(slam);
        let channels = array.channels();
        let id = RobotId::parse(&spec.id, "robots.id")?;
        let version = concat!("soundmap-sim ", env!("CARGO_PKG_VERSION")).into();
        let mut hello = pipeline_config.declare_tracks(agent::hello(id.clone(), &array, version))?;
        // The base declares its limits, as an agent's `[navigator]` does.
        hello.base_limits = BaseLimits {
            max_speed_m_per_s: Some(spec.max_speed_m_per_s),
            max_turn_rate_deg_per_s: Some(spec.max_turn_rate_deg_per_s),
        };
        let core_config = CoreConfig {
            doa_sigma_floor_rad: pipeline.doa_sigma_floor_rad(),
            pose_buffer: PoseBufferConfig { capacity: 4096, ..PoseBufferConfig::default() },
            ..CoreConfig::default()
        };
        let core = Agent::new(hello, core_config, &format!("robot {id}: SLAM poses"))?;
        let mut robot = SimRobot {
            id,
            array,
            pipeline,
            renderer,
            drive,
            navigator: SimNavigator { driver, epoch, last_progress: None, pending: Vec::new() },
            core,
            slam: SlamNoise::new(slam_config, robot_seed ^ 0x5EED)?,
            pose_covariance: pose_covariance(pos_std, yaw_std),
            epoch,
            history: VecDeque::from([(0.0, start)]),
            block: vec![0.0; channels * block_len],
            hop: Vec::new(),
            hops: Vec::new(),
            published: Vec::new(),
        };
        robot.publish_pose(0.0)?;
        Ok(robot)
    }

    /// The hello its agent sends.
    pub fn hello(&self) -> Hello {
        self.core.hello().clone()
    }

    /// Whether the coordinator may command it.
    pub fn is_commanded(&self) -> bool {
        matches!(self.navigator.driver, Driver::Commanded(_))
    }

    /// Advances the base by one hop (time `now_s` at the hop's start); SLAM
    /// then reports the pose at the hop's end to the agent core.
    pub fn step(&mut self, now_s: f64) -> Result<(), SimError> {
        let pose = self.drive.pose();
        let twist = match &mut self.navigator.driver {
            Driver::Trajectory(f) => f.command(now_s, &pose, self.drive.limits()).0,
            Driver::Commanded(nav) => nav.step(now_s, &pose, &self.drive.twist(), self.drive.limits()).0,
        };
        self.drive.step(twist);
        let t = now_s + self.drive.time_step_s();
        self.history.push_back((t, self.drive.pose()));
        while self.history.len() > 4096 {
            self.history.pop_front();
        }
        self.publish_pose(t)
    }

    /// SLAM's (noisy) pose at `t_s` since the start, handed to the core.
    fn publish_pose(&mut self, t_s: f64) -> Result<(), SimError> {
        let truth = self.pose_at(t_s).map_from_base();
        let map_from_base = self.slam.observe(t_s, &truth)?;
        let stamp = self.epoch.plus_secs(t_s);
        let pose = StampedPose { stamp, map_from_base, covariance: Some(self.pose_covariance) };
        self.core.handle_pose(stamp, pose.clone())?;
        self.published.push(pose);
        Ok(())
    }

    /// The SLAM poses published since the last call (what a recording keeps).
    pub fn take_published_poses(&mut self) -> Vec<StampedPose> {
        std::mem::take(&mut self.published)
    }

    /// The newest SLAM pose the core holds.
    pub fn slam_pose(&self) -> Option<&StampedPose> {
        self.core.poses().last()
    }

    /// True base pose at `t_s` (linear in position, shortest arc in yaw).
    pub fn pose_at(&self, t_s: f64) -> Pose2 {
        let i = self.history.partition_point(|(t, _)| *t < t_s);
        if i == 0 {
            return self.history[0].1;
        }
        if i >= self.history.len() {
            return self.history[self.history.len() - 1].1;
        }
        let ((ta, a), (tb, b)) = (self.history[i - 1], self.history[i]);
        let w = if tb > ta { (t_s - ta) / (tb - ta) } else { 1.0 };
        let dyaw = crate::kinematics::wrap_angle(b.yaw_rad - a.yaw_rad);
        Pose2::new(a.x_m + (b.x_m - a.x_m) * w, a.y_m + (b.y_m - a.y_m) * w, a.yaw_rad + dyaw * w)
    }

    /// The current true pose.
    pub fn pose(&self) -> Pose2 {
        self.drive.pose()
    }

    /// True array centre in the map at `t_s`.
    pub fn array_centre_at(&self, t_s: f64) -> Point3<f64> {
        self.pose_at(t_s).map_from_base() * self.array.base_from_array * Point3::origin()
    }

    /// Microphone positions in the map for a base pose.
    pub fn microphones_in_map(&self, map_from_base: &Isometry3<f64>) -> Vec<Point3<f64>> {
        let map_from_array = map_from_base * self.array.base_from_array;
        self.array.positions().map(|p| map_from_array * p).collect()
    }

    /// Renders the next block (positions at its end) and runs the pipeline on
    /// its hops; the results are left in [`SimRobot::hops`]. `first_sample` is
    /// the block's first sample index; `stamp_of` maps sample indices to stamps.
    pub fn hear(
        &mut self,
        microphones_in_map: &[Point3<f64>],
        sources_in_map: &[Point3<f64>],
        first_sample: u64,
        stamp_of: impl Fn(u64) -> Stamp,
        mut on_audio: impl FnMut(&[f32]),
    ) -> Result<(), SimError> {
        self.renderer.render_block(microphones_in_map, sources_in_map, &mut self.block)?;
        let (channels, block_len, hop_len) =
            (self.array.channels(), self.renderer.block_len(), self.pipeline.hop_len());
        self.hop.resize(channels * hop_len, 0.0);
        self.hops.clear();
        for h in 0..block_len / hop_len {
            for s in 0..hop_len {
                for c in 0..channels {
                    self.hop[s * channels + c] = self.block[c * block_len + h * hop_len + s];
                }
            }
            on_audio(&self.hop);
            let first = stamp_of(first_sample + (h * hop_len) as u64);
            self.pipeline.follow_poses(self.core.poses(), first);
            let r = self.pipeline.process_hop(first, &self.hop);
            self.hops.push(Hop { stamp: r.stamp, doas: r.confirmed_doas() });
        }
        Ok(())
    }

    /// Hands goals and poses to the simulated drive and its answers back to the core.
    pub fn exchange_with_navigator(&mut self, now: Stamp) {
        self.core.exchange_with(&mut self.navigator, now);
    }

    /// The (first) twist limit, for tests.
    pub fn twist(&self) -> Twist {
        self.drive.twist()
    }
}
