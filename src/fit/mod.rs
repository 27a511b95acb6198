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
    // Start the full fit from the paper's answer where that is physical.
    let start = ModelParams { e1_mpa: paper.e1_mpa, nu1: paper.nu1, contact_offset_mm: 0.0 };
    let full = fit_full(rec, &opts.full, start)?;
    Ok(Calibration { paper, full })
}
