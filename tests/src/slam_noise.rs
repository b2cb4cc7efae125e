//! The pose error a SLAM system adds: the agents see a noisy `map_from_base`,
//! the scorer keeps the truth.
//!
//! Model, per horizontal axis (x, y) and for yaw, in the map frame:
//! `reported = true + drift(t) + white`, where `white` is drawn independently at
//! every observation and `drift` is a slow process started at zero when SLAM
//! starts (t = 0):
//!
//! - first-order Gauss–Markov, `ḋ = −d/τ + noise`, discretized exactly for any
//!   step `Δt`: `d ← e^(−Δt/τ)·d + σ·√(1 − e^(−2Δt/τ))·N(0, 1)`, with stationary
//!   standard deviation `σ`; variance at time t: `σ²(1 − e^(−2t/τ))`;
//! - or a random walk, `d ← d + s·√Δt·N(0, 1)`, variance `s²·t`.
//!
//! z, roll and pitch get optional white noise only (ground robots with a planar
//! SLAM have none). Orientation errors are applied in the map frame:
//! `R_reported = R_z(δψ)·R_x(δroll)·R_y(δpitch)·R_true`. The default
//! values are in the range RTAB-Map reaches indoors: 2 cm and 0.5° white,
//! 3 cm and 0.8° Gauss–Markov drift with τ = 20 s (about 3.6 cm and 0.9° in total).

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::error::SimError;

/// The slow part of the error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Drift {
    /// No drift.
    None,
    /// First-order Gauss–Markov with stationary standard deviations.
    GaussMarkov {
        /// Stationary standard deviation per horizontal axis (m).
        position_std_m: f64,
        /// Stationary standard deviation of yaw (rad).
        yaw_std_rad: f64,
        /// Correlation time τ (s).
        time_constant_s: f64,
    },
    /// Random walk: standard deviation grows as `√t`.
    RandomWalk {
        /// Position standard deviation after 1 s, per horizontal axis (m/√s).
        position_m_per_sqrt_s: f64,
        /// Yaw standard deviation after 1 s (rad/√s).
        yaw_rad_per_sqrt_s: f64,
    },
}

/// Parameters of the SLAM pose error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlamNoiseConfig {
    /// White position noise per horizontal axis (m).
    pub position_white_std_m: f64,
    /// White yaw noise (rad).
    pub yaw_white_std_rad: f64,
    /// White z noise (m).
    pub z_white_std_m: f64,
    /// White roll and pitch noise (rad).
    pub tilt_white_std_rad: f64,
    /// The slow part.
    pub drift: Drift,
}

impl Default for SlamNoiseConfig {
    /// 2 cm / 0.5° white, 3 cm / 0.8° Gauss–Markov drift with τ = 20 s, no z or tilt noise.
    fn default() -> Self {
        SlamNoiseConfig {
            position_white_std_m: 0.02,
            yaw_white_std_rad: 0.5f64.to_radians(),
            z_white_std_m: 0.0,
            tilt_white_std_rad: 0.0,
            drift: Drift::GaussMarkov {
                position_std_m: 0.03,
                yaw_std_rad: 0.8f64.to_radians(),
                time_constant_s: 20.0,
            },
        }
    }
}

impl SlamNoiseConfig {
    /// No error at all.
    pub fn perfect() -> Self {
        SlamNoiseConfig {
            position_white_std_m: 0.0,
            yaw_white_std_rad: 0.0,
            z_white_std_m: 0.0,
            tilt_white_std_rad: 0.0,
            drift: Drift::None,
        }
    }

    /// Checks that every value is finite and non-negative (τ > 0).
    pub fn validate(&self) -> Result<(), SimError> {
        let mut values = vec![
            ("slam_noise.position_white_std_m", self.position_white_std_m),
            ("slam_noise.yaw_white_std_rad", self.yaw_white_std_rad),
            ("slam_noise.z_white_std_m", self.z_white_std_m),
            ("slam_noise.tilt_white_std_rad", self.tilt_white_std_rad),
        ];
        match self.drift {
            Drift::None => {}
            Drift::GaussMarkov { position_std_m, yaw_std_rad, time_constant_s } => {
                values.push(("slam_noise.drift.position_std_m", position_std_m));
                values.push(("slam_noise.drift.yaw_std_rad", yaw_std_rad));
                if !(time_constant_s.is_finite() && time_constant_s > 0.0) {
                    return Err(SimError::invalid(
                        "slam_noise.drift.time_constant_s",
                        format!("must be finite and > 0, got {time_constant_s}"),
                    ));
                }
            }
            Drift::RandomWalk { position_m_per_sqrt_s, yaw_rad_per_sqrt_s } => {
                values.push(("slam_noise.drift.position_m_per_sqrt_s", position_m_per_sqrt_s));
                values.push(("slam_noise.drift.yaw_rad_per_sqrt_s", yaw_rad_per_sqrt_s));
            }
        }
        for (field, v) in values {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SimError::invalid(field, format!("must be finite and ≥ 0, got {v}")));
            }
        }
        Ok(())
    }
}

