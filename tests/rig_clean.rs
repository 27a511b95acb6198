//! Issue 12's clean runs: the default calibration on the emulated rig (real
//! APT drivers over pseudo-terminals, the simulated Tac3D-class marker field
//! through the sensor link, time-accelerated), one run per noise seed. What a
//! run records must agree with the model it is fitted with: the full fit's
//! residuals are the size the samples' own standard errors say (chi²/dof), the
//! diagnosis finds nothing to name and nothing unexplained, and the paper's
//! closed form is as close to the truth as on ideal data.

#[path = "support/emulated.rs"]
mod emulated;

use easycalib::fit::{FitOptions, calibrate};
use emulated::{Outcome, assert_fit_at_their_noise, binomial_pmf, run_seed};
use sim::defaults::{ELASTOMER_E_MPA, ELASTOMER_NU};
use sim::effects::SimProfile;
use sim::generator::{GeneratorConfig, generate};

#[test]
fn clean_runs_on_the_emulated_rig_fit_near_their_errors_and_mostly_name_nothing() {
    let runs: Vec<Outcome> = (1..=20).map(|seed| run_seed(seed, SimProfile::default())).collect();
    println!("seed  chi2/dof  full E1 %  full nu1 %  paper E1 %  paper nu1 %  diagnosis");
    for o in &runs {
        // The recording carries the estimator's errors (docs/recording-format.md).
        assert!(o.with_sd.0 * 100 >= 95 * o.with_sd.1, "seed {}: {:?} samples carry gamma1_sd_mm", o.seed, o.with_sd);
        let verdict = if o.verdict == "clean" { "clean".to_string() } else { format!("{}: {}", o.verdict, o.summary) };
        println!(
            "{:4}  {:8.2}  {:+9.2}  {:+10.2}  {:+10.2}  {:+11.2}  {verdict}",
            o.seed, o.chi2_dof, o.full.0, o.full.1, o.paper.0, o.paper.1
        );
    }
    // Issue 12's bars: a diagnosis that names nothing and leaves nothing
    // unexplained (ambiguous among degenerate effects names nothing) in 19
    // of 20 runs, and chi2/dof <= 1.3 in 19 of 20 as an exact model gives it
    // (`emulated::assert_fit_at_their_noise`).
    let quiet = runs.iter().filter(|o| o.verdict == "clean" || o.verdict == "ambiguous").count();
    let mut chi2: Vec<f64> = runs.iter().map(|o| o.chi2_dof).collect();
    chi2.sort_by(f64::total_cmp);
    println!("nothing named, not unexplained: {quiet} of 20; chi2/dof median {:.2}", chi2[10]);
    assert!(quiet >= 19, "{quiet} of 20 clean runs name nothing and leave nothing unexplained");
    assert_fit_at_their_noise("clean", &runs);
    // The full fit recovers the truth in every run.
    for o in &runs {
        assert!(o.full.0.abs() <= 1.0 && o.full.1.abs() <= 2.0, "seed {}: full {:?}", o.seed, o.full);
    }
    // The paper's closed form hangs on micrometres: a micrometre of stage
    // zero moves its E1 by about 1.5 % and its nu1 by about 6 %. The run moves
    // its zero to the full fit's (docs/run.md, "Stage zero"), and the readings
    // are unbiased across its 0.2-0.8 mm window, so it must do as well as on
    // the generator's ideal recordings of the same script.
    //
    // The rig's runs are not repeatable draw for draw (its clock is wall time,
    // sped up), so this is a comparison of two scatters, judged as one: the
    // ideal recordings' scatter is measured on 100 seeds (its rms then known
    // to about 7 %), and 20 rig runs as good as them have a mean square of
    // sigma^2 chi^2_20 / 20, which exceeds 2.00 sigma^2 (rms 1.41 sigma) in
    // 0.5 % of test runs. The counts within 2 % / 6 % are binomial: 20 draws
    // at the ideal rate fall below the 0.5 % quantile in as few test runs.
    let rms = |v: &[(f64, f64)], f: fn(&(f64, f64)) -> f64| {
        (v.iter().map(|x| f(x).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
    };
    let within = |v: &[(f64, f64)]| v.iter().filter(|x| x.0.abs() <= 2.0 && x.1.abs() <= 6.0).count();
    let rig: Vec<(f64, f64)> = runs.iter().map(|o| o.paper).collect();
    let ideal: Vec<(f64, f64)> = (1..=100)
        .map(|seed| {
            let rec = generate(&GeneratorConfig { seed, ..GeneratorConfig::default() }).unwrap();
            let p = calibrate(&rec, &FitOptions::default()).unwrap().paper;
            (100.0 * (p.e1_mpa / ELASTOMER_E_MPA - 1.0), 100.0 * (p.nu1 / ELASTOMER_NU - 1.0))
        })
        .collect();
    let (rig_e1, rig_nu1, ideal_e1, ideal_nu1) =
        (rms(&rig, |x| x.0), rms(&rig, |x| x.1), rms(&ideal, |x| x.0), rms(&ideal, |x| x.1));
    let ideal_rate = within(&ideal) as f64 / ideal.len() as f64;
    let fewest = binomial_quantile(20, ideal_rate, 0.005);
    println!(
        "paper's method, rms error E1 / nu1: rig {rig_e1:.2} / {rig_nu1:.2} % (20 runs), ideal {ideal_e1:.2} / {ideal_nu1:.2} % (100 seeds); within 2 % / 6 %: rig {} of 20, ideal {:.0} %, fewest allowed {fewest}",
        within(&rig),
        100.0 * ideal_rate
    );
    let bound = (CHI2_20_Q995 / 20.0).sqrt();
    assert!(
        rig_e1 <= bound * ideal_e1 && rig_nu1 <= bound * ideal_nu1,
        "the paper's method is further off on the rig ({rig_e1:.2} / {rig_nu1:.2} %) than ideal recordings allow ({:.2} / {:.2} %)",
        bound * ideal_e1,
        bound * ideal_nu1
    );
    assert!(within(&rig) >= fewest, "{} of 20 rig runs within 2 % / 6 %, at least {fewest} expected", within(&rig));
}

/// The 99.5th percentile of chi-squared with 20 degrees of freedom.
const CHI2_20_Q995: f64 = 39.997;

/// The largest k with P(X < k) <= `tail` for X ~ Binomial(n, p): fewer than k
/// successes happen in at most `tail` of draws.
fn binomial_quantile(n: u64, p: f64, tail: f64) -> usize {
    let mut below = 0.0;
    for k in 0..=n {
        let pk = binomial_pmf(n, k, p);
        if below + pk > tail {
            return k as usize;
        }
        below += pk;
    }
    n as usize
}
