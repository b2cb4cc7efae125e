//! Minimum-cost assignment (Hungarian method, O(n³) with row/column
//! potentials): robots to target slots ([`assign`]), and the rectangular form
//! ([`assign_rect`]) the association of rays to sources and the simulator's
//! multi-target scoring use.

/// `cost[i * n + j]`: cost of giving robot `i` slot `j`. Returns `slot[i]`
/// minimising Σ cost, and that sum. `n = 0` gives an empty assignment.
pub fn assign(cost: &[f64], n: usize) -> (Vec<usize>, f64) {
    assert_eq!(cost.len(), n * n, "cost must be n × n");
    // 1-based potentials u (rows), v (columns); p[j] = row matched to column j.
    let mut u = vec![0.0; n + 1];
    let mut v = vec![0.0; n + 1];
    let mut p = vec![0usize; n + 1];
    let mut way = vec![0usize; n + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0;
        let mut minv = vec![f64::INFINITY; n + 1];
        let mut used = vec![false; n + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0;
            for j in 1..=n {
                if !used[j] {
                    let cur = cost[(i0 - 1) * n + (j - 1)] - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            if j1 == 0 {
                // Only non-finite costs left: fall back to any free column.
                j1 = (1..=n).find(|&j| !used[j]).expect("a free column exists");
                delta = 0.0;
            }
            for j in 0..=n {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut slot = vec![0usize; n];
    for j in 1..=n {
        slot[p[j] - 1] = j - 1;
    }
    let total = (0..n).map(|i| cost[i * n + slot[i]]).sum();
    (slot, total)
}

/// Rectangular minimum-cost assignment: `result[i]` is the column given to
/// row `i`, `None` for the rows left over when there are more rows than
/// columns. Padded to a square with zero-cost dummy rows or columns and solved
/// by [`assign`]. Costs should be finite (use a large value for forbidden pairs).
pub fn assign_rect(cost: &[Vec<f64>]) -> Vec<Option<usize>> {
    let rows = cost.len();
    let cols = cost.first().map_or(0, Vec::len);
    if rows == 0 || cols == 0 {
        return vec![None; rows];
    }
    let n = rows.max(cols);
    let mut square = vec![0.0; n * n];
    for (i, row) in cost.iter().enumerate() {
        square[i * n..i * n + cols].copy_from_slice(row);
    }
    let (slot, _) = assign(&square, n);
    slot.into_iter().take(rows).map(|j| (j < cols).then_some(j)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    fn permutations(n: usize) -> Vec<Vec<usize>> {
        if n == 0 {
            return vec![vec![]];
        }
        let mut out = Vec::new();
        for p in permutations(n - 1) {
            for k in 0..=p.len() {
                let mut q = p.clone();
                q.insert(k, n - 1);
                out.push(q);
            }
        }
        out
    }

    #[test]
    fn matches_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for n in 0..=6 {
            for _ in 0..40 {
                let cost: Vec<f64> = (0..n * n).map(|_| rng.random_range(0.0..10.0)).collect();
                let (slot, total) = assign(&cost, n);
                let mut seen = vec![false; n];
                slot.iter().for_each(|&s| seen[s] = true);
                assert!(seen.iter().all(|&s| s));
                let best = permutations(n)
                    .iter()
                    .map(|p| (0..n).map(|i| cost[i * n + p[i]]).sum::<f64>())
                    .fold(f64::INFINITY, f64::min);
                assert!((total - if n == 0 { 0.0 } else { best }).abs() < 1e-9, "n {n}: {total} vs {best}");
            }
        }
    }
}
