//! The coordinator as a pure state machine: fed `(now, input)`, it returns
//! outputs. The gRPC service, the simulator and a replay all drive this same
//! code; none of it opens sockets or reads clocks.
//!
//! - [`robots`]: what is known of each robot; [`commands`]: the commands sent
//!   to it and its reports;
//! - [`estimate`]: what is published about the source (triangulation and
//!   filtered state side by side);
//! - [`tracking`]: the source tracker fed with every robot's dominant DoA
//!   (one source, `sources.max_sources = 1`);
//! - [`sound_map`]: several sources (`sources.max_sources > 1`): association,
//!   births, deaths, stable ids, one tracker per source;
//! - [`positioning`]: the operator's settings, the planner and command
//!   bookkeeping; `reposition` runs a planning cycle on an estimate when the
//!   planner's [`cadence`](crate::planner::cadence) says one is due.

pub mod commands;
mod doa_queue;
pub mod estimate;
mod persist;
pub mod positioning;
pub mod records;
mod registry;
mod reposition;
pub mod robots;
pub mod sound_map;
mod source_ids;
pub mod tracking;

use std::collections::{BTreeMap, HashMap};

use nalgebra::Point3;
use soundmap_proto::{
    CommandAck, CommandProgress, Hello, Limits, Observation, Problem, RobotId, Stamp, ValidationError,
};

pub use commands::{CommandLog, ConnId, Outbound, Outgoing, Refusal};
pub use estimate::{BestSource, Estimate};
pub use positioning::{PlanKind, PlannerStatus, PositioningSettings, PositioningUpdate};
use robots::IndexPool;
pub use robots::{Liveness, RobotEntry, StoredObservation, TaggedRay};
pub use tracking::TrackingCounters;

use crate::config::CoordinatorConfig;
use crate::error::ServerError;
use crate::floor_image::{
    FloorFold, array_pattern, band_reflection, band_share, heard_band, reverberant_reflection,
};
use crate::ray::Ray;
use crate::triangulation::{Gate, triangulate_from};
use positioning::Positioning;
use sound_map::{AlignedRays, SoundMap};
use tracking::Tracking;

/// The oldest estimate whose point still starts the next N-ray fit (s): a
/// walker moves 0.7 m in that time, within the fit's reach from a point
/// that close; an older one is more likely to cost iterations than save
/// them.
pub const WARM_HINT_MAX_AGE_S: f64 = 1.0;

/// A track is taken as heard over the bands of its signature within this many
/// dB of its strongest band (PHAT weighs every bin the source dominates alike).
const HEARD_BAND_RANGE_DB: f64 = 20.0;

/// The coordinator's answer to a valid hello.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Welcome {
    /// The stream's id.
    pub conn: ConnId,
    /// The accepted robot id.
    pub robot_id: RobotId,
    /// Whether the robot's earlier state resumed.
    pub resumed: bool,
    /// Stale timeout (ms).
    pub stale_after_ms: u64,
}

/// A change of liveness found by [`Coordinator::tick`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LivenessChange {
    /// The robot.
    pub robot_id: RobotId,
    /// Its new liveness.
    pub liveness: Liveness,
}

/// Counters for monitoring.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// Observations accepted.
    pub observations: u64,
    /// Observations rejected.
    pub rejected: u64,
    /// Estimates published.
    pub estimates: u64,
    /// Estimate requests that found fewer than two aligned robots.
    pub unaligned: u64,
    /// Observations dropped from robots' histories by `server.max_history_per_robot`.
    pub history_trimmed: u64,
    /// Robots forgotten (retention passed, or replaced at `server.max_robots`).
    pub robots_forgotten: u64,
    /// Hellos refused: `server.max_robots` robots known and all connected.
    pub robots_refused: u64,
}

