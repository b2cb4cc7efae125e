//! The agent's DSP chain, one hop at a time: STFT → SRP-PHAT → DoA tracker →
//! spectral signatures of the reported tracks.
//!
//! This is what the CLI, the simulator and the live agent call. Everything is
//! planned and allocated in [`Pipeline::new`]; [`Pipeline::process_hop`]
//! allocates nothing. The pipeline is `Send` (it runs on the agent's DSP
//! thread).
//!
//! Time: the caller stamps each hop with its first sample (Unix ns, derived
//! from the sample count). A frame's DoAs are stamped at the middle of the
//! analysed frame: first sample of the frame + `frame_len/(2·fs)`.

use nalgebra::{Point3, UnitQuaternion};
use soundmap_proto::Stamp;

use crate::array::ArrayGeometry;
use crate::doa_tracker::DoaTracker;
use crate::error::AgentError;
use crate::pose::PoseBuffer;
use crate::signature::{SignatureLayout, Signatures};
use crate::srp::Srp;
use crate::stft::{Stft, Window};

pub use crate::doa_tracker::{TrackedDirection, TrackerConfig};
pub use crate::signature::SignatureConfig;
pub use crate::srp::{PotentialSource, SrpConfig};

/// Pipeline settings (TOML section of the agent config). Defaults follow
/// ODAS: 16 kHz, frames of 256 samples, hops of 128.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PipelineConfig {
    /// Sample rate of the audio, Hz.
    pub sample_rate_hz: u32,
    /// Analysis frame length, samples (even).
    pub frame_len: usize,
    /// Hop between frames, samples (≤ `frame_len`).
    pub hop_len: usize,
    /// Analysis window.
    pub window: Window,
    /// Localization.
    pub srp: SrpConfig,
    /// Tracking.
    pub tracker: TrackerConfig,
    /// Floor added (in quadrature) to each track's σ when it is reported to
    /// the coordinator, degrees per tangent axis. The tracker's σ measures the
    /// scatter it sees, which is honest in free field, but reflections bias a
    /// DoA consistently for a given geometry, invisibly to the tracker: in a
    /// simulated 0.6 s RT60 room at 2–3 m the errors were 4× the tracker's σ.
    /// Default 1.0 (theory §5.1 expects 2–4° per axis for talkers in rooms;
    /// a white-noise source is easier). With
    /// `doa_sigma_floor_full_aperture_m` set, an array smaller than it gets
    /// the floor scaled up by that aperture over its own.
    pub doa_sigma_floor_deg: f64,
    /// Aperture (largest microphone distance, m) from which the σ floor is
    /// `doa_sigma_floor_deg` itself; a smaller array's floor is scaled by
    /// this / its aperture. Reflections pull a peak by a share of its main
    /// lobe, whose width goes as wavelength over aperture: in the
    /// image-source rooms of `tests/tests/hearing_reverb.rs` (RT60 0.5 s) the
    /// 9 cm ReSpeaker 6 erred 11.7° at the case median against 2.8° for the
    /// 49 cm 16SoundsUSB, 4.2× for 5.3× less aperture. At 0.4 both
    /// 16SoundsUSB layouts keep the floor as it is and a ReSpeaker 6 gets
    /// 4.3°, a ReSpeaker 4 6.3°, a UMA-8 4.7°. Default 0.4 (0 turns it
    /// off): with the tracker's masking, `cocktail`'s OSPA fell from 0.318 to
    /// 0.283 m and `cocktail-active`'s from 0.351 to 0.314 m (seeds 1–10),
    /// with `three-robots` in band 100 % of the time on every seed
    /// (BENCHMARKS.md, "Masked silences and honest small arrays").
    pub doa_sigma_floor_full_aperture_m: f64,
    /// Most tracks reported per observation (K, 1..=64; default 4): the
    /// confirmed tracks, most active first. Declared in the hello as
    /// `max_tracks`. (The tracker may hold more, `tracker.max_tracks`.)
    pub max_reported_tracks: usize,
    /// Spectral signatures of the reported tracks (`[pipeline.signature]`).
    pub signature: SignatureConfig,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            sample_rate_hz: 16_000,
            frame_len: 256,
            hop_len: 128,
            window: Window::Hann,
            srp: SrpConfig::default(),
            tracker: TrackerConfig::default(),
            doa_sigma_floor_deg: 1.0,
            doa_sigma_floor_full_aperture_m: 0.4,
            max_reported_tracks: 4,
            signature: SignatureConfig::default(),
        }
    }
}

