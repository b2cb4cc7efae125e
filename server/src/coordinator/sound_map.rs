//! The sound map: every source the robots hear, each with its own tracker,
//! when `sources.max_sources > 1` (with 1, the coordinator follows one source
//! from each robot's dominant DoA, as before).
//!
//! Per batch ([`SoundMap::step`], called by the coordinator's estimate):
//! 1. **Deaths.** A source's track lost for silence or spread leaves the live
//!    set; its last position is remembered for `sources.memory_s`.
//! 2. **Births.** Rays no live source claims, aligned across robots, are
//!    paired and gated, confirmed by a third robot where there is one, and the
//!    best disjoint set of candidates is kept ([`crate::association`]). A
//!    candidate made of the same robot-local tracks must recur in
//!    `sources.birth_rounds` consecutive rounds before a source is born from its
//!    triangulation; candidates born in one round are checked against the
//!    sources born before them in it, so two disjoint candidates at one
//!    source (each pair's rays missing the other's point, one robot holding a
//!    spurious second track of it) give one source, not two (`cocktail` seed
//!    7: two sources 0.3 m apart at talker 1, which then took turns: three id
//!    switches). No candidate is born within `sources.exclusion_radius_m` of
//!    a live source *horizontally*, at any height: elevation is the weak
//!    coordinate (a ceiling or floor reflection, small planar arrays reading
//!    10–25° high), and a robot's second track at a live source's azimuth but
//!    a steeper elevation, met by another robot's stray ray, triangulates
//!    above that source (`cocktail` seed 31: the TurtleBot's track of talker
//!    0's ceiling image, 118° at 48° elevation beside its direct track at
//!    117° and 27°, met the ReSpeaker's stray track 1.4 m above the talker, a
//!    ghost for 4.7 s). A source born within `sources.reuse_radius_m` of a
//!    remembered one, or of a live one silent for 0.5 s (which it replaces),
//!    takes back its id: a talker who pauses and speaks again at the same
//!    place keeps their id. A source's place is where it was last trusted.
//! 3. **Updates.** Every robot's observations are applied to the sources in
//!    stamp order up to the robots' watermark (as the single-source tracker
//!    does); the rays of each observation are assigned to sources jointly by
//!    global nearest neighbour with a prior that holds each robot-local track
//!    on the source it fed ([`crate::association`]). The assignments are
//!    remembered as *labels* (robot, local track) → source. A track without a
//!    label is never given to a silent source, and pays the penalty of a
//!    foreign label for a source another track of its robot fed within
//!    0.3 s (see [`crate::association`]).
//!
//! **Unheard candidates** (negative information). Two robots' rays aimed at
//! two different sources can meet where nothing is; a third robot can say
//! so. A candidate of two robots' rays alone is not born while a third robot
//! that hears something (at least one track in its aligned observation),
//! whose array is no smaller than both of theirs, and that is no farther from
//! the candidate, horizontally, than `sources.unheard_range_ratio` (1.5) ×
//! the farther of the two, has no ray within 3σ + 3° of it in azimuth
//! (azimuth only: small planar arrays read elevation 10–25° high in
//! reverberant rooms). By spherical spreading a source 1.5× farther is heard
//! 3.5 dB weaker: a robot that hears the room hears it. A robot that hears
//! nothing at all vetoes nothing (it may be deaf, near a wall), and neither
//! does a smaller array than the pair's: it confirms later and less (a 9 cm
//! ReSpeaker 6 confirmed a talker 0.2–2.8 s after two 16-microphone arrays in
//! `cocktail-active`, its birth threshold sitting above the diffuse field's
//! coherence at its zenith), so its silence is weak evidence. Worked cases
//! (`cocktail`): seed 5, after talker 0 stops, the ReSpeaker's ray toward the
//! fan and the TurtleBot's toward talker 1 meet at (0.08, 0.37, 1.31), 2.4 and
//! 1.8 m from them; the Pioneer, 2.0 m from it, hears talker 1 (80°) and the
//! fan (−48°) and nothing at 45°, so the ghost is not born. Seed 10, talker 0
//! speaking again after a pause: the ReSpeaker's track, dragged 10° toward
//! the fan meanwhile, and the TurtleBot's meet 0.5 m from the talker; the
//! Pioneer, 2.7 m from that point (1.14 × the TurtleBot's 2.37 m), has no ray
//! there; once its own track of the talker appears the talker is born where
//! it is (RSE median 0.12 m from 30 s on, against 0.5–0.8 m without the
//! veto). The cost: a source the nearest large array does not hear (masked,
//! or just starting) waits until it does or a farther pair confirms it.
//!
//! **Diverged filters.** A planar array cannot tell a source above its plane
//! from its mirror image below it (see [`crate::floor_image`]): both give the
//! same folded DoA. A filter that crossed the arrays' plane (pulled down by a
//! floor-image read and carried on by its velocity) found every DoA as
//! consistent with the mirror and stayed there; with arrays at one height
//! the tracker now mirrors it back at once (`doa.upper_branch`,
//! [`crate::floor_image`], "The fold's two branches"), and what follows is
//! the guard for the cases that rule leaves to the data (arrays at
//! different heights, the rule turned off). After each round's updates a source's filter is
//! compared with the triangulation of its own rays, those whose track fed it
//! within the last 0.3 s (a track that went over to another source stops
//! feeding this one, and its stale label must not judge it): when they are
//! more than 0.3 m apart and beyond the 99.99 % χ² (3 dof) of their summed
//! covariances in every round for 1 s, the source is restarted from that
//! triangulation (a new tentative track, the same id). Worked case
//! (`cocktail` seed 5): the fan at (0.2, −2.7, 0.8), heard by the Pioneer and
//! the TurtleBot (arrays about 0.5 m up), was read for 1.5 s at 0.2 m (the
//! floor image); the filter followed it down through the arrays' plane and
//! sat at −0.2 m, where the folded model (floor and ceiling images included)
//! explains the DoAs as well as their meeting point at 0.8–1.0 m does: NIS ≈
//! 0.1 on every DoA. From 31.3 s on the two disagreed; at 32.3 s the fan was
//! restarted at 1.03 m (run OSPA 0.317 → 0.287 m, ghosts 0.128 → 0.078/s).
//!
//! A source's track is lost after `single_robot_timeout_s` of rays from one
//! robot alone; a silence before that robot's rays does not count (a talker
//! heard again first by one robot after a pause is not a track being dragged).
//! 4. **Estimates.** For each live source, the rays of the robots whose
//!    aligned observation holds a track labelled with it are triangulated, and
//!    the source's filtered state is published beside that triangulation.
//!    With one such ray, see "One robot's ray".
//!
//! **One robot's ray.** Talkers drop out of one robot's hearing for a few
//! hundred milliseconds at a time (a word masked by the other talker, a
//! small array's track lagging), while another robot still hears them. The
//! source's filter is then still updated by that robot's rays (a bearing
//! through a known point keeps it there), and it is published on its filter
//! alone when: two robots' fresh rays (as for diverged filters) fed it within
//! the last 0.5 s, its track fed it within 0.3 s, its filter is trusted, and
//! no other live source's gate holds the ray (a bearing through two mapped
//! sources does not say which of them sounds). The estimate carries that one
//! robot and no triangulation, so it is not *trusted* ([`Estimate::trusted`]:
//! one bearing leaves the range unobserved) and active positioning does not
//! serve it (no geometry to improve), but keeps its goals clear of it. Longer
//! holds bought little: after a talker stops, the agents' tracks linger up to
//! a second, so holding 1 or 2 s added ghosts (`cocktail` seed 4: 0.040 →
//! 0.055 or 0.065 ghosts/s) for detection 0.882 instead of 0.880 (seeds 1–5).
//! Measured (`cocktail` seeds 1–10): detection 0.833 → 0.857, OSPA 0.263 →
//! 0.249 m, ghosts 0.029 → 0.046/s; `cocktail-active` 0.821 → 0.835, 0.290 →
//! 0.281 m, 0.026 → 0.035/s.
//!
//! [`Estimate::trusted`]: super::Estimate::trusted

