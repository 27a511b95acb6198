//! Issue 12's named effects: the default calibration on the emulated rig (real
//! APT drivers over pseudo-terminals, the simulated marker field, time
//! accelerated), with one effect of the library given to the rig's contact by
//! a sim profile, ten noise seeds each. The standard sweeps identify these
//! five (docs/diagnosis.md); each is given at a size that biases the
//! calibration's E1 or nu1 by at least 2 % (the test prints the bias and
//! checks it). The run's own diagnosis must name it in at least 9 of 10 seeds
//! and bring E1 within 1 % and nu1 within 2 % of the rig's truth.
//!
//! Frame compliance and sensor gain are degenerate with E1 and nu1 on the
//! standard sweeps (issue 14's closed loop runs the experiment that tells them
//! apart): here the diagnosis must say so, ambiguous with the effect among the
//! explanations it lists, and name nothing.
//!
//! Not here, and why (docs/diagnosis.md, "On the emulated rig"): adhesion at
//! sizes that bias the calibration by 2 % is named in most seeds but its
//! correction is weakly determined; what is checked of it is that the rig
//! reads a tacky gel as its truth (the last test).

#[path = "support/emulated.rs"]
mod emulated;

use emulated::{Outcome, SPEEDUP, run_seed_at};
use sim::effects::{
    SimProfile, frame_compliance, partial_slip, rotation_backlash, sensor_gain, stage_backlash, thermal_drift,
    viscoelastic,
};

const SEEDS: u64 = 10;

fn check(effect: &str, profile: SimProfile) {
    check_at(effect, profile, SPEEDUP)
}

