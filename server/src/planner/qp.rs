//! The per-cycle convex problem (theory §3.3), solved with Clarabel.
//!
//! Variables: every robot's base position pᵢ ∈ ℝ² (map xy, m), stacked.
//!
//! ```text
//! minimise   Σᵢ ‖pᵢ − pᵢ⁰‖² + λ_g Σᵢ ‖pᵢ − cᵢ‖²        cᵢ: this cycle's heading point
//! subject to mᵢ,₁ᵀ(pᵢ − x̂) ≥ 0, mᵢ,₂ᵀ(pᵢ − x̂) ≥ 0          wedge of half-width δ around ψᵢ
//!            nᵢᵀ(pᵢ − x̂) ≥ r_lo,ᵢ                          chord: ⇒ ‖pᵢ − x̂‖ ≥ r_lo,ᵢ
//!            ‖pᵢ − x̂‖ ≤ r_hi,ᵢ                             SOC
//!            ‖pᵢ − pᵢ⁰‖ ≤ step                              SOC
//!            Fᵢ pᵢ ≤ fᵢ                                    convex free region around cᵢ
//!            ηᵢⱼᵀ(pᵢ − pⱼ) ≥ d_ij                          linearised separation
//! ```
//!
//! In Clarabel's form min ½xᵀPx + qᵀx s.t. Ax + s = b, s ∈ K: P = 2(1 + λ_g)I,
//! q = −2(p⁰ + λ_g c); a half-plane mᵀp ≥ β is the row −mᵀ with b = −β in the
//! non-negative cone; ‖p − a‖ ≤ r is the 3-row block (0; I) with b = (r; a) in
//! a second-order cone. Every bound is tightened by [`MARGIN_M`] so that the
//! solution passes the exact checks the planner applies afterwards.

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SecondOrderConeT, SolverStatus,
    SupportedConeT,
};
use nalgebra::{Point2, Vector2};

use super::cycle::{CycleRobot, Separation};

/// Tightening of every constraint of the convex problem (m).
pub(crate) const MARGIN_M: f64 = 1e-5;

/// What the convex problem gave.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum QpOutcome {
    /// Positions per robot (map xy, m).
    Solved(Vec<Point2<f64>>),
    /// Clarabel certified (or nearly) that the constraints cannot all hold.
    Infeasible(SolverStatus),
    /// The solver did not converge or could not be set up.
    Failed(String),
}

/// Rows of A in triplet form, with b and the cone list.
#[derive(Default)]
struct Rows {
    triplets: Vec<(usize, usize, f64)>,
    b: Vec<f64>,
}

impl Rows {
    fn row(&mut self, entries: &[(usize, f64)], b: f64) {
        let r = self.b.len();
        self.triplets.extend(entries.iter().filter(|e| e.1 != 0.0).map(|&(c, v)| (r, c, v)));
        self.b.push(b);
    }

    /// `m · p_robot ≥ beta`.
    fn at_least(&mut self, robot: usize, m: &Vector2<f64>, beta: f64) {
        self.row(&[(2 * robot, -m.x), (2 * robot + 1, -m.y)], -beta);
    }

    /// `‖p_robot − a‖ ≤ r` as a 3-row second-order block.
    fn within(&mut self, robot: usize, a: &Point2<f64>, r: f64) {
        self.row(&[], r);
        self.row(&[(2 * robot, 1.0)], a.x);
        self.row(&[(2 * robot + 1, 1.0)], a.y);
    }

    fn matrix(mut self, n: usize) -> (CscMatrix<f64>, Vec<f64>) {
        let m = self.b.len();
        self.triplets.sort_by_key(|t| (t.1, t.0));
        let mut colptr = vec![0usize; n + 1];
        for t in &self.triplets {
            colptr[t.1 + 1] += 1;
        }
        for c in 0..n {
            colptr[c + 1] += colptr[c];
        }
        let rowval = self.triplets.iter().map(|t| t.0).collect();
        let nzval = self.triplets.iter().map(|t| t.2).collect();
        (CscMatrix::new(m, n, colptr, rowval, nzval), self.b)
    }
}

