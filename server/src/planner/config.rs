//! Planner settings (TOML section `[planner]`), their defaults and validation.

use serde::Deserialize;
use soundmap_proto::{BaseLimits, Problem, ValidationError};

use super::free_space::{FreeSpaceConfig, polygon_problem};

/// Settings of the sampling fallback (theory §3.5).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SamplingConfig {
    /// Bearing spacing of the polar candidate grid around the source (degrees). Default 5.
    pub bearing_step_deg: f64,
    /// Range spacing of the grid (m). Default 0.25.
    pub range_step_m: f64,
    /// Score added per metre a robot travels (the score's main term is ln tr J⁻¹). Default 0.05.
    pub travel_weight_per_m: f64,
    /// Score added per degree the best pairwise θ lies outside the band. Default 0.05.
    pub band_penalty_per_deg: f64,
    /// Two robots: exhaustive search when |C₁|·|C₂| is at most this, else Gauss–Seidel. Default 250 000.
    pub max_exhaustive_pairs: usize,
    /// Gauss–Seidel sweeps over the robots (N ≥ 3). Default 8.
    pub max_sweeps: usize,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        SamplingConfig {
            bearing_step_deg: 5.0,
            range_step_m: 0.25,
            travel_weight_per_m: 0.05,
            band_penalty_per_deg: 0.05,
            max_exhaustive_pairs: 250_000,
            max_sweeps: 8,
        }
    }
}

