//! The CRC against its definition.

use super::*;

/// Bit-at-a-time reference, straight from the definition.
fn crc32_bitwise(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

#[test]
fn crc_matches_the_definition_at_every_length_and_alignment() {
    let data: Vec<u8> = (0..300u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8).collect();
    for start in 0..8 {
        for len in 0..data.len() - start {
            let d = &data[start..start + len];
            assert_eq!(crc32(d), crc32_bitwise(d), "start {start} len {len}");
        }
    }
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
}
