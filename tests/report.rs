//! Reports: files written, JSON values equal to the calibration, SVG figures
//! well-formed with the expected series, Markdown referencing them, and the
//! default run folder name.

use std::path::Path;
use std::time::{Duration, UNIX_EPOCH};

use easycalib::fit::{Calibration, FitOptions, calibrate};
use easycalib::report::json::to_json_explained;
use easycalib::report::{
    JSON_FILE, MARKDOWN_FILE, NORMAL_SVG_FILE, ReportError, TORSION_SVG_FILE, Truth, calibration_output,
    default_run_dir, normal_plot, rfc3339_utc, torsion_plot, utc_stamp, write_report,
};
use serde_json::Value;
use sim::generator::{GeneratorConfig, generate};
use sim::recording::{Phase, Recording};

fn calibrated() -> (GeneratorConfig, Recording, Calibration) {
    let cfg = GeneratorConfig::default();
    let rec = generate(&cfg).unwrap();
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    (cfg, rec, cal)
}

fn truth(cfg: &GeneratorConfig) -> Truth {
    Truth { e1_mpa: cfg.pair.elastomer.e_mpa, nu1: cfg.pair.elastomer.nu }
}

/// A JSON number equals `want` (serde_json's parser may be one ulp off).
fn same(v: &Value, want: f64) {
    let got = v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"));
    assert!((got - want).abs() <= 1e-14 * want.abs(), "{got} != {want}");
}

/// Checks that every opened element is closed in order (a small XML
/// well-formedness check: tags, self-closing tags, declarations).
fn assert_well_formed(svg: &str) {
    let mut stack: Vec<String> = Vec::new();
    let mut rest = svg;
    while let Some(i) = rest.find('<') {
        rest = &rest[i + 1..];
        let end = rest.find('>').expect("unterminated tag");
        let tag = &rest[..end];
        rest = &rest[end + 1..];
        if tag.starts_with('?') || tag.starts_with('!') {
            continue;
        }
        if let Some(name) = tag.strip_prefix('/') {
            let open = stack.pop().unwrap_or_else(|| panic!("closing </{name}> with nothing open"));
            assert_eq!(open, name.trim(), "mismatched closing tag");
        } else if !tag.ends_with('/') {
            let name = tag.split_whitespace().next().unwrap().to_string();
            stack.push(name);
        }
    }
    assert!(stack.is_empty(), "unclosed elements: {stack:?}");
}

