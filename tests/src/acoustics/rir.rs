//! Room impulse responses: exact image sources early, a stochastic tail late.
//!
//! **Design.** An impulse response from a source to a microphone is the sum of
//!
//! 1. *early reflections*: every image source (see [`super::image_source`]) of
//!    order ≤ `max_order` whose path is shorter than `c·t_c`, each a
//!    Hann-windowed-sinc impulse ([`FractionalDelay`]) of gain `β-product / r`
//!    (r in m: a unit source gives pressure 1 at 1 m) at delay `r/c`, the sum
//!    high-passed (below);
//! 2. *late reverberation*: Gaussian noise from `t_c` to `length_s` whose
//!    energy envelope decays by 60 dB per room RT60 (Eyring,
//!    [`ShoeboxRoom::rt60_eyring_s`]), independent for every microphone (and
//!    source), started at the energy the image series itself carries at `t_c`.
//!    Over `tail_fade_s` before `t_c` the images fade out (cos ramp) while the
//!    tail fades in (sin ramp), so the summed energy stays continuous.
//!
//! The cutoff `t_c` ([`RirModel::image_cutoff_s`]) is `image_cutoff_s` (80 ms by
//! default, past the mixing time ≈ √V ms of rooms up to 6000 m³) or earlier,
//! where the image series' expected energy has drifted `image_excess_db` above
//! the Eyring decay: with uniform absorption a flat room's image series keeps
//! its grazing paths and decays ever more slowly, whereas real rooms scatter: a
//! pure image model (order ≤ 500) of the paper's 12.5 × 12 × 3 m room with the
//! Eyring absorption for 0.6 s measures T30 = 1.1 s (0.57 s for 0.3 s). In that
//! room `t_c` is 80 ms at RT60 0.6 s and 48 ms at 0.3 s.
//!
//! The tail's starting level is the image series' *expected* energy rate at
//! time `t`: images fill space with density `1/V`, so a shell of radius `r = ct`
//! holds `4πr²c·dt/V` of them, each of energy `g²/r²`, giving
//! `E(t) = (4πc/V)·⟨Π_walls β^(2·bounces)⟩` per second. Along a direction `u` a
//! path of length `r` meets the walls across axis `a` about `r|u_a|/L_a` times,
//! so the average is taken over directions ([`RirModel::image_energy_per_second`],
//! a 4096-point Fibonacci sphere). This level does not depend on positions,
//! which is what makes the tail cacheable per microphone.
//!
//! **High-pass.** Reflection coefficients are positive, so the image pulses
//! pile up into a slowly varying positive offset: with `λ` images per sample the
//! response's mean is `λ·E[g]` and its energy `λ·E[g²] + (λ·E[g])²`, several dB
//! above the incoherent sum late in small rooms. That offset lives below
//! ~20 Hz and is not sound; like Allen & Berkley, the image part is high-passed
//! (2nd-order Butterworth, 50 Hz by default; its phase shift, the same on every
//! microphone, leaves time differences exact). The filter is applied to the
//! whole response ([`RirModel::impulse_response`]); it barely touches the
//! white tail. The renderer applies it to the source signals instead: the same
//! result by linearity, once per source rather than per response.
//!
//! Why a hybrid: the image count grows as `t³` (≈ 190 images below 80 ms in
//! the paper's 450 m³ room, ≈ 80 000 below 0.6 s), beyond the mixing time
//! (≈ √V ms ≈ 21 ms here) a real room's response is diffuse, and the pure
//! image model of a flat room decays far too slowly (above).

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::fractional_delay::FractionalDelay;
use super::image_source::{ImageSource, image_sources_into};
use super::noise::fibonacci_sphere;
use super::room::ShoeboxRoom;
use crate::error::SimError;

/// How impulse responses are built.
#[derive(Clone, Debug, PartialEq)]
pub struct RirConfig {
    /// Sample rate (Hz).
    pub sample_rate_hz: f64,
    /// Impulse response length (s). About the RT60 keeps everything down to −60 dB.
    pub length_s: f64,
    /// Highest reflection order of the image sources.
    pub max_order: u32,
    /// Image sources arriving later than this (s after emission) are replaced by
    /// the stochastic tail. Ignored (images fill the whole length) without tail.
    pub image_cutoff_s: f64,
    /// The image part also stops where its expected energy has risen this far
    /// (dB) above the Eyring decay, but not before 20 ms (or `2·tail_fade_s`):
    /// a specular shoebox with uniform absorption decays too slowly once its
    /// grazing paths dominate, while a real room scatters. `INFINITY` disables.
    pub image_excess_db: f64,
    /// Whether to add the stochastic late tail.
    pub tail: bool,
    /// Length of the image-to-tail crossfade ending at the cutoff (s).
    pub tail_fade_s: f64,
    /// Half-width of the fractional-delay kernel (taps).
    pub fractional_delay_half_width: usize,
    /// Distances below this are clamped in the 1/r law (m).
    pub min_distance_m: f64,
    /// Corner of the second-order Butterworth high-pass applied to the image
    /// part (Hz); 0 disables it. See the module notes on the DC offset.
    pub high_pass_hz: f64,
}

