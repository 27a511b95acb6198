//! `history export --csv`: one row per calibration, every column a user would
//! sort or plot by; effects and warnings as JSON text in their cells.

use crate::CalibrationRecord;

pub const COLUMNS: [&str; 19] = [
    "id",
    "sensor",
    "time_utc",
    "source",
    "model",
    "e1_mpa",
    "e1_ci95_lo",
    "e1_ci95_hi",
    "nu1",
    "nu1_ci95_lo",
    "nu1_ci95_hi",
    "indenter_e_mpa",
    "indenter_nu",
    "indenter_r_mm",
    "rig",
    "effects",
    "warnings",
    "software_version",
    "recording_sha256",
];

/// Write `rows` as CSV (RFC 4180 quoting) to `out`.
pub fn write_csv<W: std::io::Write>(rows: &[CalibrationRecord], out: W) -> Result<(), csv::Error> {
    let mut w = csv::Writer::from_writer(out);
    w.write_record(COLUMNS)?;
    let num = |v: f64| format!("{v}");
    let opt = |c: Option<[f64; 2]>, i: usize| c.map_or(String::new(), |c| num(c[i]));
    for r in rows {
        w.write_record([
            r.id(),
            r.sensor.clone(),
            r.time_utc.clone(),
            r.source.as_str().to_string(),
            r.model.clone(),
            num(r.e1_mpa),
            opt(r.e1_ci95, 0),
            opt(r.e1_ci95, 1),
            num(r.nu1),
            opt(r.nu1_ci95, 0),
            opt(r.nu1_ci95, 1),
            num(r.indenter.e_mpa),
            num(r.indenter.nu),
            num(r.indenter.r_mm),
            r.rig.clone().unwrap_or_default(),
            serde_json::to_string(&r.effects).unwrap_or_default(),
            serde_json::to_string(&r.warnings).unwrap_or_default(),
            r.software_version.clone(),
            r.recording_sha256.clone(),
        ])?;
    }
    w.flush()?;
    Ok(())
}
