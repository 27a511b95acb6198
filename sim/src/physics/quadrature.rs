//! Gauss–Legendre quadrature and Chebyshev interpolation: the two numerical
//! tools of the layered-contact solver (docs/physics.md, "Layered contact").

use std::f64::consts::PI;

/// Gauss–Legendre nodes and weights on [-1, 1] (exact for polynomials of
/// degree 2n - 1). Each rule up to [`CACHED_RULES`] points is computed once
/// per process and copied out after: the layered solver asks for one at
/// every contact radius it tries, and Newton on P_n took a quarter of a solve.
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    static RULES: [std::sync::OnceLock<(Vec<f64>, Vec<f64>)>; CACHED_RULES + 1] =
        [const { std::sync::OnceLock::new() }; CACHED_RULES + 1];
    match RULES.get(n) {
        Some(cell) => cell.get_or_init(|| gauss_legendre_newton(n)).clone(),
        None => gauss_legendre_newton(n),
    }
}

/// The largest rule [`gauss_legendre`] keeps.
pub const CACHED_RULES: usize = 256;

/// [`gauss_legendre`] computed: Newton on P_n from the Chebyshev-like first guess.
fn gauss_legendre_newton(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut x = vec![0.0; n];
    let mut w = vec![0.0; n];
    for i in 0..n.div_ceil(2) {
        let mut z = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            // P_n(z) and P_n'(z) by the three-term recurrence.
            let (mut p0, mut p1) = (1.0, z);
            for k in 2..=n {
                let p2 = ((2 * k - 1) as f64 * z * p1 - (k - 1) as f64 * p0) / k as f64;
                p0 = p1;
                p1 = p2;
            }
            let pn = if n == 0 { 1.0 } else { p1 };
            let pm = if n == 0 { 0.0 } else { p0 };
            dp = n as f64 * (z * pn - pm) / (z * z - 1.0);
            let dz = pn / dp;
            z -= dz;
            if dz.abs() < 1e-16 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        let wi = 2.0 / ((1.0 - z * z) * dp * dp);
        w[i] = wi;
        w[n - 1 - i] = wi;
    }
    (x, w)
}

/// Nodes and weights of `n`-point Gauss–Legendre on [lo, hi].
pub fn gauss_legendre_on(n: usize, lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    let (x, w) = gauss_legendre(n);
    let (m, h) = (0.5 * (lo + hi), 0.5 * (hi - lo));
    (x.iter().map(|t| m + h * t).collect(), w.iter().map(|v| h * v).collect())
}

/// A function on [0, hi] as a Chebyshev series, evaluated by Clenshaw's recurrence.
#[derive(Debug, Clone, PartialEq)]
pub struct Chebyshev {
    hi: f64,
    coef: Vec<f64>,
}

impl Chebyshev {
    /// Interpolate `f` at the `n` Chebyshev points of [0, hi].
    pub fn fit(hi: f64, n: usize, f: impl Fn(f64) -> f64) -> Self {
        let vals: Vec<f64> = (0..n)
            .map(|k| {
                let u = (PI * (k as f64 + 0.5) / n as f64).cos();
                f(0.5 * hi * (u + 1.0))
            })
            .collect();
        let coef = (0..n)
            .map(|j| {
                let s: f64 =
                    vals.iter().enumerate().map(|(k, v)| v * (PI * j as f64 * (k as f64 + 0.5) / n as f64).cos()).sum();
                s * if j == 0 { 1.0 } else { 2.0 } / n as f64
            })
            .collect::<Vec<f64>>();
        // Trailing terms below rounding carry nothing: drop them (cheaper evaluation).
        let total: f64 = coef.iter().map(|c| c.abs()).sum();
        let mut coef = coef;
        while coef.len() > 1 && coef.last().is_some_and(|c| c.abs() < 1e-16 * total) {
            coef.pop();
        }
        Self { hi, coef }
    }

    pub fn upper(&self) -> f64 {
        self.hi
    }

    /// The series at `y` in [0, hi] (clamped to the interval).
    pub fn eval(&self, y: f64) -> f64 {
        let u = (2.0 * y / self.hi - 1.0).clamp(-1.0, 1.0);
        let (mut b1, mut b2) = (0.0, 0.0);
        for &c in self.coef.iter().skip(1).rev() {
            let b0 = 2.0 * u * b1 - b2 + c;
            b2 = b1;
            b1 = b0;
        }
        u * b1 - b2 + self.coef[0]
    }
}

/// A smooth function on [0, hi] sampled on a uniform grid and read back by
/// 4-point Lagrange interpolation (error ~ Δ⁴ |f⁗| / 24): a few nanoseconds a value.
#[derive(Debug, Clone, PartialEq)]
pub struct UniformTable {
    step: f64,
    values: Vec<f64>,
}

impl UniformTable {
    pub fn from_fn(hi: f64, intervals: usize, f: impl Fn(f64) -> f64) -> Self {
        let intervals = intervals.max(4);
        let step = hi / intervals as f64;
        Self { step, values: (0..=intervals).map(|i| f(i as f64 * step)).collect() }
    }

    /// The function at `y` in [0, hi] (clamped).
    pub fn eval(&self, y: f64) -> f64 {
        let last = self.values.len() - 1;
        let x = (y / self.step).clamp(0.0, last as f64);
        // Stencil i-1..i+2 around x, kept inside the table.
        // x >= 0 here, so the cast truncates as floor would (and is no libm call).
        let i = (x as usize).clamp(1, last - 2);
        let t = x - i as f64;
        let v = &self.values[i - 1..i + 3];
        let (tm, t1, t2) = (t + 1.0, t - 1.0, t - 2.0);
        -v[0] * t * t1 * t2 / 6.0 + v[1] * tm * t1 * t2 / 2.0 - v[2] * tm * t * t2 / 2.0 + v[3] * tm * t * t1 / 6.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_legendre_integrates_polynomials_exactly() {
        // 300 is past the cached rules: computed afresh each time.
        for n in [1usize, 2, 5, 16, 33, 300, 33] {
            let (x, w) = gauss_legendre(n);
            assert!((w.iter().sum::<f64>() - 2.0).abs() < 1e-13, "n {n}");
            // x^(2n-2) integrates to 2/(2n-1).
            let k = 2 * n as i32 - 2;
            let s: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(k)).sum();
            assert!((s - 2.0 / (k as f64 + 1.0)).abs() < 1e-12, "n {n}: {s}");
        }
        let (x, w) = gauss_legendre_on(20, 0.0, PI);
        let s: f64 = x.iter().zip(&w).map(|(x, w)| w * x.sin()).sum();
        assert!((s - 2.0).abs() < 1e-14, "{s}");
    }

    #[test]
    fn uniform_table_interpolates_to_fourth_order() {
        let f = |y: f64| (-y).exp() * (3.0 * y).cos();
        let t = UniformTable::from_fn(4.0, 4000, f);
        for i in 0..=1000 {
            let y = (0.004 * i as f64 + 1e-4).min(4.0);
            assert!((t.eval(y) - f(y)).abs() < 1e-12, "{y}");
        }
    }

    #[test]
    fn chebyshev_interpolates_smooth_functions() {
        let c = Chebyshev::fit(4.0, 40, |y| (-y).exp() * (3.0 * y).cos());
        for i in 0..=100 {
            let y = 0.04 * i as f64;
            assert!((c.eval(y) - (-y).exp() * (3.0 * y).cos()).abs() < 1e-12, "{y}");
        }
    }
}
