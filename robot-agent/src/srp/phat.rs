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

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

/// Bins processed together in the vectorized loops.
const LANES: usize = 8;

/// Per pair, a half-open range `(from, to)` of indices into its row of the
/// correlation buffers.
pub type LagSpans = Vec<(usize, usize)>;

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
    /// Bins per microphone in `phat_re`/`phat_im` (K rounded up to 8, zero-padded).
    pub(super) padded: usize,
    /// PHAT spectra on the band, mic-major: `re[i*padded + (k - lo)]`.
    pub(super) phat_re: Vec<f32>,
    pub(super) phat_im: Vec<f32>,
    /// Σ |X̃ᵢ[k]|² over bins, per microphone (K, or less for silent bins).
    pub(super) phat_energy: Vec<f32>,
    /// Complex inverse FFT of `frame_len`: two pairs' correlations per call,
    /// as the real and imaginary parts.
    ifft: Arc<dyn Fft<f32>>,
    spec: Vec<Complex<f32>>,
    scratch: Vec<Complex<f32>>,
    /// Largest lag kept, samples.
    pub(super) lag_radius: usize,
    /// Entries per pair in `cc` / `cc_max` (2R + 2, one guard entry).
    pub(super) stride: usize,
    /// Correlations, `pairs × stride`.
    pub(super) cc: Vec<f32>,
    /// `[cc[n], cc[n+1] − cc[n]]`: one load per linear interpolation.
    pub(super) lin: Vec<[f32; 2]>,
    /// Sliding maxima of `cc` over `±window[p]` lags.
    pub(super) cc_max: Vec<f32>,
    pub(super) window: Vec<usize>,
    /// Per pair, the lags (row indices, half-open) whose `lin` and whose
    /// `cc_max` a search reads: the rest of those rows is never computed.
    /// The whole row unless [`Self::restrict`] narrowed them.
    lin_used: LagSpans,
    max_used: LagSpans,
    tmp: Vec<f32>,
    /// The CPU's vector instructions (see [`crate::simd`]).
    pub(super) arch: pulp::Arch,
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
        let ifft = FftPlanner::<f32>::new().plan_fft_inverse(frame_len);
        let stride = 2 * lag_radius + 2;
        let padded = band.len().div_ceil(LANES) * LANES;
        CrossCorrelator {
            mics,
            band,
            frame_len,
            padded,
            phat_re: vec![0.0; mics * padded],
            phat_im: vec![0.0; mics * padded],
            phat_energy: vec![0.0; mics],
            spec: vec![Complex::new(0.0, 0.0); frame_len],
            scratch: vec![Complex::new(0.0, 0.0); ifft.get_inplace_scratch_len()],
            ifft,
            lag_radius,
            stride,
            cc: vec![0.0; pairs.len() * stride],
            lin: vec![[0.0; 2]; pairs.len() * stride],
            cc_max: vec![0.0; pairs.len() * stride],
            tmp: vec![0.0; 2 * (stride + 2 * window.iter().copied().max().unwrap_or(0))],
            lin_used: vec![(0, stride); window.len()],
            max_used: vec![(0, stride); window.len()],
            window,
            pairs,
            arch: pulp::Arch::new(),
        }
    }

    /// Computes `lin` and `cc_max` of pair `p` only on the row indices
    /// `lin[p]` and `max[p]` (half-open, clipped to the row): the entries a
    /// search reads (see [`super::search::SearchTables::used_lags`]). A pair
    /// whose microphones are close spans few lags, so most of its row is
    /// never read. `cc` is still computed on every lag.
    pub fn restrict(&mut self, lin: &[(usize, usize)], max: &[(usize, usize)]) {
        assert!(lin.len() == self.pairs.len() && max.len() == self.pairs.len());
        let clip = |&(a, b): &(usize, usize)| (a.min(self.stride), b.min(self.stride));
        self.lin_used = lin.iter().map(clip).collect();
        self.max_used = max.iter().map(clip).collect();
    }

    /// PHAT-normalizes the band of each channel's spectrum (`spectra`:
    /// channel-major, `frame_len/2 + 1` bins per channel). Silent bins give 0.
    pub fn whiten(&mut self, spectra: &[Complex<f32>]) {
        crate::simd::run(self.arch, Whiten(self, spectra));
    }

    #[inline(always)]
    fn whiten_body(&mut self, spectra: &[Complex<f32>]) {
        let bins = self.frame_len / 2 + 1;
        let (k, padded) = (self.band.len(), self.padded);
        for i in 0..self.mics {
            let src = &spectra[i * bins + self.band.lo..i * bins + self.band.hi];
            let re = &mut self.phat_re[i * padded..i * padded + k];
            let im = &mut self.phat_im[i * padded..i * padded + k];
            let mut energy = 0u32;
            // Branch-free, so that it vectorizes: silent bins select 0.
            for ((x, r), m) in src.iter().zip(re.iter_mut()).zip(im.iter_mut()) {
                let p = x.re * x.re + x.im * x.im;
                let live = p > 1e-30;
                let inv = 1.0 / p.max(1e-30).sqrt();
                let inv = if live { inv } else { 0.0 };
                *r = x.re * inv;
                *m = x.im * inv;
                energy += live as u32;
            }
            self.phat_energy[i] = energy as f32;
        }
    }

    /// Computes `cc` of every pair from the whitened spectra (inverse FFT of
    /// the PHAT cross-spectra, two pairs per complex FFT), then `lin` and the
    /// sliding maxima `cc_max`.
    pub fn correlate(&mut self) {
        crate::simd::run(self.arch, Correlate(self));
    }

    #[inline(always)]
    fn correlate_body(&mut self) {
        let (k, padded) = (self.band.len(), self.padded);
        let (n, r, lo) = (self.frame_len, self.lag_radius, self.band.lo);
        let scale = 1.0 / (2.0 * k as f32);
        let pairs = self.pairs.len();
        for first in (0..pairs).step_by(2) {
            // Z[k] = C₁ + jC₂ and Z[N−k] = C₁* + jC₂*: the inverse FFT is cc₁ + j cc₂.
            let (i1, j1) = self.pairs[first];
            let (i2, j2) = if first + 1 < pairs { self.pairs[first + 1] } else { (i1, j1) };
            let w2 = if first + 1 < pairs { 1.0 } else { 0.0 };
            let (ar, ai) = (
                &self.phat_re[i1 * padded..(i1 + 1) * padded],
                &self.phat_im[i1 * padded..(i1 + 1) * padded],
            );
            let (br, bi) = (
                &self.phat_re[j1 * padded..(j1 + 1) * padded],
                &self.phat_im[j1 * padded..(j1 + 1) * padded],
            );
            let (cr, ci) = (
                &self.phat_re[i2 * padded..(i2 + 1) * padded],
                &self.phat_im[i2 * padded..(i2 + 1) * padded],
            );
            let (dr, di) = (
                &self.phat_re[j2 * padded..(j2 + 1) * padded],
                &self.phat_im[j2 * padded..(j2 + 1) * padded],
            );
            self.spec[..lo].fill(Complex::new(0.0, 0.0));
            self.spec[lo + k..=n - lo - k].fill(Complex::new(0.0, 0.0));
            self.spec[n - lo + 1..].fill(Complex::new(0.0, 0.0));
            let (pos, neg) = self.spec.split_at_mut(n / 2 + 1);
            // Bin kb = lo + q is pos[lo + q]; bin N − kb is neg[n/2 − 1 − kb].
            let pos = &mut pos[lo..lo + k];
            let neg = &mut neg[n / 2 - lo - k..n / 2 - lo];
            // C = X̃ᵢ · conj(X̃ⱼ) for both pairs; Z = C₁ + jC₂ at bin k and its
            // mirror C₁* + jC₂* at N − k (stored in reverse order in `neg`).
            let (ar, ai, br, bi) = (&ar[..k], &ai[..k], &br[..k], &bi[..k]);
            let (cr, ci, dr, di) = (&cr[..k], &ci[..k], &dr[..k], &di[..k]);
            let cross = |q: usize| {
                let (c1r, c1i) = (ar[q] * br[q] + ai[q] * bi[q], ai[q] * br[q] - ar[q] * bi[q]);
                let (c2r, c2i) = (cr[q] * dr[q] + ci[q] * di[q], ci[q] * dr[q] - cr[q] * di[q]);
                (c1r, c1i, w2 * c2r, w2 * c2i)
            };
            for (q, z) in pos.iter_mut().enumerate() {
                let (c1r, c1i, c2r, c2i) = cross(q);
                *z = Complex::new(c1r - c2i, c1i + c2r);
            }
            for (q, z) in neg.iter_mut().rev().enumerate() {
                let (c1r, c1i, c2r, c2i) = cross(q);
                *z = Complex::new(c1r + c2i, c2r - c1i);
            }
            self.ifft.process_with_scratch(&mut self.spec, &mut self.scratch);
            for (slot, p) in [first, first + 1].into_iter().enumerate() {
                if p >= pairs {
                    break;
                }
                let out = &mut self.cc[p * self.stride..(p + 1) * self.stride];
                // Lags −R..−1 are at the end of the circular correlation.
                let (neg, pos) = (&self.spec[n - r..], &self.spec[..=r]);
                if slot == 0 {
                    out[..r].iter_mut().zip(neg).for_each(|(o, z)| *o = z.re * scale);
                    out[r..=2 * r].iter_mut().zip(pos).for_each(|(o, z)| *o = z.re * scale);
                } else {
                    out[..r].iter_mut().zip(neg).for_each(|(o, z)| *o = z.im * scale);
                    out[r..=2 * r].iter_mut().zip(pos).for_each(|(o, z)| *o = z.im * scale);
                }
                out[2 * r + 1] = out[2 * r];
            }
        }
        for p in 0..pairs {
            self.finish_row(p);
        }
    }

    /// Updates `lin` and `cc_max` of pair `p` from its `cc` row.
    #[inline(always)]
    fn finish_row(&mut self, p: usize) {
        let s = self.stride;
        let (from, to) = self.lin_used[p];
        if from < to {
            let row = &self.cc[p * s..(p + 1) * s];
            let lin = &mut self.lin[p * s..(p + 1) * s];
            let end = to.min(s - 1);
            for ((l, &a), &b) in lin[from..end].iter_mut().zip(&row[from..end]).zip(&row[from + 1..=end]) {
                *l = [a, b - a];
            }
            if to == s {
                lin[s - 1] = [row[s - 1], 0.0];
            }
        }
        let (from, to) = self.max_used[p];
        self.sliding_max_range(p, from, to);
    }

    /// `cc_max[p][n] = max(cc[p][n−w..=n+w])` (clipped at the stored lags)
    /// for the lags `n` in `from..to` of pair `p` only.
    ///
    /// The lags it reads, `from−w..to+w` clipped to the row, are padded with
    /// −∞ up to `w` entries on each side, so that one formula holds
    /// everywhere: after ⌊log₂(2w+1)⌋ doubling passes
    /// `a[n] = max(pad[n..n+span])`, and the window `[n−w, n+w]` of the row
    /// is `[n, n+2w]` of the padding, the union of two overlapping spans.
    #[inline(always)]
    fn sliding_max_range(&mut self, p: usize, from: usize, to: usize) {
        let s = self.stride;
        let w = self.window[p];
        let (from, to) = (from.min(s), to.min(s));
        if from >= to {
            return;
        }
        let dst = &mut self.cc_max[p * s + from..p * s + to];
        if w == 0 {
            dst.copy_from_slice(&self.cc[p * s + from..p * s + to]);
            return;
        }
        // Padded row: entry n + w is lag n; lags read: [read_lo, read_hi).
        let (read_lo, read_hi) = (from.saturating_sub(w), (to + w).min(s));
        let src = &self.cc[p * s + read_lo..p * s + read_hi];
        let len = (to - from) + 2 * w;
        let lead = w - (from - read_lo);
        let half = self.tmp.len() / 2;
        let (a, b) = self.tmp.split_at_mut(half);
        let (mut a, mut b) = (&mut a[..len], &mut b[..len]);
        a[..lead].fill(f32::NEG_INFINITY);
        a[lead..lead + src.len()].copy_from_slice(src);
        a[lead + src.len()..].fill(f32::NEG_INFINITY);
        let width = 2 * w + 1;
        let mut span = 1;
        while span * 2 <= width {
            for ((o, &x), &y) in b.iter_mut().zip(a.iter()).zip(&a[span..]) {
                *o = if x > y { x } else { y };
            }
            b[len - span..].copy_from_slice(&a[len - span..]);
            std::mem::swap(&mut a, &mut b);
            span *= 2;
        }
        for ((o, &x), &y) in dst.iter_mut().zip(a.iter()).zip(&a[width - span..]) {
            *o = if x > y { x } else { y };
        }
    }

    /// Zeroes pair `p`'s correlation around fractional lag index `t`
    /// (`t = lag + R`) over `±half` lags, and updates its interpolation
    /// table and sliding maxima.
    #[inline(always)]
    pub(super) fn suppress(&mut self, p: usize, t: f32, half: usize) {
        let s = self.stride;
        let c = t.floor().max(0.0) as usize;
        let lo = c.saturating_sub(half);
        let hi = (c + 1 + half).min(s - 1);
        self.cc[p * s + lo..=p * s + hi].fill(0.0);
        let w = self.window[p];
        // Only entries that read the zeroed lags change (and only those a
        // search reads are kept).
        let row = &self.cc[p * s..(p + 1) * s];
        let (lin_from, lin_to) = self.lin_used[p];
        for q in lo.saturating_sub(1).max(lin_from)..(hi + 1).min(lin_to) {
            let next = if q + 1 < s { row[q + 1] } else { row[q] };
            self.lin[p * s + q] = [row[q], next - row[q]];
        }
        // Sliding maxima: exact bounds matter (stale ones would send the next
        // search back to this peak); only those within w of the zeroed lags change.
        let (max_from, max_to) = self.max_used[p];
        self.zeroed_max(p, lo, hi, lo.saturating_sub(w).max(max_from), (hi + w + 1).min(max_to));
    }

    /// `cc_max[p][q]` for `q` in `from..to` after `cc[p][lo..=hi]` was zeroed,
    /// every such `q` being within `w` of the zeroed lags (so up to `2w` lags
    /// each side are read): each window
    /// `[q−w, q+w]` then holds a zero, the lags of it left of `lo` and those
    /// right of `hi`, so its maximum is `max(0, L, R)` with `L` a running
    /// maximum leftward from `lo − 1` and `R` one rightward from `hi + 1`.
    /// O(w) per pair instead of the general sliding maximum's O(w log w),
    /// and the same values (a maximum does not depend on the order).
    #[inline(always)]
    fn zeroed_max(&mut self, p: usize, lo: usize, hi: usize, from: usize, to: usize) {
        let s = self.stride;
        let w = self.window[p];
        if from >= to {
            return;
        }
        debug_assert!(from + w >= lo && to <= hi + w + 1 && hi < s);
        let row = &self.cc[p * s..(p + 1) * s];
        let half = self.tmp.len() / 2;
        let (left, right) = self.tmp.split_at_mut(half);
        // left[k] = max(row[lo−1−k..lo]), right[k] = max(row[hi+1..=hi+1+k]).
        let (mut m, mut n) = (f32::NEG_INFINITY, f32::NEG_INFINITY);
        let left_len = (2 * w).min(lo);
        for (k, l) in left[..left_len].iter_mut().enumerate() {
            let x = row[lo - 1 - k];
            m = if x > m { x } else { m };
            *l = m;
        }
        let right_len = (2 * w).min(s - 1 - hi);
        for (k, r) in right[..right_len].iter_mut().enumerate() {
            let x = row[hi + 1 + k];
            n = if x > n { x } else { n };
            *r = n;
        }
        let dst = &mut self.cc_max[p * s..(p + 1) * s];
        for (q, o) in dst.iter_mut().enumerate().take(to).skip(from) {
            let mut v = 0.0f32;
            // Window [q−w, q+w] clipped to the row; its part left of lo has
            // lo − max(q−w, 0) lags, its part right of hi min(q+w, s−1) − hi.
            let start = q.saturating_sub(w);
            if start < lo {
                let x = left[lo - 1 - start];
                v = if x > v { x } else { v };
            }
            let end = (q + w).min(s - 1);
            if end > hi {
                let x = right[end - hi - 1];
                v = if x > v { x } else { v };
            }
            *o = v;
        }
    }
}

