//! What a track learns about its robots' DoAs while it follows the source:
//! each robot's real DoA noise, the consistency of the recent innovations, and
//! the geometry of the robots that feed it. All of it lives in the replayable
//! snapshot, so the fixed-lag buffer reproduces it exactly.
//!
//! ## Learned DoA noise (per robot, covariance matching)
//!
//! A robot's DoA carries a σ: the one it reports (soundmap's own pipeline), or
//! the prior of its DoA source (an ODAS bridge attaches one for ODAS's grid,
//! `[doa] default_sigma_deg` otherwise). That σ₀ gives the prior measurement
//! variance R₀ = σ_eff²·inflation per tangent axis. The filter uses R = λ·R₀
//! with a scale λ ≥ 1 learned per robot from its innovations ν against the
//! tracked source. With S = HPHᵀ + R, a consistent model has
//! E\[νᵀν\] = tr(HPHᵀ) + 2λR₀, so each DoA gives the sample
//!
//! ```text
//! λ̂ = (νᵀν − tr(HPHᵀ)) / (2 R₀) = (νᵀν − tr S + 2λR₀) / (2 R₀)
//! ```
//!
//! averaged over the last ~N applied DoAs (exponential weights 1/N, starting
//! from [`PRIOR_WEIGHT`] pseudo-samples of λ = 1). λ̂ is λ·χ²₂/2 when the model
//! holds, so its mean over n samples has a relative spread ≈ 1/√n: the prior
//! is kept (λ = 1) until the mean exceeds 1 + z/√n with z = [`SIGNIFICANCE_Z`]
//! (1.67 at n = 20, 99.9 % one-sided), and then λ = min(mean, λ_max). So
//! residuals only ever *inflate* the prior, and only when they say it is
//! wrong; a right prior is left alone (the filter stays consistent). A sample
//! is capped at 4·λ_max so one wild DoA cannot blow λ up; gated DoAs do not
//! teach λ (a 40° reflection is a wrong DoA, not noise) but count in the
//! consistency window below. Worked numbers: ODAS at σ₀ = 4° (inflation 1.5 → R₀ = 24 deg²)
//! whose DoAs really scatter by 7° per axis gives λ̂ ≈ 49/24 ≈ 2.0 once the
//! track is pinned (tr HPHᵀ small), i.e. R = (7°)².
//!
//! The scales are a property of the robots, not of one track: a new track
//! starts with the scales its predecessor learned.
//!
//! ## Consistency (windowed NIS)
//!
//! The NIS of the last W DoAs (applied or gated, each capped at
//! [`NIS_CAP`]) is summed; with a right model the sum is χ² with 2W degrees of
//! freedom, so the window is consistent while sum ≤ χ²₂W(p). At W = 20 and
//! p = 0.99 that is a mean NIS ≤ 3.19 (2 expected).
//!
//! ## Geometry
//!
//! The newest accepted ray origin of each robot is kept; θ at a point p is the
//! widest angle, folded to [0°, 90°], between p − oᵢ and p − oⱼ over the robots
//! heard within the support window. Trust needs θ ≥ the trusted gate, or
//! evidence: enough updates applied while θ was above it.

use nalgebra::Point3;
use soundmap_proto::Stamp;

/// Most robots a track remembers (the least recently heard is replaced).
pub const MAX_ROBOTS: usize = 8;
/// Longest consistency window.
pub const MAX_WINDOW: usize = 32;
/// Largest NIS counted in the consistency window (a DoA far off counts as this).
pub const NIS_CAP: f64 = 50.0;
/// Pseudo-samples of λ = 1 a robot's scale starts from.
pub const PRIOR_WEIGHT: f64 = 5.0;
/// z of the one-sided test that the noise is larger than the prior says (99.9 %).
pub const SIGNIFICANCE_Z: f64 = 3.0;

