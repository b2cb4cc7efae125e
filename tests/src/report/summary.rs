//! `summary.json`: the figures of a run in one object.
//!
//! Conventions:
//! - RSE statistics are over *estimates* (one sample per published estimate
//!   that has a position and a truth), as in the paper; they are not time-weighted.
//!   Quantiles interpolate between closest ranks ([`stats::quantile`]).
//! - Time ratios (`time_in_band_ratio`, `in_band_ratio_after_convergence`) are
//!   time-weighted: each estimate stands for the time to the next one, capped
//!   at [`stats::TIME_WEIGHT_CAP_S`] (1 s), the last one for the time to the
//!   end of the run (same cap); estimates sharing a stamp share its time. A gap
//!   in the estimates therefore counts neither as in-band nor as out-of-band
//!   time. The denominator is `covered_time_s`.
//! - θ is the true θ when known, else the published θ (`theta_source`); the band
//!   is closed, `[theta_band_deg[0], theta_band_deg[1]]`.
//! - "After convergence" means rows with `t_s ≥ time_to_band_s`, the first time
//!   θ was in the band.
//! - `multi_target` scores every true source against every published source
//!   id on a 0.1 s time grid ([`super::multi`] defines the sets and figures);
//!   the figures above stay those of the rows, each scored against its
//!   nearest active true source (source 0 in a single-source run).
//! - Every statistic that is undefined (no rows, no truth, never in band) is
//!   `null`, never NaN.

use serde::Serialize;

use super::derived::{Derived, ThetaSource};
use super::multi::MultiTargetSummary;
use super::record::{RunRecord, SmoothedRow, TimelineRow};
use super::stats;

/// RSE below which the paper calls an estimate good (m).
pub const GOOD_RSE_M: f64 = 0.3;

/// 99th percentile of χ² with 3 degrees of freedom.
pub const CHI2_3DOF_99: f64 = 11.345;

/// Figures of a run, written as `summary.json` (keys are the field names).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Summary {
    /// Scenario name (or "replay").
    pub name: String,
    /// Seed of the run (simulation only).
    pub seed: Option<u64>,
    /// Whether active positioning was on.
    pub active_positioning: bool,
    /// Duration of the run (s).
    pub duration_s: f64,
    /// Robot ids, in the order of the `dK_m` columns.
    pub robot_ids: Vec<String>,
    /// The θ band (degrees, closed).
    pub theta_band_deg: [f64; 2],
    /// Which θ the band statistics use.
    pub theta_source: ThetaSource,
    /// Published estimates (rows).
    pub estimates: usize,
    /// Estimates that carry a position.
    pub estimates_with_position: usize,
    /// Estimates with an RSE (a position and the truth).
    pub estimates_with_rse: usize,
    /// Estimates whose θ is in the band.
    pub estimates_in_band: usize,
    /// Estimates whose θ is out of the band (or NaN).
    pub estimates_out_of_band: usize,
    /// Share of estimates marked trusted.
    pub trusted_ratio: Option<f64>,
    /// Time covered by estimates (s): the sum of the capped row weights.
    pub covered_time_s: f64,
    /// Cap of one row's time weight (s).
    pub time_weight_cap_s: f64,
    /// Share of the covered time with θ in the band.
    pub time_in_band_ratio: Option<f64>,
    /// Mean RSE (m).
    pub rse_mean_m: Option<f64>,
    /// Root mean square RSE (m).
    pub rse_rms_m: Option<f64>,
    /// Sample std of the RSE (m).
    pub rse_std_m: Option<f64>,
    /// Median RSE (m).
    pub rse_median_m: Option<f64>,
    /// 95th percentile of the RSE (m).
    pub rse_p95_m: Option<f64>,
    /// Largest RSE (m).
    pub rse_max_m: Option<f64>,
    /// Share of RSE samples below [`GOOD_RSE_M`] (0.3 m, the paper's figure).
    pub rse_below_0_3_m_ratio: Option<f64>,
    /// Median RSE with θ in the band (m).
    pub rse_median_in_band_m: Option<f64>,
    /// 95th percentile of the RSE with θ in the band (m).
    pub rse_p95_in_band_m: Option<f64>,
    /// Median RSE with θ out of the band (m).
    pub rse_median_out_of_band_m: Option<f64>,
    /// 95th percentile of the RSE with θ out of the band (m).
    pub rse_p95_out_of_band_m: Option<f64>,
    /// Median RSE of trusted estimates (m).
    pub rse_median_trusted_m: Option<f64>,
    /// 95th percentile of the RSE of trusted estimates (m).
    pub rse_p95_trusted_m: Option<f64>,
    /// Mean NEES (eᵀP⁻¹e with the published covariance P) of trusted estimates;
    /// 3 when the published covariance is honest.
    pub nees_mean_trusted: Option<f64>,
    /// Share of trusted estimates whose NEES exceeds χ²₃(0.99) = 11.34 (1 % when honest).
    pub nees_above_chi2_99_trusted_ratio: Option<f64>,
    /// First time θ is in the band (s since the start); `null` if never.
    pub time_to_band_s: Option<f64>,
    /// Share of the covered time in the band from `time_to_band_s` on.
    pub in_band_ratio_after_convergence: Option<f64>,
    /// Median RSE from `time_to_band_s` on (m).
    pub rse_median_after_convergence_m: Option<f64>,
    /// 95th percentile of the RSE from `time_to_band_s` on (m).
    pub rse_p95_after_convergence_m: Option<f64>,
    /// The same figures for the instantaneous triangulation beside a filtered
    /// estimate; `null` when no row has one.
    pub triangulation: Option<TriangulationSummary>,
    /// The tracks' fixed-lag smoothed states published beside the estimates;
    /// `null` when none was.
    pub smoothed: Option<SmoothedSummary>,
    /// Every true source against every published source id over time (OSPA,
    /// detection, ghosts, id switches, per-source RSE; see [`super::multi`]);
    /// `null` without truth.
    pub multi_target: Option<MultiTargetSummary>,
}

