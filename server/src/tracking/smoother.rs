//! Fixed-lag smoothing of a track: where the source was `lag` seconds ago,
//! estimated from the DoAs before *and after* that moment.
//!
//! # Why
//!
//! A filter's estimate at t uses only the DoAs up to t. DoA errors in a room
//! are correlated over a few tenths of a second (a reverberant room's peak
//! scatter; ODAS's ≈ 4° grid dithered by its tracker's slow jitter), so a
//! walker's filter, which may average over only ≈ 0.7 s without lagging the
//! walker, follows them. The DoAs after t carry as much about the source at t
//! as those before it: a smoother that uses both halves the lag of the
//! averaging window and roughly doubles its length. The price is latency: the
//! smoothed estimate is published `[tracking] smoothing_lag_s` behind the
//! live one, beside it (the live estimate is unchanged). A sound map, a
//! recording's replay or an operator's display can take the smoothed one; a
//! planner reacting to the source now takes the live one.
//!
//! # Method (Kim 1994, the backward pass for switching linear models)
//!
//! The filter is the IMM of [`super::imm`]: per mode j a state xⱼ, Pⱼ and a
//! probability μⱼ; each mode is linear over a step Δt, x' = Fⱼ x + w,
//! w ~ N(0, Qⱼ) (`Modes::linear`), and the mode is a Markov chain with
//! Πᵢⱼ(Δt) (stay 1 − s, switch s). Given the smoothed per-mode states
//! xⱼˢ(k+1), Pⱼˢ(k+1) and probabilities μⱼˢ(k+1), and the filtered ones at k:
//!
//! ```text
//! x̂ᵢⱼ = Fⱼ xᵢ ,  P̂ᵢⱼ = Fⱼ Pᵢ Fⱼᵀ + Qⱼ          mode i at k predicted by mode j
//! Jᵢⱼ = Pᵢ Fⱼᵀ P̂ᵢⱼ⁻¹                            the RTS gain
//! xᵢⱼˢ = xᵢ + Jᵢⱼ (xⱼˢ(k+1) − x̂ᵢⱼ)
//! Pᵢⱼˢ = Pᵢ + Jᵢⱼ (Pⱼˢ(k+1) − P̂ᵢⱼ) Jᵢⱼᵀ
//! μᵢⱼˢ = μⱼˢ(k+1) · Πᵢⱼ μᵢ / Σₗ Πₗⱼ μₗ          joint mode probability
//! μᵢˢ = Σⱼ μᵢⱼˢ ,  xᵢˢ, Pᵢˢ = the μᵢⱼˢ/μᵢˢ-weighted mixture of xᵢⱼˢ, Pᵢⱼˢ
//! ```
//!
//! starting from the newest filtered state, and the published state is the
//! mixture of the modes at the lagged stamp, as for the filter. With one mode
//! (`still_mode = false`) this is the Rauch–Tung–Striebel smoother exactly.
//! Kim's step is an approximation (it takes p(x(k) | x(k+1), mode) as if the
//! later DoAs told nothing more about x(k) once x(k+1) and the mode are
//! known); it is the standard one for IMM smoothing.
//!
//! The history is the filtered state after applied DoAs, at most one per
//! [`HISTORY_STEP_S`]. Between two kept states the DoAs in between are
//! counted at the later state's stamp (they are in its filtered estimate);
//! with 50 ms against a walker's ≈ 0.7 s averaging this changes little, and it
//! bounds the cost: a query is one backward pass over at most
//! lag / 50 ms + 1 steps of four 6×6 gains.
//!
//! # Worked numbers
//!
//! - Model-matched (the single CV filter, q̃ 0.01 m²/s³, DoAs σ 3° from two
//!   robots at 10 and 15 Hz; `server/tests/tracking.rs`, 40 runs): smoothed
//!   RMS 0.072 m against the live filter's 0.133 m at the same stamps, NEES
//!   2.67 (3 when consistent; the 50 ms history spacing makes it slightly
//!   conservative).
//! - DoA errors held for 0.4 s, a walker at 0.7 m/s with 2 s pauses, the IMM
//!   (this module's tests, 1 s lag): RMS 0.126 m against live 0.220 m.
//! - ODAS-like DoAs (level-4 grid, room bias, 0.3 s jitter), walking talker,
//!   seeds 1–5: in-band RSE p95 0.265 m against the live 0.431 m and the
//!   closest point's 0.534 m; lag 0.5 / 1 / 2 s gives 0.292 / 0.265 /
//!   0.268 m: the gain stops at about the moving mode's averaging time, so
//!   the default lag is 1 s (BENCHMARKS.md, *The smoothed states*).
//! - Cost: ≈ 44 µs per refresh (≈ 30 kept states × four 6×6 gains), one
//!   refresh per 50 ms of DoA time: ≈ 0.9 ms of CPU per second per source.
//!
//! The published covariance of a smoothed state adds the current
//! triangulation's, as for the live estimate (`tracking.correlated_doa_fraction`,
//! `coordinator::Estimate::smoothed_covariance`): on the ODAS-like DoAs
//! only 42–87 % of the smoothed states fell inside the smoother's own 99 %
//! ellipsoid, 100 % of the trusted ones inside the published one.
//!
//! Reference: C.-J. Kim, "Dynamic linear models with Markov-switching",
//! Journal of Econometrics 60 (1994) 1–22.

