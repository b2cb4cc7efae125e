//! Spectral signature of each reported track: what the array hears when
//! steered at it.
//!
//! Per track and per hop, the STFT frame the pipeline already computed is
//! steered at the track's direction `u` (far-field delay-and-sum, no new FFT):
//! microphone `m` at `pₘ` hears a plane wave from `u` earlier by `pₘ·u/c`, so
//! `Xₘ[k] = S[k]·e^{+jωₖ pₘ·u/c}` and the beam is
//!
//! ```text
//! Y[k] = (1/M) Σₘ Xₘ[k] · e^{−jωₖ pₘ·u/c},        ωₖ = 2π k fs / N
//! P[k] = |Y[k]|² / Σₙ w[n]²                          (w: analysis window)
//! ```
//!
//! so that a unit-variance white noise arriving from `u` gives `E P[k] = 1`
//! (0 dB) at full scale (samples ±1). Band `b` averages `P[k]` over the bins
//! `k` with `edge[b] ≤ k·fs/N < edge[b+1]` (the last band includes its upper
//! edge); a band narrower than the bin spacing that holds no bin takes the one
//! bin nearest its geometric centre `√(edge[b]·edge[b+1])` (neighbouring low
//! bands may then repeat a value). Edges are log-spaced:
//! `edge[i] = low·(high/low)^{i/B}`, `i = 0..=B`, with `low =
//! `[`SignatureConfig::low_edge_hz`] and `high = high_edge_fraction_of_fs·fs`
//! (defaults: 24 bands, 100 Hz to 0.45·fs).
//!
//! Each band's power is smoothed per track with
//! `s ← s + α(P − s)`, `α = 1 − e^{−n·hop/τ}` (τ =
//! [`SignatureConfig::time_constant_s`], 0.1 s by default), refreshed every
//! n = [`SignatureConfig::update_interval_hops`] hops (default 2: with 50 %
//! overlap every other frame still covers every sample) and restarted from the
//! current frame when a track id is new to its slot (new tracks get a value at
//! once). The reported value is `10·log10(s)` dB, clamped to [−200, 200] dB.
//!
//! Everything is planned in [`Signatures::new`]: the bin ranges of the bands,
//! the microphone delays, `K × bins` beam buffers and `K × B` smoothed powers
//! for the K reported tracks. [`Signatures::update`] allocates nothing: the
//! phasors of each microphone are computed per hop from the direction by
//! recursion over the bins (two sines and cosines per microphone and 128 bins,
//! branch-free polynomials in one vectorized pass, `crate::fastmath`; the
//! decibels likewise).

use nalgebra::Vector3;
use realfft::num_complex::Complex;

use crate::array::ArrayGeometry;
use crate::doa_tracker::{MAX_TRACKS, TrackedDirection};
use crate::error::AgentError;

/// Most signature bands (the contract's limit).
pub const MAX_BANDS: usize = soundmap_proto::messages::MAX_SIGNATURE_BANDS;

/// Floor of the smoothed power before the logarithm (−200 dB).
const POWER_FLOOR: f32 = 1e-20;

/// Bins per chunk of the inner loops (fixed-size arrays the compiler
/// vectorizes, as in [`crate::srp`]).
const LANES: usize = 8;

/// Bins between two exact evaluations of a phasor (the recursion in f32
/// drifts by ~1e-7 per step); a multiple of `LANES`.
const REANCHOR_BINS: usize = 128;

/// Signature settings (`[pipeline.signature]` of the agent config).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SignatureConfig {
    /// Number of bands B, 0..=64; 0 turns signatures off.
    pub bands: usize,
    /// Lower edge of the first band, Hz.
    pub low_edge_hz: f64,
    /// Upper edge of the last band as a fraction of the sample rate, in (0, 0.5].
    pub high_edge_fraction_of_fs: f64,
    /// Time constant of the per-track exponential average, seconds.
    pub time_constant_s: f64,
    /// The signatures are refreshed every this many hops (1..=16; default 2:
    /// with the default 50 % frame overlap every other frame still covers
    /// every sample, at half the cost); a new track gets its first value at
    /// once. Values in between repeat the last refresh.
    pub update_interval_hops: u32,
}

impl Default for SignatureConfig {
    /// 24 bands from 100 Hz to 0.45·fs, averaged over 0.1 s, refreshed every other hop.
    fn default() -> Self {
        SignatureConfig {
            bands: 24,
            low_edge_hz: 100.0,
            high_edge_fraction_of_fs: 0.45,
            time_constant_s: 0.1,
            update_interval_hops: 2,
        }
    }
}

