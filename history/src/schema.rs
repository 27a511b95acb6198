//! The versioned schema, shared by both backends (`{blob}` is the one word
//! they spell differently). A migration is never edited once released: a
//! change is a new entry.

/// (version, SQL statements separated by `;`).
pub const MIGRATIONS: &[(i64, &str)] = &[(
    1,
    "CREATE TABLE recordings (
            sha256 TEXT PRIMARY KEY,
            bytes {blob} NOT NULL,
            size_bytes BIGINT NOT NULL
        );
        CREATE TABLE calibrations (
            id TEXT PRIMARY KEY,
            sensor TEXT NOT NULL,
            time_utc TEXT NOT NULL,
            time_unix_s DOUBLE PRECISION NOT NULL,
            source TEXT NOT NULL,
            model TEXT NOT NULL,
            e1_mpa DOUBLE PRECISION NOT NULL,
            e1_lo DOUBLE PRECISION,
            e1_hi DOUBLE PRECISION,
            nu1 DOUBLE PRECISION NOT NULL,
            nu1_lo DOUBLE PRECISION,
            nu1_hi DOUBLE PRECISION,
            software_version TEXT NOT NULL,
            recording_sha256 TEXT NOT NULL REFERENCES recordings (sha256),
            record_json TEXT NOT NULL
        );
        CREATE INDEX calibrations_by_sensor ON calibrations (sensor, time_unix_s)",
)];

/// The newest schema version this build knows.
pub fn latest() -> i64 {
    MIGRATIONS.iter().map(|m| m.0).max().unwrap_or(0)
}

/// The statements of one migration for a backend.
pub fn statements(sql: &str, blob: &str) -> Vec<String> {
    sql.replace("{blob}", blob).split(';').map(str::trim).filter(|s| !s.is_empty()).map(String::from).collect()
}

/// The row of a record: the columns queried, and the whole record as JSON.
pub struct Row {
    pub id: String,
    pub e1_lo: Option<f64>,
    pub e1_hi: Option<f64>,
    pub nu1_lo: Option<f64>,
    pub nu1_hi: Option<f64>,
    pub json: String,
}

impl Row {
    pub fn of(rec: &crate::CalibrationRecord) -> Result<Row, crate::HistoryError> {
        rec.check().map_err(crate::HistoryError::Invalid)?;
        let json = serde_json::to_string(rec).map_err(|e| crate::HistoryError::Invalid(e.to_string()))?;
        Ok(Row {
            id: rec.id(),
            e1_lo: rec.e1_ci95.map(|c| c[0]),
            e1_hi: rec.e1_ci95.map(|c| c[1]),
            nu1_lo: rec.nu1_ci95.map(|c| c[0]),
            nu1_hi: rec.nu1_ci95.map(|c| c[1]),
            json,
        })
    }
}

/// A stored row back into a record; a row that does not parse is named.
pub fn parse_row(target: &str, id: &str, json: &str) -> Result<crate::CalibrationRecord, crate::HistoryError> {
    serde_json::from_str(json).map_err(|e| crate::HistoryError::Database {
        target: target.to_string(),
        source: format!("calibration {id}: stored record does not parse: {e}").into(),
    })
}

pub const INSERT_RECORDING: &str =
    "INSERT INTO recordings (sha256, bytes, size_bytes) VALUES ($1, $2, $3) ON CONFLICT (sha256) DO NOTHING";
pub const INSERT_CALIBRATION: &str = "INSERT INTO calibrations (id, sensor, time_utc, time_unix_s, source, model, e1_mpa, e1_lo, e1_hi, nu1, nu1_lo, nu1_hi, software_version, recording_sha256, record_json) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15) ON CONFLICT (id) DO NOTHING";
pub const SELECT_ALL: &str = "SELECT id, record_json FROM calibrations ORDER BY time_unix_s, id";
pub const SELECT_SENSOR: &str = "SELECT id, record_json FROM calibrations WHERE sensor = $1 ORDER BY time_unix_s, id";
pub const SELECT_RECORDING: &str = "SELECT bytes FROM recordings WHERE sha256 = $1";
