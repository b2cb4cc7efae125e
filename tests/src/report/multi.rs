//! Multi-target figures: every true source against every published source id,
//! over time (`multi_target` in `summary.json`).
//!
//! The coordinator publishes estimates one by one, each carrying its
//! `source_id` (0 when no live track follows it). To compare *sets*, time is
//! cut into steps of [`STEP_S`] (0.1 s) from `STEP_S` to the end of the run,
//! and at each step `t`:
//!
//! - the **estimate set** holds, for each published `source_id` (0 counts as
//!   one more id), its latest estimate with a position stamped in
//!   `(t − WINDOW_S, t]` ([`WINDOW_S`] = 1 s, long enough to bridge a talker's
//!   pauses, short enough that a lost source leaves the set within a second);
//! - the **truth set** holds the position at `t` of every source *active* in
//!   the same window `(t − WINDOW_S, t]` (its `active` intervals; a source
//!   without intervals is always active). Both sets describe the same second:
//!   an estimate published while its source played is no ghost, and no missed
//!   source, in the second after the source stops (with the truth taken at
//!   `t` alone, every source that stops counted as a ghost for up to a second,
//!   `cocktail`'s two stops and the run's last step about 0.06 ghosts/s of
//!   correct estimates).
//!
//! Figures (steps where both sets are empty are not scored):
//!
//! - **OSPA** (Schuhmacher, Vo & Vo 2008) with cut-off `c` = [`OSPA_CUTOFF_M`]
//!   (1 m) and order `p` = 1: for truths X (m of them) and estimates Y (n),
//!   with m ≤ n (else swap), `d = ((min_π Σᵢ min(c, ‖xᵢ − y_π(i)‖)ᵖ + cᵖ (n − m)) / n)^(1/p)`;
//!   0 when both are empty, `c` when exactly one is. It mixes localisation error
//!   (≤ c per pair) and cardinality error (c per missed or extra estimate) into
//!   one number in [0, c]. `ospa_mean_m` and `ospa_p95_m` are over scored steps.
//!   Worked example (the unit test): X = {(0,0,0), (3,0,0)}, Y = {(0.3,0,0),
//!   (3,0.4,0), (10,0,0)}: best pairs 0.3 m and 0.4 m, one extra estimate,
//!   d = (0.3 + 0.4 + 1) / 3 = 0.5667 m.
//! - **detection ratio**: share of (step, source active *at* `t`) pairs with
//!   an estimate of the set within [`DETECTION_RADIUS_M`] (0.5 m), any id.
//! - **ghosts**: estimates of the set farther than [`GHOST_DISTANCE_M`] (1 m)
//!   from every source of the truth set (all of them when it is empty).
//!   `ghosts_per_s` is ghost estimate-seconds per second: the mean number of
//!   ghosts present over the scored steps; `ghost_ratio` is the share of the
//!   estimates in the sets that are ghosts.
//! - **id switches**: each step, estimates and active sources are paired by an
//!   optimal assignment ([`assignment`], Hungarian) on distance, a pair kept
//!   only when closer than `c`. A source's id switches when the id paired with
//!   it differs from the last id paired with it (an unpaired step in between
//!   is no switch; the first pairing is none).
//! - **per source**: active time, detection ratio, id switches, the ids it was
//!   paired with (in order of first pairing), and the RSE median/p95 of the
//!   timeline rows scored against it (each row is scored against the *nearest
//!   active* true source at its stamp, `truth_source` in `timeline.csv`).

use nalgebra::Point3;
use serde::Serialize;

use super::record::{RunRecord, SourceTruth};
use super::stats;

/// Time step of the set figures (s).
pub const STEP_S: f64 = 0.1;
/// How far back an id's latest estimate still counts at a step (s).
pub const WINDOW_S: f64 = 1.0;
/// OSPA cut-off `c` (m).
pub const OSPA_CUTOFF_M: f64 = 1.0;
/// OSPA order `p`.
pub const OSPA_ORDER: f64 = 1.0;
/// An active source is detected at a step when an estimate is this close (m).
pub const DETECTION_RADIUS_M: f64 = 0.5;
/// An estimate farther than this from every source of the truth set is a ghost (m).
pub const GHOST_DISTANCE_M: f64 = 1.0;

