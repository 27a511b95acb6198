//! Frames to datagrams and back: the 8-byte packet header, the YAML header
//! of packet 0 and the f64 blob of packets 1..N.

use std::fmt::Write as _;

use super::{HEADER_LEN, Tac3dEncodeError, Tac3dError, Tac3dFrame, Tac3dValue, header, yaml};

/// The YAML header text of packet 0 and the blob of packets 1..N.
pub fn encode_parts(frame: &Tac3dFrame) -> Result<(String, Vec<u8>), Tac3dEncodeError> {
    if !frame.timestamp.is_finite() {
        return Err(Tac3dEncodeError::Timestamp(frame.timestamp));
    }
    let mut head = String::with_capacity(256 + 128 * frame.items.len());
    let _ = writeln!(head, "index: {}", frame.index);
    head.push_str("SN: ");
    yaml::write_str(&mut head, &frame.sn);
    head.push_str("\ntimestamp: ");
    yaml::write_f64(&mut head, frame.timestamp);
    head.push('\n');
    if let Some(msg) = &frame.msg {
        head.push_str("msg: ");
        if msg.is_empty() {
            head.push_str("''");
        } else {
            yaml::write_str(&mut head, msg);
        }
        head.push('\n');
    }
    head.push_str("data:\n");
    let total: usize = frame.items.iter().map(|i| i.value.byte_len()).sum();
    let mut blob = Vec::with_capacity(total);
    for item in &frame.items {
        let offset = blob.len();
        head.push_str("  - name: ");
        yaml::write_str(&mut head, &item.name);
        let _ = write!(head, "\n    type: {}\n", item.value.type_name());
        match &item.value {
            Tac3dValue::Mat { rows, cols, data } => {
                if rows * cols != data.len() {
                    return Err(Tac3dEncodeError::MatShape {
                        item: item.name.clone(),
                        rows: *rows,
                        cols: *cols,
                        len: data.len(),
                    });
                }
                let _ = write!(head, "    dtype: f64\n    width: {cols}\n    height: {rows}\n");
                for x in data {
                    blob.extend_from_slice(&x.to_le_bytes());
                }
            }
            Tac3dValue::F64(x) => blob.extend_from_slice(&x.to_le_bytes()),
            Tac3dValue::I32(x) => blob.extend_from_slice(&x.to_le_bytes()),
            Tac3dValue::Img(b) => blob.extend_from_slice(b),
        }
        let _ = writeln!(head, "    offset: {offset}\n    length: {}", blob.len() - offset);
    }
    Ok((head, blob))
}

/// Split a frame into datagrams of at most `max_datagram` bytes (header
/// included): packet 0 = YAML header, packets 1..N = blob chunks. The
/// datagram serial is the frame index modulo 2^32.
pub fn encode_frame(frame: &Tac3dFrame, max_datagram: usize) -> Result<Vec<Vec<u8>>, Tac3dEncodeError> {
    let (head, blob) = encode_parts(frame)?;
    if max_datagram < HEADER_LEN + head.len() || max_datagram <= HEADER_LEN {
        return Err(Tac3dEncodeError::DatagramTooSmall { max_datagram, needed: HEADER_LEN + head.len() });
    }
    let chunk = max_datagram - HEADER_LEN;
    let chunks: Vec<&[u8]> = blob.chunks(chunk).collect();
    let packets = 1 + chunks.len();
    if packets > usize::from(u16::MAX) + 1 {
        return Err(Tac3dEncodeError::TooManyPackets { packets });
    }
    let serial = frame.index as u32;
    let last = (packets - 1) as u16;
    let mut out = Vec::with_capacity(packets);
    let header = |this: u16| {
        let mut h = Vec::with_capacity(max_datagram);
        h.extend_from_slice(&serial.to_le_bytes());
        h.extend_from_slice(&last.to_le_bytes());
        h.extend_from_slice(&this.to_le_bytes());
        h
    };
    let mut p0 = header(0);
    p0.extend_from_slice(head.as_bytes());
    out.push(p0);
    for (i, c) in chunks.iter().enumerate() {
        let mut p = header((i + 1) as u16);
        p.extend_from_slice(c);
        out.push(p);
    }
    Ok(out)
}

/// The 8-byte datagram header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PacketHeader {
    pub serial: u32,
    pub last: u16,
    pub this: u16,
}

pub fn parse_packet_header(datagram: &[u8]) -> Result<PacketHeader, Tac3dError> {
    let Some(h) = datagram.get(..HEADER_LEN) else {
        return Err(Tac3dError::ShortDatagram { len: datagram.len() });
    };
    Ok(PacketHeader {
        serial: u32::from_le_bytes([h[0], h[1], h[2], h[3]]),
        last: u16::from_le_bytes([h[4], h[5]]),
        this: u16::from_le_bytes([h[6], h[7]]),
    })
}

/// Decode a frame from its header text bytes (packet 0's payload) and the
/// concatenated blob (packets 1..N). Items of a type or dtype this decoder does
/// not know are skipped, as the vendor's client does. A frame carrying
/// `InitializeProgress` other than 100 is refused, as the client refuses it.
///
/// The header is YAML; consecutive frames of one sensor send the same header
/// but for `index` and `timestamp`, so the last header read on this thread is
/// remembered and a header that differs from it only there is decoded without
/// parsing it again (see `header.rs`: same frames, same errors, a fraction of the
/// time).
pub fn decode_frame(head: &[u8], blob: &[u8]) -> Result<Tac3dFrame, Tac3dError> {
    if let Some(at) = head.iter().position(|b| !b.is_ascii()) {
        return Err(Tac3dError::NotAscii { at });
    }
    let text = std::str::from_utf8(head).map_err(|e| Tac3dError::NotAscii { at: e.valid_up_to() })?;
    header::decode(text, blob)
}
