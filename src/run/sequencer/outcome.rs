//! How a run ends: who stopped it, where the stage went, and the outcome the caller fits.

use std::fmt;
use std::path::PathBuf;

use crate::run::events::RunSummary;

/// Who or what ended a run early.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Culprit {
    /// Abort or quit from the operator (key, Ctrl-C).
    Operator,
    Stage,
    Mount,
    Sensor,
    /// A move would have left the soft limits.
    Safety,
    /// The recording could not be written.
    Recording,
    /// The procedure could not go on (no contact found, depth not reached).
    Procedure,
    /// easycalib itself failed (a panic in the run): the same safe path.
    Internal,
}

impl Culprit {
    pub fn as_str(self) -> &'static str {
        match self {
            Culprit::Operator => "operator",
            Culprit::Stage => "stage",
            Culprit::Mount => "rotation mount",
            Culprit::Sensor => "sensor",
            Culprit::Safety => "safety",
            Culprit::Recording => "recording",
            Culprit::Procedure => "procedure",
            Culprit::Internal => "internal error",
        }
    }
}

/// What happened to the stage after an abort.
#[derive(Debug, Clone, PartialEq)]
pub enum Backoff {
    /// The stage backed off and stopped here, mm.
    To(f64),
    /// The stage was never homed, so its position is unknown: left where it is.
    NotHomed,
    /// Backing off failed.
    Failed(String),
}

/// Why and how a run ended early.
#[derive(Debug, Clone, PartialEq)]
pub struct AbortInfo {
    pub culprit: Culprit,
    /// What happened, naming the device and the step.
    pub message: String,
    pub backoff: Backoff,
}

impl fmt::Display for AbortInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}; motion stopped", self.message)?;
        match &self.backoff {
            Backoff::To(mm) => write!(f, "; stage backed off to {mm:.3} mm"),
            Backoff::NotHomed => write!(f, "; stage was not homed, left where it is"),
            Backoff::Failed(e) => write!(f, "; COULD NOT back the stage off: {e}"),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum RunStatus {
    Completed,
    Aborted(AbortInfo),
}

/// One experiment the closed loop ran (docs/experiments.md): why, how long, what came of it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AdaptiveStep {
    pub name: &'static str,
    pub spec: sim::experiment::ExperimentSpec,
    /// The hypotheses it was chosen to separate, and its predicted separation.
    pub why: String,
    /// Rig time it took, s.
    pub rig_time_s: f64,
    /// The diagnosis's verdict with its samples.
    pub outcome: String,
    /// E1 and nu1 the diagnosis gives with its samples (corrected when it names an effect).
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    /// 95 % intervals of `E1_MPa` and `nu1` (absent until the diagnosis after the step is made).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ci95: Option<crate::fit::Ci95>,
    /// An operator step's samples: their recording of its own (another
    /// indenter in its header, `operator_step` among its keys).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recording: Option<std::path::PathBuf>,
    /// Effects named after it (an operator step's decision; empty otherwise:
    /// the outcome's verdict names them).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub effects: Vec<&'static str>,
}

/// Rig time of one phase of the procedure.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PhaseTime {
    pub phase: &'static str,
    pub rig_time_s: f64,
}

/// Durations between phase marks; the last phase runs to `end_s`. A phase
/// marked more than once (the normal sweep's unloading after a torsion sweep
/// at its top) is summed, in the order of its first mark.
pub(super) fn phase_times(marks: &[(&'static str, f64)], end_s: f64) -> Vec<PhaseTime> {
    let mut out: Vec<PhaseTime> = Vec::new();
    for (i, &(phase, t)) in marks.iter().enumerate() {
        let next = marks.get(i + 1).map_or(end_s, |m| m.1);
        let d = (next - t).max(0.0);
        match out.iter_mut().find(|p| p.phase == phase) {
            Some(p) => p.rig_time_s += d,
            None => out.push(PhaseTime { phase, rig_time_s: d }),
        }
    }
    out
}

/// What a run leaves behind. The caller fits the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RunOutcome {
    /// The recording (written and flushed sample by sample).
    pub recording: PathBuf,
    /// Settled samples recorded.
    pub samples: usize,
    /// Sensor time from the first reading to the last, s.
    pub rig_time_s: f64,
    pub wall_time_s: f64,
    /// Stage position of first contact, mm (absolute), once found.
    pub contact_mm: Option<f64>,
    /// gamma1 noise measured before the approach, mm.
    pub noise_gamma1_mm: Option<f64>,
    /// beta = gamma2 / R2 held during the torsion sweep.
    pub torsion_beta: Option<f64>,
    /// Rig time per phase of the procedure, in order (`homing`, `approach`,
    /// `normal`, `torsion`, `retract`), by the sensor's clock.
    pub phase_rig_time_s: Vec<PhaseTime>,
    /// The experiments the closed loop ran, in order (empty without `[adaptive]`).
    pub adaptive: Vec<AdaptiveStep>,
    /// What the run warned of as it went (a step shortened to the depth
    /// limit, a sensor that timed out...), in order: the log's warnings.
    pub warnings: Vec<String>,
    pub status: RunStatus,
}

impl RunOutcome {
    pub fn completed(&self) -> bool {
        self.status == RunStatus::Completed
    }

    /// The run's summary with the fit's values (the full-model fit is the best estimate).
    pub fn summary(&self, cal: Option<&crate::fit::Calibration>) -> RunSummary {
        RunSummary {
            samples: self.samples,
            wall_time_s: self.wall_time_s,
            rig_time_s: self.rig_time_s,
            e1_mpa: cal.map(|c| c.full.e1_mpa),
            nu1: cal.map(|c| c.full.nu1),
            e1_ci95: cal.map(|c| c.full.ci95.e1_mpa),
            nu1_ci95: cal.map(|c| c.full.ci95.nu1),
            recording: Some(self.recording.display().to_string()),
            report: None,
        }
    }
}
