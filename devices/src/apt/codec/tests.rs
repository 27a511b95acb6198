//! The APT codec against bytes from the protocol document and round trips.

use super::*;
use proptest::prelude::*;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
}

fn info() -> HwInfo {
    HwInfo {
        serial: 27000001,
        model: "KDC101".into(),
        hw_type: 16,
        firmware: (3, 0, 10),
        notes: "Z825B emulated".into(),
        reserved: [0; 10],
        stage_id: 9,
        hw_version: 1,
        mod_state: 0,
        n_channels: 1,
    }
}

/// One sample of every message variant.
fn samples() -> Vec<AptMessage> {
    use AptMessage as M;
    let vel = VelParams { chan: 1, min_velocity: 0, acceleration: 1055, max_velocity: 1_777_857 };
    let jog = JogParams {
        chan: 1,
        mode: 2,
        step: 3455,
        min_velocity: 0,
        acceleration: 1055,
        max_velocity: 1_000_000,
        stop_mode: 2,
    };
    let home = HomeParams { chan: 1, direction: 2, limit_switch: 1, velocity: 772_981, offset: 34_555 };
    let lim = LimSwitchParams { chan: 1, cw_hard: 2, ccw_hard: 2, cw_soft: 863_874, ccw_soft: 0, soft_mode: 1 };
    let st = StatusPayload::dc(1, 42641, -27, 0x8000_0500);
    let sst = StatusPayload::stepper(1, -136_533, 7, 0x8000_0410);
    vec![
        M::HwDisconnect,
        M::HwReqInfo,
        M::HwGetInfo(Box::new(info())),
        M::HwStartUpdateMsgs,
        M::HwStopUpdateMsgs,
        M::HwYesFlashProgramming,
        M::HwNoFlashProgramming,
        M::HwResponse { p1: 3, p2: 7 },
        M::HwRichResponse { msg_id: 0x0453, code: 40, text: "position outside travel".into() },
        M::ModIdentify { chan: 1 },
        M::ModSetChanEnableState { chan: 1, enabled: true },
        M::ModSetChanEnableState { chan: 1, enabled: false },
        M::ModReqChanEnableState { chan: 1 },
        M::ModGetChanEnableState { chan: 1, enabled: true },
        M::MotSetEncCounter { chan: 1, count: -5 },
        M::MotReqEncCounter { chan: 1 },
        M::MotGetEncCounter { chan: 1, count: 99 },
        M::MotSetPosCounter { chan: 1, position: 0 },
        M::MotReqPosCounter { chan: 1 },
        M::MotGetPosCounter { chan: 1, position: -42641 },
        M::MotSetVelParams(vel),
        M::MotReqVelParams { chan: 1 },
        M::MotGetVelParams(vel),
        M::MotSetJogParams(jog),
        M::MotReqJogParams { chan: 1 },
        M::MotGetJogParams(jog),
        M::MotSetLimSwitchParams(lim),
        M::MotReqLimSwitchParams { chan: 1 },
        M::MotGetLimSwitchParams(lim),
        M::MotReqStatusBits { chan: 1 },
        M::MotGetStatusBits { chan: 1, status: 0x8000_0410 },
        M::MotSetGenMoveParams { chan: 1, backlash: 35 },
        M::MotReqGenMoveParams { chan: 1 },
        M::MotGetGenMoveParams { chan: 1, backlash: 35 },
        M::MotSetHomeParams(home),
        M::MotReqHomeParams { chan: 1 },
        M::MotGetHomeParams(home),
        M::MotMoveHome { chan: 1 },
        M::MotMoveHomed { chan: 1 },
        M::MotSetMoveRelParams { chan: 1, distance: -3455 },
        M::MotReqMoveRelParams { chan: 1 },
        M::MotGetMoveRelParams { chan: 1, distance: -3455 },
        M::MotMoveRelative { chan: 1, distance: None },
        M::MotMoveRelative { chan: 1, distance: Some(-3455) },
        M::MotSetMoveAbsParams { chan: 1, position: 42641 },
        M::MotReqMoveAbsParams { chan: 1 },
        M::MotGetMoveAbsParams { chan: 1, position: 42641 },
        M::MotMoveAbsolute { chan: 1, position: None },
        M::MotMoveAbsolute { chan: 1, position: Some(42641) },
        M::MotMoveVelocity { chan: 1, direction: Direction::Reverse },
        M::MotMoveJog { chan: 1, direction: Direction::Forward },
        M::MotMoveCompleted(st),
        M::MotMoveStop { chan: 1, mode: StopMode::Profiled },
        M::MotMoveStop { chan: 1, mode: StopMode::Immediate },
        M::MotMoveStopped(st),
        M::MotSuspendEndOfMoveMsgs,
        M::MotResumeEndOfMoveMsgs,
        M::MotReqStatusUpdate { chan: 1 },
        M::MotGetStatusUpdate(sst),
        M::MotReqDcStatusUpdate { chan: 1 },
        M::MotGetDcStatusUpdate(st),
        M::MotAckDcStatusUpdate,
    ]
}

