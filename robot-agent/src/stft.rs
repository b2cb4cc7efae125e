//! Short-time Fourier transform of multichannel audio, one hop at a time.
//!
//! Each call to [`Stft::push_hop`] takes `hop_len` new samples per channel
//! (interleaved, f32 full scale ±1), slides the analysis frame of `frame_len`
//! samples and, once a full frame has been seen, windows it and computes one
//! real FFT per channel. Everything is planned and allocated in [`Stft::new`];
//! a hop allocates nothing (realfft's `process_with_scratch`).
//!
//! Spectrum convention: bin `k` (0..=frame_len/2) is at `k·fs/frame_len` Hz,
//! `X[k] = Σ_n w[n] x[n] e^{-j2πkn/N}` (unnormalized forward DFT).

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{RealFftPlanner, RealToComplex};

use crate::error::AgentError;

/// Analysis window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Window {
    /// Periodic Hann window (the default).
    #[default]
    Hann,
    /// Square root of the periodic Hann window (ODAS's analysis window).
    SqrtHann,
    /// No window.
    Rectangular,
}

impl Window {
    /// The window's `len` coefficients.
    pub fn coefficients(self, len: usize) -> Vec<f32> {
        (0..len)
            .map(|n| {
                let hann = 0.5 - 0.5 * (2.0 * std::f64::consts::PI * n as f64 / len as f64).cos();
                match self {
                    Window::Hann => hann as f32,
                    Window::SqrtHann => hann.sqrt() as f32,
                    Window::Rectangular => 1.0,
                }
            })
            .collect()
    }
}

/// Sliding multichannel STFT.
pub struct Stft {
    channels: usize,
    frame_len: usize,
    hop_len: usize,
    window: Vec<f32>,
    /// Last `frame_len` samples of each channel, channel-major.
    history: Vec<f32>,
    fft: Arc<dyn RealToComplex<f32>>,
    input: Vec<f32>,
    scratch: Vec<Complex<f32>>,
    /// `channels × bins` spectra of the last full frame, channel-major.
    spectra: Vec<Complex<f32>>,
    samples_seen: usize,
}

impl std::fmt::Debug for Stft {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stft")
            .field("channels", &self.channels)
            .field("frame_len", &self.frame_len)
            .field("hop_len", &self.hop_len)
            .finish_non_exhaustive()
    }
}

impl Stft {
    /// Plans an STFT of `channels` channels with frames of `frame_len`
    /// samples (even, ≥ 16) advanced by `hop_len` samples (1..=frame_len).
    pub fn new(
        channels: usize,
        frame_len: usize,
        hop_len: usize,
        window: Window,
    ) -> Result<Self, AgentError> {
        let bad =
            |field: &str, message: String| AgentError::InvalidParameter { field: field.into(), message };
        if channels == 0 {
            return Err(bad("channels", "must be at least 1".into()));
        }
        if frame_len < 16 || !frame_len.is_multiple_of(2) || frame_len > 1 << 16 {
            return Err(bad("frame_len", format!("must be even and in 16..=65536, got {frame_len}")));
        }
        if hop_len == 0 || hop_len > frame_len {
            return Err(bad("hop_len", format!("must be in 1..=frame_len ({frame_len}), got {hop_len}")));
        }
        let fft = RealFftPlanner::<f32>::new().plan_fft_forward(frame_len);
        let scratch = fft.make_scratch_vec();
        let bins = frame_len / 2 + 1;
        Ok(Stft {
            channels,
            frame_len,
            hop_len,
            window: window.coefficients(frame_len),
            history: vec![0.0; channels * frame_len],
            input: vec![0.0; frame_len],
            scratch,
            spectra: vec![Complex::new(0.0, 0.0); channels * bins],
            fft,
            samples_seen: 0,
        })
    }

    /// Number of channels.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Frame length, samples.
    pub fn frame_len(&self) -> usize {
        self.frame_len
    }

    /// Hop length, samples.
    pub fn hop_len(&self) -> usize {
        self.hop_len
    }

    /// Number of frequency bins per channel (`frame_len/2 + 1`).
    pub fn bins(&self) -> usize {
        self.frame_len / 2 + 1
    }

