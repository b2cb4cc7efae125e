//! Microphone self-noise and diffuse (spherically isotropic) background noise.
//!
//! Levels are RMS pressures in the scene's unit (a unit source gives 1 at 1 m),
//! set from an SNR against the direct-path level at the array with
//! [`direct_path_rms`] and [`noise_std_for_snr`].
//!
//! **Diffuse noise** is the sum of `2K` plane waves of independent white noise
//! arriving from `K` directions of a Fibonacci sphere and from their opposites
//! (so that the expected cross-spectra are real), so that the coherence between
//! two microphones a distance `d` apart tends to `sinc(kd) = sin(kd)/(kd)`. It is
//! synthesized once, in the frequency domain, as a periodic loop of `N` samples:
//! per bin, `Y_m(f) = Σ_k Z_k(f)·exp(j·2πf·u_k·p_m/c)` with complex Gaussian `Z_k`.
//! On a periodic signal the circular delays are exact, so there is no
//! fractional-delay error at any frequency. An isotropic field's statistics do
//! not change when the array moves rigidly, so the field is generated for the
//! array's own geometry (relative microphone positions) and simply played back.

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use realfft::RealFftPlanner;
use realfft::num_complex::Complex;

use crate::error::SimError;

/// RMS of the direct path of a source of RMS `source_rms_at_1m` (at 1 m) heard at
/// `distance_m` (1/r law).
pub fn direct_path_rms(source_rms_at_1m: f64, distance_m: f64) -> f64 {
    source_rms_at_1m / distance_m
}

/// Noise standard deviation giving `snr_db` against a signal of RMS `signal_rms`.
pub fn noise_std_for_snr(signal_rms: f64, snr_db: f64) -> f64 {
    signal_rms * 10f64.powf(-snr_db / 20.0)
}

/// Independent white Gaussian noise on every microphone.
#[derive(Clone, Debug)]
pub struct SensorNoise {
    std: f64,
    rng: ChaCha8Rng,
}

impl SensorNoise {
    /// Noise of standard deviation `std` drawn from `seed`.
    pub fn new(std: f64, seed: u64) -> Result<Self, SimError> {
        if !(std.is_finite() && std >= 0.0) {
            return Err(SimError::invalid("sensor_noise_std", format!("must be ≥ 0, got {std}")));
        }
        Ok(SensorNoise { std, rng: ChaCha8Rng::seed_from_u64(seed) })
    }

    /// Adds noise to every sample of `out`.
    pub fn add_to(&mut self, out: &mut [f32]) {
        if self.std == 0.0 {
            return;
        }
        for o in out {
            let z: f64 = self.rng.sample(StandardNormal);
            *o += (self.std * z) as f32;
        }
    }
}

/// Parameters of the diffuse noise field.
#[derive(Clone, Debug, PartialEq)]
pub struct DiffuseNoiseConfig {
    /// RMS per microphone (pressure units of the scene).
    pub std: f64,
    /// Loop length (samples, even); the field repeats after this.
    pub loop_len: usize,
    /// Number of Fibonacci-sphere directions; each also gets its opposite, so
    /// the field has twice as many plane waves.
    pub directions: usize,
}

impl DiffuseNoiseConfig {
    /// A field of RMS `std` with a 65 536-sample loop (4.1 s at 16 kHz) and 128
    /// directions (256 plane waves).
    pub fn with_std(std: f64) -> Self {
        DiffuseNoiseConfig { std, loop_len: 1 << 16, directions: 128 }
    }
}

/// A precomputed diffuse noise loop, played back block by block.
#[derive(Clone, Debug)]
pub struct DiffuseNoise {
    channels: usize,
    loop_len: usize,
    /// Planar: channel `m` at `data[m·N .. (m+1)·N]`.
    data: Vec<f32>,
    position: usize,
}

