//! The report of a calibration: `report.json` (the stable JSON document),
//! `report.md` (summary with units and intervals, fit quality, figures) and
//! one SVG figure per sweep, written into an output directory.

pub mod diagnosis;
pub mod json;
mod markdown;
pub mod plot;

use std::path::{Path, PathBuf};
use std::time::SystemTime;

use sim::recording::{Recording, RecordingError};

use crate::fit::{Calibration, FitError};

pub use diagnosis::{CLOSED_LOOP, Decided, EffectFound, RunDiagnosis, VerdictClass, diagnose_run};
pub use json::{CalibrationOutput, RunTimings, Truth, calibration_output};
pub use markdown::render_markdown;
pub use plot::{NORMAL_TEXT, PlotText, SweepPlot, TORSION_TEXT, normal_plot, render_svg, torsion_plot};

pub const JSON_FILE: &str = "report.json";
pub const MARKDOWN_FILE: &str = "report.md";
pub const NORMAL_SVG_FILE: &str = "normal_sweep.svg";
pub const TORSION_SVG_FILE: &str = "torsion_sweep.svg";

#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("cannot read the recording {path}: {source}")]
    Recording { path: PathBuf, source: RecordingError },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("cannot evaluate the fitted model for the figures: {0}")]
    Model(#[from] FitError),
    #[error("cannot draw the figure `{what}`: {message}")]
    Plot { what: String, message: String },
    #[error("cannot encode the JSON report: {0}")]
    Json(#[from] serde_json::Error),
}

/// Where the report's files went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReportFiles {
    pub dir: PathBuf,
    pub json: PathBuf,
    pub markdown: PathBuf,
    pub normal_svg: PathBuf,
    pub torsion_svg: PathBuf,
}

fn write(path: PathBuf, text: &str) -> Result<PathBuf, ReportError> {
    use std::io::Write;
    // Never through a symbolic link planted at the report's name (docs/run.md).
    crate::run::outdir::create_nofollow(&path)
        .and_then(|mut f| f.write_all(text.as_bytes()))
        .map_err(|source| ReportError::Io { path: path.clone(), source })?;
    Ok(path)
}

/// Read the recording at `recording_path` and write the report of `cal` into
/// `out_dir` (created if missing). `truth` is the simulated rig's elastomer.
pub fn write_report(
    out_dir: &Path,
    recording_path: &Path,
    cal: &Calibration,
    truth: Option<Truth>,
) -> Result<ReportFiles, ReportError> {
    let rec = Recording::read_path(recording_path)
        .map_err(|source| ReportError::Recording { path: recording_path.to_path_buf(), source })?;
    write_report_for(out_dir, &rec, Some(recording_path), cal, truth, RunExtras::default())
}

/// What a run adds to the report of its calibration.
#[derive(Debug, Clone, Default)]
pub struct RunExtras {
    pub timings: Option<RunTimings>,
    /// The diagnosis made at the end of the run (absent with `--no-diagnose`).
    pub diagnosis: Option<RunDiagnosis>,
}

/// Write the report of `cal`, fitted to `rec`, into `out_dir` (created if
/// missing). `recording_path` is where `rec` lives, for the record.
pub fn write_report_for(
    out_dir: &Path,
    rec: &Recording,
    recording_path: Option<&Path>,
    cal: &Calibration,
    truth: Option<Truth>,
    extras: RunExtras,
) -> Result<ReportFiles, ReportError> {
    write_report_decided(out_dir, rec, recording_path, cal, truth, extras, None)
}

/// As [`write_report_for`], with the closed loop's decision when it decided
/// (docs/experiments.md, "The headline after the loop"): the top-level
/// `effects`, `E1_MPa`, `nu1`, `ci95` and the `diagnosis` are then the
/// decision's, the run recording's own diagnosis goes under `standard` when
/// it is not the decision, and the calibration stays under `full`.
pub fn write_report_decided(
    out_dir: &Path,
    rec: &Recording,
    recording_path: Option<&Path>,
    cal: &Calibration,
    truth: Option<Truth>,
    extras: RunExtras,
    decided: Option<Decided>,
) -> Result<ReportFiles, ReportError> {
    std::fs::create_dir_all(out_dir).map_err(|source| ReportError::Io { path: out_dir.to_path_buf(), source })?;
    // Figures first: a model that cannot be evaluated fails before any file is written.
    let normal = render_svg(&normal_plot(rec, cal)?, &NORMAL_TEXT)?;
    let torsion = render_svg(&torsion_plot(rec, cal)?, &TORSION_TEXT)?;
    let mut out = calibration_output(rec, cal, recording_path, truth);
    out.run = extras.timings;
    out.diagnosis = extras.diagnosis;
    if let Some(d) = decided {
        out.apply(d);
    }
    let json = json::to_json_explained(&out)?;
    let md = render_markdown(&out, rec, NORMAL_SVG_FILE, TORSION_SVG_FILE);
    Ok(ReportFiles {
        dir: out_dir.to_path_buf(),
        normal_svg: write(out_dir.join(NORMAL_SVG_FILE), &normal)?,
        torsion_svg: write(out_dir.join(TORSION_SVG_FILE), &torsion)?,
        json: write(out_dir.join(JSON_FILE), &(json + "\n"))?,
        markdown: write(out_dir.join(MARKDOWN_FILE), &md)?,
    })
}

