//! The GRBL line protocol against literal lines.

use super::*;
use proptest::prelude::*;

#[test]
fn banner_ok_error_alarm() {
    assert_eq!(parse_line("Grbl 1.1h ['$' for help]\r").unwrap(), Response::Welcome { version: "1.1h".into() });
    assert_eq!(parse_line("ok").unwrap(), Response::Ok);
    assert_eq!(parse_line("").unwrap(), Response::Empty);
    let Response::Error(e) = parse_line("error:22").unwrap() else { panic!() };
    assert_eq!(e, ErrorCode(22));
    assert_eq!(e.meaning(), "Feed rate has not yet been set or is undefined.");
    let Response::Alarm(a) = parse_line("ALARM:2").unwrap() else { panic!() };
    assert_eq!(a, AlarmCode::SOFT_LIMIT);
    assert!(a.is_critical());
    assert!(a.meaning().starts_with("G-code motion target exceeds machine travel"));
    assert!(AlarmCode(1).meaning().starts_with("Hard limit triggered"));
    assert!(!AlarmCode(3).is_critical());
}

#[test]
fn malformed_codes_are_typed_errors() {
    for bad in ["error:", "error:x", "error:300", "ALARM:-1", "ALARM:1a"] {
        assert!(matches!(parse_line(bad), Err(ParseError::BadCode { .. })), "{bad}");
    }
    assert!(matches!(parse_line("okay"), Err(ParseError::Unrecognised { .. })));
    assert!(matches!(parse_line("<Idle|MPos:0,0,0"), Err(ParseError::UnterminatedStatus { .. })));
    assert!(matches!(parse_line("<Walk|MPos:0,0,0>"), Err(ParseError::UnknownState { .. })));
    assert!(matches!(parse_line("<Idle|FS:0,0>"), Err(ParseError::MissingPosition { .. })));
    match parse_line("<Idle|MPos:0,abc,0>") {
        Err(ParseError::BadField { field, text, .. }) => {
            assert_eq!(field, "MPos");
            assert_eq!(text, "0,abc,0");
        }
        other => panic!("{other:?}"),
    }
    assert!(matches!(parse_line("<Idle|MPos:0,0,0|Bf:15>"), Err(ParseError::BadField { .. })));
    assert!(matches!(parse_line("[MSG:oops"), Err(ParseError::UnterminatedFeedback { .. })));
    assert!(matches!(parse_line("$x=1"), Err(ParseError::BadSetting { .. })));
    assert!(matches!(parse_line_bytes(b"ok\xff"), Err(ParseError::NotUtf8 { at: 2 })));
}

#[test]
fn status_report_all_fields() {
    let line =
        "<Hold:0|WPos:1.000,-2.500,0.750|Bf:15,128|Ln:99|FS:30,0|Pn:XZ|WCO:0.000,1.000,2.000|Ov:100,50,120|A:SF>";
    let Response::Status(s) = parse_line(line).unwrap() else { panic!() };
    assert_eq!(s.state, MachineState::Hold(0));
    assert_eq!(s.position_kind, PositionKind::Work);
    assert_eq!(s.position.as_slice(), &[1.0, -2.5, 0.75]);
    assert_eq!(s.buffer, Some((15, 128)));
    assert_eq!(s.line_number, Some(99));
    assert_eq!(s.feed, Some(30.0));
    assert_eq!(s.spindle, Some(0.0));
    assert!(s.pin('Z') && s.pin('X') && !s.pin('Y'));
    assert_eq!(s.overrides, Some((100, 50, 120)));
    assert_eq!(s.accessory.as_deref(), Some("SF"));
    // WPos + WCO = MPos.
    assert_eq!(s.machine_position(2, None), Some(2.75));
    assert_eq!(s.to_string(), line);
    let Response::Status(m) = parse_line("<Idle|MPos:0.000,0.000,1.234|FS:0,0>").unwrap() else { panic!() };
    assert_eq!(m.machine_position(2, None), Some(1.234));
    assert_eq!(m.state, MachineState::Idle);
    // WPos without any WCO known: position cannot be converted.
    let Response::Status(w) = parse_line("<Run|WPos:0,0,1|F:30>").unwrap() else { panic!() };
    assert_eq!(w.machine_position(2, None), None);
    let wco = AxisValues::new(&[0.0, 0.0, -1.0]).unwrap();
    assert_eq!(w.machine_position(2, Some(&wco)), Some(0.0));
}

