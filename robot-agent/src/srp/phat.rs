//! PHAT-weighted spectra and generalized cross-correlations (GCC-PHAT) of
//! every microphone pair, plus their sliding maxima for the coarse search.
//!
//! Conventions. `X̃ᵢ[k] = Xᵢ[k]/|Xᵢ[k]|` on the band bins only. For pair
//! `p = (i, j)` (i < j), the correlation at lag `n` samples is
//! `ccₚ[n] = (1/K) Σₖ Re(X̃ᵢ[k] X̃ⱼ*[k] e^{j2πkn/N})` over the `K` band bins,
//! so a noise-free plane wave gives `ccₚ = 1` at its lag and `ccₚ ≈ 0` for
//! incoherent noise. A plane wave from direction `d` peaks at
//! `τₚ(d) = (pⱼ − pᵢ)·d · fs/c` samples (the pair's TDOA), see [`super::search`].
//! Lags `−R..=R` are kept, stored at index `p·stride + (n + R)`.

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner};

/// Frequency band, in FFT bins `lo..hi` (excluding DC and Nyquist).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Band {
    /// First bin.
    pub lo: usize,
    /// One past the last bin.
    pub hi: usize,
}

impl Band {
    /// Number of bins.
    pub fn len(&self) -> usize {
        self.hi - self.lo
    }

    /// Whether the band is empty.
    pub fn is_empty(&self) -> bool {
        self.hi <= self.lo
    }
}

/// GCC-PHAT of all pairs for one frame.
pub struct CrossCorrelator {
    pub(super) mics: usize,
    pub(super) pairs: Vec<(usize, usize)>,
    pub(super) band: Band,
    frame_len: usize,
    /// PHAT spectra on the band, mic-major: `re[i*K + (k - lo)]`.
    pub(super) phat_re: Vec<f32>,
    pub(super) phat_im: Vec<f32>,
    /// Σ |X̃ᵢ[k]|² over bins, per microphone (K, or less for silent bins).
    pub(super) phat_energy: Vec<f32>,
    ifft: Arc<dyn ComplexToReal<f32>>,
    spec: Vec<Complex<f32>>,
    time: Vec<f32>,
    scratch: Vec<Complex<f32>>,
    /// Largest lag kept, samples.
    pub(super) lag_radius: usize,
    /// Entries per pair in `cc` / `cc_max` (2R + 2, one guard entry).
    pub(super) stride: usize,
    /// Correlations, `pairs × stride`.
    pub(super) cc: Vec<f32>,
    /// Sliding maxima of `cc` over `±window[p]` lags.
    pub(super) cc_max: Vec<f32>,
    pub(super) window: Vec<usize>,
    tmp: Vec<f32>,
}

impl std::fmt::Debug for CrossCorrelator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CrossCorrelator")
            .field("mics", &self.mics)
            .field("pairs", &self.pairs.len())
            .field("band", &self.band)
            .field("lag_radius", &self.lag_radius)
            .finish_non_exhaustive()
    }
}

impl CrossCorrelator {
    /// Plans the correlator. `lag_radius < frame_len/2`; `window[p]` is the
    /// half-width of the sliding maximum of pair `p` (≤ `lag_radius`).
    pub fn new(mics: usize, frame_len: usize, band: Band, lag_radius: usize, window: Vec<usize>) -> Self {
        assert!(lag_radius < frame_len / 2 && !band.is_empty() && band.lo >= 1 && band.hi <= frame_len / 2);
        let pairs: Vec<_> = (0..mics).flat_map(|i| (i + 1..mics).map(move |j| (i, j))).collect();
        assert_eq!(window.len(), pairs.len());
        let ifft = RealFftPlanner::<f32>::new().plan_fft_inverse(frame_len);
        let stride = 2 * lag_radius + 2;
        let k = band.len();
        CrossCorrelator {
            mics,
            band,
            frame_len,
            phat_re: vec![0.0; mics * k],
            phat_im: vec![0.0; mics * k],
            phat_energy: vec![0.0; mics],
            spec: ifft.make_input_vec(),
            time: ifft.make_output_vec(),
            scratch: ifft.make_scratch_vec(),
            ifft,
            lag_radius,
            stride,
            cc: vec![0.0; pairs.len() * stride],
            cc_max: vec![0.0; pairs.len() * stride],
            tmp: vec![0.0; 2 * stride],
            window,
            pairs,
        }
    }