/// The coordinator state.
#[derive(Debug)]
pub struct Coordinator {
    config: CoordinatorConfig,
    robots: BTreeMap<RobotId, RobotEntry>,
    connections: HashMap<ConnId, RobotId>,
    next_conn: ConnId,
    /// Newest observation stamp not yet covered by an estimate.
    pending: Option<Stamp>,
    last_estimate: Option<Estimate>,
    counters: Counters,
    liveness: BTreeMap<RobotId, Liveness>,
    tracking: Tracking,
    /// Several sources (`sources.max_sources > 1`).
    sound_map: Option<SoundMap>,
    /// The latest estimate of each source (several sources).
    latest_by_source: BTreeMap<u64, Estimate>,
    /// The source active positioning serves; 0: all (several sources).
    focus: u64,
    /// Which source(s) the planning cycle under way serves, for its commands.
    serving: Option<String>,
    positioning: Positioning,
    /// Messages for robots' streams, sent by the shell before the batch's acknowledgements.
    outbox: Vec<Outgoing>,
    /// Tracker indices of the robots.
    indices: IndexPool,
}

impl Coordinator {
    /// A coordinator with no robots. The configuration is validated first
    /// (errors name the key, with `<config>` as the file).
    pub fn new(config: CoordinatorConfig) -> Result<Self, ServerError> {
        config.validate(std::path::Path::new("<config>"))?;
        Ok(Coordinator {
            tracking: Tracking::new(&config.tracking),
            sound_map: (config.sources.max_sources > 1 && config.tracking.enabled)
                .then(|| SoundMap::new(config.sources.clone(), config.tracking.clone())),
            latest_by_source: BTreeMap::new(),
            focus: 0,
            serving: None,
            positioning: Positioning::new(&config)?,
            config,
            robots: BTreeMap::new(),
            connections: HashMap::new(),
            next_conn: 1,
            pending: None,
            last_estimate: None,
            counters: Counters::default(),
            liveness: BTreeMap::new(),
            outbox: Vec::new(),
            indices: IndexPool::default(),
        })
    }

    /// Its configuration.
    pub fn config(&self) -> &CoordinatorConfig {
        &self.config
    }

    /// Validation limits at `now` for incoming messages.
    pub fn limits(&self, now: Stamp) -> Limits {
        Limits {
            now,
            max_future_ns: self.config.limits.max_future_ms as i64 * 1_000_000,
            max_past_ns: self.config.limits.max_past_ms as i64 * 1_000_000,
            unit_vector_tolerance: self.config.limits.unit_vector_tolerance,
            quaternion_tolerance: self.config.limits.quaternion_tolerance,
        }
    }

    fn stale_after_ns(&self) -> i64 {
        self.config.liveness.stale_after_ms as i64 * 1_000_000
    }

    /// A robot says hello on a new stream. `authenticated` is the identity its
    /// credentials prove, when the transport authenticated it.
    pub fn connect(
        &mut self,
        now: Stamp,
        hello: Hello,
        authenticated: Option<&RobotId>,
    ) -> Result<Welcome, ServerError> {
        if let Some(auth) = authenticated
            && *auth != hello.robot_id
        {
            return Err(ServerError::IdentityMismatch {
                claimed: hello.robot_id,
                authenticated: auth.clone(),
            });
        }
        let stale_after_ns = self.stale_after_ns();
        let conn = self.next_conn;
        let id = hello.robot_id.clone();
        let resumed = match self.robots.get_mut(&id) {
            Some(entry) => {
                if entry.liveness(now, stale_after_ns) == Liveness::Live {
                    return Err(ServerError::AlreadyConnected(id));
                }
                // A stale stream is taken over; a closed one resumes.
                if let Some(old) = entry.conn.take() {
                    self.connections.remove(&old);
                }
                entry.hello = hello;
                entry.conn = Some(conn);
                // Whether the robot still drives to its last goal is unknown: the
                // planner does not count on it (a report on it is still accepted).
                entry.commands.cancel();
                entry.last_seen = now;
                entry.last_sequence = None;
                true
            }
            None => {
                self.make_room(&id)?;
                let index = self.indices.take();
                self.robots.insert(id.clone(), RobotEntry::new(hello, index, conn, now));
                false
            }
        };
        self.next_conn += 1;
        self.connections.insert(conn, id.clone());
        self.liveness.insert(id.clone(), Liveness::Live);
        Ok(Welcome { conn, robot_id: id, resumed, stale_after_ms: self.config.liveness.stale_after_ms })
    }

