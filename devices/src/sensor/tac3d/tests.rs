//! Bounds on what a hostile sender can make the decoder hold or parse.

use std::time::{Duration, Instant};

use super::*;

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
