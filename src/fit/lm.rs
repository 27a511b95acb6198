//! Levenberg–Marquardt for small dense problems (a handful of parameters,
//! a few hundred residuals), with Marquardt's diagonal scaling. The residual
//! function may refuse a trial point (returns `false`): the step is then
//! treated as a failed one and the damping raised, which is how parameter
//! regions where the forward model has no solution are kept out.

use nalgebra::{DMatrix, DVector};

#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    pub max_iterations: usize,
    /// Stop when a step reduces the cost by less than this fraction.
    pub cost_tolerance: f64,
    /// Stop when a step changes every parameter by less than this (relative to max(|x|, 1)).
    pub step_tolerance: f64,
    /// Relative finite-difference step for the Jacobian.
    pub fd_step: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self { max_iterations: 200, cost_tolerance: 1e-12, step_tolerance: 1e-10, fd_step: 1e-7 }
    }
}

#[derive(Debug, Clone)]
pub struct LmResult {
    pub x: Vec<f64>,
    pub residuals: Vec<f64>,
    /// Sum of squared residuals.
    pub ssr: f64,
    pub iterations: usize,
    pub converged: bool,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LmError {
    #[error("the model cannot be evaluated at the starting point")]
    BadStart,
    #[error("the fit has {residuals} residuals for {params} parameters")]
    Underdetermined { residuals: usize, params: usize },
}

/// Forward-difference Jacobian of `f` at `x` (rows = residuals). `None` if any probe fails.
pub fn jacobian<F>(f: &mut F, x: &[f64], r0: &[f64], fd_step: f64) -> Option<DMatrix<f64>>
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
    let m = r0.len();
    let n = x.len();
    let mut jac = DMatrix::zeros(m, n);
    let mut xp = x.to_vec();
    let mut r = Vec::with_capacity(m);
    for j in 0..n {
        let h = fd_step * x[j].abs().max(1.0);
        xp[j] = x[j] + h;
        r.clear();
        if !f(&xp, &mut r) || r.len() != m {
            // Try the other side before giving up (a bound may be just past x).
            xp[j] = x[j] - h;
            r.clear();
            if !f(&xp, &mut r) || r.len() != m {
                return None;
            }
            for i in 0..m {
                jac[(i, j)] = (r0[i] - r[i]) / h;
            }
        } else {
            for i in 0..m {
                jac[(i, j)] = (r[i] - r0[i]) / h;
            }
        }
        xp[j] = x[j];
    }
    Some(jac)
}

/// Minimise the sum of squares of `f(x)`.
pub fn minimize<F>(mut f: F, x0: &[f64], opts: LmOptions) -> Result<LmResult, LmError>
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
    let n = x0.len();
    let mut x = x0.to_vec();
    let mut r = Vec::new();
    if !f(&x, &mut r) || r.iter().any(|v| !v.is_finite()) {
        return Err(LmError::BadStart);
    }
    if r.len() < n {
        return Err(LmError::Underdetermined { residuals: r.len(), params: n });
    }
    let ssr_of = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
    let mut ssr = ssr_of(&r);
    let mut lambda = 1e-3;
    let mut trial = Vec::with_capacity(r.len());
    let mut converged = false;
    let mut iterations = 0;
    'outer: while iterations < opts.max_iterations {
        iterations += 1;
        let Some(jac) = jacobian(&mut f, &x, &r, opts.fd_step) else {
            break;
        };
        let jt = jac.transpose();
        let a = &jt * &jac;
        let g = &jt * DVector::from_column_slice(&r);
        loop {
            let mut damped = a.clone();
            for i in 0..n {
                let d = a[(i, i)].max(1e-30);
                damped[(i, i)] += lambda * d;
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                if lambda > 1e16 {
                    break 'outer;
                }
                continue;
            };
            let step = chol.solve(&(-&g));
            let xn: Vec<f64> = x.iter().zip(step.iter()).map(|(a, b)| a + b).collect();
            trial.clear();
            let ok = f(&xn, &mut trial) && trial.iter().all(|v| v.is_finite());
            let ssr_new = if ok { ssr_of(&trial) } else { f64::INFINITY };
            if ssr_new <= ssr {
                let small_step = step.iter().zip(&x).all(|(s, xi)| s.abs() <= opts.step_tolerance * xi.abs().max(1.0));
                let small_gain = ssr - ssr_new <= opts.cost_tolerance * ssr.max(1e-300);
                x = xn;
                std::mem::swap(&mut r, &mut trial);
                ssr = ssr_new;
                lambda = (lambda / 3.0).max(1e-12);
                if small_step || small_gain {
                    converged = true;
                    break 'outer;
                }
                break;
            }
            lambda *= 4.0;
            if lambda > 1e16 {
                // No step lowers the cost: we are at the minimum to working precision.
                converged = true;
                break 'outer;
            }
        }
    }
    Ok(LmResult { x, residuals: r, ssr, iterations, converged })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_rosenbrock_and_an_exponential() {
        let res = minimize(
            |x, r| {
                r.clear();
                r.push(10.0 * (x[1] - x[0] * x[0]));
                r.push(1.0 - x[0]);
                true
            },
            &[-1.2, 1.0],
            LmOptions::default(),
        )
        .unwrap();
        assert!((res.x[0] - 1.0).abs() < 1e-6 && (res.x[1] - 1.0).abs() < 1e-6, "{:?}", res.x);

        let ts: Vec<f64> = (0..50).map(|i| i as f64 * 0.1).collect();
        let ys: Vec<f64> = ts.iter().map(|t| 2.5 * (-1.3 * t).exp() + 0.5).collect();
        let res = minimize(
            |p, r| {
                r.clear();
                r.extend(ts.iter().zip(&ys).map(|(t, y)| p[0] * (-p[1] * t).exp() + p[2] - y));
                true
            },
            &[1.0, 0.5, 0.0],
            LmOptions::default(),
        )
        .unwrap();
        assert!((res.x[0] - 2.5).abs() < 1e-6 && (res.x[1] - 1.3).abs() < 1e-6 && (res.x[2] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn refused_regions_are_avoided() {
        // Minimum of (x - 3)^2 but the model refuses x > 2: the fit stops at the edge.
        let res = minimize(
            |x, r| {
                r.clear();
                r.push(x[0] - 3.0);
                x[0] <= 2.0
            },
            &[0.0],
            LmOptions::default(),
        )
        .unwrap();
        assert!(res.x[0] <= 2.0 && res.x[0] > 1.9, "{:?}", res.x);
        assert!(matches!(
            minimize(
                |_, r| {
                    r.clear();
                    r.push(1.0);
                    false
                },
                &[0.0],
                LmOptions::default()
            ),
            Err(LmError::BadStart)
        ));
    }
}
