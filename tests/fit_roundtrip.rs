//! Round trip: simulate with known E1, nu1, then fit; the full-model fit must
//! recover the truth tightly, and beat the paper's truncated relations.

use easycalib::fit::{FitOptions, calibrate};
use sim::generator::{GeneratorConfig, generate};

#[test]
fn full_model_fit_recovers_truth_on_20_seeds() {
    let mut worst_full = (0.0f64, 0.0f64);
    let mut worst_paper = (0.0f64, 0.0f64);
    let mut inside = 0;
    for seed in 1..=20u64 {
        let cfg = GeneratorConfig { seed, ..Default::default() };
        let (e1, nu1) = (cfg.pair.elastomer.e_mpa, cfg.pair.elastomer.nu);
        let rec = generate(&cfg).unwrap();
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        let fe = (cal.full.e1_mpa / e1 - 1.0).abs();
        let fn_ = (cal.full.nu1 / nu1 - 1.0).abs();
        let pe = (cal.paper.e1_mpa / e1 - 1.0).abs();
        let pn = (cal.paper.nu1 / nu1 - 1.0).abs();
        println!(
            "seed {seed:2}: full E1 {:+.3}% nu1 {:+.3}% | paper E1 {:+.3}% nu1 {:+.3}% | rms {:.2} um {:.4} deg",
            (cal.full.e1_mpa / e1 - 1.0) * 100.0,
            (cal.full.nu1 / nu1 - 1.0) * 100.0,
            (cal.paper.e1_mpa / e1 - 1.0) * 100.0,
            (cal.paper.nu1 / nu1 - 1.0) * 100.0,
            cal.full.rms.normal_um,
            cal.full.rms.torsion_deg,
        );
        assert!(fe < 0.005, "seed {seed}: E1 {} vs {e1}", cal.full.e1_mpa);
        assert!(fn_ < 0.015, "seed {seed}: nu1 {} vs {nu1}", cal.full.nu1);
        println!(
            "  se E1 {:.3}% nu1 {:.3}% z0 {:.4} mm corr {:.3} beta {:.4} it {}",
            cal.full.e1_se / e1 * 100.0,
            cal.full.nu1_se / nu1 * 100.0,
            cal.full.contact_offset_mm,
            cal.full.corr_e1_nu1,
            cal.full.beta,
            cal.full.iterations
        );
        if cal.full.ci95.e1_mpa[0] <= e1 && e1 <= cal.full.ci95.e1_mpa[1] {
            inside += 1;
        }
        worst_full = (worst_full.0.max(fe), worst_full.1.max(fn_));
        worst_paper = (worst_paper.0.max(pe), worst_paper.1.max(pn));
    }
    println!("worst full: E1 {:.3}% nu1 {:.3}%", worst_full.0 * 100.0, worst_full.1 * 100.0);
    println!("worst paper: E1 {:.3}% nu1 {:.3}%", worst_paper.0 * 100.0, worst_paper.1 * 100.0);
    // The intervals are honest: the truth lies inside the 95 % interval for most seeds.
    assert!(inside >= 16, "truth inside the 95% interval on only {inside}/20 seeds");
    // The full model is the better estimator on the generator's data.
    assert!(worst_full.1 < worst_paper.1, "full {worst_full:?} vs paper {worst_paper:?}");
}
