//! Command-line interface: argument parsing and dispatch to the subcommands.

mod calibrate;
pub mod devices;
mod diagnose;
pub mod history;
mod plan;
pub mod run;
mod script;
pub mod sensor;
pub mod sim;
pub mod sim_setup;
mod simulate_fe;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};

pub use calibrate::{CalibrationOutput, calibration_output};

#[derive(Debug, Parser)]
#[command(name = "easycalib", version, about = "Calibrate a tactile sensor's elastomer (E1, nu1) on an EasyCalib rig")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run a calibration (default: on the built-in simulated rig) and print E1 and nu1.
    Run(RunArgs),
    /// Fit E1 and nu1 from a recording (the paper's method and the full-model fit).
    Fit(FitArgs),
    /// Write a synthetic recording of a simulated elastomer.
    Simulate(SimulateArgs),
    /// List serial ports (USB ids, serial, product, udev links); `--probe` asks each what it is.
    Devices(devices::DevicesArgs),
    /// Tactile sensor link tools.
    Sensor(sensor::SensorArgs),
    /// The emulated rig: `sim serve` serves it on pseudo-terminals for your own client.
    Sim(sim::SimArgs),
    /// Print the built-in calibration script (`--default`) or check a script file.
    Script(ScriptArgs),
    /// Locate and explain a mismatch between the model and a recording (docs/diagnosis.md).
    Diagnose(DiagnoseArgs),
    /// Per-sensor calibration history: list, plot, import, export, sync (docs/history.md).
    History(history::HistoryArgs),
    /// Which experiment would separate the explanations a recording leaves standing (docs/experiments.md).
    Plan(PlanArgs),
}

#[derive(Debug, Args)]
pub struct PlanArgs {
    /// Recording in easycalib format v1 (CSV with `#` metadata).
    pub recording: PathBuf,
    /// Print JSON instead of the human report.
    #[arg(long)]
    pub json: bool,
    /// Weigh only the experiments the rig runs alone (no indenter swap by an operator).
    #[arg(long)]
    pub no_operator: bool,
}

#[derive(Debug, Args)]
pub struct ScriptArgs {
    /// Print the built-in default script (TOML) to stdout.
    #[arg(long, conflicts_with = "check")]
    pub default: bool,
    /// Validate this script file instead.
    #[arg(long, value_name = "SCRIPT")]
    pub check: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct DiagnoseArgs {
    /// Recording in easycalib format v1 (CSV with `#` metadata).
    pub recording: PathBuf,
    /// Print the stable JSON document instead of the human report.
    #[arg(long)]
    pub json: bool,
    /// Write residual plots before/after correction (SVG) into this directory.
    #[arg(long, value_name = "DIR")]
    pub plots: Option<PathBuf>,
    /// Write a sim profile (TOML) with the fitted material and the effects found.
    #[arg(long, value_name = "PROFILE.toml")]
    pub profile_out: Option<PathBuf>,
    /// Noise of the gamma1 readings, µm (estimated from the data if not given).
    #[arg(long)]
    pub noise_um: Option<f64>,
    /// Write the corrected calibration to the history (docs/history.md).
    #[arg(long)]
    pub record: bool,
    #[command(flatten)]
    pub db: history::DbArg,
    #[command(flatten)]
    pub layer: LayerArgs,
}

#[derive(Debug, Args)]
pub struct FitArgs {
    /// Recording in easycalib format v1 (CSV with `#` metadata).
    pub recording: PathBuf,
    /// Print the stable JSON document instead of the human summary.
    #[arg(long)]
    pub json: bool,
    /// gamma1 window of the paper's Eq. 22 fit, mm (low, high).
    #[arg(long, num_args = 2, value_names = ["LOW_MM", "HIGH_MM"], default_values_t = [0.2, 0.8])]
    pub window_mm: Vec<f64>,
    /// Noise of the gamma1 readings, µm (estimated from the data if not given).
    #[arg(long)]
    pub noise_um: Option<f64>,
    /// Write the calibration to the history (docs/history.md).
    #[arg(long)]
    pub record: bool,
    #[command(flatten)]
    pub db: history::DbArg,
    #[command(flatten)]
    pub layer: LayerArgs,
}

/// The sensor's elastomer layer, declared on the command line (it replaces the
/// recording's `elastomer_thickness_mm` / `elastomer_base`; docs/recording-format.md).
#[derive(Debug, Clone, Default, Args)]
pub struct LayerArgs {
    /// Thickness of the sensor's gel layer, mm (from its datasheet).
    #[arg(long, value_name = "MM")]
    pub thickness_mm: Option<f64>,
    /// How the gel sits on its window: `bonded` (default with a thickness) or `sliding`.
    #[arg(long, value_name = "BASE", requires = "thickness_mm")]
    pub base: Option<String>,
}

/// `--base`: bonded when not given; another word is an error naming it.
pub(crate) fn base_flag(base: Option<&str>) -> Result<::sim::physics::LayerBase, CliError> {
    match base {
        None => Ok(::sim::physics::LayerBase::Bonded),
        Some(b) => ::sim::physics::LayerBase::parse(b)
            .ok_or_else(|| CliError::bad_input(format!("--base {b}: expected `bonded` or `sliding`"))),
    }
}

impl LayerArgs {
    /// The layer declared here (no thickness tolerance), if any; a bad value
    /// is an error naming its flag.
    pub fn layer(&self) -> Result<Option<::sim::physics::Layer>, CliError> {
        let Some(h) = self.thickness_mm else {
            return Ok(None);
        };
        let layer =
            ::sim::physics::Layer { thickness_mm: h, base: base_flag(self.base.as_deref())?, thickness_tol_mm: None };
        layer.validate().map_err(|e| CliError::bad_input(format!("--thickness-mm {h}: {e}")))?;
        Ok(Some(layer))
    }

