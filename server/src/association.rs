//! Data association for several sources: which rays belong to which source.
//! Pure functions; the [sound map](crate::coordinator::sound_map) uses them.
//!
//! **Rays to known sources (global nearest neighbour).** The rays of one
//! observation (one robot, one stamp: up to K tracked DoAs) are assigned to the
//! live sources jointly, by the minimum-cost assignment ([`assign`], the
//! Hungarian method) over the cost
//!
//! `c(i, j) = NIS(ray i, source j) + prior(i, j)`,
//!
//! with NIS the normalized innovation squared of the ray against source j's
//! filter predicted to the ray's stamp (χ², 2 dof), pairs with NIS above the
//! gate γ (χ²₂ quantile of `tracking.association_probability`, 9.21 at 0.99)
//! forbidden, and every ray free to stay unassigned at cost γ. The prior holds
//! associations over time: a robot's DoA track keeps its identity on board, so
//! a ray of robot-local track k that fed source j last time costs γ/2 less
//! for j and γ/2 more for any other source. Worked numbers: a ray with NIS
//! 1.2 to its own source and 0.9 to another costs 1.2 − 4.6 = −3.4 against
//! 0.9 + 4.6 = 5.5: it stays with its source unless it leaves its gate.
//!
//! **One track per robot per source.** A robot's tracker holds one track per
//! source it hears, so while a robot's track k fed source j within the last
//! 0.3 s, a track of the same robot that no source has claimed costs γ/2 more
//! for j, as a track labelled elsewhere does. Talkers pause between words, and
//! agents leave a track out of the observations in which it is not active: in
//! such a round the robot's other tracks (another talker, a reflection) would
//! otherwise be free to take source j on NIS alone, near the edge of its gate,
//! be labelled with it, and drag it away. Worked numbers (`cocktail` seed 7,
//! 27.3 s): the ReSpeaker's track of talker 1 is missing from one observation;
//! its other track, NIS 6.0 against talker 1's source (within γ = 9.21),
//! took the source, and within 0.5 s the TurtleBot's track of talker 0
//! (NIS 7.8) joined it: the source moved 1 m to where those two rays meet.
//! With the rule both cost 6.0 + 4.6 and 7.8 + 4.6, beyond γ: they stay
//! unassigned (a new track of a source whose old track ended takes it over
//! 0.3 s later, or through a birth).
//!
//! **Silent sources.** Talkers pause, and a source not heard for a while
//! (0.5 s) is predicted with a covariance that grows with the silence (its
//! filter allows it to walk away). A robot-local track no source has claimed
//! yet is then as likely a new source as the silent one resuming, and one
//! robot's bearing cannot tell them apart: the grown covariance lets almost
//! any bearing near the silent source through. So an unclaimed track is never
//! given to a silent source by its NIS; it goes to births, and a birth —
//! two robots' rays that meet in 3D — within `sources.reuse_radius_m` of the
//! silent source's place resumes it with its id (the sound map's rule). Its
//! place is where it was last *trusted*, not where one robot's rays may have
//! dragged its filter before it fell silent. Worked numbers: a seated talker
//! stops; 1.2 s later a second talker 1.6 m away speaks on, 34° away as one
//! robot sees them at 2.9 m. The silent source's horizontal σ has grown to
//! ≈ 0.8 m (q̃ = 0.5 m²/s³, 1.2 s, plus its velocity's uncertainty), so that
//! robot's new track has NIS ≈ 4.5 against it — inside the gate γ = 9.21
//! even with a γ/2 penalty. Given to it, it would drag the silent source onto
//! the other talker and take its id there. Through a birth, the new talker's
//! two-robot triangulation is 1.6 m from the silent source's place, beyond
//! the 1 m reuse radius: it gets a new id, and the first talker resuming in
//! place later takes back its own. A track that kept its robot-local id
//! through the pause (the agent coasts tracks over short gaps) is still
//! labelled, and resumes its source directly.
//!
//! **New sources (births).** Rays no source claims (by label) or explains
//! (within the gate of a live, non-silent source: births run before a batch's
//! updates, so a source born last round has not yet labelled the other robots'
//! tracks of it) are paired across robots:
//! every pair of two robots' unclaimed rays is triangulated, and a pair is a
//! candidate when its triangulation is usable: finite, in front of both
//! arrays, rays that meet (residual χ² within its quantile), and accepted by
//! the gate or rejected only as ill-conditioned (robots side by side: the
//! tracker then starts with the large covariance that geometry gives). A third
//! robot's unclaimed ray that passes within 3 σ of the candidate point joins
//! it. Where robots send spectral signatures (log band energies of the array
//! steered at each track), two tracks whose signatures correlate below 0.3
//! ([`signature_similarity`]) are never paired — a fan and a talker are not
//! one source, however well their rays meet — and a pair's correlation ρ adds
//! γρ to its score. Candidates that share a ray exclude each other; the set kept maximizes
//! `Σ (w · rays − χ²)` ([`best_disjoint`], exact for the small numbers here;
//! the sound map uses w = 2γ),
//! so that real intersections (rays that meet in 3D: χ² small) win over
//! ghosts (rays from different sources are skew lines unless the sources
//! share a height: χ² large), and three-ray candidates over two-ray ones.
//! Worked numbers: two robots ~3 m from two talkers at 1.2 m and 1.7 m
//! height, σ = 2° = 0.035 rad. A pair's miss distance d has variance
//! (r₁σ)² + (r₂σ)² = 2 · (3 · 0.035)² ≈ 0.022 m², so χ² ≈ d² / 0.022. A true
//! pair meets up to noise: χ² ≈ 1 (its mean, 1 dof). A ghost pair joins one
//! talker's ray to the other's, and the rays pass each other ~0.4 m apart
//! vertically: χ² ≈ 0.16 / 0.022 ≈ 7. With w = 2γ per ray, {true, true}
//! scores 8γ − 2 and {ghost, ghost} 8γ − 14: the true pairing wins by ~12.
//! Talkers at one height are told apart over time instead: while one of them
//! pauses only true pairs exist, and the robot-local track labels then hold
//! the pairing when both speak. A candidate must recur in consecutive rounds
//! before a source is born (the sound map's rule), and a ghost that is born
//! anyway moves when the robots move, leaves its rays' gates and dies.

