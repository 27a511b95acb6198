//! Hardening of the analysis side (issue 11): the reproducers of implausible
//! recordings end in an error naming what is wrong, never in a converged fit; a
//! well-formed recording whose fit is merely poor gets an answer with warnings;
//! JSON never carries an unexplained null; the reader's cost is bounded.

use std::path::PathBuf;

use easycalib::diagnosis::{DiagnoseOptions, diagnose, thin};
use easycalib::fit::{FitError, FitOptions, calibrate};
use easycalib::report::json::{calibration_output, to_json_explained};
use sim::generator::{GeneratorConfig, generate};
use sim::recording::{MAX_METADATA_LINES, MAX_SAMPLES, Phase, Recording};

fn clean() -> Recording {
    generate(&GeneratorConfig { seed: 7, ..Default::default() }).unwrap()
}

fn implausible(rec: &Recording) -> String {
    let e = calibrate(rec, &FitOptions::default()).expect_err("an implausible recording must not be fitted");
    let FitError::Implausible(ref what) = e else { panic!("expected an implausibility error, got {e}") };
    // The diagnosis refuses the same recording for the same reason.
    let d = diagnose(rec, &DiagnoseOptions::default()).expect_err("diagnose must refuse it too");
    assert!(d.to_string().contains(&what.what), "{d}");
    e.to_string()
}

fn map_stage(rec: &Recording, f: impl Fn(f64) -> f64) -> Recording {
    let mut r = rec.clone();
    for s in &mut r.samples {
        s.stage_mm = f(s.stage_mm);
    }
    r
}

#[test]
fn a_zero_negated_or_rescaled_stage_is_refused() {
    let rec = clean();
    assert!(calibrate(&rec, &FitOptions::default()).is_ok(), "the clean recording itself must fit");
    let e = implausible(&map_stage(&rec, |_| 0.0));
    assert!(e.contains("gamma1") && e.contains("stage travels only"), "{e}");
    let e = implausible(&map_stage(&rec, |x| x * 1e-300));
    assert!(e.contains("stage travels only"), "{e}");
    let e = implausible(&map_stage(&rec, |x| -x));
    assert!(e.contains("stage_mm"), "{e}");
    let e = implausible(&map_stage(&rec, |x| x * 1e300));
    assert!(e.contains("buried"), "{e}");
    println!("negated stage: {e}");
}

#[test]
fn an_absurd_twist_is_refused_and_names_the_column() {
    let mut rec = clean();
    for s in rec.samples.iter_mut().filter(|s| s.phase == Phase::Torsion) {
        s.rot_deg *= 1e300;
    }
    let e = implausible(&rec);
    assert!(e.contains("rot_deg") && e.contains("mount angle"), "{e}");
    // theta1 larger than the mount's own angle.
    let mut rec = clean();
    for s in rec.samples.iter_mut().filter(|s| s.phase == Phase::Torsion) {
        s.theta1_deg = 3.0 * s.rot_deg + 0.5;
    }
    let e = implausible(&rec);
    assert!(e.contains("theta1_deg"), "{e}");
}

#[test]
fn absurd_times_are_refused_before_any_model_runs() {
    let mut rec = clean();
    if let Some(s) = rec.samples.last_mut() {
        s.t_s = 1e12;
    }
    let e = implausible(&rec);
    assert!(e.contains("t_s") && e.contains("span"), "{e}");
}

#[test]
fn an_implausible_indenter_is_refused_by_the_reader() {
    let text = clean().to_csv_string();
    for (bad, key) in [
        ("indenter_E_MPa: 1e-308", "indenter_E_MPa"),
        ("indenter_E_MPa: 1e300", "indenter_E_MPa"),
        ("indenter_R_mm: 1e-9", "indenter_R_mm"),
    ] {
        let k = bad.split(':').next().unwrap();
        let line = text.lines().find(|l| l.starts_with(&format!("# {k}:"))).unwrap();
        let e = Recording::parse(&text.replace(line, &format!("# {bad}"))).unwrap_err();
        assert!(e.line > 0 && e.message.contains(key), "{bad}: {e}");
    }
}

#[test]
fn reader_limits_bound_the_work_of_any_file() {
    let text = clean().to_csv_string();
    let (head, body) = text.split_at(text.find("t_s,phase").unwrap());
    // Many distinct metadata keys: accepted up to the limit, refused beyond it with the line.
    let keys = |n: usize| (0..n).map(|i| format!("# note_{i}: x\n")).collect::<String>();
    let meta_now = head.lines().filter(|l| l.contains(':')).count();
    let ok = format!("{head}{}{body}", keys(MAX_METADATA_LINES - meta_now));
    assert!(Recording::parse(&ok).is_ok());
    let too_many = format!("{head}{}{body}", keys(100_000));
    let e = Recording::parse(&too_many).unwrap_err();
    assert!(e.message.contains("metadata lines") && e.line == MAX_METADATA_LINES + 1, "{e}");
    // A line longer than the limit.
    let long = format!("{head}# note: {}\n{body}", "x".repeat(10_000));
    assert!(Recording::parse(&long).unwrap_err().message.contains("bytes long"));
    // More rows than the limit: refused at the first row beyond it.
    let row = body.lines().nth(1).unwrap();
    let mut big = String::with_capacity(text.len() + (MAX_SAMPLES + 2) * (row.len() + 1));
    big.push_str(head);
    big.push_str(body.lines().next().unwrap());
    big.push('\n');
    for _ in 0..=MAX_SAMPLES {
        big.push_str(row);
        big.push('\n');
    }
    let e = Recording::parse(&big).unwrap_err();
    assert!(e.message.contains("more than"), "{e}");
}

