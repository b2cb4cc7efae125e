//! Measurements on simulated signals: energy decay and RT60 (Schroeder),
//! levels, and spatial coherence. Used by the tests and by reports.

use realfft::RealFftPlanner;
use realfft::num_complex::Complex;

/// Reverberation times measured on one impulse response.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecayFit {
    /// T20: the −5 … −25 dB range of the Schroeder curve, extrapolated to 60 dB (s).
    pub t20_s: f64,
    /// T30: the −5 … −35 dB range, extrapolated to 60 dB (s).
    pub t30_s: f64,
}

/// Schroeder backward-integrated energy decay curve in dB (0 dB at sample 0).
pub fn schroeder_decay_db(h: &[f64]) -> Vec<f64> {
    let mut acc = 0.0;
    let mut edc: Vec<f64> = h
        .iter()
        .rev()
        .map(|v| {
            acc += v * v;
            acc
        })
        .collect();
    edc.reverse();
    let total = edc.first().copied().unwrap_or(0.0).max(f64::MIN_POSITIVE);
    edc.iter().map(|e| 10.0 * (e.max(f64::MIN_POSITIVE) / total).log10()).collect()
}

/// T20 and T30 of an impulse response sampled at `sample_rate_hz`, by a
/// least-squares line through the Schroeder curve between −5 dB and −25/−35 dB.
/// `None` when the curve does not reach the lower bound.
pub fn measure_rt60(h: &[f64], sample_rate_hz: f64) -> Option<DecayFit> {
    let edc = schroeder_decay_db(h);
    let fit = |lo_db: f64| -> Option<f64> {
        let start = edc.iter().position(|d| *d <= -5.0)?;
        let end = edc.iter().position(|d| *d <= lo_db)?;
        if end <= start + 2 {
            return None;
        }
        let (mut st, mut sd, mut stt, mut std_, n) = (0.0, 0.0, 0.0, 0.0, (end - start) as f64);
        for (i, d) in edc[start..end].iter().enumerate() {
            let t = (start + i) as f64 / sample_rate_hz;
            st += t;
            sd += d;
            stt += t * t;
            std_ += t * d;
        }
        let slope = (n * std_ - st * sd) / (n * stt - st * st);
        (slope < 0.0).then(|| -60.0 / slope)
    };
    Some(DecayFit { t20_s: fit(-25.0)?, t30_s: fit(-35.0)? })
}

/// Root mean square.
pub fn rms(x: &[f32]) -> f64 {
    (x.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / x.len().max(1) as f64).sqrt()
}

/// Welch estimate of the complex coherence `S_ab / √(S_aa·S_bb)` between two
/// signals, Hann windows of `fft_len` samples with 50 % overlap. Element `i` is
/// the bin at `i·fs/fft_len` Hz, `i = 0 ..= fft_len/2`.
pub fn coherence(a: &[f32], b: &[f32], fft_len: usize) -> Vec<Complex<f64>> {
    let fft = RealFftPlanner::<f64>::new().plan_fft_forward(fft_len);
    let bins = fft_len / 2 + 1;
    let window: Vec<f64> = (0..fft_len)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / fft_len as f64).cos())
        .collect();
    let (mut saa, mut sbb) = (vec![0.0; bins], vec![0.0; bins]);
    let mut sab = vec![Complex::new(0.0, 0.0); bins];
    let mut ta = fft.make_input_vec();
    let mut tb = fft.make_input_vec();
    let mut fa = fft.make_output_vec();
    let mut fb = fft.make_output_vec();
    let len = a.len().min(b.len());
    let mut start = 0;
    while start + fft_len <= len {
        for i in 0..fft_len {
            ta[i] = a[start + i] as f64 * window[i];
            tb[i] = b[start + i] as f64 * window[i];
        }
        fft.process(&mut ta, &mut fa).expect("sizes from the plan");
        fft.process(&mut tb, &mut fb).expect("sizes from the plan");
        for k in 0..bins {
            saa[k] += fa[k].norm_sqr();
            sbb[k] += fb[k].norm_sqr();
            sab[k] += fa[k] * fb[k].conj();
        }
        start += fft_len / 2;
    }
    (0..bins).map(|k| sab[k] / (saa[k] * sbb[k]).sqrt().max(f64::MIN_POSITIVE)).collect()
}
