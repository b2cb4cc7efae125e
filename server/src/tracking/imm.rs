//! Two motion modes of one source, mixed by an interacting multiple model
//! (IMM) filter: a *still* mode (a seated talker, a loudspeaker, a fan: it
//! stays where it is, up to a slow sway) and a *moving* mode (a walker, the
//! constant-velocity model of theory §4.1).
//!
//! # Why
//!
//! One constant-velocity filter must choose its acceleration PSD q̃. Chosen for
//! a walker (0.5 m²/s³), it follows DoA noise that is correlated over a second
//! or more (a reverberant room's peak scatter; ODAS's ≈ 4° grid, dithered by
//! its tracker's slow jitter): with 10 DoAs a second of σ ≈ 5° at 3 m, its
//! position averages over only ≈ 0.7 s. Chosen for a still source (0.01), it
//! lags a walker on every turn. The IMM runs both and weighs them by how well
//! each predicted the DoAs; the published state is their moment-matched
//! mixture, so a still source is averaged over several seconds and a walker
//! is followed as before.
//!
//! The still mode is a *constant-position* model, not a constant-velocity one
//! with a small q̃: its velocity is zero (1-σ [`STILL_VELOCITY_SIGMA`]) and its
//! position diffuses (D, m²/s: variance D·Δt per axis). A walker at constant
//! speed fits a small-q̃ CV model as well as the walker's, so such a pair
//! cannot tell them apart and the mixture lags on turns; against a
//! constant-position model, a source moving at v leaves the still prediction
//! by v·Δt more every step, and the moving mode takes over within a few DoAs.
//!
//! # Cycle (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan 2001, §11.6)
//!
//! With mode probabilities μᵢ and a switch probability s(Δt) = ½(1 − e^{−Δt/τ})
//! over a step Δt (τ the mean time in a mode, `tracking.mode_sojourn_s`;
//! Π = [[1 − s, s], [s, 1 − s]]):
//!
//! ```text
//! c̄ⱼ = Σᵢ Πᵢⱼ μᵢ                      predicted mode probabilities
//! μᵢ|ⱼ = Πᵢⱼ μᵢ / c̄ⱼ                  mixing weights
//! x₀ⱼ = Σᵢ μᵢ|ⱼ xᵢ ,  P₀ⱼ = Σᵢ μᵢ|ⱼ (Pᵢ + (xᵢ − x₀ⱼ)(xᵢ − x₀ⱼ)ᵀ)
//! xⱼ⁻, Pⱼ⁻ = mode j's prediction of x₀ⱼ, P₀ⱼ
//!   moving: F = [I Δt·I; 0 I], Q = the CV white-noise acceleration Q(Δt)
//!   still:  position kept, P_pp + D·Δt; velocity 0, covariance σ_v²·I, no cross terms
//! ```
//!
//! then, for a DoA, each mode's own tangent-plane update ([`super::filter`]),
//! with likelihood Λⱼ = N(νⱼ; 0, Sⱼ) and μⱼ ∝ Λⱼ c̄ⱼ. The mixture (published,
//! gated, used for association) is x = Σ μⱼ xⱼ, P = Σ μⱼ (Pⱼ + (xⱼ − x)(xⱼ − x)ᵀ).
//!
//! Worked numbers (defaults: D = 0.002 / 0.0005 m²/s horizontal / vertical,
//! moving q̃ 0.5 / 0.01 m²/s³, τ = 30 s): at 10 DoAs a second, s = 0.17 % per
//! step and the still mode's position spreads by √(D·Δt) ≈ 1.4 cm per step
//! (10 cm in 5 s: a seated talker's sway). A walker at 0.5 m/s gets 5 cm away
//! from the still prediction per step; with DoAs of σ = 1° from 3 m (5 cm),
//! the still mode's likelihood falls by about e^{−½} per step against the
//! moving one's and μ_moving passes 0.9 in ≈ 0.5 s. Measured (one seed each):
//! following the walker of `active-moving`, μ_moving has median 0.993 and 5th
//! percentile 0.976; on the swaying talker of the ODAS-like trial, median 0.011
//! and 95th percentile 0.039. The idle mode keeps some weight since mixing
//! re-seeds it from the active one every step, so a walker's mixture carries
//! a little of the still mode's lag. With
//! `tracking.still_mode = false` the filter is the single CV filter exactly.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

