//! Pose inputs: TUM files, the JSON-lines feed over TCP, the pose buffer and the
//! attachment of poses to DoA frames.

use std::time::Duration;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;
use soundmap_agent::AgentError;
use soundmap_agent::pose::{
    Attached, Attacher, PoseBuffer, PoseBufferConfig, PoseLine, PoseLookupError, PoseTimeMapping,
    StampedPose, jsonl, parse_pose_line, parse_tum, read_tum,
};
use soundmap_proto::Stamp;
use tokio::io::AsyncWriteExt;

fn pose(ns: i64, x: f64, yaw_rad: f64) -> StampedPose {
    StampedPose {
        stamp: Stamp::from_ns(ns),
        map_from_base: Isometry3::from_parts(
            Translation3::new(x, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad),
        ),
        covariance: None,
    }
}

fn config(capacity: usize, max_gap_s: f64, tol_s: f64) -> PoseBufferConfig {
    PoseBufferConfig { capacity, max_gap_s, extrapolation_tolerance_s: tol_s }
}

fn pose_message(e: AgentError) -> (String, String) {
    match e {
        AgentError::Pose { source_name, message } => (source_name, message),
        other => panic!("expected a pose error, got {other:?}"),
    }
}

const TUM: &str = "\
# timestamp tx ty tz qx qy qz qw
1700000000.000000001 1.0 2.0 0.0 0 0 0 1

1700000000.5 2.0 2.0 0.0 0 0 0.7071067811865476 0.7071067811865476  # comment
1700000001.0 3.0 2.0 0.5 0 0 1 0
";

