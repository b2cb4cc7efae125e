//! The floor's reflection, fitted: each reported track's elevation and
//! range fitted with the floor's image (and the ceiling's, when its height
//! is known) in the steering model, on the recent frames' averaged
//! cross-spectra.
//!
//! **Why.** A microphone array on a ground robot hears every source twice
//! within a frame: the direct path and its reflection off the floor, which
//! arrives 0.5–1 ms later from the source's mirror image below the floor
//! (and, with a ceiling, the ceiling's image above, a few ms later). A nearly
//! planar array (the 16SoundsUSB rings are 1.5 cm apart in height across
//! 0.49 m) measures elevation only through `cos e` of the horizontal
//! slowness, so it cannot separate the image, folded to `+e'` above the
//! horizon, from the direct path at `e`: both lie in one elevation lobe, and
//! the plane-wave peak is the direction whose phases best match their
//! *coherent sum*. That sum reads high: in image-source rooms with RT60
//! 0.65 s the Pioneer layout's single-frame peaks were 3.5–5.9° high for
//! sources 2.6–4.8 m away and 6–15° above the array plane (`BENCHMARKS.md`,
//! "Reverberant rooms"). Onsets, PHAT-β, band limits and frame averaging do
//! not reach it: the image is coherent with the direct path inside every
//! frame, so no weighting of bins or frames removes it. It has to be
//! modelled.
//!
//! **Model.** For a candidate source `s` (array frame, range `ρ = |s|`) the
//! array expects at microphone `pᵢ` and bin `ω`
//! `aᵢ(ω) = Σ_q γ_q (ρ/|s_q − pᵢ|) e^{−jω(|s_q − pᵢ| − ρ)/c}` over the direct
//! path `s₀ = s` (γ = 1) and the images `s_q`: `s` mirrored through the floor
//! (γ = `reflection`), and with a ceiling height the ceiling's mirror (γ =
//! `reflection`). Each image's γ also carries the analysis window's
//! autocorrelation at its extra delay: a copy delayed by τ shares only that
//! part of a frame with the direct sound (Hann, 256 samples at 16 kHz: 0.99
//! at 0.7 ms, 0.66 at 4 ms). The fit maximizes the steered power of the
//! whitened spectra against the model's phases, summed over the recent
//! frames: `P(s) = Σ_frames Σ_k |Σᵢ gᵢ X̃ᵢ[k] âᵢ*(ω_k)|²`, `â = a/|a|`
//! (PHAT-matched, the plane wave's `â` being the refinement's own steering;
//! see [`super::refine`]), which is `Σ_k Σ_{i≠j} wᵢ Rᵢⱼ[k] wⱼ*` on the
//! averaged cross-spectra `R` ([`Csm`]) plus a constant.
//! The unknowns are the elevation above the floor and the range; the
//! azimuth is the plane-wave peak's (the floor and ceiling images lie at the
//! source's own azimuth, and a planar array measures azimuth well). This is
//! the reflection-aware steering of robot sound localization (An, Lee, Lee
//! and Yoon, "Reflection-Aware Sound Source Localization", ICRA 2018)
//! reduced to the two planes a ground robot always has, with the range as a
//! second unknown: the image's delay and direction both follow from it, so
//! a 0.5 m array resolves it at 1–5 m.
//!
//! **Where.** One frame is not enough: in a reverberant room a single
//! frame's peak scatters by several degrees in elevation (0–19° for a
//! source at 8°, 4.8 m away, RT60 0.65 s), and a fit per frame found the
//! model's maximum near each scattered peak, not the source (far, low
//! sources stayed 2.7–6.4° high). Summed over frames the landscape is
//! steady. So [`Csm`] keeps the whitened cross-spectra of every microphone
//! pair averaged over about `floor_fit_frames` frames (16, 128 ms; the
//! average is kept in the array frame, so a robot turning at 90°/s smears
//! it by ~10°), and the pipeline fits each *reported track* on it every
//! `floor_fit_every_hops` hops (8), starting from the track's direction,
//! and moves what it reports by the elevation offset found (smoothed, half
//! of each new fit). A track that has been fitted 4 times and whose
//! elevation above the floor has since moved less than 1° is *steady* and
//! is fitted only every `floor_fit_steady_every_hops` hops (32): its
//! source's elevation and range as the array sees them have not changed
//! (its azimuth may have: the images lie at the source's own azimuth, so
//! the offset does not depend on it), and the averaged cross-spectra
//! remember only ~16 frames, so fits 8 hops apart see mostly the same
//! frames twice (`crate::pipeline`). The tracker
//! keeps tracking the plane-wave peaks, so births, gates and several
//! sources behave as without the fit.
//!
//! **Search.** The model's steered power is sharp in the image's extra
//! path `Δ = |s′| − |s|` (a path error of half a wavelength at the band's
//! top, 2 cm at 8 kHz, turns the image's phase over) and smooth in elevation;
//! in (elevation, range) its peak is a narrow ridge along which `Δ` stays
//! put (`Δ ≈ 2h sin e + 2h²/ρ`), which a coarse grid in range steps over
//! (a 6-range grid missed a noise-free source's peak by 2.3°). So the fit
//! works in (elevation, `Δ`), the range following in closed form,
//! `ρ = (4h² − Δ²)/(2Δ − 4h sin e)`: scans of `Δ` in 15 mm steps (for
//! ranges 1–12 m) at the track's elevation and 4° and 8° below it (where
//! the pull puts the direct path), then a coordinate ascent (steps halved
//! from 1° and 7.5 mm down to 0.1°) from the scans' three best local
//! maxima; 150–180 model evaluations a fit, each on every second bin of
//! the band. One scan at the track's elevation left a far, low source 6°
//! high; the three scans bring it within 1.4–2.7°.
//!
//! **Guard.** The fit is kept only when its power beats the best the direct
//! path alone (spherical, a pattern search from the plane-wave peak at the
//! fitted range) gives by more than `min_gain` (relative, default 0):
//! where the floor does not reflect, or the data do not support the image,
//! the track keeps its plane-wave direction.
//!
//! **What it reports.** The fit resolves Δ sharply but the range only
//! weakly beyond 3–4 m (along `Δ ≈ 2h sin e + 2h²/ρ`, sin e + h/ρ stays
//! nearly constant, and the direct path's curvature barely chooses): a
//! source 5 m away was fitted at 5–12 m and 0–3° high. So the pipeline
//! reports, with each corrected DoA, the range its elevation was fitted at
//! (`TrackedDoa.floor_fit_range_m`, smoothed in 1/ρ with the offset, so the
//! pair stays on the ridge), and the coordinator reads the elevation along
//! that Δ at the range its triangulation gives
//! (`soundmap_server::floor_image`, "A robot's own floor fit").
//!
//! What it needs to know: the floor's normal in the array frame and the
//! array's height above the floor (from the array's mount on the base,
//! `base_from_array`, the base frame's origin on the floor as ROS's
//! `base_footprint`), optionally the ceiling's height, and a reflection
//! coefficient. Measured in `BENCHMARKS.md`, "The floor's reflection,
//! fitted": the reverberant set's reported DoAs at RT60 0.65 s 0.61° / 1.33°
//! (Pioneer, median / p95 of case medians) and 0.60° / 0.77° read at the
//! true range; sources at 2–6 m placed within ±0.04 m in height by the
//! coordinator; at about twice the localizer's CPU with steady tracks
//! fitted less often (4.5× fitting every track every 8 hops). All of that
//! is on white noise. A talker (300–3400 Hz) is pulled further (+8 to +12°
//! in the same rooms) and the fit leaves 3–6° of it at the median: its fits
//! are weak (1–5 % above the direct path alone) and scatter by several
//! degrees from one to the next; in the closed loop with a walking talker
//! (`corner-start`) the coordinator's estimates came out worse than with
//! the default's plane-wave peaks and the coordinator's own pull model.
//! With the CPU, that is why it is off by default.

