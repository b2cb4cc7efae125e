//! Sub-grid refinement: Newton ascent of the exact steered response power.
//!
//! SRP-PHAT over all pairs equals the power of the PHAT-weighted
//! delay-and-sum beamformer minus a constant:
//! `Σₖ |Bₖ(d)|² = Σₖ Σᵢ gᵢ² |X̃ᵢ[k]|² + 2 Σ_{i<j} gᵢgⱼ Σₖ Re(X̃ᵢ X̃ⱼ* e^{jωₖ(pᵢ−pⱼ)·d/c})`
//! with `Bₖ(d) = Σᵢ gᵢ X̃ᵢ[k] e^{−jωₖ pᵢ·d/c}` (`gᵢ` the directivity gains).
//! Evaluating `B` costs microphones × bins instead of pairs × bins, and its
//! first and second derivatives along the tangent plane come in the same
//! pass, so the peak is found to the precision of the data, not of a grid and
//! not of an interpolation of the correlations.
//!
//! Tangent coordinates `(u, v)` at `d` with basis `(e₁, e₂)`:
//! `d(u, v) ≈ d(1 − (u²+v²)/2) + u e₁ + v e₂`, radians.
//!
//! **Near field.** A source at range `ρ` sends a spherical wavefront: the
//! arrival at microphone `pᵢ` leads the array centre's by
//! `aᵢ = (ρ − |ρd − pᵢ|)/c = (1 − Sᵢ)/(κc)`, `Sᵢ = √(1 − 2κ pᵢ·d + κ²|pᵢ|²)`,
//! with `κ = 1/ρ` (the plane wave, `aᵢ = pᵢ·d/c`, is `κ = 0`). Across a
//! 0.49 m array the curvature is not negligible for a robot: its phase error
//! reaches ~0.9 rad at 8 kHz for a source 5 m away, and a plane-wave fit
//! trades it for elevation. For the 16SoundsUSB (Pioneer) layout, a
//! noise-free source 5 m away at 6.8° elevation peaks 1.34° *low* in a
//! plane-wave search (0.3° at 2.7 m, 16°), the same direction as the bias of
//! the "no reflections" rooms in `tests/tests/hearing_reverb.rs`. So with
//! `near_field` on, κ is a third coordinate of the ascent (as `t = κ R/2`,
//! `R` the microphones' RMS radius, so that a unit of `t` moves the delays
//! about as much as a radian of direction), bounded to `0 ≤ κ ≤ 1/ρ_min`.
//! Derivatives: `∂a/∂u = (pᵢ·e₁)/(Sᵢc)`, `∂a/∂κ = ((pᵢ·d − κ|pᵢ|²)/(κSᵢ) −
//! (1 − Sᵢ)/κ²)/c` (`−(|pᵢ|² − (pᵢ·d)²)/(2c)` at κ = 0). The Hessian keeps
//! the `ω²` products of first derivatives and the plane-wave curvature term,
//! and drops the second derivatives of `a` in κ and the κ-dependent part of
//! those in direction: they are ~`κc/ω` (a few %) of what is kept, and the
//! ascent checks every step against the power anyway.
//!
//! The inner loops run over bins in chunks of `LANES` (8) with fixed-size
//! arrays so that they vectorize.

use nalgebra::{Unit, Vector3};

use super::phat::CrossCorrelator;
use crate::array::SearchRegion;

/// Bins processed together in the inner loops.
const LANES: usize = 8;
/// Accumulators per bin: Σ Y, Σ aY, Σ bY, Σ cY, Σ b²Y, Σ bcY, Σ c²Y, and
/// with the range, Σ kY, Σ bkY, Σ ckY, Σ k²Y (complex; `k = ∂a/∂t`).
const ACCS: usize = 11;
/// A Newton step shorter than this is taken without checking and ends the
/// refinement (radians, 0.03°): near the peak Newton converges quadratically,
/// so what remains after it is far below the data's noise.
const STEP_TOLERANCE: f64 = 5e-4;

/// Value, gradient and Hessian of `Σₖ |Bₖ|²` in tangent coordinates (and
/// the scaled inverse range `t` when the range is refined; its entries are
/// 0 otherwise).
#[derive(Clone, Copy, Debug, Default)]
pub struct Local {
    /// `Σₖ |Bₖ|²`.
    pub power: f64,
    /// ∂/∂(u, v, t).
    pub grad: [f64; 3],
    /// ∂²/∂(u, v, t)² (symmetric: `[uu, uv, vv, ut, vt, tt]`).
    pub hess: [f64; 6],
    /// The diffuse field's expected power subtracted from `power` (0 unless
    /// the refiner's `diffuse_weight` is set).
    pub diffuse: f64,
}

