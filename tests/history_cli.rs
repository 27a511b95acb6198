//! The history from the command line: a run on the emulated rig whose
//! history server refuses the connection still completes and keeps its files;
//! its result is queued and `history sync` delivers it exactly once; then
//! listing, plotting, import and export of what was delivered.

use std::path::Path;
use std::process::{Command, Output, Stdio};

fn easycalib(home: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_easycalib"))
        .args(args)
        .env("EASYCALIB_HOME", home)
        .env_remove("EASYCALIB_DB")
        .stdin(Stdio::null())
        .output()
        .expect("easycalib runs")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Where the queued result goes: the test PostgreSQL server when there is one
/// (a fresh database), else a SQLite file.
fn sync_target(dir: &Path) -> (String, Option<(String, String)>) {
    let Ok(admin) = std::env::var("EASYCALIB_TEST_POSTGRES_URL") else {
        assert!(std::env::var_os("CI").is_none(), "CI is set but EASYCALIB_TEST_POSTGRES_URL is not");
        eprintln!("no PostgreSQL server: the queue is synced into SQLite");
        return (dir.join("synced.sqlite").display().to_string(), None);
    };
    let name = format!("easycalib_cli_{}", std::process::id());
    let mut c = postgres::Client::connect(&admin, postgres::NoTls).unwrap();
    c.batch_execute(&format!("DROP DATABASE IF EXISTS {name}")).unwrap();
    c.batch_execute(&format!("CREATE DATABASE {name}")).unwrap();
    let (base, _) = admin.rsplit_once('/').unwrap();
    (format!("{base}/{name}"), Some((admin, name)))
}

#[test]
fn an_unreachable_server_queues_the_run_and_sync_delivers_it_once() {
    let dir = tempfile::tempdir().unwrap();
    let home = dir.path().join("home");
    let out = dir.path().join("run");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let refused = format!("postgres://easycalib@127.0.0.1:{port}/fleet");
    let o =
        easycalib(&home, &["run", "--speedup", "400", "--seed", "3", "--out", out.to_str().unwrap(), "--db", &refused]);
    let t = text(&o);
    assert!(o.status.success(), "the run completes: {t}");
    assert!(out.join("recording.csv").is_file() && out.join("report.json").is_file(), "its files are written");
    assert!(t.contains("cannot reach the history database") && t.contains("queued"), "{t}");
    let queued: Vec<_> = std::fs::read_dir(home.join("queue")).unwrap().collect();
    assert_eq!(queued.len(), 2, "one record and its recording");

    let (db, pg) = sync_target(dir.path());
    let o = easycalib(&home, &["history", "sync", "--db", &db]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("1 delivered, 0 already there, 0 failed"), "{}", text(&o));
    let o = easycalib(&home, &["history", "sync", "--db", &db]);
    assert!(text(&o).contains("nothing queued"), "{}", text(&o));

    // Delivered once: the list, the export, and an import of the same folder.
    let o = easycalib(&home, &["history", "--json", "--db", &db]);
    assert!(o.status.success(), "{}", text(&o));
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let sensors = doc["sensors"].as_array().unwrap();
    assert_eq!(sensors.len(), 1);
    let cal = &sensors[0]["calibrations"].as_array().unwrap()[0];
    assert_eq!(sensors[0]["calibrations"].as_array().unwrap().len(), 1);
    assert_eq!(cal["source"], "run");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(cal["e1_mpa"], report["E1_MPa"], "the run's answer, unchanged");
    assert!(cal["script"].as_str().unwrap().contains("[approach]"), "the script is kept");
    let sensor = sensors[0]["sensor"].as_str().unwrap().to_string();

    let o = easycalib(&home, &["history", "import", out.to_str().unwrap(), "--db", &db]);
    assert!(text(&o).contains("0 imported, 1 already there"), "{}", text(&o));
    let csv_path = dir.path().join("h.csv");
    let o = easycalib(&home, &["history", "export", "--csv", "-o", csv_path.to_str().unwrap(), "--db", &db]);
    assert!(o.status.success(), "{}", text(&o));
    let csv = std::fs::read_to_string(&csv_path).unwrap();
    assert_eq!(csv.lines().count(), 2, "{csv}");
    assert!(csv.starts_with("id,sensor,time_utc,source,model,e1_mpa"), "{csv}");
    let svg = dir.path().join("h.svg");
    let o = easycalib(&home, &["history", &sensor, "--plot", svg.to_str().unwrap(), "--db", &db]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(std::fs::read_to_string(&svg).unwrap().starts_with("<svg"));
    let o = easycalib(&home, &["history", "no-such-sensor", "--db", &db]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));

    if let Some((admin, name)) = pg {
        let mut c = postgres::Client::connect(&admin, postgres::NoTls).unwrap();
        let _ = c.batch_execute(&format!("DROP DATABASE IF EXISTS {name} WITH (FORCE)"));
    }
}

#[test]
fn fit_record_writes_the_default_history_and_says_what_changed() {
    let dir = tempfile::tempdir().unwrap();
    let home = dir.path().join("home");
    for seed in ["1", "2"] {
        let rec = dir.path().join(format!("r{seed}.csv"));
        let o = easycalib(&home, &["simulate", "--seed", seed, "-o", rec.to_str().unwrap()]);
        assert!(o.status.success());
        let o = easycalib(&home, &["fit", rec.to_str().unwrap(), "--record"]);
        assert!(o.status.success(), "{}", text(&o));
        let t = text(&o);
        assert!(t.contains("history: recorded in SQLite"), "{t}");
        if seed == "2" {
            assert!(t.contains("no change beyond the repeatability"), "{t}");
        }
    }
    assert!(home.join("history.sqlite").is_file(), "the default store lives in EASYCALIB_HOME");
    // A second --record of the same file stores nothing new.
    let o = easycalib(&home, &["fit", dir.path().join("r1.csv").to_str().unwrap(), "--record"]);
    assert!(text(&o).contains("already recorded"), "{}", text(&o));
    // Without --record nothing is written.
    let o = easycalib(&home, &["history", "--json"]);
    let doc: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(doc["sensors"][0]["calibrations"].as_array().unwrap().len(), 2);
}