use crate::planner::assignment::assign_rect;

/// Minimum-cost assignment of rows to columns for a rectangular cost matrix
/// (`cost[i][j]`, `f64::INFINITY` = forbidden), every row free to stay
/// unassigned at `unassigned_cost`. Returns, per row, its column or `None`.
/// Solved by the planner's Hungarian method ([`assign_rect`]) with one
/// "unassigned" column per row.
pub fn assign(cost: &[Vec<f64>], unassigned_cost: f64) -> Vec<Option<usize>> {
    let n = cost.len();
    if n == 0 {
        return Vec::new();
    }
    let m = cost[0].len();
    // Columns: the m real ones, then one "unassigned" column per row.
    let big = 1e12;
    let padded: Vec<Vec<f64>> = cost
        .iter()
        .enumerate()
        .map(|(i, row)| {
            let real = row.iter().map(|&v| if v.is_finite() { v } else { big });
            real.chain((0..n).map(|k| if k == i { unassigned_cost } else { big })).collect()
        })
        .collect();
    assign_rect(&padded)
        .into_iter()
        .enumerate()
        .map(|(i, j)| j.filter(|&j| j < m && cost[i][j].is_finite()))
        .collect()
}

/// The subset of candidates, no two sharing an element, with the largest total
/// score (candidates with a non-positive score are never worth taking). Exact
/// (branch and bound) up to `EXACT_LIMIT` candidates, best-score-first greedy
/// beyond. `members[i]` lists candidate i's elements (e.g. ray keys).
pub fn best_disjoint<K: PartialEq>(members: &[Vec<K>], scores: &[f64]) -> Vec<usize> {
    const EXACT_LIMIT: usize = 24;
    let mut order: Vec<usize> = (0..members.len()).filter(|&i| scores[i] > 0.0).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]));
    if order.len() > EXACT_LIMIT {
        let mut taken: Vec<usize> = Vec::new();
        for &i in &order {
            if taken.iter().all(|&t| !overlaps(&members[t], &members[i])) {
                taken.push(i);
            }
        }
        return taken;
    }
    let mut best = (0.0, Vec::new());
    let mut current = Vec::new();
    search(&order, 0, members, scores, &mut current, 0.0, &mut best);
    best.1
}

fn overlaps<K: PartialEq>(a: &[K], b: &[K]) -> bool {
    a.iter().any(|x| b.contains(x))
}

fn search<K: PartialEq>(
    order: &[usize],
    at: usize,
    members: &[Vec<K>],
    scores: &[f64],
    current: &mut Vec<usize>,
    total: f64,
    best: &mut (f64, Vec<usize>),
) {
    if total > best.0 {
        *best = (total, current.clone());
    }
    // Bound: even taking every remaining candidate cannot beat the best.
    let rest: f64 = order[at..].iter().map(|&i| scores[i]).sum();
    if at == order.len() || total + rest <= best.0 {
        return;
    }
    let i = order[at];
    if current.iter().all(|&t| !overlaps(&members[t], &members[i])) {
        current.push(i);
        search(order, at + 1, members, scores, current, total + scores[i], best);
        current.pop();
    }
    search(order, at + 1, members, scores, current, total, best);
}

