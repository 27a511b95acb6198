//! `easycalib run`: a calibration on the built-in emulated rig (default) or on
//! a real rig described by `--rig rig.toml`, with the live display, Ctrl-C as
//! abort, and the fit and report at the end.

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use sim::recording::Recording;
use tokio::sync::mpsc::unbounded_channel;

use super::calibrate::human_summary;
use super::sim_setup::{SimSetupArgs, sim_setup};
use super::{CliError, RunArgs};
use crate::report::{Truth, calibration_output, default_run_dir};
use crate::rig::emulated::{EmulatedRig, ServeOptions};
use crate::rig::{RigConfig, RigSpec, RunRequest, RunResult, run_calibration_with};
use crate::run::events::{RunControl, format_duration};
use crate::run::{RunStatus, Script};

/// Exit code of a run that was aborted (operator, device fault, safety); the
/// recording of everything before the abort is kept.
pub const EXIT_ABORTED: u8 = 4;
/// Exit code when a device cannot be opened (nothing moved).
pub const EXIT_DEVICE: u8 = 5;

fn read_script(path: &Path) -> Result<Script, CliError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::bad_input(format!("cannot read script {}: {e}", path.display())))?;
    Script::from_toml(&text).map_err(|e| CliError::bad_input(format!("{}: {e}", path.display())))
}

pub fn run(args: &RunArgs) -> Result<(), CliError> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::other(format!("cannot start the async runtime: {e}")))?;
    rt.block_on(run_async(args))
}

/// What the history needs of a completed run.
struct Completed {
    recording: PathBuf,
    calibration: crate::fit::Calibration,
    diagnosis: Option<crate::report::RunDiagnosis>,
    truth: Option<Truth>,
    rig_note: String,
    script_toml: Option<String>,
    /// What the run warned of as it went (kept on the record as `run_warning`s).
    run_warnings: Vec<String>,
}

/// Write a completed run to the history; the lines say what happened.
fn write_history(db: &super::history::DbArg, done: Completed) -> Vec<String> {
    match Recording::read_path(&done.recording) {
        Ok(rec) => {
            let out = calibration_output(&rec, &done.calibration, Some(&done.recording), done.truth);
            let mut outcome = super::history::outcome_of_fit(&out, history::Source::Run);
            outcome.rig = Some(done.rig_note);
            outcome.warnings.extend(done.diagnosis.as_ref().and_then(diagnosis_note));
            outcome.warnings.extend(
                done.run_warnings
                    .into_iter()
                    .map(|message| history::record::WarningRecord { code: "run_warning".into(), message }),
            );
            outcome.script = done.script_toml;
            super::history::record(db, &done.recording, &rec, outcome)
        }
        Err(e) => vec![format!("history: not recorded: cannot read back {}: {e}", done.recording.display())],
    }
}

/// The diagnosis' verdict as a note on the run's history record (a warning
/// record, so the schema stays as it is): only when it is not clean. The
/// record's E1 and nu1 stay the calibration's.
fn diagnosis_note(d: &crate::report::RunDiagnosis) -> Option<history::record::WarningRecord> {
    use crate::report::VerdictClass;
    (d.verdict != VerdictClass::Clean).then(|| history::record::WarningRecord {
        code: format!("diagnosis_{}", d.verdict.as_str()),
        message: d.summary.trim_end().to_string(),
    })
}

/// The rig a run drives and what it knows of it.
struct RigChoice {
    spec: RigSpec,
    /// The simulated elastomer's truth (emulated rig only).
    truth: Option<Truth>,
    script: Script,
    /// The running emulators, kept until the run ends.
    emulated: Option<EmulatedRig>,
}

