//! Fisher information, covariance, GDOP, θ and conditioning of a ray geometry
//! (theory §1.4 and §2).

use nalgebra::{Matrix3, Point3, SymmetricEigen, Unit, Vector3};

use crate::ray::{MIN_RANGE_M, Ray};

/// A bearing sensor as the information calculus needs it: where it is and how
/// noisy its bearings are. The planner evaluates sensors at candidate places.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sensor {
    /// Array centre, map frame (m).
    pub origin: Point3<f64>,
    /// 1-σ angular noise per tangent axis (rad).
    pub sigma_rad: f64,
    /// 1-σ lateral uncertainty of the origin (m).
    pub origin_sigma_m: f64,
}

impl From<&Ray> for Sensor {
    fn from(r: &Ray) -> Self {
        Sensor { origin: r.origin_in_map, sigma_rad: r.sigma_rad, origin_sigma_m: r.origin_sigma_m }
    }
}

impl Sensor {
    /// Lateral variance at range r (m²): σ²r² + σ_origin².
    pub fn lateral_variance(&self, range_m: f64) -> f64 {
        let r = range_m.max(MIN_RANGE_M);
        self.sigma_rad * self.sigma_rad * r * r + self.origin_sigma_m * self.origin_sigma_m
    }
}

/// Fisher information about a source at `x` (m⁻²):
/// J = Σᵢ (I − uᵢuᵢᵀ) / (σᵢ²rᵢ² + σ_origin,ᵢ²), uᵢ = (x − oᵢ)/rᵢ (theory §2.1).
pub fn fisher_information(sensors: &[Sensor], x: &Point3<f64>) -> Matrix3<f64> {
    sensors.iter().fold(Matrix3::zeros(), |acc, s| acc + s.fisher_at(x))
}

/// Angle at `x` between the directions toward `a` and `b`, degrees in [0, 180].
pub fn angle_at_deg(x: &Point3<f64>, a: &Point3<f64>, b: &Point3<f64>) -> f64 {
    angle_between_deg(&(a - x), &(b - x))
}

/// Angle between two vectors, degrees in [0, 180]; 0 when either is zero.
pub fn angle_between_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let (na, nb) = (a.norm(), b.norm());
    if na == 0.0 || nb == 0.0 {
        return 0.0;
    }
    // atan2 of |a×b| and a·b is accurate at all angles, unlike acos.
    a.cross(b).norm().atan2(a.dot(b)).to_degrees()
}

/// Condition number κ = λ₃/λ₁ of the equal-weight normalized least-squares
/// matrix Ā = Σ(I − dᵢdᵢᵀ)/N (theory §1.4). Two rays at angle θ give
/// 2/(1 − |cos θ|); the paper's 40–140° band is κ ≤ 8.55. Infinite when singular.
pub fn condition_number(directions: &[Unit<Vector3<f64>>]) -> f64 {
    match directions {
        [] => return f64::INFINITY,
        // Closed form for two rays (theory §1.4).
        [a, b] => {
            let c = a.dot(b).abs().min(1.0);
            return if c >= 1.0 - 1e-15 { f64::INFINITY } else { 2.0 / (1.0 - c) };
        }
        _ => {}
    }
    let a = directions
        .iter()
        .fold(Matrix3::zeros(), |acc, d| acc + (Matrix3::identity() - d.into_inner() * d.transpose()))
        / directions.len() as f64;
    let eig = SymmetricEigen::new(a).eigenvalues;
    let (lo, hi) = (eig.min(), eig.max());
    if lo <= hi * 1e-15 { f64::INFINITY } else { hi / lo }
}

