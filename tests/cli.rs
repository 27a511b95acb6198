//! The `easycalib` binary as a user meets it: simulate a recording, fit it,
//! read the stable JSON, and get a clear error and exit code 2 on bad input.

use std::path::Path;
use std::process::{Command, Output};

fn easycalib(args: &[&str]) -> Output {
    // The history goes to a folder of the test's, never the user's.
    Command::new(env!("CARGO_BIN_EXE_easycalib"))
        .args(args)
        .env("EASYCALIB_HOME", std::env::temp_dir().join("easycalib-test-home"))
        .env_remove("EASYCALIB_DB")
        .output()
        .expect("easycalib binary runs")
}

fn simulate(dir: &Path, extra: &[&str]) -> std::path::PathBuf {
    let path = dir.join("rec.csv");
    let mut args = vec!["simulate", "-o", path.to_str().unwrap()];
    args.extend_from_slice(extra);
    let out = easycalib(&args);
    assert!(out.status.success(), "simulate failed: {}", String::from_utf8_lossy(&out.stderr));
    path
}

fn fit_json(path: &Path) -> serde_json::Value {
    let out = easycalib(&["fit", path.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "fit failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("fit --json prints one JSON document")
}

#[test]
fn simulate_then_fit_recovers_the_elastomer_through_the_documented_json() {
    let dir = tempfile::tempdir().unwrap();
    let rec = simulate(dir.path(), &["--e1-mpa", "0.25", "--nu1", "0.45", "--seed", "11"]);
    let v = fit_json(&rec);

    let e1 = v["E1_MPa"].as_f64().unwrap();
    let nu1 = v["nu1"].as_f64().unwrap();
    assert!((e1 / 0.25 - 1.0).abs() < 0.01, "E1 {e1}");
    assert!((nu1 / 0.45 - 1.0).abs() < 0.02, "nu1 {nu1}");
    for key in ["E1_MPa", "nu1"] {
        let ci = v["ci95"][key].as_array().unwrap();
        let (lo, hi) = (ci[0].as_f64().unwrap(), ci[1].as_f64().unwrap());
        let best = v[key].as_f64().unwrap();
        assert!(lo < best && best < hi, "{key} interval [{lo}, {hi}] misses {best}");
    }
    for key in ["H1", "H3", "E1_MPa", "nu1", "E1_MPa_rounded", "nu1_rounded"] {
        assert!(v["paper"][key].as_f64().unwrap().is_finite(), "paper.{key}");
    }
    // The best estimate is the full-model fit.
    assert_eq!(v["full"]["E1_MPa"], v["E1_MPa"]);
    assert!(v["full"]["rms"]["normal_um"].as_f64().unwrap() > 0.0);
    assert!(v["full"]["rms"]["torsion_deg"].as_f64().unwrap() > 0.0);
    // Recordings written by `simulate` carry the truth; `fit` does not invent one.
    assert!(v.get("sim_truth").is_none_or(|t| t.is_null()));
}

#[test]
fn run_on_the_simulated_rig_reports_truth_alongside_the_fit() {
    let dir = tempfile::tempdir().unwrap();
    let out = easycalib(&["run", "--json", "--seed", "5", "--out", dir.path().to_str().unwrap()]);
    assert!(out.status.success(), "run failed: {}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let truth_e1 = v["sim_truth"]["E1_MPa"].as_f64().unwrap();
    let e1 = v["E1_MPa"].as_f64().unwrap();
    assert!((e1 / truth_e1 - 1.0).abs() < 0.01, "E1 {e1} vs truth {truth_e1}");
    // The run left its recording and report in --out.
    for f in ["recording.csv", "report.json", "report.md", "normal_sweep.svg", "torsion_sweep.svg"] {
        assert!(dir.path().join(f).is_file(), "{f} missing");
    }
    // It ended with the diagnosis of its recording; the top-level answer stays the calibration's.
    let d = check_diagnosis(&v);
    eprintln!("diagnosis of the clean emulated run: {}", d["summary"].as_str().unwrap());
    assert_eq!(v["E1_MPa"], v["full"]["E1_MPa"]);
    assert_eq!(v["nu1"], v["full"]["nu1"]);
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(md.contains("## Diagnosis") && md.contains("| diagnosis ("), "{md}");
}

/// A stiff indenter (E2 = 2 MPa) on the default gel: its target depth lies
/// just inside the depth limit (gamma1 about 4.97 of 5 mm) where the
/// worst-case bound of a full step passes it. Through the real drivers the
/// run shortens its last steps to the limit (the warning on stderr), reaches
/// beta 0.2 without pressing the gel past 5 mm and recovers it; it used to
/// stop at beta 0.16.
#[test]
fn a_stiff_indenter_reaches_the_target_depth_just_inside_the_limit() {
    let dir = tempfile::tempdir().unwrap();
    let (out_dir, db) = (dir.path().join("run"), dir.path().join("history.sqlite"));
    let out = easycalib(&[
        "run",
        "--json",
        "--db",
        db.to_str().unwrap(),
        "--no-diagnose",
        "--seed",
        "3",
        "--indenter-e-mpa",
        "2",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "run failed: {stderr}");
    assert!(stderr.contains("more than max gamma1 5.0000 mm: shortened to"), "{stderr}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let beta = v["full"]["beta"].as_f64().unwrap();
    assert!((beta - 0.2).abs() < 0.002, "torsion at beta {beta}");
    let rec = sim::recording::Recording::read_path(&out_dir.join("recording.csv")).unwrap();
    let deepest = rec.samples.iter().map(|s| s.gamma1_mm).fold(0.0, f64::max);
    assert!(deepest > 4.5 && deepest <= 5.0, "deepest gamma1 {deepest} mm");
    let (e1, truth) = (v["E1_MPa"].as_f64().unwrap(), v["sim_truth"]["E1_MPa"].as_f64().unwrap());
    assert!((e1 / truth - 1.0).abs() < 0.01, "E1 {e1} vs truth {truth}");
    // The report keeps what the run warned of: the shortened step is in
    // report.json's run.warnings and in report.md, not only on stderr.
    let warned: Vec<&str> =
        v["run"]["warnings"].as_array().map_or(vec![], |w| w.iter().filter_map(|x| x.as_str()).collect());
    assert!(warned.iter().any(|w| w.contains("shortened to")), "run.warnings {warned:?}");
    let md = std::fs::read_to_string(out_dir.join("report.md")).unwrap();
    assert!(md.contains("| run warning |") && md.contains("shortened to"), "{md}");
    // So does the history: the run's own record, and an import of its folder.
    let imported = dir.path().join("imported.sqlite");
    let o = easycalib(&["history", "import", out_dir.to_str().unwrap(), "--db", imported.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for db in [&db, &imported] {
        let o = easycalib(&["history", "--json", "--db", db.to_str().unwrap()]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let cal = &doc["sensors"][0]["calibrations"][0];
        let kept = cal["warnings"].as_array().map_or(vec![], |w| {
            w.iter().filter(|w| w["code"] == "run_warning").filter_map(|w| w["message"].as_str()).collect()
        });
        assert!(kept.iter().any(|m| m.contains("shortened to")), "{}: {cal:#}", db.display());
    }
}

/// report.json's `diagnosis`: a verdict, effects with parameters, E1/nu1 with
/// intervals around them; the calibration's values when nothing is named.
fn check_diagnosis(v: &serde_json::Value) -> &serde_json::Value {
    let d = &v["diagnosis"];
    let verdict = d["verdict"].as_str().unwrap_or_else(|| panic!("no diagnosis verdict in {v:#}"));
    assert!(["clean", "effects", "ambiguous", "unexplained"].contains(&verdict), "{d:#}");
    let effects = d["effects"].as_array().unwrap();
    assert_eq!(effects.is_empty(), verdict != "effects", "{d:#}");
    for e in effects {
        assert!(e["name"].is_string() && e["params"].as_array().is_some_and(|p| !p.is_empty()), "{e:#}");
    }
    for (k, ci) in [("E1_MPa", "E1_MPa"), ("nu1", "nu1")] {
        let x = d[k].as_f64().unwrap();
        let [lo, hi] = [0, 1].map(|i| d["ci95"][ci][i].as_f64().unwrap());
        assert!(lo <= x && x <= hi, "{k} {x} outside [{lo}, {hi}]");
    }
    if verdict != "effects" {
        assert_eq!((&d["E1_MPa"], &d["nu1"]), (&v["full"]["E1_MPa"], &v["full"]["nu1"]));
    }
    d
}

#[test]
fn run_with_no_diagnose_skips_the_diagnosis() {
    let dir = tempfile::tempdir().unwrap();
    let out = easycalib(&["run", "--json", "--seed", "6", "--no-diagnose", "--out", dir.path().to_str().unwrap()]);
    assert!(out.status.success(), "run failed: {}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v.get("diagnosis").is_none(), "{v:#}");
    assert!(v["E1_MPa"].as_f64().is_some());
    // Not run at all: the progress never announces it, the report has no section.
    let progress = String::from_utf8_lossy(&out.stderr);
    assert!(!progress.contains("diagnos"), "{progress}");
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(!md.contains("## Diagnosis"));
}

/// A rig whose stage has 20 µm of backlash: the run's report carries the
/// diagnosis and the CLI's last lines print its verdict. On rig-made
/// recordings the diagnosis does not name effects yet (issue 12): this
/// asserts the structure and prints what it said; a named effect must be the
/// backlash.
#[test]
fn run_with_a_backlash_profile_prints_and_reports_the_diagnosis() {
    let dir = tempfile::tempdir().unwrap();
    let profile = dir.path().join("backlash.toml");
    std::fs::write(&profile, "[stage_backlash]\nb_mm = 0.02\nengaged = true\n").unwrap();
    let run_dir = dir.path().join("run");
    let args = ["run", "--seed", "7", "--no-history", "--profile", profile.to_str().unwrap()];
    let out = easycalib(&[&args[..], &["--out", run_dir.to_str().unwrap()]].concat());
    assert!(out.status.success(), "run failed: {}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("report.json")).unwrap()).unwrap();
    let d = check_diagnosis(&v);
    let summary = d["summary"].as_str().unwrap();
    eprintln!("backlash 0.02 mm on the emulated rig: verdict {}\n{summary}", d["verdict"]);
    assert!(text.contains("\nDiagnosis (") && text.contains(summary), "{text}");
    let headline = d["verdict"].as_str().unwrap().to_uppercase();
    assert!(summary.starts_with(&format!("{headline}:")), "{summary}");
    if d["verdict"] == "effects" {
        assert!(d["effects"].as_array().unwrap().iter().any(|e| e["name"] == "stage_backlash"), "{d:#}");
    }
}

fn expect_bad_input(path: &Path, what: &str) {
    let out = easycalib(&["fit", path.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "{what}: exit code");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(what), "stderr should name `{what}`: {err}");
}

#[test]
fn malformed_recordings_exit_2_naming_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read_to_string(simulate(dir.path(), &[])).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let header = lines.iter().position(|l| l.starts_with("t_s,")).unwrap();

    // A NaN reading in the first data row.
    let mut nan = lines.clone();
    let row = nan[header + 1].replace("0.00000,0.00000,0,load", "nan,0.00000,0,load");
    nan[header + 1] = &row;
    let p = dir.path().join("nan.csv");
    std::fs::write(&p, nan.join("\n")).unwrap();
    expect_bad_input(&p, &format!("line {}", header + 2));

    // An unknown phase.
    let mut phase = lines.clone();
    let row = phase[header + 1].replace("normal", "sideways");
    phase[header + 1] = &row;
    let p = dir.path().join("phase.csv");
    std::fs::write(&p, phase.join("\n")).unwrap();
    expect_bad_input(&p, "sideways");

    // Missing the indenter's modulus.
    let missing: Vec<&str> = lines.iter().copied().filter(|l| !l.starts_with("# indenter_E_MPa")).collect();
    let p = dir.path().join("missing.csv");
    std::fs::write(&p, missing.join("\n")).unwrap();
    expect_bad_input(&p, "indenter_E_MPa");

    // Not a recording at all, and a file that does not exist.
    let p = dir.path().join("junk.csv");
    std::fs::write(&p, "hello\n").unwrap();
    expect_bad_input(&p, "line 1");
    expect_bad_input(&dir.path().join("absent.csv"), "absent.csv");
}

#[test]
fn impossible_parameters_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = easycalib(&["simulate", "--nu1", "0.7", "-o", dir.path().join("x.csv").to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("0.7"));
    assert!(!dir.path().join("x.csv").exists(), "nothing is written for impossible parameters");
}

/// A declared layer on the command line: bad values are refused naming the
/// flag, and the physics that cannot take a layer says so instead of ignoring it.
#[test]
fn layer_flags_are_checked_and_name_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let rec = simulate(dir.path(), &[]);
    let out_path = dir.path().join("x.csv");
    let out_file = out_path.to_str().unwrap();
    let sliding_fe = format!("simulate -o {out_file} --fidelity fe --thickness-mm 5 --r1-mm inf --base sliding");
    for (args, needle) in [
        (vec!["fit", rec.to_str().unwrap(), "--thickness-mm=-2"], "--thickness-mm"),
        (vec!["fit", rec.to_str().unwrap(), "--thickness-mm", "5", "--base", "glued"], "--base glued"),
        (vec!["diagnose", rec.to_str().unwrap(), "--thickness-mm", "0"], "--thickness-mm"),
        (vec!["simulate", "-o", out_file, "--thickness-mm", "5"], "--r1-mm inf"),
        (vec!["simulate", "-o", out_file, "--thickness-mm", "5", "--r1-mm", "inf", "--base", "glued"], "--base glued"),
        (sliding_fe.split(' ').collect(), "bonded"),
        (vec!["simulate", "-o", out_file, "--fidelity", "fe", "--profile", "p.toml"], "--profile"),
        (vec!["simulate", "-o", out_file, "--fidelity", "fe"], "--thickness-mm"),
        (vec!["simulate", "-o", out_file, "--fidelity", "fe", "--thickness-mm", "5", "--r1-mm", "30"], "flat gel"),
    ] {
        let out = easycalib(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    assert!(!out_path.exists(), "nothing is written for a refused simulation");
}

/// `simulate --thickness-mm` (analytic fidelity): the generator's sweeps on a
/// 5 mm gel bonded to its window, from the linear FE layer model pressed and
/// twisted with friction, the layer declared in the recording; `fit` picks the
/// linear layer model and recovers the truth (the fit's own model family: this
/// checks the generator's wiring and the truth it writes, not the physics;
/// tests/layer_fit.rs does that on independent finite-element recordings).
#[test]
fn a_layered_recording_is_simulated_and_fitted_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = simulate(dir.path(), &["--thickness-mm", "5", "--r1-mm", "inf", "--seed", "2"]);
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("# elastomer_thickness_mm: 5") && text.contains("# elastomer_base: bonded"), "{text:.400}");
    let v = fit_json(&path);
    let (e1, nu1) = (v["E1_MPa"].as_f64().unwrap(), v["nu1"].as_f64().unwrap());
    let (te, tn) = (sim::defaults::ELASTOMER_E_MPA, sim::defaults::ELASTOMER_NU);
    println!(
        "E1 {:+.2} %, nu1 {:+.2} %, model {}",
        (e1 / te - 1.0) * 100.0,
        (nu1 / tn - 1.0) * 100.0,
        v["full"]["model"]
    );
    assert_eq!(v["full"]["model"], "layer-fe");
    assert!((e1 / te - 1.0).abs() < 0.01 && (nu1 / tn - 1.0).abs() < 0.02, "E1 {e1}, nu1 {nu1}");
    for (name, truth) in [("E1_MPa", te), ("nu1", tn)] {
        let ci = &v["ci95"][name];
        assert!(ci[0].as_f64().unwrap() <= truth && truth <= ci[1].as_f64().unwrap(), "{name} interval {ci}");
    }
}

/// `simulate --fidelity fe` writes what the large-strain reference predicts for
/// a gel off the correction table's grid (E2/E1 = 1.5, nu1 0.45, nu2 0.45), and
/// the fit recovers it with the large-strain model. This checks the table's
/// interpolation and the fit's use of it against the reference the table was
/// made from (not an independent check: tests/layer_fit.rs does that on the
/// test data's neo-Hookean recordings).
#[test]
fn a_large_strain_fe_recording_is_fitted_at_large_strain() {
    let dir = tempfile::tempdir().unwrap();
    let path = simulate(
        dir.path(),
        &[
            "--fidelity",
            "fe",
            "--thickness-mm",
            "5",
            "--e1-mpa",
            "1.0",
            "--nu1",
            "0.45",
            "--indenter-e-mpa",
            "1.5",
            "--indenter-nu",
            "0.45",
            "--r1-mm",
            "inf",
            "--seed",
            "3",
        ],
    );
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains("# elastomer_thickness_mm: 5"), "the layer is declared");
    let v = fit_json(&path);
    let (e1, nu1) = (v["E1_MPa"].as_f64().unwrap(), v["nu1"].as_f64().unwrap());
    println!(
        "E1 {e1:.4} ({:+.2} %), nu1 {nu1:.4} ({:+.2} %), model {}",
        (e1 - 1.0) * 100.0,
        (nu1 / 0.45 - 1.0) * 100.0,
        v["full"]["model"]
    );
    assert_eq!(v["full"]["model"], "layer-fe-large-strain");
    // Measured: E1 -0.8 %, nu1 +1.1 % (E1 -0.9 %, nu1 +8.7 % with the first
    // table and linear interpolation: the table's nodes in the Poisson's
    // ratios, 0.3, 0.4, 0.48 and 0.33, 0.4, 0.47, are far apart for the
    // ratios' bend near incompressibility; the fit's intervals carry that
    // interpolation error, docs/physics.md, "Large strain").
    assert!((e1 - 1.0).abs() < 0.02 && (nu1 / 0.45 - 1.0).abs() < 0.10, "E1 {e1}, nu1 {nu1}");
    let ci = &v["ci95"]["nu1"];
    assert!(ci[0].as_f64().unwrap() <= 0.45 && 0.45 <= ci[1].as_f64().unwrap(), "nu1 interval {ci}");
}

/// The default pair (a Tac3D-like gel, E2/E1 3.3) on a 5 mm layer: the
/// large-strain reference stops settling before beta = 0.2 (the gel's surface
/// under the tip stretched 40-50 %). `simulate --fidelity fe` then ends the
/// sweep at the deepest settled state, says so and records how deep it got,
/// rather than failing; the fit recovers the gel from that shorter sweep with
/// the large-strain model, whose press is frictionless like the reference's
/// (the scaled frictional press gave E1 +3.5 %, nu1 -4.6 % here, with an E1
/// interval that missed the truth).
#[test]
fn a_large_strain_sweep_that_stops_short_says_so_and_still_fits() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.csv");
    let out = easycalib(&[
        "simulate",
        "-o",
        path.to_str().unwrap(),
        "--fidelity",
        "fe",
        "--thickness-mm",
        "5",
        "--r1-mm",
        "inf",
        "--seed",
        "1",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("stopped settling at beta"), "{err}");
    let text = std::fs::read_to_string(&path).unwrap();
    let reached: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix("# sim_beta_reached: "))
        .expect("the recording says how deep the sweep got")
        .trim()
        .parse()
        .unwrap();
    assert!((0.1..0.2).contains(&reached), "beta reached {reached}");
    let v = fit_json(&path);
    let (e1, nu1) = (v["E1_MPa"].as_f64().unwrap(), v["nu1"].as_f64().unwrap());
    println!(
        "beta {reached}: E1 {:+.2} %, nu1 {:+.2} %, model {}",
        (e1 / 0.33 - 1.0) * 100.0,
        (nu1 / 0.39 - 1.0) * 100.0,
        v["full"]["model"]
    );
    assert_eq!(v["full"]["model"], "layer-fe-large-strain");
    // Measured: E1 -0.65 %, nu1 -1.4 % (standard errors 1.5 % and 4.2 %).
    assert!((e1 / 0.33 - 1.0).abs() < 0.01 && (nu1 / 0.39 - 1.0).abs() < 0.03, "E1 {e1}, nu1 {nu1}");
    for (key, truth) in [("E1_MPa", 0.33), ("nu1", 0.39)] {
        let ci = &v["ci95"][key];
        assert!(ci[0].as_f64().unwrap() <= truth && truth <= ci[1].as_f64().unwrap(), "{key} interval {ci}");
    }
}

/// Issue 11: absurd durations are refused before anything listens or moves.
#[test]
fn absurd_durations_are_refused_with_the_flag_named() {
    let out = easycalib(&["sensor", "watch", "--tac3d", "0", "--timeout-s", "1e300"]);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--timeout-s"));
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("s.toml");
    std::fs::write(&script, "[timeouts]\nmove_s = 1e20\n").unwrap();
    let out = easycalib(&["script", "--check", script.to_str().unwrap()]);
    assert_ne!(out.status.code(), Some(0));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("timeouts.move_s"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Issue 10: on the emulated rig the script describes the indenter and R1, so
/// flags that would be silently dropped are refused before anything starts;
/// the simulated-hardware flags mean nothing with a real rig file.
#[test]
fn flags_a_script_or_rig_file_would_drop_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("s.toml");
    std::fs::write(&script, "[indenter]\ne_mpa = 1.1\nnu = 0.39\nr_mm = 4.0\n").unwrap();
    let out_dir = dir.path().join("out");
    let out = easycalib(&[
        "run",
        "--script",
        script.to_str().unwrap(),
        "--indenter-r-mm",
        "6",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--indenter-r-mm cannot be used with --script") && err.contains("[indenter]"), "{err}");
    assert!(!out_dir.exists(), "nothing is written for refused flags");

    let rig = dir.path().join("rig.toml");
    std::fs::write(&rig, "").unwrap();
    let out = easycalib(&["run", "--rig", rig.to_str().unwrap(), "--e1-mpa", "0.3"]);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--rig") && err.contains("--e1-mpa"), "{err}");
}

/// A script that declares the sensor's gel layer runs on the emulated rig as
/// a layered gel (docs/physics.md, "The layer in the generator"): the real
/// drivers over pseudo-terminals, the simulated marker field and the sensing
/// chain, the layer declared in the recording, the layered fit at the end.
/// With a frame drifting 0.5 µm/s (a profile) the fit alone is biased
/// (printed; E1 -1.7 % in two runs) and the run's diagnosis names the drift,
/// measures it and corrects E1 and nu1: a layer and a rig effect at once, as
/// on a real rig. The rig runs 10 times faster than real time, not the
/// default 40: a drifting frame makes the recording depend on how much rig
/// time the run spends, and at 40 a loaded host (three busy processes
/// beside the test) left the corrected E1 at -1.22 % in 1 of 8 runs (-0.73
/// to +0.30 % over 12 idle runs; once -1.23 % in CI), at 10 within -0.22 to
/// +0.14 % in 8 of 8 under the same load. A layer on a domed gel is refused,
/// naming the key.
#[test]
fn a_declared_layer_runs_on_the_emulated_rig_and_is_recovered() {
    let dir = tempfile::tempdir().unwrap();
    let script = dir.path().join("layer.toml");
    std::fs::write(&script, "[sensor]\nelastomer_r_mm = \"inf\"\nelastomer_thickness_mm = 5.0\n").unwrap();
    let drift = dir.path().join("drift.toml");
    std::fs::write(&drift, "[thermal_drift]\nv_mm_per_s = 0.0005\n").unwrap();
    let (te, tn) = (sim::defaults::ELASTOMER_E_MPA, sim::defaults::ELASTOMER_NU);
    let pct = |v: &serde_json::Value, t: f64| (v.as_f64().unwrap() / t - 1.0) * 100.0;
    for (name, profile) in [("clean", None), ("drift", Some(&drift))] {
        let out_dir = dir.path().join(name);
        let mut args = vec!["run", "--no-history", "--json", "--speedup", "10", "--script", script.to_str().unwrap()];
        args.extend(["--out", out_dir.to_str().unwrap()]);
        if let Some(p) = profile {
            args.extend(["--profile", p.to_str().unwrap()]);
        }
        let out = easycalib(&args);
        assert!(out.status.success(), "{name}: {}", String::from_utf8_lossy(&out.stderr));
        let rec = std::fs::read_to_string(out_dir.join("recording.csv")).unwrap();
        assert!(rec.contains("# elastomer_thickness_mm: 5") && rec.contains("# elastomer_base: bonded"), "{name}");
        let v: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out_dir.join("report.json")).unwrap()).unwrap();
        let d = &v["diagnosis"];
        println!(
            "{name}: model {}, fit E1 {:+.2} % nu1 {:+.2} %; diagnosis {} E1 {:+.2} % nu1 {:+.2} %",
            v["full"]["model"],
            pct(&v["E1_MPa"], te),
            pct(&v["nu1"], tn),
            d["effects"],
            pct(&d["E1_MPa"], te),
            pct(&d["nu1"], tn)
        );
        assert!(v["full"]["model"].as_str().unwrap().starts_with("layer-fe"), "{name}: {}", v["full"]["model"]);
        let names: Vec<&str> = d["effects"].as_array().unwrap().iter().map(|e| e["name"].as_str().unwrap()).collect();
        if profile.is_none() {
            assert!(names.is_empty(), "clean: {names:?}");
            assert!(pct(&v["E1_MPa"], te).abs() < 1.0 && pct(&v["nu1"], tn).abs() < 2.0, "clean fit");
        } else {
            assert!(names.contains(&"thermal_drift"), "drift: {names:?}");
            let drift = d["effects"].as_array().unwrap().iter().find(|e| e["name"] == "thermal_drift").unwrap();
            let found = drift["params"][0]["value"].as_f64().unwrap();
            assert!((found / 5e-4 - 1.0).abs() < 0.2, "drift found {found} mm/s for 5e-4");
        }
        assert!(
            pct(&d["E1_MPa"], te).abs() < 1.0 && pct(&d["nu1"], tn).abs() < 2.0,
            "{name}: the diagnosis's estimate"
        );
    }
    let domed = dir.path().join("domed.toml");
    std::fs::write(&domed, "[sensor]\nelastomer_r_mm = 33.0\nelastomer_thickness_mm = 5.0\n").unwrap();
    let out = easycalib(&[
        "run",
        "--no-history",
        "--script",
        domed.to_str().unwrap(),
        "--out",
        dir.path().join("d").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("elastomer_thickness_mm") && err.contains("elastomer_r_mm"), "{err}");
    assert!(!dir.path().join("d").join("recording.csv").exists());
}