use nalgebra::Matrix6;
use soundmap_proto::Stamp;

use super::filter::{CvState, symmetric};
use super::imm::{ImmState, Modes};

/// Least spacing of the states the smoother keeps (s).
pub const HISTORY_STEP_S: f64 = 0.05;

/// No smoothed mode probability falls below this (as in the filter).
const MIN_PROBABILITY: f64 = 1e-6;

/// Smoothed mode-conditioned states and mode probabilities at one stamp.
#[derive(Clone, Copy, Debug)]
struct Smoothed {
    modes: [CvState; 2],
    probability: [f64; 2],
}

impl Smoothed {
    fn of(filtered: &ImmState) -> Smoothed {
        Smoothed { modes: *filtered.mode_states(), probability: filtered.probabilities() }
    }

    fn combined(&self) -> CvState {
        mixture(&self.modes, &self.probability)
    }
}

/// The moment-matched mixture of `states` with weights `w` (summing to 1).
fn mixture(states: &[CvState; 2], w: &[f64; 2]) -> CvState {
    let mean = states[0].mean * w[0] + states[1].mean * w[1];
    let mut covariance = Matrix6::zeros();
    for (s, wk) in states.iter().zip(w) {
        let d = s.mean - mean;
        covariance += (s.covariance + d * d.transpose()) * *wk;
    }
    CvState { mean, covariance: symmetric(&covariance) }
}

/// One backward step: the smoothed state at the filtered state `filtered`
/// from the smoothed one `next`, `dt_s` later. `None` when a predicted
/// covariance is not positive definite or a result is not finite.
fn backward_step(filtered: &ImmState, next: &Smoothed, dt_s: f64, modes: &Modes) -> Option<Smoothed> {
    if dt_s <= 0.0 {
        return Some(*next);
    }
    let s = modes.switch_probability(dt_s);
    let pi = |i: usize, j: usize| if i == j { 1.0 - s } else { s };
    let mu = filtered.probabilities();
    let states = filtered.mode_states();
    let predicted_probability = [0, 1].map(|j| pi(0, j) * mu[0] + pi(1, j) * mu[1]);
    let linear = [modes.linear(0, dt_s), modes.linear(1, dt_s)];
    let mut out = *next;
    for i in 0..2 {
        let mut pairs = [states[i]; 2];
        let mut joint = [0.0; 2];
        for j in 0..2 {
            let (f, q) = &linear[j];
            let x = &states[i];
            let predicted_mean = f * x.mean;
            let predicted_cov = symmetric(&(f * x.covariance * f.transpose() + q));
            // J = P Fᵀ P̂⁻¹, so Jᵀ = P̂⁻¹ F P (P, P̂ symmetric).
            let gain_t = predicted_cov.cholesky()?.solve(&(f * x.covariance));
            let gain = gain_t.transpose();
            pairs[j] = CvState {
                mean: x.mean + gain * (next.modes[j].mean - predicted_mean),
                covariance: symmetric(
                    &(x.covariance + gain * (next.modes[j].covariance - predicted_cov) * gain_t),
                ),
            };
            joint[j] = next.probability[j] * pi(i, j) * mu[i] / predicted_probability[j];
        }
        let total = joint[0] + joint[1];
        out.probability[i] = total;
        out.modes[i] = mixture(&pairs, &[joint[0] / total, joint[1] / total]);
    }
    let total = out.probability[0] + out.probability[1];
    let p = (out.probability[1] / total).clamp(MIN_PROBABILITY, 1.0 - MIN_PROBABILITY);
    out.probability = [1.0 - p, p];
    (p.is_finite() && out.modes.iter().all(CvState::is_finite)).then_some(out)
}