use nalgebra::{Unit, Vector3};

use super::phat::CrossCorrelator;

/// Bins processed together.
const LANES: usize = 8;
/// The fit keeps every second bin of the band (125 Hz apart at 16 kHz
/// with 256-sample frames): the image path's phase `ωΔ/c` is then
/// sampled without ambiguity up to Δ = 2.7 m, far beyond the 1.2 m a
/// source 1 m away gives, at half the cost of every bin.
const BIN_STRIDE: usize = 2;

/// Ranges the fit considers (m).
const MIN_RANGE_M: f64 = 1.0;
const MAX_RANGE_M: f64 = 12.0;
/// Elevations the fit considers (floor frame, rad).
const LOWEST_EL_RAD: f64 = -4.0 * std::f64::consts::PI / 180.0;
const HIGHEST_EL_RAD: f64 = 70.0 * std::f64::consts::PI / 180.0;
/// Step of the scan of the image's extra path (m): the steered power of the
/// model is sharp in it (a path error of λ/2 at the band's top, 2 cm at
/// 8 kHz, turns the image's phase over), smooth in elevation.
const PATH_SCAN_STEP_M: f64 = 0.015;
/// Most points of that scan.
const MAX_PATH_SCAN: usize = 48;
/// The scans' elevations below the tracked one (rad): the pull puts the
/// direct path below it, by up to ~6° for far, low sources.
const SCAN_DROPS_RAD: [f64; 3] =
    [0.0, 4.0 * std::f64::consts::PI / 180.0, 8.0 * std::f64::consts::PI / 180.0];
