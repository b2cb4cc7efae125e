//! The constant-velocity extended Kalman filter of one source (theory §4.1–4.2 B).
//!
//! State s = [x, y, z, ẋ, ẏ, ż]ᵀ in the map frame (m, m/s). Prediction uses the
//! continuous white-noise acceleration model with a horizontal and a (much
//! smaller) vertical power spectral density q̃. Each DoA is one update with a
//! 2-D tangent-plane residual: with p̂ the predicted position, v̂ = (p̂ − o)/r̂ and
//! B̂ = [b₁ b₂] an orthonormal basis ⊥ v̂ (from [`tangent_basis`]),
//!
//! ```text
//! ν = log-map of the measured direction d in the tangent plane of v̂   (≈ B̂ᵀd, 2-vector)
//! H = [ B̂ᵀ / r̂ , 0₂ₓ₃ ]          R = σ_eff² · inflation · I₂  (+ vertical excess)
//! S = HPHᵀ + R ,  K = PHᵀS⁻¹ ,  P⁺ = (I − KH)P(I − KH)ᵀ + KRKᵀ   (Joseph form)
//! ```
//!
//! The residual is the rotation angle from v̂ to d along the great circle,
//! expressed on (b₁, b₂): ν = atan2(‖B̂ᵀd‖, v̂·d) · B̂ᵀd/‖B̂ᵀd‖. To first order it
//! is the theory's B̂ᵀd; unlike B̂ᵀd it is exact for a DoA rotated by a random
//! tangent angle, and a direction pointing *away* from the track gives a residual
//! near π, not near 0, so it is gated instead of accepted.
//!
//! A ray from a planar array on a ground robot ([`Ray::fold`]) is compared not
//! with the direction v̂ toward the predicted source but with what such an array
//! measures for it, h(p̂) ([`crate::floor_image`]: elevation folded onto the upper
//! hemisphere and pulled toward the floor image). B̂ is then built around h(p̂),
//! and H's position block is B̂ᵀ ∂h/∂p with the basis held fixed, h and ∂h/∂p
//! from one evaluation of the model
//! ([`crate::floor_image::FloorFold::measured_with_jacobian`]). Such an array
//! also resolves elevation worse than azimuth: R then carries the extra
//! variance along the vertical tangent
//! ([`Ray::angular_covariance`], [`Ray::vertical_excess`]).

use nalgebra::{
    Matrix2, Matrix2x6, Matrix3, Matrix3x2, Matrix6, Matrix6x2, Point3, Vector2, Vector3, Vector6,
};

use crate::ray::{Ray, tangent_basis};

/// Continuous white-noise acceleration power spectral densities q̃ (m²/s³): the
/// velocity of an axis random-walks with variance q̃·Δt (theory §4.1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProcessNoise {
    /// q̃ of the x and y axes (m²/s³).
    pub horizontal_m2_per_s3: f64,
    /// q̃ of the z axis (m²/s³); talkers change height slowly.
    pub vertical_m2_per_s3: f64,
}

/// The state transition F(Δt) = [I₃ Δt·I₃; 0 I₃].
pub fn transition(dt_s: f64) -> Matrix6<f64> {
    let mut f = Matrix6::identity();
    for k in 0..3 {
        f[(k, k + 3)] = dt_s;
    }
    f
}

/// The process noise Q(Δt) = q̃ [Δt³/3 Δt²/2; Δt²/2 Δt] per axis (theory §4.1).
pub fn process_noise(dt_s: f64, q: &ProcessNoise) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    let (dt2, dt3) = (dt_s * dt_s, dt_s * dt_s * dt_s);
    for k in 0..3 {
        let qk = if k < 2 { q.horizontal_m2_per_s3 } else { q.vertical_m2_per_s3 };
        m[(k, k)] = qk * dt3 / 3.0;
        m[(k, k + 3)] = qk * dt2 / 2.0;
        m[(k + 3, k)] = qk * dt2 / 2.0;
        m[(k + 3, k + 3)] = qk * dt_s;
    }
    m
}

