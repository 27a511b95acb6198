//! Calibration recordings, format v1 (docs/recording-format.md):
//! `# key: value` metadata lines, a CSV header row, then one row per settled
//! sample. The reader rejects anything it cannot take at face value with an
//! error naming the line (and column); nothing is silently dropped. The writer
//! flushes every row, so a run killed mid-way leaves a readable file.

use std::collections::HashSet;
use std::fmt;
use std::io::{self, Write};
use std::path::Path;

use serde::Serialize;

use crate::experiment::Experiment;
use crate::physics::{Body, Layer, LayerBase};

pub const FORMAT_VERSION: u32 = 1;

/// Limits of the reader (docs/recording-format.md, "Limits"): a calibration has a
/// few hundred samples and a dozen metadata lines; these bound the work and memory
/// any file can cause, with room for long logged runs.
pub const MAX_FILE_BYTES: u64 = 64 * 1024 * 1024;
pub const MAX_LINE_BYTES: usize = 4096;
pub const MAX_METADATA_LINES: usize = 1000;
pub const MAX_SAMPLES: usize = 200_000;
/// Plausible indenter: from the softest gel to steel (MPa), radius (mm).
pub const INDENTER_E_RANGE_MPA: [f64; 2] = [1e-3, 1e6];
pub const INDENTER_R_RANGE_MM: [f64; 2] = [0.05, 1000.0];

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    Normal,
    Torsion,
}

impl Phase {
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::Normal => "normal",
            Phase::Torsion => "torsion",
        }
    }
}

/// Direction of travel within a sweep: `load` going in / twisting out, `unload` coming back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    Load,
    Unload,
}

impl Direction {
    pub fn as_str(self) -> &'static str {
        match self {
            Direction::Load => "load",
            Direction::Unload => "unload",
        }
    }
}

/// One settled sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Sample {
    pub t_s: f64,
    pub phase: Phase,
    pub stage_mm: f64,
    pub rot_deg: f64,
    pub gamma1_mm: f64,
    pub theta1_deg: f64,
    pub rep: Option<u32>,
    pub dir: Option<Direction>,
    /// Standard error of `gamma1_mm` as the sensor's estimator reports it
    /// (optional column `gamma1_sd_mm`; docs/recording-format.md), mm.
    pub gamma1_sd_mm: Option<f64>,
    /// Standard error of `theta1_deg` (optional column `theta1_sd_deg`), degrees.
    pub theta1_sd_deg: Option<f64>,
    /// The experiment the sample belongs to, `None` in the standard sweeps; the
    /// `phase` column then names the experiment and `phase` is its kind
    /// ([`Experiment::kind`], docs/recording-format.md).
    pub experiment: Option<Experiment>,
    /// When the reading was taken and how the rig got there (optional
    /// columns; `easycalib run` writes them): what a time-dependent model
    /// of the rig needs to reproduce the reading.
    pub timing: Timing,
}

/// The times behind one sample (rig time, s; optional columns
/// `t_frames_from_s`, `t_move_start_s`, `t_move_end_s`,
/// docs/recording-format.md). The sample's readings are the mean of the
/// frames from `frames_from_s` to `t_s`; the move that brought the rig to
/// its pose ran from `move_s.0` to `move_s.1` (none: the rig did not move
/// since the previous sample).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct Timing {
    pub frames_from_s: Option<f64>,
    pub move_s: Option<(f64, f64)>,
}

impl Timing {
    /// No time is given.
    pub fn is_empty(&self) -> bool {
        self.frames_from_s.is_none() && self.move_s.is_none()
    }
}

impl Sample {
    /// A sample without standard errors or repeat/direction labels.
    pub fn new(t_s: f64, phase: Phase, stage_mm: f64, rot_deg: f64, gamma1_mm: f64, theta1_deg: f64) -> Self {
        Self {
            t_s,
            phase,
            stage_mm,
            rot_deg,
            gamma1_mm,
            theta1_deg,
            rep: None,
            dir: None,
            gamma1_sd_mm: None,
            theta1_sd_deg: None,
            experiment: None,
            timing: Timing::default(),
        }
    }

    /// A sample of `experiment` (its kind is the sample's `phase`).
    pub fn of_experiment(self, experiment: Experiment) -> Self {
        Self { phase: experiment.kind(), experiment: Some(experiment), ..self }
    }

