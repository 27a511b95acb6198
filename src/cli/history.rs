//! `easycalib history`, and the history write at the end of `run` and of
//! `fit --record` / `diagnose --record` (docs/history.md). A history that
//! cannot be written never fails the command: the result is queued locally.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};
use history::change::{self, Assessment, Quantity, Settings, Trend};
use history::queue::Queue;
use history::{CalibrationRecord, EffectRecord, ErrorKind, Indenter, Recorded, Source, Target, WarningRecord};
use sim::recording::Recording;

use super::CliError;

#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct HistoryArgs {
    #[command(subcommand)]
    pub command: Option<HistoryCommand>,
    /// The sensor whose calibrations to show (all sensors when omitted).
    pub sensor: Option<String>,
    /// Print JSON instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Plot the sensor's E1 and nu1 with their intervals over time (SVG).
    #[arg(long, value_name = "OUT.svg", requires = "sensor")]
    pub plot: Option<PathBuf>,
    #[command(flatten)]
    pub db: DbArg,
}

#[derive(Debug, Subcommand)]
pub enum HistoryCommand {
    /// Take existing run folders (recording.csv + report.json) into the history.
    Import {
        /// Run folders, or folders of run folders (one level down).
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
    },
    /// Write every calibration as CSV.
    Export {
        /// CSV (the one format).
        #[arg(long, required = true)]
        csv: bool,
        /// Output file (default: stdout).
        #[arg(short = 'o', long)]
        output: Option<PathBuf>,
    },
    /// Deliver the results queued while the database could not be reached.
    Sync,
}

/// Where the history is: `--db`, else `EASYCALIB_DB`, else the platform's data folder.
#[derive(Debug, Clone, Default, Args)]
pub struct DbArg {
    /// History database: a SQLite file or a postgres://user@host/db URL
    /// (default: history.sqlite in the platform's data folder, or in EASYCALIB_HOME).
    #[arg(long, env = "EASYCALIB_DB", value_name = "PATH|URL", global = true)]
    pub db: Option<String>,
    /// The rig's repeatability between calibrations, percent of the value (a
    /// floor under the history's own estimate; it alone counts until a sensor
    /// has 4 calibrations). Default 0: the fits' intervals only.
    #[arg(long, env = "EASYCALIB_REPEATABILITY_PCT", value_name = "PCT", global = true)]
    pub repeatability_pct: Option<f64>,
}

impl DbArg {
    /// The change test's settings, with the repeatability floor given.
    pub fn settings(&self) -> Settings {
        let floor = self.repeatability_pct.filter(|p| p.is_finite() && *p > 0.0).map_or(0.0, |p| p / 100.0);
        Settings { repeatability_floor: [floor, floor], ..Settings::default() }
    }

    pub fn target(&self) -> Target {
        match &self.db {
            Some(s) => Target::parse(s),
            None => Target::Sqlite(home().join("history.sqlite")),
        }
    }
}

/// easycalib's own folder: `EASYCALIB_HOME`, else `<data dir>/easycalib`.
pub fn home() -> PathBuf {
    match std::env::var_os("EASYCALIB_HOME") {
        Some(h) if !h.is_empty() => PathBuf::from(h),
        _ => dirs::data_dir().unwrap_or_else(|| PathBuf::from(".")).join("easycalib"),
    }
}

/// Results waiting for an unreachable database.
pub fn queue() -> Queue {
    Queue::at(&home().join("queue"))
}

/// What a command knows about the calibration it made.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub source: Source,
    pub model: String,
    pub e1_mpa: f64,
    pub e1_ci95: [f64; 2],
    pub nu1: f64,
    pub nu1_ci95: [f64; 2],
    pub effects: Vec<EffectRecord>,
    pub warnings: Vec<WarningRecord>,
    pub rig: Option<String>,
    pub script: Option<String>,
}