#[test]
fn tum_files_parse_with_exact_stamps_and_time_mapping() {
    let poses = parse_tum(TUM, "traj.txt", PoseTimeMapping::UNIX).unwrap();
    assert_eq!(poses.len(), 3);
    assert_eq!(poses[0].stamp, Stamp::from_ns(1_700_000_000_000_000_001));
    assert_eq!(poses[2].map_from_base.translation.vector, Vector3::new(3.0, 2.0, 0.5));
    let yaw = poses[1].map_from_base.rotation.euler_angles().2;
    assert!((yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-12);

    // Audio sample 0 (stamped `origin`) is at t = 1700000000.5 of the file's clock.
    let origin = Stamp::from_ns(5_000_000_000);
    let mapped = parse_tum(TUM, "traj.txt", PoseTimeMapping::new(1_700_000_000.5, origin)).unwrap();
    assert_eq!(mapped[1].stamp, origin);
    assert_eq!(mapped[2].stamp, origin.plus_ns(500_000_000));
    assert_eq!(mapped[0].stamp, origin.plus_ns(-499_999_999));

    let dir = tempfile::Builder::new().prefix("soundmap-pose-").tempdir().unwrap();
    let path = dir.path().join("traj.txt");
    std::fs::write(&path, TUM).unwrap();
    assert_eq!(read_tum(&path, PoseTimeMapping::UNIX).unwrap(), poses);
    let e = read_tum(&dir.path().join("none.txt"), PoseTimeMapping::UNIX).unwrap_err();
    assert!(e.to_string().contains("none.txt"), "{e}");
}

#[test]
fn tum_errors_name_the_file_and_line() {
    let cases = [
        ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n", 2, "expected 8 values"),
        ("1.0 0 0 0 0 0 0 1\n\n# c\n2.0 0 x 0 0 0 0 1\n", 4, "ty \"x\" is not a number"),
        ("1.0 0 0 0 0 0 0 1\nabc 0 0 0 0 0 0 1\n", 2, "not a number of seconds"),
        ("1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", 2, "does not increase"),
        ("1.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n", 2, "does not increase"),
        ("1.0 0 0 0 0 0 0 0\n", 1, "zero quaternion"),
        ("1.0 0 0 0 0 0 0 1.5\n", 1, "norm 1.5"),
        ("1.0 0 0 0 nan 0 0 1\n", 1, "not finite"),
        ("1.0 inf 0 0 0 0 0 1\n", 1, "translation"),
    ];
    for (text, line, what) in cases {
        let (source, message) = pose_message(parse_tum(text, "run3.tum", PoseTimeMapping::UNIX).unwrap_err());
        assert_eq!(source, format!("run3.tum:{line}"), "{text:?}: {message}");
        assert!(message.contains(what), "{text:?}: {message}");
    }
}

#[test]
fn buffer_interpolates_linearly_and_by_slerp() {
    let mut b = PoseBuffer::new("slam", config(100, 1.0, 0.0)).unwrap();
    b.push(pose(1_000_000_000, 0.0, 0.0)).unwrap();
    b.push(pose(1_400_000_000, 4.0, std::f64::consts::FRAC_PI_2)).unwrap();
    let p = b.lookup(Stamp::from_ns(1_100_000_000)).unwrap();
    assert_eq!(p.stamp, Stamp::from_ns(1_100_000_000));
    assert!((p.map_from_base.translation.vector.x - 1.0).abs() < 1e-12);
    let yaw = p.map_from_base.rotation.euler_angles().2;
    assert!((yaw - std::f64::consts::FRAC_PI_8).abs() < 1e-12, "yaw {yaw}");
    // Exactly at a pose.
    let p = b.map_from_base(Stamp::from_ns(1_400_000_000)).unwrap();
    assert!((p.translation.vector.x - 4.0).abs() < 1e-12);
}

#[test]
fn buffer_limits_give_clear_outcomes() {
    let mut b = PoseBuffer::new("slam", config(3, 0.3, 0.01)).unwrap();
    assert_eq!(b.lookup(Stamp::from_ns(5)), Err(PoseLookupError::Empty));
    b.push(pose(1_000_000_000, 0.0, 0.0)).unwrap();
    b.push(pose(1_200_000_000, 1.0, 0.0)).unwrap();
    b.push(pose(1_600_000_000, 2.0, 0.0)).unwrap(); // 0.4 s gap
    // Within the tolerance outside the buffer: the end pose, held.
    let p = b.lookup(Stamp::from_ns(1_605_000_000)).unwrap();
    assert_eq!(p.map_from_base.translation.vector.x, 2.0);
    assert_eq!(b.lookup(Stamp::from_ns(995_000_000)).unwrap().map_from_base.translation.vector.x, 0.0);
    // Beyond it.
    assert_eq!(
        b.lookup(Stamp::from_ns(1_700_000_000)),
        Err(PoseLookupError::AfterLast {
            at: Stamp::from_ns(1_700_000_000),
            last: Stamp::from_ns(1_600_000_000)
        })
    );
    assert!(matches!(b.lookup(Stamp::from_ns(900_000_000)), Err(PoseLookupError::BeforeFirst { .. })));
    // Inside the 0.4 s gap (max 0.3 s).
    let e = b.lookup(Stamp::from_ns(1_300_000_000)).unwrap_err();
    assert!(matches!(e, PoseLookupError::Gap { .. }));
    assert!(e.to_string().contains("0.400 s apart"), "{e}");
    let (source, message) = pose_message(b.map_from_base(Stamp::from_ns(1_300_000_000)).unwrap_err());
    assert_eq!(source, "slam");
    assert!(message.contains("apart"));
    // Non-increasing time.
    let (_, message) = pose_message(b.push(pose(1_600_000_000, 0.0, 0.0)).unwrap_err());
    assert!(message.contains("does not increase"), "{message}");
    // Bounded: the oldest pose goes.
    b.push(pose(1_700_000_000, 3.0, 0.0)).unwrap();
    assert_eq!(b.len(), 3);
    assert_eq!(b.dropped(), 1);
    assert!(matches!(b.lookup(Stamp::from_ns(1_000_000_000)), Err(PoseLookupError::BeforeFirst { .. })));
    // Bad limits are rejected.
    let (_, message) = pose_message(PoseBuffer::new("slam", config(1, 0.3, 0.0)).unwrap_err());
    assert!(message.starts_with("capacity"), "{message}");
    let (_, message) = pose_message(PoseBuffer::new("slam", config(5, -1.0, 0.0)).unwrap_err());
    assert!(message.starts_with("max_gap_s"), "{message}");
}

proptest! {
    /// Between two poses rotated about one axis, the interpolated rotation is about
    /// that axis at the linearly interpolated angle, whatever the quaternion signs.
    #[test]
    fn slerp_is_linear_in_angle(
        angle in -3.0f64..3.0, t in 0.0f64..=1.0, ax in -1.0f64..1.0, ay in -1.0f64..1.0, flip in any::<bool>()
    ) {
        let axis = nalgebra::Unit::new_normalize(Vector3::new(ax, ay, 1.0));
        let base = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0);
        let a = StampedPose { stamp: Stamp::from_ns(0), map_from_base: Isometry3::from_parts(Translation3::identity(), base), covariance: None };
        let mut q = UnitQuaternion::from_axis_angle(&axis, angle) * base;
        if flip { q = UnitQuaternion::new_unchecked(-q.into_inner()); }
        let b = StampedPose { stamp: Stamp::from_ns(1_000_000), map_from_base: Isometry3::from_parts(Translation3::new(1.0, 2.0, 3.0), q), covariance: None };
        let at = Stamp::from_ns((t * 1e6).round() as i64);
        let t = at.as_ns() as f64 / 1e6;
        let m = soundmap_agent::pose::interpolate(&a, &b, at);
        let want = UnitQuaternion::from_axis_angle(&axis, angle * t) * base;
        prop_assert!(m.map_from_base.rotation.angle_to(&want) < 1e-9);
        prop_assert!((m.map_from_base.translation.vector - Vector3::new(1.0, 2.0, 3.0) * t).norm() < 1e-12);
    }
}

