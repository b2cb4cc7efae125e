//! SRP-PHAT localization on a hierarchical icosphere grid, with sub-grid
//! refinement.
//!
//! Per frame ([`Srp::process`]):
//! 1. PHAT-whiten each channel's spectrum on the band and compute the
//!    GCC-PHAT of every microphone pair by inverse FFT, summed per baseline
//!    (pairs displaced by the same vector share one row, since the steered
//!    response only reads their sum), two rows per complex FFT, keeping only
//!    the lags a direction can produce ([`phat`]).
//! 2. Find the best direction on the fine icosphere by a coarse → fine branch
//!    and bound over max-filtered correlations, as ODAS's SRP-PHAT-HSDA does
//!    ([`search`]); or, for reference, scan every fine point.
//! 3. Start from a quadratic fit around the best grid point and refine off
//!    the grid by Newton ascent of the exact beamformer power ([`refine`]),
//!    so the accuracy does not depend on the grid spacing (nor on an
//!    interpolation of the correlations).
//! 4. Up to `max_sources` potential sources: after each peak, zero every
//!    row's correlation around the peak's TDOA (ODAS's suppression) and
//!    search again, away from the peaks already found; a later peak is
//!    refined and scored after projecting the earlier sources out of the
//!    whitened spectra, so a strong source's sidelobes do not come back as
//!    coherent ghosts. Peaks too weak to matter (grid coherence below
//!    `refine_min_coherence`) are reported unrefined.
//!
//! Each potential's `energy` is the *PHAT coherence* at its direction: the
//! steered response normalized per pair and bin, 1 for a noise-free plane
//! wave, ≈ 0 for incoherent noise, whatever the signal level (PHAT makes it
//! scale-free). The tracker uses it to tell sources from noise.
//!
//! Frames: directions are unit vectors in the `array` frame.

pub mod diffuse;
pub mod floor_fit;
pub mod grid;
pub mod phat;
pub mod refine;
pub mod search;
#[cfg(test)]
mod tests;

use std::path::PathBuf;

use nalgebra::{Unit, Vector3};
use realfft::num_complex::Complex;

use crate::array::{ArrayGeometry, SearchRegion};
use crate::error::AgentError;
use phat::{Band, CrossCorrelator};
use refine::{Refiner, Wavefront};
use search::{Exclusion, SearchTables};

/// How the fine grid is searched.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SearchMode {
    /// Coarse → fine branch and bound (ODAS's SRP-PHAT-HSDA idea).
    #[default]
    Hierarchical,
    /// Every fine point (classic SRP-PHAT; the reference for benchmarks).
    Exhaustive,
}

/// A cone of directions for [`SrpConfig::region`].
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionConfig {
    /// Cone axis, array frame (need not be normalized).
    pub axis: [f64; 3],
    /// Cone half-angle, degrees (90 = hemisphere, 180 = whole sphere).
    pub max_angle_deg: f64,
}