    /// PHAT-normalizes the band of each channel's spectrum (`spectra`:
    /// channel-major, `frame_len/2 + 1` bins per channel). Silent bins give 0.
    pub fn whiten(&mut self, spectra: &[Complex<f32>]) {
        let bins = self.frame_len / 2 + 1;
        let k = self.band.len();
        for i in 0..self.mics {
            let src = &spectra[i * bins + self.band.lo..i * bins + self.band.hi];
            let re = &mut self.phat_re[i * k..(i + 1) * k];
            let im = &mut self.phat_im[i * k..(i + 1) * k];
            let mut energy = 0.0;
            for ((x, r), m) in src.iter().zip(re.iter_mut()).zip(im.iter_mut()) {
                let p = x.re * x.re + x.im * x.im;
                let inv = if p > 1e-30 { 1.0 / p.sqrt() } else { 0.0 };
                *r = x.re * inv;
                *m = x.im * inv;
                energy += if p > 1e-30 { 1.0 } else { 0.0 };
            }
            self.phat_energy[i] = energy;
        }
    }

    /// Computes `cc` of every pair from the whitened spectra (inverse FFT of
    /// each PHAT cross-spectrum), then the sliding maxima `cc_max`.
    pub fn correlate(&mut self) {
        let k = self.band.len();
        let n = self.frame_len;
        let r = self.lag_radius;
        let scale = 1.0 / (2.0 * k as f32);
        for (p, &(i, j)) in self.pairs.iter().enumerate() {
            self.spec.fill(Complex::new(0.0, 0.0));
            let (ar, ai) = (&self.phat_re[i * k..(i + 1) * k], &self.phat_im[i * k..(i + 1) * k]);
            let (br, bi) = (&self.phat_re[j * k..(j + 1) * k], &self.phat_im[j * k..(j + 1) * k]);
            for (q, s) in self.spec[self.band.lo..self.band.hi].iter_mut().enumerate() {
                // X̃ᵢ · conj(X̃ⱼ)
                *s = Complex::new(ar[q] * br[q] + ai[q] * bi[q], ai[q] * br[q] - ar[q] * bi[q]);
            }
            self.ifft
                .process_with_scratch(&mut self.spec, &mut self.time, &mut self.scratch)
                .expect("buffer sizes are planned in new(); DC and Nyquist are zero");
            let out = &mut self.cc[p * self.stride..(p + 1) * self.stride];
            // Lags −R..−1 are at the end of the circular correlation.
            for (o, &t) in out[..r].iter_mut().zip(&self.time[n - r..]) {
                *o = t * scale;
            }
            for (o, &t) in out[r..=2 * r].iter_mut().zip(&self.time[..=r]) {
                *o = t * scale;
            }
            out[2 * r + 1] = out[2 * r];
        }
        for p in 0..self.pairs.len() {
            self.sliding_max(p);
        }
    }