#[test]
fn json_lines_parse_and_reject_with_line_numbers() {
    let p = parse_pose_line(
        r#"{"stamp_ns": 1700000000123456789, "x": 1, "y": 2, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1}"#,
        "bridge",
        1,
    )
    .unwrap();
    assert_eq!(p.stamp, Stamp::from_ns(1_700_000_000_123_456_789));
    assert_eq!(p.map_from_base.translation.vector, Vector3::new(1.0, 2.0, 0.0));
    // Round trip through the writer side, with a covariance.
    let mut q = pose(42, 1.5, 0.4);
    q.covariance = Some(nalgebra::Matrix6::identity() * 0.01);
    let line = serde_json::to_string(&PoseLine::from_pose(&q)).unwrap();
    let back = parse_pose_line(&line, "bridge", 2).unwrap();
    assert_eq!(back.covariance, q.covariance);
    assert!(back.map_from_base.rotation.angle_to(&q.map_from_base.rotation) < 1e-12);

    let bad = [
        (r#"{"stamp_ns": 1, "x": 1, "y": 2, "z": 0, "qx": 0, "qy": 0, "qz": 0}"#, "missing field `qw`"),
        (
            r#"{"stamp_ns": 1, "x": 1, "y": 2, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1, "yaw": 3}"#,
            "unknown field `yaw`",
        ),
        (r#"{"stamp_ns": 1, "x": 1, "y": 2, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 0}"#, "zero quaternion"),
        (
            r#"{"stamp_ns": 1, "x": 1, "y": 2, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1, "covariance": [1, 2]}"#,
            "36 values",
        ),
        ("stamp_ns=1", "malformed pose line"),
    ];
    for (line, what) in bad {
        let (source, message) = pose_message(parse_pose_line(line, "bridge", 17).unwrap_err());
        assert_eq!(source, "bridge:17");
        assert!(message.contains(what), "{line}: {message}");
    }
}

#[tokio::test]
async fn tcp_feed_forwards_valid_poses_and_skips_bad_lines() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::channel(16);
    let server = tokio::spawn(jsonl::serve_tcp(listener, tx));
    for round in 0..2 {
        // A bridge connects, sends, disconnects; then reconnects.
        let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
        let base = round * 10;
        let mut text = String::new();
        for k in 0..3 {
            let p = pose((base + k) as i64 * 1_000_000, k as f64, 0.0);
            text += &serde_json::to_string(&PoseLine::from_pose(&p)).unwrap();
            text += "\n";
            if k == 1 {
                text += "{\"oops\": true}\n";
                // Not increasing: skipped.
                text += &serde_json::to_string(&PoseLine::from_pose(&pose(0, 9.0, 0.0))).unwrap();
                text += "\n";
            }
        }
        s.write_all(text.as_bytes()).await.unwrap();
        drop(s);
        for k in 0..3 {
            let p = tokio::time::timeout(Duration::from_secs(5), rx.recv()).await.unwrap().unwrap();
            assert_eq!(p.stamp, Stamp::from_ns((base + k) as i64 * 1_000_000));
            assert_eq!(p.map_from_base.translation.vector.x, k as f64);
        }
    }
    drop(rx);
    server.abort();
}

#[test]
fn frames_wait_for_their_pose_then_get_it_or_are_dropped() {
    let buffer = PoseBuffer::new("slam", config(100, 0.5, 0.0)).unwrap();
    let mut a: Attacher<&str> = Attacher::new(buffer, 0.2, 10);
    let mut out = vec![];
    let s = |ms: i64| Stamp::from_ns(ms * 1_000_000);
    a.push_pose(pose(s(0).as_ns(), 0.0, 0.0)).unwrap();
    a.push_frame(s(50), "a", &mut out);
    a.push_frame(s(100), "b", &mut out);
    a.poll(s(120), &mut out);
    assert!(out.is_empty(), "the pose after 50 ms has not arrived yet");
    assert_eq!(a.pending(), 2);
    a.push_pose(pose(s(80).as_ns(), 8.0, 0.0)).unwrap();
    a.poll(s(130), &mut out);
    assert_eq!(out.len(), 1);
    match &out[0] {
        Attached::Ready { pose, payload } => {
            assert_eq!(*payload, "a");
            assert_eq!(pose.stamp, s(50));
            assert!((pose.map_from_base.translation.vector.x - 5.0).abs() < 1e-12);
        }
        other => panic!("{other:?}"),
    }
    out.clear();
    // "b" (100 ms) waits until 300 ms, then is dropped.
    a.poll(s(299), &mut out);
    assert!(out.is_empty());
    a.poll(s(300), &mut out);
    assert!(matches!(
        &out[0],
        Attached::Dropped { payload: "b", reason: PoseLookupError::AfterLast { .. }, .. }
    ));
    out.clear();
    // After the end of a replayed trajectory nothing waits.
    a.push_frame(s(400), "c", &mut out);
    a.finish_poses();
    a.poll(s(400), &mut out);
    assert!(matches!(&out[0], Attached::Dropped { payload: "c", .. }));
    out.clear();
    // A frame older than the buffer is dropped at once.
    a.push_frame(s(-100), "d", &mut out);
    a.poll(s(0), &mut out);
    assert!(matches!(
        &out[0],
        Attached::Dropped { payload: "d", reason: PoseLookupError::BeforeFirst { .. }, .. }
    ));
}
