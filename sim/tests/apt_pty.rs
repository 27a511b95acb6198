//! The real APT drivers against the APT emulator over real pseudo-terminals,
//! with the rig's motion time-accelerated (the drivers keep wall-clock
//! timeouts). Covers identify, home, absolute / relative moves, stop, soft
//! limits, a cut cable, device-reported errors, and the raw byte sequences an
//! independent client sends on connect.

use std::time::Duration;

use devices::apt::codec::{Addressing, AptDecoder, AptMessage, Frame, decode_frame, status};
use devices::apt::{AptConfig, AptError, AptRotation, AptStage, probe};
use devices::serial::open_serial_settle;
use devices::{Axis, Deg, DeviceFault, FaultKind, Identify, Mm};
use sim::clock::VirtualClock;
use sim::emulator::apt::{
    AptEmulatorConfig, EmulatorHandle, InjectedError, k10cr1_axis, spawn_apt, spawn_apt_rotation, spawn_apt_stage,
    z8_axis,
};
use sim::emulator::rig::Rig;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::SerialStream;

const T: Duration = Duration::from_secs(10);

fn rig(speedup: f64) -> Rig {
    Rig::new(VirtualClock::new(speedup), z8_axis(25.0), k10cr1_axis())
}

async fn port(h: &EmulatorHandle) -> SerialStream {
    open_serial_settle(h.path(), Duration::ZERO).await.expect("open pty slave")
}

async fn stage(speedup: f64) -> (Rig, EmulatorHandle, AptStage<SerialStream>) {
    let rig = rig(speedup);
    let h = spawn_apt_stage(rig.clone()).unwrap();
    let s = AptStage::connect(port(&h).await, AptConfig::kdc101_z825b()).await.unwrap();
    (rig, h, s)
}

async fn rotation(speedup: f64) -> (Rig, EmulatorHandle, AptRotation<SerialStream>) {
    let rig = rig(speedup);
    let h = spawn_apt_rotation(rig.clone()).unwrap();
    let r = AptRotation::connect(port(&h).await, AptConfig::k10cr1()).await.unwrap();
    (rig, h, r)
}

fn z8_counts(mm: f64) -> f64 {
    mm * 34_554.96
}

#[tokio::test]
async fn stage_identifies_and_connects_with_the_documented_sequence() {
    let (_rig, h, mut s) = stage(100.0).await;
    let info = s.identify().await.unwrap();
    assert_eq!(info.model, "KDC101");
    assert_eq!(info.serial, "27000001");
    assert_eq!(info.firmware, "3.0.10");
    // A.5 start-up: no-flash, stop updates, identify, enable, set velocity; then our identify.
    // (The once-a-second keep-alive 0x0492 may interleave on a slow machine.)
    let ids: Vec<u16> = h.received().into_iter().filter(|&id| id != 0x0492).collect();
    assert_eq!(ids, vec![0x0018, 0x0012, 0x0005, 0x0210, 0x0413, 0x0005]);
    // The velocity parameters the driver set are what the unit now reports (2.3 mm/s, 4 mm/s²).
    let (v, a) = s.velocity_params().await.unwrap();
    assert!((v - 2.3).abs() < 1e-6, "{v}");
    assert!((a - 4.0).abs() < 2e-3, "{a}");
}

#[tokio::test]
async fn probe_only_identifies() {
    let rig = rig(100.0);
    let h = spawn_apt_stage(rig.clone()).unwrap();
    let before = rig.pose();
    let info = probe(h.path(), Duration::from_secs(1)).await.unwrap();
    assert_eq!(info.model, "KDC101");
    assert_eq!(h.received(), vec![0x0005]);
    assert_eq!(rig.pose().stage_mm, before.stage_mm);
}

