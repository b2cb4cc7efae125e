//! Scenario checks the types cannot express. Errors name the key.

use soundmap_agent::array::ArrayGeometry;
use soundmap_proto::RobotId;

use super::Scenario;
use crate::error::SimError;

impl Scenario {
    /// Checks every value before anything starts.
    pub(super) fn validate(&self, origin: &str) -> Result<(), SimError> {
        let err =
            |field: String, message: String| Err(SimError::Scenario { path: origin.into(), field, message });
        let finite_positive = |v: f64| v.is_finite() && v > 0.0;
        if !finite_positive(self.duration_s) || self.duration_s > 3600.0 {
            return err("duration_s".into(), format!("{} not in (0, 3600]", self.duration_s));
        }
        let room = &self.room;
        if room.size_m.iter().any(|v| !finite_positive(*v))
            || room.min_corner_m.iter().any(|v| !v.is_finite())
        {
            return err("room".into(), "min_corner_m must be finite and size_m positive".into());
        }
        if !(0.05..=3.0).contains(&room.rt60_s) {
            return err("room.rt60_s".into(), format!("{} not in [0.05, 3] s", room.rt60_s));
        }
        let inside = |x: f64, y: f64| {
            x > room.min_corner_m[0]
                && x < room.min_corner_m[0] + room.size_m[0]
                && y > room.min_corner_m[1]
                && y < room.min_corner_m[1] + room.size_m[1]
        };
        for (i, poly) in room.obstacles.iter().enumerate() {
            if poly.len() < 3 || poly.iter().flatten().any(|v| !v.is_finite()) {
                return err(format!("room.obstacles[{i}]"), "needs at least 3 finite [x, y] points".into());
            }
        }
        let n = &self.noise;
        if !n.sensor_snr_db.is_finite() || n.diffuse_snr_db.is_some_and(|v| !v.is_finite()) {
            return err("noise".into(), "SNRs must be finite (dB)".into());
        }
        if !finite_positive(n.reference_distance_m) {
            return err(
                "noise.reference_distance_m".into(),
                format!("{} must be positive", n.reference_distance_m),
            );
        }
        let s = &self.slam;
        for (k, v) in [
            ("position_white_std_m", s.position_white_std_m),
            ("yaw_white_std_deg", s.yaw_white_std_deg),
            ("drift_position_std_m", s.drift_position_std_m),
            ("drift_yaw_std_deg", s.drift_yaw_std_deg),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return err(format!("slam.{k}"), format!("{v} must be ≥ 0"));
            }
        }
        if !finite_positive(s.drift_time_constant_s) {
            return err("slam.drift_time_constant_s".into(), "must be positive".into());
        }
        if self.robots.len() < 2 {
            return err(
                "robots".into(),
                format!("{} robot(s): at least 2 are needed to triangulate", self.robots.len()),
            );
        }
        for (i, r) in self.robots.iter().enumerate() {
            let at = |k: &str| format!("robots[{i}].{k}");
            if let Err(e) = RobotId::parse(&r.id, &at("id")) {
                return err(e.field, e.problem.to_string());
            }
            if self.robots[..i].iter().any(|o| o.id == r.id) {
                return err(at("id"), format!("duplicate robot id {:?}", r.id));
            }
            if let Err(e) = ArrayGeometry::load(&r.array) {
                return err(at("array"), e.to_string());
            }
            if r.start.iter().any(|v| !v.is_finite()) || !inside(r.start[0], r.start[1]) {
                return err(at("start"), format!("{:?} must be finite and inside the room", r.start));
            }
            let mut last_t = f64::NEG_INFINITY;
            for (k, w) in r.waypoints.iter().enumerate() {
                if !inside(w.x_m, w.y_m) {
                    return err(
                        at(&format!("waypoints[{k}]")),
                        format!("({}, {}) is outside the room", w.x_m, w.y_m),
                    );
                }
                if let Some(t) = w.t_s {
                    if !(t.is_finite() && t >= last_t) {
                        return err(at(&format!("waypoints[{k}].t_s")), "times must not decrease".into());
                    }
                    last_t = t;
                }
            }
            if !finite_positive(r.max_speed_m_per_s) || r.max_speed_m_per_s > 2.0 {
                return err(at("max_speed_m_per_s"), format!("{} not in (0, 2]", r.max_speed_m_per_s));
            }
            if !finite_positive(r.max_turn_rate_deg_per_s) {
                return err(at("max_turn_rate_deg_per_s"), "must be positive".into());
            }
        }
        if self.sources.is_empty() {
            return err("sources".into(), "at least one source is needed".into());
        }
        for (i, src) in self.sources.iter().enumerate() {
            let at = |k: &str| format!("sources[{i}].{k}");
            if src.path.is_empty() {
                return err(at("path"), "needs at least one point".into());
            }
            let mut last_t = f64::NEG_INFINITY;
            for (k, p) in src.path.iter().enumerate() {
                if !(p.t_s.is_finite() && p.t_s > last_t) {
                    return err(at(&format!("path[{k}].t_s")), "times must increase".into());
                }
                last_t = p.t_s;
                let z_ok = p.z_m > room.min_corner_m[2] && p.z_m < room.min_corner_m[2] + room.size_m[2];
                if !inside(p.x_m, p.y_m) || !z_ok {
                    return err(
                        at(&format!("path[{k}]")),
                        format!("({}, {}, {}) is outside the room", p.x_m, p.y_m, p.z_m),
                    );
                }
            }
            let signal = crate::acoustics::SourceSignal {
                waveform: src.signal.waveform(),
                ..crate::acoustics::SourceSignal::white_noise(1.0, 0)
            };
            if let Err(SimError::InvalidConfig { field, reason }) =
                signal.validate(f64::from(self.agent.sample_rate_hz))
            {
                let key = field.strip_prefix("signal.").unwrap_or(field);
                return err(at(&format!("signal.{key}")), reason);
            }
            if !finite_positive(src.rms) {
                return err(at("rms"), format!("{} must be positive", src.rms));
            }
            for (k, [a, b]) in src.active.iter().enumerate() {
                if !(a.is_finite() && b.is_finite() && a < b) {
                    return err(
                        at(&format!("active[{k}]")),
                        format!("[{a}, {b}] must be an increasing interval"),
                    );
                }
            }
        }
        let a = &self.active_positioning;
        if !(a.theta_min_deg >= 0.0 && a.theta_min_deg < a.theta_max_deg && a.theta_max_deg <= 180.0) {
            return err(
                "active_positioning".into(),
                format!("θ band [{}, {}] must satisfy 0 ≤ min < max ≤ 180", a.theta_min_deg, a.theta_max_deg),
            );
        }
        Ok(())
    }
}
