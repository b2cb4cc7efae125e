//! Precomputed TDOA tables and the hierarchical (coarse → fine) search.
//!
//! The fine grid (icosphere `fine_level`, only the points in the search
//! region) is partitioned into cells: each fine point belongs to its nearest
//! coarse point (icosphere `coarse_level`). As in ODAS's SRP-PHAT-HSDA, the
//! coarse response of a cell sums, per correlation row (a baseline: one
//! pair, or the pairs displaced by the same vector, see [`super::phat`]),
//! the *maximum* of the row's
//! correlation over every lag a fine point of the cell may read, so it bounds
//! the fine response of every point of the cell from above. The search is then
//! a branch and bound: cells are opened in decreasing order of their bound
//! until the best fine value found beats the next bound (at most
//! `max_cells`), and a hill climb on the fine mesh finishes the job when the
//! cap stopped it early. Fine values interpolate the correlations linearly
//! between integer lags.
//!
//! TDOA convention: pair `p = (i, j)` has `τₚ(d) = (pⱼ − pᵢ)·d · fs/c`
//! samples for a far-field source in direction `d` (array frame); a row's
//! is that of its first pair. Below, "pair" `p` is the correlator's row `p`.

use nalgebra::Vector3;

use super::grid::SphereGrid;
use super::phat::LagSpans;
use crate::array::{ArrayGeometry, SearchRegion};

/// TDOA tables of the coarse and fine grids.
#[derive(Debug)]
pub struct SearchTables {
    pairs: usize,
    /// Entries per pair row of the correlation buffers.
    stride: usize,
    /// Fine points kept, grouped by cell.
    pub(super) fine_dirs: Vec<Vector3<f64>>,
    /// `fine_idx[f*P + p] = p·stride + ⌊τₚ(d_f) + R⌋` (index into the correlation rows).
    fine_idx: Vec<u32>,
    /// Fractional part of `τₚ(d_f) + R`.
    fine_frac: Vec<f32>,
    /// Directivity weights per (fine point, pair), when any microphone is directional.
    fine_weight: Option<Vec<f32>>,
    fine_nb_offsets: Vec<u32>,
    fine_nb: Vec<u32>,
    /// Fine points `cell_offsets[c]..cell_offsets[c+1]` form coarse cell `c`.
    cell_offsets: Vec<u32>,
    coarse_dirs: Vec<Vector3<f64>>,
    /// Angular radius of each cell (largest angle from its coarse point to
    /// its fine points), and its cosine and sine.
    cell_radius: Vec<f64>,
    cell_radius_cos_sin: Vec<(f64, f64)>,
    /// `coarse_idx[c*P + p]`: flat index into `cc_max` (pair row + rounded lag).
    coarse_idx: Vec<u32>,
    coarse_weight: Option<Vec<f32>>,
    /// Half-width of the sliding maximum each pair needs.
    pub(super) windows: Vec<usize>,
    /// Largest |τ| over pairs and kept points, samples.
    pub(super) max_tdoa: f64,
    // Per-frame scratch.
    coarse_val: Vec<f32>,
    cell_open: Vec<bool>,
    /// Fine values computed in the current search (valid when `cache_gen[f] == generation`).
    cache: Vec<f32>,
    cache_gen: Vec<u32>,
    generation: u32,
    /// Counters since last read: searches, cells opened, fine points evaluated.
    pub(super) counters: [usize; 3],
    /// The CPU's vector instructions (see [`crate::simd`]).
    pub(super) arch: pulp::Arch,
}

/// Which fine points are excluded (too close to an earlier potential).
#[derive(Debug)]
pub struct Exclusion<'a> {
    /// Directions already reported this frame.
    pub found: &'a [Vector3<f64>],
    /// cos of the minimum separation.
    pub cos_sep: f64,
    /// sin of the minimum separation.
    pub sin_sep: f64,
    /// The minimum separation, radians.
    pub sep_rad: f64,
}

impl Exclusion<'_> {
    #[inline(always)]
    fn excludes(&self, d: &Vector3<f64>) -> bool {
        self.found.iter().any(|f| f.dot(d) > self.cos_sep)
    }
}