#[test]
fn every_message_round_trips_both_directions() {
    for msg in samples() {
        // Host -> unit.
        let bytes = encode(&msg, USB_UNIT, HOST);
        let (frame, used) = decode_frame(&bytes, &Addressing::unit()).unwrap();
        assert_eq!(used, bytes.len(), "{msg:?}");
        assert_eq!(frame.message, msg);
        assert_eq!((frame.dest, frame.source), (USB_UNIT, HOST));
        // Unit -> host.
        let bytes = encode(&msg, HOST, USB_UNIT);
        let (frame, _) = decode_frame(&bytes, &Addressing::host()).unwrap();
        assert_eq!(frame.message, msg);
        assert_eq!((frame.dest, frame.source), (HOST, USB_UNIT));
    }
}

#[test]
fn streaming_decoder_splits_a_concatenated_stream_fed_byte_by_byte() {
    let msgs = samples();
    let stream: Vec<u8> = msgs.iter().flat_map(|m| encode(m, HOST, USB_UNIT)).collect();
    let mut dec = AptDecoder::for_host();
    let mut out = Vec::new();
    for b in stream {
        dec.feed(&[b]);
        while let Some(f) = dec.next_frame() {
            out.push(f.unwrap().message);
        }
    }
    assert_eq!(out, msgs);
    assert!(dec.finish().is_ok());
    assert_eq!(dec.dropped_bytes(), 0);
}

#[test]
fn byte_exact_encodings_match_hardware_md_a8() {
    let cases: Vec<(AptMessage, u8, u8, &str)> = vec![
        (AptMessage::HwNoFlashProgramming, USB_UNIT, HOST, "18 00 00 00 50 01"),
        (AptMessage::HwReqInfo, USB_UNIT, HOST, "05 00 00 00 50 01"),
        (AptMessage::ModIdentify { chan: 1 }, USB_UNIT, HOST, "23 02 01 00 50 01"),
        (AptMessage::ModSetChanEnableState { chan: 1, enabled: true }, USB_UNIT, HOST, "10 02 01 01 50 01"),
        (AptMessage::MotMoveHome { chan: 1 }, USB_UNIT, HOST, "43 04 01 00 50 01"),
        (AptMessage::MotMoveHomed { chan: 1 }, HOST, USB_UNIT, "44 04 01 00 01 50"),
        (
            AptMessage::MotMoveAbsolute { chan: 1, position: Some(42641) },
            USB_UNIT,
            HOST,
            "53 04 06 00 D0 01 01 00 91 A6 00 00",
        ),
        (
            AptMessage::MotMoveAbsolute { chan: 1, position: Some(2048) },
            USB_UNIT,
            HOST,
            "53 04 06 00 D0 01 01 00 00 08 00 00",
        ),
        (
            AptMessage::MotMoveRelative { chan: 1, distance: Some(-3455) },
            USB_UNIT,
            HOST,
            "48 04 06 00 D0 01 01 00 81 F2 FF FF",
        ),
        (
            AptMessage::MotSetVelParams(VelParams {
                chan: 1,
                min_velocity: 0,
                acceleration: 1055,
                max_velocity: 1_777_857,
            }),
            USB_UNIT,
            HOST,
            "13 04 0E 00 D0 01 01 00 00 00 00 00 1F 04 00 00 C1 20 1B 00",
        ),
        (AptMessage::MotReqDcStatusUpdate { chan: 1 }, USB_UNIT, HOST, "90 04 01 00 50 01"),
        (
            AptMessage::MotGetDcStatusUpdate(StatusPayload::dc(
                1,
                42641,
                0,
                status::HOMED | status::MOTOR_CONNECTED | status::ENABLED,
            )),
            HOST,
            USB_UNIT,
            "91 04 0E 00 81 50 01 00 91 A6 00 00 00 00 00 00 00 05 00 80",
        ),
        (AptMessage::MotAckDcStatusUpdate, USB_UNIT, HOST, "92 04 00 00 50 01"),
        (AptMessage::HwStartUpdateMsgs, USB_UNIT, HOST, "11 00 00 00 50 01"),
        (AptMessage::HwStopUpdateMsgs, USB_UNIT, HOST, "12 00 00 00 50 01"),
        (AptMessage::MotMoveStop { chan: 1, mode: StopMode::Profiled }, USB_UNIT, HOST, "65 04 01 02 50 01"),
    ];
    for (msg, dest, src, want) in cases {
        assert_eq!(encode(&msg, dest, src), hex(want), "{msg:?}");
    }
}

