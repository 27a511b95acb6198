//! One calibration as the history keeps it.

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Where a calibration came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// `easycalib run` on a rig.
    Run,
    /// `easycalib fit --record` on a recording.
    Fit,
    /// `easycalib diagnose --record` (the corrected values).
    Diagnose,
    /// `easycalib history import` of an earlier run folder.
    Import,
}

impl Source {
    pub fn as_str(self) -> &'static str {
        match self {
            Source::Run => "run",
            Source::Fit => "fit",
            Source::Diagnose => "diagnose",
            Source::Import => "import",
        }
    }
}

/// The calibration indenter (E2, nu2, R2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Indenter {
    pub e_mpa: f64,
    pub nu: f64,
    pub r_mm: f64,
}

/// An effect the diagnosis named, with its fitted parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EffectRecord {
    pub name: String,
    pub params: Vec<EffectParam>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EffectParam {
    pub name: String,
    pub value: f64,
    pub unit: String,
}

/// A warning the fit or the run gave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WarningRecord {
    pub code: String,
    pub message: String,
}

/// One calibration: who, when, with what, the answer, and the recording it
/// came from (by content hash; the bytes are stored beside the row).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// The sensor's identity (the recording's `sensor`).
    pub sensor: String,
    /// When the recording was made, RFC 3339 UTC.
    pub time_utc: String,
    /// The same instant, seconds since 1970-01-01 UTC (for ordering and trends).
    pub time_unix_s: f64,
    pub source: Source,
    /// The rig, as the run described it.
    pub rig: Option<String>,
    pub indenter: Indenter,
    /// The calibration script (TOML text), when a run made the recording.
    pub script: Option<String>,
    /// The forward model of the fit (`half-space`, `layer-fe`, ...).
    pub model: String,
    pub e1_mpa: f64,
    /// 95 % interval of E1, when the fit gave one.
    pub e1_ci95: Option<[f64; 2]>,
    pub nu1: f64,
    pub nu1_ci95: Option<[f64; 2]>,
    pub effects: Vec<EffectRecord>,
    pub warnings: Vec<WarningRecord>,
    /// easycalib's version that made the calibration.
    pub software_version: String,
    /// Where the recording was when it was recorded (it may be gone since).
    pub recording_path: Option<String>,
    /// SHA-256 of the recording's bytes, lower-case hex.
    pub recording_sha256: String,
}

impl CalibrationRecord {
    /// The record's identity: the recording's hash and what made the answer.
    /// Writing the same record twice (a retried or queued write) stores it
    /// once; importing a run folder the run already recorded finds it there
    /// (an import is the run's own report).
    pub fn id(&self) -> String {
        let made_by = match self.source {
            Source::Import => Source::Run,
            s => s,
        };
        sha256_hex(format!("{}\n{}", self.recording_sha256, made_by.as_str()).as_bytes())
    }

    /// A record that cannot go into the store: what is wrong with it.
    pub fn check(&self) -> Result<(), String> {
        if self.sensor.trim().is_empty() {
            return Err("the sensor's name is empty".into());
        }
        if !self.time_unix_s.is_finite() {
            return Err(format!("time_unix_s is {}", self.time_unix_s));
        }
        if !(self.e1_mpa.is_finite() && self.e1_mpa > 0.0) {
            return Err(format!("E1 = {} MPa is not a positive number", self.e1_mpa));
        }
        if !self.nu1.is_finite() {
            return Err(format!("nu1 = {} is not a number", self.nu1));
        }
        for (name, ci) in [("E1", self.e1_ci95), ("nu1", self.nu1_ci95)] {
            if let Some([lo, hi]) = ci
                && !(lo.is_finite() && hi.is_finite() && lo <= hi)
            {
                return Err(format!("the {name} interval [{lo}, {hi}] is not an interval"));
            }
        }
        if self.recording_sha256.len() != 64 || !self.recording_sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(format!("recording_sha256 {:?} is not a SHA-256 in hex", self.recording_sha256));
        }
        Ok(())
    }
}

/// SHA-256 of `bytes`, lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// Seconds since 1970-01-01 UTC of an RFC 3339 time (`2026-11-25T03:16:24Z`,
/// fractional seconds and `+hh:mm` offsets accepted).
pub fn parse_rfc3339(s: &str) -> Option<f64> {
    let t = time::OffsetDateTime::parse(s.trim(), &time::format_description::well_known::Rfc3339).ok()?;
    Some(t.unix_timestamp() as f64 + f64::from(t.nanosecond()) * 1e-9)
}

/// RFC 3339 UTC (whole seconds) of seconds since 1970-01-01 UTC.
pub fn format_rfc3339(unix_s: f64) -> String {
    time::OffsetDateTime::from_unix_timestamp(unix_s.floor() as i64)
        .ok()
        .and_then(|t| t.format(&time::format_description::well_known::Rfc3339).ok())
        .unwrap_or_else(|| "1970-01-01T00:00:00Z".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc3339_round_trips_and_knows_its_calendar() {
        assert_eq!(parse_rfc3339("1970-01-01T00:00:00Z"), Some(0.0));
        // 2000-03-01 follows a leap day: 11017 days after the epoch.
        assert_eq!(parse_rfc3339("2000-03-01T00:00:00Z"), Some(11_017.0 * 86_400.0));
        assert_eq!(parse_rfc3339("2026-11-25T04:16:24+01:00"), parse_rfc3339("2026-11-25T03:16:24Z"));
        assert_eq!(parse_rfc3339("2026-11-25T03:16:24.250Z").map(|t| t.fract()), Some(0.25));
        for t in [0.0, 951_782_400.0, 1_795_000_000.0, -86_400.0] {
            assert_eq!(parse_rfc3339(&format_rfc3339(t)), Some(t));
        }
        for bad in ["", "2026-13-01T00:00:00Z", "2026-11-25 03:16", "2026-11-25T03:16:24", "x026-11-25T03:16:24Z"] {
            assert_eq!(parse_rfc3339(bad), None, "{bad}");
        }
    }

    #[test]
    fn sha256_of_the_empty_string() {
        assert_eq!(sha256_hex(b""), "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
    }
}