impl SignatureConfig {
    /// The B+1 band edges at `sample_rate_hz`, Hz (empty when `bands` is 0),
    /// after checking the settings; errors name the setting under `signature.`.
    pub fn band_edges_hz(&self, sample_rate_hz: u32) -> Result<Vec<f64>, AgentError> {
        let bad = |field: &str, message: String| AgentError::InvalidParameter {
            field: format!("signature.{field}"),
            message,
        };
        if !(1..=16).contains(&self.update_interval_hops) {
            return Err(bad(
                "update_interval_hops",
                format!("must be in 1..=16, got {}", self.update_interval_hops),
            ));
        }
        if self.bands > MAX_BANDS {
            return Err(bad("bands", format!("must be in 0..={MAX_BANDS}, got {}", self.bands)));
        }
        let tau = self.time_constant_s;
        if !(tau.is_finite() && tau > 0.0) {
            return Err(bad("time_constant_s", format!("must be positive, got {tau}")));
        }
        let frac = self.high_edge_fraction_of_fs;
        if !(frac.is_finite() && frac > 0.0 && frac <= 0.5) {
            return Err(bad("high_edge_fraction_of_fs", format!("must be in (0, 0.5], got {frac}")));
        }
        let (low, high) = (self.low_edge_hz, frac * sample_rate_hz as f64);
        if !(low.is_finite() && low > 0.0 && low < high) {
            return Err(bad(
                "low_edge_hz",
                format!("must be positive and below the upper edge {high} Hz, got {low}"),
            ));
        }
        if self.bands == 0 {
            return Ok(Vec::new());
        }
        let b = self.bands as f64;
        let mut edges: Vec<f64> = (0..=self.bands).map(|i| low * (high / low).powf(i as f64 / b)).collect();
        edges[self.bands] = high;
        Ok(edges)
    }
}

/// Per-track spectral signatures (see the [module docs](self)).
#[derive(Debug)]
pub struct Signatures {
    edges_hz: Vec<f64>,
    bins: usize,
    /// First bin any band uses; beams cover `first_bin .. first_bin + span`.
    first_bin: usize,
    span: usize,
    /// `span` rounded up to a multiple of `LANES`.
    padded: usize,
    /// Per band: first bin (relative to `first_bin`) and number of bins.
    band_bins: Vec<(usize, usize)>,
    /// Microphone positions over the speed of sound (s): the lead of microphone m for direction u is `delays[m]·u`.
    delays: Vec<Vector3<f64>>,
    /// Bin spacing, rad/s.
    domega: f64,
    /// `1 / (M² Σ w²)`.
    norm: f32,
    alpha: f32,
    /// Refresh every this many calls of `update`, counted by `calls`.
    interval: u32,
    calls: u32,
    /// Track id held by each of the K slots.
    slot_ids: Vec<Option<u64>>,
    /// `K × B` smoothed band powers, slot-major.
    smoothed: Vec<f32>,
    /// The same in dB (what is reported).
    db: Vec<f32>,
    /// Scratch: the frame's spectra over the span, split into real and
    /// imaginary parts, `M × padded` each (zero beyond the span).
    xr: Vec<[f32; LANES]>,
    xi: Vec<[f32; LANES]>,
    /// Scratch: one beam spectrum, real and imaginary parts, `padded` each.
    yr: Vec<[f32; LANES]>,
    yi: Vec<[f32; LANES]>,
    /// Scratch per microphone: the phase step per bin `w` (rad), its
    /// `(sin, cos)` and those of the first anchor `w·first_bin`.
    w: Vec<f64>,
    step: Vec<(f32, f32)>,
    anchor: Vec<(f32, f32)>,
    /// The CPU's vector instructions (see [`crate::simd`]).
    arch: pulp::Arch,
}

/// [`Signatures::update`] as a vectorized kernel.
struct Update<'a> {
    signatures: &'a mut Signatures,
    spectra: &'a [Complex<f32>],
    tracks: &'a [TrackedDirection],
    reported: &'a [usize],
    out: &'a mut Vec<f32>,
}

impl crate::simd::Kernel for Update<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        self.signatures.update_body(self.spectra, self.tracks, self.reported, self.out)
    }
}

