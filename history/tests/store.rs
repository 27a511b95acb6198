//! The store against real databases: a SQLite file, and a PostgreSQL server
//! when `EASYCALIB_TEST_POSTGRES_URL` names one (`.ci/run` starts one on
//! loopback; without it these tests say so and pass, except under `CI`, where
//! a missing server is a failure). Nothing is mocked at the database boundary.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod common;

use history::queue::Queue;
use history::{CalibrationRecord, ErrorKind, Recorded, Store, Target, sha256_hex};

/// A calibration of `sensor` with a recording of about `size` bytes.
fn calibration(sensor: &str, i: usize, size: usize) -> (CalibrationRecord, Vec<u8>) {
    let head = format!("# easycalib-recording: 1\n# sensor: {sensor}\n# n: {i}\n");
    let mut bytes = head.into_bytes();
    while bytes.len() < size {
        bytes.extend_from_slice(format!("{:.6},normal,{:.4},0,0,0\n", bytes.len(), i).as_bytes());
    }
    let t = 1.78e9 + i as f64 * 86_400.0;
    let rec = common::calibration_record(sensor, t, 0.33 + 1e-5 * i as f64, &bytes);
    (rec, bytes)
}

fn write_idempotent_and_read_back(store: &mut dyn Store) {
    let (a, ab) = calibration("s-1", 2, 500);
    let (b, bb) = calibration("s-1", 1, 500);
    let (c, cb) = calibration("s-2", 3, 500);
    assert_eq!(store.record(&a, &ab).unwrap(), Recorded::New);
    assert_eq!(store.record(&b, &bb).unwrap(), Recorded::New);
    assert_eq!(store.record(&c, &cb).unwrap(), Recorded::New);
    // Written again (a retried or queued write): nothing changes.
    assert_eq!(store.record(&a, &ab).unwrap(), Recorded::AlreadyPresent);
    let s1 = store.list(Some("s-1")).unwrap();
    assert_eq!(s1, vec![b.clone(), a.clone()], "one sensor, oldest first");
    assert_eq!(store.list(None).unwrap().len(), 3);
    assert_eq!(store.recording(&a.recording_sha256).unwrap(), Some(ab.clone()));
    assert_eq!(store.recording(&"0".repeat(64)).unwrap(), None);
    // Bytes that are not the recording named, and records that are not records.
    let e = store.record(&c, &ab).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Invalid, "{e}");
    let mut bad = c.clone();
    bad.e1_mpa = f64::NAN;
    assert_eq!(store.record(&bad, &cb).unwrap_err().kind(), ErrorKind::Invalid);
}

/// Four writers at once, 50 calibrations each: every row present, none twice.
fn four_concurrent_writers(target: &Target) {
    let writers: Vec<_> = (0..4)
        .map(|w| {
            let target = target.clone();
            std::thread::spawn(move || {
                let mut store = history::open(&target).expect("open");
                for i in 0..50 {
                    let (rec, bytes) = calibration(&format!("rig-{w}"), i, 2_000);
                    assert_eq!(store.record(&rec, &bytes).expect("no error surfaces to a writer"), Recorded::New);
                }
            })
        })
        .collect();
    for w in writers {
        w.join().expect("writer");
    }
    let rows = history::open(target).unwrap().list(None).unwrap();
    assert_eq!(rows.len(), 200);
    let mut ids: Vec<String> = rows.iter().map(|r| r.id()).collect();
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), 200, "no row twice");
    for w in 0..4 {
        assert_eq!(rows.iter().filter(|r| r.sensor == format!("rig-{w}")).count(), 50);
    }
}

/// The child side of the kill test: write large calibrations until killed.
#[test]
#[ignore = "run by killed_writer_leaves_a_consistent_store as a child process"]
fn child_writer() {
    let Ok(target) = std::env::var("HISTORY_TEST_CHILD_TARGET") else { return };
    let mut store = history::open(&Target::parse(&target)).expect("open");
    for i in 0.. {
        let (rec, bytes) = calibration("killed", i, 2_000_000);
        store.record(&rec, &bytes).expect("record");
    }
}

