//! `easycalib diagnose`: locate, explain and model a mismatch between the
//! model and a recording (see docs/diagnosis.md).

use sim::recording::Recording;

use super::{CliError, DiagnoseArgs};
use crate::diagnosis::{DiagnoseError, DiagnoseOptions, Diagnosis, diagnose, plot, prose};
use crate::fit::FitError;

pub fn run(args: &DiagnoseArgs) -> Result<(), CliError> {
    let mut rec = Recording::read_path(&args.recording)
        .map_err(|e| CliError::bad_input(format!("{}: {e}", args.recording.display())))?;
    args.layer.apply(&mut rec)?;
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
        print!("{}", prose::report(&d));
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
