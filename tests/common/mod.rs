//! Shared by the integration tests that read the independent finite-element
//! development set (`tests/data/fem-dev`, a copy of ../shared/data/fem-dev).

use std::path::PathBuf;

use sim::recording::Recording;

/// Each row of `set`'s truth.csv (file, E1_MPa, nu1, E2_MPa, nu2, as written)
/// with its recording.
pub fn fem_dev(set: &str) -> Vec<(Vec<String>, Recording)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev").join(set);
    let truth = std::fs::read_to_string(dir.join("truth.csv")).unwrap();
    truth
        .lines()
        .skip(1)
        .map(|line| {
            let f: Vec<String> = line.split(',').map(str::to_string).collect();
            let rec = Recording::read_path(&dir.join(&f[0])).unwrap();
            (f, rec)
        })
        .collect()
}