/// Settings of the [`Planner`](super::Planner). Ranges and separations are
/// horizontal distances between base centres and the source (m, map xy).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlannerConfig {
    /// Lower edge of the acceptable angle at the source between robots (degrees). Default 40.
    pub theta_min_deg: f64,
    /// Upper edge of that band (degrees). Default 140.
    pub theta_max_deg: f64,
    /// Re-plan when the GDOP of the current geometry exceeds this. Default 2.5
    /// (two robots at θ = 40° give 2.31, at 90° 1.58).
    pub max_gdop: f64,
    /// Keep-out radius around the source, r_min (m). Default 1.0.
    pub min_range_m: f64,
    /// Largest range from the source, r_max (m). Default 5.0.
    pub max_range_m: f64,
    /// A robot that finds itself inside the keep-out (a walker came up to it)
    /// is sent out to r_min plus the larger of this and twice the estimate's
    /// horizontal 1-σ (that part at most 1 m), at once (`planner::escape`);
    /// ordinary goals are pushed out to the same clearance from the
    /// estimate's path where the cycle's constraints allow. With 0, both keep
    /// only the 2σ part. Default 0.3 (m).
    pub keep_out_margin_m: f64,
    /// Range of the ideal spots for a still source (m), in [r_min, r_max];
    /// information grows as 1/r². Default 2.0.
    pub preferred_range_m: f64,
    /// Added to `preferred_range_m` per m/s of the source's tracked horizontal
    /// speed (s), the sum capped at r_max. Default 0.7: 2.5 m for a walker at
    /// 0.7 m/s, 2.7 m at 1 m/s.
    ///
    /// A walker sweeps a robot's bearing at v/r (20°/s at 0.7 m/s and 2 m),
    /// and θ with it, faster than robots that turn and accelerate before
    /// they drive can follow; further out it sweeps it more slowly, at a cost
    /// in accuracy about in the ratio of the ranges. Measured on the start
    /// and walker scenarios (BENCHMARKS.md, "The formation's range"): runs
    /// below 95 % in band 45 → 27 of 200 (a fixed 2.5 m: 13, but it cost the
    /// still talkers of `cocktail-active` OSPA 0.250 → 0.286 m and twice the
    /// ghosts, where this keeps 0.254 m). 0 plans every source at
    /// `preferred_range_m`.
    pub range_per_speed_s: f64,
    /// Smallest distance between two robots' goals (m). Default 0.8.
    pub min_separation_m: f64,
    /// Largest move per planning cycle (m); the cycle's step is
    /// min(this, robot speed × planning period). Default 1.0.
    pub max_step_m: f64,
    /// Cruise speed (m/s) of a robot whose hello declares none
    /// (`BaseLimits`), and the reference speed travel times are counted in
    /// when target spots are assigned. Default 0.5. The key `robot_speed_mps` is
    /// accepted as an alias (metres per second are spelled `_m_per_s` in every key).
    #[serde(alias = "robot_speed_mps")]
    pub robot_speed_m_per_s: f64,
    /// Robot turn rate in place (degrees/s), experimental, unset by default;
    /// a robot whose hello declares its turn rate uses its own.
    /// When set, the target pattern's choice counts the turn a robot makes
    /// towards its spot before it drives as travel, speed ÷ turn rate metres
    /// per radian, so that a base that turns in place is not sent behind
    /// itself when a spot ahead serves as well (`planner::bearings`). In the
    /// start scenarios' sweeps it took the runs below 95 % in band from 28 to
    /// 19 of 160, but `cocktail-active` gained id switches (2 → 24 in 20
    /// runs), a cause not understood: BENCHMARKS.md, session 15.
    pub robot_turn_rate_deg_per_s: Option<f64>,
    /// Shortest time between two re-taskings (s). Default 1.0: a walking source (0.5 m/s) moves half a metre between re-taskings.
    pub planning_period_s: f64,
    /// Re-tasking that follows a moving source (`planner::cadence`): while the
    /// estimate is precise (largest horizontal 1-σ at most
    /// `follow_retask_max_sigma_m`), goals are re-issued as soon as the source
    /// is predicted to have moved this far (m) since the last ones, but not
    /// sooner than half of `planning_period_s`; the step shrinks with the
    /// period. 0: always `planning_period_s`. Default 0.5 (m).
    pub follow_retask_travel_m: f64,
    /// The largest horizontal 1-σ (m) of an estimate whose motion shortens
    /// the re-tasking period (see `follow_retask_travel_m`). Default 0.15.
    pub follow_retask_max_sigma_m: f64,
    /// Robot footprint radius (m). Default 0.25.
    pub robot_radius_m: f64,
    /// Extra margin to walls and obstacles beyond the radius (m). Default 0.1.
    pub clearance_m: f64,
    /// Half-width of the tolerance wedge around each target bearing, δ (degrees);
    /// the det J ratio inside stays ≥ cos²2δ. Default 15.
    pub wedge_half_width_deg: f64,
    /// Weight λ_g of ‖p − g‖² against travel ‖p − p⁰‖² in the per-cycle QP; an
    /// unconstrained robot moves λ_g/(1 + λ_g) of the way. Default 50 (98 %): the
    /// travel term mostly decides where on a binding constraint the robot stops.
    pub goal_weight: f64,
    /// Re-plan a good geometry when √tr J⁻¹ would shrink by at least this fraction. Default 0.2.
    pub improvement_threshold: f64,
    /// Once re-planning for improvement, continue until the predicted gain is below this. Default 0.1.
    pub improvement_release: f64,
    /// θ must come this far inside the band to end a θ-triggered correction (degrees). Default 5.
    pub theta_hysteresis_deg: f64,
    /// A θ correction starts when θ comes this close to an edge of the band
    /// (degrees), before it leaves it: robots need seconds to move while a
    /// walking source changes θ by several degrees a second. Never narrower
    /// than 90° ± 2 × `theta_hysteresis_deg`. Default 10 (trigger outside
    /// 50–130° for the paper's 40–140° band).
    pub theta_margin_deg: f64,
    /// GDOP must fall below max_gdop × (1 − this) to end a GDOP-triggered correction. Default 0.1.
    pub gdop_hysteresis: f64,
    /// Robots with goals keep them until the source has moved this far from
    /// where it was planned for (m), unless a goal becomes infeasible. Default 0.5.
    pub follow_distance_m: f64,
    /// The source is predicted this far ahead with its velocity (s): the
    /// pattern is built around that point and the keep-out runs along the
    /// path to it. Default 1.0. Over the sweeps (BENCHMARKS.md, "The
    /// planning lead again") 2.0 keeps walkers that walk straight between
    /// turns in band more often (28 → 10 of 140 runs below 95 %; on a second
    /// seed set 26 → 18 of 100, `corner-start`'s talker no better) but loses
    /// a walker circling within the robots' range (17 → 34 of 60) and
    /// places the source less accurately; shortening it while the walker
    /// turns was tried and did not help overall.
    pub source_lead_s: f64,
    /// No planning around a source whose √tr P exceeds this (m). Default 3.0,
    /// which still lets the planner fix the paper's θ ≈ 10° geometry at 3 m (≈ 1.4 m).
    pub max_source_rms_m: f64,
    /// A waypoint closer than this to the robot is not sent (m). Default 0.1.
    pub goal_tolerance_m: f64,
    /// Rotation grid of the target pattern (degrees). Default 5.
    pub pattern_rotation_step_deg: f64,
    /// Cost per metre of arc between a robot's new and previous target bearing,
    /// against metres of travel; above 1 the pattern keeps its bearings rather than
    /// rotating toward lagging robots (no drift, no flips). Default 2.
    pub pattern_switch_weight: f64,
    /// Cost, in metres of travel, of a target spot that is not free. Default 3.0.
    pub blocked_spot_penalty_m: f64,
    /// Cost, in metres of travel, per unit of −ln det J of the pattern (3D). Default 1.0.
    pub pattern_info_weight_m: f64,
    /// Sampling fallback.
    pub sampling: SamplingConfig,
    /// Room and obstacles.
    pub free_space: FreeSpaceConfig,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        PlannerConfig {
            theta_min_deg: 40.0,
            theta_max_deg: 140.0,
            max_gdop: 2.5,
            min_range_m: 1.0,
            max_range_m: 5.0,
            keep_out_margin_m: 0.3,
            preferred_range_m: 2.0,
            range_per_speed_s: 0.7,
            min_separation_m: 0.8,
            max_step_m: 1.0,
            robot_speed_m_per_s: 0.5,
            robot_turn_rate_deg_per_s: None,
            planning_period_s: 1.0,
            follow_retask_travel_m: 0.5,
            follow_retask_max_sigma_m: 0.15,
            robot_radius_m: 0.25,
            clearance_m: 0.1,
            wedge_half_width_deg: 15.0,
            goal_weight: 50.0,
            improvement_threshold: 0.2,
            improvement_release: 0.1,
            theta_hysteresis_deg: 5.0,
            theta_margin_deg: 10.0,
            gdop_hysteresis: 0.1,
            follow_distance_m: 0.5,
            source_lead_s: 1.0,
            max_source_rms_m: 3.0,
            goal_tolerance_m: 0.1,
            pattern_rotation_step_deg: 5.0,
            pattern_switch_weight: 2.0,
            blocked_spot_penalty_m: 3.0,
            pattern_info_weight_m: 1.0,
            sampling: SamplingConfig::default(),
            free_space: FreeSpaceConfig::default(),
        }
    }
}