/// How the noise is learned and consistency judged.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LearningRules {
    /// Whether λ is learned (false: λ = 1, the prior σ is used as given).
    pub learn: bool,
    /// Averaging length N (DoAs).
    pub updates: f64,
    /// Largest λ.
    pub max_scale: f64,
    /// Consistency window W (1..=[`MAX_WINDOW`]).
    pub window: usize,
    /// Largest NIS sum of a full window (χ²₂W at the consistency probability).
    pub window_limit: f64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct RobotNoise {
    robot: u32,
    /// Running mean of λ̂.
    mean: f64,
    /// DoAs averaged so far.
    samples: u32,
    /// Newest accepted ray origin and its stamp.
    origin: Option<(Stamp, Point3<f64>)>,
    /// Whether that ray was folded with the upper branch kept
    /// ([`crate::floor_image::FloorFold::upper_branch`]).
    folded: bool,
    /// Stamp of the newest DoA seen (for replacement).
    seen: Stamp,
}

/// Per-robot noise scales, the NIS window and the robots' positions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Learned {
    robots: [Option<RobotNoise>; MAX_ROBOTS],
    nis: [f64; MAX_WINDOW],
    nis_len: usize,
    nis_next: usize,
    /// Updates applied while θ was at or above the trusted gate.
    pub good_geometry_updates: u32,
}

impl Default for Learned {
    fn default() -> Self {
        Learned {
            robots: [None; MAX_ROBOTS],
            nis: [0.0; MAX_WINDOW],
            nis_len: 0,
            nis_next: 0,
            good_geometry_updates: 0,
        }
    }
}

impl Learned {
    /// The noise scales of `other` (a previous track) with nothing else.
    pub fn scales_of(other: &Learned) -> Learned {
        let mut l = Learned::default();
        for (slot, r) in l.robots.iter_mut().zip(&other.robots) {
            *slot = r.map(|r| RobotNoise { origin: None, ..r });
        }
        l
    }

    /// λ of `robot` (1 when unknown or not learned).
    pub fn scale(&self, robot: u32, rules: &LearningRules) -> f64 {
        if !rules.learn {
            return 1.0;
        }
        let Some(r) = self.find(robot) else { return 1.0 };
        let n = (r.samples as f64 + PRIOR_WEIGHT).min(rules.updates.max(1.0));
        if r.mean > 1.0 + SIGNIFICANCE_Z / n.sqrt() { r.mean.min(rules.max_scale) } else { 1.0 }
    }

    /// The largest λ among the robots.
    pub fn max_scale(&self, rules: &LearningRules) -> f64 {
        self.robots.iter().flatten().map(|r| self.scale(r.robot, rules)).fold(1.0, f64::max)
    }

    fn find(&self, robot: u32) -> Option<&RobotNoise> {
        self.robots.iter().flatten().find(|r| r.robot == robot)
    }

    fn slot(&mut self, robot: u32, stamp: Stamp) -> &mut RobotNoise {
        let k = match self.robots.iter().position(|r| r.is_some_and(|r| r.robot == robot)) {
            Some(k) => k,
            None => {
                let k = self.robots.iter().position(Option::is_none).unwrap_or_else(|| {
                    (0..MAX_ROBOTS)
                        .min_by_key(|&k| self.robots[k].map_or(Stamp::ZERO, |r| r.seen))
                        .unwrap_or(0)
                });
                self.robots[k] = Some(RobotNoise {
                    robot,
                    mean: 1.0,
                    samples: 0,
                    origin: None,
                    folded: false,
                    seen: stamp,
                });
                k
            }
        };
        self.robots[k].as_mut().expect("slot just filled")
    }

    /// Records the NIS of a DoA (applied or gated) in the consistency window.
    pub fn record_nis(&mut self, nis: f64, rules: &LearningRules) {
        let w = rules.window.clamp(1, MAX_WINDOW);
        self.nis[self.nis_next % w] = if nis.is_nan() { NIS_CAP } else { nis.min(NIS_CAP) };
        self.nis_next = (self.nis_next + 1) % w;
        self.nis_len = (self.nis_len + 1).min(w);
    }

