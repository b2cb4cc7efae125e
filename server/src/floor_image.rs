//! What a ground robot's planar array measures: the direct path folded onto
//! the upper hemisphere and pulled toward the floor image.
//!
//! # Physics
//!
//! A planar (horizontal) array measures only the horizontal part of the
//! wavevector: for a plane wave at azimuth φ and elevation e its steered
//! response depends on u = cos e · (cos φ, sin φ). Elevations +e and −e give the
//! same u, so the array cannot tell up from down and its search keeps the upper
//! hemisphere. On a ground robot the floor reflection arrives at the same
//! azimuth from below the horizon, at elevation −eᵢ with
//!
//! ```text
//! tan e_d = (h_s − h_a)/ρ      (direct path; h_s, h_a heights above the floor, ρ horizontal range)
//! tan e_i = (h_s + h_a)/ρ      (floor image, heard mirrored at +e_i)
//! ```
//!
//! In the radial coordinate c = cos e the two arrivals sit at c_d = cos e_d and
//! c_i = cos e_i, Δc = c_d − c_i apart. The steered response power is about
//! B(c − c_d) + r² B(c − c_i): B is the array's azimuth-averaged radial beam
//! pattern, and r = R·R_d/R_i the image's amplitude relative to the direct path
//! (R the floor's pressure reflection coefficient, R_d/R_i spherical spreading).
//! The two add in power, not in amplitude: the image arrives
//! (R_i − R_d)/c ≈ 2h_s h_a/(R c) later, ≥ 0.5 ms at indoor ranges, so their cross
//! terms change sign every ≤ 2 kHz and average out over a broadband SRP.
//! Where Δc is larger than the main lobe, the peak stays on the direct path; as
//! the range grows Δc shrinks as ≈ 2h_s h_a/ρ², the lobes merge, and the peak moves
//! a fraction β(Δc, r²) of the way toward the image, up to r²/(1 + r²).
//!
//! The measurement model is then: measured direction = azimuth of the source,
//! elevation acos(c_d − β·Δc), never below the horizon. With R = 0 it is the
//! folded direct path, which is also right for a source below the array. The
//! fold cannot be undone from the DoAs alone: arrays at one height hear a
//! source below their plane exactly as its mirror image above it (up to the
//! weak floor term), and the fits start from the raw rays' intersection, so a
//! source below the arrays is placed at its mirror above them.
//!
//! The model applies to a robot whose hello declares both its microphone
//! positions and the band of its SRP (`microphone_positions_m`,
//! `srp_band_hz`): soundmap-agent does for its own localization. DoAs from
//! another process (an ODAS bridge) are taken as straight directions, since
//! how that process folds and weights is not known here.
//!
//! B is computed from the array's own microphone positions for SRP-PHAT over
//! the declared band (each frequency
//! weighted equally, as phase transform weighting does): for a pair with
//! horizontal baseline b and azimuth â, the band mean of cos(2πf·δ·(b·â)/c) has
//! the closed form [sin(2πf₂x) − sin(2πf₁x)]/(2π(f₂ − f₁)x), x = δ·(b·â)/c.
//! β is tabulated once per array shape over (Δc, r²) by maximizing the sum above.
//!
//! Worked numbers (16SoundsUSB pioneer array, 100–8000 Hz, array 0.51 m above
//! the floor, talker at 1.2 m, R = 0.8): at ρ = 2 m, e_d = 19.0° and e_i = 40.6°,
//! Δc = 0.19 and the lobes are apart (β ≈ 0.01, +0.02 m in height at the
//! source); at 4 m, Δc = 0.066, β ≈ 0.29, the peak is at 14.9° instead of 9.8°
//! (+0.37 m); at 6 m, Δc = 0.032, β ≈ 0.36, 10.9° instead of 6.5° (+0.47 m).
//! A simulated image-source room (RT60 0.5 s, 14 × 12 × 3 m) shows +0.09, +0.25,
//! +0.41 and +0.42 m at 3, 4, 5 and 6 m for a model that ignores this.
//!
//! # What the model is and is not
//!
//! It is a model of the *mechanism* the measurements show (elevations pulled up
//! by a growing fraction of the direct-to-image gap as the range grows), not a
//! derivation of SRP-PHAT in a room. Taken literally for one specular floor
//! reflection, phase-transform weighting is barely biased: with r < 1 the phase
//! at each microphone follows the direct path on average over frequency. The
//! pull seen in reverberant simulations comes from the whole vertical family of
//! early reflections (floor, ceiling and their repeats, all at the source's
//! azimuth and, folded, above the direct path) against a diffuse field, and the
//! power-sum model stands in for it. With the room's own R (≈ 0.8 for the room
//! above) it over-corrects at 3–4 m by 0.15 m, because its lobes merge earlier
//! than the simulated ones. The default `doa.floor_reflection = 0.6` was chosen
//! to under-correct at every range rather than over-correct anywhere: residual
//! height errors 0.00, +0.04, +0.15, +0.15 m at 3, 4, 5, 6 m in that room (R = 0.7:
//! −0.05, −0.05, +0.07, +0.07 m). Set it to 0 for an array that does not hear
//! the floor (high mount, absorbing floor).
//!
//! **Coherence (experimental, `doa.reverberant_pull`, off by default).** The
//! pull grows as the room's reflections take the SRP's bins over from the
//! direct path, and soundmap agents send how much of it their track's peaks
//! still point at: the PHAT coherence C (proto `TrackedDoa.coherence`). In
//! the distance sweep's room the image weight each range needed (R² = 0.37,
//! 0.42, 0.63, 0.64 at 3–6 m, RT60 0.5 s) follows `R² ≈ 0.06 ((1 − C)/C)²`
//! with the Pioneer array's C = 0.29 → 0.20, and the same law holds in that
//! room at RT60 0.25 s (C = 0.43 → 0.32), where the fixed R = 0.6
//! over-corrects by 0.11–0.18 m: with the law the mean height errors there
//! are +0.01 to +0.05 m, and at RT60 0.5 s within ±0.02 m to 5 m. But it does
//! not carry over to `paper-static`'s room: at 3 m its arrays hear C = 0.23
//! (the sweep's room: 0.29) with the *same* elevation bias (1.4°), so the
//! law over-corrects there (in-band RSE p95 0.16 → 0.38 m, height
//! −0.17 m). Coherence counts every reflection and the late field; the pull
//! comes from the early vertical ones, and how the two relate depends on the
//! room's shape and where the source stands in it. So it stays off, and
//! [`reverberant_reflection`] is there for rooms where it has been checked.
//!
//! # The ceiling
//!
//! The floor is not the only surface a planar array hears at the source's
//! azimuth: the ceiling (height H) mirrors the source to 2H − h_s, above the
//! direct path, and the floor–ceiling pairs to 2H + h_s and h_s − 2H (two
//! reflections each), −2H − h_s… (three). Every image of this vertical family
//! arrives at the same azimuth at a higher folded elevation, so each pulls the
//! same way. For broadband sources the high frequencies' narrow lobes keep the
//! ceiling image apart (it is 20–30° above the direct path at 3–6 m), but a
//! talker's band (300–3400 Hz) merges it: the pioneer array's lobe is then
//! ~0.25 wide in c, and the ceiling image sits 0.1–0.2 away in c.
//!
//! Measured in the simulator's image-source room (14 × 12 × 3 m, RT60 0.5 s,
//! the room's R ≈ 0.82, two robots at 90°, source 1.6 m high, DoAs taken as
//! straight directions), the height error of the estimate at 2, 3, 4, 5, 6 m:
//! white noise +0.02, +0.03, +0.18, +0.33, +0.41 m; band noise 300–3400 Hz
//! +0.14, +0.36, +0.69, +1.03, +1.48 m. With the ceiling raised to 12 m (and
//! the reverberation time set so that R stays 0.82) the band noise gives +0.10
//! and +0.27 m at 2 and 4 m: the ceiling, not the floor, makes most of a
//! talker's bias. The power-sum model over the vertical family (images up to
//! two reflections: floor, ceiling and the two floor–ceiling pairs; a third
//! changes the peak by less than 0.01 m at 2–6 m, weights (R^order · R_d/R_k)², peak of
//! B(c − c_d) + Σ wₖ B(c − cₖ) found by [`LobeTable::family_peak`])
//! predicts +0.01, +0.04, +0.18, +0.31, +0.42 m for the white noise at R = 0.65
//! and +0.21, +0.45, +0.68, +1.05, +1.38 m for the band noise at R = 0.82: one
//! mechanism explains both, though not with one R (the broadband pull is
//! over-predicted at the room's own R, as for the floor alone). With the
//! default R = 0.6 and the ceiling known, the residual height errors of the
//! tracked estimate are −0.05 to +0.02 m for the white noise at 2–6 m and
//! +0.04, +0.11, +0.24, +0.42 m for the band noise at 2–5 m (the floor image
//! alone: +0.47 and +0.79 m at 4 and 5 m): under-corrected, as the floor-only
//! default was chosen to be. At 6 m the band noise stays +1.0 m high and its
//! estimate wanders (RSE p95 1.9 m): there the modelled elevation changes by
//! only ~3° per metre of source height above 2 m, and two rays barely fix it.
//!
//! The ceiling height is configuration (`doa.ceiling_height_m`): a deployment
//! knows its rooms, and the simulator sets it from the scenario's room. Unset,
//! the model is the floor image alone (above). With it, a fit that tries a
//! source above the ceiling keeps the same formulas (the ceiling image then
//! passes below the source), so the measurement function stays continuous.
//!
//! # Narrow bands
//!
//! The same rooms ask for a larger R when the source is band-limited: the
//! power-sum model over the vertical family fits white noise at R ≈ 0.65 and
//! band noise (300–3400 Hz) at the room's own R ≈ 0.82 (above). The model's
//! lobes already narrow or widen with the band; what it leaves out is the
//! cross terms between the direct path and the images, which it assumes
//! average out over the band, and they do so less over a narrow one. So R
//! is taken from the band each track is heard in (its signature,
//! [`heard_band`]): `doa.floor_reflection` (0.6) for the SRP's whole band,
//! `doa.narrow_band_reflection` (0.75) at or below
//! [`NARROW_BAND_FRACTION`] of it, linear between ([`band_reflection`]).
//! Measured (BENCHMARKS.md, "Several sources" and `paper-static`; seeds 1–5,
//! against R = 0.6 for every band): the sources' heights were +0.13 to
//! +0.25 m too high in `two-talkers`, `cocktail` and `crossing`, and OSPA fell
//! from 0.206 to 0.171 m (`two-talkers`) and 0.403 to 0.370 m (`cocktail`),
//! with `crossing` unchanged (0.431 → 0.437 m); the white-noise `paper-static`
//! moved from 0.143 to 0.151 m (in-band RSE p95), since its signatures span
//! nearly the whole band. A single R of 0.7 for every band over-corrects
//! white noise (`paper-static` 0.197 m) and 0.8 more (0.308 m).
//!
//! # Elevation is resolved worse than azimuth
//!
//! A delay-based DoA's information along a tangent t of its direction is
//! ∝ tᵀCt, C the covariance of the microphones' positions. A planar array's
//! C is flat: along the horizontal tangent it has the array's horizontal
//! spread, along the vertical tangent only sin²e of it (plus cos²e of its
//! small vertical spread), e the elevation above the array's plane. Near the
//! plane the array measures elevation through cos e alone. With the reported
//! σ taken as the horizontal axis's, the vertical one is
//! σ_v = σ / √(sin²e + ρ·cos²e + 1.25·σ), ρ = var(z)/var(horizontal) of the
//! microphones ([`ArrayPattern::vertical_spread`]; 0.0036 for the 16SoundsUSB
//! Pioneer preset, 0 for flat boards), the last term the second-order limit
//! on the plane (E\[e²\] = 0.8·σ there). With σ = 1°, for the Pioneer preset:
//! σ_v = 6.3° on the plane, 4.7° at e = 8°, 2.7° at 20°, 1.4° at 45°. The reflections
//! follow the same sensitivity: an image that shifts the horizontal
//! component by δ shifts the elevation by δ / sin e. The agents' errors
//! match it (BENCHMARKS.md, "Where that error lies": 16SoundsUSB sources
//! 6–15° above the plane read +3.5 to +5.9° high at RT60 0.65 s, those
//! ≥ 17° within ±0.7°; the ReSpeaker 6's elevations +11 to +14° against an
//! azimuth error of 1.5–3°).
//!
//! `doa.planar_elevation_noise` puts this in the rays' noise
//! ([`crate::ray::Ray::vertical_excess`], [`crate::ray::Ray::angular_covariance`]:
//! the triangulation's weights and covariance and the tracker's R). It is
//! **off** by default. Measured (BENCHMARKS.md, "Elevation noise"; seeds 1–5)
//! it makes the trusted estimates of the several-source scenarios far more
//! honest (outside their 99 % ellipsoid: `cocktail` 22.5 → 11.8 %,
//! `crossing` 26.8 → 15.1 %; `crossing`'s id switches 12.2 → 4.6 per run)
//! but not more accurate: the weight of height moves to the robots that see
//! a source highest, whose elevations carry biases the model above does not
//! take out (the ReSpeaker 6's +11°, reported with the same 1° σ floor as the
//! 16-microphone arrays), and heights rise (`cocktail` +0.08 → +0.16 m,
//! OSPA 0.370 → 0.374 m, `cocktail-active` 0.347 → 0.379 m; `three-robots`,
//! seeds 1–10: RSE p95 median 0.105 → 0.154 m, mean height error +0.02 →
//! +0.06 m). With the ReSpeaker's σ floor scaled by its aperture as well,
//! `cocktail` reaches 0.321 m with honest trusted estimates, but
//! `three-robots` and `crossing` still lose. It waits for agents that report
//! a σ as honest for small arrays as for large ones.
//!
//! # The fold's two branches
//!
//! Arrays at one height fold a source above their plane and its mirror image
//! below it onto the same DoAs; only the floor term tells them apart, and
//! near the arrays' plane it does not tell them apart reliably in the
//! simulated rooms: a white-noise source 0.19 m above two arrays 2.5 m away
//! (RT60 0.5 s) and one 0.16 m below them (its mirror image) were both
//! placed 0.35–0.5 m up, on the lower side. Left to the fits, the source
//! above was placed at its mirror in 83–100 % of the estimates (height
//! 0.2–0.3 m low, trusted NEES 7–9), and a walking one 0.35 m above them
//! had its filter cross into the mirror and stay there to the end of the
//! run, 33 s (0.5–0.9 m low, NEES 100–230), while the ray pairs went back
//! above (BENCHMARKS.md, "The fold's upper branch").
//!
//! Soundmap therefore takes the **upper branch** (`doa.upper_branch`, on by
//! default) whenever every ray of a fit
//! (or every robot a filter heard within its support window) is folded and
//! their arrays lie within [`COPLANAR_M`] of one height ([`fold_plane`]): a
//! triangulation that converges below the lowest of those arrays is fitted
//! again from its mirror image above their mean height (and placed on the
//! arrays' plane when that fit slides back below), and a filter mode that an
//! update takes below it is mirrored above it (position and vertical
//! velocity, covariance alike; the data cannot object, since they are
//! symmetric up to the floor term). The cost is stated: a source truly below
//! the arrays (on the floor, under a table) is placed above them, in the
//! simulated rooms on their plane (0.16–0.31 m too high for sources 0.35
//! and 0.2 m up). Most sources a ground robot localizes (voices, devices on
//! tables and shelves, alarms) are above an array 0.3–0.6 m high. Arrays at
//! clearly different heights, or straight rays from a process that does not
//! fold (an ODAS bridge), see the two branches differently and are left to
//! the fit.
//!
//! # A robot's own floor fit
//!
//! A soundmap agent with `[pipeline.srp] floor_fit` fits the floor's image
//! into its steering model and sends direct-path elevations
//! (`ArrayDescription.direct_path_elevations`): such rays get no pull. What
//! the fit resolves sharply is the image's extra path Δ = |s′| − |s|, not
//! the range: with the array h above the floor, a source at range r and
//! elevation e has Δ = √(r² + 4hr sin e + 4h²) − r ≈ 2h sin e + 2h²/r, so
//! beyond a few metres many (e, r) pairs share one Δ (sin e + h/r nearly
//! constant) and the array's curvature and slowness barely choose among
//! them. Measured (distance sweep, 5 m, RT60 0.5 s): the fits' ranges
//! spread over 5–12 m (median 9 m) and their elevations 0–3° high (median
//! +2.2°), while the same fits read at the true range with their own Δ
//! were within −0.4 to +0.1° (10th–90th percentile).
//!
//! So each such DoA also carries the range it was fitted at
//! (`TrackedDoa.floor_fit_range_m`, ρ_f), and the model here
//! ([`FloorFold::fitted_range_m`]) predicts, for a candidate source, the
//! elevation the robot reports: its Δ from the candidate's own range and
//! height, then the elevation of a source at ρ_f with that Δ,
//! `sin e = (2Δρ_f + Δ² − 4h²)/(4hρ_f)` (exact, from (r + Δ)² = r² + 4hr sin e + 4h²),
//! with its gradient in closed form. At ρ_f equal to the candidate's range
//! it is the direct path. The coordinator's range comes from the other
//! robots' rays, so the elevation the fit could not pin down is pinned by
//! the triangulation. Measured in `BENCHMARKS.md`, "The floor's reflection,
//! fitted": with it the distance sweep's height errors are within ±0.04 m
//! at 2–6 m (the fit's own elevations alone: +0.18 m at 5 m).
//!
//! Assumptions, stated: the array is level (its plane parallel to the floor), the
//! floor is the plane `doa.base_height_m` below the robot's base frame, and the
//! floor reflects every frequency with the same R. An array is treated as
//! planar when its microphones' vertical extent is at most 10 % of their
//! horizontal extent.