impl PipelineConfig {
    /// What the signatures need of this pipeline (frames, window, speed of sound).
    pub fn signature_layout(&self) -> SignatureLayout {
        SignatureLayout {
            sample_rate_hz: self.sample_rate_hz,
            frame_len: self.frame_len,
            hop_len: self.hop_len,
            max_tracks: self.max_reported_tracks,
            window_energy: self.window.coefficients(self.frame_len).iter().map(|&w| (w as f64).powi(2)).sum(),
            speed_of_sound_m_per_s: self.srp.speed_of_sound_m_per_s,
        }
    }

    /// `hello` declaring what this pipeline sends: at most
    /// [`PipelineConfig::max_reported_tracks`] tracks per observation,
    /// signatures in the bands of [`SignatureConfig::band_edges_hz`] (none when
    /// signatures are off), and the SRP's band (`ArrayInfo::srp_band_hz`, which
    /// lets the coordinator model the floor image for a planar array), and
    /// with `srp.floor_fit` that the elevations are the direct path's
    /// (`ArrayInfo::direct_path_elevations`). Errors name a bad signature setting.
    pub fn declare_tracks(
        &self,
        mut hello: soundmap_proto::Hello,
    ) -> Result<soundmap_proto::Hello, AgentError> {
        let edges = self.signature.band_edges_hz(self.sample_rate_hz)?;
        hello.max_tracks = Some(self.max_reported_tracks as u32);
        hello.signature_bands = (!edges.is_empty()).then_some(edges);
        hello.array.srp_band_hz = Some(self.srp_band_hz());
        hello.array.direct_path_elevations = self.srp.floor_fit;
        Ok(hello)
    }

    /// The SRP's band as the hello declares it (`ArrayInfo::srp_band_hz`), Hz:
    /// `[srp.min_frequency_hz, srp.max_frequency_hz]`, the top capped at Nyquist.
    pub fn srp_band_hz(&self) -> [f64; 2] {
        let nyquist = 0.5 * self.sample_rate_hz as f64;
        [self.srp.min_frequency_hz, self.srp.max_frequency_hz.min(nyquist)]
    }
}

/// What one hop produced.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameResult {
    /// Stamp of the DoAs: first sample of the analysed frame + `frame_len/(2·fs)`.
    pub stamp: Stamp,
    /// This frame's SRP peaks, strongest first (empty until the first full frame).
    pub potentials: Vec<PotentialSource>,
    /// Current tracks (tentative ones have `confirmed = false`).
    pub tracks: Vec<TrackedDirection>,
    /// The tracks that are reported, as indices into `tracks`: the confirmed
    /// ones, most active first (ties: lower id first), at most
    /// [`PipelineConfig::max_reported_tracks`].
    pub reported: Vec<usize>,
    /// Number of signature bands B (0 when signatures are off).
    pub signature_bands: usize,
    /// Signatures of the reported tracks, dB (see [`crate::signature`]): B
    /// values per entry of `reported`, in that order.
    pub signatures_db: Vec<f32>,
    /// With the floor fit: per entry of `reported`, the range (m) its
    /// elevation was fitted at, 0 where it has no fit yet (see
    /// [`soundmap_proto::TrackedDoa::floor_fit_range_m`]); empty without it.
    pub floor_fit_ranges_m: Vec<f64>,
}

