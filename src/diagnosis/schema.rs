//! The result schema of a diagnosis: what `easycalib diagnose --json` writes
//! (documented in docs/diagnosis.md). Plain data; the steps that fill it live
//! in the sibling modules.

use serde::Serialize;
use sim::effects::SimProfile;

use super::locate::{Quantity, SegmentReport};
use crate::fit::Warning;

/// RMS residuals per reading group.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Rms {
    /// gamma1 over the normal sweep (dead band agreeing excluded), µm.
    pub normal_um: f64,
    /// gamma1 while the torsion sweep holds the depth, µm.
    pub hold_um: f64,
    /// theta1 over the torsion sweep, degrees.
    pub torsion_deg: f64,
}

/// One model's fit of the recording.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FitSummary {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    pub contact_offset_mm: f64,
    pub ci95: Ci95,
    pub rms: Rms,
    /// chi² per degree of freedom against the noise floor (about 1 when only noise is left).
    pub chi2_per_dof: f64,
}

pub use crate::fit::Ci95;

/// A systematic residual: where and what shape.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Mismatch {
    /// "normal/load", "normal/unload", "torsion/hold", "torsion/out", "torsion/back".
    pub phase: &'static str,
    pub quantity: Quantity,
    /// Variable of `from`/`to`: "gamma1_mm", "t_s" or "rot_deg".
    pub axis: &'static str,
    pub from: f64,
    pub to: f64,
    pub shape: String,
    /// RMS residual of the branch (µm for gamma1, degrees for theta1).
    pub rms: f64,
}

/// A fitted parameter of a named effect.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamEstimate {
    pub name: &'static str,
    pub unit: &'static str,
    pub value: f64,
    /// 95 % interval (null for an open end: the data do not bound it).
    pub ci95: [Option<f64>; 2],
    /// False when the interval is open or wider than the value itself.
    pub well_determined: bool,
}

/// A named effect with its parameters.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Explained {
    pub effect: &'static str,
    /// The left-out physics in one sentence.
    pub sentence: &'static str,
    pub params: Vec<ParamEstimate>,
}

/// An effect that cannot be told apart from a change of E1/nu1 with these sweeps.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Degenerate {
    pub effect: &'static str,
    /// Variance inflation of its parameter against E1, nu1 and z0
    /// (1: independent; above 1000: E1/nu1 can stand in for it).
    pub vif: f64,
    pub reason: String,
    /// The extra measurement that would separate it.
    pub separate_by: Option<&'static str>,
}

/// One of several explanations the sweeps cannot rank (BIC within the
/// ambiguity margin of the best: docs/diagnosis.md, "3. Explain").
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Alternative {
    pub effects: Vec<&'static str>,
    /// BIC above the best explanation's (0 for the best itself).
    pub delta_bic: f64,
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    /// 95 % intervals of E1 and nu1 under this explanation.
    pub ci95: Ci95,
}

/// How one candidate (or pair) fared.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CandidateScore {
    pub effects: Vec<&'static str>,
    /// chi² gain over the model it extends (baseline, or the best single effect for a pair).
    pub delta_chi2: f64,
    /// BIC change against that model (negative: better).
    pub delta_bic: f64,
    pub significant: bool,
    pub chi2_per_dof: f64,
    /// Largest variance inflation of the added parameters against E1, nu1 and z0
    /// (computed for significant candidates only).
    pub vif: Option<f64>,
}

/// Residuals of one sample before and after correction (reading units; None: nothing to compare).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SampleResidual {
    pub t_s: f64,
    pub torsion: bool,
    pub gamma1_before_mm: Option<f64>,
    pub gamma1_after_mm: Option<f64>,
    pub theta1_before_deg: Option<f64>,
    pub theta1_after_deg: Option<f64>,
}

/// How the recording's per-sample standard errors were used: the factor each
/// channel's errors were multiplied by before judging the residuals (1 when
/// they account for the scatter between samples; never below 1). `None`: the
/// channel has no recorded errors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StandardErrors {
    pub gamma1_factor: Option<f64>,
    pub theta1_factor: Option<f64>,
}

impl StandardErrors {
    /// Whether a channel's recorded errors were found too small and inflated.
    pub fn inflated(&self) -> bool {
        self.gamma1_factor.is_some_and(|k| k > 1.0) || self.theta1_factor.is_some_and(|k| k > 1.0)
    }
}

/// The diagnosis of one recording. Its JSON form is documented in docs/diagnosis.md.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Diagnosis {
    /// Named effects (empty on a clean recording or when unexplained).
    pub effects: Vec<&'static str>,
    /// A systematic mismatch remains that no effect of the library explains.
    pub unexplained: bool,
    /// Best estimate after correction.
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    /// Noise floor used (gamma1 in µm for normal_um and hold_um, theta1 in degrees);
    /// with recorded standard errors, their median times the factor applied.
    pub noise: Rms,
    /// Present when the recording carries per-sample standard errors.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub standard_errors: Option<StandardErrors>,
    pub baseline: FitSummary,
    pub corrected: FitSummary,
    /// Where the baseline's residuals are systematic.
    pub mismatch: Vec<Mismatch>,
    /// What is still systematic after correction.
    pub remaining: Vec<Mismatch>,
    pub explanation: Vec<Explained>,
    pub degenerate: Vec<Degenerate>,
    /// When the best explanation cannot be told from others: all of them, best first.
    pub ambiguous: Vec<Alternative>,
    pub candidates: Vec<CandidateScore>,
    /// Per-branch statistics of the baseline and the corrected fit.
    pub segments_before: Vec<SegmentReport>,
    pub segments_after: Vec<SegmentReport>,
    /// The answer in a few sentences.
    pub verdict: String,
    /// What the reader should know about the inputs and the baseline fit.
    pub warnings: Vec<Warning>,
    #[serde(skip)]
    pub residuals: Vec<SampleResidual>,
    /// Sim profile reproducing the recording (fitted material, z0, named effects).
    #[serde(skip)]
    pub profile: SimProfile,
}