impl SearchTables {
    /// Builds the tables. `pair_axes[p]` maps a direction to row `p`'s TDOA
    /// in samples (`τₚ(d) = pair_axes[p]·d`), `pair_mics[p]` are its first pair's
    /// microphones; only fine points within half a fine spacing of `region`
    /// are kept. The correlator must keep lags up to [`Self::lag_radius`].
    pub fn new(
        array: &ArrayGeometry,
        pair_axes: &[Vector3<f64>],
        pair_mics: &[(usize, usize)],
        region: &SearchRegion,
        coarse_level: u32,
        fine_level: u32,
    ) -> Self {
        let coarse_grid = SphereGrid::icosphere(coarse_level);
        let fine_grid = SphereGrid::icosphere(fine_level);
        let margin = 0.5 * fine_grid.mean_spacing_rad();
        let keep: Vec<bool> = fine_grid.points().iter().map(|d| region.contains(d, margin)).collect();
        // Cell of every kept fine point.
        let mut members: Vec<Vec<usize>> = vec![Vec::new(); coarse_grid.len()];
        for (f, d) in fine_grid.points().iter().enumerate() {
            if keep[f] {
                members[coarse_grid.nearest(d)].push(f);
            }
        }
        let mut order = Vec::new(); // kept fine indices in cell order
        let mut cell_offsets = vec![0u32];
        let mut coarse_dirs = Vec::new();
        let mut cell_radius = Vec::new();
        for (c, m) in members.iter().enumerate() {
            if m.is_empty() {
                continue;
            }
            let cd = coarse_grid.points()[c];
            cell_radius.push(m.iter().map(|&f| cd.angle(&fine_grid.points()[f])).fold(0.0, f64::max));
            coarse_dirs.push(cd);
            order.extend_from_slice(m);
            cell_offsets.push(order.len() as u32);
        }
        let mut new_index = vec![u32::MAX; fine_grid.len()];
        for (k, &f) in order.iter().enumerate() {
            new_index[f] = k as u32;
        }
        let mut fine_nb_offsets = vec![0u32];
        let mut fine_nb = Vec::new();
        for &f in &order {
            fine_nb.extend(
                fine_grid.neighbours(f).iter().map(|&n| new_index[n as usize]).filter(|&n| n != u32::MAX),
            );
            fine_nb_offsets.push(fine_nb.len() as u32);
        }
        let fine_dirs: Vec<_> = order.iter().map(|&f| fine_grid.points()[f]).collect();

        let pairs = pair_axes.len();
        let tau = |a: &Vector3<f64>, d: &Vector3<f64>| a.dot(d);
        let mut max_tdoa = 0.0f64;
        for d in fine_dirs.iter().chain(&coarse_dirs) {
            for a in pair_axes {
                max_tdoa = max_tdoa.max(tau(a, d).abs());
            }
        }
        // Sliding-maximum half-width per pair so that every lag a fine point
        // of a cell reads (floor(τ) and floor(τ)+1) is within ±w of the cell's
        // rounded coarse lag.
        let mut windows = vec![0usize; pairs];
        for c in 0..coarse_dirs.len() {
            for f in cell_offsets[c] as usize..cell_offsets[c + 1] as usize {
                for (p, a) in pair_axes.iter().enumerate() {
                    let nc = tau(a, &coarse_dirs[c]).round() as i64;
                    let fl = tau(a, &fine_dirs[f]).floor() as i64;
                    let need = (nc - fl).max(fl + 1 - nc).max(0) as usize;
                    windows[p] = windows[p].max(need);
                }
            }
        }

        let directional = array.microphones.iter().any(|m| m.axis_in_array.is_some());
        let weight = |d: &Vector3<f64>, p: usize| -> f32 {
            let u = nalgebra::Unit::new_normalize(*d);
            let (i, j) = pair_mics[p];
            (array.microphones[i].gain(&u) * array.microphones[j].gain(&u)) as f32
        };
        let fine_weight = directional.then(|| {
            fine_dirs.iter().flat_map(|d| (0..pairs).map(move |p| weight(d, p))).collect::<Vec<f32>>()
        });
        let coarse_weight = fine_weight.as_ref().map(|fw| {
            let mut cw = vec![0.0f32; coarse_dirs.len() * pairs];
            for c in 0..coarse_dirs.len() {
                for f in cell_offsets[c] as usize..cell_offsets[c + 1] as usize {
                    for p in 0..pairs {
                        cw[c * pairs + p] = cw[c * pairs + p].max(fw[f * pairs + p]);
                    }
                }
            }
            cw
        });

        SearchTables {
            pairs,
            stride: 0,
            fine_idx: Vec::new(),
            fine_frac: Vec::new(),
            coarse_idx: Vec::new(),
            cache: vec![0.0; fine_dirs.len()],
            cache_gen: vec![0; fine_dirs.len()],
            generation: 0,
            counters: [0; 3],
            fine_weight,
            fine_nb_offsets,
            fine_nb,
            coarse_val: vec![0.0; coarse_dirs.len()],
            cell_open: vec![false; coarse_dirs.len()],
            cell_offsets,
            cell_radius_cos_sin: cell_radius.iter().map(|r| (r.cos(), r.sin())).collect(),
            cell_radius,
            coarse_weight,
            coarse_dirs,
            fine_dirs,
            windows,
            max_tdoa,
            arch: pulp::Arch::new(),
        }
        .with_lags(pair_axes)
    }

