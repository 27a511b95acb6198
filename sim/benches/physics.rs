//! Forward-model throughput: normal-contact solves and torsion splits per second.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use sim::physics::{Body, ContactPair, NormalModel, torsion_at};

fn pair() -> ContactPair {
    ContactPair { elastomer: Body::new(0.33, 0.39, 33.0), indenter: Body::new(1.1, 0.39, 5.0) }
}

fn forward(c: &mut Criterion) {
    let model = NormalModel::new(pair()).expect("valid pair");
    let deltas: Vec<f64> = (1..=1000).map(|i| i as f64 * 0.0053).collect();
    let mut g = c.benchmark_group("forward_model");
    g.throughput(Throughput::Elements(deltas.len() as u64));
    g.bench_function("normal_solve_x1000", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for &d in &deltas {
                acc += model.solve(black_box(d)).map(|s| s.gamma1_mm).unwrap_or(0.0);
            }
            acc
        })
    });
    let p = pair();
    let twists: Vec<f64> = (0..1000).map(|i| i as f64 * 1e-4).collect();
    g.bench_function("torsion_split_x1000", |b| {
        b.iter(|| {
            let mut acc = 0.0;
            for &t in &twists {
                acc += torsion_at(black_box(&p), black_box(0.2), t).theta1_rad;
            }
            acc
        })
    });
    g.bench_function("model_setup", |b| b.iter(|| NormalModel::new(black_box(pair()))));
    g.finish();
}

/// The layered solver (issue 13 targets: normal solve <= 50 µs, torsion <= 20 µs).
fn layered(c: &mut Criterion) {
    use sim::physics::{Body, ContactPair, Layer, LayeredNormal, LayeredTorsion};
    let p = ContactPair { elastomer: Body::new(1.0, 0.48, f64::INFINITY), indenter: Body::new(2.0, 0.4, 5.0) };
    let layer = Layer::bonded(5.0);
    let model = LayeredNormal::new(&p, &layer, 4.0).expect("valid layer");
    let torsion = LayeredTorsion::new(&layer, 4.0).expect("valid layer");
    let delta = model.at_contact_radius(2.5).delta_mm;
    let mut g = c.benchmark_group("layered");
    g.bench_function("normal_solve_one_stage_position", |b| b.iter(|| model.solve(black_box(delta))));
    g.bench_function("normal_at_contact_radius", |b| b.iter(|| model.at_contact_radius(black_box(2.5))));
    g.bench_function("torsion_stiffness", |b| b.iter(|| torsion.stiffness_factor(black_box(2.5))));
    g.bench_function("normal_model_setup", |b| b.iter(|| LayeredNormal::new(black_box(&p), &layer, 4.0)));
    g.finish();
}

criterion_group!(benches, forward, layered);
criterion_main!(benches);