/// Local maxima of the scans the ascent starts from.
const STARTS: usize = 3;

/// What the fit knows about the room.
#[derive(Clone, Debug, PartialEq)]
pub struct FloorGeometry {
    /// Unit normal of the floor, pointing up, in the array frame.
    pub up: Unit<Vector3<f64>>,
    /// Height of the array origin above the floor (m).
    pub height_m: f64,
    /// Height of the ceiling above the floor (m), if known.
    pub ceiling_m: Option<f64>,
    /// Pressure reflection coefficient of the floor (and ceiling).
    pub reflection: f64,
    /// Smallest relative power gain over the direct path alone for the fit
    /// to be kept.
    pub min_gain: f64,
}

/// A fitted peak.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FloorFitted {
    /// Direct-path direction, array frame.
    pub direction: Unit<Vector3<f64>>,
    /// Range to the source (m).
    pub range_m: f64,
    /// Steered power of the model at the fit over the direct path's best.
    pub gain: f64,
    /// Fitted elevation above the floor minus the given direction's (rad).
    pub offset_rad: f64,
}

/// The fitter: planned once, allocation-free per frame.
#[derive(Debug)]
pub struct FloorFit {
    geometry: FloorGeometry,
    positions: Vec<Vector3<f64>>,
    inv_c: f64,
    /// Spacing of the kept bins (rad/s: `BIN_STRIDE` FFT bins) and the
    /// band's first FFT bin.
    domega: f64,
    first_bin: usize,
    padded: usize,
    fs: f64,
    /// Autocorrelation of the analysis window per lag (samples), normalized.
    window_ac: Vec<f64>,
    /// The model's matched weights per microphone and bin.
    wr: Vec<f32>,
    wi: Vec<f32>,
    /// Horizontal basis of the floor frame (array frame vectors).
    e1: Vector3<f64>,
    e2: Vector3<f64>,
    /// Model evaluations since last read.
    pub(super) evaluations: usize,
    pub(super) arch: pulp::Arch,
}

/// A candidate source at the fit's azimuth: elevation above the floor
/// (rad) and range (m).
#[derive(Clone, Copy, Debug)]
struct Candidate {
    el: f64,
    range: f64,
}