impl FrameResult {
    /// The reported tracks (confirmed, most active first, at most K) as DoAs,
    /// with the tracker's own σ and their signatures. The agent core floors σ
    /// ([`PipelineConfig::doa_sigma_floor_deg`], see [`crate::agent`]) before
    /// anything is sent.
    pub fn confirmed_doas(&self) -> Vec<soundmap_proto::TrackedDoa> {
        let b = self.signature_bands;
        self.reported
            .iter()
            .enumerate()
            .map(|(i, &t)| {
                let mut d = self.tracks[t].to_doa(0.0);
                d.signature =
                    self.signatures_db.get(i * b..(i + 1) * b).filter(|_| b > 0).map(<[f32]>::to_vec);
                d.floor_fit_range_m = self.floor_fit_ranges_m.get(i).copied().filter(|&r| r > 0.0);
                d
            })
            .collect()
    }

    /// Signature of the reported track with id `track_id`, dB per band.
    pub fn signature_of(&self, track_id: u64) -> Option<&[f32]> {
        let b = self.signature_bands;
        let i = self.reported.iter().position(|&t| self.tracks[t].track_id == track_id)?;
        self.signatures_db.get(i * b..(i + 1) * b).filter(|_| b > 0)
    }
}

/// The factor on the σ floor for an array of `aperture_m` when the floor is
/// full from `full_m` on: `max(1, full_m / aperture_m)` (1 when either is 0).
pub fn aperture_scale(aperture_m: f64, full_m: f64) -> f64 {
    if aperture_m > 0.0 && full_m > 0.0 { (full_m / aperture_m).max(1.0) } else { 1.0 }
}

/// A track's elevation above the floor moving less than this since its
/// last floor fit (degrees) counts as steady (see
/// [`Pipeline::correct_floor_pull`]).
const STEADY_DEG: f64 = 1.0;
/// Fits of a track at the full rate before it may count as steady.
const SETTLING_FITS: u32 = 4;

/// A track's floor-reflection correction (see [`Pipeline::correct_floor_pull`]).
#[derive(Clone, Copy, Debug)]
struct FloorOffset {
    track_id: u64,
    /// Elevation offset applied to what is reported (rad), and the inverse
    /// of the range it was fitted at (1/m), both smoothed alike: along the
    /// fit's ridge of one image path, sin e + h/ρ stays nearly constant, so
    /// the smoothed pair stays on it.
    offset_rad: f64,
    inverse_range: f64,
    /// The track's elevation above the floor at its last kept fit (rad),
    /// and the hops since that fit.
    fitted_elevation: f64,
    hops_since_fit: usize,
    /// Kept fits of this track.
    fits: u32,
}

/// STFT → SRP-PHAT → tracker for one array.
#[derive(Debug)]
pub struct Pipeline {
    channels: usize,
    sample_rate_hz: u32,
    stft: Stft,
    srp: Srp,
    tracker: DoaTracker,
    signatures: Signatures,
    result: FrameResult,
    /// Offset from a hop's first sample to its frame's DoA stamp, ns.
    stamp_offset_ns: i64,
    /// σ floor of reported DoAs (rad).
    doa_sigma_floor_rad: f64,
    /// Longest silence of a reported track, s (see [`TrackerConfig::report_max_silence_s`]).
    report_max_silence_s: f64,
    /// The array's orientation on the base.
    base_from_array: UnitQuaternion<f64>,
    /// The array's orientation in the map that the tracks are expressed in
    /// (`None` until a pose is given: the tracks then stay in the array frame).
    tracks_frame: Option<UnitQuaternion<f64>>,
    /// See [`TrackerConfig::rotation_deadband_deg`] (rad).
    rotation_deadband_rad: f64,
    /// The base's position in the map at the current hop (from SLAM), if given.
    base_position: Option<Point3<f64>>,
    /// With the floor-reflection fit: each reported track's elevation
    /// offset (smoothed); the hops so far, and hops between fits (of any
    /// track, and of a steady one: 0 = as any).
    floor_offsets: Vec<FloorOffset>,
    floor_hops: usize,
    floor_every: usize,
    floor_steady_every: usize,
}

