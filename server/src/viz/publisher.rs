//! The viewer thread's state: the channel set on one Foxglove context (which
//! feeds the WebSocket clients and the MCAP writer alike) and what it remembers
//! per robot to draw (its array mount, its path).
//!
//! Topics (log time: the coordinator clock when it happened):
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/tf` | `foxglove.FrameTransforms` | `map → {robot}/base → {robot}/array`, per observation |
//! | `/soundmap/doas` | `foxglove.SceneUpdate` | each robot's DoA rays (entity `doa/{robot}`) |
//! | `/soundmap/sources` | `foxglove.SceneUpdate` | estimates (`source/{id}`), their smoothed states (`smoothed/{id}`), true sources (`truth/{k}`) |
//! | `/soundmap/goals` | `foxglove.SceneUpdate` | reposition goals (`goal/{robot}`) |
//! | `/soundmap/paths` | `foxglove.SceneUpdate` | robot paths (`path/{robot}`), every 0.5 s |
//! | `/soundmap/room` | `foxglove.SceneUpdate` | room outline and obstacles, every 1 s |
//! | `/soundmap/quality` | JSON | `{stamp_ns, source_id, theta_deg, gdop, trusted, rse_m?}` per estimate |
//! | `/soundmap/truth` | JSON | `{stamp_ns, sources: [{index, x, y, z, active}]}` (when known) |
//! | `/soundmap/estimates` | `soundmap.v1.SourceEstimate` | every published estimate |
//! | `/soundmap/robots/{id}/hello` | `soundmap.v1.Hello` | the robot's hello |
//! | `/soundmap/robots/{id}/observation` | `soundmap.v1.Observation` | every accepted observation |
//! | `/soundmap/robots/{id}/from_robot` | `soundmap.v1.RobotMessage` | command acks and progress |
//! | `/soundmap/robots/{id}/to_robot` | `soundmap.v1.CoordinatorMessage` | reposition and cancel commands |

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use foxglove::messages::{FrameTransforms, SceneEntityDeletion, SceneUpdate, scene_entity_deletion};
use foxglove::{Channel, Context, PartialMetadata, RawChannel, Schema};
use nalgebra::{Isometry3, Point3};
use prost::Message;
use soundmap_proto::wire;

use super::Event;
use super::scene;

/// Length of a drawn DoA ray (m).
const RAY_LENGTH_M: f64 = 6.0;
/// Path points are kept at most this often (ns of log time).
const PATH_PERIOD_NS: i64 = 500_000_000;
/// Most path points kept per robot.
const PATH_POINTS: usize = 2000;
/// The room is drawn again this often (ns of log time), for viewers that join late.
const ROOM_PERIOD_NS: i64 = 1_000_000_000;

const QUALITY_SCHEMA: &str = r#"{"type":"object","properties":{"stamp_ns":{"type":"integer"},"source_id":{"type":"integer"},"theta_deg":{"type":"number"},"gdop":{"type":"number"},"trusted":{"type":"boolean"},"rse_m":{"type":"number"}}}"#;
const TRUTH_SCHEMA: &str = r#"{"type":"object","properties":{"stamp_ns":{"type":"integer"},"sources":{"type":"array","items":{"type":"object","properties":{"index":{"type":"integer"},"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"active":{"type":"boolean"}}}}}}"#;

/// A robot's topics and drawing state.
struct RobotState {
    hello: Arc<RawChannel>,
    observation: Arc<RawChannel>,
    from_robot: Arc<RawChannel>,
    to_robot: Arc<RawChannel>,
    base_from_array: Isometry3<f64>,
    path: VecDeque<Point3<f64>>,
    path_next_ns: i64,
}

/// The channel set and its state.
pub(crate) struct Publisher {
    ctx: Arc<Context>,
    tf: Arc<Channel<FrameTransforms>>,
    doas: Arc<Channel<SceneUpdate>>,
    sources: Channel<SceneUpdate>,
    goals: Arc<Channel<SceneUpdate>>,
    paths: Arc<Channel<SceneUpdate>>,
    room: Channel<SceneUpdate>,
    quality: Arc<RawChannel>,
    truth_json: Arc<RawChannel>,
    estimates: Arc<RawChannel>,
    robots: HashMap<String, RobotState>,
    free_space: (Vec<[f64; 2]>, Vec<Vec<[f64; 2]>>),
    room_next_ns: i64,
    truth: Vec<(Point3<f64>, bool)>,
}

fn protobuf_channel(ctx: &Arc<Context>, topic: &str, message: &str) -> Arc<RawChannel> {
    let schema =
        Schema::new(format!("soundmap.v1.{message}"), "protobuf", soundmap_proto::FILE_DESCRIPTOR_SET);
    ctx.channel_builder(topic)
        .message_encoding("protobuf")
        .schema(schema)
        .build_raw()
        .expect("a protobuf channel with a schema is valid")
}

fn json_channel(ctx: &Arc<Context>, topic: &str, schema: &'static str) -> Arc<RawChannel> {
    ctx.channel_builder(topic)
        .message_encoding("json")
        .schema(Schema::new(topic.trim_start_matches('/').replace('/', "."), "jsonschema", schema.as_bytes()))
        .build_raw()
        .expect("a JSON channel with a schema is valid")
}

fn log_raw(channel: &RawChannel, ns: i64, bytes: impl FnOnce() -> Vec<u8>) {
    if channel.has_sinks() {
        channel.log_with_meta(&bytes(), PartialMetadata::with_log_time(ns.max(0) as u64));
    }
}

/// A scene update that adds or replaces one entity.
fn one(entity: foxglove::messages::SceneEntity) -> SceneUpdate {
    SceneUpdate { deletions: vec![], entities: vec![entity] }
}

impl Publisher {
    /// The channels on `ctx`; `free_space` is the room and obstacles drawn.
    pub(crate) fn new(ctx: Arc<Context>, free_space: (Vec<[f64; 2]>, Vec<Vec<[f64; 2]>>)) -> Self {
        Publisher {
            tf: Arc::new(ctx.channel_builder("/tf").build()),
            doas: Arc::new(ctx.channel_builder("/soundmap/doas").build()),
            sources: ctx.channel_builder("/soundmap/sources").build(),
            goals: Arc::new(ctx.channel_builder("/soundmap/goals").build()),
            paths: Arc::new(ctx.channel_builder("/soundmap/paths").build()),
            room: ctx.channel_builder("/soundmap/room").build(),
            quality: json_channel(&ctx, "/soundmap/quality", QUALITY_SCHEMA),
            truth_json: json_channel(&ctx, "/soundmap/truth", TRUTH_SCHEMA),
            estimates: protobuf_channel(&ctx, "/soundmap/estimates", "SourceEstimate"),
            robots: HashMap::new(),
            free_space,
            room_next_ns: i64::MIN,
            truth: Vec::new(),
            ctx,
        }
    }

    /// Publishes one event on its channels.
    pub(crate) fn handle(&mut self, event: Event) {
        match event {
            Event::Hello { now, hello } => {
                let id = hello.robot_id.to_string();
                let robot = self.robot(&id);
                robot.base_from_array = hello.array.base_from_array;
                log_raw(&robot.hello, now.as_ns(), || hello.to_wire().encode_to_vec());
                self.draw_room(now.as_ns());
            }
            Event::Observation { now, robot, obs } => self.observation(now.as_ns(), robot.as_str(), &obs),
            Event::FromRobot { now, robot, input } => {
                let r = self.robot(robot.as_str());
                log_raw(&r.from_robot, now.as_ns(), || input.to_wire().encode_to_vec());
            }
            Event::ToRobot { now, robot, msg } => self.sent_to_robot(now.as_ns(), robot.as_str(), &msg),
            Event::Estimate { now, estimate } => self.estimate(now.as_ns(), &estimate),
            Event::Truth { now, sources } => self.truth(now.as_ns(), sources),
        }
    }

    fn robot(&mut self, id: &str) -> &mut RobotState {
        let ctx = &self.ctx;
        self.robots.entry(id.to_string()).or_insert_with(|| {
            let topic = |leaf: &str| format!("/soundmap/robots/{id}/{leaf}");
            RobotState {
                hello: protobuf_channel(ctx, &topic("hello"), "Hello"),
                observation: protobuf_channel(ctx, &topic("observation"), "Observation"),
                from_robot: protobuf_channel(ctx, &topic("from_robot"), "RobotMessage"),
                to_robot: protobuf_channel(ctx, &topic("to_robot"), "CoordinatorMessage"),
                base_from_array: Isometry3::identity(),
                path: VecDeque::new(),
                path_next_ns: i64::MIN,
            }
        })
    }

    fn observation(&mut self, ns: i64, id: &str, obs: &soundmap_proto::Observation) {
        let (tf, doas, paths) = (self.tf.clone(), self.doas.clone(), self.paths.clone());
        let r = self.robot(id);
        log_raw(&r.observation, ns, || obs.to_wire().encode_to_vec());
        let map_from_array = obs.map_from_base * r.base_from_array;
        tf.log_with_time(
            &scene::transforms(ns, id, &obs.map_from_base, &r.base_from_array),
            ns.max(0) as u64,
        );
        let rays: Vec<_> = obs.doas.iter().map(|d| (d.track_id, d.direction_in_array.into_inner())).collect();
        let entity = scene::doa_rays(ns, id, &map_from_array, &rays, RAY_LENGTH_M);
        doas.log_with_time(&one(entity), ns.max(0) as u64);
        if ns >= r.path_next_ns {
            r.path_next_ns = ns.saturating_add(PATH_PERIOD_NS);
            if r.path.len() >= PATH_POINTS {
                r.path.pop_front();
            }
            r.path.push_back(map_from_array * Point3::origin());
            let entity = scene::path_entity(ns, id, r.path.iter().copied());
            paths.log_with_time(&one(entity), ns.max(0) as u64);
        }
        self.draw_room(ns);
    }

    fn sent_to_robot(&mut self, ns: i64, id: &str, msg: &wire::CoordinatorMessage) {
        let goals = self.goals.clone();
        let r = self.robot(id);
        log_raw(&r.to_robot, ns, || msg.encode_to_vec());
        let update = match &msg.msg {
            Some(wire::coordinator_message::Msg::Reposition(c)) => {
                let limits = soundmap_proto::Limits::at(soundmap_proto::Stamp::from_ns(ns));
                let Some(goal) = soundmap_proto::pose_from_wire(&c.goal_map_from_base, "goal", &limits).ok()
                else {
                    return;
                };
                one(scene::goal_entity(ns, id, &goal))
            }
            Some(wire::coordinator_message::Msg::Cancel(_)) => SceneUpdate {
                deletions: vec![SceneEntityDeletion {
                    timestamp: Some(scene::timestamp(ns)),
                    r#type: scene_entity_deletion::Type::MatchingId as i32,
                    id: format!("goal/{id}"),
                }],
                entities: vec![],
            },
            _ => return,
        };
        goals.log_with_time(&update, ns.max(0) as u64);
    }

    fn estimate(&mut self, ns: i64, e: &wire::SourceEstimate) {
        log_raw(&self.estimates, ns, || e.encode_to_vec());
        if let Some(entity) = scene::source_entity(ns, e) {
            self.sources.log_with_time(&one(entity), ns.max(0) as u64);
        }
        if let Some(entity) = scene::smoothed_entity(ns, e) {
            self.sources.log_with_time(&one(entity), ns.max(0) as u64);
        }
        let rse = e.position_in_map_m.as_ref().and_then(|p| {
            let p = Point3::new(p.x, p.y, p.z);
            self.truth
                .iter()
                .filter(|(_, active)| *active)
                .map(|(t, _)| (t - p).norm())
                .min_by(f64::total_cmp)
        });
        log_raw(&self.quality, ns, || {
            let mut v = serde_json::json!({
                "stamp_ns": e.stamp_ns, "source_id": e.source_id, "theta_deg": e.theta_deg,
                "gdop": e.gdop, "trusted": e.trusted,
            });
            if let Some(rse) = rse {
                v["rse_m"] = rse.into();
            }
            v.to_string().into_bytes()
        });
    }

    fn truth(&mut self, ns: i64, sources: Vec<(Point3<f64>, bool)>) {
        let entities =
            sources.iter().enumerate().map(|(k, (p, a))| scene::truth_entity(ns, k, p, *a)).collect();
        self.sources.log_with_time(&SceneUpdate { deletions: vec![], entities }, ns.max(0) as u64);
        log_raw(&self.truth_json, ns, || {
            let list: Vec<_> = sources
                .iter()
                .enumerate()
                .map(|(k, (p, a))| serde_json::json!({"index": k, "x": p.x, "y": p.y, "z": p.z, "active": a}))
                .collect();
            serde_json::json!({"stamp_ns": ns, "sources": list}).to_string().into_bytes()
        });
        self.truth = sources;
    }

    fn draw_room(&mut self, ns: i64) {
        if ns < self.room_next_ns {
            return;
        }
        self.room_next_ns = ns.saturating_add(ROOM_PERIOD_NS);
        let (room, obstacles) = &self.free_space;
        if room.is_empty() && obstacles.is_empty() {
            return;
        }
        self.room.log_with_time(&one(scene::room_entity(ns, room, obstacles)), ns.max(0) as u64);
    }
}
