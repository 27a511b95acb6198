//! Frame processing timing: one 20 x 20 (400-marker) Tac3D-like frame to
//! gamma1 and theta1. Target (issue 4): >= 20,000 frames/s on one core.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use easycalib::sensing::{SensingConfig, measure};
use sim::rng::Rng;
use sim::sensor::field::{ContactState, MarkerGrid, NoiseConfig, synth_frame};

fn frames(c: &mut Criterion) {
    let grid = MarkerGrid::tac3d();
    let mut rng = Rng::seed_from(1);
    let cfg = SensingConfig::default();
    let mut g = c.benchmark_group("measure_400_markers");
    // Torsion-phase contact (a ~ 4.9 mm), 4 um noise, 5 % outliers.
    let torsion = ContactState::new([0.13, -0.21], 3.9, 4.9, 3f64.to_radians()).with_nu1(0.39);
    let f = synth_frame(&torsion, &grid, &NoiseConfig::gaussian(0.004).with_outliers(0.05), &mut rng, 0, 0.0);
    g.bench_function("torsion_contact_noisy", |b| b.iter(|| measure(black_box(&f), &cfg)));
    // Early normal sweep (a ~ 1.2 mm): the Hertz-field fit runs.
    let small = ContactState::new([0.13, -0.21], 0.25, 1.2, 0.0).with_nu1(0.39);
    let f = synth_frame(&small, &grid, &NoiseConfig::gaussian(0.004), &mut rng, 1, 0.0);
    g.bench_function("small_contact_hertz_fit", |b| b.iter(|| measure(black_box(&f), &cfg)));
    g.finish();
}

criterion_group!(benches, frames);
criterion_main!(benches);