#[tokio::test]
async fn stage_homes_then_moves_absolute_and_relative() {
    let (rig, _h, mut s) = stage(100.0).await;
    let st = s.status().await.unwrap();
    assert!(!st.homed);
    s.home(T).await.unwrap();
    let st = s.status().await.unwrap();
    assert!(st.homed && !st.moving && st.reverse_limit, "{st:?}");
    assert_eq!(st.position, 0.0);
    assert!(rig.pose().stage_mm.abs() < 1e-9);

    // 1.234 mm is 42 641 counts (A.6 worked number); the rig's load really is there.
    let p = s.move_to(Mm(1.234), T).await.unwrap().0;
    assert_eq!((p * 34_554.96).round(), 42_641.0);
    assert!((rig.pose().stage_mm - 1.234).abs() < 1.0 / 34_554.96, "{:?}", rig.pose());

    let p = s.move_by(Mm(1.5), T).await.unwrap().0;
    assert!((z8_counts(p) - z8_counts(2.734)).abs() <= 1.0, "{p}");
    let p = s.move_by(Mm(-0.5), T).await.unwrap().0;
    assert!((z8_counts(p) - z8_counts(2.234)).abs() <= 1.0, "{p}");
    assert!((s.position().await.unwrap().0 - p).abs() < 1e-12);
    assert!((rig.pose().stage_mm - 2.234).abs() < 2.0 / 34_554.96);
}

#[tokio::test]
async fn stop_during_a_move_ends_short_of_the_target() {
    let (rig, _h, mut s) = stage(20.0).await;
    s.home(T).await.unwrap();
    s.start_move_to(Mm(20.0)).await.unwrap();
    // Wait (by polling the device, not by sleeping) until the move is well under way.
    let mut seen_moving = false;
    loop {
        let st = s.status().await.unwrap();
        seen_moving |= st.moving;
        assert!(st.position < 19.0, "the move ended before the stop could be sent");
        if st.position > 1.0 {
            break;
        }
    }
    assert!(seen_moving);
    s.stop().await.unwrap();
    let p = s.wait_until_stopped(T).await.unwrap().0;
    assert!(p > 1.0 && p < 19.0, "stopped at {p}");
    let st = s.status().await.unwrap();
    assert!(!st.moving);
    assert!((st.position - p).abs() < 1e-9);
    assert!((rig.pose().stage_mm - p).abs() < 1e-4);
}

#[tokio::test]
async fn moves_past_travel_are_refused_before_anything_is_sent() {
    let (rig, h, mut s) = stage(100.0).await;
    s.home(T).await.unwrap();
    s.move_to(Mm(24.0), T).await.unwrap();
    let sent_before = h.received();
    let pose = rig.pose();

    for r in [s.start_move_to(Mm(25.5)).await, s.start_move_to(Mm(-0.1)).await, s.start_move_to(Mm(f64::NAN)).await] {
        let e = r.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Limit, "{e}");
    }
    // A relative move is checked against the position it starts from (24 + 2 > 25).
    let e = s.start_move_by(Mm(2.0)).await.unwrap_err();
    assert!(matches!(e, AptError::Limit { .. }), "{e}");

    let sent = h.received();
    let new: Vec<u16> = sent[sent_before.len()..].to_vec();
    assert!(!new.contains(&0x0453) && !new.contains(&0x0448), "a move command reached the unit: {new:04X?}");
    let after = rig.pose();
    assert_eq!(after.stage_mm, pose.stage_mm);
}

#[tokio::test]
async fn cut_cable_mid_move_gives_disconnected_within_one_second() {
    let (_rig, h, mut s) = stage(5.0).await;
    s.start_move_to(Mm(20.0)).await.unwrap();
    h.cut();
    let r = tokio::time::timeout(Duration::from_secs(1), s.wait_until_stopped(T))
        .await
        .expect("driver did not notice the cut within 1 s");
    let e = r.unwrap_err();
    assert_eq!(e.kind(), FaultKind::Disconnected, "{e}");
    // And it stays disconnected.
    assert_eq!(s.status().await.unwrap_err().kind(), FaultKind::Disconnected);
}

#[tokio::test]
async fn injected_device_errors_surface_as_device_reported() {
    let (_rig, h, mut s) = stage(100.0).await;
    h.inject_error(InjectedError::Rich { msg_id: 0x0453, code: 42, text: "motor overload".into() });
    let mut got = None;
    for _ in 0..5 {
        if let Err(e) = s.status().await {
            got = Some(e);
            break;
        }
    }
    match got.expect("no error surfaced") {
        AptError::DeviceReported { msg_id, code, text } => {
            assert_eq!((msg_id, code, text.as_str()), (0x0453, 42, "motor overload"));
        }
        e => panic!("wrong error {e}"),
    }
    h.inject_error(InjectedError::Response { p1: 3, p2: 0 });
    let mut kind = None;
    for _ in 0..5 {
        if let Err(e) = s.status().await {
            kind = Some(e.kind());
            break;
        }
    }
    assert_eq!(kind, Some(FaultKind::DeviceReported));
    // The link survives a reported error.
    assert!(s.status().await.is_ok());
}