/// The smoothed state at `history[at]` given all of `history` (filtered IMM
/// states in time order with their stamps): the backward pass from the
/// newest. `None` when `at` is out of range or a step fails numerically.
pub(super) fn smooth(history: &[(Stamp, &ImmState)], at: usize, modes: &Modes) -> Option<CvState> {
    let (_, newest) = history.last()?;
    if at >= history.len() {
        return None;
    }
    let mut smoothed = Smoothed::of(newest);
    for k in (at..history.len() - 1).rev() {
        let dt = history[k + 1].0.seconds_since(history[k].0);
        smoothed = backward_step(history[k].1, &smoothed, dt, modes)?;
    }
    Some(smoothed.combined())
}

#[cfg(test)]
mod tests {
    use nalgebra::{Point3, Vector3, Vector6};

    use super::*;
    use crate::tracking::filter::{doa_innovation, joseph_update};
    use crate::tracking::test_support::{MODEL, modes, ray};

    const MODES: Modes = modes(30.0);
    const MOVING_ONLY: Modes = Modes { still: None, ..MODES };

    fn start(at: Point3<f64>) -> ImmState {
        crate::tracking::test_support::start(at, 0.04)
    }

    /// Filtered states of a source on `path`, heard at 10 Hz by two arrays in
    /// turn with DoA errors that persist for `hold` steps (a deterministic
    /// pseudo-random ±σ per hold, in both angles).
    fn filter_run(
        path: impl Fn(f64) -> Point3<f64>,
        steps: usize,
        hold: usize,
        modes: &Modes,
    ) -> Vec<(Stamp, ImmState)> {
        let arrays = [Point3::new(0.0, 0.0, 0.5), Point3::new(5.0, 0.0, 0.5)];
        let sigma = 0.04;
        let mut s = start(path(0.0));
        let mut out = vec![(Stamp::from_ns(0), s)];
        let mut seed = 12345u64;
        let mut offsets = (0.0, 0.0);
        for k in 1..=steps {
            if k % hold == 1 || hold == 1 {
                let mut draw = || {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    ((seed >> 33) as f64 / (1u64 << 31) as f64 - 0.5) * 2.0 * sigma * 1.7
                };
                offsets = (draw(), draw());
            }
            let t = k as f64 * 0.1;
            s = s.predicted(0.1, modes);
            let o = arrays[k % 2];
            let to = path(t) - o;
            let r = to.norm();
            let side = Vector3::z().cross(&to).normalize();
            let target = path(t) + side * offsets.0 * r + Vector3::z() * offsets.1 * r;
            s = s.updated(&ray(o, target, sigma), &MODEL).unwrap();
            out.push((Stamp::from_ns((t * 1e9).round() as i64), s));
        }
        out
    }

    fn refs(h: &[(Stamp, ImmState)]) -> Vec<(Stamp, &ImmState)> {
        h.iter().map(|(t, s)| (*t, s)).collect()
    }

    /// A walker back and forth along x at 0.7 m/s with 2 s pauses.
    fn walker(t: f64) -> Point3<f64> {
        let period = 2.0 * (3.0 / 0.7 + 2.0);
        let u = t % period;
        let leg = 3.0 / 0.7;
        let x = if u < leg {
            1.0 + 0.7 * u
        } else if u < leg + 2.0 {
            4.0
        } else if u < 2.0 * leg + 2.0 {
            4.0 - 0.7 * (u - leg - 2.0)
        } else {
            1.0
        };
        Point3::new(x, 3.5, 1.2)
    }

