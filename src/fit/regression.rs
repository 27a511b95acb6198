//! The paper's two regressions and the torsion depth, shared by the paper's
//! method ([`super::fit_paper`]) and the running fit of a calibration run
//! (`run::FitUpdate`): Eq. 22, gamma2 = H1 gamma1 + H2 gamma1^1.5, by least
//! squares, and Eq. 38, theta2 = H3 theta1, through the origin
//! (docs/physics.md §1.3 and §1.4).

use nalgebra::{Matrix2, Vector2};
use sim::recording::Sample;

use crate::numerics::stats::r_squared;

/// gamma1 window of the Eq. 22 fit, mm (the paper's mid range).
pub const PAPER_WINDOW_MM: [f64; 2] = [0.2, 0.8];

/// A normal-sweep sample as an Eq. 22 point (gamma1, gamma2), mm: the stage's
/// travel past contact is shared by the elastomer and the indenter.
pub fn eq22_point(s: &Sample) -> (f64, f64) {
    (s.gamma1_mm, s.stage_mm - s.gamma1_mm)
}

/// A torsion-sweep sample as an Eq. 38 point (theta1, theta2), degrees: the
/// mount's angle is shared by the elastomer and the indenter.
pub fn eq38_point(s: &Sample) -> (f64, f64) {
    (s.theta1_deg, s.rot_deg - s.theta1_deg)
}

/// Eq. 22 fitted to (gamma1, gamma2) points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eq22 {
    pub h1: f64,
    pub h2: f64,
    pub h1_se: f64,
    /// Residual degrees of freedom (points - 2).
    pub dof: usize,
    /// R² of gamma2.
    pub r2: f64,
}

/// Least-squares Eq. 22; `None` when the points cannot separate H1 from H2
/// (a singular design matrix).
pub fn fit_eq22(points: &[(f64, f64)]) -> Option<Eq22> {
    let mut xtx = Matrix2::zeros();
    let mut xty = Vector2::zeros();
    for &(g1, g2) in points {
        let row = Vector2::new(g1, g1.powf(1.5));
        xtx += row * row.transpose();
        xty += row * g2;
    }
    if xtx.determinant().abs() <= 1e-12 * (xtx[(0, 0)] * xtx[(1, 1)]).max(f64::MIN_POSITIVE) {
        return None;
    }
    let inv = xtx.try_inverse()?;
    let coef = inv * xty;
    let (h1, h2) = (coef[0], coef[1]);
    let pred: Vec<f64> = points.iter().map(|&(g1, _)| h1 * g1 + h2 * g1.powf(1.5)).collect();
    let obs: Vec<f64> = points.iter().map(|p| p.1).collect();
    let ssr: f64 = obs.iter().zip(&pred).map(|(o, p)| (o - p).powi(2)).sum();
    let dof = points.len().saturating_sub(2);
    let s2 = ssr / dof as f64;
    Some(Eq22 { h1, h2, h1_se: (s2 * inv[(0, 0)]).sqrt(), dof, r2: r_squared(&obs, &pred) })
}

/// Eq. 38 fitted to (theta1, theta2) points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eq38 {
    pub h3: f64,
    pub h3_se: f64,
    /// Residual degrees of freedom (points - 1).
    pub dof: usize,
    /// R² of theta2.
    pub r2: f64,
}

/// Eq. 38 through the origin; `None` when theta1 is zero at every point.
pub fn fit_eq38(points: &[(f64, f64)]) -> Option<Eq38> {
    let sxx: f64 = points.iter().map(|(t1, _)| t1 * t1).sum();
    let sxy: f64 = points.iter().map(|(t1, t2)| t1 * t2).sum();
    if sxx <= 0.0 {
        return None;
    }
    let h3 = sxy / sxx;
    let pred: Vec<f64> = points.iter().map(|(t1, _)| h3 * t1).collect();
    let obs: Vec<f64> = points.iter().map(|t| t.1).collect();
    let ssr: f64 = obs.iter().zip(&pred).map(|(o, p)| (o - p).powi(2)).sum();
    let dof = points.len().saturating_sub(1);
    Some(Eq38 { h3, h3_se: (ssr / dof as f64 / sxx).sqrt(), dof, r2: r_squared(&obs, &pred) })
}

/// The torsion depth beta = gamma2 / R2 the torsion samples reached: their
/// mean and its standard error (0 from a single sample); `None` without samples.
pub fn torsion_depth<'a>(torsion: impl IntoIterator<Item = &'a Sample>, indenter_r_mm: f64) -> Option<(f64, f64)> {
    let depths: Vec<f64> = torsion.into_iter().map(|s| eq22_point(s).1 / indenter_r_mm).collect();
    if depths.is_empty() {
        return None;
    }
    let n = depths.len() as f64;
    let beta = depths.iter().sum::<f64>() / n;
    let se = if depths.len() > 1 {
        (depths.iter().map(|b| (b - beta).powi(2)).sum::<f64>() / (n - 1.0) / n).sqrt()
    } else {
        0.0
    };
    Some((beta, se))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regressions_recover_exact_coefficients() {
        let pts: Vec<(f64, f64)> = (1..=8).map(|i| i as f64 * 0.1).map(|g| (g, 0.6 * g - 0.05 * g.powf(1.5))).collect();
        let f = fit_eq22(&pts).unwrap();
        assert!((f.h1 - 0.6).abs() < 1e-12 && (f.h2 + 0.05).abs() < 1e-12 && f.dof == 6, "{f:?}");
        // One gamma1 repeated cannot separate H1 from H2.
        assert_eq!(fit_eq22(&[(0.4, 0.2); 5]), None);
        let tors: Vec<(f64, f64)> = (-3..=3).map(|i| i as f64).map(|t| (t, 1.7 * t)).collect();
        let f = fit_eq38(&tors).unwrap();
        assert!((f.h3 - 1.7).abs() < 1e-12 && f.h3_se < 1e-12 && f.dof == 6, "{f:?}");
        assert_eq!(fit_eq38(&[(0.0, 1.0), (0.0, 2.0)]), None);
    }
}
