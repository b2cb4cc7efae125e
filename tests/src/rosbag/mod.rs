//! ROS 2 bags as replay input: `soundmap-sim replay --rosbag BAG --robot
//! id=NAME,audio_topic=TOPIC,array=PRESET[,info_topic=TOPIC][,base_frame=base_link][,map_frame=map] …`.
//!
//! A bag is converted, streaming, into the inputs the replay already reads,
//! so that the same pipeline, agent core and coordinator run on it:
//!
//! 1. a first pass reads `AudioInfo` (`info_topic`, by default the
//!    `audio_info` topic beside the audio topic: `/r1/audio/audio_stamped` →
//!    `/r1/audio/audio_info`), `/tf` and `/tf_static`, and checks that every
//!    topic used exists and that its message definition is the one soundmap
//!    decodes ([`cdr`]);
//! 2. each robot's `map_frame → … → base_frame` chain is composed
//!    ([`tf`]) and written as a TUM trajectory;
//! 3. a second pass writes each robot's audio as a float WAV ([`audio`]),
//!    checking it has no gap.
//!
//! Time: the files count seconds from the bag's origin, the whole second at or
//! before its first audio or tf sample; the replay runs that origin at the
//! simulator's epoch. `--truth` files are TUM with stamps on the bag's clock
//! (Unix seconds, as ROS tools write them) and are shifted the same way.
//! The converted files stay in `OUT/rosbag/` (WAV, TUM, and the replay command
//! that reruns them).

pub mod audio;
pub mod cdr;
pub mod reader;
pub mod tf;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use soundmap_agent::pose::tum::{PoseTimeMapping, read_tum};
use soundmap_proto::RobotId;

use crate::error::SimError;
use crate::replay::{ReplayArgs, RobotRecording, TruthTrack};
use audio::AudioTrack;
use tf::TfTree;

/// What a `--robot` argument says about a robot in a bag.
#[derive(Clone, Debug, PartialEq)]
pub struct BagRobot {
    /// Topic of `audio_common_msgs/msg/AudioDataStamped`.
    pub audio_topic: String,
    /// Topic of `audio_common_msgs/msg/AudioInfo`.
    pub info_topic: String,
    /// The robot's base frame in tf.
    pub base_frame: String,
    /// The shared map frame in tf.
    pub map_frame: String,
}

/// The keys of a bag robot's `--robot` argument.
pub const KEYS: &str = "id, audio_topic, array, info_topic, base_frame, map_frame, pose_std_m, yaw_std_deg";

/// Whether a `--robot` argument describes a robot in a bag.
pub fn is_bag_robot(keys: &BTreeMap<String, String>) -> bool {
    keys.contains_key("audio_topic")
}

/// A bag robot from its `--robot` keys (see [`KEYS`]); the audio and pose
/// files are filled in by [`convert`].
pub fn robot_from_keys(mut kv: BTreeMap<String, String>) -> Result<RobotRecording, String> {
    let mut take = |k: &str| kv.remove(k);
    let need = |v: Option<String>, k: &str| {
        v.ok_or_else(|| format!("{k}: missing (id, audio_topic and array are required)"))
    };
    let number = crate::replay::robot_key_number;
    let id = need(take("id"), "id")?;
    RobotId::parse(&id, "id").map_err(|e| e.to_string())?;
    let audio_topic = need(take("audio_topic"), "audio_topic")?;
    let info_topic = take("info_topic").unwrap_or_else(|| default_info_topic(&audio_topic));
    let bag = BagRobot {
        info_topic,
        base_frame: take("base_frame").unwrap_or_else(|| "base_link".into()),
        map_frame: take("map_frame").unwrap_or_else(|| "map".into()),
        audio_topic,
    };
    let array = need(take("array"), "array")?;
    let (pose_std_m, yaw_std_deg) =
        (number(take("pose_std_m"), "pose_std_m")?, number(take("yaw_std_deg"), "yaw_std_deg")?);
    if let Some(k) = kv.keys().next() {
        return Err(format!("{k}: unknown key for a robot in a bag (expected {KEYS})"));
    }
    // Audio and poses are placeholders until [`convert`] writes them.
    let mut robot = crate::replay::parse_robot(&format!("id={id},audio=-,poses=-,array={array}"))?;
    robot.pose_std_m = pose_std_m;
    robot.yaw_std_deg = yaw_std_deg;
    robot.rosbag = Some(bag);
    Ok(robot)
}

