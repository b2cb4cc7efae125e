//! PHAT-weighted spectra and generalized cross-correlations (GCC-PHAT) of
//! every microphone pair, plus their sliding maxima for the coarse search.
//!
//! Conventions. `X̃ᵢ[k] = Xᵢ[k]/|Xᵢ[k]|` on the band bins only. For pair
//! `p = (i, j)` (i < j), the correlation at lag `n` samples is
//! `ccₚ[n] = (1/K) Σₖ Re(X̃ᵢ[k] X̃ⱼ*[k] e^{j2πkn/N})` over the `K` band bins,
//! so a noise-free plane wave gives `ccₚ = 1` at its lag and `ccₚ ≈ 0` for
//! incoherent noise. A plane wave from direction `d` peaks at
//! `τₚ(d) = (pⱼ − pᵢ)·d · fs/c` samples (the pair's TDOA), see [`super::search`].
//!
//! **Rows.** What is stored is one row per *baseline*, not per pair: pairs
//! whose microphones are displaced by the same vector (a rectangular or
//! circular ring has many: opposite sides, parallel chords) have the same
//! TDOA in every direction, so the steered response only ever reads the sum
//! of their correlations, at the same lag. A row `r` sums the pairs
//! `(a, b)` it lists, each ordered so that `p_b − p_a` is the row's baseline
//! (a pair met reversed contributes `X̃_b X̃_a*`, the conjugate, i.e. its
//! correlation mirrored in lag), and its correlation is the inverse FFT of
//! the summed cross-spectra: `cc_r = Σ_{(a,b) ∈ r} cc_ab`, exactly the sum
//! of the pairs' correlations but computed once (the 16SoundsUSB rings: 88
//! rows for 120 pairs). The sliding maximum of a summed row is at most the
//! sum of its pairs' maxima, so the coarse bounds are tighter too, and still
//! bounds. With one pair per row this is plain per-pair GCC-PHAT.
//! Lags `−R..=R` are kept, stored at index `r·stride + (n + R)`.

use std::sync::Arc;

use nalgebra::Vector3;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

/// Bins processed together in the vectorized loops.
const LANES: usize = 8;

/// Per row, a half-open range `(from, to)` of indices into it in the
/// correlation buffers.
pub type LagSpans = Vec<(usize, usize)>;

/// The correlator's rows: each lists the ordered microphone pairs `(a, b)`
/// whose cross-spectra `X̃_a X̃_b*` it sums (see the module docs).
pub type PairRows = Vec<Vec<(usize, usize)>>;

/// One row per pair `(i, j)`, `i < j`, in lexicographic order.
pub fn pair_rows(mics: usize) -> PairRows {
    (0..mics).flat_map(|i| (i + 1..mics).map(move |j| vec![(i, j)])).collect()
}

/// Displacements closer than this (m) are the same baseline: far below any
/// array's manufacturing tolerance, far above rounding in its coordinates.
const SAME_BASELINE_M: f64 = 1e-9;

/// The pairs `(i, j)`, `i < j`, grouped by baseline `p_j − p_i` (see the
/// module docs): rows in the order of their first pair in lexicographic
/// order, each row's pairs in that order too, a pair whose baseline is the
/// row's reversed entered as `(j, i)`.
pub fn baseline_rows(positions: &[Vector3<f64>]) -> PairRows {
    let m = positions.len();
    let mut rows: PairRows = Vec::new();
    let mut axes: Vec<Vector3<f64>> = Vec::new();
    for i in 0..m {
        for j in i + 1..m {
            let b = positions[j] - positions[i];
            let same = |a: &Vector3<f64>| (a - b).norm() < SAME_BASELINE_M;
            let reversed = |a: &Vector3<f64>| (a + b).norm() < SAME_BASELINE_M;
            if let Some(r) = axes.iter().position(same) {
                rows[r].push((i, j));
            } else if let Some(r) = axes.iter().position(reversed) {
                rows[r].push((j, i));
            } else {
                axes.push(b);
                rows.push(vec![(i, j)]);
            }
        }
    }
    rows
}

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