use std::collections::HashMap;

use nalgebra::Point3;
use soundmap_proto::Stamp;

use super::doa_queue::{DoaQueue, Queued};
use crate::association::{assign, best_disjoint, signature_similarity};
use crate::config::SourcesConfig;
use crate::ray::Ray;
use crate::stats::chi2_quantile;
use crate::tracking::{
    InitOutcome, SmoothedEstimate, SourceTracker, TrackEstimate, TrackerConfig, UpdateOutcome,
};
use crate::triangulation::{
    Gate, GateReason, Triangulation, TriangulationConfig, triangulate, triangulate_from,
};

pub use super::records::SourceRecord;
pub use super::robots::TaggedRay;

/// A robot-local track: (robot index, the robot's track id).
type TrackKey = (u32, u64);

/// A birth candidate: its tracks (sorted), their triangulation and newest stamp.
type Candidate = (Vec<TrackKey>, Triangulation, Stamp);

/// A robot's rays aligned with the estimate's stamp.
#[derive(Clone, Debug)]
pub struct AlignedRays {
    /// Robot index.
    pub robot: u32,
    /// Stamp of the observation.
    pub stamp: Stamp,
    /// Its rays.
    pub rays: Vec<TaggedRay>,
}

/// A source in the map.
#[derive(Clone, Debug)]
struct MapSource {
    id: u64,
    tracker: SourceTracker,
    first_heard: Stamp,
    last_heard: Stamp,
    /// Where the source was when last trusted (two robots' rays, consistent
    /// filter): its place for id reuse. One robot's rays alone can drag the
    /// filter along that robot's bearing before the source is lost.
    anchor: Option<Point3<f64>>,
    /// Since when the filter has disagreed with its own rays' triangulation
    /// in every round (see the module docs, "Diverged filters").
    diverged_since: Option<Stamp>,
    /// Newest stamp at which two robots' fresh rays fed it.
    last_pair: Option<Stamp>,
}

impl MapSource {
    /// The position that stands for this source when it is lost or silent.
    fn place(&self) -> Option<Point3<f64>> {
        self.anchor.or_else(|| self.tracker.estimate().map(|e| e.position_in_map))
    }

    fn is_silent(&self, at: Stamp) -> bool {
        at - self.last_heard > SILENT_NS
    }
}

/// A lost source kept for its id.
#[derive(Clone, Copy, Debug)]
struct Remembered {
    id: u64,
    first_heard: Stamp,
    position_in_map: Point3<f64>,
    last_heard: Stamp,
    covariance: nalgebra::Matrix3<f64>,
}

/// Which source a robot-local track fed last, and when.
#[derive(Clone, Copy, Debug)]
struct Label {
    source: u64,
    last: Stamp,
}

/// Where a birth takes its id from.
#[derive(Clone, Copy, Debug)]
enum Reuse {
    Remembered(usize),
    Silent(usize),
}

/// An unclaimed ray, as births see it.
#[derive(Clone, Debug)]
struct Free {
    robot: u32,
    track: u64,
    ray: Ray,
    stamp: Stamp,
    signature: Option<std::sync::Arc<[f32]>>,
}

/// Two tracks whose signatures correlate less than this are not paired
/// (a fan and a talker); above it, the correlation × γ is added to the
/// candidate's score.
const MIN_SIGNATURE_SIMILARITY: f64 = 0.3;

/// A source not heard for this long is *silent* (ns): a robot-local track
/// that no source has claimed yet costs γ/2 more to give it (see
/// [`crate::association`]).
const SILENT_NS: i64 = 500_000_000;

/// Slack beyond 3 σ within which a ray counts as pointing at a point (rad,
/// 3°): rooms bias DoAs by about a degree. Used by unheard candidates (in
/// azimuth) and diverged filters.
const RAY_SLACK_RAD: f64 = 0.052;

/// A source's filter and its own rays' triangulation further apart than this
/// χ² (3 dof) quantile of their summed covariances, and than
/// [`DIVERGED_MIN_M`], disagree.
const DIVERGED_PROBABILITY: f64 = 0.9999;

/// Only rays whose track fed the source this recently (ns) judge its filter:
/// a track that has gone over to another source stops feeding it.
const FRESH_LABEL_NS: i64 = 300_000_000;

/// Disagreements smaller than this (m) are left to the filter.
const DIVERGED_MIN_M: f64 = 0.3;

/// A source whose filter disagrees with its rays in every round for this long
/// (ns) is restarted from them.
const DIVERGED_NS: i64 = 1_000_000_000;

/// A source two robots' fresh rays fed within this long (ns) is still
/// published on one robot's ray (see the module docs, "One robot's ray").
const ONE_ROBOT_HOLD_NS: i64 = 500_000_000;

/// Labels not refreshed for this long are forgotten (ns).
const LABEL_TTL_NS: i64 = 5_000_000_000;

/// One published source at a stamp: its id, the robots and rays that heard
/// it, their triangulation, and its filtered state.
#[derive(Clone, Debug)]
pub struct SourceSighting {
    /// Source id.
    pub source_id: u64,
    /// Robot indices of the rays.
    pub robots: Vec<u32>,
    /// The rays' triangulation.
    pub triangulation: Triangulation,
    /// The source's filtered state at the stamp.
    pub filtered: Option<TrackEstimate>,
    /// The source's fixed-lag smoothed state (behind the stamp).
    pub smoothed: Option<SmoothedEstimate>,
    /// Newest stamp of the rays.
    pub newest: Stamp,
}