/// SRP-PHAT settings. Defaults follow ODAS (coarse level 2, fine level 4).
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SrpConfig {
    /// Speed of sound, m/s (key `speed_of_sound_m_s` accepted as an alias).
    #[serde(alias = "speed_of_sound_m_s")]
    pub speed_of_sound_m_per_s: f64,
    /// Lowest frequency used, Hz.
    pub min_frequency_hz: f64,
    /// Highest frequency used, Hz (capped just below Nyquist).
    pub max_frequency_hz: f64,
    /// Icosphere level of the coarse grid (2 → 162 points on the sphere).
    pub coarse_level: u32,
    /// Icosphere level of the fine grid (4 → 2562 points on the sphere).
    pub fine_level: u32,
    /// Hierarchical (default) or exhaustive search of the fine grid.
    pub search: SearchMode,
    /// Most coarse cells opened by the branch and bound for the strongest peak.
    pub max_coarse_cells: usize,
    /// Most coarse cells opened for each later peak (after suppression,
    /// usually noise or a weaker source).
    pub max_coarse_cells_secondary: usize,
    /// Newton refinement off the grid (default on).
    pub refine: bool,
    /// Most Newton steps per peak.
    pub refine_iterations: usize,
    /// Refine each peak with a spherical wavefront, its range a third
    /// unknown: a plane-wave fit of a source a few metres from a 0.5 m array
    /// biases its elevation low (1.3° at 5 m and 7° elevation for the
    /// 16SoundsUSB layout, see [`refine`]). Default off: in reverberant rooms
    /// that bias partly cancels the floor reflection's upward pull, and the
    /// coordinator's floor-image model (`[doa] floor_reflection` 0.6) is
    /// calibrated on plane-wave DoAs; with this on, 0.7 fits (measured in
    /// `BENCHMARKS.md`, "Near-field refinement").
    pub near_field: bool,
    /// Nearest range the near-field refinement considers, m (default 0.5).
    pub near_field_min_range_m: f64,
    /// How much of the diffuse field's expected steered power the
    /// refinement subtracts, in `0..=2` (0, the default: none; 1: the share
    /// the peak's coherence implies). Experimental: it takes the reverberant
    /// elevation bias of small arrays down by half (ReSpeaker 6, RT60 0.65 s:
    /// +12.7° → +5.6° at the median) but makes the several-source scenarios
    /// worse, where another source's energy is counted as diffuse (see
    /// [`diffuse::DiffusePower`] and `BENCHMARKS.md`, "Diffuse compensation").
    pub diffuse_compensation: f64,
    /// Peaks whose grid coherence is below this are noise for every
    /// practical purpose: they are reported at grid resolution, unrefined.
    pub refine_min_coherence: f64,
    /// Potential sources reported per frame (ODAS: 4).
    pub max_sources: usize,
    /// Minimum angle between two potentials of a frame, degrees.
    pub min_separation_deg: f64,
    /// Directions searched; `None` uses the array's default region.
    pub region: Option<RegionConfig>,
    /// Fit each reported track's elevation and range with the floor's
    /// reflection in the steering model, on the recent frames' averaged
    /// cross-spectra ([`floor_fit`]): the DoAs are then the direct path's,
    /// not pulled up by the floor's image.
    pub floor_fit: bool,
    /// Pressure reflection coefficient of the floor (and ceiling) the fit
    /// assumes, in `0..=1`.
    pub floor_reflection: f64,
    /// Height of the array origin above the floor, m; `None` takes it from
    /// the array's mount (`base_from_array`, the base frame's origin on the
    /// floor).
    pub floor_height_m: Option<f64>,
    /// Height of the ceiling above the floor, m, if known (its image joins
    /// the model).
    pub ceiling_height_m: Option<f64>,
    /// Smallest relative gain of steered power over the direct path alone
    /// for a fit to be kept.
    pub floor_fit_min_gain: f64,
    /// Frames the averaged cross-spectra of the fit remember (the forgetting
    /// time constant, in frames).
    pub floor_fit_frames: f64,
    /// Hops between two fits of each reported track (1: every hop).
    pub floor_fit_every_hops: usize,
    /// Hops between two fits of a *steady* track: one whose elevation above
    /// the floor has moved less than 1° since its last fit (its azimuth may
    /// move: the floor's image lies at the source's own azimuth). 0 fits
    /// every track every `floor_fit_every_hops`.
    pub floor_fit_steady_every_hops: usize,
}

impl Default for SrpConfig {
    fn default() -> Self {
        SrpConfig {
            speed_of_sound_m_per_s: 343.0,
            min_frequency_hz: 100.0,
            max_frequency_hz: 8000.0,
            coarse_level: 2,
            fine_level: 4,
            search: SearchMode::Hierarchical,
            max_coarse_cells: 8,
            max_coarse_cells_secondary: 3,
            refine: true,
            refine_iterations: 6,
            near_field: false,
            near_field_min_range_m: 0.5,
            diffuse_compensation: 0.0,
            refine_min_coherence: 0.05,
            max_sources: 2,
            min_separation_deg: 15.0,
            region: None,
            floor_fit: false,
            floor_reflection: 0.8,
            floor_height_m: None,
            ceiling_height_m: None,
            floor_fit_min_gain: 0.0,
            floor_fit_frames: 16.0,
            floor_fit_every_hops: 8,
            floor_fit_steady_every_hops: 32,
        }
    }
}