/// Mean and covariance of the constant-velocity state, map frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CvState {
    /// [x, y, z, ẋ, ẏ, ż] (m, m/s).
    pub mean: Vector6<f64>,
    /// Its covariance (SI units squared).
    pub covariance: Matrix6<f64>,
}

impl CvState {
    /// A state from a position, a velocity and a 6×6 covariance.
    pub fn new(position: Point3<f64>, velocity: Vector3<f64>, covariance: Matrix6<f64>) -> CvState {
        let mut mean = Vector6::zeros();
        mean.fixed_rows_mut::<3>(0).copy_from(&position.coords);
        mean.fixed_rows_mut::<3>(3).copy_from(&velocity);
        CvState { mean, covariance }
    }

    /// Position, map frame (m).
    pub fn position(&self) -> Point3<f64> {
        Point3::from(self.mean.fixed_rows::<3>(0).into_owned())
    }

    /// Velocity, map frame (m/s).
    pub fn velocity(&self) -> Vector3<f64> {
        self.mean.fixed_rows::<3>(3).into_owned()
    }

    /// The 3×3 position block of the covariance (m²).
    pub fn position_covariance(&self) -> Matrix3<f64> {
        self.covariance.fixed_view::<3, 3>(0, 0).into_owned()
    }

    /// √tr of the position covariance (m): the predicted RMS 3-D position error.
    pub fn position_rms_m(&self) -> f64 {
        self.position_covariance().trace().max(0.0).sqrt()
    }

    /// True when every number of the mean and covariance is finite.
    pub fn is_finite(&self) -> bool {
        self.mean.iter().chain(self.covariance.iter()).all(|v| v.is_finite())
    }

    /// This state mirrored through the horizontal plane z = `plane_z`: height
    /// and vertical velocity change sign about it, and so do their
    /// covariances with the other components (`M P M`, M = diag(1, 1, −1, 1, 1, −1)).
    pub fn mirrored(&self, plane_z: f64) -> CvState {
        const SIGN: [f64; 6] = [1.0, 1.0, -1.0, 1.0, 1.0, -1.0];
        let mut mean = self.mean;
        mean[2] = 2.0 * plane_z - mean[2];
        mean[5] = -mean[5];
        let covariance = Matrix6::from_fn(|i, j| SIGN[i] * SIGN[j] * self.covariance[(i, j)]);
        CvState { mean, covariance }
    }

    /// This state predicted `dt_s` seconds ahead (dt ≥ 0).
    pub fn predicted(&self, dt_s: f64, q: &ProcessNoise) -> CvState {
        if dt_s == 0.0 {
            return *self;
        }
        let f = transition(dt_s);
        let p = f * self.covariance * f.transpose() + process_noise(dt_s, q);
        CvState { mean: f * self.mean, covariance: symmetric(&p) }
    }
}

/// How DoA rays are turned into measurement noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DoaNoiseModel {
    /// Factor on σ_eff² (theory §7: 1.5–2 for reverberant DoAs; 1 for the ideal model).
    pub variance_inflation: f64,
    /// Floor on the ray's σ (rad), so that no DoA gets infinite weight.
    pub min_sigma_rad: f64,
    /// A track closer than this to the array (m) gets no update: the far-field
    /// bearing model does not hold and the Jacobian blows up as 1/r̂.
    pub min_range_m: f64,
}

/// Why a DoA cannot update the filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Unusable {
    /// The ray or the state holds NaN or infinity.
    NonFinite,
    /// The predicted source is too close to the array (range in m).
    TooClose {
        /// Predicted range from the array centre (m).
        range_m: f64,
    },
}

/// A DoA linearized at a predicted state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DoaInnovation {
    /// ν on (b₁, b₂) (rad).
    pub residual: Vector2<f64>,
    /// Measurement Jacobian H = [B̂ᵀ/r̂, 0] (1/m).
    pub jacobian: Matrix2x6<f64>,
    /// Measurement noise variance per tangent axis, σ_eff² × inflation (rad²):
    /// the horizontal axis's for a ray with a vertical excess.
    pub noise_variance_rad2: f64,
    /// Measurement noise covariance R on (b₁, b₂), × inflation (rad²):
    /// `noise_variance_rad2`·I, plus the vertical excess of an array that
    /// resolves elevation worse ([`Ray::angular_covariance`]).
    pub noise_covariance: Matrix2<f64>,
    /// Innovation covariance S = HPHᵀ + R (rad²).
    pub covariance: Matrix2<f64>,
    /// S⁻¹.
    pub covariance_inv: Matrix2<f64>,
    /// Normalized innovation squared νᵀS⁻¹ν (χ², 2 dof when consistent).
    pub nis: f64,
    /// Predicted range r̂ (m).
    pub range_m: f64,
}

