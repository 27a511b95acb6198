//! The offline queue: results that could not be written (server unreachable)
//! wait in a local folder, one `<id>.json` record and its `<id>.csv`
//! recording, until `easycalib history sync` delivers them. Delivery is
//! idempotent (a record's id is its recording's hash and source), so a sync
//! killed half-way and run again still stores each result once.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::{CalibrationRecord, HistoryError, Recorded, Store};

pub struct Queue {
    dir: PathBuf,
}

/// What a sync did.
#[derive(Debug, Default)]
pub struct SyncReport {
    pub delivered: usize,
    /// Already in the store (an earlier sync was interrupted after its commit).
    pub already_present: usize,
    /// Entries that could not be delivered, with why; they stay queued.
    pub failed: Vec<(PathBuf, HistoryError)>,
}

impl Queue {
    pub fn at(dir: &Path) -> Queue {
        Queue { dir: dir.to_path_buf() }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Queue one result. The recording is written first and the record last
    /// (by rename), so a queued record always has its recording.
    pub fn push(&self, rec: &CalibrationRecord, recording: &[u8]) -> Result<PathBuf, HistoryError> {
        rec.check().map_err(HistoryError::Invalid)?;
        std::fs::create_dir_all(&self.dir).map_err(|e| HistoryError::io(&self.dir, e))?;
        let id = rec.id();
        write_atomic(&self.dir.join(format!("{id}.csv")), recording)?;
        let json = serde_json::to_vec_pretty(rec).map_err(|e| HistoryError::Invalid(e.to_string()))?;
        let path = self.dir.join(format!("{id}.json"));
        write_atomic(&path, &json)?;
        Ok(path)
    }

    /// The queued records, oldest file name first (ids are hashes: the order
    /// does not matter for the store, which orders by time).
    pub fn pending(&self) -> Result<Vec<PathBuf>, HistoryError> {
        let rd = match std::fs::read_dir(&self.dir) {
            Ok(rd) => rd,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(vec![]),
            Err(e) => return Err(HistoryError::io(&self.dir, e)),
        };
        let mut out: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "json"))
            .collect();
        out.sort();
        Ok(out)
    }

    /// Deliver every queued result to `store`; delivered ones leave the queue.
    pub fn sync(&self, store: &mut dyn Store) -> Result<SyncReport, HistoryError> {
        let mut report = SyncReport::default();
        for json_path in self.pending()? {
            match deliver(store, &json_path) {
                Ok(r) => {
                    match r {
                        Recorded::New => report.delivered += 1,
                        Recorded::AlreadyPresent => report.already_present += 1,
                    }
                    std::fs::remove_file(&json_path).map_err(|e| HistoryError::io(&json_path, e))?;
                    let csv = json_path.with_extension("csv");
                    std::fs::remove_file(&csv).map_err(|e| HistoryError::io(&csv, e))?;
                }
                // The server went away mid-sync: stop, the rest stays queued.
                Err(e) if e.kind() == crate::ErrorKind::Unreachable => return Err(e),
                Err(e) => report.failed.push((json_path, e)),
            }
        }
        Ok(report)
    }
}

fn deliver(store: &mut dyn Store, json_path: &Path) -> Result<Recorded, HistoryError> {
    let text = std::fs::read(json_path).map_err(|e| HistoryError::io(json_path, e))?;
    let rec: CalibrationRecord =
        serde_json::from_slice(&text).map_err(|e| HistoryError::Invalid(format!("{}: {e}", json_path.display())))?;
    let csv = json_path.with_extension("csv");
    let bytes = std::fs::read(&csv).map_err(|e| HistoryError::io(&csv, e))?;
    store.record(&rec, &bytes)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), HistoryError> {
    let tmp = path.with_extension("partial");
    let mut f = std::fs::File::create(&tmp).map_err(|e| HistoryError::io(&tmp, e))?;
    f.write_all(bytes).and_then(|_| f.sync_all()).map_err(|e| HistoryError::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| HistoryError::io(path, e))
}
