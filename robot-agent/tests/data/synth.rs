//! Test-signal synthesis shared by the agent's DSP tests and benchmark
//! (included with `#[path]`): free-field plane waves with exact fractional
//! delays, diffuse noise, moving sources, sensor noise, and error statistics.
//!
//! Conventions: a far-field source in direction `d` (unit vector, array
//! frame) reaches microphone `i` at `pᵢ` earlier by `pᵢ·d/c` than the array
//! origin, so `xᵢ(t) = s(t + pᵢ·d/c)`.
#![allow(dead_code)]

use nalgebra::Vector3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use realfft::RealFftPlanner;
use realfft::num_complex::Complex;
use soundmap_agent::array::{ArrayGeometry, SearchRegion};
use soundmap_agent::pipeline::{FrameResult, Pipeline};
use soundmap_proto::Stamp;

/// Speed of sound used by the synthesis, m/s (the pipeline's default).
pub const C: f64 = 343.0;

/// A seeded generator.
pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// `n` samples of unit-variance white Gaussian noise.
pub fn white(rng: &mut ChaCha8Rng, n: usize) -> Vec<f64> {
    (0..n).map(|_| rng.sample::<f64, _>(StandardNormal)).collect()
}

/// Microphone positions of an array, metres.
pub fn positions(array: &ArrayGeometry) -> Vec<Vector3<f64>> {
    array.positions().map(|p| p.coords).collect()
}

/// Adds plane waves (one independent white source per direction in `dirs`)
/// to per-microphone spectra `acc` (`len/2 + 1` bins each), exact
/// fractional delays, DC and Nyquist left at 0.
fn add_plane_waves(
    acc: &mut [Vec<Complex<f64>>],
    mics: &[Vector3<f64>],
    dirs: &[Vector3<f64>],
    fs: f64,
    rng: &mut ChaCha8Rng,
) {
    let len = (acc[0].len() - 1) * 2;
    let fft = RealFftPlanner::<f64>::new().plan_fft_forward(len);
    let mut spec = fft.make_output_vec();
    for d in dirs {
        let mut s = white(rng, len);
        fft.process(&mut s, &mut spec).unwrap();
        for (m, p) in mics.iter().enumerate() {
            let advance = p.dot(d) / C; // seconds
            // e^{jωₖ·advance} by recursion over k (re-anchored every 1024 bins).
            let dw = 2.0 * std::f64::consts::PI * fs / len as f64 * advance;
            let step = Complex::new(dw.cos(), dw.sin());
            let mut ph = step;
            for k in 1..len / 2 {
                if k % 1024 == 0 {
                    ph = Complex::new((dw * k as f64).cos(), (dw * k as f64).sin());
                }
                acc[m][k] += spec[k] * ph;
                ph *= step;
            }
        }
    }
}

fn spectra_to_signals(acc: Vec<Vec<Complex<f64>>>) -> Vec<Vec<f64>> {
    let len = (acc[0].len() - 1) * 2;
    let ifft = RealFftPlanner::<f64>::new().plan_fft_inverse(len);
    let mut out: Vec<Vec<f64>> = acc
        .into_iter()
        .map(|mut spec| {
            let mut x = vec![0.0; len];
            ifft.process(&mut spec, &mut x).unwrap();
            x
        })
        .collect();
    // Unit power on average over microphones.
    let power: f64 = out.iter().flat_map(|x| x.iter()).map(|v| v * v).sum::<f64>() / (out.len() * len) as f64;
    let g = 1.0 / power.sqrt();
    for x in &mut out {
        x.iter_mut().for_each(|v| *v *= g);
    }
    out
}

/// White-noise plane wave from `d` at every microphone, `len` samples
/// (a power of two; the signal is periodic with period `len`), unit power.
pub fn plane_wave(
    mics: &[Vector3<f64>],
    d: &Vector3<f64>,
    fs: f64,
    len: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<Vec<f64>> {
    let mut acc = vec![vec![Complex::new(0.0, 0.0); len / 2 + 1]; mics.len()];
    add_plane_waves(&mut acc, mics, &[*d], fs, rng);
    spectra_to_signals(acc)
}

/// Spherically isotropic noise approximated by `waves` independent white
/// plane waves from a randomly rotated Fibonacci sphere, unit power.
pub fn diffuse(
    mics: &[Vector3<f64>],
    fs: f64,
    len: usize,
    waves: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<Vec<f64>> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let rot = nalgebra::Rotation3::from_euler_angles(
        rng.random::<f64>() * 6.3,
        rng.random::<f64>() * 6.3,
        rng.random::<f64>() * 6.3,
    );
    let dirs: Vec<Vector3<f64>> = (0..waves)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / waves as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i as f64;
            rot * Vector3::new(r * a.cos(), r * a.sin(), z)
        })
        .collect();
    let mut acc = vec![vec![Complex::new(0.0, 0.0); len / 2 + 1]; mics.len()];
    add_plane_waves(&mut acc, mics, &dirs, fs, rng);
    spectra_to_signals(acc)
}