/// The sound map (see the [module docs](self)).
#[derive(Debug)]
pub struct SoundMap {
    config: SourcesConfig,
    tracker: TrackerConfig,
    gate: f64,
    sources: Vec<MapSource>,
    remembered: Vec<Remembered>,
    labels: HashMap<(u32, u64), Label>,
    /// Birth candidates by their (robot, track) keys: consecutive rounds seen.
    candidates: HashMap<Vec<(u32, u64)>, u32>,
    /// Observations not yet applied, at most `tracking.max_doa_rate_hz` per robot.
    queue: DoaQueue<Vec<TaggedRay>>,
    next_id: u64,
    /// Sources born since start.
    pub births: u64,
    /// Diverged sources restarted from their rays since start.
    pub restarts: u64,
}

impl SoundMap {
    /// An empty map.
    pub fn new(config: SourcesConfig, tracker: TrackerConfig) -> Self {
        let gate = chi2_quantile(2, tracker.association_probability);
        let queue = DoaQueue::new(tracker.max_doa_rate_hz);
        SoundMap {
            config,
            tracker,
            gate,
            sources: Vec::new(),
            remembered: Vec::new(),
            labels: HashMap::new(),
            candidates: HashMap::new(),
            queue,
            next_id: 1,
            births: 0,
            restarts: 0,
        }
    }

    /// Robot `robot`'s observation stamped `stamp` (its rays may be empty). As
    /// for one source, a robot's observations reach the trackers at most
    /// `tracking.max_doa_rate_hz` times a second: a room biases a robot's
    /// successive DoAs alike, and applied as independent they would make the
    /// filters overconfident.
    pub fn push(&mut self, stamp: Stamp, robot: u32, rays: Vec<TaggedRay>) {
        self.queue.note_stamp(robot, stamp);
        for t in &rays {
            let d = t.ray.direction_in_map;
            tracing::trace!(
                robot,
                at_ns = stamp.as_ns(),
                track = t.track_id,
                activity = t.activity,
                azimuth_deg = d.y.atan2(d.x).to_degrees(),
                elevation_deg = d.z.asin().to_degrees(),
                sigma_deg = t.ray.sigma_rad.to_degrees(),
                "ray"
            );
        }
        if !rays.is_empty() {
            self.queue.push(stamp, robot, rays);
        }
    }

    /// Robot `robot` is gone: the watermark no longer waits for it.
    pub fn forget_robot(&mut self, robot: u32) {
        self.queue.forget_robot(robot);
    }

    /// Deaths, births from `aligned` (each live robot's observation nearest the
    /// stamp), then the queued updates up to the watermark at `now`.
    pub fn step(&mut self, now: Stamp, aligned: &[AlignedRays], triangulation: &TriangulationConfig) {
        self.deaths(now);
        self.births(now, aligned, triangulation);
        self.flush(now);
        self.restarts(aligned, triangulation);
        self.labels.retain(|_, l| now - l.last < LABEL_TTL_NS);
    }

    /// Applies queued observations up to the watermark.
    pub fn flush(&mut self, now: Stamp) {
        let Some(watermark) = self.queue.watermark(now) else { return };
        while let Some(q) = self.queue.pop_until(watermark) {
            self.apply(q);
        }
    }

    fn deaths(&mut self, now: Stamp) {
        let memory_ns = (self.config.memory_s * 1e9) as i64;
        self.remembered.retain(|r| now - r.last_heard <= memory_ns);
        let mut i = 0;
        while i < self.sources.len() {
            self.sources[i].tracker.maintain(now);
            if self.sources[i].tracker.needs_track() {
                let s = self.sources.swap_remove(i);
                if let (Some(e), Some(place)) = (s.tracker.estimate(), s.place()) {
                    self.remembered.push(Remembered {
                        id: s.id,
                        first_heard: s.first_heard,
                        position_in_map: place,
                        last_heard: s.last_heard,
                        covariance: e.position_covariance(),
                    });
                }
                self.labels.retain(|_, l| l.source != s.id);
                tracing::debug!(source = s.id, at_ns = now.as_ns(), reason = ?s.tracker.loss(), "source lost");
            } else {
                i += 1;
            }
        }
    }

    /// One observation's rays assigned to the live sources (GNN with the label prior).
    fn apply(&mut self, q: Queued<Vec<TaggedRay>>) {
        if self.sources.is_empty() {
            return;
        }
        let half = self.gate * 0.5;
        // Whether a track of this robot fed each source within the last
        // 0.3 s: an unlabelled track of the robot (necessarily another one)
        // joins that source only as a track labelled elsewhere does (see
        // the module docs). Only needed when the observation has one.
        let mut held = vec![false; self.sources.len()];
        if q.item.iter().any(|t| !self.labels.contains_key(&(q.robot, t.track_id))) {
            for ((robot, _), l) in &self.labels {
                if *robot == q.robot
                    && q.stamp - l.last <= FRESH_LABEL_NS
                    && let Some(j) = self.sources.iter().position(|s| s.id == l.source)
                {
                    held[j] = true;
                }
            }
        }
        let cost: Vec<Vec<f64>> = q
            .item
            .iter()
            .map(|t| {
                let (ray, track) = (&t.ray, &t.track_id);
                let label = self.labels.get(&(q.robot, *track)).map(|l| l.source);
                self.sources
                    .iter()
                    .zip(&held)
                    .map(|(s, held)| match s.tracker.nis(q.stamp, ray) {
                        Some(nis) if nis <= self.gate => match label {
                            Some(l) if l == s.id => nis - half,
                            Some(_) => nis + half,
                            None if *held => nis + half,
                            // A new robot-local track resumes a silent source
                            // only through a birth at its place (see the module docs).
                            None if s.is_silent(q.stamp) => f64::INFINITY,
                            None => nis,
                        },
                        _ => f64::INFINITY,
                    })
                    .collect()
            })
            .collect();
        for (k, j) in assign(&cost, self.gate).into_iter().enumerate() {
            tracing::trace!(
                at_ns = q.stamp.as_ns(),
                robot = q.robot,
                track = q.item[k].track_id,
                source = j.map(|j| self.sources[j].id),
                costs = ?cost[k],
                "ray assigned"
            );
            let Some(j) = j else { continue };
            let (ray, track) = (q.item[k].ray, q.item[k].track_id);
            let s = &mut self.sources[j];
            if matches!(s.tracker.update(q.stamp, q.robot, &ray), UpdateOutcome::Applied { .. }) {
                s.last_heard = s.last_heard.max(q.stamp);
                if let Some(e) = s.tracker.estimate().filter(|e| e.trusted) {
                    s.anchor = Some(e.position_in_map);
                }
                self.labels.insert((q.robot, track), Label { source: s.id, last: q.stamp });
            }
        }
    }