/// Peaks below this grid coherence are refined as plane waves even with
/// `near_field` on: their direction scatters far more than the near-field
/// bias (sensor-noise peaks of a 16-microphone array reach ~0.05), and the
/// range costs a third of the refinement again.
const NEAR_FIELD_MIN_COHERENCE: f64 = 0.1;

/// A direction where the steered response peaks in one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PotentialSource {
    /// Unit vector toward the peak, array frame.
    pub direction_in_array: Unit<Vector3<f64>>,
    /// PHAT coherence at the peak: 1 for a noise-free plane wave, ≈ 0 for noise.
    pub energy: f64,
    /// Inverse range 1/ρ the near-field refinement found, 1/m (0: a plane
    /// wave fits best, or the peak was not refined). Without reflections it
    /// is within ~2 % for the 16SoundsUSB arrays up to 5 m; in a room the
    /// reflections' curvature shortens it (`cocktail`, RT60 0.5 s, sources
    /// 2.3–2.8 m away: per-frame medians 1.5–2.0 m, quartiles ±0.6 m), so it
    /// is a by-product of the refinement, not a range measurement.
    pub inverse_range_per_m: f64,
}

/// Work done by [`Srp::process`], see [`Srp::take_stats`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SrpStats {
    /// Grid searches (one per potential).
    pub searches: usize,
    /// Coarse cells opened by the branch and bound.
    pub cells_opened: usize,
    /// Fine points whose response was computed.
    pub fine_points: usize,
    /// Beamformer evaluations (value, gradient, Hessian) of the refinement.
    pub refine_evaluations: usize,
    /// Model evaluations of the floor-reflection fit.
    pub floor_fit_evaluations: usize,
}

/// SRP-PHAT localizer of one array.
#[derive(Debug)]
pub struct Srp {
    config: SrpConfig,
    region: SearchRegion,
    /// Normal of the array plane when the array is planar (mirror symmetry).
    planar_normal: Option<Unit<Vector3<f64>>>,
    cc: CrossCorrelator,
    tables: SearchTables,
    refiner: Refiner,
    /// `τₚ(d) = pair_axes[p]·d` samples.
    pair_axes: Vec<Vector3<f64>>,
    /// The same for the correlator's rows (one per baseline).
    row_axes: Vec<Vector3<f64>>,
    mics: Vec<crate::array::Microphone>,
    gains: Vec<f32>,
    found: Vec<Vector3<f64>>,
    /// Whether `found[j]` was refined (with its inverse range), and how many
    /// of `found` were projected out.
    found_refined: Vec<Option<f64>>,
    projected: usize,
    max_step_rad: f64,
    diffuse: diffuse::DiffuseMap,
    /// The floor-reflection fit, when on, and the averaged cross-spectra
    /// it fits tracks on.
    floor: Option<floor_fit::FloorFit>,
    csm: Option<floor_fit::Csm>,
}