/// What signatures need to know of the pipeline they run in.
#[derive(Clone, Debug, PartialEq)]
pub struct SignatureLayout {
    /// Sample rate, Hz.
    pub sample_rate_hz: u32,
    /// STFT frame length, samples.
    pub frame_len: usize,
    /// Hop, samples.
    pub hop_len: usize,
    /// Most tracks reported per hop (1..=64).
    pub max_tracks: usize,
    /// Σ w² of the analysis window over one frame.
    pub window_energy: f64,
    /// Speed of sound, m/s.
    pub speed_of_sound_m_per_s: f64,
}

impl Signatures {
    /// Plans signatures of at most `layout.max_tracks` (1..=64) tracks for
    /// `array` with the `config` settings, in a pipeline of that layout.
    pub fn new(
        array: &ArrayGeometry,
        config: &SignatureConfig,
        layout: &SignatureLayout,
    ) -> Result<Self, AgentError> {
        let sample_rate_hz = layout.sample_rate_hz;
        let (frame_len, max_tracks) = (layout.frame_len, layout.max_tracks);
        let hop_s = layout.hop_len as f64 / sample_rate_hz as f64;
        let edges_hz = config.band_edges_hz(sample_rate_hz)?;
        if max_tracks == 0 || max_tracks > MAX_TRACKS {
            return Err(AgentError::InvalidParameter {
                field: "max_reported_tracks".into(),
                message: format!("must be in 1..={MAX_TRACKS}, got {max_tracks}"),
            });
        }
        let (fs, n) = (sample_rate_hz as f64, frame_len);
        let bins = n / 2 + 1;
        let bands = edges_hz.len().saturating_sub(1);
        let mut ranges = Vec::with_capacity(bands);
        for b in 0..bands {
            let (lo, hi) = (edges_hz[b], edges_hz[b + 1]);
            let last = b + 1 == bands;
            let inside = |k: usize| {
                let f = k as f64 * fs / n as f64;
                f >= lo && (f < hi || (last && f <= hi))
            };
            let start = (lo * n as f64 / fs).ceil() as usize;
            let count = (start..bins).take_while(|&k| inside(k)).count();
            if count > 0 {
                ranges.push((start, count));
            } else {
                let centre = ((lo * hi).sqrt() * n as f64 / fs).round() as usize;
                ranges.push((centre.min(bins - 1), 1));
            }
        }
        let first_bin = ranges.iter().map(|r| r.0).min().unwrap_or(0);
        let end = ranges.iter().map(|r| r.0 + r.1).max().unwrap_or(0);
        let span = end - first_bin;
        let padded = span.div_ceil(LANES) * LANES;
        let m = array.channels();
        let window_energy = layout.window_energy;
        Ok(Signatures {
            bins,
            first_bin,
            span,
            padded,
            band_bins: ranges.iter().map(|&(s, c)| (s - first_bin, c)).collect(),
            delays: array.positions().map(|p| p.coords / layout.speed_of_sound_m_per_s).collect(),
            domega: 2.0 * std::f64::consts::PI * fs / n as f64,
            norm: (1.0 / ((m * m) as f64 * window_energy.max(f64::MIN_POSITIVE))) as f32,
            alpha: (1.0 - (-hop_s * config.update_interval_hops as f64 / config.time_constant_s).exp())
                as f32,
            interval: config.update_interval_hops,
            calls: 0,
            slot_ids: vec![None; max_tracks],
            smoothed: vec![0.0; max_tracks * bands],
            db: vec![0.0; max_tracks * bands],
            xr: vec![[0.0; LANES]; m * padded / LANES],
            xi: vec![[0.0; LANES]; m * padded / LANES],
            yr: vec![[0.0; LANES]; padded / LANES],
            yi: vec![[0.0; LANES]; padded / LANES],
            w: vec![0.0; m],
            step: vec![(0.0, 1.0); m],
            anchor: vec![(0.0, 1.0); m],
            edges_hz,
            arch: pulp::Arch::new(),
        })
    }

    /// Number of bands B (0 when signatures are off).
    pub fn bands(&self) -> usize {
        self.edges_hz.len().saturating_sub(1)
    }

    /// The B+1 band edges, Hz (empty when signatures are off).
    pub fn band_edges_hz(&self) -> &[f64] {
        &self.edges_hz
    }

    /// Most tracks with a signature at once (K).
    pub fn max_tracks(&self) -> usize {
        self.slot_ids.len()
    }

