//! The PHAT coherence that diffuse (spherically isotropic) noise alone puts
//! into the steered response, per direction.
//!
//! Diffuse noise is partly coherent between close microphones: its
//! cross-spectrum between microphones `r` metres apart is
//! `sinc(ωr/c) = sin(ωr/c)/(ωr/c)` (real, so it favours zero lags). Steered
//! to `d`, the expected coherence is
//! `(1/(P K)) Σₚ Σₖ sinc(ωₖ rₚ/c) cos(2πk τₚ(d)/N)`, largest where all TDOAs
//! vanish (the zenith of a planar array). Using the raw coherence in place
//! of its PHAT-whitened expectation slightly overestimates it for weakly
//! coherent pairs, which only makes the birth threshold safer.

use nalgebra::Vector3;

/// Largest expected diffuse-noise coherence over `directions`.
/// `pair_axes[p]·d` is pair `p`'s TDOA in samples and `pair_dist_m[p]` its
/// length; the band is FFT bins `lo..hi` of an `n`-point FFT at `fs` Hz.
pub fn diffuse_floor(
    pair_axes: &[Vector3<f64>],
    pair_dist_m: &[f64],
    directions: &[Vector3<f64>],
    (lo, hi): (usize, usize),
    n: usize,
    fs: f64,
    speed_of_sound: f64,
) -> f64 {
    let pairs = pair_axes.len();
    let k_count = hi - lo;
    // Per (pair, bin) coherence, computed once.
    let mut gamma = vec![0.0f64; pairs * k_count];
    for p in 0..pairs {
        for k in lo..hi {
            let x = 2.0 * std::f64::consts::PI * k as f64 * fs / n as f64 * pair_dist_m[p] / speed_of_sound;
            gamma[p * k_count + k - lo] = if x.abs() < 1e-9 { 1.0 } else { x.sin() / x };
        }
    }
    let mut best = f64::NEG_INFINITY;
    for d in directions {
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
        best = best.max(acc / (pairs * k_count) as f64);
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn close_pairs_are_more_coherent_than_far_ones() {
        let d = [Vector3::z()];
        let near = diffuse_floor(&[Vector3::new(1.0, 0.0, 0.0)], &[0.02], &d, (2, 128), 256, 16000.0, 343.0);
        let far = diffuse_floor(&[Vector3::new(1.0, 0.0, 0.0)], &[0.5], &d, (2, 128), 256, 16000.0, 343.0);
        assert!(near > 0.5 && far < 0.05, "{near} {far}");
    }
}
