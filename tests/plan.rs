//! `plan` (issue 14): on a recording whose diagnosis is ambiguous, the
//! experiment it chooses separates the explanations, and the diagnosis of
//! the recording with that experiment names the truth.

#[path = "support/creep_drift.rs"]
mod creep_drift;

use easycalib::diagnosis::{DiagnoseOptions, diagnose};
use easycalib::plan::{DECISIVE_SEPARATION, PlanOptions, decide_with_ball, plan};
use sim::effects::{SimProfile, finite_thickness, frame_compliance, sensor_gain};
use sim::generator::{GeneratorConfig, generate, operator_recording};

fn check(truth: &str, profile: SimProfile, seed: u64) {
    let cfg = GeneratorConfig { seed, profile, ..GeneratorConfig::default() };
    let rec = generate(&cfg).unwrap();
    let p = plan(&rec, PlanOptions::default()).unwrap();
    println!("{truth} seed {seed}:\n{}", easycalib::plan::report(&p));
    let listed: Vec<&str> = p.hypotheses.iter().flat_map(|h| h.effects.iter().copied()).collect();
    assert!(listed.contains(&truth), "{truth} seed {seed}: the truth must stand: {listed:?}");
    let c = p.choice().expect("an experiment is proposed");
    assert!(!c.operator, "a rig-only experiment decides, no swap: {c:?}");
    assert!(c.decisive && c.separation >= DECISIVE_SEPARATION, "{c:?}");
    // Run it: the diagnosis of the recording with it names the truth.
    let with = GeneratorConfig { experiments: vec![c.spec], ..cfg };
    let d = diagnose(&generate(&with).unwrap(), &DiagnoseOptions::default()).unwrap();
    assert_eq!(d.effects, [truth], "{truth} seed {seed} after {}: {}", c.name, d.verdict);
}

#[test]
fn plan_chooses_an_experiment_that_separates_frame_compliance_from_a_layer() {
    let frame =
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..SimProfile::default() };
    let layer =
        SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 100.0 }), ..SimProfile::default() };
    check("frame_compliance", frame, 1);
    check("finite_thickness", layer, 1);
}

#[test]
fn plan_proposes_nothing_for_a_clean_recording() {
    let rec = generate(&GeneratorConfig::default()).unwrap();
    let p = plan(&rec, PlanOptions::default()).unwrap();
    assert!(p.choice().is_none() && p.nothing_because.is_some(), "{}", easycalib::plan::report(&p));
}

/// `easycalib plan REC.csv --json` on a recording taken before (here
/// written by the generator): the JSON names the hypotheses and puts a
/// decisive experiment first; a recording with a phase this reader does not
/// know is refused with exit code 2, naming the phase and the line.
#[test]
fn plan_command_prints_the_choice_as_json_and_refuses_unknown_phases() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.csv");
    let profile =
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..SimProfile::default() };
    generate(&GeneratorConfig { seed: 1, profile, ..GeneratorConfig::default() }).unwrap().write_path(&path).unwrap();
    let run = |p: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_easycalib"))
            .args(["plan", p.to_str().unwrap(), "--json"])
            .env("EASYCALIB_HOME", dir.path())
            .output()
            .unwrap()
    };
    let out = run(&path);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let first = &v["experiments"][0];
    assert_eq!(first["name"], "torsion_at_depth", "{v:#}");
    assert_eq!(first["decisive"], true);
    assert!(first["rig_time_s"].as_f64().unwrap() > 0.0);
    assert!(v["hypotheses"].as_array().unwrap().iter().any(|h| h["effects"][0] == "frame_compliance"));

    let text = std::fs::read_to_string(&path).unwrap();
    let n = text.lines().position(|l| l.contains(",torsion,")).unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, text.replacen(",torsion,", ",torsion3,", 1)).unwrap();
    let out = run(&bad);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("unknown phase `torsion3`") && err.contains(&format!("line {}", n + 1)), "{err}");
}

