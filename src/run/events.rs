//! What a running calibration tells its observers ([`RunEvent`]) and what they
//! may ask of it ([`RunControl`]). The sequencer sends events down a channel;
//! the TUI, the plain progress printer and tests only ever see these values,
//! so the way a run is shown is independent of how it is driven.
//!
//! Events serialize (serde) with an `event` tag, e.g.
//! `{"event":"step_started","index":2,"total":9,"name":"normal sweep","phase":"normal"}`,
//! so a run can also be logged as JSON lines.

use devices::motion::AxisStatus;
use serde::{Deserialize, Serialize};
use sim::physics::{Body, invert_exact};
use sim::recording::{Phase, Sample};

use crate::fit::regression::{PAPER_WINDOW_MM, eq22_point, eq38_point, fit_eq22, fit_eq38, torsion_depth};

/// Coarse stage of the run a step belongs to (the step's own name says more).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunPhase {
    /// Connect, identify, home.
    Setup,
    /// Approach and first-contact detection.
    Approach,
    /// The normal (indentation) sweep, load and unload.
    Normal,
    /// Depth hold and the torsion sweep.
    Torsion,
    /// Retract and finish.
    Retract,
}

impl RunPhase {
    pub fn as_str(self) -> &'static str {
        match self {
            RunPhase::Setup => "setup",
            RunPhase::Approach => "approach",
            RunPhase::Normal => "normal",
            RunPhase::Torsion => "torsion",
            RunPhase::Retract => "retract",
        }
    }

    /// The recording phase samples of this step carry, if it records any.
    pub fn recording_phase(self) -> Option<Phase> {
        match self {
            RunPhase::Normal => Some(Phase::Normal),
            RunPhase::Torsion => Some(Phase::Torsion),
            _ => None,
        }
    }
}

/// Progress of the current step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    /// Fraction of the current step done, 0..=1 (clamped by consumers).
    pub step_fraction: f64,
    /// Rig time since the run started, s.
    pub elapsed_s: f64,
    /// Estimated rig time left for the whole run, s (`None` while unknown).
    pub eta_s: Option<f64>,
}

/// The sensor stream's health.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct SensorStatus {
    /// Frame rate measured over the last second, Hz.
    pub rate_hz: f64,
    /// Frames received since the run started.
    pub frames: u64,
    /// Frames lost on the link: gaps in the sensor's frame counter, and input
    /// rejected as malformed (the link's fault, shown as a warning).
    pub dropped: u64,
    /// Good frames the consumer did not take: replaced in a full queue while
    /// the run was busy, or late repeats. Normal on a fast sensor; not a fault.
    #[serde(default)]
    pub skipped: u64,
    /// Frames taken but not measurable (no contact pattern the estimator accepts).
    #[serde(default)]
    pub unmeasured: u64,
}

/// A snapshot of every device.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct DeviceStatus {
    /// Linear stage, mm.
    pub stage: AxisStatus,
    /// Rotation mount, degrees.
    pub rotation: AxisStatus,
    pub sensor: SensorStatus,
}

/// The running fit as the sweeps progress. Any field may be unknown yet:
/// H1/H2 exist once the normal sweep has enough points, H3 once torsion has,
/// E1/nu1 once both have.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FitUpdate {
    /// Eq. 22 slope: gamma2 = H1 gamma1 + H2 gamma1^1.5.
    pub h1: Option<f64>,
    /// Eq. 22 nuisance coefficient of gamma1^1.5.
    pub h2: Option<f64>,
    /// Eq. 38 slope: theta2 = H3 theta1.
    pub h3: Option<f64>,
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: Option<f64>,
    pub nu1: Option<f64>,
}

