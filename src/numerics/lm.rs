//! Levenberg–Marquardt for small dense problems (a handful of parameters,
//! a few dozen to a few hundred residuals), with Marquardt's diagonal scaling.
//! One loop ([`solve`]) serves every least-squares fit of the controller: the
//! fits of a recording and the diagnosis through [`minimize`] (a residual
//! closure, finite-difference Jacobian), and the frame's Hertz field through
//! [`Problem`] (an analytic Jacobian accumulated into fixed-size normal
//! equations). The two differ only in their [`Strategy`] (damping and what
//! counts as a small step).
//!
//! A problem may refuse a trial point (its forward model has no solution
//! there): the step then counts as a failed one and the damping is raised,
//! which is how such parameter regions are kept out.
//!
//! Why ours and not the `levenberg-marquardt` crate (MINPACK's lmder over
//! nalgebra): the crate has no refused region (a residual it cannot compute
//! ends the fit), and each of its iterations QR-factors the whole m x n
//! Jacobian, where the frame fit (run per frame, about 20,000 frames/s)
//! accumulates 4 x 4 normal equations on the stack without allocating; the
//! fits' results and their tests were also established on this solver's path.

use nalgebra::allocator::Allocator;
use nalgebra::{DMatrix, DVector, DefaultAllocator, Dim, Dyn, OMatrix, OVector};

#[derive(Debug, Clone, Copy)]
pub struct LmOptions {
    pub max_iterations: usize,
    /// Stop when a step reduces the cost by less than this fraction.
    pub cost_tolerance: f64,
    /// Stop when a step changes every parameter by less than this (relative to max(|x|, 1)).
    pub step_tolerance: f64,
    /// Relative finite-difference step for the Jacobian of [`minimize`].
    pub fd_step: f64,
    /// For residuals weighted by their noise: stop once the Gauss–Newton step
    /// from the current point is shorter than this many standard errors of
    /// the estimate (the noise scaled by the residuals' own chi²/dof). A fit
    /// closer to its optimum than a small fraction of its spread gains
    /// nothing by going on, and a forward model with kinks in its last digits
    /// (the FE contact's nodes) otherwise spends dozens of refused trials
    /// proving it is at the minimum. `None`: only the tolerances above.
    pub within_se: Option<f64>,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self { max_iterations: 200, cost_tolerance: 1e-12, step_tolerance: 1e-10, fd_step: 1e-7, within_se: None }
    }
}

/// How the damping lambda moves and when a step is small enough to stop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Strategy {
    /// lambda at the start.
    pub initial_damping: f64,
    /// lambda * max(A_ii, diagonal_floor) is added to each diagonal entry A_ii
    /// of the normal equations (Marquardt's scaling).
    pub diagonal_floor: f64,
    /// After an accepted step lambda becomes lambda * shrink.0 / shrink.1
    /// (never below 1e-12; a ratio, so that a third is exact)...
    pub shrink: (f64, f64),
    /// ...and multiplied by this after a rejected one.
    pub grow: f64,
    /// A lambda beyond this means no step lowers the cost: the search ends,
    /// converged (a singular system past it ends it unconverged).
    pub max_damping: f64,
    /// Trials per iteration (a singular damped system counts as one) before
    /// the search ends without an improvement.
    pub max_trials: usize,
    pub tolerances: Tolerances,
}

/// How [`LmOptions`]' step and cost tolerances are scaled.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tolerances {
    /// |step_i| <= step_tolerance * max(|x_i|, 1) at the point stepped from,
    /// or a gain of at most cost_tolerance * cost.
    Relative,
    /// |step_i| <= step_tolerance * (1 + |x_i|) at the point stepped to, or a
    /// gain of at most cost_tolerance * (1 + cost) that still lowers the cost
    /// (for costs far below 1, an absolute floor).
    Offset,
}

impl Strategy {
    /// For the fits of a recording: forward models with refused regions and a
    /// finite-difference Jacobian. lambda / 3 after a success, x 4 after a
    /// failure, until 1e16.
    pub const FIT: Strategy = Strategy {
        initial_damping: 1e-3,
        diagonal_floor: 1e-30,
        shrink: (1.0, 3.0),
        grow: 4.0,
        max_damping: 1e16,
        max_trials: usize::MAX,
        tolerances: Tolerances::Relative,
    };

