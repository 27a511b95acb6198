//! The fleet backend: a PostgreSQL server. Migrations run on connect under a
//! transaction-scoped advisory lock, so rigs connecting at once migrate once;
//! each write is one transaction whose inserts skip rows already there, so
//! concurrent and repeated writers never fail on each other.

use std::time::Duration;

use postgres::{Client, Config, NoTls};

use crate::schema::{self, Row};
use crate::{CalibrationRecord, HistoryError, Recorded, Store};

/// How long connecting may take before the server counts as unreachable.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// The advisory lock that serialises migrations ("easycali" in ASCII).
const MIGRATION_LOCK: i64 = 0x6561_7379_6361_6c69;

pub struct PostgresStore {
    client: Client,
    target: String,
}

impl PostgresStore {
    pub fn connect(url: &str) -> Result<PostgresStore, HistoryError> {
        let target = crate::redact_url(url);
        let mut config: Config = url.parse().map_err(|e: postgres::Error| HistoryError::Database {
            target: target.clone(),
            source: format!("not a PostgreSQL connection URL: {e}").into(),
        })?;
        if config.get_connect_timeout().is_none() {
            config.connect_timeout(CONNECT_TIMEOUT);
        }
        config.application_name("easycalib");
        let client = config
            .connect(NoTls)
            .map_err(|e| HistoryError::Unreachable { target: target.clone(), source: Box::new(e) })?;
        let mut store = PostgresStore { client, target };
        store.migrate()?;
        Ok(store)
    }

    fn err(&self, e: postgres::Error) -> HistoryError {
        classify(&self.target, e)
    }

    fn migrate(&mut self) -> Result<(), HistoryError> {
        let target = self.target.clone();
        let mut tx = self.client.transaction().map_err(|e| classify(&target, e))?;
        tx.execute("SELECT pg_advisory_xact_lock($1)", &[&MIGRATION_LOCK]).map_err(|e| classify(&target, e))?;
        tx.batch_execute(
            "CREATE TABLE IF NOT EXISTS schema_version (version BIGINT PRIMARY KEY, applied_utc TIMESTAMPTZ NOT NULL DEFAULT now())",
        )
        .map_err(|e| classify(&target, e))?;
        let found: i64 = tx
            .query_one("SELECT COALESCE(MAX(version), 0)::BIGINT FROM schema_version", &[])
            .map_err(|e| classify(&target, e))?
            .get(0);
        if found > schema::latest() {
            return Err(HistoryError::Schema { target, found, known: schema::latest() });
        }
        for (version, sql) in schema::MIGRATIONS.iter().filter(|m| m.0 > found) {
            for stmt in schema::statements(sql, "BYTEA") {
                tx.batch_execute(&stmt).map_err(|e| classify(&target, e))?;
            }
            tx.execute("INSERT INTO schema_version (version) VALUES ($1)", &[version])
                .map_err(|e| classify(&target, e))?;
        }
        tx.commit().map_err(|e| classify(&target, e))
    }
}

/// A lost or refused connection is `Unreachable` (the caller queues the
/// write); an answer from the server is a database error.
fn classify(target: &str, e: postgres::Error) -> HistoryError {
    if e.as_db_error().is_none()
        && (e.is_closed() || std::error::Error::source(&e).is_some_and(|s| s.is::<std::io::Error>()))
    {
        HistoryError::Unreachable { target: target.to_string(), source: Box::new(e) }
    } else {
        HistoryError::Database { target: target.to_string(), source: Box::new(e) }
    }
}

impl Store for PostgresStore {
    fn record(&mut self, rec: &CalibrationRecord, recording: &[u8]) -> Result<Recorded, HistoryError> {
        let row = Row::of(rec)?;
        if crate::sha256_hex(recording) != rec.recording_sha256 {
            return Err(HistoryError::Invalid("the recording's bytes do not match recording_sha256".into()));
        }
        let target = self.target.clone();
        let mut tx = self.client.transaction().map_err(|e| classify(&target, e))?;
        let size = recording.len() as i64;
        tx.execute(schema::INSERT_RECORDING, &[&rec.recording_sha256, &recording, &size])
            .map_err(|e| classify(&target, e))?;
        let n = tx
            .execute(
                schema::INSERT_CALIBRATION,
                &[
                    &row.id,
                    &rec.sensor,
                    &rec.time_utc,
                    &rec.time_unix_s,
                    &rec.source.as_str(),
                    &rec.model,
                    &rec.e1_mpa,
                    &row.e1_lo,
                    &row.e1_hi,
                    &rec.nu1,
                    &row.nu1_lo,
                    &row.nu1_hi,
                    &rec.software_version,
                    &rec.recording_sha256,
                    &row.json,
                ],
            )
            .map_err(|e| classify(&target, e))?;
        tx.commit().map_err(|e| classify(&target, e))?;
        Ok(if n == 1 { Recorded::New } else { Recorded::AlreadyPresent })
    }

    fn list(&mut self, sensor: Option<&str>) -> Result<Vec<CalibrationRecord>, HistoryError> {
        let rows = match sensor {
            Some(s) => self.client.query(schema::SELECT_SENSOR, &[&s]),
            None => self.client.query(schema::SELECT_ALL, &[]),
        }
        .map_err(|e| self.err(e))?;
        rows.iter().map(|r| schema::parse_row(&self.target, r.get(0), r.get(1))).collect()
    }

    fn recording(&mut self, sha256: &str) -> Result<Option<Vec<u8>>, HistoryError> {
        let row = self.client.query_opt(schema::SELECT_RECORDING, &[&sha256]).map_err(|e| self.err(e))?;
        Ok(row.map(|r| r.get(0)))
    }

    fn describe(&self) -> String {
        format!("PostgreSQL {}", self.target)
    }
}
