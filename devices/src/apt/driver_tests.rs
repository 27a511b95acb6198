//! Byte-exact transaction scripts against an in-memory pipe: the test
//! plays the unit, reading exactly what the driver must write.
use super::*;
use crate::apt::codec::{AptMessage, AptMessage as M, HOST, HomeParams, HwInfo, StatusPayload, encode, status};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream, duplex};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

async fn expect(dev: &mut DuplexStream, want: &str) {
    let want = hex(want);
    let mut got = vec![0u8; want.len()];
    dev.read_exact(&mut got).await.unwrap();
    assert_eq!(got, want);
}

async fn reply(dev: &mut DuplexStream, m: &AptMessage) {
    dev.write_all(&encode(m, HOST, USB_UNIT)).await.unwrap();
}

fn info() -> AptMessage {
    M::HwGetInfo(Box::new(HwInfo {
        serial: 27_000_123,
        model: "KDC101".into(),
        hw_type: 16,
        firmware: (3, 1, 4),
        notes: String::new(),
        reserved: [0; 10],
        stage_id: 9,
        hw_version: 1,
        mod_state: 0,
        n_channels: 1,
    }))
}

fn cfg() -> AptConfig {
    AptConfig { reply_timeout: Duration::from_millis(20), ..AptConfig::kdc101_z825b() }
}

/// Play the unit through the connect sequence; returns the connected stage.
async fn connected() -> (AptStage<DuplexStream>, DuplexStream) {
    let (host, mut dev) = duplex(4096);
    let unit = async {
        expect(&mut dev, "18 00 00 00 50 01 12 00 00 00 50 01 05 00 00 00 50 01").await;
        reply(&mut dev, &info()).await;
        // Enable, then VELPARAMS 2.3 mm/s, 4 mm/s²: the A.8 example frame.
        expect(&mut dev, "10 02 01 01 50 01").await;
        expect(&mut dev, "13 04 0E 00 D0 01 01 00 00 00 00 00 1F 04 00 00 C1 20 1B 00").await;
        dev
    };
    let (stage, dev) = tokio::join!(AptStage::connect(host, cfg()), unit);
    (stage.unwrap(), dev)
}

#[tokio::test]
async fn connect_sends_the_documented_bytes_and_reads_identity() {
    let (stage, _dev) = connected().await;
    let i = stage.hw_info().unwrap();
    assert_eq!((i.model.as_str(), i.serial, i.firmware), ("KDC101", 27_000_123, (3, 1, 4)));
}

#[tokio::test]
async fn wrong_model_is_refused() {
    let (host, mut dev) = duplex(4096);
    let unit = async {
        expect(&mut dev, "18 00 00 00 50 01 12 00 00 00 50 01 05 00 00 00 50 01").await;
        let mut m = info();
        if let M::HwGetInfo(i) = &mut m {
            i.model = "KST101".into();
        }
        reply(&mut dev, &m).await;
        dev
    };
    let (r, _dev) = tokio::join!(AptStage::connect(host, cfg()), unit);
    assert_eq!(r.unwrap_err().kind(), FaultKind::Protocol);
}

#[tokio::test]
async fn silence_is_a_timeout_and_garbage_a_protocol_error_with_its_bytes() {
    let (mut stage, mut dev) = connected().await;
    let e = stage.status().await.unwrap_err();
    assert!(matches!(e, AptError::Timeout { waiting_for: "MOT_GET_DCSTATUSUPDATE", .. }), "{e}");
    expect(&mut dev, "90 04 01 00 50 01").await;
    dev.write_all(&hex("34 12 00 00 01 50")).await.unwrap();
    match stage.status().await.unwrap_err() {
        AptError::Protocol { bytes, .. } => assert_eq!(&bytes[..2], &[0x34, 0x12]),
        e => panic!("{e}"),
    }
}

#[tokio::test]
async fn a_late_move_stopped_does_not_end_the_next_move() {
    let (mut stage, mut dev) = connected().await;
    stage.start_move_to(Mm(1.234)).await.unwrap();
    expect(&mut dev, "53 04 06 00 D0 01 01 00 91 A6 00 00").await;
    let idle = StatusPayload::dc(1, 0, 0, status::HOMED | status::ENABLED);
    let done = StatusPayload::dc(1, 42_641, 0, status::HOMED | status::ENABLED);
    reply(&mut dev, &M::MotMoveStopped(idle)).await;
    reply(&mut dev, &M::MotMoveCompleted(done)).await;
    let p = stage.wait_until_stopped(Duration::from_secs(5)).await.unwrap();
    assert_eq!(stage.config().scale.to_counts(p.0).unwrap(), 42_641);
}

#[tokio::test]
async fn device_errors_and_hangups_are_typed() {
    let (mut stage, mut dev) = connected().await;
    reply(&mut dev, &M::HwRichResponse { msg_id: 0x0443, code: 7, text: "no motor".into() }).await;
    let e = stage.home(Duration::from_secs(5)).await.unwrap_err();
    assert!(matches!(&e, AptError::DeviceReported { msg_id: 0x0443, code: 7, text } if text == "no motor"), "{e}");
    drop(dev);
    let e = stage.status().await.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Disconnected, "{e}");
}