/// How good a geometry is for a source at a point.
#[derive(Clone, Debug, PartialEq)]
pub struct GeometryQuality {
    /// Fisher information (m⁻²).
    pub fisher: Matrix3<f64>,
    /// CRLB covariance J⁻¹ (m²); `None` when J is singular (fewer than two non-parallel rays).
    pub covariance: Option<Matrix3<f64>>,
    /// √tr J⁻¹ (m): the predicted RMS 3D error; infinite when singular.
    pub rms_m: f64,
    /// Geometric dilution of precision: √tr G⁻¹ with G = Σ (r̄/rᵢ)²(I − uᵢuᵢᵀ), r̄ the
    /// mean range. It is σ-free, and equals √tr(J⁻¹)/(σ r̄) when all sensors share σ:
    /// 1.58 for two robots at θ = 90°, 2.31 at 40° (theory §2.3). Infinite when singular.
    pub gdop: f64,
    /// Mean range from the sensors to the point (m).
    pub mean_range_m: f64,
    /// Angle at the point between each pair of sensors (i, j, degrees), i < j; for
    /// more than [`MAX_LISTED_PAIRS_ROBOTS`] sensors only the best pair.
    pub pairwise_theta_deg: Vec<(usize, usize, f64)>,
    /// Two sensors: their θ. More: the pairwise θ closest to 90° (the best pair). 0 for one sensor.
    pub theta_deg: f64,
}

/// Anything that is a bearing sensor for the information calculus.
pub trait AsSensor {
    /// The sensor.
    fn sensor(&self) -> Sensor;

    /// Fisher information about a source at `x` (m⁻²): by default
    /// (I − uuᵀ)/(σ²r² + σ_origin²).
    fn fisher_at(&self, x: &Point3<f64>) -> Matrix3<f64> {
        let s = self.sensor();
        let v = x - s.origin;
        let r = v.norm().max(MIN_RANGE_M);
        let u = v / r;
        (Matrix3::identity() - u * u.transpose()) / s.lateral_variance(r)
    }
}

impl AsSensor for Sensor {
    fn sensor(&self) -> Sensor {
        *self
    }
}

impl AsSensor for Ray {
    fn sensor(&self) -> Sensor {
        Sensor::from(self)
    }

    /// With the array's weaker elevation when it has one ([`Ray::fisher_at`]).
    fn fisher_at(&self, x: &Point3<f64>) -> Matrix3<f64> {
        Ray::fisher_at(self, x)
    }
}

/// Evaluates the geometry of `sensors` for a source at `x`.
pub fn assess<S: AsSensor>(sensors: &[S], x: &Point3<f64>) -> GeometryQuality {
    let mut fisher = Matrix3::zeros();
    let mut g = Matrix3::zeros();
    let mut range_sum = 0.0;
    for sensor in sensors {
        let s = sensor.sensor();
        let v = x - s.origin;
        let r = v.norm().max(MIN_RANGE_M);
        let u = v / r;
        let p = Matrix3::identity() - u * u.transpose();
        fisher += sensor.fisher_at(x);
        g += p / (r * r);
        range_sum += r;
    }
    let mean_range_m = if sensors.is_empty() { 0.0 } else { range_sum / sensors.len() as f64 };
    // G = Σ (r̄/rᵢ)²(I − uᵢuᵢᵀ) = r̄² Σ (I − uᵢuᵢᵀ)/rᵢ².
    g *= mean_range_m * mean_range_m;
    let covariance = invert_spd(&fisher);
    let rms_m = covariance.map_or(f64::INFINITY, |c| c.trace().max(0.0).sqrt());
    let gdop = invert_spd(&g).map_or(f64::INFINITY, |c| c.trace().max(0.0).sqrt());
    let (pairwise_theta_deg, theta_deg) = pairwise_angles(sensors, x);
    GeometryQuality { fisher, covariance, rms_m, gdop, mean_range_m, pairwise_theta_deg, theta_deg }
}

/// Most robots for which every pairwise θ is listed; above it only the best pair is.
pub const MAX_LISTED_PAIRS_ROBOTS: usize = 8;

/// Pairwise θ at `x` (listed for up to [`MAX_LISTED_PAIRS_ROBOTS`] sensors) and
/// the θ closest to 90°. The best pair is found from dot products, so that many
/// robots cost O(N²) multiplications, not O(N²) trigonometry.
fn pairwise_angles<S: AsSensor>(sensors: &[S], x: &Point3<f64>) -> (Vec<(usize, usize, f64)>, f64) {
    let n = sensors.len();
    if n <= MAX_LISTED_PAIRS_ROBOTS {
        let mut list = Vec::with_capacity(n * n.saturating_sub(1) / 2);
        for i in 0..n {
            for j in (i + 1)..n {
                list.push((i, j, angle_at_deg(x, &sensors[i].sensor().origin, &sensors[j].sensor().origin)));
            }
        }
        let best = best_pair_theta(&list);
        return (list, best);
    }
    let (i, j) = most_perpendicular_pair(
        sensors.iter().map(|s| (s.sensor().origin - x).try_normalize(0.0).unwrap_or_else(Vector3::zeros)),
    );
    let theta = angle_at_deg(x, &sensors[i].sensor().origin, &sensors[j].sensor().origin);
    (vec![(i, j, theta)], theta)
}