    /// `cc_max[p][n] = max(cc[p][n−w..=n+w])` (clipped at the stored lags).
    pub(super) fn sliding_max(&mut self, p: usize) {
        let s = self.stride;
        let w = self.window[p];
        let src = &self.cc[p * s..(p + 1) * s];
        let dst = &mut self.cc_max[p * s..(p + 1) * s];
        if w == 0 {
            dst.copy_from_slice(src);
            return;
        }
        // Doubling: after step `h`, a[n] = max(src[n..n+span]).
        let (a, b) = self.tmp.split_at_mut(s);
        a.copy_from_slice(src);
        let width = 2 * w + 1;
        let mut span = 1;
        while span * 2 <= width {
            for q in 0..s - span {
                let (x, y) = (a[q], a[q + span]);
                b[q] = if x > y { x } else { y };
            }
            b[s - span..].copy_from_slice(&a[s - span..]);
            a.copy_from_slice(b);
            span *= 2;
        }
        // Interior: max over [n−w, n+w] = max(a[n−w], a[n+w+1−span]).
        for q in w..s.saturating_sub(w) {
            let (x, y) = (a[q - w], a[q + w + 1 - span]);
            dst[q] = if x > y { x } else { y };
        }
        // Edges (window clipped by the ends of the row): directly.
        for q in (0..w.min(s)).chain(s.saturating_sub(w).max(w)..s) {
            let (lo, hi) = (q.saturating_sub(w), (q + w).min(s - 1));
            dst[q] = src[lo..=hi].iter().fold(f32::NEG_INFINITY, |m, &v| if v > m { v } else { m });
        }
    }

    /// Zeroes pair `p`'s correlation around fractional lag index `t`
    /// (`t = lag + R`) over `±half` lags and updates its sliding maximum.
    pub(super) fn suppress(&mut self, p: usize, t: f32, half: usize) {
        let s = self.stride;
        let c = t.floor().max(0.0) as usize;
        let lo = c.saturating_sub(half);
        let hi = (c + 1 + half).min(s - 1);
        self.cc[p * s + lo..=p * s + hi].fill(0.0);
        self.sliding_max(p);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pure_delay_peaks_at_its_lag_with_unit_height() {
        let n = 256;
        let bins = n / 2 + 1;
        let band = Band { lo: 1, hi: n / 2 };
        let mut cc = CrossCorrelator::new(2, n, band, 20, vec![2]);
        // Mic 1 hears the signal 5 samples after mic 0: X1 = X0 e^{-jω5}.
        let mut spectra = vec![Complex::new(0.0f32, 0.0); 2 * bins];
        for k in 0..bins {
            let w = 2.0 * std::f32::consts::PI * k as f32 / n as f32;
            let x0 = Complex::new((k as f32 * 0.7).cos(), (k as f32 * 1.3).sin()) * (1.0 + k as f32);
            spectra[k] = x0;
            spectra[bins + k] = x0 * Complex::new((-5.0 * w).cos(), (-5.0 * w).sin());
        }
        cc.whiten(&spectra);
        cc.correlate();
        // cc peaks at τ = t_j − t_i... here mic j = 1 lags by 5: lag −5 (τ = (pⱼ−pᵢ)·d fs/c < 0 when j is farther).
        let r = 20;
        let (imax, vmax) = cc.cc[..cc.stride - 1]
            .iter()
            .enumerate()
            .fold((0, f32::MIN), |b, (i, &v)| if v > b.1 { (i, v) } else { b });
        assert_eq!(imax as i64 - r as i64, -5);
        assert!((vmax - 1.0).abs() < 1e-4, "{vmax}");
        assert!((cc.cc_max[r - 5 + 2] - 1.0).abs() < 1e-4 && (cc.cc_max[r - 5 + 3] - 1.0).abs() > 1e-3);
    }

    #[test]
    fn sliding_max_matches_brute_force() {
        let n = 64;
        let mut c = CrossCorrelator::new(2, n, Band { lo: 1, hi: 32 }, 12, vec![3]);
        let s = c.stride;
        for q in 0..s {
            c.cc[q] = ((q * 7919) % 23) as f32 - 11.0;
        }
        for w in 0..8 {
            c.window[0] = w;
            c.sliding_max(0);
            for q in 0..s {
                let lo = q.saturating_sub(w);
                let hi = (q + w).min(s - 1);
                let m = c.cc[lo..=hi].iter().cloned().fold(f32::MIN, f32::max);
                assert_eq!(c.cc_max[q], m, "w={w} q={q}");
            }
        }
    }
}
