//! The statistics shared by the fits, the diagnosis and the frame measurement:
//! quantiles of the Student t, chi-square and normal distributions (`statrs`),
//! and the small summaries of residuals.

use std::sync::atomic::{AtomicU64, Ordering};

use statrs::distribution::{ChiSquared, ContinuousCDF, Normal, StudentsT};

/// Two-sided 95 % quantile of Student's t with `dof` degrees of freedom
/// (infinite for none). Each is computed once per process: the inverse takes
/// microseconds, longer than the paper's whole regression, and every fit asks
/// for the same few.
pub fn t_quantile_975(dof: usize) -> f64 {
    static KNOWN: [AtomicU64; 4096] = [const { AtomicU64::new(0) }; 4096];
    let quantile = || match StudentsT::new(0.0, 1.0, dof as f64) {
        Ok(t) if dof > 0 => t.inverse_cdf(0.975),
        _ => f64::INFINITY,
    };
    let Some(slot) = KNOWN.get(dof) else {
        return quantile();
    };
    match slot.load(Ordering::Relaxed) {
        0 => {
            let t = quantile();
            slot.store(t.to_bits(), Ordering::Relaxed);
            t
        }
        bits => f64::from_bits(bits),
    }
}

/// Quantile of the chi-square distribution with `k` degrees of freedom at
/// probability `p` (0 for none).
pub fn chi2_quantile(p: f64, k: usize) -> f64 {
    match ChiSquared::new(k as f64) {
        Ok(c) if k > 0 => c.inverse_cdf(p.clamp(0.0, 1.0)),
        _ => 0.0,
    }
}

/// Upper-tail standard normal quantile: the z exceeded with probability `p`
/// (p is kept within [1e-300, 0.5]).
pub fn normal_quantile_upper(p: f64) -> f64 {
    -Normal::standard().inverse_cdf(p.clamp(1e-300, 0.5))
}

/// `MAD_TO_SIGMA * median |r|` estimates a Gaussian sigma (1 / the normal's 75 % quantile).
pub const MAD_TO_SIGMA: f64 = 1.482_602_218_505_602;

/// Median of a slice (reorders it); 0 for an empty one.
pub fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    let mid = n / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    let upper = *m;
    if n % 2 == 1 {
        upper
    } else {
        let lower = v[..mid].iter().copied().fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lower + upper)
    }
}

/// Root mean square of a slice (0 for an empty one).
pub fn rms(xs: &[f64]) -> f64 {
    if xs.is_empty() { 0.0 } else { (xs.iter().map(|x| x * x).sum::<f64>() / xs.len() as f64).sqrt() }
}

/// Noise standard deviation from second differences of residuals ordered along
/// the sweep: a smooth model misfit cancels, white noise of variance s² gives
/// differences of variance 6 s². Needs at least 5 points.
pub fn noise_from_second_differences(ordered: &[f64]) -> Option<f64> {
    if ordered.len() < 5 {
        return None;
    }
    let d: Vec<f64> = ordered.windows(3).map(|w| w[0] - 2.0 * w[1] + w[2]).collect();
    Some((d.iter().map(|x| x * x).sum::<f64>() / (6.0 * d.len() as f64)).sqrt())
}

/// Coefficient of determination of `observed` against `predicted`.
pub fn r_squared(observed: &[f64], predicted: &[f64]) -> f64 {
    let n = observed.len() as f64;
    if n < 2.0 {
        return f64::NAN;
    }
    let mean = observed.iter().sum::<f64>() / n;
    let sst: f64 = observed.iter().map(|y| (y - mean).powi(2)).sum();
    let ssr: f64 = observed.iter().zip(predicted).map(|(y, p)| (y - p).powi(2)).sum();
    if sst > 0.0 { 1.0 - ssr / sst } else { f64::NAN }
}

/// Estimate ± t·se as a `[low, high]` interval.
pub fn interval(estimate: f64, se: f64, dof: usize) -> [f64; 2] {
    let h = t_quantile_975(dof) * se;
    [estimate - h, estimate + h]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn t_quantiles_match_tables() {
        for (dof, t) in [(3, 3.182446), (5, 2.570582), (10, 2.228139), (13, 2.160369), (30, 2.042272), (200, 1.971896)]
        {
            assert!((t_quantile_975(dof) / t - 1.0).abs() < 5e-4, "dof {dof}: {}", t_quantile_975(dof));
        }
    }

    #[test]
    fn chi2_and_normal_quantiles_match_tables() {
        // chi² at p = 0.999 (the diagnosis' significance guard) and upper normal quantiles.
        for (k, q) in [(1, 10.828), (2, 13.816), (4, 18.467), (5, 20.515), (10, 29.588)] {
            assert!((chi2_quantile(0.999, k) - q).abs() < 1e-3, "k {k}: {}", chi2_quantile(0.999, k));
        }
        assert_eq!(chi2_quantile(0.999, 0), 0.0);
        assert_eq!(t_quantile_975(0), f64::INFINITY);
        for (p, z) in [(0.025, 1.959964), (1e-3, 3.090232), (1e-10, 6.361341)] {
            assert!((normal_quantile_upper(p) - z).abs() < 1e-5, "p {p}: {}", normal_quantile_upper(p));
        }
        assert!((1.0 / MAD_TO_SIGMA - Normal::standard().inverse_cdf(0.75)).abs() < 1e-12);
    }

    #[test]
    fn second_difference_noise_ignores_smooth_trends() {
        let mut rng = sim::rng::Rng::seed_from(3);
        let xs: Vec<f64> = (0..2000).map(|i| 0.3 * (i as f64 / 300.0).sin() + rng.gaussian(0.01)).collect();
        let s = noise_from_second_differences(&xs).unwrap();
        assert!((s - 0.01).abs() < 0.0008, "{s}");
    }

    #[test]
    fn median_odd_and_even() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&mut []), 0.0);
    }
}