/// A real rig from `--rig`, or the emulated rig for the simulated set-up the
/// command line asks for (resolved once, here).
async fn choose_rig(args: &RunArgs) -> Result<RigChoice, CliError> {
    let rig_cfg = match &args.rig {
        Some(p) => Some(RigConfig::read_path(p).map_err(|e| CliError::bad_input(e.to_string()))?),
        None => None,
    };
    let script_path = args.script.clone().or_else(|| rig_cfg.as_ref().and_then(|c| c.script.clone()));
    let given_script = script_path.as_deref().map(read_script).transpose()?;
    if let Some(cfg) = &rig_cfg {
        let spec = cfg.to_spec().map_err(|e| CliError::bad_input(e.to_string()))?;
        return Ok(RigChoice { spec, truth: None, script: given_script.unwrap_or_default(), emulated: None });
    }
    // The gel: the script's declaration, else the flags' (by default the
    // reference sensor's flat layer, whose R1 is then inf).
    let layer = match &given_script {
        Some(s) => s.sensor.layer().map_err(|e| CliError::bad_input(e.to_string()))?,
        None => emulated_layer(args)?,
    };
    let mut elastomer = args.elastomer.clone();
    if given_script.is_none() && layer.is_some() {
        elastomer.elastomer_r_mm.get_or_insert(f64::INFINITY);
    }
    let setup = sim_setup(SimSetupArgs {
        elastomer: &elastomer,
        script: script_path.as_deref().zip(given_script.as_ref()),
        profile: args.profile.as_deref(),
        speedup: if args.realtime { 1.0 } else { args.speedup.unwrap_or(sim::defaults::SPEEDUP) },
    })?;
    // A declared layer: the emulated rig simulates that layer (docs/physics.md,
    // "The layer in the generator and the emulated rig").
    let from_script = given_script.is_some();
    let setup = match layer {
        None => setup,
        Some(layer) => layered_setup(setup, layer, from_script)?,
    };
    // Without a script, the built-in one on the simulated indenter, R1 and layer.
    let script = given_script.unwrap_or_else(|| {
        let mut s = Script { indenter: setup.pair().indenter, ..Script::default() };
        s.sensor.elastomer_r_mm = setup.pair().elastomer.r_mm;
        s.sensor.elastomer_thickness_mm = layer.map(|l| l.thickness_mm);
        s.sensor.elastomer_base =
            layer.filter(|l| l.base != sim::physics::LayerBase::Bonded).map(|l| l.base.as_str().to_string());
        s
    });
    let rig = EmulatedRig::start(setup, ServeOptions { grbl: args.grbl, ..ServeOptions::default() })
        .await
        .map_err(|e| CliError::other(format!("cannot start the emulated rig: {e}")))?;
    Ok(RigChoice { spec: rig.spec(), truth: Some(rig.truth()), script, emulated: Some(rig) })
}

/// The emulated gel's layer without a script: `--thickness-mm` (`inf`: a
/// half-space), by default the reference sensor's
/// ([`sim::defaults::ELASTOMER_THICKNESS_MM`]), bonded to its window. A dome
/// (`--r1-mm` finite) is a half-space's: with the default layer it is refused,
/// naming the flag that makes it one.
fn emulated_layer(args: &RunArgs) -> Result<Option<sim::physics::Layer>, CliError> {
    let h = args.thickness_mm.unwrap_or(sim::defaults::ELASTOMER_THICKNESS_MM);
    let base = super::base_flag(args.base.as_deref())?;
    if h == f64::INFINITY {
        return match &args.base {
            Some(b) => Err(CliError::bad_input(format!(
                "--base {b}: --thickness-mm inf simulates a half-space, which has no base"
            ))),
            None => Ok(None),
        };
    }
    if !(h.is_finite() && h > 0.0) {
        return Err(CliError::bad_input(format!("--thickness-mm must be a positive thickness or `inf`, got {h}")));
    }
    if let Some(r1) = args.elastomer.elastomer_r_mm.filter(|r| r.is_finite()) {
        return Err(CliError::bad_input(format!(
            "--r1-mm {r1}: the emulated gel is a flat {h} mm layer{}; a domed gel is simulated as a half-space: \
             add --thickness-mm inf",
            if args.thickness_mm.is_some() { "" } else { " by default" }
        )));
    }
    Ok(Some(sim::physics::Layer { thickness_mm: h, base, thickness_tol_mm: None }))
}

/// The emulated rig on the declared gel layer
/// ([`crate::rig::emulated::on_declared_layer`]); a refusal names where the
/// layer was declared and how to simulate a half-space instead.
fn layered_setup(
    setup: sim::setup::SimSetup,
    layer: sim::physics::Layer,
    from_script: bool,
) -> Result<sim::setup::SimSetup, CliError> {
    crate::rig::emulated::on_declared_layer(setup, layer).map_err(|why| {
        let h = layer.thickness_mm;
        CliError::bad_input(if from_script {
            format!("the script declares a {h} mm gel layer ([sensor] elastomer_thickness_mm): {why}")
        } else {
            format!(
                "the emulated gel is a {h} mm layer (--thickness-mm): {why}; --thickness-mm inf simulates a half-space"
            )
        })
    })
}