/// One sensor-gain recording through the operator path: what the plan
/// proposes with and without an operator, the rigid ball's run (generator:
/// the simulated operator mounts the ball), and the decision it gives.
/// Returns (named, E1 error %, nu1 error %, g measured).
fn gain_case(g: f64, seed: u64) -> (bool, f64, f64, f64) {
    let profile = SimProfile { sensor_gain: Some(sensor_gain::Params { g }), ..SimProfile::default() };
    let cfg = GeneratorConfig { seed, profile, ..GeneratorConfig::default() };
    let rec = generate(&cfg).unwrap();
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    let p = easycalib::plan::plan_for(&rec, &d, PlanOptions::default()).unwrap();
    println!("gain {g} seed {seed}: {}\n{}", d.verdict, easycalib::plan::report(&p));
    let c = p.choice().expect("an experiment is proposed");
    assert!(c.operator && c.decisive && c.name == "rigid_ball", "seed {seed}: {c:?}");
    // Without an operator the swap is not proposed, and the plan says what it leaves.
    let bare = easycalib::plan::plan_for(&rec, &d, PlanOptions { operator: false, experiment_sd: None }).unwrap();
    assert!(bare.experiments.iter().all(|e| !e.operator), "seed {seed}");
    assert!(bare.operator_steps.iter().any(|o| o.contains("rigid_ball")), "seed {seed}: {:?}", bare.operator_steps);
    let t = rec.samples.last().unwrap().t_s + 1.0;
    let ball = operator_recording(&cfg, &c.spec, t).unwrap();
    assert_eq!(ball.meta.indenter, c.spec.operator_indenter().unwrap());
    let dec = decide_with_ball(&rec, &d, &p, &ball).unwrap();
    println!("  -> {} {:?}", dec.outcome, dec.chi2);
    let truth = cfg.pair.elastomer;
    let e1 = 100.0 * (dec.e1_mpa / truth.e_mpa - 1.0);
    let nu1 = 100.0 * (dec.nu1 / truth.nu - 1.0);
    (dec.named && dec.effects.first() == Some(&"sensor_gain"), e1, nu1, dec.gain.g)
}

/// issue 14: a sensor gain the sweeps cannot tell from a compliant frame is
/// named once the rigid ball ran, with E1 within 1 % and nu1 within 2 %.
#[test]
fn a_rigid_ball_measures_the_sensor_gain_and_the_calibration_follows() {
    let (named, e1, nu1, g) = gain_case(0.99, 1);
    assert!(named, "not named: g {g}");
    assert!((g - 0.99).abs() < 0.002, "g {g}");
    assert!(e1.abs() < 1.0 && nu1.abs() < 2.0, "E1 {e1:.2} %, nu1 {nu1:.2} %");
}

/// issue 14: a rigid ball that rules the sensor gain out still weighs the
/// rest. On a compliant frame (which the sweeps cannot tell from a sensor
/// gain or a layer) the ball's readings under each hypothesis, and under no
/// effect at all, name the frame, with the corrected E1 within 1 % and nu1
/// within 2 %; the intervals cover the truth. Printed: each hypothesis's
/// chi² on the ball.
#[test]
fn a_rigid_ball_that_rules_the_gain_out_names_a_compliant_frame() {
    let profile =
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..SimProfile::default() };
    let mut named = 0;
    for seed in 1..=3 {
        let cfg = GeneratorConfig { seed, profile: profile.clone(), ..GeneratorConfig::default() };
        let rec = generate(&cfg).unwrap();
        let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        let p = easycalib::plan::plan_for(&rec, &d, PlanOptions::default()).unwrap();
        let standing: Vec<&str> = p.hypotheses.iter().flat_map(|h| h.effects.iter().copied()).collect();
        assert!(standing.contains(&"frame_compliance") && standing.contains(&"sensor_gain"), "{standing:?}");
        let ball = p.experiments.iter().find(|c| c.name == "rigid_ball").expect("the ball is a candidate");
        let t = rec.samples.last().unwrap().t_s + 1.0;
        let dec = decide_with_ball(&rec, &d, &p, &operator_recording(&cfg, &ball.spec, t).unwrap()).unwrap();
        println!("seed {seed}: {}", dec.outcome);
        assert!(!dec.named, "the gain is ruled out: {}", dec.outcome);
        let truth = cfg.pair.elastomer;
        if dec.effects == ["frame_compliance"] {
            named += 1;
            let (e1, nu1) = (100.0 * (dec.e1_mpa / truth.e_mpa - 1.0), 100.0 * (dec.nu1 / truth.nu - 1.0));
            assert!(e1.abs() < 1.0 && nu1.abs() < 2.0, "seed {seed}: E1 {e1:+.2} %, nu1 {nu1:+.2} %");
            let [lo, hi] = dec.ci95.nu1;
            assert!(lo <= truth.nu && truth.nu <= hi, "seed {seed}: nu1 {:?} misses {}", dec.ci95.nu1, truth.nu);
        } else {
            assert!(dec.effects.is_empty(), "seed {seed}: a wrong effect named: {:?}", dec.effects);
        }
    }
    assert!(named >= 2, "the frame named in {named}/3");
}

