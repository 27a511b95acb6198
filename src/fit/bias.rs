//! The least-squares estimator's own second-order bias (Box 1971; docs/physics.md,
//! "The estimator's bias"). A least-squares fit of a model that is curved in its
//! parameters is biased even when the model is exact and the noise is zero-mean:
//! to second order in the noise the bias is
//!
//! b = -(1/2) (J'J)^-1 J' d,   d_i = tr(C H_i),
//!
//! with r the residuals weighted by each sample's noise (so that the noise is
//! unit-variance), J their Jacobian in the parameters, C = (J'J)^-1 the
//! estimate's covariance from that noise and H_i the Hessian of residual i. The
//! layer fit reports b (`curvature_bias`); optimum minus b is the corrected
//! estimate.

use nalgebra::{DMatrix, DVector};

/// The second-order bias of the least-squares optimum `theta` of the weighted
/// residuals `eval` (unit-variance noise), with `jac` their Jacobian there.
///
/// tr(C H_i) is summed over C's principal axes, C = sum_m u_m u_m' with u_m
/// one standard deviation along axis m, so that tr(C H_i) = sum_m u_m' H_i u_m:
/// one central second difference per axis (2 model evaluations per parameter,
/// where the Hessian's entries would take 2 n²). Steps of one standard
/// deviation take the curvature as the noise meets it, over the spread of the
/// estimate, rather than at a point (a numerical model may have kinks finer
/// than that). Where the model cannot be evaluated at a step (`eval` returns
/// `None`: a parameter's range), the step is halved, up to three times;
/// `None` if that does not help.
pub(super) fn box_bias(
    eval: impl Fn(&[f64]) -> Option<Vec<f64>> + Sync,
    theta: &[f64],
    jac: &DMatrix<f64>,
) -> Option<Vec<f64>> {
    use rayon::prelude::*;
    let np = theta.len();
    let m = jac.nrows();
    if jac.ncols() != np {
        return None;
    }
    let cov = (jac.transpose() * jac).try_inverse()?;
    let r0 = eval(theta).filter(|r| r.len() == m)?;
    let eigen = nalgebra::SymmetricEigen::new(cov.clone());
    if !eigen.eigenvalues.iter().all(|l| l.is_finite() && *l >= 0.0) {
        return None;
    }
    // The second difference along each principal axis; the axes' probes are
    // independent (the FE layer model's, on the cores there are).
    let along = |k: usize| -> Option<Vec<f64>> {
        let axis = eigen.eigenvectors.column(k) * eigen.eigenvalues[k].sqrt();
        let mut scale = 1.0;
        let at = |sign: f64, scale: f64| {
            let x: Vec<f64> = theta.iter().zip(axis.iter()).map(|(t, a)| t + sign * scale * a).collect();
            eval(&x).filter(|r| r.len() == m)
        };
        let (up, down) = loop {
            match (at(1.0, scale), at(-1.0, scale)) {
                (Some(u), Some(v)) => break (u, v),
                _ if scale > 0.2 => scale *= 0.5,
                _ => return None,
            }
        };
        Some((0..m).map(|i| (up[i] - 2.0 * r0[i] + down[i]) / (scale * scale)).collect())
    };
    let seconds = (0..np).into_par_iter().map(along).collect::<Option<Vec<_>>>()?;
    let mut d = DVector::<f64>::zeros(m);
    for s in &seconds {
        for i in 0..m {
            d[i] += s[i];
        }
    }
    let b = -0.5 * &cov * (jac.transpose() * d);
    b.iter().all(|v| v.is_finite()).then(|| b.iter().copied().collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::lm::{LmOptions, minimize};

    /// y_i = theta² x_i: the estimate is sqrt(theta² + e), e ~ N(0, s²/Σx²),
    /// whose bias is -s²/(8 theta³ Σx²) to second order.
    #[test]
    fn one_parameter_bias_is_the_closed_form() {
        let xs: Vec<f64> = (1..=20).map(|i| i as f64 * 0.1).collect();
        let (theta, sigma) = (0.7_f64, 0.05_f64);
        let sxx: f64 = xs.iter().map(|x| x * x).sum();
        let residuals = |t: &[f64]| Some(xs.iter().map(|x| -(t[0] * t[0] * x) / sigma).collect::<Vec<_>>());
        let jac = DMatrix::from_iterator(xs.len(), 1, xs.iter().map(|x| -2.0 * theta * x / sigma));
        let b = box_bias(residuals, &[theta], &jac).unwrap();
        let expected = -sigma * sigma / (8.0 * theta.powi(3) * sxx);
        assert!((b[0] / expected - 1.0).abs() < 1e-6, "{} vs {expected}", b[0]);
    }

    /// A curved two-parameter model (y = a exp(-k x)) fitted by the crate's own
    /// solver over many noise draws, each as z and -z (antithetic pairs: the
    /// pair's mean cancels the noise's odd orders, leaving the bias): the mean
    /// estimate of k is biased by what Box's formula says, and the corrected
    /// mean is unbiased within its standard error.
    #[test]
    fn monte_carlo_bias_matches_and_the_correction_removes_it() {
        let xs: Vec<f64> = (0..12).map(|i| i as f64 * 0.5).collect();
        let (a, k, sigma) = (1.0_f64, 0.8_f64, 0.05_f64);
        let clean: Vec<f64> = xs.iter().map(|x| a * (-k * x).exp()).collect();
        let mut state = 12345u64;
        let mut gauss = || {
            let mut u = || {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (p, q) = (u(), u());
            (-2.0 * p.ln()).sqrt() * (2.0 * std::f64::consts::PI * q).cos()
        };
        let n = 2000;
        let (mut raw, mut corrected, mut predicted) = (Vec::with_capacity(n), Vec::with_capacity(n), Vec::new());
        for _ in 0..n {
            let z: Vec<f64> = clean.iter().map(|_| gauss()).collect();
            let (mut pair_raw, mut pair_corrected) = (0.0, 0.0);
            for sign in [1.0, -1.0] {
                let y: Vec<f64> = clean.iter().zip(&z).map(|(c, zi)| c + sign * sigma * zi).collect();
                let res = |t: &[f64], out: &mut Vec<f64>| {
                    out.clear();
                    out.extend(xs.iter().zip(&y).map(|(x, yi)| (yi - t[0] * (-t[1] * x).exp()) / sigma));
                    true
                };
                let t = minimize(res, &[a, k], LmOptions::default()).unwrap().x;
                let eval = |p: &[f64]| {
                    Some(xs.iter().zip(&y).map(|(x, yi)| (yi - p[0] * (-p[1] * x).exp()) / sigma).collect::<Vec<_>>())
                };
                let jac = DMatrix::from_fn(xs.len(), 2, |i, j| {
                    let e = (-t[1] * xs[i]).exp();
                    if j == 0 { -e / sigma } else { t[0] * xs[i] * e / sigma }
                });
                let b = box_bias(eval, &t, &jac).unwrap();
                pair_raw += t[1] / 2.0;
                pair_corrected += (t[1] - b[1]) / 2.0;
                predicted.push(b[1]);
            }
            raw.push(pair_raw);
            corrected.push(pair_corrected);
        }
        let mean_sd = |v: &[f64]| {
            let m = v.iter().sum::<f64>() / v.len() as f64;
            let sd = (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt();
            (m, sd / (v.len() as f64).sqrt())
        };
        let ((mr, se_r), (mc, se_c), (mb, _)) = (mean_sd(&raw), mean_sd(&corrected), mean_sd(&predicted));
        println!("k: raw mean {mr:.6} ± {se_r:.6}, corrected {mc:.6} ± {se_c:.6}, Box's bias {mb:.6}, truth {k}");
        // The raw estimate is biased high by many of its standard errors...
        assert!((mr - k) / se_r > 5.0, "raw bias {} ({} se)", mr - k, (mr - k) / se_r);
        // ...by what Box's formula says (to a tenth: the higher orders)...
        assert!(((mr - k) / mb - 1.0).abs() < 0.1, "bias {} against Box's {mb}", mr - k);
        // ...and the corrected one is not biased.
        assert!(((mc - k) / se_c).abs() < 2.5, "corrected bias {} ({} se)", mc - k, (mc - k) / se_c);
    }
}