    /// Whether `conn` is still the robot's current stream.
    pub fn is_current(&self, conn: ConnId) -> bool {
        self.connections.contains_key(&conn)
    }

    /// The robot of a stream.
    pub fn robot_of(&self, conn: ConnId) -> Option<&RobotId> {
        self.connections.get(&conn)
    }

    fn entry_mut(&mut self, conn: ConnId, what: &'static str) -> Result<&mut RobotEntry, ServerError> {
        let id = self.connections.get(&conn).ok_or(ServerError::NoHello(what))?;
        Ok(self.robots.get_mut(id).expect("connections point at known robots"))
    }

    /// A stream closed. The robot's state is kept for a reconnection.
    pub fn disconnect(&mut self, _now: Stamp, conn: ConnId) {
        if let Some(id) = self.connections.remove(&conn) {
            if let Some(e) = self.robots.get_mut(&id) {
                e.conn = None;
                // A disconnected robot takes no part in alignment.
                e.history = Default::default();
                self.tracking.forget_robot(e.index);
                if let Some(m) = self.sound_map.as_mut() {
                    m.forget_robot(e.index);
                }
            }
            self.liveness.insert(id, Liveness::Disconnected);
        }
    }

    /// Any message is a sign of life.
    pub fn heartbeat(&mut self, now: Stamp, conn: ConnId) -> Result<(), ServerError> {
        self.entry_mut(conn, "heartbeat")?.last_seen = now;
        Ok(())
    }

    /// Counts an observation that failed validation before reaching the core.
    pub fn note_rejected(&mut self, now: Stamp, conn: ConnId) {
        if let Ok(e) = self.entry_mut(conn, "observation") {
            e.rejected += 1;
            e.last_seen = now;
        }
        self.counters.rejected += 1;
    }

