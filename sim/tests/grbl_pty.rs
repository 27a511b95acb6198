//! `GrblStage` (devices) against the GRBL emulator (sim) over a real
//! pseudo-terminal. The driver opens the slave path with tokio-serial's
//! `SerialStream`, exactly as it opens `/dev/ttyACM0` (serialport ignores the
//! DTR ioctl that fails with ENOTTY on a pty). The rig runs 50x wall time;
//! the driver keeps real wall-clock timeouts.

use std::time::Duration;

use devices::grbl::{AlarmCode, GrblConfig, GrblError, GrblStage, MachineState};
use devices::{Axis, DeviceFault, FaultKind, Identify, Mm};
use sim::clock::VirtualClock;
use sim::emulator::grbl::{GrblEmulatorConfig, GrblPort, free_rotation_axis, serve_grbl_stage, stepper_stage_axis};
use sim::emulator::rig::Rig;
use tokio_serial::SerialStream;

const SPEEDUP: f64 = 50.0;
const LONG: Duration = Duration::from_secs(10);

fn rig(speedup: f64) -> Rig {
    Rig::new(VirtualClock::new(speedup), stepper_stage_axis(25.0), free_rotation_axis())
}

fn driver_cfg() -> GrblConfig {
    GrblConfig {
        travel_mm: (0.0, 25.0),
        feed_mm_per_min: 120.0,
        reply_timeout: Duration::from_secs(1),
        banner_timeout: Duration::from_secs(1),
        poll_interval: Duration::from_millis(5),
        ..GrblConfig::default()
    }
}

async fn setup() -> (Rig, GrblPort, GrblStage<SerialStream>) {
    setup_at(SPEEDUP).await
}

async fn setup_at(speedup: f64) -> (Rig, GrblPort, GrblStage<SerialStream>) {
    let rig = rig(speedup);
    let port = serve_grbl_stage(rig.clone(), GrblEmulatorConfig::default()).await.unwrap();
    let stage = GrblStage::open(port.path(), driver_cfg()).await.unwrap();
    (rig, port, stage)
}

#[tokio::test]
async fn connect_identify_home_and_move() {
    let (rig, port, mut stage) = setup().await;
    // Power-up homing lock: GRBL reports Alarm until homed.
    let st = stage.status().await.unwrap();
    assert!(!st.enabled && !st.homed);
    assert!(matches!(
        stage.start_move_to(Mm(1.0)).await,
        Err(GrblError::Rejected { code, .. }) if code.0 == 9
    ));

    let info = stage.identify().await.unwrap();
    assert_eq!(info.model, "GRBL 1.1h");
    assert_eq!(info.firmware, "1.1h.20190830");

    stage.home(LONG).await.unwrap();
    assert!(rig.with_stage(|ax, _| ax.is_homed()));
    let st = stage.status().await.unwrap();
    assert!(st.homed && st.enabled && !st.moving);
    assert!(st.position.abs() < 1e-9);

    let p = stage.move_to(Mm(2.5), LONG).await.unwrap().0;
    assert!((p - 2.5).abs() < 1e-3, "{p}");
    assert!((rig.pose().stage_mm - 2.5).abs() < 1e-3);

    let p = stage.move_by(Mm(-0.75), LONG).await.unwrap().0;
    assert!((p - 1.75).abs() < 1e-3, "{p}");
    assert!((rig.pose().stage_mm - 1.75).abs() < 1e-3);
    assert!((stage.position().await.unwrap().0 - 1.75).abs() < 1e-3);

    port.cut_cable();
    let stats = port.task.await.unwrap().unwrap();
    assert_eq!(stats.rx_overflow_bytes, 0);
    // `G1` with soft limits on, `$I`, `$H`, two moves: five lines, four without error.
    assert_eq!(stats.lines, 5);
    assert_eq!(stats.errors, 1);
}

#[tokio::test]
async fn stop_during_move_keeps_position() {
    // Slower rig here (20 mm take ~0.5 wall s) so the stop surely lands mid-move.
    let (rig, port, mut stage) = setup_at(20.0).await;
    stage.home(LONG).await.unwrap();
    stage.start_move_to(Mm(20.0)).await.unwrap();
    while stage.position().await.unwrap().0 < 0.5 {
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    stage.stop().await.unwrap();
    let st = stage.status().await.unwrap();
    assert!(!st.moving);
    assert!(st.position > 0.05 && st.position < 19.0, "{}", st.position);
    // Hold then reset: no ALARM:3, position kept, still homed.
    assert_eq!(stage.alarm(), None);
    assert!(st.enabled);
    assert!((rig.pose().stage_mm - st.position).abs() < 1e-3);
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    // The planner was flushed: the axis stays put and accepts a new move.
    let p = stage.move_to(Mm(1.0), LONG).await.unwrap().0;
    assert!((p - 1.0).abs() < 1e-3);
    port.cut_cable();
    let stats = port.task.await.unwrap().unwrap();
    assert_eq!(stats.alarms, 0);
}

#[tokio::test]
async fn move_past_travel_is_refused_before_sending() {
    let (rig, port, mut stage) = setup().await;
    stage.home(LONG).await.unwrap();
    let e = stage.start_move_to(Mm(25.5)).await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Limit);
    let e = stage.move_by(Mm(-0.1), LONG).await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Limit);
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    port.cut_cable();
    let stats = port.task.await.unwrap().unwrap();
    // Only `$H` ever reached the controller: no ALARM:2 from its own soft limits.
    assert_eq!(stats.lines, 1);
    assert_eq!(stats.alarms, 0);
}