/// The wavefront a refinement assumes: plane, or spherical with its inverse
/// range refined within `0..=max_inverse_range_per_m`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Wavefront {
    /// Far field: `aᵢ = pᵢ·d/c`.
    Plane,
    /// Near field: κ = 1/ρ is refined with the direction.
    Spherical {
        /// Largest κ (1/m): the nearest range considered.
        max_inverse_range_per_m: f64,
    },
}

/// The phasors of one microphone at the band's first `LANES` bins (moved
/// on by `LANES` bins at a time) and the step that moves them.
#[derive(Clone, Copy, Debug, Default)]
struct Phasors {
    pr: [f32; LANES],
    pi: [f32; LANES],
    c8: f32,
    s8: f32,
}

/// One microphone's part of an evaluation: its phasors and the weights of
/// its `Y` in each accumulator (see [`Refiner::bin_sums`]).
#[derive(Clone, Copy, Debug)]
struct MicTerms {
    mic: usize,
    phasors: Phasors,
    w: [f32; ACCS],
}

/// Beamformer-domain Newton refinement.
#[derive(Debug)]
pub struct Refiner {
    /// Microphone positions, m, and their squared norms.
    positions: Vec<Vector3<f64>>,
    norms2: Vec<f64>,
    /// `t = κ · range_scale` (m): R/2, R the RMS radius of the microphones.
    range_scale: f64,
    inv_c: f64,
    /// Bin spacing, rad/s, and index of the first band bin.
    domega: f64,
    first_bin: usize,
    bins: usize,
    padded: usize,
    /// ωₖ and ωₖ² per bin (rad/s), padded with zeros.
    omega: Vec<f32>,
    omega2: Vec<f32>,
    /// Scratch for the projection: the beamformer `B`, re and im.
    sums: Vec<f32>,
    /// Scratch: one microphone's Y = X̃·phasor, re and im.
    yr: Vec<f32>,
    yi: Vec<f32>,
    /// Scratch: phasors of every microphone (for the projection).
    ph: Vec<f32>,
    /// Scratch: each microphone's terms of an evaluation.
    terms: Vec<MicTerms>,
    /// Beamformer evaluations since the counter was last read.
    pub(super) evaluations: usize,
    /// The diffuse field's part of the power, and how much of it each
    /// evaluation subtracts (0: none; see [`Local::diffuse`]).
    diffuse: Option<super::diffuse::DiffusePower>,
    pub(super) diffuse_weight: f64,
    /// The CPU's vector instructions (see [`crate::simd`]).
    pub(super) arch: pulp::Arch,
}

impl Refiner {
    /// `positions` in metres (array frame), `speed_of_sound` in m/s; the band
    /// starts at bin `lo` of an FFT of `frame_len` at `fs` Hz and has `bins` bins.
    pub fn new(
        positions: &[Vector3<f64>],
        speed_of_sound: f64,
        fs: f64,
        frame_len: usize,
        lo: usize,
        bins: usize,
    ) -> Self {
        let domega = 2.0 * std::f64::consts::PI * fs / frame_len as f64;
        let padded = bins.div_ceil(LANES) * LANES;
        let omega: Vec<f32> =
            (0..padded).map(|k| if k < bins { (domega * (lo + k) as f64) as f32 } else { 0.0 }).collect();
        let rms =
            (positions.iter().map(|p| p.norm_squared()).sum::<f64>() / positions.len().max(1) as f64).sqrt();
        Refiner {
            positions: positions.to_vec(),
            norms2: positions.iter().map(|p| p.norm_squared()).collect(),
            range_scale: (0.5 * rms).max(1e-3),
            inv_c: 1.0 / speed_of_sound,
            domega,
            first_bin: lo,
            bins,
            padded,
            omega2: omega.iter().map(|w| w * w).collect(),
            omega,
            sums: vec![0.0; 2 * padded],
            yr: vec![0.0; padded],
            yi: vec![0.0; padded],
            ph: vec![0.0; 2 * positions.len() * padded],
            terms: Vec::with_capacity(positions.len()),
            evaluations: 0,
            diffuse: None,
            diffuse_weight: 0.0,
            arch: pulp::Arch::new(),
        }
    }

