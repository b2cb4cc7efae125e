//! The acceptable band of the angle θ at the source between two robots, as
//! the planner needs it: both edges finite, 0 ≤ min < max ≤ 180 (degrees),
//! wider than twice the planner's θ hysteresis h, and containing 90° ± h.
//!
//! The planner owns this type; the configuration (`[active_positioning]`) and
//! the operator's run-time switch (`Monitoring.SetActivePositioning`) both
//! build a band through [`ThetaBand::new`], so one rule checks both.

use soundmap_proto::{Problem, ValidationError};

/// A checked θ band (degrees).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThetaBand {
    /// Lower edge (degrees, in [0, 180)).
    pub min_deg: f64,
    /// Upper edge (degrees, in (0, 180]).
    pub max_deg: f64,
}

impl ThetaBand {
    /// Checks a band: both edges finite, 0 ≤ min < max ≤ 180, wider than twice
    /// the planner's θ hysteresis h (else no θ could end a correction), and
    /// containing 90° ± h: the planner always aims at the Fisher-optimal
    /// geometry (90° between two robots), so a band without it could never be
    /// satisfied and would re-task the robots forever. Errors name
    /// `theta_min_deg` or `theta_max_deg`; relations between the two name
    /// `theta_max_deg` when `blame_max`, else `theta_min_deg`.
    pub fn new(min: f64, max: f64, hysteresis_deg: f64, blame_max: bool) -> Result<Self, ValidationError> {
        for (field, v, ok, range) in [
            ("theta_min_deg", min, (0.0..180.0).contains(&min), "[0, 180)"),
            ("theta_max_deg", max, max > 0.0 && max <= 180.0, "(0, 180]"),
        ] {
            if !v.is_finite() {
                return Err(ValidationError::new(field, Problem::NonFinite(v)));
            }
            if !ok {
                return Err(ValidationError::new(field, Problem::OutOfRange { value: v, range }));
            }
        }
        let field = if blame_max { "theta_max_deg" } else { "theta_min_deg" };
        if min >= max {
            return Err(ValidationError::new(
                field,
                Problem::Invalid(format!(
                    "band {min}°–{max}° is empty: theta_min_deg must be below theta_max_deg"
                )),
            ));
        }
        if max - min <= 2.0 * hysteresis_deg {
            return Err(ValidationError::new(
                field,
                Problem::Invalid(format!(
                    "band {min}°–{max}° is not wider than twice planner.theta_hysteresis_deg ({hysteresis_deg}°)"
                )),
            ));
        }
        for (field, outside) in
            [("theta_min_deg", min + hysteresis_deg >= 90.0), ("theta_max_deg", max - hysteresis_deg <= 90.0)]
        {
            if outside {
                return Err(ValidationError::new(
                    field,
                    Problem::Invalid(format!(
                        "band {min}°–{max}° must contain 90° ± planner.theta_hysteresis_deg ({hysteresis_deg}°), \
                         the geometry the planner aims at"
                    )),
                ));
            }
        }
        Ok(ThetaBand { min_deg: min, max_deg: max })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_are_checked_naming_the_field() {
        let check = |min, max, blame_max| ThetaBand::new(min, max, 5.0, blame_max);
        let field = |min, max, blame_max| check(min, max, blame_max).unwrap_err().field;
        assert_eq!(check(40.0, 140.0, false), Ok(ThetaBand { min_deg: 40.0, max_deg: 140.0 }));
        assert!(check(0.0, 180.0, false).is_ok());
        assert!(check(84.0, 96.0, false).is_ok());
        assert_eq!(field(-0.1, 140.0, false), "theta_min_deg");
        assert_eq!(field(f64::NAN, 140.0, true), "theta_min_deg");
        assert_eq!(field(40.0, 180.5, false), "theta_max_deg");
        assert_eq!(field(40.0, f64::INFINITY, false), "theta_max_deg");
        assert_eq!(field(100.0, 90.0, false), "theta_min_deg");
        assert_eq!(field(100.0, 90.0, true), "theta_max_deg");
        assert_eq!(field(86.0, 94.0, true), "theta_max_deg", "narrower than 2h");
        assert_eq!(field(86.0, 140.0, false), "theta_min_deg", "90° − h outside");
        assert_eq!(field(40.0, 94.0, false), "theta_max_deg", "90° + h outside");
        let e = check(100.0, 170.0, false).unwrap_err().to_string();
        assert!(e.starts_with("theta_min_deg: ") && e.contains("90°"), "{e}");
    }
}
