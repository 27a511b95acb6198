//! The concealed-data corpus really conceals (issue 6, deliverable 3).
//!
//! For every case of `tests/data/corpus.toml`:
//! * the committed CSV is exactly what `sim::corpus` generates from the
//!   manifest's seed and parameters (so the corpus is reproducible);
//! * the paper's fit still looks excellent: R² > 0.995 on both sweeps;
//! * the full-model fit's residual RMS is at most 2x the noise on both sweeps;
//! * yet E1 or nu1 is biased by at least 3 % — in the full-model fit for the
//!   `bias_in = "full"` cases, in the paper's fit for `bias_in = "paper"` ones;
//! * and on the clean controls both fits are within the noise of the truth.

use std::path::PathBuf;

use easycalib::fit::{Calibration, FitOptions, FullOptions, calibrate};
use sim::corpus::{BiasIn, CorpusCase, CorpusManifest};
use sim::recording::Recording;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

fn manifest() -> CorpusManifest {
    let text = std::fs::read_to_string(data_dir().join("corpus.toml")).unwrap();
    CorpusManifest::from_toml_str(&text).unwrap()
}

fn fit(case: &CorpusCase, rec: &Recording) -> Calibration {
    let opts = FitOptions {
        full: FullOptions {
            gamma1_sigma_mm: Some(case.gamma1_sigma_mm),
            theta1_sigma_deg: Some(case.theta1_sigma_deg),
        },
        ..Default::default()
    };
    calibrate(rec, &opts).unwrap_or_else(|e| panic!("{}: {e}", case.file))
}

fn pct(x: f64, truth: f64) -> f64 {
    (x / truth - 1.0) * 100.0
}

#[test]
fn manifest_matches_the_corpus_table_and_files_regenerate() {
    let m = manifest();
    assert_eq!(m.cases, sim::corpus::cases(), "corpus.toml is stale: rerun make_corpus");
    for c in &m.cases {
        let text = std::fs::read_to_string(data_dir().join(&c.file)).unwrap();
        assert_eq!(text, c.generate().unwrap().to_csv_string(), "{} is stale: rerun make_corpus", c.file);
    }
}

#[test]
fn every_case_conceals_its_effect() {
    let m = manifest();
    let mut failures = Vec::new();
    println!(
        "{:18} {:>9} | {:>8} {:>8} | {:>8} {:>8} | {:>8} {:>8} | {:>6} {:>6}",
        "effect", "bias_in", "fullE1%", "fullnu%", "papE1%", "papnu%", "R2 norm", "R2 tors", "rmsN/s", "rmsT/s"
    );
    for c in &m.cases {
        let rec = Recording::read_path(&data_dir().join(&c.file)).unwrap();
        let cal = fit(c, &rec);
        let (fe, fn_) = (pct(cal.full.e1_mpa, c.e1_mpa), pct(cal.full.nu1, c.nu1));
        let (pe, pn) = (pct(cal.paper.e1_mpa, c.e1_mpa), pct(cal.paper.nu1, c.nu1));
        let rms_n = cal.full.rms.normal_um / (c.gamma1_sigma_mm * 1e3);
        let rms_t = cal.full.rms.torsion_deg / c.theta1_sigma_deg;
        println!(
            "{:18} {:>9} | {fe:+8.2} {fn_:+8.2} | {pe:+8.2} {pn:+8.2} | {:8.5} {:8.5} | {rms_n:6.2} {rms_t:6.2}",
            c.effect,
            format!("{:?}", c.bias_in),
            cal.paper.r2_normal,
            cal.paper.r2_torsion
        );
        let mut fail = |why: String| failures.push(format!("{}: {why}", c.file));
        if !(cal.paper.r2_normal > 0.995 && cal.paper.r2_torsion > 0.995) {
            fail(format!("paper R² {} / {} not > 0.995", cal.paper.r2_normal, cal.paper.r2_torsion));
        }
        if !(rms_n <= 2.0 && rms_t <= 2.0) {
            fail(format!("full-fit RMS {rms_n:.2} / {rms_t:.2} x noise exceeds 2"));
        }
        match c.bias_in {
            BiasIn::Full if fe.abs().max(fn_.abs()) < 3.0 => fail(format!("full fit bias only {fe:+.2}% / {fn_:+.2}%")),
            BiasIn::Paper if pe.abs().max(pn.abs()) < 3.0 => fail(format!("paper fit bias only {pe:+.2}% / {pn:+.2}%")),
            BiasIn::None if fe.abs() > 1.0 || fn_.abs() > 2.0 => {
                fail(format!("clean control off: {fe:+.2}% / {fn_:+.2}%"))
            }
            _ => {}
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
