//! Uniformly partitioned overlap-save convolution (UPOLS) with realfft, and the
//! slow direct convolution it is checked against.
//!
//! A filter `h` is cut into `P` partitions of `B` samples; partition `p` is
//! zero-padded to `2B` and transformed once ([`Upols::filter_spectra`]). Each
//! input block `x_b` (B samples) is transformed together with its predecessor,
//! `X_b = FFT([x_{b−1}, x_b])`, and kept in a [`SpectrumHistory`]. The output
//! block is the last `B` samples of `IFFT(Σ_p X_{b−p}·H_p)`. Per output sample
//! that is `P` complex multiply-adds and `1/B` of a `2B` inverse FFT, instead of
//! `P·B` multiply-adds for direct convolution. Spectra are f32, carry the
//! `1/(2B)` inverse-FFT scale, and are stored *split*: a spectrum of `B + 1`
//! bins is `2(B + 1)` floats, all real parts then all imaginary parts, so that
//! the complex multiply-add vectorizes without shuffles ([`multiply_add`]).

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};

/// Shared FFT plans and scratch for one block length.
#[derive(Clone)]
pub struct Upols {
    block_len: usize,
    forward: Arc<dyn RealToComplex<f32>>,
    inverse: Arc<dyn ComplexToReal<f32>>,
    time: Vec<f32>,
    spectrum: Vec<Complex<f32>>,
    scratch_forward: Vec<Complex<f32>>,
    scratch_inverse: Vec<Complex<f32>>,
}

impl std::fmt::Debug for Upols {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Upols").field("block_len", &self.block_len).finish_non_exhaustive()
    }
}

impl Upols {
    /// Plans FFTs of length `2·block_len` (block_len ≥ 1).
    pub fn new(block_len: usize) -> Self {
        let block_len = block_len.max(1);
        let mut planner = RealFftPlanner::<f32>::new();
        let forward = planner.plan_fft_forward(2 * block_len);
        let inverse = planner.plan_fft_inverse(2 * block_len);
        Upols {
            block_len,
            time: forward.make_input_vec(),
            spectrum: forward.make_output_vec(),
            scratch_forward: forward.make_scratch_vec(),
            scratch_inverse: inverse.make_scratch_vec(),
            forward,
            inverse,
        }
    }

    /// Block length `B` (samples).
    pub fn block_len(&self) -> usize {
        self.block_len
    }

    /// Bins per spectrum, `B + 1`.
    pub fn bins(&self) -> usize {
        self.block_len + 1
    }

    /// Partitions needed for a filter of `len` taps.
    pub fn partitions_for(&self, len: usize) -> usize {
        len.div_ceil(self.block_len).max(1)
    }

    /// Floats per split spectrum, `2(B + 1)`.
    pub fn split_len(&self) -> usize {
        2 * self.bins()
    }

    /// Writes the split spectra of the `out.len() / split_len()` partitions of
    /// `h` (f64 taps, missing taps are zero) into `out`, scaled by `1/(2B)`.
    pub fn filter_spectra(&mut self, h: &[f64], out: &mut [f32]) {
        let b = self.block_len;
        let scale = 1.0 / (2 * b) as f64;
        for (p, dst) in out.chunks_exact_mut(self.split_len()).enumerate() {
            self.time.fill(0.0);
            let lo = (p * b).min(h.len());
            let hi = ((p + 1) * b).min(h.len());
            for (t, v) in self.time.iter_mut().zip(&h[lo..hi]) {
                *t = (v * scale) as f32;
            }
            self.forward
                .process_with_scratch(&mut self.time, &mut self.spectrum, &mut self.scratch_forward)
                .expect("buffer sizes come from the plan");
            split(&self.spectrum, dst);
        }
    }

    /// Split spectrum of `[previous, current]` (each `B` samples) into `out`.
    pub fn input_spectrum(&mut self, previous: &[f32], current: &[f32], out: &mut [f32]) {
        let b = self.block_len;
        self.time[..b].copy_from_slice(previous);
        self.time[b..].copy_from_slice(current);
        self.forward
            .process_with_scratch(&mut self.time, &mut self.spectrum, &mut self.scratch_forward)
            .expect("buffer sizes come from the plan");
        split(&self.spectrum, out);
    }

    /// Inverse transform of the split spectrum `acc`; writes the last `B`
    /// samples (the valid overlap-save output) to `out`.
    pub fn output_block(&mut self, acc: &[f32], out: &mut [f32]) {
        let bins = self.bins();
        let (re, im) = acc.split_at(bins);
        for ((c, r), i) in self.spectrum.iter_mut().zip(re).zip(im) {
            *c = Complex::new(*r, *i);
        }
        // Real signals have real DC and Nyquist bins; clear rounding residue.
        self.spectrum[0].im = 0.0;
        self.spectrum[bins - 1].im = 0.0;
        self.inverse
            .process_with_scratch(&mut self.spectrum, &mut self.time, &mut self.scratch_inverse)
            .expect("buffer sizes come from the plan");
        out.copy_from_slice(&self.time[self.block_len..]);
    }
}

