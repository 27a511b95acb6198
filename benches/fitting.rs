//! Fit timing on a ~200-sample recording: the paper's method and the full-model
//! fit; and the full-model fit of a declared bonded layer (the FE model with
//! friction) on a recording of the independent finite-element dev set, at
//! small and at large strain.

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
    let start = ModelParams {
        e1_mpa: paper.e1_mpa,
        nu1: paper.nu1,
        contact_offset_mm: 0.0,
        contact_friction: None,
        large_strain: false,
    };
    g.bench_function("full_model_fit", |b| b.iter(|| fit_full(black_box(&rec), &opts.full, start)));
    g.finish();

    // The layered fit: the gel tables are built once per process (cached), so
    // this is the cost of each further fit of the same gel.
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev/linear/tableI_2_E2-2.0_nu2-0.40.csv");
    let layered = sim::recording::Recording::read_path(&path).expect("dev-set recording");
    let start =
        ModelParams { e1_mpa: 0.8, nu1: 0.4, contact_offset_mm: 0.0, contact_friction: None, large_strain: false };
    fit_full(&layered, &opts.full, start).expect("layered fit (warms the tables)");
    let mut g = c.benchmark_group("fit_layer_fe");
    g.sample_size(10);
    g.bench_function(format!("{}_samples", layered.samples.len()), |b| {
        b.iter(|| fit_full(black_box(&layered), &opts.full, start))
    });
    // The large-strain layer model on a neo-Hookean recording of the dev set.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/fem-dev/nonlinear/tableI_2_E2-2.0_nu2-0.40.csv");
    let large = sim::recording::Recording::read_path(&path).expect("dev-set recording");
    let start = ModelParams { large_strain: true, ..start };
    g.bench_function(format!("{}_samples_large_strain", large.samples.len()), |b| {
        b.iter(|| fit_full(black_box(&large), &opts.full, start))
    });
    g.finish();
}

criterion_group!(benches, fits);
criterion_main!(benches);
