//! The calibration run end to end: the emulated rig (APT or GRBL stage, APT
//! rotation mount, simulated sensor on easycalib's link protocol), each device
//! behind a real pseudo-terminal, driven by the real drivers through
//! `easycalib::rig::run_calibration` exactly as `easycalib run` does; time
//! accelerated, the drivers keep real timeouts. Faults are injected at a chosen
//! point by watching the run's own event stream.
//!
//! The runs share two cores with the rest of the suite, so they take turns.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::Duration;

use devices::apt::{AptConfig, AptStage};
use devices::serial::open_serial_settle;
use devices::{Axis, Identify, Mm};
use easycalib::fit::{FitOptions, calibrate};
use easycalib::rig::emulated::{CONTACT_STAGE_MM, EmulatedRig, ServeOptions};
use easycalib::rig::{RunRequest, RunResult, run_calibration};
use easycalib::run::events::RunEvent;
use easycalib::run::{Backoff, Culprit, RunStatus, Script};
use sim::emulator::apt::InjectedError;
use sim::recording::{Direction, Phase, Recording};
use sim::setup::{SimSetup, SimSetupInput};
use tokio::sync::mpsc::unbounded_channel;

/// One rig at a time: two cores, real timeouts.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

const SPEEDUP: f64 = 40.0;

/// Run `body` on its own runtime while no other rig runs.
fn one_at_a_time<F: std::future::Future>(body: F) -> F::Output {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    rt.block_on(body)
}

/// The default simulated rig at the tests' speed-up.
fn setup() -> SimSetup {
    SimSetupInput { speedup: SPEEDUP, ..SimSetupInput::default() }.resolve().unwrap()
}

async fn rig(grbl: bool) -> EmulatedRig {
    EmulatedRig::start(setup(), ServeOptions { grbl, ..ServeOptions::default() }).await.unwrap()
}

/// Run the default script (with `tweak`) on `rig`, without the diagnosis at
/// the end; after the `at`-th recorded sample, call `fault`. Returns the
/// result and every event.
async fn run_on(
    rig: &EmulatedRig,
    dir: &Path,
    tweak: impl FnOnce(&mut Script),
    at: usize,
    fault: impl FnOnce(&EmulatedRig),
) -> (RunResult, Vec<RunEvent>) {
    run_with(rig, dir, tweak, at, fault, false).await
}

/// [`run_on`], with the diagnosis when `diagnose`.
async fn run_with(
    rig: &EmulatedRig,
    dir: &Path,
    tweak: impl FnOnce(&mut Script),
    at: usize,
    fault: impl FnOnce(&EmulatedRig),
    diagnose: bool,
) -> (RunResult, Vec<RunEvent>) {
    let mut script = Script::default();
    tweak(&mut script);
    let req = RunRequest {
        spec: rig.spec(),
        script,
        out_dir: dir.to_path_buf(),
        truth: Some(rig.truth()),
        metadata: vec![("test".into(), "run_e2e".into())],
        diagnose,
    };
    let (ev_tx, mut ev_rx) = unbounded_channel();
    let (_ctl_tx, ctl_rx) = unbounded_channel();
    let task = tokio::spawn(run_calibration(req, ev_tx, ctl_rx));
    let mut events = Vec::new();
    let mut samples = 0;
    let mut fault = Some(fault);
    while let Some(ev) = ev_rx.recv().await {
        if matches!(ev, RunEvent::Sample(_)) {
            samples += 1;
            if samples == at
                && let Some(f) = fault.take()
            {
                f(rig);
            }
        }
        events.push(ev);
    }
    (task.await.unwrap().expect("devices open"), events)
}

fn sample_events(events: &[RunEvent]) -> usize {
    events.iter().filter(|e| matches!(e, RunEvent::Sample(_))).count()
}