impl FloorFit {
    /// Plans the fit for microphones at `positions` (array frame, m), speed of
    /// sound `c`, frames of `frame_len` at `fs` with the Hann `window`
    /// coefficients, band bins `lo..lo + bins`.
    pub fn new(
        geometry: FloorGeometry,
        positions: &[Vector3<f64>],
        c: f64,
        fs: f64,
        window: &[f32],
        lo: usize,
        bins: usize,
    ) -> Self {
        let frame_len = window.len();
        let padded = bins.div_ceil(BIN_STRIDE).div_ceil(LANES) * LANES;
        let window_ac = window_autocorrelation(window);
        let up = geometry.up.into_inner();
        let seed = if up.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
        let e1 = (seed - up * up.dot(&seed)).normalize();
        let e2 = up.cross(&e1);
        FloorFit {
            geometry,
            positions: positions.to_vec(),
            inv_c: 1.0 / c,
            domega: std::f64::consts::TAU * fs / frame_len as f64 * BIN_STRIDE as f64,
            first_bin: lo,
            padded,
            fs,
            window_ac,
            wr: vec![0.0; padded * positions.len()],
            wi: vec![0.0; padded * positions.len()],
            e1,
            e2,
            evaluations: 0,
            arch: pulp::Arch::new(),
        }
    }

    /// Takes the analysis window's coefficients (the images' overlap with
    /// the direct sound in a frame follows from them; Hann until told).
    pub fn set_window(&mut self, window: &[f32]) {
        self.window_ac = window_autocorrelation(window);
    }

    /// The geometry the fit assumes.
    pub fn geometry(&self) -> &FloorGeometry {
        &self.geometry
    }

    /// `d` with its elevation above the floor moved by `offset_rad`.
    pub fn shift_elevation(&self, d: &Unit<Vector3<f64>>, offset_rad: f64) -> Unit<Vector3<f64>> {
        let (az, el) = self.azimuth_elevation(d);
        Unit::new_normalize(self.direction(az, el + offset_rad))
    }

    /// Elevation of `d` above the floor (rad).
    pub fn elevation(&self, d: &Vector3<f64>) -> f64 {
        self.azimuth_elevation(d).1
    }

    fn azimuth_elevation(&self, d: &Vector3<f64>) -> (f64, f64) {
        let up = self.geometry.up.into_inner();
        let z = d.dot(&up).clamp(-1.0, 1.0);
        (d.dot(&self.e2).atan2(d.dot(&self.e1)), z.asin())
    }

    fn direction(&self, az: f64, el: f64) -> Vector3<f64> {
        let up = self.geometry.up.into_inner();
        (self.e1 * az.cos() + self.e2 * az.sin()) * el.cos() + up * el.sin()
    }

    /// Fits the direction `plane` (a track's, pulled as plane-wave peaks
    /// are) on the recent frames' averaged cross-spectra `csm`, with
    /// microphone gains `gains`. `None` when the model does not beat the
    /// direct path alone by more than `min_gain`.
    pub fn fit_averaged(
        &mut self,
        csm: &Csm,
        plane: &Unit<Vector3<f64>>,
        gains: &[f32],
    ) -> Option<FloorFitted> {
        let (az, el0) = self.azimuth_elevation(plane);
        let with_images = |s: &mut Self, c: Candidate| s.power(csm, gains, az, c, true);
        let (best, p_best) = self.search_images(el0, with_images);
        // The direct path alone: the same search without images, from the
        // plane-wave peak at the fitted range.
        let direct = |s: &mut Self, c: Candidate| s.power(csm, gains, az, c, false);
        let c0 = Candidate { el: el0, range: best.range };
        let p0 = direct(self, c0);
        let (_, p_direct) = self.pattern(c0, p0, 0.5f64.to_radians(), 0.2, direct);
        let gain = p_best / p_direct.max(1e-30);
        (gain > 1.0 + self.geometry.min_gain).then(|| FloorFitted {
            direction: Unit::new_normalize(self.direction(az, best.el)),
            range_m: best.range,
            gain,
            offset_rad: best.el - el0,
        })
    }

