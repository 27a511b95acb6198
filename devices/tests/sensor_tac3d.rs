//! Tac3D UDP codec (docs/hardware.md C.1): byte-exact encoding as the vendor's main
//! program sends, decoding as the vendor's PyTac3D client reads, round trips,
//! and every kind of malformed input rejected with its reason.

use std::time::{Duration, Instant};

use devices::sensor::tac3d::{
    HEADER_LEN, Tac3dCommand, Tac3dError, Tac3dFrame, Tac3dReassembler, Tac3dValue, decode_frame, encode_frame,
    parse_packet_header,
};
use devices::sensor::{BadReason, SensorFrame};

/// One datagram as docs/hardware.md C.1 lays it out: `=IHH` (serial u32, last
/// packet index u16, this packet index u16), little-endian, then the payload.
fn datagram(serial: u32, last: u16, this: u16, payload: &[u8]) -> Vec<u8> {
    let mut d = Vec::new();
    d.extend_from_slice(&serial.to_le_bytes());
    d.extend_from_slice(&last.to_le_bytes());
    d.extend_from_slice(&this.to_le_bytes());
    d.extend_from_slice(payload);
    d
}

fn f64s(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// A small frame: `n` markers with distinct, exactly representable values.
fn small_frame(index: u64, n: usize) -> SensorFrame {
    SensorFrame {
        index,
        t_s: 71.25,
        positions: (0..n).map(|i| [i as f64 * 0.5, -(i as f64), 1.5]).collect(),
        displacements: (0..n).map(|i| [0.0, i as f64 * 0.25, -0.125 * i as f64]).collect(),
    }
}

fn reassemble(packets: &[Vec<u8>]) -> Result<Option<Tac3dFrame>, Tac3dError> {
    let mut re = Tac3dReassembler::new(Duration::from_secs(1));
    let now = Instant::now();
    let mut out = None;
    for p in packets {
        if let Some(f) = re.push(p, now)? {
            out = Some(f);
        }
    }
    Ok(out)
}

#[test]
fn encoding_is_byte_exact_to_the_documented_layout() {
    let frame = Tac3dFrame::from_sensor_frame(&small_frame(1919, 20), "AD2-0065L");
    // 20 x 3 f64 = 480 B per matrix, 960 B of blob; 400-byte datagrams carry
    // 392 B of blob each: packets 1..3 hold 392, 392 and 176 bytes.
    let packets = encode_frame(&frame, 400).unwrap();
    assert_eq!(packets.len(), 4);

    let yaml = "index: 1919\n\
                SN: AD2-0065L\n\
                timestamp: 71.25\n\
                msg: ''\n\
                data:\n\
                \x20 - name: 3D_Positions\n\
                \x20   type: mat\n\
                \x20   dtype: f64\n\
                \x20   width: 3\n\
                \x20   height: 20\n\
                \x20   offset: 0\n\
                \x20   length: 480\n\
                \x20 - name: 3D_Displacements\n\
                \x20   type: mat\n\
                \x20   dtype: f64\n\
                \x20   width: 3\n\
                \x20   height: 20\n\
                \x20   offset: 480\n\
                \x20   length: 480\n";
    // Header: serial 1919 = 0x0000077F, last packet 3, this packet k; all LE.
    assert_eq!(&packets[0][..HEADER_LEN], &[0x7F, 0x07, 0x00, 0x00, 0x03, 0x00, 0x00, 0x00]);
    assert_eq!(std::str::from_utf8(&packets[0][HEADER_LEN..]).unwrap(), yaml);
    for (k, p) in packets.iter().enumerate().skip(1) {
        assert_eq!(&p[..HEADER_LEN], &[0x7F, 0x07, 0x00, 0x00, 0x03, 0x00, k as u8, 0x00], "packet {k}");
    }
    assert_eq!(packets.iter().map(Vec::len).collect::<Vec<_>>(), vec![8 + yaml.len(), 400, 400, 8 + 176]);

    // Blob: 3D_Positions row-major (x, y, z of marker 0, then marker 1, ...),
    // then 3D_Displacements; float64 little-endian. Tac3D's positions are the
    // current ones: reference + displacement.
    let blob: Vec<u8> = packets[1..].iter().flat_map(|p| p[HEADER_LEN..].to_vec()).collect();
    assert_eq!(blob.len(), 960);
    // Marker 1: reference (0.5, -1.0, 1.5) + displacement (0, 0.25, -0.125)
    // = (0.5, -0.75, 1.375) at bytes 24..48.
    assert_eq!(&blob[24..32], &[0, 0, 0, 0, 0, 0, 0xE0, 0x3F]);
    assert_eq!(&blob[32..40], &[0, 0, 0, 0, 0, 0, 0xE8, 0xBF]);
    assert_eq!(&blob[40..48], &[0, 0, 0, 0, 0, 0, 0xF6, 0x3F]);
    // Marker 19 displacement = (0, 4.75, -2.375) at 480 + 19 * 24.
    assert_eq!(&blob[480 + 456..480 + 480], f64s(&[0.0, 4.75, -2.375]).as_slice());
    let sf = small_frame(1919, 20);
    let current: Vec<[f64; 3]> =
        sf.positions.iter().zip(&sf.displacements).map(|(r, d)| [r[0] + d[0], r[1] + d[1], r[2] + d[2]]).collect();
    let expect_blob: Vec<u8> = current.iter().chain(sf.displacements.iter()).flat_map(|r| f64s(r)).collect();
    assert_eq!(blob, expect_blob);
    // Read back: the reference positions again (exact for these values).
    let f = reassemble(&packets).unwrap().expect("complete");
    assert_eq!(f.to_sensor_frame().unwrap(), sf);
}

#[test]
fn a_frame_fits_one_blob_packet_when_the_datagram_is_large() {
    let frame = Tac3dFrame::from_sensor_frame(&small_frame(7, 400), "S");
    let packets = encode_frame(&frame, 65507).unwrap();
    // 19 200 B of blob fits one datagram: packet 0 (YAML) + packet 1 (blob).
    assert_eq!(packets.len(), 2);
    assert_eq!(&packets[1][..8], &[7, 0, 0, 0, 1, 0, 1, 0]);
    assert_eq!(packets[1].len(), 8 + 400 * 3 * 8 * 2);
}

#[test]
fn datagram_too_small_for_the_header_is_an_encode_error() {
    let frame = Tac3dFrame::from_sensor_frame(&small_frame(7, 4), "S");
    assert!(encode_frame(&frame, 64).is_err());
}

/// Reference positions travel as reference + displacement, so they come back
/// within a rounding of the sum; displacements, index and time come back exact.
fn assert_same_frame(got: &SensorFrame, want: &SensorFrame) {
    assert_eq!((got.index, got.t_s), (want.index, want.t_s));
    assert_eq!(got.displacements, want.displacements);
    assert_eq!(got.positions.len(), want.positions.len());
    for (g, w) in got.positions.iter().zip(&want.positions) {
        for k in 0..3 {
            assert!((g[k] - w[k]).abs() <= 1e-12 * (1.0 + w[k].abs()), "{g:?} vs {w:?}");
        }
    }
}

#[test]
fn round_trip_reproduces_the_frame() {
    let sf = SensorFrame {
        index: 5_000_000_123,
        t_s: 1_234.000_000_1,
        positions: (0..400).map(|i| [i as f64 / 3.0, -(i as f64).sqrt(), 1e-9 * i as f64]).collect(),
        displacements: (0..400).map(|i| [f64::MIN_POSITIVE, -1.49 + i as f64 * 1e-7, 0.0]).collect(),
    };
    let packets = encode_frame(&Tac3dFrame::from_sensor_frame(&sf, "HDL1-GWH0021"), 1472).unwrap();
    // The datagram serial is the frame index modulo 2^32; the YAML keeps all 64 bits.
    let h = parse_packet_header(&packets[0]).unwrap();
    assert_eq!(h.serial, (5_000_000_123u64 % (1 << 32)) as u32);
    assert_eq!(usize::from(h.last) + 1, packets.len());
    let mut shuffled = packets.clone();
    shuffled.reverse();
    let f = reassemble(&shuffled).unwrap().expect("complete frame");
    assert_eq!(f.sn, "HDL1-GWH0021");
    assert_eq!(f.msg.as_deref(), Some(""));
    assert_same_frame(&f.to_sensor_frame().unwrap(), &sf);
}

/// A frame written the way other YAML emitters write it (sequence items at
/// the key's indentation, as ruamel.yaml and PyYAML emit; a document marker;
/// a comment), carrying every field the vendor's main program sends, split over
/// packets that arrive out of order and interleaved with another frame.
#[test]
fn a_frame_as_the_vendor_sends_it_decodes() {
    let pos: Vec<f64> = (0..6).map(|i| i as f64 + 0.5).collect();
    let nrm: Vec<f64> = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0].to_vec();
    let dis: Vec<f64> = [0.0, 0.0, 0.0, 0.01, -0.02, -1.49].to_vec();
    let frc: Vec<f64> = [0.0, 0.0, 0.0, 0.1, 0.2, -0.3].to_vec();
    let rf: Vec<f64> = [0.1, 0.2, -0.3].to_vec();
    let rm: Vec<f64> = [0.0, 0.0, 17.0].to_vec();
    let mut blob = Vec::new();
    for m in [&pos, &nrm, &dis, &frc, &rf, &rm] {
        blob.extend(f64s(m));
    }
    blob.extend(100i32.to_le_bytes());
    let head = "---\n\
        index: 1919\n\
        SN: AD2-0065L\n\
        timestamp: 71.616892\n\
        msg: ''\n\
        data:  # items point into the blob\n\
        - name: 3D_Positions\n  type: mat\n  dtype: f64\n  width: 3\n  height: 2\n  offset: 0\n  length: 48\n\
        - name: 3D_Normals\n  type: mat\n  dtype: f64\n  width: 3\n  height: 2\n  offset: 48\n  length: 48\n\
        - name: 3D_Displacements\n  type: mat\n  dtype: f64\n  width: 3\n  height: 2\n  offset: 96\n  length: 48\n\
        - {name: 3D_Forces, type: mat, dtype: f64, width: 3, height: 2, offset: 144, length: 48}\n\
        - name: 3D_ResultantForce\n  type: mat\n  dtype: f64\n  width: 3\n  height: 1\n  offset: 192\n  length: 24\n\
        - name: 3D_ResultantMoment\n  type: mat\n  dtype: f64\n  width: 3\n  height: 1\n  offset: 216\n  length: 24\n\
        - name: InitializeProgress\n  type: i32\n  offset: 240\n  length: 4\n";
    assert_eq!(blob.len(), 244);
    let other = encode_frame(&Tac3dFrame::from_sensor_frame(&small_frame(1918, 3), "AD2-0065L"), 100_000).unwrap();
    let packets = [
        datagram(1919, 3, 2, &blob[100..200]),
        other[1].clone(),
        datagram(1919, 3, 0, head.as_bytes()),
        datagram(1919, 3, 3, &blob[200..]),
        other[0].clone(),
        datagram(1919, 3, 1, &blob[..100]),
    ];
    let mut re = Tac3dReassembler::new(Duration::from_secs(1));
    let now = Instant::now();
    let done: Vec<Tac3dFrame> = packets.iter().filter_map(|p| re.push(p, now).unwrap()).collect();
    assert_eq!(re.pending(), 0);
    assert_eq!(done.len(), 2);
    assert_eq!(done[0].index, 1918, "the interleaved frame completes first");
    let f = &done[1];
    assert_eq!((f.index, f.sn.as_str(), f.timestamp), (1919, "AD2-0065L", 71.616892));
    assert_eq!(f.item("3D_ResultantMoment"), Some(&Tac3dValue::Mat { rows: 1, cols: 3, data: rm }));
    assert_eq!(f.item("InitializeProgress"), Some(&Tac3dValue::I32(100)));
    assert_eq!(f.item("3D_Forces"), Some(&Tac3dValue::Mat { rows: 2, cols: 3, data: frc }));
    assert_eq!(f.item("3D_ResultantForce"), Some(&Tac3dValue::from_rows(&[[0.1, 0.2, -0.3]])));
    let sf = f.to_sensor_frame().unwrap();
    // Reference = current - displacement.
    assert_eq!(sf.positions, vec![[0.5, 1.5, 2.5], [3.5 - 0.01, 4.5 + 0.02, 5.5 + 1.49]]);
    assert_eq!(sf.displacements, vec![[0.0, 0.0, 0.0], [0.01, -0.02, -1.49]]);
    assert_eq!(sf.t_s, 71.616892);
}