#[test]
fn a_long_recording_is_thinned_evenly_for_the_diagnosis() {
    let rec = clean();
    let n = rec.samples.len();
    assert!(thin(&rec, n).is_none());
    let (t, every) = thin(&rec, n / 3).unwrap();
    assert_eq!(every, n.div_ceil(n / 3));
    assert!(t.samples.len() <= n / 3);
    assert_eq!(t.samples[1], rec.samples[every]);
    // Both sweeps survive the thinning.
    assert!(t.phase(Phase::Torsion).count() >= rec.phase(Phase::Torsion).count() / every);
}

fn fem_dev() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev");
    let mut files = Vec::new();
    for set in ["linear", "nonlinear"] {
        for e in std::fs::read_dir(root.join(set)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "csv") && !p.ends_with("truth.csv") {
                files.push(p);
            }
        }
    }
    files.sort();
    files
}

/// Every null in a JSON document is listed, with a reason, under `undefined`.
fn assert_nulls_explained(json: &str) {
    let v: serde_json::Value = serde_json::from_str(json).unwrap();
    let listed: Vec<String> = v
        .get("undefined")
        .and_then(|u| u.as_array())
        .map(|a| a.iter().map(|x| x["path"].as_str().unwrap().to_string()).collect())
        .unwrap_or_default();
    let mut found = Vec::new();
    fn walk(v: &serde_json::Value, p: String, found: &mut Vec<String>) {
        match v {
            serde_json::Value::Null => found.push(p),
            serde_json::Value::Array(a) => a.iter().enumerate().for_each(|(i, x)| walk(x, format!("{p}[{i}]"), found)),
            serde_json::Value::Object(m) => {
                m.iter().for_each(|(k, x)| walk(x, if p.is_empty() { k.clone() } else { format!("{p}.{k}") }, found))
            }
            _ => {}
        }
    }
    walk(&v, String::new(), &mut found);
    for p in &found {
        assert!(listed.contains(p), "null at {p} is not explained");
    }
}

#[test]
fn well_formed_but_poorly_modelled_recordings_get_an_answer_with_warnings() {
    // The dev set's large-strain recordings, declared on a 4 mm gel: the
    // large-strain correction is tabulated for a gel as thick as the
    // indenter's radius (5 mm), so it is taken off its table; the fit answers,
    // says so, and its JSON explains any null.
    let files: Vec<PathBuf> = fem_dev().into_iter().filter(|p| p.to_string_lossy().contains("nonlinear")).collect();
    assert_eq!(files.len(), 2, "{files:?}");
    for p in files {
        let mut rec = Recording::read_path(&p).unwrap();
        if let Some(l) = rec.meta.layer.as_mut() {
            l.thickness_mm = 4.0;
        }
        let cal = calibrate(&rec, &FitOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
        assert!(cal.full.e1_mpa.is_finite() && cal.full.e1_mpa > 0.0 && (0.0..=0.5).contains(&cal.full.nu1));
        assert_eq!(cal.full.model, "layer-fe-large-strain");
        assert!(
            cal.warnings.iter().any(|w| w.code == "large_strain_extrapolated"),
            "{}: {:?}",
            p.display(),
            cal.warnings
        );
        let [lo, hi] = cal.full.ci95.nu1;
        assert!(lo >= 0.0 && hi <= 0.5, "interval cut at the physical range: {lo} {hi}");
        let out = calibration_output(&rec, &cal, Some(&p), None);
        let json = to_json_explained(&out).unwrap();
        assert!(json.contains("\"warnings\""));
        assert_nulls_explained(&json);
    }
    // A layer the model does not take (on a domed gel) is fitted as a half-space, and says so.
    let mut rec = Recording::read_path(&fem_dev()[0]).unwrap();
    rec.meta.elastomer_r_mm = 40.0;
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    assert_eq!(cal.full.model, "half-space");
    assert!(cal.warnings.iter().any(|w| w.code == "layer_not_modelled"), "{:?}", cal.warnings);
    // A sliding base is modelled, with the warning that its large strain is the bonded gel's.
    let mut rec = Recording::read_path(&fem_dev()[0]).unwrap();
    if let Some(l) = rec.meta.layer.as_mut() {
        l.base = sim::physics::LayerBase::Sliding;
    }
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    assert!(cal.full.model.starts_with("layer-fe"), "{}", cal.full.model);
    assert!(cal.warnings.iter().any(|w| w.code == "sliding_base_approximate"), "{:?}", cal.warnings);
}

#[test]
fn non_finite_numbers_are_explained_in_json() {
    #[derive(serde::Serialize)]
    struct Doc {
        ci95: [f64; 2],
        corr_e1_nu1: f64,
        value: f64,
    }
    let json = to_json_explained(&Doc { ci95: [0.1, f64::INFINITY], corr_e1_nu1: f64::NAN, value: 1.0 }).unwrap();
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let u = v["undefined"].as_array().unwrap();
    assert_eq!(u.len(), 2, "{json}");
    assert_eq!(u[0]["path"], "ci95[1]");
    assert!(u[0]["why"].as_str().unwrap().contains("open interval"));
    assert_eq!(u[1]["path"], "corr_e1_nu1");
    assert_nulls_explained(&json);
    // Nothing to explain: no `undefined` key at all.
    let json = to_json_explained(&Doc { ci95: [0.1, 0.2], corr_e1_nu1: 0.5, value: 1.0 }).unwrap();
    assert!(!json.contains("undefined"));
}

#[test]
fn diagnosis_json_explains_its_open_interval_ends() {
    let rec = Recording::read_path(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev/linear/tableI_2_E2-2.0_nu2-0.40.csv"),
    )
    .unwrap();
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    assert_nulls_explained(&to_json_explained(&d).unwrap());
}
