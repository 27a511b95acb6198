//! Full diagnosis (baseline, every candidate effect, the pairs tried, the
//! degeneracy probe) of a ~240-sample recording: a clean one and one with
//! stage backlash (the commanded history of the generator's run, re-read
//! through the true-rig model with the effect, plus seeded noise).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use easycalib::diagnosis::{DiagnoseOptions, diagnose};
use sim::effects::{Command, SimProfile, simulate, stage_backlash};
use sim::generator::{GeneratorConfig, generate};
use sim::recording::Phase;
use sim::rng::Rng;

fn bench(c: &mut Criterion) {
    let cfg = GeneratorConfig::default();
    let clean = generate(&cfg).expect("default generator config is valid");
    let profile = SimProfile {
        stage_backlash: Some(stage_backlash::Params { b_mm: 0.008, engaged: true }),
        ..Default::default()
    };
    let cmds: Vec<Command> =
        clean.samples.iter().map(|s| Command { t_s: s.t_s, stage_mm: s.stage_mm, rot_deg: s.rot_deg }).collect();
    let readings = simulate(cfg.pair, &profile, &cmds).expect("backlash profile simulates");
    let mut rng = Rng::seed_from(5);
    let mut backlash = clean.clone();
    for (s, r) in backlash.samples.iter_mut().zip(&readings) {
        s.gamma1_mm = if r.in_contact { r.gamma1_mm + rng.gaussian(0.002) } else { 0.0 };
        s.theta1_deg = if s.phase == Phase::Torsion { r.theta1_deg + rng.gaussian(0.02) } else { 0.0 };
    }
    eprintln!("recording: {} samples", clean.samples.len());
    let opts = DiagnoseOptions::default();
    let mut g = c.benchmark_group("diagnose");
    g.sample_size(10);
    g.bench_function("clean", |b| b.iter(|| diagnose(black_box(&clean), &opts)));
    g.bench_function("stage_backlash", |b| b.iter(|| diagnose(black_box(&backlash), &opts)));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
