//! Helpers shared by the unit tests of the filter's modes and the smoother.

use nalgebra::{Matrix6, Point3, Unit, Vector3, Vector6};

use super::filter::{CvState, DoaNoiseModel, ProcessNoise};
use super::imm::{Diffusion, ImmState, Modes};
use crate::ray::Ray;

/// The ideal DoA noise model (no inflation).
pub(super) const MODEL: DoaNoiseModel =
    DoaNoiseModel { variance_inflation: 1.0, min_sigma_rad: 1e-4, min_range_m: 0.3 };

/// The default modes (still D 0.002 / 0.0005 m²/s, moving q̃ 0.5 / 0.01 m²/s³)
/// with mean sojourn `sojourn_s`.
pub(super) const fn modes(sojourn_s: f64) -> Modes {
    Modes {
        still: Some(Diffusion { horizontal_m2_per_s: 0.002, vertical_m2_per_s: 0.0005 }),
        moving: ProcessNoise { horizontal_m2_per_s3: 0.5, vertical_m2_per_s3: 0.01 },
        sojourn_s,
    }
}

/// Both modes at `at`, still, with position variance `position_var_m2` per axis.
pub(super) fn start(at: Point3<f64>, position_var_m2: f64) -> ImmState {
    let v = position_var_m2;
    let p = Matrix6::from_diagonal(&Vector6::new(v, v, v, 1.0, 1.0, 0.09));
    ImmState::new(CvState::new(at, Vector3::zeros(), p))
}

/// An exact ray from `origin` through `target` reported with `sigma_rad`.
pub(super) fn ray(origin: Point3<f64>, target: Point3<f64>, sigma_rad: f64) -> Ray {
    Ray {
        origin_in_map: origin,
        direction_in_map: Unit::new_normalize(target - origin),
        sigma_rad,
        origin_sigma_m: 0.0,
        fold: None,
    }
}