    fn claimed(&self, robot: u32, track: u64) -> bool {
        self.labels.get(&(robot, track)).is_some_and(|l| self.sources.iter().any(|s| s.id == l.source))
    }

    /// Candidate births from the unclaimed aligned rays (see the module docs).
    fn births(&mut self, now: Stamp, aligned: &[AlignedRays], config: &TriangulationConfig) {
        // A ray a live source explains (within its gate) seeds no birth even
        // before its observation is applied: births run before the batch's
        // updates, and a source born last round has not yet labelled the
        // other robots' tracks of it.
        let explained = |stamp: Stamp, ray: &Ray| {
            self.sources
                .iter()
                .filter(|s| !s.is_silent(stamp))
                .any(|s| s.tracker.nis(stamp, ray).is_some_and(|nis| nis <= self.gate))
        };
        let free: Vec<Free> = aligned
            .iter()
            .flat_map(|a| {
                a.rays
                    .iter()
                    .filter(|t| !self.claimed(a.robot, t.track_id) && !explained(a.stamp, &t.ray))
                    .map(move |t| Free {
                        robot: a.robot,
                        track: t.track_id,
                        ray: t.ray,
                        stamp: a.stamp,
                        signature: t.signature.clone(),
                    })
            })
            .collect();
        let mut members: Vec<Vec<(u32, u64)>> = Vec::new();
        let mut scores = Vec::new();
        let mut solutions = Vec::new();
        for (i, a) in free.iter().enumerate() {
            for b in free.iter().skip(i + 1).filter(|b| b.robot != a.robot) {
                // Two tracks whose spectra clearly differ hear different sources.
                let similarity = signature_similarity(a.signature.as_deref(), b.signature.as_deref());
                if similarity.is_some_and(|s| s < MIN_SIGNATURE_SIMILARITY) {
                    continue;
                }
                let Some((keys, tri, newest)) = self.candidate(a, b, &free, config) else { continue };
                let unheard = if keys.len() == 2 { self.unheard(&tri, &keys, aligned) } else { None };
                if let (Some(robot), Some(p)) = (unheard, tri.solution().map(|s| s.source_in_map)) {
                    tracing::debug!(
                        at_ns = a.stamp.as_ns(),
                        robot,
                        x = p.x,
                        y = p.y,
                        z = p.z,
                        "unheard candidate"
                    );
                    continue;
                }
                let bonus = similarity.map_or(0.0, |s| self.gate * s);
                scores.push(2.0 * self.gate * keys.len() as f64 - tri_chi2(&tri) + bonus);
                members.push(keys);
                solutions.push((tri, newest));
            }
        }
        let chosen = best_disjoint(&members, &scores);
        let mut seen = HashMap::new();
        for i in chosen {
            let rounds = self.candidates.get(&members[i]).copied().unwrap_or(0) + 1;
            seen.insert(members[i].clone(), rounds);
            if rounds >= self.config.birth_rounds {
                let (tri, newest) = &solutions[i];
                // Two candidates born in one round at one source (disjoint
                // tracks of it): the first born excludes the other.
                if self.near_live(*newest, tri) {
                    seen.remove(&members[i]);
                    continue;
                }
                self.birth(now, *newest, tri, &members[i]);
                seen.remove(&members[i]);
            }
        }
        self.candidates = seen;
    }

    /// The candidate made of rays `a` and `b` and any third robots' rays that
    /// pass near its point, if its triangulation is accepted and it is not at a
    /// live source.
    fn candidate(
        &self,
        a: &Free,
        b: &Free,
        free: &[Free],
        config: &TriangulationConfig,
    ) -> Option<Candidate> {
        let pair = triangulate(&[a.ray, b.ray], config);
        let point = usable(&pair, config)?;
        let mut keys = vec![(a.robot, a.track), (b.robot, b.track)];
        let mut rays = vec![a.ray, b.ray];
        let mut newest = a.stamp.max(b.stamp);
        let mut robots = vec![a.robot, b.robot];
        for c in free {
            if robots.contains(&c.robot) {
                continue;
            }
            let similarity = signature_similarity(a.signature.as_deref(), c.signature.as_deref());
            if similarity.is_some_and(|s| s < MIN_SIGNATURE_SIMILARITY) {
                continue;
            }
            let to = point - c.ray.origin_in_map;
            let angle = to.normalize().dot(&c.ray.direction_in_map).clamp(-1.0, 1.0).acos();
            if angle <= 3.0 * c.ray.sigma_rad.max(1e-3) {
                robots.push(c.robot);
                keys.push((c.robot, c.track));
                rays.push(c.ray);
                newest = newest.max(c.stamp);
            }
        }
        let tri = if rays.len() > 2 { triangulate(&rays, config) } else { pair };
        usable(&tri, config)?;
        // A silent source is no obstacle: a birth at its place resumes it.
        let at = a.stamp.max(b.stamp);
        if self.near_live(at, &tri) {
            return None;
        }
        keys.sort();
        Some((keys, tri, newest))
    }

    /// Whether a live source is consistent with triangulation `tri` at `at`
    /// (within the exclusion radius horizontally, at any height, or within
    /// the 99 % χ² (3 dof) of their summed covariances): the same source
    /// heard by tracks not yet labelled with it (see the module docs).
    fn near_live(&self, at: Stamp, tri: &Triangulation) -> bool {
        let Some(solution) = tri.solution() else { return false };
        let point = solution.source_in_map;
        let tri_cov = solution.quality.covariance;
        let same = chi2_quantile(3, 0.99);
        self.sources.iter().filter(|s| !s.is_silent(at)).any(|s| {
            s.tracker.estimate().is_some_and(|e| {
                let d = e.position_in_map - point;
                horizontal(d).norm() < self.config.exclusion_radius_m
                    || tri_cov
                        .and_then(|c| (c + e.position_covariance()).try_inverse())
                        .is_some_and(|inv| (d.transpose() * inv * d)[(0, 0)] <= same)
            })
        })
    }