fn aborted(r: &RunResult) -> &easycalib::run::AbortInfo {
    match &r.outcome.status {
        RunStatus::Aborted(info) => info,
        RunStatus::Completed => panic!("the run should have aborted"),
    }
}

/// The recording left behind is readable and holds every sample announced.
fn check_recording(r: &RunResult, events: &[RunEvent], at_least: usize) -> Recording {
    let rec = Recording::read_path(&r.outcome.recording).expect("readable recording after the abort");
    assert_eq!(rec.samples.len(), sample_events(events));
    assert_eq!(rec.samples.len(), r.outcome.samples);
    assert!(rec.samples.len() >= at_least, "{} samples", rec.samples.len());
    assert!(r.calibration.is_none() && r.report.is_none());
    assert!(events.iter().any(|e| matches!(e, RunEvent::Aborted { .. })));
    assert!(!events.iter().any(|e| matches!(e, RunEvent::Finished { .. })));
    rec
}

/// The diagnosis a run made: announced by its event just before `Finished`,
/// written into report.json beside the calibration (whose top-level values it
/// leaves alone), and E1/nu1 are the calibration's unless an effect was named.
fn check_run_diagnosis(r: &RunResult, events: &[RunEvent], v: &serde_json::Value, (e1, nu1): (f64, f64)) {
    let d = r.diagnosis.as_ref().expect("the run diagnosed its recording");
    eprintln!("diagnosis ({:.2} s): {}", d.wall_time_s, d.summary);
    let n = events.len();
    assert!(matches!(&events[n - 2], RunEvent::Diagnosis(ev) if **ev == *d), "{:?}", &events[n - 2]);
    let j = &v["diagnosis"];
    assert_eq!(j["verdict"].as_str(), Some(d.verdict.as_str()));
    assert_ne!(d.verdict.as_str(), "not_made", "{:?}", d.error);
    assert_eq!(j["effects"].as_array().map(Vec::len), Some(d.effects.len()));
    assert_eq!(j["E1_MPa"].as_f64(), Some(d.e1_mpa));
    assert!(j["ci95"]["nu1"][0].as_f64().unwrap() <= d.nu1 && d.nu1 <= j["ci95"]["nu1"][1].as_f64().unwrap());
    assert_eq!(v["E1_MPa"].as_f64(), Some(e1), "the run's own answer stays the calibration's");
    if d.effects.is_empty() {
        assert_eq!((d.e1_mpa, d.nu1), (e1, nu1));
    }
}