#[test]
fn move_completed_uses_the_status_layout() {
    // 0x0464, 14-byte packet: chan 1, pos 42641, velocity 0, reserved, status.
    let msg = AptMessage::MotMoveCompleted(StatusPayload::dc(
        1,
        42641,
        0,
        status::HOMED | status::MOTOR_CONNECTED | status::ENABLED,
    ));
    assert_eq!(encode(&msg, HOST, USB_UNIT), hex("64 04 0E 00 81 50 01 00 91 A6 00 00 00 00 00 00 00 05 00 80"));
}

#[test]
fn hw_get_info_layout_matches_documented_offsets() {
    let bytes = encode(&AptMessage::HwGetInfo(Box::new(info())), HOST, USB_UNIT);
    assert_eq!(&bytes[..6], &hex("06 00 54 00 81 50")[..]);
    let d = &bytes[6..];
    assert_eq!(d.len(), 84);
    assert_eq!(u32::from_le_bytes(d[0..4].try_into().unwrap()), 27000001);
    assert_eq!(&d[4..12], b"KDC101\0\0");
    assert_eq!(u16::from_le_bytes([d[12], d[13]]), 16);
    // Firmware minor, interim, major at 14, 15, 16.
    assert_eq!(&d[14..17], &[10, 0, 3]);
    assert_eq!(&d[18..32], b"Z825B emulated");
    // pylablib's stage id at 76, then hw version, mod state, channels.
    assert_eq!(u16::from_le_bytes([d[76], d[77]]), 9);
    assert_eq!(u16::from_le_bytes([d[78], d[79]]), 1);
    assert_eq!(u16::from_le_bytes([d[82], d[83]]), 1);
    // And the documented request.
    assert_eq!(encode(&AptMessage::HwReqInfo, USB_UNIT, HOST), hex("05 00 00 00 50 01"));
}

#[test]
fn truncated_frame_is_a_typed_error() {
    let full = hex("53 04 06 00 D0 01 01 00 91 A6 00 00");
    for cut in 0..full.len() {
        match decode_frame(&full[..cut], &Addressing::unit()) {
            Err(CodecError::TruncatedFrame { needed, available }) => {
                assert_eq!(available, cut);
                assert!(needed > cut);
            }
            other => panic!("cut {cut}: {other:?}"),
        }
    }
    let mut dec = AptDecoder::for_unit();
    dec.feed(&full[..9]);
    assert!(dec.next_frame().is_none());
    assert!(matches!(dec.finish(), Err(CodecError::TruncatedFrame { needed: 12, available: 9 })));
}

#[test]
fn unknown_id_is_a_typed_error_and_the_decoder_resynchronises() {
    let bad = hex("34 12 00 00 50 01");
    assert_eq!(decode_frame(&bad, &Addressing::unit()), Err(CodecError::UnknownMessageId { id: 0x1234 }));
    let mut dec = AptDecoder::for_unit();
    dec.feed(&bad);
    dec.feed(&hex("05 00 00 00 50 01"));
    let mut errors = 0;
    let mut frames = Vec::new();
    while let Some(r) = dec.next_frame() {
        match r {
            Ok(f) => frames.push(f.message),
            Err(_) => errors += 1,
        }
    }
    assert_eq!(frames, vec![AptMessage::HwReqInfo]);
    assert!(errors >= 1);
    assert_eq!(dec.dropped_bytes(), 6);
}

