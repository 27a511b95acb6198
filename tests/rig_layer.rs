//! A declared gel layer and a rig effect at once, through the whole emulated
//! rig: real APT drivers over pseudo-terminals, the simulated marker field
//! read by the run's estimator, time-accelerated; the gel a 5 mm layer bonded
//! to its window (the script's `[sensor] elastomer_thickness_mm`), simulated
//! by the linear FE layer model with Coulomb friction (docs/physics.md, "The
//! layer in the generator and the emulated rig"). What a real rig is: both
//! the independent finite-element world of a thin gel and the sensing chain.
//!
//! The clean case is the default `easycalib run`'s gel (the reference
//! sensor's, `sim::defaults::ELASTOMER_THICKNESS_MM`), held to issue 12's bars
//! over 20 seeds; each effect on seeds 1-3 (the closing figures of ten seeds
//! each are in docs/diagnosis.md, "On a declared layer, on the emulated rig").

#[path = "support/emulated.rs"]
mod emulated;

use easycalib::run::Script;
use emulated::{Outcome, assert_fit_at_their_noise, run_script};
use sim::effects::{SimProfile, frame_compliance, rotation_backlash, stage_backlash};
use sim::recording::{Direction, Phase, Recording};

const SEEDS: u64 = 3;

/// The default script on the emulated rig's default gel, a flat layer
/// bonded to its window, as `easycalib run` declares it.
fn layered_script() -> Script {
    let mut s = Script::default();
    s.sensor.elastomer_r_mm = f64::INFINITY;
    s.sensor.elastomer_thickness_mm = Some(sim::defaults::ELASTOMER_THICKNESS_MM);
    s
}

/// The same estimate (errors in %, to a millionth of a percent).
fn same(a: (f64, f64), b: (f64, f64)) -> bool {
    (a.0 - b.0).abs() < 1e-6 && (a.1 - b.1).abs() < 1e-6
}

fn runs(profile: SimProfile) -> Vec<Outcome> {
    (1..=SEEDS).map(|seed| run_script(seed, profile.clone(), layered_script()).0).collect()
}

fn print(case: &str, runs: &[Outcome]) {
    for o in runs {
        println!(
            "{case}: seed {}  chi2/dof {:.2}  fit E1 {:+.2} % nu1 {:+.2} %  diagnosis {} {:?}  E1 {:+.2} % nu1 {:+.2} %",
            o.seed, o.chi2_dof, o.full.0, o.full.1, o.verdict, o.named, o.corrected.0, o.corrected.1
        );
    }
}

/// The default run's gel, clean, on 20 seeds: issue 12's bars for a clean
/// run (nothing named and nothing unexplained in 19 of 20; chi²/dof <= 1.3
/// in 19 of 20 as an exact model gives it, `emulated::assert_fit_at_their_noise`),
/// and the full fit within 1 % / 2 % of the truth in every run.
#[test]
fn clean_runs_on_the_default_layered_gel_fit_at_their_noise_and_name_nothing() {
    let runs: Vec<Outcome> = (1..=20).map(|seed| run_script(seed, SimProfile::default(), layered_script()).0).collect();
    print("clean", &runs);
    let quiet = runs.iter().filter(|o| ["clean", "ambiguous"].contains(&o.verdict) && o.named.is_empty()).count();
    println!("nothing named, not unexplained: {quiet} of 20");
    assert!(quiet >= 19, "{quiet} of 20 clean layered runs name nothing and leave nothing unexplained");
    assert_fit_at_their_noise("clean layered", &runs);
    for o in &runs {
        assert!(o.full.0.abs() <= 1.0 && o.full.1.abs() <= 2.0, "seed {}: fit {:?}", o.seed, o.full);
        if o.named.is_empty() {
            assert!(same(o.corrected, o.full), "seed {}: nothing named, the diagnosis keeps the fit's numbers", o.seed);
        }
    }
}

/// A gel resting on its window instead of glued to it (`elastomer_base =
/// "sliding"`), clean, on five seeds: the rig simulates that layer (the FE
/// model on a sliding base, its own field drawn by the simulated sensor) and
/// the run reads it with that base's field and tie, so the full fit recovers
/// the truth within 1 % / 2 %, fits at its noise and names nothing.
#[test]
fn clean_runs_on_a_sliding_gel_fit_at_their_noise_and_name_nothing() {
    let mut script = layered_script();
    script.sensor.elastomer_base = Some("sliding".into());
    let runs: Vec<Outcome> = (1..=5).map(|seed| run_script(seed, SimProfile::default(), script.clone()).0).collect();
    print("sliding", &runs);
    for o in &runs {
        assert!(o.full.0.abs() <= 1.0 && o.full.1.abs() <= 2.0, "seed {}: fit {:?}", o.seed, o.full);
        assert!(o.named.is_empty() && o.verdict != "unexplained", "seed {}: {}", o.seed, o.summary);
    }
    assert_fit_at_their_noise("clean sliding", &runs);
}

/// gamma1 of each unloading sample less the loading branch's at its stage
/// position (linear between the loading samples), µm, with the position.
fn unload_against_load(rec: &Recording) -> Vec<(f64, f64)> {
    let normal = |dir: Direction| -> Vec<(f64, f64)> {
        let mut v: Vec<(f64, f64)> = rec
            .samples
            .iter()
            .filter(|s| s.phase == Phase::Normal && s.experiment.is_none() && s.dir == Some(dir) && s.gamma1_mm > 0.0)
            .map(|s| (s.stage_mm, s.gamma1_mm))
            .collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v
    };
    let load = normal(Direction::Load);
    normal(Direction::Unload)
        .into_iter()
        .filter_map(|(z, g)| {
            let k = load.partition_point(|p| p.0 < z);
            let (a, b) = (load.get(k.checked_sub(1)?)?, load.get(k)?);
            let at = a.1 + (b.1 - a.1) * (z - a.0) / (b.0 - a.0);
            Some((z, 1000.0 * (g - at)))
        })
        .collect()
}

