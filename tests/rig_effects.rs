//! Issue 12's named effects: the default calibration on the emulated rig (real
//! APT drivers over pseudo-terminals, the simulated marker field, time
//! accelerated), with one effect of the library given to the rig's contact by
//! a sim profile, ten noise seeds each. The standard sweeps identify these
//! three (docs/diagnosis.md); each is given at a size that biases the
//! calibration's E1 or nu1 by at least 2 % (the test prints the bias and
//! checks it). The run's own diagnosis must name it in at least 9 of 10 seeds
//! and bring E1 within 1 % and nu1 within 2 % of the rig's truth.
//!
//! Not here, and why (docs/diagnosis.md, "On the emulated rig"): frame
//! compliance and sensor gain come out ambiguous and adhesion degenerate on
//! the standard sweeps (issue 14's closed loop runs the experiment that tells
//! them apart); thermal drift and viscoelastic creep are named at sizes below
//! the 2 % bias, and left unexplained above it.

#[path = "support/emulated.rs"]
mod emulated;

use emulated::{Outcome, run_seed};
use sim::effects::{SimProfile, partial_slip, rotation_backlash, stage_backlash};

const SEEDS: u64 = 10;

fn check(effect: &str, profile: SimProfile) {
    let runs: Vec<Outcome> = (1..=SEEDS).map(|seed| run_seed(seed, profile.clone())).collect();
    println!("{effect}: seed  calibration E1 % nu1 %   corrected E1 % nu1 %   named");
    for o in &runs {
        println!(
            "{effect}: {:4}  {:+8.2} {:+8.2}   {:+8.2} {:+8.2}   {} ({})",
            o.seed,
            o.full.0,
            o.full.1,
            o.corrected.0,
            o.corrected.1,
            o.named.join(", "),
            o.verdict
        );
    }
    // The effect matters: the calibration that ignores it is off by 2 % or more.
    let mut bias: Vec<f64> = runs.iter().map(|o| o.full.0.abs().max(o.full.1.abs())).collect();
    bias.sort_by(f64::total_cmp);
    let median_bias = bias[bias.len() / 2];
    assert!(median_bias >= 2.0, "{effect} biases the calibration by only {median_bias:.2} % (median)");
    let good = runs
        .iter()
        .filter(|o| o.named.contains(&effect) && o.corrected.0.abs() <= 1.0 && o.corrected.1.abs() <= 2.0)
        .count();
    println!("{effect}: median bias {median_bias:.2} %; named and corrected in {good} of {SEEDS}");
    assert!(good * 10 >= 9 * SEEDS as usize, "{effect}: named and corrected in {good} of {SEEDS} seeds");
}

#[test]
fn partial_slip_is_named_and_corrected_on_the_emulated_rig() {
    check("partial_slip", SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.3 }), ..Default::default() });
}

#[test]
fn rotation_backlash_is_named_and_corrected_on_the_emulated_rig() {
    // Issue 15's torsion sweep averages most frames at the largest twists,
    // where a lost motion of 0.15 deg biases nu1 by only 1.7-2.0 %: 0.2 deg.
    let p = rotation_backlash::Params { b_deg: 0.2, engaged: true };
    check("rotation_backlash", SimProfile { rotation_backlash: Some(p), ..Default::default() });
}

#[test]
fn stage_backlash_is_named_and_corrected_on_the_emulated_rig() {
    let p = stage_backlash::Params { b_mm: 0.02, engaged: true };
    check("stage_backlash", SimProfile { stage_backlash: Some(p), ..Default::default() });
}
