//! What the coordinator tells an operator's Prometheus: the families behind
//! `GET /metrics` ([`super::metrics_http`]), in the OpenMetrics text format of
//! the `prometheus-client` library.
//!
//! Two kinds of series:
//!
//! - **Events**, counted where they happen (the coordinator task): observations
//!   accepted per robot and rejected per robot and reason, estimates published,
//!   the receipt → publication latency of each observation that led to an
//!   estimate, the coordinator task's time per batch of requests, planner
//!   decisions by outcome and reason, commands sent and robots' reports on them
//!   by state, source tracks born and restarted. Rates are Prometheus' `rate()` of these counters.
//! - **State**, read at scrape time from the same snapshot `GetState` returns:
//!   each robot's liveness (one series per robot with value 1 at its current
//!   state) and the age of its last message, sources by track state and
//!   trust, the sound map's live and remembered sources, the planner's latest
//!   outcome, open robot streams and estimate watchers, and the resource-bound
//!   counters of `[server]`.
//!
//! Latency buckets: 50 µs × 2ᵏ, k = 0…18 (50 µs … 13 s); a publication on a
//! 2-robot fleet typically takes 0.1–1 ms, so the p50/p99 fall in the fine
//! end. Label values are bounded: robot ids (at most `server.max_robots`),
//! fixed reason and state names.

use std::sync::atomic::AtomicU64;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::encoding::text::{encode_eof, encode_registry};
use prometheus_client::metrics::counter::{ConstCounter, Counter};
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;
use soundmap_proto::wire;

use crate::error::ServerError;

/// A robot (empty when a message came before any hello).
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct RobotLabel {
    /// Robot id.
    pub robot: String,
}

/// A rejected observation: which robot, and why.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct RejectLabel {
    /// Robot id, or empty before a hello.
    pub robot: String,
    /// A fixed name of the reason ([`reject_reason`]).
    pub reason: &'static str,
}

/// A planner decision.
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct PlannerLabel {
    /// `planned`, `hold` or `infeasible`.
    pub outcome: &'static str,
    /// The decision's reason key, e.g. `geometry_good`, `no_source`.
    pub reason: &'static str,
}