impl Default for RirConfig {
    /// 16 kHz, 0.6 s (the paper's RT60), images up to 80 ms with any order, tail
    /// on, 50 Hz high-pass.
    fn default() -> Self {
        RirConfig {
            sample_rate_hz: 16_000.0,
            length_s: 0.6,
            max_order: 1000,
            image_cutoff_s: 0.08,
            image_excess_db: 1.0,
            tail: true,
            tail_fade_s: 0.01,
            fractional_delay_half_width: 16,
            min_distance_m: 0.05,
            high_pass_hz: 50.0,
        }
    }
}

/// Everything needed to build impulse responses in one room, planned once.
#[derive(Clone, Debug)]
pub struct RirModel {
    room: ShoeboxRoom,
    config: RirConfig,
    fd: FractionalDelay,
    len: usize,
    /// Images arriving at or after this sample are dropped.
    cutoff_samples: f64,
    /// Samples of the image fade-out (0 without tail).
    fade_samples: f64,
    /// Tail standard deviation at the cutoff (per sample).
    tail_std_at_cutoff: f64,
    /// Tail amplitude factor per sample.
    tail_decay_per_sample: f64,
    /// High-pass coefficients (None when disabled).
    high_pass: Option<Biquad>,
    /// Per direction of a Fibonacci sphere, ln(energy factor) per metre of path.
    direction_rates: Vec<f64>,
}

impl RirModel {
    /// Plans impulse responses for `room` with `config`.
    pub fn new(room: &ShoeboxRoom, config: &RirConfig) -> Result<Self, SimError> {
        let c = config;
        if !(c.sample_rate_hz.is_finite() && c.sample_rate_hz > 0.0) {
            return Err(SimError::invalid(
                "rir.sample_rate_hz",
                format!("must be > 0, got {}", c.sample_rate_hz),
            ));
        }
        if !(c.length_s.is_finite() && c.length_s * c.sample_rate_hz >= 1.0) {
            return Err(SimError::invalid(
                "rir.length_s",
                format!("must be ≥ one sample, got {}", c.length_s),
            ));
        }
        if c.tail
            && !(c.image_cutoff_s.is_finite() && c.image_cutoff_s > 0.0 && c.image_cutoff_s < c.length_s)
        {
            return Err(SimError::invalid(
                "rir.image_cutoff_s",
                format!("must be in (0, length_s = {}), got {}", c.length_s, c.image_cutoff_s),
            ));
        }
        if c.tail && !(c.tail_fade_s >= 0.0 && c.tail_fade_s <= c.image_cutoff_s) {
            return Err(SimError::invalid(
                "rir.tail_fade_s",
                format!("must be in [0, image_cutoff_s], got {}", c.tail_fade_s),
            ));
        }
        if !(c.high_pass_hz.is_finite() && c.high_pass_hz >= 0.0 && c.high_pass_hz < c.sample_rate_hz / 2.0) {
            return Err(SimError::invalid(
                "rir.high_pass_hz",
                format!("must be in [0, fs/2), got {}", c.high_pass_hz),
            ));
        }
        if !(c.min_distance_m.is_finite() && c.min_distance_m > 0.0) {
            return Err(SimError::invalid(
                "rir.min_distance_m",
                format!("must be > 0, got {}", c.min_distance_m),
            ));
        }
        let fs = c.sample_rate_hz;
        let len = (c.length_s * fs).round() as usize;
        if !(c.image_excess_db > 0.0) {
            return Err(SimError::invalid(
                "rir.image_excess_db",
                format!("must be > 0, got {}", c.image_excess_db),
            ));
        }
        let mut model = RirModel {
            room: room.clone(),
            config: config.clone(),
            fd: FractionalDelay::new(c.fractional_delay_half_width),
            len,
            cutoff_samples: 0.0,
            fade_samples: if c.tail { c.tail_fade_s * fs } else { 0.0 },
            tail_std_at_cutoff: 0.0,
            tail_decay_per_sample: 1.0,
            high_pass: (c.high_pass_hz > 0.0).then(|| Biquad::butterworth_high_pass(c.high_pass_hz / fs)),
            direction_rates: direction_rates(room),
        };
        let cutoff_s = if c.tail {
            model
                .excess_time_s()
                .clamp(c.image_cutoff_s.min((2.0 * c.tail_fade_s).max(0.02)), c.image_cutoff_s)
        } else {
            c.length_s + c.fractional_delay_half_width as f64 / fs
        };
        model.cutoff_samples = cutoff_s * fs;
        if c.tail {
            model.tail_std_at_cutoff = (model.image_energy_per_second(cutoff_s) / fs).sqrt();
            // Amplitude falls 60 dB (×10⁻³) in one RT60.
            model.tail_decay_per_sample = 10f64.powf(-3.0 / (room.rt60_eyring_s() * fs));
        }
        Ok(model)
    }