/// What the history keeps of a fit.
pub fn outcome_of_fit(out: &crate::report::CalibrationOutput, source: Source) -> Outcome {
    Outcome {
        source,
        model: out.full.model.to_string(),
        e1_mpa: out.e1_mpa,
        e1_ci95: out.ci95.e1_mpa,
        nu1: out.nu1,
        nu1_ci95: out.ci95.nu1,
        effects: vec![],
        warnings: warning_records(&out.warnings),
        rig: None,
        script: None,
    }
}

/// The warnings of a fit or a diagnosis as the history keeps them.
pub(super) fn warning_records(warnings: &[crate::fit::Warning]) -> Vec<WarningRecord> {
    warnings.iter().map(|w| WarningRecord { code: w.code.into(), message: w.message.clone() }).collect()
}

fn finite(ci: [f64; 2]) -> Option<[f64; 2]> {
    (ci[0].is_finite() && ci[1].is_finite() && ci[0] <= ci[1]).then_some(ci)
}

/// The record of a calibration of `rec` (read from `path`, whose bytes are `bytes`).
pub fn make_record(path: &Path, bytes: &[u8], rec: &Recording, o: Outcome) -> CalibrationRecord {
    let time_unix_s = rec
        .meta
        .created
        .as_deref()
        .and_then(history::record::parse_rfc3339)
        .or_else(|| {
            let m = std::fs::metadata(path).and_then(|m| m.modified()).ok()?;
            Some(m.duration_since(std::time::UNIX_EPOCH).ok()?.as_secs_f64())
        })
        .unwrap_or(0.0);
    let ind = rec.meta.indenter;
    CalibrationRecord {
        sensor: rec.meta.sensor.clone().filter(|s| !s.trim().is_empty()).unwrap_or_else(|| "unknown".into()),
        time_utc: history::record::format_rfc3339(time_unix_s),
        time_unix_s,
        source: o.source,
        rig: o.rig,
        indenter: Indenter { e_mpa: ind.e_mpa, nu: ind.nu, r_mm: ind.r_mm },
        script: o.script,
        model: o.model,
        e1_mpa: o.e1_mpa,
        e1_ci95: finite(o.e1_ci95),
        nu1: o.nu1,
        nu1_ci95: finite(o.nu1_ci95),
        effects: o.effects,
        warnings: o.warnings,
        software_version: env!("CARGO_PKG_VERSION").to_string(),
        recording_path: Some(std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()).display().to_string()),
        recording_sha256: history::sha256_hex(bytes),
    }
}

/// Write a calibration to the history, or queue it when the database cannot
/// take it. Returns the lines to show the user (what happened, and whether the
/// sensor changed); never fails.
pub fn record(db: &DbArg, path: &Path, rec: &Recording, outcome: Outcome) -> Vec<String> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) => return vec![format!("history: not recorded: cannot read {}: {e}", path.display())],
    };
    let record = make_record(path, &bytes, rec, outcome);
    let target = db.target();
    let written = history::open(&target).and_then(|mut s| Ok((s.record(&record, &bytes)?, s)));
    match written {
        Ok((status, mut store)) => {
            let mut lines = vec![format!(
                "history: {} in {}",
                if status == Recorded::New { "recorded" } else { "already recorded" },
                store.describe()
            )];
            match store.list(Some(&record.sensor)) {
                Ok(rows) => lines.extend(verdict_lines(&rows, &record, &db.settings())),
                Err(e) => lines.push(format!("history: cannot read the sensor's history back: {e}")),
            }
            lines
        }
        Err(e) if e.kind() == ErrorKind::Invalid => vec![format!("history: not recorded: {e}")],
        Err(e) => match queue().push(&record, &bytes) {
            Ok(p) => vec![
                format!("history: {e}"),
                format!(
                    "history: the result is queued in {}; `easycalib history sync` delivers it",
                    p.parent().unwrap_or(Path::new(".")).display()
                ),
            ],
            Err(q) => vec![format!("history: {e}"), format!("history: and it could not be queued: {q}")],
        },
    }
}