/// RSE figures of the triangulation published beside a filtered estimate.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TriangulationSummary {
    /// Rows with a triangulation.
    pub estimates: usize,
    /// Rows with a triangulation RSE.
    pub estimates_with_rse: usize,
    /// Mean RSE (m).
    pub rse_mean_m: Option<f64>,
    /// Median RSE (m).
    pub rse_median_m: Option<f64>,
    /// 95th percentile of the RSE (m).
    pub rse_p95_m: Option<f64>,
    /// 95th percentile with θ in the band (m).
    pub rse_p95_in_band_m: Option<f64>,
    /// 95th percentile with θ out of the band (m).
    pub rse_p95_out_of_band_m: Option<f64>,
}

/// Figures of the smoothed states published beside the estimates. A smoothed
/// state is refreshed every 50 ms of DoA time and repeated with the estimates
/// in between: each distinct (source id, stamp) counts once. "In band" is the
/// true θ at the smoothed state's own stamp.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SmoothedSummary {
    /// Distinct smoothed states.
    pub states: usize,
    /// Those with an RSE (the truth known at their stamp).
    pub states_with_rse: usize,
    /// Mean lag behind the estimate they were published with (s).
    pub lag_mean_s: Option<f64>,
    /// Median RSE (m).
    pub rse_median_m: Option<f64>,
    /// 95th percentile of the RSE (m).
    pub rse_p95_m: Option<f64>,
    /// Median RSE with the true θ in the band (m).
    pub rse_median_in_band_m: Option<f64>,
    /// 95th percentile of the RSE with the true θ in the band (m).
    pub rse_p95_in_band_m: Option<f64>,
    /// Share published trusted.
    pub trusted_ratio: Option<f64>,
    /// Mean NEES of the trusted ones against their published covariance (3 when honest).
    pub nees_mean_trusted: Option<f64>,
    /// Share of the trusted ones with NEES above χ²₃(0.99) = 11.34 (1 % when honest).
    pub nees_above_chi2_99_trusted_ratio: Option<f64>,
    /// Trusted ones at a true θ below 20° (or above 160°) with an RSE over 0.5 m.
    pub trusted_low_theta_over_0_5_m: usize,
    /// The multi-target figures of the smoothed states as a map of sources:
    /// [`MultiTargetSummary`] with each state at its own stamp, scored up to
    /// the run's end minus the longest lag (the last states come after it).
    pub multi_target: Option<MultiTargetSummary>,
}