    /// The floor image's extra path (m) for a source at elevation `el` and
    /// range `r`: `|s′| − |s|`, `s′` the image `2h` below the source's mirror.
    fn image_path(&self, el: f64, r: f64) -> f64 {
        let h = self.geometry.height_m;
        (r * r + 4.0 * h * r * el.sin() + 4.0 * h * h).max(0.0).sqrt() - r
    }

    /// The range at which a source at elevation `el` has the floor image's
    /// extra path `path` (the inverse of [`FloorFit::image_path`]:
    /// `r = (4h² − Δ²)/(2Δ − 4h sin e)`), within `MIN_RANGE_M..=MAX_RANGE_M`.
    fn range_for_path(&self, el: f64, path: f64) -> f64 {
        let h = self.geometry.height_m;
        let den = 2.0 * path - 4.0 * h * el.sin();
        let r = if den > 1e-9 { (4.0 * h * h - path * path) / den } else { MAX_RANGE_M };
        r.clamp(MIN_RANGE_M, MAX_RANGE_M)
    }

    /// The fit's search in (elevation, image path): a scan of the image's
    /// extra path at the plane-wave elevation, then a coordinate ascent from
    /// the scan's two best local maxima (see the module docs, "Search").
    fn search_images(
        &mut self,
        el0: f64,
        mut power: impl FnMut(&mut Self, Candidate) -> f64,
    ) -> (Candidate, f64) {
        // The best local maxima of the scans (elevation, path, power).
        let mut starts = [(0.0f64, 0.0f64, f64::MIN); STARTS];
        for drop in SCAN_DROPS_RAD {
            let el = (el0 - drop).clamp(LOWEST_EL_RAD, HIGHEST_EL_RAD);
            let (far, near) = (self.image_path(el, MAX_RANGE_M), self.image_path(el, MIN_RANGE_M));
            let steps = (((near - far) / PATH_SCAN_STEP_M).ceil() as usize).clamp(4, MAX_PATH_SCAN);
            let mut scan = [(0.0f64, f64::MIN); MAX_PATH_SCAN + 1];
            for (j, slot) in scan.iter_mut().enumerate().take(steps + 1) {
                let path = far + (near - far) * j as f64 / steps as f64;
                *slot = (path, power(self, Candidate { el, range: self.range_for_path(el, path) }));
            }
            for j in 0..=steps {
                let v = scan[j].1;
                let left = if j > 0 { scan[j - 1].1 } else { f64::MIN };
                let right = if j < steps { scan[j + 1].1 } else { f64::MIN };
                if v >= left && v >= right && v > starts[STARTS - 1].2 {
                    starts[STARTS - 1] = (el, scan[j].0, v);
                    starts.sort_by(|a, b| b.2.total_cmp(&a.2));
                }
            }
        }
        let (el, path, _) = starts[0];
        let mut best = (Candidate { el, range: self.range_for_path(el, path) }, starts[0].2);
        for &(el0, path0, p0) in starts.iter().filter(|s| s.2 > f64::MIN) {
            let (el, path, p) =
                self.ascend(el0, path0, p0, 1f64.to_radians(), 0.5 * PATH_SCAN_STEP_M, &mut power);
            if p > best.1 {
                best = (Candidate { el, range: self.range_for_path(el, path) }, p);
            }
        }
        best
    }

    /// Coordinate ascent in (elevation, image path) from `(el, path)` of
    /// power `p`, steps halved from `step_el`, `step_path` down to 0.1°.
    fn ascend(
        &mut self,
        mut el: f64,
        mut path: f64,
        mut p: f64,
        mut step_el: f64,
        mut step_path: f64,
        mut power: impl FnMut(&mut Self, Candidate) -> f64,
    ) -> (f64, f64, f64) {
        while step_el >= 0.1f64.to_radians() {
            let mut moved = false;
            for (te, tp) in
                [(el + step_el, path), (el - step_el, path), (el, path + step_path), (el, path - step_path)]
            {
                let te = te.clamp(LOWEST_EL_RAD, HIGHEST_EL_RAD);
                let q = power(self, Candidate { el: te, range: self.range_for_path(te, tp) });
                if q > p {
                    (el, path, p, moved) = (te, tp, q, true);
                    break;
                }
            }
            if !moved {
                step_el *= 0.5;
                step_path *= 0.5;
            }
        }
        (el, path, p)
    }

