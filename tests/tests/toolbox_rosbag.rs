//! ROS 2 bags in: bags written by the `rosbags` Python library (the standard
//! pure-Python rosbag2 writer) from the simulator's own recording replay to
//! the same estimates as the WAV + TUM files they were made from, and broken
//! bags fail with errors that name what is wrong.

use std::path::{Path, PathBuf};

use soundmap_sim::pytools;
use soundmap_sim::replay::{ReplayArgs, RobotRecording, TruthTrack, parse_robot, replay};
use soundmap_sim::runner::{RunOptions, SIM_EPOCH, run};
use soundmap_sim::scenario::Scenario;
use soundmap_sim::viewer::ViewArgs;

/// A scratch directory for one test, removed when dropped.
fn temp_dir(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new().prefix(&format!("soundmap-rosbag-{name}-")).tempdir().unwrap()
}

fn args(
    robots: Vec<RobotRecording>,
    truths: Vec<TruthTrack>,
    out: PathBuf,
    bag: Option<&Path>,
) -> ReplayArgs {
    ReplayArgs {
        robots,
        truths,
        out,
        coordinator_config: None,
        pipeline: None,
        max_pose_gap_s: 0.5,
        view: ViewArgs::default(),
        rosbag: bag.map(Path::to_path_buf),
    }
}

/// Writes a bag of `recorded` with `write_rosbag.py` (`variant`: normal, gap, bad-definition).
fn write_bag(recorded: &[RobotRecording], dir: &Path, bag: &Path, format: &str, variant: &str) {
    let mut a: Vec<String> = vec![
        "--out".into(),
        bag.display().to_string(),
        "--origin-ns".into(),
        SIM_EPOCH.as_ns().to_string(),
        "--format".into(),
        format.into(),
        "--variant".into(),
        variant.into(),
        "--truth-in".into(),
        dir.join("source.tum").display().to_string(),
        "--truth-out".into(),
        dir.join("truth-unix.tum").display().to_string(),
    ];
    for r in recorded {
        a.push("--robot".into());
        a.push(format!("{}:{}:{}", r.id, dir.join(format!("{}.wav", r.id)).display(), r.poses.display()));
    }
    pytools::run("tests/python/write_rosbag.py", &a);
}

/// The `--robot` arguments reading `recorded`'s robots from a bag written by write_rosbag.py.
fn bag_robots(recorded: &[RobotRecording], base_frame: Option<&str>) -> Vec<RobotRecording> {
    recorded
        .iter()
        .map(|r| {
            let base = base_frame.map_or(format!("{}/base_link", r.id), str::to_string);
            parse_robot(&format!(
                "id={id},audio_topic=/{id}/audio/audio_stamped,array={array},base_frame={base},pose_std_m={p},yaw_std_deg={y}",
                id = r.id,
                array = r.array,
                p = r.pose_std_m.unwrap(),
                y = r.yaw_std_deg.unwrap()
            ))
            .unwrap()
        })
        .collect()
}