impl SmoothedSummary {
    /// `None` when no row carries a smoothed state.
    fn new(record: &RunRecord) -> Option<Self> {
        let states = distinct_smoothed_states(record);
        if states.is_empty() {
            return None;
        }
        let (lo, hi) = record.theta_band_deg;
        let rse: Vec<f64> = states.iter().filter_map(|(_, s)| s.rse_m()).collect();
        let in_band: Vec<f64> = states
            .iter()
            .filter(|(_, s)| s.true_theta_deg.is_some_and(|t| (lo..=hi).contains(&t)))
            .filter_map(|(_, s)| s.rse_m())
            .collect();
        let trusted: Vec<&SmoothedRow> = states.iter().map(|(_, s)| *s).filter(|s| s.trusted).collect();
        let nees: Vec<f64> = trusted.iter().filter_map(|s| s.nees()).collect();
        let low_theta_bad = trusted
            .iter()
            .filter(|s| s.true_theta_deg.is_some_and(|t| t.min(180.0 - t) < 20.0))
            .filter(|s| s.rse_m().is_some_and(|e| e > 0.5))
            .count();
        let lags: Vec<f64> = states.iter().map(|(r, s)| r.t_s - s.t_s).collect();
        Some(SmoothedSummary {
            states: states.len(),
            states_with_rse: rse.len(),
            lag_mean_s: stats::mean(&lags),
            rse_median_m: stats::median(&rse),
            rse_p95_m: stats::p95(&rse),
            rse_median_in_band_m: stats::median(&in_band),
            rse_p95_in_band_m: stats::p95(&in_band),
            trusted_ratio: Some(trusted.len() as f64 / states.len() as f64),
            nees_mean_trusted: stats::mean(&nees),
            nees_above_chi2_99_trusted_ratio: share_above(&nees, CHI2_3DOF_99),
            trusted_low_theta_over_0_5_m: low_theta_bad,
            multi_target: MultiTargetSummary::new(&as_record_of_smoothed_states(record, &states)),
        })
    }
}

/// `record` with its rows replaced by `states` (each at its own stamp, in
/// time order) and its duration cut by the longest lag.
fn as_record_of_smoothed_states(record: &RunRecord, states: &[(&TimelineRow, &SmoothedRow)]) -> RunRecord {
    let mut rows: Vec<TimelineRow> = states
        .iter()
        .map(|(r, s)| TimelineRow {
            t_s: s.t_s,
            estimate_in_map: Some(s.estimate_in_map),
            truth_in_map: s.truth_in_map,
            true_theta_deg: s.true_theta_deg,
            covariance: s.covariance,
            trusted: s.trusted,
            smoothed: None,
            ..(*r).clone()
        })
        .collect();
    rows.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    let lag = states.iter().map(|(r, s)| r.t_s - s.t_s).fold(0.0, f64::max);
    RunRecord { rows, duration_s: (record.duration_s - lag).max(0.0), ..record.clone() }
}

/// Share of `values` above `limit`; `None` when empty.
fn share_above(values: &[f64], limit: f64) -> Option<f64> {
    (!values.is_empty()).then(|| values.iter().filter(|v| **v > limit).count() as f64 / values.len() as f64)
}

/// The distinct smoothed states of `record`, each with the first row that
/// carried it: a state is repeated with the estimates published until its
/// next refresh, and counts once per (source id, stamp).
pub fn distinct_smoothed_states(record: &RunRecord) -> Vec<(&TimelineRow, &SmoothedRow)> {
    let mut seen = std::collections::HashSet::new();
    record
        .rows
        .iter()
        .filter_map(|r| Some((r, r.smoothed.as_ref()?)))
        .filter(|(r, s)| seen.insert((r.source_id, s.t_s.to_bits())))
        .collect()
}

/// Values of `values` at the rows where `keep` holds.
fn select(values: &[Option<f64>], keep: impl Fn(usize) -> bool) -> Vec<f64> {
    values.iter().enumerate().filter(|(i, _)| keep(*i)).filter_map(|(_, v)| *v).collect()
}

