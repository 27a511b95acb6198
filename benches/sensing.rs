//! Frame processing timing: one 20 x 20 (400-marker) Tac3D-like frame to
//! gamma1 and theta1. Targets (issues 4 and 12): >= 20,000 frames/s on one
//! core for torsion-size contacts, >= 10,000 at contact onset, where a run's
//! estimator fits the contact at its learnt curvature and centre.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use easycalib::sensing::{LayerSurface, SensingConfig, measure};
use sim::rng::Rng;
use sim::sensor::field::{ContactState, MarkerGrid, NoiseConfig, synth_frame, synth_frame_on};

fn frames(c: &mut Criterion) {
    let grid = MarkerGrid::tac3d();
    let mut rng = Rng::seed_from(1);
    // A run's settings: the rig's indenter and dome, whose spheres' sag the
    // fits take out (docs/sensing.md, "The spheres inside a wide contact").
    let cfg = SensingConfig::for_contact(5.0, 33.0);
    let mut g = c.benchmark_group("measure_400_markers");
    // Torsion-phase contact (a ~ 4.9 mm), 4 um noise, 5 % outliers.
    let torsion = ContactState::new([0.13, -0.21], 3.9, 4.9, 3f64.to_radians()).with_nu1(0.39).with_spheres(5.0, 33.0);
    let f = synth_frame(&torsion, &grid, &NoiseConfig::gaussian(0.004).with_outliers(0.05), &mut rng, 0, 0.0);
    g.bench_function("torsion_contact_noisy", |b| b.iter(|| measure(black_box(&f), &cfg)));
    // Early normal sweep (a ~ 1.2 mm): the Hertz-field fit runs.
    let small = ContactState::new([0.13, -0.21], 0.25, 1.2, 0.0).with_nu1(0.39).with_spheres(5.0, 33.0);
    let f = synth_frame(&small, &grid, &NoiseConfig::gaussian(0.004), &mut rng, 1, 0.0);
    g.bench_function("small_contact_hertz_fit", |b| b.iter(|| measure(black_box(&f), &cfg)));
    // What a run does once its estimator has learnt the contact (docs/sensing.md):
    // onset (a 0.5 mm, between markers: gamma1 alone is fitted) and a contact of
    // 1.3 mm (also fitted with its radius free, to learn the curvature there).
    let learnt = SensingConfig {
        contact_curvature_per_mm: Some((0.175, 0.0005)),
        contact_centre_mm: Some([0.0, 0.0]),
        ..SensingConfig::for_contact(5.0, 33.0)
    };
    for (name, a) in [("onset_learnt_contact", 0.5), ("mid_contact_learns_curvature", 1.3)] {
        let state = ContactState::new([0.0, 0.0], 0.175 * a * a, a, 0.0).with_nu1(0.39).with_spheres(5.0, 33.0);
        let f = synth_frame(&state, &grid, &NoiseConfig::gaussian(0.004), &mut rng, 2, 0.0);
        g.bench_function(name, |b| b.iter(|| measure(black_box(&f), &learnt)));
    }
    // A tacky gel's small contact (a 0.9 mm, the loading branch's punch at
    // 500 mJ/m²): the tied fit with the punch term, from four starts.
    let tacky = SensingConfig { adhesive: true, marker_noise_mm: Some((0.004, 0.004)), ..learnt.clone() };
    let jkr = ContactState::new([0.0, 0.0], 0.175 * 0.81 - 0.0747, 0.9, 0.0)
        .with_nu1(0.39)
        .with_punch(-0.0747)
        .with_spheres(5.0, 33.0);
    let f = synth_frame(&jkr, &grid, &NoiseConfig::gaussian(0.004), &mut rng, 3, 0.0);
    g.bench_function("tacky_small_contact_punch_fit", |b| b.iter(|| measure(black_box(&f), &tacky)));
    // On a declared 5 mm layer (docs/sensing.md, "On a layer"): the same
    // onset and mid contacts drawn and read with the layer's own field
    // (the table built once, outside the timing).
    let surface = LayerSurface::declared(sim::physics::Layer::bonded(5.0), sim::physics::Body::new(1.1, 0.39, 5.0))
        .expect("the layer model");
    let on_layer = SensingConfig {
        contact_curvature_per_mm: Some((0.14, 0.0005)),
        contact_centre_mm: Some([0.0, 0.0]),
        layer: Some(surface.clone()),
        ..SensingConfig::for_contact(5.0, f64::INFINITY)
    };
    for (name, a) in [("layer_onset_learnt_contact", 0.5), ("layer_mid_contact_learns_curvature", 1.3)] {
        let state = ContactState::new([0.0, 0.0], 0.14 * a * a, a, 0.0).with_nu1(0.39).with_spheres(5.0, f64::INFINITY);
        let f = synth_frame_on(&state, Some(&surface.shape), &grid, &NoiseConfig::gaussian(0.004), &mut rng, 4, 0.0);
        g.bench_function(name, |b| b.iter(|| measure(black_box(&f), &on_layer)));
    }
    g.finish();
}

criterion_group!(benches, frames);
criterion_main!(benches);