/// Linearizes `ray` at `state` (theory §4.2 B).
pub fn doa_innovation(state: &CvState, ray: &Ray, model: &DoaNoiseModel) -> Result<DoaInnovation, Unusable> {
    let finite = ray.origin_in_map.iter().chain(ray.direction_in_map.iter()).all(|v| v.is_finite())
        && ray.sigma_rad.is_finite()
        && ray.origin_sigma_m.is_finite()
        && state.is_finite();
    if !finite {
        return Err(Unusable::NonFinite);
    }
    let v = state.position() - ray.origin_in_map;
    let range_m = v.norm();
    if !(range_m >= model.min_range_m) || range_m == 0.0 {
        return Err(Unusable::TooClose { range_m });
    }
    let position = state.position();
    let folded = ray.fold.and_then(|f| f.measured_with_jacobian(&ray.origin_in_map, &position));
    let v_hat = folded.map_or(nalgebra::Unit::new_unchecked(v / range_m), |(at, _)| at);
    let (b1, b2) = tangent_basis(&v_hat);
    let basis = Matrix3x2::from_columns(&[b1, b2]);
    let d = ray.direction_in_map.into_inner() / ray.direction_in_map.norm();
    if !d.iter().all(|c| c.is_finite()) {
        return Err(Unusable::NonFinite);
    }
    let tangent = basis.transpose() * d;
    let sin = tangent.norm();
    let angle = sin.atan2(v_hat.dot(&d));
    let residual = if sin > 0.0 { tangent * (angle / sin) } else { Vector2::new(angle, 0.0) };

    let ray = Ray { sigma_rad: ray.sigma_rad.max(model.min_sigma_rad), ..*ray };
    let noise_variance_rad2 = ray.angular_variance(range_m) * model.variance_inflation;
    let noise_covariance = ray.angular_covariance(&basis, range_m) * model.variance_inflation;
    let mut jacobian = Matrix2x6::zeros();
    if let Some((_, dh)) = folded {
        // B̂ᵀ ∂h/∂p with the basis held fixed (FloorFold::measured_with_jacobian).
        let dh = basis.transpose() * dh;
        if !dh.iter().all(|v| v.is_finite()) {
            return Err(Unusable::NonFinite);
        }
        jacobian.fixed_view_mut::<2, 3>(0, 0).copy_from(&dh);
    } else {
        jacobian.fixed_view_mut::<2, 3>(0, 0).copy_from(&(basis.transpose() / range_m));
    }
    let covariance = symmetric2(&(jacobian * state.covariance * jacobian.transpose() + noise_covariance));
    let det = covariance[(0, 0)] * covariance[(1, 1)] - covariance[(0, 1)] * covariance[(1, 0)];
    if !(det > 0.0 && det.is_finite()) {
        return Err(Unusable::NonFinite);
    }
    let covariance_inv =
        Matrix2::new(covariance[(1, 1)], -covariance[(0, 1)], -covariance[(1, 0)], covariance[(0, 0)]) / det;
    let nis = (residual.transpose() * covariance_inv * residual)[0];
    Ok(DoaInnovation {
        residual,
        jacobian,
        noise_variance_rad2,
        noise_covariance,
        covariance,
        covariance_inv,
        nis,
        range_m,
    })
}

