//! The paper's method: fit the reduced relations (Eq. 22 over a mid-range
//! window of gamma1, Eq. 38 through the origin) and invert them to E1, nu1
//! (exactly, and with the paper's rounded constants, Eqs. 39-40).

use serde::Serialize;
use sim::physics::{invert_exact, invert_paper_rounded, rod_correction_factor};
use sim::recording::{Phase, Recording};

use super::regression::{PAPER_WINDOW_MM, eq22_point, eq38_point, fit_eq22, fit_eq38, torsion_depth};
use super::{Ci95, FitError, Warning};
use crate::numerics::stats::interval;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PaperOptions {
    /// gamma1 window of the Eq. 22 fit, mm (the paper's mid range 0.2-0.8 mm).
    pub window_mm: [f64; 2],
}

impl Default for PaperOptions {
    fn default() -> Self {
        Self { window_mm: PAPER_WINDOW_MM }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PaperFit {
    #[serde(rename = "H1")]
    pub h1: f64,
    #[serde(rename = "H1_se")]
    pub h1_se: f64,
    #[serde(rename = "H1_ci95")]
    pub h1_ci95: [f64; 2],
    /// Nuisance coefficient of gamma1^1.5; its sign is left free (docs/physics.md 1.3).
    #[serde(rename = "H2")]
    pub h2: f64,
    #[serde(rename = "H3")]
    pub h3: f64,
    #[serde(rename = "H3_se")]
    pub h3_se: f64,
    #[serde(rename = "H3_ci95")]
    pub h3_ci95: [f64; 2],
    /// Torsion depth measured from the torsion samples, gamma2 / R2.
    pub beta: f64,
    /// c(beta) used by the exact inversion.
    pub rod_factor: f64,
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    #[serde(rename = "E1_MPa_se")]
    pub e1_se: f64,
    pub nu1_se: f64,
    pub ci95: Ci95,
    #[serde(rename = "corr_E1_nu1")]
    pub corr_e1_nu1: f64,
    #[serde(rename = "E1_MPa_rounded")]
    pub e1_mpa_rounded: f64,
    pub nu1_rounded: f64,
    pub window_mm: [f64; 2],
    pub n_normal: usize,
    pub n_torsion: usize,
    pub r2_normal: f64,
    pub r2_torsion: f64,
}

pub fn fit_paper(rec: &Recording, opts: &PaperOptions) -> Result<PaperFit, FitError> {
    let [lo, hi] = opts.window_mm;
    if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && hi > lo) {
        return Err(FitError::Options(format!("gamma1 window [{lo}, {hi}] mm is not a valid range")));
    }
    // Eq. 22: gamma2 = H1 gamma1 + H2 gamma1^1.5 over the window.
    let pts: Vec<(f64, f64)> =
        rec.sweep(Phase::Normal).filter(|s| s.gamma1_mm >= lo && s.gamma1_mm <= hi).map(eq22_point).collect();
    if pts.len() < 4 {
        return Err(FitError::TooFewSamples {
            what: format!("normal samples with gamma1 in [{lo}, {hi}] mm"),
            found: pts.len(),
            need: 4,
        });
    }
    let normal = fit_eq22(&pts).ok_or_else(|| FitError::Degenerate("Eq. 22 design matrix is singular".into()))?;

    // Eq. 38: theta2 = H3 theta1 through the origin.
    let tors: Vec<(f64, f64)> =
        rec.sweep(Phase::Torsion).filter(|s| s.theta1_deg != 0.0 || s.rot_deg != 0.0).map(eq38_point).collect();
    // One slope through the origin: two twists leave it a degree of freedom.
    if tors.len() < 2 {
        return Err(FitError::TooFewSamples { what: "torsion samples with twist".into(), found: tors.len(), need: 2 });
    }
    let torsion =
        fit_eq38(&tors).ok_or_else(|| FitError::Degenerate("theta1 is zero in every torsion sample".into()))?;

    // The depth actually reached, from the torsion samples themselves.
    let (beta, beta_se) = torsion_depth(rec.sweep(Phase::Torsion), rec.meta.indenter.r_mm).unwrap_or((f64::NAN, 0.0));
    let (h1, h1_se, h3, h3_se) = (normal.h1, normal.h1_se, torsion.h3, torsion.h3_se);

    let e2 = rec.meta.indenter.e_mpa;
    let nu2 = rec.meta.indenter.nu;
    let inv_at = |h1: f64, h3: f64, beta: f64| invert_exact(h1, h3, e2, nu2, beta);
    let best = inv_at(h1, h3, beta);
    // Delta method: H1, H3 and beta come from disjoint data, so they are independent.
    let partials = |dh1: f64, dh3: f64, db: f64| {
        let p = inv_at(h1 + dh1, h3 + dh3, beta + db);
        let m = inv_at(h1 - dh1, h3 - dh3, beta - db);
        ((p.e1_mpa - m.e1_mpa) / 2.0, (p.nu1 - m.nu1) / 2.0)
    };
    let (de_1, dn_1) = partials(h1_se, 0.0, 0.0);
    let (de_3, dn_3) = partials(0.0, h3_se, 0.0);
    let (de_b, dn_b) = partials(0.0, 0.0, beta_se);
    let e1_se = (de_1 * de_1 + de_3 * de_3 + de_b * de_b).sqrt();
    let nu1_se = (dn_1 * dn_1 + dn_3 * dn_3 + dn_b * dn_b).sqrt();
    let cov = de_1 * dn_1 + de_3 * dn_3 + de_b * dn_b;
    let corr = if e1_se > 0.0 && nu1_se > 0.0 { cov / (e1_se * nu1_se) } else { f64::NAN };
    let dof = normal.dof.min(torsion.dof);
    let rounded = invert_paper_rounded(h1, h3, e2, nu2);

    Ok(PaperFit {
        h1,
        h1_se,
        h1_ci95: interval(h1, h1_se, normal.dof),
        h2: normal.h2,
        h3,
        h3_se,
        h3_ci95: interval(h3, h3_se, torsion.dof),
        beta,
        rod_factor: rod_correction_factor(beta),
        e1_mpa: best.e1_mpa,
        nu1: best.nu1,
        e1_se,
        nu1_se,
        ci95: Ci95 { e1_mpa: interval(best.e1_mpa, e1_se, dof), nu1: interval(best.nu1, nu1_se, dof) },
        corr_e1_nu1: corr,
        e1_mpa_rounded: rounded.e1_mpa,
        nu1_rounded: rounded.nu1,
        window_mm: opts.window_mm,
        n_normal: pts.len(),
        n_torsion: tors.len(),
        r2_normal: normal.r2,
        r2_torsion: torsion.r2,
    })
}

/// The paper's method on its window, or, where the sweep puts fewer than the
/// four samples Eq. 22 needs there (a coarse sweep of a stiff pair passes
/// through 0.2-0.8 mm in two or three steps), on the narrowest widening of
/// the window that holds four, with a warning saying so. The paper's answer
/// only starts the full fit and is reported beside it; a recording the full
/// fit can take is not refused for it.
pub fn fit_paper_or_widened(rec: &Recording, opts: &PaperOptions) -> Result<(PaperFit, Option<Warning>), FitError> {
    let first = fit_paper(rec, opts);
    let Err(FitError::TooFewSamples { .. }) = &first else {
        return first.map(|p| (p, None));
    };
    let Some(window_mm) = widened_window(rec, opts.window_mm, 4) else {
        return first.map(|p| (p, None));
    };
    let p = fit_paper(rec, &PaperOptions { window_mm })?;
    let [lo, hi] = opts.window_mm;
    let w = Warning::new(
        "paper_window_widened",
        format!(
            "the normal sweep has fewer than 4 samples with gamma1 in the paper's window [{lo}, {hi}] mm; the \
             paper's method (Eq. 22) was fitted on [{:.4}, {:.4}] mm, the narrowest widening that holds 4",
            window_mm[0], window_mm[1]
        ),
    );
    Ok((p, Some(w)))
}

/// `window` widened to the nearest normal samples in contact outside it,
/// one at a time (nearest in gamma1 first), until it holds `need`; `None`
/// if it already does or the sweep has fewer in contact.
fn widened_window(rec: &Recording, window: [f64; 2], need: usize) -> Option<[f64; 2]> {
    let [mut lo, mut hi] = window;
    let g: Vec<f64> = rec.sweep(Phase::Normal).map(|s| s.gamma1_mm).filter(|&g| g > 0.0).collect();
    let inside = |lo: f64, hi: f64| g.iter().filter(|&&x| x >= lo && x <= hi).count();
    if inside(lo, hi) >= need || g.len() < need {
        return None;
    }
    while inside(lo, hi) < need {
        let gap = |x: f64| if x < lo { lo - x } else { x - hi };
        let next = g.iter().copied().filter(|&x| x < lo || x > hi).min_by(|a, b| gap(*a).total_cmp(&gap(*b)))?;
        (lo, hi) = (lo.min(next), hi.max(next));
    }
    Some([lo, hi])
}