#[tokio::test]
async fn rotation_identifies_homes_and_turns_both_ways() {
    let (rig, h, mut r) = rotation(400.0).await;
    let info = r.identify().await.unwrap();
    assert_eq!((info.model.as_str(), info.serial.as_str()), ("K10CR1", "55000001"));
    r.home(T).await.unwrap();
    let st = r.status().await.unwrap();
    assert!(st.homed && !st.moving, "{st:?}");
    assert!(st.position.abs() < 1e-9);
    // The K10CR1 is polled with STATUSBITS + POSCOUNTER (A.7), never the DC update.
    assert!(h.received().contains(&0x0429) && !h.received().contains(&0x0490));

    let c = 409_600.0 / 3.0;
    let p = r.move_to(Deg(-30.0), T).await.unwrap().0;
    assert!((p * c - (-30.0 * c)).abs() <= 1.0, "{p}");
    assert!((rig.pose().rot_deg + 30.0).abs() < 1e-4);
    let p = r.move_by(Deg(45.5), T).await.unwrap().0;
    assert!((p * c - 15.5 * c).abs() <= 1.0, "{p}");
    assert_eq!(r.start_move_to(Deg(400.0)).await.unwrap_err().kind(), FaultKind::Limit);
    assert_eq!(r.start_move_by(Deg(-380.0)).await.unwrap_err().kind(), FaultKind::Limit);
}

#[tokio::test]
async fn rotation_stop_during_a_move() {
    // Unhomed, the counter reads the power-on angle (365°); turning back to 0
    // takes 36.5 rig seconds, 0.7 s of wall time at 50x: ample room to stop.
    let (rig, _h, mut r) = rotation(50.0).await;
    let start = r.position().await.unwrap().0;
    assert!((start - 365.0).abs() < 1e-4, "{start}");
    r.start_move_to(Deg(0.0)).await.unwrap();
    loop {
        let st = r.status().await.unwrap();
        assert!(st.position > 5.0, "the move ended before the stop could be sent");
        if st.moving && st.position < 345.0 {
            break;
        }
    }
    r.stop().await.unwrap();
    let p = r.wait_until_stopped(T).await.unwrap().0;
    assert!(p > 5.0 && p < 345.0, "{p}");
    let st = r.status().await.unwrap();
    assert!(!st.moving && (st.position - p).abs() < 1e-9);
    assert!((rig.pose().rot_deg - p).abs() < 1e-4);
}

#[tokio::test]
async fn rotation_cut_cable_gives_disconnected() {
    let (_rig, h, mut r) = rotation(2.0).await;
    r.start_move_to(Deg(200.0)).await.unwrap();
    h.cut();
    let e = tokio::time::timeout(Duration::from_secs(1), r.wait_until_stopped(T))
        .await
        .expect("no disconnect within 1 s")
        .unwrap_err();
    assert_eq!(e.kind(), FaultKind::Disconnected);
}

// ---- raw bytes, as an independent client sends them -------------------------

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

/// Read until a frame with `id` arrives (other frames are collected too).
async fn read_until(p: &mut SerialStream, dec: &mut AptDecoder, id: u16, seen: &mut Vec<Frame>) -> Vec<u8> {
    let mut buf = [0u8; 256];
    let mut raw = Vec::new();
    loop {
        while let Some(f) = dec.next_frame() {
            let f = f.expect("emulator sent a malformed frame");
            let hit = f.message.id() == id;
            seen.push(f);
            if hit {
                return raw;
            }
        }
        let n = tokio::time::timeout(T, p.read(&mut buf)).await.expect("no reply").unwrap();
        assert!(n > 0, "emulator hung up");
        raw.extend_from_slice(&buf[..n]);
        dec.feed(&buf[..n]);
    }
}

