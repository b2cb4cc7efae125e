//! Settings of the source tracker, with documented defaults and validation.

use serde::Deserialize;
use soundmap_proto::{Problem, ValidationError};

use super::filter::{DoaNoiseModel, ProcessNoise};
use super::imm::{Diffusion, Modes};
use super::lifecycle::{LifecycleRules, MAX_CONFIRM_UPDATES};
use super::noise::{LearningRules, MAX_WINDOW};
use crate::ray::MIN_RANGE_M;
use crate::stats::chi2_quantile;

/// Longest `smoothing_lag_s` (s): bounds the smoother's history.
pub const MAX_SMOOTHING_LAG_S: f64 = 10.0;

/// Settings of [`SourceTracker`](super::SourceTracker). Times are seconds,
/// distances metres, probabilities in (0, 1).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Whether the coordinator runs the tracker (`[tracking] enabled`). Default
    /// true. [`SourceTracker`](super::SourceTracker) itself ignores it.
    pub enabled: bool,
    /// Horizontal (x, y) white-noise acceleration PSD q̃ of the *moving* mode
    /// (m²/s³). Default 0.5: σ_a ≈ 1 m/s² over τ ≈ 0.5 s, a walking person
    /// (theory §4.1). The tracker mixes it with the still mode below
    /// (`tracking::imm`).
    pub accel_psd_horizontal_m2_per_s3: f64,
    /// Vertical (z) PSD q̃ of the moving mode (m²/s³). Default 0.01: talker
    /// height changes slowly.
    pub accel_psd_vertical_m2_per_s3: f64,
    /// Whether the tracker mixes a *still* mode with the moving one (an IMM
    /// filter, `tracking::imm`): a still source is then averaged over
    /// seconds, a walker followed as before. Default true; false gives the
    /// single constant-velocity filter.
    pub still_mode: bool,
    /// Position diffusion D of the still mode, x and y (m²/s: variance D·Δt).
    /// Default 0.002 (≈ 10 cm in 5 s, a seated talker's sway).
    pub still_diffusion_horizontal_m2_per_s: f64,
    /// Position diffusion D of the still mode, z (m²/s). Default 0.0005.
    pub still_diffusion_vertical_m2_per_s: f64,
    /// Mean time a source stays in one mode (s), which sets the switch
    /// probability ½(1 − e^{−Δt/τ}) per step. Default 30: longer keeps
    /// the idle mode's weight (and so its lag or jitter in the mixture) smaller,
    /// shorter lets the modes take over from each other sooner.
    pub mode_sojourn_s: f64,
    /// 1-σ of the initial horizontal velocity (m/s). Default 1.0 (theory §4.2).
    pub initial_velocity_sigma_horizontal_m_per_s: f64,
    /// 1-σ of the initial vertical velocity (m/s). Default 0.3.
    pub initial_velocity_sigma_vertical_m_per_s: f64,
    /// Factor on a triangulation's covariance when it initializes a track.
    /// Default 1.5: that covariance is a Cramér–Rao floor (theory §7).
    pub init_covariance_inflation: f64,
    /// Factor on each DoA's σ_eff² (theory §7: 1.5–2 for reverberant rooms).
    /// Default 1.5; 1.0 is the ideal model.
    pub doa_variance_inflation: f64,
    /// Floor on a DoA's σ (rad). Default 1e-4.
    pub min_sigma_rad: f64,
    /// A predicted source closer than this to an array gets no update from it (m).
    /// Default 0.3 (the far-field limit used by the rays).
    pub min_range_m: f64,
    /// χ² (2 dof) gate probability of a tentative track, where a DoA must
    /// *associate* to it. Default 0.99 (9.21, theory §4.3). Also the gate of [`SourceTracker::nis`](super::SourceTracker::nis) callers should use
    /// for association, see [`SourceTracker::association_threshold`](super::SourceTracker::association_threshold).
    pub association_probability: f64,
    /// χ² (2 dof) gate probability of a confirmed track (maintenance). Default 0.999 (13.82).
    pub maintenance_probability: f64,
    /// Fixed lag of the out-of-sequence buffer (s): DoAs stamped up to this much
    /// before the newest are applied exactly; older ones are dropped. Default 0.5.
    pub lag_s: f64,
    /// Most DoAs held in the lag buffer (bounds memory and replay cost). Default 256.
    pub max_buffered: usize,
    /// Accepted updates needed for confirmation, 1..=16. Default 6.
    pub confirm_updates: usize,
    /// Distinct robots among them. Default 2.
    pub confirm_min_robots: usize,
    /// Time span they must fall within (s). Default 2.0.
    pub confirm_window_s: f64,
    /// Largest position RMS √tr P_pos at confirmation (m). Default 0.5.
    pub confirm_max_rms_m: f64,
    /// Silence (no accepted DoA) that loses a tentative track (s). Default 2.0.
    pub tentative_timeout_s: f64,
    /// Silence that loses a confirmed track (s). Default 3.0.
    pub lost_timeout_s: f64,
    /// Position RMS that loses any track (m). Default 2.0.
    pub lost_max_rms_m: f64,
    /// Largest position RMS of an estimate marked trusted (m). Default 0.5.
    pub trusted_max_rms_m: f64,
    /// Most DoAs per second applied from each robot (Hz); more frequent ones
    /// are skipped. Agents send every hop (125 Hz) of their own DoA tracker,
    /// whose outputs are smoothed and whose errors are correlated over much
    /// longer (reflections bias them consistently): applied as independent
    /// measurements they would shrink the covariance far below the real
    /// error. 0 applies every DoA. Default 10.
    pub max_doa_rate_hz: f64,
    /// A confirmed track is trusted only while a second robot's DoA was
    /// accepted within this long of its newest one (s). Default 0.5: one
    /// robot's bearings alone leave the range along them unobserved, and a
    /// filter fed by one robot slides along its ray while its covariance still
    /// looks small.
    pub support_window_s: f64,
    /// Share of one triangulation's covariance added to the filter's when a
    /// filtered estimate is published. In a room, a robot's DoAs carry an error
    /// that persists while the geometry holds (reflections), so averaging them
    /// does not bring the error below that of one triangulation of the current
    /// rays, however small the filter's own covariance grows. 1 keeps that
    /// floor; 0 trusts the filter's independent-noise model (free field).
    /// The tracked state itself (and its published `filtered` covariance) is
    /// unchanged. Default 1.0.
    pub correlated_doa_fraction: f64,
    /// A confirmed track fed by a single robot (the others' DoAs gated) for
    /// this long is lost and restarts from the next trusted triangulation (s). Default 1.0.
    pub single_robot_timeout_s: f64,
    /// Learn each robot's DoA noise from its innovations against the track
    /// and inflate the measurement variance when they say the prior σ is too
    /// small (never deflate it; see `tracking::noise`). Default true.
    pub learn_doa_noise: bool,
    /// Averaging length of the learned noise (DoAs). Default 20 (2 s at 10 Hz).
    pub noise_learning_updates: f64,
    /// Largest learned variance scale λ (R = λ·R₀). Default 16 (σ × 4).
    pub max_noise_scale: f64,
    /// DoAs in the consistency window (applied or gated), 1..=32. Default 20.
    pub consistency_window: usize,
    /// A track is trusted only while the NIS sum of its window is within the
    /// χ² (2W dof) quantile at this probability. Default 0.99 (mean NIS ≤ 3.19 at W = 20).
    pub consistency_probability: f64,
    /// θ at the track (widest angle between the rays of robots heard within
    /// `support_window_s`, folded to ≤ 90°) from which the geometry counts as
    /// good (degrees). A track is trusted only at θ at or above it, or once
    /// `evidence_updates` DoAs were applied at such a θ; a track started from a
    /// triangulation with θ below it restarts from the first accepted
    /// triangulation above it while it has no such evidence. Default 30.
    pub good_geometry_theta_deg: f64,
    /// DoAs applied at good geometry after which a track may stay trusted when
    /// the geometry degrades (its covariance then says how well it is pinned). Default 20.
    pub evidence_updates: u32,
    /// How far behind the live estimate the fixed-lag smoothed estimate is
    /// (s): the track's state at (newest DoA − lag), from the DoAs before and
    /// after it (`tracking::smoother`). Default 1.0; 0 switches it off;
    /// at most [`MAX_SMOOTHING_LAG_S`].
    pub smoothing_lag_s: f64,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            enabled: true,
            accel_psd_horizontal_m2_per_s3: 0.5,
            accel_psd_vertical_m2_per_s3: 0.01,
            still_mode: true,
            still_diffusion_horizontal_m2_per_s: 0.002,
            still_diffusion_vertical_m2_per_s: 0.0005,
            mode_sojourn_s: 30.0,
            initial_velocity_sigma_horizontal_m_per_s: 1.0,
            initial_velocity_sigma_vertical_m_per_s: 0.3,
            init_covariance_inflation: 1.5,
            doa_variance_inflation: 1.5,
            min_sigma_rad: 1e-4,
            min_range_m: MIN_RANGE_M,
            association_probability: 0.99,
            maintenance_probability: 0.999,
            lag_s: 0.5,
            max_buffered: 256,
            confirm_updates: 6,
            confirm_min_robots: 2,
            confirm_window_s: 2.0,
            confirm_max_rms_m: 0.5,
            tentative_timeout_s: 2.0,
            lost_timeout_s: 3.0,
            lost_max_rms_m: 2.0,
            trusted_max_rms_m: 0.5,
            max_doa_rate_hz: 10.0,
            support_window_s: 0.5,
            single_robot_timeout_s: 1.0,
            correlated_doa_fraction: 1.0,
            learn_doa_noise: true,
            noise_learning_updates: 20.0,
            max_noise_scale: 16.0,
            consistency_window: 20,
            consistency_probability: 0.99,
            good_geometry_theta_deg: 30.0,
            evidence_updates: 20,
            smoothing_lag_s: 1.0,
        }
    }
}