    /// A robot other than the candidate's, hearing something, with an array
    /// no smaller than theirs and no farther from the candidate than
    /// `unheard_range_ratio` × the farther of its robots, that has no ray
    /// towards it, if there is one (see the module docs).
    fn unheard(&self, tri: &Triangulation, keys: &[TrackKey], aligned: &[AlignedRays]) -> Option<u32> {
        let ratio = self.config.unheard_range_ratio;
        let point = tri.solution().map(|s| s.source_in_map)?;
        if ratio <= 0.0 {
            return None;
        }
        let first = |robot: u32| aligned.iter().find(|a| a.robot == robot).and_then(|a| a.rays.first());
        let reach = keys
            .iter()
            .filter_map(|&(robot, _)| first(robot))
            .map(|t| horizontal(point - t.ray.origin_in_map).norm())
            .fold(0.0, f64::max);
        // The smaller of the two arrays, when both are known.
        let smallest = keys
            .iter()
            .map(|&(robot, _)| first(robot).and_then(|t| t.aperture_m))
            .try_fold(f64::INFINITY, |m, a| a.map(|a| m.min(a)));
        let unheard_by = aligned.iter().filter(|a| keys.iter().all(|k| k.0 != a.robot)).find(|a| {
            let Some(t0) = a.rays.first() else { return false };
            // A smaller array than both of the pair's hears later and less.
            if t0.aperture_m.zip(smallest).is_some_and(|(own, pair)| own < pair) {
                return false;
            }
            let to = horizontal(point - t0.ray.origin_in_map);
            let near = to.norm() <= ratio * reach;
            near && a.rays.iter().all(|t| {
                let d = horizontal(t.ray.direction_in_map.into_inner());
                let angle = to.angle(&d);
                angle > 3.0 * t.ray.sigma_rad + RAY_SLACK_RAD
            })
        });
        unheard_by.map(|a| a.robot)
    }

    fn birth(&mut self, now: Stamp, newest: Stamp, tri: &Triangulation, keys: &[(u32, u64)]) {
        let mut tracker = SourceTracker::new(self.tracker.clone());
        let Some(solution) = tri.solution() else { return };
        let Some(covariance) = solution.quality.covariance else { return };
        // An accepted triangulation or one only ill-conditioned (robots side by
        // side): its covariance says how little it pins down the range.
        let inflation = self.tracker.init_covariance_inflation;
        let started = tracker.initialize(newest, solution.source_in_map, covariance * inflation);
        if !matches!(started, InitOutcome::Started { .. }) {
            return;
        }
        let point = solution.source_in_map;
        let mut first_heard = newest;
        // The nearest within the reuse radius of the remembered sources and
        // the live ones gone silent gives its id (a silent one is replaced).
        let radius = self.config.reuse_radius_m;
        let remembered =
            self.remembered.iter().enumerate().map(|(i, r)| (Reuse::Remembered(i), r.position_in_map));
        let silent = (self.sources.iter().enumerate())
            .filter(|(_, s)| s.is_silent(newest))
            .filter_map(|(i, s)| Some((Reuse::Silent(i), s.place()?)));
        let reuse = remembered
            .chain(silent)
            .map(|(k, p)| (k, (p - point).norm()))
            .filter(|(_, d)| *d <= radius)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(k, _)| k);
        let full = self.sources.len() >= self.config.max_sources;
        if full && !matches!(reuse, Some(Reuse::Silent(_))) {
            return;
        }
        let id = match reuse {
            Some(Reuse::Remembered(i)) => {
                let r = self.remembered.swap_remove(i);
                first_heard = r.first_heard;
                r.id
            }
            Some(Reuse::Silent(i)) => {
                let s = self.sources.swap_remove(i);
                self.labels.retain(|_, l| l.source != s.id);
                first_heard = s.first_heard;
                tracing::debug!(source = s.id, at_ns = newest.as_ns(), "silent source resumed");
                s.id
            }
            None => {
                self.next_id += 1;
                self.next_id - 1
            }
        };
        for &(robot, track) in keys {
            self.labels.insert((robot, track), Label { source: id, last: now });
        }
        self.births += 1;
        tracing::debug!(
            source = id,
            at_ns = newest.as_ns(),
            x = point.x,
            y = point.y,
            z = point.z,
            "source born"
        );
        // Two robots' rays that meet: its place until it is trusted.
        self.sources.push(MapSource {
            id,
            tracker,
            first_heard,
            last_heard: newest,
            anchor: Some(point),
            diverged_since: None,
            last_pair: None,
        });
    }

    /// The rays in `aligned` labelled with source `id` (one per robot), their
    /// robots and newest stamp; with `fresh_ns`, only those whose track fed
    /// the source within that long before the ray.
    fn labelled(
        &self,
        id: u64,
        aligned: &[AlignedRays],
        fresh_ns: Option<i64>,
    ) -> (Vec<u32>, Vec<Ray>, Stamp) {
        let mut robots = Vec::new();
        let mut rays = Vec::new();
        let mut newest = Stamp::ZERO;
        for a in aligned {
            let labelled = a.rays.iter().find(|t| {
                self.labels
                    .get(&(a.robot, t.track_id))
                    .is_some_and(|l| l.source == id && fresh_ns.is_none_or(|f| a.stamp - l.last <= f))
            });
            if let Some(t) = labelled {
                robots.push(a.robot);
                rays.push(t.ray);
                newest = newest.max(a.stamp);
            }
        }
        (robots, rays, newest)
    }

    /// Restarts, from its own rays' triangulation, a source whose filter has
    /// disagreed with that triangulation for [`DIVERGED_NS`] (see the module
    /// docs, "Diverged filters"). On the way, notes when two robots' fresh
    /// rays last fed each source (`last_pair`, read by
    /// [`SoundMap::held_by_one`]): the same fresh rays judge both.
    fn restarts(&mut self, aligned: &[AlignedRays], config: &TriangulationConfig) {
        let limit = chi2_quantile(3, DIVERGED_PROBABILITY);
        let inflation = self.tracker.init_covariance_inflation;
        for i in 0..self.sources.len() {
            let (_, rays, newest) = self.labelled(self.sources[i].id, aligned, Some(FRESH_LABEL_NS));
            if rays.len() < 2 {
                continue;
            }
            self.sources[i].last_pair = Some(newest);
            let Some(e) = self.sources[i].tracker.predict_to(newest) else { continue };
            // Rays that each pass near the filter (unfolded) meet near it: no
            // triangulation needed.
            let near = rays.iter().all(|r| {
                let to = e.position_in_map - r.origin_in_map;
                to.angle(&r.direction_in_map) <= 3.0 * r.sigma_rad + RAY_SLACK_RAD
            });
            let s = &mut self.sources[i];
            if near {
                s.diverged_since = None;
                continue;
            }
            let tri = triangulate(&rays, config);
            let Some(solution) = tri.solution().filter(|s| s.gate == Gate::Accepted) else { continue };
            let Some(covariance) = solution.quality.covariance else { continue };
            let d = solution.source_in_map - e.position_in_map;
            let m = (covariance + e.position_covariance())
                .try_inverse()
                .map_or(f64::INFINITY, |inv| (d.transpose() * inv * d)[(0, 0)]);
            if !(m > limit && d.norm() > DIVERGED_MIN_M) {
                s.diverged_since = None;
                continue;
            }
            let since = *s.diverged_since.get_or_insert(newest);
            if newest - since < DIVERGED_NS {
                continue;
            }
            let point = solution.source_in_map;
            if matches!(
                s.tracker.initialize(newest, point, covariance * inflation),
                InitOutcome::Started { .. }
            ) {
                tracing::debug!(
                    source = s.id,
                    at_ns = newest.as_ns(),
                    x = point.x,
                    y = point.y,
                    z = point.z,
                    off_m = d.norm(),
                    "diverged source restarted from its rays"
                );
                s.anchor = Some(point);
                s.diverged_since = None;
                self.restarts += 1;
            }
        }
    }

    /// Whether a source that only robot's `ray` (stamped `newest`) hears is
    /// still published (see the module docs, "One robot's ray"): its track fed
    /// the source within [`FRESH_LABEL_NS`], two robots' fresh rays fed it
    /// within [`ONE_ROBOT_HOLD_NS`], its filter at the sighting (`filtered`)
    /// is trusted, and no other live source explains the ray.
    fn held_by_one(
        &self,
        s: &MapSource,
        aligned: &[AlignedRays],
        ray: &Ray,
        newest: Stamp,
        filtered: Option<&TrackEstimate>,
    ) -> bool {
        s.last_pair.is_some_and(|p| newest - p <= ONE_ROBOT_HOLD_NS)
            && self.labelled(s.id, aligned, Some(FRESH_LABEL_NS)).1.len() == 1
            && filtered.is_some_and(|e| e.trusted)
            && !self
                .sources
                .iter()
                .any(|o| o.id != s.id && o.tracker.nis(newest, ray).is_some_and(|n| n <= self.gate))
    }

    /// What each live source looks like at `stamp`: the aligned rays labelled
    /// with it, their triangulation and its filter; heard by at least two
    /// robots, or by one for a short while (see the module docs, "One robot's ray").
    pub fn sightings(
        &self,
        aligned: &[AlignedRays],
        stamp: Stamp,
        config: &TriangulationConfig,
    ) -> Vec<SourceSighting> {
        let mut out = Vec::new();
        for s in &self.sources {
            let (robots, rays, newest) = self.labelled(s.id, aligned, None);
            if rays.is_empty() {
                continue;
            }
            let filtered = s.tracker.predict_to(stamp);
            if rays.len() == 1 && !self.held_by_one(s, aligned, &rays[0], newest, filtered.as_ref()) {
                continue;
            }
            // The filter predicted to the rays' stamp starts the N-ray fit
            // (crate::triangulation, "Warm starts").
            let hint = filtered.as_ref().map(|f| f.position_in_map);
            out.push(SourceSighting {
                source_id: s.id,
                robots,
                triangulation: triangulate_from(&rays, config, hint),
                filtered,
                smoothed: s.tracker.smoothed(),
                newest,
            });
        }
        out
    }

    /// Whether `id` was ever given to a source.
    pub fn has_given(&self, id: u64) -> bool {
        id != 0 && id < self.next_id
    }

    /// Every source, live and remembered, as it survives a restart, and the next id.
    pub fn export(&self) -> (Vec<SourceRecord>, u64) {
        let live = self.sources.iter().filter_map(|s| {
            let e = s.tracker.estimate()?;
            Some(SourceRecord {
                id: s.id,
                position_in_map: e.position_in_map,
                covariance: e.position_covariance(),
                first_heard: s.first_heard,
                last_heard: s.last_heard,
            })
        });
        let remembered = self.remembered.iter().map(|r| SourceRecord {
            id: r.id,
            position_in_map: r.position_in_map,
            covariance: r.covariance,
            first_heard: r.first_heard,
            last_heard: r.last_heard,
        });
        (live.chain(remembered).collect(), self.next_id)
    }

    /// After a restart: every recorded source is remembered (a source born
    /// within `reuse_radius_m` of one takes back its id), and ids start at
    /// `next_id` at least.
    pub fn restore(&mut self, records: &[SourceRecord], next_id: u64) {
        self.next_id = self.next_id.max(next_id).max(records.iter().map(|r| r.id + 1).max().unwrap_or(1));
        for r in records {
            if self.remembered.iter().any(|m| m.id == r.id) {
                continue;
            }
            self.remembered.push(Remembered {
                id: r.id,
                first_heard: r.first_heard,
                position_in_map: r.position_in_map,
                last_heard: r.last_heard,
                covariance: r.covariance,
            });
        }
    }

    /// Lost sources still remembered for their ids: (id, last position, first heard, last heard).
    pub fn remembered(&self) -> impl Iterator<Item = (u64, Point3<f64>, Stamp, Stamp)> + '_ {
        self.remembered.iter().map(|r| (r.id, r.position_in_map, r.first_heard, r.last_heard))
    }

    /// Live sources: (id, first heard, last heard, filtered state).
    pub fn sources(&self) -> impl Iterator<Item = (u64, Stamp, Stamp, Option<TrackEstimate>)> + '_ {
        self.sources.iter().map(|s| (s.id, s.first_heard, s.last_heard, s.tracker.estimate()))
    }
}

