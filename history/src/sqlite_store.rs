//! The embedded backend: one SQLite file in WAL mode, every write one
//! `BEGIN IMMEDIATE` transaction (writers queue on the file lock with a busy
//! timeout instead of failing).

use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{Connection, OptionalExtension, TransactionBehavior, params};

use crate::schema::{self, Row};
use crate::{CalibrationRecord, HistoryError, Recorded, Store};

/// How long a writer waits for another's transaction before it gives up.
const BUSY_TIMEOUT: Duration = Duration::from_secs(30);

pub struct SqliteStore {
    conn: Connection,
    path: PathBuf,
}

impl SqliteStore {
    pub fn open(path: &Path) -> Result<SqliteStore, HistoryError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| HistoryError::io(dir, e))?;
        }
        let conn = Connection::open(path).map_err(|e| db(path, e))?;
        conn.busy_timeout(BUSY_TIMEOUT).map_err(|e| db(path, e))?;
        // WAL: readers never block the writer, and a killed writer leaves the
        // last committed state. NORMAL sync is consistent after any crash (a
        // power cut may lose the last commit, never corrupt).
        conn.pragma_update(None, "journal_mode", "WAL").map_err(|e| db(path, e))?;
        conn.pragma_update(None, "synchronous", "NORMAL").map_err(|e| db(path, e))?;
        let mut store = SqliteStore { conn, path: path.to_path_buf() };
        store.migrate()?;
        Ok(store)
    }

    fn migrate(&mut self) -> Result<(), HistoryError> {
        let path = self.path.clone();
        let tx = self.conn.transaction_with_behavior(TransactionBehavior::Immediate).map_err(|e| db(&path, e))?;
        tx.execute(
            "CREATE TABLE IF NOT EXISTS schema_version (version BIGINT PRIMARY KEY, applied_utc TEXT NOT NULL)",
            [],
        )
        .map_err(|e| db(&path, e))?;
        let found: i64 = tx
            .query_row("SELECT COALESCE(MAX(version), 0) FROM schema_version", [], |r| r.get(0))
            .map_err(|e| db(&path, e))?;
        if found > schema::latest() {
            return Err(HistoryError::Schema { target: path.display().to_string(), found, known: schema::latest() });
        }
        for (version, sql) in schema::MIGRATIONS.iter().filter(|m| m.0 > found) {
            for stmt in schema::statements(sql, "BLOB") {
                tx.execute(&stmt, []).map_err(|e| db(&path, e))?;
            }
            tx.execute("INSERT INTO schema_version (version, applied_utc) VALUES (?1, datetime('now'))", [version])
                .map_err(|e| db(&path, e))?;
        }
        tx.commit().map_err(|e| db(&path, e))
    }
}

fn db(path: &Path, e: rusqlite::Error) -> HistoryError {
    HistoryError::Database { target: path.display().to_string(), source: Box::new(e) }
}

impl Store for SqliteStore {
    fn record(&mut self, rec: &CalibrationRecord, recording: &[u8]) -> Result<Recorded, HistoryError> {
        let row = Row::of(rec)?;
        if crate::sha256_hex(recording) != rec.recording_sha256 {
            return Err(HistoryError::Invalid("the recording's bytes do not match recording_sha256".into()));
        }
        let path = self.path.clone();
        let tx = self.conn.transaction_with_behavior(TransactionBehavior::Immediate).map_err(|e| db(&path, e))?;
        tx.execute(schema::INSERT_RECORDING, params![rec.recording_sha256, recording, recording.len() as i64])
            .map_err(|e| db(&path, e))?;
        let n = tx
            .execute(
                schema::INSERT_CALIBRATION,
                params![
                    row.id,
                    rec.sensor,
                    rec.time_utc,
                    rec.time_unix_s,
                    rec.source.as_str(),
                    rec.model,
                    rec.e1_mpa,
                    row.e1_lo,
                    row.e1_hi,
                    rec.nu1,
                    row.nu1_lo,
                    row.nu1_hi,
                    rec.software_version,
                    rec.recording_sha256,
                    row.json
                ],
            )
            .map_err(|e| db(&path, e))?;
        tx.commit().map_err(|e| db(&path, e))?;
        Ok(if n == 1 { Recorded::New } else { Recorded::AlreadyPresent })
    }

    fn list(&mut self, sensor: Option<&str>) -> Result<Vec<CalibrationRecord>, HistoryError> {
        let target = self.path.display().to_string();
        let rows: Vec<(String, String)> = {
            let mut stmt = self
                .conn
                .prepare_cached(if sensor.is_some() { schema::SELECT_SENSOR } else { schema::SELECT_ALL })
                .map_err(|e| db(&self.path, e))?;
            let map = |r: &rusqlite::Row| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?));
            let it = match sensor {
                Some(s) => stmt.query_map([s], map),
                None => stmt.query_map([], map),
            }
            .map_err(|e| db(&self.path, e))?;
            it.collect::<Result<_, _>>().map_err(|e| db(&self.path, e))?
        };
        rows.iter().map(|(id, json)| schema::parse_row(&target, id, json)).collect()
    }

    fn recording(&mut self, sha256: &str) -> Result<Option<Vec<u8>>, HistoryError> {
        self.conn.query_row(schema::SELECT_RECORDING, [sha256], |r| r.get(0)).optional().map_err(|e| db(&self.path, e))
    }

    fn describe(&self) -> String {
        format!("SQLite {}", self.path.display())
    }
}