    /// Updates the signatures of `tracks[i]` for each `i` in `reported` (at
    /// most K, distinct ids) from this frame's `spectra` (`channels × bins`,
    /// channel-major, as [`crate::stft::Stft::spectra`]) and writes them to
    /// `out`, cleared first: B values (dB) per reported track, in the order of
    /// `reported`. Tracks beyond K are ignored. Allocates nothing once `out`
    /// holds `K × B`.
    pub fn update(
        &mut self,
        spectra: &[Complex<f32>],
        tracks: &[TrackedDirection],
        reported: &[usize],
        out: &mut Vec<f32>,
    ) {
        let arch = self.arch;
        crate::simd::run(arch, Update { signatures: self, spectra, tracks, reported, out });
    }

    #[inline(always)]
    fn update_body(
        &mut self,
        spectra: &[Complex<f32>],
        tracks: &[TrackedDirection],
        reported: &[usize],
        out: &mut Vec<f32>,
    ) {
        out.clear();
        let (k_max, bands) = (self.slot_ids.len(), self.bands());
        if bands == 0 {
            return;
        }
        let reported = &reported[..reported.len().min(k_max)];
        // Slots: a track keeps its slot; a new id takes a free one (fresh start).
        let mut slot_of = [usize::MAX; MAX_TRACKS];
        let mut taken = [false; MAX_TRACKS];
        for (j, &t) in reported.iter().enumerate() {
            if let Some(s) = self.slot_ids.iter().position(|&id| id == Some(tracks[t].track_id)) {
                slot_of[j] = s;
                taken[s] = true;
            }
        }
        let mut fresh = [false; MAX_TRACKS];
        for (j, &t) in reported.iter().enumerate() {
            if slot_of[j] == usize::MAX {
                let s = (0..k_max).find(|&s| !taken[s]).expect("at most K reported tracks");
                taken[s] = true;
                self.slot_ids[s] = Some(tracks[t].track_id);
                slot_of[j] = s;
                fresh[j] = true;
            }
        }
        for (s, id) in self.slot_ids.iter_mut().enumerate() {
            if !taken[s] {
                *id = None;
            }
        }
        self.calls = (self.calls + 1) % self.interval;
        let refresh = self.calls == 0;
        if reported.is_empty() {
            return;
        }
        if refresh || fresh[..reported.len()].iter().any(|&f| f) {
            self.split_spectra(spectra);
        }
        for (j, &t) in reported.iter().enumerate() {
            let s = slot_of[j];
            if refresh || fresh[j] {
                self.steer(&tracks[t].direction_in_array);
                let (yr, yi) = (self.yr.as_flattened(), self.yi.as_flattened());
                let smoothed = &mut self.smoothed[s * bands..(s + 1) * bands];
                let db = &mut self.db[s * bands..(s + 1) * bands];
                for (sm, &(start, count)) in smoothed.iter_mut().zip(&self.band_bins) {
                    let sum: f32 = (start..start + count).map(|k| yr[k] * yr[k] + yi[k] * yi[k]).sum();
                    let p = sum / count as f32 * self.norm;
                    *sm = if fresh[j] { p } else { *sm + self.alpha * (p - *sm) };
                }
                // Apart, so that it vectorizes (crate::fastmath).
                for (db, sm) in db.iter_mut().zip(smoothed.iter()) {
                    *db = crate::fastmath::decibels(sm.max(POWER_FLOOR)).clamp(-200.0, 200.0);
                }
            }
            out.extend_from_slice(&self.db[s * bands..(s + 1) * bands]);
        }
    }

    /// Copies the span of every microphone's spectrum into `xr`/`xi`.
    #[inline(always)]
    fn split_spectra(&mut self, spectra: &[Complex<f32>]) {
        let (span, padded) = (self.span, self.padded);
        for (m, (xr, xi)) in self
            .xr
            .as_flattened_mut()
            .chunks_exact_mut(padded)
            .zip(self.xi.as_flattened_mut().chunks_exact_mut(padded))
            .enumerate()
        {
            let x = &spectra[m * self.bins + self.first_bin..m * self.bins + self.first_bin + span];
            for ((r, i), x) in xr.iter_mut().zip(xi.iter_mut()).zip(x) {
                (*r, *i) = (x.re, x.im);
            }
        }
    }

    /// Forgets every track's signature.
    pub fn reset(&mut self) {
        self.slot_ids.fill(None);
        self.calls = 0;
    }