impl Srp {
    /// Plans the localizer for `array` at `sample_rate_hz` with frames of
    /// `frame_len` samples. Everything per-frame is allocated here.
    pub fn new(
        array: &ArrayGeometry,
        sample_rate_hz: u32,
        frame_len: usize,
        config: &SrpConfig,
    ) -> Result<Self, AgentError> {
        let bad = |field: &str, message: String| AgentError::InvalidParameter {
            field: format!("srp.{field}"),
            message,
        };
        array.validate(&PathBuf::from(format!("<array {}>", array.name)))?;
        let fs = sample_rate_hz as f64;
        let c = config.speed_of_sound_m_per_s;
        if !(c.is_finite() && (200.0..=2000.0).contains(&c)) {
            return Err(bad("speed_of_sound_m_per_s", format!("must be in 200..=2000 m/s, got {c}")));
        }
        if config.coarse_level > config.fine_level || config.fine_level > 6 {
            return Err(bad(
                "fine_level",
                format!(
                    "need coarse_level <= fine_level <= 6, got {} and {}",
                    config.coarse_level, config.fine_level
                ),
            ));
        }
        let bin_hz = fs / frame_len as f64;
        let lo = (config.min_frequency_hz / bin_hz).ceil().max(1.0) as usize;
        let hi = ((config.max_frequency_hz / bin_hz).floor() as usize + 1).min(frame_len / 2);
        if !(config.min_frequency_hz.is_finite() && config.max_frequency_hz.is_finite()) || hi <= lo + 2 {
            return Err(bad(
                "max_frequency_hz",
                format!(
                    "band {}..{} Hz leaves fewer than 3 FFT bins of {bin_hz} Hz below Nyquist",
                    config.min_frequency_hz, config.max_frequency_hz
                ),
            ));
        }
        if config.max_sources == 0 {
            return Err(bad("max_sources", "must be at least 1".into()));
        }
        let min_range = config.near_field_min_range_m;
        if !(min_range.is_finite() && (0.1..=100.0).contains(&min_range)) {
            return Err(bad("near_field_min_range_m", format!("must be in 0.1..=100 m, got {min_range}")));
        }
        let region = match &config.region {
            None => array.default_region,
            Some(r) => {
                let axis = Vector3::from(r.axis);
                let ok =
                    axis.iter().all(|v| v.is_finite()) && r.max_angle_deg > 0.0 && r.max_angle_deg <= 180.0;
                let axis = ok.then(|| Unit::try_new(axis, 1e-9)).flatten().ok_or_else(|| {
                    bad("region", "needs a finite non-zero axis and 0 < max_angle_deg <= 180".into())
                })?;
                SearchRegion { axis, max_angle_rad: r.max_angle_deg.to_radians() }
            }
        };
        let positions: Vec<Vector3<f64>> = array.positions().map(|p| p.coords).collect();
        let m = positions.len();
        let pair_mics: Vec<(usize, usize)> = (0..m).flat_map(|i| (i + 1..m).map(move |j| (i, j))).collect();
        let tdoa_axis = |&(i, j): &(usize, usize)| (positions[j] - positions[i]) * (fs / c);
        let pair_axes: Vec<Vector3<f64>> = pair_mics.iter().map(tdoa_axis).collect();
        // One correlation row per baseline (`phat`, module docs); a pair of
        // directional microphones weighs its own correlation, so keeps its own row.
        let directional = array.microphones.iter().any(|m| m.axis_in_array.is_some());
        let rows = if directional { phat::pair_rows(m) } else { phat::baseline_rows(&positions) };
        let row_mics: Vec<(usize, usize)> = rows.iter().map(|r| r[0]).collect();
        let row_axes: Vec<Vector3<f64>> = row_mics.iter().map(tdoa_axis).collect();
        let tables =
            SearchTables::new(array, &row_axes, &row_mics, &region, config.coarse_level, config.fine_level);
        let radius = tables.lag_radius();
        if radius >= frame_len / 2 {
            return Err(bad(
                "frame_len",
                format!(
                    "frames of {frame_len} samples are too short for an array of aperture {:.3} m \
                     (needs lags up to {radius})",
                    array.aperture_m()
                ),
            ));
        }
        let band = Band { lo, hi };
        let mut cc = CrossCorrelator::new(m, frame_len, band, radius, rows, tables.windows.clone());
        let (lin_used, max_used) = tables.used_lags();
        cc.restrict(&lin_used, &max_used);
        let compensation = config.diffuse_compensation;
        if !(compensation.is_finite() && (0.0..=2.0).contains(&compensation)) {
            return Err(bad("diffuse_compensation", format!("must be in 0..=2, got {compensation}")));
        }
        let mut refiner = Refiner::new(&positions, c, fs, frame_len, lo, band.len());
        if compensation > 0.0 {
            refiner = refiner.with_diffuse_power();
        }
        let (normal, _) = array.best_fit_plane();
        let padded_bins = cc.padded;
        let frames = config.floor_fit_frames;
        if !(frames.is_finite() && (1.0..=1000.0).contains(&frames)) {
            return Err(bad("floor_fit_frames", format!("must be in 1..=1000 frames, got {frames}")));
        }
        if config.floor_fit_every_hops == 0 {
            return Err(bad("floor_fit_every_hops", "must be at least 1".into()));
        }
        let steady = config.floor_fit_steady_every_hops;
        if steady != 0 && steady < config.floor_fit_every_hops {
            return Err(bad(
                "floor_fit_steady_every_hops",
                format!(
                    "must be 0 (off) or at least floor_fit_every_hops ({}), got {steady}",
                    config.floor_fit_every_hops
                ),
            ));
        }
        let floor = if config.floor_fit {
            let beta = config.floor_reflection;
            if !(beta.is_finite() && (0.0..=1.0).contains(&beta)) {
                return Err(bad("floor_reflection", format!("must be in 0..=1, got {beta}")));
            }
            let mount = array.base_from_array;
            let height = config.floor_height_m.unwrap_or(mount.translation.vector.z);
            if !(height.is_finite() && (0.05..=10.0).contains(&height)) {
                return Err(bad(
                    "floor_height_m",
                    format!(
                        "the array's height above the floor must be in 0.05..=10 m, got {height} \
                         (set floor_height_m when the array's mount does not give it)"
                    ),
                ));
            }
            if let Some(h) = config.ceiling_height_m
                && !(h.is_finite() && h > height + 0.1 && h <= 100.0)
            {
                return Err(bad(
                    "ceiling_height_m",
                    format!("must be above the array ({height} m) and at most 100 m, got {h}"),
                ));
            }
            let gain = config.floor_fit_min_gain;
            if !(gain.is_finite() && (0.0..=1.0).contains(&gain)) {
                return Err(bad("floor_fit_min_gain", format!("must be in 0..=1, got {gain}")));
            }
            let up = Unit::new_normalize(mount.rotation.inverse() * Vector3::z());
            let geometry = floor_fit::FloorGeometry {
                up,
                height_m: height,
                ceiling_m: config.ceiling_height_m,
                reflection: beta,
                min_gain: gain,
            };
            let window = crate::stft::Window::Hann.coefficients(frame_len);
            Some(floor_fit::FloorFit::new(geometry, &positions, c, fs, &window, lo, band.len()))
        } else {
            None
        };
        let fine_spacing = grid::SphereGrid::icosphere(config.fine_level).mean_spacing_rad();
        let pair_dist: Vec<f64> =
            pair_mics.iter().map(|&(i, j)| (positions[j] - positions[i]).norm()).collect();
        let diffuse = diffuse::DiffuseMap::new(&pair_axes, &pair_dist, (lo, hi), frame_len, fs, c);
        Ok(Srp {
            config: config.clone(),
            region,
            planar_normal: array.is_planar().then_some(normal),
            cc,
            tables,
            refiner,
            pair_axes,
            row_axes,
            mics: array.microphones.clone(),
            gains: vec![1.0; m],
            found: Vec::with_capacity(config.max_sources),
            found_refined: Vec::with_capacity(config.max_sources),
            projected: 0,
            max_step_rad: 0.75 * fine_spacing,
            diffuse,
            csm: floor
                .as_ref()
                .map(|_| floor_fit::Csm::new(m, band.len(), padded_bins, config.floor_fit_frames)),
            floor,
        })
    }

