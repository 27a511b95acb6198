//! `easycalib script`: print the built-in calibration script, or check one.

use std::path::Path;

use super::{CliError, ScriptArgs};
use crate::run::script::{DEFAULT_SCRIPT_TOML, Script};

pub fn script(a: &ScriptArgs) -> Result<(), CliError> {
    match &a.check {
        Some(path) => {
            let s = check(path)?;
            println!(
                "{}: valid; normal sweep to beta {} in {} mm steps x {}, torsion to {} deg in {} deg steps",
                path.display(),
                s.normal.target_beta,
                s.normal.step_mm,
                s.normal.repeats,
                s.torsion.amplitude_deg,
                s.torsion.step_deg
            );
            Ok(())
        }
        None => {
            // `--default` and no option both print the built-in script.
            print!("{DEFAULT_SCRIPT_TOML}");
            Ok(())
        }
    }
}

/// Read and validate a script file.
pub fn check(path: &Path) -> Result<Script, CliError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::bad_input(format!("cannot read script {}: {e}", path.display())))?;
    Script::from_toml(&text).map_err(|e| CliError::bad_input(format!("{}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn printed_default_checks_and_bad_scripts_are_bad_input() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("default.toml");
        std::fs::write(&good, DEFAULT_SCRIPT_TOML).unwrap();
        assert_eq!(check(&good).unwrap(), Script::default());
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, "[torsion]\nstep_deg = -1\n").unwrap();
        let e = check(&bad).unwrap_err();
        assert_eq!(e.code, super::super::EXIT_BAD_INPUT);
        assert!(e.message.contains("torsion.step_deg"), "{}", e.message);
        let e = check(&dir.path().join("missing.toml")).unwrap_err();
        assert!(e.message.contains("cannot read script"), "{}", e.message);
    }
}
