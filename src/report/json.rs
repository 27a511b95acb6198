//! The stable JSON document of a calibration: what `easycalib fit --json`
//! prints and what a run writes as `report.json` (documented in docs/cli.md).

use std::path::Path;

use serde::Serialize;
use sim::recording::{Phase, Recording};

use crate::fit::{Calibration, FullFit, PaperFit};

#[derive(Debug, Clone, Serialize)]
pub struct CalibrationOutput {
    pub recording: Option<String>,
    pub samples: SampleCounts,
    /// Best estimate: the full-model fit.
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    pub ci95: Ci95Out,
    pub paper: PaperFit,
    pub full: FullFit,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sim_truth: Option<Truth>,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct SampleCounts {
    pub normal: usize,
    pub torsion: usize,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct Ci95Out {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: [f64; 2],
    pub nu1: [f64; 2],
}

/// The true elastomer of a simulated rig.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Truth {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
}

pub fn calibration_output(
    rec: &Recording,
    cal: &Calibration,
    path: Option<&Path>,
    truth: Option<Truth>,
) -> CalibrationOutput {
    CalibrationOutput {
        recording: path.map(|p| p.display().to_string()),
        samples: SampleCounts { normal: rec.phase(Phase::Normal).count(), torsion: rec.phase(Phase::Torsion).count() },
        e1_mpa: cal.full.e1_mpa,
        nu1: cal.full.nu1,
        ci95: Ci95Out { e1_mpa: cal.full.ci95.e1_mpa, nu1: cal.full.ci95.nu1 },
        paper: cal.paper.clone(),
        full: cal.full.clone(),
        sim_truth: truth,
    }
}