    #[test]
    fn with_one_mode_it_is_the_rauch_tung_striebel_smoother() {
        // Two steps by hand: filtered x0 → predicted → updated x1; RTS gives
        // x0ˢ = x0 + J (x1 − F x0), P0ˢ = P0 + J (P1 − P̂) Jᵀ.
        let s0 = start(Point3::new(2.0, 3.0, 1.2));
        let r = ray(Point3::new(0.0, 0.0, 0.5), Point3::new(2.2, 3.1, 1.3), 0.03);
        let s1 = s0.predicted(0.1, &MOVING_ONLY).updated(&r, &MODEL).unwrap();
        let x0 = s0.combined();
        let predicted = x0.predicted(0.1, &MOVING_ONLY.moving);
        let x1 = joseph_update(&predicted, &doa_innovation(&predicted, &r, &MODEL).unwrap()).unwrap();
        let gain = x0.covariance
            * crate::tracking::filter::transition(0.1).transpose()
            * predicted.covariance.try_inverse().unwrap();
        let mean = x0.mean + gain * (x1.mean - predicted.mean);
        let cov = x0.covariance + gain * (x1.covariance - predicted.covariance) * gain.transpose();
        let h = [(Stamp::from_ns(0), s0), (Stamp::from_ns(100_000_000), s1)];
        let smoothed = smooth(&refs(&h), 0, &MOVING_ONLY).unwrap();
        assert!((smoothed.mean - mean).norm() < 1e-9, "{} vs {}", smoothed.mean, mean);
        assert!((smoothed.covariance - cov).norm() < 1e-9);
        // The newest state is its own smoothed state, and the smoothed
        // covariance is no larger than the filtered one.
        assert!((smooth(&refs(&h), 1, &MOVING_ONLY).unwrap().mean - s1.combined().mean).norm() < 1e-12);
        assert!((x0.covariance - smoothed.covariance).symmetric_eigenvalues().min() > -1e-12);
        assert!(smooth(&refs(&h), 2, &MOVING_ONLY).is_none());
    }

    #[test]
    fn the_still_mode_is_the_filters_prediction_as_a_linear_model() {
        let s = start(Point3::new(2.0, 3.0, 1.2)).combined();
        let s = CvState { mean: s.mean + Vector6::new(0.0, 0.0, 0.0, 0.3, -0.2, 0.1), ..s };
        for mode in 0..2 {
            let predicted = MODES.predict(mode, &s, 0.2);
            let (f, q) = MODES.linear(mode, 0.2);
            assert!((predicted.mean - f * s.mean).norm() < 1e-12);
            assert!((predicted.covariance - (f * s.covariance * f.transpose() + q)).norm() < 1e-12);
        }
    }

    #[test]
    fn a_walker_with_persistent_doa_errors_is_found_better_a_second_later() {
        // DoA errors held for 0.4 s: the live filter follows them, the
        // smoother a second behind averages them from both sides.
        let h = filter_run(walker, 400, 4, &MODES);
        let refs = refs(&h);
        let lag = 10; // 1 s at 10 Hz
        let (mut live, mut smoothed) = (Vec::new(), Vec::new());
        for k in 50..h.len() - lag {
            let t = k as f64 * 0.1;
            live.push((h[k].1.combined().position() - walker(t)).norm());
            let window = &refs[k..=k + lag];
            smoothed.push((smooth(window, 0, &MODES).unwrap().position() - walker(t)).norm());
        }
        let rms = |e: &[f64]| (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
        let (l, s) = (rms(&live), rms(&smoothed));
        eprintln!("RMS: smoothed {s} m, live {l} m");
        assert!(s < 0.8 * l, "smoothed RMS {s} m vs live {l} m");
        // And it does not lag: on the legs (walking), no worse than live.
        let legs: Vec<usize> = (50..h.len() - lag)
            .filter(|k| {
                let t = *k as f64 * 0.1;
                (walker(t + 0.5) - walker(t - 0.5)).norm() > 0.6
            })
            .map(|k| k - 50)
            .collect();
        let pick = |e: &[f64]| legs.iter().map(|i| e[*i]).collect::<Vec<f64>>();
        let (l, s) = (rms(&pick(&live)), rms(&pick(&smoothed)));
        assert!(s < l, "walking: smoothed RMS {s} m vs live {l} m");
    }

    #[test]
    fn a_still_source_is_averaged_over_the_lag() {
        let at = |_| Point3::new(2.5, 3.0, 1.2);
        let h = filter_run(at, 200, 4, &MODES);
        let refs = refs(&h);
        let (mut live, mut smoothed) = (0.0, 0.0);
        for k in 100..180 {
            live += (h[k].1.combined().position() - at(0.0)).norm_squared();
            smoothed += (smooth(&refs[k..=k + 20], 0, &MODES).unwrap().position() - at(0.0)).norm_squared();
        }
        assert!(smoothed < 0.8 * live, "smoothed MSE {smoothed} vs live {live}");
    }
}