#[tokio::test]
async fn raw_client_session_gets_byte_exact_replies() {
    let rig = rig(100.0);
    let cfg = AptEmulatorConfig { update_period: Duration::from_millis(5), ..AptEmulatorConfig::kdc101_z8(25.0) };
    let h = spawn_apt(rig.clone(), cfg).unwrap();
    let mut p = port(&h).await;
    let mut dec = AptDecoder::for_host();
    let mut seen = Vec::new();

    // yaq-style and pylablib-style connect: no-flash, stop updates, identify.
    p.write_all(&hex("18 00 00 00 50 01 12 00 00 00 50 01 05 00 00 00 50 01")).await.unwrap();
    let raw = read_until(&mut p, &mut dec, 0x0006, &mut seen).await;
    assert_eq!(&raw[..6], &hex("06 00 54 00 81 50")[..]);
    assert_eq!(&raw[6 + 4..6 + 10], b"KDC101");

    // thorlabs_apt_device: params requests, enable, status request.
    p.write_all(&hex("14 04 01 00 50 01 3B 04 01 00 50 01 17 04 01 00 50 01 41 04 01 00 50 01 10 02 01 01 50 01"))
        .await
        .unwrap();
    read_until(&mut p, &mut dec, 0x0442, &mut seen).await;
    let ids: Vec<u16> = seen.iter().map(|f| f.message.id()).collect();
    assert_eq!(&ids[ids.len() - 4..], &[0x0415, 0x043C, 0x0418, 0x0442]);

    // Home, then the documented MOVE_HOMED reply bytes.
    p.write_all(&hex("43 04 01 00 50 01")).await.unwrap();
    let raw = read_until(&mut p, &mut dec, 0x0444, &mut seen).await;
    let at = raw.windows(6).position(|w| w == hex("44 04 01 00 01 50")).expect("MOVE_HOMED bytes");
    assert_eq!(at + 6, raw.len());

    // Long MOVE_ABSOLUTE to 42 641 counts; MOVE_COMPLETED carries exactly that position.
    p.write_all(&hex("53 04 06 00 D0 01 01 00 91 A6 00 00")).await.unwrap();
    let raw = read_until(&mut p, &mut dec, 0x0464, &mut seen).await;
    let done = &raw[raw.len() - 20..];
    assert_eq!(&done[..12], &hex("64 04 0E 00 81 50 01 00 91 A6 00 00")[..]);
    let bits = u32::from_le_bytes(done[16..20].try_into().unwrap());
    assert_eq!(bits & status::ANY_MOTION, 0);
    assert_ne!(bits & status::HOMED, 0);

    // Status request: the A.8 example reply, bit for bit except the limit bits
    // the emulator adds (none here: 1.234 mm is inside the travel).
    p.write_all(&hex("90 04 01 00 50 01")).await.unwrap();
    let raw = read_until(&mut p, &mut dec, 0x0491, &mut seen).await;
    assert_eq!(&raw[raw.len() - 20..], &hex("91 04 0E 00 81 50 01 00 91 A6 00 00 00 00 00 00 00 05 00 80")[..]);

    // Pushed updates at the configured period once started, in the DC layout.
    p.write_all(&hex("11 00 00 00 50 01")).await.unwrap();
    let before = seen.iter().filter(|f| f.message.id() == 0x0491).count();
    while seen.iter().filter(|f| f.message.id() == 0x0491).count() < before + 3 {
        read_until(&mut p, &mut dec, 0x0491, &mut seen).await;
    }
    // Keep-alive and a profiled stop while idle (thorlabs_apt_device's close()).
    p.write_all(&hex("92 04 00 00 50 01 65 04 01 02 50 01 12 00 00 00 50 01")).await.unwrap();
    read_until(&mut p, &mut dec, 0x0466, &mut seen).await;
    assert!(h.received().ends_with(&[0x0011, 0x0492, 0x0465, 0x0012]));
}

#[tokio::test]
async fn emulator_skips_garbage_and_keeps_answering() {
    let rig = rig(100.0);
    let h = spawn_apt_stage(rig).unwrap();
    let mut p = port(&h).await;
    let mut dec = AptDecoder::for_host();
    // Unknown id, oversize length, then a valid request.
    p.write_all(&hex("34 12 00 00 50 01 64 04 00 01 D0 01 FF 05 00 00 00 50 01")).await.unwrap();
    let raw = read_until(&mut p, &mut dec, 0x0006, &mut Vec::new()).await;
    let (f, _) = decode_frame(&raw, &Addressing::host()).unwrap();
    assert!(matches!(f.message, AptMessage::HwGetInfo(_)));
}
