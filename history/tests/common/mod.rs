//! The calibration record the store tests and the benches write: one home for
//! the fixture (the bench includes this file by path).

use history::{CalibrationRecord, Indenter, Source, sha256_hex};

/// A run's calibration of `sensor` at `unix_s` with modulus `e1_mpa`, whose
/// recording is `bytes`.
pub fn calibration_record(sensor: &str, unix_s: f64, e1_mpa: f64, bytes: &[u8]) -> CalibrationRecord {
    CalibrationRecord {
        sensor: sensor.into(),
        time_utc: history::record::format_rfc3339(unix_s),
        time_unix_s: unix_s,
        source: Source::Run,
        rig: Some("test rig".into()),
        indenter: Indenter { e_mpa: 2.0, nu: 0.4, r_mm: 5.0 },
        script: None,
        model: "half-space".into(),
        e1_mpa,
        e1_ci95: Some([e1_mpa - 0.001, e1_mpa + 0.001]),
        nu1: 0.39,
        nu1_ci95: Some([0.387, 0.393]),
        effects: vec![],
        warnings: vec![],
        software_version: "test".into(),
        recording_path: None,
        recording_sha256: sha256_hex(bytes),
    }
}
