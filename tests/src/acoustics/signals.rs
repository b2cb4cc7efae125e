//! Source signals: white noise (the paper's loudspeaker), band-limited noise,
//! tones, and on/off activity (intermittent sources). Seeded and seekable.
//!
//! A signal is a pure function of the sample index: sample `n` is the source's
//! free-field pressure at 1 m at time `n / fs` after the scene start (samples
//! before 0 are silent). Noise comes from ChaCha8 in chunks of
//! [`NOISE_CHUNK_LEN`] samples, chunk `i` drawn from stream `i` of the source's
//! seed, so any stretch can be produced in any order by any number of
//! consumers (every robot hears the same loudspeaker).

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::error::SimError;

/// Samples per independently seeded noise chunk.
pub const NOISE_CHUNK_LEN: usize = 1024;

/// What a source emits while active.
#[derive(Clone, Debug, PartialEq)]
pub enum Waveform {
    /// Gaussian white noise (flat to the Nyquist frequency).
    WhiteNoise,
    /// Gaussian noise through a linear-phase band-pass FIR (Blackman-windowed sinc,
    /// 257 taps: transition bands ≈ 0.02·fs wide).
    BandNoise {
        /// Lower band edge (Hz), ≥ 0.
        low_hz: f64,
        /// Upper band edge (Hz), ≤ fs/2.
        high_hz: f64,
    },
    /// A sine.
    Tone {
        /// Frequency (Hz).
        frequency_hz: f64,
        /// Phase at sample 0 (rad).
        phase_rad: f64,
    },
}

/// When a source is on. Edges are smoothed by raised-cosine ramps of
/// [`SourceSignal::ramp_s`] inside each on-interval.
#[derive(Clone, Debug, PartialEq)]
pub enum Activity {
    /// Always on.
    Always,
    /// On during each `(start_s, end_s)` interval (sorted, disjoint).
    Intervals(Vec<(f64, f64)>),
    /// On for `on_s`, off for `off_s`, repeating from `start_s` (off before).
    Periodic {
        /// Seconds on per period.
        on_s: f64,
        /// Seconds off per period.
        off_s: f64,
        /// Start of the first on-interval (s).
        start_s: f64,
    },
}

/// A source signal definition.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceSignal {
    /// The waveform.
    pub waveform: Waveform,
    /// RMS free-field pressure at 1 m while on (arbitrary pressure unit shared by
    /// all levels of a scene).
    pub rms: f64,
    /// On/off pattern.
    pub activity: Activity,
    /// Length of the on/off ramps (s).
    pub ramp_s: f64,
    /// Noise seed.
    pub seed: u64,
}

impl SourceSignal {
    /// Continuous white noise of RMS `rms` at 1 m, like the paper's loudspeaker.
    pub fn white_noise(rms: f64, seed: u64) -> Self {
        SourceSignal { waveform: Waveform::WhiteNoise, rms, activity: Activity::Always, ramp_s: 0.005, seed }
    }

    /// This signal switched on and off as `activity` says.
    pub fn with_activity(mut self, activity: Activity) -> Self {
        self.activity = activity;
        self
    }

    /// Checks values against the sample rate.
    pub fn validate(&self, sample_rate_hz: f64) -> Result<(), SimError> {
        if !(self.rms.is_finite() && self.rms >= 0.0) {
            return Err(SimError::invalid("signal.rms", format!("must be ≥ 0, got {}", self.rms)));
        }
        if !(self.ramp_s.is_finite() && self.ramp_s >= 0.0) {
            return Err(SimError::invalid("signal.ramp_s", format!("must be ≥ 0, got {}", self.ramp_s)));
        }
        let nyquist = sample_rate_hz / 2.0;
        match &self.waveform {
            Waveform::WhiteNoise => {}
            Waveform::BandNoise { low_hz, high_hz } => {
                if !(*low_hz >= 0.0 && low_hz < high_hz && *high_hz <= nyquist) {
                    return Err(SimError::invalid(
                        "signal.band_hz",
                        format!("need 0 ≤ low < high ≤ {nyquist}, got {low_hz}..{high_hz}"),
                    ));
                }
            }
            Waveform::Tone { frequency_hz, phase_rad } => {
                if !(frequency_hz.is_finite()
                    && *frequency_hz >= 0.0
                    && *frequency_hz < nyquist
                    && phase_rad.is_finite())
                {
                    return Err(SimError::invalid(
                        "signal.frequency_hz",
                        format!("must be in [0, {nyquist})"),
                    ));
                }
            }
        }
        match &self.activity {
            Activity::Always => {}
            Activity::Intervals(v) => {
                let mut last = f64::NEG_INFINITY;
                for &(a, b) in v {
                    if !(a.is_finite() && b.is_finite() && a >= last && b > a) {
                        return Err(SimError::invalid(
                            "signal.activity",
                            "intervals must be finite, sorted, disjoint",
                        ));
                    }
                    last = b;
                }
            }
            Activity::Periodic { on_s, off_s, start_s } => {
                if !(*on_s > 0.0
                    && *off_s >= 0.0
                    && start_s.is_finite()
                    && on_s.is_finite()
                    && off_s.is_finite())
                {
                    return Err(SimError::invalid("signal.activity", "periodic needs on_s > 0, off_s ≥ 0"));
                }
            }
        }
        Ok(())
    }
}