    /// What the `phase` column holds: the experiment's name, or the sweep's.
    pub fn phase_name(&self) -> &'static str {
        self.experiment.map_or(self.phase.as_str(), Experiment::as_str)
    }

    /// A sample of the standard normal or torsion sweep (no experiment).
    pub fn in_sweep(&self) -> bool {
        self.experiment.is_none()
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Metadata {
    pub sensor: Option<String>,
    /// The calibration indenter (E2, nu2, R2).
    pub indenter: Body,
    /// Effective radius R1 of the elastomer, mm (`inf` = flat).
    pub elastomer_r_mm: f64,
    /// The elastomer layer as declared (`elastomer_thickness_mm`, `elastomer_base`,
    /// `elastomer_thickness_tol_mm`); `None` is a half-space.
    pub layer: Option<Layer>,
    pub created: Option<String>,
    /// Keys this version does not know, kept in order.
    pub extra: Vec<(String, String)>,
}

/// Metadata key of the stage zero's standard uncertainty: how well the
/// recorder found the first contact, mm (docs/recording-format.md).
pub const CONTACT_SD_KEY: &str = "contact_sd_mm";

impl Metadata {
    /// The declared uncertainty of the stage zero ([`CONTACT_SD_KEY`]), when
    /// given as a positive number.
    pub fn contact_sd_mm(&self) -> Option<f64> {
        let (_, v) = self.extra.iter().find(|(k, _)| k == CONTACT_SD_KEY)?;
        v.trim().parse::<f64>().ok().filter(|x| x.is_finite() && *x > 0.0)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Recording {
    pub meta: Metadata,
    pub samples: Vec<Sample>,
}

/// What is wrong with a recording, and where (1-based line; column by number and name).
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingError {
    pub line: usize,
    pub column: Option<(usize, String)>,
    pub message: String,
}

impl fmt::Display for RecordingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.column {
            Some((n, name)) => write!(f, "line {}, column {} ({}): {}", self.line, n, name, self.message),
            None if self.line > 0 => write!(f, "line {}: {}", self.line, self.message),
            None => write!(f, "{}", self.message),
        }
    }
}

impl std::error::Error for RecordingError {}

fn err(line: usize, message: impl Into<String>) -> RecordingError {
    RecordingError { line, column: None, message: message.into() }
}

const REQUIRED_COLUMNS: [&str; 6] = ["t_s", "phase", "stage_mm", "rot_deg", "gamma1_mm", "theta1_deg"];

/// The phases this reader knows, as its error for an unknown one says.
const KNOWN: &str = "this reader knows `normal`, `torsion`, `dwell`, `reload`, `reversal`, `torsion2`, `rigid_ball` and `swap_indenter`";

/// The optional per-sample standard errors (docs/recording-format.md).
const SD_COLUMNS: [&str; 2] = ["gamma1_sd_mm", "theta1_sd_deg"];

/// The optional per-sample times ([`Timing`], docs/recording-format.md).
const TIMING_COLUMNS: [&str; 3] = ["t_frames_from_s", "t_move_start_s", "t_move_end_s"];

fn parse_meta_number(line: usize, key: &str, value: &str) -> Result<f64, RecordingError> {
    let v = value.trim();
    let x = if v.eq_ignore_ascii_case("inf") || v.eq_ignore_ascii_case("infinity") {
        f64::INFINITY
    } else {
        v.parse::<f64>().map_err(|_| err(line, format!("`{key}` value `{v}` is not a number")))?
    };
    if x.is_nan() {
        return Err(err(line, format!("`{key}` is NaN")));
    }
    Ok(x)
}

impl Recording {
    pub fn read_path(path: &Path) -> Result<Recording, RecordingError> {
        if let Ok(m) = std::fs::metadata(path)
            && m.len() > MAX_FILE_BYTES
        {
            return Err(err(
                0,
                format!("{} is {} bytes; a recording may hold at most {MAX_FILE_BYTES}", path.display(), m.len()),
            ));
        }
        let bytes = std::fs::read(path).map_err(|e| err(0, format!("cannot read {}: {e}", path.display())))?;
        let text = String::from_utf8(bytes).map_err(|e| {
            let upto = &e.as_bytes()[..e.utf8_error().valid_up_to()];
            let line = upto.iter().filter(|&&b| b == b'\n').count() + 1;
            err(line, "not valid UTF-8 text")
        })?;
        Recording::parse(&text)
    }

    /// Read a recording from its text: the metadata block, the header row, the
    /// sample rows, each checked where it stands.
    pub fn parse(text: &str) -> Result<Recording, RecordingError> {
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim_end_matches('\r')));
        let block = read_metadata(&mut lines)?;
        let (indenter, r1) = block.indenter()?;
        let layer = layer_from_meta(block.thickness, block.base, block.thickness_tol)?;
        let Some((hline, header)) = block.header else {
            return Err(err(block.last_line.max(1), "missing the column header row after the metadata"));
        };
        let columns = Columns::from_header(hline, header)?;
        let samples = read_samples(lines, &columns)?;
        if samples.is_empty() {
            return Err(err(hline, "the recording has a header but no samples"));
        }
        let MetaBlock { sensor, created, extra, .. } = block;
        Ok(Recording { meta: Metadata { sensor, indenter, elastomer_r_mm: r1, layer, created, extra }, samples })
    }

    /// The whole recording as text, exactly as `RecordingWriter` writes it.
    pub fn to_csv_string(&self) -> String {
        let mut buf = Vec::new();
        // Writing to a Vec cannot fail.
        let columns = OptionalColumns {
            standard_errors: self.samples.iter().any(|s| s.gamma1_sd_mm.is_some() || s.theta1_sd_deg.is_some()),
            timing: self.samples.iter().any(|s| !s.timing.is_empty()),
        };
        let writer = RecordingWriter::start(&mut buf, &self.meta, columns);
        if let Ok(mut w) = writer {
            for s in &self.samples {
                let _ = w.append(s);
            }
        }
        String::from_utf8_lossy(&buf).into_owned()
    }

    pub fn write_path(&self, path: &Path) -> io::Result<()> {
        std::fs::write(path, self.to_csv_string())
    }

    /// Every sample of this kind, the experiments' included (what the full model covers).
    pub fn phase(&self, phase: Phase) -> impl Iterator<Item = &Sample> {
        self.samples.iter().filter(move |s| s.phase == phase)
    }

    /// The samples of the standard sweep of this kind only (what the paper's method covers).
    pub fn sweep(&self, phase: Phase) -> impl Iterator<Item = &Sample> {
        self.samples.iter().filter(move |s| s.phase == phase && s.in_sweep())
    }
}

/// The metadata block as read, each value with its line (for errors that
/// name where the offending key stands).
struct MetaBlock<'t> {
    version: Option<(usize, String)>,
    e2: Option<(usize, f64)>,
    nu2: Option<(usize, f64)>,
    r2: Option<(usize, f64)>,
    r1: f64,
    r1_line: usize,
    sensor: Option<String>,
    thickness: Option<(usize, f64)>,
    base: Option<(usize, LayerBase)>,
    thickness_tol: Option<(usize, f64)>,
    created: Option<String>,
    extra: Vec<(String, String)>,
    /// The header row (the first line that is neither blank nor `#`), with its line.
    header: Option<(usize, &'t str)>,
    /// The last line read.
    last_line: usize,
}