/// `/r1/audio/audio_stamped` → `/r1/audio/audio_info`.
pub fn default_info_topic(audio_topic: &str) -> String {
    match audio_topic.rsplit_once('/') {
        Some((ns, _)) => format!("{ns}/audio_info"),
        None => "audio_info".into(),
    }
}

/// How long the pose of a robot whose chain is all static holds (30 days).
const STATIC_SPAN_NS: i64 = 30 * 86_400 * 1_000_000_000;

/// What the first pass learns.
#[derive(Debug, Default)]
struct Survey {
    topics: BTreeMap<String, String>,
    infos: BTreeMap<String, cdr::AudioInfo>,
    first_audio_ns: BTreeMap<String, i64>,
    tf: TfTree,
}

fn decode_error(bag: &Path, topic: &str, e: String) -> SimError {
    SimError::Replay(format!("{}: topic {topic}: cannot decode a message: {e}", bag.display()))
}

/// Checks a topic's type and definition the first time it is seen.
fn check_topic(
    bag: &Path,
    survey: &mut Survey,
    t: &reader::Topic,
    expected: &[(&str, &[(&str, &str)])],
) -> Result<(), SimError> {
    if survey.topics.contains_key(&t.name) {
        return Ok(());
    }
    if t.encoding != "cdr" {
        return Err(SimError::Replay(format!(
            "{}: topic {}: message encoding {:?}, expected cdr",
            bag.display(),
            t.name,
            t.encoding
        )));
    }
    cdr::check_definition(&t.msg_type, &t.definition, expected)
        .map_err(|e| SimError::Replay(format!("{}: topic {}: {e}", bag.display(), t.name)))?;
    survey.topics.insert(t.name.clone(), t.msg_type.clone());
    Ok(())
}

fn survey(bag: &Path, robots: &[(String, BagRobot)]) -> Result<Survey, SimError> {
    let mut s = Survey::default();
    let mut all_topics = BTreeMap::new();
    let mut messages = reader::BagMessages::open(bag)?;
    while let Some((topic, data)) = messages.next_message()? {
        all_topics.entry(topic.name.clone()).or_insert_with(|| topic.msg_type.clone());
        let name = topic.name.as_str();
        if name == "/tf" || name == "/tf_static" {
            check_topic(bag, &mut s, &topic, cdr::TF_MESSAGE)?;
            for t in cdr::tf_message(&data).map_err(|e| decode_error(bag, name, e))? {
                s.tf.add(&t, name == "/tf_static")
                    .map_err(|e| SimError::Replay(format!("{}: {name}: {e}", bag.display())))?;
            }
        } else if robots.iter().any(|(_, r)| r.info_topic == name) {
            check_topic(bag, &mut s, &topic, cdr::AUDIO_INFO)?;
            if !s.infos.contains_key(name) {
                s.infos.insert(
                    name.into(),
                    cdr::AudioInfo::decode(&data).map_err(|e| decode_error(bag, name, e))?,
                );
            }
        } else if robots.iter().any(|(_, r)| r.audio_topic == name) {
            check_topic(bag, &mut s, &topic, cdr::AUDIO_DATA_STAMPED)?;
            let (stamp, _) = cdr::audio_data_stamped(&data).map_err(|e| decode_error(bag, name, e))?;
            let first = s.first_audio_ns.entry(name.into()).or_insert(stamp);
            *first = (*first).min(stamp);
        }
    }
    for cut in messages.cut_short() {
        eprintln!(
            "replay: {}: the bag file ends in the middle of a record (cut short while it was recorded?): \
             reading the messages before it",
            cut.display()
        );
    }
    let listing = || all_topics.iter().map(|(t, ty)| format!("{t} ({ty})")).collect::<Vec<_>>().join(", ");
    for (id, r) in robots {
        for (topic, what) in [(&r.audio_topic, "audio_topic"), (&r.info_topic, "info_topic")] {
            if !all_topics.contains_key(topic) {
                return Err(SimError::Replay(format!(
                    "{}: robot {id}: no topic {topic} ({what}) in the bag; its topics: {}",
                    bag.display(),
                    listing()
                )));
            }
        }
    }
    Ok(s)
}