#[tokio::test]
async fn soft_limit_refuses_without_writing() {
    let (mut stage, mut dev) = connected().await;
    assert_eq!(stage.start_move_to(Mm(25.01)).await.unwrap_err().kind(), FaultKind::Limit);
    assert_eq!(stage.start_move_to(Mm(-0.01)).await.unwrap_err().kind(), FaultKind::Limit);
    // Nothing was written: the next bytes the unit sees are the status request.
    let (r, ()) = tokio::join!(stage.status(), async {
        expect(&mut dev, "90 04 01 00 50 01").await;
        reply(&mut dev, &M::MotGetDcStatusUpdate(StatusPayload::dc(1, 5, 0, 0))).await;
    });
    assert_eq!(stage.config().scale.to_counts(r.unwrap().position).unwrap(), 5);
}

#[tokio::test]
async fn a_stale_move_completed_is_followed_to_the_target() {
    // A MOVE_COMPLETED left over from an earlier move (at 0 counts) ends the
    // link's wait at once; the axis polls on until the unit is at the target.
    let (mut stage, mut dev) = connected().await;
    let unit = tokio::spawn(async move {
        expect(&mut dev, "53 04 06 00 D0 01 01 00 91 A6 00 00").await;
        let idle = status::HOMED | status::ENABLED;
        reply(&mut dev, &M::MotMoveCompleted(StatusPayload::dc(1, 0, 0, idle))).await;
        for (counts, bits) in [(20_000, idle | status::MOVING_CW), (42_641, idle)] {
            expect(&mut dev, "90 04 01 00 50 01").await;
            reply(&mut dev, &M::MotGetDcStatusUpdate(StatusPayload::dc(1, counts, 0, bits))).await;
        }
        dev
    });
    let p = stage.move_to(Mm(1.234), Duration::from_secs(5)).await.unwrap();
    assert_eq!(stage.config().scale.to_counts(p.0).unwrap(), 42_641);
    unit.await.unwrap();
}

#[tokio::test]
async fn stop_returns_once_the_unit_stands_still() {
    let (mut stage, mut dev) = connected().await;
    let (r, ()) = tokio::join!(stage.start_move_to(Mm(20.0)), expect(&mut dev, "53 04 06 00 D0 01 01 00 9B 8B 0A 00"));
    r.unwrap();
    let (r, ()) = tokio::join!(stage.stop(), async {
        expect(&mut dev, "65 04 01 02 50 01").await;
        let bits = status::HOMED | status::ENABLED;
        // Still decelerating (a pushed update), then the stop's own answer.
        reply(&mut dev, &M::MotGetDcStatusUpdate(StatusPayload::dc(1, 180_000, 0, bits | status::MOVING_CW))).await;
        reply(&mut dev, &M::MotMoveStopped(StatusPayload::dc(1, 181_000, 0, bits))).await;
    });
    r.unwrap();
    let st = stage.last_status().unwrap();
    assert!(!st.moving);
    assert_eq!(stage.config().scale.to_counts(st.position).unwrap(), 181_000);
}

#[tokio::test]
async fn homing_sets_the_home_velocity_first_and_keeps_the_units_other_home_parameters() {
    let (mut stage, mut dev) = connected().await;
    let unit = async {
        // MOT_REQ_HOMEPARAMS; the unit answers its own: reverse, switch 1, 1 mm/s, offset 0.1 mm.
        expect(&mut dev, "41 04 01 00 50 01").await;
        let own = HomeParams { chan: 1, direction: 2, limit_switch: 1, velocity: 772_981, offset: 3_455 };
        reply(&mut dev, &M::MotGetHomeParams(own)).await;
        // MOT_SET_HOMEPARAMS with 2.3 mm/s (1 777 857, A.6), the rest as the unit had it; then MOVE_HOME.
        expect(&mut dev, "40 04 0E 00 D0 01 01 00 02 00 01 00 C1 20 1B 00 7F 0D 00 00").await;
        expect(&mut dev, "43 04 01 00 50 01").await;
        reply(&mut dev, &M::MotMoveHomed { chan: 1 }).await;
    };
    let (homed, ()) = tokio::join!(stage.home(Duration::from_secs(5)), unit);
    homed.unwrap();
}

#[tokio::test]
async fn set_max_speed_asks_the_units_velocity_parameters_and_keeps_its_acceleration() {
    use crate::apt::codec::VelParams;
    let (mut stage, mut dev) = connected().await;
    let unit = async {
        // MOT_REQ_VELPARAMS; the unit answers 2.3 mm/s, 4 mm/s² (1 777 857, 1055).
        expect(&mut dev, "14 04 01 00 50 01").await;
        let own = VelParams { chan: 1, min_velocity: 0, acceleration: 1055, max_velocity: 1_777_857 };
        reply(&mut dev, &M::MotGetVelParams(own)).await;
        // MOT_SET_VELPARAMS: 0.1 mm/s (77 298 = 0x012DF2), the same 4 mm/s².
        expect(&mut dev, "13 04 0E 00 D0 01 01 00 00 00 00 00 1F 04 00 00 F2 2D 01 00").await;
    };
    let (was, ()) = tokio::join!(stage.set_max_speed(0.1), unit);
    let was = was.unwrap().expect("the APT stage sets its speed");
    assert!((was - 2.3).abs() < 1e-6, "{was}");
}