    /// Tabulates the diffuse field's power (see [`super::diffuse::DiffusePower`])
    /// so that `diffuse_weight` can subtract it.
    pub fn with_diffuse_power(mut self) -> Self {
        let c = 1.0 / self.inv_c;
        let power =
            super::diffuse::DiffusePower::new(&self.positions, self.domega, self.first_bin, self.bins, c);
        self.diffuse = Some(power);
        self
    }

    /// The phasors `e^{−jωₖ a}` of the band's first `LANES` bins and the
    /// `LANES`-bin step that moves them on (one `sin_cos`: the start and the
    /// step are powers of `e^{−jΔω a}`).
    #[inline(always)]
    fn phasors(&self, a: f64) -> Phasors {
        let (s1, c1) = (-self.domega * a).sin_cos();
        let cmul = |(ar, ai): (f64, f64), (br, bi): (f64, f64)| (ar * br - ai * bi, ar * bi + ai * br);
        let mut c0s0 = (1.0, 0.0);
        for _ in 0..self.first_bin {
            c0s0 = cmul(c0s0, (c1, s1));
        }
        let (c0, s0) = c0s0;
        let sq2 = cmul((c1, s1), (c1, s1));
        let sq4 = cmul(sq2, sq2);
        let (c8, s8) = cmul(sq4, sq4);
        let mut pr = [0f32; LANES];
        let mut pi = [0f32; LANES];
        let (mut r, mut m) = (c0, s0);
        for l in 0..LANES {
            pr[l] = r as f32;
            pi[l] = m as f32;
            (r, m) = (r * c1 - m * s1, r * s1 + m * c1);
        }
        Phasors { pr, pi, c8: c8 as f32, s8: s8 as f32 }
    }

    /// Writes `Y[k] = X̃ᵢ[k] e^{−jωₖ a}` of microphone `i` to `yr`/`yi`, and
    /// its phasors to `ph` (for the projection; an evaluation steers in
    /// [`Self::bin_sums`]).
    #[inline(always)]
    fn steer(&mut self, cc: &CrossCorrelator, i: usize, a: f64) {
        let (k, padded) = (self.bins, self.padded);
        let Phasors { mut pr, mut pi, c8, s8 } = self.phasors(a);
        let xr = &cc.phat_re[i * padded..(i + 1) * padded];
        let xi = &cc.phat_im[i * padded..(i + 1) * padded];
        let (phr, phi) = self.ph[2 * i * padded..2 * (i + 1) * padded].split_at_mut(padded);
        for (((((yr, yi), xr), xi), phr), phi) in self
            .yr
            .chunks_exact_mut(LANES)
            .zip(self.yi.chunks_exact_mut(LANES))
            .zip(xr.chunks_exact(LANES))
            .zip(xi.chunks_exact(LANES))
            .zip(phr.chunks_exact_mut(LANES))
            .zip(phi.chunks_exact_mut(LANES))
        {
            for l in 0..LANES {
                yr[l] = xr[l] * pr[l] - xi[l] * pi[l];
                yi[l] = xr[l] * pi[l] + xi[l] * pr[l];
                phr[l] = pr[l];
                phi[l] = pi[l];
                let nr = pr[l] * c8 - pi[l] * s8;
                pi[l] = pr[l] * s8 + pi[l] * c8;
                pr[l] = nr;
            }
        }
        debug_assert!(k <= padded);
    }

    /// The delay terms of microphone `i` at direction `d` (tangent basis
    /// `e1`, `e2`) and scaled inverse range `t` (0: plane wave), seconds:
    /// the lead `a`, `∂a/∂u`, `∂a/∂v`, `∂a/∂t` and the curvature weight `x`
    /// (`∂²a/∂u² ≈ ∂²a/∂v² ≈ −x` in the sphere's tangent coordinates).
    fn delay_terms(
        &self,
        i: usize,
        d: &Vector3<f64>,
        e1: &Vector3<f64>,
        e2: &Vector3<f64>,
        t: f64,
    ) -> [f64; 5] {
        let p = &self.positions[i];
        let (x, b, c) = (p.dot(d), p.dot(e1), p.dot(e2));
        let kappa = t / self.range_scale;
        let ic = self.inv_c;
        if kappa < 1e-6 {
            let dk = -0.5 * (self.norms2[i] - x * x);
            return [x * ic, b * ic, c * ic, dk * ic / self.range_scale, x * ic];
        }
        let s = (1.0 - 2.0 * kappa * x + kappa * kappa * self.norms2[i]).max(1e-12).sqrt();
        let a = (1.0 - s) / kappa;
        let dk = (x - kappa * self.norms2[i]) / (kappa * s) - a / kappa;
        [a * ic, b * ic / s, c * ic / s, dk * ic / self.range_scale, x * ic / s]
    }

