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
use emulated::{Outcome, run_seed};
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
    // Issue 12's bars: chi2/dof <= 1.3, and a diagnosis that names nothing and
    // leaves nothing unexplained (ambiguous among degenerate effects names
    // nothing), in 19 of 20 runs.
    let quiet = runs.iter().filter(|o| o.verdict == "clean" || o.verdict == "ambiguous").count();
    let fitted = runs.iter().filter(|o| o.chi2_dof <= 1.3).count();
    let mut chi2: Vec<f64> = runs.iter().map(|o| o.chi2_dof).collect();
    chi2.sort_by(f64::total_cmp);
    println!("nothing named, not unexplained: {quiet} of 20; chi2/dof <= 1.3: {fitted} of 20, median {:.2}", chi2[10]);
    assert!(quiet >= 19, "{quiet} of 20 clean runs name nothing and leave nothing unexplained");
    assert!(fitted >= 19, "{fitted} of 20 clean runs fit to chi2/dof <= 1.3 (median {:.2})", chi2[10]);
    // The full fit recovers the truth in every run.
    for o in &runs {
        assert!(o.full.0.abs() <= 1.0 && o.full.1.abs() <= 2.0, "seed {}: full {:?}", o.seed, o.full);
    }
    // The paper's closed form hangs on micrometres: a micrometre of stage
    // zero moves its E1 by about 1.5 % and its nu1 by about 6 %. The run moves
    // its zero to the full fit's (docs/run.md, "Stage zero"), and the readings
    // are unbiased across its 0.2-0.8 mm window, so it must do as well as on
    // the generator's ideal recordings of the same script, seeds 1..20: no
    // larger an rms error (a fifth of margin for the rms of 20), and within 2 %
    // (E1) and 6 % (nu1) as often (ideal recordings stray beyond 6 % in nu1
    // about once in ten: 3 of 30 seeds, rms 3.1 %).
    let rms = |v: &[(f64, f64)], f: fn(&(f64, f64)) -> f64| {
        (v.iter().map(|x| f(x).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
    };
    let within = |v: &[(f64, f64)]| v.iter().filter(|x| x.0.abs() <= 2.0 && x.1.abs() <= 6.0).count();
    let rig: Vec<(f64, f64)> = runs.iter().map(|o| o.paper).collect();
    let ideal: Vec<(f64, f64)> = (1..=20)
        .map(|seed| {
            let rec = generate(&GeneratorConfig { seed, ..GeneratorConfig::default() }).unwrap();
            let p = calibrate(&rec, &FitOptions::default()).unwrap().paper;
            (100.0 * (p.e1_mpa / ELASTOMER_E_MPA - 1.0), 100.0 * (p.nu1 / ELASTOMER_NU - 1.0))
        })
        .collect();
    let (rig_e1, rig_nu1, ideal_e1, ideal_nu1) =
        (rms(&rig, |x| x.0), rms(&rig, |x| x.1), rms(&ideal, |x| x.0), rms(&ideal, |x| x.1));
    println!(
        "paper's method, rms error E1 / nu1: rig {rig_e1:.2} / {rig_nu1:.2} %, ideal {ideal_e1:.2} / {ideal_nu1:.2} %; within 2 % / 6 %: rig {}, ideal {} of 20",
        within(&rig),
        within(&ideal)
    );
    assert!(
        rig_e1 <= 1.2 * ideal_e1 && rig_nu1 <= 1.2 * ideal_nu1,
        "the paper's method is further off on the rig than on ideal recordings"
    );
    // The rms above is the comparison; the counts are binomial draws of 20.
    // A rig exactly as good as the ideal recordings (18 of 20 within here)
    // still draws 17 or fewer in about a third of runs, 15 or fewer in under
    // 5 %: so the count may fall two below the ideal one, not three.
    assert!(
        within(&rig) + 2 >= 18.min(within(&ideal)),
        "{} of 20 rig runs within 2 % / 6 %, {} ideal",
        within(&rig),
        within(&ideal)
    );
}
