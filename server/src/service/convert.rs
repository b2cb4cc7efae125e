//! Domain → wire conversions of the coordinator's estimator types for
//! monitoring (source estimates: triangulation, filtered state), and the
//! JSON-lines form of an estimate. Those of the types the contract shares
//! (robot state, liveness, planner status, active positioning, covariance
//! read-back) are in [`soundmap_proto::monitoring`].

use nalgebra::Point3;
use soundmap_proto::geometry::covariance3_to_wire;
use soundmap_proto::monitoring::finite_or;
use soundmap_proto::{vec3_to_wire, wire};

use crate::coordinator::{BestSource, Estimate};
use crate::tracking::{SmoothedEstimate, TrackEstimate, TrackState};
use crate::triangulation::{Gate, Method, Triangulation};

fn method(m: Method) -> wire::EstimateMethod {
    match m {
        Method::RayPair => wire::EstimateMethod::RayPair,
        Method::LeastSquares => wire::EstimateMethod::LeastSquares,
        Method::LevenbergMarquardt => wire::EstimateMethod::LevenbergMarquardt,
    }
}

fn point(p: &Point3<f64>) -> wire::Vec3 {
    vec3_to_wire(&p.coords)
}

/// The wire form of a triangulation.
pub fn triangulation_to_wire(t: &Triangulation, robots: &[String]) -> wire::Triangulation {
    match t {
        Triangulation::Solved(s) => wire::Triangulation {
            method: method(s.method) as i32,
            position_in_map_m: Some(point(&s.source_in_map)),
            covariance: s.quality.covariance.as_ref().map(covariance3_to_wire),
            gdop: finite_or(s.quality.gdop, 0.0),
            theta_deg: s.quality.theta_deg,
            pairwise_theta: s
                .quality
                .pairwise_theta_deg
                .iter()
                .map(|(i, j, th)| wire::RobotPairAngle {
                    robot_a: robots[*i].clone(),
                    robot_b: robots[*j].clone(),
                    theta_deg: *th,
                })
                .collect(),
            condition_number: finite_or(s.condition_number, 0.0),
            miss_distance_m: s.miss_distance_m.unwrap_or(0.0),
            residual_chi2: finite_or(s.residual_chi2, 0.0),
            gate: match s.gate {
                Gate::Accepted => wire::GateDecision::Accepted,
                Gate::Rejected(_) => wire::GateDecision::Rejected,
            } as i32,
            gate_reason: match s.gate {
                Gate::Accepted => String::new(),
                Gate::Rejected(r) => r.to_string(),
            },
            robots: robots.to_vec(),
        },
        Triangulation::Degenerate(d) => wire::Triangulation {
            method: wire::EstimateMethod::Unspecified as i32,
            gate: wire::GateDecision::Rejected as i32,
            gate_reason: d.to_string(),
            robots: robots.to_vec(),
            ..Default::default()
        },
    }
}

/// The wire form of a track's state.
pub fn filtered_to_wire(f: &TrackEstimate) -> wire::FilteredState {
    wire::FilteredState {
        position_in_map_m: Some(point(&f.position_in_map)),
        velocity_in_map_m_s: Some(vec3_to_wire(&f.velocity_in_map)),
        position_covariance: Some(covariance3_to_wire(&f.position_covariance())),
        state: match f.state {
            TrackState::Tentative => wire::TrackState::Tentative,
            TrackState::Confirmed => wire::TrackState::Confirmed,
            TrackState::Lost(_) => wire::TrackState::Lost,
        } as i32,
        last_nis: f.last_nis.map_or(0.0, |v| finite_or(v, 0.0)),
        trusted: f.trusted,
        position_rms_m: finite_or(f.position_rms_m, 0.0),
        mean_nis: f.mean_nis.map_or(0.0, |v| finite_or(v, 0.0)),
        doas_applied: f.counts.applied,
        doas_gated: f.counts.gated,
    }
}

