//! The simulated set-up from the command line, resolved once: the elastomer
//! flags, the script (which describes the rig it runs on), the sim profile,
//! the seed and the speed-up become one [`SimSetup`], which the emulated rig
//! and the generator take and a run reports as its truth. Flags that the
//! script or the profile would silently override are refused here, with a
//! message that says where the value belongs.

use std::path::Path;

use sim::defaults;
use sim::effects::SimProfile;
use sim::physics::{Body, ContactPair};
use sim::setup::{SetupError, SimSetup, SimSetupInput};

use super::{CliError, ElastomerArgs};
use crate::run::Script;

/// The flags (clap ids) that set the simulated hardware: they mean nothing
/// with `--rig`, which clap refuses together with any of them.
pub const SIMULATED_HARDWARE_FLAGS: [&str; 7] =
    ["e1_mpa", "nu1", "elastomer_r_mm", "indenter_e_mpa", "indenter_nu", "indenter_r_mm", "seed"];

/// Everything on the command line that says what to simulate.
#[derive(Debug, Clone, Copy)]
pub struct SimSetupArgs<'a> {
    pub elastomer: &'a ElastomerArgs,
    /// The calibration script and where it came from: its indenter and R1 are
    /// the simulated rig's.
    pub script: Option<(&'a Path, &'a Script)>,
    /// `--profile`: the left-out physics (and perhaps the material) to simulate.
    pub profile: Option<&'a Path>,
    pub speedup: f64,
}

/// The one simulated set-up of a command, every value checked once.
pub fn sim_setup(args: SimSetupArgs<'_>) -> Result<SimSetup, CliError> {
    let e = args.elastomer;
    if let Some((path, _)) = args.script {
        let given = e.script_flags_given();
        if !given.is_empty() {
            return Err(CliError::bad_input(format!(
                "{} cannot be used with --script: the script {} describes the indenter ([indenter]) and R1 \
                 ([sensor] elastomer_r_mm) of the rig it runs on; set them there, or leave out --script",
                given.join(", "),
                path.display()
            )));
        }
    }
    let profile = load_profile(args.profile)?;
    if let (Some(path), Some(_)) = (args.profile, profile.material)
        && (e.e1_mpa.is_some() || e.nu1.is_some())
    {
        return Err(CliError::bad_input(format!(
            "--e1-mpa and --nu1 cannot be used with the sim profile {}: its [material] (E1_MPa, nu1) is the \
             simulated elastomer; change it there, or leave out the flags",
            path.display()
        )));
    }
    let input = SimSetupInput {
        pair: e.pair(args.script.map(|(_, s)| s)),
        profile,
        seed: e.seed.unwrap_or(defaults::SEED),
        speedup: args.speedup,
        ..SimSetupInput::default()
    };
    input.resolve().map_err(|err| match err {
        SetupError::Speedup(s) => CliError::bad_input(format!("--speedup must be a positive number, got {s}")),
        other => CliError::bad_input(other.to_string()),
    })
}

impl ElastomerArgs {
    /// The flags given that a script describes instead (R1 and the indenter).
    fn script_flags_given(&self) -> Vec<&'static str> {
        [
            ("--r1-mm", self.elastomer_r_mm.is_some()),
            ("--indenter-e-mpa", self.indenter_e_mpa.is_some()),
            ("--indenter-nu", self.indenter_nu.is_some()),
            ("--indenter-r-mm", self.indenter_r_mm.is_some()),
        ]
        .into_iter()
        .filter_map(|(flag, given)| given.then_some(flag))
        .collect()
    }

    /// The contact pair the flags describe (defaults for what is not given),
    /// with R1 and the indenter from `script` when there is one.
    fn pair(&self, script: Option<&Script>) -> ContactPair {
        let elastomer_r_mm = match script {
            Some(s) => s.sensor.elastomer_r_mm,
            None => self.elastomer_r_mm.unwrap_or(defaults::ELASTOMER_R_MM),
        };
        let e1_mpa = self.e1_mpa.unwrap_or(defaults::ELASTOMER_E_MPA);
        let elastomer = Body::new(e1_mpa, self.nu1.unwrap_or(defaults::ELASTOMER_NU), elastomer_r_mm);
        let indenter = match script {
            Some(s) => s.indenter,
            None => Body::new(
                self.indenter_e_mpa.unwrap_or(defaults::INDENTER_E_MPA),
                self.indenter_nu.unwrap_or(defaults::INDENTER_NU),
                self.indenter_r_mm.unwrap_or(defaults::INDENTER_R_MM),
            ),
        };
        ContactPair { elastomer, indenter }
    }
}

