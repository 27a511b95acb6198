//! Issue 16: a simulated year of one sensor, calibrated by the project's own
//! generator and fit, recorded into a real SQLite history — the change test
//! and the trend judged against the truth the recordings were made from.

use std::path::Path;

use easycalib::cli::history::{make_record, outcome_of_fit};
use easycalib::fit::{FitOptions, calibrate};
use easycalib::report::calibration_output;
use history::change::{self, MONTH_S, Quantity, Settings};
use history::{Source, Target};
use sim::defaults::{ELASTOMER_E_MPA, ELASTOMER_NU, ELASTOMER_R_MM, INDENTER_E_MPA, INDENTER_NU, INDENTER_R_MM};
use sim::generator::{GeneratorConfig, generate};
use sim::physics::{Body, ContactPair};

const SENSOR: &str = "gel-A";
const T0: f64 = 1.767e9; // 2025-12-29

/// One calibration of an elastomer of modulus `e1_mpa` at time `t`, recorded.
fn calibrate_into(store: &mut dyn history::Store, dir: &Path, e1_mpa: f64, seed: u64, t: f64) {
    let pair = ContactPair {
        elastomer: Body::new(e1_mpa, ELASTOMER_NU, ELASTOMER_R_MM),
        indenter: Body::new(INDENTER_E_MPA, INDENTER_NU, INDENTER_R_MM),
    };
    let mut rec = generate(&GeneratorConfig { pair, seed, ..GeneratorConfig::default() }).unwrap();
    rec.meta.sensor = Some(SENSOR.into());
    rec.meta.created = Some(history::record::format_rfc3339(t));
    let path = dir.join(format!("{seed}.csv"));
    rec.write_path(&path).unwrap();
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let out = calibration_output(&rec, &cal, Some(&path), None);
    let bytes = std::fs::read(&path).unwrap();
    let record = make_record(&path, &bytes, &rec, outcome_of_fit(&out, Source::Run));
    assert_eq!(record.time_unix_s, t);
    store.record(&record, &bytes).unwrap();
}

/// 20 calibrations spread evenly over a year.
fn times() -> Vec<f64> {
    (0..20).map(|k| (T0 + k as f64 * 365.2425 * 86_400.0 / 19.0).round()).collect()
}

#[test]
fn a_gel_stiffening_one_percent_a_month_is_caught_early_and_its_rate_measured() {
    let dir = tempfile::tempdir().unwrap();
    let mut store = history::open(&Target::Sqlite(dir.path().join("h.sqlite"))).unwrap();
    let truth = |t: f64| ELASTOMER_E_MPA * (1.0 + 0.01 * (t - T0) / MONTH_S);
    for (k, &t) in times().iter().enumerate() {
        calibrate_into(store.as_mut(), dir.path(), truth(t), 1000 + k as u64, t);
    }
    let rows = store.list(Some(SENSOR)).unwrap();
    let series = change::series(&rows, SENSOR, "half-space");
    assert_eq!(series.len(), 20);
    let settings = Settings::default();
    let assessed = change::assess_all(&series, &settings);

    // The rig's repeatability (ISO 5725): sd from the fits' intervals (this
    // generator adds no scatter between calibrations), limit r = 2.8 sd.
    let mut sds: Vec<f64> =
        series.iter().map(|r| r.e1_ci95.map(|c| (c[1] - c[0]) / 3.92 / r.e1_mpa).unwrap()).collect();
    sds.sort_by(f64::total_cmp);
    let limit = 2.8 * sds[sds.len() / 2];
    let exceeds = times().iter().position(|&t| truth(t) / ELASTOMER_E_MPA - 1.0 > limit).unwrap();
    let first_alarm = assessed.iter().position(|a| a.alarm).expect("the drift raises an alarm");
    println!(
        "repeatability limit {:.3} %: exceeded at calibration {exceeds}, first alarm at {first_alarm}",
        100.0 * limit
    );
    assert!(first_alarm <= exceeds + 2, "alarm at {first_alarm}, change beyond the repeatability at {exceeds}");
    assert!(assessed[first_alarm].e1.as_ref().unwrap().alarm, "it is E1 that moved");

    let trend = change::trend(&series, Quantity::E1, &settings).expect("a year of calibrations has a trend");
    println!(
        "E1 trend {:.4} %/month, 95 % [{:.4}, {:.4}]",
        trend.rate_pct_per_month, trend.rate_pct_ci95[0], trend.rate_pct_ci95[1]
    );
    assert!(trend.rate_pct_ci95[0] <= 1.0 && 1.0 <= trend.rate_pct_ci95[1], "{trend:?}");
    assert!(trend.rate_pct_ci95[1] - trend.rate_pct_ci95[0] < 0.5, "a useful interval: {trend:?}");
    // nu1 did not move: its trend interval holds zero.
    let nu = change::trend(&series, Quantity::Nu1, &settings).unwrap();
    assert!(nu.rate_ci95[0] <= 0.0 && 0.0 <= nu.rate_ci95[1], "{nu:?}");
}

#[test]
fn a_stable_gel_raises_no_alarm_in_a_year() {
    let dir = tempfile::tempdir().unwrap();
    let mut store = history::open(&Target::Sqlite(dir.path().join("h.sqlite"))).unwrap();
    for (k, &t) in times().iter().enumerate() {
        calibrate_into(store.as_mut(), dir.path(), ELASTOMER_E_MPA, 2000 + k as u64, t);
    }
    let rows = store.list(Some(SENSOR)).unwrap();
    let series = change::series(&rows, SENSOR, "half-space");
    let assessed = change::assess_all(&series, &Settings::default());
    let worst = assessed
        .iter()
        .filter_map(|a| {
            a.e1.as_ref()
                .map(|v| v.z_step.abs())
                .into_iter()
                .chain(a.nu1.as_ref().map(|v| v.z_step.abs()))
                .reduce(f64::max)
        })
        .fold(0.0, f64::max);
    println!("largest |z step| over 19 comparisons: {worst:.2}");
    assert!(assessed.iter().all(|a| !a.alarm), "{:#?}", assessed.iter().find(|a| a.alarm));
    let trend = change::trend(&series, Quantity::E1, &Settings::default()).unwrap();
    assert!(trend.rate_ci95[0] <= 0.0 && 0.0 <= trend.rate_ci95[1], "{trend:?}");
}