/// A writer killed (SIGKILL) in the middle of its writes leaves a store whose
/// every row has its recording, and the next writer succeeds.
fn killed_writer_leaves_a_consistent_store(target: &str) {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "child_writer", "--ignored", "--nocapture"])
        .env("HISTORY_TEST_CHILD_TARGET", target)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t = Target::parse(target);
    let start = Instant::now();
    // Let it commit a few, then kill it wherever it is (most likely mid-transaction:
    // each write carries 2 MB).
    loop {
        let n = history::open(&t).unwrap().list(Some("killed")).unwrap().len();
        if n >= 3 {
            break;
        }
        if start.elapsed() > Duration::from_secs(120) || child.try_wait().is_ok_and(|s| s.is_some()) {
            // Say why: the child's own account (it stops at its first error).
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "the child wrote {n} rows in {:?} ({}): {}",
                start.elapsed(),
                out.status,
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    let mut store = history::open(&t).unwrap();
    let rows = store.list(Some("killed")).unwrap();
    for r in &rows {
        let bytes = store.recording(&r.recording_sha256).unwrap().expect("every row has its recording");
        assert_eq!(sha256_hex(&bytes), r.recording_sha256, "the stored recording is whole");
    }
    let (next, bytes) = calibration("after-kill", 0, 1_000);
    assert_eq!(store.record(&next, &bytes).unwrap(), Recorded::New);
    assert_eq!(store.list(Some("after-kill")).unwrap(), vec![next]);
}

/// The queue: a result for an unreachable server waits, and a sync delivers it
/// once, even when a sync was interrupted after its commit.
fn queue_delivers_exactly_once(store: &mut dyn Store, queue_dir: &Path) {
    let q = Queue::at(queue_dir);
    let (rec, bytes) = calibration("queued", 0, 3_000);
    q.push(&rec, &bytes).unwrap();
    assert_eq!(q.pending().unwrap().len(), 1);
    let r = q.sync(store).unwrap();
    assert_eq!((r.delivered, r.already_present, r.failed.len()), (1, 0, 0));
    assert!(q.pending().unwrap().is_empty());
    let r = q.sync(store).unwrap();
    assert_eq!((r.delivered, r.already_present), (0, 0));
    // A sync killed between its commit and removing the file: the entry is
    // still queued; the next sync finds it present and removes it.
    q.push(&rec, &bytes).unwrap();
    let r = q.sync(store).unwrap();
    assert_eq!((r.delivered, r.already_present), (0, 1));
    assert_eq!(store.list(Some("queued")).unwrap().len(), 1, "delivered exactly once");
}

mod sqlite {
    use super::*;

    fn target(dir: &Path) -> Target {
        Target::Sqlite(dir.join("nested").join("history.sqlite"))
    }

    #[test]
    fn writes_are_idempotent_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        write_idempotent_and_read_back(history::open(&target(dir.path())).unwrap().as_mut());
    }

    #[test]
    fn four_writers_at_once() {
        let dir = tempfile::tempdir().unwrap();
        four_concurrent_writers(&target(dir.path()));
    }

    #[test]
    fn a_killed_writer_leaves_the_file_consistent() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.sqlite");
        killed_writer_leaves_a_consistent_store(path.to_str().unwrap());
        let conn = rusqlite::Connection::open(&path).unwrap();
        let check: String = conn.query_row("PRAGMA integrity_check", [], |r| r.get(0)).unwrap();
        assert_eq!(check, "ok");
        let mode: String = conn.query_row("PRAGMA journal_mode", [], |r| r.get(0)).unwrap();
        assert_eq!(mode, "wal");
    }

    #[test]
    fn the_queue_delivers_once() {
        let dir = tempfile::tempdir().unwrap();
        let mut store = history::open(&target(dir.path())).unwrap();
        queue_delivers_exactly_once(store.as_mut(), &dir.path().join("queue"));
    }

    #[test]
    fn a_newer_schema_is_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.sqlite");
        drop(history::open(&Target::Sqlite(path.clone())).unwrap());
        let conn = rusqlite::Connection::open(&path).unwrap();
        conn.execute("INSERT INTO schema_version (version, applied_utc) VALUES (99, 'later')", []).unwrap();
        let e = history::open(&Target::Sqlite(path)).err().expect("refused");
        assert_eq!(e.kind(), ErrorKind::Schema);
        assert!(e.to_string().contains("99"), "{e}");
    }
}