/// The closed loop as `run --adaptive` runs it, on the generator with a
/// simulated operator: plan, run the choice (a rig step into the recording,
/// an operator step as its own recording), diagnose again, at most three
/// steps. Returns (effects named, E1, nu1, the steps run).
fn loop_on_generator(cfg: &GeneratorConfig) -> (Vec<&'static str>, f64, f64, Vec<&'static str>) {
    let mut cfg = cfg.clone();
    let mut ran = Vec::new();
    loop {
        let rec = generate(&cfg).unwrap();
        let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        if ran.len() >= 3 || d.ambiguous.len() < 2 {
            return (d.effects.clone(), d.e1_mpa, d.nu1, ran);
        }
        let p = easycalib::plan::plan_for(&rec, &d, PlanOptions::default()).unwrap();
        let Some(c) = p.choice().filter(|c| c.separates > 0).cloned() else {
            return (d.effects.clone(), d.e1_mpa, d.nu1, ran);
        };
        ran.push(c.name);
        if c.operator {
            let t = rec.samples.last().unwrap().t_s + 1.0;
            let ball = operator_recording(&cfg, &c.spec, t).unwrap();
            let dec = decide_with_ball(&rec, &d, &p, &ball).unwrap();
            println!("  {} -> {}", c.name, dec.outcome);
            return (dec.effects, dec.e1_mpa, dec.nu1, ran);
        }
        cfg.experiments.push(c.spec);
    }
}

/// The rate over seeds (ignored: about a minute in release): a sensor gain
/// of 0.99 through the whole loop (a torsion at a second depth first when
/// the two best explanations are frame and layer, then the rigid ball).
/// `cargo test --release --test plan -- --ignored --nocapture`.
#[test]
#[ignore = "a rate study over ten seeds"]
fn rigid_ball_rates_over_seeds() {
    let mut ok = 0;
    for seed in 1..=10 {
        let profile = SimProfile { sensor_gain: Some(sensor_gain::Params { g: 0.99 }), ..SimProfile::default() };
        let cfg = GeneratorConfig { seed, profile, ..GeneratorConfig::default() };
        let (named, e1, nu1, ran) = loop_on_generator(&cfg);
        let truth = cfg.pair.elastomer;
        let (e1, nu1) = (100.0 * (e1 / truth.e_mpa - 1.0), 100.0 * (nu1 / truth.nu - 1.0));
        let good = named == ["sensor_gain"] && e1.abs() < 1.0 && nu1.abs() < 2.0;
        ok += usize::from(good);
        println!("RATE gain seed {seed}: {good} {named:?} E1 {e1:+.3} % nu1 {nu1:+.3} % after {ran:?}");
    }
    println!("RATE sensor_gain 0.99: named within 1 %/2 % in {ok}/10");
    assert!(ok >= 9, "{ok}/10");
}

/// `easycalib plan --json` on a sensor-gain recording puts the rigid ball
/// first, marked as an operator step weighed with the operator's effort;
/// `--no-operator` proposes no swap and says what is left to one.
#[test]
fn plan_command_weighs_operator_steps_and_leaves_them_out_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("gain.csv");
    let profile = SimProfile { sensor_gain: Some(sensor_gain::Params { g: 0.99 }), ..SimProfile::default() };
    generate(&GeneratorConfig { seed: 1, profile, ..GeneratorConfig::default() }).unwrap().write_path(&path).unwrap();
    let run = |extra: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_easycalib"))
            .args(["plan", path.to_str().unwrap(), "--json"])
            .args(extra)
            .env("EASYCALIB_HOME", dir.path())
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };
    let v = run(&[]);
    let first = &v["experiments"][0];
    assert_eq!((first["name"].as_str(), first["operator"].as_bool()), (Some("rigid_ball"), Some(true)), "{v:#}");
    let (rig, cost) = (first["rig_time_s"].as_f64().unwrap(), first["cost_s"].as_f64().unwrap());
    assert!((cost - rig - easycalib::plan::OPERATOR_EFFORT_S).abs() < 1e-9, "{v:#}");
    let bare = run(&["--no-operator"]);
    let exps = bare["experiments"].as_array().unwrap();
    assert!(exps.iter().all(|e| e["operator"] == false), "{bare:#}");
    let left = bare["operator_steps"].as_array().unwrap();
    assert!(left.iter().any(|o| o.as_str().is_some_and(|o| o.contains("rigid_ball"))), "{bare:#}");
}

