//! RSE in 15° bins of θ (`theta_bins.csv`), the paper's "RSE in relation to θ".
//!
//! Bins are `[0, 15)`, `[15, 30)`, … `[165, 180]` (the last one closed, so θ =
//! 180° counts). θ is the true θ when the row has one, else the published θ
//! (column `theta_source`: `true`, `published` or `mixed`, see
//! [`ThetaSource`]); rows whose θ is NaN or outside 0–180° are left out.
//!
//! Columns of `theta_bins.csv`:
//! `theta_lo_deg, theta_hi_deg, theta_mid_deg, theta_source, estimates,
//! rse_count, rse_mean_m, rse_std_m, tri_rse_count, tri_rse_mean_m, tri_rse_std_m`.
//! `estimates` counts the rows in the bin; `rse_count` those with an RSE (an
//! estimate position and the truth). The std is the sample std (n − 1), empty
//! below two samples; the mean is empty without samples. The `tri_*` columns are
//! the same for the triangulation beside a filtered estimate (empty when the
//! record has none).

use std::fmt::Write as _;

use serde::Serialize;

use super::csv::{num, opt};
use super::derived::{Derived, ThetaSource};
use super::stats;

/// Width of a θ bin (degrees).
pub const BIN_WIDTH_DEG: f64 = 15.0;
/// Number of bins over 0–180°.
pub const BIN_COUNT: usize = 12;

/// One bin of θ.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ThetaBin {
    /// Lower edge (degrees, inclusive).
    pub theta_lo_deg: f64,
    /// Upper edge (degrees; exclusive except for the last bin).
    pub theta_hi_deg: f64,
    /// Rows whose θ falls in the bin.
    pub estimates: usize,
    /// Rows with an RSE among them.
    pub rse_count: usize,
    /// Mean RSE (m).
    pub rse_mean_m: Option<f64>,
    /// Sample std of the RSE (m).
    pub rse_std_m: Option<f64>,
    /// Rows with a triangulation RSE.
    pub tri_rse_count: usize,
    /// Mean triangulation RSE (m).
    pub tri_rse_mean_m: Option<f64>,
    /// Sample std of the triangulation RSE (m).
    pub tri_rse_std_m: Option<f64>,
}

impl ThetaBin {
    /// Centre of the bin (degrees).
    pub fn theta_mid_deg(&self) -> f64 {
        0.5 * (self.theta_lo_deg + self.theta_hi_deg)
    }
}

/// Index of the bin holding `theta_deg`, `None` when NaN or outside 0–180°.
pub fn bin_index(theta_deg: f64) -> Option<usize> {
    if !(0.0..=180.0).contains(&theta_deg) {
        return None;
    }
    Some(((theta_deg / BIN_WIDTH_DEG) as usize).min(BIN_COUNT - 1))
}

/// The twelve bins of a record's derived values (see [`Derived`]).
pub fn theta_bins(derived: &Derived) -> Vec<ThetaBin> {
    let mut rows: Vec<usize> = vec![0; BIN_COUNT];
    let mut rse: Vec<Vec<f64>> = vec![Vec::new(); BIN_COUNT];
    let mut tri: Vec<Vec<f64>> = vec![Vec::new(); BIN_COUNT];
    for (i, theta) in derived.theta_deg.iter().enumerate() {
        let Some(b) = bin_index(*theta) else { continue };
        rows[b] += 1;
        if let Some(v) = derived.rse_m[i] {
            rse[b].push(v);
        }
        if let Some(v) = derived.tri_rse_m[i] {
            tri[b].push(v);
        }
    }
    (0..BIN_COUNT)
        .map(|b| ThetaBin {
            theta_lo_deg: b as f64 * BIN_WIDTH_DEG,
            theta_hi_deg: (b + 1) as f64 * BIN_WIDTH_DEG,
            estimates: rows[b],
            rse_count: rse[b].len(),
            rse_mean_m: stats::mean(&rse[b]),
            rse_std_m: stats::sample_std(&rse[b]),
            tri_rse_count: tri[b].len(),
            tri_rse_mean_m: stats::mean(&tri[b]),
            tri_rse_std_m: stats::sample_std(&tri[b]),
        })
        .collect()
}

/// Header of `theta_bins.csv`.
pub const BINS_HEADER: &str = "theta_lo_deg,theta_hi_deg,theta_mid_deg,theta_source,estimates,\
rse_count,rse_mean_m,rse_std_m,tri_rse_count,tri_rse_mean_m,tri_rse_std_m";

/// `theta_bins.csv` as text.
pub fn bins_csv(bins: &[ThetaBin], source: ThetaSource) -> String {
    let mut out = String::from(BINS_HEADER);
    out.push('\n');
    for b in bins {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{}",
            num(b.theta_lo_deg),
            num(b.theta_hi_deg),
            num(b.theta_mid_deg()),
            source.as_str(),
            b.estimates,
            b.rse_count,
            opt(b.rse_mean_m),
            opt(b.rse_std_m),
            b.tri_rse_count,
            opt(b.tri_rse_mean_m),
            opt(b.tri_rse_std_m),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bin_edges() {
        assert_eq!(bin_index(0.0), Some(0));
        assert_eq!(bin_index(14.999), Some(0));
        assert_eq!(bin_index(15.0), Some(1));
        assert_eq!(bin_index(179.0), Some(11));
        assert_eq!(bin_index(180.0), Some(11));
        assert_eq!(bin_index(180.1), None);
        assert_eq!(bin_index(-1.0), None);
        assert_eq!(bin_index(f64::NAN), None);
    }
}