/// The `multi_target` object of `summary.json` (conventions in the module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MultiTargetSummary {
    /// [`STEP_S`].
    pub step_s: f64,
    /// [`WINDOW_S`].
    pub window_s: f64,
    /// [`OSPA_CUTOFF_M`].
    pub ospa_cutoff_m: f64,
    /// [`OSPA_ORDER`].
    pub ospa_order: f64,
    /// True sources in the record.
    pub true_sources: usize,
    /// Distinct `source_id`s published (0 included when published).
    pub published_ids: usize,
    /// Steps scored (a truth or an estimate present).
    pub steps: usize,
    /// Mean OSPA over the scored steps (m).
    pub ospa_mean_m: Option<f64>,
    /// 95th percentile of the OSPA over the scored steps (m).
    pub ospa_p95_m: Option<f64>,
    /// Share of active source-steps with an estimate within [`DETECTION_RADIUS_M`].
    pub detection_ratio: Option<f64>,
    /// Mean number of ghost estimates present (ghost estimate-seconds per second).
    pub ghosts_per_s: Option<f64>,
    /// Share of the estimates in the sets that are ghosts.
    pub ghost_ratio: Option<f64>,
    /// Id switches summed over the sources.
    pub id_switches: usize,
    /// Per true source, in record order.
    pub sources: Vec<SourceFigures>,
}

/// Figures of one true source.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SourceFigures {
    /// Index of the source (its order in the scenario / the `--truth` arguments).
    pub index: usize,
    /// Time it was active, over the scored range (s).
    pub active_s: f64,
    /// Share of its active steps with an estimate within [`DETECTION_RADIUS_M`].
    pub detection_ratio: Option<f64>,
    /// Times the id paired with it changed.
    pub id_switches: usize,
    /// Ids it was paired with, in order of first pairing.
    pub ids: Vec<u64>,
    /// Timeline rows scored against it.
    pub estimates: usize,
    /// Median RSE of those rows (m).
    pub rse_median_m: Option<f64>,
    /// 95th percentile RSE of those rows (m).
    pub rse_p95_m: Option<f64>,
}

/// Optimal assignment minimizing the summed cost: `result[i]` is the column
/// given to row `i` (`None` for rows left over when there are more rows than
/// columns). The coordinator's Hungarian method
/// ([`soundmap_server::planner::assignment::assign_rect`]).
pub fn assignment(cost: &[Vec<f64>]) -> Vec<Option<usize>> {
    soundmap_server::planner::assignment::assign_rect(cost)
}

/// OSPA distance between `truths` and `estimates` with cut-off `c` (m) and order `p`.
pub fn ospa(truths: &[Point3<f64>], estimates: &[Point3<f64>], c: f64, p: f64) -> f64 {
    let (small, large) =
        if truths.len() <= estimates.len() { (truths, estimates) } else { (estimates, truths) };
    let (m, n) = (small.len(), large.len());
    if n == 0 {
        return 0.0;
    }
    let cost: Vec<Vec<f64>> =
        small.iter().map(|x| large.iter().map(|y| (x - y).norm().min(c).powf(p)).collect()).collect();
    let paired: f64 = assignment(&cost).iter().enumerate().filter_map(|(i, j)| j.map(|j| cost[i][j])).sum();
    ((paired + c.powf(p) * (n - m) as f64) / n as f64).powf(1.0 / p)
}

/// The estimate set at `t_s`: per `source_id`, the latest positioned row in
/// `(t_s − window_s, t_s]`, as `(id, position)` sorted by id.
pub fn estimate_set(record: &RunRecord, t_s: f64, window_s: f64) -> Vec<(u64, Point3<f64>)> {
    let rows = &record.rows;
    let end = rows.partition_point(|r| r.t_s <= t_s);
    let start = rows[..end].partition_point(|r| r.t_s <= t_s - window_s);
    let mut set: Vec<(u64, Point3<f64>)> = Vec::new();
    for r in rows[start..end].iter().rev() {
        if let Some(p) = r.estimate_in_map.filter(|p| p.coords.iter().all(|v| v.is_finite()))
            && !set.iter().any(|(id, _)| *id == r.source_id)
        {
            set.push((r.source_id, p));
        }
    }
    set.sort_by_key(|(id, _)| *id);
    set
}