    /// A validated observation. Checks ordering against the robot's previous
    /// ones, builds its rays in the map frame and keeps them for alignment.
    pub fn observe(&mut self, now: Stamp, conn: ConnId, obs: Observation) -> Result<(), ServerError> {
        let min_activity = self.config.doa.min_activity;
        let several = self.sound_map.is_some();
        let default_sigma = self.config.doa.default_sigma_deg.to_radians();
        let (reflection, base_height_m) = (self.config.doa.floor_reflection, self.config.doa.base_height_m);
        let narrow_reflection = self.config.doa.narrow_band_reflection;
        let pull = self.config.doa.reverberant_pull;
        let ceiling_m = self.config.doa.ceiling_height_m;
        let elevation_noise = self.config.doa.planar_elevation_noise;
        let upper_branch = self.config.doa.upper_branch;
        let history_ns = self.config.alignment.history_ms as i64 * 1_000_000;
        let max_history = self.config.server.max_history_per_robot;
        let entry = match self.entry_mut(conn, "observation") {
            Ok(e) => e,
            Err(e) => {
                self.counters.rejected += 1;
                return Err(e);
            }
        };
        entry.last_seen = now;
        let ordering = if let Some(prev) = entry.last_sequence.filter(|p| obs.sequence <= *p) {
            Some(ValidationError::new(
                "observation.sequence",
                Problem::SequenceNotIncreasing { sequence: obs.sequence, previous: prev },
            ))
        } else if let Some(prev) = entry.last_stamp.filter(|p| obs.stamp < *p) {
            Some(ValidationError::new(
                "observation.stamp_ns",
                Problem::OutOfOrder { stamp_ns: obs.stamp.as_ns(), previous_ns: prev.as_ns() },
            ))
        } else {
            None
        };
        if let Some(e) = ordering {
            entry.rejected += 1;
            self.counters.rejected += 1;
            return Err(e.into());
        }
        let base_from_array = entry.hello.array.base_from_array;
        let pattern = *entry.pattern.get_or_insert_with(|| {
            let a = &entry.hello.array;
            a.srp_band_hz.and_then(|[lo, hi]| array_pattern(&a.microphone_positions, (lo, hi)))
        });
        let array_height_m = (obs.map_from_base * base_from_array).translation.z
            - obs.map_from_base.translation.z
            + base_height_m;
        let edges = entry.hello.signature_bands.as_deref();
        let aperture_m = entry.aperture_m;
        let declared = entry.hello.array.srp_band_hz;
        // A robot that fitted the floor's reflection into its DoAs (see
        // `ArrayDescription.direct_path_elevations`) sends the direct path:
        // its rays are folded without a pull.
        let direct_path = entry.hello.array.direct_path_elevations;
        let rays = obs
            .doas
            .iter()
            .filter(|d| d.activity >= min_activity)
            .map(|d| {
                let sigma = d.angular_sigma_rad.unwrap_or(default_sigma);
                // The band the track is heard over (its signature) sets how wide
                // the array's lobes are, and so how soon they merge.
                let band = edges
                    .zip(d.signature.as_deref())
                    .and_then(|(e, levels)| heard_band(e, levels, HEARD_BAND_RANGE_DB));
                // The reflections' pull as this DoA's coherence reports it (the
                // share of the SRP band the track is heard in rescales it), or
                // else as that share says (see floor_image, "Narrow bands").
                let share = declared.and_then(|[lo, hi]| band_share(band, (lo, hi)));
                let reflection = if direct_path {
                    0.0
                } else {
                    d.coherence
                        .filter(|_| pull > 0.0)
                        .and_then(|c| reverberant_reflection(c, share?, pull))
                        .unwrap_or_else(|| band_reflection(reflection, narrow_reflection, share))
                };
                let fold = pattern.map(|p| FloorFold {
                    array_height_m,
                    reflection,
                    lobe: p.lobe(band),
                    ceiling_m,
                    vertical_spread: elevation_noise.then(|| p.vertical_spread()),
                    upper_branch,
                    // Its elevation read along the robot's fit at the
                    // coordinator's range (see floor_image, "A robot's own floor fit").
                    fitted_range_m: d.floor_fit_range_m.filter(|_| direct_path),
                });
                let ray = Ray {
                    fold,
                    ..Ray::from_doa(
                        &obs.map_from_base,
                        &base_from_array,
                        &d.direction_in_array,
                        sigma,
                        obs.pose_covariance.as_ref(),
                    )
                };
                TaggedRay {
                    ray,
                    activity: d.activity,
                    track_id: d.track_id,
                    signature: d.signature.as_deref().map(std::sync::Arc::from),
                    aperture_m,
                }
            })
            .collect::<Vec<_>>();
        entry.last_sequence = Some(obs.sequence);
        entry.last_stamp = Some(obs.stamp);
        entry.last_map_from_base = Some(obs.map_from_base);
        entry.accepted += 1;
        let stored = StoredObservation { stamp: obs.stamp, rays, received: now };
        let dominant = stored.dominant().copied();
        if let Some(ray) = &dominant {
            entry.last_sigma_rad = Some(ray.sigma_rad);
        }
        let index = entry.index;
        let all_rays = several.then(|| stored.rays.clone());
        let trimmed = entry.remember(stored, history_ns, max_history);
        self.counters.history_trimmed += trimmed as u64;
        self.counters.observations += 1;
        if let (Some(map), Some(rays)) = (self.sound_map.as_mut(), all_rays) {
            if !rays.is_empty() {
                self.pending = Some(self.pending.map_or(obs.stamp, |p| p.max(obs.stamp)));
            }
            map.push(obs.stamp, index, rays);
            return Ok(());
        }
        self.tracking.note_stamp(index, obs.stamp);
        if let Some(ray) = dominant {
            self.tracking.push(obs.stamp, index, ray);
            self.pending = Some(self.pending.map_or(obs.stamp, |p| p.max(obs.stamp)));
        }
        Ok(())
    }

    /// A robot answers a command.
    pub fn command_ack(&mut self, now: Stamp, conn: ConnId, ack: &CommandAck) -> Result<(), ServerError> {
        let entry = self.entry_mut(conn, "command_ack")?;
        entry.last_seen = now;
        entry.commands.acknowledge(now, ack)
    }