/// `t_ns − origin` as TUM seconds, exactly.
fn seconds(t_ns: i64, origin_ns: i64) -> String {
    let d = t_ns - origin_ns;
    format!("{}{}.{:09}", if d < 0 { "-" } else { "" }, d.abs() / 1_000_000_000, d.abs() % 1_000_000_000)
}

/// Writes the robot's `map_from_base` along its tf chain as TUM; returns the rows written.
fn write_poses(
    bag: &Path,
    s: &Survey,
    id: &str,
    r: &BagRobot,
    origin: i64,
    path: &Path,
) -> Result<usize, SimError> {
    let chain =
        s.tf.chain(&r.map_frame, &r.base_frame)
            .map_err(|e| SimError::Replay(format!("{}: robot {id}: {e}", bag.display())))?;
    let stamps = match s.tf.stamps(&chain) {
        Some(stamps) => stamps,
        // A static chain: the pose holds over the whole audio.
        None => vec![origin, origin + STATIC_SPAN_NS],
    };
    let mut text = String::new();
    let mut rows = 0;
    for t in stamps {
        let Some(p) = s.tf.pose_at(&chain, t) else { continue };
        let (v, q) = (p.translation.vector, p.rotation.quaternion());
        let _ =
            writeln!(text, "{} {} {} {} {} {} {} {}", seconds(t, origin), v.x, v.y, v.z, q.i, q.j, q.k, q.w);
        rows += 1;
    }
    std::fs::write(path, text).map_err(|e| SimError::file(path, e))?;
    Ok(rows)
}

/// Writes every robot's audio (second pass).
fn write_audio(bag: &Path, s: &Survey, robots: &[(String, BagRobot)], dir: &Path) -> Result<(), SimError> {
    let mut tracks = BTreeMap::new();
    for (id, r) in robots {
        let info = s.infos.get(&r.info_topic).expect("checked by the survey");
        tracks.insert(
            r.audio_topic.clone(),
            AudioTrack::create(&r.audio_topic, info, &dir.join(format!("{id}.wav")))?,
        );
    }
    let mut messages = reader::BagMessages::open(bag)?;
    while let Some((topic, data)) = messages.next_message()? {
        if let Some(track) = tracks.get_mut(&topic.name) {
            let (stamp, bytes) =
                cdr::audio_data_stamped(&data).map_err(|e| decode_error(bag, &topic.name, e))?;
            track.push(stamp, bytes)?;
        }
    }
    for track in tracks.into_values() {
        track.finish()?;
    }
    Ok(())
}

/// A truth file on the bag's clock, shifted to the bag's origin.
fn convert_truth(truth: &TruthTrack, origin: i64, dir: &Path, k: usize) -> Result<TruthTrack, SimError> {
    let poses = read_tum(&truth.path, PoseTimeMapping::UNIX)?;
    let mut text = String::new();
    for p in &poses {
        let (v, q) = (p.map_from_base.translation.vector, p.map_from_base.rotation.quaternion());
        let _ = writeln!(
            text,
            "{} {} {} {} {} {} {} {}",
            seconds(p.stamp.as_ns(), origin),
            v.x,
            v.y,
            v.z,
            q.i,
            q.j,
            q.k,
            q.w
        );
    }
    let path = dir.join(format!("truth-{k}.tum"));
    std::fs::write(&path, text).map_err(|e| SimError::file(&path, e))?;
    let shift = origin as f64 * 1e-9;
    Ok(TruthTrack { path, active: truth.active.iter().map(|(a, b)| (a - shift, b - shift)).collect() })
}