impl PlannerConfig {
    /// The band inside which θ triggers no correction (degrees): the band
    /// narrowed by `theta_margin_deg`, never narrower than 90° ± 2h.
    pub fn trigger_band_deg(&self) -> (f64, f64) {
        let h2 = 2.0 * self.theta_hysteresis_deg;
        let lo = (self.theta_min_deg + self.theta_margin_deg).min(90.0 - h2).max(self.theta_min_deg);
        let hi = (self.theta_max_deg - self.theta_margin_deg).max(90.0 + h2).min(self.theta_max_deg);
        (lo, hi)
    }

    /// The step a robot may take in one cycle (m): 1.5 × what it drives in a
    /// planning period, so that it is still driving when the next plan comes
    /// (a robot that reaches each waypoint stops and restarts, and falls behind
    /// a walking source), capped at `max_step_m`.
    pub fn step_m(&self) -> f64 {
        self.step_for_period_m(self.planning_period_s)
    }

    /// The step for a re-tasking period of `period_s` (see [`Self::step_m`]).
    pub fn step_for_period_m(&self, period_s: f64) -> f64 {
        self.step_of(&BaseLimits::default(), period_s)
    }

    /// The step of a robot whose base declared `base`, driving at
    /// [`Self::speed_of`], for a re-tasking period of `period_s` (see
    /// [`Self::step_m`]).
    pub fn step_of(&self, base: &BaseLimits, period_s: f64) -> f64 {
        self.max_step_m.min(1.5 * self.speed_of(base) * period_s)
    }