impl Pipeline {
    /// Plans the pipeline for `array`; errors name the bad setting.
    pub fn new(array: &ArrayGeometry, config: &PipelineConfig) -> Result<Self, AgentError> {
        let fs = config.sample_rate_hz;
        if !(1000..=384_000).contains(&fs) {
            return Err(AgentError::InvalidParameter {
                field: "sample_rate_hz".into(),
                message: format!("must be in 1000..=384000, got {fs}"),
            });
        }
        let floor = config.doa_sigma_floor_deg;
        if !(floor.is_finite() && (0.0..=30.0).contains(&floor)) {
            return Err(AgentError::InvalidParameter {
                field: "doa_sigma_floor_deg".into(),
                message: format!("must be in [0, 30] degrees, got {floor}"),
            });
        }
        let full = config.doa_sigma_floor_full_aperture_m;
        if !(full.is_finite() && (0.0..=10.0).contains(&full)) {
            return Err(AgentError::InvalidParameter {
                field: "doa_sigma_floor_full_aperture_m".into(),
                message: format!("must be in [0, 10] m, got {full}"),
            });
        }
        let stft = Stft::new(array.channels(), config.frame_len, config.hop_len, config.window)?;
        let mut srp = Srp::new(array, fs, config.frame_len, &config.srp)?;
        srp.set_analysis_window(&config.window.coefficients(config.frame_len));
        let hop_s = config.hop_len as f64 / fs as f64;
        let mut tracker = DoaTracker::new(&config.tracker, hop_s, config.srp.max_sources, srp.noise_model())?;
        tracker.set_microphones(&array.positions().map(|p| p.coords).collect::<Vec<_>>());
        tracker.set_search_region(srp.region());
        let signatures = Signatures::new(array, &config.signature, &config.signature_layout())?;
        let (k, bands) = (signatures.max_tracks(), signatures.bands());
        let offset_samples = config.hop_len as f64 - config.frame_len as f64 / 2.0;
        Ok(Pipeline {
            channels: array.channels(),
            sample_rate_hz: fs,
            stft,
            srp,
            tracker,
            signatures,
            result: FrameResult {
                stamp: Stamp::ZERO,
                potentials: Vec::with_capacity(config.srp.max_sources),
                tracks: Vec::with_capacity(config.tracker.max_tracks),
                reported: Vec::with_capacity(config.tracker.max_tracks.max(k)),
                signature_bands: bands,
                signatures_db: Vec::with_capacity(k * bands),
                floor_fit_ranges_m: Vec::with_capacity(config.tracker.max_tracks.max(k)),
            },
            stamp_offset_ns: (offset_samples * 1e9 / fs as f64).round() as i64,
            doa_sigma_floor_rad: floor.to_radians()
                * aperture_scale(array.aperture_m(), config.doa_sigma_floor_full_aperture_m),
            report_max_silence_s: config.tracker.report_max_silence_s,
            base_from_array: array.base_from_array.rotation,
            tracks_frame: None,
            rotation_deadband_rad: config.tracker.rotation_deadband_deg.to_radians(),
            base_position: None,
            floor_offsets: Vec::with_capacity(config.tracker.max_tracks),
            floor_hops: 0,
            floor_every: config.srp.floor_fit_every_hops,
            floor_steady_every: config.srp.floor_fit_steady_every_hops,
        })
    }

    /// The base's orientation in the map (from SLAM) at the next hop. DoA
    /// tracks live in the array frame, which turns with the robot: a robot
    /// turning at 90°/s moves every bearing by 0.7° a hop, and a turn's start
    /// and end are accelerations no constant-velocity track follows. Given
    /// the orientation, the tracker re-expresses its tracks whenever the array
    /// has turned by more than [`TrackerConfig::rotation_deadband_deg`] since
    /// the last time, so a source that stays put in the room stays put for
    /// the tracker. Drivers call it through [`Pipeline::follow_poses`].
    /// Without it the tracks stay in the array frame.
    pub fn set_base_orientation(&mut self, map_from_base: &UnitQuaternion<f64>) {
        let map_from_array = map_from_base * self.base_from_array;
        let Some(old) = self.tracks_frame else {
            self.tracks_frame = Some(map_from_array);
            return;
        };
        if old.angle_to(&map_from_array) > self.rotation_deadband_rad {
            let new_from_old = (map_from_array.inverse() * old).to_rotation_matrix();
            self.tracker.change_frame(&new_from_old);
            self.tracks_frame = Some(map_from_array);
        }
    }