#[test]
fn default_run_through_the_real_drivers_recovers_the_truth() {
    one_at_a_time(async {
        let dir = tempfile::tempdir().unwrap();
        let rig = rig(false).await;
        let (r, events) = run_with(&rig, dir.path(), |_| {}, usize::MAX, |_| {}, true).await;
        assert_eq!(r.outcome.status, RunStatus::Completed, "{:?}", r.outcome.status);
        let truth = rig.truth();
        let cal = r.calibration.as_ref().expect("fit");
        let (e1, nu1) = (cal.full.e1_mpa, cal.full.nu1);
        eprintln!(
            "default emulated run: {} samples, rig {:.1} s, wall {:.2} s, E1 {e1:.4} (truth {}), nu1 {nu1:.4} (truth {})",
            r.outcome.samples, r.outcome.rig_time_s, r.outcome.wall_time_s, truth.e1_mpa, truth.nu1
        );
        assert!((e1 / truth.e1_mpa - 1.0).abs() < 0.01, "E1 {e1} vs {}", truth.e1_mpa);
        assert!((nu1 / truth.nu1 - 1.0).abs() < 0.02, "nu1 {nu1} vs {}", truth.nu1);
        // The contact was found where the simulated elastomer is.
        let contact = r.outcome.contact_mm.unwrap();
        // (Found a few tens of µm late: the sensor's dead band; the fit's contact offset takes it up.)
        assert!((contact - CONTACT_STAGE_MM).abs() < 0.1, "contact at {contact} mm");

        // The recording, read back and fitted on its own, gives the same result.
        let rec = Recording::read_path(&r.outcome.recording).unwrap();
        assert_eq!(rec.samples.len(), sample_events(&events));
        // Both branches of the normal sweep, and the paper's method's window
        // (at least 4 samples with gamma1 in 0.2-0.8 mm) covered.
        let branch = |d: Direction| rec.phase(Phase::Normal).filter(|s| s.dir == Some(d)).count();
        assert!(branch(Direction::Load) >= 10 && branch(Direction::Unload) >= 10);
        assert!(rec.phase(Phase::Normal).filter(|s| (0.2..=0.8).contains(&s.gamma1_mm)).count() >= 4);
        assert_eq!(rec.phase(Phase::Torsion).count(), Script::default().twist_samples());
        let again = calibrate(&rec, &FitOptions::default()).unwrap();
        assert_eq!((again.full.e1_mpa, again.full.nu1), (e1, nu1));
        assert!(rec.meta.extra.iter().any(|(k, v)| k == "sim_E1_MPa" && v.parse::<f64>().unwrap() == truth.e1_mpa));

        // The report: JSON with the truth, Markdown and both figures.
        let files = r.report.as_ref().unwrap();
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
        assert_eq!(v["sim_truth"]["E1_MPa"].as_f64(), Some(truth.e1_mpa));
        assert_eq!(v["E1_MPa"].as_f64(), Some(e1));
        assert!(std::fs::read_to_string(&files.markdown).unwrap().contains("normal_sweep.svg"));
        // The report's timings: every phase took rig time, they add up to the
        // run's, and homing holds the K10CR1's turn back to its switch from
        // its seeded power-on angle at 5 deg/s.
        let run = &v["run"];
        assert_eq!(run["rig_time_s"].as_f64(), Some(r.outcome.rig_time_s));
        let phases: Vec<(&str, f64)> = run["phases"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| (p["phase"].as_str().unwrap(), p["rig_time_s"].as_f64().unwrap()))
            .collect();
        eprintln!("rig time per phase: {phases:?}");
        let names: Vec<&str> = phases.iter().map(|p| p.0).collect();
        assert_eq!(names, ["homing", "approach", "normal", "torsion", "retract"]);
        assert!(phases.iter().all(|p| p.1 > 0.0), "{phases:?}");
        let sum: f64 = phases.iter().map(|p| p.1).sum();
        assert!((sum - r.outcome.rig_time_s).abs() < 1e-6 * sum, "{sum} vs {}", r.outcome.rig_time_s);
        let turn_s = sim::emulator::served::mount_power_on_deg(setup().seed()) / 5.0;
        assert!(phases[0].1 > turn_s, "homing {} s for a {turn_s:.1} s turn", phases[0].1);
        assert!(std::fs::read_to_string(&files.markdown).unwrap().contains("| run | rig time"));
        assert!(std::fs::read_to_string(&files.torsion_svg).unwrap().starts_with("<svg"));
        check_run_diagnosis(&r, &events, &v, (e1, nu1));
        // The run ended with the summary, and the stage is parked out of contact.
        assert!(matches!(events.last(), Some(RunEvent::Finished { summary }) if summary.e1_mpa == Some(e1)));
        let pose = rig.pose();
        assert!((pose.stage_mm - Script::default().park_mm()).abs() < 1e-3, "{pose:?}");
    });
}