/// The point of a triangulation a source may be born from: one its gate
/// accepted, or one rejected only as ill-conditioned or uncertain whose rays
/// still meet (residual χ² within its quantile), as robots side by side give.
fn usable(t: &Triangulation, config: &TriangulationConfig) -> Option<Point3<f64>> {
    let s = t.solution()?;
    let ok = match s.gate {
        Gate::Accepted => true,
        Gate::Rejected(GateReason::IllConditioned { .. } | GateReason::Uncertain { .. }) => {
            s.residual_chi2 <= chi2_quantile(s.residual_dof, config.residual_probability)
        }
        Gate::Rejected(_) => false,
    };
    ok.then_some(s.source_in_map)
}

/// The horizontal part of a map-frame vector.
fn horizontal(v: nalgebra::Vector3<f64>) -> nalgebra::Vector2<f64> {
    nalgebra::Vector2::new(v.x, v.y)
}

fn tri_chi2(t: &Triangulation) -> f64 {
    t.solution().map_or(f64::INFINITY, |s| s.residual_chi2)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix3, Point3};
    use soundmap_proto::Stamp;

    use super::{AlignedRays, SoundMap, TaggedRay};
    use crate::config::SourcesConfig;
    use crate::floor_image::three_mic_fold;
    use crate::ray::Ray;
    use crate::tracking::TrackerConfig;
    use crate::triangulation::TriangulationConfig;

    /// The source the arrays of [`folded_pair`] hear.
    const SOURCE: Point3<f64> = Point3::new(0.0, 0.0, 1.2);
    /// Its mirror image in their plane.
    const MIRROR: Point3<f64> = Point3::new(0.0, 0.0, -0.2);

    /// Two planar arrays 0.5 m above the floor hear [`SOURCE`]; each
    /// measures it folded onto the upper hemisphere. The closure runs round
    /// k: both robots' DoAs at k × 50 ms, and a step of the map.
    fn folded_pair(upper_branch: bool) -> (SoundMap, impl FnMut(&mut SoundMap, i64) -> Stamp) {
        let fold = crate::floor_image::FloorFold { upper_branch, ..three_mic_fold(0.0, None) };
        let origins = [Point3::new(-3.0, 0.0, 0.5), Point3::new(0.0, -3.0, 0.5)];
        let config = SourcesConfig { max_sources: 4, ..SourcesConfig::default() };
        let map = SoundMap::new(config, TrackerConfig::default());
        let tri = TriangulationConfig::default();
        let t0 = Stamp::from_ns(1_767_225_600_000_000_000);
        let ray = move |o: Point3<f64>| Ray {
            origin_in_map: o,
            direction_in_map: fold.measured_direction(&o, &SOURCE).expect("not straight above"),
            sigma_rad: 1f64.to_radians(),
            origin_sigma_m: 0.0,
            fold: Some(fold),
        };
        let round = move |map: &mut SoundMap, k: i64| {
            let stamp = t0.plus_ns(k * 50_000_000);
            let aligned: Vec<AlignedRays> = (0..2u32)
                .map(|r| AlignedRays {
                    robot: r,
                    stamp,
                    rays: vec![TaggedRay {
                        ray: ray(origins[r as usize]),
                        activity: 0.9,
                        track_id: 1,
                        signature: None,
                        aperture_m: Some(0.2),
                    }],
                })
                .collect();
            for a in &aligned {
                map.push(a.stamp, a.robot, a.rays.clone());
            }
            map.step(stamp.plus_ns(20_000_000), &aligned, &tri);
            stamp
        };
        (map, round)
    }

    fn only_position(map: &SoundMap) -> (u64, Point3<f64>) {
        let all: Vec<_> = map.sources().collect();
        assert_eq!(all.len(), 1, "one source");
        (all[0].0, all[0].3.expect("an estimate").position_in_map)
    }

    /// [`folded_pair`] run for 2 s (the source born where it is), its filter
    /// then put at the source's mirror image and ten more rounds run: the map,
    /// the rounds and the source's id.
    fn put_at_the_mirror(upper_branch: bool) -> (SoundMap, impl FnMut(&mut SoundMap, i64) -> Stamp, u64) {
        let (mut map, mut round) = folded_pair(upper_branch);
        for k in 0..40 {
            round(&mut map, k);
        }
        let (id, p) = only_position(&map);
        assert!((p - SOURCE).norm() < 0.15, "born at {p}");
        let stamp = round(&mut map, 40);
        map.sources[0].tracker.initialize(stamp, MIRROR, Matrix3::identity() * 0.01);
        for k in 41..51 {
            round(&mut map, k);
        }
        (map, round, id)
    }

    /// The source's mirror image in the arrays' plane, at −0.2 m, explains
    /// their DoAs as well as the source does. A filter put there (as a
    /// floor-image read can push one) is taken back to the upper branch by
    /// the next DoAs (crate::floor_image, "The fold's two branches"), without
    /// a restart.
    #[test]
    fn a_filter_at_the_mirror_image_returns_to_the_upper_branch() {
        let (map, _, id) = put_at_the_mirror(true);
        let (after, p) = only_position(&map);
        assert!((p - SOURCE).norm() < 0.15, "back on the upper branch: {p}");
        assert_eq!((after, map.restarts), (id, 0));
    }

    /// With the upper branch left to the data (`doa.upper_branch = false`),
    /// a filter put at the mirror image stays there on the DoAs alone; its
    /// own rays' triangulation, taken from the rays' intersection above the
    /// arrays, disagrees, and after a second the source is restarted from it,
    /// keeping its id.
    #[test]
    fn a_filter_stuck_at_the_mirror_image_is_restarted_from_its_rays() {
        let (mut map, mut round, id) = put_at_the_mirror(false);
        let (_, p) = only_position(&map);
        assert!((p - MIRROR).norm() < 0.15, "the DoAs alone keep it at the mirror: {p}");
        assert_eq!(map.restarts, 0);
        for k in 51..80 {
            round(&mut map, k);
        }
        let (after, p) = only_position(&map);
        assert_eq!(map.restarts, 1);
        assert_eq!(after, id, "the restarted source keeps its id");
        assert!((p - SOURCE).norm() < 0.15, "restarted at {p}");
    }
}