impl TrackerConfig {
    /// Checks every field; the first violation is returned, naming the field
    /// within `[tracking]`.
    pub fn validate(&self) -> Result<(), ValidationError> {
        let fail = |field: &str, requirement: &str| {
            Err(ValidationError::new(field, Problem::Invalid(requirement.into())))
        };
        let non_negative = [
            ("accel_psd_horizontal_m2_per_s3", self.accel_psd_horizontal_m2_per_s3),
            ("accel_psd_vertical_m2_per_s3", self.accel_psd_vertical_m2_per_s3),
            ("still_diffusion_horizontal_m2_per_s", self.still_diffusion_horizontal_m2_per_s),
            ("still_diffusion_vertical_m2_per_s", self.still_diffusion_vertical_m2_per_s),
            ("initial_velocity_sigma_horizontal_m_per_s", self.initial_velocity_sigma_horizontal_m_per_s),
            ("initial_velocity_sigma_vertical_m_per_s", self.initial_velocity_sigma_vertical_m_per_s),
            ("lag_s", self.lag_s),
            ("confirm_window_s", self.confirm_window_s),
            ("tentative_timeout_s", self.tentative_timeout_s),
            ("lost_timeout_s", self.lost_timeout_s),
            ("support_window_s", self.support_window_s),
            ("max_doa_rate_hz", self.max_doa_rate_hz),
            ("single_robot_timeout_s", self.single_robot_timeout_s),
            ("correlated_doa_fraction", self.correlated_doa_fraction),
            ("good_geometry_theta_deg", self.good_geometry_theta_deg),
        ];
        for (field, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return fail(field, "must be finite and ≥ 0");
            }
        }
        let positive = [
            ("mode_sojourn_s", self.mode_sojourn_s),
            ("init_covariance_inflation", self.init_covariance_inflation),
            ("doa_variance_inflation", self.doa_variance_inflation),
            ("min_sigma_rad", self.min_sigma_rad),
            ("min_range_m", self.min_range_m),
            ("confirm_max_rms_m", self.confirm_max_rms_m),
            ("lost_max_rms_m", self.lost_max_rms_m),
            ("trusted_max_rms_m", self.trusted_max_rms_m),
        ];
        if !(self.noise_learning_updates.is_finite() && self.noise_learning_updates >= 1.0) {
            return fail("noise_learning_updates", "must be finite and ≥ 1");
        }
        if !(self.max_noise_scale.is_finite() && self.max_noise_scale >= 1.0) {
            return fail("max_noise_scale", "must be finite and ≥ 1");
        }
        if !(1..=MAX_WINDOW).contains(&self.consistency_window) {
            return fail("consistency_window", "must be in 1..=32");
        }
        if !(self.smoothing_lag_s.is_finite() && (0.0..=MAX_SMOOTHING_LAG_S).contains(&self.smoothing_lag_s))
        {
            return fail("smoothing_lag_s", "must be in [0, 10]");
        }
        if self.good_geometry_theta_deg > 90.0 {
            return fail("good_geometry_theta_deg", "must be in [0, 90]");
        }
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return fail(field, "must be finite and > 0");
            }
        }
        for (field, p) in [
            ("association_probability", self.association_probability),
            ("maintenance_probability", self.maintenance_probability),
            ("consistency_probability", self.consistency_probability),
        ] {
            if !(p > 0.0 && p < 1.0) {
                return fail(field, "must be in (0, 1)");
            }
        }
        if self.association_probability > self.maintenance_probability {
            return fail("association_probability", "must be ≤ maintenance_probability");
        }
        if !(1..=MAX_CONFIRM_UPDATES).contains(&self.confirm_updates) {
            return fail("confirm_updates", "must be in 1..=16");
        }
        if !(1..=self.confirm_updates).contains(&self.confirm_min_robots) {
            return fail("confirm_min_robots", "must be in 1..=confirm_updates");
        }
        if self.max_buffered == 0 {
            return fail("max_buffered", "must be ≥ 1");
        }
        if self.trusted_max_rms_m > self.lost_max_rms_m {
            return fail("trusted_max_rms_m", "must be ≤ lost_max_rms_m");
        }
        Ok(())
    }

    pub(super) fn modes(&self) -> Modes {
        Modes {
            still: self.still_mode.then_some(Diffusion {
                horizontal_m2_per_s: self.still_diffusion_horizontal_m2_per_s,
                vertical_m2_per_s: self.still_diffusion_vertical_m2_per_s,
            }),
            moving: ProcessNoise {
                horizontal_m2_per_s3: self.accel_psd_horizontal_m2_per_s3,
                vertical_m2_per_s3: self.accel_psd_vertical_m2_per_s3,
            },
            sojourn_s: self.mode_sojourn_s,
        }
    }

    pub(super) fn doa_noise(&self) -> DoaNoiseModel {
        DoaNoiseModel {
            variance_inflation: self.doa_variance_inflation,
            min_sigma_rad: self.min_sigma_rad,
            min_range_m: self.min_range_m,
        }
    }

    pub(super) fn lifecycle(&self) -> LifecycleRules {
        LifecycleRules {
            confirm_updates: self.confirm_updates,
            confirm_min_robots: self.confirm_min_robots,
            confirm_window_ns: secs_to_ns(self.confirm_window_s),
            confirm_max_rms_m: self.confirm_max_rms_m,
            tentative_timeout_s: self.tentative_timeout_s,
            lost_timeout_s: self.lost_timeout_s,
            lost_max_rms_m: self.lost_max_rms_m,
            support_window_ns: secs_to_ns(self.support_window_s),
            single_robot_timeout_s: self.single_robot_timeout_s,
        }
    }

    pub(super) fn learning(&self) -> LearningRules {
        let window = self.consistency_window.clamp(1, MAX_WINDOW);
        LearningRules {
            learn: self.learn_doa_noise,
            updates: self.noise_learning_updates,
            max_scale: self.max_noise_scale,
            window,
            window_limit: chi2_quantile(2 * window, self.consistency_probability),
        }
    }

    pub(super) fn lag_ns(&self) -> i64 {
        secs_to_ns(self.lag_s)
    }

    pub(super) fn smoothing_lag_ns(&self) -> i64 {
        secs_to_ns(self.smoothing_lag_s)
    }
}