impl FitUpdate {
    /// A quick running estimate by the paper's reduced relations over the
    /// samples so far: cheap enough to recompute after every sample (two
    /// small least-squares sums). Falls back to every in-contact normal sample
    /// while the paper's gamma1 window has fewer than four; returns `None`
    /// when nothing can be fitted yet.
    pub fn estimate(samples: &[Sample], indenter: &Body) -> Option<FitUpdate> {
        let normal: Vec<(f64, f64)> = samples
            .iter()
            .filter(|s| s.phase == Phase::Normal && s.in_sweep() && s.gamma1_mm > 0.0)
            .map(eq22_point)
            .collect();
        let windowed: Vec<(f64, f64)> =
            normal.iter().copied().filter(|&(g1, _)| (PAPER_WINDOW_MM[0]..=PAPER_WINDOW_MM[1]).contains(&g1)).collect();
        let pts = if windowed.len() >= 4 { windowed } else { normal };
        let mut fit = FitUpdate::default();
        if let Some(eq22) = fit_eq22(&pts).filter(|_| pts.len() >= 3) {
            fit.h1 = Some(eq22.h1);
            fit.h2 = Some(eq22.h2);
        }
        let tors: Vec<&Sample> = samples.iter().filter(|s| s.phase == Phase::Torsion && s.in_sweep()).collect();
        let twist: Vec<(f64, f64)> = tors.iter().map(|s| eq38_point(s)).collect();
        if let Some(eq38) = fit_eq38(&twist).filter(|_| tors.len() >= 2) {
            fit.h3 = Some(eq38.h3);
        }
        if let (Some(h1), Some(h3), Some((beta, _))) = (fit.h1, fit.h3, torsion_depth(tors, indenter.r_mm)) {
            let inv = invert_exact(h1, h3, indenter.e_mpa, indenter.nu, beta);
            if inv.e1_mpa.is_finite() && inv.nu1.is_finite() {
                fit.e1_mpa = Some(inv.e1_mpa);
                fit.nu1 = Some(inv.nu1);
            }
        }
        if fit == FitUpdate::default() { None } else { Some(fit) }
    }

    /// The Eq. 22 curve gamma2(gamma1), when H1 is known (H2 defaults to 0).
    pub fn gamma2_at(&self, gamma1_mm: f64) -> Option<f64> {
        let h1 = self.h1?;
        Some(h1 * gamma1_mm + self.h2.unwrap_or(0.0) * gamma1_mm.max(0.0).powf(1.5))
    }

    /// The Eq. 38 line theta2(theta1), when H3 is known.
    pub fn theta2_at(&self, theta1_deg: f64) -> Option<f64> {
        Some(self.h3? * theta1_deg)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LogLevel {
    Info,
    Warn,
    Error,
}

impl LogLevel {
    pub fn as_str(self) -> &'static str {
        match self {
            LogLevel::Info => "info",
            LogLevel::Warn => "warn",
            LogLevel::Error => "error",
        }
    }
}

/// The closed loop at one of its decision points (docs/experiments.md,
/// "Watching the loop"): what still stands, what it runs next and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopView {
    /// Experiments run so far.
    pub steps_run: usize,
    /// The explanations still standing, best first, with their odds.
    pub hypotheses: Vec<LoopHypothesis>,
    /// The experiment chosen to separate them; `None` when the loop stops (`note` says why).
    pub chosen: Option<LoopChoice>,
    /// What the loop concluded or why it stops, in one line.
    pub note: String,
}

/// One standing explanation ([`LoopView`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopHypothesis {
    /// Its effects, joined by ` + `.
    pub effects: String,
    /// Its share of the evidence among those standing, 0..1 (BIC weights
    /// under equal prior odds, `plan::Plan::odds`).
    pub odds: f64,
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
}

/// The experiment the loop runs next ([`LoopView`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LoopChoice {
    pub name: String,
    /// Which explanations it separates, and by how much.
    pub why: String,
    /// Its predicted rig time, s.
    pub rig_time_s: f64,
    /// It needs an operator to swap the indenter.
    pub operator: bool,
}

impl LoopView {
    /// The view as one line (the plain event printer, the log).
    pub fn line(&self) -> String {
        let standing: Vec<String> =
            self.hypotheses.iter().map(|h| format!("{} {:.0} %", h.effects, 100.0 * h.odds)).collect();
        let next = match &self.chosen {
            Some(c) => format!(
                "runs {} ({:.0} s{}): {}",
                c.name,
                c.rig_time_s,
                if c.operator { ", operator" } else { "" },
                c.why
            ),
            None => self.note.clone(),
        };
        if standing.is_empty() {
            format!("closed loop after {} step(s): {next}", self.steps_run)
        } else {
            format!("closed loop after {} step(s): standing {}; {next}", self.steps_run, standing.join(", "))
        }
    }
}

