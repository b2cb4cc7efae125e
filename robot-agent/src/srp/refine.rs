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

use nalgebra::{Unit, Vector3};

use super::phat::CrossCorrelator;

const LANES: usize = 8;

/// Value, gradient and Hessian of `Σₖ |Bₖ|²` in tangent coordinates.
#[derive(Clone, Copy, Debug, Default)]
pub struct Local {
    /// `Σₖ |Bₖ|²`.
    pub power: f64,
    /// ∂/∂(u, v).
    pub grad: [f64; 2],
    /// ∂²/∂(u, v)² (symmetric: `[uu, uv, vv]`).
    pub hess: [f64; 3],
}

/// Beamformer-domain Newton refinement.
#[derive(Debug)]
pub struct Refiner {
    /// Microphone positions divided by the speed of sound, seconds per unit direction.
    delays: Vec<Vector3<f64>>,
    /// Angular frequency of the first band bin and bin spacing, rad/s.
    omega0: f64,
    domega: f64,
    bins: usize,
    /// Per-bin sums over microphones: 7 complex accumulators, `[acc][re/im][bin]`.
    sums: Vec<f32>,
}

/// Accumulators (index into `sums`): Σ Y, Σ aY, Σ bY, Σ cY, Σ b²Y, Σ bcY, Σ c²Y.
const ACCS: usize = 7;

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
        Refiner {
            delays: positions.iter().map(|p| p / speed_of_sound).collect(),
            omega0: domega * lo as f64,
            domega,
            bins,
            sums: vec![0.0; ACCS * 2 * padded],
        }
    }

    /// Power, gradient and Hessian at `d` in the basis `(e1, e2)`, with
    /// microphone gains `gains` (all 1 for omnidirectional microphones).
    ///
    /// With `curvature = false` the coordinates are linear, `d + u e₁ + v e₂`
    /// (used for planar arrays, whose delays only see the in-plane part of `d`).
    pub fn local(
        &mut self,
        cc: &CrossCorrelator,
        d: &Vector3<f64>,
        e1: &Vector3<f64>,
        e2: &Vector3<f64>,
        gains: &[f32],
        curvature: bool,
    ) -> Local {
        let k = self.bins;
        let padded = k.div_ceil(LANES) * LANES;
        self.sums.fill(0.0);
        for (i, q) in self.delays.iter().enumerate() {
            let g = gains[i];
            if g == 0.0 {
                continue;
            }
            let (a, b, c) = (q.dot(d), q.dot(e1), q.dot(e2));
            let (af, bf, cf) = (a as f32, b as f32, c as f32);
            let ac = if curvature { af } else { 0.0 };
            let w = [g, g * ac, g * bf, g * cf, g * bf * bf, g * bf * cf, g * cf * cf];
            // Phasor e^{−jωₖ a} for the 8 lanes of a chunk, advanced by 8 bins per chunk.
            let (s0, c0) = (-self.omega0 * a).sin_cos();
            let (s1, c1) = (-self.domega * a).sin_cos();
            let (s8, c8) = (-self.domega * a * LANES as f64).sin_cos();
            let mut pr = [0f32; LANES];
            let mut pi = [0f32; LANES];
            let (mut r, mut m) = (c0, s0);
            for l in 0..LANES {
                pr[l] = r as f32;
                pi[l] = m as f32;
                (r, m) = (r * c1 - m * s1, r * s1 + m * c1);
            }
            let (c8, s8) = (c8 as f32, s8 as f32);
            let xr = &cc.phat_re[i * k..(i + 1) * k];
            let xi = &cc.phat_im[i * k..(i + 1) * k];
            for chunk in 0..padded / LANES {
                let base = chunk * LANES;
                let mut yr = [0f32; LANES];
                let mut yi = [0f32; LANES];
                for l in 0..LANES {
                    let kk = base + l;
                    let (x_r, x_i) = if kk < k { (xr[kk], xi[kk]) } else { (0.0, 0.0) };
                    yr[l] = x_r * pr[l] - x_i * pi[l];
                    yi[l] = x_r * pi[l] + x_i * pr[l];
                    let nr = pr[l] * c8 - pi[l] * s8;
                    pi[l] = pr[l] * s8 + pi[l] * c8;
                    pr[l] = nr;
                }
                for (acc, &wt) in w.iter().enumerate() {
                    let off = acc * 2 * padded + base;
                    let (re, rest) = self.sums[off..].split_at_mut(padded);
                    for l in 0..LANES {
                        re[l] += wt * yr[l];
                        rest[l] += wt * yi[l];
                    }
                }
            }
        }
        let mut out = Local::default();
        let s = |acc: usize, kk: usize| -> (f64, f64) {
            let off = acc * 2 * padded;
            (self.sums[off + kk] as f64, self.sums[off + padded + kk] as f64)
        };
        for kk in 0..k {
            let om = self.omega0 + self.domega * kk as f64;
            let om2 = om * om;
            let b = s(0, kk);
            let sa = s(1, kk);
            let sb = s(2, kk);
            let sc = s(3, kk);
            let sbb = s(4, kk);
            let sbc = s(5, kk);
            let scc = s(6, kk);
            // B_u = −jω Σ bY, B_v = −jω Σ cY
            let bu = (om * sb.1, -om * sb.0);
            let bv = (om * sc.1, -om * sc.0);
            // B_uu = −ω² Σ b²Y + jω Σ aY, B_vv likewise, B_uv = −ω² Σ bcY
            let buu = (-om2 * sbb.0 - om * sa.1, -om2 * sbb.1 + om * sa.0);
            let bvv = (-om2 * scc.0 - om * sa.1, -om2 * scc.1 + om * sa.0);
            let buv = (-om2 * sbc.0, -om2 * sbc.1);
            let re = |x: (f64, f64), y: (f64, f64)| x.0 * y.0 + x.1 * y.1; // Re(x* y)
            out.power += re(b, b);
            out.grad[0] += 2.0 * re(b, bu);
            out.grad[1] += 2.0 * re(b, bv);
            out.hess[0] += 2.0 * (re(bu, bu) + re(b, buu));
            out.hess[1] += 2.0 * (re(bu, bv) + re(b, buv));
            out.hess[2] += 2.0 * (re(bv, bv) + re(b, bvv));
        }
        out
    }

    /// Newton ascent from `d0`: at most `iterations` steps, each at most
    /// `max_step_rad`, backtracking when the power drops. Returns the refined
    /// direction and the power there.
    pub fn refine(
        &mut self,
        cc: &CrossCorrelator,
        d0: Unit<Vector3<f64>>,
        gains: &[f32],
        iterations: usize,
        max_step_rad: f64,
    ) -> (Unit<Vector3<f64>>, Local) {
        let mut d = d0;
        let (mut e1, mut e2) = tangent_basis(&d);
        let mut cur = self.local(cc, &d, &e1, &e2, gains, true);
        for _ in 0..iterations {
            let mut step = newton_step(&cur, max_step_rad);
            let mut accepted = false;
            for _ in 0..4 {
                let cand = exp_map(&d, &e1, &e2, step);
                let (c1, c2) = tangent_basis(&cand);
                let next = self.local(cc, &cand, &c1, &c2, gains, true);
                if next.power >= cur.power {
                    (d, e1, e2, cur) = (cand, c1, c2, next);
                    accepted = true;
                    break;
                }
                step = [0.5 * step[0], 0.5 * step[1]];
            }
            let len = (step[0] * step[0] + step[1] * step[1]).sqrt();
            if !accepted || len < 2e-5 {
                break;
            }
        }
        (d, cur)
    }
}