    /// A robot reports progress on a command.
    pub fn command_progress(
        &mut self,
        now: Stamp,
        conn: ConnId,
        p: &CommandProgress,
    ) -> Result<(), ServerError> {
        let entry = self.entry_mut(conn, "command_progress")?;
        entry.last_seen = now;
        entry.commands.progress(now, p)
    }

    /// Housekeeping: applies queued DoAs to the tracker, checks its lifecycle,
    /// and returns the robots whose liveness changed since the last tick.
    pub fn tick(&mut self, now: Stamp) -> Vec<LivenessChange> {
        self.tracking.flush(now);
        self.tracking.maintain(now);
        if let Some(m) = self.sound_map.as_mut() {
            m.flush(now);
        }
        self.forget_gone(now);
        let stale_after_ns = self.stale_after_ns();
        let mut changes = Vec::new();
        for (id, e) in &self.robots {
            let l = e.liveness(now, stale_after_ns);
            if self.liveness.get(id) != Some(&l) {
                self.liveness.insert(id.clone(), l);
                changes.push(LivenessChange { robot_id: id.clone(), liveness: l });
            }
        }
        changes
    }

    /// The estimate for the observations that arrived since the last one, if
    /// any did: the triangulation of the rays aligned with the newest
    /// observation (only live robots, each with its observation nearest in time
    /// within the alignment window and that observation's most active DoA; at
    /// least two robots), and the track's state at that stamp beside it.
    ///
    /// On the way it checks the track's lifecycle at `now`, starts a track from
    /// the triangulation when none is live and the triangulation is trusted,
    /// applies the queued DoAs to the tracker, and, when active positioning is on
    /// and due, runs a planning cycle whose commands are queued for
    /// [`Coordinator::take_outgoing`].
    pub fn estimate(&mut self, now: Stamp) -> Vec<Estimate> {
        if self.sound_map.is_some() {
            return self.estimate_sources(now);
        }
        self.estimate_one(now).into_iter().collect()
    }

    fn estimate_one(&mut self, now: Stamp) -> Option<Estimate> {
        // A track silent too long is lost before a new one may start from this batch.
        self.tracking.maintain(now);
        let aligned = self.pending.take().and_then(|t| self.triangulate_at(now, t));
        if let Some((e, newest)) = &aligned {
            self.tracking.start_if_needed(*newest, &e.triangulation);
        }
        self.tracking.flush(now);
        let Some((mut estimate, _)) = aligned else {
            if self.positioning.due(now) {
                self.reposition_without_estimate(now);
            }
            return None;
        };
        estimate.filtered = self.tracking.estimate_at(estimate.stamp);
        estimate.smoothed = self.tracking.smoothed();
        estimate.source_id = self.tracking.live_track_id().unwrap_or(0);
        self.counters.estimates += 1;
        self.last_estimate = Some(estimate.clone());
        if self.positioning.due(now) {
            self.reposition(now, &estimate, &[]);
        }
        Some(estimate)
    }

    /// Several sources: the sound map steps (deaths, births, updates) and every
    /// live source heard by at least two robots at the pending stamp gets an
    /// estimate. The planner works on the primary source: the longest-followed
    /// one with an estimate in this batch.
    fn estimate_sources(&mut self, now: Stamp) -> Vec<Estimate> {
        let Some(t) = self.pending.take() else {
            if self.positioning.due(now) {
                self.reposition_without_estimate(now);
            }
            return Vec::new();
        };
        let (aligned, ids) = self.aligned_rays(now, t);
        let Some(map) = self.sound_map.as_mut() else { return Vec::new() };
        map.step(now, &aligned, &self.config.triangulation);
        let live: Vec<u64> = map.sources().map(|(id, ..)| id).collect();
        self.latest_by_source.retain(|id, _| live.contains(id));
        let sightings = map.sightings(&aligned, t, &self.config.triangulation);
        let correlated_doa_fraction = self.config.tracking.correlated_doa_fraction;
        let estimates: Vec<Estimate> = sightings
            .into_iter()
            .map(|s| Estimate {
                source_id: s.source_id,
                stamp: t,
                robots: s.robots.iter().filter_map(|i| ids.get(i).cloned()).collect(),
                triangulation: s.triangulation,
                filtered: s.filtered,
                smoothed: s.smoothed,
                correlated_doa_fraction,
            })
            .collect();
        if estimates.is_empty() {
            self.counters.unaligned += 1;
        }
        for e in &estimates {
            self.latest_by_source.insert(e.source_id, e.clone());
        }
        self.counters.estimates += estimates.len() as u64;
        // The latest estimate: of the source followed longest (the map lists them in birth order).
        if let Some(first) = live.iter().find_map(|id| estimates.iter().find(|e| e.source_id == *id)) {
            self.last_estimate = Some(first.clone());
        }
        if let Some((served, why)) = self.served(&estimates)
            && self.positioning.due(now)
        {
            self.serving = Some(format!("for source {} ({why})", served.source_id));
            let served = served.clone();
            let others: Vec<Estimate> =
                estimates.iter().filter(|e| e.source_id != served.source_id).cloned().collect();
            self.reposition(now, &served, &others);
            self.serving = None;
        } else if !estimates.iter().any(Estimate::triangulated) && self.positioning.due(now) {
            self.reposition_without_estimate(now);
        }
        estimates
    }