    /// For a frame's Hertz field (mm-scale parameters, an analytic Jacobian):
    /// lambda x 0.3 after a success, x 10 after a failure, at most 12 trials
    /// per iteration.
    pub const FIELD: Strategy = Strategy {
        initial_damping: 1e-3,
        diagonal_floor: 1e-12,
        shrink: (0.3, 1.0),
        grow: 10.0,
        max_damping: f64::INFINITY,
        max_trials: 12,
        tolerances: Tolerances::Offset,
    };

    /// Whether the accepted step from `x` to `trial` (cost `before` -> `after`) ends the search.
    fn small<D: Dim>(
        &self,
        opts: &LmOptions,
        step: &OVector<f64, D>,
        x: &OVector<f64, D>,
        trial: &OVector<f64, D>,
        before: f64,
        after: f64,
    ) -> bool
    where
        DefaultAllocator: Allocator<D>,
    {
        let tol = opts.step_tolerance;
        match self.tolerances {
            Tolerances::Relative => {
                let small_step = step.iter().zip(x.iter()).all(|(s, xi)| s.abs() <= tol * xi.abs().max(1.0));
                small_step || before - after <= opts.cost_tolerance * before.max(1e-300)
            }
            Tolerances::Offset => {
                let small_step = step.iter().zip(trial.iter()).all(|(s, t)| s.abs() <= tol * (1.0 + t.abs()));
                small_step || before - after <= opts.cost_tolerance * (1.0 + before) && after < before
            }
        }
    }
}

/// (JᵀJ, Jᵀr) for residuals r and their Jacobian J.
pub type NormalEquations<D> = (OMatrix<f64, D, D>, OVector<f64, D>);

/// A least-squares problem in `D` parameters, as [`solve`] sees it.
pub trait Problem<D: Dim>
where
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    /// The cost (sum of squared residuals) at the start, or why there is none.
    fn start(&mut self, x: &OVector<f64, D>) -> Result<f64, LmError>;
    /// The cost at a trial point; `None` where the problem refuses the point.
    fn cost(&mut self, x: &OVector<f64, D>) -> Option<f64>;
    /// The trial point last passed to [`Problem::cost`] becomes the current one.
    fn accept(&mut self) {}
    /// The normal equations at the current point `x`; `None` if they cannot be formed there.
    fn normal_equations(&mut self, x: &OVector<f64, D>) -> Option<NormalEquations<D>>;
    /// Move a point onto a constraint the problem keeps (default: none).
    fn project(&self, _x: &mut OVector<f64, D>) {}
    /// Residuals less parameters, when known (for [`LmOptions::within_se`]).
    fn dof(&self) -> Option<usize> {
        None
    }
}

/// A step's length in standard errors of the estimate: stepᵀ a step over
/// the residual variance cost / dof (a the undamped normal matrix, whose
/// inverse times that variance is the estimate's covariance).
fn step_in_se<D: Dim>(a: &OMatrix<f64, D, D>, step: &OVector<f64, D>, cost: f64, dof: usize) -> f64
where
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    let s2 = cost / dof.max(1) as f64;
    (step.dot(&(a * step)) / s2).sqrt()
}

/// Where [`solve`] ended.
#[derive(Debug, Clone)]
pub struct Solution<D: Dim>
where
    DefaultAllocator: Allocator<D>,
{
    pub x: OVector<f64, D>,
    /// Sum of squared residuals at `x`.
    pub cost: f64,
    pub iterations: usize,
    pub converged: bool,
}