/// Header and blob for a minimal valid frame, to mutate in the tests below.
fn parts(n: usize) -> (String, Vec<u8>) {
    devices::sensor::tac3d::encode_parts(&Tac3dFrame::from_sensor_frame(&small_frame(42, n), "SN1")).unwrap()
}

fn frame_error(head: &str, blob: &[u8]) -> Tac3dError {
    let f = decode_frame(head.as_bytes(), blob);
    match f.and_then(|f| f.to_sensor_frame()) {
        Ok(f) => panic!("accepted a malformed frame: {f:?}"),
        Err(e) => e,
    }
}

#[test]
fn malformed_frames_are_rejected_with_their_reason() {
    let (head, blob) = parts(2);
    assert!(decode_frame(head.as_bytes(), &blob).unwrap().to_sensor_frame().is_ok());

    // Truncated blob: the last item runs past its end.
    let e = frame_error(&head, &blob[..blob.len() - 1]);
    assert_eq!(e.reason(), BadReason::Length, "{e}");
    assert!(e.to_string().contains("3D_Displacements"), "{e}");
    // Matrix length that disagrees with width x height.
    let e = frame_error(&head.replacen("length: 48", "length: 40", 1), &blob);
    assert_eq!(e.reason(), BadReason::Length, "{e}");
    // Not n x 3.
    let bad = head.replacen("width: 3\n    height: 2", "width: 2\n    height: 3", 1);
    assert_eq!(frame_error(&bad, &blob).reason(), BadReason::Length);
    // Positions and displacements of different marker counts.
    let bad =
        head.replacen("height: 2\n    offset: 48\n    length: 48", "height: 1\n    offset: 48\n    length: 24", 1);
    assert_eq!(frame_error(&bad, &blob).reason(), BadReason::Length);
    // NaN in a displacement.
    let mut nan = blob.clone();
    nan[48 + 8..48 + 16].copy_from_slice(&f64::NAN.to_le_bytes());
    let e = frame_error(&head, &nan);
    assert_eq!(e, Tac3dError::NotFinite { item: "3D_Displacements".into(), at: 1 });
    // Infinite timestamp.
    assert_eq!(frame_error(&head.replace("timestamp: 71.25", "timestamp: .inf"), &blob).reason(), BadReason::NotFinite);
    // Missing keys and items.
    assert_eq!(frame_error(&head.replace("SN: SN1\n", ""), &blob).reason(), BadReason::MissingField);
    assert_eq!(frame_error(&head.replace("index: 42\n", ""), &blob).reason(), BadReason::MissingField);
    assert_eq!(frame_error(&head.replace("index: 42", "index: -3"), &blob).reason(), BadReason::MissingField);
    let e = frame_error(&head.replace("3D_Positions", "3D_Other"), &blob);
    assert_eq!(e, Tac3dError::MissingField { field: "3D_Positions".into() });
    // Not YAML, not ASCII.
    assert_eq!(frame_error("index: [1, 2\n", &blob).reason(), BadReason::Yaml);
    assert_eq!(frame_error(&head.replace("SN1", "S\u{e9}"), &blob).reason(), BadReason::Yaml);
    assert_eq!(frame_error("", &blob).reason(), BadReason::Yaml);
    // Still initialising (the client drops such frames).
    let mut b = blob.clone();
    b.extend(50i32.to_le_bytes());
    let init =
        format!("{head}  - name: InitializeProgress\n    type: i32\n    offset: {}\n    length: 4\n", blob.len());
    assert_eq!(frame_error(&init, &b), Tac3dError::Initializing { progress: 50.0 });
    // The same item with 100 is accepted.
    let mut b100 = blob.clone();
    b100.extend(100i32.to_le_bytes());
    assert!(decode_frame(init.as_bytes(), &b100).unwrap().to_sensor_frame().is_ok());
}