/// A source moving along `dir_at(t)` (t in seconds), `len` samples: white
/// noise band-limited to 0.45·fs, delayed per sample by windowed-sinc
/// interpolation (64 taps). Unit power.
pub fn moving_source(
    mics: &[Vector3<f64>],
    dir_at: impl Fn(f64) -> Vector3<f64>,
    fs: f64,
    len: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<Vec<f64>> {
    const HALF: isize = 32;
    let pad = 64usize;
    let n = (len + 2 * pad).next_power_of_two();
    // Band-limit the source in the frequency domain (periodic, so indexing wraps).
    let mut s = white(rng, n);
    let planner = &mut RealFftPlanner::<f64>::new();
    let (fwd, inv) = (planner.plan_fft_forward(n), planner.plan_fft_inverse(n));
    let mut spec = fwd.make_output_vec();
    fwd.process(&mut s, &mut spec).unwrap();
    for (k, v) in spec.iter_mut().enumerate() {
        if k as f64 > 0.45 * n as f64 || k == 0 {
            *v = Complex::new(0.0, 0.0);
        }
    }
    inv.process(&mut spec, &mut s).unwrap();
    let pi = std::f64::consts::PI;
    let at = |x: f64| -> f64 {
        let i0 = x.floor() as isize;
        let frac = x - i0 as f64;
        if frac.abs() < 1e-12 {
            return s[i0.rem_euclid(n as isize) as usize];
        }
        // sin(π(x − j)) = ±sin(π·frac); the Hann window by rotation over taps.
        let s_frac = (pi * frac).sin();
        let step = Complex::new((pi / HALF as f64).cos(), (pi / HALF as f64).sin());
        let u0 = x - (i0 - HALF + 1) as f64;
        let mut win = Complex::new((pi * u0 / HALF as f64).cos(), -(pi * u0 / HALF as f64).sin());
        let mut acc = 0.0;
        for j in i0 - HALF + 1..=i0 + HALF {
            let u = x - j as f64;
            let sign = if (i0 - j).rem_euclid(2) == 0 { 1.0 } else { -1.0 };
            acc += s[j.rem_euclid(n as isize) as usize] * (sign * s_frac / (pi * u)) * (0.5 + 0.5 * win.re);
            win *= step;
        }
        acc
    };
    let mut out = vec![vec![0.0; len]; mics.len()];
    for t in 0..len {
        let d = dir_at(t as f64 / fs);
        for (m, p) in mics.iter().enumerate() {
            out[m][t] = at(t as f64 + p.dot(&d) / C * fs);
        }
    }
    let power: f64 =
        out.iter().flat_map(|x| x.iter()).map(|v| v * v).sum::<f64>() / (mics.len() * len) as f64;
    let g = 1.0 / power.sqrt();
    out.iter_mut().for_each(|x| x.iter_mut().for_each(|v| *v *= g));
    out
}

/// Adds independent white sensor noise at `snr_db` below the (unit) signal power.
pub fn add_sensor_noise(x: &mut [Vec<f64>], snr_db: f64, rng: &mut ChaCha8Rng) {
    let sigma = 10f64.powf(-snr_db / 20.0);
    for ch in x.iter_mut() {
        for v in ch.iter_mut() {
            *v += sigma * rng.sample::<f64, _>(StandardNormal);
        }
    }
}

/// Interleaves channels (`s[t*channels + c]`) as f32 scaled by `gain`.
pub fn interleave(x: &[Vec<f64>], gain: f64) -> Vec<f32> {
    let len = x[0].len();
    let mut out = Vec::with_capacity(len * x.len());
    for t in 0..len {
        for ch in x {
            out.push((ch[t] * gain) as f32);
        }
    }
    out
}

/// A direction drawn uniformly in `region`.
pub fn random_direction(region: &SearchRegion, rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
            rng.sample::<f64, _>(StandardNormal),
        );
        if v.norm() < 1e-9 {
            continue;
        }
        let d = v.normalize();
        if region.contains(&d, 0.0) {
            return d;
        }
    }
}

/// Feeds interleaved audio hop by hop (hops stamped from t = 0) and
/// collects every hop's result.
pub fn run(p: &mut Pipeline, interleaved: &[f32]) -> Vec<FrameResult> {
    let block = p.hop_len() * p.channels();
    let fs = p.sample_rate_hz() as f64;
    interleaved
        .chunks_exact(block)
        .enumerate()
        .map(|(h, b)| {
            let stamp = Stamp::ZERO.plus_secs(h as f64 * p.hop_len() as f64 / fs);
            p.process_hop(stamp, b).clone()
        })
        .collect()
}

/// Angle between two directions, degrees.
pub fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    a.angle(b).to_degrees()
}

/// (mean, median, 95th percentile) of `v`.
pub fn stats(v: &[f64]) -> (f64, f64, f64) {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let q = |f: f64| s[((s.len() - 1) as f64 * f).round() as usize];
    (s.iter().sum::<f64>() / s.len() as f64, q(0.5), q(0.95))
}
