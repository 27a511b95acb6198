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
    /// The full fit's degrees of freedom (readings less fitted parameters).
    pub dof: usize,
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
            // E1, nu1 and z0, and the friction when it was fitted.
            dof: cal.full.samples_used.saturating_sub(3 + usize::from(cal.full.contact_friction.is_some())).max(1),
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

/// Issue 12's bar for clean runs, chi²/dof <= 1.3 in 19 runs of 20, held as
/// what a model exact to the recorded errors gives: each run's chi² is then
/// chi-squared with its dof (130-140 for the default script), and a run
/// passes 1.3 in 1.0-1.3 % of seeds, so two of twenty do in 2-3 % of test
/// runs: the CI failures of a1b4bef (1.32 and 1.37, median 0.97) and of
/// df69c1c (docs/run.md). So the count of runs past 1.3 may reach what 20
/// draws of an exact model reach in all but 0.5 % of test runs (two of
/// twenty at the default script's dof), and the runs' pooled chi² must be
/// what an exact model gives, at 0.5 % too: over some 2,600 dof that is
/// about 1.07, a far finer check of the model than the count (a misfit
/// worth a tenth of the noise variance fails it). Prints its figures.
pub fn assert_fit_at_their_noise(case: &str, runs: &[Outcome]) {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    const BAR: f64 = 1.3;
    let past = runs.iter().filter(|o| o.chi2_dof > BAR).count();
    // The likeliest run to pass the bar by noise alone sets the rate.
    let p = runs
        .iter()
        .map(|o| ChiSquared::new(o.dof as f64).map_or(1.0, |c| c.sf(BAR * o.dof as f64)))
        .fold(0.0, f64::max);
    let allowed = binomial_upper(runs.len() as u64, p, 0.005).max(runs.len() / 20);
    let dof: usize = runs.iter().map(|o| o.dof).sum();
    let pooled = runs.iter().map(|o| o.chi2_dof * o.dof as f64).sum::<f64>() / dof as f64;
    let pooled_bound = ChiSquared::new(dof as f64).map_or(f64::NAN, |c| c.inverse_cdf(0.995)) / dof as f64;
    println!(
        "{case}: chi2/dof <= {BAR} in {} of {} runs (past it by noise alone: {:.2} % of runs, at most {allowed} allowed); pooled chi2/dof {pooled:.3} over {dof} dof (an exact model: <= {pooled_bound:.3})",
        runs.len() - past,
        runs.len(),
        100.0 * p
    );
    assert!(past <= allowed, "{case}: {past} of {} runs past chi2/dof {BAR}, at most {allowed} expected", runs.len());
    assert!(
        pooled <= pooled_bound,
        "{case}: pooled chi2/dof {pooled:.3} over {dof} dof, an exact model gives <= {pooled_bound:.3}"
    );
}

/// The smallest c with P(X > c) <= `tail` for X ~ Binomial(n, p).
pub fn binomial_upper(n: u64, p: f64, tail: f64) -> usize {
    let mut at_most = 0.0;
    for k in 0..=n {
        at_most += binomial_pmf(n, k, p);
        if 1.0 - at_most <= tail {
            return k as usize;
        }
    }
    n as usize
}

/// P(X = k) for X ~ Binomial(n, p).
pub fn binomial_pmf(n: u64, k: u64, p: f64) -> f64 {
    let choose: f64 = (0..k).map(|i| (n - i) as f64 / (i + 1) as f64).product();
    choose * p.powi(k as i32) * (1.0 - p).powi((n - k) as i32)
}