    /// `rec` with the layer declared here, if any (keeping the recording's
    /// own thickness tolerance); a bad value is an error naming it.
    pub fn apply(&self, rec: &mut ::sim::recording::Recording) -> Result<(), CliError> {
        if let Some(layer) = self.layer()? {
            let tol = rec.meta.layer.and_then(|l| l.thickness_tol_mm);
            rec.meta.layer = Some(::sim::physics::Layer { thickness_tol_mm: tol, ..layer });
        }
        Ok(())
    }
}

/// The simulated elastomer, indenter and noise seed. A flag not given takes
/// the default of `sim::defaults`; [`sim_setup`] turns them into the one
/// simulated set-up.
#[derive(Debug, Clone, Default, Args)]
pub struct ElastomerArgs {
    #[arg(long, help = format!("True Young's modulus of the simulated elastomer, MPa [default: {}]", ::sim::defaults::ELASTOMER_E_MPA))]
    pub e1_mpa: Option<f64>,
    #[arg(long, help = format!("True Poisson's ratio of the simulated elastomer [default: {}]", ::sim::defaults::ELASTOMER_NU))]
    pub nu1: Option<f64>,
    // R1; the flag keeps its short name `--r1-mm`.
    #[arg(long = "r1-mm", value_name = "R1_MM", help = format!("Effective radius R1 of the elastomer's dome, mm (`inf` for flat) [default: {}]", ::sim::defaults::ELASTOMER_R_MM))]
    pub elastomer_r_mm: Option<f64>,
    #[arg(long, help = format!("Young's modulus of the calibration indenter, MPa [default: {}]", ::sim::defaults::INDENTER_E_MPA))]
    pub indenter_e_mpa: Option<f64>,
    #[arg(long, help = format!("Poisson's ratio of the calibration indenter [default: {}]", ::sim::defaults::INDENTER_NU))]
    pub indenter_nu: Option<f64>,
    #[arg(long, help = format!("Radius of the hemispherical indenter, mm [default: {}]", ::sim::defaults::INDENTER_R_MM))]
    pub indenter_r_mm: Option<f64>,
    #[arg(long, help = format!("Seed of the simulated measurement noise [default: {}]", ::sim::defaults::SEED))]
    pub seed: Option<u64>,
}

#[derive(Debug, Args)]
pub struct SimulateArgs {
    #[command(flatten)]
    pub elastomer: ElastomerArgs,
    /// Where to write the recording.
    #[arg(short = 'o', long = "output")]
    pub output: PathBuf,
    /// Which physics makes the recording: `analytic` (the paper's model, a
    /// half-space; with --thickness-mm the linear FE layer model of a bonded
    /// gel, with friction) or `fe` (the project's large-strain finite-element
    /// reference of a bonded gel layer, taken to zero element size from two
    /// meshes: needs --thickness-mm; a few minutes).
    #[arg(long, value_enum, default_value_t = Fidelity::Analytic)]
    pub fidelity: Fidelity,
    #[command(flatten)]
    pub layer: LayerArgs,
    /// Sim profile (TOML) of left-out physics to simulate (e.g. from
    /// `easycalib diagnose --profile-out`); on a declared layer only the
    /// effects outside the contact (play, frame, drift, gain).
    #[arg(long, value_name = "PROFILE_TOML")]
    pub profile: Option<PathBuf>,
}

/// The physics `simulate` writes a recording from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Fidelity {
    Analytic,
    Fe,
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Run on the real rig described by this file (default: the built-in emulated rig).
    #[arg(long, value_name = "RIG_TOML", conflicts_with_all = sim_setup::SIMULATED_HARDWARE_FLAGS)]
    pub rig: Option<PathBuf>,
    /// Calibration script (default: the rig file's, else the built-in one). On
    /// the emulated rig the script's indenter and R1 are the simulated ones:
    /// --indenter-* and --r1-mm are refused with it.
    #[arg(long, value_name = "SCRIPT_TOML")]
    pub script: Option<PathBuf>,
    /// Folder for the recording and the report (default: runs/<UTC time>-<sensor>).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Write into an --out folder that already holds files (they are replaced;
    /// symbolic links among them are removed, never followed).
    #[arg(long)]
    pub overwrite: bool,
    /// Print the report's JSON document on stdout (progress goes to stderr).
    #[arg(long)]
    pub json: bool,
    /// Emulated rig: run at real rig speed.
    #[arg(long, conflicts_with_all = ["speedup", "rig"])]
    pub realtime: bool,
    /// Emulated rig: rig time runs this many times faster than wall time.
    #[arg(long, value_name = "N", conflicts_with = "rig")]
    pub speedup: Option<f64>,
    /// Emulated rig: serve the stage as a GRBL controller instead of a Thorlabs KDC101.
    #[arg(long, conflicts_with = "rig")]
    pub grbl: bool,
    /// Emulated rig: give the simulated contact the left-out physics of this sim
    /// profile (e.g. from `easycalib diagnose --profile-out`), so the rig
    /// reproduces the recording it was diagnosed from.
    #[arg(long, value_name = "PROFILE.toml", conflicts_with = "rig")]
    pub profile: Option<PathBuf>,
    /// Do not write the calibration to the history (docs/history.md).
    #[arg(long)]
    pub no_history: bool,
    /// Do not diagnose the recording after the fit (by default the run ends
    /// with `easycalib diagnose`'s verdict and corrected E1, nu1; docs/run.md).
    #[arg(long)]
    pub no_diagnose: bool,
    /// After the sweeps, run the experiments `plan` chooses while the
    /// diagnosis leaves explanations standing (the script's `[adaptive]`; docs/experiments.md).
    #[arg(long)]
    pub adaptive: bool,
    /// Rig time the closed loop may spend on experiments, s (with --adaptive).
    #[arg(long, value_name = "N", requires = "adaptive")]
    pub budget_s: Option<f64>,
    /// The closed loop may not choose operator-assisted steps (a rigid ball,
    /// a second indenter); without it, a real rig prompts for them and the
    /// emulated rig's simulation performs them (with --adaptive).
    #[arg(long, requires = "adaptive")]
    pub no_operator: bool,
    #[command(flatten)]
    pub db: history::DbArg,
    /// Emulated rig: thickness of the simulated gel, a flat layer on its
    /// window, mm; `inf` simulates a half-space (with --r1-mm for its dome).
    /// The recording declares it. A script declares its own ([sensor]
    /// elastomer_thickness_mm) [default: the reference sensor's 5 mm gel]
    #[arg(long, value_name = "MM", conflicts_with_all = ["rig", "script"])]
    pub thickness_mm: Option<f64>,
    /// Emulated rig: how the simulated gel sits on its window, `bonded`
    /// (default) or `sliding`; the recording declares it.
    #[arg(long, value_name = "BASE", conflicts_with_all = ["rig", "script"])]
    pub base: Option<String>,
    /// The simulated elastomer and indenter (emulated rig only).
    #[command(flatten)]
    pub elastomer: ElastomerArgs,
}