/// The change verdict of `new` against the sensor's earlier calibrations, and the trend.
fn verdict_lines(rows: &[CalibrationRecord], new: &CalibrationRecord, settings: &Settings) -> Vec<String> {
    let series = change::series(rows, &new.sensor, &new.model);
    let mut lines = vec![];
    let Some(k) = series.iter().position(|r| r.recording_sha256 == new.recording_sha256) else { return lines };
    let a = change::assess(&series, k, settings);
    lines.push(format!("history: {} — calibration {} of {} ({} model)", new.sensor, k + 1, series.len(), new.model));
    if a.e1.is_none() && a.nu1.is_none() {
        lines.push("history: the first calibration with intervals: nothing to compare with yet".into());
    }
    for v in [&a.e1, &a.nu1].into_iter().flatten() {
        lines.push(format!(
            "  {:<3} {:+.2} % against the {} before (z step {:+.2}{}; repeatability {:.3} %): {}",
            v.quantity.label(),
            v.change_pct,
            v.n_reference,
            v.z_step,
            v.z_trend.map_or(String::new(), |z| format!(", z trend {z:+.2}")),
            100.0 * v.repeatability_sd / v.reference.abs(),
            if v.alarm { "CHANGED beyond the repeatability" } else { "no change beyond the repeatability" }
        ));
    }
    if a.alarm {
        lines.push(format!(
            "  CHANGE: |z| > {:.2} (false-alarm rate {:.1} % per calibration); recalibrate the sensor's model",
            a.z_critical,
            100.0 * a.false_alarm_rate
        ));
    }
    for t in [Quantity::E1, Quantity::Nu1].iter().filter_map(|&q| change::trend(&series[..=k], q, settings)) {
        lines.push(trend_line(&t));
    }
    lines
}

fn trend_line(t: &Trend) -> String {
    format!(
        "  trend {:<3} {:+.3} %/month [{:+.3}, {:+.3}] over {} calibrations, {:.0} days",
        t.quantity.label(),
        t.rate_pct_per_month,
        t.rate_pct_ci95[0],
        t.rate_pct_ci95[1],
        t.n,
        t.span_days
    )
}

pub fn run(args: &HistoryArgs) -> Result<(), CliError> {
    let target = args.db.target();
    match &args.command {
        Some(HistoryCommand::Sync) => sync(&target),
        Some(HistoryCommand::Import { dirs }) => import(&target, dirs),
        Some(HistoryCommand::Export { output, .. }) => export(&target, output.as_deref()),
        None => list(&target, args),
    }
}

fn open(target: &Target) -> Result<Box<dyn history::Store>, CliError> {
    history::open(target).map_err(|e| CliError::other(e.to_string()))
}

fn sync(target: &Target) -> Result<(), CliError> {
    let q = queue();
    let pending = q.pending().map_err(|e| CliError::other(e.to_string()))?;
    if pending.is_empty() {
        println!("history sync: nothing queued in {}", q.dir().display());
        return Ok(());
    }
    let mut store = open(target)?;
    let r = q.sync(store.as_mut()).map_err(|e| CliError::other(e.to_string()))?;
    println!(
        "history sync: {} delivered, {} already there, {} failed, to {}",
        r.delivered,
        r.already_present,
        r.failed.len(),
        store.describe()
    );
    for (p, e) in &r.failed {
        eprintln!("  {}: {e}", p.display());
    }
    if r.failed.is_empty() {
        Ok(())
    } else {
        Err(CliError::other(format!("{} queued results stay queued", r.failed.len())))
    }
}