    /// [`Pipeline::set_base_orientation`] from the SLAM poses the agent holds,
    /// for the hop whose first sample is at `first_sample`: the pose
    /// interpolated there, else the newest; nothing without poses. Live, replay
    /// and simulation all call this, so they follow turns by one rule.
    pub fn follow_poses(&mut self, poses: &PoseBuffer, first_sample: Stamp) {
        if let Some(p) = poses.lookup(first_sample).ok().or_else(|| poses.last().cloned()) {
            self.set_base_orientation(&p.map_from_base.rotation);
            self.base_position = Some(Point3::from(p.map_from_base.translation.vector));
        }
    }

    /// The σ floor of reported DoAs (rad), see [`PipelineConfig::doa_sigma_floor_deg`].
    pub fn doa_sigma_floor_rad(&self) -> f64 {
        self.doa_sigma_floor_rad
    }

    /// Number of channels expected (= microphones).
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Samples per channel in a hop.
    pub fn hop_len(&self) -> usize {
        self.stft.hop_len()
    }

    /// Analysis frame length, samples.
    pub fn frame_len(&self) -> usize {
        self.stft.frame_len()
    }

    /// Sample rate, Hz.
    pub fn sample_rate_hz(&self) -> u32 {
        self.sample_rate_hz
    }

    /// The localizer (grid sizes, band, diffuse floor).
    pub fn srp(&self) -> &Srp {
        &self.srp
    }

    /// The localizer, mutably (to read its work counters).
    pub fn srp_mut(&mut self) -> &mut Srp {
        &mut self.srp
    }

    /// The tracker (birth threshold).
    pub fn tracker(&self) -> &DoaTracker {
        &self.tracker
    }

    /// The signatures (band edges, number of reported tracks).
    pub fn signatures(&self) -> &Signatures {
        &self.signatures
    }

    /// Processes one hop. `interleaved` holds exactly `hop_len` samples per
    /// channel, interleaved (`s[t*channels + c]`), f32 full scale ±1 (non-finite
    /// samples count as 0). `first_sample` is the Stamp of the hop's first
    /// sample. Returns the result for the analysis frame that ends with this
    /// hop (potentials and tracks empty until the first full frame).
    ///
    /// # Panics
    /// If `interleaved.len() != hop_len * channels` (see [`Pipeline::try_process_hop`]).
    pub fn process_hop(&mut self, first_sample: Stamp, interleaved: &[f32]) -> &FrameResult {
        assert_eq!(
            interleaved.len(),
            self.hop_len() * self.channels,
            "process_hop needs hop_len × channels interleaved samples"
        );
        self.result.stamp = first_sample.plus_ns(self.stamp_offset_ns);
        let r = &mut self.result;
        if self.stft.push_hop(interleaved) {
            self.srp.process(self.stft.spectra(), &mut r.potentials);
            let level_db = self.srp.band_level_db(self.stft.spectra());
            self.tracker.update_at(&r.potentials, level_db, self.base_position, &mut r.tracks);
            r.reported.clear();
            let audible = self.report_max_silence_s;
            r.reported.extend((0..r.tracks.len()).filter(|&i| {
                let t = &r.tracks[i];
                t.confirmed && (t.silent_s <= audible || t.held_by_masking)
            }));
            let tracks = &r.tracks;
            r.reported.sort_unstable_by(|&a, &b| {
                let (a, b) = (&tracks[a], &tracks[b]);
                b.activity.total_cmp(&a.activity).then(a.track_id.cmp(&b.track_id))
            });
            r.reported.truncate(self.signatures.max_tracks());
            self.signatures.update(self.stft.spectra(), &r.tracks, &r.reported, &mut r.signatures_db);
            if self.srp.floor_fit_on() {
                self.correct_floor_pull();
            }
        } else {
            r.potentials.clear();
            r.tracks.clear();
            r.reported.clear();
            r.signatures_db.clear();
            r.floor_fit_ranges_m.clear();
        }
        &self.result
    }