/// Similarity of two spectral signatures (log band energies): the Pearson
/// correlation of the two vectors, in [−1, 1]; `None` when either is missing,
/// their lengths differ, or one is flat.
pub fn signature_similarity(a: Option<&[f32]>, b: Option<&[f32]>) -> Option<f64> {
    let (a, b) = (a?, b?);
    if a.len() != b.len() || a.len() < 2 {
        return None;
    }
    let n = a.len() as f64;
    let ma = a.iter().map(|&x| x as f64).sum::<f64>() / n;
    let mb = b.iter().map(|&x| x as f64).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (&x, &y) in a.iter().zip(b) {
        let (dx, dy) = (x as f64 - ma, y as f64 - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    (saa > 0.0 && sbb > 0.0).then(|| sab / (saa * sbb).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(cost: &[Vec<f64>], unassigned: f64) -> f64 {
        // Every assignment of rows to distinct columns or none.
        fn go(i: usize, cost: &[Vec<f64>], used: &mut Vec<bool>, un: f64) -> f64 {
            if i == cost.len() {
                return 0.0;
            }
            let mut best = un + go(i + 1, cost, used, un);
            for j in 0..cost[i].len() {
                if !used[j] && cost[i][j].is_finite() {
                    used[j] = true;
                    best = best.min(cost[i][j] + go(i + 1, cost, used, un));
                    used[j] = false;
                }
            }
            best
        }
        go(0, cost, &mut vec![false; cost.first().map_or(0, |r| r.len())], unassigned)
    }

    fn total(cost: &[Vec<f64>], a: &[Option<usize>], unassigned: f64) -> f64 {
        a.iter().enumerate().map(|(i, j)| j.map_or(unassigned, |j| cost[i][j])).sum()
    }

    #[test]
    fn assignment_is_optimal_against_brute_force() {
        let inf = f64::INFINITY;
        let cases = vec![
            vec![vec![1.0, 2.0], vec![2.0, 1.0]],
            // Greedy (row 0 takes its best, 1.0) costs 1 + 9.21; optimal 2 + 2.
            vec![vec![1.0, 2.0], vec![2.0, inf]],
            vec![vec![5.0, inf, 0.5], vec![inf, inf, 0.4], vec![0.3, 8.0, 9.0]],
            vec![vec![20.0, 30.0]],
            vec![vec![1.0], vec![0.5], vec![3.0]],
        ];
        for cost in cases {
            let a = assign(&cost, 9.21);
            let mut cols: Vec<usize> = a.iter().flatten().copied().collect();
            cols.sort();
            cols.dedup();
            assert_eq!(cols.len(), a.iter().flatten().count(), "a column used twice: {a:?}");
            assert!((total(&cost, &a, 9.21) - brute(&cost, 9.21)).abs() < 1e-9, "{cost:?} → {a:?}");
        }
        assert_eq!(assign(&[vec![1.0, 2.0], vec![2.0, f64::INFINITY]], 9.21), vec![Some(1), Some(0)]);
    }

    #[test]
    fn disjoint_selection_beats_greedy() {
        // Greedy takes the best single candidate {a1, b1} (score 5), which blocks
        // both others; the optimum takes {a1, b2} + {a2, b1} (4 + 4).
        let members = vec![vec!["a1", "b1"], vec!["a1", "b2"], vec!["a2", "b1"], vec!["a2", "b2"]];
        let scores = [5.0, 4.0, 4.0, -1.0];
        let mut got = best_disjoint(&members, &scores);
        got.sort();
        assert_eq!(got, vec![1, 2]);
    }

    #[test]
    fn signatures_correlate() {
        let fan = [60.0f32, 58.0, 50.0, 40.0, 35.0, 30.0];
        let fan2 = [55.0f32, 53.5, 46.0, 35.0, 31.0, 25.0];
        let talker = [30.0f32, 45.0, 55.0, 52.0, 40.0, 28.0];
        assert!(signature_similarity(Some(&fan), Some(&fan2)).unwrap() > 0.95);
        assert!(signature_similarity(Some(&fan), Some(&talker)).unwrap() < 0.3);
        assert_eq!(signature_similarity(Some(&fan), None), None);
        assert_eq!(signature_similarity(Some(&fan), Some(&fan[..3])), None);
    }
}