#[test]
fn stage_cable_cut_mid_sweep() {
    one_at_a_time(async {
        let dir = tempfile::tempdir().unwrap();
        let rig = rig(false).await;
        let (r, events) = run_on(&rig, dir.path(), |_| {}, 25, |rig| rig.cut_stage()).await;
        let info = aborted(&r);
        eprintln!("cut: {info}");
        assert_eq!(info.culprit, Culprit::Stage);
        assert!(info.message.contains("stage") && info.message.contains("disconnected"), "{}", info.message);
        // Nobody can move a stage whose cable is cut: the abort says so.
        assert!(matches!(&info.backoff, Backoff::Failed(m) if m.contains("disconnected")), "{:?}", info.backoff);
        let rec = check_recording(&r, &events, 25);
        // The stage did not go past the move it was given when the cable was
        // cut, and that move was one step of the sweep beyond its deepest
        // sample (the step the sweep takes there: 0.05, 0.1 or 1.3 mm).
        let deepest = rec.samples.iter().map(|s| s.stage_mm).fold(f64::MIN, f64::max) + r.outcome.contact_mm.unwrap();
        let target: f64 = info
            .message
            .split("move to ")
            .nth(1)
            .and_then(|t| t.split(" mm").next())
            .and_then(|t| t.parse().ok())
            .unwrap_or_else(|| panic!("the abort names the move: {}", info.message));
        let n = Script::default().normal;
        let step = n.step_mm.max(n.window_step_mm).max(Script::default().approach.step_mm);
        assert!(target <= deepest + step + 1e-3, "move to {target} mm past one step ({step} mm) from {deepest}");
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert!(rig.pose().stage_mm <= target + 1e-3, "{:?} vs the move's target {target}", rig.pose());
    });
}

#[test]
fn sensor_stream_stopping_mid_sweep() {
    one_at_a_time(async {
        let dir = tempfile::tempdir().unwrap();
        let rig = rig(false).await;
        let (r, events) =
            run_on(&rig, dir.path(), |s| s.timeouts.sensor_dropout_s = 1.0, 25, |rig| rig.silence_sensor(true)).await;
        let info = aborted(&r);
        eprintln!("silenced: {info}");
        assert_eq!(info.culprit, Culprit::Sensor);
        assert!(info.message.contains("sensor"), "{}", info.message);
        check_recording(&r, &events, 25);
        // Backed off to the retract position.
        let retract = Script::default().limits.retract_mm;
        assert!(matches!(info.backoff, Backoff::To(p) if (p - retract).abs() < 1e-3), "{:?}", info.backoff);
        assert!((rig.pose().stage_mm - retract).abs() < 1e-3, "{:?}", rig.pose());
    });
}

#[test]
fn apt_device_error_mid_sweep() {
    one_at_a_time(async {
        let dir = tempfile::tempdir().unwrap();
        let rig = rig(false).await;
        let (r, events) = run_on(
            &rig,
            dir.path(),
            |_| {},
            25,
            |rig| {
                assert!(rig.inject_stage_error(InjectedError::Rich {
                    msg_id: 0x0453,
                    code: 7,
                    text: "motor overcurrent".into()
                }))
            },
        )
        .await;
        let info = aborted(&r);
        eprintln!("device error: {info}");
        assert_eq!(info.culprit, Culprit::Stage);
        assert!(info.message.contains("motor overcurrent"), "{}", info.message);
        check_recording(&r, &events, 25);
        let retract = Script::default().limits.retract_mm;
        assert!(matches!(info.backoff, Backoff::To(p) if (p - retract).abs() < 1e-3), "{:?}", info.backoff);
        assert!((rig.pose().stage_mm - retract).abs() < 1e-3, "{:?}", rig.pose());
    });
}

#[test]
fn grbl_alarm_mid_sweep() {
    one_at_a_time(async {
        let dir = tempfile::tempdir().unwrap();
        let rig = rig(true).await;
        let (r, events) = run_on(&rig, dir.path(), |_| {}, 25, |rig| assert!(rig.inject_stage_alarm(1))).await;
        let info = aborted(&r);
        eprintln!("GRBL alarm: {info}; pose {:?}", rig.pose());
        assert_eq!(info.culprit, Culprit::Stage);
        assert!(info.message.contains("GRBL") && info.message.contains("ALARM"), "{}", info.message);
        check_recording(&r, &events, 25);
        // Unlocked and backed off out of contact, to the retract position.
        let retract = Script::default().limits.retract_mm;
        assert!(matches!(info.backoff, Backoff::To(p) if (p - retract).abs() < 1e-3), "{:?}", info.backoff);
        assert!((rig.pose().stage_mm - retract).abs() < 1e-3, "{:?}", rig.pose());
    });
}

