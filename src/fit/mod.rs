//! Fitting E1 and nu1 from a recording: the paper's method and the full-model fit.

pub mod full;
pub mod lm;
pub mod paper;
pub mod stats;

use serde::Serialize;
use sim::recording::Recording;

pub use full::{FullFit, FullOptions, ModelParams, fit_full, predict};
pub use paper::{PaperFit, PaperOptions, fit_paper};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error("not enough {what}: found {found}, need at least {need}")]
    TooFewSamples { what: String, found: usize, need: usize },
    #[error("the data cannot determine the fit: {0}")]
    Degenerate(String),
    #[error("forward model: {0}")]
    Model(String),
    #[error("fit options: {0}")]
    Options(String),
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct FitOptions {
    pub paper: PaperOptions,
    pub full: FullOptions,
}

/// Both fits of one recording. The best estimate is the full-model fit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Calibration {
    pub paper: PaperFit,
    pub full: FullFit,
}

pub fn calibrate(rec: &Recording, opts: &FitOptions) -> Result<Calibration, FitError> {
    let paper = fit_paper(rec, &opts.paper)?;
    // Start the full fit from the paper's answer where that is plausible; the
    // paper's method is fragile (a few micrometres of contact error move its
    // nu1 a lot), so otherwise, or if that start fails, start from typical
    // elastomers too and keep the best fit.
    let paper_start = ModelParams { e1_mpa: paper.e1_mpa, nu1: paper.nu1, contact_offset_mm: 0.0 };
    let plausible = paper.e1_mpa > 0.0 && (0.1..=0.49).contains(&paper.nu1);
    let first = plausible.then(|| fit_full(rec, &opts.full, paper_start));
    if let Some(Ok(full)) = first {
        return Ok(Calibration { paper, full });
    }
    let e2 = rec.meta.indenter.e_mpa;
    let mut best: Option<FullFit> = None;
    let mut last_err = first.and_then(Result::err);
    for (e1_mpa, nu1) in [(e2 / 3.0, 0.4), (e2 / 3.0, 0.25), (e2, 0.45), (e2 / 10.0, 0.35)] {
        match fit_full(rec, &opts.full, ModelParams { e1_mpa, nu1, contact_offset_mm: 0.0 }) {
            Ok(f) => {
                if best.as_ref().is_none_or(|b| fit_cost(&f) < fit_cost(b)) {
                    best = Some(f);
                }
            }
            Err(e) => last_err = Some(e),
        }
    }
    match best {
        Some(full) => Ok(Calibration { paper, full }),
        None => Err(last_err.unwrap_or_else(|| FitError::Model("no start of the full fit converged".into()))),
    }
}

/// Residual size of a full fit against its own noise floors (smaller is better).
fn fit_cost(f: &FullFit) -> f64 {
    let n = f.rms.normal_um / f.noise_floor.normal_um.max(1e-9);
    let t = f.rms.torsion_deg / f.noise_floor.torsion_deg.max(1e-12);
    n * n + t * t
}
