//! Per-sensor calibration history (docs/history.md).
//!
//! Every calibration is one row keyed by its recording's hash, with the
//! recording's bytes kept beside it, in an embedded SQLite database by default
//! or on a PostgreSQL server for a fleet of rigs. The schema is versioned and
//! migrated on open; writes are transactions and idempotent, so a retried or
//! queued write lands exactly once. [`change`] says whether a new calibration
//! moved beyond what the intervals and the rig's repeatability explain.
// Library code answers bad input with an error, never a panic: no unwrap or
// expect outside tests (ARCHITECTURE.md, "Conventions").
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub mod change;
pub mod export;
pub mod plot;
mod postgres_store;
pub mod queue;
pub mod record;
mod schema;
mod sqlite_store;

use std::path::{Path, PathBuf};

pub use record::{CalibrationRecord, EffectParam, EffectRecord, Indenter, Source, WarningRecord, sha256_hex};

/// What went wrong, coarsely, so a caller can act (queue the write, tell the user).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// The server cannot be reached or refused us: queue and retry later.
    Unreachable,
    /// The database holds a newer schema than this version knows.
    Schema,
    /// The database answered with an error.
    Database,
    /// A local file could not be read or written.
    Io,
    /// The record itself is not valid.
    Invalid,
}

#[derive(Debug, thiserror::Error)]
pub enum HistoryError {
    #[error("cannot reach the history database {target}: {source}")]
    Unreachable {
        target: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("the history database {target} has schema version {found}; this easycalib knows up to {known}")]
    Schema { target: String, found: i64, known: i64 },
    #[error("history database {target}: {source}")]
    Database {
        target: String,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("not a valid calibration record: {0}")]
    Invalid(String),
}

impl HistoryError {
    pub fn kind(&self) -> ErrorKind {
        match self {
            HistoryError::Unreachable { .. } => ErrorKind::Unreachable,
            HistoryError::Schema { .. } => ErrorKind::Schema,
            HistoryError::Database { .. } => ErrorKind::Database,
            HistoryError::Io { .. } => ErrorKind::Io,
            HistoryError::Invalid(_) => ErrorKind::Invalid,
        }
    }

    pub(crate) fn io(path: &Path, source: std::io::Error) -> Self {
        HistoryError::Io { path: path.to_path_buf(), source }
    }
}

/// Whether a write added a row or found it already there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Recorded {
    New,
    AlreadyPresent,
}

/// A calibration history: one small capability, two backends.
pub trait Store {
    /// Store `rec` and the recording's bytes in one transaction. Writing the
    /// same record again changes nothing.
    fn record(&mut self, rec: &CalibrationRecord, recording: &[u8]) -> Result<Recorded, HistoryError>;
    /// Calibrations, oldest first; of one sensor, or all.
    fn list(&mut self, sensor: Option<&str>) -> Result<Vec<CalibrationRecord>, HistoryError>;
    /// The stored bytes of a recording, by its SHA-256.
    fn recording(&mut self, sha256: &str) -> Result<Option<Vec<u8>>, HistoryError>;
    /// A short description of where the store is (no password).
    fn describe(&self) -> String;
}

/// Where the history lives: a SQLite file or a PostgreSQL URL.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    Sqlite(PathBuf),
    Postgres(String),
}

impl Target {
    /// `postgres://…` / `postgresql://…` is a server, anything else a SQLite file.
    pub fn parse(s: &str) -> Target {
        if s.starts_with("postgres://") || s.starts_with("postgresql://") {
            Target::Postgres(s.to_string())
        } else {
            Target::Sqlite(PathBuf::from(s.strip_prefix("sqlite://").unwrap_or(s)))
        }
    }

    /// The target without any password, for messages.
    pub fn describe(&self) -> String {
        match self {
            Target::Sqlite(p) => p.display().to_string(),
            Target::Postgres(url) => redact_url(url),
        }
    }
}

/// Open (and migrate) the store.
pub fn open(target: &Target) -> Result<Box<dyn Store>, HistoryError> {
    Ok(match target {
        Target::Sqlite(p) => Box::new(sqlite_store::SqliteStore::open(p)?),
        Target::Postgres(url) => Box::new(postgres_store::PostgresStore::connect(url)?),
    })
}

/// `postgres://user:secret@host/db` -> `postgres://user@host/db`.
pub fn redact_url(url: &str) -> String {
    let Some((scheme, rest)) = url.split_once("://") else { return url.to_string() };
    let (auth, tail) = match rest.rsplit_once('@') {
        Some((a, t)) => (a, t),
        None => return url.to_string(),
    };
    let user = auth.split(':').next().unwrap_or("");
    format!("{scheme}://{user}@{tail}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_and_redaction() {
        assert_eq!(Target::parse("/tmp/h.sqlite"), Target::Sqlite("/tmp/h.sqlite".into()));
        assert_eq!(Target::parse("sqlite:///tmp/h.sqlite"), Target::Sqlite("/tmp/h.sqlite".into()));
        assert!(matches!(Target::parse("postgresql://u@localhost/x"), Target::Postgres(_)));
        assert_eq!(redact_url("postgres://u:pw@127.0.0.1:5432/db"), "postgres://u@127.0.0.1:5432/db");
        assert_eq!(redact_url("postgres://127.0.0.1/db"), "postgres://127.0.0.1/db");
    }
}
