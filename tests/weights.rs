//! The fits and the diagnosis weigh samples by the standard errors a recording
//! carries (`gamma1_sd_mm`, `theta1_sd_deg`; docs/recording-format.md), and
//! behave exactly as before on recordings without them.
//!
//! Recordings: the generator's noise-free sweeps, with noise added here sample
//! by sample at a known standard deviation that changes along the sweep (larger
//! for small contacts, as a marker field resolves them worst).

use std::path::Path;

use easycalib::diagnosis::{DiagnoseOptions, diagnose, prose};
use easycalib::fit::{Calibration, FitOptions, calibrate};
use easycalib::report::json::{calibration_output, to_json_explained};
use sim::generator::{GeneratorConfig, NoiseSpec, generate};
use sim::recording::{Phase, Recording};
use sim::rng::Rng;

/// The generator's standard sweeps without noise (truth: the default pair).
fn clean() -> (Recording, f64, f64) {
    let cfg = GeneratorConfig {
        noise: NoiseSpec { gamma1_sigma_mm: 0.0, theta1_sigma_deg: 0.0, ..Default::default() },
        ..Default::default()
    };
    (generate(&cfg).unwrap(), cfg.pair.elastomer.e_mpa, cfg.pair.elastomer.nu)
}

/// gamma1 noise of a sample, mm: several µm at first contact, ~1.5 µm for large contacts.
fn sd_gamma1_mm(gamma1_mm: f64) -> f64 {
    0.0015 + 0.0045 * (-gamma1_mm / 0.25).exp()
}

/// theta1 noise of torsion sample `i`, degrees (0.005 to 0.015).
fn sd_theta1_deg(i: usize) -> f64 {
    0.005 * (1 + i % 3) as f64
}

/// Noise of the per-sample standard deviations added to every live reading;
/// the recording states `reported` times that deviation as its standard error.
fn noisy(seed: u64, reported: f64) -> (Recording, f64, f64) {
    let (mut rec, e1, nu1) = clean();
    let mut rng = Rng::seed_from(seed);
    for (i, s) in rec.samples.iter_mut().enumerate() {
        if s.gamma1_mm != 0.0 {
            let sd = sd_gamma1_mm(s.gamma1_mm);
            s.gamma1_mm += rng.gaussian(sd);
            s.gamma1_sd_mm = Some(sd * reported);
        }
        if s.phase == Phase::Torsion {
            let sd = sd_theta1_deg(i);
            s.theta1_deg += rng.gaussian(sd);
            s.theta1_sd_deg = Some(sd * reported);
        }
    }
    (rec, e1, nu1)
}

fn stripped(rec: &Recording) -> Recording {
    let mut r = rec.clone();
    for s in &mut r.samples {
        s.gamma1_sd_mm = None;
        s.theta1_sd_deg = None;
    }
    r
}

fn errors(cal: &Calibration, e1: f64, nu1: f64) -> (f64, f64) {
    (cal.full.e1_mpa / e1 - 1.0, cal.full.nu1 / nu1 - 1.0)
}

#[test]
fn weighted_fit_sees_through_poor_samples_the_unweighted_one_believes() {
    let (mut rec, e1, nu1) = clean();
    let mut rng = Rng::seed_from(41);
    let mut live = 0;
    let mut poor = 0;
    for s in rec.samples.iter_mut() {
        if s.gamma1_mm == 0.0 {
            continue;
        }
        // Every other live normal sample is poor: 20 µm standard error, read
        // 4 standard errors high. The others are good to 1 µm.
        let bad = s.phase == Phase::Normal && live % 2 == 1;
        let sd = if bad { 0.020 } else { 0.001 };
        s.gamma1_mm += rng.gaussian(sd) + if bad { 4.0 * sd } else { 0.0 };
        s.gamma1_sd_mm = Some(sd);
        if s.phase == Phase::Torsion {
            s.theta1_deg += rng.gaussian(0.01);
            s.theta1_sd_deg = Some(0.01);
        }
        live += usize::from(s.phase == Phase::Normal);
        poor += usize::from(bad);
    }
    let weighted = calibrate(&rec, &FitOptions::default()).unwrap();
    let unweighted = calibrate(&stripped(&rec), &FitOptions::default()).unwrap();
    let (we, wn) = errors(&weighted, e1, nu1);
    let (ue, un) = errors(&unweighted, e1, nu1);
    println!("{poor} of {live} live normal samples poor (20 µm, biased +80 µm)");
    println!(
        "weighted:   E1 {:+.3}% nu1 {:+.3}% chi2/dof {:.2} ci E1 {:?}",
        we * 100.0,
        wn * 100.0,
        weighted.full.chi2_dof.unwrap_or(f64::NAN),
        weighted.full.ci95.e1_mpa
    );
    println!("unweighted: E1 {:+.3}% nu1 {:+.3}% ci E1 {:?}", ue * 100.0, un * 100.0, unweighted.full.ci95.e1_mpa);
    assert!(we.abs() < 0.01 && wn.abs() < 0.02, "weighted fit off: E1 {we:+.4}, nu1 {wn:+.4}");
    assert!(ue.abs() > 0.01 || un.abs() > 0.02, "unweighted fit not biased: E1 {ue:+.4}, nu1 {un:+.4}");
    // The poor samples' bias is model error to the weighted fit: chi²/dof above 1 widens its interval.
    assert!(weighted.full.chi2_dof.is_some_and(|c| c > 1.5), "{:?}", weighted.full.chi2_dof);
    assert!(unweighted.full.chi2_dof.is_none());
}