    /// Largest PHAT coherence that diffuse noise alone is expected to give
    /// in the search region (see [`diffuse`]).
    pub fn diffuse_floor(&self) -> f64 {
        self.diffuse.max_where(|d| self.region.contains(d, 0.0))
    }

    /// The coherence of peaks on noise alone: the diffuse-noise response per
    /// direction and the standard deviation `1/√(2·pairs·bins)` of incoherent
    /// noise's coherence at one direction.
    pub fn noise_model(&self) -> diffuse::NoiseModel {
        diffuse::NoiseModel {
            diffuse: self.diffuse.clone(),
            sigma: 1.0 / (2.0 * self.pairs() as f64 * self.cc.band.len() as f64).sqrt(),
        }
    }

    /// The directions searched.
    pub fn region(&self) -> &SearchRegion {
        &self.region
    }

    /// Level of a frame on the band: the mean power per microphone and bin
    /// before whitening, dB (full scale; −300 dB for silence). `spectra` as
    /// for [`Srp::process`]. The tracker compares it with the level at which
    /// each track is heard (see [`crate::doa_tracker`], masking).
    pub fn band_level_db(&self, spectra: &[Complex<f32>]) -> f64 {
        let bins = spectra.len() / self.mics.len().max(1);
        let band = self.cc.band;
        let mut total = 0.0f64;
        for mic in spectra.chunks_exact(bins.max(1)) {
            // Eight partial sums, so that the loop vectorizes.
            let mut acc = [0.0f32; 8];
            let band_bins = &mic[band.lo..band.hi.min(mic.len())];
            let mut chunks = band_bins.chunks_exact(8);
            for c in &mut chunks {
                for (a, x) in acc.iter_mut().zip(c) {
                    *a += x.re * x.re + x.im * x.im;
                }
            }
            let tail: f32 = chunks.remainder().iter().map(|x| x.re * x.re + x.im * x.im).sum();
            total += acc.iter().map(|&a| a as f64).sum::<f64>() + tail as f64;
        }
        let mean = total / (self.mics.len() * band.len()).max(1) as f64;
        10.0 * mean.max(1e-30).log10()
    }