impl Refiner {
    /// Newton ascent for a planar array with unit normal `n`: the delays only
    /// depend on the in-plane part `h` of the direction, so the search runs
    /// on `h` (linear coordinates, no grazing-angle degeneracy) and the
    /// direction is `h + n·s·√(1 − |h|²)` on the side `s` of `d0`; `|h| > 1`
    /// is pulled back onto the horizon of the plane. `max_step` bounds `|Δh|`.
    pub fn refine_planar(
        &mut self,
        cc: &CrossCorrelator,
        d0: Unit<Vector3<f64>>,
        n: &Unit<Vector3<f64>>,
        gains: &[f32],
        iterations: usize,
        max_step: f64,
    ) -> (Unit<Vector3<f64>>, Local) {
        let (e1, e2) = tangent_basis(n);
        let side = if n.dot(&d0) >= 0.0 { 1.0 } else { -1.0 };
        let lift = |h: [f64; 2]| -> Unit<Vector3<f64>> {
            let mut h = h;
            let r2 = h[0] * h[0] + h[1] * h[1];
            if r2 > 1.0 {
                let r = r2.sqrt();
                h = [h[0] / r, h[1] / r];
            }
            let up = (1.0 - h[0] * h[0] - h[1] * h[1]).max(0.0).sqrt();
            Unit::new_normalize(e1 * h[0] + e2 * h[1] + n.into_inner() * (side * up))
        };
        let mut h = [e1.dot(&d0), e2.dot(&d0)];
        let mut cur = self.local(cc, &lift(h), &e1, &e2, gains, false);
        for _ in 0..iterations {
            let mut step = newton_step(&cur, max_step);
            let mut accepted = false;
            for _ in 0..4 {
                let cand = [h[0] + step[0], h[1] + step[1]];
                let next = self.local(cc, &lift(cand), &e1, &e2, gains, false);
                if next.power >= cur.power {
                    (h, cur) = (cand, next);
                    accepted = true;
                    break;
                }
                step = [0.5 * step[0], 0.5 * step[1]];
            }
            let len = (step[0] * step[0] + step[1] * step[1]).sqrt();
            if !accepted || len < 2e-5 {
                break;
            }
        }
        (lift(h), cur)
    }
}

/// Newton step on `local` (gradient step of a quarter of `max_step` where
/// the power is not concave), at most `max_step` long.
fn newton_step(local: &Local, max_step: f64) -> [f64; 2] {
    let [huu, huv, hvv] = local.hess;
    let det = huu * hvv - huv * huv;
    let [gu, gv] = local.grad;
    let step = if huu < 0.0 && det > 0.0 {
        [-(hvv * gu - huv * gv) / det, -(-huv * gu + huu * gv) / det]
    } else {
        let n = (gu * gu + gv * gv).sqrt().max(1e-30);
        [0.25 * max_step * gu / n, 0.25 * max_step * gv / n]
    };
    let len = (step[0] * step[0] + step[1] * step[1]).sqrt();
    if len > max_step { [step[0] * max_step / len, step[1] * max_step / len] } else { step }
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