    /// Coordinate pattern search in (elevation, log range) from `c`.
    fn pattern(
        &mut self,
        mut c: Candidate,
        mut p: f64,
        mut step_el: f64,
        mut step_log_range: f64,
        mut power: impl FnMut(&mut Self, Candidate) -> f64,
    ) -> (Candidate, f64) {
        let min_el = 0.1f64.to_radians();
        while step_el >= min_el {
            let mut moved = false;
            for trial in [
                Candidate { el: c.el + step_el, ..c },
                Candidate { el: c.el - step_el, ..c },
                Candidate { range: (c.range * step_log_range.exp()).min(20.0), ..c },
                Candidate { range: (c.range * (-step_log_range).exp()).max(0.5), ..c },
            ] {
                let q = power(self, trial);
                if q > p {
                    (c, p, moved) = (trial, q, true);
                    break;
                }
            }
            if !moved {
                step_el *= 0.5;
                step_log_range *= 0.5;
            }
        }
        (c, p)
    }

    /// Steered power of the data against the model at `c` (with or without
    /// the images).
    fn power(&mut self, csm: &Csm, gains: &[f32], az: f64, c: Candidate, images: bool) -> f64 {
        self.evaluations += 1;
        crate::simd::run(self.arch, Evaluate { fit: self, csm, gains, az, c, images })
    }

    /// The model's matched weights `wᵢ = gᵢ âᵢ*` for every microphone and
    /// bin at `c`, into `wr`/`wi` (microphone-major, padded bins).
    #[inline(always)]
    fn steer(&mut self, gains: &[f32], az: f64, c: Candidate, images: bool) {
        let up = self.geometry.up.into_inner();
        let s = self.direction(az, c.el) * c.range;
        let h = self.geometry.height_m;
        let beta = self.geometry.reflection;
        // Paths: the source and its images, with gains for the window's overlap.
        let mut paths = [(s, 1.0f64); 3];
        let mut n = 1;
        if images {
            let floor = s - up * (2.0 * (s.dot(&up) + h));
            paths[n] = (floor, beta);
            n += 1;
            if let Some(ceiling) = self.geometry.ceiling_m {
                let image = s + up * (2.0 * (ceiling - h - s.dot(&up)));
                paths[n] = (image, beta);
                n += 1;
            }
        }
        let rho = c.range;
        for path in paths.iter_mut().take(n).skip(1) {
            let lag = ((path.0.norm() - rho) * self.inv_c * self.fs).round().max(0.0) as usize;
            path.1 *= self.window_ac.get(lag).copied().unwrap_or(0.0);
        }
        let padded = self.padded;
        for (i, p) in self.positions.iter().enumerate() {
            let g = gains[i];
            let (wr, wi) =
                (&mut self.wr[i * padded..(i + 1) * padded], &mut self.wi[i * padded..(i + 1) * padded]);
            if g == 0.0 {
                wr.fill(0.0);
                wi.fill(0.0);
                continue;
            }
            // Per path: its lane phasors e^{+jω τ} for the first 8 bins and
            // the 8-bin step, τ = (|s_q − p| − ρ)/c; amplitude γ ρ/|s_q − p|.
            let mut pr = [[0f32; LANES]; 3];
            let mut pi = [[0f32; LANES]; 3];
            let mut step = [(0f32, 0f32); 3];
            let mut amp = [0f32; 3];
            for q in 0..n {
                let r = (paths[q].0 - p).norm();
                let tau = (r - rho) * self.inv_c;
                amp[q] = (paths[q].1 * rho / r.max(1e-3)) as f32;
                let (s1, c1) = (self.domega * tau).sin_cos();
                let (s0, c0) = (self.domega / BIN_STRIDE as f64 * tau * self.first_bin as f64).sin_cos();
                let (mut re, mut im) = (c0, s0);
                for l in 0..LANES {
                    pr[q][l] = re as f32;
                    pi[q][l] = im as f32;
                    (re, im) = (re * c1 - im * s1, re * s1 + im * c1);
                }
                // The 8-bin step e^{jω₈τ}: where the lanes' rotation ended,
                // over where it began.
                step[q] = ((re * c0 + im * s0) as f32, (im * c0 - re * s0) as f32);
            }
            for (wr, wi) in wr.chunks_exact_mut(LANES).zip(wi.chunks_exact_mut(LANES)) {
                let mut ar = [0f32; LANES];
                let mut ai = [0f32; LANES];
                for q in 0..n {
                    for l in 0..LANES {
                        ar[l] += amp[q] * pr[q][l];
                        ai[l] += amp[q] * pi[q][l];
                    }
                    let (c8, s8) = step[q];
                    for l in 0..LANES {
                        let nr = pr[q][l] * c8 - pi[q][l] * s8;
                        pi[q][l] = pr[q][l] * s8 + pi[q][l] * c8;
                        pr[q][l] = nr;
                    }
                }
                for l in 0..LANES {
                    let inv = g / (ar[l] * ar[l] + ai[l] * ai[l]).max(1e-20).sqrt();
                    wr[l] = ar[l] * inv;
                    wi[l] = ai[l] * inv;
                }
            }
        }
    }