#[test]
fn chi2_per_dof_is_near_one_when_the_errors_are_right() {
    for seed in [3, 4, 5] {
        let (rec, e1, nu1) = noisy(seed, 1.0);
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        let c = cal.full.chi2_dof.unwrap_or(f64::NAN);
        let (e, n) = errors(&cal, e1, nu1);
        println!("seed {seed}: chi2/dof {c:.3}, E1 {:+.3}% nu1 {:+.3}%", e * 100.0, n * 100.0);
        assert!((0.7..=1.3).contains(&c), "seed {seed}: chi2/dof {c}");
        assert!(cal.full.ci95.e1_mpa[0] < e1 && e1 < cal.full.ci95.e1_mpa[1], "seed {seed}: {:?}", cal.full.ci95);
    }
}

#[test]
fn diagnosis_inflates_errors_reported_three_times_too_small() {
    let (rec, _, _) = noisy(7, 1.0 / 3.0);
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    let report = prose::report(&d);
    println!("{report}");
    let se = d.standard_errors.unwrap();
    assert!(!d.unexplained, "{}", d.verdict);
    let k = se.gamma1_factor.unwrap_or(f64::NAN);
    let kt = se.theta1_factor.unwrap_or(f64::NAN);
    assert!((2.4..=3.6).contains(&k), "gamma1 factor {k}");
    assert!((2.4..=3.6).contains(&kt), "theta1 factor {kt}");
    assert!(report.contains("gamma1 inflated x"), "{report}");

    // Right errors are kept as they are (a factor near 1), and judged without inflation.
    let (rec, _, _) = noisy(7, 1.0);
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    let se = d.standard_errors.unwrap();
    println!("right errors: factors {se:?}, effects {:?}, unexplained {}", d.effects, d.unexplained);
    assert!(se.gamma1_factor.is_some_and(|k| k < 1.25), "{se:?}");
    assert!(!d.unexplained, "{}", d.verdict);
}

/// The JSON `easycalib fit --json` and `easycalib diagnose --json` printed
/// for corpus files before standard errors existed (tests/data/golden):
/// a recording without them gives exactly the same document. (The fit
/// documents gained one key since, `effects`, empty here: the closed loop's
/// named effects, docs/cli.md.)
#[test]
fn recordings_without_errors_give_the_same_json_as_before() {
    for name in ["clean_21", "frame_compliance"] {
        let path = format!("tests/data/{name}.csv");
        let rec = Recording::read_path(Path::new(&path)).unwrap();
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        let doc = to_json_explained(&calibration_output(&rec, &cal, Some(Path::new(&path)), None)).unwrap() + "\n";
        let golden = std::fs::read_to_string(format!("tests/data/golden/{name}.fit.json")).unwrap();
        assert!(doc == golden, "{name}: fit JSON changed:\n{doc}");
    }
    let rec = Recording::read_path(Path::new("tests/data/clean_21.csv")).unwrap();
    let d = diagnose(&rec, &DiagnoseOptions::default()).unwrap();
    let doc = to_json_explained(&d).unwrap() + "\n";
    let golden = std::fs::read_to_string("tests/data/golden/clean_21.diag.json").unwrap();
    assert!(doc == golden, "diagnosis JSON changed:\n{doc}");
}