/// [`CrossCorrelator::whiten`] as a vectorized kernel.
struct Whiten<'a, 's>(&'a mut CrossCorrelator, &'s [Complex<f32>]);

impl crate::simd::Kernel for Whiten<'_, '_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        self.0.whiten_body(self.1)
    }
}

/// [`CrossCorrelator::correlate`] as a vectorized kernel.
struct Correlate<'a>(&'a mut CrossCorrelator);

impl crate::simd::Kernel for Correlate<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        self.0.correlate_body()
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
        let mut c = CrossCorrelator::new(2, n, Band { lo: 1, hi: 32 }, 12, vec![7]);
        let s = c.stride;
        for q in 0..s {
            c.cc[q] = ((q * 7919) % 23) as f32 - 11.0;
        }
        let brute = |c: &CrossCorrelator, w: usize, q: usize| {
            let (lo, hi) = (q.saturating_sub(w), (q + w).min(s - 1));
            c.cc[lo..=hi].iter().cloned().fold(f32::MIN, f32::max)
        };
        for w in 0..8 {
            c.window[0] = w;
            c.sliding_max_range(0, 0, s);
            for q in 0..s {
                assert_eq!(c.cc_max[q], brute(&c, w, q), "w={w} q={q}");
            }
            // After a suppression anywhere in the row (the edges too), the
            // maxima near it are those of the zeroed row, the rest untouched.
            for (t, half) in [(0.3f32, 1), (4.7, 1), (11.0, 2), ((s - 2) as f32 + 0.5, 1), (15.2, 0)] {
                c.lin_used = vec![(0, s)];
                c.max_used = vec![(0, s)];
                for q in 0..s {
                    c.cc[q] = ((q * 7919) % 23) as f32 - 11.0;
                }
                c.sliding_max_range(0, 0, s);
                let before = c.cc_max.clone();
                c.suppress(0, t, half);
                let zc = t.floor() as usize;
                let (zlo, zhi) = (zc.saturating_sub(half), (zc + 1 + half).min(s - 1));
                assert!(c.cc[zlo..=zhi].iter().all(|&v| v == 0.0));
                for q in 0..s {
                    let near = q + w >= zlo && q <= zhi + w;
                    let want = if near { brute(&c, w, q) } else { before[q] };
                    assert_eq!(c.cc_max[q], want, "w={w} q={q} suppressed at {t} ±{half}");
                }
            }
            // Part of a row, anywhere in it, leaves the rest alone.
            for (from, to) in [(0, 3), (5, 9), (s - 4, s), (2, s + 5)] {
                c.cc_max.fill(-99.0);
                c.sliding_max_range(0, from, to);
                for q in 0..s {
                    let want = if (from..to).contains(&q) { brute(&c, w, q) } else { -99.0 };
                    assert_eq!(c.cc_max[q], want, "w={w} q={q} range {from}..{to}");
                }
            }
        }
    }
}