use std::collections::HashMap;
use std::sync::{Mutex, OnceLock};

use nalgebra::{Matrix3, Point3, Unit, Vector3};

/// Speed of sound used for the beam pattern (m/s).
const SPEED_OF_SOUND: f64 = 343.0;
/// Azimuths the beam pattern is averaged over, in [0, π).
const AZIMUTHS: usize = 12;
/// Radial offsets of the beam pattern table: 0 to `PATTERN_MAX` in `PATTERN_STEP`.
const PATTERN_STEP: f64 = 0.002;
const PATTERN_MAX: f64 = 0.6;
/// Frequency grid of the band-integrated pattern (Hz); bands are rounded to it.
const F_STEP: f64 = 250.0;
/// Δc axis of the β table.
const DC_STEP: f64 = 0.0025;
const DC_MAX: f64 = 0.3;
/// r² axis of the β table.
const R2_STEPS: usize = 20;
/// Largest vertical extent of the microphones, relative to their horizontal extent,
/// for which an array counts as planar.
const PLANAR_RATIO: f64 = 0.1;
/// Distinct array shapes kept (a hostile client cannot grow the registry past this).
const MAX_SHAPES: usize = 32;
/// Distinct bands kept per array shape (beyond: the declared band's table).
const MAX_BANDS: usize = 64;
/// Most microphones an array may have for a table (32: 496 pairs).
const MAX_MICROPHONES: usize = 32;
/// Highest declared band edge a pattern is computed to (Hz).
const MAX_BAND_HZ: f64 = 48_000.0;