#[test]
fn report_files_are_written_and_json_matches_the_calibration() {
    let (cfg, rec, cal) = calibrated();
    let dir = tempfile::tempdir().unwrap();
    let rec_path = dir.path().join("recording.csv");
    rec.write_path(&rec_path).unwrap();
    // Fit the file as written (rounded to the CSV's precision), as a run does.
    let back = Recording::read_path(&rec_path).unwrap();
    let cal_back = calibrate(&back, &FitOptions::default()).unwrap();
    assert_ne!(cal_back, cal, "rounding changes the fit slightly, so the check below is specific");
    let cal = cal_back;
    let out = dir.path().join("runs").join("r1");
    let files = write_report(&out, &rec_path, &cal, Some(truth(&cfg))).unwrap();
    assert_eq!(files.dir, out);
    for (p, name) in [
        (&files.json, JSON_FILE),
        (&files.markdown, MARKDOWN_FILE),
        (&files.normal_svg, NORMAL_SVG_FILE),
        (&files.torsion_svg, TORSION_SVG_FILE),
    ] {
        assert_eq!(p, &out.join(name));
        assert!(std::fs::metadata(p).unwrap().len() > 100, "{} is empty", p.display());
    }

    let j: Value = serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
    same(&j["E1_MPa"], cal.full.e1_mpa);
    same(&j["nu1"], cal.full.nu1);
    same(&j["ci95"]["E1_MPa"][0], cal.full.ci95.e1_mpa[0]);
    same(&j["ci95"]["E1_MPa"][1], cal.full.ci95.e1_mpa[1]);
    same(&j["ci95"]["nu1"][0], cal.full.ci95.nu1[0]);
    same(&j["ci95"]["nu1"][1], cal.full.ci95.nu1[1]);
    let p = &j["paper"];
    same(&p["H1"], cal.paper.h1);
    same(&p["H3"], cal.paper.h3);
    same(&p["E1_MPa"], cal.paper.e1_mpa);
    same(&p["nu1"], cal.paper.nu1);
    same(&p["E1_MPa_rounded"], cal.paper.e1_mpa_rounded);
    same(&p["nu1_rounded"], cal.paper.nu1_rounded);
    same(&j["full"]["E1_MPa"], cal.full.e1_mpa);
    same(&j["full"]["contact_offset_mm"], cal.full.contact_offset_mm);
    assert_eq!(j["recording"], rec_path.display().to_string());
    same(&j["sim_truth"]["E1_MPa"], 0.33);
    same(&j["sim_truth"]["nu1"], 0.39);
    assert_eq!(j["samples"]["normal"], back.phase(Phase::Normal).count());
    assert_eq!(j["samples"]["torsion"], back.phase(Phase::Torsion).count());
    // The same document `easycalib fit --json` prints.
    let doc = calibration_output(&back, &cal, Some(&rec_path), Some(truth(&cfg)));
    assert_eq!(std::fs::read_to_string(&files.json).unwrap(), to_json_explained(&doc).unwrap() + "\n");
    // And the values are the truth, within the run's target accuracy.
    assert!((cal.full.e1_mpa / 0.33 - 1.0).abs() < 0.01, "E1 {}", cal.full.e1_mpa);
    assert!((cal.full.nu1 / 0.39 - 1.0).abs() < 0.02, "nu1 {}", cal.full.nu1);
}

#[test]
fn real_rig_report_has_no_sim_truth() {
    let (_, rec, _) = calibrated();
    let dir = tempfile::tempdir().unwrap();
    let rec_path = dir.path().join("r.csv");
    rec.write_path(&rec_path).unwrap();
    let back = Recording::read_path(&rec_path).unwrap();
    let cal = calibrate(&back, &FitOptions::default()).unwrap();
    let files = write_report(dir.path(), &rec_path, &cal, None).unwrap();
    let j: Value = serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
    assert!(j.get("sim_truth").is_none(), "{j}");
    let md = std::fs::read_to_string(&files.markdown).unwrap();
    assert!(!md.contains("Simulation truth"));
}

#[test]
fn missing_recording_is_an_error_naming_the_path() {
    let (_, _, cal) = calibrated();
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.csv");
    let err = write_report(&dir.path().join("out"), &missing, &cal, None).unwrap_err();
    assert!(matches!(err, ReportError::Recording { .. }), "{err:?}");
    assert!(err.to_string().contains("nope.csv"), "{err}");
    assert!(!dir.path().join("out").join(JSON_FILE).exists());
}

#[test]
fn plot_series_follow_the_fits() {
    let (_, rec, cal) = calibrated();
    let n = normal_plot(&rec, &cal).unwrap();
    assert_eq!(n.points.len(), rec.phase(Phase::Normal).count());
    // The paper's curve is Eq. 22 with the fitted H1, H2.
    for &(x, y) in &n.paper {
        assert!((y - (cal.paper.h1 * x + cal.paper.h2 * x.powf(1.5))).abs() < 1e-12);
    }
    // Full-model residuals are the ones the fit reports.
    let rms = |v: &[(f64, f64)]| (v.iter().map(|p| p.1 * p.1).sum::<f64>() / v.len() as f64).sqrt();
    assert!((rms(&n.full_residuals) / cal.full.rms.normal_um - 1.0).abs() < 1e-9);
    assert_eq!(n.paper_residuals.len(), cal.paper.n_normal);
    // The full-model curve runs through the data: each point within a few
    // noise floors of the curve at its own gamma1.
    assert!(n.full.windows(2).all(|w| w[0].0 < w[1].0), "ordered along gamma1");
    assert!(rms(&n.full_residuals) < 5.0, "µm: {}", rms(&n.full_residuals));

    let t = torsion_plot(&rec, &cal).unwrap();
    assert_eq!(t.points.len(), rec.phase(Phase::Torsion).count());
    for &(x, y) in &t.paper {
        assert!((y - cal.paper.h3 * x).abs() < 1e-12);
    }
    assert!((rms(&t.full_residuals) / cal.full.rms.torsion_deg - 1.0).abs() < 1e-9);
    // theta2 grows with theta1 along the paper line.
    let (x0, x1) = (t.paper[0].0, t.paper[t.paper.len() - 1].0);
    assert!(x1 > x0 && cal.paper.h3 > 0.0);
}

