//! Issue 16's targets: recording one calibration on SQLite (<= 5 ms) and
//! `history SENSOR` over 10,000 calibrations (<= 50 ms): read, one value per
//! recording, every calibration assessed against the ones before it, trends.

use criterion::{Criterion, criterion_group, criterion_main};
use history::change::{self, Quantity, Settings};
use history::{CalibrationRecord, Target};

#[path = "../tests/common/mod.rs"]
mod common;

fn record(i: usize, sensor: &str) -> (CalibrationRecord, Vec<u8>) {
    let bytes = format!("# easycalib-recording: 1\n# sensor: {sensor}\n# run {i}\n").repeat(200).into_bytes();
    let e1 = 0.33 * (1.0 + 1e-4 * (i % 17) as f64);
    let t = 1.7e9 + i as f64 * 3600.0;
    let rec = common::calibration_record(sensor, t, e1, &bytes);
    (rec, bytes)
}

fn benches(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut store = history::open(&Target::Sqlite(dir.path().join("h.sqlite"))).expect("open");
    let mut i = 0;
    c.bench_function("sqlite: record one calibration", |b| {
        b.iter(|| {
            i += 1;
            let (rec, bytes) = record(1_000_000 + i, "bench-write");
            store.record(&rec, &bytes).expect("record")
        })
    });
    for k in 0..10_000 {
        let (rec, bytes) = record(k, "fleet-0001");
        store.record(&rec, &bytes).expect("record");
    }
    let settings = Settings::default();
    c.bench_function("history SENSOR over 10,000 calibrations", |b| {
        b.iter(|| {
            let rows = store.list(Some("fleet-0001")).expect("list");
            let s = change::series(&rows, "fleet-0001", "half-space");
            let a = change::assess_all(&s, &settings);
            let t = change::trend(&s, Quantity::E1, &settings);
            (a.len(), t.map(|t| t.n))
        })
    });
}

criterion_group! {
    name = history;
    config = Criterion::default().sample_size(20);
    targets = benches
}
criterion_main!(history);
