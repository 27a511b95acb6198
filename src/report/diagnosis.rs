//! The diagnosis at the end of a run (docs/run.md): what `easycalib diagnose`
//! would say of the recording the run just wrote, reduced to what the run's
//! report, the CLI's last lines and the TUI's final panel show. A diagnosis
//! that fails never fails the run: the report says why it is missing.

use std::time::Instant;

use serde::Serialize;
use sim::recording::Recording;

use crate::diagnosis::{DiagnoseOptions, Diagnosis, ParamEstimate, diagnose, prose};
use crate::fit::{Calibration, Ci95};

/// The diagnosis' answer in one word (the `diagnosis.verdict` of report.json).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VerdictClass {
    /// Nothing named and nothing systematic left over.
    Clean,
    /// One or more effects named, E1 and nu1 corrected for them.
    Effects,
    /// Several explanations fit equally well; none is named.
    Ambiguous,
    /// A systematic mismatch remains that no effect of the library explains.
    Unexplained,
    /// The diagnosis failed; `error` says why.
    NotMade,
}

impl VerdictClass {
    /// The class of a diagnosis, decided in the order the verdict's prose uses.
    pub fn of(d: &Diagnosis) -> Self {
        if d.unexplained {
            Self::Unexplained
        } else if !d.ambiguous.is_empty() {
            Self::Ambiguous
        } else if d.effects.is_empty() {
            Self::Clean
        } else {
            Self::Effects
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            Self::Clean => "clean",
            Self::Effects => "effects",
            Self::Ambiguous => "ambiguous",
            Self::Unexplained => "unexplained",
            Self::NotMade => "not_made",
        }
    }
}

/// A named effect and its fitted parameters.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EffectFound {
    pub name: &'static str,
    pub params: Vec<ParamEstimate>,
}

/// The diagnosis as a run reports it: `diagnosis` in report.json (docs/run.md).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunDiagnosis {
    pub verdict: VerdictClass,
    /// The diagnosis in a few lines (the CLI prints them at the end of a run).
    pub summary: String,
    /// Named effects with their parameters (empty unless `verdict` is `effects`).
    pub effects: Vec<EffectFound>,
    /// E1 corrected for the named effects; the calibration's (the baseline)
    /// when nothing is named.
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    pub ci95: Ci95,
    /// Where the named effects' fit places the first contact, mm from the
    /// recording's stage zero (present only when effects are named). A run
    /// moves its zero to the calibration's contact, and the calibration
    /// models no effect: under a compliant frame it reads the frame's give
    /// as a later contact (docs/run.md, "Stage zero"). Absent, not NaN, when
    /// that fit gives no finite contact.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact_offset_mm: Option<f64>,
    /// Why the diagnosis could not be made (`verdict` is `not_made`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Wall time the diagnosis took, s.
    pub wall_time_s: f64,
}

impl RunDiagnosis {
    /// The report of diagnosis `d`; `cal` is the run's calibration, the baseline.
    pub fn from_diagnosis(d: &Diagnosis, cal: &Calibration, wall_time_s: f64) -> Self {
        let verdict = VerdictClass::of(d);
        let named = verdict == VerdictClass::Effects;
        let (e1_mpa, nu1, ci95) =
            if named { (d.corrected.e1_mpa, d.corrected.nu1, d.corrected.ci95) } else { baseline(cal) };
        let effects = if named {
            d.explanation.iter().map(|e| EffectFound { name: e.effect, params: e.params.clone() }).collect()
        } else {
            Vec::new()
        };
        let contact_offset_mm = named.then_some(d.corrected.contact_offset_mm).filter(|z| z.is_finite());
        Self {
            verdict,
            summary: prose::brief(d),
            effects,
            e1_mpa,
            nu1,
            ci95,
            contact_offset_mm,
            error: None,
            wall_time_s,
        }
    }

    /// A diagnosis that failed with `why`: E1 and nu1 are the calibration's.
    pub fn not_made(why: String, cal: &Calibration, wall_time_s: f64) -> Self {
        let (e1_mpa, nu1, ci95) = baseline(cal);
        Self {
            verdict: VerdictClass::NotMade,
            summary: prose::not_made(&why),
            effects: Vec::new(),
            e1_mpa,
            nu1,
            ci95,
            contact_offset_mm: None,
            error: Some(why),
            wall_time_s,
        }
    }

    /// Whether E1 and nu1 differ from the calibration's because effects were named.
    pub fn corrected(&self) -> bool {
        self.verdict == VerdictClass::Effects
    }

    /// The first line of a closed loop's decision ([`Decided`]), which names
    /// the step it came after; `None` for a recording's own diagnosis.
    pub fn closed_loop(&self) -> Option<&str> {
        self.summary.lines().next().filter(|l| l.starts_with(CLOSED_LOOP))
    }
}

/// How the summary of a closed loop's decision begins ([`RunDiagnosis::closed_loop`]).
pub const CLOSED_LOOP: &str = "CLOSED LOOP, after ";

/// The calibration's full-model E1, nu1 and intervals.
fn baseline(cal: &Calibration) -> (f64, f64, Ci95) {
    (cal.full.e1_mpa, cal.full.nu1, Ci95 { e1_mpa: cal.full.ci95.e1_mpa, nu1: cal.full.ci95.nu1 })
}