impl MultiTargetSummary {
    /// The figures of `record`; `None` without any true source.
    pub fn new(record: &RunRecord) -> Option<Self> {
        let truths = &record.sources;
        if truths.is_empty() {
            return None;
        }
        let k = truths.len();
        let steps = (record.duration_s / STEP_S + 1e-9).floor() as usize;
        let mut ospas = Vec::new();
        let (mut detected, mut active_steps) = (vec![0usize; k], vec![0usize; k]);
        let (mut ghosts, mut estimates_seen) = (0usize, 0usize);
        let mut last_id: Vec<Option<u64>> = vec![None; k];
        let mut switches = vec![0usize; k];
        let mut ids: Vec<Vec<u64>> = vec![Vec::new(); k];
        for s in 1..=steps {
            let t = s as f64 * STEP_S;
            let set = estimate_set(record, t, WINDOW_S);
            // The truth set spans the estimate set's window (see the module docs).
            let active: Vec<(usize, Point3<f64>)> = truths
                .iter()
                .enumerate()
                .filter(|(_, x)| x.active_within(t - WINDOW_S, t))
                .filter_map(|(i, x)| Some((i, x.position_at(t)?)))
                .collect();
            if set.is_empty() && active.is_empty() {
                continue;
            }
            let xs: Vec<Point3<f64>> = active.iter().map(|(_, p)| *p).collect();
            let ys: Vec<Point3<f64>> = set.iter().map(|(_, p)| *p).collect();
            ospas.push(ospa(&xs, &ys, OSPA_CUTOFF_M, OSPA_ORDER));
            for (i, x) in active.iter().filter(|(i, _)| truths[*i].active_at(t)) {
                active_steps[*i] += 1;
                detected[*i] += usize::from(ys.iter().any(|y| (x - y).norm() <= DETECTION_RADIUS_M));
            }
            estimates_seen += ys.len();
            ghosts += ys.iter().filter(|y| xs.iter().all(|x| (*x - **y).norm() > GHOST_DISTANCE_M)).count();
            let cost: Vec<Vec<f64>> =
                xs.iter().map(|x| ys.iter().map(|y| (x - y).norm().min(OSPA_CUTOFF_M)).collect()).collect();
            for (a, j) in assignment(&cost).into_iter().enumerate() {
                let Some(j) = j.filter(|j| cost[a][*j] < OSPA_CUTOFF_M) else { continue };
                let (i, id) = (active[a].0, set[j].0);
                if last_id[i].is_some_and(|last| last != id) {
                    switches[i] += 1;
                }
                last_id[i] = Some(id);
                if !ids[i].contains(&id) {
                    ids[i].push(id);
                }
            }
        }
        let mut published: Vec<u64> = record.rows.iter().map(|r| r.source_id).collect();
        published.sort_unstable();
        published.dedup();
        let ratio = |a: usize, b: usize| (b > 0).then(|| a as f64 / b as f64);
        let sources = (0..k)
            .map(|i| {
                let rse: Vec<f64> = record
                    .rows
                    .iter()
                    .filter(|r| r.truth_source == Some(i))
                    .filter_map(|r| r.rse_m().filter(|v| v.is_finite()))
                    .collect();
                SourceFigures {
                    index: i,
                    active_s: active_steps[i] as f64 * STEP_S,
                    detection_ratio: ratio(detected[i], active_steps[i]),
                    id_switches: switches[i],
                    ids: ids[i].clone(),
                    estimates: record.rows.iter().filter(|r| r.truth_source == Some(i)).count(),
                    rse_median_m: stats::median(&rse),
                    rse_p95_m: stats::p95(&rse),
                }
            })
            .collect();
        Some(MultiTargetSummary {
            step_s: STEP_S,
            window_s: WINDOW_S,
            ospa_cutoff_m: OSPA_CUTOFF_M,
            ospa_order: OSPA_ORDER,
            true_sources: k,
            published_ids: published.len(),
            steps: ospas.len(),
            ospa_mean_m: stats::mean(&ospas),
            ospa_p95_m: stats::p95(&ospas),
            detection_ratio: ratio(detected.iter().sum(), active_steps.iter().sum()),
            ghosts_per_s: ratio(ghosts, ospas.len()),
            ghost_ratio: ratio(ghosts, estimates_seen),
            id_switches: switches.iter().sum(),
            sources,
        })
    }
}