use super::filter::{
    CvState, DoaInnovation, DoaNoiseModel, ProcessNoise, Unusable, doa_innovation, joseph_update,
    process_noise, symmetric, transition,
};
use crate::ray::Ray;

/// 1-σ of the still mode's velocity (m/s): a sway, not a walk.
pub const STILL_VELOCITY_SIGMA: f64 = 0.05;

/// Position diffusion of the still mode (m²/s): the position variance grows by
/// D·Δt per axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Diffusion {
    /// D of the x and y axes (m²/s).
    pub horizontal_m2_per_s: f64,
    /// D of the z axis (m²/s).
    pub vertical_m2_per_s: f64,
}

/// The two modes and how often a source switches between them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Modes {
    /// The still mode's diffusion; `None` runs the moving mode alone.
    pub still: Option<Diffusion>,
    /// Process noise of the moving (CV) mode.
    pub moving: ProcessNoise,
    /// Mean time in a mode τ (s).
    pub sojourn_s: f64,
}

impl Modes {
    /// Probability of switching mode over `dt_s`.
    pub(super) fn switch_probability(&self, dt_s: f64) -> f64 {
        0.5 * (1.0 - (-dt_s / self.sojourn_s.max(1e-9)).exp())
    }

    /// Mode `mode`'s prediction of `state` over `dt_s`.
    pub(super) fn predict(&self, mode: usize, state: &CvState, dt_s: f64) -> CvState {
        match (mode, self.still) {
            (STILL, Some(d)) => {
                let mut mean = state.mean;
                mean.fixed_rows_mut::<3>(3).fill(0.0);
                let mut p = Matrix6::zeros();
                let grow = Matrix3::from_diagonal(&Vector3::new(
                    d.horizontal_m2_per_s * dt_s,
                    d.horizontal_m2_per_s * dt_s,
                    d.vertical_m2_per_s * dt_s,
                ));
                p.fixed_view_mut::<3, 3>(0, 0).copy_from(&(state.position_covariance() + grow));
                p.fixed_view_mut::<3, 3>(3, 3)
                    .copy_from(&(Matrix3::identity() * (STILL_VELOCITY_SIGMA * STILL_VELOCITY_SIGMA)));
                CvState { mean, covariance: p }
            }
            _ => state.predicted(dt_s, &self.moving),
        }
    }

    /// Mode `mode`'s prediction over `dt_s` as a linear model x' = F x + w,
    /// w ~ N(0, Q): what [`Modes::predict`] does, for the smoother. The still
    /// mode keeps the position and forgets the velocity: F = [I 0; 0 0],
    /// Q = [D·Δt 0; 0 σ_v²·I].
    pub(super) fn linear(&self, mode: usize, dt_s: f64) -> (Matrix6<f64>, Matrix6<f64>) {
        match (mode, self.still) {
            (STILL, Some(d)) => {
                let f = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 0.0, 0.0, 0.0));
                let v = STILL_VELOCITY_SIGMA * STILL_VELOCITY_SIGMA;
                let q = Matrix6::from_diagonal(&Vector6::new(
                    d.horizontal_m2_per_s * dt_s,
                    d.horizontal_m2_per_s * dt_s,
                    d.vertical_m2_per_s * dt_s,
                    v,
                    v,
                    v,
                ));
                (f, q)
            }
            _ => (transition(dt_s), process_noise(dt_s, &self.moving)),
        }
    }
}

pub(super) const STILL: usize = 0;
pub(super) const MOVING: usize = 1;
/// No mode's probability falls below this, so that either can take over again.
const MIN_PROBABILITY: f64 = 1e-6;

/// The IMM state: one CV state per mode and the mode probabilities.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImmState {
    modes: [CvState; 2],
    probability: [f64; 2],
}

impl ImmState {
    /// Both modes at `state`, equally likely.
    pub fn new(state: CvState) -> ImmState {
        ImmState { modes: [state; 2], probability: [0.5; 2] }
    }

    /// Probability of the moving mode.
    pub fn moving_probability(&self) -> f64 {
        self.probability[MOVING]
    }

    /// Each mode's state (still, moving).
    pub(super) fn mode_states(&self) -> &[CvState; 2] {
        &self.modes
    }

    /// The mode probabilities (still, moving).
    pub(super) fn probabilities(&self) -> [f64; 2] {
        self.probability
    }