/// Solves the cycle's convex problem around the source `x` (map xy).
pub(crate) fn solve(
    x: &Point2<f64>,
    robots: &[CycleRobot],
    separations: &[Separation],
    goal_weight: f64,
) -> QpOutcome {
    let n = 2 * robots.len();
    if n == 0 {
        return QpOutcome::Solved(vec![]);
    }
    let diag = 2.0 * (1.0 + goal_weight);
    let p = CscMatrix::new(n, n, (0..=n).collect(), (0..n).collect(), vec![diag; n]);
    let mut q = vec![0.0; n];
    for (i, r) in robots.iter().enumerate() {
        let lin = r.p0.coords + r.target.coords * goal_weight;
        q[2 * i] = -2.0 * lin.x;
        q[2 * i + 1] = -2.0 * lin.y;
    }

    let mut rows = Rows::default();
    for (i, r) in robots.iter().enumerate() {
        let (lo, hi) = (r.wedge_center_rad - r.wedge_half_rad, r.wedge_center_rad + r.wedge_half_rad);
        let m1 = Vector2::new(-lo.sin(), lo.cos());
        let m2 = Vector2::new(hi.sin(), -hi.cos());
        rows.at_least(i, &m1, m1.dot(&x.coords) + MARGIN_M);
        rows.at_least(i, &m2, m2.dot(&x.coords) + MARGIN_M);
        let axis = Vector2::new(r.wedge_center_rad.cos(), r.wedge_center_rad.sin());
        rows.at_least(i, &axis, axis.dot(&x.coords) + r.range_lo + MARGIN_M);
        for h in &r.region {
            rows.at_least(i, &(-h.normal), -(h.offset - MARGIN_M));
        }
    }
    for s in separations {
        rows.row(
            &[(2 * s.i, -s.eta.x), (2 * s.i + 1, -s.eta.y), (2 * s.j, s.eta.x), (2 * s.j + 1, s.eta.y)],
            -(s.min_m + MARGIN_M),
        );
    }
    let linear = rows.b.len();
    let mut cones: Vec<SupportedConeT<f64>> = vec![NonnegativeConeT(linear)];
    for (i, r) in robots.iter().enumerate() {
        rows.within(i, x, r.range_hi - MARGIN_M);
        rows.within(i, &r.p0, r.step - MARGIN_M);
        cones.push(SecondOrderConeT(3));
        cones.push(SecondOrderConeT(3));
    }
    let (a, b) = rows.matrix(n);

    let settings = DefaultSettings { verbose: false, max_iter: 100, ..DefaultSettings::default() };
    let mut solver = match DefaultSolver::new(&p, &q, &a, &b, &cones, settings) {
        Ok(s) => s,
        Err(e) => return QpOutcome::Failed(format!("solver setup: {e}")),
    };
    solver.solve();
    let status = solver.solution.status;
    match status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => {
            let xs = &solver.solution.x;
            if xs.iter().any(|v| !v.is_finite()) {
                return QpOutcome::Failed(format!("{status:?} with non-finite solution"));
            }
            QpOutcome::Solved((0..robots.len()).map(|i| Point2::new(xs[2 * i], xs[2 * i + 1])).collect())
        }
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => {
            QpOutcome::Infeasible(status)
        }
        other => QpOutcome::Failed(format!("solver status {other:?}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planner::free_space::HalfPlane;

    fn robot(p0: Point2<f64>, target: Point2<f64>, psi: f64) -> CycleRobot {
        CycleRobot {
            p0,
            target,
            wedge_center_rad: psi,
            wedge_half_rad: 15f64.to_radians(),
            range_lo: 1.0,
            range_hi: 5.0,
            step: 1.0,
            region: vec![],
        }
    }

    #[test]
    fn unconstrained_robot_moves_toward_its_target() {
        let x = Point2::origin();
        let r = robot(Point2::new(2.0, 0.0), Point2::new(2.0, 0.5), 0.0);
        let QpOutcome::Solved(p) = solve(&x, &[r], &[], 4.0) else { panic!() };
        // (p⁰ + λ c)/(1 + λ) = (2, 0.4).
        assert!((p[0] - Point2::new(2.0, 0.4)).norm() < 1e-6, "{p:?}");
    }

    #[test]
    fn constraints_bind() {
        let x = Point2::origin();
        // Target far along +y; the step (1 m) and the wedge (±15° about +x) bind.
        let mut r = robot(Point2::new(2.0, 0.0), Point2::new(2.0, 3.0), 0.0);
        r.region = vec![HalfPlane { normal: Vector2::x(), offset: 2.2 }];
        let QpOutcome::Solved(p) = solve(&x, &[r.clone()], &[], 10.0) else { panic!() };
        let q = p[0];
        assert!(q.y.atan2(q.x) <= 15f64.to_radians() + 1e-9);
        assert!((q - r.p0).norm() <= 1.0 && q.x <= 2.2, "{q:?}");
        // A region excluding the whole wedge makes it infeasible.
        r.region = vec![HalfPlane { normal: Vector2::x(), offset: 0.5 }];
        assert!(matches!(solve(&x, &[r], &[], 10.0), QpOutcome::Infeasible(_)));
    }

    #[test]
    fn separation_is_kept() {
        let x = Point2::origin();
        let a = robot(Point2::new(2.0, 0.3), Point2::new(2.0, 0.0), 0.0);
        let b = robot(Point2::new(2.0, -0.3), Point2::new(2.0, 0.0), 0.0);
        let sep = [Separation { i: 0, j: 1, eta: Vector2::y(), min_m: 0.8 }];
        let QpOutcome::Solved(p) = solve(&x, &[a, b], &sep, 10.0) else { panic!() };
        assert!((p[0] - p[1]).norm() >= 0.8 - 1e-9, "{p:?}");
    }
}