/// Produces samples of one [`SourceSignal`]; keeps the last noise chunks cached.
#[derive(Clone, Debug)]
pub struct SignalGenerator {
    signal: SourceSignal,
    sample_rate_hz: f64,
    /// Band-pass FIR scaled for unit output variance (empty for other waveforms).
    fir: Vec<f64>,
    /// Two cached chunks: (chunk index, samples).
    cache: [(i64, Vec<f64>); 2],
    next_slot: usize,
    /// White-noise scratch, kept between calls.
    scratch: Vec<f64>,
}

impl SignalGenerator {
    /// Plans a generator (designs the band-pass filter, if any).
    pub fn new(signal: &SourceSignal, sample_rate_hz: f64) -> Result<Self, SimError> {
        signal.validate(sample_rate_hz)?;
        let fir = match signal.waveform {
            Waveform::BandNoise { low_hz, high_hz } => {
                band_pass(low_hz / sample_rate_hz, high_hz / sample_rate_hz, 257)
            }
            _ => Vec::new(),
        };
        Ok(SignalGenerator {
            signal: signal.clone(),
            sample_rate_hz,
            fir,
            cache: [(i64::MIN, vec![0.0; NOISE_CHUNK_LEN]), (i64::MIN, vec![0.0; NOISE_CHUNK_LEN])],
            next_slot: 0,
            scratch: Vec::new(),
        })
    }

    /// The signal definition.
    pub fn signal(&self) -> &SourceSignal {
        &self.signal
    }

    /// Writes samples `first .. first + out.len()` into `out`.
    pub fn fill(&mut self, first: i64, out: &mut [f32]) {
        let rms = self.signal.rms;
        match self.signal.waveform {
            Waveform::WhiteNoise => {
                let mut white = std::mem::take(&mut self.scratch);
                white.resize(out.len(), 0.0);
                self.fill_white(first, &mut white);
                for (o, w) in out.iter_mut().zip(&white) {
                    *o = (rms * w) as f32;
                }
                self.scratch = white;
            }
            Waveform::BandNoise { .. } => {
                let taps = self.fir.len();
                let mut white = std::mem::take(&mut self.scratch);
                white.resize(out.len() + taps - 1, 0.0);
                self.fill_white(first - (taps as i64 - 1), &mut white);
                // out[i] = Σ_k fir[k]·white[i + taps − 1 − k]
                for (i, o) in out.iter_mut().enumerate() {
                    let window = &white[i..i + taps];
                    let acc: f64 = window.iter().rev().zip(&self.fir).map(|(w, h)| w * h).sum();
                    *o = (rms * acc) as f32;
                }
                self.scratch = white;
            }
            Waveform::Tone { frequency_hz, phase_rad } => {
                let w = 2.0 * std::f64::consts::PI * frequency_hz / self.sample_rate_hz;
                let a = rms * std::f64::consts::SQRT_2;
                for (i, o) in out.iter_mut().enumerate() {
                    let n = first + i as i64;
                    // Reduce the phase index modulo one period's worth of samples is not
                    // exact for irrational ratios; f64 keeps n·w accurate to ~1e-9 rad for hours.
                    *o = if n < 0 { 0.0 } else { (a * (w * n as f64 + phase_rad).sin()) as f32 };
                }
            }
        }
        for (i, o) in out.iter_mut().enumerate() {
            let g = self.gate((first + i as i64) as f64 / self.sample_rate_hz);
            if g != 1.0 {
                *o *= g as f32;
            }
        }
    }

    /// Activity gain in [0, 1] at time `t_s` (0 before the scene start).
    pub fn gate(&self, t_s: f64) -> f64 {
        if t_s < 0.0 {
            return 0.0;
        }
        let ramp = self.signal.ramp_s;
        let inside = |a: f64, b: f64| -> f64 {
            if t_s < a || t_s >= b {
                return 0.0;
            }
            let r = ramp.min((b - a) / 2.0);
            let edge = (t_s - a).min(b - t_s);
            if r <= 0.0 || edge >= r { 1.0 } else { 0.5 - 0.5 * (std::f64::consts::PI * edge / r).cos() }
        };
        match &self.signal.activity {
            Activity::Always => 1.0,
            Activity::Intervals(v) => {
                // Last interval starting at or before t.
                let i = v.partition_point(|&(a, _)| a <= t_s);
                if i == 0 { 0.0 } else { inside(v[i - 1].0, v[i - 1].1) }
            }
            Activity::Periodic { on_s, off_s, start_s } => {
                if t_s < *start_s {
                    return 0.0;
                }
                let period = on_s + off_s;
                let k = ((t_s - start_s) / period).floor();
                let a = start_s + k * period;
                if *off_s == 0.0 && t_s >= *start_s + ramp { 1.0 } else { inside(a, a + on_s) }
            }
        }
    }

