//! `easycalib plan`: for a recording already taken, which experiment would
//! separate the explanations its diagnosis leaves standing (docs/experiments.md).

use sim::recording::Recording;

use super::{CliError, PlanArgs};
use crate::diagnosis::DiagnoseError;
use crate::fit::FitError;
use crate::plan::{PlanError, PlanOptions, plan, report};

pub fn run(args: &PlanArgs) -> Result<(), CliError> {
    let rec = Recording::read_path(&args.recording)
        .map_err(|e| CliError::bad_input(format!("{}: {e}", args.recording.display())))?;
    let p = plan(&rec, PlanOptions { operator: !args.no_operator, experiment_sd: None }).map_err(|e| match e {
        PlanError::Diagnose(DiagnoseError::Options(m)) => CliError::bad_input(m),
        PlanError::Diagnose(DiagnoseError::Fit(FitError::Implausible(m))) => {
            CliError::bad_input(format!("{}: {m}", args.recording.display()))
        }
        e => CliError::fit_failed(e.to_string()),
    })?;
    if args.json {
        let text = serde_json::to_string_pretty(&p).map_err(|e| CliError::other(e.to_string()))?;
        println!("{text}");
    } else {
        print!("{}", report(&p));
    }
    Ok(())
}