#[tokio::test]
async fn emulator_alarm_is_device_reported_and_home_recovers() {
    let (rig, port, mut stage) = setup().await;
    stage.home(LONG).await.unwrap();
    stage.start_move_to(Mm(20.0)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(20)).await;
    port.inject_alarm(1);
    let e = stage.wait_until_stopped(LONG).await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::DeviceReported);
    assert!(matches!(e, GrblError::Alarm { code } if code == AlarmCode::HARD_LIMIT), "{e}");
    assert!(e.to_string().contains("Hard limit triggered"));
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    // Refused while locked, without sending.
    assert_eq!(stage.start_move_to(Mm(1.0)).await.unwrap_err().kind(), FaultKind::DeviceReported);
    // Re-homing resets the critical alarm and unlocks.
    stage.home(LONG).await.unwrap();
    assert_eq!(stage.alarm(), None);
    let p = stage.move_to(Mm(0.5), LONG).await.unwrap().0;
    assert!((p - 0.5).abs() < 1e-3);
}

#[tokio::test]
async fn cable_cut_mid_move_is_disconnected_within_a_second() {
    let (_rig, port, mut stage) = setup().await;
    stage.home(LONG).await.unwrap();
    stage.start_move_to(Mm(20.0)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(20)).await;
    port.cut_cable();
    // A one-second wait budget (and a one-second reply timeout): the only way
    // to get anything but Timeout is to notice the hang-up.
    let e = stage.wait_until_stopped(Duration::from_secs(1)).await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Disconnected, "{e}");
    port.task.await.unwrap().unwrap();
}

#[tokio::test]
async fn feed_hold_pauses_and_resume_finishes_the_move() {
    let (rig, port, mut stage) = setup_at(20.0).await;
    stage.home(LONG).await.unwrap();
    stage.start_move_to(Mm(20.0)).await.unwrap();
    while stage.position().await.unwrap().0 < 0.5 {
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let held = stage.feed_hold().await.unwrap();
    assert_eq!(held.state, MachineState::Hold(0));
    let at = rig.pose().stage_mm;
    assert!(at > 0.5 && at < 19.0, "{at}");
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    // Held, not finished: the axis stays put while held.
    let st = stage.status().await.unwrap();
    assert!(!st.moving);
    assert!((st.position - at).abs() < 1e-3);
    stage.resume().await.unwrap();
    let p = stage.wait_until_stopped(LONG).await.unwrap().0;
    assert!((p - 20.0).abs() < 1e-3, "{p}");
    assert!((rig.pose().stage_mm - 20.0).abs() < 1e-3);
    port.cut_cable();
    let stats = port.task.await.unwrap().unwrap();
    assert_eq!(stats.alarms, 0);
    assert_eq!(stats.resets, 1, "only the connect reset");
}

#[tokio::test]
async fn probe_identifies_the_emulator_without_moving_it() {
    let rig = rig(SPEEDUP);
    let port = serve_grbl_stage(rig.clone(), GrblEmulatorConfig::default()).await.unwrap();
    let before = rig.pose().stage_mm;
    let info = devices::grbl::probe(port.path(), Duration::from_secs(1)).await.unwrap();
    assert_eq!(info.model, "GRBL 1.1h");
    assert_eq!(info.firmware, "1.1h.20190830");
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    assert_eq!(rig.pose().stage_mm, before);
    port.cut_cable();
    let stats = port.task.await.unwrap().unwrap();
    // `$I` only (sent again after the power-up banner): no reset, no G-code.
    assert!((1..=2).contains(&stats.lines), "{stats:?}");
    assert_eq!(stats.resets, 0);
    assert_eq!(stats.errors, 0);
}

#[tokio::test]
async fn probe_still_identifies_grbl_after_an_apt_probe_went_first() {
    use tokio::io::AsyncWriteExt;
    let rig = rig(SPEEDUP);
    let port = serve_grbl_stage(rig.clone(), GrblEmulatorConfig::default()).await.unwrap();
    // What an APT prober sends on an unknown port (docs/hardware.md A.8):
    // HW_NO_FLASH_PROGRAMMING (its 0x18 is GRBL's soft reset) and HW_REQ_INFO
    // (its 'P' bytes stay in GRBL's line buffer).
    {
        let mut apt = devices::grbl::open_serial(port.path()).unwrap();
        apt.write_all(&[0x18, 0x00, 0x00, 0x00, 0x50, 0x01, 0x05, 0x00, 0x00, 0x00, 0x50, 0x01]).await.unwrap();
        apt.flush().await.unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let info = devices::grbl::probe(port.path(), Duration::from_secs(1)).await.unwrap();
    assert_eq!(info.model, "GRBL 1.1h");
    assert_eq!(info.firmware, "1.1h.20190830");
    assert!(!rig.with_stage(|ax, _| ax.is_moving()));
    port.cut_cable();
    let stats = port.task.await.unwrap().unwrap();
    assert_eq!(stats.alarms, 0);
}