/// The sim profile given with `--profile` (clean without one).
fn load_profile(path: Option<&Path>) -> Result<SimProfile, CliError> {
    match path {
        None => Ok(SimProfile::default()),
        Some(p) => SimProfile::load(p).map_err(|e| CliError::bad_input(format!("sim profile {}: {e}", p.display()))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sim::effects::Material;

    fn args(elastomer: &ElastomerArgs) -> SimSetupArgs<'_> {
        SimSetupArgs { elastomer, script: None, profile: None, speedup: defaults::SPEEDUP }
    }

    #[test]
    fn flags_not_given_take_the_defaults_and_a_script_sets_r1_and_the_indenter() {
        let none = ElastomerArgs::default();
        let s = sim_setup(args(&none)).unwrap();
        assert_eq!(*s.pair(), defaults::pair());
        assert_eq!(s.seed(), defaults::SEED);
        let mut script = Script { indenter: Body::new(2.0, 0.45, 4.0), ..Script::default() };
        script.sensor.elastomer_r_mm = f64::INFINITY;
        let e = ElastomerArgs { e1_mpa: Some(0.5), seed: Some(7), ..ElastomerArgs::default() };
        let s = sim_setup(SimSetupArgs { script: Some((Path::new("s.toml"), &script)), ..args(&e) }).unwrap();
        assert_eq!(s.pair().elastomer, Body::new(0.5, defaults::ELASTOMER_NU, f64::INFINITY));
        assert_eq!(s.pair().indenter, Body::new(2.0, 0.45, 4.0));
        assert_eq!(s.seed(), 7);
    }

    #[test]
    fn flags_a_script_or_profile_would_override_are_refused() {
        let script = Script::default();
        let e = ElastomerArgs { indenter_r_mm: Some(4.0), elastomer_r_mm: Some(20.0), ..ElastomerArgs::default() };
        let err = sim_setup(SimSetupArgs { script: Some((Path::new("s.toml"), &script)), ..args(&e) }).unwrap_err();
        assert_eq!(err.code, super::super::EXIT_BAD_INPUT);
        assert!(err.message.starts_with("--r1-mm, --indenter-r-mm cannot be used with --script"), "{}", err.message);
        // E1 and nu1 are the elastomer's own: a script does not describe them.
        let e1 = ElastomerArgs { e1_mpa: Some(0.4), ..ElastomerArgs::default() };
        assert!(sim_setup(SimSetupArgs { script: Some((Path::new("s.toml"), &script)), ..args(&e1) }).is_ok());

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.toml");
        let material = SimProfile { material: Some(Material { e1_mpa: 0.5, nu1: 0.3 }), ..SimProfile::default() };
        material.save(&path).unwrap();
        let err = sim_setup(SimSetupArgs { profile: Some(&path), ..args(&e1) }).unwrap_err();
        assert!(err.message.contains("--e1-mpa and --nu1 cannot be used with the sim profile"), "{}", err.message);
        // Without the flags the profile's material is the truth.
        let none = ElastomerArgs::default();
        let s = sim_setup(SimSetupArgs { profile: Some(&path), ..args(&none) }).unwrap();
        assert_eq!(s.truth(), Material { e1_mpa: 0.5, nu1: 0.3 });
    }

    #[test]
    fn impossible_values_are_refused_naming_them() {
        let e = ElastomerArgs { nu1: Some(0.7), ..ElastomerArgs::default() };
        assert!(sim_setup(args(&e)).unwrap_err().message.contains("0.7"));
        let none = ElastomerArgs::default();
        let err = sim_setup(SimSetupArgs { speedup: 0.0, ..args(&none) }).unwrap_err();
        assert_eq!(err.message, "--speedup must be a positive number, got 0");
    }
}
