//! What one evaluation of the FE layer model costs the fit, piece by piece
//! (docs/physics.md, "Finite-element reference"): a parameter set (E1, nu1)
//! made from the gel's tables, the frictionless press at one approach, the
//! frictional press followed along a sweep's approaches, and the torsion
//! sweep at one depth (its ten twists, under friction, from the state's
//! setup on). The dev set's tableI_2 geometry: a 5 mm bonded gel, E1 1 MPa,
//! nu1 0.48, under a 5 mm hemisphere of 2 MPa, nu2 0.4, pressed 1.8 mm.
//! And the rig's tabulated law (docs/fem.md, "The tabulated law"): its
//! one-off build, one parameter set contracted from it, and one sample read
//! off that (a press and a twist).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use fem::forward::Forward;

fn forward(c: &mut Criterion) {
    let fw = Forward::cached(5.0, 2.0, 0.4, 5.0).expect("the dev set's gel and indenter");
    let model = fw.model(1.0, 0.48);
    let delta_mm = 1.8;
    let state = model.normal(delta_mm).expect("a press of 1.8 mm");
    // Ten twists to 2°, where the contact's rim slips under friction 0.4.
    let twists_rad: Vec<f64> = (1..=10).map(|k| (0.2 * k as f64).to_radians()).collect();
    // Thirty even steps to the torsion depth, as the dev set's normal sweep.
    let approaches_mm: Vec<f64> = (1..=30).map(|k| delta_mm * k as f64 / 30.0).collect();
    let mut g = c.benchmark_group("fe_forward");
    g.bench_function("model_at_e1_nu1", |b| b.iter(|| fw.model(black_box(1.0), black_box(0.48))));
    g.bench_function("normal_one_approach", |b| b.iter(|| model.normal(black_box(delta_mm))));
    g.bench_function("normal_path_30_approaches", |b| {
        b.iter(|| model.normal_path(black_box(&approaches_mm), 0.4, delta_mm / 60.0))
    });
    g.bench_function("twist_sweep_10_twists", |b| {
        b.iter(|| {
            let setup = model.twist_setup(black_box(&state), 0.4).expect("a contact off the axis");
            model.theta1_rad_sweep(&setup, &twists_rad)
        })
    });
    g.finish();

    let mut g = c.benchmark_group("fe_tabulated");
    g.sample_size(10);
    g.bench_function("build", |b| b.iter(|| fem::tabulated::TabulatedLaw::build(black_box(&fw))));
    let table = fw.tabulated().expect("the rig's tabulated law");
    g.bench_function("at_e1_nu1", |b| b.iter(|| table.at(black_box(1.0), black_box(0.48))));
    let at = table.at(1.0, 0.48).expect("inside the table");
    g.bench_function("one_sample", |b| {
        b.iter(|| {
            let g1 = at.gamma1_mm(black_box(delta_mm));
            let t1 = at.theta1_rad(black_box(delta_mm), black_box(2f64.to_radians()), 0.4);
            (g1, t1)
        })
    });
    g.finish();
}

criterion_group!(benches, forward);
criterion_main!(benches);