/// Minimise a [`Problem`]'s cost from `x0`.
pub fn solve<D, P>(
    problem: &mut P,
    x0: OVector<f64, D>,
    opts: &LmOptions,
    strategy: &Strategy,
) -> Result<Solution<D>, LmError>
where
    D: Dim,
    P: Problem<D>,
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    let mut x = x0;
    problem.project(&mut x);
    let mut cost = problem.start(&x)?;
    let mut lambda = strategy.initial_damping;
    let mut converged = false;
    let mut iterations = 0;
    'outer: while iterations < opts.max_iterations {
        iterations += 1;
        let Some((a, g)) = problem.normal_equations(&x) else {
            break;
        };
        let mut trials = 0;
        loop {
            if trials == strategy.max_trials {
                break 'outer;
            }
            trials += 1;
            let mut damped = a.clone();
            for i in 0..a.nrows() {
                damped[(i, i)] += lambda * a[(i, i)].max(strategy.diagonal_floor);
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                if lambda > strategy.max_damping {
                    break 'outer;
                }
                continue;
            };
            let step = chol.solve(&(-&g));
            // A step shorter than the tolerance, in standard errors, ends the
            // search whether or not it lowers the cost: the estimate is
            // there to within a small fraction of its spread.
            let negligible = match (opts.within_se, problem.dof()) {
                (Some(tol), Some(dof)) => step_in_se(&a, &step, cost, dof) <= tol,
                _ => false,
            };
            let mut trial = &x + &step;
            problem.project(&mut trial);
            if let Some(c) = problem.cost(&trial).filter(|c| *c <= cost) {
                let done = negligible || strategy.small(opts, &step, &x, &trial, cost, c);
                problem.accept();
                x = trial;
                cost = c;
                let (times, over) = strategy.shrink;
                lambda = (lambda * times / over).max(1e-12);
                if done {
                    converged = true;
                    break 'outer;
                }
                break;
            }
            if negligible {
                converged = true;
                break 'outer;
            }
            lambda *= strategy.grow;
            if lambda > strategy.max_damping {
                // No step lowers the cost: we are at the minimum to working precision.
                converged = true;
                break 'outer;
            }
        }
    }
    Ok(Solution { x, cost, iterations, converged })
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

/// Column `j` of the forward-difference Jacobian of `f` at `x`, whose
/// residuals are `r0`; backward where the forward probe is refused (a bound
/// may be just past `x`). `None` if both are.
fn column<F>(f: &mut F, x: &[f64], r0: &[f64], fd_step: f64, j: usize) -> Option<Vec<f64>>
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
    let m = r0.len();
    let h = fd_step * x[j].abs().max(1.0);
    let mut xp = x.to_vec();
    let mut r = Vec::with_capacity(m);
    xp[j] = x[j] + h;
    if f(&xp, &mut r) && r.len() == m {
        return Some(r.iter().zip(r0).map(|(a, b)| (a - b) / h).collect());
    }
    xp[j] = x[j] - h;
    r.clear();
    (f(&xp, &mut r) && r.len() == m).then(|| r0.iter().zip(&r).map(|(a, b)| (a - b) / h).collect())
}

fn to_matrix(m: usize, columns: Vec<Vec<f64>>) -> DMatrix<f64> {
    let n = columns.len();
    DMatrix::from_iterator(m, n, columns.into_iter().flatten())
}