#[test]
fn malformed_datagrams_are_rejected_with_their_reason() {
    let (head, blob) = parts(2);
    let now = Instant::now();
    let mut re = Tac3dReassembler::new(Duration::from_secs(1));
    let reason = |r: Result<Option<Tac3dFrame>, Tac3dError>| r.unwrap_err().reason();

    assert_eq!(reason(re.push(&[1, 2, 3, 4, 5], now)), BadReason::ShortDatagram);
    // Packet index beyond the last packet.
    assert_eq!(reason(re.push(&datagram(9, 1, 2, &blob), now)), BadReason::PacketIndex);
    // Packets of one frame disagreeing on the packet count.
    assert!(re.push(&datagram(10, 1, 0, head.as_bytes()), now).unwrap().is_none());
    assert_eq!(reason(re.push(&datagram(10, 2, 1, &blob), now)), BadReason::PacketIndex);
    assert_eq!(re.pending(), 0, "the inconsistent frame is dropped");
    // The same packet twice.
    assert!(re.push(&datagram(11, 1, 0, head.as_bytes()), now).unwrap().is_none());
    assert_eq!(reason(re.push(&datagram(11, 1, 0, head.as_bytes()), now)), BadReason::DuplicatePacket);
    assert!(re.push(&datagram(11, 1, 1, &blob), now).unwrap().is_some(), "the frame still completes");
    // A frame whose other packets never come is dropped after the timeout.
    assert!(re.push(&datagram(12, 2, 0, head.as_bytes()), now).unwrap().is_none());
    assert_eq!(re.expire(now + Duration::from_millis(500)), 0);
    assert_eq!(re.expire(now + Duration::from_millis(1001)), 1);
    assert_eq!(re.pending(), 0);
    // Absurd packet counts are refused before any allocation.
    assert_eq!(reason(re.push(&datagram(13, u16::MAX, 0, b""), now)), BadReason::PacketIndex);
}

