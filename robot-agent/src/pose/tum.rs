//! TUM trajectory files: one pose per line, `t tx ty tz qx qy qz qw`, `t` in
//! seconds, translation in metres, quaternion with `w` last; `#` starts a
//! comment; blank lines are ignored. RTAB-Map and the SLAM evaluation tools
//! write this format.
//!
//! `t` is read exactly to the nanosecond (no f64 rounding of Unix-time seconds),
//! then mapped to the fleet timebase with a [`PoseTimeMapping`].

use std::path::Path;

use soundmap_proto::Stamp;

use super::{StampedPose, pose_from_components};
use crate::AgentError;

/// Maps a pose file's clock to the fleet timebase (Unix ns): file time
/// `file_start_ns` is fleet time `origin`. With the `start` option of a replay,
/// audio sample 0 (stamped `origin`) is at `t = start` seconds of the file's clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PoseTimeMapping {
    /// File time of `origin`, nanoseconds of the file's clock.
    pub file_start_ns: i64,
    /// Fleet time of `file_start_ns`.
    pub origin: Stamp,
}

impl PoseTimeMapping {
    /// File times are already Unix time.
    pub const UNIX: PoseTimeMapping = PoseTimeMapping { file_start_ns: 0, origin: Stamp::ZERO };

    /// File time `start_s` (seconds) is fleet time `origin`.
    pub fn new(start_s: f64, origin: Stamp) -> Self {
        PoseTimeMapping { file_start_ns: (start_s * 1e9).round() as i64, origin }
    }

    /// Fleet stamp of file time `file_ns`.
    pub fn map(&self, file_ns: i64) -> Stamp {
        self.origin.plus_ns(file_ns.saturating_sub(self.file_start_ns))
    }
}

/// Reads a TUM trajectory file. Errors name the file and line.
pub fn read_tum(path: &Path, mapping: PoseTimeMapping) -> Result<Vec<StampedPose>, AgentError> {
    let text = std::fs::read_to_string(path)
        .map_err(|source| AgentError::Io { path: path.to_path_buf(), source })?;
    parse_tum(&text, &path.display().to_string(), mapping)
}

/// Parses TUM trajectory text; `name` (the file) and the line number go into errors
/// as `name:line`. Times must strictly increase.
pub fn parse_tum(text: &str, name: &str, mapping: PoseTimeMapping) -> Result<Vec<StampedPose>, AgentError> {
    let mut poses: Vec<StampedPose> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let err = |message: String| AgentError::Pose { source_name: format!("{name}:{}", i + 1), message };
        let content = line.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let fields: Vec<&str> = content.split_whitespace().collect();
        if fields.len() != 8 {
            return Err(err(format!(
                "expected 8 values `t tx ty tz qx qy qz qw`, found {}: {content:?}",
                fields.len()
            )));
        }
        let t_ns = parse_seconds_ns(fields[0])
            .ok_or_else(|| err(format!("time {:?} is not a number of seconds", fields[0])))?;
        let mut v = [0.0; 7];
        const NAMES: [&str; 7] = ["tx", "ty", "tz", "qx", "qy", "qz", "qw"];
        for k in 0..7 {
            v[k] = fields[k + 1]
                .parse::<f64>()
                .map_err(|_| err(format!("{} {:?} is not a number", NAMES[k], fields[k + 1])))?;
        }
        let map_from_base =
            pose_from_components([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]]).map_err(err)?;
        let stamp = mapping.map(t_ns);
        if let Some(prev) = poses.last()
            && stamp <= prev.stamp
        {
            return Err(err(format!(
                "time {} s does not increase (previous pose at {:.9} s of the file's clock)",
                fields[0],
                (prev.stamp - mapping.origin + mapping.file_start_ns) as f64 * 1e-9
            )));
        }
        poses.push(StampedPose { stamp, map_from_base, covariance: None });
    }
    Ok(poses)
}

/// Parses decimal seconds to integer nanoseconds without going through f64 (so
/// Unix times keep their nanoseconds); exponent forms fall back to f64.
pub fn parse_seconds_ns(s: &str) -> Option<i64> {
    if s.contains(['e', 'E']) {
        let v: f64 = s.parse().ok()?;
        return (v.is_finite() && v.abs() < 9.2e9).then(|| (v * 1e9).round() as i64);
    }
    let (neg, digits) = match s.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, s.strip_prefix('+').unwrap_or(s)),
    };
    let (int, frac) = digits.split_once('.').unwrap_or((digits, ""));
    if (int.is_empty() && frac.is_empty())
        || !int.bytes().all(|b| b.is_ascii_digit())
        || !frac.bytes().all(|b| b.is_ascii_digit())
    {
        return None;
    }
    let whole: i64 = if int.is_empty() { 0 } else { int.parse().ok()? };
    let mut ns: i64 = 0;
    for k in 0..9 {
        ns = ns * 10 + frac.as_bytes().get(k).map_or(0, |b| (b - b'0') as i64);
    }
    if frac.as_bytes().get(9).is_some_and(|&b| b >= b'5') {
        ns += 1;
    }
    let total = whole.checked_mul(1_000_000_000)?.checked_add(ns)?;
    Some(if neg { -total } else { total })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_are_exact() {
        assert_eq!(parse_seconds_ns("1700000000.123456789"), Some(1_700_000_000_123_456_789));
        assert_eq!(parse_seconds_ns("1.5"), Some(1_500_000_000));
        assert_eq!(parse_seconds_ns(".25"), Some(250_000_000));
        assert_eq!(parse_seconds_ns("-0.5"), Some(-500_000_000));
        assert_eq!(parse_seconds_ns("0.0000000016"), Some(2));
        assert_eq!(parse_seconds_ns("1.3e2"), Some(130_000_000_000));
        assert_eq!(parse_seconds_ns("1.2.3"), None);
        assert_eq!(parse_seconds_ns("abc"), None);
        assert_eq!(parse_seconds_ns("."), None);
    }
}
