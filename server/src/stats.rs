//! χ² quantiles for gating (theory §4.3).

/// Quantile of the standard normal distribution (Acklam's rational
/// approximation, relative error below 1.2e-9), for p in (0, 1).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Complementary error function (Numerical Recipes' Chebyshev fit, relative error < 1.2e-7).
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.26551223
        + t * (1.00002368
            + t * (0.37409196
                + t * (0.09678418
                    + t * (-0.18628806
                        + t * (0.27886807
                            + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
    let r = t * poly.exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// ln(eᵃ + eᵇ) without overflow.
fn log_add(a: f64, b: f64) -> f64 {
    let (hi, lo) = if a >= b { (a, b) } else { (b, a) };
    hi + (lo - hi).exp().ln_1p()
}

/// Survival function Q(x) = P(χ²_k > x) for integer k ≥ 1, by the closed forms for
/// even and odd degrees of freedom. The sums run in the log domain, so that the
/// terms (up to e^{x/2}) do not overflow at large k.
pub fn chi2_survival(k: usize, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let h = x / 2.0;
    if k.is_multiple_of(2) {
        // Q = e^{−h} Σ_{j < k/2} h^j / j!
        let (mut ln_term, mut ln_sum) = (-h, -h);
        for j in 1..k / 2 {
            ln_term += (h / j as f64).ln();
            ln_sum = log_add(ln_sum, ln_term);
        }
        ln_sum.exp().min(1.0)
    } else {
        let mut q = erfc(h.sqrt());
        if k > 1 {
            // √(2x/π) e^{−h} Σ_{j ≤ (k−3)/2} x^j / (3·5···(2j+1))
            let mut ln_term = 0.5 * (2.0 * x / std::f64::consts::PI).ln() - h;
            let mut ln_sum = ln_term;
            for j in 1..=(k - 3) / 2 {
                ln_term += (x / (2 * j + 1) as f64).ln();
                ln_sum = log_add(ln_sum, ln_term);
            }
            q += ln_sum.exp();
        }
        q.min(1.0)
    }
}

/// Density of χ²_k at x.
fn chi2_density(k: usize, x: f64) -> f64 {
    let a = k as f64 / 2.0;
    // ln Γ(a) for half-integers, exactly.
    let ln_gamma = if k.is_multiple_of(2) {
        (1..k / 2).map(|j| (j as f64).ln()).sum::<f64>()
    } else {
        0.5 * std::f64::consts::PI.ln() + (0..(k - 1) / 2).map(|j| (j as f64 + 0.5).ln()).sum::<f64>()
    };
    ((a - 1.0) * x.ln() - x / 2.0 - a * std::f64::consts::LN_2 - ln_gamma).exp()
}

/// Above this many degrees of freedom [`chi2_quantile`] is the Wilson–Hilferty
/// approximation itself (relative error below 2e-6 there, shrinking as k^{-3/2});
/// below it, Newton's refinement (whose sums cost O(k)) is exact to 1e-10.
pub const WILSON_HILFERTY_MIN_DOF: usize = 5000;

/// Wilson–Hilferty approximation of the χ² quantile: χ²ₖ/k is close to normal
/// after a cube root, so x ≈ k (1 − h + z √h)³ with h = 2/(9k) and z the normal quantile.
pub fn chi2_quantile_wilson_hilferty(dof: usize, p: f64) -> f64 {
    let kf = dof as f64;
    let z = normal_quantile(p);
    let h = 2.0 / (9.0 * kf);
    (kf * (1.0 - h + z * h.sqrt()).powi(3)).max(0.0)
}

/// Quantile of the χ² distribution with `dof` degrees of freedom at probability `p`:
/// closed forms for 1 and 2 dof, Newton's method from the Wilson–Hilferty guess
/// up to [`WILSON_HILFERTY_MIN_DOF`], Wilson–Hilferty alone above (finite for any dof).
///
/// Newton's sums cost O(dof) logarithms per step: for a 128-ray gate (253 dof)
/// about 10 µs, as much as the rest of the gate. The gates ask for the same few
/// (dof, p) again and again, so the Newton results are kept in a small
/// per-thread table (direct-mapped, [`QUANTILE_CACHE_SLOTS`] slots, no
/// allocation): a hit returns the value computed before, bit for bit.
pub fn chi2_quantile(dof: usize, p: f64) -> f64 {
    match dof {
        0 => 0.0,
        1 => normal_quantile(0.5 + p / 2.0).powi(2),
        2 => -2.0 * (1.0 - p).ln(),
        k if k > WILSON_HILFERTY_MIN_DOF => chi2_quantile_wilson_hilferty(k, p),
        k => QUANTILE_CACHE.with(|cache| {
            let key = (k, p.to_bits());
            let slot = &cache[quantile_slot(key)];
            if let Some((cached, value)) = slot.get()
                && cached == key
            {
                return value;
            }
            let value = chi2_quantile_newton(k, p);
            slot.set(Some((key, value)));
            value
        }),
    }
}

/// Slots of the per-thread table of [`chi2_quantile`]'s Newton results.
pub const QUANTILE_CACHE_SLOTS: usize = 64;

type QuantileSlot = std::cell::Cell<Option<((usize, u64), f64)>>;

thread_local! {
    static QUANTILE_CACHE: [QuantileSlot; QUANTILE_CACHE_SLOTS] =
        const { [const { std::cell::Cell::new(None) }; QUANTILE_CACHE_SLOTS] };
}

/// The table's slot for (dof, p's bits): a multiplicative hash of both.
fn quantile_slot((dof, p_bits): (usize, u64)) -> usize {
    let h = (dof as u64 ^ p_bits.rotate_left(29)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    (h >> 58) as usize % QUANTILE_CACHE_SLOTS
}

/// Newton's method from the Wilson–Hilferty guess, for 3 ≤ dof ≤ [`WILSON_HILFERTY_MIN_DOF`].
fn chi2_quantile_newton(k: usize, p: f64) -> f64 {
    let mut x = chi2_quantile_wilson_hilferty(k, p).max(1e-6);
    for _ in 0..8 {
        // F(x) − p = (1 − Q) − p; F' = density.
        let step = ((1.0 - chi2_survival(k, x)) - p) / chi2_density(k, x);
        x = (x - step).max(x / 10.0);
        if step.abs() < 1e-10 * x {
            break;
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_tables() {
        // theory §4.3 table and standard tables.
        for (dof, p, q) in [
            (1, 0.99, 6.63),
            (1, 0.999, 10.83),
            (2, 0.99, 9.21),
            (2, 0.999, 13.82),
            (3, 0.99, 11.34),
            (3, 0.999, 16.27),
            (5, 0.99, 15.09),
            (10, 0.95, 18.31),
            (4, 0.999, 18.47),
            (7, 0.99, 18.48),
        ] {
            let got = chi2_quantile(dof, p);
            assert!((got - q).abs() / q < 2e-3, "dof {dof} p {p}: {got} vs {q}");
        }
        assert!((normal_quantile(0.975) - 1.959964).abs() < 1e-5);
    }

    #[test]
    fn the_table_returns_what_newton_computes_for_each_key() {
        // More keys than slots, asked in order and then in reverse, each twice in a row: every answer
        // is Newton's for its own (dof, p), whether it came from the table or not.
        let keys: Vec<(usize, f64)> = (3..=80).flat_map(|k| [(k, 0.99), (k, 0.999), (k * 3, 0.95)]).collect();
        assert!(keys.len() > 3 * QUANTILE_CACHE_SLOTS);
        let reversed: Vec<(usize, f64)> = keys.iter().rev().copied().collect();
        for order in [&keys, &reversed] {
            for &(k, p) in order {
                for _ in 0..2 {
                    assert_eq!(
                        chi2_quantile(k, p).to_bits(),
                        chi2_quantile_newton(k, p).to_bits(),
                        "dof {k} p {p}"
                    );
                }
            }
        }
    }

    #[test]
    fn large_dof_is_finite_and_accurate() {
        // References: bisection on the regularized incomplete gamma function
        // (series / continued fraction in the log domain), to 1e-5.
        let probabilities = [0.001, 0.025, 0.975, 0.999];
        for (k, reference) in [
            (600, [498.622874, 534.01855, 669.769152, 712.771163]),
            (1000, [867.479083, 914.257154, 1089.530913, 1143.917093]),
            (1401, [1243.10387, 1299.15852, 1506.6297, 1570.29322]),
            (5000, [4696.66738, 4805.90473, 5197.88377, 5314.73136]),
            (5001, [4697.63648, 4806.88513, 5198.90337, 5315.76226]),
        ] {
            for (p, q) in probabilities.iter().zip(reference) {
                let got = chi2_quantile(k, *p);
                assert!((got - q).abs() / q < 2e-6, "dof {k} p {p}: {got} vs {q}");
            }
        }
        // Far beyond: finite, and mean ± z·√(2k) to first order.
        for k in [10_000usize, 1_000_000] {
            for (p, z) in [(0.025, -1.959964), (0.975, 1.959964)] {
                let q = chi2_quantile(k, p);
                let kf = k as f64;
                assert!(q.is_finite(), "dof {k}: {q}");
                assert!(
                    (q - (kf + z * (2.0 * kf).sqrt())).abs() < 0.01 * kf.sqrt() + 2.0,
                    "dof {k} p {p}: {q}"
                );
            }
        }
        assert!((chi2_survival(3000, 3000.0) - 0.496566).abs() < 1e-5, "no overflow in the survival sums");
        assert!((chi2_survival(3000, 3200.0) - 0.005617).abs() < 1e-5);
    }
}