#[test]
fn svgs_are_well_formed_and_carry_every_series() {
    let (cfg, rec, cal) = calibrated();
    let dir = tempfile::tempdir().unwrap();
    let rec_path = dir.path().join("recording.csv");
    rec.write_path(&rec_path).unwrap();
    let back = Recording::read_path(&rec_path).unwrap();
    let files = write_report(dir.path(), &rec_path, &cal, Some(truth(&cfg))).unwrap();
    for (path, phase, eq) in [
        (&files.normal_svg, Phase::Normal, "paper fit (Eq. 22)"),
        (&files.torsion_svg, Phase::Torsion, "paper fit (Eq. 38)"),
    ] {
        let svg = std::fs::read_to_string(path).unwrap();
        assert!(svg.trim_start().starts_with("<svg") || svg.trim_start().starts_with("<?xml"), "{path:?}");
        assert!(svg.trim_end().ends_with("</svg>"));
        assert_well_formed(&svg);
        // One filled circle per measured sample plus the legend's.
        let circles = svg.matches("<circle").count();
        assert_eq!(circles, back.phase(phase).count() + 1, "{path:?}");
        for label in [eq, "full model", "measured", &format!("{eq} residual"), "full model residual"] {
            assert!(
                svg.contains(&format!(">{label}<")) || svg.contains(&format!(">\n{label}\n<")),
                "{label} in {path:?}"
            );
        }
        // Fit curves and zero line are polylines.
        assert!(svg.matches("<polyline").count() >= 3, "{path:?}");
    }
}

#[test]
fn markdown_summarises_with_units_and_references_the_figures() {
    let (cfg, rec, cal) = calibrated();
    let dir = tempfile::tempdir().unwrap();
    let rec_path = dir.path().join("recording.csv");
    rec.write_path(&rec_path).unwrap();
    let back = Recording::read_path(&rec_path).unwrap();
    let cal2 = calibrate(&back, &FitOptions::default()).unwrap();
    let files = write_report(dir.path(), &rec_path, &cal2, Some(truth(&cfg))).unwrap();
    let md = std::fs::read_to_string(&files.markdown).unwrap();
    assert!(md.contains(&format!("{:.4}", cal2.full.e1_mpa)) && cal2 != cal);
    assert!(md.starts_with("# Calibration report"));
    assert!(md.contains(&format!("![Normal sweep: gamma2 vs gamma1]({NORMAL_SVG_FILE})")), "{md}");
    assert!(md.contains(&format!("![Torsion sweep: theta2 vs theta1]({TORSION_SVG_FILE})")));
    let f = &cal2.full;
    assert!(
        md.contains(&format!(
            "| E1 | full model | {:.4} | [{:.4}, {:.4}] | MPa |",
            f.e1_mpa, f.ci95.e1_mpa[0], f.ci95.e1_mpa[1]
        )),
        "{md}"
    );
    assert!(
        md.contains(&format!("| nu1 | full model | {:.4} | [{:.4}, {:.4}] | – |", f.nu1, f.ci95.nu1[0], f.ci95.nu1[1]))
    );
    assert!(md.contains(&format!("| E1 | paper, rounded constants (Eqs. 39-40) | {:.4} |", cal2.paper.e1_mpa_rounded)));
    assert!(md.contains(&format!("| full model: residual RMS | {:.2} µm |", f.rms.normal_um)));
    assert!(md.contains("## Simulation truth") && md.contains("| truth | 0.3300 | 0.3900 |"));
    assert!(md.contains(&format!("| sensor | {} |", cfg.sensor)));
    assert!(md.contains(&format!("`{}`", rec_path.display())));
}