/// What a finished run reports. Fit values are absent when the fit failed.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct RunSummary {
    /// Settled samples recorded.
    pub samples: usize,
    pub wall_time_s: f64,
    pub rig_time_s: f64,
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: Option<f64>,
    pub nu1: Option<f64>,
    #[serde(rename = "E1_MPa_ci95")]
    pub e1_ci95: Option<[f64; 2]>,
    pub nu1_ci95: Option<[f64; 2]>,
    /// Where the recording was written.
    pub recording: Option<String>,
    /// Where the report was written.
    pub report: Option<String>,
}

/// Everything a sequencer tells its observers, in order.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum RunEvent {
    /// A script step began; `index` counts from 0, `total` is the number of steps.
    StepStarted {
        index: usize,
        total: usize,
        name: String,
        phase: RunPhase,
    },
    Progress(Progress),
    DeviceStatus(DeviceStatus),
    /// A settled sample, just appended (and flushed) to the recording.
    Sample(Sample),
    /// The running fit changed.
    Fit(FitUpdate),
    Log {
        level: LogLevel,
        message: String,
    },
    /// The run stopped at a safe point and waits for `Resume`.
    Paused,
    Resumed,
    /// An operator-assisted step (docs/run.md, "Operator steps"): the stage
    /// stands retracted clear of the gel and the run waits for `Confirm`
    /// (or `Abort`) once the operator mounted `indenter` with its apex on the
    /// first indenter's reference.
    OperatorPrompt {
        /// The step (`rigid_ball`, `swap_indenter`).
        step: String,
        /// The indenter to mount: E (MPa), nu, R (mm).
        indenter: Body,
        /// What to do, in one sentence.
        message: String,
    },
    /// The operator confirmed (or, on the emulated rig, the simulation
    /// mounted the indenter itself): the step runs.
    OperatorConfirmed {
        step: String,
    },
    /// The run was aborted (motion stopped, stage backed off); `reason` says why.
    Aborted {
        reason: String,
    },
    /// The closed loop (`--adaptive`) at a decision point: what stands, what
    /// it runs next and why, or why it stops.
    ClosedLoop(Box<LoopView>),
    /// After a completed run's fit, before `Finished`: the diagnosis of the
    /// recording (docs/run.md), or why it could not be made.
    Diagnosis(Box<crate::report::RunDiagnosis>),
    /// The run completed.
    Finished {
        summary: RunSummary,
    },
    /// After a completed run: what the calibration history made of it
    /// (recorded or queued; changed or not; the trend). docs/history.md.
    History {
        lines: Vec<String>,
    },
}

/// What an observer may ask of a running sequencer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunControl {
    /// Stop at the next safe point and hold.
    Pause,
    /// Continue after a pause.
    Resume,
    /// Stop motion, back the stage off, end the run as failed.
    Abort,
    /// The operator wants to leave: abort if still running, then end.
    Quit,
    /// The operator mounted what an [`RunEvent::OperatorPrompt`] asked for:
    /// the step may run (ignored when no prompt waits).
    Confirm,
}

/// Seconds as `1m05.3s` / `12.3s`: fixed precision so logs diff cleanly.
pub fn format_duration(s: f64) -> String {
    if !s.is_finite() || s < 0.0 {
        return "--".to_string();
    }
    let tenths = (s * 10.0).round() as u64;
    let (m, rest) = (tenths / 600, tenths % 600);
    if m > 0 { format!("{m}m{:02}.{}s", rest / 10, rest % 10) } else { format!("{}.{}s", rest / 10, rest % 10) }
}

fn fmt_opt(v: Option<f64>, decimals: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.decimals$}"),
        _ => "--".to_string(),
    }
}

/// Plain one-line progress for output that is not a terminal (CI logs). It
/// prints step starts, progress at every 10 % of a step, pauses, aborts, log
/// messages and the result, and keeps the latest running fit to append to the
/// progress lines; samples and device snapshots only update counters. The text
/// depends only on the events, never on the wall clock.
#[derive(Debug, Clone, Default)]
pub struct ProgressLine {
    step: Option<(usize, usize, String)>,
    last_decile: Option<u32>,
    samples: usize,
    fit: Option<FitUpdate>,
}