/// Diagnose the run's recording `rec`, calibrated as `cal`. Never fails: an
/// error of the diagnosis, or a panic inside it, becomes a `not_made` report.
/// The diagnosis refits the baseline itself: on a run's few hundred samples
/// the full-model fit is a small share of its cost, and it needs its own
/// noise-floor weighting (docs/diagnosis.md).
pub fn diagnose_run(rec: &Recording, cal: &Calibration, opts: &DiagnoseOptions) -> RunDiagnosis {
    let start = Instant::now();
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| diagnose(rec, opts)));
    let took = start.elapsed().as_secs_f64();
    match result {
        Ok(Ok(d)) => RunDiagnosis::from_diagnosis(&d, cal, took),
        Ok(Err(e)) => RunDiagnosis::not_made(e.to_string(), cal, took),
        Err(panic) => {
            let what = crate::run::sequencer::panic_message(panic.as_ref());
            RunDiagnosis::not_made(format!("the diagnosis panicked: {what}"), cal, took)
        }
    }
}

/// The closed loop's decision as a run reports it (docs/experiments.md, "The
/// headline after the loop"): the report's best estimate, its `diagnosis`,
/// the CLI's last lines and the TUI's final panel show it.
#[derive(Debug, Clone, PartialEq)]
pub struct Decided {
    /// The loop's step the decision came after.
    pub by: &'static str,
    pub decision: RunDiagnosis,
    /// The run recording's own diagnosis, when the decision is not it (the
    /// rigid ball's samples are in a recording of their own).
    pub standard: Option<RunDiagnosis>,
}

impl Decided {
    /// After rig-only steps, whose samples are in the run's recording: its
    /// diagnosis is the decision when it names effects.
    pub fn by_recording(by: &'static str, d: &RunDiagnosis) -> Option<Self> {
        let summary = format!("{CLOSED_LOOP}{by}: {}", d.summary);
        d.corrected().then(|| Self { by, decision: RunDiagnosis { summary, ..d.clone() }, standard: None })
    }

    /// After a rigid ball that ruled the gain out and named another of the
    /// standing explanations: `settled`, the run recording's diagnosis with
    /// that explanation named; `None` if it names nothing after all.
    pub fn by_ball_ranking(settled: RunDiagnosis, standard: Option<RunDiagnosis>) -> Option<Self> {
        use std::fmt::Write;
        if !settled.corrected() {
            return None;
        }
        let mut summary = format!("{CLOSED_LOOP}rigid_ball: {}", settled.summary);
        if let Some(first) = standard.as_ref().and_then(|s| s.summary.lines().next()) {
            if !summary.ends_with('\n') {
                summary.push('\n');
            }
            let _ = writeln!(summary, "  the run's recording alone: {first}");
        }
        Some(Self { by: "rigid_ball", decision: RunDiagnosis { summary, ..settled }, standard })
    }

    /// After a rigid ball that named the sensor gain: the run's recording
    /// corrected for the measured gain (`c`), with `standard` the run
    /// recording's own diagnosis (absent with `--no-diagnose`).
    pub fn by_ball(
        c: &crate::plan::GainCorrected,
        gain: &crate::plan::GainMeasure,
        standard: Option<RunDiagnosis>,
        wall_time_s: f64,
    ) -> Self {
        use std::fmt::Write;
        let half = 1.96 * gain.g_sd;
        let g = ParamEstimate {
            name: "g",
            unit: "",
            value: gain.g,
            ci95: [Some(gain.g - half), Some(gain.g + half)],
            well_determined: true,
        };
        let mut effects = vec![EffectFound { name: "sensor_gain", params: vec![g] }];
        effects.extend(
            c.diagnosis
                .explanation
                .iter()
                .filter(|e| e.effect != "sensor_gain" && c.effects.contains(&e.effect))
                .map(|e| EffectFound { name: e.effect, params: e.params.clone() }),
        );
        let names: Vec<&str> = effects.iter().map(|e| e.name).collect();
        let mut summary = format!("{CLOSED_LOOP}rigid_ball: EFFECTS: {}.\n", names.join(", "));
        for e in &effects {
            let params: Vec<String> = e.params.iter().map(prose::param).collect();
            let _ = writeln!(summary, "  {}: {}", e.name, params.join(", "));
        }
        let _ = writeln!(
            summary,
            "  corrected E1 = {:.4} MPa [{:.4}, {:.4}], nu1 = {:.4} [{:.4}, {:.4}] (the gain's share of each \
             half-width: {:.4} MPa, {:.4})",
            c.e1_mpa,
            c.ci95.e1_mpa[0],
            c.ci95.e1_mpa[1],
            c.nu1,
            c.ci95.nu1[0],
            c.ci95.nu1[1],
            c.gain_share[0],
            c.gain_share[1]
        );
        if let Some(first) = standard.as_ref().and_then(|s| s.summary.lines().next()) {
            let _ = writeln!(summary, "  the run's recording alone: {first}");
        }
        let decision = RunDiagnosis {
            verdict: VerdictClass::Effects,
            summary,
            effects,
            e1_mpa: c.e1_mpa,
            nu1: c.nu1,
            ci95: c.ci95,
            contact_offset_mm: Some(c.diagnosis.corrected.contact_offset_mm).filter(|z| z.is_finite()),
            error: None,
            wall_time_s,
        };
        Self { by: "rigid_ball", decision, standard }
    }
}