    /// Power, gradient and Hessian at `at.d` in the basis `(at.e1, at.e2)`,
    /// with microphone gains `gains` (all 1 for omnidirectional microphones),
    /// for a wavefront at scaled inverse range `at.t` (see the module docs);
    /// with `at.with_range` the derivatives in `t` are computed too.
    ///
    /// With `at.curvature = false` the coordinates are linear, `d + u e₁ + v e₂`
    /// (used for planar arrays, whose delays only see the in-plane part of `d`).
    ///
    /// With a `diffuse_weight` w > 0, `w·D` (the diffuse field's expected
    /// part, see [`super::diffuse::DiffusePower`]) is subtracted from the
    /// power and its derivatives, and kept in [`Local::diffuse`].
    pub fn local(&mut self, cc: &CrossCorrelator, gains: &[f32], at: At<'_>) -> Local {
        let (d, e1, e2, curvature) = (at.d, at.e1, at.e2, at.curvature);
        let mut local = crate::simd::run(self.arch, Evaluate { refiner: self, cc, gains, at });
        let w = self.diffuse_weight;
        if let Some(diffuse) = self.diffuse.as_ref().filter(|_| w > 0.0) {
            let dl = diffuse.local(d, e1, e2, curvature, gains);
            local.diffuse = w * dl.value;
            local.power -= local.diffuse;
            local.grad[0] -= w * dl.grad[0];
            local.grad[1] -= w * dl.grad[1];
            local.hess[0] -= w * dl.hess[0];
            local.hess[1] -= w * dl.hess[1];
            local.hess[2] -= w * dl.hess[2];
        }
        local
    }

    #[inline(always)]
    fn local_body(&mut self, cc: &CrossCorrelator, gains: &[f32], at: At<'_>) -> Local {
        let At { d, e1, e2, curvature, t, with_range } = at;
        self.evaluations += 1;
        let mut terms = std::mem::take(&mut self.terms);
        terms.clear();
        for (i, &g) in gains.iter().enumerate().take(self.positions.len()) {
            if g == 0.0 {
                continue;
            }
            let [a, b, c, k, x] = self.delay_terms(i, d, e1, e2, t);
            let (b, c, k) = (b as f32, c as f32, k as f32);
            let ac = if curvature { x as f32 } else { 0.0 };
            let w = [
                g,
                g * ac,
                g * b,
                g * c,
                g * b * b,
                g * b * c,
                g * c * c,
                g * k,
                g * b * k,
                g * c * k,
                g * k * k,
            ];
            terms.push(MicTerms { mic: i, phasors: self.phasors(a), w });
        }
        let v = match (curvature, with_range) {
            (false, false) => self.bin_sums::<false, false>(cc, &mut terms),
            (true, false) => self.bin_sums::<true, false>(cc, &mut terms),
            (false, true) => self.bin_sums::<false, true>(cc, &mut terms),
            (true, true) => self.bin_sums::<true, true>(cc, &mut terms),
        };
        self.terms = terms;
        Local {
            power: v[0],
            grad: [2.0 * v[1], 2.0 * v[2], 2.0 * v[6]],
            hess: [2.0 * v[3], 2.0 * v[4], 2.0 * v[5], 2.0 * v[7], 2.0 * v[8], 2.0 * v[9]],
            diffuse: 0.0,
        }
    }

