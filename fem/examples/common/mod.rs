//! The finite-element dev recordings with their truth, for the examples.
use sim::recording::Recording;

/// One dev recording: its set (`linear`, `nonlinear`), file name, samples and true E1, nu1.
pub struct DevRecording {
    pub set: &'static str,
    pub file: String,
    pub rec: Recording,
    pub e1: f64,
    pub nu1: f64,
}

/// Every recording listed in the sets' `truth.csv` under `root` (the first
/// argument, or the repository's tests/data/fem-dev).
pub fn dev_recordings() -> Vec<DevRecording> {
    let root = std::env::args().nth(1).unwrap_or(concat!(env!("CARGO_MANIFEST_DIR"), "/../tests/data/fem-dev").into());
    let mut out = Vec::new();
    for set in ["linear", "nonlinear"] {
        let truth = std::fs::read_to_string(format!("{root}/{set}/truth.csv")).expect("truth.csv of the dev set");
        for line in truth.lines().skip(1) {
            let f: Vec<&str> = line.split(',').collect();
            let rec =
                Recording::read_path(std::path::Path::new(&format!("{root}/{set}/{}", f[0]))).expect("a dev recording");
            let (e1, nu1) = (f[1].parse().expect("E1 in truth.csv"), f[2].parse().expect("nu1 in truth.csv"));
            out.push(DevRecording { set, file: f[0].to_string(), rec, e1, nu1 });
        }
    }
    out
}
