//! One calibration on the built-in emulated rig (real APT drivers over
//! pseudo-terminals, the simulated Tac3D-class marker field through the
//! sensor link, time-accelerated), as `easycalib run` makes it, and what it
//! came to against the rig's truth. Included with
//! `#[path = "support/emulated.rs"] mod emulated;` by the rig tests.

#![allow(dead_code)] // each rig test reads the fields it checks
use std::sync::Mutex;

use easycalib::rig::emulated::{EmulatedRig, ServeOptions};
use easycalib::run::{RunStatus, Script};
use sim::effects::SimProfile;
use sim::recording::Recording;
use sim::setup::SimSetupInput;

/// One rig at a time: two cores, real timeouts.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// What one run came to. Errors are relative to the rig's truth, %.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub seed: u64,
    pub chi2_dof: f64,
    /// The run's diagnosis: `clean`, `effects`, `ambiguous`, `unexplained`.
    pub verdict: &'static str,
    /// Its first line.
    pub summary: String,
    /// The effects it says E1/nu1 can stand in for with these sweeps
    /// ("... cannot be told from E1/nu1 here").
    pub degenerate: Vec<String>,
    /// The effects it named.
    pub named: Vec<&'static str>,
    /// (E1, nu1): the full fit (the calibration), the paper's method, and the
    /// diagnosis's values (corrected for what it named; the calibration's
    /// when it named nothing).
    pub full: (f64, f64),
    pub paper: (f64, f64),
    pub corrected: (f64, f64),
    /// Samples that carry their standard error, of the samples in contact.
    pub with_sd: (usize, usize),
    /// The experiments the closed loop ran (`[adaptive]`), in order.
    pub adaptive: Vec<easycalib::run::AdaptiveStep>,
    /// The closed loop's chain as the run's reports give it: report.json's
    /// `run.experiments` (null when absent), report.md's `| experiment` rows.
    pub report_chain: (serde_json::Value, Vec<String>),
}

/// Run the default script on the emulated rig with noise seed `seed` and the
/// left-out physics of `profile`.
pub fn run_seed(seed: u64, profile: SimProfile) -> Outcome {
    run_script(seed, profile, Script::default()).0
}

/// As [`run_seed`] with the rig's clock `speedup` times faster than wall time
/// (the rig tests' default is [`SPEEDUP`]).
pub fn run_seed_at(seed: u64, profile: SimProfile, speedup: f64) -> Outcome {
    run_script_at(seed, profile, Script::default(), speedup).0
}

/// How much faster than wall time the rig's clock runs in these tests.
pub const SPEEDUP: f64 = 40.0;

/// As [`run_seed`] with `script`; also the recording the run left (stage zero moved).
pub fn run_script(seed: u64, profile: SimProfile, script: Script) -> (Outcome, Recording) {
    run_script_at(seed, profile, script, SPEEDUP)
}

/// As [`run_script`] at `speedup`.
pub fn run_script_at(seed: u64, profile: SimProfile, script: Script, speedup: f64) -> (Outcome, Recording) {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    rt.block_on(async {
        // A script that declares a gel layer runs on that layer with the
        // script's R1 and indenter, as `easycalib run --script` does.
        let layer = script.sensor.layer().expect("a valid script");
        let clean_rig = profile == SimProfile::default();
        let mut input = SimSetupInput { speedup, seed, profile, ..SimSetupInput::default() };
        if layer.is_some() {
            input.pair.elastomer.r_mm = script.sensor.elastomer_r_mm;
            input.pair.indenter = script.indenter;
        }
        let setup = input.resolve().unwrap();
        let setup = match layer {
            Some(layer) => {
                easycalib::rig::emulated::on_declared_layer(setup, layer).expect("a layer the rig simulates")
            }
            None => setup,
        };
        let rig = EmulatedRig::start(setup, ServeOptions::default()).await.unwrap();
        let dir = tempfile::tempdir().unwrap();
        let truth = rig.truth();
        let r = rig.calibrate(script, dir.path()).await.expect("devices open");
        assert_eq!(r.outcome.status, RunStatus::Completed, "seed {seed}: {:?}", r.outcome.status);
        let cal = r.calibration.as_ref().unwrap_or_else(|| panic!("seed {seed}: no fit: {:?}", r.fit_error));
        let rec = Recording::read_path(&r.outcome.recording).unwrap();
        // The diagnosis the run made of its own recording (on by default).
        let d = r.diagnosis.as_ref().expect("the run diagnoses by default");
        let live: Vec<_> = rec.samples.iter().filter(|s| s.gamma1_mm != 0.0).collect();
        let with_sd = live.iter().filter(|s| s.gamma1_sd_mm.is_some()).count();
        let pct = |x: f64, t: f64| 100.0 * (x / t - 1.0);
        // A clean rig the diagnosis does not call clean (or any run it
        // leaves unexplained): its folder is kept for whoever traces it.
        if (clean_rig && !d.effects.is_empty()) || d.verdict.as_str() == "unexplained" {
            let keep = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("rig-runs").join(format!(
                "seed{seed}-{}-{}",
                d.verdict.as_str(),
                std::process::id()
            ));
            if std::fs::create_dir_all(&keep).is_ok() {
                for f in std::fs::read_dir(dir.path()).into_iter().flatten().flatten() {
                    let _ = std::fs::copy(f.path(), keep.join(f.file_name()));
                }
                println!(
                    "seed {seed}: {} on this rig; its run folder is kept in {}",
                    d.verdict.as_str(),
                    keep.display()
                );
            }
        }
        let out = Outcome {
            seed,
            chi2_dof: cal.full.chi2_dof.expect("a rig-made recording carries standard errors"),
            verdict: d.verdict.as_str(),
            summary: d.summary.lines().next().unwrap_or("").to_string(),
            degenerate: d
                .summary
                .lines()
                .filter_map(|l| l.trim().split_once(" cannot be told from E1/nu1").map(|(e, _)| e.to_string()))
                .collect(),
            named: d.effects.iter().map(|e| e.name).collect(),
            full: (pct(cal.full.e1_mpa, truth.e1_mpa), pct(cal.full.nu1, truth.nu1)),
            paper: (pct(cal.paper.e1_mpa, truth.e1_mpa), pct(cal.paper.nu1, truth.nu1)),
            corrected: (pct(d.e1_mpa, truth.e1_mpa), pct(d.nu1, truth.nu1)),
            with_sd: (with_sd, live.len()),
            adaptive: r.outcome.adaptive.clone(),
            report_chain: {
                let files = r.report.as_ref().expect("a completed run writes its report");
                let json: serde_json::Value =
                    serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
                let md = std::fs::read_to_string(&files.markdown).unwrap();
                let rows = md.lines().filter(|l| l.starts_with("| experiment")).map(str::to_string).collect();
                (json["run"]["experiments"].clone(), rows)
            },
        };
        (out, rec)
    })
}