    /// Fills the lag tables once the correlator's radius `R` is known
    /// (`R` = ⌈max TDOA⌉ + max window + 2).
    fn with_lags(mut self, pair_axes: &[Vector3<f64>]) -> Self {
        let r = self.lag_radius();
        self.stride = 2 * r + 2;
        let rf = r as f64;
        let stride = self.stride;
        for d in &self.fine_dirs {
            for (p, a) in pair_axes.iter().enumerate() {
                let t = a.dot(d) + rf;
                let i = t.floor();
                self.fine_idx.push((p * stride) as u32 + i as u32);
                self.fine_frac.push((t - i) as f32);
            }
        }
        self.coarse_idx = self
            .coarse_dirs
            .iter()
            .flat_map(|d| {
                pair_axes
                    .iter()
                    .enumerate()
                    .map(move |(p, a)| (p * stride) as u32 + (a.dot(d).round() + rf) as u32)
            })
            .collect();
        self
    }

    /// The correlation lag radius `R` these tables need.
    pub fn lag_radius(&self) -> usize {
        self.max_tdoa.ceil() as usize + self.windows.iter().copied().max().unwrap_or(0) + 2
    }

    /// Per pair, the row indices (half-open) of the correlator's `lin` and
    /// of its `cc_max` that the searches read: `lin` at every fine point's
    /// ⌊τ⌋ (its entry holds `cc[n]` and `cc[n+1] − cc[n]`), `cc_max` at every
    /// coarse point's rounded lag. See [`super::phat::CrossCorrelator::restrict`].
    pub fn used_lags(&self) -> (LagSpans, LagSpans) {
        let span = |idx: &[u32], p: usize| {
            let rows = idx.iter().skip(p).step_by(self.pairs).map(|&i| i as usize - p * self.stride);
            rows.fold(None, |r: Option<(usize, usize)>, i| {
                Some(r.map_or((i, i + 1), |(a, b)| (a.min(i), b.max(i + 1))))
            })
            .unwrap_or((0, 0))
        };
        (0..self.pairs).map(|p| (span(&self.fine_idx, p), span(&self.coarse_idx, p))).unzip()
    }

    /// Number of fine points searched.
    pub fn fine_len(&self) -> usize {
        self.fine_dirs.len()
    }

    /// Number of coarse cells.
    pub fn coarse_len(&self) -> usize {
        self.coarse_dirs.len()
    }

    /// Fine response (sum over pairs of the linearly interpolated
    /// correlation) at fine point `f`; `lin` holds `[cc[n], cc[n+1] − cc[n]]`.
    #[inline(always)]
    pub fn fine_value(&self, lin: &[[f32; 2]], f: usize) -> f32 {
        let range = f * self.pairs..(f + 1) * self.pairs;
        let (idx, frac) = (&self.fine_idx[range.clone()], &self.fine_frac[range.clone()]);
        match &self.fine_weight {
            None => {
                // Independent accumulators: the sum is bound by loads, not by add latency.
                let mut acc = [0f32; 8];
                let (ic, fc) = (idx.chunks_exact(8), frac.chunks_exact(8));
                let (ir, fr) = (ic.remainder(), fc.remainder());
                for (i8, f8) in ic.zip(fc) {
                    for l in 0..8 {
                        let [c, d] = lin[i8[l] as usize];
                        acc[l] += c + f8[l] * d;
                    }
                }
                for (&i, &a) in ir.iter().zip(fr) {
                    let [c, d] = lin[i as usize];
                    acc[0] += c + a * d;
                }
                acc.iter().sum()
            }
            Some(w) => {
                let mut acc = 0f32;
                for ((&i, &a), &g) in idx.iter().zip(frac).zip(&w[range]) {
                    let [c, d] = lin[i as usize];
                    acc += g * (c + a * d);
                }
                acc
            }
        }
    }