/// GCC-PHAT of all pairs for one frame, one row per baseline.
pub struct CrossCorrelator {
    pub(super) mics: usize,
    pub(super) rows: PairRows,
    pub(super) band: Band,
    frame_len: usize,
    /// Bins per microphone in `phat_re`/`phat_im` (K rounded up to 8, zero-padded).
    pub(super) padded: usize,
    /// PHAT spectra on the band, mic-major: `re[i*padded + (k - lo)]`.
    pub(super) phat_re: Vec<f32>,
    pub(super) phat_im: Vec<f32>,
    /// Σ |X̃ᵢ[k]|² over bins, per microphone (K, or less for silent bins).
    pub(super) phat_energy: Vec<f32>,
    /// Complex inverse FFT of `frame_len`: two rows' correlations per call,
    /// as the real and imaginary parts.
    ifft: Arc<dyn Fft<f32>>,
    spec: Vec<Complex<f32>>,
    scratch: Vec<Complex<f32>>,
    /// Two rows' summed cross-spectra on the band: `[re₁, im₁, re₂, im₂]`,
    /// `padded` bins each.
    cross: Vec<f32>,
    /// Largest lag kept, samples.
    pub(super) lag_radius: usize,
    /// Entries per row in `cc` / `cc_max` (2R + 2, one guard entry).
    pub(super) stride: usize,
    /// Correlations, `rows × stride`.
    pub(super) cc: Vec<f32>,
    /// `[cc[n], cc[n+1] − cc[n]]`: one load per linear interpolation.
    pub(super) lin: Vec<[f32; 2]>,
    /// Sliding maxima of `cc` over `±window[p]` lags.
    pub(super) cc_max: Vec<f32>,
    pub(super) window: Vec<usize>,
    /// Per row, the lags (row indices, half-open) whose `lin` and whose
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
            .field("rows", &self.rows.len())
            .field("band", &self.band)
            .field("lag_radius", &self.lag_radius)
            .finish_non_exhaustive()
    }
}

