//! `easycalib diagnose`: locate, explain and model a mismatch between the
//! model and a recording (see docs/diagnosis.md).

use std::fmt::Write as _;

use sim::recording::Recording;

use super::{CliError, DiagnoseArgs};
use crate::diagnosis::{DiagnoseError, DiagnoseOptions, Diagnosis, diagnose, plot};
use crate::fit::FitError;

pub fn run(args: &DiagnoseArgs) -> Result<(), CliError> {
    let rec = Recording::read_path(&args.recording)
        .map_err(|e| CliError::bad_input(format!("{}: {e}", args.recording.display())))?;
    let opts = DiagnoseOptions { noise_um: args.noise_um, ..Default::default() };
    let d = diagnose(&rec, &opts).map_err(|e| match e {
        DiagnoseError::Options(m) => CliError::bad_input(m),
        DiagnoseError::Fit(FitError::Implausible(m)) => {
            CliError::bad_input(format!("{}: {m}", args.recording.display()))
        }
        e => CliError::fit_failed(e.to_string()),
    })?;
    if let Some(dir) = &args.plots {
        let p = plot::write_residual_plot(&d, dir).map_err(|e| CliError::other(e.to_string()))?;
        if !args.json {
            eprintln!("wrote {}", p.display());
        }
    }
    if let Some(path) = &args.profile_out {
        let text = d.profile.to_toml_string().map_err(|e| CliError::other(e.to_string()))?;
        let text = format!(
            "# sim profile written by `easycalib diagnose {}`: the fitted material, stage zero and the effects found\n{text}",
            args.recording.display()
        );
        std::fs::write(path, text).map_err(|e| CliError::other(format!("{}: {e}", path.display())))?;
    }
    if args.json {
        let text = crate::report::json::to_json_explained(&d).map_err(|e| CliError::other(e.to_string()))?;
        println!("{text}");
    } else {
        print!("{}", human(&d));
    }
    if args.record {
        let lines = super::history::record(&args.db, &args.recording, &rec, history_outcome(&rec, &d));
        super::calibrate::print_history(&lines, args.json);
    }
    Ok(())
}

/// What the history keeps of a diagnosis: the corrected values and the effects named.
fn history_outcome(rec: &Recording, d: &Diagnosis) -> super::history::Outcome {
    use history::{EffectParam, EffectRecord, Source};
    let c = &d.corrected;
    super::history::Outcome {
        source: Source::Diagnose,
        model: if crate::fit::full::fe_layer(rec).is_some() { "layer-fe" } else { "half-space" }.to_string(),
        e1_mpa: c.e1_mpa,
        e1_ci95: c.ci95.e1_mpa,
        nu1: c.nu1,
        nu1_ci95: c.ci95.nu1,
        effects: d
            .explanation
            .iter()
            .map(|e| EffectRecord {
                name: e.effect.to_string(),
                params: e
                    .params
                    .iter()
                    .map(|p| EffectParam { name: p.name.to_string(), value: p.value, unit: p.unit.to_string() })
                    .collect(),
            })
            .collect(),
        warnings: super::history::warning_records(&d.warnings),
        rig: None,
        script: None,
    }
}

/// The human report.
pub fn human(d: &Diagnosis) -> String {
    let mut s = String::new();
    let b = &d.baseline;
    let c = &d.corrected;
    let _ = writeln!(s, "Noise floor: gamma1 {:.2} µm, theta1 {:.4} deg", d.noise.normal_um, d.noise.torsion_deg);
    let _ = writeln!(
        s,
        "Baseline (paper's physics, full-model fit): E1 {:.4} MPa [{:.4}, {:.4}], nu1 {:.4} [{:.4}, {:.4}], z0 {:+.4} mm",
        b.e1_mpa, b.ci95.e1_mpa[0], b.ci95.e1_mpa[1], b.nu1, b.ci95.nu1[0], b.ci95.nu1[1], b.contact_offset_mm
    );
    if d.mismatch.is_empty() {
        let _ = writeln!(s, "Mismatch: none beyond the noise floor");
    } else {
        let _ = writeln!(s, "Mismatch:");
        for m in &d.mismatch {
            let _ = writeln!(s, "  {:<14} {} {:.3} .. {:.3}: {}", m.phase, m.axis, m.from, m.to, m.shape);
        }
    }
    if d.unexplained {
        let _ = writeln!(s, "Explanation: UNEXPLAINED by the effect library; nothing is attributed");
    } else if d.effects.is_empty() {
        let _ = writeln!(s, "Explanation: no effect named");
    } else {
        for e in &d.explanation {
            let _ = writeln!(s, "Effect {}: {}", e.effect, e.sentence);
            for p in &e.params {
                let f = |v: Option<f64>| v.map_or("open".to_string(), |v| format!("{v:.5}"));
                let _ = writeln!(
                    s,
                    "  {} = {:.5} {} (95% [{}, {}]){}",
                    p.name,
                    p.value,
                    p.unit,
                    f(p.ci95[0]),
                    f(p.ci95[1]),
                    if p.well_determined { "" } else { "  weakly determined" }
                );
            }
        }
        let _ = writeln!(
            s,
            "Corrected: E1 {:.4} MPa [{:.4}, {:.4}], nu1 {:.4} [{:.4}, {:.4}]",
            c.e1_mpa, c.ci95.e1_mpa[0], c.ci95.e1_mpa[1], c.nu1, c.ci95.nu1[0], c.ci95.nu1[1]
        );
    }
    let _ = writeln!(
        s,
        "Residual RMS: normal {:.2} -> {:.2} µm, hold {:.2} -> {:.2} µm, torsion {:.4} -> {:.4} deg",
        b.rms.normal_um, c.rms.normal_um, b.rms.hold_um, c.rms.hold_um, b.rms.torsion_deg, c.rms.torsion_deg
    );
    for g in &d.degenerate {
        let _ = writeln!(s, "Degenerate: {}", g.reason);
        if let Some(m) = g.separate_by {
            let _ = writeln!(s, "  to separate it: {m}");
        }
    }
    for w in &d.warnings {
        let _ = writeln!(s, "Warning ({}): {}", w.code, w.message);
    }
    let _ = writeln!(s, "\n{}", d.verdict);
    s
}