    /// Whether the frame is full (at least `frame_len` samples seen).
    pub fn frame_ready(&self) -> bool {
        self.samples_seen >= self.frame_len
    }

    /// Takes one hop, `hop_len` samples per channel interleaved
    /// (`s[t*channels + c]`); non-finite samples are read as 0. Returns whether
    /// a full frame was analysed (then [`Stft::spectra`] holds it).
    ///
    /// # Panics
    /// If `interleaved.len() != hop_len * channels`.
    pub fn push_hop(&mut self, interleaved: &[f32]) -> bool {
        let (n, h, c) = (self.frame_len, self.hop_len, self.channels);
        assert_eq!(interleaved.len(), h * c, "a hop holds hop_len × channels samples");
        for (ch, hist) in self.history.chunks_exact_mut(n).enumerate() {
            hist.copy_within(h.., 0);
            let tail = &mut hist[n - h..];
            for (t, v) in tail.iter_mut().enumerate() {
                let s = interleaved[t * c + ch];
                *v = if s.is_finite() { s } else { 0.0 };
            }
        }
        self.samples_seen = self.samples_seen.saturating_add(h);
        if !self.frame_ready() {
            return false;
        }
        let bins = self.bins();
        for (hist, spec) in self.history.chunks_exact(n).zip(self.spectra.chunks_exact_mut(bins)) {
            for ((x, &s), &w) in self.input.iter_mut().zip(hist).zip(&self.window) {
                *x = s * w;
            }
            self.fft
                .process_with_scratch(&mut self.input, spec, &mut self.scratch)
                .expect("buffer sizes are planned in new()");
        }
        true
    }

    /// Spectra of the last analysed frame, `channels × bins`, channel-major.
    pub fn spectra(&self) -> &[Complex<f32>] {
        &self.spectra
    }

    /// Forgets the audio seen so far.
    pub fn reset(&mut self) {
        self.history.fill(0.0);
        self.samples_seen = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_ready_after_frame_len_samples() {
        let mut s = Stft::new(2, 256, 128, Window::Hann).unwrap();
        assert!(!s.push_hop(&[0.0; 256]));
        assert!(s.push_hop(&[0.0; 256]));
        assert!(s.push_hop(&[0.0; 256]));
    }

    #[test]
    fn matches_a_direct_dft_of_the_windowed_frame() {
        let (ch, n, h) = (3, 64, 16);
        let mut s = Stft::new(ch, n, h, Window::Hann).unwrap();
        let signal = |c: usize, t: usize| ((t * (c + 2)) as f32 * 0.37).sin() + 0.1 * c as f32;
        let total = 7 * h;
        for hop in 0..total / h {
            let block: Vec<f32> = (0..h * ch).map(|i| signal(i % ch, hop * h + i / ch)).collect();
            s.push_hop(&block);
        }
        let w = Window::Hann.coefficients(n);
        for c in 0..ch {
            for k in [0, 1, 5, n / 2] {
                let mut acc = Complex::new(0.0f64, 0.0);
                for t in 0..n {
                    let x = (signal(c, total - n + t) * w[t]) as f64;
                    let ph = -2.0 * std::f64::consts::PI * (k * t) as f64 / n as f64;
                    acc += Complex::new(ph.cos(), ph.sin()) * x;
                }
                let got = s.spectra()[c * (n / 2 + 1) + k];
                assert!((got.re as f64 - acc.re).abs() < 1e-3 && (got.im as f64 - acc.im).abs() < 1e-3);
            }
        }
    }

    #[test]
    fn rejects_bad_sizes() {
        assert!(Stft::new(1, 255, 128, Window::Hann).is_err());
        assert!(Stft::new(1, 256, 0, Window::Hann).is_err());
        assert!(Stft::new(1, 256, 257, Window::Hann).is_err());
        assert!(Stft::new(0, 256, 128, Window::Hann).is_err());
    }

    #[test]
    fn windows() {
        let w = Window::SqrtHann.coefficients(4);
        assert!((w[2] - 1.0).abs() < 1e-7 && w[0] == 0.0);
        assert!(Window::Rectangular.coefficients(3).iter().all(|&v| v == 1.0));
    }
}