    /// The estimate active positioning serves in this batch, and why: the focus
    /// source, or with focus 0 ("all") the source whose geometry is worst
    /// (largest GDOP), so that each cycle improves the worst-placed source.
    /// Only estimates of at least two robots' rays are served: one robot's ray
    /// gives the planner no geometry to improve.
    fn served<'e>(&self, estimates: &'e [Estimate]) -> Option<(&'e Estimate, String)> {
        let mut triangulated = estimates.iter().filter(|e| e.triangulated());
        if self.focus != 0 {
            let e = triangulated.find(|e| e.source_id == self.focus)?;
            return Some((e, "the operator's focus".into()));
        }
        let n = triangulated.clone().count();
        let worst = triangulated.max_by(|a, b| a.gdop().total_cmp(&b.gdop()))?;
        let why = match n {
            1 => "the only source heard".to_owned(),
            n => format!("the worst geometry of {n} sources, GDOP {:.1}", worst.gdop()),
        };
        Some((worst, why))
    }

    /// Chooses the source active positioning serves: an id the sound map gave,
    /// or 0 for all. Returns the focus now in force.
    pub fn set_focus(&mut self, source_id: u64) -> Result<u64, ServerError> {
        let known = source_id == 0 || self.sound_map.as_ref().is_some_and(|m| m.has_given(source_id));
        if !known {
            return Err(ValidationError::new(
                "source_id",
                Problem::OutOfRange {
                    value: source_id as f64,
                    range: "a source id the coordinator gave, or 0",
                },
            )
            .into());
        }
        self.focus = source_id;
        Ok(source_id)
    }

    /// The source active positioning serves; 0: all.
    pub fn focus(&self) -> u64 {
        self.focus
    }

    /// Each live robot's observation nearest `t` within the alignment window
    /// (with rays), and robot ids by index.
    fn aligned_rays(&self, now: Stamp, t: Stamp) -> (Vec<AlignedRays>, HashMap<u32, RobotId>) {
        let mut aligned = Vec::new();
        let mut ids = HashMap::new();
        for (id, e, o) in self.nearest_of_live(now, t) {
            aligned.push(AlignedRays { robot: e.index, stamp: o.stamp, rays: o.rays.clone() });
            ids.insert(e.index, id.clone());
        }
        (aligned, ids)
    }

    /// Each live robot with its kept observation nearest to `t` within the
    /// alignment window that has rays ([`RobotEntry::nearest`]), in the
    /// robots' order.
    fn nearest_of_live(
        &self,
        now: Stamp,
        t: Stamp,
    ) -> impl Iterator<Item = (&RobotId, &RobotEntry, &StoredObservation)> {
        let window_ns = self.config.alignment.window_ms as i64 * 1_000_000;
        let stale_after_ns = self.stale_after_ns();
        self.robots
            .iter()
            .filter(move |(_, e)| e.liveness(now, stale_after_ns) == Liveness::Live)
            .filter_map(move |(id, e)| Some((id, e, e.nearest(t, window_ns)?)))
    }

    /// The latest estimate of every live source (one source: the latest estimate).
    pub fn latest_estimates(&self) -> Vec<&Estimate> {
        if self.sound_map.is_some() {
            self.latest_by_source.values().collect()
        } else {
            self.last_estimate.iter().collect()
        }
    }

    /// The sound map, when several sources are followed.
    pub fn sound_map(&self) -> Option<&SoundMap> {
        self.sound_map.as_ref()
    }

    /// Where the N-ray fit at `t` starts ([`triangulate_from`]): the last
    /// estimate's triangulated point when the gate accepted it and it is at
    /// most [`WARM_HINT_MAX_AGE_S`] from `t`.
    fn warm_hint(&self, t: Stamp) -> Option<Point3<f64>> {
        let last = self.last_estimate.as_ref()?;
        let s = last.triangulation.solution().filter(|s| s.gate == Gate::Accepted)?;
        (t.seconds_since(last.stamp).abs() <= WARM_HINT_MAX_AGE_S).then_some(s.source_in_map)
    }

    /// Triangulates the rays aligned with `t`; also returns the newest stamp among them.
    fn triangulate_at(&mut self, now: Stamp, t: Stamp) -> Option<(Estimate, Stamp)> {
        let mut robots = Vec::with_capacity(self.robots.len());
        let mut rays = Vec::with_capacity(self.robots.len());
        let mut newest = Stamp::ZERO;
        for (id, _, o) in self.nearest_of_live(now, t) {
            if let Some(ray) = o.dominant() {
                robots.push(id.clone());
                rays.push(*ray);
                newest = newest.max(o.stamp);
            }
        }
        if rays.len() < 2 {
            self.counters.unaligned += 1;
            return None;
        }
        let triangulation = triangulate_from(&rays, &self.config.triangulation, self.warm_hint(t));
        let correlated_doa_fraction = self.config.tracking.correlated_doa_fraction;
        let estimate = Estimate {
            source_id: 0,
            stamp: t,
            robots,
            triangulation,
            filtered: None,
            smoothed: None,
            correlated_doa_fraction,
        };
        Some((estimate, newest))
    }

    /// Messages queued for robots' streams (commands, cancellations), oldest first.
    pub fn take_outgoing(&mut self) -> Vec<Outgoing> {
        std::mem::take(&mut self.outbox)
    }

    /// Active positioning settings.
    pub fn positioning(&self) -> PositioningSettings {
        self.positioning.settings()
    }

    /// The planner's latest decision, if it ran.
    pub fn planner_status(&self) -> Option<&PlannerStatus> {
        self.positioning.status()
    }

    /// What became of the DoAs given to the tracker; `None` when tracking is off.
    pub fn tracking_counters(&self) -> Option<TrackingCounters> {
        self.tracking.enabled().then(|| self.tracking.counters())
    }

    /// The latest estimate.
    pub fn last_estimate(&self) -> Option<&Estimate> {
        self.last_estimate.as_ref()
    }

    /// Known robots, by id.
    pub fn robots(&self) -> impl Iterator<Item = (&RobotId, &RobotEntry)> {
        self.robots.iter()
    }

    /// Liveness of a robot at `now`.
    pub fn liveness_of(&self, id: &RobotId, now: Stamp) -> Option<Liveness> {
        self.robots.get(id).map(|e| e.liveness(now, self.stale_after_ns()))
    }

    /// Source tracks since start: (born, restarted). With several sources,
    /// the sound map's births and diverged sources restarted from their rays;
    /// with one, the tracker's new tracks and its restarts from a good
    /// geometry after a poor start.
    pub fn source_track_events(&self) -> (u64, u64) {
        if let Some(map) = self.sound_map() {
            return (map.births, map.restarts);
        }
        self.tracking_counters().map_or((0, 0), |c| (c.tracks_started - c.restarts, c.restarts))
    }

    /// Counters since start.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Array centre of a robot in the map at its last pose.
    pub fn array_in_map(&self, id: &RobotId) -> Option<Point3<f64>> {
        let e = self.robots.get(id)?;
        Some(e.last_map_from_base? * e.hello.array.base_from_array * Point3::origin())
    }
}