#[test]
fn feedback_settings_startup_lines() {
    assert_eq!(parse_line("[MSG:'$H'|'$X' to unlock]").unwrap(), Response::Message("'$H'|'$X' to unlock".into()));
    assert_eq!(
        parse_line("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]").unwrap(),
        Response::ParserState("G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0".split(' ').map(String::from).collect())
    );
    assert_eq!(
        parse_line("[VER:1.1h.20190830:rig-z]").unwrap(),
        Response::Version { version: "1.1h.20190830".into(), info: "rig-z".into() }
    );
    assert_eq!(
        parse_line("[OPT:V,15,128]").unwrap(),
        Response::Feedback { tag: "OPT".into(), body: "V,15,128".into() }
    );
    assert_eq!(parse_line("$102=6400.000").unwrap(), Response::Setting { number: 102, value: 6400.0 });
    assert_eq!(
        parse_line(">G21:error:20").unwrap(),
        Response::StartupLine { line: "G21".into(), result: Err(ErrorCode(20)) }
    );
    assert_eq!(parse_line(">G54:ok").unwrap(), Response::StartupLine { line: "G54".into(), result: Ok(()) });
}

#[test]
fn encodes_documented_lines() {
    let c = GrblCommand::Feed { distance: Distance::Absolute, axis: 'Z', mm: 1.234, feed_mm_min: 60.0 };
    assert_eq!(c.encode().unwrap(), "G90 G1 Z1.2340 F60.0000\n");
    let c = GrblCommand::Feed { distance: Distance::Incremental, axis: 'z', mm: 0.05, feed_mm_min: 30.0 };
    assert_eq!(c.encode().unwrap(), "G91 G1 Z0.0500 F30.0000\n");
    let j = GrblCommand::Jog { distance: Distance::Incremental, axis: 'Z', mm: -0.0, feed_mm_min: 30.0 };
    assert_eq!(j.encode().unwrap(), "$J=G91 G21 Z0.0000 F30.0000\n");
    assert_eq!(GrblCommand::Home.encode().unwrap(), "$H\n");
    assert_eq!(GrblCommand::Unlock.encode().unwrap(), "$X\n");
    assert_eq!(GrblCommand::SetSetting { number: 20, value: 1.0 }.encode().unwrap(), "$20=1.0000\n");
    assert_eq!(Realtime::StatusQuery.byte(), b'?');
    assert_eq!(Realtime::FeedHold.byte(), b'!');
    assert_eq!(Realtime::CycleStart.byte(), b'~');
    assert_eq!(Realtime::SoftReset.byte(), 0x18);
    for r in [Realtime::StatusQuery, Realtime::FeedHold, Realtime::CycleStart, Realtime::SoftReset, Realtime::JogCancel]
    {
        assert_eq!(Realtime::from_byte(r.byte()), Some(r));
    }
}

#[test]
fn encode_rejects_bad_values() {
    let mk = |mm: f64, f: f64| GrblCommand::Feed { distance: Distance::Absolute, axis: 'Z', mm, feed_mm_min: f };
    assert!(matches!(mk(f64::NAN, 1.0).encode(), Err(EncodeError::NotFinite { .. })));
    assert!(matches!(mk(1.0, 0.0).encode(), Err(EncodeError::NotPositive { .. })));
    assert!(matches!(mk(1e80, 1.0).encode(), Err(EncodeError::TooLong { .. })));
    assert!(matches!(
        GrblCommand::Rapid { distance: Distance::Absolute, axis: 'Q', mm: 0.0 }.encode(),
        Err(EncodeError::BadAxis('Q'))
    ));
}