/// β(Δc, r²) for one array shape and band (see the module docs).
pub struct LobeTable {
    /// β at Δc = i·DC_STEP (rows) and r² = j/R2_STEPS (columns), row-major.
    beta: Vec<f32>,
    /// The radial pattern B(i·PATTERN_STEP), B(0) = 1.
    pattern: Vec<f64>,
    /// Half-power half-width of the radial beam pattern (in c).
    half_width: f64,
}

impl std::fmt::Debug for LobeTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LobeTable").field("half_width", &self.half_width).finish_non_exhaustive()
    }
}

impl PartialEq for LobeTable {
    fn eq(&self, other: &Self) -> bool {
        std::ptr::eq(self, other)
    }
}

impl LobeTable {
    /// The table of the array with microphones at `positions` (array frame, m)
    /// for an SRP over `band_hz`; `None` when the array is not planar, has no
    /// horizontal extent, has more than 32 microphones, or the band is not one.
    #[cfg(test)]
    pub fn for_array(positions: &[Point3<f64>], band_hz: (f64, f64)) -> Option<LobeTable> {
        let pattern = ArrayPattern::for_array(positions, band_hz)?;
        let (k1, k2) = pattern.declared;
        Some(LobeTable::from_pattern(&pattern.band_pattern(k1, k2)))
    }

    /// β over the table's grid from a radial pattern B(i·PATTERN_STEP).
    fn from_pattern(pattern: &[f64]) -> LobeTable {
        let at = |delta: f64| interpolate(pattern, delta.abs() / PATTERN_STEP);
        let half_width = (0..pattern.len())
            .find(|&i| pattern[i] < 0.5 * pattern[0])
            .map_or(PATTERN_MAX, |i| i as f64 * PATTERN_STEP);
        let rows = (DC_MAX / DC_STEP).round() as usize + 1;
        let mut beta = Vec::with_capacity(rows * (R2_STEPS + 1));
        for i in 0..rows {
            let dc = i as f64 * DC_STEP;
            for j in 0..=R2_STEPS {
                beta.push(peak_fraction(&at, dc, j as f64 / R2_STEPS as f64) as f32);
            }
        }
        LobeTable { beta, pattern: pattern.to_vec(), half_width }
    }

    /// Half-power half-width of the array's radial beam pattern, in c = cos e.
    #[cfg(test)]
    pub fn half_width(&self) -> f64 {
        self.half_width
    }

    /// β(Δc, r²): the fraction of the way from the direct path toward the image
    /// where the merged peak lies (0 when they are apart).
    pub fn beta(&self, dc: f64, r2: f64) -> f64 {
        self.beta_with_gradient(dc, r2)[0]
    }

    /// [`Self::beta`] and its partial derivatives ∂β/∂Δc and ∂β/∂r², those
    /// of the bilinear interpolant within its cell (0 where β is 0 or r² is
    /// clamped at 1).
    pub fn beta_with_gradient(&self, dc: f64, r2: f64) -> [f64; 3] {
        if !(dc > 0.0) || !(r2 > 0.0) {
            return [0.0; 3];
        }
        let x = dc / DC_STEP;
        let rows = self.beta.len() / (R2_STEPS + 1);
        if x >= (rows - 1) as f64 {
            return [0.0; 3];
        }
        let y = r2.min(1.0) * R2_STEPS as f64;
        let (i, j) = (x.floor() as usize, (y.floor() as usize).min(R2_STEPS - 1));
        let (fx, fy) = (x - i as f64, y - j as f64);
        let v = |i: usize, j: usize| f64::from(self.beta[i * (R2_STEPS + 1) + j]);
        let (v00, v01, v10, v11) = (v(i, j), v(i, j + 1), v(i + 1, j), v(i + 1, j + 1));
        let value = (1.0 - fx) * ((1.0 - fy) * v00 + fy * v01) + fx * ((1.0 - fy) * v10 + fy * v11);
        let d_dc = ((1.0 - fy) * (v10 - v00) + fy * (v11 - v01)) / DC_STEP;
        let d_r2 =
            if r2 < 1.0 { ((1.0 - fx) * (v01 - v00) + fx * (v11 - v10)) * R2_STEPS as f64 } else { 0.0 };
        [value, d_dc, d_r2]
    }

    /// B(δ), dB/dδ and d²B/dδ² by Catmull–Rom interpolation of the pattern
    /// (C¹, so that the merged peak found by [`Self::family_peak`] moves
    /// smoothly with the geometry); 0 beyond the table.
    #[inline]
    fn pattern_at(&self, delta: f64) -> [f64; 3] {
        let sign = if delta < 0.0 { -1.0 } else { 1.0 };
        let x = delta.abs() * (1.0 / PATTERN_STEP);
        // x ≥ 0: truncation is the floor.
        let i = x as usize;
        let n = self.pattern.len();
        if i + 2 >= n {
            return [0.0; 3];
        }
        let t = x - i as f64;
        // B is even: the point before δ = 0 mirrors the one after it.
        let p0 = self.pattern[if i == 0 { 1 } else { i - 1 }];
        let (p1, p2, p3) = (self.pattern[i], self.pattern[i + 1], self.pattern[i + 2]);
        let a = -0.5 * p0 + 1.5 * p1 - 1.5 * p2 + 0.5 * p3;
        let b = p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3;
        let c = 0.5 * (p2 - p0);
        let value = ((a * t + b) * t + c) * t + p1;
        let slope = ((3.0 * a * t + 2.0 * b) * t + c) * (1.0 / PATTERN_STEP);
        let curvature = (6.0 * a * t + 2.0 * b) * (1.0 / (PATTERN_STEP * PATTERN_STEP));
        [value, sign * slope, curvature]
    }

    /// The radial coordinate c of the maximum of B(c − c_d) + Σ wₖ B(c − cₖ):
    /// the peak of a direct path at `c_direct` merged with weaker arrivals at
    /// the same azimuth (`images`: (cₖ, wₖ), wₖ their power relative to the
    /// direct path). The merged peak lies within twice the main lobe's
    /// half-width of the direct path: a scan in halves of the half-width
    /// finds the strongest point there, Newton's
    /// method on the slope (kept inside the scan's bracket) places it to 1e-12.
    pub fn family_peak(&self, c_direct: f64, images: &[(f64, f64)]) -> f64 {
        self.family_peak_found(c_direct, images).0
    }

    /// [`Self::family_peak`], and how it was found.
    fn family_peak_found(&self, c_direct: f64, images: &[(f64, f64)]) -> (f64, PeakFound) {
        let power = |c: f64| {
            images
                .iter()
                .fold(self.pattern_at(c - c_direct)[0], |acc, &(ck, w)| acc + w * self.pattern_at(c - ck)[0])
        };
        // Slope and curvature in one pass.
        let slope = |c: f64| {
            let [_, g, h] = self.pattern_at(c - c_direct);
            images.iter().fold((g, h), |(g, h), &(ck, w)| {
                let [_, gk, hk] = self.pattern_at(c - ck);
                (g + w * gk, h + w * hk)
            })
        };
        // Images weaker than the direct path move its peak by less than the
        // main lobe's half-width (the power centroid of merged lobes).
        let reach = 2.0 * self.half_width;
        let lowest = images.iter().map(|&(ck, _)| ck).fold(c_direct, f64::min).max(c_direct - reach);
        let highest = images.iter().map(|&(ck, _)| ck).fold(c_direct, f64::max).min(c_direct + reach);
        // Points half the half-width apart find the peak's basin.
        let scan = self.half_width / 2.0;
        let steps = ((highest - lowest) / scan).ceil() as usize;
        if steps == 0 {
            return (c_direct, PeakFound::Direct);
        }
        let step = (highest - lowest) / steps as f64;
        let (best, _) = (0..=steps)
            .map(|k| (k, power(highest - k as f64 * step)))
            .fold((0, f64::MIN), |acc, (k, p)| if p > acc.1 { (k, p) } else { acc });
        let centre = highest - best as f64 * step;
        // Bracket: the slope is positive below the peak and negative above it.
        let (mut lo, mut hi) = ((centre - step).max(lowest), (centre + step).min(highest));
        if !(slope(lo).0 > 0.0 && slope(hi).0 < 0.0) {
            return (centre, PeakFound::Scanned);
        }
        let mut c = centre;
        for _ in 0..40 {
            let (g, h) = slope(c);
            if g > 0.0 {
                lo = c;
            } else {
                hi = c;
            }
            // Newton where it stays inside the bracket, else bisection.
            let newton = c - g / h;
            if h < 0.0 && (newton - c).abs() < 1e-13 {
                return (newton, PeakFound::Stationary);
            }
            let next = if h < 0.0 && newton > lo && newton < hi { newton } else { 0.5 * (lo + hi) };
            if (next - c).abs() < 1e-13 || hi - lo < 1e-13 {
                return (next, PeakFound::Stationary);
            }
            c = next;
        }
        (c, PeakFound::Stationary)
    }

