//! Small statistics for reports: percentiles, mean/std, time weights.
//!
//! Every function returns `None` when the statistic is undefined (no samples),
//! never NaN, so reports can write `null` or an empty cell.

/// Longest time (s) one estimate stands for in time-weighted ratios.
///
/// A row is weighted by the time to the next row, capped here, so a gap in the
/// estimates (nothing published) does not count as time in (or out of) the band.
pub const TIME_WEIGHT_CAP_S: f64 = 1.0;

/// The `p`-quantile (`p` in 0–1) of `values` by linear interpolation between
/// closest ranks (the common "type 7" definition, NumPy's default): with the
/// values sorted, `h = (n − 1)·p`, result `x[⌊h⌋] + (h − ⌊h⌋)(x[⌊h⌋+1] − x[⌊h⌋])`.
///
/// Non-finite values are ignored. `None` when no finite value is left.
pub fn quantile(values: &[f64], p: f64) -> Option<f64> {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if sorted.is_empty() {
        return None;
    }
    sorted.sort_by(f64::total_cmp);
    let h = (sorted.len() - 1) as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    Some(sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo]))
}

/// Median (0.5-quantile, see [`quantile`]).
pub fn median(values: &[f64]) -> Option<f64> {
    quantile(values, 0.5)
}

/// 95th percentile (see [`quantile`]).
pub fn p95(values: &[f64]) -> Option<f64> {
    quantile(values, 0.95)
}

/// Arithmetic mean of the finite values.
pub fn mean(values: &[f64]) -> Option<f64> {
    let (sum, n) = values.iter().filter(|v| v.is_finite()).fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// Sample standard deviation (divides by `n − 1`) of the finite values;
/// `None` with fewer than two values.
pub fn sample_std(values: &[f64]) -> Option<f64> {
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.len() < 2 {
        return None;
    }
    let m = finite.iter().sum::<f64>() / finite.len() as f64;
    let ss: f64 = finite.iter().map(|v| (v - m) * (v - m)).sum();
    Some((ss / (finite.len() - 1) as f64).sqrt())
}

/// Root mean square of the finite values.
pub fn rms(values: &[f64]) -> Option<f64> {
    let squares: Vec<f64> = values.iter().filter(|v| v.is_finite()).map(|v| v * v).collect();
    mean(&squares).map(f64::sqrt)
}

/// Largest finite value.
pub fn max(values: &[f64]) -> Option<f64> {
    values.iter().copied().filter(|v| v.is_finite()).reduce(f64::max)
}

/// Time each row stands for (s): the time to the next row with a later stamp,
/// capped at [`TIME_WEIGHT_CAP_S`]; the last stamp gets the time to `end_s`
/// (the run's duration), capped the same way. Rows sharing one stamp (several
/// estimates published together) share that time equally. Expects rows in time
/// order; a negative gap counts as 0.
pub fn time_weights(times_s: &[f64], end_s: f64) -> Vec<f64> {
    let n = times_s.len();
    let mut weights = vec![0.0; n];
    let mut start = 0;
    while start < n {
        let stop = (start..n).find(|&j| times_s[j] != times_s[start]).unwrap_or(n);
        let next = if stop < n { times_s[stop] } else { end_s };
        let gap = next - times_s[start];
        let gap = if gap.is_finite() { gap.clamp(0.0, TIME_WEIGHT_CAP_S) } else { 0.0 };
        weights[start..stop].fill(gap / (stop - start) as f64);
        start = stop;
    }
    weights
}

/// Share of the weight whose flag is set: `Σ w·[flag] / Σ w`.
///
/// When the total weight is 0 but there are rows (all at one instant, or a
/// single row at the end of the run) each row weighs 1, so the ratio falls back
/// to a share of rows. `None` without rows.
pub fn weighted_ratio(weights: &[f64], flags: impl IntoIterator<Item = bool>) -> Option<f64> {
    let flags: Vec<bool> = flags.into_iter().take(weights.len()).collect();
    let (hit, total) =
        weights.iter().zip(&flags).fold((0.0, 0.0), |(h, t), (w, f)| (if *f { h + w } else { h }, t + w));
    if total > 0.0 {
        Some(hit / total)
    } else if flags.is_empty() {
        None
    } else {
        Some(flags.iter().filter(|f| **f).count() as f64 / flags.len() as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantile_interpolates_between_ranks() {
        let v = [4.0, 1.0, 3.0, 2.0, 5.0];
        assert_eq!(median(&v), Some(3.0));
        assert_eq!(quantile(&v, 0.0), Some(1.0));
        assert_eq!(quantile(&v, 1.0), Some(5.0));
        // h = 4·0.95 = 3.8 → 4 + 0.8·(5 − 4)
        assert!((p95(&v).unwrap() - 4.8).abs() < 1e-12);
        assert_eq!(median(&[1.0, 2.0]), Some(1.5));
        assert_eq!(median(&[]), None);
        assert_eq!(median(&[f64::NAN]), None);
    }

    #[test]
    fn std_needs_two_values() {
        assert_eq!(sample_std(&[1.0]), None);
        assert!((sample_std(&[1.0, 3.0]).unwrap() - 2f64.sqrt()).abs() < 1e-12);
        assert!((rms(&[3.0, 4.0]).unwrap() - 12.5f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn weights_cap_gaps_and_fall_back_to_counts() {
        let w = time_weights(&[0.0, 0.5, 3.0, 3.2], 3.3);
        let expected = [0.5, 1.0, 0.2, 0.1];
        for (a, b) in w.iter().zip(expected) {
            assert!((a - b).abs() < 1e-12, "{w:?}");
        }
        assert_eq!(time_weights(&[2.0, 2.0], 2.0), vec![0.0, 0.0]);
        // Two rows at 1 s share the 0.5 s to the next stamp.
        assert_eq!(time_weights(&[0.0, 1.0, 1.0, 1.5], 1.5), vec![1.0, 0.25, 0.25, 0.0]);
        assert_eq!(weighted_ratio(&[0.0, 0.0], [true, false]), Some(0.5));
        assert_eq!(weighted_ratio(&[], []), None);
        assert_eq!(weighted_ratio(&[1.0, 3.0], [true, false]), Some(0.25));
    }
}