    /// `(yr + j·yi)[k − first_bin] = Σₘ Xₘ[k] e^{−jωₖ dₘ·u}` over the span
    /// (the 1/M of the module docs is in the normalization), from `xr`/`xi`.
    /// Each microphone's phasors run in `LANES` lanes (bins k..k+8) advanced
    /// by `e^{−j8Δω dₘ·u}`, re-anchored exactly every `REANCHOR_BINS` bins.
    #[inline(always)]
    fn steer(&mut self, u: &Vector3<f64>) {
        let chunks = self.padded / LANES;
        let per_anchor = REANCHOR_BINS / LANES;
        self.yr.fill([0.0; LANES]);
        self.yi.fill([0.0; LANES]);
        // Every microphone's one-bin step e^{jw} and first anchor e^{jw·k₀}
        // in one pass the compiler vectorizes (crate::fastmath).
        let k0 = self.first_bin as f64;
        for (((d, step), anchor), w) in
            self.delays.iter().zip(&mut self.step).zip(&mut self.anchor).zip(&mut self.w)
        {
            *w = -self.domega * d.dot(u);
            *step = crate::fastmath::sin_cos(*w);
            *anchor = crate::fastmath::sin_cos(*w * k0);
        }
        let cmul = |(ar, ai): (f32, f32), (br, bi): (f32, f32)| (ar * br - ai * bi, ar * bi + ai * br);
        for m in 0..self.delays.len() {
            let w = self.w[m];
            // Per microphone: one bin's step, its 8th power by squaring, and
            // one exact anchor per REANCHOR_BINS.
            let (s1, c1) = self.step[m];
            let sq2 = cmul((c1, s1), (c1, s1));
            let sq4 = cmul(sq2, sq2);
            let (c8, s8) = cmul(sq4, sq4);
            let xr = &self.xr[m * chunks..(m + 1) * chunks];
            let xi = &self.xi[m * chunks..(m + 1) * chunks];
            for block in (0..chunks).step_by(per_anchor) {
                let (mut pr, mut pi) = ([0f32; LANES], [0f32; LANES]);
                let (s0, c0) = if block == 0 {
                    self.anchor[m]
                } else {
                    crate::fastmath::sin_cos(w * (self.first_bin + block * LANES) as f64)
                };
                (pr[0], pi[0]) = (c0, s0);
                for l in 1..LANES {
                    (pr[l], pi[l]) = cmul((pr[l - 1], pi[l - 1]), (c1, s1));
                }
                let end = (block + per_anchor).min(chunks);
                for (((yr, yi), xr), xi) in self.yr[block..end]
                    .iter_mut()
                    .zip(&mut self.yi[block..end])
                    .zip(&xr[block..end])
                    .zip(&xi[block..end])
                {
                    let (ar, ai) = (*yr, *yi);
                    *yr = std::array::from_fn(|l| ar[l] + (xr[l] * pr[l] - xi[l] * pi[l]));
                    *yi = std::array::from_fn(|l| ai[l] + (xr[l] * pi[l] + xi[l] * pr[l]));
                    (pr, pi) = (
                        std::array::from_fn(|l| pr[l] * c8 - pi[l] * s8),
                        std::array::from_fn(|l| pr[l] * s8 + pi[l] * c8),
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Unit;
    use rand::{RngExt, SeedableRng};

    fn signatures(array: &ArrayGeometry, config: &SignatureConfig) -> Signatures {
        let pipeline = crate::pipeline::PipelineConfig::default();
        Signatures::new(array, config, &pipeline.signature_layout()).unwrap()
    }

    #[test]
    fn default_bands_are_log_spaced_from_100_hz_to_0_45_fs() {
        let e = SignatureConfig::default().band_edges_hz(16_000).unwrap();
        assert_eq!(e.len(), 25);
        assert!((e[0] - 100.0).abs() < 1e-9 && (e[24] - 7200.0).abs() < 1e-9);
        let r = e[1] / e[0];
        assert!(e.windows(2).all(|w| (w[1] / w[0] - r).abs() < 1e-9));
        let off = SignatureConfig { bands: 0, ..Default::default() };
        assert!(off.band_edges_hz(16_000).unwrap().is_empty());
        let bad = |c: SignatureConfig| match c.band_edges_hz(16_000) {
            Err(AgentError::InvalidParameter { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        assert_eq!(bad(SignatureConfig { bands: 65, ..Default::default() }), "signature.bands");
        assert_eq!(
            bad(SignatureConfig { low_edge_hz: 9000.0, ..Default::default() }),
            "signature.low_edge_hz"
        );
        assert_eq!(
            bad(SignatureConfig { high_edge_fraction_of_fs: 0.6, ..Default::default() }),
            "signature.high_edge_fraction_of_fs"
        );
        assert_eq!(
            bad(SignatureConfig { time_constant_s: 0.0, ..Default::default() }),
            "signature.time_constant_s"
        );
    }

    #[test]
    fn every_band_has_bins_and_bands_cover_their_edges() {
        let array = ArrayGeometry::load("respeaker-4").unwrap();
        let s = signatures(&array, &SignatureConfig::default());
        let df = 16_000.0 / 256.0;
        for (b, &(start, count)) in s.band_bins.iter().enumerate() {
            assert!(count >= 1);
            let (lo, hi) = (s.edges_hz[b], s.edges_hz[b + 1]);
            let k = (s.first_bin + start) as f64;
            if count > 1 || (k * df >= lo && k * df < hi) {
                assert!(k * df >= lo - 1e-9 && (k + count as f64 - 1.0) * df <= hi + 1e-9, "band {b}");
            } else {
                // Narrow band: the bin nearest its centre.
                assert!((k * df - (lo * hi).sqrt()).abs() <= df / 2.0 + 1e-9, "band {b}");
            }
        }
    }

    /// The beam against a direct evaluation in f64 (one `sin_cos` per microphone and bin).
    #[test]
    fn steering_matches_a_direct_sum() {
        let array = ArrayGeometry::load("16soundsusb-pioneer").unwrap();
        let mut s = signatures(&array, &SignatureConfig::default());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let spectra: Vec<Complex<f32>> = (0..array.channels() * s.bins)
            .map(|_| Complex::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5))
            .collect();
        let u = Unit::new_normalize(Vector3::new(0.3, -0.5, 0.8));
        let track = TrackedDirection {
            track_id: 1,
            direction_in_array: u,
            activity: 1.0,
            angular_sigma_rad: 0.01,
            confirmed: true,
            silent_s: 0.0,
            audible_silent_s: 0.0,
            held_by_masking: false,
            coherence: 0.5,
        };
        let mut out = Vec::new();
        s.update(&spectra, &[track], &[0], &mut out);
        for i in 0..s.span {
            let got = Complex::new(s.yr.as_flattened()[i], s.yi.as_flattened()[i]);
            let k = s.first_bin + i;
            let mut want = Complex::new(0.0f64, 0.0);
            for (m, d) in s.delays.iter().enumerate() {
                let ph = -s.domega * k as f64 * d.dot(&u);
                let x = spectra[m * s.bins + k];
                want += Complex::new(x.re as f64, x.im as f64) * Complex::new(ph.cos(), ph.sin());
            }
            assert!(
                (got.re as f64 - want.re).abs() < 1e-4 && (got.im as f64 - want.im).abs() < 1e-4,
                "bin {k}"
            );
        }
    }

    #[test]
    fn slots_follow_ids_and_restart_for_new_ones() {
        let array = ArrayGeometry::load("respeaker-4").unwrap();
        let mut s = signatures(&array, &SignatureConfig::default());
        let spectra = vec![Complex::new(1.0f32, 0.0); array.channels() * s.bins];
        let track = |id| TrackedDirection {
            track_id: id,
            direction_in_array: Vector3::z_axis(),
            activity: 1.0,
            angular_sigma_rad: 0.01,
            confirmed: true,
            silent_s: 0.0,
            audible_silent_s: 0.0,
            held_by_masking: false,
            coherence: 0.5,
        };
        let tracks = [track(5), track(9)];
        let mut out = Vec::with_capacity(4 * 24);
        s.update(&spectra, &tracks, &[0, 1], &mut out);
        assert_eq!(out.len(), 48);
        let first = out.clone();
        let zero = vec![Complex::new(0.0f32, 0.0); spectra.len()];
        // Same ids on silence: the average decays from the previous level, it does not restart.
        s.update(&zero, &tracks, &[1, 0], &mut out);
        assert!((out[24] - first[0]).abs() < 1.0, "track 5 kept its average: {} vs {}", out[24], first[0]);
        // A new id restarts from the current frame (silence: the floor).
        let tracks = [track(5), track(11)];
        s.update(&zero, &tracks, &[1, 0], &mut out);
        assert_eq!(out[0], -200.0);
        assert!(out[24] > -200.0);
    }
}