/// Converts the bag of `args.rosbag` into WAV + TUM files under `OUT/rosbag/`
/// and returns the replay arguments that read them.
pub fn convert(args: &ReplayArgs) -> Result<ReplayArgs, SimError> {
    let bag = args.rosbag.as_deref().expect("convert is called with --rosbag");
    let mut robots = Vec::new();
    for r in &args.robots {
        let Some(b) = &r.rosbag else {
            return Err(SimError::Replay(format!(
                "robot {}: with --rosbag every robot is read from the bag: give audio_topic= (keys: {KEYS})",
                r.id
            )));
        };
        robots.push((r.id.clone(), b.clone()));
    }
    let s = survey(bag, &robots)?;
    let dir = args.out.join("rosbag");
    std::fs::create_dir_all(&dir).map_err(|e| SimError::file(&dir, e))?;
    let mut origin = i64::MAX;
    for (id, r) in &robots {
        let first = s.first_audio_ns.get(&r.audio_topic).copied().ok_or_else(|| {
            SimError::Replay(format!("{}: robot {id}: no message on {}", bag.display(), r.audio_topic))
        })?;
        origin = origin.min(first);
        let chain =
            s.tf.chain(&r.map_frame, &r.base_frame)
                .map_err(|e| SimError::Replay(format!("{}: robot {id}: {e}", bag.display())))?;
        if let Some(first_tf) = s.tf.stamps(&chain).and_then(|t| t.first().copied()) {
            origin = origin.min(first_tf);
        }
    }
    let origin = origin.div_euclid(1_000_000_000) * 1_000_000_000;
    let mut converted = args.clone();
    converted.rosbag = None;
    for (robot, (id, r)) in converted.robots.iter_mut().zip(&robots) {
        let poses = dir.join(format!("{id}.tum"));
        if write_poses(bag, &s, id, r, origin, &poses)? < 2 {
            return Err(SimError::Replay(format!(
                "{}: robot {id}: fewer than two poses of {} in {} on /tf",
                bag.display(),
                r.base_frame,
                r.map_frame
            )));
        }
        let start_s = (s.first_audio_ns[&r.audio_topic] - origin) as f64 * 1e-9;
        let (pose_std_m, yaw_std_deg) = (robot.pose_std_m, robot.yaw_std_deg);
        let wav = dir.join(format!("{id}.wav"));
        *robot = crate::replay::parse_robot(&format!(
            "id={id},audio={},poses={},array={},start={start_s}",
            wav.display(),
            poses.display(),
            robot.array
        ))
        .map_err(|e| SimError::Replay(format!("robot {id}: {e}")))?;
        robot.pose_std_m = pose_std_m;
        robot.yaw_std_deg = yaw_std_deg;
    }
    write_audio(bag, &s, &robots, &dir)?;
    converted.truths = args
        .truths
        .iter()
        .enumerate()
        .map(|(k, t)| convert_truth(t, origin, &dir, k))
        .collect::<Result<_, _>>()?;
    let command: Vec<String> =
        converted.robots.iter().map(|r| format!("--robot {}", r.to_argument())).collect();
    let note = format!(
        "# converted from {} (origin {} ns)\nsoundmap-sim replay {}\n",
        bag.display(),
        origin,
        command.join(" ")
    );
    std::fs::write(dir.join("replay-command.txt"), note)
        .map_err(|e| SimError::file(dir.join("replay-command.txt"), e))?;
    Ok(converted)
}