    #[inline(always)]
    fn power_body(&mut self, csm: &Csm, gains: &[f32], az: f64, c: Candidate, images: bool) -> f64 {
        self.steer(gains, az, c, images);
        let padded = self.padded;
        // Σₖ Σ_{i<j} 2 Re(Rᵢⱼ wᵢ wⱼ*): the averaged frames' steered power,
        // less its diagonal, which no steering changes.
        let mut acc = [0f32; LANES];
        for (p, &(i, j)) in csm.pairs.iter().enumerate() {
            let rr = &csm.re[p * padded..(p + 1) * padded];
            let ri = &csm.im[p * padded..(p + 1) * padded];
            let (wri, wii) = (&self.wr[i * padded..(i + 1) * padded], &self.wi[i * padded..(i + 1) * padded]);
            let (wrj, wij) = (&self.wr[j * padded..(j + 1) * padded], &self.wi[j * padded..(j + 1) * padded]);
            for k0 in (0..padded).step_by(LANES) {
                for l in 0..LANES {
                    let k = k0 + l;
                    let zr = wri[k] * wrj[k] + wii[k] * wij[k];
                    let zi = wii[k] * wrj[k] - wri[k] * wij[k];
                    acc[l] += rr[k] * zr - ri[k] * zi;
                }
            }
        }
        2.0 * acc.iter().map(|&v| v as f64).sum::<f64>()
    }
}

/// The normalized autocorrelation of `window` at every lag (samples).
fn window_autocorrelation(window: &[f32]) -> Vec<f64> {
    let e: f64 = window.iter().map(|&w| (w as f64).powi(2)).sum();
    (0..window.len())
        .map(|l| {
            (0..window.len() - l).map(|n| window[n] as f64 * window[n + l] as f64).sum::<f64>() / e.max(1e-30)
        })
        .collect()
}

/// The whitened cross-spectra of every microphone pair, averaged over the
/// recent frames (exponential forgetting): `Rᵢⱼ[k] ← λ Rᵢⱼ[k] + (1 − λ) X̃ᵢ X̃ⱼ*`.
/// A fit on them is a fit on the sum of those frames' steered powers, whose
/// peak scatters far less than one frame's.
#[derive(Debug)]
pub struct Csm {
    pairs: Vec<(usize, usize)>,
    /// Bins kept (every `BIN_STRIDE`-th of the band), padded to `LANES`, and
    /// the whitened spectra's padded bins per microphone.
    padded: usize,
    kept: usize,
    source_padded: usize,
    re: Vec<f32>,
    im: Vec<f32>,
    /// The frame's kept bins per microphone (padded), gathered.
    xr: Vec<f32>,
    xi: Vec<f32>,
    keep: f32,
    /// Frames accumulated since the last reset (saturating).
    pub frames: u32,
    pub(super) arch: pulp::Arch,
}