    /// [`Self::fine_value`] through the per-search cache.
    #[inline(always)]
    fn cached(&mut self, lin: &[[f32; 2]], f: usize) -> f32 {
        if self.cache_gen[f] != self.generation {
            self.cache[f] = self.fine_value(lin, f);
            self.cache_gen[f] = self.generation;
            self.counters[2] += 1;
        }
        self.cache[f]
    }

    #[inline(always)]
    fn new_generation(&mut self) {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.cache_gen.fill(0);
            self.generation = 1;
        }
        self.counters[0] += 1;
    }

    #[inline(always)]
    fn coarse_values(&mut self, cc_max: &[f32]) {
        let p = self.pairs;
        for (c, v) in self.coarse_val.iter_mut().enumerate() {
            let idx = &self.coarse_idx[c * p..(c + 1) * p];
            *v = match &self.coarse_weight {
                None => sum_gather(cc_max, idx),
                Some(w) => idx
                    .iter()
                    .zip(&w[c * p..(c + 1) * p])
                    .map(|(&i, &g)| g * cc_max[i as usize].max(0.0))
                    .sum(),
            };
        }
    }

    /// Hierarchical search: the best fine point (index, response) outside
    /// `exclusion`, or `None` when every point is excluded.
    pub fn search_hierarchical(
        &mut self,
        lin: &[[f32; 2]],
        cc_max: &[f32],
        max_cells: usize,
        exclusion: &Exclusion<'_>,
    ) -> Option<(usize, f32)> {
        crate::simd::run(self.arch, Hierarchical { tables: self, lin, cc_max, max_cells, exclusion })
    }

    #[inline(always)]
    fn search_hierarchical_body(
        &mut self,
        lin: &[[f32; 2]],
        cc_max: &[f32],
        max_cells: usize,
        exclusion: &Exclusion<'_>,
    ) -> Option<(usize, f32)> {
        self.new_generation();
        self.coarse_values(cc_max);
        for (c, open) in self.cell_open.iter_mut().enumerate() {
            // Cells entirely inside an exclusion zone are never opened:
            // angle(found, centre) + radius < sep.
            let slack = exclusion.sep_rad - self.cell_radius[c];
            *open = !exclusion.found.is_empty() && slack > 0.0 && {
                // cos(sep − radius), without a cosine per cell and search.
                let (cos_r, sin_r) = self.cell_radius_cos_sin[c];
                let cos_slack = exclusion.cos_sep * cos_r + exclusion.sin_sep * sin_r;
                exclusion.found.iter().any(|f| f.dot(&self.coarse_dirs[c]) > cos_slack)
            };
        }
        let mut best: Option<(usize, f32)> = None;
        for _ in 0..max_cells.max(1) {
            let mut next: Option<(usize, f32)> = None;
            for (c, (&v, &open)) in self.coarse_val.iter().zip(&self.cell_open).enumerate() {
                if !open && next.is_none_or(|(_, nv)| v > nv) {
                    next = Some((c, v));
                }
            }
            let Some((c, bound)) = next else { break };
            if best.is_some_and(|(_, bv)| bound <= bv) {
                break;
            }
            self.cell_open[c] = true;
            self.counters[1] += 1;
            for f in self.cell_offsets[c] as usize..self.cell_offsets[c + 1] as usize {
                if exclusion.excludes(&self.fine_dirs[f]) {
                    continue;
                }
                let v = self.cached(lin, f);
                if best.is_none_or(|(_, bv)| v > bv) {
                    best = Some((f, v));
                }
            }
        }
        best.map(|b| self.hill_climb(lin, b, exclusion))
    }

    /// Sub-grid estimate of the peak at fine point `f`: a quadratic fitted
    /// to the responses of `f` and its mesh neighbours (gnomonic tangent
    /// coordinates). Falls back to the grid point when the fit is not a
    /// maximum within one grid spacing.
    pub fn quadratic_peak(&mut self, lin: &[[f32; 2]], f: usize) -> Vector3<f64> {
        let d0 = self.fine_dirs[f];
        let (e1, e2) = super::refine::tangent_basis(&d0);
        let mut ata = nalgebra::Matrix6::<f64>::zeros();
        let mut atb = nalgebra::Vector6::<f64>::zeros();
        let (a, b) = (self.fine_nb_offsets[f] as usize, self.fine_nb_offsets[f + 1] as usize);
        let mut spacing = 0.0f64;
        for k in a..=b {
            let q = if k == b { f } else { self.fine_nb[k] as usize };
            let d = self.fine_dirs[q];
            let z = d0.dot(&d);
            let (x, y) = (e1.dot(&d) / z, e2.dot(&d) / z);
            spacing = spacing.max((x * x + y * y).sqrt());
            let row = nalgebra::Vector6::new(1.0, x, y, 0.5 * x * x, x * y, 0.5 * y * y);
            let v = self.cached(lin, q) as f64;
            ata += row * row.transpose();
            atb += row * v;
        }
        let Some(c) = ata.try_inverse().map(|inv| inv * atb) else { return d0 };
        let (g, h) = (nalgebra::Vector2::new(c[1], c[2]), nalgebra::Matrix2::new(c[3], c[4], c[4], c[5]));
        if !(h[(0, 0)] < 0.0 && h.determinant() > 0.0) {
            return d0;
        }
        let Some(x) = h.try_inverse().map(|hi| -(hi * g)) else { return d0 };
        if x.norm() > spacing {
            return d0;
        }
        (d0 + e1 * x.x + e2 * x.y).normalize()
    }

    /// Exhaustive search over every fine point (the classic SRP-PHAT scan).
    pub fn search_exhaustive(&mut self, lin: &[[f32; 2]], exclusion: &Exclusion<'_>) -> Option<(usize, f32)> {
        self.new_generation();
        self.counters[2] += self.fine_dirs.len();
        let mut best: Option<(usize, f32)> = None;
        for f in 0..self.fine_dirs.len() {
            if exclusion.excludes(&self.fine_dirs[f]) {
                continue;
            }
            let v = self.fine_value(lin, f);
            if best.is_none_or(|(_, bv)| v > bv) {
                best = Some((f, v));
            }
        }
        best
    }

    /// Moves to the best neighbour until none is better (a local maximum of the fine mesh).
    #[inline(always)]
    fn hill_climb(
        &mut self,
        lin: &[[f32; 2]],
        start: (usize, f32),
        exclusion: &Exclusion<'_>,
    ) -> (usize, f32) {
        let mut cur = start;
        for _ in 0..64 {
            let mut moved = false;
            let (a, b) = (self.fine_nb_offsets[cur.0] as usize, self.fine_nb_offsets[cur.0 + 1] as usize);
            for q in a..b {
                let n = self.fine_nb[q] as usize;
                if exclusion.excludes(&self.fine_dirs[n]) {
                    continue;
                }
                let v = self.cached(lin, n);
                if v > cur.1 {
                    cur = (n, v);
                    moved = true;
                }
            }
            if !moved {
                break;
            }
        }
        cur
    }
}

/// [`SearchTables::search_hierarchical`] as a vectorized kernel.
struct Hierarchical<'a, 'e> {
    tables: &'a mut SearchTables,
    lin: &'a [[f32; 2]],
    cc_max: &'a [f32],
    max_cells: usize,
    exclusion: &'a Exclusion<'e>,
}

impl crate::simd::Kernel for Hierarchical<'_, '_> {
    type Output = Option<(usize, f32)>;

    #[inline(always)]
    fn run(self) -> Self::Output {
        self.tables.search_hierarchical_body(self.lin, self.cc_max, self.max_cells, self.exclusion)
    }
}

/// `Σ v[idx[q]]` with independent accumulators.
#[inline(always)]
fn sum_gather(v: &[f32], idx: &[u32]) -> f32 {
    let mut acc = [0f32; 8];
    let chunks = idx.chunks_exact(8);
    let rest = chunks.remainder();
    for i8 in chunks {
        for l in 0..8 {
            acc[l] += v[i8[l] as usize];
        }
    }
    for &i in rest {
        acc[0] += v[i as usize];
    }
    acc.iter().sum()
}