/// A sweep that unloads back to a small contact (`unload_step_mm` 0.85: its
/// last stop at about 0.45 mm, a contact of 1.6 mm, after the torsion
/// sweep's long hold at 4.5 mm) reads it as the loading branch did. The
/// clean gel's contact has no hysteresis (the rig's layer law is a function
/// of the approach), so the two branches agree to the noise; the run's
/// sensing once fitted that contact with the curvature of the deepest one,
/// which its many frames had made "the smallest resolved", and read it 9-15
/// µm deep (8 of 10 seeds then called the run unexplained). That bias is in
/// every repeat's last stop, so the mean over them is held to 5 µm, and each
/// one (a reading less the loading branch interpolated, both with recorded
/// standard errors of about 0.9 µm) to 8: each alone was held to 5 µm, which
/// seed 1 once reached exactly on the CI machine (1.7, 5.0 and 2.7 µm over
/// its three repeats).
#[test]
fn a_sweep_that_unloads_back_to_a_small_contact_reads_it_as_the_loading_branch_did() {
    let mut script = layered_script();
    script.normal.unload_step_mm = 0.85;
    for seed in 1..=4 {
        let (o, rec) = run_script(seed, SimProfile::default(), script.clone());
        let off = unload_against_load(&rec);
        println!("seed {seed}: {} {:?}; unloading less loading (stage mm: um) {off:.1?}", o.verdict, o.named);
        let last: Vec<f64> = off.iter().filter(|p| p.0 < 0.6).map(|p| p.1).collect();
        let mean = last.iter().sum::<f64>() / last.len() as f64;
        let worst = last.iter().map(|v| v.abs()).fold(f64::NAN, f64::max);
        assert!(
            mean.abs() < 5.0 && worst < 8.0,
            "seed {seed}: the last unloading stop reads {mean:.1} um off the loading branch on average, {worst:.1} at worst"
        );
        assert!(o.verdict != "unexplained" && o.named.is_empty(), "seed {seed}: {}", o.summary);
    }
}

/// `effect`, given to the layered rig at a size that matters (checked: it
/// biases the plain calibration by 2 % or more and leaves it a misfit of
/// chi²/dof 3 or more in every run), is named and E1/nu1 corrected to
/// within 1 %/2 %. Ten seeds named ten of ten at 0.02 mm
/// (docs/diagnosis.md); two of these three must. (The emulated rig runs on
/// wall time, so a seed's run is not repeatable to the sample: a stage
/// backlash of 0.02 mm biased seed
/// 1's plain fit by 1.60-1.75 % in nu1 and seeds 2-3 by 2.00-3.13 % from run
/// to run; at 0.03 mm, the size used, by 3.46-4.65 % over twelve runs.)
fn named_and_corrected(effect: &str, profile: SimProfile) {
    let runs = runs(profile);
    print(effect, &runs);
    for o in &runs {
        let bias = o.full.0.abs().max(o.full.1.abs());
        assert!(bias >= 2.0, "seed {}: {effect} biases the plain fit by only {bias:.2} %", o.seed);
        assert!(o.chi2_dof >= 3.0, "seed {}: {effect} leaves the plain fit at chi2/dof {:.2}", o.seed, o.chi2_dof);
    }
    let good =
        runs.iter().filter(|o| o.named == [effect] && o.corrected.0.abs() <= 1.0 && o.corrected.1.abs() <= 2.0).count();
    assert!(good >= 2, "{effect} named and corrected in {good} of {SEEDS} layered runs");
}

#[test]
fn stage_backlash_on_a_layered_rig_is_named_and_corrected() {
    let p = stage_backlash::Params { b_mm: 0.03, engaged: true };
    named_and_corrected("stage_backlash", SimProfile { stage_backlash: Some(p), ..Default::default() });
}

#[test]
fn rotation_backlash_on_a_layered_rig_is_named_and_corrected() {
    let p = rotation_backlash::Params { b_deg: 0.2, engaged: true };
    named_and_corrected("rotation_backlash", SimProfile { rotation_backlash: Some(p), ..Default::default() });
}

#[test]
fn frame_compliance_on_a_layered_rig_is_listed_not_named() {
    // On the layer a frame compliance leaves curvature the baseline cannot
    // absorb, which the compliance removes; but E1/nu1 can stand in for it
    // (variance inflation ~2500-4300), and a sensor gain fits nearly as well:
    // the diagnosis lists it, as ambiguous with the gain or as an effect
    // E1/nu1 can stand in for (seeds 1-6: ambiguous 3 or 4 times, the rest
    // clean with it listed so), names nothing and keeps the calibration's
    // numbers.
    let p = frame_compliance::Params { c_mm_per_n: 0.004 };
    let profile = SimProfile { frame_compliance: Some(p), ..Default::default() };
    let runs = vec![run_script(1, profile, layered_script()).0];
    print("frame_compliance", &runs);
    for o in &runs {
        assert!(o.full.1.abs() >= 2.0, "frame compliance biases nu1 only {:+.2} %", o.full.1);
        let listed = match o.verdict {
            "ambiguous" => o.summary.contains("frame_compliance"),
            "clean" => o.degenerate.iter().any(|e| e == "frame_compliance"),
            _ => false,
        };
        assert!(listed && o.named.is_empty(), "seed {}: {} {:?}", o.seed, o.summary, o.degenerate);
        assert!(same(o.corrected, o.full), "seed {}: nothing named, the calibration's numbers", o.seed);
    }
}
