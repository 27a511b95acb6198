//! The diagnosis a run makes at its end (docs/run.md), in process on the
//! generator's recordings: an effect is named with its parameters and the
//! corrected E1/nu1 land on the truth, beside the calibration in report.json
//! and report.md; a clean recording names nothing and keeps the calibration's
//! values; a diagnosis that fails leaves the calibration and its report standing.

use easycalib::diagnosis::DiagnoseOptions;
use easycalib::fit::{Calibration, FitOptions, calibrate};
use easycalib::report::{RunDiagnosis, RunExtras, Truth, VerdictClass, diagnose_run, write_report_for};
use serde_json::Value;
use sim::effects::{SimProfile, stage_backlash};
use sim::generator::{GeneratorConfig, generate};
use sim::physics::{Body, ContactPair};
use sim::recording::Recording;

const E1: f64 = 0.33;
const NU1: f64 = 0.39;

fn recording(profile: SimProfile, seed: u64) -> (Recording, Calibration) {
    let pair = ContactPair { elastomer: Body::new(E1, NU1, 33.0), indenter: Body::new(1.1, 0.39, 5.0) };
    let rec = generate(&GeneratorConfig { pair, profile, seed, ..Default::default() }).unwrap();
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    (rec, cal)
}

/// Write the run's report with `d` and read back report.json and report.md.
fn report(rec: &Recording, cal: &Calibration, d: &RunDiagnosis) -> (Value, String) {
    let dir = tempfile::tempdir().unwrap();
    let extras = RunExtras { timings: None, diagnosis: Some(d.clone()) };
    let truth = Truth { e1_mpa: E1, nu1: NU1 };
    let files = write_report_for(dir.path(), rec, None, cal, Some(truth), extras).unwrap();
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
    (v, std::fs::read_to_string(&files.markdown).unwrap())
}

fn err(v: f64, t: f64) -> f64 {
    (v / t - 1.0).abs()
}

#[test]
fn a_named_effect_corrects_e1_and_nu1_beside_the_calibration() {
    let profile = SimProfile {
        stage_backlash: Some(stage_backlash::Params { b_mm: 0.008, engaged: true }),
        ..Default::default()
    };
    let (rec, cal) = recording(profile, 12);
    let d = diagnose_run(&rec, &cal, &DiagnoseOptions::default());
    println!("{}", d.summary);
    assert_eq!(d.verdict, VerdictClass::Effects, "{}", d.summary);
    let names: Vec<&str> = d.effects.iter().map(|e| e.name).collect();
    assert!(names.contains(&"stage_backlash"), "{names:?}");
    let b = d.effects.iter().find(|e| e.name == "stage_backlash").unwrap();
    let b_mm = b.params.iter().find(|p| p.name == "b_mm").unwrap().value;
    assert!((b_mm - 0.008).abs() < 0.002, "b {b_mm} mm");
    // The correction moves towards the truth, within the diagnosis' own bounds.
    assert!(err(d.e1_mpa, E1) + err(d.nu1, NU1) < err(cal.full.e1_mpa, E1) + err(cal.full.nu1, NU1));
    assert!(err(d.e1_mpa, E1) < 0.01 && err(d.nu1, NU1) < 0.03, "E1 {} nu1 {}", d.e1_mpa, d.nu1);
    assert!(d.summary.starts_with("EFFECTS: ") && d.summary.contains("corrected E1"), "{}", d.summary);

    let (v, md) = report(&rec, &cal, &d);
    let j = &v["diagnosis"];
    assert_eq!(j["verdict"], "effects");
    assert_eq!(j["E1_MPa"].as_f64(), Some(d.e1_mpa));
    assert_eq!(j["nu1"].as_f64(), Some(d.nu1));
    assert_eq!(j["ci95"]["E1_MPa"][0].as_f64(), Some(d.ci95.e1_mpa[0]));
    let effects = j["effects"].as_array().unwrap();
    let jb = effects.iter().find(|e| e["name"] == "stage_backlash").unwrap();
    assert_eq!(jb["params"][0]["name"], "b_mm");
    assert_eq!(jb["params"][0]["value"].as_f64(), Some(b_mm));
    // The report's own answer stays the calibration's.
    assert_eq!(v["E1_MPa"].as_f64(), Some(cal.full.e1_mpa));
    assert_eq!(v["nu1"].as_f64(), Some(cal.full.nu1));
    assert!(md.contains("## Diagnosis") && md.contains("Verdict: **effects**"), "{md}");
    assert!(md.contains("`stage_backlash`: b_mm = "), "{md}");
    assert!(md.contains(&format!("| E1 | {:.4} |", cal.full.e1_mpa)), "{md}");
    let truth_row = format!("| diagnosis (corrected) error | {:+.2} % |", (d.e1_mpa / E1 - 1.0) * 100.0);
    assert!(md.contains(&truth_row), "{md}");
}

#[test]
fn a_clean_recording_names_nothing_and_keeps_the_calibration() {
    let (rec, cal) = recording(SimProfile::default(), 21);
    let d = diagnose_run(&rec, &cal, &DiagnoseOptions::default());
    println!("{}", d.summary);
    assert_eq!(d.verdict, VerdictClass::Clean, "{}", d.summary);
    assert!(d.effects.is_empty() && d.error.is_none());
    assert_eq!((d.e1_mpa, d.nu1), (cal.full.e1_mpa, cal.full.nu1));
    assert_eq!(d.ci95.nu1, cal.full.ci95.nu1);
    let (v, md) = report(&rec, &cal, &d);
    assert_eq!(v["diagnosis"]["verdict"], "clean");
    assert_eq!(v["diagnosis"]["effects"].as_array().map(Vec::len), Some(0));
    assert_eq!(v["diagnosis"]["E1_MPa"], v["E1_MPa"]);
    assert!(v["diagnosis"].get("error").is_none());
    assert!(md.contains("diagnosis (nothing named: the full model's) error"), "{md}");
}

#[test]
fn a_failed_diagnosis_is_reported_and_the_calibration_stands() {
    let (rec, cal) = recording(SimProfile::default(), 22);
    // A noise floor that is not positive is refused by the diagnosis.
    let opts = DiagnoseOptions { noise_um: Some(-1.0), ..Default::default() };
    let d = diagnose_run(&rec, &cal, &opts);
    assert_eq!(d.verdict, VerdictClass::NotMade);
    let why = d.error.as_deref().unwrap();
    assert!(why.contains("--noise-um must be > 0"), "{why}");
    assert!(d.summary.contains("could not be made") && d.summary.contains(why), "{}", d.summary);
    assert_eq!((d.e1_mpa, d.nu1), (cal.full.e1_mpa, cal.full.nu1));
    let (v, md) = report(&rec, &cal, &d);
    assert_eq!(v["diagnosis"]["verdict"], "not_made");
    assert_eq!(v["diagnosis"]["error"].as_str(), Some(why));
    assert_eq!(v["E1_MPa"].as_f64(), Some(cal.full.e1_mpa));
    assert!(md.contains("Verdict: **not_made**") && md.contains(why), "{md}");
}