/// Interleaved complex → split (real parts, then imaginary parts).
fn split(c: &[Complex<f32>], out: &mut [f32]) {
    let (re, im) = out.split_at_mut(c.len());
    for ((v, r), i) in c.iter().zip(re).zip(im) {
        *r = v.re;
        *i = v.im;
    }
}

/// The last `P` input spectra of one signal (newest first), and its last block.
#[derive(Clone, Debug)]
pub struct SpectrumHistory {
    split_len: usize,
    partitions: usize,
    data: Vec<f32>,
    /// Slot of the newest spectrum.
    head: usize,
    previous: Vec<f32>,
}

impl SpectrumHistory {
    /// An all-silent history for `partitions` partitions.
    pub fn new(engine: &Upols, partitions: usize) -> Self {
        SpectrumHistory {
            split_len: engine.split_len(),
            partitions,
            data: vec![0.0; engine.split_len() * partitions],
            head: 0,
            previous: vec![0.0; engine.block_len()],
        }
    }

    /// Transforms the next input block (`B` samples) and makes it the newest.
    pub fn push(&mut self, engine: &mut Upols, block: &[f32]) {
        self.head = (self.head + self.partitions - 1) % self.partitions;
        let n = self.split_len;
        let slot = &mut self.data[self.head * n..(self.head + 1) * n];
        engine.input_spectrum(&self.previous, block, slot);
        self.previous.copy_from_slice(block);
    }

    /// The split spectrum of the block `age` blocks ago (0 = newest).
    pub fn get(&self, age: usize) -> &[f32] {
        let slot = (self.head + age) % self.partitions;
        &self.data[slot * self.split_len..(slot + 1) * self.split_len]
    }
}

/// `acc += Σ_{p in partitions} X_{b−p} · H_p` on split spectra, with `filter`
/// holding consecutive partition spectra starting at partition `partitions.start`.
pub fn accumulate(
    acc: &mut [f32],
    history: &SpectrumHistory,
    filter: &[f32],
    partitions: std::ops::Range<usize>,
) {
    let n = acc.len();
    let first = partitions.start;
    for p in partitions {
        let h = &filter[(p - first) * n..(p - first + 1) * n];
        multiply_add(acc, history.get(p), h);
    }
}

/// `acc += x · h`, element-wise complex on split spectra (real parts, then
/// imaginary parts).
#[inline]
pub fn multiply_add(acc: &mut [f32], x: &[f32], h: &[f32]) {
    let n = acc.len() / 2;
    let (ar, ai) = acc.split_at_mut(n);
    let (xr, xi) = x.split_at(n);
    let (hr, hi) = h.split_at(n);
    for (((((ar, ai), xr), xi), hr), hi) in ar.iter_mut().zip(ai.iter_mut()).zip(xr).zip(xi).zip(hr).zip(hi) {
        *ar += xr * hr - xi * hi;
        *ai += xr * hi + xi * hr;
    }
}

/// Direct time-domain convolution `out[n] = Σ_k h[k]·x[n − k]` for
/// `n < out.len()` (x zero before 0): the slow obvious reference.
pub fn direct_convolution(x: &[f32], h: &[f64], out: &mut [f64]) {
    for (n, o) in out.iter_mut().enumerate() {
        let kmax = n.min(h.len().saturating_sub(1));
        let mut acc = 0.0;
        for k in 0..=kmax {
            if n - k < x.len() {
                acc += h[k] * x[n - k] as f64;
            }
        }
        *o = acc;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upols_equals_direct_convolution() {
        let b = 64;
        let h: Vec<f64> =
            (0..300).map(|i| ((i * 37 % 101) as f64 / 50.0 - 1.0) * (-(i as f64) / 80.0).exp()).collect();
        let x: Vec<f32> = (0..1000).map(|i| (i * 53 % 97) as f32 / 48.0 - 1.0).collect();
        let mut engine = Upols::new(b);
        let p = engine.partitions_for(h.len());
        let mut spectra = vec![0.0f32; p * engine.split_len()];
        engine.filter_spectra(&h, &mut spectra);
        let mut hist = SpectrumHistory::new(&engine, p);
        let mut got = Vec::new();
        let mut acc = vec![0.0f32; engine.split_len()];
        let mut out = vec![0.0f32; b];
        for block in x.chunks_exact(b) {
            hist.push(&mut engine, block);
            acc.fill(0.0);
            accumulate(&mut acc, &hist, &spectra, 0..p);
            engine.output_block(&acc, &mut out);
            got.extend_from_slice(&out);
        }
        let mut want = vec![0.0; got.len()];
        direct_convolution(&x, &h, &mut want);
        for (g, w) in got.iter().zip(&want) {
            assert!((*g as f64 - w).abs() < 1e-4, "{g} vs {w}");
        }
    }
}