#[test]
fn sim_serve_prints_devices_an_apt_client_can_drive() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let mut child = Command::new(env!("CARGO_BIN_EXE_easycalib"))
        .args(["sim", "serve", "--speedup", "20"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let mut devices = Vec::new();
    for _ in 0..3 {
        let line = lines.next().unwrap().unwrap();
        let (name, path) = line.split_once(' ').unwrap();
        devices.push((name.to_string(), path.to_string()));
    }
    let names: Vec<&str> = devices.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["stage", "rotation", "sensor"]);
    assert!(devices.iter().all(|(_, p)| p.starts_with("/dev/pts/")), "{devices:?}");
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    let result = rt.block_on(async {
        let io = open_serial_settle(&devices[0].1, Duration::ZERO).await.unwrap();
        let mut stage = AptStage::connect(io, AptConfig::kdc101_z825b()).await.unwrap();
        let info = stage.identify().await.unwrap();
        stage.home(Duration::from_secs(10)).await.unwrap();
        let p = stage.move_to(Mm(1.0), Duration::from_secs(10)).await.unwrap().0;
        (info, p)
    });
    let _ = child.kill();
    let _ = child.wait();
    let (info, p) = result;
    assert_eq!(info.model, "KDC101");
    assert!((p - 1.0).abs() < 1e-3, "{p}");
}

#[test]
fn ctrl_c_aborts_the_cli_run_backs_off_and_keeps_the_recording() {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let dir = tempfile::tempdir().unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_easycalib"))
        .args(["run", "--no-history", "--out", dir.path().to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Plain progress lines (stdout is a pipe): interrupt once the normal sweep records.
    let stdout = BufReader::new(child.stdout.take().unwrap());
    let mut lines = stdout.lines();
    for line in lines.by_ref() {
        let line = line.unwrap();
        if line.contains("normal sweep 1/1") && line.contains("% elapsed") {
            break;
        }
    }
    // SAFETY: kill(2) on our own child's pid with SIGINT, as Ctrl-C in a terminal.
    assert_eq!(unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) }, 0);
    let rest: Vec<String> = lines.map(|l| l.unwrap()).collect();
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(4), "stderr: {err}");
    assert!(err.contains("run aborted by operator") && err.contains("backed off to 0.000 mm"), "{err}");
    assert!(rest.iter().any(|l| l.contains("ABORTED")), "{rest:?}");
    let rec = Recording::read_path(&dir.path().join("recording.csv")).expect("readable recording");
    assert!(rec.phase(Phase::Normal).count() > 0);
    assert!(!dir.path().join("report.json").exists(), "no report for an aborted run");
}