/// [`check`] with the rig's clock `speedup` times faster than wall time.
fn check_at(effect: &str, profile: SimProfile, speedup: f64) {
    let runs: Vec<Outcome> = (1..=SEEDS).map(|seed| run_seed_at(seed, profile.clone(), speedup)).collect();
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

#[test]
fn thermal_drift_is_named_and_corrected_on_the_emulated_rig() {
    // 4 um/s of the frame: about 0.3 mm more approach by the end of a run.
    // The issue-15 sweeps take half the rig time and twist at the top of the
    // loading branch: 0.15 um/s, which biased the step-by-step design by
    // 3.2 %, moves nu1 by 0.2 % here (docs/diagnosis.md). At 2.5 um/s the
    // plain fit's nu1 lay anywhere from -0.04 to -5.8 % from one run of a
    // seed to the next (a CI run's median 1.87 %, under the 2 % an effect
    // must bias by); at 4 um/s it is -6.4 to -11.2 %. The rig runs 10 times
    // faster than real time, not 40: a loaded host stretches the rig time
    // between stops at 40, and with it the drift a stop sees (in CI seed 3
    // once stopped at the depth limit at beta 0.1972).
    let p = thermal_drift::Params { v_mm_per_s: 4e-3, vdot_mm_per_s2: 0.0 };
    check_at("thermal_drift", SimProfile { thermal_drift: Some(p), ..Default::default() }, 10.0);
}

#[test]
fn viscoelastic_creep_is_named_and_corrected_on_the_emulated_rig() {
    // The rig's approach presses the gel before the recording begins: the
    // diagnosis fits the memory of that unrecorded history and reads each
    // sample over the frames and moves the recording's times say
    // (docs/diagnosis.md, "The measurement").
    let p = viscoelastic::Params { rho: 1.06, tau_s: 8.0, memory_n: 0.0 };
    check("viscoelastic", SimProfile { viscoelastic: Some(p), ..Default::default() });
}

/// Seeds of the degenerate effects: the check is that nothing is falsely
/// named, which five seeds show as well as ten at half the CI time.
const DEGENERATE_SEEDS: u64 = 5;

/// An effect E1/nu1 can stand in for on the standard sweeps: it biases the
/// calibration, and the diagnosis lists it among explanations it cannot tell
/// apart, names nothing and keeps the calibration's E1/nu1.
fn check_ambiguous(effect: &str, profile: SimProfile) {
    let runs: Vec<Outcome> = (1..=DEGENERATE_SEEDS).map(|seed| run_seed_at(seed, profile.clone(), SPEEDUP)).collect();
    for o in &runs {
        println!("{effect}: {:4}  {:+8.2} {:+8.2}   {}: {}", o.seed, o.full.0, o.full.1, o.verdict, o.summary);
    }
    let mut bias: Vec<f64> = runs.iter().map(|o| o.full.0.abs().max(o.full.1.abs())).collect();
    bias.sort_by(f64::total_cmp);
    assert!(bias[bias.len() / 2] >= 2.0, "{effect} biases the calibration by only {:.2} %", bias[bias.len() / 2]);
    for o in &runs {
        assert!(o.named.is_empty(), "{effect} seed {}: named {:?}", o.seed, o.named);
        assert_eq!(o.verdict, "ambiguous", "{effect} seed {}: {}", o.seed, o.summary);
        assert!(o.summary.contains(effect), "{effect} seed {}: not listed: {}", o.seed, o.summary);
    }
}

#[test]
fn frame_compliance_is_reported_ambiguous_on_the_emulated_rig() {
    let p = frame_compliance::Params { c_mm_per_n: 0.004 };
    check_ambiguous("frame_compliance", SimProfile { frame_compliance: Some(p), ..Default::default() });
}

#[test]
fn sensor_gain_is_reported_ambiguous_on_the_emulated_rig() {
    let p = sensor_gain::Params { g: 0.99 };
    check_ambiguous("sensor_gain", SimProfile { sensor_gain: Some(p), ..Default::default() });
}

/// What a time-dependent model needs from a rig-made recording
/// (docs/recording-format.md, the time columns): every sample says which
/// frames it averaged, and every change of pose says when its move ran, in
/// the order the rig lived them.
#[test]
fn the_rig_records_when_each_sample_was_read_and_how_it_got_there() {
    let (_, rec) = emulated::run_script(3, SimProfile::default(), easycalib::run::Script::default());
    let mut prev: Option<&sim::recording::Sample> = None;
    for (i, s) in rec.samples.iter().enumerate() {
        let from = s.timing.frames_from_s.unwrap_or_else(|| panic!("sample {i} has no t_frames_from_s"));
        assert!(from <= s.t_s, "sample {i}: frames from {from} after t_s {}", s.t_s);
        if let Some(p) = prev {
            assert!(
                from >= p.t_s,
                "sample {i}: its frames start at {from}, before the previous sample ended ({})",
                p.t_s
            );
            let moved = (s.stage_mm - p.stage_mm).abs() > 1e-9 || (s.rot_deg - p.rot_deg).abs() > 1e-9;
            match s.timing.move_s {
                Some((a, b)) => {
                    assert!(
                        p.t_s <= a && a <= b && b <= from,
                        "sample {i}: move {a}..{b}, previous {}, frames {from}",
                        p.t_s
                    )
                }
                None => assert!(!moved, "sample {i} changed pose without a recorded move"),
            }
        } else {
            // The first sample's move comes from the approach, before the recording.
            let (a, b) = s.timing.move_s.expect("the first sample says when the rig last moved");
            assert!(a <= b && b <= from, "first sample: move {a}..{b}, frames {from}");
        }
        prev = Some(s);
    }
    // A millimetre of stage takes a measurable time (the emulated KDC101 runs
    // at 2.3 mm/s): the longest loading move is not instantaneous.
    let longest = rec
        .samples
        .windows(2)
        .filter_map(|w| w[1].timing.move_s.map(|(a, b)| ((w[1].stage_mm - w[0].stage_mm).abs(), b - a)))
        .max_by(|x, y| x.0.total_cmp(&y.0))
        .unwrap();
    println!("longest stage move {:.3} mm in {:.3} s", longest.0, longest.1);
    assert!(longest.0 > 0.5 && longest.1 > longest.0 / 10.0, "{longest:?}");
}

/// Adhesion stays out of the table above (its correction is weakly
/// determined: w, eta, E1 and nu1 trade along a valley), but what the rig
/// reads of a tacky gel must agree with the rig's truth at the errors the
/// run states, or no diagnosis can explain it. At 500 mJ/m², eta 3, the
/// recording is run through the truth (E1, nu1, w, eta; the stage zero
/// scanned) and its chi² per reading printed and bounded. It was 3.4-10.7
/// (seeds 1-8) while the run took the gel as tacky only 3 s into the
/// sweep, and while a first contact seen in some frames only claimed a
/// micrometre's error (docs/sensing.md, "Adhesive contacts"); 0.9-1.6 now.
#[test]
fn a_tacky_gel_reads_as_the_rigs_truth_at_the_stated_errors() {
    use easycalib::diagnosis::model::{Base, Candidate, Model};
    use easycalib::fit::weights::SampleSd;
    let truth = sim::setup::SimSetupInput::default().resolve().expect("the default rig").truth();
    let (w, eta) = (500.0, 3.0);
    for seed in 1..=3 {
        let profile =
            SimProfile { adhesion: Some(sim::effects::adhesion::Params { w_mj_m2: w, eta }), ..Default::default() };
        let (o, rec) = emulated::run_script(seed, profile, easycalib::run::Script::default());
        let sd = SampleSd::of(&rec);
        let model = Model::new(&rec, 1.0, 1.0).with_standard_errors(&sd);
        let chi2_at = |z0: f64| {
            let mut x = Base { e1_mpa: truth.e1_mpa, nu1: truth.nu1, contact_offset_mm: z0 }.internal().to_vec();
            x.extend([w / 100.0, eta]);
            let readings = model.readings(&model.profile(&[Candidate::Adhesion], &x).expect("in range")).expect("runs");
            let mut r = Vec::new();
            model.weighted(&readings, &mut r);
            r.iter().map(|v| v * v).sum::<f64>()
        };
        let (chi2, z0) =
            (-40..=40).map(|k| (chi2_at(k as f64 * 5e-4), k as f64 * 5e-4)).min_by(|a, b| a.0.total_cmp(&b.0)).unwrap();
        let per = chi2 / model.n_obs() as f64;
        println!(
            "adhesion seed {seed}: chi² at the truth {chi2:.1} over {} readings ({per:.2} each, stage zero {:+.1} µm); \
             calibration E1 {:+.2} %, nu1 {:+.2} %; diagnosis {} {:?}",
            model.n_obs(),
            z0 * 1e3,
            o.full.0,
            o.full.1,
            o.verdict,
            o.named
        );
        assert!(per <= 2.5, "seed {seed}: the rig's readings sit {per:.2} x their stated variance off its truth");
    }
}

/// Where `TWIN_BIC` (src/diagnosis/mod.rs) comes from: with a compliant
/// frame, the standard sweeps' diagnosis fits a thin layer about as well as
/// the frame, and which leads changes from run to run of the same seed (the
/// rig's timing moves the samples and the noise they draw). Seeds 1-10, three
/// runs each: the layer's BIC less the frame's, its mean, spread and extremes.
/// The margin claims the true frame never lies that far behind the layer.
#[test]
#[ignore = "a rate study (30 emulated runs): the twins' spread behind TWIN_BIC"]
fn stiffness_twins_spread_probe() {
    use easycalib::diagnosis::{DiagnoseOptions, TWIN_BIC, diagnose};
    let p = frame_compliance::Params { c_mm_per_n: 0.004 };
    let profile = SimProfile { frame_compliance: Some(p), ..Default::default() };
    let mut gaps = Vec::new();
    for round in 1..=3 {
        for seed in 1..=10 {
            let (_, rec) = emulated::run_script(seed, profile.clone(), easycalib::run::Script::default());
            let d = diagnose(&rec, &DiagnoseOptions::default()).expect("a rig-made recording is diagnosed");
            let bic = |name: &str| d.candidates.iter().find(|c| c.effects == [name]).map(|c| c.delta_bic);
            let (Some(layer), Some(frame)) = (bic("finite_thickness"), bic("frame_compliance")) else {
                panic!("seed {seed}: both twins are tried: {:?}", d.candidates)
            };
            println!("round {round} seed {seed:2}: layer - frame {:+6.1}", layer - frame);
            gaps.push(layer - frame);
        }
    }
    let n = gaps.len() as f64;
    let mean = gaps.iter().sum::<f64>() / n;
    let sd = (gaps.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    let (lo, hi) = gaps.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), g| (a.min(*g), b.max(*g)));
    println!("layer - frame over {n} runs: mean {mean:+.1}, sd {sd:.1}, from {lo:+.1} to {hi:+.1}; margin {TWIN_BIC}");
    assert!(lo > -TWIN_BIC, "the frame fell {:.1} behind the layer, beyond the twins' margin", -lo);
}
