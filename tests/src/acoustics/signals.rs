//! Source signals: white noise (the paper's loudspeaker), band-limited noise,
//! tones, talker-like speech surrogates, a fan, and on/off activity
//! (intermittent sources). Seeded and seekable.
//!
//! A *talker* ([`Waveform::Talker`]) is band-limited noise under a syllabic
//! envelope: time is cut into syllable slots of `1 / syllable_hz` seconds, each
//! voiced slot carries one raised-cosine bump (`sin²`, so the envelope is
//! modulated at `syllable_hz`, 4–6 Hz for speech) with a seeded level in
//! [0.55, 1]; slots are grouped by [`TALKER_WORD_SLOTS`] into words, a word is
//! a pause with probability [`TALKER_PAUSE_PROBABILITY`] and a voiced word drops
//! single syllables with probability [`TALKER_GAP_PROBABILITY`]. At 5 Hz this
//! gives gaps of 0.2 s (a dropped syllable) and pauses of 0.8 s and longer
//! (pause words in a row): speech-like on/off at the 0.3–1 s scale. Every
//! choice is a hash of (seed, slot), so any stretch is produced in any order.
//! `rms` is the RMS over voiced syllables at full level.
//!
//! A *fan* ([`Waveform::Fan`]) is steady: a harmonic hum (harmonics 1–6 of
//! `hum_hz`, amplitudes ∝ 1/k, seeded phases) carrying half the power, and
//! broadband noise (100 Hz – 4 kHz, capped below Nyquist) the other half.
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

