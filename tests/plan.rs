//! `plan` (issue 14): on a recording whose diagnosis is ambiguous, the
//! experiment it chooses separates the explanations, and the diagnosis of
//! the recording with that experiment names the truth.

use easycalib::diagnosis::{DiagnoseOptions, diagnose};
use easycalib::plan::{DECISIVE_SEPARATION, plan};
use sim::effects::{SimProfile, finite_thickness, frame_compliance};
use sim::generator::{GeneratorConfig, generate};

fn check(truth: &str, profile: SimProfile, seed: u64) {
    let cfg = GeneratorConfig { seed, profile, ..GeneratorConfig::default() };
    let rec = generate(&cfg).unwrap();
    let p = plan(&rec).unwrap();
    println!("{truth} seed {seed}:\n{}", easycalib::plan::report(&p));
    let listed: Vec<&str> = p.hypotheses.iter().flat_map(|h| h.effects.iter().copied()).collect();
    assert!(listed.contains(&truth), "{truth} seed {seed}: the truth must stand: {listed:?}");
    let c = p.choice().expect("an experiment is proposed");
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
    let p = plan(&rec).unwrap();
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