#[test]
fn tac3d_sensor_over_loopback_udp_reads_the_emulated_press() {
    use easycalib::rig::connect::open_sensor;
    use easycalib::rig::emulated::EmulatedSensor;
    use easycalib::rig::{SensorSpec, measure_frame};
    use easycalib::run::gauge::{Gauge, SensorGauge};
    use easycalib::sensing::{FrameEstimator, SensingConfig};

    one_at_a_time(async {
        // A free loopback port for the receiver (the emulated Tac3D sends to it).
        let port = std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let to: std::net::SocketAddr = format!("127.0.0.1:{port}").parse().unwrap();
        let rig = EmulatedRig::start(
            setup(),
            ServeOptions { sensor: EmulatedSensor::Tac3d { to }, ..ServeOptions::default() },
        )
        .await
        .unwrap();
        assert_eq!(rig.spec().sensor, SensorSpec::Tac3d { bind: to, source: None });
        assert_eq!(rig.device_lines()[2], format!("sensor udp://{to}"));
        let link = open_sensor(&rig.spec().sensor).await.unwrap();
        let mut estimator = FrameEstimator::new(SensingConfig::for_contact(5.0, f64::INFINITY));
        let measure = move |f: &devices::sensor::SensorFrame| measure_frame(&mut estimator, f);
        let mut gauge = SensorGauge::new(link, measure, "tac3d");
        gauge.start().await.unwrap();
        // Out of contact: a valid reading of zero.
        let r = gauge.read(Duration::from_secs(2)).await.unwrap();
        assert_eq!(r.gamma1_mm, 0.0);
        // Press 0.5 mm past the contact point: gamma1 becomes most of the approach
        // (the indenter is three times stiffer than the elastomer).
        rig.rig().with_stage(|ax, t| ax.command_move_to(t, CONTACT_STAGE_MM + 0.5));
        let mut last = 0.0;
        for _ in 0..2000 {
            last = gauge.read(Duration::from_secs(2)).await.unwrap().gamma1_mm;
            if last > 0.3 && (rig.pose().stage_mm - (CONTACT_STAGE_MM + 0.5)).abs() < 1e-6 {
                break;
            }
        }
        assert!(last > 0.3 && last < 0.5, "gamma1 {last} mm at a 0.5 mm approach");
        assert!(gauge.link_stats().frames > 0);
    });
}

#[test]
fn a_second_calibration_on_homed_devices_skips_homing_and_says_so() {
    one_at_a_time(async {
        let rig = rig(false).await;
        let homing_s = |r: &RunResult| {
            let v: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&r.report.as_ref().unwrap().json).unwrap()).unwrap();
            v["run"]["phases"][0]["rig_time_s"].as_f64().unwrap()
        };
        let logs = |events: &[RunEvent]| -> Vec<String> {
            events
                .iter()
                .filter_map(|e| if let RunEvent::Log { message, .. } = e { Some(message.clone()) } else { None })
                .collect()
        };
        let first = tempfile::tempdir().unwrap();
        let (r1, ev1) = run_on(&rig, first.path(), |_| {}, usize::MAX, |_| {}).await;
        assert_eq!(r1.outcome.status, RunStatus::Completed);
        assert!(logs(&ev1).iter().any(|m| m.starts_with("homed:")), "{:?}", logs(&ev1));
        // The same powered rig again: both controllers still report homed.
        let second = tempfile::tempdir().unwrap();
        let (r2, ev2) = run_on(&rig, second.path(), |_| {}, usize::MAX, |_| {}).await;
        assert_eq!(r2.outcome.status, RunStatus::Completed);
        assert!(logs(&ev2).iter().any(|m| m.starts_with("already homed, homing skipped")), "{:?}", logs(&ev2));
        let (h1, h2) = (homing_s(&r1), homing_s(&r2));
        eprintln!(
            "homing: first run {h1:.1} s, second {h2:.1} s; rig time {:.1} s -> {:.1} s",
            r1.outcome.rig_time_s, r2.outcome.rig_time_s
        );
        // The K10CR1 alone turns back to its switch from its seeded power-on
        // angle at 5 deg/s; skipped, the phase holds only the stage's fast
        // move to the approach start (10 mm at 2.3 mm/s) and the rest readings.
        let turn_s = sim::emulator::served::mount_power_on_deg(setup().seed()) / 5.0;
        assert!(h1 > turn_s && h2 < 8.0 && h2 < h1, "{h1} {h2} (turn {turn_s:.1} s)");
        // And the answer is the same calibration.
        let truth = rig.truth();
        let cal = r2.calibration.as_ref().unwrap();
        assert!((cal.full.e1_mpa / truth.e1_mpa - 1.0).abs() < 0.01 && (cal.full.nu1 / truth.nu1 - 1.0).abs() < 0.02);
    });
}