    /// Each mode whose height is below `lowest` mirrored through z = `plane_z`
    /// ([`CvState::mirrored`]): the fold's upper branch
    /// ([`crate::floor_image`], "The fold's two branches").
    pub fn on_upper_branch(&self, lowest: f64, plane_z: f64) -> ImmState {
        let mut next = *self;
        for m in &mut next.modes {
            if m.mean[2] < lowest {
                *m = m.mirrored(plane_z);
            }
        }
        next
    }

    /// The moment-matched mixture of the modes.
    pub fn combined(&self) -> CvState {
        let [a, b] = &self.modes;
        let [wa, wb] = self.probability;
        let mean: Vector6<f64> = a.mean * wa + b.mean * wb;
        let spread = |s: &CvState| -> Matrix6<f64> {
            let d = s.mean - mean;
            s.covariance + d * d.transpose()
        };
        CvState { mean, covariance: symmetric(&(spread(a) * wa + spread(b) * wb)) }
    }

    /// Mixed and predicted `dt_s` ahead (dt ≥ 0); the probabilities become the
    /// predicted ones c̄.
    pub fn predicted(&self, dt_s: f64, modes: &Modes) -> ImmState {
        if dt_s <= 0.0 {
            return *self;
        }
        let s = modes.switch_probability(dt_s);
        let pi = |i: usize, j: usize| if i == j { 1.0 - s } else { s };
        let mut next = *self;
        for j in 0..2 {
            let c = (0..2).map(|i| pi(i, j) * self.probability[i]).sum::<f64>();
            let w = [pi(0, j) * self.probability[0] / c, pi(1, j) * self.probability[1] / c];
            let mixed = ImmState { modes: self.modes, probability: w }.combined();
            next.modes[j] = modes.predict(j, &mixed, dt_s);
            next.probability[j] = c;
        }
        next
    }

    /// Each mode's update with `ray` and the new probabilities. `None` when a
    /// mode cannot use the ray or a result is not finite (the caller keeps the prior).
    pub fn updated(&self, ray: &Ray, model: &DoaNoiseModel) -> Option<ImmState> {
        let mut next = *self;
        let mut log_weight = [0.0; 2];
        for j in 0..2 {
            let inn = doa_innovation(&self.modes[j], ray, model).ok()?;
            next.modes[j] = joseph_update(&self.modes[j], &inn)?;
            let det = inn.covariance.determinant();
            log_weight[j] = self.probability[j].ln() - 0.5 * inn.nis - 0.5 * det.ln();
        }
        // μ_moving = 1 / (1 + e^{w_still − w_moving}), without underflow.
        let p = 1.0 / (1.0 + (log_weight[STILL] - log_weight[MOVING]).exp());
        if p.is_finite() {
            let p = p.clamp(MIN_PROBABILITY, 1.0 - MIN_PROBABILITY);
            next.probability = [1.0 - p, p];
        }
        next.modes.iter().all(CvState::is_finite).then_some(next)
    }

    /// The innovation of `ray` against the mixture (for gating and association).
    pub fn innovation(&self, ray: &Ray, model: &DoaNoiseModel) -> Result<DoaInnovation, Unusable> {
        doa_innovation(&self.combined(), ray, model)
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Vector3};

    use super::*;
    use crate::tracking::test_support::{MODEL, modes, ray};

    const MODES: Modes = modes(4.0);
    const MOVING_ONLY: Modes = Modes { still: None, ..MODES };

    fn start(at: Point3<f64>) -> ImmState {
        crate::tracking::test_support::start(at, 0.01)
    }

    /// Runs `steps` DoAs at 10 Hz from two arrays, alternating, at the
    /// source's path `at(t)`, with a deterministic ±σ zig-zag on the direction
    /// (held for 0.4 s, as a room's DoA errors persist); returns per step
    /// (t, position error, μ_moving).
    fn run(at: impl Fn(f64) -> Point3<f64>, steps: usize, modes: &Modes) -> Vec<(f64, f64, f64)> {
        let arrays = [Point3::new(0.0, 0.0, 0.5), Point3::new(4.0, 0.0, 0.5)];
        let sigma = 0.03;
        let mut s = start(at(0.0));
        let mut out = Vec::new();
        for k in 1..=steps {
            let t = k as f64 * 0.1;
            s = s.predicted(0.1, modes);
            let o = arrays[k % 2];
            let wiggle = if (k / 4) % 2 == 0 { sigma } else { -sigma };
            let target = at(t) + Vector3::new(0.0, 0.0, wiggle * (at(t) - o).norm());
            s = s.updated(&ray(o, target, sigma), &MODEL).unwrap();
            out.push((t, (s.combined().position() - at(t)).norm(), s.moving_probability()));
        }
        out
    }