/// A probe (issue 14, creep against drift): over weak creep and drift on the
/// generator, where the standard sweeps may leave the two standing together,
/// what the plan scores for each candidate, the slow repeat and the approach
/// at another speed among them. Prints one line per recording whose
/// diagnosis lists both; run by hand:
/// `cargo test --release --test plan -- --ignored --nocapture creep_against_drift`.
#[test]
#[ignore = "a probe over 45 generated recordings"]
fn creep_against_drift_probe() {
    use sim::effects::{thermal_drift, viscoelastic};
    let mut cases: Vec<(String, SimProfile)> = Vec::new();
    for (rho, tau) in [(1.003, 5.0), (1.005, 20.0), (1.01, 60.0), (1.01, 200.0), (1.02, 100.0)] {
        let p = SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho, tau_s: tau, memory_n: 0.0 }),
            ..SimProfile::default()
        };
        cases.push((format!("creep rho {rho} tau {tau}"), p));
    }
    for v in [5e-6, 1e-5, 2e-5, 5e-5] {
        let p = SimProfile {
            thermal_drift: Some(thermal_drift::Params { v_mm_per_s: v, vdot_mm_per_s2: 0.0 }),
            ..SimProfile::default()
        };
        cases.push((format!("drift {} nm/s", v * 1e6), p));
    }
    let (mut both, mut chosen) = (0, 0);
    for (label, profile) in &cases {
        for seed in 1..=5 {
            let cfg = GeneratorConfig { seed, profile: profile.clone(), ..GeneratorConfig::default() };
            let rec = generate(&cfg).unwrap();
            let p = plan(&rec, PlanOptions::default()).unwrap();
            let listed: Vec<&str> = p.hypotheses.iter().flat_map(|h| h.effects.iter().copied()).collect();
            if !(listed.contains(&"viscoelastic") && listed.contains(&"thermal_drift")) {
                println!("{label} seed {seed}: {}", p.verdict);
                continue;
            }
            both += 1;
            let scores: Vec<String> = p
                .experiments
                .iter()
                .map(|e| format!("{} {:.1} ({:.0} s)", e.name, e.separation, e.rig_time_s))
                .collect();
            let pick = p.experiments.iter().find(|c| c.separates > 0).map(|c| c.name);
            chosen += usize::from(matches!(pick, Some("slow_repeat" | "approach_speed")));
            println!("{label} seed {seed}: {} | pick {pick:?} | {}", p.verdict, scores.join(", "));
        }
    }
    println!("PROBE creep/drift both standing in {both} recordings; slow_repeat or approach_speed chosen in {chosen}");
}

/// The plan's predictions for the slow repeat and the approach at another
/// speed under creep and under drift (issue 14). At the emulated rig's sizes
/// (creep rho 1.06, tau 8 s; drift 2.5 um/s) the standard sweeps already
/// name either; here the diagnosis is made to leave both standing, as it
/// would for a pair it cannot rank, and the plan refits both and scores
/// every candidate: both new steps must separate the two decisively (their
/// predicted samples differ by more than the noise under the two refitted
/// hypotheses), and the diagnosis of the recording with the one the plan
/// ranks first among them names the truth.
#[test]
fn with_creep_and_drift_both_standing_the_slow_steps_separate_them() {
    use easycalib::diagnosis::Alternative;
    use easycalib::plan::plan_for;
    for (truth, profile) in creep_drift::creep_and_drift() {
        let cfg = GeneratorConfig { seed: 1, profile, ..GeneratorConfig::default() };
        let rec = generate(&cfg).unwrap();
        let mut d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
        assert_eq!(d.effects, [truth], "{}", d.verdict);
        let standing = |name: &'static str| Alternative {
            effects: vec![name],
            delta_bic: 0.0,
            e1_mpa: d.e1_mpa,
            nu1: d.nu1,
            ci95: d.baseline.ci95,
        };
        d.ambiguous = vec![standing("viscoelastic"), standing("thermal_drift")];
        let p = plan_for(&rec, &d, PlanOptions { operator: false, experiment_sd: None }).unwrap();
        println!("{truth}:\n{}", easycalib::plan::report(&p));
        assert_eq!(p.hypotheses[0].effects, [truth], "the truth refits best");
        let new: Vec<_> = p.experiments.iter().filter(|e| matches!(e.name, "slow_repeat" | "approach_speed")).collect();
        assert_eq!(new.len(), 2);
        for e in &new {
            assert!(e.decisive && e.separates == 1, "{truth}: {} separates by {:.1}", e.name, e.separation);
        }
        let with = GeneratorConfig { experiments: vec![new[0].spec], ..cfg };
        let after = diagnose(&generate(&with).unwrap(), &DiagnoseOptions::default()).unwrap();
        assert_eq!(after.effects, [truth], "{truth} after {}: {}", new[0].name, after.verdict);
    }
}
