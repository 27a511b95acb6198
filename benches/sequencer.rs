//! The sequencer's own cost per sample: a whole default calibration (connect,
//! home, approach, normal sweep, torsion, retract; ~300 samples, each written
//! and flushed to a recording, with the running fit and the events) on the
//! in-process simulated rig, whose devices answer at once on a simulated clock.
//! What is measured is easycalib's overhead, not rig time; criterion reports
//! it per run and, through the throughput, per sample (issue 15).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use easycalib::run::script::Script;
use easycalib::run::sequencer::{RunStatus, Sequencer};

#[allow(dead_code)]
#[path = "../tests/support/simrig.rs"]
mod simrig;
use simrig::{SimRig, SimRigConfig};

fn one_run(dir: &std::path::Path, rt: &tokio::runtime::Runtime) -> usize {
    let rig = SimRig::new(SimRigConfig::default()).expect("default simulated rig");
    let path = dir.join("recording.csv");
    let _ = std::fs::remove_file(&path);
    let mut seq = Sequencer::new(Script::default(), rig.stage(), rig.mount(), rig.gauge(), &path)
        .expect("the default script is valid");
    let out = rt.block_on(seq.run());
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    out.samples
}

fn bench(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().expect("tokio runtime");
    let dir = tempfile::tempdir().expect("temporary folder");
    let samples = one_run(dir.path(), &rt);
    let mut g = c.benchmark_group("sequencer_sim_rig");
    g.throughput(Throughput::Elements(samples as u64));
    g.sample_size(10);
    g.bench_function(format!("default_run_{samples}_samples"), |b| b.iter(|| one_run(dir.path(), &rt)));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