impl Csm {
    /// For `mics` microphones and a band of `bins` bins (stored `source_padded`
    /// per microphone in the whitened spectra), forgetting `1/frames` a frame.
    pub fn new(mics: usize, bins: usize, source_padded: usize, frames: f64) -> Self {
        let pairs: Vec<(usize, usize)> = (0..mics).flat_map(|i| (i + 1..mics).map(move |j| (i, j))).collect();
        let kept = bins.div_ceil(BIN_STRIDE);
        let padded = kept.div_ceil(LANES) * LANES;
        let len = pairs.len() * padded;
        Csm {
            pairs,
            padded,
            kept,
            source_padded,
            re: vec![0.0; len],
            im: vec![0.0; len],
            xr: vec![0.0; mics * padded],
            xi: vec![0.0; mics * padded],
            keep: (1.0 - 1.0 / frames.max(1.0)) as f32,
            frames: 0,
            arch: pulp::Arch::new(),
        }
    }

    /// Adds the frame whitened in `cc`.
    pub fn accumulate(&mut self, cc: &CrossCorrelator) {
        crate::simd::run(self.arch, Accumulate { csm: self, cc });
    }

    /// Forgets every frame.
    pub fn reset(&mut self) {
        self.re.fill(0.0);
        self.im.fill(0.0);
        self.frames = 0;
    }
}

struct Accumulate<'a> {
    csm: &'a mut Csm,
    cc: &'a CrossCorrelator,
}

impl crate::simd::Kernel for Accumulate<'_> {
    type Output = ();

    #[inline(always)]
    fn run(self) {
        let Accumulate { csm, cc } = self;
        let (padded, src, keep) = (csm.padded, csm.source_padded, csm.keep);
        let fresh = 1.0 - keep;
        // The kept bins of each microphone, gathered once (their padding
        // stays zero), so that the pairs' loop runs over contiguous lanes.
        let mics = csm.xr.len() / padded;
        for m in 0..mics {
            let (sr, si) = (&cc.phat_re[m * src..(m + 1) * src], &cc.phat_im[m * src..(m + 1) * src]);
            let (xr, xi) =
                (&mut csm.xr[m * padded..(m + 1) * padded], &mut csm.xi[m * padded..(m + 1) * padded]);
            for c in 0..csm.kept {
                xr[c] = sr[c * BIN_STRIDE];
                xi[c] = si[c * BIN_STRIDE];
            }
        }
        for (p, &(i, j)) in csm.pairs.iter().enumerate() {
            let (xri, xii) = (&csm.xr[i * padded..(i + 1) * padded], &csm.xi[i * padded..(i + 1) * padded]);
            let (xrj, xij) = (&csm.xr[j * padded..(j + 1) * padded], &csm.xi[j * padded..(j + 1) * padded]);
            let rr = &mut csm.re[p * padded..(p + 1) * padded];
            let ri = &mut csm.im[p * padded..(p + 1) * padded];
            for k0 in (0..padded).step_by(LANES) {
                for l in 0..LANES {
                    let k = k0 + l;
                    rr[k] = keep * rr[k] + fresh * (xri[k] * xrj[k] + xii[k] * xij[k]);
                    ri[k] = keep * ri[k] + fresh * (xii[k] * xrj[k] - xri[k] * xij[k]);
                }
            }
        }
        csm.frames = csm.frames.saturating_add(1);
    }
}

struct Evaluate<'a> {
    fit: &'a mut FloorFit,
    csm: &'a Csm,
    gains: &'a [f32],
    az: f64,
    c: Candidate,
    images: bool,
}

impl crate::simd::Kernel for Evaluate<'_> {
    type Output = f64;

    #[inline(always)]
    fn run(self) -> f64 {
        self.fit.power_body(self.csm, self.gains, self.az, self.c, self.images)
    }
}