    /// Number of microphone pairs.
    pub fn pairs(&self) -> usize {
        self.pair_axes.len()
    }

    /// Number of fine-grid points in the search region.
    pub fn fine_points(&self) -> usize {
        self.tables.fine_len()
    }

    /// Number of coarse cells.
    pub fn coarse_cells(&self) -> usize {
        self.tables.coarse_len()
    }

    /// The frequency band used, Hz (first and last bin centres).
    pub fn band_hz(&self, sample_rate_hz: u32, frame_len: usize) -> (f64, f64) {
        let b = sample_rate_hz as f64 / frame_len as f64;
        (self.cc.band.lo as f64 * b, (self.cc.band.hi - 1) as f64 * b)
    }

    /// TDOA of pair `p` (microphones `i < j`, pairs in lexicographic order)
    /// for a far-field source in direction `d`, samples: `(pⱼ − pᵢ)·d fs/c`.
    pub fn tdoa_samples(&self, p: usize, d: &Vector3<f64>) -> f64 {
        self.pair_axes[p].dot(d)
    }

    /// Localizes one frame. `spectra` are the channels' spectra (channel-major,
    /// `frame_len/2 + 1` bins each, see [`crate::stft`]). `out` is cleared and
    /// receives up to `max_sources` potentials, strongest first; it does not
    /// grow beyond its capacity once that is ≥ `max_sources`.
    pub fn process(&mut self, spectra: &[Complex<f32>], out: &mut Vec<PotentialSource>) {
        out.clear();
        self.found.clear();
        self.found_refined.clear();
        self.projected = 0;
        self.cc.whiten(spectra);
        if self.cc.phat_energy.iter().all(|&e| e == 0.0) {
            return; // silence: no direction
        }
        if let Some(csm) = self.csm.as_mut() {
            csm.accumulate(&self.cc);
        }
        self.cc.correlate();
        let sep = self.config.min_separation_deg.to_radians();
        let (sin_sep, cos_sep) = sep.sin_cos();
        for _ in 0..self.config.max_sources {
            let exclusion = Exclusion { found: &self.found, cos_sep, sin_sep, sep_rad: sep };
            let hit = match self.config.search {
                SearchMode::Hierarchical => self.tables.search_hierarchical(
                    &self.cc.lin,
                    &self.cc.cc_max,
                    if out.is_empty() {
                        self.config.max_coarse_cells
                    } else {
                        self.config.max_coarse_cells_secondary
                    },
                    &exclusion,
                ),
                SearchMode::Exhaustive => self.tables.search_exhaustive(&self.cc.lin, &exclusion),
            };
            let Some((f, value)) = hit else { break };
            let grid_dir = Unit::new_normalize(self.tables.fine_dirs[f]);
            let grid_coherence = value as f64 / self.pair_weight(&grid_dir);
            let refine = self.config.refine && grid_coherence >= self.config.refine_min_coherence;
            let (direction, energy, kappa) = if refine {
                // Later peaks are refined and scored on what the earlier
                // (refined) sources leave: project those out first.
                for j in self.projected..self.found.len() {
                    if let Some(kappa) = self.found_refined[j] {
                        let d = Unit::new_unchecked(self.found[j]);
                        self.set_gains(&d);
                        self.refiner.project_out(&mut self.cc, &d, kappa, &self.gains);
                    }
                }
                self.projected = self.found.len();
                let start = Unit::new_normalize(self.tables.quadratic_peak(&self.cc.lin, f));
                self.refine_peak(start, grid_coherence)
            } else {
                (self.region.clamp(grid_dir), grid_coherence, 0.0)
            };
            out.push(PotentialSource { direction_in_array: direction, energy, inverse_range_per_m: kappa });
            self.found.push(direction.into_inner());
            self.found_refined.push(refine.then_some(kappa));
            if out.len() < self.config.max_sources {
                self.suppress(&direction);
            }
        }
    }