    /// Learns from an applied DoA of `robot`: its innovation's νᵀν, tr S, the
    /// prior variance R₀ and the λ it was evaluated with.
    pub fn learn(&mut self, robot: u32, stamp: Stamp, sample: InnovationSample, rules: &LearningRules) {
        let cap = 4.0 * rules.max_scale;
        let r = self.slot(robot, stamp);
        r.seen = r.seen.max(stamp);
        if !(sample.prior_variance > 0.0) {
            return;
        }
        let lambda_hat = ((sample.residual_sq - sample.trace_s + 2.0 * sample.scale * sample.prior_variance)
            / (2.0 * sample.prior_variance))
            .clamp(0.0, cap);
        if lambda_hat.is_finite() {
            let alpha = 1.0 / (r.samples as f64 + PRIOR_WEIGHT + 1.0).min(rules.updates.max(1.0));
            r.mean += alpha * (lambda_hat - r.mean);
            r.samples = r.samples.saturating_add(1);
        }
    }

    /// Records that `robot`'s DoA from `origin` (`folded`: a planar array's
    /// folded ray, its upper branch kept) was applied at `stamp`.
    pub fn accepted(&mut self, robot: u32, stamp: Stamp, origin: Point3<f64>, folded: bool) {
        let slot = self.slot(robot, stamp);
        slot.origin = Some((stamp, origin));
        slot.folded = folded;
    }

    /// The fold plane ([`crate::floor_image::fold_plane`]: lowest and mean
    /// height) of the robots whose newest accepted DoA is at most `window_ns`
    /// older than `at`, when they all sent folded rays from one height.
    pub fn fold_plane(&self, at: Stamp, window_ns: i64) -> Option<(f64, f64)> {
        crate::floor_image::fold_plane(self.recent(at, window_ns).map(|(o, folded)| (o.z, folded)))
    }

    /// The newest accepted ray origin of each robot (and whether that ray was
    /// folded with the upper branch kept) at most `window_ns` older than `at`.
    fn recent(&self, at: Stamp, window_ns: i64) -> impl Iterator<Item = (Point3<f64>, bool)> + '_ {
        self.robots
            .iter()
            .flatten()
            .filter_map(|r| r.origin.map(|(t, o)| (t, o, r.folded)))
            .filter(move |(t, _, _)| at - *t <= window_ns)
            .map(|(_, o, folded)| (o, folded))
    }

    /// Whether the NIS window is full and its sum within the limit.
    pub fn consistent(&self, rules: &LearningRules) -> bool {
        let w = rules.window.clamp(1, MAX_WINDOW);
        self.nis_len >= w && self.nis[..w].iter().sum::<f64>() <= rules.window_limit
    }

    /// Mean NIS of the window, if it holds any.
    pub fn window_mean_nis(&self) -> Option<f64> {
        (self.nis_len > 0).then(|| self.nis[..self.nis_len].iter().sum::<f64>() / self.nis_len as f64)
    }

    /// θ (degrees, folded to [0, 90]) at `p` between the robots whose newest
    /// accepted DoA is within `window_ns` of `at`; 0 with fewer than two.
    pub fn theta_deg(&self, p: &Point3<f64>, at: Stamp, window_ns: i64) -> f64 {
        let dirs: Vec<_> =
            self.recent(at, window_ns).filter_map(|(o, _)| (p - o).try_normalize(1e-9)).collect();
        let mut best: f64 = 0.0;
        for i in 0..dirs.len() {
            for j in i + 1..dirs.len() {
                let a = dirs[i].dot(&dirs[j]).clamp(-1.0, 1.0).acos().to_degrees();
                best = best.max(a.min(180.0 - a));
            }
        }
        best
    }
}