#[cfg(test)]
mod map_tests {
    use nalgebra::Point3;
    use soundmap_proto::Stamp;

    use super::{AlignedRays, SoundMap, SourceSighting, TaggedRay};
    use crate::config::SourcesConfig;
    use crate::ray::Ray;
    use crate::tracking::TrackerConfig;
    use crate::triangulation::TriangulationConfig;

    const T0: i64 = 1_767_225_600_000_000_000;

    /// A robot index, its array's position and the sources it hears (point, track id).
    type Hearing = (u32, Point3<f64>, Vec<(Point3<f64>, u64)>);

    fn tagged(origin: Point3<f64>, source: Point3<f64>, track_id: u64) -> TaggedRay {
        TaggedRay {
            ray: Ray {
                origin_in_map: origin,
                direction_in_map: nalgebra::Unit::new_normalize(source - origin),
                sigma_rad: 1f64.to_radians(),
                origin_sigma_m: 0.0,
                fold: None,
            },
            activity: 0.9,
            track_id,
            signature: None,
            aperture_m: Some(0.3),
        }
    }

    /// One round 50 ms after the last, with each robot's rays; the sightings
    /// at its stamp.
    fn round(map: &mut SoundMap, k: i64, heard: &[Hearing]) -> Vec<SourceSighting> {
        let stamp = Stamp::from_ns(T0 + k * 50_000_000);
        let aligned: Vec<AlignedRays> = heard
            .iter()
            .map(|(robot, origin, sources)| AlignedRays {
                robot: *robot,
                stamp,
                rays: sources.iter().map(|(s, track)| tagged(*origin, *s, *track)).collect(),
            })
            .collect();
        for a in &aligned {
            map.push(a.stamp, a.robot, a.rays.clone());
        }
        let tri = TriangulationConfig::default();
        map.step(stamp.plus_ns(20_000_000), &aligned, &tri);
        map.sightings(&aligned, stamp, &tri)
    }

    fn map() -> SoundMap {
        SoundMap::new(SourcesConfig { max_sources: 4, ..SourcesConfig::default() }, TrackerConfig::default())
    }