    /// The beamformer's sums and the power's derivatives, one chunk of
    /// `LANES` bins at a time: per chunk, every microphone's
    /// `Yᵢ = X̃ᵢ·e^{−jωₖaᵢ}` is weighed into the accumulators (Σ Y, Σ aY,
    /// Σ bY, Σ cY, Σ b²Y, Σ bcY, Σ c²Y, and with `RANGE` Σ kY, Σ bkY, Σ ckY,
    /// Σ k²Y; `CURV` keeps Σ aY, which linear coordinates leave at 0), which
    /// stay in registers, and then folded into the lanes' sums
    /// `[Σ|B|², Σ Re B*B_u, Σ Re B*B_v, ½P_uu, ½P_uv, ½P_vv]`, with `RANGE`
    /// `[Σ Re B*B_t, ½P_ut, ½P_vt, ½P_tt]` (0 without). `terms` (one per
    /// microphone with a gain) have their phasors moved on chunk by chunk.
    #[inline(always)]
    fn bin_sums<const CURV: bool, const RANGE: bool>(
        &self,
        cc: &CrossCorrelator,
        terms: &mut [MicTerms],
    ) -> [f64; 10] {
        let padded = self.padded;
        let mut acc = [[0f32; LANES]; 10];
        let used = |a: usize| (a != 1 || CURV) && (a < 7 || RANGE);
        for base in (0..padded).step_by(LANES) {
            let mut sr = [[0f32; LANES]; ACCS];
            let mut si = [[0f32; LANES]; ACCS];
            for term in terms.iter_mut() {
                let at = term.mic * padded + base;
                let xr = &cc.phat_re[at..at + LANES];
                let xi = &cc.phat_im[at..at + LANES];
                let Phasors { pr, pi, c8, s8 } = &mut term.phasors;
                let mut yr = [0f32; LANES];
                let mut yi = [0f32; LANES];
                for l in 0..LANES {
                    yr[l] = xr[l] * pr[l] - xi[l] * pi[l];
                    yi[l] = xr[l] * pi[l] + xi[l] * pr[l];
                    let nr = pr[l] * *c8 - pi[l] * *s8;
                    pi[l] = pr[l] * *s8 + pi[l] * *c8;
                    pr[l] = nr;
                }
                for a in (0..ACCS).filter(|&a| used(a)) {
                    let wt = term.w[a];
                    for l in 0..LANES {
                        sr[a][l] += wt * yr[l];
                        si[a][l] += wt * yi[l];
                    }
                }
            }
            for l in 0..LANES {
                let k = base + l;
                let (om, om2) = (self.omega[k], self.omega2[k]);
                let (br, bi) = (sr[0][l], si[0][l]);
                let (sa_r, sa_i, sb_r, sb_i, sc_r, sc_i) =
                    (sr[1][l], si[1][l], sr[2][l], si[2][l], sr[3][l], si[3][l]);
                // B_u = −jω Σ bY, B_v = −jω Σ cY
                let (bur, bui) = (om * sb_i, -om * sb_r);
                let (bvr, bvi) = (om * sc_i, -om * sc_r);
                // B_uu = −ω² Σ b²Y + jω Σ aY, B_vv likewise, B_uv = −ω² Σ bcY
                let (buur, buui) = (-om2 * sr[4][l] - om * sa_i, -om2 * si[4][l] + om * sa_r);
                let (bvvr, bvvi) = (-om2 * sr[6][l] - om * sa_i, -om2 * si[6][l] + om * sa_r);
                let (buvr, buvi) = (-om2 * sr[5][l], -om2 * si[5][l]);
                acc[0][l] += br * br + bi * bi;
                acc[1][l] += br * bur + bi * bui;
                acc[2][l] += br * bvr + bi * bvi;
                acc[3][l] += bur * bur + bui * bui + br * buur + bi * buui;
                acc[4][l] += bur * bvr + bui * bvi + br * buvr + bi * buvi;
                acc[5][l] += bvr * bvr + bvi * bvi + br * bvvr + bi * bvvi;
                if RANGE {
                    // B_t = −jω Σ kY; B_ut = −ω² Σ bkY, B_vt = −ω² Σ ckY, B_tt = −ω² Σ k²Y
                    let (btr, bti) = (om * si[7][l], -om * sr[7][l]);
                    let (butr, buti) = (-om2 * sr[8][l], -om2 * si[8][l]);
                    let (bvtr, bvti) = (-om2 * sr[9][l], -om2 * si[9][l]);
                    let (bttr, btti) = (-om2 * sr[10][l], -om2 * si[10][l]);
                    acc[6][l] += br * btr + bi * bti;
                    acc[7][l] += bur * btr + bui * bti + br * butr + bi * buti;
                    acc[8][l] += bvr * btr + bvi * bti + br * bvtr + bi * bvti;
                    acc[9][l] += btr * btr + bti * bti + br * bttr + bi * btti;
                }
            }
        }
        acc.map(|a| a.iter().map(|&v| v as f64).sum::<f64>())
    }