impl CrossCorrelator {
    /// Plans the correlator for `rows` (see [`pair_rows`] for one per pair).
    /// `lag_radius < frame_len/2`; `window[r]` is the half-width of the
    /// sliding maximum of row `r` (≤ `lag_radius`).
    pub fn new(
        mics: usize,
        frame_len: usize,
        band: Band,
        lag_radius: usize,
        rows: PairRows,
        window: Vec<usize>,
    ) -> Self {
        assert!(lag_radius < frame_len / 2 && !band.is_empty() && band.lo >= 1 && band.hi <= frame_len / 2);
        assert!(rows.iter().all(|r| !r.is_empty() && r.iter().all(|&(a, b)| a < mics && b < mics && a != b)));
        let pairs = rows.len();
        assert_eq!(window.len(), pairs);
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
            cross: vec![0.0; 4 * padded],
            ifft,
            lag_radius,
            stride,
            cc: vec![0.0; pairs * stride],
            lin: vec![[0.0; 2]; pairs * stride],
            cc_max: vec![0.0; pairs * stride],
            tmp: vec![0.0; 2 * (stride + 2 * window.iter().copied().max().unwrap_or(0))],
            lin_used: vec![(0, stride); window.len()],
            max_used: vec![(0, stride); window.len()],
            window,
            rows,
            arch: pulp::Arch::new(),
        }
    }

    /// Computes `lin` and `cc_max` of row `r` only on the indices `lin[r]`
    /// and `max[r]` (half-open, clipped to the row): the entries a search
    /// reads (see [`super::search::SearchTables::used_lags`]). A baseline
    /// between close microphones spans few lags, so most of its row is
    /// never read. `cc` is still computed on every lag.
    pub fn restrict(&mut self, lin: &[(usize, usize)], max: &[(usize, usize)]) {
        assert!(lin.len() == self.rows.len() && max.len() == self.rows.len());
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

    /// Computes `cc` of every row from the whitened spectra (inverse FFT of
    /// the rows' summed PHAT cross-spectra, two rows per complex FFT), then
    /// `lin` and the sliding maxima `cc_max`.
    pub fn correlate(&mut self) {
        crate::simd::run(self.arch, Correlate(self));
    }

    /// Row `r`'s summed cross-spectrum `Σ X̃_a · conj(X̃_b)` into `out`
    /// (`[re | im]`, `padded` bins each; the padding stays 0).
    #[inline(always)]
    fn row_cross(&self, r: usize, out: &mut [f32]) {
        let padded = self.padded;
        let (or, oi) = out.split_at_mut(padded);
        for (m, &(a, b)) in self.rows[r].iter().enumerate() {
            let (ar, ai) =
                (&self.phat_re[a * padded..(a + 1) * padded], &self.phat_im[a * padded..(a + 1) * padded]);
            let (br, bi) =
                (&self.phat_re[b * padded..(b + 1) * padded], &self.phat_im[b * padded..(b + 1) * padded]);
            if m == 0 {
                for q in 0..padded {
                    or[q] = ar[q] * br[q] + ai[q] * bi[q];
                    oi[q] = ai[q] * br[q] - ar[q] * bi[q];
                }
            } else {
                for q in 0..padded {
                    or[q] += ar[q] * br[q] + ai[q] * bi[q];
                    oi[q] += ai[q] * br[q] - ar[q] * bi[q];
                }
            }
        }
    }

    #[inline(always)]
    fn correlate_body(&mut self) {
        let (k, padded) = (self.band.len(), self.padded);
        let (n, r, lo) = (self.frame_len, self.lag_radius, self.band.lo);
        let scale = 1.0 / (2.0 * k as f32);
        let rows = self.rows.len();
        let mut cross = std::mem::take(&mut self.cross);
        for first in (0..rows).step_by(2) {
            // Z[k] = C₁ + jC₂ and Z[N−k] = C₁* + jC₂*: the inverse FFT is cc₁ + j cc₂.
            let (c1, c2) = cross.split_at_mut(2 * padded);
            self.row_cross(first, c1);
            if first + 1 < rows {
                self.row_cross(first + 1, c2);
            } else {
                c2.fill(0.0);
            }
            let (c1r, c1i) = c1.split_at(padded);
            let (c2r, c2i) = c2.split_at(padded);
            let (c1r, c1i, c2r, c2i) = (&c1r[..k], &c1i[..k], &c2r[..k], &c2i[..k]);
            self.spec[..lo].fill(Complex::new(0.0, 0.0));
            self.spec[lo + k..=n - lo - k].fill(Complex::new(0.0, 0.0));
            self.spec[n - lo + 1..].fill(Complex::new(0.0, 0.0));
            let (pos, neg) = self.spec.split_at_mut(n / 2 + 1);
            // Bin kb = lo + q is pos[lo + q]; bin N − kb is neg[n/2 − 1 − kb].
            let pos = &mut pos[lo..lo + k];
            let neg = &mut neg[n / 2 - lo - k..n / 2 - lo];
            // Z = C₁ + jC₂ at bin k and its mirror C₁* + jC₂* at N − k
            // (stored in reverse order in `neg`).
            for (q, z) in pos.iter_mut().enumerate() {
                *z = Complex::new(c1r[q] - c2i[q], c1i[q] + c2r[q]);
            }
            for (q, z) in neg.iter_mut().rev().enumerate() {
                *z = Complex::new(c1r[q] + c2i[q], c2r[q] - c1i[q]);
            }
            self.ifft.process_with_scratch(&mut self.spec, &mut self.scratch);
            for (slot, p) in [first, first + 1].into_iter().enumerate() {
                if p >= rows {
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
        self.cross = cross;
        for p in 0..rows {
            self.finish_row(p);
        }
    }

    /// Updates `lin` and `cc_max` of row `p` from its `cc` row.
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
    /// for the lags `n` in `from..to` of row `p` only.
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

    /// Zeroes row `p`'s correlation around fractional lag index `t`
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
        let mut cc = CrossCorrelator::new(2, n, band, 20, pair_rows(2), vec![2]);
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
    fn a_baseline_row_is_the_sum_of_its_pairs_correlations() {
        // The Pioneer's two rectangular rings: 120 pairs on 88 baselines.
        let array = crate::array::ArrayGeometry::load("16soundsusb-pioneer").unwrap();
        let positions: Vec<Vector3<f64>> = array.positions().map(|p| p.coords).collect();
        let m = positions.len();
        let rows = baseline_rows(&positions);
        assert_eq!(rows.len(), 88);
        assert_eq!(rows.iter().map(Vec::len).sum::<usize>(), m * (m - 1) / 2);
        for r in &rows {
            let axis = positions[r[0].1] - positions[r[0].0];
            for &(a, b) in r {
                assert!((positions[b] - positions[a] - axis).norm() < 1e-9, "{r:?}");
            }
        }
        let (n, radius) = (256, 40);
        let band = Band { lo: 2, hi: 120 };
        let pairs = pair_rows(m);
        let mut merged = CrossCorrelator::new(m, n, band, radius, rows.clone(), vec![1; rows.len()]);
        let mut single = CrossCorrelator::new(m, n, band, radius, pairs.clone(), vec![1; pairs.len()]);
        let bins = n / 2 + 1;
        let spectra: Vec<Complex<f32>> = (0..m * bins)
            .map(|q| {
                Complex::from_polar(1.0 + (q % 7) as f32, (q as f32 * 0.37).sin() * 3.0 + q as f32 * 0.011)
            })
            .collect();
        merged.whiten(&spectra);
        merged.correlate();
        single.whiten(&spectra);
        single.correlate();
        let s = single.stride;
        for (r, row) in rows.iter().enumerate() {
            for lag in 0..=2 * radius {
                let want: f32 = row
                    .iter()
                    .map(|&(a, b)| {
                        // Pair (a, b) reversed is pair (b, a) at the mirrored lag.
                        let (p, q) = if a < b { ((a, b), lag) } else { ((b, a), 2 * radius - lag) };
                        let p = pairs.iter().position(|x| x[0] == p).unwrap();
                        single.cc[p * s + q]
                    })
                    .sum();
                let got = merged.cc[r * s + lag];
                assert!((got - want).abs() < 1e-5, "row {r} {row:?} lag {lag}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn sliding_max_matches_brute_force() {
        let n = 64;
        let mut c = CrossCorrelator::new(2, n, Band { lo: 1, hi: 32 }, 12, pair_rows(2), vec![7]);
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
