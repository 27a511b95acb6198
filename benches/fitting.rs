//! Fit timing on a ~200-sample recording: the paper's method and the full-model
//! fit; and the full-model fit of a declared bonded layer (the FE model with
//! friction) on a recording of the independent finite-element dev set, at
//! small and at large strain, and on a layered recording of the ~200-sample
//! plan.
//!
//! The layered fits are of a fresh copy of their recording each time, nudged
//! by a picometre per iteration ([`common::nudged`]): the layer model keeps
//! the last few parameter sets it solved (a fit's finite differences come
//! back to them), and the same fit repeated bit for bit would find every
//! frictional path of the last one there, which no fit of a new recording
//! does.

#[path = "common/mod.rs"]
mod common;

use std::hint::black_box;

use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use easycalib::fit::fe_law::frictional_truth;
use easycalib::fit::{FitOptions, ModelParams, fit_full, fit_paper};
use sim::generator::{GeneratorConfig, LayeredTruth, SweepPlan, generate, generate_on};

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
    let mut k = 0;
    g.bench_function(format!("{}_samples", layered.samples.len()), |b| {
        b.iter_batched(|| common::nudged(&layered, &mut k), |r| fit_full(&r, &opts.full, start), BatchSize::SmallInput)
    });
    // The large-strain layer model on a neo-Hookean recording of the dev set.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/fem-dev/nonlinear/tableI_2_E2-2.0_nu2-0.40.csv");
    let large = sim::recording::Recording::read_path(&path).expect("dev-set recording");
    let start = ModelParams { large_strain: true, ..start };
    g.bench_function(format!("{}_samples_large_strain", large.samples.len()), |b| {
        b.iter_batched(|| common::nudged(&large, &mut k), |r| fit_full(&r, &opts.full, start), BatchSize::SmallInput)
    });
    // The size: the 200-sample plan above on the simulated rig's gel
    // (E1 0.33 MPa, nu1 0.39) as a 5 mm bonded layer, written by the linear
    // FE layer model with friction (what `simulate --thickness-mm 5` writes).
    let layer = sim::physics::Layer::bonded(5.0);
    let mut cfg = cfg;
    cfg.pair.elastomer.r_mm = f64::INFINITY;
    let gel = cfg.pair.elastomer;
    let law = frictional_truth(layer, cfg.pair.indenter, gel.e_mpa, gel.nu, sim::defaults::GEL_FRICTION)
        .expect("the simulated gel's layer law");
    let long = generate_on(&cfg, Some(&LayeredTruth { law, layer })).expect("layered recording");
    let start = ModelParams { e1_mpa: 0.25, nu1: 0.3, large_strain: false, ..start };
    fit_full(&long, &opts.full, start).expect("layered fit of the long recording");
    g.bench_function(format!("{}_samples", long.samples.len()), |b| {
        b.iter_batched(|| common::nudged(&long, &mut k), |r| fit_full(&r, &opts.full, start), BatchSize::SmallInput)
    });
    g.finish();
}

criterion_group!(benches, fits);
criterion_main!(benches);