    /// The scaled inverse range `t` bounds of a wavefront: `None` for a plane wave.
    fn range_bound(&self, wavefront: Wavefront) -> Option<f64> {
        match wavefront {
            Wavefront::Plane => None,
            Wavefront::Spherical { max_inverse_range_per_m } => {
                Some(max_inverse_range_per_m * self.range_scale)
            }
        }
    }

    /// Newton ascent from `d0`: at most `iterations` steps, each at most
    /// `max_step_rad`, backtracking when the power drops, stopping once a
    /// step is below 1e-4 rad. Returns the refined direction, the inverse
    /// range κ (1/m, 0 for a plane wave) and the power.
    ///
    /// Every iterate is kept inside `region` (projected ascent): a source
    /// near the edge of a hemisphere is not pulled onto its mirror image.
    #[allow(clippy::too_many_arguments)]
    pub fn refine(
        &mut self,
        cc: &CrossCorrelator,
        d0: Unit<Vector3<f64>>,
        gains: &[f32],
        iterations: usize,
        max_step_rad: f64,
        region: &SearchRegion,
        wavefront: Wavefront,
    ) -> (Unit<Vector3<f64>>, f64, Local) {
        let bound = self.range_bound(wavefront);
        let apply = |d: &Unit<Vector3<f64>>, step: [f64; 2]| {
            let (e1, e2) = tangent_basis(d);
            region.clamp(exp_map(d, &e1, &e2, step))
        };
        let evaluate = |this: &mut Self, d: &Unit<Vector3<f64>>, t: f64, with_range: bool| {
            let (e1, e2) = tangent_basis(d);
            this.local(cc, gains, At { d, e1: &e1, e2: &e2, curvature: true, t, with_range })
        };
        let (d, t, cur) = self.ascend(d0, bound, iterations, max_step_rad, apply, evaluate);
        (d, t / self.range_scale, cur)
    }

    /// Newton ascent for a planar array with unit normal `n`: the delays only
    /// depend on the in-plane part `h` of the direction, so the search runs
    /// on `h` (linear coordinates, no grazing-angle degeneracy) and the
    /// direction is `h + n·s·√(1 − |h|²)` on the side `s` of `d0`; `|h| > 1`
    /// is pulled back onto the horizon of the plane. `max_step` bounds `|Δh|`.
    /// Returns the direction, the inverse range κ (1/m) and the power.
    #[allow(clippy::too_many_arguments)]
    pub fn refine_planar(
        &mut self,
        cc: &CrossCorrelator,
        d0: Unit<Vector3<f64>>,
        n: &Unit<Vector3<f64>>,
        gains: &[f32],
        iterations: usize,
        max_step: f64,
        wavefront: Wavefront,
    ) -> (Unit<Vector3<f64>>, f64, Local) {
        let bound = self.range_bound(wavefront);
        let (e1, e2) = tangent_basis(n);
        let side = if n.dot(&d0) >= 0.0 { 1.0 } else { -1.0 };
        let lift = |h: [f64; 2]| -> Unit<Vector3<f64>> {
            let r = norm([h[0], h[1], 0.0]);
            let h = if r > 1.0 { [h[0] / r, h[1] / r] } else { h };
            let up = (1.0 - h[0] * h[0] - h[1] * h[1]).max(0.0).sqrt();
            Unit::new_normalize(e1 * h[0] + e2 * h[1] + n.into_inner() * (side * up))
        };
        let apply = |h: &[f64; 2], step: [f64; 2]| [h[0] + step[0], h[1] + step[1]];
        let evaluate = |this: &mut Self, h: &[f64; 2], t: f64, with_range: bool| {
            this.local(cc, gains, At { d: &lift(*h), e1: &e1, e2: &e2, curvature: false, t, with_range })
        };
        let h0 = [e1.dot(&d0), e2.dot(&d0)];
        let (h, t, cur) = self.ascend(h0, bound, iterations, max_step, apply, evaluate);
        (lift(h), t / self.range_scale, cur)
    }

