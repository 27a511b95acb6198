//! Frames to datagrams and back: the 8-byte packet header, the YAML header
//! of packet 0 and the f64 blob of packets 1..N.

use std::fmt::Write as _;

use super::yaml::{self, Yaml, YamlError, YamlErrorKind};
use super::{HEADER_LEN, INITIALIZE_PROGRESS, Tac3dEncodeError, Tac3dError, Tac3dFrame, Tac3dItem, Tac3dValue};

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

fn field<'a, 'y>(y: &'a Yaml<'y>, key: &str) -> Result<&'a Yaml<'y>, Tac3dError> {
    y.get(key).ok_or_else(|| Tac3dError::MissingField { field: key.to_string() })
}

fn field_u64(y: &Yaml, key: &str, ctx: &str) -> Result<u64, Tac3dError> {
    let v = y.get(key).ok_or_else(|| Tac3dError::MissingField { field: format!("{ctx}{key}") })?;
    v.as_u64().ok_or_else(|| Tac3dError::BadField {
        field: format!("{ctx}{key}"),
        what: format!("is not an unsigned integer: {v:?}"),
    })
}

fn field_str<'a>(y: &'a Yaml<'_>, key: &str, ctx: &str) -> Result<&'a str, Tac3dError> {
    let v = y.get(key).ok_or_else(|| Tac3dError::MissingField { field: format!("{ctx}{key}") })?;
    v.as_str().ok_or_else(|| Tac3dError::BadField { field: format!("{ctx}{key}"), what: "is not a scalar".into() })
}

/// Decode a frame from its header text bytes (packet 0's payload) and the
/// concatenated blob (packets 1..N). Items of a type or dtype this decoder does
/// not know are skipped, as the vendor's client does. A frame carrying
/// `InitializeProgress` other than 100 is refused, as the client refuses it.
pub fn decode_frame(head: &[u8], blob: &[u8]) -> Result<Tac3dFrame, Tac3dError> {
    if let Some(at) = head.iter().position(|b| !b.is_ascii()) {
        return Err(Tac3dError::NotAscii { at });
    }
    let text = std::str::from_utf8(head).map_err(|e| Tac3dError::NotAscii { at: e.valid_up_to() })?;
    let y = yaml::parse(text)?;
    if !matches!(y, Yaml::Map(_)) {
        return Err(YamlError { line: 1, kind: YamlErrorKind::NotMapping }.into());
    }
    let index = field_u64(&y, "index", "")?;
    let sn = field_str(&y, "SN", "")?.to_string();
    let ts = field(&y, "timestamp")?;
    let timestamp = ts
        .as_f64()
        .ok_or_else(|| Tac3dError::BadField { field: "timestamp".into(), what: format!("is not a number: {ts:?}") })?;
    if !timestamp.is_finite() {
        return Err(Tac3dError::NotFinite { item: "timestamp".into(), at: 0 });
    }
    let msg = match y.get("msg") {
        None => None,
        Some(m) => Some(
            m.as_str()
                .ok_or_else(|| Tac3dError::BadField { field: "msg".into(), what: "is not a scalar".into() })?
                .to_string(),
        ),
    };
    let items_y = match field(&y, "data")? {
        Yaml::Seq(v) => v.as_slice(),
        // `data:` with nothing under it: a frame without items.
        Yaml::Scalar { text, quoted: false } if text.is_empty() => &[],
        other => {
            return Err(Tac3dError::BadField { field: "data".into(), what: format!("is not a list: {other:?}") });
        }
    };
    let mut items = Vec::with_capacity(items_y.len());
    for (k, it) in items_y.iter().enumerate() {
        let ctx = format!("data[{k}].");
        let name = field_str(it, "name", &ctx)?.to_string();
        let ty = field_str(it, "type", &ctx)?;
        let known = match ty {
            "mat" => field_str(it, "dtype", &ctx)? == "f64",
            "f64" | "i32" | "img" => true,
            _ => false,
        };
        if !known {
            continue;
        }
        let offset = field_u64(it, "offset", &ctx)?;
        let length = field_u64(it, "length", &ctx)?;
        let end = offset.checked_add(length).filter(|e| *e <= blob.len() as u64);
        let Some(end) = end else {
            return Err(Tac3dError::Length {
                item: name,
                what: format!("offset {offset} + length {length} runs past the {} B blob", blob.len()),
            });
        };
        let bytes = &blob[offset as usize..end as usize];
        let value = match ty {
            "mat" => {
                let cols = field_u64(it, "width", &ctx)?;
                let rows = field_u64(it, "height", &ctx)?;
                let want = rows.checked_mul(cols).and_then(|n| n.checked_mul(8));
                if want != Some(length) {
                    return Err(Tac3dError::Length {
                        item: name,
                        what: format!("{rows} x {cols} f64 matrix needs {want:?} B, length says {length}"),
                    });
                }
                let data = bytes
                    .chunks_exact(8)
                    .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
                    .collect();
                Tac3dValue::Mat { rows: rows as usize, cols: cols as usize, data }
            }
            "f64" => match <[u8; 8]>::try_from(bytes) {
                Ok(b) => Tac3dValue::F64(f64::from_le_bytes(b)),
                Err(_) => {
                    return Err(Tac3dError::Length {
                        item: name,
                        what: format!("f64 needs 8 B, length says {length}"),
                    });
                }
            },
            "i32" => match <[u8; 4]>::try_from(bytes) {
                Ok(b) => Tac3dValue::I32(i32::from_le_bytes(b)),
                Err(_) => {
                    return Err(Tac3dError::Length {
                        item: name,
                        what: format!("i32 needs 4 B, length says {length}"),
                    });
                }
            },
            _ => Tac3dValue::Img(bytes.to_vec()),
        };
        if name == INITIALIZE_PROGRESS {
            let progress = match value {
                Tac3dValue::I32(p) => f64::from(p),
                Tac3dValue::F64(p) => p,
                _ => 100.0,
            };
            if progress != 100.0 {
                return Err(Tac3dError::Initializing { progress });
            }
        }
        items.push(Tac3dItem { name, value });
    }
    Ok(Tac3dFrame { index, sn, timestamp, msg, items })
}