    /// With `srp.floor_fit`: every `floor_fit_every_hops` hops, each reported
    /// track's direction is fitted with the floor's reflection on the recent
    /// frames' averaged cross-spectra ([`Srp::fit_floor`]), and the
    /// elevation offset found (smoothed, half of each new fit) moves the
    /// reported direction every hop. The tracker keeps tracking the
    /// plane-wave peaks; only what is reported is corrected.
    ///
    /// A *steady* track, one whose elevation above the floor has moved less
    /// than [`STEADY_DEG`] since its last kept fit, is fitted only every
    /// `floor_fit_steady_every_hops` hops: its offset depends on the
    /// source's elevation and range as the array sees them, which have not
    /// changed, and the averaged cross-spectra it would be fitted on are
    /// mostly the same frames again (they remember ~16, the fits come every
    /// 8). The floor's image lies at the source's own azimuth, so the
    /// offset does not depend on it: a robot turning on the spot moves the
    /// track's azimuth in the array frame and leaves it steady (and the
    /// averaged cross-spectra, kept in the array frame, are smeared by the
    /// turn anyway). A source rising or falling as the array sees it (the
    /// robot driving towards it, a source moving closer) makes it unsteady,
    /// and it is fitted at the full rate again.
    fn correct_floor_pull(&mut self) {
        let r = &mut self.result;
        self.floor_hops += 1;
        if self.floor_hops.is_multiple_of(self.floor_every) {
            let steady_rad = STEADY_DEG.to_radians();
            for &i in &r.reported {
                let (id, d) = (r.tracks[i].track_id, r.tracks[i].direction_in_array);
                let elevation = self.srp.floor_elevation(&d).unwrap_or(0.0);
                let entry = self.floor_offsets.iter().position(|f| f.track_id == id);
                if let Some(f) = entry.map(|k| &mut self.floor_offsets[k]) {
                    f.hops_since_fit += self.floor_every;
                    let steady =
                        f.fits >= SETTLING_FITS && (f.fitted_elevation - elevation).abs() < steady_rad;
                    if self.floor_steady_every > 0 && steady && f.hops_since_fit < self.floor_steady_every {
                        continue;
                    }
                }
                let Some(fit) = self.srp.fit_floor(&d) else { continue };
                let room = self.floor_offsets.len() < self.floor_offsets.capacity();
                match entry.map(|k| &mut self.floor_offsets[k]) {
                    Some(f) => {
                        f.offset_rad = 0.5 * (f.offset_rad + fit.offset_rad);
                        f.inverse_range = 0.5 * (f.inverse_range + 1.0 / fit.range_m);
                        f.fits = f.fits.saturating_add(1);
                        f.fitted_elevation = elevation;
                        f.hops_since_fit = 0;
                    }
                    None if room => self.floor_offsets.push(FloorOffset {
                        track_id: id,
                        offset_rad: fit.offset_rad,
                        inverse_range: 1.0 / fit.range_m,
                        fitted_elevation: elevation,
                        hops_since_fit: 0,
                        fits: 1,
                    }),
                    None => {}
                }
            }
            let tracks = &r.tracks;
            self.floor_offsets.retain(|f| tracks.iter().any(|t| t.track_id == f.track_id));
        }
        r.floor_fit_ranges_m.clear();
        for &i in &r.reported {
            let t = &mut r.tracks[i];
            let mut range = 0.0;
            if let Some(f) = self.floor_offsets.iter().find(|f| f.track_id == t.track_id)
                && let Some(d) = self.srp.shift_elevation(&t.direction_in_array, f.offset_rad)
            {
                t.direction_in_array = d;
                range = 1.0 / f.inverse_range;
            }
            r.floor_fit_ranges_m.push(range);
        }
    }

    /// [`Pipeline::process_hop`] returning an error instead of panicking on a
    /// block of the wrong size.
    pub fn try_process_hop(
        &mut self,
        first_sample: Stamp,
        interleaved: &[f32],
    ) -> Result<&FrameResult, AgentError> {
        let want = self.hop_len() * self.channels;
        if interleaved.len() != want {
            return Err(AgentError::InvalidParameter {
                field: "hop".into(),
                message: format!(
                    "got {} samples, need hop_len × channels = {} × {} = {want}",
                    interleaved.len(),
                    self.hop_len(),
                    self.channels
                ),
            });
        }
        Ok(self.process_hop(first_sample, interleaved))
    }