fn sum_of_squares(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Residuals `f(x, r) -> accepted` and their forward-difference Jacobian:
/// probed one column after the other ([`Serial`]) or each column on a core
/// of its own ([`Parallel`]; the same numbers).
trait Residuals {
    fn eval(&mut self, x: &[f64], r: &mut Vec<f64>) -> bool;
    fn jacobian(&mut self, x: &[f64], r0: &[f64], fd_step: f64) -> Option<DMatrix<f64>>;
}

struct Serial<F>(F);

impl<F: FnMut(&[f64], &mut Vec<f64>) -> bool> Residuals for Serial<F> {
    fn eval(&mut self, x: &[f64], r: &mut Vec<f64>) -> bool {
        (self.0)(x, r)
    }

    fn jacobian(&mut self, x: &[f64], r0: &[f64], fd_step: f64) -> Option<DMatrix<f64>> {
        let columns = (0..x.len()).map(|j| column(&mut self.0, x, r0, fd_step, j)).collect::<Option<Vec<_>>>()?;
        Some(to_matrix(r0.len(), columns))
    }
}

struct Parallel<F>(F);

impl<F: Fn(&[f64], &mut Vec<f64>) -> bool + Sync> Residuals for Parallel<F> {
    fn eval(&mut self, x: &[f64], r: &mut Vec<f64>) -> bool {
        (self.0)(x, r)
    }

    fn jacobian(&mut self, x: &[f64], r0: &[f64], fd_step: f64) -> Option<DMatrix<f64>> {
        use rayon::prelude::*;
        let f = &self.0;
        let columns = (0..x.len())
            .into_par_iter()
            .map(|j| column(&mut |x: &[f64], r: &mut Vec<f64>| f(x, r), x, r0, fd_step, j))
            .collect::<Option<Vec<_>>>()?;
        Some(to_matrix(r0.len(), columns))
    }
}

/// A residual closure with its finite-difference Jacobian.
struct FiniteDifferences<R> {
    f: R,
    fd_step: f64,
    /// Parameters.
    n: usize,
    /// Residuals at the current point, and at the last trial.
    residuals: Vec<f64>,
    trial: Vec<f64>,
}

impl<R: Residuals> Problem<Dyn> for FiniteDifferences<R> {
    fn start(&mut self, x: &DVector<f64>) -> Result<f64, LmError> {
        if !self.f.eval(x.as_slice(), &mut self.residuals) || self.residuals.iter().any(|v| !v.is_finite()) {
            return Err(LmError::BadStart);
        }
        if self.residuals.len() < x.len() {
            return Err(LmError::Underdetermined { residuals: self.residuals.len(), params: x.len() });
        }
        self.trial = Vec::with_capacity(self.residuals.len());
        Ok(sum_of_squares(&self.residuals))
    }

    fn cost(&mut self, x: &DVector<f64>) -> Option<f64> {
        self.trial.clear();
        let ok = self.f.eval(x.as_slice(), &mut self.trial) && self.trial.iter().all(|v| v.is_finite());
        ok.then(|| sum_of_squares(&self.trial))
    }

    fn accept(&mut self) {
        std::mem::swap(&mut self.residuals, &mut self.trial);
    }

    fn dof(&self) -> Option<usize> {
        self.residuals.len().checked_sub(self.n)
    }

    fn normal_equations(&mut self, x: &DVector<f64>) -> Option<NormalEquations<Dyn>> {
        let jac = self.f.jacobian(x.as_slice(), &self.residuals, self.fd_step)?;
        let jt = jac.transpose();
        let a = &jt * &jac;
        let g = &jt * DVector::from_column_slice(&self.residuals);
        Some((a, g))
    }
}

fn run<R: Residuals>(f: R, x0: &[f64], opts: LmOptions) -> Result<LmResult, LmError> {
    let mut problem =
        FiniteDifferences { f, fd_step: opts.fd_step, n: x0.len(), residuals: Vec::new(), trial: Vec::new() };
    let out = solve(&mut problem, DVector::from_column_slice(x0), &opts, &Strategy::FIT)?;
    Ok(LmResult {
        x: out.x.as_slice().to_vec(),
        residuals: problem.residuals,
        ssr: out.cost,
        iterations: out.iterations,
        converged: out.converged,
    })
}

/// Minimise the sum of squares of `f(x)`; `f` fills its residuals and returns
/// `false` where the model refuses `x`.
pub fn minimize<F>(f: F, x0: &[f64], opts: LmOptions) -> Result<LmResult, LmError>
where
    F: FnMut(&[f64], &mut Vec<f64>) -> bool,
{
    run(Serial(f), x0, opts)
}

/// [`minimize`] with the Jacobian's columns probed on the cores there are:
/// the same numbers, for a forward model that costs a fraction of a
/// millisecond or more per evaluation (the FE layer model), where the
/// probes are most of a fit's wall time.
pub fn minimize_parallel<F>(f: F, x0: &[f64], opts: LmOptions) -> Result<LmResult, LmError>
where
    F: Fn(&[f64], &mut Vec<f64>) -> bool + Sync,
{
    run(Parallel(f), x0, opts)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Matrix2, U2, Vector2};

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

    /// Rosenbrock's valley with its analytic Jacobian on fixed-size matrices,
    /// optionally held on the parabola x1 = x0^2 (a projection, as the frame
    /// fit ties the contact radius to the depth).
    struct Valley {
        on_parabola: bool,
    }

    impl Valley {
        fn residuals(x: &Vector2<f64>) -> [f64; 2] {
            [10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]]
        }
    }

    impl Problem<U2> for Valley {
        fn start(&mut self, x: &Vector2<f64>) -> Result<f64, LmError> {
            self.cost(x).ok_or(LmError::BadStart)
        }
        fn cost(&mut self, x: &Vector2<f64>) -> Option<f64> {
            Some(sum_of_squares(&Self::residuals(x)))
        }
        fn normal_equations(&mut self, x: &Vector2<f64>) -> Option<NormalEquations<U2>> {
            let j = Matrix2::new(-20.0 * x[0], 10.0, -1.0, 0.0);
            let r = Vector2::from(Self::residuals(x));
            Some((j.transpose() * j, j.transpose() * r))
        }
        fn project(&self, x: &mut Vector2<f64>) {
            if self.on_parabola {
                x[1] = x[0] * x[0];
            }
        }
    }

    #[test]
    fn both_strategies_solve_an_analytic_problem_on_the_stack() {
        let opts = LmOptions {
            max_iterations: 500,
            cost_tolerance: 1e-16,
            step_tolerance: 1e-12,
            fd_step: 0.0,
            within_se: None,
        };
        for strategy in [Strategy::FIT, Strategy::FIELD] {
            for on_parabola in [false, true] {
                let out = solve(&mut Valley { on_parabola }, Vector2::new(-1.2, 1.0), &opts, &strategy).unwrap();
                assert!((out.x[0] - 1.0).abs() < 1e-6 && (out.x[1] - 1.0).abs() < 1e-6, "{strategy:?}: {:?}", out.x);
                assert!(out.cost < 1e-12 && out.iterations < opts.max_iterations, "{strategy:?}: {out:?}");
                if on_parabola {
                    assert_eq!(out.x[1], out.x[0] * out.x[0]);
                }
            }
        }
    }

    /// A straight line through noisy points, its model rippled in the last
    /// digits as the FE contact's nodes ripple it: the search told to stop
    /// within a hundredth of a standard error ends there (against the exact
    /// least-squares line) in fewer evaluations than it spends otherwise
    /// proving it is at the minimum.
    #[test]
    fn a_search_stops_within_the_standard_errors_it_is_given() {
        let mut rng = sim::rng::Rng::seed_from(7);
        let ts: Vec<f64> = (0..40).map(|i| i as f64 / 39.0).collect();
        let ys: Vec<f64> = ts.iter().map(|t| 1.0 + 2.0 * t + rng.normal()).collect();
        // Exact least squares and its covariance (unit weights, s² from the residuals).
        let n = ts.len() as f64;
        let (st, sy) = (ts.iter().sum::<f64>(), ys.iter().sum::<f64>());
        let stt = ts.iter().map(|t| t * t).sum::<f64>();
        let sty = ts.iter().zip(&ys).map(|(t, y)| t * y).sum::<f64>();
        let det = n * stt - st * st;
        let exact = [(stt * sy - st * sty) / det, (n * sty - st * sy) / det];
        let ssr: f64 = ts.iter().zip(&ys).map(|(t, y)| (exact[0] + exact[1] * t - y).powi(2)).sum();
        let s2 = ssr / (n - 2.0);
        let se = [(s2 * stt / det).sqrt(), (s2 * n / det).sqrt()];
        let run = |within_se: Option<f64>| {
            let mut evals = 0usize;
            let out = minimize(
                |p, r| {
                    evals += 1;
                    r.clear();
                    let ripple = 1e-8 * (p[0] * 1e8).sin();
                    r.extend(ts.iter().zip(&ys).map(|(t, y)| p[0] + p[1] * t - y + ripple));
                    true
                },
                &[0.0, 0.0],
                LmOptions { within_se, ..LmOptions::default() },
            )
            .unwrap();
            (out, evals)
        };
        let (loose, loose_evals) = run(Some(0.01));
        let (strict, strict_evals) = run(None);
        for k in 0..2 {
            let off = (loose.x[k] - exact[k]).abs() / se[k];
            assert!(off < 0.01, "parameter {k}: {off} standard errors from the optimum");
            assert!((strict.x[k] - exact[k]).abs() / se[k] < 0.01);
        }
        assert!(loose.converged);
        // Measured: 13 evaluations against 22.
        assert!(3 * loose_evals < 2 * strict_evals, "{loose_evals} evaluations against {strict_evals}");
    }
}