    /// The room.
    pub fn room(&self) -> &ShoeboxRoom {
        &self.room
    }

    /// The configuration.
    pub fn config(&self) -> &RirConfig {
        &self.config
    }

    /// Impulse response length (samples).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always false: a model has at least one sample.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Number of leading samples image sources can touch (≤ [`Self::len`]); the
    /// rest holds only the position-independent tail.
    pub fn early_len(&self) -> usize {
        let n = self.cutoff_samples.ceil() as usize + self.fd.half_width();
        n.min(self.len)
    }

    /// Start of the tail, fade included (samples); `len()` without tail.
    pub fn tail_start(&self) -> usize {
        if self.config.tail {
            (self.cutoff_samples - self.fade_samples).floor().max(0.0) as usize
        } else {
            self.len
        }
    }

    /// Expected energy per second of the image series at time `t_s` after
    /// emission, for a unit source (pressure 1 at 1 m): `(4πc/V)·⟨Πβ^(2·bounces)⟩`.
    pub fn image_energy_per_second(&self, t_s: f64) -> f64 {
        let c = self.room.speed_of_sound_m_per_s();
        let r = c * t_s;
        let mean = self.direction_rates.iter().map(|k| (r * k).exp()).sum::<f64>()
            / self.direction_rates.len() as f64;
        4.0 * std::f64::consts::PI * c / self.room.volume_m3() * mean
    }

    /// The high-pass every response gets, at rest (None when disabled). It is
    /// linear and time-invariant, so a renderer may apply it to the source
    /// signals instead of to every response.
    pub fn high_pass(&self) -> Option<Biquad> {
        self.high_pass
    }

    /// Time after emission where the images end and the tail takes over (s).
    pub fn image_cutoff_s(&self) -> f64 {
        self.cutoff_samples / self.config.sample_rate_hz
    }

    /// First time (1 ms steps, up to `image_cutoff_s`) at which the expected image
    /// energy exceeds the Eyring decay by `image_excess_db`.
    fn excess_time_s(&self) -> f64 {
        let e0 = self.image_energy_per_second(0.0);
        let rt60 = self.room.rt60_eyring_s();
        let steps = (self.config.image_cutoff_s * 1000.0).ceil() as usize;
        (1..=steps)
            .map(|i| i as f64 * 1e-3)
            .find(|t| {
                10.0 * (self.image_energy_per_second(*t) / e0).log10() + 60.0 * t / rt60
                    > self.config.image_excess_db
            })
            .unwrap_or(self.config.image_cutoff_s)
    }

    /// The image sources of `source_in_map` that can arrive before the cutoff
    /// at some point of the room, into `out`.
    pub fn image_sources_into(&self, source_in_map: &Point3<f64>, out: &mut Vec<ImageSource>) {
        let c = self.room.speed_of_sound_m_per_s();
        let max_distance = c * self.cutoff_samples / self.config.sample_rate_hz;
        image_sources_into(&self.room, source_in_map, self.config.max_order, max_distance, out);
    }

    /// Writes the early part (images, before the high-pass) for a microphone at
    /// `mic_in_map` into `out[..early_len()]` (sample 0 = emission time) and
    /// zeroes the rest of `out`.
    pub fn early_response(&self, images: &[ImageSource], mic_in_map: &Point3<f64>, out: &mut [f64]) {
        out.fill(0.0);
        let n = self.early_len().min(out.len());
        let early = &mut out[..n];
        let per_metre = self.config.sample_rate_hz / self.room.speed_of_sound_m_per_s();
        let fade_start = self.cutoff_samples - self.fade_samples;
        for img in images {
            let r = (img.position_in_map - mic_in_map).norm();
            let delay = r * per_metre;
            if delay >= self.cutoff_samples {
                continue;
            }
            let mut gain = img.gain / r.max(self.config.min_distance_m);
            if delay > fade_start {
                gain *= (std::f64::consts::FRAC_PI_2 * (delay - fade_start) / self.fade_samples).cos();
            }
            self.fd.add(early, delay, gain);
        }
    }

