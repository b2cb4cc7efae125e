//! Constant-velocity Kalman filter of a direction on the unit sphere
//! (error-state filter in the tangent plane).
//!
//! State: a unit vector `d` with an orthonormal tangent basis `(e₁, e₂)`, and
//! the angular velocity `ω = ω₁e₁ + ω₂e₂` (rad/s) along the sphere. The
//! covariance `P` (4×4, rad² and rad²/s²) is over the tangent error
//! `(δθ₁, δθ₂, δω₁, δω₂)` expressed in `(e₁, e₂)`. Prediction moves `d` along
//! the great circle of `ω` and transports the basis with it (so `ω`'s
//! coordinates stay valid); an update measures `d` directly, the residual
//! being the log map of the measured direction at `d`.

use nalgebra::{Matrix2, Matrix2x4, Matrix4, Matrix4x2, Rotation3, Unit, Vector2, Vector3, Vector4};

/// The log map of unit vector `z` at unit vector `d`: the tangent vector at
/// `d` (radians, in the basis `(e₁, e₂)`) whose geodesic reaches `z`. Zero
/// when `z` is `d` or its antipode (no direction is defined there).
pub fn log_map(d: &Vector3<f64>, (e1, e2): (&Vector3<f64>, &Vector3<f64>), z: &Vector3<f64>) -> Vector2<f64> {
    let c = d.dot(z).clamp(-1.0, 1.0);
    let proj = z - d * c;
    let s = proj.norm();
    if s < 1e-15 {
        return Vector2::zeros();
    }
    let angle = s.atan2(c);
    Vector2::new(proj.dot(e1), proj.dot(e2)) * (angle / s)
}

/// Filter state.
#[derive(Clone, Debug)]
pub struct SphereKf {
    /// Direction, unit vector.
    pub d: Vector3<f64>,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
    /// Angular velocity in `(e₁, e₂)`, rad/s.
    pub omega: Vector2<f64>,
    /// Error covariance over `(δθ₁, δθ₂, δω₁, δω₂)`.
    pub p: Matrix4<f64>,
}

impl SphereKf {
    /// A filter at direction `d` with per-axis position variance `var_pos`
    /// (rad²), zero velocity with per-axis variance `var_vel` (rad²/s²).
    pub fn new(d: &Unit<Vector3<f64>>, var_pos: f64, var_vel: f64) -> Self {
        let (e1, e2) = crate::srp::refine::tangent_basis(d);
        let p = Matrix4::from_diagonal(&Vector4::new(var_pos, var_pos, var_vel, var_vel));
        SphereKf { d: d.into_inner(), e1, e2, omega: Vector2::zeros(), p }
    }

    /// Direction as a unit vector.
    pub fn direction(&self) -> Unit<Vector3<f64>> {
        Unit::new_unchecked(self.d)
    }

    /// Angular speed, rad/s.
    pub fn speed(&self) -> f64 {
        self.omega.norm()
    }

    /// 1-σ angular uncertainty per tangent axis, radians: `√(tr P_θθ / 2)`.
    pub fn sigma(&self) -> f64 {
        (0.5 * (self.p[(0, 0)] + self.p[(1, 1)])).max(0.0).sqrt()
    }

    /// Scales the angular velocity by `factor` ∈ [0, 1] with its uncertainty
    /// (velocity rows and columns of `P` by `factor`, so `P_ωω` by its square):
    /// the velocity step of an Ornstein–Uhlenbeck model, which a coasting
    /// track follows so that neither its direction nor its gate runs away.
    pub fn damp_velocity(&mut self, factor: f64) {
        let f = factor.clamp(0.0, 1.0);
        self.omega *= f;
        for i in 0..4 {
            for j in 2..4 {
                self.p[(i, j)] *= f;
                self.p[(j, i)] *= f;
            }
        }
    }

    /// Predicts `dt` seconds ahead with white angular-acceleration noise of
    /// spectral density `q` (rad²/s³) per axis.
    pub fn predict(&mut self, dt: f64, q: f64) {
        let t = self.e1 * self.omega.x + self.e2 * self.omega.y;
        let angle = t.norm() * dt;
        if angle > 1e-12 {
            let axis = Unit::new_normalize(self.d.cross(&t));
            self.rotate(&Rotation3::from_axis_angle(&axis, angle));
        }
        let mut f = Matrix4::identity();
        f[(0, 2)] = dt;
        f[(1, 3)] = dt;
        let (a, b, c) = (q * dt.powi(3) / 3.0, q * dt * dt / 2.0, q * dt);
        let mut qm = Matrix4::zeros();
        for i in 0..2 {
            qm[(i, i)] = a;
            qm[(i, i + 2)] = b;
            qm[(i + 2, i)] = b;
            qm[(i + 2, i + 2)] = c;
        }
        self.p = f * self.p * f.transpose() + qm;
    }

    /// Tangent residual of measurement `z` (log map at `d`), radians in `(e₁, e₂)`.
    pub fn residual(&self, z: &Vector3<f64>) -> Vector2<f64> {
        log_map(&self.d, (&self.e1, &self.e2), z)
    }

