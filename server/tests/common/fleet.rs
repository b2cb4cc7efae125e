//! A fleet of test robots that observe one source in lock step, answer
//! reposition commands the way an agent does (ack, progress), and "drive" to
//! a goal by reporting its pose at the next step.

use nalgebra::{Isometry3, Point3, Vector3};
use soundmap_proto::wire::coordinator_message::Msg as Down;
use soundmap_proto::wire::robot_message::Msg as Up;
use soundmap_proto::{BaseLimits, Stamp, wire};
use soundmap_server::clock::ManualClock;

use super::{Robot, T0, hello, observation_of, open};

/// How a robot answers commands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    /// Accept, report EXECUTING, and arrive (SUCCEEDED) at the next step.
    Drive,
    /// Refuse (ack accepted = false).
    Refuse,
}

/// A command as a robot received it.
#[derive(Clone, Debug)]
pub struct Received {
    /// Step during which it arrived (before the ack of that step's observation).
    pub step: usize,
    /// The command.
    pub command: wire::RepositionCommand,
}

/// The fleet.
pub struct Fleet {
    pub robots: Vec<Robot>,
    pub ids: Vec<String>,
    /// Base poses, map frame.
    pub poses: Vec<Isometry3<f64>>,
    pub answers: Vec<Answer>,
    /// Commands received, per robot.
    pub commands: Vec<Vec<Received>>,
    /// Cancellations received, per robot.
    pub cancels: Vec<Vec<wire::CancelCommand>>,
    /// Goals accepted and not yet reached: (command id, goal).
    driving: Vec<Option<(u64, Isometry3<f64>)>>,
    pub source: Point3<f64>,
    /// Declared DoA σ (rad).
    pub sigma_rad: f64,
    pub step: usize,
    /// Simulated seconds per step.
    pub dt_s: f64,
}

/// Time of step `k`.
pub fn time_of(step: usize, dt_s: f64) -> Stamp {
    T0.plus_secs(dt_s * step as f64)
}

impl Fleet {
    /// Connects robots `ids` with their bases at `bases` (facing +x).
    pub async fn connect(
        addr: std::net::SocketAddr,
        ids: &[&str],
        bases: &[Point3<f64>],
        source: Point3<f64>,
    ) -> Self {
        Self::connect_declaring(addr, ids, bases, source, &vec![BaseLimits::default(); ids.len()]).await
    }

    /// [`Fleet::connect`] with each robot declaring its base's limits in its hello.
    pub async fn connect_declaring(
        addr: std::net::SocketAddr,
        ids: &[&str],
        bases: &[Point3<f64>],
        source: Point3<f64>,
        limits: &[BaseLimits],
    ) -> Self {
        let mut robots = Vec::new();
        for (id, l) in ids.iter().zip(limits) {
            let mut first = hello(id);
            if let Some(Up::Hello(h)) = &mut first.msg {
                h.base_limits = l.to_wire();
            }
            robots.push(open(addr, first, None).await.unwrap());
        }
        let n = ids.len();
        Fleet {
            robots,
            ids: ids.iter().map(|s| s.to_string()).collect(),
            poses: bases.iter().map(|b| Isometry3::translation(b.x, b.y, b.z)).collect(),
            answers: vec![Answer::Drive; n],
            commands: vec![Vec::new(); n],
            cancels: vec![Vec::new(); n],
            driving: vec![None; n],
            source,
            sigma_rad: 3f64.to_radians(),
            step: 0,
            dt_s: 0.1,
        }
    }

    /// Exact DoAs from every robot in turn at the next step's time; robots that
    /// were driving arrive first. Returns the step's time.
    pub async fn step(&mut self, clock: &ManualClock) -> Stamp {
        let t = time_of(self.step, self.dt_s);
        clock.set(t);
        for i in 0..self.robots.len() {
            if let Some((command_id, goal)) = self.driving[i].take() {
                self.poses[i] = goal;
                self.robots[i]
                    .send(Up::CommandProgress(wire::CommandProgress {
                        command_id,
                        state: wire::CommandState::Succeeded as i32,
                        distance_remaining_m: 0.0,
                        detail: "arrived".into(),
                    }))
                    .await;
            }
            let p = self.poses[i];
            let base = Point3::from(p.translation.vector);
            let yaw = p.rotation.euler_angles().2;
            let obs = observation_of(t, base, yaw, &self.source, None, self.sigma_rad);
            let seq = self.robots[i].observe(obs).await;
            let messages = self.robots[i].until_acked(seq).await;
            for m in messages {
                self.handle(i, m).await;
            }
        }
        self.step += 1;
        t
    }

    async fn handle(&mut self, i: usize, m: Down) {
        match m {
            Down::Reposition(c) => {
                let id = c.command_id;
                let goal = soundmap_proto::pose_from_wire(
                    &c.goal_map_from_base,
                    "goal",
                    &soundmap_proto::Limits {
                        now: Stamp::ZERO,
                        max_future_ns: i64::MAX,
                        max_past_ns: i64::MAX,
                        unit_vector_tolerance: 1e-3,
                        quaternion_tolerance: 1e-2,
                    },
                )
                .expect("a valid goal pose");
                self.commands[i].push(Received { step: self.step, command: c });
                let accepted = self.answers[i] == Answer::Drive;
                let robot = &self.robots[i];
                robot
                    .send(Up::CommandAck(wire::CommandAck {
                        command_id: id,
                        accepted,
                        reason: if accepted { String::new() } else { "test robot refuses".into() },
                    }))
                    .await;
                if accepted {
                    robot
                        .send(Up::CommandProgress(wire::CommandProgress {
                            command_id: id,
                            state: wire::CommandState::Executing as i32,
                            distance_remaining_m: -1.0,
                            detail: String::new(),
                        }))
                        .await;
                    self.driving[i] = Some((id, goal));
                } else {
                    self.driving[i] = None;
                }
            }
            Down::Cancel(c) => {
                if self.driving[i].is_some_and(|(id, _)| id == c.command_id) {
                    self.driving[i] = None;
                }
                self.cancels[i].push(c);
            }
            other => panic!("robot {}: unexpected {other:?}", self.ids[i]),
        }
    }

    /// Array centres in the map frame.
    pub fn arrays(&self) -> Vec<Point3<f64>> {
        self.poses.iter().map(|p| p * super::array().base_from_array * Point3::origin()).collect()
    }

    /// Best pairwise θ at the source between the robots' arrays (degrees).
    pub fn theta_deg(&self) -> f64 {
        let a = self.arrays();
        let mut best: f64 = 0.0;
        for i in 0..a.len() {
            for j in (i + 1)..a.len() {
                let (u, v): (Vector3<f64>, Vector3<f64>) = (a[i] - self.source, a[j] - self.source);
                let th = u.angle(&v).to_degrees();
                if (th - 90.0).abs() < (best - 90.0).abs() {
                    best = th;
                }
            }
        }
        best
    }

    /// Total commands received.
    pub fn command_count(&self) -> usize {
        self.commands.iter().map(Vec::len).sum()
    }
}