    /// Unit-variance white samples `first .. first + out.len()` (0 before the start).
    fn fill_white(&mut self, first: i64, out: &mut [f64]) {
        let chunk_len = NOISE_CHUNK_LEN as i64;
        let mut i = 0usize;
        while i < out.len() {
            let n = first + i as i64;
            let chunk = n.div_euclid(chunk_len);
            let offset = n.rem_euclid(chunk_len) as usize;
            let take = (NOISE_CHUNK_LEN - offset).min(out.len() - i);
            if chunk < 0 {
                out[i..i + take].fill(0.0);
            } else {
                let v = self.chunk(chunk);
                out[i..i + take].copy_from_slice(&v[offset..offset + take]);
            }
            i += take;
        }
    }

    /// Noise chunk `chunk` (≥ 0), from the cache or drawn.
    fn chunk(&mut self, chunk: i64) -> &[f64] {
        let slot = match self.cache.iter().position(|(c, _)| *c == chunk) {
            Some(s) => s,
            None => {
                let slot = self.next_slot;
                self.next_slot ^= 1;
                let mut rng = ChaCha8Rng::seed_from_u64(self.signal.seed);
                rng.set_stream(chunk as u64);
                let (c, v) = &mut self.cache[slot];
                *c = chunk;
                for s in v.iter_mut() {
                    *s = rng.sample(StandardNormal);
                }
                slot
            }
        };
        &self.cache[slot].1
    }
}

/// Blackman-windowed sinc band-pass from `lo` to `hi` (cycles per sample), scaled
/// so that unit-variance white noise in gives unit variance out.
fn band_pass(lo: f64, hi: f64, taps: usize) -> Vec<f64> {
    let m = (taps - 1) as f64;
    let pi = std::f64::consts::PI;
    let sinc_lp = |fc: f64, x: f64| if x == 0.0 { 2.0 * fc } else { (2.0 * pi * fc * x).sin() / (pi * x) };
    let mut h: Vec<f64> = (0..taps)
        .map(|n| {
            let x = n as f64 - m / 2.0;
            let w = 0.42 - 0.5 * (2.0 * pi * n as f64 / m).cos() + 0.08 * (4.0 * pi * n as f64 / m).cos();
            w * (sinc_lp(hi, x) - sinc_lp(lo, x))
        })
        .collect();
    let energy: f64 = h.iter().map(|v| v * v).sum();
    let scale = 1.0 / energy.sqrt();
    h.iter_mut().for_each(|v| *v *= scale);
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seekable_and_deterministic() {
        for waveform in [Waveform::WhiteNoise, Waveform::BandNoise { low_hz: 500.0, high_hz: 2000.0 }] {
            let sig = SourceSignal { waveform, ..SourceSignal::white_noise(1.0, 7) };
            let mut a = SignalGenerator::new(&sig, 16_000.0).unwrap();
            let mut b = SignalGenerator::new(&sig, 16_000.0).unwrap();
            let mut whole = vec![0.0f32; 5000];
            a.fill(0, &mut whole);
            let mut part = vec![0.0f32; 700];
            b.fill(3000, &mut part);
            assert_eq!(&whole[3000..3700], &part[..]);
            let rms = (whole[1000..].iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / 4000.0).sqrt();
            assert!((rms - 1.0).abs() < 0.06, "rms {rms}");
        }
    }

    #[test]
    fn gate_ramps_and_intervals() {
        let sig = SourceSignal::white_noise(1.0, 1)
            .with_activity(Activity::Intervals(vec![(1.0, 2.0), (3.0, 3.5)]));
        let g = SignalGenerator::new(&sig, 16_000.0).unwrap();
        assert_eq!(g.gate(0.5), 0.0);
        assert_eq!(g.gate(1.5), 1.0);
        assert!(g.gate(1.0025) > 0.4 && g.gate(1.0025) < 0.6);
        assert_eq!(g.gate(2.5), 0.0);
        assert_eq!(g.gate(3.2), 1.0);
        let p = SourceSignal::white_noise(1.0, 1).with_activity(Activity::Periodic {
            on_s: 1.0,
            off_s: 2.0,
            start_s: 0.5,
        });
        let g = SignalGenerator::new(&p, 16_000.0).unwrap();
        assert_eq!(g.gate(0.2), 0.0);
        assert_eq!(g.gate(1.0), 1.0);
        assert_eq!(g.gate(2.0), 0.0);
        assert_eq!(g.gate(4.0), 1.0);
    }
}
