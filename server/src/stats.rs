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

/// Survival function Q(x) = P(χ²_k > x) for integer k ≥ 1, by the closed forms for
/// even and odd degrees of freedom.
pub fn chi2_survival(k: usize, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let h = x / 2.0;
    if k.is_multiple_of(2) {
        let (mut term, mut sum) = (1.0, 1.0);
        for j in 1..k / 2 {
            term *= h / j as f64;
            sum += term;
        }
        (-h).exp() * sum
    } else {
        let mut q = erfc((h).sqrt());
        if k > 1 {
            let (mut term, mut sum) = ((2.0 * x / std::f64::consts::PI).sqrt() * (-h).exp(), 0.0);
            sum += term;
            for j in 1..=(k - 3) / 2 {
                term *= x / (2 * j + 1) as f64;
                sum += term;
            }
            q += sum;
        }
        q
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

/// Quantile of the χ² distribution with `dof` degrees of freedom at probability `p`:
/// closed forms for 1 and 2 dof, Newton's method from the Wilson–Hilferty guess above.
pub fn chi2_quantile(dof: usize, p: f64) -> f64 {
    match dof {
        0 => 0.0,
        1 => normal_quantile(0.5 + p / 2.0).powi(2),
        2 => -2.0 * (1.0 - p).ln(),
        k => {
            let kf = k as f64;
            let z = normal_quantile(p);
            let h = 2.0 / (9.0 * kf);
            let mut x = (kf * (1.0 - h + z * h.sqrt()).powi(3)).max(1e-6);
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
    }
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
}