    /// The range of the ideal spots for a source moving at `speed_m_per_s`
    /// horizontally (m): `preferred_range_m` plus `range_per_speed_s` per m/s,
    /// at most r_max.
    pub fn range_for_speed_m(&self, speed_m_per_s: f64) -> f64 {
        let extra = self.range_per_speed_s * speed_m_per_s.max(0.0);
        (self.preferred_range_m + if extra.is_finite() { extra } else { 0.0 }).min(self.max_range_m)
    }

    /// A robot's speed (m/s): what its hello declared, else `robot_speed_m_per_s`.
    pub fn speed_of(&self, base: &BaseLimits) -> f64 {
        base.max_speed_m_per_s.unwrap_or(self.robot_speed_m_per_s)
    }

    /// What a metre driven costs a robot, in metres driven at
    /// `robot_speed_m_per_s` in the same time: 1 for a robot of that speed.
    pub fn travel_scale(&self, base: &BaseLimits) -> f64 {
        self.robot_speed_m_per_s / self.speed_of(base)
    }

    /// What a radian turned in place costs a robot, in metres driven at
    /// `robot_speed_m_per_s` in the same time: 0 unless
    /// `robot_turn_rate_deg_per_s` is set (turns counted, experimental); the
    /// robot's declared turn rate, else that setting.
    pub fn turn_cost_m_per_rad(&self, base: &BaseLimits) -> f64 {
        self.robot_turn_rate_deg_per_s.map_or(0.0, |rate| {
            self.robot_speed_m_per_s / base.max_turn_rate_deg_per_s.unwrap_or(rate).to_radians()
        })
    }

    /// The re-tasking period for a source moving at `speed_m_per_s`
    /// horizontally whose estimate's largest horizontal 1-σ is `sigma_h_m`
    /// (see `follow_retask_travel_m`).
    pub fn retask_period_s(&self, speed_m_per_s: f64, sigma_h_m: f64) -> f64 {
        let p = self.planning_period_s;
        if !(self.follow_retask_travel_m > 0.0
            && sigma_h_m <= self.follow_retask_max_sigma_m
            && speed_m_per_s > 0.0)
        {
            return p;
        }
        (self.follow_retask_travel_m / speed_m_per_s).clamp(0.5 * p, p)
    }

    /// Robot radius plus margin: distance kept from walls and obstacles (m).
    pub fn wall_clearance_m(&self) -> f64 {
        self.robot_radius_m + self.clearance_m
    }