    /// The derivatives of a stationary peak `c` of B(c − c_d) + Σ wₖ B(c − cₖ)
    /// with respect to two parameters the arrivals depend on: `d_direct` is
    /// ∂c_d, and `d_images[k]` is (∂cₖ, ∂wₖ), for each parameter. With S(c) the
    /// summed slope, S(c) = 0 at the peak, so dc = −(∂S/∂c_d dc_d + Σ ∂S/∂cₖ dcₖ
    /// + ∂S/∂wₖ dwₖ)/S′(c). `None` where the sum is not curved downward there.
    fn family_peak_gradient(
        &self,
        c: f64,
        c_direct: f64,
        images: &[(f64, f64)],
        d_direct: [f64; 2],
        d_images: &[[(f64, f64); 2]],
    ) -> Option<[f64; 2]> {
        let [_, _, hd] = self.pattern_at(c - c_direct);
        let mut curvature = hd;
        let mut num = [hd * d_direct[0], hd * d_direct[1]];
        for (&(ck, w), d) in images.iter().zip(d_images) {
            let [_, gk, hk] = self.pattern_at(c - ck);
            curvature += w * hk;
            for (n, &(dck, dwk)) in num.iter_mut().zip(d) {
                *n += w * hk * dck - gk * dwk;
            }
        }
        (curvature < 0.0).then(|| [num[0] / curvature, num[1] / curvature])
    }
}

/// How [`LobeTable::family_peak`] found its peak, which says how the peak
/// moves with the arrivals.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PeakFound {
    /// No image within reach: the direct path itself.
    Direct,
    /// A stationary point of the summed pattern (Newton's method), whose
    /// derivatives follow from the implicit function theorem
    /// ([`LobeTable::family_peak_gradient`]).
    Stationary,
    /// The scan's best point, no bracket found: no closed-form derivative.
    Scanned,
}

/// A planar array's radial SRP-PHAT pattern integrated over frequency, from
/// which the pattern of any band on the `F_STEP` grid follows, and the β
/// tables of the bands asked for so far.
pub struct ArrayPattern {
    /// G(δᵢ, f_k) = mean over pairs and azimuths of ∫₀^f_k cos(2πf·δᵢτ) df
    /// = sin(2πf_kδᵢτ)/(2πδᵢτ), row k, column i (Hz).
    g: Vec<f64>,
    n_delta: usize,
    n_f: usize,
    /// The declared band on the grid (indices into f_k).
    declared: (usize, usize),
    /// β tables by band (grid indices).
    tables: Mutex<HashMap<(usize, usize), &'static LobeTable>>,
    /// ρ = var(z) / mean horizontal var of the microphones' positions
    /// ([`ArrayPattern::vertical_spread`]).
    vertical_spread: f64,
}

impl std::fmt::Debug for ArrayPattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ArrayPattern").field("declared", &self.declared).finish_non_exhaustive()
    }
}

impl ArrayPattern {
    /// The pattern of the array with microphones at `positions` whose SRP
    /// covers `band_hz`; `None` as for `LobeTable::for_array`.
    pub fn for_array(positions: &[Point3<f64>], band_hz: (f64, f64)) -> Option<ArrayPattern> {
        let usable = (2..=MAX_MICROPHONES).contains(&positions.len())
            && band_hz.0 > 0.0
            && band_hz.1 > band_hz.0
            && band_hz.1 <= MAX_BAND_HZ;
        if !usable {
            return None;
        }
        let span = |f: fn(&Point3<f64>) -> f64| {
            let (lo, hi) =
                positions.iter().map(f).fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(v), h.max(v)));
            hi - lo
        };
        let horizontal = span(|p| p.x).max(span(|p| p.y));
        let planar = horizontal > 0.0 && horizontal.is_finite() && span(|p| p.z) <= PLANAR_RATIO * horizontal;
        if !planar {
            return None;
        }
        let k2 = ((band_hz.1 / F_STEP).round() as usize).max(1);
        let k1 = ((band_hz.0 / F_STEP).round() as usize).min(k2 - 1);
        let n_f = k2 + 1;
        let n_delta = (PATTERN_MAX / PATTERN_STEP).round() as usize + 1;
        let mut g = vec![0.0; n_f * n_delta];
        let mut count = 0usize;
        let azimuths: Vec<(f64, f64)> = (0..AZIMUTHS)
            .map(|k| {
                let a = std::f64::consts::PI * k as f64 / AZIMUTHS as f64;
                (a.cos(), a.sin())
            })
            .collect();
        let two_pi = 2.0 * std::f64::consts::PI;
        for (i, a) in positions.iter().enumerate() {
            for b in &positions[i + 1..] {
                let (bx, by) = (a.x - b.x, a.y - b.y);
                for (ca, sa) in &azimuths {
                    // Delay per unit δ (s): the pair's projection on the azimuth over c.
                    let tau = (bx * ca + by * sa) / SPEED_OF_SOUND;
                    count += 1;
                    for d in 0..n_delta {
                        let x = d as f64 * PATTERN_STEP * tau;
                        if x.abs() < 1e-12 {
                            for k in 0..n_f {
                                g[k * n_delta + d] += k as f64 * F_STEP;
                            }
                            continue;
                        }
                        // sin(2π f_k x) for k = 0, 1, … by rotation.
                        let (step_s, step_c) = (two_pi * F_STEP * x).sin_cos();
                        let (mut s, mut c) = (0.0f64, 1.0f64);
                        let scale = 1.0 / (two_pi * x);
                        for k in 0..n_f {
                            g[k * n_delta + d] += s * scale;
                            (s, c) = (s * step_c + c * step_s, c * step_c - s * step_s);
                        }
                    }
                }
            }
        }
        let norm = 1.0 / count.max(1) as f64;
        g.iter_mut().for_each(|v| *v *= norm);
        let vertical_spread = vertical_spread(positions);
        Some(ArrayPattern {
            g,
            n_delta,
            n_f,
            declared: (k1, k2),
            tables: Mutex::new(HashMap::new()),
            vertical_spread,
        })
    }

    /// ρ = var(z) / ½(var(x) + var(y)) of the microphones' positions: how
    /// much of the array's aperture is vertical (0 for a flat board; the
    /// 16SoundsUSB Pioneer preset 0.0036). It sets how poorly the array resolves
    /// elevation near its plane ([`FloorFold::vertical_spread`]).
    pub fn vertical_spread(&self) -> f64 {
        self.vertical_spread
    }

    /// B(δ) of the band [f_k1, f_k2], normalized so that B(0) = 1.
    fn band_pattern(&self, k1: usize, k2: usize) -> Vec<f64> {
        let width = (k2 - k1) as f64 * F_STEP;
        (0..self.n_delta)
            .map(|d| (self.g[k2 * self.n_delta + d] - self.g[k1 * self.n_delta + d]) / width)
            .collect()
    }

    /// The β table for a source heard over `band_hz` (None: the declared band),
    /// clipped to the declared band and rounded to the 250 Hz grid. Bands past
    /// the first 64 asked for get the declared band's table.
    pub fn lobe(&self, band_hz: Option<(f64, f64)>) -> &'static LobeTable {
        let (d1, d2) = self.declared;
        let (k1, k2) = match band_hz {
            Some((lo, hi)) if lo.is_finite() && hi.is_finite() => {
                let k2 = ((hi / F_STEP).round().max(0.0) as usize).clamp(d1 + 1, d2);
                let k1 = ((lo / F_STEP).round().max(0.0) as usize).clamp(d1, k2 - 1);
                (k1, k2)
            }
            _ => (d1, d2),
        };
        debug_assert!(k2 < self.n_f);
        let mut tables = self.tables.lock().unwrap_or_else(|e| e.into_inner());
        let key =
            if tables.contains_key(&(k1, k2)) || tables.len() < MAX_BANDS { (k1, k2) } else { (d1, d2) };
        if let Some(t) = tables.get(&key) {
            return t;
        }
        let table: &'static LobeTable =
            Box::leak(Box::new(LobeTable::from_pattern(&self.band_pattern(key.0, key.1))));
        tables.insert(key, table);
        table
    }
}

/// Linear interpolation of `table` at fractional index `x` (0 beyond the end).
fn interpolate(table: &[f64], x: f64) -> f64 {
    let i = x.floor() as usize;
    if i + 1 >= table.len() {
        return 0.0;
    }
    let f = x - i as f64;
    table[i] * (1.0 - f) + table[i + 1] * f
}