/// Reads the `# key: value` lines up to and including the header row.
fn read_metadata<'t>(lines: &mut impl Iterator<Item = (usize, &'t str)>) -> Result<MetaBlock<'t>, RecordingError> {
    let mut m = MetaBlock {
        version: None,
        e2: None,
        nu2: None,
        r2: None,
        r1: f64::INFINITY,
        r1_line: 0,
        sensor: None,
        thickness: None,
        base: None,
        thickness_tol: None,
        created: None,
        extra: Vec::new(),
        header: None,
        last_line: 0,
    };
    let mut seen: HashSet<&str> = HashSet::new();
    let mut meta_lines = 0usize;
    for (n, line) in lines {
        m.last_line = n;
        if line.len() > MAX_LINE_BYTES {
            return Err(err(n, format!("line is {} bytes long; the limit is {MAX_LINE_BYTES}", line.len())));
        }
        if line.trim().is_empty() {
            continue;
        }
        let Some(rest) = line.strip_prefix('#') else {
            m.header = Some((n, line));
            break;
        };
        let Some((key, value)) = rest.split_once(':') else {
            // A plain comment line: allowed, carries no data.
            continue;
        };
        let key = key.trim();
        let value = value.trim();
        meta_lines += 1;
        if meta_lines > MAX_METADATA_LINES {
            return Err(err(n, format!("more than {MAX_METADATA_LINES} metadata lines")));
        }
        if !seen.insert(key) {
            return Err(err(n, format!("metadata key `{key}` appears twice")));
        }
        m.take(n, key, value)?;
    }
    Ok(m)
}

impl MetaBlock<'_> {
    /// Keeps one metadata value (line `n`); numbers and the layer base are parsed here.
    fn take(&mut self, n: usize, key: &str, value: &str) -> Result<(), RecordingError> {
        match key {
            "easycalib-recording" => self.version = Some((n, value.to_string())),
            "indenter_E_MPa" => self.e2 = Some((n, parse_meta_number(n, key, value)?)),
            "indenter_nu" => self.nu2 = Some((n, parse_meta_number(n, key, value)?)),
            "indenter_R_mm" => self.r2 = Some((n, parse_meta_number(n, key, value)?)),
            "elastomer_R_mm" => {
                self.r1 = parse_meta_number(n, key, value)?;
                self.r1_line = n;
            }
            "elastomer_thickness_mm" => self.thickness = Some((n, parse_meta_number(n, key, value)?)),
            "elastomer_thickness_tol_mm" => self.thickness_tol = Some((n, parse_meta_number(n, key, value)?)),
            "elastomer_base" => {
                let b = LayerBase::parse(value)
                    .ok_or_else(|| err(n, format!("elastomer_base must be `bonded` or `sliding`, got `{value}`")))?;
                self.base = Some((n, b));
            }
            "sensor" => self.sensor = Some(value.to_string()),
            "created" => self.created = Some(value.to_string()),
            _ => self.extra.push((key.to_string(), value.to_string())),
        }
        Ok(())
    }

    /// The format version, then the indenter (E2, nu2, R2) and the elastomer
    /// radius R1, each required where the format requires it and in its range.
    fn indenter(&self) -> Result<(Body, f64), RecordingError> {
        let Some((vline, v)) = &self.version else {
            return Err(err(
                1,
                "missing required metadata `# easycalib-recording: 1` (is this an easycalib recording?)",
            ));
        };
        if v.trim() != "1" {
            return Err(err(
                *vline,
                format!("unsupported recording format version `{v}` (this easycalib reads version 1)"),
            ));
        }
        // A missing key has no line of its own: point at where the metadata block ends.
        let meta_end = self.header.map(|(n, _)| n).unwrap_or(self.last_line).max(1);
        let need = |x: Option<(usize, f64)>, key: &str| {
            x.ok_or_else(|| err(meta_end, format!("missing required metadata key `{key}` before the header row")))
        };
        let (e2_line, e2) = need(self.e2, "indenter_E_MPa")?;
        let (nu2_line, nu2) = need(self.nu2, "indenter_nu")?;
        let (r2_line, r2) = need(self.r2, "indenter_R_mm")?;
        let [e_lo, e_hi] = INDENTER_E_RANGE_MPA;
        if !(e_lo..=e_hi).contains(&e2) {
            return Err(err(
                e2_line,
                format!("indenter_E_MPa must lie in [{e_lo}, {e_hi}] MPa (a gel to steel), got {e2}"),
            ));
        }
        if !(nu2 > 0.0 && nu2 < 0.5) {
            return Err(err(nu2_line, format!("indenter_nu must lie in (0, 0.5), got {nu2}")));
        }
        let [r_lo, r_hi] = INDENTER_R_RANGE_MM;
        if !(r_lo..=r_hi).contains(&r2) {
            return Err(err(r2_line, format!("indenter_R_mm must be a radius in [{r_lo}, {r_hi}] mm, got {r2}")));
        }
        let r1 = self.r1;
        if r1 < r_lo {
            return Err(err(self.r1_line, format!("elastomer_R_mm must be at least {r_lo} mm (or inf), got {r1}")));
        }
        Ok((Body::new(e2, nu2, r2), r1))
    }
}

