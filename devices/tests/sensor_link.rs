//! easycalib's own link protocol (docs/sensor-link.md): the documented bytes,
//! round trips over a stream and datagrams, and every kind of malformed input
//! rejected with its reason and never a panic.

use devices::sensor::link::{
    LinkCommand, LinkDecoder, LinkError, LinkMessage, MAX_PAYLOAD, crc32, decode_datagram, encode, encode_raw,
    encode_raw_version, kind,
};
use devices::sensor::{BadReason, SensorFrame};

const DOC: &str = include_str!("../../docs/sensor-link.md");

/// The hex bytes of the fenced block after `<!-- example:NAME ... -->` in the doc.
fn doc_example(name: &str) -> Vec<u8> {
    let marker = format!("<!-- example:{name}");
    let at = DOC.find(&marker).unwrap_or_else(|| panic!("doc lacks {marker}"));
    let rest = &DOC[at..];
    let start = rest.find("```text\n").expect("fenced block") + "```text\n".len();
    let end = start + rest[start..].find("```").expect("closing fence");
    rest[start..end].split_whitespace().map(|h| u8::from_str_radix(h, 16).expect("hex byte")).collect()
}

fn frame(index: u64, n: usize) -> SensorFrame {
    SensorFrame {
        index,
        t_s: index as f64 / 30.0,
        positions: (0..n).map(|i| [(i % 20) as f64 - 9.5, (i / 20) as f64 - 9.5, -0.25]).collect(),
        displacements: (0..n).map(|i| [0.0, 0.001 * i as f64, -0.5]).collect(),
    }
}

/// Decode everything a stream decoder yields for `bytes` fed in `chunk`-sized pieces.
fn decode_stream(bytes: &[u8], chunk: usize) -> Vec<Result<LinkMessage, LinkError>> {
    let mut d = LinkDecoder::new();
    let mut out = Vec::new();
    for c in bytes.chunks(chunk.max(1)) {
        d.push(c);
        while let Some(m) = d.next_message() {
            out.push(m);
        }
    }
    out
}

fn reasons(v: &[Result<LinkMessage, LinkError>]) -> Vec<BadReason> {
    v.iter().filter_map(|m| m.as_ref().err().map(LinkError::reason)).collect()
}

fn frames(v: &[Result<LinkMessage, LinkError>]) -> Vec<SensorFrame> {
    v.iter()
        .filter_map(|m| match m {
            Ok(LinkMessage::Frame(f)) => Some(f.clone()),
            _ => None,
        })
        .collect()
}

#[test]
fn crc32_is_the_zlib_crc() {
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc32(b""), 0);
}

#[test]
fn the_documented_worked_example_is_what_the_codec_writes_and_reads() {
    let f =
        SensorFrame { index: 7, t_s: 0.5, positions: vec![[1.0, -2.0, 0.5]], displacements: vec![[0.0, 0.0, -0.25]] };
    let bytes = doc_example("frame");
    assert_eq!(bytes.len(), 60);
    assert_eq!(encode(&LinkMessage::Frame(f.clone())).unwrap(), bytes);
    assert_eq!(decode_datagram(&bytes).unwrap(), LinkMessage::Frame(f.clone()));
    assert_eq!(frames(&decode_stream(&bytes, 1)), vec![f]);

    let start = doc_example("start");
    assert_eq!(encode(&LinkMessage::Command(LinkCommand::Start)).unwrap(), start);
    assert_eq!(decode_datagram(&start).unwrap(), LinkMessage::Command(LinkCommand::Start));
    let ack = doc_example("ack-start");
    assert_eq!(encode(&LinkMessage::Ack(LinkCommand::Start)).unwrap(), ack);
    assert_eq!(decode_datagram(&ack).unwrap(), LinkMessage::Ack(LinkCommand::Start));
}