#[test]
fn splitter_handles_crlf_fragments_and_overflow() {
    let mut s = LineSplitter::new();
    let mut out = Vec::new();
    s.push(b"\r\nGrbl 1.1h ['$' for help]\r\no", &mut out);
    s.push(b"k\r\n", &mut out);
    let lines: Vec<_> = out.into_iter().map(|r| r.unwrap()).collect();
    assert_eq!(lines, vec![b"".to_vec(), b"Grbl 1.1h ['$' for help]".to_vec(), b"ok".to_vec()]);
    let mut out = Vec::new();
    s.push(&vec![b'x'; MAX_RESPONSE_LINE + 10], &mut out);
    s.push(b"\nok\n", &mut out);
    assert_eq!(out.len(), 2);
    assert!(matches!(out[0], Err(ParseError::TooLong { .. })));
    assert_eq!(out[1].as_deref().unwrap(), b"ok");
}

fn arb_state() -> impl Strategy<Value = MachineState> {
    prop_oneof![
        Just(MachineState::Idle),
        Just(MachineState::Run),
        (0u8..=1).prop_map(MachineState::Hold),
        Just(MachineState::Jog),
        Just(MachineState::Alarm),
        (0u8..=3).prop_map(MachineState::Door),
        Just(MachineState::Check),
        Just(MachineState::Home),
        Just(MachineState::Sleep),
    ]
}

fn arb_axes() -> impl Strategy<Value = AxisValues> {
    proptest::collection::vec(-1_000_000i64..1_000_000, 3)
        .prop_map(|v| AxisValues::new(&v.iter().map(|&x| x as f64 / 1000.0).collect::<Vec<_>>()).unwrap())
}

proptest! {
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = parse_line_bytes(&bytes);
        let mut s = LineSplitter::new();
        let mut out = Vec::new();
        s.push(&bytes, &mut out);
        for l in out.into_iter().flatten() {
            let _ = parse_line_bytes(&l);
        }
    }

    #[test]
    fn grbl_like_lines_never_panic(line in "[<\\[$>]?[A-Za-z0-9:|,.\\-=\\]>\\[ ]{0,90}") {
        let _ = parse_line(&line);
    }

    #[test]
    fn status_round_trip(
        state in arb_state(),
        machine in any::<bool>(),
        pos in arb_axes(),
        wco in proptest::option::of(arb_axes()),
        buffer in proptest::option::of((0u16..=15, 0u16..=128)),
        feed in proptest::option::of(0u32..5000),
        pins in proptest::option::of("[XYZP]{1,4}"),
        ov in proptest::option::of((10u16..=200, 25u16..=100, 10u16..=200)),
    ) {
        let report = StatusReport {
            state,
            position_kind: if machine { PositionKind::Machine } else { PositionKind::Work },
            position: pos,
            wco,
            buffer,
            line_number: None,
            feed: feed.map(f64::from),
            spindle: feed.map(|_| 0.0),
            pins,
            overrides: ov,
            accessory: None,
        };
        let text = report.to_string();
        prop_assert_eq!(parse_line(&text).unwrap(), Response::Status(report));
    }

    #[test]
    fn error_and_alarm_codes_round_trip(code in any::<u8>()) {
        prop_assert_eq!(parse_line(&format!("error:{code}")).unwrap(), Response::Error(ErrorCode(code)));
        prop_assert_eq!(parse_line(&format!("ALARM:{code}")).unwrap(), Response::Alarm(AlarmCode(code)));
    }

    #[test]
    fn encoded_moves_are_short_and_parse_back(mm in -1000.0f64..1000.0, feed in 0.1f64..5000.0) {
        let line = GrblCommand::Feed { distance: Distance::Absolute, axis: 'Z', mm, feed_mm_min: feed }.encode().unwrap();
        prop_assert!(line.len() <= LINE_BUFFER_SIZE);
        prop_assert!(line.ends_with('\n'));
        let z: f64 = line.split_whitespace().find_map(|w| w.strip_prefix('Z')).unwrap().parse().unwrap();
        prop_assert!((z - mm).abs() <= 5e-5);
    }
}
