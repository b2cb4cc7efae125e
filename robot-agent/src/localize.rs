//! `soundmap-agent localize`: the on-board pipeline on a recording, one JSON
//! line per hop.
//!
//! `{"stamp_ns":…, "sources":[{"id","x","y","z","activity"}]}` with (x, y, z)
//! the unit vector toward the source in the array frame (x forward, y left,
//! z up); optionally the hop's SRP peaks as
//! `"potentials":[{"x","y","z","energy"}]`, each with `"range_m"` when the
//! near-field refinement (`[srp] near_field`) found the peak at a finite range.
//! With the floor-reflection fit (`[srp] floor_fit`), a reported track whose
//! elevation was fitted also carries `"floor_fit_range_m"`, the range it was
//! fitted at (what `TrackedDoa.floor_fit_range_m` sends the coordinator).

use std::io::Write;

use serde::Serialize;

use crate::AgentError;
use crate::audio::AudioSource;
use crate::pipeline::{FrameResult, Pipeline};

#[derive(Serialize)]
struct SourceLine {
    id: u64,
    x: f64,
    y: f64,
    z: f64,
    activity: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    floor_fit_range_m: Option<f64>,
}

#[derive(Serialize)]
struct PotentialLine {
    x: f64,
    y: f64,
    z: f64,
    energy: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    range_m: Option<f64>,
}

#[derive(Serialize)]
struct HopLine {
    stamp_ns: i64,
    sources: Vec<SourceLine>,
    #[serde(skip_serializing_if = "Option::is_none")]
    potentials: Option<Vec<PotentialLine>>,
}

/// What each line holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineOptions {
    /// Also write the hop's SRP peaks.
    pub potentials: bool,
    /// Also write tentative (unconfirmed) tracks.
    pub all_tracks: bool,
}

/// Runs `pipeline` over every block of `source`, writing one line per hop to `out`.
pub fn localize(
    source: &mut dyn AudioSource,
    pipeline: &mut Pipeline,
    options: LineOptions,
    out: &mut dyn Write,
) -> Result<(), AgentError> {
    let io = |source| AgentError::Io { path: "localize output".into(), source };
    let mut block = vec![0.0f32; source.hop_len() * source.channels()];
    while let Some(stamp) = source.next_block(&mut block)? {
        let line = hop_line(pipeline.process_hop(stamp, &block), options);
        serde_json::to_writer(&mut *out, &line).map_err(|e| io(e.into()))?;
        out.write_all(b"\n").map_err(io)?;
    }
    out.flush().map_err(io)
}

fn hop_line(r: &FrameResult, options: LineOptions) -> HopLine {
    HopLine {
        stamp_ns: r.stamp.as_ns(),
        sources: r
            .tracks
            .iter()
            .enumerate()
            .filter(|(_, t)| options.all_tracks || t.confirmed)
            .map(|(i, t)| SourceLine {
                id: t.track_id,
                x: t.direction_in_array.x,
                y: t.direction_in_array.y,
                z: t.direction_in_array.z,
                activity: t.activity,
                floor_fit_range_m: r
                    .reported
                    .iter()
                    .position(|&k| k == i)
                    .and_then(|n| r.floor_fit_ranges_m.get(n).copied())
                    .filter(|&m| m > 0.0),
            })
            .collect(),
        potentials: options.potentials.then(|| {
            r.potentials
                .iter()
                .map(|p| PotentialLine {
                    x: p.direction_in_array.x,
                    y: p.direction_in_array.y,
                    z: p.direction_in_array.z,
                    energy: p.energy,
                    range_m: (p.inverse_range_per_m > 0.0).then(|| 1.0 / p.inverse_range_per_m),
                })
                .collect()
        }),
    }
}