/// What the learner needs of one innovation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InnovationSample {
    /// νᵀν (rad²).
    pub residual_sq: f64,
    /// tr S (rad²).
    pub trace_s: f64,
    /// R₀, the prior variance per axis (rad²).
    pub prior_variance: f64,
    /// λ the innovation was evaluated with.
    pub scale: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULES: LearningRules =
        LearningRules { learn: true, updates: 20.0, max_scale: 16.0, window: 10, window_limit: 37.6 };

    fn sample(residual_sq: f64, scale: f64) -> InnovationSample {
        // A pinned track: HPHᵀ ≈ 0, so tr S = 2λR₀.
        let r0 = 1e-3;
        InnovationSample { residual_sq, trace_s: 2.0 * scale * r0, prior_variance: r0, scale }
    }

    #[test]
    fn right_noise_keeps_the_prior_and_larger_noise_inflates() {
        let mut l = Learned::default();
        for k in 0..200 {
            let s = l.scale(1, &RULES);
            // νᵀν alternating around its expectation 2R₀.
            l.learn(1, Stamp::from_ns(k), sample(if k % 2 == 0 { 1e-3 } else { 3e-3 }, s), &RULES);
            assert_eq!(l.scale(1, &RULES), 1.0);
        }
        for k in 200..400 {
            let s = l.scale(2, &RULES);
            l.learn(2, Stamp::from_ns(k), sample(8e-3, s), &RULES);
        }
        assert!((l.scale(2, &RULES) - 4.0).abs() < 0.2, "{}", l.scale(2, &RULES));
        assert_eq!(l.scale(1, &RULES), 1.0, "robots learn separately");
        let off = LearningRules { learn: false, ..RULES };
        assert_eq!(l.scale(2, &off), 1.0);
    }

    #[test]
    fn scales_never_go_below_the_prior_nor_above_the_cap() {
        let mut l = Learned::default();
        for k in 0..100 {
            l.learn(1, Stamp::from_ns(k), sample(0.0, l.scale(1, &RULES)), &RULES);
            l.learn(2, Stamp::from_ns(k), sample(10.0, l.scale(2, &RULES)), &RULES);
        }
        assert_eq!(l.scale(1, &RULES), 1.0);
        assert_eq!(l.scale(2, &RULES), 16.0);
        let carried = Learned::scales_of(&l);
        assert_eq!(carried.scale(2, &RULES), 16.0);
        assert!(!carried.consistent(&RULES));
    }

    #[test]
    fn consistency_needs_a_full_window_within_the_limit() {
        let mut l = Learned::default();
        for _ in 0..9 {
            l.record_nis(2.0, &RULES);
        }
        assert!(!l.consistent(&RULES), "window not full");
        l.record_nis(2.0, &RULES);
        assert!(l.consistent(&RULES));
        assert_eq!(l.window_mean_nis(), Some(2.0));
        for _ in 0..4 {
            l.record_nis(9.0, &RULES);
        }
        assert!(!l.consistent(&RULES), "4 × 9 + 6 × 2 = 48 > 37.6");
        l.record_nis(f64::NAN, &RULES);
        assert!(l.window_mean_nis().unwrap() > 5.0, "NaN counts as the cap");
    }

    #[test]
    fn theta_is_the_widest_folded_angle_of_recent_robots() {
        let mut l = Learned::default();
        let p = Point3::new(0.0, 0.0, 0.0);
        l.accepted(1, Stamp::from_ns(0), Point3::new(1.0, 0.0, 0.0), false);
        assert_eq!(l.theta_deg(&p, Stamp::from_ns(0), 10), 0.0);
        l.accepted(2, Stamp::from_ns(5), Point3::new(0.0, 2.0, 0.0), false);
        assert!((l.theta_deg(&p, Stamp::from_ns(5), 10) - 90.0).abs() < 1e-9);
        l.accepted(3, Stamp::from_ns(20), Point3::new(-1.0, 0.1, 0.0), false);
        // Robot 3 is almost opposite robot 1 (folded ≈ 5.7°); robot 1 is too old at 20.
        let t = l.theta_deg(&p, Stamp::from_ns(20), 16);
        assert!((t - 84.3).abs() < 0.1, "{t}");
    }
}