/// A state name (commands, liveness, tracks).
#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
pub struct StateLabel {
    /// The state.
    pub state: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct RobotStateLabel {
    robot: String,
    state: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct SourceLabel {
    state: &'static str,
    trusted: &'static str,
}

/// The event series, registered once (see the module docs).
#[derive(Debug)]
pub struct Telemetry {
    registry: Registry,
    /// Observations accepted, by robot.
    pub observations_accepted: Family<RobotLabel, Counter>,
    /// Observations rejected, by robot and reason.
    pub observations_rejected: Family<RejectLabel, Counter>,
    /// Estimates published (one per source and batch).
    pub estimates_published: Counter,
    /// Receipt → publication latency of observations that led to an estimate (s).
    pub estimate_latency: Histogram,
    /// The coordinator task's time per batch of requests (s): validation
    /// aside, everything the coordinator does, planning included.
    pub batch_seconds: Histogram,
    /// Planner decisions by outcome and reason.
    pub planner_decisions: Family<PlannerLabel, Counter>,
    /// Reposition commands and cancellations sent (`state` = `sent`, `cancel_sent`),
    /// and robots' reports on them (`accepted`, `refused`, `executing`,
    /// `succeeded`, `failed`, `canceled`).
    pub commands: Family<StateLabel, Counter>,
    /// Source tracks started: `born` (a new source, or a new track of the
    /// single source) and `restarted` (a live one started again: from its own
    /// rays when its filter diverged, or from a good geometry after a poor
    /// start).
    pub source_tracks: Family<StateLabel, Counter>,
}

impl Default for Telemetry {
    fn default() -> Self {
        let mut registry = Registry::with_prefix("soundmap");
        let observations_accepted = Family::<RobotLabel, Counter>::default();
        registry.register(
            "observations_accepted",
            "Observations accepted, by robot",
            observations_accepted.clone(),
        );
        let observations_rejected = Family::<RejectLabel, Counter>::default();
        registry.register(
            "observations_rejected",
            "Observations rejected, by robot (empty before a hello) and reason",
            observations_rejected.clone(),
        );
        let estimates_published = Counter::default();
        registry.register("estimates_published", "Source estimates published", estimates_published.clone());
        let estimate_latency = Histogram::new(exponential_buckets(50e-6, 2.0, 19));
        registry.register(
            "estimate_latency_seconds",
            "Receipt to publication latency of observations that led to an estimate",
            estimate_latency.clone(),
        );
        let batch_seconds = Histogram::new(exponential_buckets(10e-6, 2.0, 20));
        registry.register(
            "coordinator_batch_seconds",
            "Coordinator task time per batch of requests (triangulation, tracking, planning)",
            batch_seconds.clone(),
        );
        let planner_decisions = Family::<PlannerLabel, Counter>::default();
        registry.register(
            "planner_decisions",
            "Planner decisions by outcome and reason",
            planner_decisions.clone(),
        );
        let commands = Family::<StateLabel, Counter>::default();
        registry.register(
            "commands",
            "Reposition commands sent and cancelled, and robots' reports on them, by state",
            commands.clone(),
        );
        let source_tracks = Family::<StateLabel, Counter>::default();
        registry.register(
            "source_tracks",
            "Source tracks started, by state: born (a new source or track), restarted (a live one started again)",
            source_tracks.clone(),
        );
        for state in ["born", "restarted"] {
            let _series = source_tracks.get_or_create(&StateLabel { state });
        }
        Telemetry {
            registry,
            observations_accepted,
            observations_rejected,
            estimates_published,
            estimate_latency,
            batch_seconds,
            planner_decisions,
            commands,
            source_tracks,
        }
    }
}

/// A fixed, low-cardinality name for why an observation was rejected.
pub fn reject_reason(e: &ServerError) -> &'static str {
    match e {
        ServerError::Invalid(_) => "invalid",
        ServerError::NoHello(_) => "no_hello",
        ServerError::SecondHello(_) => "second_hello",
        ServerError::UnknownCommand { .. } => "unknown_command",
        ServerError::AlreadyConnected(_) => "already_connected",
        ServerError::Unauthenticated(_) => "unauthenticated",
        ServerError::PermissionDenied(_) | ServerError::IdentityMismatch { .. } => "permission_denied",
        ServerError::ShuttingDown => "shutting_down",
        _ => "other",
    }
}

/// What the scrape reads besides the event series.
#[derive(Debug, Default)]
pub struct ScrapeState<'a> {
    /// The coordinator's snapshot (absent when it did not answer in time).
    pub state: Option<&'a wire::CoordinatorState>,
    /// Robot streams open.
    pub robot_streams: usize,
    /// `WatchEstimates` calls open.
    pub watchers: usize,
    /// Resource-bound counters by name (`[server]`), monotonic.
    pub limits: Vec<(&'static str, u64)>,
}

impl Telemetry {
    /// The OpenMetrics text of every series, ending with `# EOF`.
    pub fn render(&self, scrape: &ScrapeState<'_>) -> Result<String, std::fmt::Error> {
        let mut text = String::with_capacity(8 * 1024);
        encode_registry(&mut text, &self.registry)?;
        encode_registry(&mut text, &state_registry(scrape))?;
        encode_eof(&mut text)?;
        Ok(text)
    }
}

/// The scrape-time series, in a registry built for this scrape.
fn state_registry(scrape: &ScrapeState<'_>) -> Registry {
    let mut registry = Registry::with_prefix("soundmap");
    let gauge = |v: i64| {
        let g = Gauge::<i64>::default();
        g.set(v);
        g
    };
    registry.register("robot_streams", "Robot streams open", gauge(scrape.robot_streams as i64));
    registry.register("estimate_watchers", "WatchEstimates calls open", gauge(scrape.watchers as i64));
    for (name, value) in &scrape.limits {
        registry.register(
            format!("limits_{name}"),
            format!("Resource bound counter {name} ([server])"),
            ConstCounter::new(*value),
        );
    }
    registry.register(
        "up",
        "1 when the coordinator task answered this scrape",
        gauge(i64::from(scrape.state.is_some())),
    );
    if let Some(state) = scrape.state {
        register_state(&mut registry, state);
    }
    registry
}

fn register_state(registry: &mut Registry, state: &wire::CoordinatorState) {
    let liveness = Family::<RobotStateLabel, Gauge>::default();
    let age = Family::<RobotLabel, Gauge<f64, AtomicU64>>::default();
    for r in &state.robots {
        let name = match wire::Liveness::try_from(r.liveness) {
            Ok(wire::Liveness::Live) => "live",
            Ok(wire::Liveness::Stale) => "stale",
            Ok(wire::Liveness::Disconnected) => "disconnected",
            _ => "unspecified",
        };
        liveness.get_or_create(&RobotStateLabel { robot: r.robot_id.clone(), state: name }).set(1);
        let seconds = (state.now_ns - r.last_seen_ns).max(0) as f64 * 1e-9;
        age.get_or_create(&RobotLabel { robot: r.robot_id.clone() }).set(seconds);
    }
    registry.register(
        "robot_liveness",
        "1 for each robot at its liveness (live, stale, disconnected)",
        liveness,
    );
    registry.register("robot_last_seen_age_seconds", "Time since each robot was last heard from", age);
    let sources = Family::<SourceLabel, Gauge>::default();
    for s in &state.sources {
        let track = s.filtered.as_ref().and_then(|f| wire::TrackState::try_from(f.state).ok());
        let name = match track {
            Some(wire::TrackState::Tentative) => "tentative",
            Some(wire::TrackState::Confirmed) => "confirmed",
            Some(wire::TrackState::Lost) => "lost",
            _ => "untracked",
        };
        let trusted = if s.trusted { "true" } else { "false" };
        sources.get_or_create(&SourceLabel { state: name, trusted }).inc();
    }
    registry.register("sources", "Source estimates by track state and trust", sources);
    let map = Family::<StateLabel, Gauge>::default();
    for m in &state.sound_map {
        map.get_or_create(&StateLabel { state: if m.live { "live" } else { "remembered" } }).inc();
    }
    registry.register("sound_map_sources", "Sound map sources, live and remembered", map);
    if let Some(p) = &state.planner {
        let outcome = Family::<StateLabel, Gauge>::default();
        let name = match wire::PlannerOutcome::try_from(p.outcome) {
            Ok(wire::PlannerOutcome::Planned) => "planned",
            Ok(wire::PlannerOutcome::Hold) => "hold",
            Ok(wire::PlannerOutcome::Infeasible) => "infeasible",
            _ => "unspecified",
        };
        outcome.get_or_create(&StateLabel { state: name }).set(1);
        registry.register("planner_last_outcome", "1 at the planner's latest outcome", outcome);
    }
}