    /// The ascent of [`Self::refine`] and [`Self::refine_planar`] over a
    /// state `S` (a direction, or an in-plane vector): `apply` moves a state by
    /// a (u, v) step, `evaluate` gives the power and its derivatives at a
    /// state and scaled inverse range `t`. The plane-wave peak first, then the
    /// range from there when `bound` is set: a range that the array cannot
    /// resolve (small aperture, far source) leaves the plane-wave peak as it
    /// is. Returns the state, `t` and the last evaluation.
    fn ascend<S: Copy>(
        &mut self,
        mut state: S,
        bound: Option<f64>,
        iterations: usize,
        max_step: f64,
        apply: impl Fn(&S, [f64; 2]) -> S,
        mut evaluate: impl FnMut(&mut Self, &S, f64, bool) -> Local,
    ) -> (S, f64, Local) {
        let mut t = 0.0;
        let mut cur = Local::default();
        for phase in std::iter::once(None).chain(bound.map(Some)) {
            let with_range = phase.is_some();
            cur = evaluate(self, &state, t, with_range);
            for _ in 0..iterations {
                let mut step = newton_step(&cur, max_step, t, phase);
                if norm(step) < STEP_TOLERANCE {
                    // Taken unchecked (see STEP_TOLERANCE); the returned
                    // power is that of the last evaluated point.
                    state = apply(&state, [step[0], step[1]]);
                    t += step[2];
                    break;
                }
                let mut accepted = false;
                for _ in 0..4 {
                    let cand = apply(&state, [step[0], step[1]]);
                    let next = evaluate(self, &cand, t + step[2], with_range);
                    if next.power >= cur.power {
                        (state, cur) = (cand, next);
                        t += step[2];
                        accepted = true;
                        break;
                    }
                    step = [0.5 * step[0], 0.5 * step[1], 0.5 * step[2]];
                }
                if !accepted {
                    break;
                }
            }
        }
        (state, t, cur)
    }

    /// Removes the wave from `d` at inverse range `inverse_range_per_m` (0:
    /// a plane wave) from the whitened spectra: per bin, the projection of
    /// `X̃` on the steering vector `vᵢ = gᵢ e^{jωₖaᵢ}` is subtracted
    /// (`X̃ ← X̃ − v (vᴴX̃)/|v|²`), so that a later refinement or coherence
    /// does not see that source's sidelobes.
    pub fn project_out(
        &mut self,
        cc: &mut CrossCorrelator,
        d: &Vector3<f64>,
        inverse_range_per_m: f64,
        gains: &[f32],
    ) {
        let padded = self.padded;
        let norm2: f32 = gains.iter().map(|g| g * g).sum();
        if norm2 <= 0.0 {
            return;
        }
        let t = inverse_range_per_m * self.range_scale;
        let (e1, e2) = tangent_basis(d);
        // B (into sums[0]) and every microphone's phasors (into ph).
        self.sums[..2 * padded].fill(0.0);
        for i in 0..self.positions.len() {
            let a = self.delay_terms(i, d, &e1, &e2, t)[0];
            self.steer(cc, i, a);
            let g = gains[i];
            let (re, im) = self.sums[..2 * padded].split_at_mut(padded);
            for ((r, m), (&yr, &yi)) in re.iter_mut().zip(im.iter_mut()).zip(self.yr.iter().zip(&self.yi)) {
                *r += g * yr;
                *m += g * yi;
            }
        }
        let (br, bi) = self.sums[..2 * padded].split_at(padded);
        for i in 0..self.positions.len() {
            let g = gains[i] / norm2;
            let (phr, phi) = self.ph[2 * i * padded..2 * (i + 1) * padded].split_at(padded);
            let xr = &mut cc.phat_re[i * padded..(i + 1) * padded];
            let xi = &mut cc.phat_im[i * padded..(i + 1) * padded];
            let mut energy = 0.0f32;
            for k in 0..padded {
                // v_i = g_i conj(ph_i); X̃ −= v · B / |v|²
                let (pr, pi) = (phr[k], -phi[k]);
                xr[k] -= g * (pr * br[k] - pi * bi[k]);
                xi[k] -= g * (pr * bi[k] + pi * br[k]);
                energy += xr[k] * xr[k] + xi[k] * xi[k];
            }
            cc.phat_energy[i] = energy;
        }
    }
}

/// Where [`Refiner::local`] evaluates: direction `d`, tangent basis
/// `(e1, e2)`, curved (sphere) or linear (plane) coordinates, scaled inverse
/// range `t`, and whether the derivatives in `t` are wanted.
#[derive(Clone, Copy, Debug)]
pub struct At<'a> {
    /// The direction.
    pub d: &'a Vector3<f64>,
    /// First tangent axis.
    pub e1: &'a Vector3<f64>,
    /// Second tangent axis.
    pub e2: &'a Vector3<f64>,
    /// Tangent coordinates on the sphere (`false`: linear, `d + u e₁ + v e₂`).
    pub curvature: bool,
    /// Scaled inverse range.
    pub t: f64,
    /// Derivatives in `t` too.
    pub with_range: bool,
}