/// One robot's SLAM error process.
#[derive(Clone, Debug)]
pub struct SlamNoise {
    config: SlamNoiseConfig,
    rng: ChaCha8Rng,
    /// Drift of (x, y, yaw), m and rad.
    drift: Vector3<f64>,
    /// Time of the last observation (s since SLAM start).
    time_s: f64,
}

impl SlamNoise {
    /// A process started at t = 0 with zero drift, drawn from `seed`.
    pub fn new(config: SlamNoiseConfig, seed: u64) -> Result<Self, SimError> {
        config.validate()?;
        Ok(SlamNoise { config, rng: ChaCha8Rng::seed_from_u64(seed), drift: Vector3::zeros(), time_s: 0.0 })
    }

    /// The configuration.
    pub fn config(&self) -> &SlamNoiseConfig {
        &self.config
    }

    /// Current drift `(x m, y m, yaw rad)`.
    pub fn drift(&self) -> Vector3<f64> {
        self.drift
    }

    /// Time of the last observation (s).
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Advances the drift to `t_s` (s since SLAM start, never decreasing) and
    /// returns the pose SLAM reports for the true `map_from_base`.
    pub fn observe(
        &mut self,
        t_s: f64,
        true_map_from_base: &Isometry3<f64>,
    ) -> Result<Isometry3<f64>, SimError> {
        if !(t_s.is_finite() && t_s >= self.time_s) {
            return Err(SimError::invalid(
                "slam_noise.t_s",
                format!("times must not decrease: {t_s} after {}", self.time_s),
            ));
        }
        self.advance(t_s - self.time_s);
        self.time_s = t_s;
        let c = self.config;
        let mut n = || -> f64 { self.rng.sample(StandardNormal) };
        let dx = self.drift.x + c.position_white_std_m * n();
        let dy = self.drift.y + c.position_white_std_m * n();
        let dz = c.z_white_std_m * n();
        let dyaw = self.drift.z + c.yaw_white_std_rad * n();
        let droll = c.tilt_white_std_rad * n();
        let dpitch = c.tilt_white_std_rad * n();
        let rot_error = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), dyaw)
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), droll)
            * UnitQuaternion::from_axis_angle(&Vector3::y_axis(), dpitch);
        let t = true_map_from_base.translation.vector + Vector3::new(dx, dy, dz);
        Ok(Isometry3::from_parts(Translation3::from(t), rot_error * true_map_from_base.rotation))
    }

    /// Covariance of the reported pose's error at the last observation's time,
    /// over (x, y, z, rx, ry, rz) in the map frame, m² and rad²: white plus drift
    /// variance. This is what an agent should report with its pose.
    pub fn covariance(&self) -> Matrix6<f64> {
        self.covariance_at(self.time_s)
    }

    /// [`Self::covariance`] at `t_s` seconds after SLAM start.
    pub fn covariance_at(&self, t_s: f64) -> Matrix6<f64> {
        let c = self.config;
        let t = t_s.max(0.0);
        let (dp, dyaw) = match c.drift {
            Drift::None => (0.0, 0.0),
            Drift::GaussMarkov { position_std_m, yaw_std_rad, time_constant_s } => {
                let f = 1.0 - (-2.0 * t / time_constant_s).exp();
                (position_std_m.powi(2) * f, yaw_std_rad.powi(2) * f)
            }
            Drift::RandomWalk { position_m_per_sqrt_s, yaw_rad_per_sqrt_s } => {
                (position_m_per_sqrt_s.powi(2) * t, yaw_rad_per_sqrt_s.powi(2) * t)
            }
        };
        let p = c.position_white_std_m.powi(2) + dp;
        let tilt = c.tilt_white_std_rad.powi(2);
        Matrix6::from_diagonal(&nalgebra::Vector6::new(
            p,
            p,
            c.z_white_std_m.powi(2),
            tilt,
            tilt,
            c.yaw_white_std_rad.powi(2) + dyaw,
        ))
    }

    fn advance(&mut self, dt: f64) {
        if dt <= 0.0 {
            return;
        }
        let (decay, pos_std, yaw_std) = match self.config.drift {
            Drift::None => return,
            Drift::GaussMarkov { position_std_m, yaw_std_rad, time_constant_s } => {
                let a = (-dt / time_constant_s).exp();
                let q = (1.0 - a * a).sqrt();
                (a, position_std_m * q, yaw_std_rad * q)
            }
            Drift::RandomWalk { position_m_per_sqrt_s, yaw_rad_per_sqrt_s } => {
                (1.0, position_m_per_sqrt_s * dt.sqrt(), yaw_rad_per_sqrt_s * dt.sqrt())
            }
        };
        let z: [f64; 3] = std::array::from_fn(|_| self.rng.sample(StandardNormal));
        self.drift = self.drift * decay + Vector3::new(pos_std * z[0], pos_std * z[1], yaw_std * z[2]);
    }
}