async fn run_async(args: &RunArgs) -> Result<(), CliError> {
    // Signals are caught from the start: one that comes while the rig is being
    // set up (building a simulated layer takes a second) aborts the run as
    // soon as it starts, before anything has moved.
    let (ctl_tx, ctl_rx) = unbounded_channel();
    let ctrl_c = tokio::spawn(abort_on_signals(signal_streams(), ctl_tx.clone()));
    let RigChoice { spec, truth, mut script, emulated } = choose_rig(args).await?;
    if args.adaptive {
        script.adaptive.enabled = true;
        if let Some(b) = args.budget_s {
            script.adaptive.budget_s = b;
        }
        if args.no_operator {
            script.adaptive.operator = false;
        }
        script.validate().map_err(|e| CliError::bad_input(e.to_string()))?;
    }
    let out_dir = match &args.out {
        Some(d) => d.clone(),
        None => default_run_dir(Path::new("runs"), Some(&spec.sensor_name), SystemTime::now()),
    };
    // Before anything moves: the folder is new, empty, or explicitly overwritten.
    crate::run::outdir::prepare(&out_dir, args.overwrite).map_err(|e| CliError::bad_input(e.to_string()))?;
    if let Some(rig) = &emulated {
        eprintln!(
            "easycalib run: emulated rig at {}x real time ({}), real drivers over {}",
            rig.speedup(),
            if args.grbl { "GRBL stage" } else { "APT stage" },
            rig.device_lines().join(", ")
        );
    }

    // The run, the display and Ctrl-C, concurrently.
    let (ev_tx, ev_rx) = unbounded_channel();
    let display = {
        let ctl = ctl_tx.clone();
        let json = args.json;
        tokio::spawn(async move {
            if json {
                // stdout carries the JSON document: progress goes to stderr.
                // An operator step is answered on stdin.
                crate::tui::run_plain_prompting(ev_rx, std::io::stderr(), ctl, crate::tui::read_stdin_line).await
            } else {
                crate::tui::run_display(ev_rx, ctl).await
            }
        })
    };
    let rig_note = match (&args.rig, &emulated) {
        (Some(p), _) => format!("rig file {}", p.display()),
        (None, Some(rig)) => format!(
            "emulated ({} stage, K10CR1, link-protocol sensor) at {}x",
            if args.grbl { "GRBL" } else { "KDC101 + Z825B" },
            rig.speedup()
        ),
        (None, None) => "unknown".into(),
    };
    let metadata = vec![("rig".to_string(), rig_note.clone())];
    let script_toml = script.to_toml().ok();
    let req = RunRequest { spec, script, out_dir: out_dir.clone(), truth, metadata, diagnose: !args.no_diagnose };
    let history_tx = ev_tx.clone();
    let mount = emulated.as_ref().map(|rig| rig.indenter_mount());
    let result = run_calibration_with(req, ev_tx, ctl_rx, mount).await;
    // The history, while the display still shows the result (its verdict goes
    // into the final panel). Its PostgreSQL client blocks: off the async workers.
    let mut history_lines = vec![];
    if let Ok(r) = &result
        && let (Some(cal), false) = (&r.calibration, args.no_history)
    {
        let done = Completed {
            recording: r.outcome.recording.clone(),
            calibration: cal.clone(),
            diagnosis: r.diagnosis.clone(),
            truth,
            rig_note: rig_note.clone(),
            script_toml: script_toml.clone(),
            run_warnings: r.outcome.warnings.clone(),
        };
        let db = args.db.clone();
        history_lines = tokio::task::spawn_blocking(move || write_history(&db, done))
            .await
            .unwrap_or_else(|e| vec![format!("history: not recorded: {e}")]);
        let _ = history_tx.send(crate::run::events::RunEvent::History { lines: history_lines.clone() });
    }
    drop(history_tx);
    let display_result = display.await;
    ctrl_c.abort();
    drop(ctl_tx);
    let result = result.map_err(|e| match e {
        crate::rig::StartError::Connect(c) => CliError { code: EXIT_DEVICE, message: c.to_string() },
        other => CliError::bad_input(other.to_string()),
    })?;
    if let Ok(Err(e)) = display_result {
        eprintln!("warning: the display failed: {e}");
    }
    // A profile's effect the simulated sensor could not draw everywhere.
    if let Some(w) = emulated.as_ref().and_then(|rig| rig.note_effect_failures(result.report.as_ref())) {
        eprintln!("warning: {w}");
    }
    drop(emulated);
    report(args, &result, truth)?;
    // The display is gone: the verdict with the summary (on stderr beside JSON).
    super::calibrate::print_history(&history_lines, args.json);
    Ok(())
}