mod postgres {
    use super::*;

    /// The server's URL (a database the tests may create databases from).
    fn server() -> Option<String> {
        match std::env::var("EASYCALIB_TEST_POSTGRES_URL") {
            Ok(u) if !u.is_empty() => Some(u),
            _ if std::env::var_os("CI").is_some() => {
                panic!("CI is set but EASYCALIB_TEST_POSTGRES_URL is not: .ci/run starts the server")
            }
            _ => {
                eprintln!("skipped: no PostgreSQL server (set EASYCALIB_TEST_POSTGRES_URL, docs/history.md)");
                None
            }
        }
    }

    /// A fresh database on the server, dropped when the guard goes.
    struct Fresh {
        admin: String,
        name: String,
        url: String,
    }

    impl Fresh {
        fn new(tag: &str) -> Option<Fresh> {
            let admin = server()?;
            let name = format!("easycalib_test_{tag}_{}", std::process::id());
            let mut c = ::postgres::Client::connect(&admin, ::postgres::NoTls).expect("the test server");
            c.batch_execute(&format!("DROP DATABASE IF EXISTS {name}")).unwrap();
            c.batch_execute(&format!("CREATE DATABASE {name}")).unwrap();
            let url = match admin.rsplit_once('/') {
                Some((base, tail)) => {
                    let query = tail.split_once('?').map_or(String::new(), |(_, q)| format!("?{q}"));
                    format!("{base}/{name}{query}")
                }
                None => panic!("EASYCALIB_TEST_POSTGRES_URL must end in /DATABASE"),
            };
            Some(Fresh { admin, name, url })
        }
    }

    impl Drop for Fresh {
        fn drop(&mut self) {
            if let Ok(mut c) = ::postgres::Client::connect(&self.admin, ::postgres::NoTls) {
                let _ = c.batch_execute(&format!("DROP DATABASE IF EXISTS {} WITH (FORCE)", self.name));
            }
        }
    }

    #[test]
    fn writes_are_idempotent_and_read_back() {
        let Some(db) = Fresh::new("rw") else { return };
        write_idempotent_and_read_back(history::open(&Target::parse(&db.url)).unwrap().as_mut());
    }

    #[test]
    fn four_writers_at_once_and_one_migration() {
        let Some(db) = Fresh::new("conc") else { return };
        four_concurrent_writers(&Target::parse(&db.url));
        let mut c = ::postgres::Client::connect(&db.url, ::postgres::NoTls).unwrap();
        let n: i64 = c.query_one("SELECT count(*) FROM schema_version", &[]).unwrap().get(0);
        assert_eq!(n, 1, "four writers connecting at once migrated once");
    }

    #[test]
    fn a_killed_writer_leaves_the_database_consistent() {
        let Some(db) = Fresh::new("kill") else { return };
        killed_writer_leaves_a_consistent_store(&db.url);
    }

    #[test]
    fn a_refused_connection_is_unreachable_and_the_queue_delivers_later() {
        let Some(db) = Fresh::new("queue") else { return };
        // A loopback port nobody listens on.
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let e =
            history::open(&Target::parse(&format!("postgres://easycalib:secret@127.0.0.1:{port}/x"))).err().unwrap();
        assert_eq!(e.kind(), ErrorKind::Unreachable, "{e}");
        assert!(!e.to_string().contains("secret"), "no password in messages: {e}");
        let dir = tempfile::tempdir().unwrap();
        let mut store = history::open(&Target::parse(&db.url)).unwrap();
        queue_delivers_exactly_once(store.as_mut(), &dir.path().join("queue"));
    }
}