    /// Runs the hot loops with `arch`'s instructions instead of the best
    /// the CPU has (tests compare the two).
    #[cfg(test)]
    fn set_arch(&mut self, arch: pulp::Arch) {
        self.cc.arch = arch;
        self.tables.arch = arch;
        self.refiner.arch = arch;
        if let Some(f) = self.floor.as_mut() {
            f.arch = arch;
        }
        if let Some(c) = self.csm.as_mut() {
            c.arch = arch;
        }
    }

    /// Directivity gains of the microphones toward `d`.
    fn set_gains(&mut self, d: &Unit<Vector3<f64>>) {
        for (g, m) in self.gains.iter_mut().zip(&self.mics) {
            *g = m.gain(d) as f32;
        }
    }

    /// Only the front end of [`Srp::process`]: PHAT whitening and the
    /// correlations of every pair (for benchmarks).
    pub fn correlate_only(&mut self, spectra: &[Complex<f32>]) {
        self.cc.whiten(spectra);
        self.cc.correlate();
    }

    /// Work counters since the last call (then reset): how many searches,
    /// coarse cells opened, fine points evaluated and beamformer evaluations
    /// of the refinement.
    pub fn take_stats(&mut self) -> SrpStats {
        let [searches, cells, fine] = std::mem::take(&mut self.tables.counters);
        let refine = std::mem::take(&mut self.refiner.evaluations);
        let floor = self.floor.as_mut().map_or(0, |f| std::mem::take(&mut f.evaluations));
        SrpStats {
            searches,
            cells_opened: cells,
            fine_points: fine,
            refine_evaluations: refine,
            floor_fit_evaluations: floor,
        }
    }

    /// Sum of the pair weights (directivity) at `d`; the number of pairs for
    /// omnidirectional microphones.
    fn pair_weight(&self, d: &Unit<Vector3<f64>>) -> f64 {
        let (s, s2) = self.mics.iter().map(|m| m.gain(d)).fold((0.0, 0.0), |(s, s2), g| (s + g, s2 + g * g));
        (0.5 * (s * s - s2)).max(1e-12)
    }

