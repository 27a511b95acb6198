//! Encoding and decoding of single messages: bytes in, messages out.

use super::{
    CRC_LEN, FRAME_FIXED, FRAME_PER_MARKER, HEADER_LEN, LinkCommand, LinkEncodeError, LinkError, LinkMessage,
    MAX_MARKERS, MAX_PAYLOAD, SYNC, VERSION, crc32, kind,
};
use crate::sensor::frame::SensorFrame;

/// Frame any payload with any kind byte (version 1). Bridge programs and
/// tests use it directly; [`encode`] builds the payloads.
pub fn encode_raw(kind: u8, payload: &[u8]) -> Result<Vec<u8>, LinkEncodeError> {
    encode_raw_version(VERSION, kind, payload)
}

/// [`encode_raw`] with an explicit version byte (for tests of version handling).
pub fn encode_raw_version(version: u8, kind: u8, payload: &[u8]) -> Result<Vec<u8>, LinkEncodeError> {
    if payload.len() > MAX_PAYLOAD {
        return Err(LinkEncodeError::TooLong(payload.len()));
    }
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len() + CRC_LEN);
    out.extend_from_slice(&SYNC);
    out.push(version);
    out.push(kind);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    let hcrc = crc32(&out[..8]);
    out.extend_from_slice(&hcrc.to_le_bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&crc32(payload).to_le_bytes());
    Ok(out)
}

fn frame_payload(f: &SensorFrame) -> Result<Vec<u8>, LinkEncodeError> {
    let n = f.positions.len();
    if f.displacements.len() != n {
        return Err(LinkEncodeError::MarkerMismatch { positions: n, displacements: f.displacements.len() });
    }
    if n > MAX_MARKERS {
        return Err(LinkEncodeError::TooManyMarkers(n));
    }
    let mut p = Vec::with_capacity(FRAME_FIXED + FRAME_PER_MARKER * n);
    p.extend_from_slice(&f.index.to_le_bytes());
    p.extend_from_slice(&f.t_s.to_le_bytes());
    p.extend_from_slice(&(n as u32).to_le_bytes());
    for (field, rows) in [("position", &f.positions), ("displacement", &f.displacements)] {
        for (marker, row) in rows.iter().enumerate() {
            for &x in row {
                let x = x as f32;
                if !x.is_finite() {
                    return Err(LinkEncodeError::NotFinite { field, marker });
                }
                p.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    Ok(p)
}

/// Encode a frame message ([`encode`] of [`LinkMessage::Frame`], without
/// handing over the frame).
pub fn encode_frame(f: &SensorFrame) -> Result<Vec<u8>, LinkEncodeError> {
    encode_raw(kind::FRAME, &frame_payload(f)?)
}

/// Encode one message into its bytes on the wire.
pub fn encode(msg: &LinkMessage) -> Result<Vec<u8>, LinkEncodeError> {
    match msg {
        LinkMessage::Frame(f) => encode_frame(f),
        LinkMessage::Command(c) => encode_raw(c.kind(), &[]),
        LinkMessage::Ack(c) => encode_raw(kind::ACK, &[c.kind()]),
    }
}

pub(super) fn u32_at(b: &[u8], i: usize) -> u32 {
    u32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

fn f32_at(b: &[u8], i: usize) -> f32 {
    f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

fn u64_at(b: &[u8], i: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[i..i + 8]);
    u64::from_le_bytes(a)
}

/// Parse a payload whose checksums already passed.
pub(super) fn parse_payload(at: u64, k: u8, p: &[u8]) -> Result<LinkMessage, LinkError> {
    let len_err = |expected: usize| LinkError::Length { at, kind: k, expected, got: p.len() };
    match k {
        kind::FRAME => {
            if p.len() < FRAME_FIXED {
                return Err(len_err(FRAME_FIXED));
            }
            let index = u64_at(p, 0);
            let t_s = f64::from_le_bytes({
                let mut a = [0u8; 8];
                a.copy_from_slice(&p[8..16]);
                a
            });
            let n = u32_at(p, 16) as usize;
            let expected =
                n.checked_mul(FRAME_PER_MARKER).and_then(|x| x.checked_add(FRAME_FIXED)).unwrap_or(usize::MAX);
            if p.len() != expected {
                return Err(len_err(expected));
            }
            if !t_s.is_finite() {
                return Err(LinkError::NotFinite { at, field: "timestamp", marker: 0 });
            }
            let read = |base: usize, field: &'static str| -> Result<Vec<[f64; 3]>, LinkError> {
                (0..n)
                    .map(|m| {
                        let o = base + 12 * m;
                        let v = [f32_at(p, o), f32_at(p, o + 4), f32_at(p, o + 8)];
                        if v.iter().all(|x| x.is_finite()) {
                            Ok(v.map(f64::from))
                        } else {
                            Err(LinkError::NotFinite { at, field, marker: m })
                        }
                    })
                    .collect()
            };
            let positions = read(FRAME_FIXED, "position")?;
            let displacements = read(FRAME_FIXED + 12 * n, "displacement")?;
            Ok(LinkMessage::Frame(SensorFrame { index, t_s, positions, displacements }))
        }
        kind::START | kind::STOP | kind::TARE => {
            if !p.is_empty() {
                return Err(len_err(0));
            }
            Ok(LinkMessage::Command(LinkCommand::from_kind(k).ok_or(LinkError::UnknownKind { at, kind: k })?))
        }
        kind::ACK => {
            if p.len() != 1 {
                return Err(len_err(1));
            }
            LinkCommand::from_kind(p[0]).map(LinkMessage::Ack).ok_or(LinkError::UnknownKind { at, kind: p[0] })
        }
        other => Err(LinkError::UnknownKind { at, kind: other }),
    }
}

/// What the fixed header says, after its checksum passed.
pub(super) struct Header {
    pub version: u8,
    pub kind: u8,
    pub len: usize,
}

pub(super) fn parse_header(at: u64, h: &[u8]) -> Result<Header, LinkError> {
    let computed = crc32(&h[..8]);
    let received = u32_at(h, 8);
    if computed != received {
        return Err(LinkError::HeaderChecksum { at, computed, received });
    }
    Ok(Header { version: h[2], kind: h[3], len: u32_at(h, 4) as usize })
}

/// Decode a datagram holding exactly one message.
pub fn decode_datagram(d: &[u8]) -> Result<LinkMessage, LinkError> {
    let short = |what| LinkError::Datagram { len: d.len(), what };
    if d.len() < HEADER_LEN + CRC_LEN {
        return Err(short("shorter than header and checksum"));
    }
    if d[..2] != SYNC {
        return Err(LinkError::Garbage { at: 0, skipped: d.len() });
    }
    let h = parse_header(0, &d[..HEADER_LEN])?;
    if h.len > MAX_PAYLOAD {
        return Err(LinkError::TooLong { at: 0, len: h.len });
    }
    if d.len() != HEADER_LEN + h.len + CRC_LEN {
        return Err(short("length field disagrees with datagram size"));
    }
    let payload = &d[HEADER_LEN..HEADER_LEN + h.len];
    let computed = crc32(payload);
    let received = u32_at(d, HEADER_LEN + h.len);
    if computed != received {
        return Err(LinkError::Checksum { at: 0, computed, received });
    }
    if h.version != VERSION {
        return Err(LinkError::Version { at: 0, version: h.version });
    }
    parse_payload(0, h.kind, payload)
}