/// A run's warnings reach both documents: report.json's `run.warnings` as
/// logged, report.md one table row each even when a message holds a `|` or
/// a line break (a device's own text can).
#[test]
fn a_runs_warnings_are_one_row_each_and_kept_in_the_json() {
    use easycalib::report::{RunExtras, json::RunTimings, write_report_for};
    let (_, rec, cal) = calibrated();
    let dir = tempfile::tempdir().unwrap();
    let warnings = vec![
        "normal sweep 1: stage target 18.0 mm could deform the elastomer by up to 5.2 mm: shortened to 17.8 mm"
            .to_string(),
        "stage said: ERR|7\nlimit".to_string(),
    ];
    let timings = RunTimings {
        rig_time_s: 90.0,
        wall_time_s: 2.0,
        phases: vec![],
        experiments: vec![],
        warnings: warnings.clone(),
    };
    let extras = RunExtras { timings: Some(timings), diagnosis: None };
    let files = write_report_for(dir.path(), &rec, None, &cal, None, extras).unwrap();
    let json: Value = serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
    let kept: Vec<&str> = json["run"]["warnings"].as_array().unwrap().iter().map(|w| w.as_str().unwrap()).collect();
    assert_eq!(kept, warnings.iter().map(String::as_str).collect::<Vec<_>>());
    let md = std::fs::read_to_string(&files.markdown).unwrap();
    let rows: Vec<&str> = md.lines().filter(|l| l.starts_with("| run warning |")).collect();
    assert_eq!(rows.len(), 2, "{md}");
    assert!(rows[0].ends_with("shortened to 17.8 mm |"), "{}", rows[0]);
    assert_eq!(rows[1], "| run warning | stage said: ERR/7 limit |");
    // Without warnings there is neither the key nor a row.
    let files = write_report_for(
        &dir.path().join("quiet"),
        &rec,
        None,
        &cal,
        None,
        RunExtras {
            timings: Some(RunTimings {
                rig_time_s: 90.0,
                wall_time_s: 2.0,
                phases: vec![],
                experiments: vec![],
                warnings: vec![],
            }),
            diagnosis: None,
        },
    )
    .unwrap();
    let json: Value = serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
    assert!(json["run"].get("warnings").is_none() && json["run"]["rig_time_s"] == 90.0, "{}", json["run"]);
    assert!(!std::fs::read_to_string(&files.markdown).unwrap().contains("run warning"));
}

#[test]
fn default_run_dir_is_utc_time_and_sensor() {
    let at = |s: u64| UNIX_EPOCH + Duration::from_secs(s);
    assert_eq!(utc_stamp(UNIX_EPOCH), "19700101-000000");
    assert_eq!(utc_stamp(at(1_795_433_080)), "20261123-112440");
    assert_eq!(utc_stamp(at(1_709_251_199)), "20240229-235959");
    assert_eq!(utc_stamp(at(951_868_800)), "20000301-000000");
    assert_eq!(utc_stamp(at(946_684_799)), "19991231-235959");
    assert_eq!(rfc3339_utc(at(1_795_433_080)), "2026-11-23T11:24:40Z");
    let root = Path::new("runs");
    assert_eq!(
        default_run_dir(root, Some("tac3d-SN0042"), at(1_795_433_080)),
        Path::new("runs/20261123-112440-tac3d-SN0042")
    );
    assert_eq!(
        default_run_dir(root, Some("gel sight/../x"), at(1_795_433_080)),
        Path::new("runs/20261123-112440-gel_sight_.._x")
    );
    assert_eq!(default_run_dir(root, None, at(0)), Path::new("runs/19700101-000000-sensor"));
    assert_eq!(default_run_dir(root, Some(".."), at(0)), Path::new("runs/19700101-000000-sensor"));
}