/// The index of the true source nearest to `estimate` among those active at
/// `t_s`; without an estimate position, the first active one; with none
/// active, the nearest (or first) of all. `None` without sources.
pub fn nearest_truth(sources: &[SourceTruth], t_s: f64, estimate: Option<Point3<f64>>) -> Option<usize> {
    nearest_truth_among(sources, &(0..sources.len()).collect::<Vec<_>>(), t_s, estimate)
}

/// [`nearest_truth`] among the sources `usable` (indices into `sources`).
pub fn nearest_truth_among(
    sources: &[SourceTruth],
    usable: &[usize],
    t_s: f64,
    estimate: Option<Point3<f64>>,
) -> Option<usize> {
    let pick = |candidates: &[usize]| -> Option<usize> {
        let first = *candidates.first()?;
        let Some(e) = estimate else { return Some(first) };
        candidates
            .iter()
            .copied()
            .filter_map(|i| Some((i, (sources[i].position_at(t_s)? - e).norm())))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i)
            .or(Some(first))
    };
    let active: Vec<usize> = usable.iter().copied().filter(|i| sources[*i].active_at(t_s)).collect();
    if active.is_empty() { pick(usable) } else { pick(&active) }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute_force(cost: &[Vec<f64>]) -> f64 {
        // Rows ≤ cols: every injective map of rows into columns.
        fn go(cost: &[Vec<f64>], i: usize, used: &mut Vec<bool>) -> f64 {
            if i == cost.len() {
                return 0.0;
            }
            let mut best = f64::INFINITY;
            for j in 0..used.len() {
                if !used[j] {
                    used[j] = true;
                    best = best.min(cost[i][j] + go(cost, i + 1, used));
                    used[j] = false;
                }
            }
            best
        }
        go(cost, 0, &mut vec![false; cost[0].len()])
    }

    #[test]
    fn hungarian_matches_brute_force() {
        let mut state: u64 = 12345;
        let mut rnd = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for trial in 0..300 {
            let rows = 1 + trial % 5;
            let cols = rows + (trial / 5) % 3;
            let cost: Vec<Vec<f64>> =
                (0..rows).map(|_| (0..cols).map(|_| (rnd() * 10.0).round()).collect()).collect();
            let a = assignment(&cost);
            let total: f64 = a.iter().enumerate().map(|(i, j)| cost[i][j.unwrap()]).sum();
            assert!((total - brute_force(&cost)).abs() < 1e-9, "{cost:?}: {a:?}");
            let mut cols_used: Vec<usize> = a.iter().map(|j| j.unwrap()).collect();
            cols_used.sort_unstable();
            cols_used.dedup();
            assert_eq!(cols_used.len(), rows, "a column given twice");
            // The transposed problem leaves cols − rows rows unassigned, same total.
            let t: Vec<Vec<f64>> = (0..cols).map(|j| (0..rows).map(|i| cost[i][j]).collect()).collect();
            let b = assignment(&t);
            assert_eq!(b.iter().filter(|j| j.is_none()).count(), cols - rows);
            let total_t: f64 = b.iter().enumerate().filter_map(|(i, j)| j.map(|j| t[i][j])).sum();
            assert!((total_t - total).abs() < 1e-9);
        }
        // Hand case: the greedy choice (0→0, cost 1) is not optimal.
        let cost = vec![vec![1.0, 2.0], vec![1.0, 10.0]];
        assert_eq!(assignment(&cost), vec![Some(1), Some(0)]);
    }

    #[test]
    fn ospa_worked_examples() {
        let p = |x: f64, y: f64| Point3::new(x, y, 0.0);
        // The module docs' example: (0.3 + 0.4 + 1) / 3.
        let d = ospa(&[p(0.0, 0.0), p(3.0, 0.0)], &[p(0.3, 0.0), p(3.0, 0.4), p(10.0, 0.0)], 1.0, 1.0);
        assert!((d - 1.7 / 3.0).abs() < 1e-12, "{d}");
        // Symmetric in its arguments.
        let e = ospa(&[p(0.3, 0.0), p(3.0, 0.4), p(10.0, 0.0)], &[p(0.0, 0.0), p(3.0, 0.0)], 1.0, 1.0);
        assert!((d - e).abs() < 1e-12);
        assert_eq!(ospa(&[], &[], 1.0, 1.0), 0.0);
        assert_eq!(ospa(&[p(0.0, 0.0)], &[], 1.0, 1.0), 1.0);
        assert_eq!(ospa(&[], &[p(0.0, 0.0), p(1.0, 1.0)], 1.0, 1.0), 1.0);
        // A far pair is cut at c: one truth, one estimate 5 m away → 1.
        assert_eq!(ospa(&[p(0.0, 0.0)], &[p(5.0, 0.0)], 1.0, 1.0), 1.0);
        // Order 2: pairs 0.3 and 0.4 → sqrt((0.09 + 0.16) / 2).
        let d2 = ospa(&[p(0.0, 0.0), p(3.0, 0.0)], &[p(0.3, 0.0), p(3.0, 0.4)], 1.0, 2.0);
        assert!((d2 - (0.125f64).sqrt()).abs() < 1e-12);
        // Assignment, not nearest neighbour: both truths near estimate A.
        let d3 = ospa(&[p(0.0, 0.0), p(0.2, 0.0)], &[p(0.1, 0.0), p(0.9, 0.0)], 1.0, 1.0);
        assert!((d3 - (0.1 + 0.7) / 2.0).abs() < 1e-12, "{d3}");
    }

    #[test]
    fn nearest_active_truth() {
        let s = |x: f64, active: Vec<(f64, f64)>| SourceTruth {
            path: vec![(0.0, Point3::new(x, 0.0, 1.0))],
            active,
        };
        let sources = vec![s(0.0, vec![(0.0, 5.0)]), s(2.0, vec![(3.0, 10.0)])];
        let near_b = Some(Point3::new(1.9, 0.0, 1.0));
        assert_eq!(nearest_truth(&sources, 1.0, near_b), Some(0), "only source 0 is active");
        assert_eq!(nearest_truth(&sources, 4.0, near_b), Some(1));
        assert_eq!(nearest_truth(&sources, 6.0, None), Some(1));
        assert_eq!(nearest_truth(&sources, 20.0, near_b), Some(1), "none active: nearest of all");
        assert_eq!(nearest_truth(&[], 1.0, near_b), None);
    }

    /// A source plays until 5 s and is published at its place until 4.95 s:
    /// that last estimate, still in the window after 5 s, is no ghost (and
    /// no missed source); one published 1.5 s after it stopped is a ghost.
    #[test]
    fn an_estimate_of_a_source_that_just_stopped_is_no_ghost() {
        let at = Point3::new(1.0, 2.0, 1.2);
        let row = |t_s: f64| crate::report::record::TimelineRow {
            t_s,
            distances_m: vec![],
            theta_deg: 90.0,
            true_theta_deg: None,
            gdop: 1.0,
            estimate_in_map: Some(at),
            triangulation_in_map: None,
            trusted: true,
            method: "kalman_filter".into(),
            robots: vec![],
            truth_in_map: None,
            covariance: None,
            source_id: 1,
            truth_source: Some(0),
            smoothed: None,
        };
        let record = |rows: Vec<crate::report::record::TimelineRow>| RunRecord {
            name: "t".into(),
            duration_s: 8.0,
            active_positioning: false,
            theta_band_deg: (40.0, 140.0),
            rows,
            robot_ids: vec![],
            robots: vec![],
            sources: vec![SourceTruth { path: vec![(0.0, at)], active: vec![(0.0, 5.0)] }],
            room: None,
            seed: None,
            commands: vec![],
        };
        let until_stop: Vec<_> = (1..100).map(|k| row(k as f64 * 0.05)).collect();
        let m = MultiTargetSummary::new(&record(until_stop.clone())).unwrap();
        assert_eq!(m.ghosts_per_s, Some(0.0), "{m:?}");
        assert!(m.ospa_mean_m.unwrap() < 1e-9, "{m:?}");
        assert_eq!(m.detection_ratio, Some(1.0));
        let mut late = until_stop;
        late.push(row(6.5));
        let m = MultiTargetSummary::new(&record(late)).unwrap();
        // A ghost in the 10 steps from 6.5 s to 7.4 s, of the steps scored.
        assert!((m.ghosts_per_s.unwrap() * m.steps as f64 - 10.0).abs() < 1e-9, "{m:?}");
    }
}