/// The Joseph-form update of `state` with `innovation`; `None` when the result
/// is not finite (the caller keeps the prior).
pub fn joseph_update(state: &CvState, innovation: &DoaInnovation) -> Option<CvState> {
    let p = &state.covariance;
    let h = &innovation.jacobian;
    let gain: Matrix6x2<f64> = p * h.transpose() * innovation.covariance_inv;
    let i_kh = Matrix6::identity() - gain * h;
    let covariance = i_kh * p * i_kh.transpose() + gain * innovation.noise_covariance * gain.transpose();
    let next = CvState { mean: state.mean + gain * innovation.residual, covariance: symmetric(&covariance) };
    next.is_finite().then_some(next)
}

/// (M + Mᵀ)/2: rounding keeps a covariance from drifting off symmetry.
pub(super) fn symmetric(m: &Matrix6<f64>) -> Matrix6<f64> {
    (m + m.transpose()) * 0.5
}

fn symmetric2(m: &Matrix2<f64>) -> Matrix2<f64> {
    (m + m.transpose()) * 0.5
}

#[cfg(test)]
mod tests {
    use nalgebra::Unit;

    use super::*;

    const MODEL: DoaNoiseModel =
        DoaNoiseModel { variance_inflation: 1.0, min_sigma_rad: 1e-4, min_range_m: 0.3 };

    fn state() -> CvState {
        let mut p = Matrix6::from_diagonal(&Vector6::new(0.04, 0.09, 0.02, 1.0, 0.5, 0.1));
        p[(0, 1)] = 0.01;
        p[(1, 0)] = 0.01;
        p[(0, 3)] = 0.05;
        p[(3, 0)] = 0.05;
        CvState::new(Point3::new(2.0, 3.0, 1.5), Vector3::new(0.3, -0.2, 0.05), p)
    }

    fn ray_through(origin: Point3<f64>, target: Point3<f64>) -> Ray {
        Ray {
            origin_in_map: origin,
            direction_in_map: Unit::new_normalize(target - origin),
            sigma_rad: 0.05,
            origin_sigma_m: 0.0,
            fold: None,
        }
    }

    #[test]
    fn a_mirrored_state_turns_height_and_climb_about_the_plane() {
        let mut s = state();
        s.covariance[(2, 0)] = 0.004;
        s.covariance[(0, 2)] = 0.004;
        s.covariance[(5, 3)] = 0.02;
        s.covariance[(3, 5)] = 0.02;
        let m = s.mirrored(0.5);
        assert_eq!(m.position(), Point3::new(2.0, 3.0, -0.5));
        assert_eq!(m.velocity(), Vector3::new(0.3, -0.2, -0.05));
        assert_eq!(m.covariance[(2, 0)], -0.004);
        assert_eq!(m.covariance[(5, 3)], -0.02);
        assert_eq!(m.covariance[(2, 2)], s.covariance[(2, 2)]);
        assert_eq!(m.covariance[(0, 1)], s.covariance[(0, 1)]);
        let back = m.mirrored(0.5);
        assert!((back.mean - s.mean).norm() < 1e-12 && back.covariance == s.covariance);
    }

    /// A planar array's weaker elevation ([`Ray::vertical_excess`]) enters R:
    /// the update leaves more of the height's variance than the same DoA with
    /// one σ, and the innovation is normalized by it.
    #[test]
    fn a_planar_arrays_elevation_noise_enters_the_update() {
        let s = state();
        let o = Point3::new(-1.0, 0.5, 0.5);
        let fold = |spread| Some(crate::floor_image::three_mic_fold(0.0, spread));
        let folded = Ray { sigma_rad: 0.02, fold: fold(None), ..ray_through(o, Point3::new(2.1, 2.9, 1.7)) };
        let planar = Ray { fold: fold(Some(0.0)), ..folded };
        let (one, two) =
            (doa_innovation(&s, &folded, &MODEL).unwrap(), doa_innovation(&s, &planar, &MODEL).unwrap());
        assert!(one.noise_covariance.determinant() < two.noise_covariance.determinant());
        assert_eq!(one.noise_variance_rad2, two.noise_variance_rad2);
        assert!(two.nis < one.nis);
        let (a, b) = (joseph_update(&s, &one).unwrap(), joseph_update(&s, &two).unwrap());
        assert!(b.covariance[(2, 2)] > a.covariance[(2, 2)]);
    }

