//! The stable JSON document of a calibration: what `easycalib fit --json`
//! prints and what a run writes as `report.json` (documented in docs/cli.md).

use std::path::Path;

use serde::Serialize;
use sim::recording::{Phase, Recording};

use crate::fit::{Calibration, Ci95, FullFit, PaperFit, Warning};

#[derive(Debug, Clone, Serialize)]
pub struct CalibrationOutput {
    pub recording: Option<String>,
    pub samples: SampleCounts,
    /// Effects the best estimate is corrected for: those the closed loop
    /// named when it decided (docs/experiments.md); empty otherwise.
    pub effects: Vec<&'static str>,
    /// Best estimate: the closed loop's decision when it decided, else the full-model fit.
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    pub ci95: Ci95,
    /// The closed-loop step whose outcome the best estimate is (absent: the full-model fit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub decided_by: Option<&'static str>,
    pub paper: PaperFit,
    pub full: FullFit,
    /// Everything the reader of the estimate should know (empty when nothing).
    pub warnings: Vec<Warning>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sim_truth: Option<Truth>,
    /// How long the run took, when a run made the recording (docs/run.md).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub run: Option<RunTimings>,
    /// The diagnosis at the end of a run (docs/run.md): the closed loop's
    /// decision when it decided (then also the top-level values); otherwise
    /// the run recording's, whose corrected values stay in here (the
    /// top-level E1_MPa and nu1 are then the calibration's).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diagnosis: Option<super::RunDiagnosis>,
    /// The run recording's own diagnosis when the decision rests on samples
    /// outside it (a rigid ball's recording): what the standard sweeps (and
    /// the loop's rig-only steps) said by themselves.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub standard: Option<super::RunDiagnosis>,
}

impl CalibrationOutput {
    /// Make the closed loop's decision the report's headline.
    pub fn apply(&mut self, d: super::Decided) {
        self.effects = d.decision.effects.iter().map(|e| e.name).collect();
        (self.e1_mpa, self.nu1, self.ci95) = (d.decision.e1_mpa, d.decision.nu1, d.decision.ci95);
        self.decided_by = Some(d.by);
        self.diagnosis = Some(d.decision);
        self.standard = d.standard;
    }
}

/// A run's timings: rig time (the sensor's clock, homing included), wall
/// time, and rig time per phase of the procedure.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunTimings {
    pub rig_time_s: f64,
    pub wall_time_s: f64,
    pub phases: Vec<crate::run::PhaseTime>,
    /// The experiments the closed loop ran (`run --adaptive`, docs/experiments.md), in order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub experiments: Vec<crate::run::AdaptiveStep>,
    /// What the run warned of as it went, in order (its log's warnings: a
    /// step shortened to the depth limit, a sensor reading that timed out).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct SampleCounts {
    pub normal: usize,
    pub torsion: usize,
}

/// The true elastomer of a simulated rig.
pub type Truth = sim::physics::Material;

pub fn calibration_output(
    rec: &Recording,
    cal: &Calibration,
    path: Option<&Path>,
    truth: Option<Truth>,
) -> CalibrationOutput {
    CalibrationOutput {
        recording: path.map(|p| p.display().to_string()),
        samples: SampleCounts { normal: rec.phase(Phase::Normal).count(), torsion: rec.phase(Phase::Torsion).count() },
        effects: Vec::new(),
        e1_mpa: cal.full.e1_mpa,
        nu1: cal.full.nu1,
        ci95: Ci95 { e1_mpa: cal.full.ci95.e1_mpa, nu1: cal.full.ci95.nu1 },
        paper: cal.paper.clone(),
        full: cal.full.clone(),
        warnings: cal.warnings.clone(),
        decided_by: None,
        sim_truth: truth,
        run: None,
        diagnosis: None,
        standard: None,
    }
}

/// Where a JSON document has no number to give, and why.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Undefined {
    /// Dotted path of the null value (`full.ci95.nu1[1]`).
    pub path: String,
    pub why: &'static str,
}

/// Why a value named `key` (the innermost object key on its path) can be absent.
fn why_null(key: &str) -> &'static str {
    match key {
        "recording" => "the recording was not read from or written to a file",
        "vif" => "variance inflation is computed only for effects that improve the fit significantly",
        "beta" => "the recording has no torsion sample at which to evaluate the torsion depth",
        k if k.contains("ci95") => {
            "open interval end: the data bound this parameter on one side only, or leave too few degrees of \
             freedom for a finite interval"
        }
        k if k.starts_with("corr") => "a standard error is zero, so the correlation is undefined",
        k if k.starts_with("r2") || k == "normal" || k == "torsion" => {
            "R² is undefined: fewer than two samples, or the observed values do not vary"
        }
        k if k.contains("noise") || k.ends_with("_um") || k.ends_with("_deg") => {
            "too few samples in this group (fewer than five) to estimate it"
        }
        k if k.contains("before") || k.contains("after") => "no reading of this kind at this sample",
        _ => "not a finite number: the computation of this quantity diverged on this recording",
    }
}

fn collect_nulls(v: &serde_json::Value, path: &str, key: &str, out: &mut Vec<Undefined>) {
    use serde_json::Value;
    match v {
        Value::Null => out.push(Undefined { path: path.to_string(), why: why_null(key) }),
        Value::Array(items) => {
            for (i, x) in items.iter().enumerate() {
                collect_nulls(x, &format!("{path}[{i}]"), key, out);
            }
        }
        Value::Object(map) => {
            for (k, x) in map {
                let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                collect_nulls(x, &p, k, out);
            }
        }
        _ => {}
    }
}

/// Pretty JSON of `value` in which no `null` goes unexplained: serde writes a
/// non-finite number as `null`, so every null is listed under a top-level
/// `undefined: [{path, why}]` (absent when there is none; docs/cli.md).
pub fn to_json_explained<T: Serialize>(value: &T) -> Result<String, serde_json::Error> {
    let mut doc = serde_json::to_value(value)?;
    let mut nulls = Vec::new();
    collect_nulls(&doc, "", "", &mut nulls);
    if !nulls.is_empty()
        && let serde_json::Value::Object(map) = &mut doc
    {
        map.insert("undefined".to_string(), serde_json::to_value(&nulls)?);
    }
    serde_json::to_string_pretty(&doc)
}
