//! The PHAT coherence that diffuse (spherically isotropic) noise alone puts
//! into the steered response, per direction.
//!
//! Diffuse noise is partly coherent between close microphones: its
//! cross-spectrum between microphones `r` metres apart is
//! `sinc(ωr/c) = sin(ωr/c)/(ωr/c)` (real, so it favours zero lags). Steered
//! to `d`, the expected coherence is
//! `(1/(P K)) Σₚ Σₖ sinc(ωₖ rₚ/c) cos(2πk τₚ(d)/N)`, largest where all TDOAs
//! vanish (the zenith of a planar array): there, diffuse noise alone looks
//! like a source to a small array. Using the raw coherence in place of its
//! PHAT-whitened expectation slightly overestimates it for weakly coherent
//! pairs, which only makes the tracker's birth threshold safer.
//!
//! The response is smooth (low frequencies dominate it), so it is tabulated
//! on the level-2 icosphere plus the poles and read at the nearest point.

use nalgebra::Vector3;

use super::grid::SphereGrid;

/// How coherent the localizer's peaks are on noise alone (PHAT coherence):
/// what the DoA tracker needs to tell a source from noise (see
/// [`crate::srp::Srp::noise_model`]).
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    /// Expected coherence of diffuse noise, per direction.
    pub diffuse: DiffuseMap,
    /// Standard deviation of the coherence of incoherent noise at one direction.
    pub sigma: f64,
}

/// Expected diffuse-noise coherence of the steered response, per direction.
#[derive(Clone, Debug, PartialEq)]
pub struct DiffuseMap {
    points: Vec<Vector3<f64>>,
    values: Vec<f64>,
}

impl DiffuseMap {
    /// Tabulates the response. `pair_axes[p]·d` is pair `p`'s TDOA in
    /// samples and `pair_dist_m[p]` its length; the band is FFT bins
    /// `lo..hi` of an `n`-point FFT at `fs` Hz.
    pub fn new(
        pair_axes: &[Vector3<f64>],
        pair_dist_m: &[f64],
        (lo, hi): (usize, usize),
        n: usize,
        fs: f64,
        speed_of_sound: f64,
    ) -> Self {
        let mut points = SphereGrid::icosphere(2).points().to_vec();
        points.extend([Vector3::z(), -Vector3::z()]);
        let pairs = pair_axes.len();
        let k_count = hi - lo;
        // Per (pair, bin) coherence, computed once.
        let mut gamma = vec![0.0f64; pairs * k_count];
        for p in 0..pairs {
            for k in lo..hi {
                let x =
                    2.0 * std::f64::consts::PI * k as f64 * fs / n as f64 * pair_dist_m[p] / speed_of_sound;
                gamma[p * k_count + k - lo] = if x.abs() < 1e-9 { 1.0 } else { x.sin() / x };
            }
        }
        let values = points
            .iter()
            .map(|d| {
                let mut acc = 0.0;
                for p in 0..pairs {
                    let phase = 2.0 * std::f64::consts::PI * pair_axes[p].dot(d) / n as f64;
                    // cos(phase·k) by recursion over k.
                    let (s1, c1) = phase.sin_cos();
                    let (mut s, mut c) = (phase * lo as f64).sin_cos();
                    for g in &gamma[p * k_count..(p + 1) * k_count] {
                        acc += g * c;
                        (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
                    }
                }
                acc / (pairs * k_count) as f64
            })
            .collect();
        DiffuseMap { points, values }
    }

    /// Expected coherence of diffuse noise steered to `d` (unit vector).
    pub fn at(&self, d: &Vector3<f64>) -> f64 {
        let mut best = (f64::NEG_INFINITY, 0.0);
        for (p, &v) in self.points.iter().zip(&self.values) {
            let c = p.dot(d);
            if c > best.0 {
                best = (c, v);
            }
        }
        best.1
    }

    /// Largest expected coherence over the directions accepted by `inside`.
    pub fn max_where(&self, inside: impl Fn(&Vector3<f64>) -> bool) -> f64 {
        self.points
            .iter()
            .zip(&self.values)
            .filter(|(p, _)| inside(p))
            .map(|(_, &v)| v)
            .fold(f64::NEG_INFINITY, f64::max)
    }
}

/// Points per pair in [`DiffusePower`]'s tables.
const TABLE_POINTS: usize = 257;

/// The diffuse field's expected part of the refinement's beamformer power
/// (see [`crate::srp::refine`]) as a function of direction, with its
/// derivatives: `D(d) = 2 Σ_{i<j} gᵢgⱼ fᵢⱼ(τᵢⱼ(d))`, where
/// `fᵢⱼ(τ) = Σₖ sinc(ωₖ rᵢⱼ/c) cos(ωₖ τ)` and `τᵢⱼ(d) = (pᵢ − pⱼ)·d/c`.
/// Each `fᵢⱼ` and its first two derivatives are tabulated over the pair's
/// delays `|τ| ≤ rᵢⱼ/c` and read by linear interpolation.
///
/// With `[srp] diffuse_compensation` s > 0, the refinement ascends
/// `P(d) − s·β·ē·D(d)` instead of `P(d)`: `ē` the mean whitened energy per
/// microphone and bin, and `β` the diffuse share of the spectra implied by
/// the grid peak's coherence `C = (1 − β) + β·D̄(d)` (D̄ the normalized
/// [`DiffuseMap`]), `β = (1 − C)/(1 − D̄)`. Measured (`BENCHMARKS.md`,
/// "Diffuse compensation"): a small planar array's reverberant elevation
/// bias is mostly this term (ReSpeaker 6, RT60 0.65 s: +12.7° → +5.6°), but
/// `β` counts every other source's energy as diffuse too, and the
/// several-source scenarios lose accuracy, so it is off by default.
#[derive(Clone, Debug)]
pub struct DiffusePower {
    pairs: Vec<DiffusePair>,
}

#[derive(Clone, Debug)]
struct DiffusePair {
    i: usize,
    j: usize,
    /// `(pᵢ − pⱼ)/c`, s per unit of direction.
    axis: Vector3<f64>,
    /// `rᵢⱼ/c`, s.
    max_delay: f64,
    /// `[f, f′, f″]` at `TABLE_POINTS` delays evenly over `±max_delay`.
    table: Vec<[f64; 3]>,
}

/// `D`, its gradient `[D_u, D_v]` and Hessian `[D_uu, D_uv, D_vv]` at a point.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DiffuseLocal {
    /// `D`.
    pub value: f64,
    /// `∂D/∂(u, v)`.
    pub grad: [f64; 2],
    /// `∂²D/∂(u, v)²` as `[uu, uv, vv]`.
    pub hess: [f64; 3],
}

