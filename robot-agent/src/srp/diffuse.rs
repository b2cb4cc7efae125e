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

#[cfg(test)]
mod tests {
    use super::*;

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
