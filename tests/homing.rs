//! Homing on the emulated rig (real APT drivers over pseudo-terminals,
//! time-accelerated): the mount homes beside the stage's fast move only while
//! the indenter is known clear of the gel, the contact search waits for it,
//! and a fault while both move still backs the stage off (docs/run.md, "Homing").
//! The rig's motion log (one pose a sensor frame at least) is the witness.

use std::sync::Mutex;

use easycalib::rig::emulated::{EmulatedRig, ServeOptions};
use easycalib::rig::{RunRequest, RunResult, run_calibration};
use easycalib::run::events::{LogLevel, RunControl, RunEvent};
use easycalib::run::{Backoff, Culprit, RunStatus, Script};
use sim::emulator::apt::InjectedError;
use sim::emulator::served::mount_power_on_deg;
use sim::setup::SimSetupInput;
use tokio::sync::mpsc::unbounded_channel;

/// One rig at a time: two cores, real timeouts.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// A seed whose mount powers on far from its switch: a homing of 40 s or
/// more of rig time, long enough to overlap the stage's moves and to be hit.
fn long_homing_seed() -> u64 {
    (1..1000).find(|&s| mount_power_on_deg(s) > 200.0).expect("a seed with a long homing")
}

/// Run the default script on a fresh emulated rig with its motion logged;
/// `on_event` sees every event and may inject a fault or send a control.
fn run(
    on_event: impl Fn(&RunEvent, &EmulatedRig) -> Option<RunControl>,
) -> (RunResult, Vec<sim::emulator::rig::MotionSample>) {
    let _turn = ONE_AT_A_TIME.lock().unwrap_or_else(|p| p.into_inner());
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    rt.block_on(async {
        let setup =
            SimSetupInput { speedup: 40.0, seed: long_homing_seed(), ..SimSetupInput::default() }.resolve().unwrap();
        let rig = EmulatedRig::start(setup, ServeOptions::default()).await.unwrap();
        rig.rig().log_motion(true);
        let dir = tempfile::tempdir().unwrap();
        let req = RunRequest {
            spec: rig.spec(),
            script: Script::default(),
            out_dir: dir.path().to_path_buf(),
            truth: Some(rig.truth()),
            metadata: vec![],
            diagnose: false,
        };
        let (ev_tx, mut ev_rx) = unbounded_channel();
        let (ctl_tx, ctl_rx) = unbounded_channel();
        let task = tokio::spawn(run_calibration(req, ev_tx, ctl_rx));
        while let Some(ev) = ev_rx.recv().await {
            if let Some(c) = on_event(&ev, &rig) {
                let _ = ctl_tx.send(c);
            }
        }
        let r = task.await.unwrap().expect("devices open");
        (r, rig.rig().motion_log())
    })
}

#[test]
fn the_mount_homes_only_while_the_stage_is_clear_and_before_the_contact_search() {
    // The clear zone ends at the approach start (to an encoder count or two).
    let clear_mm = Script::default().approach.start_mm;
    // Stop at the first sample: homing and the contact search are behind.
    let (r, log) = run(|ev, _| matches!(ev, RunEvent::Sample(_)).then_some(RunControl::Abort));
    let RunStatus::Aborted(info) = &r.outcome.status else { panic!("{:?}", r.outcome.status) };
    assert_eq!(info.culprit, Culprit::Operator, "{info}");
    assert!(log.len() > 100, "{} poses logged", log.len());
    // The mount's homing turns it back from 360 + (power-on angle) to its
    // switch at 360 (its counter reads mechanical degrees until homed).
    let homing: Vec<_> = log.iter().filter(|m| m.rot_homing && m.rot_moving).collect();
    assert!(!homing.is_empty(), "the mount never homed");
    for m in &homing {
        assert!(m.stage_homed && m.pose.stage_mm <= clear_mm + 1e-4, "mount turning at {m:?}");
    }
    // The homing overlapped the stage's fast move to the approach start.
    assert!(homing.iter().any(|m| m.stage_moving), "the mount homed alone");
    // Deeper than the clear zone, the mount is homed and still.
    let deeper: Vec<_> = log.iter().filter(|m| m.pose.stage_mm > clear_mm + 1e-4).collect();
    assert!(!deeper.is_empty(), "the contact search never started");
    for m in &deeper {
        assert!(!m.rot_moving && m.pose.rot_deg.abs() < 1e-3, "contact search with the mount at {m:?}");
    }
    // The homing phase holds the mount's turn home, not the stage's homing on top of it.
    let homing_s = r.outcome.phase_rig_time_s.iter().find(|p| p.phase == "homing").unwrap().rig_time_s;
    let turn_s = mount_power_on_deg(long_homing_seed()) / 5.0;
    assert!(homing_s > turn_s && homing_s < turn_s + 8.0, "homing {homing_s:.1} s for a {turn_s:.1} s turn");
}

#[test]
fn a_mount_fault_while_both_axes_move_stops_both_and_backs_the_stage_off() {
    let (r, log) = run(|ev, rig| {
        if let RunEvent::Log { level: LogLevel::Info, message } = ev
            && message.starts_with("stage homed at")
        {
            rig.rotation().inject_error(InjectedError::Rich {
                msg_id: 0x0443,
                code: 7,
                text: "motor overcurrent".into(),
            });
        }
        None
    });
    let RunStatus::Aborted(info) = &r.outcome.status else { panic!("{:?}", r.outcome.status) };
    assert_eq!(info.culprit, Culprit::Mount, "{info}");
    assert!(info.message.contains("homing") && info.message.contains("motor overcurrent"), "{info}");
    let retract = Script::default().limits.retract_mm;
    assert!(matches!(info.backoff, Backoff::To(p) if (p - retract).abs() < 1e-3), "{info}");
    // Stopped both: the last pose has the stage back and neither axis moving.
    let last = log.last().expect("poses logged");
    assert!((last.pose.stage_mm - retract).abs() < 1e-3 && !last.rot_moving, "{last:?}");
    assert_eq!(r.outcome.samples, 0);
}
