//! Bounds on what a hostile sender can make the decoder hold or parse, and
//! the remembered header reading frames exactly as a fresh parse does.

use std::time::{Duration, Instant};

use super::*;
use crate::sensor::SensorFrame;

/// Issue 11: four never-completed frames of 4,095 x 65,000-byte packets pinned
/// 768 MB. Memory in flight now stays within the budget, whatever arrives.
#[test]
fn memory_in_flight_is_bounded() {
    let mut re = Tac3dReassembler::new(Duration::from_secs(60));
    let now = Instant::now();
    let payload = vec![b'x'; 65_000];
    let mut peak = 0;
    for serial in 0..4u32 {
        for index in 0..200u16 {
            let mut d = Vec::with_capacity(HEADER_LEN + payload.len());
            d.extend_from_slice(&serial.to_le_bytes());
            d.extend_from_slice(&4094u16.to_le_bytes());
            d.extend_from_slice(&index.to_le_bytes());
            d.extend_from_slice(&payload);
            let _ = re.push(&d, now);
            peak = peak.max(re.bytes_in_flight());
        }
    }
    assert!(peak <= MAX_BYTES_IN_FLIGHT, "{peak}");
    // Expiry releases everything.
    assert!(re.expire(now + Duration::from_secs(120)) > 0);
    assert_eq!(re.bytes_in_flight(), 0);
}

#[test]
fn nesting_is_bounded_in_both_readers() {
    let deep_flow = format!("index: 1\nSN: x\ntimestamp: 0.5\ndata: {}{}\n", "[".repeat(12_000), "]".repeat(12_000));
    let e = decode_frame(deep_flow.as_bytes(), &[]).unwrap_err();
    assert!(e.to_string().contains("nesting"), "{e}");
    let deep_block: String = (0..200).map(|i| format!("{}k{i}:\n", " ".repeat(i))).collect();
    let e = decode_frame(deep_block.as_bytes(), &[]).unwrap_err();
    assert!(e.to_string().contains("nesting"), "{e}");
}

fn small_frame(index: u64, n: usize) -> Tac3dFrame {
    let sf = SensorFrame {
        index,
        t_s: 71.25,
        positions: (0..n).map(|i| [i as f64 * 0.5, -(i as f64), 1.5]).collect(),
        displacements: (0..n).map(|i| [0.0, i as f64 * 0.25, -0.125 * i as f64]).collect(),
    };
    Tac3dFrame::from_sensor_frame(&sf, "AD2-0065L")
}

/// `decode_frame` with the header remembered from `primer` and without any.
fn both_ways(
    primer: &str,
    head: &str,
    blob: &[u8],
) -> (Result<Tac3dFrame, Tac3dError>, Result<Tac3dFrame, Tac3dError>) {
    header::forget();
    let fresh = decode_frame(head.as_bytes(), blob);
    header::forget();
    let _ = decode_frame(primer.as_bytes(), blob);
    (fresh, decode_frame(head.as_bytes(), blob))
}

/// A remembered header changes nothing: every header, valid or not, decodes to
/// the same frame or the same error as with nothing remembered.
#[test]
fn a_remembered_header_decodes_exactly_as_a_fresh_parse() {
    let (head, blob) = encode_parts(&small_frame(42, 3)).unwrap();
    let values = [
        ("1920", "71.5"),
        ("+7", "1e3"),
        ("0x10", "1"),
        ("-", "1"),
        ("7", "-"),
        ("7", ".inf"),
        ("7", "-.5"),
        ("[1, 2", "1"),
        ("7", "1 # a comment"),
        ("'7'", "1"),
        ("7", "'1.5'"),
        ("", "1"),
        ("7", "1\n  extra: 2"),
        ("7\nindex: 8", "1"),
        ("99999999999999999999", "1"),
        ("1e3", "abc"),
    ];
    for (index, ts) in values {
        let h = head
            .replace("index: 42", &format!("index: {index}"))
            .replace("timestamp: 71.25", &format!("timestamp: {ts}"));
        let (fresh, remembered) = both_ways(&head, &h, &blob);
        assert_eq!(fresh, remembered, "{h}");
    }
    // Same header, other blobs: short, with a NaN, grown.
    let mut nan = blob.clone();
    nan[8..16].copy_from_slice(&f64::NAN.to_le_bytes());
    let mut longer = blob.clone();
    longer.extend([0u8; 5]);
    for b in [&blob[..blob.len() - 1], &nan[..], &longer[..], &[][..]] {
        header::forget();
        let fresh = decode_frame(head.as_bytes(), b);
        let _ = decode_frame(head.as_bytes(), &blob);
        assert_eq!(
            fresh.and_then(|f| f.to_sensor_frame()),
            decode_frame(head.as_bytes(), b).and_then(|f| f.to_sensor_frame())
        );
    }
    // A header as other emitters write it (document marker, comment, items at
    // the key's indentation, a flow item) remembered and varied the same way.
    let vendor = "---\nindex: 1919\nSN: AD2-0065L\ntimestamp: 71.616892\nmsg: ''\ndata:  # items\n\
        - name: 3D_Positions\n  type: mat\n  dtype: f64\n  width: 3\n  height: 1\n  offset: 0\n  length: 24\n\
        - {name: 3D_Displacements, type: mat, dtype: f64, width: 3, height: 1, offset: 24, length: 24}\n";
    let vblob: Vec<u8> = [0.5f64, 1.5, 2.5, 0.0, 0.0, -0.2].iter().flat_map(|x| x.to_le_bytes()).collect();
    for (index, ts) in [("1920", "72"), ("1921", "1 # c"), ("'1922'", "73"), ("1923", "[74]")] {
        let h = vendor.replace("1919", index).replace("71.616892", ts);
        let (fresh, remembered) = both_ways(vendor, &h, &vblob);
        assert_eq!(fresh, remembered, "{h}");
    }
    // Another sensor, another layout.
    let (other, other_blob) = encode_parts(&small_frame(43, 5)).unwrap();
    let (fresh, remembered) = both_ways(&head, &other.replace("AD2-0065L", "SN-2"), &other_blob);
    assert_eq!(fresh, remembered);
}

/// The next frame of the same sensor takes the remembered header.
#[test]
fn the_next_frame_of_a_sensor_is_read_from_the_template() {
    header::forget();
    let (head, blob) = encode_parts(&small_frame(42, 3)).unwrap();
    let first = decode_frame(head.as_bytes(), &blob).unwrap();
    let (next, next_blob) = encode_parts(&small_frame(1_000_000, 3)).unwrap();
    let t = header::remembered(&next, &next_blob).expect("read from the template");
    assert_eq!(t, decode_frame(next.as_bytes(), &next_blob).unwrap());
    assert_eq!((t.index, first.index), (1_000_000, 42));
    // A quoted index is not a plain value: the full parse reads it (and refuses it).
    assert!(header::remembered(&next.replace("index: 1000000", "index: '1000000'"), &next_blob).is_none());
}