/// `aborted.json` beside the recording: why the run ended and where the stage is
/// (docs/run.md). Best effort: the exit code and message carry the same.
fn write_abort_report(o: &crate::run::RunOutcome, info: &crate::run::AbortInfo) {
    use crate::run::Backoff;
    let backoff = match &info.backoff {
        Backoff::To(mm) => serde_json::json!({ "to_mm": mm }),
        Backoff::NotHomed => serde_json::json!({ "not_homed": true }),
        Backoff::Failed(e) => serde_json::json!({ "failed": e }),
    };
    let doc = serde_json::json!({
        "aborted": {
            "culprit": info.culprit.as_str(),
            "message": info.message,
            "backoff": backoff,
            "samples": o.samples,
            "rig_time_s": o.rig_time_s,
            "recording": o.recording.display().to_string(),
        }
    });
    let path = o.recording.with_file_name(ABORT_REPORT_FILE);
    let written = crate::run::outdir::create_nofollow(&path)
        .and_then(|mut f| std::io::Write::write_all(&mut f, format!("{doc:#}\n").as_bytes()));
    if let Err(e) = written {
        eprintln!("warning: cannot write {}: {e}", path.display());
    }
}

/// The abort report's file name, beside the recording.
pub const ABORT_REPORT_FILE: &str = "aborted.json";

/// The terminating signals (INT, TERM, HUP), caught from the moment this
/// returns; `None` if a handler cannot be installed.
fn signal_streams() -> Option<[tokio::signal::unix::Signal; 3]> {
    use tokio::signal::unix::{SignalKind, signal};
    let kinds = [SignalKind::interrupt(), SignalKind::terminate(), SignalKind::hangup()];
    let [int, term, hup] = kinds.map(signal);
    Some([int.ok()?, term.ok()?, hup.ok()?])
}

/// Every terminating signal asks the sequencer to abort: stop, back off to
/// the approach position, flush and report (docs/run.md). Further signals
/// while it backs off ask again; the back-off is not skipped.
async fn abort_on_signals(
    signals: Option<[tokio::signal::unix::Signal; 3]>,
    ctl: tokio::sync::mpsc::UnboundedSender<RunControl>,
) {
    let Some([mut int, mut term, mut hup]) = signals else {
        // Without handlers the default action stands; the run cannot catch signals.
        eprintln!("warning: cannot install signal handlers; a signal ends the run without a back-off");
        return;
    };
    loop {
        let which = tokio::select! {
            _ = int.recv() => "SIGINT",
            _ = term.recv() => "SIGTERM",
            _ = hup.recv() => "SIGHUP",
        };
        eprintln!("{which}: aborting — the stage backs off before the program ends");
        if ctl.send(RunControl::Abort).is_err() {
            return;
        }
    }
}