impl DiffuseNoise {
    /// Synthesizes the field for microphones at `microphones` (any frame: only
    /// their relative positions matter), sample rate `sample_rate_hz`, speed of
    /// sound `c_m_per_s`.
    pub fn new(
        microphones: &[Point3<f64>],
        config: &DiffuseNoiseConfig,
        sample_rate_hz: f64,
        c_m_per_s: f64,
        seed: u64,
    ) -> Result<Self, SimError> {
        let n = config.loop_len;
        if n < 4 || !n.is_multiple_of(2) {
            return Err(SimError::invalid(
                "diffuse_noise.loop_len",
                format!("must be even and ≥ 4, got {n}"),
            ));
        }
        if config.directions == 0 {
            return Err(SimError::invalid("diffuse_noise.directions", "must be ≥ 1"));
        }
        if !(config.std.is_finite() && config.std >= 0.0) {
            return Err(SimError::invalid("diffuse_noise.std", format!("must be ≥ 0, got {}", config.std)));
        }
        let m_count = microphones.len();
        let centroid = microphones.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / m_count.max(1) as f64;
        // Antipodal pairs: the expected cross-spectrum is then exactly real, like
        // the isotropic field's sinc.
        let half = fibonacci_sphere(config.directions);
        let dirs: Vec<Vector3<f64>> = half.iter().copied().chain(half.iter().map(|u| -u)).collect();
        // Delay of direction k at microphone m (s): a wave from direction u reaches p early by u·p/c.
        let tau: Vec<f64> = dirs
            .iter()
            .flat_map(|u| microphones.iter().map(move |p| u.dot(&(p.coords - centroid)) / c_m_per_s))
            .collect();
        let bins = n / 2 + 1;
        let mut spectra = vec![Complex::new(0.0f64, 0.0); m_count * bins];
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let two_pi_df = 2.0 * std::f64::consts::PI * sample_rate_hz / n as f64;
        let step: Vec<Complex<f64>> = tau.iter().map(|t| Complex::from_polar(1.0, two_pi_df * t)).collect();
        let mut phasor = vec![Complex::new(1.0, 0.0); tau.len()];
        let mut y = vec![Complex::new(0.0, 0.0); m_count];
        // Bins 1 .. N/2 − 1: DC and Nyquist stay zero.
        for f in 1..bins - 1 {
            if f % 256 == 1 {
                // Re-anchor the phasors exactly every 256 bins (no drift).
                for (ph, t) in phasor.iter_mut().zip(&tau) {
                    *ph = Complex::from_polar(1.0, two_pi_df * f as f64 * t);
                }
            }
            y.fill(Complex::new(0.0, 0.0));
            for k in 0..dirs.len() {
                let z =
                    Complex::new(rng.sample::<f64, _>(StandardNormal), rng.sample::<f64, _>(StandardNormal));
                let row = k * m_count..(k + 1) * m_count;
                for ((ym, ph), st) in y.iter_mut().zip(&mut phasor[row.clone()]).zip(&step[row]) {
                    *ym += z * *ph;
                    *ph *= *st;
                }
            }
            for (m, ym) in y.iter().enumerate() {
                spectra[m * bins + f] = *ym;
            }
        }
        let inverse = RealFftPlanner::<f64>::new().plan_fft_inverse(n);
        let mut time = vec![0.0f64; n];
        let mut scratch = inverse.make_scratch_vec();
        let mut planar = vec![0.0f64; m_count * n];
        for (m, chunk) in planar.chunks_exact_mut(n).enumerate() {
            inverse
                .process_with_scratch(&mut spectra[m * bins..(m + 1) * bins], &mut time, &mut scratch)
                .expect("buffer sizes come from the plan");
            chunk.copy_from_slice(&time);
        }
        // One common scale so that the mean power over microphones is std².
        let power = planar.iter().map(|v| v * v).sum::<f64>() / planar.len().max(1) as f64;
        let scale = if power > 0.0 { config.std / power.sqrt() } else { 0.0 };
        let data = planar.iter().map(|v| (v * scale) as f32).collect();
        Ok(DiffuseNoise { channels: m_count, loop_len: n, data, position: 0 })
    }

    /// Number of channels.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Adds the next `out.len() / channels` samples of every channel to the planar
    /// block `out` (channel `m` at `out[m·B .. (m+1)·B]`).
    pub fn add_to(&mut self, out: &mut [f32]) {
        let b = out.len() / self.channels.max(1);
        for (m, ch) in out.chunks_exact_mut(b).enumerate() {
            let src = &self.data[m * self.loop_len..(m + 1) * self.loop_len];
            let mut pos = self.position;
            let mut i = 0;
            while i < b {
                let take = (self.loop_len - pos).min(b - i);
                for (o, s) in ch[i..i + take].iter_mut().zip(&src[pos..pos + take]) {
                    *o += *s;
                }
                i += take;
                pos = (pos + take) % self.loop_len;
            }
        }
        self.position = (self.position + b) % self.loop_len;
    }
}

/// `n` nearly uniform unit vectors (Fibonacci sphere).
pub fn fibonacci_sphere(n: usize) -> Vec<Vector3<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let rho = (1.0 - z * z).sqrt();
            let (s, c) = (golden * i as f64).sin_cos();
            Vector3::new(rho * c, rho * s, z)
        })
        .collect()
}