/// Seconds to nanoseconds, saturating, NaN as 0.
fn secs_to_ns(s: f64) -> i64 {
    let ns = (s * 1e9).round();
    if ns.is_nan() { 0 } else { ns.clamp(i64::MIN as f64, i64::MAX as f64) as i64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_toml_parses() {
        TrackerConfig::default().validate().unwrap();
        let c: TrackerConfig = toml::from_str("lag_s = 0.3\nconfirm_updates = 4").unwrap();
        assert_eq!(c.lag_s, 0.3);
        assert_eq!(c.confirm_updates, 4);
        assert_eq!(c.lost_timeout_s, 3.0);
        assert!(toml::from_str::<TrackerConfig>("lag = 0.3").is_err(), "unknown fields are rejected");
    }

    #[test]
    fn bad_values_name_their_field() {
        let bad = TrackerConfig { lag_s: f64::NAN, ..TrackerConfig::default() };
        assert_eq!(bad.validate().unwrap_err().field, "lag_s");
        for lag in [f64::NAN, -0.5, 10.5] {
            let bad = TrackerConfig { smoothing_lag_s: lag, ..TrackerConfig::default() };
            assert_eq!(bad.validate().unwrap_err().field, "smoothing_lag_s");
        }
        let bad = TrackerConfig { confirm_updates: 17, ..TrackerConfig::default() };
        assert_eq!(bad.validate().unwrap_err().field, "confirm_updates");
        let bad = TrackerConfig { association_probability: 0.9995, ..TrackerConfig::default() };
        assert_eq!(bad.validate().unwrap_err().field, "association_probability");
    }
}