    /// The last result.
    pub fn last_result(&self) -> &FrameResult {
        &self.result
    }

    /// Forgets the audio and tracks seen so far (after a gap in the input).
    pub fn reset(&mut self) {
        self.stft.reset();
        self.tracker.reset();
        self.srp.reset();
        self.floor_offsets.clear();
        self.tracks_frame = None;
        self.signatures.reset();
        self.result.potentials.clear();
        self.result.tracks.clear();
        self.result.reported.clear();
        self.result.signatures_db.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send<T: Send>() {}

    #[test]
    fn config_reads_from_toml_and_rejects_unknown_keys() {
        let text = r#"
            sample_rate_hz = 16000
            frame_len = 512
            window = "sqrt-hann"
            [srp]
            search = "exhaustive"
            max_sources = 3
            region = { axis = [0.0, 0.0, 1.0], max_angle_deg = 180.0 }
            [tracker]
            birth_gate_deg = 8.0
        "#;
        let c: PipelineConfig = toml::from_str(text).unwrap();
        assert_eq!(c.frame_len, 512);
        assert_eq!(c.hop_len, 128, "defaults fill the rest");
        assert_eq!(c.window, Window::SqrtHann);
        assert_eq!(c.srp.search, crate::srp::SearchMode::Exhaustive);
        assert_eq!(c.srp.max_sources, 3);
        assert_eq!(c.tracker.birth_gate_deg, 8.0);
        assert!(
            toml::from_str::<PipelineConfig>(
                "[srp]
max_source = 3
"
            )
            .is_err()
        );
        assert!(
            toml::from_str::<PipelineConfig>(
                "hop = 64
"
            )
            .is_err()
        );
        let array = ArrayGeometry::load("respeaker-4").unwrap();
        assert!(Pipeline::new(&array, &c).is_ok());
    }

    #[test]
    fn sigma_floor_scales_with_a_small_aperture_only_when_asked() {
        let floor = |preset: &str, full: f64| {
            let array = ArrayGeometry::load(preset).unwrap();
            let config =
                PipelineConfig { doa_sigma_floor_full_aperture_m: full, ..PipelineConfig::default() };
            Pipeline::new(&array, &config).unwrap().doa_sigma_floor_rad().to_degrees()
        };
        // Off by default: 1° for every array.
        assert!((floor("respeaker-6", 0.0) - 1.0).abs() < 1e-12);
        // At 0.4 m: the 16SoundsUSB keeps 1°, the 9.3 cm ReSpeaker 6 gets 0.4/0.093.
        assert!((floor("16soundsusb-pioneer", 0.4) - 1.0).abs() < 1e-12);
        let respeaker = floor("respeaker-6", 0.4);
        assert!((4.2..4.4).contains(&respeaker), "{respeaker}");
        let bad = PipelineConfig { doa_sigma_floor_full_aperture_m: f64::NAN, ..PipelineConfig::default() };
        let err = Pipeline::new(&ArrayGeometry::load("uma8").unwrap(), &bad).unwrap_err();
        assert!(err.to_string().contains("doa_sigma_floor_full_aperture_m"), "{err}");
    }

    #[test]
    fn pipeline_is_send_and_stamps_mid_frame() {
        assert_send::<Pipeline>();
        let array = ArrayGeometry::load("respeaker-4").unwrap();
        let config = PipelineConfig { frame_len: 512, hop_len: 128, ..Default::default() };
        let mut p = Pipeline::new(&array, &config).unwrap();
        let hop = vec![0.0f32; 128 * 4];
        let r = p.process_hop(Stamp::from_ns(1_000_000_000), &hop);
        assert!(r.potentials.is_empty());
        // Frame = [hop_start − 384, hop_start + 128) samples; middle = hop_start − 128 samples = −8 ms.
        assert_eq!(r.stamp, Stamp::from_ns(1_000_000_000 - 8_000_000));
        assert!(p.try_process_hop(Stamp::ZERO, &hop[1..]).is_err());
    }
}