/// Syllable slots per talker word (a word is voiced or a pause as a whole).
pub const TALKER_WORD_SLOTS: u64 = 4;
/// Probability that a talker word is a pause.
pub const TALKER_PAUSE_PROBABILITY: f64 = 0.3;
/// Probability that a syllable of a voiced word is dropped (a short gap).
pub const TALKER_GAP_PROBABILITY: f64 = 0.15;
/// Harmonics in a fan's hum.
pub const FAN_HARMONICS: usize = 6;

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
    /// Speech-like: band noise from `low_hz` to `high_hz` under a syllabic
    /// envelope at `syllable_hz` with pauses (see the module docs).
    Talker {
        /// Lower band edge (Hz), ≥ 0.
        low_hz: f64,
        /// Upper band edge (Hz), ≤ fs/2.
        high_hz: f64,
        /// Syllable rate (Hz), in [1, 20]; speech is 4–6 Hz.
        syllable_hz: f64,
    },
    /// A steady fan: harmonic hum at `hum_hz` plus broadband noise (module docs).
    Fan {
        /// Fundamental of the hum (Hz), > 0, below fs/12 (six harmonics fit).
        hum_hz: f64,
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
            Waveform::BandNoise { low_hz, high_hz } | Waveform::Talker { low_hz, high_hz, .. } => {
                if !(*low_hz >= 0.0 && low_hz < high_hz && *high_hz <= nyquist) {
                    return Err(SimError::invalid(
                        "signal.band_hz",
                        format!("need 0 ≤ low < high ≤ {nyquist}, got {low_hz}..{high_hz}"),
                    ));
                }
                if let Waveform::Talker { syllable_hz, .. } = &self.waveform
                    && !(1.0..=20.0).contains(syllable_hz)
                {
                    return Err(SimError::invalid(
                        "signal.syllable_hz",
                        format!("must be in [1, 20] Hz, got {syllable_hz}"),
                    ));
                }
            }
            Waveform::Fan { hum_hz } => {
                if !(*hum_hz > 0.0 && hum_hz * FAN_HARMONICS as f64 * 2.0 <= nyquist) {
                    return Err(SimError::invalid(
                        "signal.hum_hz",
                        format!("must be in (0, {}] Hz, got {hum_hz}", nyquist / (2 * FAN_HARMONICS) as f64),
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
            Waveform::BandNoise { low_hz, high_hz } | Waveform::Talker { low_hz, high_hz, .. } => {
                band_pass(low_hz / sample_rate_hz, high_hz / sample_rate_hz, 257)
            }
            Waveform::Fan { .. } => {
                let high = FAN_NOISE_HIGH_HZ.min(0.45 * sample_rate_hz);
                band_pass(FAN_NOISE_LOW_HZ / sample_rate_hz, high / sample_rate_hz, 257)
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
            Waveform::BandNoise { .. } => self.fill_band(first, out, rms),
            Waveform::Talker { syllable_hz, .. } => {
                // sin⁴ averages 3/8 over a slot and the level² averages LEVEL_MEAN_SQ.
                let scale = rms / (0.375 * TALKER_LEVEL_MEAN_SQ).sqrt();
                self.fill_band(first, out, scale);
                let seed = self.signal.seed;
                for (i, o) in out.iter_mut().enumerate() {
                    let t = (first + i as i64) as f64 / self.sample_rate_hz;
                    *o *= talker_envelope(seed, syllable_hz, t) as f32;
                }
            }
            Waveform::Fan { hum_hz } => {
                let half = rms * std::f64::consts::FRAC_1_SQRT_2;
                self.fill_band(first, out, half);
                // Harmonic k has amplitude a/k; Σ (a/k)²/2 = half² sets a.
                let power: f64 = (1..=FAN_HARMONICS).map(|k| 0.5 / (k * k) as f64).sum();
                let a = half / power.sqrt();
                let phases: Vec<f64> = (1..=FAN_HARMONICS)
                    .map(|k| {
                        unit(crate::acoustics::mix_seed(self.signal.seed, 0xFA40 + k as u64))
                            * std::f64::consts::TAU
                    })
                    .collect();
                let w = 2.0 * std::f64::consts::PI * hum_hz / self.sample_rate_hz;
                for (i, o) in out.iter_mut().enumerate() {
                    let n = first + i as i64;
                    if n < 0 {
                        *o = 0.0;
                        continue;
                    }
                    let hum: f64 = phases
                        .iter()
                        .enumerate()
                        .map(|(j, ph)| a / (j + 1) as f64 * (w * (j + 1) as f64 * n as f64 + ph).sin())
                        .sum();
                    *o += hum as f32;
                }
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

    /// Band-passed noise (the planned FIR) times `gain` into `out`.
    fn fill_band(&mut self, first: i64, out: &mut [f32], gain: f64) {
        let taps = self.fir.len();
        let mut white = std::mem::take(&mut self.scratch);
        white.resize(out.len() + taps - 1, 0.0);
        self.fill_white(first - (taps as i64 - 1), &mut white);
        // out[i] = Σ_k fir[k]·white[i + taps − 1 − k]
        for (i, o) in out.iter_mut().enumerate() {
            let window = &white[i..i + taps];
            let acc: f64 = window.iter().rev().zip(&self.fir).map(|(w, h)| w * h).sum();
            *o = (gain * acc) as f32;
        }
        self.scratch = white;
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

/// Band of a fan's broadband noise (Hz).
const FAN_NOISE_LOW_HZ: f64 = 100.0;
const FAN_NOISE_HIGH_HZ: f64 = 4000.0;
/// A talker syllable's level is uniform in [TALKER_LEVEL_MIN, 1].
const TALKER_LEVEL_MIN: f64 = 0.55;
/// Mean of the squared level: (1 − m³) / (3 (1 − m)) for m = TALKER_LEVEL_MIN.
const TALKER_LEVEL_MEAN_SQ: f64 =
    (1.0 - TALKER_LEVEL_MIN * TALKER_LEVEL_MIN * TALKER_LEVEL_MIN) / (3.0 * (1.0 - TALKER_LEVEL_MIN));

/// A hash as a uniform number in [0, 1).
fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Whether syllable slot `k` of a talker is voiced, and its level (0 when not).
pub fn talker_syllable_level(seed: u64, k: u64) -> f64 {
    use crate::acoustics::mix_seed;
    let word = k / TALKER_WORD_SLOTS;
    if unit(mix_seed(seed ^ 0x007A_1CE4, word)) < TALKER_PAUSE_PROBABILITY {
        return 0.0;
    }
    let h = mix_seed(seed ^ 0x5711_AB1E, k);
    if unit(h) < TALKER_GAP_PROBABILITY {
        return 0.0;
    }
    TALKER_LEVEL_MIN + (1.0 - TALKER_LEVEL_MIN) * unit(mix_seed(h, 1))
}

/// A talker's envelope at `t_s` (0 before the start): `level_k · sin²(π u)`
/// in syllable slot `k = ⌊t · syllable_hz⌋`, `u` the position within the slot.
pub fn talker_envelope(seed: u64, syllable_hz: f64, t_s: f64) -> f64 {
    if t_s < 0.0 {
        return 0.0;
    }
    let x = t_s * syllable_hz;
    let k = x.floor();
    let level = talker_syllable_level(seed, k as u64);
    if level == 0.0 {
        return 0.0;
    }
    let s = (std::f64::consts::PI * (x - k)).sin();
    level * s * s
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

    fn talker(seed: u64) -> SourceSignal {
        SourceSignal {
            waveform: Waveform::Talker { low_hz: 300.0, high_hz: 3000.0, syllable_hz: 5.0 },
            ..SourceSignal::white_noise(1.0, seed)
        }
    }

    fn rms_of(v: &[f32]) -> f64 {
        (v.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>() / v.len().max(1) as f64).sqrt()
    }

    #[test]
    fn talker_is_seekable_deterministic_and_calibrated() {
        let fs = 16_000.0;
        let mut a = SignalGenerator::new(&talker(3), fs).unwrap();
        let mut b = SignalGenerator::new(&talker(3), fs).unwrap();
        let mut whole = vec![0.0f32; 60 * 16_000];
        a.fill(0, &mut whole);
        let mut part = vec![0.0f32; 3000];
        b.fill(123_456, &mut part);
        assert_eq!(&whole[123_456..126_456], &part[..]);
        let mut other = vec![0.0f32; whole.len()];
        SignalGenerator::new(&talker(4), fs).unwrap().fill(0, &mut other);
        let differ =
            (0..300u64).filter(|k| talker_syllable_level(3, *k) != talker_syllable_level(4, *k)).count();
        assert!(whole != other && differ > 100, "another seed, another talker ({differ} slots differ)");
        // RMS over voiced syllables ≈ rms: the signal power divided by the share
        // of voiced slots, each slot's level² averaging TALKER_LEVEL_MEAN_SQ.
        let slots = 60 * 5;
        let levels: Vec<f64> = (0..slots).map(|k| talker_syllable_level(3, k)).collect();
        let voiced = levels.iter().filter(|l| **l > 0.0).count() as f64 / slots as f64;
        let mean_sq: f64 = levels.iter().map(|l| l * l).sum::<f64>() / slots as f64;
        let expected = (mean_sq / voiced / TALKER_LEVEL_MEAN_SQ).sqrt();
        let measured = rms_of(&whole) / voiced.sqrt();
        assert!((measured - expected).abs() < 0.08, "voiced RMS {measured} vs {expected}");
        assert!((0.45..0.8).contains(&voiced), "voiced share {voiced}");
    }

    #[test]
    fn talker_has_syllables_and_pauses_at_speech_scales() {
        // Envelope: silent at slot edges, peaks mid-slot (5 Hz modulation).
        let seed = 9;
        let k = (0..200u64).find(|k| talker_syllable_level(seed, *k) > 0.0).unwrap();
        let t_mid = (k as f64 + 0.5) / 5.0;
        assert!(talker_envelope(seed, 5.0, t_mid) >= TALKER_LEVEL_MIN - 1e-12);
        assert!(talker_envelope(seed, 5.0, k as f64 / 5.0) < 1e-12);
        // Silent runs (in slots of 0.2 s): both short gaps and pauses of ≥ 0.8 s occur,
        // and none is absurdly long over 10 minutes.
        let levels: Vec<bool> = (0..3000u64).map(|k| talker_syllable_level(seed, k) > 0.0).collect();
        let mut runs = Vec::new();
        let mut run = 0usize;
        for v in &levels {
            if *v {
                if run > 0 {
                    runs.push(run);
                }
                run = 0;
            } else {
                run += 1;
            }
        }
        let short = runs.iter().filter(|r| **r == 1 || **r == 2).count();
        let long = runs.iter().filter(|r| **r >= 4).count();
        assert!(short > 50 && long > 50, "gaps of 0.2–0.4 s: {short}, pauses ≥ 0.8 s: {long}");
        assert!(runs.iter().all(|r| *r <= 40), "a pause over 8 s: {runs:?}");
    }

    #[test]
    fn talker_spectrum_stays_in_its_band() {
        // Energy in 300–3000 Hz dominates for one talker; a 1–2.5 kHz talker has
        // little below 700 Hz. Measured by a crude DFT on a voiced stretch.
        let fs = 16_000.0;
        let power_in = |sig: &SourceSignal, lo: f64, hi: f64| -> f64 {
            let mut g = SignalGenerator::new(sig, fs).unwrap();
            let mut v = vec![0.0f32; 16_000 * 4];
            g.fill(0, &mut v);
            let n = 2048;
            let mut total = 0.0;
            for f in (0..n / 2).map(|b| b as f64 * fs / n as f64).filter(|f| *f >= lo && *f < hi) {
                for frame in v.chunks_exact(n) {
                    let w = 2.0 * std::f64::consts::PI * f / fs;
                    let (re, im) = frame.iter().enumerate().fold((0.0, 0.0), |(re, im), (i, x)| {
                        (re + f64::from(*x) * (w * i as f64).cos(), im + f64::from(*x) * (w * i as f64).sin())
                    });
                    total += re * re + im * im;
                }
            }
            total
        };
        let high = SourceSignal {
            waveform: Waveform::Talker { low_hz: 1000.0, high_hz: 2500.0, syllable_hz: 4.0 },
            ..SourceSignal::white_noise(1.0, 5)
        };
        let inside = power_in(&high, 1100.0, 2400.0);
        let below = power_in(&high, 100.0, 700.0);
        assert!(below < 1e-3 * inside, "below band {below} vs in band {inside}");
    }

    #[test]
    fn fan_is_steady_with_a_hum() {
        let fs = 16_000.0;
        let sig =
            SourceSignal { waveform: Waveform::Fan { hum_hz: 120.0 }, ..SourceSignal::white_noise(0.5, 2) };
        let mut g = SignalGenerator::new(&sig, fs).unwrap();
        let mut v = vec![0.0f32; 16_000 * 5];
        g.fill(0, &mut v);
        let mut part = vec![0.0f32; 1000];
        SignalGenerator::new(&sig, fs).unwrap().fill(40_000, &mut part);
        assert_eq!(&v[40_000..41_000], &part[..]);
        assert!((rms_of(&v[1000..]) - 0.5).abs() < 0.03, "rms {}", rms_of(&v));
        for w in v[1000..].chunks(8000) {
            assert!((rms_of(w) - 0.5).abs() < 0.05, "steady over 0.5 s windows: {}", rms_of(w));
        }
        // The hum: the 120 Hz bin stands far above its 170 Hz neighbour.
        let bin = |f: f64| {
            let w = 2.0 * std::f64::consts::PI * f / fs;
            let (re, im) = v.iter().enumerate().fold((0.0, 0.0), |(re, im), (i, x)| {
                (re + f64::from(*x) * (w * i as f64).cos(), im + f64::from(*x) * (w * i as f64).sin())
            });
            re * re + im * im
        };
        assert!(bin(120.0) > 100.0 * bin(170.0));
        assert!(sig.validate(fs).is_ok());
        let bad = SourceSignal { waveform: Waveform::Fan { hum_hz: 1000.0 }, ..sig };
        assert!(bad.validate(fs).is_err(), "six harmonics of 1 kHz at 16 kHz are fine but 12 kHz is not");
    }
}