/// [`Refiner::local`] as a vectorized kernel.
struct Evaluate<'a> {
    refiner: &'a mut Refiner,
    cc: &'a CrossCorrelator,
    gains: &'a [f32],
    at: At<'a>,
}

impl crate::simd::Kernel for Evaluate<'_> {
    type Output = Local;

    #[inline(always)]
    fn run(self) -> Local {
        self.refiner.local_body(self.cc, self.gains, self.at)
    }
}

fn norm([u, v, t]: [f64; 3]) -> f64 {
    (u * u + v * v + t * t).sqrt()
}

/// Ascent step on `local`, at most `max_step` long: along each eigenvector
/// of the Hessian, the Newton step where the power is concave, and a step of
/// half `max_step` up the gradient where it is not (at a saddle, e.g. between
/// a source and its mirror image near the plane of a flat array).
///
/// With a range (`bound` = largest `t`, current `t`), the step is in
/// (u, v, t); if it would leave `0 ≤ t ≤ bound`, `t` stops at the bound and
/// the direction takes the Newton step with `t` held.
fn newton_step(local: &Local, max_step: f64, t: f64, bound: Option<f64>) -> [f64; 3] {
    let [a, b, c, at, bt, tt] = local.hess;
    if let Some(t_max) = bound {
        let h = nalgebra::Matrix3::new(a, b, at, b, c, bt, at, bt, tt);
        let g = nalgebra::Vector3::new(local.grad[0], local.grad[1], local.grad[2]);
        let step = ascent(h.symmetric_eigen(), &g, max_step);
        let to = t + step[2];
        if (0.0..=t_max).contains(&to) {
            return [step[0], step[1], step[2]];
        }
        let held = newton_step(local, max_step, t, None);
        return [held[0], held[1], to.clamp(0.0, t_max) - t];
    }
    let g = nalgebra::Vector2::new(local.grad[0], local.grad[1]);
    let step = ascent(nalgebra::Matrix2::new(a, b, b, c).symmetric_eigen(), &g, max_step);
    [step[0], step[1], 0.0]
}

/// The bounded eigen-ascent step of [`newton_step`] in any dimension.
fn ascent<D>(
    eig: nalgebra::linalg::SymmetricEigen<f64, D>,
    g: &nalgebra::OVector<f64, D>,
    max_step: f64,
) -> nalgebra::OVector<f64, D>
where
    D: nalgebra::Dim,
    nalgebra::DefaultAllocator: nalgebra::allocator::Allocator<D, D> + nalgebra::allocator::Allocator<D>,
{
    let scale = eig.eigenvalues.abs().max().max(1e-30);
    let mut step = nalgebra::OVector::<f64, D>::zeros_generic(g.shape_generic().0, nalgebra::Const::<1>);
    for i in 0..g.len() {
        let (lambda, v) = (eig.eigenvalues[i], eig.eigenvectors.column(i).into_owned());
        let gv = g.dot(&v);
        if lambda < -1e-9 * scale {
            step += v * (-gv / lambda);
        } else if gv.abs() > 0.0 {
            step += v * (0.5 * max_step * gv.signum());
        }
    }
    let len = step.norm();
    if len > max_step { step * (max_step / len) } else { step }
}

/// An orthonormal basis `(e₁, e₂)` of the tangent plane at `d`, right-handed
/// with `d` (`e₁ × e₂ = d`).
pub fn tangent_basis(d: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let reference = if d.z.abs() < 0.9 { Vector3::z() } else { Vector3::x() };
    let e1 = reference.cross(d).normalize();
    let e2 = d.cross(&e1);
    (e1, e2)
}

/// The unit vector reached from `d` by the tangent step `u e₁ + v e₂` along a great circle.
pub fn exp_map(
    d: &Vector3<f64>,
    e1: &Vector3<f64>,
    e2: &Vector3<f64>,
    [u, v]: [f64; 2],
) -> Unit<Vector3<f64>> {
    let t = e1 * u + e2 * v;
    let angle = t.norm();
    if angle < 1e-15 {
        return Unit::new_normalize(*d);
    }
    Unit::new_normalize(d * angle.cos() + t * (angle.sin() / angle))
}