    /// A source two robots located stays published, on its filter, while one
    /// of them alone hears it, for half a second; the estimate says it rests on
    /// one robot's ray (no triangulation).
    #[test]
    fn a_source_one_robot_still_hears_is_published_for_half_a_second() {
        let source = Point3::new(0.0, 0.0, 1.2);
        let origins = [Point3::new(-3.0, 0.0, 0.5), Point3::new(0.0, -3.0, 0.5)];
        let mut map = map();
        for k in 0..40 {
            let both: Vec<_> = (0..2).map(|r| (r, origins[r as usize], vec![(source, 1)])).collect();
            let seen = round(&mut map, k, &both);
            if k == 39 {
                assert_eq!(seen.len(), 1);
                assert_eq!(seen[0].robots, vec![0, 1]);
                assert!(seen[0].filtered.as_ref().is_some_and(|f| f.trusted), "trusted after 2 s");
            }
        }
        let one = vec![(0, origins[0], vec![(source, 1)])];
        let mut published = Vec::new();
        for k in 40..60 {
            let seen = round(&mut map, k, &one);
            if let Some(s) = seen.first() {
                assert_eq!(s.robots, vec![0]);
                assert!(s.triangulation.solution().is_none(), "one ray gives no point");
                let f = s.filtered.as_ref().expect("the filter");
                assert!((f.position_in_map - source).norm() < 0.1, "at {}", f.position_in_map);
                published.push(k);
            }
        }
        // Two robots last fed it at round 39 (1.95 s): published up to 2.45 s.
        assert_eq!(published, (40..=49).collect::<Vec<_>>());
    }

    /// Two pairs of robots that each hear one source a little apart (0.28 m,
    /// each pair's rays missing the other's point by more than 3σ) are two
    /// disjoint birth candidates that recur in the same rounds: one source is
    /// born, not two.
    #[test]
    fn two_pairs_at_one_source_give_one_birth() {
        let p = Point3::new(0.0, 0.0, 1.2);
        let q = Point3::new(0.2, 0.2, 1.2);
        let origins = [
            Point3::new(-3.0, 0.0, 0.5),
            Point3::new(0.0, -3.0, 0.5),
            Point3::new(3.0, 0.0, 0.5),
            Point3::new(0.0, 3.0, 0.5),
        ];
        let mut map = map();
        for k in 0..10 {
            let heard: Vec<Hearing> =
                (0..4).map(|r| (r, origins[r as usize], vec![(if r < 2 { p } else { q }, 1)])).collect();
            round(&mut map, k, &heard);
        }
        assert_eq!(map.births, 1);
        assert_eq!(map.sources.len(), 1);
    }

    /// Rays that meet 1.3 m straight above a live source (each robot's second
    /// track at its azimuth, steeper: the ceiling image) give no birth.
    #[test]
    fn no_source_is_born_above_a_live_one() {
        let p = Point3::new(0.0, 0.0, 1.2);
        let above = Point3::new(0.0, 0.0, 2.5);
        let origins = [Point3::new(-3.0, 0.0, 0.5), Point3::new(0.0, -3.0, 0.5)];
        let mut map = map();
        for k in 0..40 {
            round(&mut map, k, &[(0, origins[0], vec![(p, 1)]), (1, origins[1], vec![(p, 1)])]);
        }
        for k in 40..60 {
            round(
                &mut map,
                k,
                &[(0, origins[0], vec![(p, 1), (above, 2)]), (1, origins[1], vec![(p, 1), (above, 2)])],
            );
        }
        assert_eq!(map.births, 1);
    }

    /// While a robot's track feeds a source, another track of the same robot
    /// near the edge of that source's gate does not take it over in a round
    /// the first one is missing from: one robot hears one source as one track.
    #[test]
    fn a_robot_s_second_track_does_not_take_over_its_first_track_s_source() {
        let a = Point3::new(0.0, 0.0, 1.2);
        let origins = [Point3::new(-3.0, 0.0, 0.5), Point3::new(0.0, -3.0, 0.5)];
        // 3.5 degrees to the side of `a` from robot 0.
        let b = Point3::new(0.0, 3.0 * 3.5f64.to_radians().tan(), 1.2);
        let mut map = map();
        for k in 0..40 {
            round(&mut map, k, &[(0, origins[0], vec![(a, 1)]), (1, origins[1], vec![(a, 1)])]);
        }
        let id = map.sources[0].id;
        let stamp = Stamp::from_ns(T0 + 40 * 50_000_000);
        let nis = map.sources[0].tracker.nis(stamp, &tagged(origins[0], b, 2).ray).expect("a track");
        assert!(nis > map.gate * 0.5 && nis < map.gate, "NIS {nis} inside the gate, beyond its half");
        round(&mut map, 40, &[(0, origins[0], vec![(b, 2)]), (1, origins[1], vec![(a, 1)])]);
        assert!(map.labels.get(&(0, 2)).is_none_or(|l| l.source != id), "track 2 took source {id}");
        assert_eq!(map.labels.get(&(0, 1)).map(|l| l.source), Some(id));
    }

    /// A robot's ray that points at two mapped sources does not say which one
    /// is sounding: the one it fed is not published on it alone.
    #[test]
    fn a_ray_through_two_sources_publishes_neither_alone() {
        let a = Point3::new(0.0, 0.0, 1.2);
        // Behind `a` on robot 0's bearing, 2.3 degrees higher.
        let c = Point3::new(2.5, 0.0, 2.0);
        let origins = [Point3::new(-3.0, 0.0, 0.5), Point3::new(0.0, -3.0, 0.5), Point3::new(2.5, -3.0, 0.5)];
        let mut map = map();
        // `a` first (robot 0's ray is labelled with it), then `c` too.
        for k in 0..40 {
            round(&mut map, k, &[(0, origins[0], vec![(a, 1)]), (1, origins[1], vec![(a, 1)])]);
        }
        for k in 40..80 {
            let heard = vec![
                (0, origins[0], vec![(a, 1)]),
                (1, origins[1], vec![(a, 1), (c, 2)]),
                (2, origins[2], vec![(c, 1)]),
            ];
            let seen = round(&mut map, k, &heard);
            if k == 79 {
                assert_eq!(seen.len(), 2, "both sources located: {seen:?}");
            }
        }
        // Only robot 0 hears `a`; robots 1 and 2 still hear `c`.
        let heard =
            vec![(0, origins[0], vec![(a, 1)]), (1, origins[1], vec![(c, 2)]), (2, origins[2], vec![(c, 1)])];
        let seen = round(&mut map, 80, &heard);
        assert_eq!(seen.len(), 1, "{seen:?}");
        assert_eq!(seen[0].robots, vec![1, 2], "only `c`, heard by two robots");
    }
}
