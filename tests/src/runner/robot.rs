//! A simulated robot: its base moves (preset waypoints or commanded goals),
//! its array hears the room, its agent pipeline turns the audio into tracked
//! DoAs, and SLAM reports a noisy pose.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Matrix6, Point3};
use soundmap_agent::array::ArrayGeometry;
use soundmap_agent::pipeline::{Pipeline, PipelineConfig};
use soundmap_proto::{ArrayInfo, CommandState, Hello, Observation, RobotId, Stamp, TrackedDoa};

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

/// DoAs of one hop, before the pose is attached.
#[derive(Clone, Debug)]
pub struct HopDoas {
    /// DoA stamp (mid-frame).
    pub stamp: Stamp,
    /// Confirmed tracks.
    pub doas: Vec<TrackedDoa>,
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
    driver: Driver,
    slam: SlamNoise,
    pose_covariance: Matrix6<f64>,
    /// True base poses at hop boundaries: (time since start (s), pose).
    history: VecDeque<(f64, Pose2)>,
    /// Planar audio of the current block.
    block: Vec<f32>,
    /// One interleaved hop.
    hop: Vec<f32>,
    /// Results of the current block's hops.
    pub hops: Vec<HopDoas>,
    last_progress: Option<(u64, CommandState, f64)>,
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
    ) -> Result<Self, SimError> {
        let array = ArrayGeometry::load(&spec.array).map_err(|e| SimError::Agent(e.to_string()))?;
        let pipeline = Pipeline::new(&array, pipeline_config).map_err(|e| SimError::Agent(e.to_string()))?;
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
        Ok(SimRobot {
            id: RobotId::parse(&spec.id, "robots.id").map_err(|e| SimError::Agent(e.to_string()))?,
            array,
            pipeline,
            renderer,
            drive,
            driver,
            slam: SlamNoise::new(slam_config, robot_seed ^ 0x5EED)?,
            pose_covariance: pose_covariance(pos_std, yaw_std),
            history: VecDeque::from([(0.0, start)]),
            block: vec![0.0; channels * block_len],
            hop: Vec::new(),
            hops: Vec::new(),
            last_progress: None,
        })
    }

    /// The hello its agent sends.
    pub fn hello(&self) -> Hello {
        Hello {
            robot_id: self.id.clone(),
            array: ArrayInfo {
                base_from_array: self.array.base_from_array,
                microphone_count: self.array.channels() as u32,
                preset: Some(self.array.name.clone()),
                microphone_positions: self.array.positions().collect(),
            },
            software_version: concat!("soundmap-sim ", env!("CARGO_PKG_VERSION")).into(),
        }
    }

    /// Whether the coordinator may command it.
    pub fn is_commanded(&self) -> bool {
        matches!(self.driver, Driver::Commanded(_))
    }

    /// Advances the base by one hop (time `now_s` at the hop's start).
    pub fn step(&mut self, now_s: f64) {
        let pose = self.drive.pose();
        let twist = match &mut self.driver {
            Driver::Trajectory(f) => f.command(now_s, &pose, self.drive.limits()).0,
            Driver::Commanded(nav) => nav.step(now_s, &pose, &self.drive.twist(), self.drive.limits()).0,
        };
        self.drive.step(twist);
        let t = now_s + self.drive.time_step_s();
        self.history.push_back((t, self.drive.pose()));
        while self.history.len() > 4096 {
            self.history.pop_front();
        }
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
            let sigma_floor = self.pipeline.doa_sigma_floor_rad();
            let r = self.pipeline.process_hop(stamp_of(first_sample + (h * hop_len) as u64), &self.hop);
            let doas = r.confirmed_doas(sigma_floor);
            self.hops.push(HopDoas { stamp: r.stamp, doas });
        }
        Ok(())
    }

    /// The observation the agent sends for hop results `hop`: the SLAM pose
    /// at the DoA stamp (`t_s` since the start), with its covariance.
    pub fn observation(&mut self, hop: &HopDoas, t_s: f64) -> Result<Observation, SimError> {
        let truth = self.pose_at(t_s).map_from_base();
        let map_from_base = self.slam.observe(t_s, &truth)?;
        Ok(Observation {
            sequence: 0,
            stamp: hop.stamp,
            map_from_base,
            pose_covariance: Some(self.pose_covariance),
            doas: hop.doas.clone(),
        })
    }

    /// Takes a goal from the coordinator; `Err(reason)` when it cannot.
    pub fn command(&mut self, id: u64, goal: &Isometry3<f64>, deadline_s: f64) -> Result<(), String> {
        match &mut self.driver {
            Driver::Trajectory(_) => Err("this robot follows a preset trajectory".into()),
            Driver::Commanded(nav) => {
                nav.set_goal(id, goal, Some(deadline_s)).map(|_| ()).map_err(|e| e.to_string())
            }
        }
    }

    /// The commanded goal's progress when it is worth reporting: a new state,
    /// or 0.25 m more progress since the last report.
    pub fn progress_to_report(&mut self) -> Option<NavProgress> {
        let Driver::Commanded(nav) = &self.driver else { return None };
        let p = nav.progress()?;
        let report = match self.last_progress {
            Some((id, state, d)) => {
                id != p.goal_id || state != p.state || (d - p.distance_remaining_m).abs() >= 0.25
            }
            None => true,
        };
        if report {
            self.last_progress = Some((p.goal_id, p.state, p.distance_remaining_m));
            Some(p)
        } else {
            None
        }
    }

    /// The (first) twist limit, for tests.
    pub fn twist(&self) -> Twist {
        self.drive.twist()
    }
}