#[test]
fn a_flood_of_partial_frames_is_bounded_and_counted() {
    let mut re = Tac3dReassembler::new(Duration::from_secs(1));
    let now = Instant::now();
    for serial in 0..100u32 {
        assert!(re.push(&datagram(serial, 3, 1, b"x"), now).unwrap().is_none());
    }
    assert!(re.pending() <= 32, "{} partial frames held", re.pending());
    let evicted = re.expire(now);
    assert_eq!(evicted + re.pending(), 100);
    assert_eq!(re.expire(now + Duration::from_secs(2)) + evicted, 100);
}

#[test]
fn client_commands_parse() {
    assert_eq!(Tac3dCommand::parse(b"$C"), Some(Tac3dCommand::Calibrate));
    assert_eq!(Tac3dCommand::parse(b"$Q"), Some(Tac3dCommand::Quit));
    assert_eq!(Tac3dCommand::parse(b"$C\n"), None);
    assert_eq!(Tac3dCommand::parse(b""), None);
}

#[test]
fn unknown_item_types_are_skipped_as_the_client_skips_them() {
    let (head, mut blob) = parts(1);
    let extra_at = blob.len();
    blob.extend([1u8, 2, 3]);
    let head = format!(
        "{head}  - name: Weird\n    type: u8vec\n    offset: {extra_at}\n    length: 3\n  - name: Img\n    type: img\n    offset: {extra_at}\n    length: 3\n"
    );
    let f = decode_frame(head.as_bytes(), &blob).unwrap();
    assert!(f.item("Weird").is_none());
    assert_eq!(f.item("Img"), Some(&Tac3dValue::Img(vec![1, 2, 3])));
    assert_eq!(
        f.items.iter().map(|i| i.name.as_str()).collect::<Vec<_>>(),
        ["3D_Positions", "3D_Displacements", "Img"]
    );
}
