//! Fit timing on a ~200-sample recording: the paper's method and the full-model fit.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use easycalib::fit::{FitOptions, ModelParams, fit_full, fit_paper};
use sim::generator::{GeneratorConfig, SweepPlan, generate};

fn fits(c: &mut Criterion) {
    let cfg = GeneratorConfig {
        plan: SweepPlan { normal_step_mm: 0.075, torsion_step_deg: 0.25, ..SweepPlan::default() },
        ..GeneratorConfig::default()
    };
    let rec = generate(&cfg).expect("default generator config is valid");
    eprintln!("recording: {} samples", rec.samples.len());
    let opts = FitOptions::default();
    let mut g = c.benchmark_group("fit_200_samples");
    g.bench_function("paper_method", |b| b.iter(|| fit_paper(black_box(&rec), &opts.paper)));
    let paper = fit_paper(&rec, &opts.paper).expect("paper fit");
    let start = ModelParams { e1_mpa: paper.e1_mpa, nu1: paper.nu1, contact_offset_mm: 0.0, contact_friction: None };
    g.bench_function("full_model_fit", |b| b.iter(|| fit_full(black_box(&rec), &opts.full, start)));
    g.finish();
}

criterion_group!(benches, fits);
criterion_main!(benches);