impl ProgressLine {
    pub fn new() -> Self {
        Self::default()
    }

    fn prefix(&self) -> String {
        match &self.step {
            Some((i, n, name)) => format!("[{}/{}] {}", i + 1, n, name),
            None => "[-/-]".to_string(),
        }
    }

    /// The line to print for `ev`, if any (no trailing newline).
    pub fn line(&mut self, ev: &RunEvent) -> Option<String> {
        match ev {
            RunEvent::StepStarted { index, total, name, phase } => {
                self.step = Some((*index, *total, name.clone()));
                self.last_decile = Some(0);
                Some(format!("{} ({}) started", self.prefix(), phase.as_str()))
            }
            RunEvent::Progress(p) => {
                let frac = if p.step_fraction.is_finite() { p.step_fraction.clamp(0.0, 1.0) } else { 0.0 };
                let decile = (frac * 10.0 + 1e-9).floor() as u32;
                if self.last_decile.is_some_and(|d| decile <= d) {
                    return None;
                }
                self.last_decile = Some(decile);
                let mut s = format!(
                    "{} {:3.0}% elapsed {} eta {} samples {}",
                    self.prefix(),
                    frac * 100.0,
                    format_duration(p.elapsed_s),
                    p.eta_s.map(format_duration).unwrap_or_else(|| "--".into()),
                    self.samples
                );
                if let Some(f) = &self.fit {
                    s.push_str(&format!(
                        " fit H1={} H3={} E1={} MPa nu1={}",
                        fmt_opt(f.h1, 4),
                        fmt_opt(f.h3, 4),
                        fmt_opt(f.e1_mpa, 4),
                        fmt_opt(f.nu1, 3)
                    ));
                }
                Some(s)
            }
            RunEvent::DeviceStatus(_) => None,
            RunEvent::Sample(_) => {
                self.samples += 1;
                None
            }
            RunEvent::Fit(f) => {
                self.fit = Some(*f);
                None
            }
            RunEvent::Log { level, message } => Some(format!("{} {}: {}", self.prefix(), level.as_str(), message)),
            RunEvent::Paused => Some(format!("{} paused", self.prefix())),
            RunEvent::Resumed => Some(format!("{} resumed", self.prefix())),
            RunEvent::OperatorPrompt { step, indenter, message } => Some(format!(
                "{} OPERATOR ({step}): {message} [E {} MPa, nu {}, R {} mm]",
                self.prefix(),
                indenter.e_mpa,
                indenter.nu,
                indenter.r_mm
            )),
            RunEvent::OperatorConfirmed { step } => {
                Some(format!("{} {step}: indenter mounted, running", self.prefix()))
            }
            RunEvent::Aborted { reason } => Some(format!("{} ABORTED: {}", self.prefix(), reason)),
            RunEvent::ClosedLoop(v) => Some(format!("{} {}", self.prefix(), v.line())),
            RunEvent::Diagnosis(d) => Some(diagnosis_line(d)),
            RunEvent::Finished { summary } => Some(summary_line(summary)),
            RunEvent::History { lines } => Some(lines.join("\n")),
        }
    }
}

/// One line with the diagnosis' verdict and its E1, nu1.
pub fn diagnosis_line(d: &crate::report::RunDiagnosis) -> String {
    let values = format!(
        "E1 = {:.4} MPa [{:.4}, {:.4}], nu1 = {:.3} [{:.3}, {:.3}]",
        d.e1_mpa, d.ci95.e1_mpa[0], d.ci95.e1_mpa[1], d.nu1, d.ci95.nu1[0], d.ci95.nu1[1]
    );
    let names: Vec<&str> = d.effects.iter().map(|e| e.name).collect();
    match (d.corrected(), &d.error) {
        (true, _) => format!("diagnosis: {} ({}); corrected {values}", d.verdict.as_str(), names.join(", ")),
        (false, Some(e)) => format!("diagnosis: not made ({e}); the calibration stands"),
        (false, None) => format!("diagnosis: {}; nothing named, {values} as calibrated", d.verdict.as_str()),
    }
}