    #[test]
    fn prediction_composes_exactly() {
        let q = ProcessNoise { horizontal_m2_per_s3: 0.7, vertical_m2_per_s3: 0.01 };
        let s = state();
        let once = s.predicted(0.5, &q);
        let twice = s.predicted(0.2, &q).predicted(0.3, &q);
        assert!((once.mean - twice.mean).norm() < 1e-12);
        assert!((once.covariance - twice.covariance).norm() < 1e-12);
    }

    #[test]
    fn jacobian_matches_finite_differences_of_the_residual() {
        let s = state();
        let o = Point3::new(-1.0, 0.5, 0.4);
        let ray = ray_through(o, Point3::new(2.1, 2.9, 1.6));
        let inn = doa_innovation(&s, &ray, &MODEL).unwrap();
        // The predicted measurement h(p) = B̂ᵀ(p − o)/‖p − o‖ with the basis held
        // fixed; its derivative at p̂ is H's position block (and ν = meas − h).
        let (b1, b2) = tangent_basis(&Unit::new_normalize(s.position() - o));
        let basis = Matrix3x2::from_columns(&[b1, b2]);
        let tangent_of = |p: Point3<f64>| basis.transpose() * (p - o).normalize();
        let eps = 1e-6;
        for k in 0..3 {
            let mut dp = Vector3::zeros();
            dp[k] = eps;
            let fd = (tangent_of(s.position() + dp) - tangent_of(s.position() - dp)) / (2.0 * eps);
            let h = inn.jacobian.fixed_view::<2, 1>(0, k).into_owned();
            assert!((fd - h).norm() < 1e-6, "axis {k}: {fd} vs {h}");
        }
    }

    #[test]
    fn joseph_form_equals_the_standard_form_for_the_optimal_gain() {
        let s = state();
        let ray = ray_through(Point3::new(5.0, 0.0, 0.5), Point3::new(2.2, 3.1, 1.4));
        let inn = doa_innovation(&s, &ray, &MODEL).unwrap();
        let post = joseph_update(&s, &inn).unwrap();
        let k = s.covariance * inn.jacobian.transpose() * inn.covariance.try_inverse().unwrap();
        let standard = s.covariance - k * inn.covariance * k.transpose();
        assert!((post.covariance - standard).norm() < 1e-12);
        assert!((post.mean - (s.mean + k * inn.residual)).norm() < 1e-12);
        // The update reduces uncertainty and the residual at the posterior shrinks.
        assert!(post.position_rms_m() < s.position_rms_m());
        let after = doa_innovation(&post, &ray, &MODEL).unwrap();
        assert!(after.residual.norm() < inn.residual.norm());
    }

    #[test]
    fn residual_is_the_rotation_angle_and_backward_rays_are_far() {
        let s = state();
        let o = Point3::new(0.0, 0.0, 1.5);
        let toward = s.position() - o;
        // Rotate by 0.3 rad about z: residual norm 0.3.
        let rot = nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 0.3);
        let ray = Ray { direction_in_map: Unit::new_normalize(rot * toward), ..ray_through(o, s.position()) };
        let inn = doa_innovation(&s, &ray, &MODEL).unwrap();
        assert!((inn.residual.norm() - 0.3).abs() < 1e-12);
        // Pointing exactly away: π, not 0.
        let away = Ray { direction_in_map: Unit::new_normalize(-toward), ..ray };
        let inn = doa_innovation(&s, &away, &MODEL).unwrap();
        assert!((inn.residual.norm() - std::f64::consts::PI).abs() < 1e-12);
        assert!(inn.nis > 1e3);
    }

    #[test]
    fn zero_range_and_nan_are_unusable_not_nan() {
        let s = state();
        let at_source = Ray { origin_in_map: s.position(), ..ray_through(Point3::origin(), s.position()) };
        assert_eq!(doa_innovation(&s, &at_source, &MODEL), Err(Unusable::TooClose { range_m: 0.0 }));
        let mut nan = ray_through(Point3::origin(), s.position());
        nan.sigma_rad = f64::NAN;
        assert_eq!(doa_innovation(&s, &nan, &MODEL), Err(Unusable::NonFinite));
    }
}
