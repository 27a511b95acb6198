//! Small statistics helpers shared by the fits.

/// Two-sided 95 % quantile of Student's t with `dof` degrees of freedom
/// (tabulated up to 12 degrees of freedom, where the expansion is poor; above,
/// the Cornish–Fisher expansion around the normal quantile, < 0.05 % error).
pub fn t_quantile_975(dof: usize) -> f64 {
    const Z: f64 = 1.959_963_984_540_054;
    const TABLE: [f64; 13] = [
        f64::INFINITY,
        12.706_205,
        4.302_653,
        3.182_446,
        2.776_445,
        2.570_582,
        2.446_912,
        2.364_624,
        2.306_004,
        2.262_157,
        2.228_139,
        2.200_985,
        2.178_813,
    ];
    match TABLE.get(dof) {
        Some(&t) => t,
        None => {
            let v = dof as f64;
            let z3 = Z * Z * Z;
            let z5 = z3 * Z * Z;
            let z7 = z5 * Z * Z;
            Z + (z3 + Z) / (4.0 * v)
                + (5.0 * z5 + 16.0 * z3 + 3.0 * Z) / (96.0 * v * v)
                + (3.0 * z7 + 19.0 * z5 + 17.0 * z3 - 15.0 * Z) / (384.0 * v * v * v)
        }
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
    fn second_difference_noise_ignores_smooth_trends() {
        let mut rng = sim::rng::Rng::seed_from(3);
        let xs: Vec<f64> = (0..2000).map(|i| 0.3 * (i as f64 / 300.0).sin() + rng.gaussian(0.01)).collect();
        let s = noise_from_second_differences(&xs).unwrap();
        assert!((s - 0.01).abs() < 0.0008, "{s}");
    }
}