/// Where between the direct path (t = 0) and the image (t = 1), Δc apart, the
/// maximum of B(tΔc) + r²B((1 − t)Δc) lies, searched over t ∈ [0, 1] on a
/// grid and refined by a parabola through the best point and its neighbours.
fn peak_fraction(at: &impl Fn(f64) -> f64, dc: f64, r2: f64) -> f64 {
    if dc <= 0.0 || r2 <= 0.0 {
        return 0.0;
    }
    const N: usize = 200;
    let power = |t: f64| at(t * dc) + r2 * at((1.0 - t) * dc);
    let (best, _) = (0..=N)
        .map(|k| (k, power(k as f64 / N as f64)))
        .fold((0, f64::MIN), |acc, (k, p)| if p > acc.1 { (k, p) } else { acc });
    let t = best as f64 / N as f64;
    if best == 0 || best == N {
        return t;
    }
    let h = 1.0 / N as f64;
    let (pm, p0, pp) = (power(t - h), power(t), power(t + h));
    let denom = pm - 2.0 * p0 + pp;
    if denom < 0.0 { (t + 0.5 * h * (pm - pp) / denom).clamp(0.0, 1.0) } else { t }
}

/// The pattern of an array shape and declared band, computed once per distinct
/// shape and kept for the life of the process; `None` when the array is not
/// planar (or not usable), or when `MAX_SHAPES` distinct shapes are held.
pub fn array_pattern(positions: &[Point3<f64>], band_hz: (f64, f64)) -> Option<&'static ArrayPattern> {
    type Shapes = Mutex<HashMap<Vec<i64>, Option<&'static ArrayPattern>>>;
    static SHAPES: OnceLock<Shapes> = OnceLock::new();
    // Shape key: positions to 0.1 mm and the band to 1 Hz.
    let mut key: Vec<i64> =
        positions.iter().flat_map(|p| [p.x, p.y, p.z]).map(|v| (v * 1e4).round() as i64).collect();
    key.extend([band_hz.0.round() as i64, band_hz.1.round() as i64]);
    let shapes = SHAPES.get_or_init(|| Mutex::new(HashMap::new()));
    let mut shapes = shapes.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(t) = shapes.get(&key) {
        return *t;
    }
    if shapes.len() >= MAX_SHAPES {
        return None;
    }
    let pattern = ArrayPattern::for_array(positions, band_hz).map(|t| &*Box::leak(Box::new(t)));
    shapes.insert(key, pattern);
    pattern
}

/// Largest reflection coefficient [`reverberant_reflection`] returns.
pub const MAX_REFLECTION: f64 = 0.95;

/// The image weight a DoA's own coherence calls for (see the module docs,
/// "Coherence"): `R² = gain · ((1 − C)/C)²` with `C` the track's PHAT
/// coherence rescaled to the band it is heard in (`band_fraction` = heard
/// width / the SRP's width, so that a talker's empty bins do not count as
/// reverberation), capped at [`MAX_REFLECTION`]. `None` for a coherence
/// outside (0, 1] or a band fraction outside (0, 1].
pub fn reverberant_reflection(coherence: f64, band_fraction: f64, gain: f64) -> Option<f64> {
    if !(coherence > 0.0 && coherence <= 1.0 && band_fraction > 0.0 && band_fraction <= 1.0) {
        return None;
    }
    let c = (coherence / band_fraction).min(1.0);
    let x = (1.0 - c) / c;
    Some((gain.max(0.0).sqrt() * x).min(MAX_REFLECTION))
}

/// Share of the SRP's band at and below which a DoA counts as narrow-band
/// for [`band_reflection`]: a talker's 300–3400 Hz in the 100–8000 Hz band
/// soundmap agents declare is 0.39.
pub const NARROW_BAND_FRACTION: f64 = 0.4;

/// ρ = var(z) / ½(var(x) + var(y)) of `positions` (array frame); 0 when
/// they have no horizontal spread.
fn vertical_spread(positions: &[Point3<f64>]) -> f64 {
    let n = positions.len().max(1) as f64;
    let mean = positions.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let var = |k: usize| positions.iter().map(|p| (p[k] - mean[k]).powi(2)).sum::<f64>() / n;
    let horizontal = 0.5 * (var(0) + var(1));
    if horizontal > 0.0 { var(2) / horizontal } else { 0.0 }
}

/// The share of the SRP's band `srp_hz` that a track heard over `heard_hz`
/// covers, in [1e-3, 1]: 1 when the heard band is unknown (the whole band),
/// `None` for an empty SRP band.
pub fn band_share(heard_hz: Option<(f64, f64)>, (lo, hi): (f64, f64)) -> Option<f64> {
    if !(hi > lo) {
        return None;
    }
    let (h_lo, h_hi) = heard_hz.unwrap_or((lo, hi));
    Some(((h_hi.min(hi) - h_lo.max(lo)) / (hi - lo)).clamp(1e-3, 1.0))
}

/// The reflection coefficient for a DoA heard over `share` of the SRP's band
/// ([`band_share`]; see the module docs, "Narrow bands"): `broad` for the
/// whole band, `narrow` at or below [`NARROW_BAND_FRACTION`] of it, linear
/// in the share between. `broad` when the share is unknown.
pub fn band_reflection(broad: f64, narrow: f64, share: Option<f64>) -> f64 {
    let Some(share) = share else { return broad };
    let t = ((1.0 - share) / (1.0 - NARROW_BAND_FRACTION)).clamp(0.0, 1.0);
    broad + (narrow - broad) * t
}

/// The band a track is heard over, from its spectral signature: the hull of
/// the bands within `range_db` of its strongest band. `edges_hz` are the
/// hello's B + 1 band edges, `levels_db` the track's B band levels. `None`
/// when the two do not match or no level is finite.
pub fn heard_band(edges_hz: &[f64], levels_db: &[f32], range_db: f64) -> Option<(f64, f64)> {
    if edges_hz.len() != levels_db.len() + 1 || levels_db.is_empty() {
        return None;
    }
    let top = levels_db.iter().copied().filter(|v| v.is_finite()).fold(f32::MIN, f32::max);
    if top == f32::MIN {
        return None;
    }
    let floor = f64::from(top) - range_db;
    let loud = |v: &f32| v.is_finite() && f64::from(*v) >= floor;
    let first = levels_db.iter().position(loud)?;
    let last = levels_db.iter().rposition(loud)?;
    Some((edges_hz[first], edges_hz[last + 1]))
}

/// Arrays whose centres lie within this of one height share one fold plane
/// (see the module docs, "The fold's two branches") (m).
pub const COPLANAR_M: f64 = 0.1;

/// The plane that arrays at one height fold every source onto the upper side
/// of: `(lowest, mean)` height of the array centres `(z, folded)` given (map
/// frame, m; `folded`: a folded ray whose [`FloorFold::upper_branch`] is on),
/// when there is at least one, every one is folded and they lie within
/// [`COPLANAR_M`] of each other; `None` otherwise (the data then tell the
/// branches apart). An estimate below `lowest` is taken to its mirror image
/// through `mean`.
pub fn fold_plane(arrays: impl IntoIterator<Item = (f64, bool)>) -> Option<(f64, f64)> {
    let (mut lo, mut hi, mut sum, mut n) = (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0usize);
    for (z, folded) in arrays {
        if !folded || !z.is_finite() {
            return None;
        }
        (lo, hi, sum, n) = (lo.min(z), hi.max(z), sum + z, n + 1);
    }
    (n > 0 && hi - lo <= COPLANAR_M).then(|| (lo, sum / n as f64))
}

/// The measurement model of one ray from a planar array on a ground robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FloorFold {
    /// Height of the array centre above the floor (m).
    pub array_height_m: f64,
    /// The floor's pressure reflection coefficient R, in [0, 1).
    pub reflection: f64,
    /// The array's β table.
    pub lobe: &'static LobeTable,
    /// Height of the ceiling above the floor (m), when known: its image and
    /// the floor–ceiling images join the floor image (see the module docs,
    /// "The ceiling"). `None`: the floor image alone.
    pub ceiling_m: Option<f64>,
    /// ρ of the array ([`ArrayPattern::vertical_spread`]) when its DoAs'
    /// elevation noise is modelled (see the module docs, "Elevation is
    /// resolved worse than azimuth", and [`crate::ray::Ray::angular_covariance`]);
    /// `None`: the same σ on both tangent axes.
    pub vertical_spread: Option<f64>,
    /// Whether fits and filters keep a source heard by arrays at one height
    /// on the upper side of their plane (`doa.upper_branch`; see the module
    /// docs, "The fold's two branches").
    pub upper_branch: bool,
    /// The range (m) at which the robot fitted this DoA's elevation with
    /// the floor's image (proto `TrackedDoa.floor_fit_range_m`): the
    /// elevation is then read along that fit's image path at the source's
    /// range (see the module docs, "A robot's own floor fit"), and the
    /// reflection's pull is not modelled. `None`: as `reflection` says.
    pub fitted_range_m: Option<f64>,
}

/// Most reflections an image of the vertical family may have been through.
const FAMILY_ORDER: u32 = 2;
/// Images weaker than this (power relative to the direct path) are left out.
const FAMILY_MIN_WEIGHT: f64 = 1e-4;

