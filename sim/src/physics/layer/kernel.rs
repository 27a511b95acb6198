//! The layer's surface response in Hankel space (docs/physics.md, "Layered contact").
//!
//! A pressure p(r) on an elastic layer of thickness h on a rigid base moves its
//! surface by u(r) = (2/E*) ∫ K(ξh) p̄(ξ) J0(ξr) dξ, p̄ the order-0 Hankel
//! transform of p; a half-space has K = 1. The solver needs the deficit
//! M = 1 - K, which decays like e^(-2t), and its cosine transform
//! C(y) = ∫ M(x) cos(xy) dx, tabulated once per material as a Chebyshev series.
//! Torsion is the same with order-1 transforms and K_t(t) = tanh t.

use crate::physics::params::LayerBase;
use crate::physics::quadrature::{Chebyshev, UniformTable, gauss_legendre};

/// Where the deficits are below 1e-18: the cosine transforms stop there.
const X_MAX: f64 = 24.0;

/// Normal-load deficit M(t) = 1 - K(t) at t = ξh.
///
/// Bonded base, with κ = 3 - 4ν: K = (2κ sinh 2t - 4t) / (2κ cosh 2t + 1 + κ² + 4t²)
/// (thin compressible limit: the oedometric h(1+ν)(1-2ν)/(E(1-ν)); incompressible:
/// the lubrication limit h³ξ²/E). Sliding base: K = (cosh 2t - 1) / (sinh 2t + 2t).
/// Written in e^(-2t) for large t so nothing overflows or cancels.
pub fn normal_deficit(base: LayerBase, nu: f64, t: f64) -> f64 {
    let e2 = (-2.0 * t).exp();
    match base {
        LayerBase::Bonded => {
            let k = 3.0 - 4.0 * nu;
            let q = 1.0 + k * k + 4.0 * t * t;
            if t < 1.0 {
                let (s, c) = ((2.0 * t).sinh(), (2.0 * t).cosh());
                (2.0 * k * (c - s) + q + 4.0 * t) / (2.0 * k * c + q)
            } else {
                (2.0 * k * e2 * e2 + (q + 4.0 * t) * e2) / (k * (1.0 + e2 * e2) + q * e2)
            }
        }
        LayerBase::Sliding => {
            if t < 1.0 {
                let sh = t.sinh();
                1.0 - 2.0 * sh * sh / ((2.0 * t).sinh() + 2.0 * t)
            } else {
                2.0 * e2 * (1.0 + 2.0 * t - e2) / (1.0 - e2 * e2 + 4.0 * t * e2)
            }
        }
    }
}

/// Torsion deficit 1 - tanh t of a layer bonded to its base (thin limit: simple
/// shear, u = τh/G).
pub fn torsion_deficit(t: f64) -> f64 {
    let e2 = (-2.0 * t).exp();
    2.0 * e2 / (1.0 + e2)
}

/// Grid intervals per unit of y of the solver's lookup table (Δ = 1/500: the
/// interpolation error ~ Δ⁴ max|C⁗| / 24 stays below 1e-12).
const TABLE_PER_UNIT: f64 = 500.0;

/// The cosine transform on a fine uniform grid, for the solver's many lookups.
pub fn cosine_table(m: impl Fn(f64) -> f64, y_max: f64) -> UniformTable {
    let y_max = y_max.max(1.0);
    let series = cosine_transform(m, y_max);
    UniformTable::from_fn(y_max, (TABLE_PER_UNIT * y_max).ceil() as usize, |y| series.eval(y))
}

/// C(y) = ∫_0^X_MAX m(x) cos(x y) dx as a Chebyshev series on [0, y_max].
pub fn cosine_transform(m: impl Fn(f64) -> f64, y_max: f64) -> Chebyshev {
    let y_max = y_max.max(1.0);
    // Panels of width 0.5, enough nodes per panel to resolve cos(x y_max).
    let per_panel = 10 + (0.5 * y_max).ceil() as usize;
    let (gx, gw) = gauss_legendre(per_panel);
    let panels = (X_MAX / 0.5) as usize;
    let mut xs = Vec::with_capacity(panels * per_panel);
    let mut ws = Vec::with_capacity(panels * per_panel);
    for p in 0..panels {
        let lo = 0.5 * p as f64;
        for (x, w) in gx.iter().zip(&gw) {
            let xi = lo + 0.25 * (x + 1.0);
            xs.push(xi);
            ws.push(0.25 * w * m(xi));
        }
    }
    // C is analytic in a strip |Im y| < 2 (the deficit decays like e^(-2x)):
    // the series converges geometrically; this many terms reach ~1e-13.
    let n = 40 + (8.0 * y_max).ceil() as usize;
    Chebyshev::fit(y_max, n, |y| xs.iter().zip(&ws).map(|(x, w)| w * (x * y).cos()).sum())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deficits_have_their_limits_and_both_forms_agree() {
        for base in [LayerBase::Bonded, LayerBase::Sliding] {
            for nu in [0.2, 0.45, 0.5] {
                assert!((normal_deficit(base, nu, 1e-9) - 1.0).abs() < 1e-6, "{base:?} {nu}");
                assert!(normal_deficit(base, nu, 30.0) < 1e-20);
                // The two branches meet at t = 1.
                let (a, b) = (normal_deficit(base, nu, 1.0 - 1e-12), normal_deficit(base, nu, 1.0));
                assert!((a - b).abs() < 1e-10, "{base:?} {nu}: {a} {b}");
            }
        }
        // Thin bonded layer: K ~ t (1-2ν)/(2(1-ν)²), i.e. the oedometric compliance.
        let (nu, t) = (0.3f64, 1e-4);
        let k = 1.0 - normal_deficit(LayerBase::Bonded, nu, t);
        let expect = t * (1.0 - 2.0 * nu) / (2.0 * (1.0 - nu).powi(2));
        assert!((k / expect - 1.0).abs() < 1e-3, "{k} vs {expect}");
        // Incompressible: K ~ 2t³/3.
        let t = 1e-2;
        let k = 1.0 - normal_deficit(LayerBase::Bonded, 0.5, t);
        assert!((k / (2.0 * t * t * t / 3.0) - 1.0).abs() < 1e-3, "{k}");
        assert!((torsion_deficit(0.3) - (1.0 - 0.3f64.tanh())).abs() < 1e-15);
    }

    #[test]
    fn cosine_transform_matches_a_closed_form() {
        // ∫ e^(-2x) cos(xy) dx = 2 / (4 + y²).
        let c = cosine_transform(|x| (-2.0 * x).exp(), 8.0);
        for i in 0..=80 {
            let y = 0.1 * i as f64;
            assert!((c.eval(y) - 2.0 / (4.0 + y * y)).abs() < 1e-12, "{y}: {}", c.eval(y));
        }
    }
}