    /// Still for 3 s, then 0.7 m/s along +x for 3 s, then back along −x.
    fn walker(t: f64) -> Point3<f64> {
        let x = if t < 3.0 {
            1.0
        } else if t < 6.0 {
            1.0 + 0.7 * (t - 3.0)
        } else {
            3.1 - 0.7 * (t - 6.0)
        };
        Point3::new(x, 3.0, 1.2)
    }

    fn worst(run: &[(f64, f64, f64)], from: f64, to: f64) -> f64 {
        run.iter().filter(|r| (from..to).contains(&r.0)).map(|r| r.1).fold(0.0, f64::max)
    }

    fn rms(run: &[(f64, f64, f64)], from: f64) -> f64 {
        let e: Vec<f64> = run.iter().filter(|r| r.0 >= from).map(|r| r.1 * r.1).collect();
        (e.iter().sum::<f64>() / e.len() as f64).sqrt()
    }

    #[test]
    fn without_the_still_mode_it_is_the_single_filter() {
        let s = start(Point3::new(2.0, 3.0, 1.2));
        let r = ray(Point3::new(0.0, 0.0, 0.5), Point3::new(2.1, 3.0, 1.3), 0.03);
        let imm = s.predicted(0.1, &MOVING_ONLY).updated(&r, &MODEL).unwrap().combined();
        let predicted = s.combined().predicted(0.1, &MOVING_ONLY.moving);
        let kf = joseph_update(&predicted, &doa_innovation(&predicted, &r, &MODEL).unwrap()).unwrap();
        assert!((imm.mean - kf.mean).norm() < 1e-12);
        assert!((imm.covariance - kf.covariance).norm() < 1e-12);
    }

    #[test]
    fn a_still_source_is_averaged_and_a_walker_followed() {
        // A still source: the still mode wins and averages the persistent DoA
        // errors over longer than the walker's filter does.
        let still_at = |_| Point3::new(2.0, 3.0, 1.2);
        let (imm, single) = (run(still_at, 100, &MODES), run(still_at, 100, &MOVING_ONLY));
        assert!(imm.last().unwrap().2 < 0.1, "μ_moving {}", imm.last().unwrap().2);
        let (e_imm, e_single) = (rms(&imm, 3.0), rms(&single, 3.0));
        assert!(e_imm < 0.7 * e_single, "RMS {e_imm} m vs single filter {e_single} m");
        // A walker who starts and turns back: the moving mode takes over
        // within half a second.
        let (imm, single) = (run(walker, 90, &MODES), run(walker, 90, &MOVING_ONLY));
        let least = imm.iter().filter(|r| (3.7..6.0).contains(&r.0)).map(|r| r.2).fold(1.0, f64::min);
        assert!(least > 0.8, "μ_moving down to {least} while walking");
        // It costs a lag of ≈ 0.1 m in the first half second of the start
        // (while the still mode still dominates), and nothing after it.
        let start_lag = worst(&imm, 3.0, 3.7);
        assert!(start_lag < 0.25, "error {start_lag} m as the walker starts");
        let (w_imm, w_single) = (worst(&imm, 3.7, 9.0), worst(&single, 3.7, 9.0));
        assert!(w_imm < w_single + 0.02, "worst error {w_imm} m vs single filter {w_single} m");
    }

    #[test]
    fn probabilities_stay_a_distribution_and_the_mixture_covers_its_modes() {
        let mut s = start(Point3::new(2.0, 3.0, 1.2));
        for k in 1..=50 {
            let at = Point3::new(2.0 + 0.2 * (k as f64 * 0.03).sin(), 3.0, 1.2);
            let o = Point3::new((k % 2) as f64 * 4.0, 0.0, 0.5);
            s = s.predicted(0.1, &MODES).updated(&ray(o, at, 0.03), &MODEL).unwrap();
        }
        let [a, b] = s.probability;
        assert!((a + b - 1.0).abs() < 1e-12 && a >= MIN_PROBABILITY && b >= MIN_PROBABILITY);
        let c = s.combined();
        // The mixture's covariance is at least the probability-weighted modes'.
        let weighted = s.modes[0].covariance * a + s.modes[1].covariance * b;
        assert!((c.covariance - weighted).symmetric_eigenvalues().min() > -1e-12);
    }
}