/// The first pair `(i, j)`, `i < j`, in lexical order whose unit vectors
/// have the least `|cos|` (the θ nearest 90°), for at least two vectors.
///
/// Two passes, so that the N²/2 products run without a branch per pair: the
/// least `|cos|` of each row `i` (over `j > i`, in independent lanes that
/// vectorize; a minimum does not depend on the order), the first row that
/// holds the overall least, then the first `j` of that row reaching it
/// (the same expression, so the same value).
fn most_perpendicular_pair(dirs: impl Iterator<Item = Vector3<f64>>) -> (usize, usize) {
    const LANES: usize = 4;
    let (mut xs, mut ys, mut zs) = (Vec::new(), Vec::new(), Vec::new());
    for d in dirs {
        xs.push(d.x);
        ys.push(d.y);
        zs.push(d.z);
    }
    let n = xs.len();
    let cos = |i: usize, j: usize| (xs[i] * xs[j] + ys[i] * ys[j] + zs[i] * zs[j]).abs();
    let mut best = (f64::INFINITY, 0);
    for i in 0..n.saturating_sub(1) {
        let (x, y, z) = (xs[i], ys[i], zs[i]);
        let (bx, by, bz) = (&xs[i + 1..], &ys[i + 1..], &zs[i + 1..]);
        let mut acc = [f64::INFINITY; LANES];
        let chunks = bx.len() / LANES * LANES;
        for q in (0..chunks).step_by(LANES) {
            for l in 0..LANES {
                let c = (x * bx[q + l] + y * by[q + l] + z * bz[q + l]).abs();
                acc[l] = if c < acc[l] { c } else { acc[l] };
            }
        }
        for q in chunks..bx.len() {
            let c = (x * bx[q] + y * by[q] + z * bz[q]).abs();
            acc[0] = if c < acc[0] { c } else { acc[0] };
        }
        let row = acc.iter().fold(f64::INFINITY, |m, &c| if c < m { c } else { m });
        if row < best.0 {
            best = (row, i);
        }
    }
    let i = best.1;
    let j = (i + 1..n).find(|&j| cos(i, j) == best.0).unwrap_or(i + 1);
    (i, j)
}

/// The pairwise θ closest to 90° (0 when there is no pair).
pub fn best_pair_theta(pairwise: &[(usize, usize, f64)]) -> f64 {
    pairwise.iter().map(|p| p.2).min_by(|a, b| (a - 90.0).abs().total_cmp(&(b - 90.0).abs())).unwrap_or(0.0)
}