/// Where the columns stand in the header row (any order, extra columns allowed).
struct Columns<'t> {
    names: Vec<&'t str>,
    /// Positions of [`REQUIRED_COLUMNS`], in that order.
    idx: [usize; 6],
    rep: Option<usize>,
    dir: Option<usize>,
    gamma1_sd: Option<usize>,
    theta1_sd: Option<usize>,
    /// Positions of [`TIMING_COLUMNS`] that are present.
    timing: [Option<usize>; 3],
}

impl<'t> Columns<'t> {
    fn from_header(hline: usize, header: &'t str) -> Result<Self, RecordingError> {
        let names: Vec<&str> = header.split(',').map(str::trim).collect();
        let mut idx = [0usize; 6];
        for (k, want) in REQUIRED_COLUMNS.iter().enumerate() {
            let hits: Vec<usize> = names.iter().enumerate().filter(|(_, n)| *n == want).map(|(i, _)| i).collect();
            match hits.as_slice() {
                [i] => idx[k] = *i,
                [] => return Err(err(hline, format!("header row lacks the required column `{want}`"))),
                _ => return Err(err(hline, format!("header row names column `{want}` twice"))),
            }
        }
        let rep = names.iter().position(|n| *n == "rep");
        let dir = names.iter().position(|n| *n == "dir");
        let gamma1_sd = names.iter().position(|n| *n == SD_COLUMNS[0]);
        let theta1_sd = names.iter().position(|n| *n == SD_COLUMNS[1]);
        let timing = TIMING_COLUMNS.map(|want| names.iter().position(|n| *n == want));
        Ok(Columns { names, idx, rep, dir, gamma1_sd, theta1_sd, timing })
    }
}

/// The sample rows after the header, in time order.
fn read_samples<'t>(
    lines: impl Iterator<Item = (usize, &'t str)>,
    columns: &Columns,
) -> Result<Vec<Sample>, RecordingError> {
    let mut samples = Vec::new();
    let mut last_t = f64::NEG_INFINITY;
    for (n, line) in lines {
        if line.len() > MAX_LINE_BYTES {
            return Err(err(n, format!("line is {} bytes long; the limit is {MAX_LINE_BYTES}", line.len())));
        }
        if line.trim().is_empty() {
            continue;
        }
        if samples.len() == MAX_SAMPLES {
            return Err(err(n, format!("more than {MAX_SAMPLES} samples; split the recording")));
        }
        if line.starts_with('#') {
            return Err(err(n, "metadata line after the header row"));
        }
        let s = parse_row(n, line, columns, last_t)?;
        last_t = s.t_s;
        samples.push(s);
    }
    Ok(samples)
}

/// An error at column `i` (0-based) of line `n`.
fn column_err(n: usize, columns: &Columns, i: usize, message: String) -> RecordingError {
    RecordingError { line: n, column: Some((i + 1, columns.names[i].to_string())), message }
}

/// One sample row (line `n`), taken after a row at time `last_t`.
fn parse_row(n: usize, line: &str, columns: &Columns, last_t: f64) -> Result<Sample, RecordingError> {
    let (names, idx) = (&columns.names, &columns.idx);
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    if fields.len() != names.len() {
        return Err(err(
            n,
            format!(
                "expected {} fields as in the header, found {} (truncated or malformed row)",
                names.len(),
                fields.len()
            ),
        ));
    }
    let col_err = |i: usize, msg: String| column_err(n, columns, i, msg);
    let num = |k: usize| -> Result<f64, RecordingError> {
        let i = idx[k];
        let s = fields[i];
        let x: f64 = s.parse().map_err(|_| col_err(i, format!("`{s}` is not a number")))?;
        if !x.is_finite() {
            return Err(col_err(i, format!("`{s}` is not a finite number")));
        }
        Ok(x)
    };
    let t_s = num(0)?;
    let (phase, experiment) = match fields[idx[1]] {
        "normal" => (Phase::Normal, None),
        "torsion" => (Phase::Torsion, None),
        other => {
            let e = Experiment::parse(other)
                .ok_or_else(|| col_err(idx[1], format!("unknown phase `{other}` ({KNOWN})")))?;
            (e.kind(), Some(e))
        }
    };
    let stage_mm = num(2)?;
    let rot_deg = num(3)?;
    let gamma1_mm = num(4)?;
    let theta1_deg = num(5)?;
    if t_s < last_t {
        return Err(col_err(
            idx[0],
            format!("time {t_s} s goes backwards (previous row {last_t} s); rows must be in time order"),
        ));
    }
    let rep = match columns.rep {
        Some(i) if !fields[i].is_empty() => {
            Some(fields[i].parse::<u32>().map_err(|_| col_err(i, format!("`{}` is not a repeat index", fields[i])))?)
        }
        _ => None,
    };
    let dir = match columns.dir {
        Some(i) => match fields[i] {
            "" => None,
            "load" => Some(Direction::Load),
            "unload" => Some(Direction::Unload),
            other => {
                return Err(col_err(i, format!("unknown direction `{other}` (expected `load` or `unload`)")));
            }
        },
        None => None,
    };
    // A standard error is optional per row (empty), but when given it is a
    // positive finite number: zero would give the sample infinite weight.
    let sd = |col: Option<usize>| -> Result<Option<f64>, RecordingError> {
        let Some(i) = col.filter(|&i| !fields[i].is_empty()) else { return Ok(None) };
        let s = fields[i];
        match s.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => Ok(Some(x)),
            _ => Err(col_err(i, format!("`{s}` is not a standard error (a positive finite number, or empty)"))),
        }
    };
    let gamma1_sd_mm = sd(columns.gamma1_sd)?;
    let theta1_sd_deg = sd(columns.theta1_sd)?;
    let timing = parse_timing(fields.as_slice(), columns, t_s, &col_err)?;
    let sample = Sample::new(t_s, phase, stage_mm, rot_deg, gamma1_mm, theta1_deg);
    Ok(Sample { rep, dir, gamma1_sd_mm, theta1_sd_deg, experiment, timing, ..sample })
}