/// One line with the run's result.
pub fn summary_line(s: &RunSummary) -> String {
    let ci = |c: Option<[f64; 2]>, d: usize| match c {
        Some([lo, hi]) => format!(" [{lo:.d$}, {hi:.d$}]"),
        None => String::new(),
    };
    let mut line = format!(
        "finished: {} samples, E1 = {} MPa{}, nu1 = {}{}, rig time {}, wall time {}",
        s.samples,
        fmt_opt(s.e1_mpa, 4),
        ci(s.e1_ci95, 4),
        fmt_opt(s.nu1, 3),
        ci(s.nu1_ci95, 3),
        format_duration(s.rig_time_s),
        format_duration(s.wall_time_s)
    );
    if let Some(r) = &s.recording {
        line.push_str(&format!(", recording {r}"));
    }
    if let Some(r) = &s.report {
        line.push_str(&format!(", report {r}"));
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::generator::{GeneratorConfig, generate};

    fn step(index: usize, name: &str, phase: RunPhase) -> RunEvent {
        RunEvent::StepStarted { index, total: 9, name: name.into(), phase }
    }

    fn progress(f: f64, elapsed: f64, eta: Option<f64>) -> RunEvent {
        RunEvent::Progress(Progress { step_fraction: f, elapsed_s: elapsed, eta_s: eta })
    }

    #[test]
    fn durations_have_fixed_format() {
        assert_eq!(format_duration(0.0), "0.0s");
        assert_eq!(format_duration(12.34), "12.3s");
        assert_eq!(format_duration(65.3), "1m05.3s");
        assert_eq!(format_duration(f64::NAN), "--");
    }

    #[test]
    fn progress_lines_are_throttled_to_deciles_and_deterministic() {
        let mut pl = ProgressLine::new();
        let mut out = Vec::new();
        let events = [
            step(3, "normal sweep", RunPhase::Normal),
            progress(0.05, 10.0, None),
            progress(0.10, 11.0, Some(50.0)),
            progress(0.12, 11.5, Some(49.0)),
            progress(0.19, 12.0, Some(48.0)),
            progress(0.25, 13.0, Some(47.0)),
            RunEvent::Paused,
            RunEvent::Resumed,
            RunEvent::Log { level: LogLevel::Warn, message: "sensor slow".into() },
            RunEvent::Aborted { reason: "stage disconnected".into() },
        ];
        for ev in &events {
            if let Some(l) = pl.line(ev) {
                out.push(l);
            }
        }
        assert_eq!(
            out,
            vec![
                "[4/9] normal sweep (normal) started",
                "[4/9] normal sweep  10% elapsed 11.0s eta 50.0s samples 0",
                "[4/9] normal sweep  25% elapsed 13.0s eta 47.0s samples 0",
                "[4/9] normal sweep paused",
                "[4/9] normal sweep resumed",
                "[4/9] normal sweep warn: sensor slow",
                "[4/9] normal sweep ABORTED: stage disconnected",
            ]
        );
    }

    #[test]
    fn progress_line_counts_samples_and_shows_fit() {
        let mut pl = ProgressLine::new();
        pl.line(&step(0, "torsion sweep", RunPhase::Torsion));
        let rec = generate(&GeneratorConfig::default()).unwrap();
        for s in rec.samples.iter().take(7) {
            assert_eq!(pl.line(&RunEvent::Sample(*s)), None);
        }
        let fit = FitUpdate { h1: Some(0.5), h2: None, h3: Some(1.25), e1_mpa: Some(0.33), nu1: Some(0.39) };
        assert_eq!(pl.line(&RunEvent::Fit(fit)), None);
        let l = pl.line(&progress(1.0, 80.0, Some(0.0))).unwrap();
        assert_eq!(
            l,
            "[1/9] torsion sweep 100% elapsed 1m20.0s eta 0.0s samples 7 fit H1=0.5000 H3=1.2500 E1=0.3300 MPa nu1=0.390"
        );
        let fin = RunSummary {
            samples: 7,
            wall_time_s: 2.5,
            rig_time_s: 80.0,
            e1_mpa: Some(0.3301),
            nu1: Some(0.391),
            e1_ci95: Some([0.32, 0.34]),
            nu1_ci95: None,
            recording: Some("runs/x/recording.csv".into()),
            report: None,
        };
        assert_eq!(
            pl.line(&RunEvent::Finished { summary: fin }).unwrap(),
            "finished: 7 samples, E1 = 0.3301 MPa [0.3200, 0.3400], nu1 = 0.391, rig time 1m20.0s, wall time 2.5s, recording runs/x/recording.csv"
        );
    }

    #[test]
    fn plain_diagnosis_line_gives_the_verdict_and_which_values() {
        use crate::diagnosis::ParamEstimate;
        use crate::report::{EffectFound, RunDiagnosis, VerdictClass};
        let b = ParamEstimate {
            name: "b_mm",
            unit: "mm",
            value: 0.02,
            ci95: [Some(0.018), Some(0.022)],
            well_determined: true,
        };
        let ci95 = crate::fit::Ci95 { e1_mpa: [0.329, 0.331], nu1: [0.385, 0.395] };
        let named = RunDiagnosis {
            verdict: VerdictClass::Effects,
            summary: "EFFECTS: stage_backlash.\n".into(),
            effects: vec![EffectFound { name: "stage_backlash", params: vec![b] }],
            e1_mpa: 0.33,
            nu1: 0.39,
            ci95,
            contact_offset_mm: None,
            error: None,
            wall_time_s: 0.1,
        };
        let mut pl = ProgressLine::new();
        assert_eq!(
            pl.line(&RunEvent::Diagnosis(Box::new(named.clone()))).unwrap(),
            "diagnosis: effects (stage_backlash); corrected E1 = 0.3300 MPa [0.3290, 0.3310], nu1 = 0.390 [0.385, 0.395]"
        );
        let clean = RunDiagnosis { verdict: VerdictClass::Unexplained, effects: vec![], ..named.clone() };
        assert_eq!(
            diagnosis_line(&clean),
            "diagnosis: unexplained; nothing named, E1 = 0.3300 MPa [0.3290, 0.3310], nu1 = 0.390 [0.385, 0.395] as calibrated"
        );
        let failed = RunDiagnosis { verdict: VerdictClass::NotMade, error: Some("no torsion".into()), ..clean };
        assert_eq!(diagnosis_line(&failed), "diagnosis: not made (no torsion); the calibration stands");
    }

    #[test]
    fn running_fit_recovers_truth_from_a_generated_recording() {
        let cfg = GeneratorConfig::default();
        let rec = generate(&cfg).unwrap();
        let n_normal = rec.phase(Phase::Normal).count();
        // Normal sweep only: H1 but no H3, no E1 yet.
        let partial = FitUpdate::estimate(&rec.samples[..n_normal], &rec.meta.indenter).unwrap();
        assert!(partial.h1.is_some() && partial.h3.is_none() && partial.e1_mpa.is_none());
        let full = FitUpdate::estimate(&rec.samples, &rec.meta.indenter).unwrap();
        let e1 = full.e1_mpa.unwrap();
        let nu1 = full.nu1.unwrap();
        assert!((e1 / cfg.pair.elastomer.e_mpa - 1.0).abs() < 0.05, "E1 {e1}");
        assert!((nu1 - cfg.pair.elastomer.nu).abs() < 0.05, "nu1 {nu1}");
        assert_eq!(FitUpdate::estimate(&[], &rec.meta.indenter), None);
    }

    #[test]
    fn events_serialize_with_a_tag() {
        let v = serde_json::to_value(step(2, "home", RunPhase::Setup)).unwrap();
        assert_eq!(v["event"], "step_started");
        assert_eq!(v["phase"], "setup");
        assert_eq!(v["index"], 2);
        let v = serde_json::to_value(RunEvent::Aborted { reason: "x".into() }).unwrap();
        assert_eq!(v, serde_json::json!({"event": "aborted", "reason": "x"}));
        let v = serde_json::to_value(RunEvent::Progress(Progress { step_fraction: 0.5, elapsed_s: 1.0, eta_s: None }))
            .unwrap();
        assert_eq!(v["event"], "progress");
        assert_eq!(v["step_fraction"], 0.5);
        let c: RunControl = serde_json::from_str("\"pause\"").unwrap();
        assert_eq!(c, RunControl::Pause);
    }
}