/// A run folder's record, from its recording and the report the run wrote.
fn import_one(dir: &Path) -> Result<(CalibrationRecord, Vec<u8>), String> {
    let path = dir.join("recording.csv");
    let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let rec = Recording::read_path(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let report = dir.join(crate::report::JSON_FILE);
    let text = std::fs::read_to_string(&report)
        .map_err(|e| format!("{}: {e} (fit it with `easycalib fit {} --record`)", report.display(), path.display()))?;
    let j: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", report.display()))?;
    let num = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let ci = |v: &serde_json::Value| [num(&v[0]), num(&v[1])];
    let e1 = num(&j["E1_MPa"]);
    if !e1.is_finite() {
        return Err(format!("{}: no E1_MPa (not a report of easycalib's)", report.display()));
    }
    let mut warnings: Vec<WarningRecord> = j["warnings"]
        .as_array()
        .map(|ws| {
            ws.iter()
                .map(|w| WarningRecord {
                    code: w["code"].as_str().unwrap_or("").to_string(),
                    message: w["message"].as_str().unwrap_or("").to_string(),
                })
                .collect()
        })
        .unwrap_or_default();
    // What the run warned of as it went, as a run's own record keeps it.
    warnings.extend(
        j["run"]["warnings"].as_array().into_iter().flatten().filter_map(|w| {
            w.as_str().map(|m| WarningRecord { code: "run_warning".to_string(), message: m.to_string() })
        }),
    );
    let outcome = Outcome {
        source: Source::Import,
        model: j["full"]["model"].as_str().unwrap_or("half-space").to_string(),
        e1_mpa: e1,
        e1_ci95: ci(&j["ci95"]["E1_MPa"]),
        nu1: num(&j["nu1"]),
        nu1_ci95: ci(&j["ci95"]["nu1"]),
        effects: vec![],
        warnings,
        rig: rec.meta.extra.iter().find(|(k, _)| k == "rig").map(|(_, v)| v.clone()),
        script: None,
    };
    Ok((make_record(&path, &bytes, &rec, outcome), bytes))
}

fn import(target: &Target, dirs: &[PathBuf]) -> Result<(), CliError> {
    let mut folders = vec![];
    for d in dirs {
        if d.join("recording.csv").is_file() {
            folders.push(d.clone());
            continue;
        }
        let rd = std::fs::read_dir(d).map_err(|e| CliError::bad_input(format!("{}: {e}", d.display())))?;
        let mut sub: Vec<PathBuf> =
            rd.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.join("recording.csv").is_file()).collect();
        sub.sort();
        folders.extend(sub);
    }
    let mut store = open(target)?;
    let (mut new, mut present, mut skipped) = (0, 0, 0);
    for dir in &folders {
        match import_one(dir)
            .map_err(|e| e.to_string())
            .and_then(|(r, b)| store.record(&r, &b).map_err(|e| e.to_string()))
        {
            Ok(Recorded::New) => new += 1,
            Ok(Recorded::AlreadyPresent) => present += 1,
            Err(e) => {
                skipped += 1;
                eprintln!("skipped {}: {e}", dir.display());
            }
        }
    }
    println!("history import: {new} imported, {present} already there, {skipped} skipped, into {}", store.describe());
    if folders.is_empty() {
        return Err(CliError::bad_input("no run folder (with a recording.csv) found"));
    }
    Ok(())
}

fn export(target: &Target, output: Option<&Path>) -> Result<(), CliError> {
    let rows = open(target)?.list(None).map_err(|e| CliError::other(e.to_string()))?;
    let written = match output {
        Some(p) => {
            let f = std::fs::File::create(p).map_err(|e| CliError::other(format!("{}: {e}", p.display())))?;
            history::export::write_csv(&rows, f)
        }
        None => history::export::write_csv(&rows, std::io::stdout().lock()),
    };
    written.map_err(|e| CliError::other(format!("cannot write the CSV: {e}")))
}

/// One sensor's calibrations under one model, each assessed, and the trends.
#[derive(Debug, serde::Serialize)]
struct SensorHistory<'a> {
    sensor: &'a str,
    model: &'a str,
    calibrations: Vec<Listed<'a>>,
    trend: Vec<Trend>,
}

#[derive(Debug, serde::Serialize)]
struct Listed<'a> {
    id: String,
    #[serde(flatten)]
    record: &'a CalibrationRecord,
    assessment: Assessment,
}