fn report(args: &RunArgs, result: &RunResult, truth: Option<Truth>) -> Result<(), CliError> {
    let o = &result.outcome;
    if let RunStatus::Aborted(info) = &o.status {
        write_abort_report(o, info);
        return Err(CliError {
            code: EXIT_ABORTED,
            message: format!(
                "run aborted by {}: {info}\n{} samples recorded up to the abort: {}",
                info.culprit.as_str(),
                o.samples,
                o.recording.display()
            ),
        });
    }
    let (Some(cal), Some(files)) = (&result.calibration, &result.report) else {
        return Err(CliError::fit_failed(format!(
            "{} (recording: {})",
            result.fit_error.as_deref().unwrap_or("no fit"),
            o.recording.display()
        )));
    };
    if args.json {
        let text = std::fs::read_to_string(&files.json)
            .map_err(|e| CliError::other(format!("cannot read back {}: {e}", files.json.display())))?;
        print!("{text}");
        return Ok(());
    }
    let rec = Recording::read_path(&o.recording)
        .map_err(|e| CliError::other(format!("cannot read back {}: {e}", o.recording.display())))?;
    let mut out = calibration_output(&rec, cal, Some(&o.recording), truth);
    out.diagnosis = result.diagnosis.clone();
    println!();
    print!("{}", human_summary(&out, &rec.meta));
    if let Some(d) = &result.diagnosis {
        println!(
            "\nDiagnosis ({:.2} s; `easycalib diagnose {}` for the full report):",
            d.wall_time_s,
            o.recording.display()
        );
        print!("{}", d.summary);
    }
    println!(
        "\nRun: {} samples, rig time {}, wall time {}",
        o.samples,
        format_duration(o.rig_time_s),
        format_duration(o.wall_time_s)
    );
    let show = |p: &PathBuf| p.display().to_string();
    println!("Recording: {}", show(&o.recording));
    println!(
        "Report:    {} ({}, {}, {})",
        show(&files.markdown),
        show(&files.json),
        show(&files.normal_svg),
        show(&files.torsion_svg)
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Ci95;
    use crate::report::{RunDiagnosis, VerdictClass};

    fn diagnosis(verdict: VerdictClass, summary: &str) -> RunDiagnosis {
        RunDiagnosis {
            verdict,
            summary: summary.into(),
            effects: vec![],
            e1_mpa: 0.33,
            nu1: 0.39,
            ci95: Ci95 { e1_mpa: [0.32, 0.34], nu1: [0.38, 0.40] },
            contact_offset_mm: None,
            error: None,
            wall_time_s: 0.1,
        }
    }

    /// The emulated gel from the flags: by default the reference sensor's
    /// flat 5 mm layer bonded to its window; `inf` the half-space (domed or
    /// not); a dome on the default layer, a thickness that is none, or a
    /// thickness beside a script or a rig file are refused, each naming the
    /// flag that settles it.
    #[test]
    fn the_emulated_gel_is_the_reference_layer_unless_the_flags_say_otherwise() {
        use clap::Parser;
        let parse = |flags: &[&str]| super::super::Cli::try_parse_from(["easycalib", "run"].iter().chain(flags));
        let layer = |flags: &[&str]| match parse(flags).expect("valid flags").command {
            super::super::Command::Run(a) => emulated_layer(&a),
            _ => unreachable!("a run"),
        };
        let default = layer(&[]).expect("the default gel").expect("a layer");
        assert_eq!((default.thickness_mm, default.base), (5.0, sim::physics::LayerBase::Bonded));
        assert_eq!(layer(&["--thickness-mm", "3.5"]).expect("a layer").map(|l| l.thickness_mm), Some(3.5));
        assert_eq!(layer(&["--thickness-mm", "inf"]).expect("a half-space"), None);
        let sliding = layer(&["--base", "sliding"]).expect("a layer").expect("a layer");
        assert_eq!((sliding.thickness_mm, sliding.base), (5.0, sim::physics::LayerBase::Sliding));
        for (bad, says) in
            [(&["--base", "glued"][..], "--base glued"), (&["--thickness-mm", "inf", "--base", "sliding"], "no base")]
        {
            let err = layer(bad).expect_err("refused");
            assert!(err.message.contains(says), "{bad:?}: {}", err.message);
        }
        assert_eq!(layer(&["--thickness-mm", "inf", "--r1-mm", "33"]).expect("a domed half-space"), None);
        let dome = layer(&["--r1-mm", "33"]).expect_err("a domed layer");
        assert!(dome.message.contains("--thickness-mm inf"), "{}", dome.message);
        for bad in ["--thickness-mm=0", "--thickness-mm=-2", "--thickness-mm=nan"] {
            let err = layer(&[bad]).expect_err("no thickness");
            assert!(err.message.starts_with("--thickness-mm must be"), "{bad}: {}", err.message);
        }
        for other in [["--script", "s.toml"], ["--rig", "r.toml"]] {
            let err = parse(&[&other[..], &["--thickness-mm", "5"]].concat()).expect_err("refused by clap");
            assert!(err.to_string().contains("--thickness-mm"), "{other:?}: {err}");
        }
    }

    #[test]
    fn a_verdict_that_is_not_clean_goes_to_the_history_as_a_warning() {
        assert_eq!(diagnosis_note(&diagnosis(VerdictClass::Clean, "CLEAN: nothing named.\n")), None);
        for (verdict, code) in [
            (VerdictClass::Effects, "diagnosis_effects"),
            (VerdictClass::Ambiguous, "diagnosis_ambiguous"),
            (VerdictClass::Unexplained, "diagnosis_unexplained"),
            (VerdictClass::NotMade, "diagnosis_not_made"),
        ] {
            let w = diagnosis_note(&diagnosis(verdict, "EFFECTS: stage_backlash.\n")).expect("a warning");
            assert_eq!((w.code.as_str(), w.message.as_str()), (code, "EFFECTS: stage_backlash."));
        }
    }
}