    /// The tangent basis `(e₁, e₂)` at `d`.
    pub fn basis(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.e1, self.e2)
    }

    /// Innovation covariance for a measurement of per-axis variance `r2`.
    pub fn innovation_cov(&self, r2: f64) -> Matrix2<f64> {
        self.innovation_cov_of(&(Matrix2::identity() * r2))
    }

    /// Innovation covariance for a measurement of covariance `r` (in `(e₁, e₂)`).
    pub fn innovation_cov_of(&self, r: &Matrix2<f64>) -> Matrix2<f64> {
        self.p.fixed_view::<2, 2>(0, 0).into_owned() + r
    }

    /// Squared Mahalanobis distance of measurement `z` (2 dof).
    pub fn mahalanobis2(&self, z: &Vector3<f64>, r2: f64) -> f64 {
        self.mahalanobis2_of(z, &(Matrix2::identity() * r2))
    }

    /// [`Self::mahalanobis2`] for a measurement of covariance `r`.
    pub fn mahalanobis2_of(&self, z: &Vector3<f64>, r: &Matrix2<f64>) -> f64 {
        let y = self.residual(z);
        let s = self.innovation_cov_of(r);
        s.try_inverse().map_or(f64::INFINITY, |si| (y.transpose() * si * y)[(0, 0)])
    }

    /// Kalman update with measurement `z` (unit vector) of per-axis variance `r2`.
    pub fn update(&mut self, z: &Vector3<f64>, r2: f64) {
        self.update_with(z, &(Matrix2::identity() * r2));
    }

    /// [`Self::update`] for a measurement of covariance `r` (in `(e₁, e₂)`).
    pub fn update_with(&mut self, z: &Vector3<f64>, r: &Matrix2<f64>) {
        let y = self.residual(z);
        let mut h = Matrix2x4::zeros();
        h[(0, 0)] = 1.0;
        h[(1, 1)] = 1.0;
        let s = self.innovation_cov_of(r);
        let Some(si) = s.try_inverse() else { return };
        let k: Matrix4x2<f64> = self.p * h.transpose() * si;
        let dx = k * y;
        // Joseph form keeps P symmetric positive definite.
        let ikh = Matrix4::identity() - k * h;
        self.p = ikh * self.p * ikh.transpose() + k * r * k.transpose();
        self.p = 0.5 * (self.p + self.p.transpose());
        self.omega += Vector2::new(dx[2], dx[3]);
        let t = self.e1 * dx[0] + self.e2 * dx[1];
        let angle = t.norm();
        if angle > 1e-15 {
            let axis = Unit::new_normalize(self.d.cross(&t));
            self.rotate(&Rotation3::from_axis_angle(&axis, angle));
        }
    }

    /// Re-expresses the filter in another frame: `new_from_old` maps vectors
    /// of the old frame to the new one (the array turned). The direction, its
    /// tangent basis and so the velocity's coordinates and the covariance all
    /// turn together, so nothing else changes.
    pub fn change_frame(&mut self, new_from_old: &Rotation3<f64>) {
        self.rotate(new_from_old);
    }

    /// Rotates the direction and its basis, re-orthonormalizing.
    fn rotate(&mut self, r: &Rotation3<f64>) {
        self.d = (r * self.d).normalize();
        let e1 = r * self.e1;
        self.e1 = (e1 - self.d * self.d.dot(&e1)).normalize();
        self.e2 = self.d.cross(&self.e1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_rotation_is_followed_exactly_without_noise() {
        let rate = 30f64.to_radians();
        let dt = 0.008;
        let at = |t: f64| Vector3::new((rate * t).cos(), (rate * t).sin(), 0.0);
        let mut kf = SphereKf::new(&Unit::new_normalize(at(0.0)), 1e-4, 1.0);
        for n in 1..500 {
            kf.predict(dt, 1e-3);
            kf.update(&at(n as f64 * dt), 1e-6);
        }
        assert!(kf.d.angle(&at(499.0 * dt)) < 1e-5);
        assert!((kf.speed() - rate).abs() < 1e-3);
        assert!(kf.sigma() < 1e-3);
    }

    #[test]
    fn a_frame_change_turns_the_state_rigidly() {
        let d = Unit::new_normalize(Vector3::new(1.0, 0.2, 0.3));
        let mut kf = SphereKf::new(&d, 1e-4, 1e-2);
        kf.omega = Vector2::new(0.3, -0.1);
        kf.p[(0, 1)] = 2e-5;
        kf.p[(1, 0)] = 2e-5;
        let world_velocity = kf.e1 * kf.omega.x + kf.e2 * kf.omega.y;
        let z = Vector3::new(0.9, 0.3, 0.25).normalize();
        let before = kf.mahalanobis2(&z, 1e-4);
        let r = Rotation3::from_euler_angles(0.1, -0.2, 1.3);
        kf.change_frame(&r);
        assert!((kf.d - r * d.into_inner()).norm() < 1e-12);
        let turned_velocity = kf.e1 * kf.omega.x + kf.e2 * kf.omega.y;
        assert!((turned_velocity - r * world_velocity).norm() < 1e-12);
        assert!((kf.mahalanobis2(&(r * z), 1e-4) - before).abs() < 1e-9);
    }

    #[test]
    fn residual_is_the_log_map() {
        let kf = SphereKf::new(&Vector3::z_axis(), 1.0, 1.0);
        let z = Vector3::new(0.5f64.sin(), 0.0, 0.5f64.cos());
        assert!((kf.residual(&z).norm() - 0.5).abs() < 1e-12);
        assert!(kf.mahalanobis2(&z, 0.0) > 0.0);
    }
}