#[test]
fn header_fields_sit_at_the_documented_offsets() {
    let f = frame(0x0102_0304_0506_0708, 3);
    let b = encode(&LinkMessage::Frame(f.clone())).unwrap();
    let n = 20 + 24 * 3;
    assert_eq!(b.len(), 12 + n + 4);
    assert_eq!(&b[0..4], &[0xEC, 0xCA, 1, kind::FRAME]);
    assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()) as usize, n);
    assert_eq!(u32::from_le_bytes(b[8..12].try_into().unwrap()), crc32(&b[0..8]));
    assert_eq!(&b[12..20], &[8, 7, 6, 5, 4, 3, 2, 1], "counter u64 LE");
    assert_eq!(f64::from_le_bytes(b[20..28].try_into().unwrap()), f.t_s);
    assert_eq!(u32::from_le_bytes(b[28..32].try_into().unwrap()), 3);
    // Marker 2's y position, then marker 0's displacement block.
    assert_eq!(f32::from_le_bytes(b[32 + 24 + 4..32 + 24 + 8].try_into().unwrap()), -9.5);
    assert_eq!(f32::from_le_bytes(b[32 + 36 + 8..32 + 36 + 12].try_into().unwrap()), -0.5);
    assert_eq!(u32::from_le_bytes(b[12 + n..].try_into().unwrap()), crc32(&b[12..12 + n]));
    for c in [LinkCommand::Start, LinkCommand::Stop, LinkCommand::Tare] {
        let m = encode(&LinkMessage::Command(c)).unwrap();
        assert_eq!(m[3], c.kind());
        assert_eq!(m.len(), 16);
        let a = encode(&LinkMessage::Ack(c)).unwrap();
        assert_eq!((a[3], a[12], a.len()), (kind::ACK, c.kind(), 17));
    }
    assert_eq!((kind::START, kind::STOP, kind::TARE, kind::ACK), (0x10, 0x11, 0x12, 0x20));
}

#[test]
fn a_stream_decodes_the_same_in_any_chunking() {
    let msgs = [
        LinkMessage::Frame(frame(1, 400)),
        LinkMessage::Ack(LinkCommand::Start),
        LinkMessage::Frame(frame(2, 0)),
        LinkMessage::Frame(frame(3, 7)),
    ];
    let bytes: Vec<u8> = msgs.iter().flat_map(|m| encode(m).unwrap()).collect();
    // Values travel as f32: compare against the f32-rounded frames.
    let expect: Vec<LinkMessage> = msgs.iter().map(|m| decode_datagram(&encode(m).unwrap()).unwrap()).collect();
    for chunk in [1, 2, 3, 11, 12, 13, 1000, bytes.len()] {
        let got: Vec<LinkMessage> = decode_stream(&bytes, chunk).into_iter().map(Result::unwrap).collect();
        assert_eq!(got, expect, "chunk {chunk}");
    }
    let f = frame(1, 400);
    let LinkMessage::Frame(g) = &expect[0] else { panic!() };
    for (a, b) in f.displacements.iter().flatten().zip(g.displacements.iter().flatten()) {
        assert!((a - b).abs() <= 1e-7 * a.abs().max(1.0), "{a} vs {b}");
    }
}