/// Step of the forward differences where the model has no closed-form
/// derivative ([`FloorFold::measured_with_jacobian`]) (m).
const DERIVATIVE_STEP_M: f64 = 1e-5;

/// The radial coordinate c = cos e of the measured direction and, when asked,
/// its derivatives with respect to the source's horizontal range ρ and its
/// height above the array v_z.
struct Radial {
    c: f64,
    /// ∂c/∂ρ, ∂c/∂v_z.
    gradient: Option<[f64; 2]>,
}

impl FloorFold {
    /// The direction the array at `origin` measures for a source at `source`
    /// (map frame, z up): the source's azimuth, elevation acos(c_d − β·Δc) ≥ 0.
    /// `None` when the source is straight above or below the array.
    pub fn measured_direction(
        &self,
        origin: &Point3<f64>,
        source: &Point3<f64>,
    ) -> Option<Unit<Vector3<f64>>> {
        let v = source - origin;
        let rho = v.x.hypot(v.y);
        if !(rho > 1e-9) {
            return None;
        }
        let c = self.radial(rho, v.z, v.norm(), false).c.clamp(0.0, 1.0);
        let s = (1.0 - c * c).max(0.0).sqrt();
        Some(Unit::new_unchecked(Vector3::new(c * v.x / rho, c * v.y / rho, s)))
    }

    /// [`Self::measured_direction`] and its Jacobian ∂h/∂source (columns: map
    /// x, y, z; per metre) from one evaluation of the model: h depends on the
    /// source through its azimuth (in closed form) and through c(ρ, v_z),
    /// whose derivatives are those of the merged peak (the implicit function
    /// theorem at the stationary point [`LobeTable::family_peak`] finds) with
    /// the ceiling, of the direct path without a reflection, of the β
    /// table's bilinear interpolant with the floor alone
    /// ([`LobeTable::beta_with_gradient`]), and forward differences of c in ρ
    /// and v_z only where the ceiling's scan found no bracketed peak. The
    /// fits call this once per ray and iteration where forward differences
    /// in x, y and z took four evaluations.
    pub fn measured_with_jacobian(
        &self,
        origin: &Point3<f64>,
        source: &Point3<f64>,
    ) -> Option<(Unit<Vector3<f64>>, Matrix3<f64>)> {
        let v = source - origin;
        let rho = v.x.hypot(v.y);
        if !(rho > 1e-9) {
            return None;
        }
        let Radial { c: raw, gradient } = self.radial(rho, v.z, v.norm(), true);
        let [dc_rho, dc_z] = match gradient {
            Some(g) => g,
            None => {
                let at = |rho: f64, z: f64| self.radial(rho, z, rho.hypot(z), false).c;
                let step = DERIVATIVE_STEP_M;
                [(at(rho + step, v.z) - raw) / step, (at(rho, v.z + step) - raw) / step]
            }
        };
        // A clamped c does not move.
        let (c, dc_rho, dc_z) =
            if (0.0..=1.0).contains(&raw) { (raw, dc_rho, dc_z) } else { (raw.clamp(0.0, 1.0), 0.0, 0.0) };
        let s = (1.0 - c * c).max(0.0).sqrt();
        let (ux, uy) = (v.x / rho, v.y / rho);
        // ∂s/∂c = −c/s; at the zenith (s = 0) the direction no longer moves with c.
        let ds = if s > 1e-12 { -c / s } else { 0.0 };
        let rho3 = rho * rho * rho;
        let (dcx, dcy) = (dc_rho * ux, dc_rho * uy);
        let jacobian = Matrix3::new(
            dcx * ux + c * v.y * v.y / rho3,
            dcy * ux - c * v.x * v.y / rho3,
            dc_z * ux,
            dcx * uy - c * v.x * v.y / rho3,
            dcy * uy + c * v.x * v.x / rho3,
            dc_z * uy,
            ds * dcx,
            ds * dcy,
            ds * dc_z,
        );
        Some((Unit::new_unchecked(Vector3::new(c * v.x / rho, c * v.y / rho, s)), jacobian))
    }

    /// c (unclamped) for a source at horizontal range `rho` > 0, `vz` above
    /// the array and `r_direct` from it, with its gradient when `gradient` is
    /// asked and known in closed form.
    fn radial(&self, rho: f64, vz: f64, r_direct: f64, gradient: bool) -> Radial {
        let c_direct = rho / r_direct;
        let r3 = r_direct * r_direct * r_direct;
        let d_direct = [vz * vz / r3, -rho * vz / r3];
        let h_a = self.array_height_m;
        let h_s = h_a + vz;
        // A fit may try a source above the ceiling: the images' formulas go on
        // (the ceiling image then passes below the source), so the model stays
        // continuous there instead of switching to the floor image alone.
        let ceiling = self.ceiling_m.filter(|&h| h > h_a);
        if let Some(fitted) = self.fitted_range_m.filter(|&r| r > 0.0 && h_a > 0.0) {
            // The robot's fit: the floor image's extra path Δ for this
            // source, read back as the elevation of a source at the fitted
            // range with the same Δ (module docs, "A robot's own floor fit").
            let image = (r_direct * r_direct + 4.0 * h_a * vz + 4.0 * h_a * h_a).max(0.0).sqrt();
            let path = image - r_direct;
            let raw = (2.0 * path * fitted + path * path - 4.0 * h_a * h_a) / (4.0 * h_a * fitted);
            let sin_e = raw.clamp(-1.0, 1.0);
            let c = (1.0 - sin_e * sin_e).sqrt();
            let gradient = gradient.then(|| {
                if raw.abs() >= 1.0 || c < 1e-12 || image < 1e-12 {
                    return [0.0, 0.0];
                }
                // ∂c/∂Δ = −(sin e/c)·(ρ_f + Δ)/(2h ρ_f); ∂Δ/∂ρ and ∂Δ/∂v_z.
                let dc_dpath = -sin_e / c * (fitted + path) / (2.0 * h_a * fitted);
                let d_rho = rho / image - rho / r_direct;
                let d_z = (vz + 2.0 * h_a) / image - vz / r_direct;
                [dc_dpath * d_rho, dc_dpath * d_z]
            });
            return Radial { c, gradient };
        }
        if !(h_a > 0.0 && h_s > 0.0 && self.reflection > 0.0) {
            return Radial { c: c_direct, gradient: gradient.then_some(d_direct) };
        }
        let Some(ceiling) = ceiling else {
            // The floor image alone: c = c_d − β(Δc, r²)·Δc, with Δc = c_d − cᵢ,
            // cᵢ = ρ/rᵢ, rᵢ² = ρ² + (v_z + 2h_a)², r² = R²·r_d²/rᵢ².
            let dz = h_s + h_a;
            let r_image = rho.hypot(dz);
            let c_image = rho / r_image;
            let r = self.reflection * r_direct / r_image;
            let dc = c_direct - c_image;
            let r2 = r * r;
            let [beta, beta_dc, beta_r2] = self.lobe.beta_with_gradient(dc, r2);
            let c = c_direct - beta * dc;
            let gradient = gradient.then(|| {
                let ri3 = r_image * r_image * r_image;
                let (rd2, ri2) = (r_direct * r_direct, r_image * r_image);
                let d_image = [dz * dz / ri3, -rho * dz / ri3];
                let d_r2 = [r2 * (2.0 * rho / rd2 - 2.0 * rho / ri2), r2 * (2.0 * vz / rd2 - 2.0 * dz / ri2)];
                std::array::from_fn(|k| {
                    let d_dc = d_direct[k] - d_image[k];
                    d_direct[k] - (beta_dc * d_dc + beta_r2 * d_r2[k]) * dc - beta * d_dc
                })
            });
            return Radial { c, gradient };
        };
        // Images of the source in the floor (z = 0) and the ceiling (z = H):
        // at 2nH + h_s after 2|n| reflections and 2nH − h_s after |2n − 1|,
        // heard at the source's azimuth with |z − h_a| above or below the array.
        let mut images = [(0.0, 0.0); 8];
        // Per image: ∂/∂ρ and ∂/∂v_z of (cₖ, wₖ).
        let mut d_images = [[(0.0, 0.0); 2]; 8];
        let mut count = 0;
        for n in -2i32..=2 {
            let base = 2.0 * f64::from(n) * ceiling;
            for (z, order, sign) in
                [(base + h_s, 2 * n.unsigned_abs(), 1.0), (base - h_s, (2 * n - 1).unsigned_abs(), -1.0)]
            {
                if order == 0 || order > FAMILY_ORDER {
                    continue;
                }
                let dz = z - h_a;
                let r_image = rho.hypot(dz);
                let amplitude = self.reflection.powi(order as i32) * r_direct / r_image;
                let (c_image, weight) = (rho / r_image, amplitude * amplitude);
                if weight >= FAMILY_MIN_WEIGHT && count < images.len() {
                    images[count] = (c_image, weight);
                    if gradient {
                        // cₖ = ρ/rₖ, wₖ ∝ r_d²/rₖ², rₖ² = ρ² + dzₖ², ∂dzₖ/∂v_z = ±1.
                        let ri3 = r_image * r_image * r_image;
                        let (rd2, ri2) = (r_direct * r_direct, r_image * r_image);
                        d_images[count] = [
                            (dz * dz / ri3, weight * (2.0 * rho / rd2 - 2.0 * rho / ri2)),
                            (-rho * dz * sign / ri3, weight * (2.0 * vz / rd2 - 2.0 * dz * sign / ri2)),
                        ];
                    }
                    count += 1;
                }
            }
        }
        let images = &images[..count];
        let (c, found) = self.lobe.family_peak_found(c_direct, images);
        let gradient = match (gradient, found) {
            (false, _) | (true, PeakFound::Scanned) => None,
            (true, PeakFound::Stationary) => {
                self.lobe.family_peak_gradient(c, c_direct, images, d_direct, &d_images[..count])
            }
            (true, PeakFound::Direct) => Some(d_direct),
        };
        Radial { c, gradient }
    }
}