/// The elastomer as the recording declares it, in words: its surface (flat
/// or R1) and its gel layer (thickness, base, tolerance) or a half-space.
pub fn elastomer_words(meta: &sim::recording::Metadata) -> String {
    let surface =
        if meta.elastomer_r_mm.is_infinite() { "flat".to_string() } else { format!("R1 {} mm", meta.elastomer_r_mm) };
    match meta.layer {
        None => format!("{surface}, a half-space (no layer declared)"),
        Some(l) => {
            let tol = l.thickness_tol_mm.map(|t| format!(" ± {t}")).unwrap_or_default();
            let base = match l.base {
                sim::physics::LayerBase::Bonded => "bonded to its window",
                sim::physics::LayerBase::Sliding => "sliding on its window",
            };
            format!("{surface}, a {}{tol} mm gel layer {base}", l.thickness_mm)
        }
    }
}

/// UTC broken down: (year, month, day, hour, minute, second).
pub fn utc_fields(t: SystemTime) -> (i64, u32, u32, u32, u32, u32) {
    let t = time::OffsetDateTime::from(t);
    (
        i64::from(t.year()),
        u32::from(u8::from(t.month())),
        u32::from(t.day()),
        u32::from(t.hour()),
        u32::from(t.minute()),
        u32::from(t.second()),
    )
}

/// `YYYYmmdd-HHMMSS` in UTC.
pub fn utc_stamp(t: SystemTime) -> String {
    let (y, mo, d, h, mi, s) = utc_fields(t);
    format!("{y:04}{mo:02}{d:02}-{h:02}{mi:02}{s:02}")
}

/// RFC 3339 UTC time, e.g. `2026-11-23T11:24:40Z` (for a recording's `created`).
pub fn rfc3339_utc(t: SystemTime) -> String {
    let (y, mo, d, h, mi, s) = utc_fields(t);
    format!("{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}Z")
}

/// The default output folder of a run: `<root>/<YYYYmmdd-HHMMSS>-<sensor>`
/// (UTC). The sensor name is reduced to characters safe in a file name;
/// without one the folder ends in `-sensor`.
pub fn default_run_dir(root: &Path, sensor: Option<&str>, now: SystemTime) -> PathBuf {
    let name: String = sensor
        .unwrap_or("")
        .trim()
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') { c } else { '_' })
        .collect();
    let name = name.trim_matches('.');
    let name = if name.is_empty() { "sensor" } else { name };
    root.join(format!("{}-{}", utc_stamp(now), name))
}

#[cfg(test)]
mod words {
    use sim::physics::{Body, Layer, LayerBase};
    use sim::recording::Metadata;

    #[test]
    fn the_elastomer_is_described_as_declared() {
        let mut meta = Metadata {
            sensor: None,
            indenter: Body::new(1.1, 0.39, 5.0),
            elastomer_r_mm: 33.0,
            layer: None,
            created: None,
            extra: Vec::new(),
        };
        assert_eq!(super::elastomer_words(&meta), "R1 33 mm, a half-space (no layer declared)");
        meta.elastomer_r_mm = f64::INFINITY;
        meta.layer = Some(Layer { thickness_mm: 5.0, base: LayerBase::Bonded, thickness_tol_mm: Some(0.1) });
        assert_eq!(super::elastomer_words(&meta), "flat, a 5 ± 0.1 mm gel layer bonded to its window");
        meta.layer = Some(Layer { thickness_mm: 2.5, base: LayerBase::Sliding, thickness_tol_mm: None });
        assert_eq!(super::elastomer_words(&meta), "flat, a 2.5 mm gel layer sliding on its window");
    }
}