#[test]
fn malformed_datagrams_are_rejected_with_their_reason() {
    let good = encode(&LinkMessage::Frame(frame(5, 2))).unwrap();
    let reason = |d: &[u8]| decode_datagram(d).unwrap_err().reason();

    let mut b = good.clone();
    b[5] ^= 0x01; // length field: header checksum fails
    assert_eq!(reason(&b), BadReason::HeaderChecksum);
    let mut b = good.clone();
    b[40] ^= 0x80; // a float inside the payload
    assert_eq!(reason(&b), BadReason::Checksum);
    let mut b = good.clone();
    let last = b.len() - 1;
    b[last] ^= 0xFF;
    assert_eq!(reason(&b), BadReason::Checksum);
    // Truncated, and with a byte too many.
    assert_eq!(reason(&good[..good.len() - 1]), BadReason::Length);
    assert_eq!(reason(&[good.as_slice(), &[0]].concat()), BadReason::Length);
    assert_eq!(reason(&good[..10]), BadReason::Length);
    // No sync.
    assert_eq!(reason(&[0u8; 40]), BadReason::Garbage);
    // Other version (checksums fine).
    let payload = &good[12..good.len() - 4];
    assert_eq!(reason(&encode_raw_version(2, kind::FRAME, payload).unwrap()), BadReason::Version);
    // Unknown kind; an ack of an unknown command.
    assert_eq!(reason(&encode_raw(0x7F, b"").unwrap()), BadReason::UnknownKind);
    assert_eq!(reason(&encode_raw(kind::ACK, &[0x42]).unwrap()), BadReason::UnknownKind);
    // Marker count disagreeing with the payload length, either way.
    let mut p = payload.to_vec();
    p[16] = 3;
    assert_eq!(reason(&encode_raw(kind::FRAME, &p).unwrap()), BadReason::Length);
    p[16] = 1;
    assert_eq!(reason(&encode_raw(kind::FRAME, &p).unwrap()), BadReason::Length);
    assert_eq!(reason(&encode_raw(kind::FRAME, &p[..19]).unwrap()), BadReason::Length);
    // A marker count so large that 24 n overflows 32 bits on the way.
    p[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
    assert_eq!(reason(&encode_raw(kind::FRAME, &p).unwrap()), BadReason::Length);
    // Payload on a command, wrong-size ack.
    assert_eq!(reason(&encode_raw(kind::START, &[0]).unwrap()), BadReason::Length);
    assert_eq!(reason(&encode_raw(kind::ACK, &[]).unwrap()), BadReason::Length);
    // NaN and infinity in the floats, and a NaN timestamp.
    for (off, bad) in [(20 + 4, f32::NAN), (20 + 24 + 8, f32::INFINITY)] {
        let mut p = payload.to_vec();
        p[off..off + 4].copy_from_slice(&bad.to_le_bytes());
        let e = decode_datagram(&encode_raw(kind::FRAME, &p).unwrap()).unwrap_err();
        assert_eq!(e.reason(), BadReason::NotFinite, "{e}");
    }
    let mut p = payload.to_vec();
    p[8..16].copy_from_slice(&f64::NAN.to_le_bytes());
    assert_eq!(reason(&encode_raw(kind::FRAME, &p).unwrap()), BadReason::NotFinite);
    // A length over the limit is refused from the header alone.
    let mut h = vec![0xEC, 0xCA, 1, kind::FRAME];
    h.extend(((MAX_PAYLOAD + 1) as u32).to_le_bytes());
    h.extend(crc32(&h).to_le_bytes());
    h.extend([0u8; 8]);
    let e = decode_datagram(&h).unwrap_err();
    assert!(matches!(e, LinkError::TooLong { .. }), "{e}");
    assert_eq!(e.reason(), BadReason::Length);
}

#[test]
fn errors_name_what_and_where() {
    let a = encode(&LinkMessage::Frame(frame(1, 1))).unwrap();
    let mut b = encode(&LinkMessage::Frame(frame(2, 1))).unwrap();
    b[30] ^= 1;
    let stream = [a.as_slice(), &b].concat();
    let out = decode_stream(&stream, 7);
    let e = out.iter().find_map(|m| m.as_ref().err()).expect("an error");
    assert!(matches!(e, LinkError::Checksum { at, .. } if *at == a.len() as u64), "{e}");
    assert!(e.to_string().contains(&format!("offset {}", a.len())), "{e}");
}

#[test]
fn the_stream_decoder_resynchronises_and_counts_every_kind() {
    let f = |i| encode(&LinkMessage::Frame(frame(i, 3))).unwrap();
    let mut bad_payload = f(2);
    bad_payload[30] ^= 0x10;
    let mut bad_header = f(3);
    bad_header[6] ^= 0x01;
    let payload = {
        let g = f(4);
        g[12..g.len() - 4].to_vec()
    };
    let mut nan = payload.clone();
    nan[20..24].copy_from_slice(&f32::NAN.to_le_bytes());
    let mut short = payload.clone();
    short.truncate(payload.len() - 12);
    let parts: Vec<Vec<u8>> = vec![
        b"boot log line\r\n".to_vec(),
        f(1),
        bad_payload,
        f(4),
        bad_header,
        f(5),
        encode_raw_version(9, kind::FRAME, &payload).unwrap(),
        encode_raw(0x55, b"??").unwrap(),
        encode_raw(kind::FRAME, &short).unwrap(),
        encode_raw(kind::FRAME, &nan).unwrap(),
        vec![0xEC, 0xEC, 0x00, 0xCA],
        f(6),
        f(7)[..20].to_vec(), // truncated: the stream ends inside a message
    ];
    let bytes = parts.concat();
    for chunk in [1, 5, 64, bytes.len()] {
        let out = decode_stream(&bytes, chunk);
        let idx: Vec<u64> = frames(&out).iter().map(|f| f.index).collect();
        assert_eq!(idx, vec![1, 4, 5, 6], "chunk {chunk}");
        // One error per incident, in stream order, whatever the chunking.
        assert_eq!(
            reasons(&out),
            vec![
                BadReason::Garbage,        // the boot log
                BadReason::Checksum,       // frame 2
                BadReason::HeaderChecksum, // frame 3 (its remaining bytes stay quiet)
                BadReason::Version,
                BadReason::UnknownKind,
                BadReason::Length,
                BadReason::NotFinite,
                BadReason::Garbage, // the stray bytes before frame 6
            ],
            "chunk {chunk}: {out:?}"
        );
    }
    // A long run of noise (a wrong baud rate) is reported every GARBAGE_REPORT bytes.
    let noise: Vec<u8> = (0..3000u32).map(|i| (i * 7 % 200) as u8 + 1).collect();
    for chunk in [1, 100, 3000] {
        let out = decode_stream(&noise, chunk);
        let sizes: Vec<usize> = out
            .iter()
            .map(|m| match m {
                Err(LinkError::Garbage { skipped, .. }) => *skipped,
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(sizes, vec![1024, 1024], "chunk {chunk}");
    }
    // The truncated tail is held, not reported, until more bytes come.
    let mut d = LinkDecoder::new();
    d.push(&f(7)[..20]);
    assert!(d.next_message().is_none());
    assert_eq!(d.buffered(), 20);
}