fn list(target: &Target, args: &HistoryArgs) -> Result<(), CliError> {
    let mut store = open(target)?;
    let rows = store.list(args.sensor.as_deref()).map_err(|e| CliError::other(e.to_string()))?;
    if rows.is_empty() {
        return Err(CliError::bad_input(match &args.sensor {
            Some(s) => format!("no calibration of sensor {s:?} in {}", store.describe()),
            None => format!("no calibration in {}", store.describe()),
        }));
    }
    let settings = args.db.settings();
    let mut keys: Vec<(&str, &str)> = rows.iter().map(|r| (r.sensor.as_str(), r.model.as_str())).collect();
    keys.sort();
    keys.dedup();
    let mut out = vec![];
    for (sensor, model) in keys {
        let series = change::series(&rows, sensor, model);
        let assessed = change::assess_all(&series, &settings);
        let trend =
            [Quantity::E1, Quantity::Nu1].iter().filter_map(|&q| change::trend(&series, q, &settings)).collect();
        let calibrations =
            series.iter().zip(assessed).map(|(r, a)| Listed { id: r.id(), record: r, assessment: a }).collect();
        out.push(SensorHistory { sensor, model, calibrations, trend });
    }
    if let Some(p) = &args.plot {
        write_plot(p, &out)?;
    }
    if args.json {
        let doc = serde_json::json!({
            "db": store.describe(),
            "false_alarm_rate": settings.false_alarm_rate,
            "z_critical": settings.z_critical(),
            "repeatability_floor_pct": 100.0 * settings.repeatability_floor[0],
            "sensors": out,
        });
        println!("{doc:#}");
    } else {
        print!("{}", table(&out, &store.describe()));
    }
    Ok(())
}

fn write_plot(path: &Path, out: &[SensorHistory<'_>]) -> Result<(), CliError> {
    // The sensor's main series: the model with the most calibrations.
    let Some(h) = out.iter().max_by_key(|h| h.calibrations.len()) else { return Ok(()) };
    let series: Vec<&CalibrationRecord> = h.calibrations.iter().map(|c| c.record).collect();
    let assessed: Vec<Assessment> = h.calibrations.iter().map(|c| c.assessment.clone()).collect();
    let tr = |q: Quantity| h.trend.iter().find(|t| t.quantity == q);
    let panels = history::plot::panels(&series, &assessed, [tr(Quantity::E1), tr(Quantity::Nu1)]);
    let svg = history::plot::render_svg(h.sensor, &panels).map_err(|e| CliError::other(format!("plot: {e}")))?;
    std::fs::write(path, svg).map_err(|e| CliError::other(format!("{}: {e}", path.display())))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

fn table(out: &[SensorHistory<'_>], db: &str) -> String {
    let mut s = format!("History in {db}\n");
    for h in out {
        let _ = writeln!(s, "\n{} ({} model): {} calibrations", h.sensor, h.model, h.calibrations.len());
        let _ =
            writeln!(s, "  {:<20}  {:<8}  {:<28}  {:<26}  change", "time (UTC)", "source", "E1 MPa [95%]", "nu1 [95%]");
        for c in &h.calibrations {
            let r = c.record;
            let ci = |c: Option<[f64; 2]>| c.map_or("[open]".to_string(), |c| format!("[{:.4}, {:.4}]", c[0], c[1]));
            let change = match (&c.assessment.e1, &c.assessment.nu1) {
                (None, None) => "-".to_string(),
                (e, n) => {
                    let part = |v: &Option<change::Verdict>| {
                        v.as_ref().map_or(String::new(), |v| format!("{} {:+.2}% ", v.quantity.label(), v.change_pct))
                    };
                    format!("{}{}{}", part(e), part(n), if c.assessment.alarm { "CHANGED" } else { "" })
                }
            };
            let _ = writeln!(
                s,
                "  {:<20}  {:<8}  {:.4} {:<21}  {:.4} {:<19}  {}",
                r.time_utc,
                r.source.as_str(),
                r.e1_mpa,
                ci(r.e1_ci95),
                r.nu1,
                ci(r.nu1_ci95),
                change.trim_end()
            );
        }
        for t in &h.trend {
            let _ = writeln!(s, "{}", trend_line(t));
        }
    }
    s
}