impl DiffusePower {
    /// Tables for microphones at `positions` (m) and the band's angular
    /// frequencies `ωₖ = domega·(lo + k)`, `k < bins` (rad/s), at
    /// `speed_of_sound` m/s.
    pub fn new(positions: &[Vector3<f64>], domega: f64, lo: usize, bins: usize, speed_of_sound: f64) -> Self {
        let omega: Vec<f64> = (0..bins).map(|k| domega * (lo + k) as f64).collect();
        let mut pairs = Vec::new();
        for i in 0..positions.len() {
            for j in i + 1..positions.len() {
                let diff = positions[i] - positions[j];
                let max_delay = diff.norm() / speed_of_sound;
                let gamma: Vec<f64> = omega
                    .iter()
                    .map(|w| {
                        let x = w * max_delay;
                        if x.abs() < 1e-9 { 1.0 } else { x.sin() / x }
                    })
                    .collect();
                let table = (0..TABLE_POINTS)
                    .map(|n| {
                        let tau = max_delay * (2.0 * n as f64 / (TABLE_POINTS - 1) as f64 - 1.0);
                        let mut f = [0.0; 3];
                        // cos and sin of ωₖτ by rotation over k.
                        let (s1, c1) = (domega * tau).sin_cos();
                        let (mut s, mut c) = (omega.first().copied().unwrap_or(0.0) * tau).sin_cos();
                        for (g, w) in gamma.iter().zip(&omega) {
                            f[0] += g * c;
                            f[1] -= g * w * s;
                            f[2] -= g * w * w * c;
                            (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
                        }
                        f
                    })
                    .collect();
                pairs.push(DiffusePair { i, j, axis: diff / speed_of_sound, max_delay, table });
            }
        }
        DiffusePower { pairs }
    }

    /// `D` and its derivatives at `d` in the tangent basis `(e1, e2)`, with
    /// microphone gains `gains`; `curvature` as in the refinement's
    /// coordinates (`d(1 − (u²+v²)/2) + u e₁ + v e₂`, or linear).
    pub fn local(
        &self,
        d: &Vector3<f64>,
        e1: &Vector3<f64>,
        e2: &Vector3<f64>,
        curvature: bool,
        gains: &[f32],
    ) -> DiffuseLocal {
        let mut out = DiffuseLocal::default();
        for p in &self.pairs {
            let w = 2.0 * (gains[p.i] * gains[p.j]) as f64;
            if w == 0.0 || p.max_delay <= 0.0 {
                continue;
            }
            let tau = p.axis.dot(d);
            let x = ((tau / p.max_delay).clamp(-1.0, 1.0) + 1.0) * 0.5 * (TABLE_POINTS - 1) as f64;
            let n = (x.floor() as usize).min(TABLE_POINTS - 2);
            let frac = x - n as f64;
            let (a, b) = (&p.table[n], &p.table[n + 1]);
            let f: [f64; 3] = std::array::from_fn(|m| a[m] + frac * (b[m] - a[m]));
            let (tu, tv) = (p.axis.dot(e1), p.axis.dot(e2));
            let tcurv = if curvature { -tau } else { 0.0 };
            out.value += w * f[0];
            out.grad[0] += w * f[1] * tu;
            out.grad[1] += w * f[1] * tv;
            out.hess[0] += w * (f[2] * tu * tu + f[1] * tcurv);
            out.hess[1] += w * f[2] * tu * tv;
            out.hess[2] += w * (f[2] * tv * tv + f[1] * tcurv);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diffuse_power_matches_the_map_and_its_derivatives_match_finite_differences() {
        // A 9 cm hexagon with a centre microphone raised 1 cm (not planar).
        let mut positions: Vec<Vector3<f64>> = (0..6)
            .map(|k| {
                let a = k as f64 * std::f64::consts::FRAC_PI_3;
                Vector3::new(0.045 * a.cos(), 0.045 * a.sin(), 0.0)
            })
            .collect();
        positions.push(Vector3::new(0.0, 0.0, 0.01));
        let (fs, n, lo, hi, c) = (16000.0, 512usize, 4usize, 256usize, 343.0);
        let domega = 2.0 * std::f64::consts::PI * fs / n as f64;
        let power = DiffusePower::new(&positions, domega, lo, hi - lo, c);
        let pairs: Vec<(usize, usize)> = (0..7).flat_map(|i| (i + 1..7).map(move |j| (i, j))).collect();
        let axes: Vec<Vector3<f64>> =
            pairs.iter().map(|&(i, j)| (positions[j] - positions[i]) * (fs / c)).collect();
        let dist: Vec<f64> = pairs.iter().map(|&(i, j)| (positions[j] - positions[i]).norm()).collect();
        let map = DiffuseMap::new(&axes, &dist, (lo, hi), n, fs, c);
        let gains = [1.0f32; 7];
        let norm = 2.0 * pairs.len() as f64 * (hi - lo) as f64;
        for d in [Vector3::z(), -Vector3::z()] {
            let (e1, e2) = crate::srp::refine::tangent_basis(&d);
            let v = power.local(&d, &e1, &e2, true, &gains).value / norm;
            assert!((v - map.at(&d)).abs() < 0.01, "{v} against {}", map.at(&d));
        }
        let d = Vector3::new(0.8, 0.3, 0.52).normalize();
        let (e1, e2) = crate::srp::refine::tangent_basis(&d);
        let at = |u: f64, v: f64| {
            let p = crate::srp::refine::exp_map(&d, &e1, &e2, [u, v]);
            power.local(&p, &e1, &e2, true, &gains)
        };
        let h = 1e-3;
        let l = at(0.0, 0.0);
        let fd_u = (at(h, 0.0).value - at(-h, 0.0).value) / (2.0 * h);
        let fd_v = (at(0.0, h).value - at(0.0, -h).value) / (2.0 * h);
        assert!((fd_u - l.grad[0]).abs() < 0.02 * l.grad[0].abs(), "{fd_u} against {}", l.grad[0]);
        assert!((fd_v - l.grad[1]).abs() < 0.02 * l.grad[1].abs(), "{fd_v} against {}", l.grad[1]);
        // The mixed second derivative from the gradient (the tables are
        // linear between points: differences of values are too coarse).
        let fd_uv = (at(0.0, h).grad[0] - at(0.0, -h).grad[0]) / (2.0 * h);
        assert!((fd_uv - l.hess[1]).abs() < 0.05 * l.hess[1].abs(), "{fd_uv} against {}", l.hess[1]);
    }

    #[test]
    fn close_pairs_are_more_coherent_than_far_ones_and_peak_broadside() {
        let axis = [Vector3::new(1.0, 0.0, 0.0)];
        let near = DiffuseMap::new(&axis, &[0.02], (2, 128), 256, 16000.0, 343.0);
        let far = DiffuseMap::new(&axis, &[0.5], (2, 128), 256, 16000.0, 343.0);
        assert!(near.at(&Vector3::z()) > 0.5 && far.at(&Vector3::z()) < 0.05);
        // A 5 cm pair along x: zero TDOA broadside (z), the largest endfire (x).
        let five_cm = [Vector3::new(0.05 * 16000.0 / 343.0, 0.0, 0.0)];
        let m = DiffuseMap::new(&five_cm, &[0.05], (2, 128), 256, 16000.0, 343.0);
        assert!(m.at(&Vector3::z()) > m.at(&Vector3::x()), "{} {}", m.at(&Vector3::z()), m.at(&Vector3::x()));
    }
}