/// The wire form of an estimate's smoothed state, with its published
/// covariance and trust ([`Estimate::smoothed_covariance`], [`Estimate::smoothed_trusted`]).
pub fn smoothed_to_wire(e: &Estimate, s: &SmoothedEstimate) -> wire::SmoothedState {
    wire::SmoothedState {
        stamp_ns: s.stamp.as_ns(),
        lag_s: finite_or(s.lag_s, 0.0),
        position_in_map_m: Some(point(&s.position_in_map)),
        velocity_in_map_m_s: Some(vec3_to_wire(&s.velocity_in_map)),
        position_covariance: e.smoothed_covariance().as_ref().map(covariance3_to_wire),
        trusted: e.smoothed_trusted(),
    }
}

/// The wire form of an estimate: the best position (filtered when the track
/// is trusted, else the triangulation's), the triangulation, the filtered state.
pub fn estimate_to_wire(e: &Estimate) -> wire::SourceEstimate {
    let robots: Vec<String> = e.robots.iter().map(|r| r.to_string()).collect();
    let tri = triangulation_to_wire(&e.triangulation, &robots);
    let method = match e.best_source() {
        BestSource::Filter => wire::EstimateMethod::KalmanFilter as i32,
        BestSource::Triangulation => tri.method,
    };
    wire::SourceEstimate {
        source_id: e.source_id,
        stamp_ns: e.stamp.as_ns(),
        position_in_map_m: e.position().as_ref().map(point),
        covariance: e.covariance().as_ref().map(covariance3_to_wire),
        gdop: tri.gdop,
        theta_deg: e.theta_deg(),
        robots,
        method,
        trusted: e.trusted(),
        triangulation: Some(tri),
        filtered: e.filtered.as_ref().map(filtered_to_wire),
        lagged: 0,
        smoothed: e.smoothed.as_ref().map(|s| smoothed_to_wire(e, s)),
    }
}

/// One line of the estimates JSON-lines file (no trailing newline):
/// `{"stamp_ns", "source_id", "x", "y", "z", "cov" (9 values, m², row-major),
/// "gdop", "theta_deg", "robots", "trusted", "method"}`, and `"smoothed":
/// {"stamp_ns", "x", "y", "z", "cov", "trusted"}` when the estimate carries a smoothed
/// state. `None` without a position.
pub fn estimate_to_json_line(e: &wire::SourceEstimate) -> Option<String> {
    let p = e.position_in_map_m.as_ref()?;
    let cov: Vec<f64> = e.covariance.as_ref().map(|c| c.values_m2.clone()).unwrap_or_default();
    let method = wire::EstimateMethod::try_from(e.method).map_or("unspecified", |m| match m {
        wire::EstimateMethod::RayPair => "ray_pair",
        wire::EstimateMethod::LeastSquares => "least_squares",
        wire::EstimateMethod::LevenbergMarquardt => "levenberg_marquardt",
        wire::EstimateMethod::KalmanFilter => "kalman_filter",
        wire::EstimateMethod::Unspecified => "unspecified",
    });
    let mut v = serde_json::json!({
        "stamp_ns": e.stamp_ns,
        "source_id": e.source_id,
        "x": p.x, "y": p.y, "z": p.z,
        "cov": cov,
        "gdop": e.gdop,
        "theta_deg": e.theta_deg,
        "robots": e.robots,
        "trusted": e.trusted,
        "method": method,
    });
    if let Some(s) = &e.smoothed
        && let Some(p) = &s.position_in_map_m
    {
        let cov: Vec<f64> = s.position_covariance.as_ref().map(|c| c.values_m2.clone()).unwrap_or_default();
        v["smoothed"] = serde_json::json!({
            "stamp_ns": s.stamp_ns, "x": p.x, "y": p.y, "z": p.z, "cov": cov, "trusted": s.trusted,
        });
    }
    Some(v.to_string())
}