/// For other modules' tests: what a level three-microphone array (0.1 m
/// arms, no vertical spread) 0.5 m above the floor measures, with the
/// floor's `reflection` and the elevation model's `vertical_spread`.
#[cfg(test)]
pub(crate) fn three_mic_fold(reflection: f64, vertical_spread: Option<f64>) -> FloorFold {
    let positions = [Point3::new(0.1, 0.0, 0.0), Point3::new(-0.1, 0.0, 0.0), Point3::new(0.0, 0.1, 0.0)];
    let pattern = ArrayPattern::for_array(&positions, (100.0, 8000.0)).expect("planar");
    FloorFold {
        array_height_m: 0.5,
        reflection,
        lobe: pattern.lobe(None),
        ceiling_m: None,
        vertical_spread,
        upper_branch: true,
        fitted_range_m: None,
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn arrays_at_one_height_share_a_fold_plane() {
        use super::fold_plane;
        assert_eq!(fold_plane([(0.5, true), (0.52, true)]), Some((0.5, 0.51)));
        assert_eq!(fold_plane([(0.5, true), (0.58, true), (0.55, true)]).map(|p| p.0), Some(0.5));
        // Heights 0.4 m apart, a straight ray among folded ones, or nothing:
        // the data see the branches differently.
        assert_eq!(fold_plane([(0.5, true), (0.9, true)]), None);
        assert_eq!(fold_plane([(0.5, true), (0.5, false)]), None);
        assert_eq!(fold_plane([(f64::NAN, true)]), None);
        assert_eq!(fold_plane(std::iter::empty()), None);
    }

    #[test]
    fn reflection_goes_from_broad_to_narrow_with_the_heard_share_of_the_band() {
        use super::{band_reflection, band_share};
        let srp = (62.5, 7937.5);
        let r = |heard: Option<(f64, f64)>, srp: Option<(f64, f64)>| {
            band_reflection(0.6, 0.75, srp.and_then(|b| band_share(heard, b)))
        };
        assert_eq!(r(Some((62.5, 7937.5)), Some(srp)), 0.6);
        assert_eq!(r(None, Some(srp)), 0.6);
        assert_eq!(r(Some((300.0, 3400.0)), None), 0.6);
        // A talker's band (39 % of the SRP's) and narrower: the narrow value.
        assert!((r(Some((300.0, 3400.0)), Some(srp)) - 0.75).abs() < 1e-12);
        assert!((r(Some((500.0, 1000.0)), Some(srp)) - 0.75).abs() < 1e-12);
        // Halfway in share: halfway in R.
        let half = r(Some((62.5, 62.5 + 0.7 * 7875.0)), Some(srp));
        assert!((half - 0.675).abs() < 1e-9, "{half}");
        // A band outside the SRP's counts as nothing heard in it.
        assert!((r(Some((9000.0, 12000.0)), Some(srp)) - 0.75).abs() < 1e-12);
        // An empty SRP band: no share, the broad value.
        assert_eq!(band_share(Some((300.0, 3400.0)), (8000.0, 8000.0)), None);
    }

    use super::*;

    /// The 16SoundsUSB pioneer array (two rectangular rings, see the agent's presets).
    fn sixteen() -> Vec<Point3<f64>> {
        let corners = [
            (1.0, -1.0),
            (1.0, 0.0),
            (1.0, 1.0),
            (0.0, 1.0),
            (-1.0, 1.0),
            (-1.0, 0.0),
            (-1.0, -1.0),
            (0.0, -1.0),
        ];
        let mut out = vec![];
        for (dx, dy, z) in [(0.191, 0.245, -0.0075), (0.332, 0.36, 0.0075)] {
            for (sx, sy) in corners {
                out.push(Point3::new(sx * dx * 0.5, sy * dy * 0.5, z));
            }
        }
        out
    }

    #[test]
    fn vertical_spread_is_the_share_of_aperture_out_of_the_plane() {
        let pattern = ArrayPattern::for_array(&sixteen(), (100.0, 8000.0)).unwrap();
        assert!((pattern.vertical_spread() - 0.003568).abs() < 1e-5, "{}", pattern.vertical_spread());
        let flat: Vec<Point3<f64>> = sixteen().iter().map(|p| Point3::new(p.x, p.y, 0.0)).collect();
        assert_eq!(ArrayPattern::for_array(&flat, (100.0, 8000.0)).unwrap().vertical_spread(), 0.0);
    }

    #[test]
    fn non_planar_arrays_have_no_table() {
        let mut tall = sixteen();
        tall[0].z = 0.2;
        assert!(LobeTable::for_array(&tall, (100.0, 8000.0)).is_none());
        assert!(LobeTable::for_array(&sixteen()[..1], (100.0, 8000.0)).is_none());
        assert!(LobeTable::for_array(&sixteen(), (100.0, f64::NAN)).is_none());
    }

    #[test]
    fn merged_lobes_pull_the_peak_toward_the_image_and_apart_lobes_do_not() {
        let t = LobeTable::for_array(&sixteen(), (100.0, 8000.0)).unwrap();
        // Far apart: the peak stays on the direct path.
        assert!(t.beta(0.3, 0.64) < 0.02, "{}", t.beta(0.3, 0.64));
        // Nearly together: the power centroid r²/(1 + r²).
        let b = t.beta(0.005, 0.64);
        assert!((b - 0.64 / 1.64).abs() < 0.03, "{b}");
        // Monotone in r² and no image, no pull.
        assert!(t.beta(0.04, 0.3) < t.beta(0.04, 0.8));
        assert_eq!(t.beta(0.04, 0.0), 0.0);
        assert!(t.half_width() > 0.02 && t.half_width() < 0.2, "{}", t.half_width());
    }

    #[test]
    fn a_narrower_band_merges_sooner_and_bands_are_cached() {
        let pattern = array_pattern(&sixteen(), (100.0, 8000.0)).unwrap();
        let broad = pattern.lobe(None);
        let talker = pattern.lobe(Some((300.0, 3400.0)));
        // Wider lobes at low frequencies: at a gap where the broadband lobes are
        // still apart, the band-limited ones have merged.
        assert!(
            talker.beta(0.1, 0.4) > broad.beta(0.1, 0.4) + 0.1,
            "{} {}",
            talker.beta(0.1, 0.4),
            broad.beta(0.1, 0.4)
        );
        assert!(talker.half_width() > broad.half_width());
        // The same band (after rounding to the grid) is the same table; a band
        // outside the declared one is clipped to it.
        assert!(std::ptr::eq(talker, pattern.lobe(Some((310.0, 3390.0)))));
        assert!(std::ptr::eq(broad, pattern.lobe(Some((10.0, 20_000.0)))));
        assert!(std::ptr::eq(broad, pattern.lobe(Some((f64::NAN, 3000.0)))));
    }

    #[test]
    fn heard_band_is_the_hull_of_the_loud_bands() {
        let edges = [100.0, 200.0, 400.0, 800.0, 1600.0, 3200.0, 6400.0];
        assert_eq!(heard_band(&edges, &[-60.0, -20.0, -5.0, 0.0, -12.0, -45.0], 20.0), Some((200.0, 3200.0)));
        assert_eq!(heard_band(&edges, &[0.0; 6], 20.0), Some((100.0, 6400.0)));
        assert_eq!(heard_band(&edges, &[0.0; 5], 20.0), None);
        assert_eq!(heard_band(&edges, &[f32::NAN; 6], 20.0), None);
    }

    #[test]
    fn model_matches_the_worked_numbers() {
        let lobe = array_pattern(&sixteen(), (100.0, 8000.0)).unwrap().lobe(None);
        let fold = FloorFold {
            array_height_m: 0.5125,
            reflection: 0.8,
            lobe,
            ceiling_m: None,
            vertical_spread: None,
            upper_branch: true,
            fitted_range_m: None,
        };
        let origin = Point3::new(0.0, 0.0, 0.5125);
        let bias = |rho: f64| {
            let src = Point3::new(rho, 0.0, 1.2);
            let d = fold.measured_direction(&origin, &src).unwrap();
            let e = d.z.asin();
            rho * e.tan() - (1.2 - 0.5125)
        };
        assert!(bias(2.0) < 0.05, "{}", bias(2.0));
        assert!((bias(4.0) - 0.37).abs() < 0.05, "{}", bias(4.0));
        assert!((bias(6.0) - 0.47).abs() < 0.05, "{}", bias(6.0));
        // No reflection: the folded direct path, also for a source below the array.
        let dry = FloorFold { reflection: 0.0, ..fold };
        let low = Point3::new(3.0, 4.0, 0.1);
        let d = dry.measured_direction(&origin, &low).unwrap();
        let v = (low - origin).normalize();
        assert!((d.x - v.x).abs() < 1e-12 && (d.y - v.y).abs() < 1e-12 && (d.z + v.z).abs() < 1e-12);
        assert!(dry.measured_direction(&origin, &Point3::new(0.0, 0.0, 2.0)).is_none());
    }

    /// Height error at the source (m) of what `fold` measures for a source
    /// `rho` m away at height `h_s` (the array at the fold's height).
    fn height_bias(fold: &FloorFold, rho: f64, h_s: f64) -> f64 {
        let origin = Point3::new(0.0, 0.0, fold.array_height_m);
        let d = fold.measured_direction(&origin, &Point3::new(rho, 0.0, h_s)).unwrap();
        rho * d.z.asin().tan() - (h_s - fold.array_height_m)
    }

    #[test]
    fn one_image_gives_the_same_peak_either_way() {
        let lobe = array_pattern(&sixteen(), (100.0, 8000.0)).unwrap().lobe(Some((300.0, 3400.0)));
        assert_eq!(lobe.family_peak(0.97, &[]), 0.97);
        for (dc, r2) in [(0.02, 0.3), (0.06, 0.36), (0.1, 0.5), (0.2, 0.2)] {
            let c = lobe.family_peak(0.97, &[(0.97 - dc, r2)]);
            let table = 0.97 - lobe.beta(dc, r2) * dc;
            assert!((c - table).abs() < 0.003, "Δc {dc}, r² {r2}: {c} vs {table}");
        }
    }

    #[test]
    fn the_ceiling_pulls_a_talker_up_more_than_the_floor_alone() {
        let lobe = array_pattern(&sixteen(), (100.0, 8000.0)).unwrap().lobe(Some((300.0, 3400.0)));
        let floor = FloorFold {
            array_height_m: 0.51,
            reflection: 0.6,
            lobe,
            ceiling_m: None,
            vertical_spread: None,
            upper_branch: true,
            fitted_range_m: None,
        };
        let room = FloorFold { ceiling_m: Some(3.0), ..floor };
        // A ceiling far away changes nothing that matters.
        let far = FloorFold { ceiling_m: Some(60.0), ..floor };
        for rho in [2.0, 4.0, 6.0] {
            let (a, b) = (height_bias(&floor, rho, 1.6), height_bias(&far, rho, 1.6));
            assert!((a - b).abs() < 0.02, "{rho} m: {a} vs {b}");
        }
        // A 3 m ceiling: the talker 1.1 m above the array is heard 0.4 m higher at
        // 4 m and 0.6 m at 5 m (the simulated room: +0.69 and +1.03 m), where the
        // floor alone explains 0.2–0.3 m.
        let (at4, at5) = (height_bias(&room, 4.0, 1.6), height_bias(&room, 5.0, 1.6));
        assert!((0.3..0.5).contains(&at4), "{at4}");
        assert!((0.5..0.75).contains(&at5), "{at5}");
        assert!(at5 > height_bias(&floor, 5.0, 1.6) + 0.2);
        // Continuous through the ceiling, where a fit may wander.
        let below =
            room.measured_direction(&Point3::new(0.0, 0.0, 0.51), &Point3::new(5.0, 0.0, 2.999)).unwrap();
        let above =
            room.measured_direction(&Point3::new(0.0, 0.0, 0.51), &Point3::new(5.0, 0.0, 3.001)).unwrap();
        assert!((below.into_inner() - above.into_inner()).norm() < 1e-3);
        // Smooth, with a bounded Jacobian, for the fits.
        let origin = Point3::new(0.0, 0.0, 0.51);
        let src = Point3::new(4.0, 1.0, 1.6);
        let (_, jacobian) = room.measured_with_jacobian(&origin, &src).unwrap();
        for d in jacobian.column_iter() {
            assert!(d.iter().all(|v| v.is_finite()) && d.norm() < 1.0, "{d:?}");
        }
        let dz = jacobian.column(2);
        assert!(dz.z > 0.0, "a higher source is heard higher: {dz:?}");
    }

    #[test]
    fn the_jacobian_in_closed_form_matches_central_differences() {
        let sixteen = array_pattern(&sixteen(), (100.0, 8000.0)).unwrap();
        let floor = FloorFold {
            array_height_m: 0.51,
            reflection: 0.6,
            lobe: sixteen.lobe(None),
            ceiling_m: None,
            vertical_spread: None,
            upper_branch: true,
            fitted_range_m: None,
        };
        let talker = FloorFold { lobe: sixteen.lobe(Some((300.0, 3400.0))), ..floor };
        let folds = [
            FloorFold { reflection: 0.0, ..floor },
            floor,
            FloorFold { ceiling_m: Some(3.0), ..floor },
            FloorFold { ceiling_m: Some(3.0), ..talker },
            FloorFold { ceiling_m: Some(2.5), reflection: 0.8, ..talker },
            FloorFold { fitted_range_m: Some(9.0), ..floor },
        ];
        let origin = Point3::new(0.3, -0.2, 0.51);
        let mut checked = 0;
        for (f, fold) in folds.iter().enumerate() {
            for &(x, y, z) in &[
                (1.5, 0.4, 1.2),
                (-2.5, 1.0, 1.7),
                (3.0, -2.0, 0.8),
                (4.5, 2.5, 1.6),
                (-1.0, -6.0, 2.2),
                (7.0, 0.5, 1.1),
                (2.0, 2.0, 0.3),
            ] {
                let src = Point3::new(x, y, z);
                let (at, jacobian) = fold.measured_with_jacobian(&origin, &src).unwrap();
                assert_eq!(at, fold.measured_direction(&origin, &src).unwrap(), "fold {f} at {src}");
                let h = 1e-6;
                for k in 0..3 {
                    let mut step = Vector3::zeros();
                    step[k] = h;
                    let up = fold.measured_direction(&origin, &(src + step)).unwrap().into_inner();
                    let down = fold.measured_direction(&origin, &(src - step)).unwrap().into_inner();
                    let central = (up - down) / (2.0 * h);
                    let column = jacobian.column(k).into_owned();
                    let tolerance = 1e-5;
                    assert!(
                        (column - central).norm() <= tolerance * (1.0 + central.norm()),
                        "fold {f} at {src}, axis {k}: {column:?} vs {central:?}"
                    );
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 6 * 7 * 3);
    }

    #[test]
    fn a_robots_floor_fit_is_read_at_the_sources_range() {
        let fit = |range: f64| FloorFold { fitted_range_m: Some(range), ..three_mic_fold(0.6, None) };
        let origin = Point3::new(0.0, 0.0, 0.5);
        let source = Point3::new(3.0, 4.0, 1.2);
        let r = (source - origin).norm();
        let direct = (source - origin).normalize();
        // Fitted at the source's own range: the direct path, whatever R says.
        let at = fit(r).measured_direction(&origin, &source).unwrap();
        assert!((at.into_inner() - direct).norm() < 1e-12, "{at:?}");
        // Fitted 12 m away (the range poorly resolved): the elevation a
        // source 12 m away with the same floor-image path has, higher.
        let far = fit(12.0).measured_direction(&origin, &source).unwrap();
        let h = 0.5;
        let path = (r * r + 4.0 * h * 0.7 + 4.0 * h * h).sqrt() - r;
        let rf = 12.0;
        let image_path = |sin_e: f64| (rf * rf + 4.0 * h * rf * sin_e + 4.0 * h * h).sqrt() - rf;
        assert!((image_path(far.z) - path).abs() < 1e-12, "{} against {path}", image_path(far.z));
        assert!(far.z > direct.z + 0.02, "{far:?}");
        // Same azimuth; farther fits sit higher (sin e + h/ρ ≈ constant).
        assert!((far.y.atan2(far.x) - direct.y.atan2(direct.x)).abs() < 1e-12);
        assert!(((far.z + h / rf) - (direct.z + h / r)).abs() < 0.01, "{far:?}");
        // Without a fitted range, the pull as before.
        let pulled = three_mic_fold(0.6, None).measured_direction(&origin, &source).unwrap();
        assert_ne!(pulled, at);
    }

    #[test]
    fn coherence_sets_the_reflection_within_bounds() {
        // x = (1 − C)/C; R = √gain · x, capped.
        let r = reverberant_reflection(0.25, 1.0, 0.06).unwrap();
        assert!((r - 0.06f64.sqrt() * 3.0).abs() < 1e-12, "{r}");
        // A talker heard over 40 % of the band: its coherence is rescaled first.
        let talker = reverberant_reflection(0.1, 0.4, 0.06).unwrap();
        assert!((talker - r).abs() < 1e-12, "{talker}");
        assert_eq!(reverberant_reflection(1.0, 1.0, 0.06), Some(0.0));
        assert_eq!(reverberant_reflection(0.01, 1.0, 0.06), Some(MAX_REFLECTION));
        for (c, f) in [(0.0, 1.0), (-0.1, 1.0), (1.2, 1.0), (f64::NAN, 1.0), (0.3, 0.0), (0.3, 1.5)] {
            assert_eq!(reverberant_reflection(c, f, 0.06), None, "{c} {f}");
        }
    }
}