#[test]
fn bad_destination_oversize_and_length_mismatch_are_typed() {
    // A reply addressed to the unit when the host decodes.
    assert!(matches!(
        decode_frame(&hex("05 00 00 00 50 01"), &Addressing::host()),
        Err(CodecError::BadDestination { id: 0x0005, dest: 0x50, .. })
    ));
    // Long frame announcing 0x0100 = 256 data bytes.
    assert!(matches!(decode_frame(&hex("64 04 00 01 81 50"), &Addressing::host()), Err(CodecError::BadHeader { .. })));
    // Unknown source address.
    assert!(matches!(decode_frame(&hex("05 00 00 00 50 77"), &Addressing::unit()), Err(CodecError::BadHeader { .. })));
    // MOVE_COMPLETED with 6 instead of 14 data bytes.
    assert!(matches!(
        decode_frame(&hex("64 04 06 00 81 50 01 00 00 00 00 00"), &Addressing::host()),
        Err(CodecError::LengthMismatch { id: 0x0464, .. })
    ));
    // A status request sent as a long frame.
    assert!(matches!(
        decode_frame(&hex("90 04 00 00 D0 01"), &Addressing::unit()),
        Err(CodecError::LengthMismatch { id: 0x0490, .. })
    ));
}

#[test]
fn status_payload_accessors() {
    let s = StatusPayload::dc(1, 5, -300, status::MOVING_CCW);
    assert_eq!(s.dc_velocity(), -300);
    assert!(s.is_moving());
    let s = StatusPayload::stepper(1, 5, -123_456, status::HOMED);
    assert_eq!(s.stepper_encoder(), -123_456);
    assert!(!s.is_moving());
}

proptest! {
    #[test]
    fn random_bytes_never_panic_the_decoder(bytes in proptest::collection::vec(any::<u8>(), 0..600),
                                            split in 0usize..600) {
        let mut dec = AptDecoder::for_host();
        let split = split.min(bytes.len());
        dec.feed(&bytes[..split]);
        let mut n = 0usize;
        while dec.next_frame().is_some() { n += 1; }
        dec.feed(&bytes[split..]);
        while dec.next_frame().is_some() { n += 1; }
        // Every step either yields a frame or drops a byte: bounded work.
        prop_assert!(n <= bytes.len());
        let _ = dec.finish();
    }

    #[test]
    fn valid_frames_survive_leading_garbage(garbage in proptest::collection::vec(any::<u8>(), 0..40),
                                            pos in any::<i32>(), st in any::<u32>()) {
        let msg = AptMessage::MotGetDcStatusUpdate(StatusPayload::dc(1, pos, 0, st));
        let mut dec = AptDecoder::for_host();
        dec.feed(&garbage);
        // Repeat the frame so one copy is found after resynchronisation
        // even when the garbage ends in a prefix of a valid header.
        for _ in 0..6 { dec.feed(&encode(&msg, HOST, USB_UNIT)); }
        let mut found = false;
        while let Some(r) = dec.next_frame() {
            if let Ok(f) = r { if f.message == msg { found = true; } }
        }
        prop_assert!(found);
    }

    #[test]
    fn status_and_move_round_trip(pos in any::<i32>(), vel in any::<i16>(), st in any::<u32>(), chan in 1u8..=255) {
        for msg in [
            AptMessage::MotMoveAbsolute { chan, position: Some(pos) },
            AptMessage::MotMoveRelative { chan, distance: Some(pos) },
            AptMessage::MotMoveCompleted(StatusPayload::dc(u16::from(chan), pos, vel, st)),
            AptMessage::MotGetStatusBits { chan: u16::from(chan), status: st },
        ] {
            let b = encode(&msg, HOST, USB_UNIT);
            let (f, n) = decode_frame(&b, &Addressing::host()).unwrap();
            prop_assert_eq!(n, b.len());
            prop_assert_eq!(f.message, msg);
        }
    }
}