/// The optional times of one row: each empty or a finite time no later than
/// the sample's own; a move's end not before its start, and a move is
/// given whole (both ends) or not at all.
fn parse_timing(
    fields: &[&str],
    columns: &Columns,
    t_s: f64,
    col_err: &dyn Fn(usize, String) -> RecordingError,
) -> Result<Timing, RecordingError> {
    let time = |k: usize| -> Result<Option<(usize, f64)>, RecordingError> {
        let Some(i) = columns.timing[k].filter(|&i| !fields[i].is_empty()) else { return Ok(None) };
        let s = fields[i];
        match s.parse::<f64>() {
            Ok(x) if x.is_finite() && x <= t_s => Ok(Some((i, x))),
            Ok(x) if x.is_finite() => Err(col_err(
                i,
                format!("time {x} s is after the sample's own t_s {t_s} s (the sample ends its frames)"),
            )),
            _ => Err(col_err(i, format!("`{s}` is not a time (a finite number of seconds, or empty)"))),
        }
    };
    let frames_from_s = time(0)?.map(|(_, x)| x);
    let move_s = match (time(1)?, time(2)?) {
        (None, None) => None,
        (Some((_, a)), Some((i, b))) if b < a => {
            return Err(col_err(i, format!("the move ends at {b} s, before it starts ({a} s)")));
        }
        (Some((_, a)), Some((_, b))) => Some((a, b)),
        (Some((i, _)), None) | (None, Some((i, _))) => {
            return Err(col_err(i, "a move needs both t_move_start_s and t_move_end_s (or neither)".to_string()));
        }
    };
    Ok(Timing { frames_from_s, move_s })
}

/// The declared layer from its three keys: a base or a tolerance without a
/// thickness is an error (it would silently describe a half-space).
fn layer_from_meta(
    thickness: Option<(usize, f64)>,
    base: Option<(usize, LayerBase)>,
    tol: Option<(usize, f64)>,
) -> Result<Option<Layer>, RecordingError> {
    let Some((h_line, h)) = thickness else {
        if let Some((n, _)) = base {
            return Err(err(n, "elastomer_base is given without elastomer_thickness_mm"));
        }
        if let Some((n, _)) = tol {
            return Err(err(n, "elastomer_thickness_tol_mm is given without elastomer_thickness_mm"));
        }
        return Ok(None);
    };
    if !(h.is_finite() && h > 0.0) {
        return Err(err(h_line, format!("elastomer_thickness_mm must be a finite thickness > 0, got {h}")));
    }
    let layer = Layer {
        thickness_mm: h,
        base: base.map_or(LayerBase::Bonded, |(_, b)| b),
        thickness_tol_mm: tol.map(|(_, t)| t),
    };
    if let Some((n, t)) = tol
        && layer.validate().is_err()
    {
        return Err(err(n, format!("elastomer_thickness_tol_mm must be >= 0 and below the thickness, got {t}")));
    }
    Ok(Some(layer))
}

fn fmt_radius(r: f64) -> String {
    if r.is_infinite() { "inf".to_string() } else { format!("{r}") }
}

/// Appends samples to a recording as they are taken, flushing each row.
pub struct RecordingWriter<W: Write> {
    out: W,
    columns: OptionalColumns,
}

/// Which optional columns a writer's header names.
#[derive(Debug, Clone, Copy, Default)]
struct OptionalColumns {
    /// `gamma1_sd_mm`, `theta1_sd_deg`.
    standard_errors: bool,
    /// `t_frames_from_s`, `t_move_start_s`, `t_move_end_s`.
    timing: bool,
}

impl<W: Write> RecordingWriter<W> {
    /// Writes the metadata block and the header row.
    pub fn new(out: W, meta: &Metadata) -> io::Result<Self> {
        Self::start(out, meta, OptionalColumns::default())
    }

    /// As [`RecordingWriter::new`], with the optional standard-error columns
    /// `gamma1_sd_mm` and `theta1_sd_deg` (empty for a sample without them).
    pub fn with_standard_errors(out: W, meta: &Metadata) -> io::Result<Self> {
        Self::start(out, meta, OptionalColumns { standard_errors: true, timing: false })
    }

    /// What a rig writes: the standard errors and the sample's times
    /// ([`Timing`]; empty where a sample has none).
    pub fn for_rig(out: W, meta: &Metadata) -> io::Result<Self> {
        Self::start(out, meta, OptionalColumns { standard_errors: true, timing: true })
    }

    fn start(mut out: W, meta: &Metadata, columns: OptionalColumns) -> io::Result<Self> {
        writeln!(out, "# easycalib-recording: {FORMAT_VERSION}")?;
        if let Some(s) = &meta.sensor {
            writeln!(out, "# sensor: {s}")?;
        }
        writeln!(out, "# indenter_E_MPa: {}", meta.indenter.e_mpa)?;
        writeln!(out, "# indenter_nu: {}", meta.indenter.nu)?;
        writeln!(out, "# indenter_R_mm: {}", fmt_radius(meta.indenter.r_mm))?;
        writeln!(out, "# elastomer_R_mm: {}", fmt_radius(meta.elastomer_r_mm))?;
        if let Some(l) = &meta.layer {
            writeln!(out, "# elastomer_thickness_mm: {}", l.thickness_mm)?;
            writeln!(out, "# elastomer_base: {}", l.base.as_str())?;
            if let Some(t) = l.thickness_tol_mm {
                writeln!(out, "# elastomer_thickness_tol_mm: {t}")?;
            }
        }
        if let Some(c) = &meta.created {
            writeln!(out, "# created: {c}")?;
        }
        for (k, v) in &meta.extra {
            writeln!(out, "# {k}: {v}")?;
        }
        write!(out, "t_s,phase,stage_mm,rot_deg,gamma1_mm,theta1_deg,rep,dir")?;
        if columns.standard_errors {
            write!(out, ",{},{}", SD_COLUMNS[0], SD_COLUMNS[1])?;
        }
        if columns.timing {
            write!(out, ",{}", TIMING_COLUMNS.join(","))?;
        }
        writeln!(out)?;
        out.flush()?;
        Ok(Self { out, columns })
    }