#[test]
fn a_bag_replays_like_the_recording_it_was_made_from() {
    let scenario = Scenario::load("smoke").unwrap();
    let tmp = temp_dir("same");
    let dir = tmp.path();
    run(&scenario, &RunOptions { record_dir: Some(dir.to_path_buf()), ..RunOptions::default() }).unwrap();
    let recorded = RobotRecording::recorded(dir, &scenario);
    let truth = vec![TruthTrack::always(dir.join("source.tum"))];
    let direct = replay(&args(recorded.clone(), truth, dir.join("direct"), None)).unwrap();

    let bag = dir.join("bag");
    write_bag(&recorded, dir, &bag, "F32LE", "normal");
    let truth_unix = vec![TruthTrack::always(dir.join("truth-unix.tum"))];
    let from_bag =
        replay(&args(bag_robots(&recorded, None), truth_unix, dir.join("from-bag"), Some(&bag))).unwrap();
    assert_eq!(from_bag.rows.len(), direct.rows.len());
    assert!(direct.rows.len() > 500, "{} estimates", direct.rows.len());
    let mut worst: f64 = 0.0;
    for (a, b) in direct.rows.iter().zip(&from_bag.rows) {
        assert!((a.t_s - b.t_s).abs() < 1e-9, "{} vs {}", a.t_s, b.t_s);
        assert_eq!(a.robots, b.robots);
        worst = worst.max((a.estimate_in_map.unwrap() - b.estimate_in_map.unwrap()).norm());
        assert!((a.truth_in_map.unwrap() - b.truth_in_map.unwrap()).norm() < 1e-6);
    }
    println!("bag vs WAV + TUM: {} estimates, largest difference {worst:.2e} m", direct.rows.len());
    assert!(worst < 1e-6, "{worst}");

    // The bag's .mcap file alone converts to the same audio and poses as its folder.
    let mcap = std::fs::read_dir(&bag)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "mcap"))
        .unwrap();
    let from_file = soundmap_sim::rosbag::convert(&args(
        bag_robots(&recorded, None),
        vec![],
        dir.join("file"),
        Some(&mcap),
    ))
    .unwrap();
    for r in &from_file.robots {
        let folder = dir.join("from-bag/rosbag");
        let same = |name: String| {
            std::fs::read(folder.join(&name)).unwrap()
                == std::fs::read(dir.join("file/rosbag").join(&name)).unwrap()
        };
        assert!(same(format!("{}.wav", r.id)) && same(format!("{}.tum", r.id)), "{}", r.id);
    }

    // A bag file cut short (the recorder killed before it closed the file) is
    // read up to its last complete record: shorter audio, fewer estimates.
    let bytes = std::fs::read(&mcap).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 5]).unwrap();
    let from_cut = replay(&args(bag_robots(&recorded, None), vec![], dir.join("cut"), Some(&cut))).unwrap();
    for r in &from_file.robots {
        let len = |d: &str| std::fs::metadata(dir.join(d).join(format!("{}.wav", r.id))).unwrap().len();
        assert!(len("cut/rosbag") > 44 && len("cut/rosbag") < len("file/rosbag"), "{}", r.id);
    }
    let n = from_cut.rows.len();
    assert!(n > 0 && n < direct.rows.len(), "{n} of {} estimates", direct.rows.len());

    // 16-bit audio: the same run within the quantization's effect.
    let bag16 = dir.join("bag16");
    write_bag(&recorded, dir, &bag16, "S16LE", "normal");
    let s16 = replay(&args(bag_robots(&recorded, None), vec![], dir.join("s16"), Some(&bag16))).unwrap();
    let n = s16.rows.len().min(direct.rows.len());
    assert!(n * 10 >= direct.rows.len() * 9, "{} vs {}", s16.rows.len(), direct.rows.len());
    let median_shift = {
        let mut d: Vec<f64> = (0..n)
            .map(|k| (direct.rows[k].estimate_in_map.unwrap() - s16.rows[k].estimate_in_map.unwrap()).norm())
            .collect();
        d.sort_by(f64::total_cmp);
        d[n / 2]
    };
    println!("S16LE bag vs WAV: median difference {median_shift:.2e} m over {n} estimates");
    assert!(median_shift < 0.02, "{median_shift}");

    // Errors name the robot, topic or frame at fault.
    let fails = |robots: Vec<RobotRecording>, bag: &Path| {
        replay(&args(robots, vec![], dir.join("fail"), Some(bag))).unwrap_err().to_string()
    };
    let mut missing = bag_robots(&recorded, None);
    missing[1] = parse_robot("id=r9,audio_topic=/r9/audio/audio_stamped,array=respeaker-4").unwrap();
    let e = fails(missing, &bag);
    assert!(e.contains("no topic /r9/audio/audio_stamped") && e.contains("/tf_static"), "{e}");
    let e = fails(bag_robots(&recorded, Some("base_footprint")), &bag);
    assert!(e.contains("broken tf chain from map to base_footprint"), "{e}");

    let gap = dir.join("bag-gap");
    write_bag(&recorded, dir, &gap, "S16LE", "gap");
    let e = fails(bag_robots(&recorded, None), &gap);
    assert!(e.contains("a gap of 64.0 ms in the audio"), "{e}");

    let other = dir.join("bag-other");
    write_bag(&recorded, dir, &other, "F32LE", "bad-definition");
    let e = fails(bag_robots(&recorded, None), &other);
    assert!(e.contains("unknown message definition of audio_common_msgs/AudioDataStamped"), "{e}");
    let e =
        replay(&args(bag_robots(&recorded, None), vec![], dir.join("fail"), None)).unwrap_err().to_string();
    assert!(e.contains("give --rosbag BAG"), "{e}");
}