impl Summary {
    /// Compute the summary of `record` from its derived values.
    pub fn new(record: &RunRecord, d: &Derived) -> Self {
        let rows = &record.rows;
        let n = rows.len();
        let all = select(&d.rse_m, |_| true);
        let in_band = select(&d.rse_m, |i| d.in_band[i]);
        let out_band = select(&d.rse_m, |i| !d.in_band[i]);
        let trusted = select(&d.rse_m, |i| rows[i].trusted);

        let nees_trusted: Vec<f64> = rows.iter().filter(|r| r.trusted).filter_map(|r| r.nees()).collect();

        let first_in_band = d.in_band.iter().position(|b| *b);
        let time_to_band_s = first_in_band.map(|i| rows[i].t_s);
        let (after_ratio, after_rse) = match first_in_band {
            Some(k) => (
                stats::weighted_ratio(&d.weights_s[k..], d.in_band[k..].iter().copied()),
                select(&d.rse_m, |i| i >= k),
            ),
            None => (None, Vec::new()),
        };

        let estimates_in_band = d.in_band.iter().filter(|b| **b).count();
        Summary {
            name: record.name.clone(),
            seed: record.seed,
            active_positioning: record.active_positioning,
            duration_s: record.duration_s,
            robot_ids: record.robot_ids.clone(),
            theta_band_deg: [record.theta_band_deg.0, record.theta_band_deg.1],
            theta_source: d.theta_source,
            estimates: n,
            estimates_with_position: rows.iter().filter(|r| r.estimate_in_map.is_some()).count(),
            estimates_with_rse: all.len(),
            estimates_in_band,
            estimates_out_of_band: n - estimates_in_band,
            trusted_ratio: (n > 0).then(|| rows.iter().filter(|r| r.trusted).count() as f64 / n as f64),
            covered_time_s: d.weights_s.iter().sum(),
            time_weight_cap_s: stats::TIME_WEIGHT_CAP_S,
            time_in_band_ratio: stats::weighted_ratio(&d.weights_s, d.in_band.iter().copied()),
            rse_mean_m: stats::mean(&all),
            rse_rms_m: stats::rms(&all),
            rse_std_m: stats::sample_std(&all),
            rse_median_m: stats::median(&all),
            rse_p95_m: stats::p95(&all),
            rse_max_m: stats::max(&all),
            rse_below_0_3_m_ratio: (!all.is_empty())
                .then(|| all.iter().filter(|v| **v < GOOD_RSE_M).count() as f64 / all.len() as f64),
            rse_median_in_band_m: stats::median(&in_band),
            rse_p95_in_band_m: stats::p95(&in_band),
            rse_median_out_of_band_m: stats::median(&out_band),
            rse_p95_out_of_band_m: stats::p95(&out_band),
            rse_median_trusted_m: stats::median(&trusted),
            rse_p95_trusted_m: stats::p95(&trusted),
            nees_mean_trusted: stats::mean(&nees_trusted),
            nees_above_chi2_99_trusted_ratio: share_above(&nees_trusted, CHI2_3DOF_99),
            time_to_band_s,
            in_band_ratio_after_convergence: after_ratio,
            rse_median_after_convergence_m: stats::median(&after_rse),
            rse_p95_after_convergence_m: stats::p95(&after_rse),
            triangulation: TriangulationSummary::new(record, d),
            smoothed: SmoothedSummary::new(record),
            multi_target: MultiTargetSummary::new(record),
        }
    }

    /// `summary.json` text (pretty-printed, trailing newline).
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"));
        s.push('\n');
        s
    }
}

impl TriangulationSummary {
    /// `None` when no row has a triangulation.
    fn new(record: &RunRecord, d: &Derived) -> Option<Self> {
        let estimates = record.rows.iter().filter(|r| r.triangulation_in_map.is_some()).count();
        if estimates == 0 {
            return None;
        }
        let all = select(&d.tri_rse_m, |_| true);
        let in_band = select(&d.tri_rse_m, |i| d.in_band[i]);
        let out_band = select(&d.tri_rse_m, |i| !d.in_band[i]);
        Some(TriangulationSummary {
            estimates,
            estimates_with_rse: all.len(),
            rse_mean_m: stats::mean(&all),
            rse_median_m: stats::median(&all),
            rse_p95_m: stats::p95(&all),
            rse_p95_in_band_m: stats::p95(&in_band),
            rse_p95_out_of_band_m: stats::p95(&out_band),
        })
    }
}