    /// Checks every field; the error names the first bad one (its path within
    /// `[planner]`, e.g. `free_space.obstacles[2]`).
    pub fn validate(&self) -> Result<(), ValidationError> {
        let err = |field: &str, problem: String| Err(ValidationError::new(field, Problem::Invalid(problem)));
        let positive = [
            ("max_gdop", self.max_gdop),
            ("min_range_m", self.min_range_m),
            ("max_range_m", self.max_range_m),
            ("preferred_range_m", self.preferred_range_m),
            ("max_step_m", self.max_step_m),
            ("robot_speed_m_per_s", self.robot_speed_m_per_s),
            ("planning_period_s", self.planning_period_s),
            ("wedge_half_width_deg", self.wedge_half_width_deg),
            ("goal_weight", self.goal_weight),
            ("max_source_rms_m", self.max_source_rms_m),
            ("pattern_rotation_step_deg", self.pattern_rotation_step_deg),
            ("sampling.bearing_step_deg", self.sampling.bearing_step_deg),
            ("sampling.range_step_m", self.sampling.range_step_m),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return err(field, format!("must be finite and > 0, is {v}"));
            }
        }
        if let Some(v) = self.robot_turn_rate_deg_per_s
            && !(v.is_finite() && v > 0.0)
        {
            return err("robot_turn_rate_deg_per_s", format!("must be finite and > 0, is {v}"));
        }
        let non_negative = [
            ("min_separation_m", self.min_separation_m),
            ("keep_out_margin_m", self.keep_out_margin_m),
            ("range_per_speed_s", self.range_per_speed_s),
            ("follow_retask_travel_m", self.follow_retask_travel_m),
            ("follow_retask_max_sigma_m", self.follow_retask_max_sigma_m),
            ("robot_radius_m", self.robot_radius_m),
            ("clearance_m", self.clearance_m),
            ("improvement_threshold", self.improvement_threshold),
            ("improvement_release", self.improvement_release),
            ("theta_hysteresis_deg", self.theta_hysteresis_deg),
            ("theta_margin_deg", self.theta_margin_deg),
            ("gdop_hysteresis", self.gdop_hysteresis),
            ("follow_distance_m", self.follow_distance_m),
            ("source_lead_s", self.source_lead_s),
            ("goal_tolerance_m", self.goal_tolerance_m),
            ("pattern_switch_weight", self.pattern_switch_weight),
            ("blocked_spot_penalty_m", self.blocked_spot_penalty_m),
            ("pattern_info_weight_m", self.pattern_info_weight_m),
            ("sampling.travel_weight_per_m", self.sampling.travel_weight_per_m),
            ("sampling.band_penalty_per_deg", self.sampling.band_penalty_per_deg),
        ];
        for (field, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return err(field, format!("must be finite and ≥ 0, is {v}"));
            }
        }
        if !(self.theta_min_deg.is_finite() && (0.0..180.0).contains(&self.theta_min_deg)) {
            return err("theta_min_deg", format!("must be in [0°, 180°), is {}", self.theta_min_deg));
        }
        if !(self.theta_max_deg.is_finite() && self.theta_max_deg > 0.0 && self.theta_max_deg <= 180.0) {
            return err("theta_max_deg", format!("must be in (0°, 180°], is {}", self.theta_max_deg));
        }
        if self.theta_min_deg >= self.theta_max_deg {
            return err(
                "theta_min_deg",
                format!("must be below theta_max_deg ({} ≥ {})", self.theta_min_deg, self.theta_max_deg),
            );
        }
        if self.theta_min_deg + self.theta_hysteresis_deg >= self.theta_max_deg - self.theta_hysteresis_deg {
            return err("theta_hysteresis_deg", "leaves no band (min + h ≥ max − h)".into());
        }
        if self.min_range_m >= self.max_range_m {
            return err(
                "min_range_m",
                format!("must be below max_range_m ({} ≥ {})", self.min_range_m, self.max_range_m),
            );
        }
        if !(self.min_range_m..=self.max_range_m).contains(&self.preferred_range_m) {
            return err(
                "preferred_range_m",
                format!("must lie in [min_range_m, max_range_m], is {}", self.preferred_range_m),
            );
        }
        if self.wedge_half_width_deg >= 45.0 {
            return err(
                "wedge_half_width_deg",
                format!("must be below 45° (wedges up to 90° wide), is {}", self.wedge_half_width_deg),
            );
        }
        if self.improvement_threshold >= 1.0 {
            return err("improvement_threshold", "is a fraction and must be below 1".into());
        }
        if self.improvement_release > self.improvement_threshold {
            return err("improvement_release", "must not exceed improvement_threshold".into());
        }
        if self.gdop_hysteresis >= 1.0 {
            return err("gdop_hysteresis", "is a fraction and must be below 1".into());
        }
        // Grids finer than these only burn time.
        for (field, v, min) in [
            ("pattern_rotation_step_deg", self.pattern_rotation_step_deg, 0.1),
            ("sampling.bearing_step_deg", self.sampling.bearing_step_deg, 0.1),
            ("sampling.range_step_m", self.sampling.range_step_m, 0.01),
        ] {
            if v < min {
                return err(field, format!("must be ≥ {min}, is {v}"));
            }
        }
        if self.sampling.max_sweeps == 0 {
            return err("sampling.max_sweeps", "must be ≥ 1".into());
        }
        if !self.free_space.room.is_empty()
            && let Some(p) = polygon_problem(&self.free_space.room)
        {
            return err("free_space.room", p);
        }
        for (k, o) in self.free_space.obstacles.iter().enumerate() {
            if let Some(p) = polygon_problem(o) {
                return err(&format!("free_space.obstacles[{k}]"), p);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid() {
        PlannerConfig::default().validate().unwrap();
        // 1.5 × 0.5 m/s × 1 s, under the 1 m cap.
        assert!((PlannerConfig::default().step_m() - 0.75).abs() < 1e-12);
    }

    #[test]
    fn retasking_follows_a_precise_moving_source() {
        let c = PlannerConfig { follow_retask_travel_m: 0.5, ..Default::default() };
        // A still or slow source, or a vague estimate: the configured period.
        assert_eq!(c.retask_period_s(0.0, 0.05), 1.0);
        assert_eq!(c.retask_period_s(0.4, 0.05), 1.0); // 0.5 m at 0.4 m/s: 1.25 s, capped
        assert_eq!(c.retask_period_s(1.0, 0.2), 1.0);
        // 0.5 m of travel: 0.625 s at 0.8 m/s, never under half the period.
        assert!((c.retask_period_s(0.8, 0.05) - 0.625).abs() < 1e-12);
        assert_eq!(c.retask_period_s(3.0, 0.05), 0.5);
        assert!((c.step_for_period_m(0.625) - 0.46875).abs() < 1e-12);
        let off = PlannerConfig { follow_retask_travel_m: 0.0, ..Default::default() };
        assert_eq!(off.retask_period_s(3.0, 0.05), 1.0);
        assert_eq!(c.retask_period_s(f64::NAN, 0.05), 1.0);
        assert_eq!(c.retask_period_s(1.0, f64::NAN), 1.0);
    }

    #[test]
    fn the_ideal_range_grows_with_the_sources_speed() {
        let c = PlannerConfig::default();
        assert_eq!(c.range_for_speed_m(0.0), 2.0);
        assert!((c.range_for_speed_m(1.0) - 2.7).abs() < 1e-12);
        // At most r_max (5 m); a speed that is not a number adds nothing.
        assert_eq!(c.range_for_speed_m(10.0), 5.0);
        assert_eq!(c.range_for_speed_m(f64::NAN), 2.0);
        assert_eq!(c.range_for_speed_m(-1.0), 2.0);
        let fixed = PlannerConfig { range_per_speed_s: 0.0, ..Default::default() };
        assert_eq!(fixed.range_for_speed_m(1.0), 2.0);
        for bad in [-0.1, f64::NAN, f64::INFINITY] {
            let c = PlannerConfig { range_per_speed_s: bad, ..Default::default() };
            assert_eq!(c.validate().unwrap_err().field, "range_per_speed_s");
        }
    }

    #[test]
    fn errors_name_the_field() {
        let field = |c: PlannerConfig| c.validate().unwrap_err().field;
        assert_eq!(field(PlannerConfig { theta_min_deg: 150.0, ..Default::default() }), "theta_min_deg");
        assert_eq!(field(PlannerConfig { min_range_m: -1.0, ..Default::default() }), "min_range_m");
        assert_eq!(field(PlannerConfig { robot_radius_m: -0.1, ..Default::default() }), "robot_radius_m");
        for bad in [0.0, -30.0, f64::NAN, f64::INFINITY] {
            let c = PlannerConfig { robot_turn_rate_deg_per_s: Some(bad), ..Default::default() };
            assert_eq!(field(c), "robot_turn_rate_deg_per_s");
        }
        PlannerConfig { robot_turn_rate_deg_per_s: Some(120.0), ..Default::default() }.validate().unwrap();
        assert_eq!(field(PlannerConfig { max_range_m: 0.5, ..Default::default() }), "min_range_m");
        assert_eq!(
            field(PlannerConfig { preferred_range_m: 9.0, ..Default::default() }),
            "preferred_range_m"
        );
        let mut c = PlannerConfig::default();
        c.free_space.room = vec![[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]];
        assert_eq!(field(c.clone()), "free_space.room");
        c.free_space.room = vec![];
        c.free_space.obstacles = vec![vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]], vec![]];
        assert_eq!(field(c), "free_space.obstacles[1]");
        let e = PlannerConfig { theta_max_deg: 30.0, ..Default::default() }.validate().unwrap_err();
        assert!(e.to_string().contains("theta_min_deg") && e.to_string().contains("theta_max_deg"), "{e}");
    }
}