    /// Appends one row and flushes it. Non-finite values are refused, not written.
    pub fn append(&mut self, s: &Sample) -> io::Result<()> {
        for (name, v) in [
            ("t_s", s.t_s),
            ("stage_mm", s.stage_mm),
            ("rot_deg", s.rot_deg),
            ("gamma1_mm", s.gamma1_mm),
            ("theta1_deg", s.theta1_deg),
        ] {
            if !v.is_finite() {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("refusing to record non-finite {name} = {v}"),
                ));
            }
        }
        for (name, v) in [("gamma1_sd_mm", s.gamma1_sd_mm), ("theta1_sd_deg", s.theta1_sd_deg)] {
            if v.is_some_and(|v| !(v.is_finite() && v > 0.0)) {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("refusing to record {name} = {v:?}: not a positive finite number"),
                ));
            }
        }
        let times = [s.timing.frames_from_s, s.timing.move_s.map(|m| m.0), s.timing.move_s.map(|m| m.1)];
        for (name, v) in TIMING_COLUMNS.iter().zip(times) {
            if v.is_some_and(|v| !(v.is_finite() && v <= s.t_s)) {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("refusing to record {name} = {v:?}: not a finite time at or before t_s = {}", s.t_s),
                ));
            }
        }
        let rep = s.rep.map(|r| r.to_string()).unwrap_or_default();
        let dir = s.dir.map(Direction::as_str).unwrap_or("");
        write!(
            self.out,
            "{:.3},{},{:.4},{:.3},{:.5},{:.5},{},{}",
            s.t_s,
            s.phase_name(),
            s.stage_mm,
            s.rot_deg,
            s.gamma1_mm,
            s.theta1_deg,
            rep,
            dir
        )?;
        if self.columns.standard_errors {
            // Two significant digits at least, however small the error.
            let sd = |v: Option<f64>| v.map(|v| format!("{v:.3e}")).unwrap_or_default();
            write!(self.out, ",{},{}", sd(s.gamma1_sd_mm), sd(s.theta1_sd_deg))?;
        }
        if self.columns.timing {
            let time = |v: Option<f64>| v.map(|v| format!("{v:.3}")).unwrap_or_default();
            let (a, b) = (s.timing.move_s.map(|m| m.0), s.timing.move_s.map(|m| m.1));
            write!(self.out, ",{},{},{}", time(s.timing.frames_from_s), time(a), time(b))?;
        }
        writeln!(self.out)?;
        self.out.flush()
    }

    pub fn into_inner(self) -> W {
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "# easycalib-recording: 1\n# sensor: tac3d-SN0042\n# indenter_E_MPa: 2.0\n# indenter_nu: 0.40\n# indenter_R_mm: 5.0\n# elastomer_R_mm: inf\n# created: 2026-11-22T09:30:00Z\n# lab_note: kept\nt_s,phase,stage_mm,rot_deg,gamma1_mm,theta1_deg\n0.00,normal,0.000,0.000,0.0000,0.0000\n0.80,normal,0.050,0.000,0.0171,0.0000\n31.20,torsion,1.450,0.500,1.0,0.1602\n";

    #[test]
    fn sample_times_are_optional_per_row_checked_and_round_trip() {
        let text = GOOD
            .replace("theta1_deg\n", "theta1_deg,t_frames_from_s,t_move_start_s,t_move_end_s\n")
            .replace("0.0000,0.0000\n", "0.0000,0.0000,,,\n")
            .replace("0.0171,0.0000\n", "0.0171,0.0000,0.70,0.00,0.45\n")
            .replace("1.0,0.1602\n", "1.0,0.1602,30.9,,\n");
        let r = Recording::parse(&text).unwrap();
        let times: Vec<Timing> = r.samples.iter().map(|s| s.timing).collect();
        assert_eq!(
            times,
            vec![
                Timing::default(),
                Timing { frames_from_s: Some(0.70), move_s: Some((0.0, 0.45)) },
                Timing { frames_from_s: Some(30.9), move_s: None },
            ]
        );
        let written = r.to_csv_string();
        assert!(written.contains(",t_frames_from_s,t_move_start_s,t_move_end_s\n"), "{written}");
        assert_eq!(Recording::parse(&written).unwrap().samples, r.samples);
        // A time after the sample's own, a move that ends before it starts, half a
        // move, or a non-number: an error naming the line and the column.
        let row = "0.0171,0.0000,0.70,0.00,0.45";
        for (bad, column) in [
            ("0.0171,0.0000,0.90,0.00,0.45", "t_frames_from_s"),
            ("0.0171,0.0000,0.70,0.50,0.45", "t_move_end_s"),
            ("0.0171,0.0000,0.70,,0.45", "t_move_end_s"),
            ("0.0171,0.0000,0.70,0.00,", "t_move_start_s"),
            ("0.0171,0.0000,x,0.00,0.45", "t_frames_from_s"),
            ("0.0171,0.0000,0.70,NaN,0.45", "t_move_start_s"),
        ] {
            let e = error_of(&text.replace(row, bad));
            assert_eq!((e.line, e.column.clone().map(|c| c.1)), (11, Some(column.to_string())), "{bad}: {e}");
        }
        // The writer refuses a time after the sample's own.
        let mut late = r.samples[1];
        late.timing.frames_from_s = Some(late.t_s + 1.0);
        let mut w = RecordingWriter::for_rig(Vec::new(), &r.meta).unwrap();
        assert!(w.append(&late).is_err());
        // Without any time the writer keeps the six-plus-two columns.
        assert!(Recording::parse(GOOD).unwrap().to_csv_string().contains("theta1_deg,rep,dir\n"));
    }

    #[test]
    fn reads_and_writes_the_declared_layer() {
        let with = |extra: &str| GOOD.replace("# created:", &format!("{extra}# created:"));
        let r = Recording::parse(&with("# elastomer_thickness_mm: 5.0\n# elastomer_base: bonded\n")).unwrap();
        assert_eq!(r.meta.layer, Some(Layer::bonded(5.0)));
        let r = Recording::parse(&with(
            "# elastomer_thickness_mm: 3\n# elastomer_base: sliding\n# elastomer_thickness_tol_mm: 0.1\n",
        ))
        .unwrap();
        let l = r.meta.layer.unwrap();
        assert_eq!((l.thickness_mm, l.base, l.thickness_tol_mm), (3.0, LayerBase::Sliding, Some(0.1)));
        // Round trip through the writer keeps the layer.
        assert_eq!(Recording::parse(&r.to_csv_string()).unwrap().meta.layer, Some(l));
        // A thickness alone is a bonded layer; none at all is a half-space.
        assert_eq!(
            Recording::parse(&with("# elastomer_thickness_mm: 4\n")).unwrap().meta.layer,
            Some(Layer::bonded(4.0))
        );
        assert_eq!(Recording::parse(GOOD).unwrap().meta.layer, None);
        for (bad, line, what) in [
            ("# elastomer_thickness_mm: 0\n", 7, "thickness"),
            ("# elastomer_thickness_mm: -2\n", 7, "thickness"),
            ("# elastomer_thickness_mm: inf\n", 7, "thickness"),
            ("# elastomer_thickness_mm: 5\n# elastomer_base: glued\n", 8, "bonded"),
            ("# elastomer_base: bonded\n", 7, "without"),
            ("# elastomer_thickness_tol_mm: 0.1\n", 7, "without"),
            ("# elastomer_thickness_mm: 5\n# elastomer_thickness_tol_mm: 6\n", 8, "below the thickness"),
        ] {
            let e = Recording::parse(&with(bad)).unwrap_err();
            assert_eq!(e.line, line, "{bad}: {e}");
            assert!(e.message.contains(what), "{bad}: {e}");
        }
    }

    #[test]
    fn reads_the_documented_example() {
        let r = Recording::parse(GOOD).unwrap();
        assert_eq!(r.samples.len(), 3);
        assert_eq!(r.meta.indenter, Body::new(2.0, 0.4, 5.0));
        assert!(r.meta.elastomer_r_mm.is_infinite());
        assert_eq!(r.meta.sensor.as_deref(), Some("tac3d-SN0042"));
        assert_eq!(r.meta.extra, vec![("lab_note".to_string(), "kept".to_string())]);
        assert_eq!(r.samples[2].phase, Phase::Torsion);
        assert_eq!(r.samples[2].theta1_deg, 0.1602);
    }

    #[test]
    fn experiment_phases_read_as_their_kind_and_round_trip() {
        let text = GOOD.replace(
            "31.20,torsion,1.450,0.500,1.0,0.1602\n",
            "31.20,torsion,1.450,0.500,1.0,0.1602\n32.0,dwell,1.450,0.0,1.01,0\n33.0,reload,1.2,0.0,0.8,0\n\
             34.0,reversal,1.450,-0.5,1.0,-0.16\n35.0,torsion2,0.9,0.5,0.6,0.2\n",
        );
        let r = Recording::parse(&text).unwrap();
        let got: Vec<(Phase, Option<Experiment>)> = r.samples.iter().map(|s| (s.phase, s.experiment)).collect();
        use Experiment::*;
        assert_eq!(
            &got[3..],
            &[
                (Phase::Normal, Some(Dwell)),
                (Phase::Normal, Some(Reload)),
                (Phase::Torsion, Some(Reversal)),
                (Phase::Torsion, Some(Torsion2))
            ]
        );
        assert_eq!(r.phase(Phase::Torsion).count(), 3);
        assert_eq!(r.sweep(Phase::Torsion).count(), 1);
        let back = Recording::parse(&r.to_csv_string()).unwrap();
        assert_eq!(back.samples, r.samples);
        assert!(r.to_csv_string().contains(",torsion2,"));
    }

    #[test]
    fn columns_in_any_order_with_extras() {
        let text = "# easycalib-recording: 1\n# indenter_E_MPa: 2\n# indenter_nu: 0.4\n# indenter_R_mm: 5\nphase,extra,gamma1_mm,t_s,theta1_deg,rot_deg,stage_mm,dir\nnormal,x,0.1,0,0,0,0.2,load\n";
        let r = Recording::parse(text).unwrap();
        assert_eq!(r.samples[0].gamma1_mm, 0.1);
        assert_eq!(r.samples[0].stage_mm, 0.2);
        assert_eq!(r.samples[0].dir, Some(Direction::Load));
    }

    #[test]
    fn write_then_read_round_trips() {
        let r = Recording::parse(GOOD).unwrap();
        let text = r.to_csv_string();
        let back = Recording::parse(&text).unwrap();
        assert_eq!(back.samples, r.samples);
        assert_eq!(back.meta, r.meta);
    }

    #[test]
    fn standard_error_columns_are_optional_per_row_and_round_trip() {
        let text = GOOD
            .replace("theta1_deg\n", "theta1_deg,gamma1_sd_mm,theta1_sd_deg\n")
            .replace("0.0171,0.0000\n", "0.0171,0.0000,0.0021,\n")
            .replace("0.0000,0.0000\n", "0.0000,0.0000,,\n")
            .replace("1.0,0.1602\n", "1.0,0.1602,0.0015,0.0008\n");
        let r = Recording::parse(&text).unwrap();
        let sds: Vec<_> = r.samples.iter().map(|s| (s.gamma1_sd_mm, s.theta1_sd_deg)).collect();
        assert_eq!(sds, vec![(None, None), (Some(0.0021), None), (Some(0.0015), Some(0.0008))]);
        let back = Recording::parse(&r.to_csv_string()).unwrap();
        assert_eq!(back.samples, r.samples);
        // Zero, negative or non-numeric errors name the line and the column.
        for bad in ["0", "-0.002", "x", "inf"] {
            let e = error_of(&text.replace("0.0171,0.0000,0.0021,", &format!("0.0171,0.0000,{bad},")));
            assert_eq!((e.line, e.column.clone().map(|c| c.1)), (11, Some("gamma1_sd_mm".to_string())), "{e}");
        }
        // Without any error the writer keeps the six-plus-two columns.
        assert!(Recording::parse(GOOD).unwrap().to_csv_string().contains("theta1_deg,rep,dir\n"));
    }

    fn error_of(text: &str) -> RecordingError {
        Recording::parse(text).expect_err("must be rejected")
    }

    #[test]
    fn every_bad_input_names_line_and_column() {
        let e = error_of(&GOOD.replace("# indenter_nu: 0.40\n", ""));
        assert!(e.message.contains("indenter_nu"), "{e}");
        let e = error_of(&GOOD.replace("0.80,normal,0.050", "0.80,normal,0.0x0"));
        assert_eq!((e.line, e.column.clone()), (11, Some((3, "stage_mm".to_string()))), "{e}");
        let e = error_of(&GOOD.replace("0.0171", "NaN"));
        assert_eq!((e.line, e.column.clone().map(|c| c.1)), (11, Some("gamma1_mm".to_string())), "{e}");
        let e = error_of(&GOOD.replace("0.0171", "inf"));
        assert!(e.message.contains("finite"), "{e}");
        let e = error_of(&GOOD.replace("31.20,torsion", "31.20,twist"));
        assert_eq!(e.line, 12);
        assert!(e.message.contains("unknown phase `twist`"), "{e}");
        assert_eq!(e.column.clone().map(|c| c.1), Some("phase".to_string()));
        let e = error_of(&GOOD.replace("indenter_E_MPa: 2.0", "indenter_E_MPa: -2.0"));
        assert_eq!(e.line, 3, "{e}");
        let e = error_of(&GOOD.replace("indenter_nu: 0.40", "indenter_nu: 0.6"));
        assert_eq!(e.line, 4, "{e}");
        let e = error_of(&GOOD.replace("indenter_nu: 0.40", "indenter_nu: abc"));
        assert_eq!(e.line, 4, "{e}");
        let e = error_of(&GOOD.replace("indenter_R_mm: 5.0", "indenter_R_mm: 0"));
        assert_eq!(e.line, 5, "{e}");
        let e = error_of(&GOOD.replace("elastomer_R_mm: inf", "elastomer_R_mm: -3"));
        assert_eq!(e.line, 6, "{e}");
        let e = error_of(&GOOD.replace("# easycalib-recording: 1\n", ""));
        assert!(e.message.contains("easycalib-recording"), "{e}");
        let e = error_of(&GOOD.replace("easycalib-recording: 1", "easycalib-recording: 7"));
        assert!(e.message.contains("version"), "{e}");
        // Truncated mid-row: the last line lost its tail.
        let cut = &GOOD[..GOOD.len() - 12];
        let e = error_of(cut);
        assert_eq!(e.line, 12, "{e}");
        assert!(e.message.contains("truncated"), "{e}");
        let e = error_of(&GOOD.replace(",theta1_deg\n", ",theta_deg\n"));
        assert!(e.message.contains("theta1_deg"), "{e}");
        let e = error_of(&GOOD.replace("31.20,torsion", "0.10,torsion"));
        assert!(e.message.contains("backwards"), "{e}");
        let header_only: String = GOOD.lines().take(9).map(|l| format!("{l}\n")).collect();
        let e = error_of(&header_only);
        assert!(e.message.contains("no samples"), "{e}");
        let e = error_of("");
        assert!(e.message.contains("easycalib-recording"), "{e}");
        let e = error_of(&GOOD.replace("# sensor: tac3d-SN0042\n", "# sensor: a\n# sensor: b\n"));
        assert!(e.message.contains("twice"), "{e}");
    }

    #[test]
    fn writer_refuses_non_finite_and_flushes_each_row() {
        let meta = Recording::parse(GOOD).unwrap().meta;
        let mut w = RecordingWriter::new(Vec::new(), &meta).unwrap();
        let s = Sample {
            t_s: 0.0,
            phase: Phase::Normal,
            stage_mm: 0.1,
            rot_deg: 0.0,
            gamma1_mm: f64::NAN,
            theta1_deg: 0.0,
            rep: None,
            dir: None,
            gamma1_sd_mm: None,
            theta1_sd_deg: None,
            experiment: None,
            timing: Default::default(),
        };
        assert!(w.append(&s).is_err());
        let ok = Sample { gamma1_mm: 0.05, ..s };
        w.append(&ok).unwrap();
        let text = String::from_utf8(w.into_inner()).unwrap();
        let r = Recording::parse(&text).unwrap();
        assert_eq!(r.samples.len(), 1);
    }
}