    /// The refined direction, its coherence and inverse range (1/m), from a
    /// grid peak of coherence `grid_coherence`.
    fn refine_peak(
        &mut self,
        start: Unit<Vector3<f64>>,
        grid_coherence: f64,
    ) -> (Unit<Vector3<f64>>, f64, f64) {
        self.set_gains(&start);
        let iterations = self.config.refine_iterations;
        // The diffuse field's share of the whitened spectra, from the peak's
        // coherence C = (1 − β) + β·D̄(d): β = (1 − C)/(1 − D̄(d)).
        let e0: f64 = self.gains.iter().zip(&self.cc.phat_energy).map(|(&g, &e)| (g * g * e) as f64).sum();
        let (s1, s2) =
            self.gains.iter().fold((0.0f64, 0.0f64), |(a, b), &g| (a + g as f64, b + (g * g) as f64));
        let k = self.cc.band.len() as f64;
        let mean_energy = e0 / (s2 * k).max(1e-30);
        let strength = self.config.diffuse_compensation;
        self.refiner.diffuse_weight = if strength > 0.0 {
            let dbar = self.diffuse.at(&start);
            let beta = ((1.0 - grid_coherence) / (1.0 - dbar).max(1e-3)).clamp(0.0, 1.0);
            strength * beta * mean_energy
        } else {
            0.0
        };
        let wavefront = if self.config.near_field && grid_coherence >= NEAR_FIELD_MIN_COHERENCE {
            Wavefront::Spherical { max_inverse_range_per_m: 1.0 / self.config.near_field_min_range_m }
        } else {
            Wavefront::Plane
        };
        let (d, kappa, local) = match self.planar_normal {
            Some(n) => {
                // A planar array hears a source and its mirror image through
                // its plane identically: refine on the side inside the region.
                let mirror = Unit::new_normalize(start.into_inner() - n.into_inner() * (2.0 * n.dot(&start)));
                let side =
                    if self.region.axis.dot(&mirror) > self.region.axis.dot(&start) { mirror } else { start };
                self.refiner.refine_planar(
                    &self.cc,
                    side,
                    &n,
                    &self.gains,
                    iterations,
                    self.max_step_rad,
                    wavefront,
                )
            }
            None => {
                let start = self.region.clamp(start);
                self.refiner.refine(
                    &self.cc,
                    start,
                    &self.gains,
                    iterations,
                    self.max_step_rad,
                    &self.region,
                    wavefront,
                )
            }
        };
        let d = self.region.clamp(d);
        // Normalized so that a plane wave carrying all the (remaining) energy
        // scores 1: (P − E₀) / (((Σg)² − Σg²) · ē · K), ē the mean energy per
        // microphone and bin (1 before any projection). The power counts the
        // diffuse part again: the tracker's thresholds are on the raw coherence.
        let coherence = (local.power + local.diffuse - e0) / ((s1 * s1 - s2) * mean_energy * k).max(1e-30);
        (d, coherence, kappa)
    }

    /// The floor-reflection fit of the direction `d` (a track's) on the
    /// recent frames' averaged cross-spectra; `None` when the fit is off,
    /// has no frames yet, or does not beat the direct path alone.
    pub fn fit_floor(&mut self, d: &Unit<Vector3<f64>>) -> Option<floor_fit::FloorFitted> {
        let csm = self.csm.as_ref().filter(|c| c.frames > 0)?;
        for (g, m) in self.gains.iter_mut().zip(&self.mics) {
            *g = m.gain(d) as f32;
        }
        self.floor.as_mut()?.fit_averaged(csm, d, &self.gains)
    }

    /// The floor frame's elevation of `d` moved by `offset_rad` (azimuth
    /// kept), when the floor fit is on.
    pub fn shift_elevation(&self, d: &Unit<Vector3<f64>>, offset_rad: f64) -> Option<Unit<Vector3<f64>>> {
        self.floor.as_ref().map(|f| f.shift_elevation(d, offset_rad))
    }

    /// The elevation of `d` above the floor (rad), when the floor fit is on.
    pub fn floor_elevation(&self, d: &Vector3<f64>) -> Option<f64> {
        self.floor.as_ref().map(|f| f.elevation(d))
    }

    /// Tells the floor-reflection fit the analysis window (see
    /// [`floor_fit::FloorFit::set_window`]).
    pub fn set_analysis_window(&mut self, window: &[f32]) {
        if let Some(f) = self.floor.as_mut() {
            f.set_window(window);
        }
    }

    /// Whether the floor-reflection fit is on.
    pub fn floor_fit_on(&self) -> bool {
        self.floor.is_some()
    }

    /// Forgets the averaged cross-spectra (after a gap in the input).
    pub fn reset(&mut self) {
        if let Some(c) = self.csm.as_mut() {
            c.reset();
        }
    }

    /// Zeroes every row's correlation around the TDOAs of direction `d`.
    fn suppress(&mut self, d: &Unit<Vector3<f64>>) {
        crate::simd::run(self.cc.arch, Suppress { cc: &mut self.cc, row_axes: &self.row_axes, d })
    }
}

/// [`Srp::suppress`] as a vectorized kernel.
struct Suppress<'a> {
    cc: &'a mut CrossCorrelator,
    row_axes: &'a [Vector3<f64>],
    d: &'a Vector3<f64>,
}

impl crate::simd::Kernel for Suppress<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let r = self.cc.lag_radius as f64;
        for (p, axis) in self.row_axes.iter().enumerate() {
            let t = (axis.dot(self.d) + r) as f32;
            self.cc.suppress(p, t, 1);
        }
    }
}