/// Exit code for bad input (unreadable or invalid recording, impossible parameters).
pub const EXIT_BAD_INPUT: u8 = 2;
/// Exit code when the data cannot be fitted.
pub const EXIT_FIT_FAILED: u8 = 3;

pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Fit(a) => calibrate::fit(a),
        Command::Simulate(a) => calibrate::simulate(a),
        Command::Run(a) => run::run(a),
        Command::Devices(a) => devices::run(a),
        Command::Sensor(a) => sensor::run(a),
        Command::Script(a) => script::script(a),
        Command::Diagnose(a) => diagnose::run(a),
        Command::Sim(a) => sim::run(a),
        Command::History(a) => history::run(a),
        Command::Plan(a) => plan::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", e.message);
            ExitCode::from(e.code)
        }
    }
}

/// A failure with the exit code it maps to.
#[derive(Debug)]
pub struct CliError {
    pub code: u8,
    pub message: String,
}

impl CliError {
    pub fn bad_input(message: impl Into<String>) -> Self {
        Self { code: EXIT_BAD_INPUT, message: message.into() }
    }
    pub fn fit_failed(message: impl Into<String>) -> Self {
        Self { code: EXIT_FIT_FAILED, message: message.into() }
    }
    pub fn other(message: impl Into<String>) -> Self {
        Self { code: 1, message: message.into() }
    }
}