/// Inverse of a symmetric positive semi-definite 3×3 matrix, `None` when it is
/// singular to working precision. The test is scale-free: det M ≤ 1e-13 (tr M/3)³,
/// i.e. λ_min/λ_max below about 1e-13 (the other eigenvalues are at most tr M).
pub fn invert_spd(m: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let scale = m.trace() / 3.0;
    if !(scale > 0.0) || !scale.is_finite() {
        return None;
    }
    let det = m.determinant();
    if !(det > 1e-13 * scale * scale * scale) {
        return None;
    }
    let inv = m.try_inverse()?;
    // Symmetrize away rounding, and refuse anything that is not finite.
    let inv = (inv + inv.transpose()) * 0.5;
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two sensors at range r from the origin with angle θ between them, in the z = 0 plane.
    fn pair(theta_deg: f64, r: f64, sigma: f64) -> Vec<Sensor> {
        let h = theta_deg.to_radians() / 2.0;
        [h, -h]
            .iter()
            .map(|a| Sensor {
                origin: Point3::new(r * a.cos(), r * a.sin(), 0.0),
                sigma_rad: sigma,
                origin_sigma_m: 0.0,
            })
            .collect()
    }

    #[test]
    fn the_most_perpendicular_pair_is_the_first_least_of_a_plain_scan() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for n in [2usize, 3, 5, 9, 10, 33, 128] {
            for trial in 0..20 {
                let mut dirs: Vec<Vector3<f64>> = (0..n)
                    .map(|_| {
                        let v = Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 0.3);
                        v.normalize()
                    })
                    .collect();
                if trial % 4 == 1 {
                    // Repeated directions: ties, which the first pair in lexical order wins.
                    for k in (1..n).step_by(2) {
                        dirs[k] = dirs[k - 1];
                    }
                }
                if trial % 4 == 2 {
                    dirs[n - 1] = Vector3::zeros(); // a robot on the point: cos 0 with everyone
                }
                let cos = |a: &Vector3<f64>, b: &Vector3<f64>| (a.x * b.x + a.y * b.y + a.z * b.z).abs();
                let mut want = (f64::INFINITY, 0, 1);
                for i in 0..n {
                    for j in i + 1..n {
                        if cos(&dirs[i], &dirs[j]) < want.0 {
                            want = (cos(&dirs[i], &dirs[j]), i, j);
                        }
                    }
                }
                assert_eq!(
                    most_perpendicular_pair(dirs.iter().copied()),
                    (want.1, want.2),
                    "n {n} trial {trial}"
                );
            }
        }
    }

    #[test]
    fn worked_example_of_theory_section_5_4() {
        let sigma = 3f64.to_radians();
        // θ, CRLB RMS 3D (m), GDOP_3D, from theory §5.4 / §2.3.
        for (theta, rms, gdop) in [(90.0, 0.248, 1.58), (30.0, 0.458, 2.92), (10.0, 1.284, 8.18)] {
            let q = assess(&pair(theta, 3.0, sigma), &Point3::origin());
            assert!((q.rms_m - rms).abs() < 0.002, "θ {theta}: rms {}", q.rms_m);
            assert!((q.gdop - gdop).abs() < 0.01, "θ {theta}: gdop {}", q.gdop);
            assert!((q.theta_deg - theta).abs() < 1e-9);
        }
    }

    #[test]
    fn eigenvalues_of_two_ray_information() {
        let (sigma, r, theta) = (0.05, 2.0, 60f64);
        let q = assess(&pair(theta, r, sigma), &Point3::origin());
        let mut e: Vec<f64> =
            SymmetricEigen::new(q.fisher).eigenvalues.iter().map(|l| l * sigma * sigma * r * r).collect();
        e.sort_by(f64::total_cmp);
        let c = theta.to_radians().cos();
        assert!(
            (e[0] - (1.0 - c)).abs() < 1e-9 && (e[1] - (1.0 + c)).abs() < 1e-9 && (e[2] - 2.0).abs() < 1e-9
        );
    }

    #[test]
    fn condition_number_matches_band_table() {
        for (theta, kappa) in [(40f64, 8.55), (90.0, 2.0), (10.0, 132.0), (140.0, 8.55)] {
            let h = theta.to_radians() / 2.0;
            let d = [
                Unit::new_normalize(Vector3::new(h.cos(), h.sin(), 0.0)),
                Unit::new_normalize(Vector3::new(h.cos(), -h.sin(), 0.0)),
            ];
            let k = condition_number(&d);
            assert!((k - kappa).abs() / kappa < 0.01, "θ {theta}: κ {k}");
        }
        let d = Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0));
        assert!(condition_number(&[d, d]).is_infinite());
    }

    #[test]
    fn singular_geometry_is_infinite_not_nan() {
        let s = pair(0.0, 3.0, 0.05);
        let q = assess(&s, &Point3::origin());
        assert!(q.covariance.is_none() && q.rms_m.is_infinite() && q.gdop.is_infinite());
        let q1 = assess(&s[..1], &Point3::origin());
        assert!(q1.rms_m.is_infinite() && q1.theta_deg == 0.0);
    }

    #[test]
    fn angles_are_accurate_near_zero_and_180() {
        let x = Point3::origin();
        let a = Point3::new(1.0, 0.0, 0.0);
        assert!((angle_at_deg(&x, &a, &Point3::new(1.0, 1e-9, 0.0)) - 1e-9f64.to_degrees()).abs() < 1e-15);
        assert!((angle_at_deg(&x, &a, &Point3::new(-1.0, 0.0, 0.0)) - 180.0).abs() < 1e-12);
    }
}