    /// Adds the stochastic tail drawn from `seed` to `out[tail_start()..]`
    /// (clipped to `out.len()`, samples from emission time).
    pub fn add_tail(&self, seed: u64, out: &mut [f64]) {
        if !self.config.tail {
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let start = self.tail_start();
        let end = self.len.min(out.len());
        let fade_start = self.cutoff_samples - self.fade_samples;
        for (n, o) in out.iter_mut().enumerate().take(end).skip(start) {
            let t = n as f64;
            let mut std = self.tail_std_at_cutoff * self.tail_decay_per_sample.powf(t - self.cutoff_samples);
            if t < self.cutoff_samples {
                std *= (std::f64::consts::FRAC_PI_2 * ((t - fade_start) / self.fade_samples).max(0.0)).sin();
            }
            let z: f64 = rng.sample(StandardNormal);
            *o += std * z;
        }
    }

    /// The whole impulse response (length [`Self::len`]) from a source at
    /// `source_in_map` to a microphone at `mic_in_map`, tail drawn from `tail_seed`.
    pub fn impulse_response(
        &self,
        source_in_map: &Point3<f64>,
        mic_in_map: &Point3<f64>,
        tail_seed: u64,
    ) -> Vec<f64> {
        let mut images = Vec::new();
        self.image_sources_into(source_in_map, &mut images);
        let mut h = vec![0.0; self.len];
        self.early_response(&images, mic_in_map, &mut h);
        self.add_tail(tail_seed, &mut h);
        if let Some(mut hp) = self.high_pass() {
            hp.process(&mut h);
        }
        h
    }
}

/// Along a direction `u` a path of length `r` meets the two walls across axis
/// `a` about `r·|u_a|/L_a` times, alternately, so its energy factor is
/// `exp(r·Σ_a |u_a|·ln(β_lo·β_hi)/L_a)`. Returns the exponent per metre for
/// 4096 directions of a Fibonacci sphere.
fn direction_rates(room: &ShoeboxRoom) -> Vec<f64> {
    let beta = room.reflection_coefficients();
    let size = room.size_m();
    let k: Vector3<f64> = Vector3::from_fn(|a, _| (beta[2 * a] * beta[2 * a + 1]).max(1e-300).ln() / size[a]);
    fibonacci_sphere(4096).iter().map(|u| k.x * u.x.abs() + k.y * u.y.abs() + k.z * u.z.abs()).collect()
}

/// A biquad filter with its state (direct form I).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
    x: [f64; 2],
    y: [f64; 2],
}

impl Biquad {
    /// Second-order Butterworth high-pass at `fc` cycles per sample (bilinear
    /// transform with pre-warping), at rest.
    pub fn butterworth_high_pass(fc: f64) -> Self {
        let k = (std::f64::consts::PI * fc).tan();
        let q = std::f64::consts::FRAC_1_SQRT_2;
        let norm = 1.0 / (1.0 + k / q + k * k);
        Biquad {
            b: [norm, -2.0 * norm, norm],
            a: [2.0 * (k * k - 1.0) * norm, (1.0 - k / q + k * k) * norm],
            x: [0.0; 2],
            y: [0.0; 2],
        }
    }

    /// Filters one sample.
    #[inline]
    pub fn tick(&mut self, v: f64) -> f64 {
        let y = self.b[0] * v + self.b[1] * self.x[0] + self.b[2] * self.x[1]
            - self.a[0] * self.y[0]
            - self.a[1] * self.y[1];
        self.x = [v, self.x[0]];
        self.y = [y, self.y[0]];
        y
    }

    /// Filters `buf` in place, continuing from the current state.
    pub fn process(&mut self, buf: &mut [f64]) {
        buf.iter_mut().for_each(|v| *v = self.tick(*v));
    }

    /// [`Self::process`] on f32 samples (state kept in f64).
    pub fn process_f32(&mut self, buf: &mut [f32]) {
        buf.iter_mut().for_each(|v| *v = self.tick(*v as f64) as f32);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_energy_model_matches_eyring_at_time_zero_slope() {
        let room = ShoeboxRoom::from_rt60(Point3::origin(), Vector3::new(6.0, 5.0, 3.0), 0.5).unwrap();
        let m = RirModel::new(&room, &RirConfig::default()).unwrap();
        // Early on, the directional average decays at the mean rate, i.e. Eyring's.
        let dt = 1e-3;
        let slope_db_per_s =
            10.0 * (m.image_energy_per_second(dt) / m.image_energy_per_second(0.0)).log10() / dt;
        assert!((slope_db_per_s + 60.0 / 0.5).abs() < 2.0, "{slope_db_per_s} dB/s");
    }
}
