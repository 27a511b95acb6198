//! Tac3D's UDP frame format (hardware.md C.1), as the vendor's main program
//! sends it and the PyTac3D client reads it, plus a receiver for the rig.
//!
//! One frame = N+1 datagrams. Each starts with an 8-byte header
//! `serial: u32, last_packet: u16, this_packet: u16` (the client decodes it as
//! `=IHH`, host order; we write and read little-endian, which is what the x86 /
//! ARM hosts the vendor ships for use). Packet 0 carries an ASCII YAML header
//! (`index`, `SN`, `timestamp`, `msg`, `data: [...]`); packets 1..N carry the
//! binary blob in order, and each `data` item points into it by `offset` and
//! `length`. Matrices are float64, row-major, `height` rows by `width` columns.
//!
//! `3D_Positions` are the markers' *current* positions (reference +
//! displacement; checked on the recordings that ship with PyTac3D), so the
//! codec converts to and from [`SensorFrame`]'s reference positions.
//!
//! The codec here is pure (bytes in, frames out, time passed in explicitly);
//! [`Tac3dReceiver`] is the I/O edge on a tokio UDP socket.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_trait::async_trait;
use tokio::net::UdpSocket;
use tokio::task::JoinHandle;

use super::SensorLink;
use super::error::{SensorError, io_err};
use super::frame::SensorFrame;
use super::inbox::Inbox;
use super::stats::{BadReason, LinkStats};
use super::yaml::{self, Yaml};
pub use super::yaml::{YamlError, YamlErrorKind};
use crate::motion::{DeviceFault, FaultKind};

/// UDP port the PyTac3D client binds by default.
pub const DEFAULT_PORT: u16 = 9988;
/// Bytes in every datagram's header.
pub const HEADER_LEN: usize = 8;
/// Client -> sensor: re-zero (the Calibrate button; the sensor must be untouched).
pub const CMD_CALIBRATE: &[u8] = b"$C";
/// Client -> sensor: stop the sensor (SDK 3.2.1).
pub const CMD_QUIT: &[u8] = b"$Q";

/// Data item names the main program sends.
pub const POSITIONS: &str = "3D_Positions";
pub const DISPLACEMENTS: &str = "3D_Displacements";
pub const FORCES: &str = "3D_Forces";
pub const NORMALS: &str = "3D_Normals";
pub const RESULTANT_FORCE: &str = "3D_ResultantForce";
pub const RESULTANT_MOMENT: &str = "3D_ResultantMoment";
pub const INITIALIZE_PROGRESS: &str = "InitializeProgress";

/// The value of one data item.
#[derive(Debug, Clone, PartialEq)]
pub enum Tac3dValue {
    /// `type: mat, dtype: f64`: `rows` x `cols`, row-major.
    Mat { rows: usize, cols: usize, data: Vec<f64> },
    /// `type: f64`.
    F64(f64),
    /// `type: i32`.
    I32(i32),
    /// `type: img`: encoded image bytes (PNG/JPEG), passed through untouched.
    Img(Vec<u8>),
}

impl Tac3dValue {
    /// An `n x 3` matrix from rows (e.g. `3D_Forces`, `3D_Normals`, or a
    /// `1 x 3` `3D_ResultantForce`), for senders adding items to a frame.
    pub fn from_rows(rows: &[[f64; 3]]) -> Self {
        Tac3dValue::Mat { rows: rows.len(), cols: 3, data: rows.iter().flatten().copied().collect() }
    }

    fn type_name(&self) -> &'static str {
        match self {
            Tac3dValue::Mat { .. } => "mat",
            Tac3dValue::F64(_) => "f64",
            Tac3dValue::I32(_) => "i32",
            Tac3dValue::Img(_) => "img",
        }
    }

    fn byte_len(&self) -> usize {
        match self {
            Tac3dValue::Mat { data, .. } => data.len() * 8,
            Tac3dValue::F64(_) => 8,
            Tac3dValue::I32(_) => 4,
            Tac3dValue::Img(b) => b.len(),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Tac3dItem {
    pub name: String,
    pub value: Tac3dValue,
}

/// One Tac3D frame: the YAML header's scalars and the data items in blob order.
#[derive(Debug, Clone, PartialEq)]
pub struct Tac3dFrame {
    /// Frame number since the sensor started (does not begin at 0).
    pub index: u64,
    /// Sensor serial number, e.g. `AD2-0065L`.
    pub sn: String,
    /// Seconds since the main program started.
    pub timestamp: f64,
    /// Status text (SDK 3.3+); `None` = key absent (older senders).
    pub msg: Option<String>,
    pub items: Vec<Tac3dItem>,
}

impl Tac3dFrame {
    /// A frame carrying a [`SensorFrame`] as `n x 3` matrices, as the main
    /// program sends it: `3D_Positions` are the *current* marker positions,
    /// reference + displacement (the example recordings shipped with PyTac3D
    /// show `3D_Positions - 3D_Displacements` constant over a press: exactly
    /// for HDL1 sensors, within 0.08 mm for an AD2). Markers beyond the
    /// shorter of the two lists are left out.
    pub fn from_sensor_frame(frame: &SensorFrame, sn: &str) -> Self {
        let n = frame.positions.len().min(frame.displacements.len());
        let current: Vec<f64> = frame
            .positions
            .iter()
            .zip(&frame.displacements)
            .flat_map(|(r, d)| [r[0] + d[0], r[1] + d[1], r[2] + d[2]])
            .collect();
        let disp: Vec<f64> = frame.displacements[..n].iter().flatten().copied().collect();
        Self {
            index: frame.index,
            sn: sn.to_string(),
            timestamp: frame.t_s,
            msg: Some(String::new()),
            items: vec![
                Tac3dItem { name: POSITIONS.into(), value: Tac3dValue::Mat { rows: n, cols: 3, data: current } },
                Tac3dItem { name: DISPLACEMENTS.into(), value: Tac3dValue::Mat { rows: n, cols: 3, data: disp } },
            ],
        }
    }

    pub fn item(&self, name: &str) -> Option<&Tac3dValue> {
        self.items.iter().find(|i| i.name == name).map(|i| &i.value)
    }

    /// An `n x 3` matrix item as rows, checked finite.
    fn rows3(&self, name: &'static str) -> Result<Vec<[f64; 3]>, Tac3dError> {
        let Some(v) = self.item(name) else {
            return Err(Tac3dError::MissingField { field: name.to_string() });
        };
        let Tac3dValue::Mat { rows, cols, data } = v else {
            return Err(Tac3dError::BadField {
                field: name.to_string(),
                what: format!("is {}, expected mat", v.type_name()),
            });
        };
        if *cols != 3 || data.len() != rows * 3 {
            return Err(Tac3dError::Shape {
                item: name.to_string(),
                what: format!("{rows} x {cols} with {} values, expected n x 3", data.len()),
            });
        }
        if let Some(at) = data.iter().position(|x| !x.is_finite()) {
            return Err(Tac3dError::NotFinite { item: name.to_string(), at });
        }
        Ok(data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    }

    /// The rig's view of this frame: reference positions
    /// (`3D_Positions - 3D_Displacements`, since Tac3D sends current
    /// positions) and displacements (`n x 3`, same `n`, finite), and a finite
    /// timestamp.
    pub fn to_sensor_frame(&self) -> Result<SensorFrame, Tac3dError> {
        if !self.timestamp.is_finite() {
            return Err(Tac3dError::NotFinite { item: "timestamp".into(), at: 0 });
        }
        let current = self.rows3(POSITIONS)?;
        let displacements = self.rows3(DISPLACEMENTS)?;
        if current.len() != displacements.len() {
            return Err(Tac3dError::Shape {
                item: DISPLACEMENTS.into(),
                what: format!("{} rows but {POSITIONS} has {}", displacements.len(), current.len()),
            });
        }
        let mut positions = Vec::with_capacity(current.len());
        for (m, (c, d)) in current.iter().zip(&displacements).enumerate() {
            let r = [c[0] - d[0], c[1] - d[1], c[2] - d[2]];
            // Finite inputs can still overflow when subtracted.
            if !r.iter().all(|x| x.is_finite()) {
                return Err(Tac3dError::NotFinite { item: POSITIONS.into(), at: 3 * m });
            }
            positions.push(r);
        }
        Ok(SensorFrame { index: self.index, t_s: self.timestamp, positions, displacements })
    }
}

/// Malformed Tac3D input, naming what and where. Each maps to a [`BadReason`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Tac3dError {
    #[error("datagram of {len} bytes is shorter than the 8-byte header")]
    ShortDatagram { len: usize },
    #[error("frame serial {serial}: packet {index} beyond last packet {last}")]
    PacketIndex { serial: u32, index: u16, last: u16 },
    #[error("frame serial {serial}: packet says last packet {got}, earlier packets said {expected}")]
    PacketCount { serial: u32, expected: u16, got: u16 },
    #[error("frame serial {serial}: {last} packets per frame exceeds the limit {limit}")]
    TooManyPackets { serial: u32, last: u16, limit: u16 },
    #[error("frame serial {serial}: packet {index} received twice")]
    DuplicatePacket { serial: u32, index: u16 },
    #[error("frame serial {serial}: {bytes} bytes exceed the limit of {limit} per frame")]
    FrameTooLarge { serial: u32, bytes: usize, limit: usize },
    #[error("frame header is not ASCII (byte {at})")]
    NotAscii { at: usize },
    #[error("frame header YAML, {0}")]
    Yaml(#[from] YamlError),
    #[error("frame header lacks `{field}`")]
    MissingField { field: String },
    #[error("frame header field `{field}` {what}")]
    BadField { field: String, what: String },
    #[error("data item `{item}`: {what}")]
    Length { item: String, what: String },
    #[error("data item `{item}`: {what}")]
    Shape { item: String, what: String },
    #[error("data item `{item}`: value {at} is not finite")]
    NotFinite { item: String, at: usize },
    #[error("sensor still initialising ({progress}%)")]
    Initializing { progress: f64 },
}

impl Tac3dError {
    pub fn reason(&self) -> BadReason {
        match self {
            Tac3dError::ShortDatagram { .. } => BadReason::ShortDatagram,
            Tac3dError::PacketIndex { .. } | Tac3dError::PacketCount { .. } | Tac3dError::TooManyPackets { .. } => {
                BadReason::PacketIndex
            }
            Tac3dError::FrameTooLarge { .. } => BadReason::Length,
            Tac3dError::DuplicatePacket { .. } => BadReason::DuplicatePacket,
            Tac3dError::NotAscii { .. } | Tac3dError::Yaml(_) => BadReason::Yaml,
            Tac3dError::MissingField { .. } | Tac3dError::BadField { .. } => BadReason::MissingField,
            Tac3dError::Length { .. } | Tac3dError::Shape { .. } => BadReason::Length,
            Tac3dError::NotFinite { .. } => BadReason::NotFinite,
            Tac3dError::Initializing { .. } => BadReason::Initializing,
        }
    }
}

impl DeviceFault for Tac3dError {
    fn kind(&self) -> FaultKind {
        FaultKind::Protocol
    }
}

/// A frame that cannot be put on the wire.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Tac3dEncodeError {
    #[error("datagram limit {max_datagram} B cannot hold the {needed} B header packet")]
    DatagramTooSmall { max_datagram: usize, needed: usize },
    #[error("frame needs {packets} packets; the header allows 65536")]
    TooManyPackets { packets: usize },
    #[error("item `{item}`: {rows} x {cols} matrix with {len} values")]
    MatShape { item: String, rows: usize, cols: usize, len: usize },
    #[error("timestamp {0} is not finite")]
    Timestamp(f64),
}

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

#[derive(Debug)]
struct Partial {
    last: u16,
    parts: Vec<Option<Vec<u8>>>,
    got: usize,
    /// Payload bytes held.
    bytes: usize,
    /// When the latest packet of this frame arrived (the client's rule).
    touched: Instant,
}

/// Reassembles frames from datagrams that may arrive in any order and
/// interleaved across frames. Frames not complete `timeout` after their latest
/// packet are dropped; [`Tac3dReassembler::expire`] reports how many.
#[derive(Debug)]
pub struct Tac3dReassembler {
    partial: HashMap<u32, Partial>,
    timeout: Duration,
    max_packets: u16,
    max_pending: usize,
    /// Payload bytes held across all partial frames, and the budget for them.
    bytes: usize,
    max_bytes: usize,
    /// Partials pushed out to make room, not yet reported by `expire`.
    evicted: usize,
}

/// Largest frame accepted, bytes (a 20x20 frame of four matrices is ~39 kB).
pub const MAX_FRAME_BYTES: usize = 1 << 20;
/// Payload bytes held for incomplete frames at once (docs/hardening.md).
pub const MAX_BYTES_IN_FLIGHT: usize = 4 << 20;

impl Tac3dReassembler {
    /// `timeout` ~1 s as in the vendor's client.
    pub fn new(timeout: Duration) -> Self {
        Self {
            partial: HashMap::new(),
            timeout,
            // A 4-matrix frame is ~39 kB: even 64-byte datagrams stay far below this.
            max_packets: 4096,
            // Frames in flight at once; bounds memory against a flood of serials.
            max_pending: 32,
            bytes: 0,
            max_bytes: MAX_BYTES_IN_FLIGHT,
            evicted: 0,
        }
    }

    /// Frames waiting for packets.
    pub fn pending(&self) -> usize {
        self.partial.len()
    }

    /// Payload bytes held for frames waiting for packets.
    pub fn bytes_in_flight(&self) -> usize {
        self.bytes
    }

    fn drop_partial(&mut self, serial: u32) -> Option<Partial> {
        let p = self.partial.remove(&serial)?;
        self.bytes -= p.bytes;
        Some(p)
    }

    /// Push out the stalest partial (not `keep`); false when there is none.
    fn evict_stalest(&mut self, keep: u32) -> bool {
        let oldest = self.partial.iter().filter(|(k, _)| **k != keep).min_by_key(|(_, p)| p.touched).map(|(k, _)| *k);
        match oldest {
            Some(k) => {
                self.drop_partial(k);
                self.evicted += 1;
                true
            }
            None => false,
        }
    }

    /// Take one datagram. `Ok(Some(frame))` when it completed a frame.
    /// Errors name the bad datagram or frame; the frame they belong to (if any)
    /// is dropped. Call [`Self::expire`] regularly to drop stale partials.
    pub fn push(&mut self, datagram: &[u8], now: Instant) -> Result<Option<Tac3dFrame>, Tac3dError> {
        let h = parse_packet_header(datagram)?;
        if h.last >= self.max_packets {
            return Err(Tac3dError::TooManyPackets { serial: h.serial, last: h.last, limit: self.max_packets });
        }
        if h.this > h.last {
            return Err(Tac3dError::PacketIndex { serial: h.serial, index: h.this, last: h.last });
        }
        if !self.partial.contains_key(&h.serial) && self.partial.len() >= self.max_pending {
            // Make room by dropping the stalest partial; expire() would drop it soon anyway.
            self.evict_stalest(h.serial);
        }
        let payload = datagram.len() - HEADER_LEN;
        let held = self.partial.get(&h.serial).map_or(0, |p| p.bytes);
        if held + payload > MAX_FRAME_BYTES {
            self.drop_partial(h.serial);
            return Err(Tac3dError::FrameTooLarge { serial: h.serial, bytes: held + payload, limit: MAX_FRAME_BYTES });
        }
        // Memory in flight stays within the budget: the stalest other frames go first.
        while self.bytes + payload > self.max_bytes && self.evict_stalest(h.serial) {}
        let p = self.partial.entry(h.serial).or_insert_with(|| Partial {
            last: h.last,
            parts: vec![None; usize::from(h.last) + 1],
            got: 0,
            bytes: 0,
            touched: now,
        });
        if p.last != h.last {
            let expected = p.last;
            self.drop_partial(h.serial);
            return Err(Tac3dError::PacketCount { serial: h.serial, expected, got: h.last });
        }
        let slot = &mut p.parts[usize::from(h.this)];
        if slot.is_some() {
            return Err(Tac3dError::DuplicatePacket { serial: h.serial, index: h.this });
        }
        *slot = Some(datagram[HEADER_LEN..].to_vec());
        p.got += 1;
        p.bytes += payload;
        p.touched = now;
        self.bytes += payload;
        if p.got < p.parts.len() {
            return Ok(None);
        }
        let Some(p) = self.drop_partial(h.serial) else {
            return Ok(None);
        };
        let mut parts = p.parts.into_iter().flatten();
        let head = parts.next().unwrap_or_default();
        let rest: Vec<Vec<u8>> = parts.collect();
        let blob = rest.concat();
        decode_frame(&head, &blob).map(Some)
    }

    /// Drop partial frames whose latest packet is older than the timeout;
    /// returns how many incomplete frames were dropped since the last call
    /// (including those pushed out because too many were in flight).
    pub fn expire(&mut self, now: Instant) -> usize {
        let before = self.partial.len();
        let timeout = self.timeout;
        self.partial.retain(|_, p| now.saturating_duration_since(p.touched) <= timeout);
        self.bytes = self.partial.values().map(|p| p.bytes).sum();
        before - self.partial.len() + std::mem::take(&mut self.evicted)
    }
}

/// Where and how a [`Tac3dReceiver`] listens.
#[derive(Debug, Clone)]
pub struct Tac3dReceiverConfig {
    /// Local address; the main program's configured destination must point here.
    pub bind: SocketAddr,
    /// Drop frames whose packets stop arriving for this long.
    pub reassembly_timeout: Duration,
    /// Decoded frames held for the consumer; the oldest is dropped beyond this.
    pub queue_capacity: usize,
    /// Only accept frames from this sensor serial number (`None`: any sensor).
    pub serial_filter: Option<String>,
    /// Only accept datagrams from this address (`None`: any sender). Others are
    /// counted as bad (`foreign`) and never decoded.
    pub source: Option<std::net::IpAddr>,
}

impl Default for Tac3dReceiverConfig {
    fn default() -> Self {
        Self {
            // Loopback unless told otherwise (docs/hardening.md): the main program
            // usually runs on the same computer.
            bind: SocketAddr::from(([127, 0, 0, 1], DEFAULT_PORT)),
            reassembly_timeout: Duration::from_secs(1),
            queue_capacity: 8,
            serial_filter: None,
            source: None,
        }
    }
}

/// What the receive task learned about the sender.
#[derive(Debug, Default)]
struct Peer {
    addr: Option<SocketAddr>,
    sn: Option<String>,
}

/// A [`SensorLink`] that receives the Tac3D main program's UDP stream.
/// `start`/`stop` only gate delivery (the main program streams regardless);
/// `tare` sends `$C` to the address the latest frame came from.
#[derive(Debug)]
pub struct Tac3dReceiver {
    socket: Arc<UdpSocket>,
    inbox: Arc<Inbox>,
    peer: Arc<Mutex<Peer>>,
    task: JoinHandle<()>,
}

impl Drop for Tac3dReceiver {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl Tac3dReceiver {
    /// Bind the socket and start decoding in the background.
    pub async fn bind(cfg: Tac3dReceiverConfig) -> Result<Self, SensorError> {
        let socket = Arc::new(UdpSocket::bind(cfg.bind).await.map_err(io_err("bind UDP socket"))?);
        let inbox = Arc::new(Inbox::new(cfg.queue_capacity));
        let peer = Arc::new(Mutex::new(Peer::default()));
        let task = tokio::spawn(receive_loop(socket.clone(), inbox.clone(), peer.clone(), cfg));
        Ok(Self { socket, inbox, peer, task })
    }

    pub fn local_addr(&self) -> Result<SocketAddr, SensorError> {
        self.socket.local_addr().map_err(io_err("local address"))
    }

    /// Serial number of the sensor whose frame arrived last.
    pub fn sensor_serial(&self) -> Option<String> {
        self.peer.lock().unwrap_or_else(|p| p.into_inner()).sn.clone()
    }

    fn peer_addr(&self, command: &'static str) -> Result<SocketAddr, SensorError> {
        self.peer.lock().unwrap_or_else(|p| p.into_inner()).addr.ok_or(SensorError::NoPeer { command })
    }

    /// Send `$Q`: the main program stops the sensor (it needs a restart there).
    pub async fn quit_sensor(&mut self) -> Result<(), SensorError> {
        let to = self.peer_addr("$Q")?;
        self.socket.send_to(CMD_QUIT, to).await.map_err(io_err("send $Q"))?;
        Ok(())
    }
}

async fn receive_loop(socket: Arc<UdpSocket>, inbox: Arc<Inbox>, peer: Arc<Mutex<Peer>>, cfg: Tac3dReceiverConfig) {
    let mut re = Tac3dReassembler::new(cfg.reassembly_timeout);
    // Largest UDP payload: any datagram fits, so none is silently truncated.
    let mut buf = vec![0u8; 65536];
    let tick = (cfg.reassembly_timeout / 4).max(Duration::from_millis(1));
    loop {
        let got = tokio::time::timeout(tick, socket.recv_from(&mut buf)).await;
        let now = Instant::now();
        for _ in 0..re.expire(now) {
            inbox.bad(BadReason::Incomplete);
        }
        let (n, from) = match got {
            Err(_elapsed) => continue,
            Ok(Ok(x)) => x,
            Ok(Err(e)) => {
                // ICMP "port unreachable" after our own `$C` to a vanished sender
                // shows up here on Linux; it does not end the link.
                if e.kind() == std::io::ErrorKind::ConnectionRefused {
                    continue;
                }
                inbox.close(format!("UDP receive failed: {e}"));
                return;
            }
        };
        if let Some(want) = cfg.source
            && from.ip() != want
        {
            inbox.bad(BadReason::Foreign);
            continue;
        }
        let frame = match re.push(&buf[..n], now) {
            Ok(None) => continue,
            Ok(Some(f)) => f,
            Err(e) => {
                inbox.bad(e.reason());
                continue;
            }
        };
        if let Some(want) = &cfg.serial_filter
            && *want != frame.sn
        {
            continue;
        }
        match frame.to_sensor_frame() {
            Ok(sf) => {
                {
                    let mut p = peer.lock().unwrap_or_else(|p| p.into_inner());
                    p.addr = Some(from);
                    p.sn = Some(frame.sn);
                }
                inbox.frame(sf);
            }
            Err(e) => inbox.bad(e.reason()),
        }
    }
}

#[async_trait]
impl SensorLink for Tac3dReceiver {
    async fn start(&mut self) -> Result<(), SensorError> {
        self.inbox.set_streaming(true);
        Ok(())
    }

    async fn stop(&mut self) -> Result<(), SensorError> {
        self.inbox.set_streaming(false);
        Ok(())
    }

    async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError> {
        self.inbox.next(timeout).await
    }

    /// Sends `$C`. The main program does not acknowledge it; frames after the
    /// re-zero read zero displacement while the sensor stays untouched.
    async fn tare(&mut self) -> Result<(), SensorError> {
        let to = self.peer_addr("$C")?;
        self.socket.send_to(CMD_CALIBRATE, to).await.map_err(io_err("send $C"))?;
        Ok(())
    }

    fn stats(&self) -> LinkStats {
        self.inbox.stats()
    }
}

/// Largest UDP payload that fits one Ethernet frame without IP fragmentation
/// (1500 MTU - 20 IP - 8 UDP). The vendor's packet size is not documented
/// (hardware.md C.1 [U]); any size up to 65 507 B reads back through PyTac3D,
/// which receives with a 65 535-byte buffer. Smaller packets also exercise the
/// reassembly path on loopback.
pub const DEFAULT_MAX_DATAGRAM: usize = 1472;
/// Sensor serial the emulated sensor reports by default (a Tac3D-style SN).
pub const DEFAULT_SN: &str = "EC1-0000SIM";

/// A command a Tac3D client sent back to the main program.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tac3dCommand {
    /// `$C`: re-zero the displacement field (the sensor must be untouched).
    Calibrate,
    /// `$Q`: stop the sensor.
    Quit,
}

impl Tac3dCommand {
    /// Parse a client datagram; `None` for anything that is not `$C` / `$Q`.
    pub fn parse(datagram: &[u8]) -> Option<Self> {
        match datagram {
            CMD_CALIBRATE => Some(Tac3dCommand::Calibrate),
            CMD_QUIT => Some(Tac3dCommand::Quit),
            _ => None,
        }
    }
}

/// How a [`Tac3dSender`] frames its stream.
#[derive(Debug, Clone)]
pub struct Tac3dSenderConfig {
    /// Sensor serial in every frame header (`SN`).
    pub sn: String,
    /// Largest datagram, 8-byte header included.
    pub max_datagram: usize,
}

impl Default for Tac3dSenderConfig {
    fn default() -> Self {
        Self { sn: DEFAULT_SN.to_string(), max_datagram: DEFAULT_MAX_DATAGRAM }
    }
}

/// The Tac3D main program's side of the link, for emulators: sends frames as
/// the main program does (8-byte header, YAML packet 0, f64 blob packets) to a
/// fixed client address, and hears the `$C` / `$Q` commands the client sends
/// back to the address frames came from (this socket).
#[derive(Debug)]
pub struct Tac3dSender {
    socket: UdpSocket,
    to: SocketAddr,
    cfg: Tac3dSenderConfig,
    /// Datagrams from the client that were not `$C` / `$Q`.
    unknown_commands: u64,
}

impl Tac3dSender {
    /// Bind `bind` (port 0 for any) and send to `to` (the client's port, 9988
    /// for PyTac3D's default).
    pub async fn bind(bind: SocketAddr, to: SocketAddr, cfg: Tac3dSenderConfig) -> Result<Self, SensorError> {
        let socket = UdpSocket::bind(bind).await.map_err(io_err("bind UDP socket"))?;
        Ok(Self { socket, to, cfg, unknown_commands: 0 })
    }

    pub fn local_addr(&self) -> Result<SocketAddr, SensorError> {
        self.socket.local_addr().map_err(io_err("local address"))
    }

    /// Where frames go.
    pub fn destination(&self) -> SocketAddr {
        self.to
    }

    /// Send one rig frame as `3D_Positions` and `3D_Displacements` (`n x 3`).
    pub async fn send(&mut self, frame: &SensorFrame) -> Result<(), SensorError> {
        self.send_tac3d(&Tac3dFrame::from_sensor_frame(frame, &self.cfg.sn)).await
    }

    /// Send a full Tac3D frame (any items, e.g. forces and normals too).
    pub async fn send_tac3d(&mut self, frame: &Tac3dFrame) -> Result<(), SensorError> {
        let packets = encode_frame(frame, self.cfg.max_datagram).map_err(|e| SensorError::Io {
            what: "encode Tac3D frame",
            source: std::io::Error::new(std::io::ErrorKind::InvalidInput, e),
        })?;
        for p in &packets {
            match self.socket.send_to(p, self.to).await {
                Ok(_) => {}
                // Nobody listening yet (ICMP port unreachable from an earlier
                // datagram): the main program keeps streaming regardless.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {}
                Err(e) => return Err(io_err("send Tac3D datagram")(e)),
            }
        }
        Ok(())
    }

    /// A command the client sent, if one is waiting (never blocks).
    pub fn try_command(&mut self) -> Result<Option<Tac3dCommand>, SensorError> {
        let mut buf = [0u8; 64];
        loop {
            match self.socket.try_recv_from(&mut buf) {
                Ok((n, _from)) => match Tac3dCommand::parse(&buf[..n]) {
                    Some(c) => return Ok(Some(c)),
                    None => self.unknown_commands += 1,
                },
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(None),
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => continue,
                Err(e) => return Err(io_err("receive client command")(e)),
            }
        }
    }

    /// Wait for the client's next command.
    pub async fn recv_command(&mut self) -> Result<Tac3dCommand, SensorError> {
        let mut buf = [0u8; 64];
        loop {
            match self.socket.recv_from(&mut buf).await {
                Ok((n, _from)) => match Tac3dCommand::parse(&buf[..n]) {
                    Some(c) => return Ok(c),
                    None => self.unknown_commands += 1,
                },
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => continue,
                Err(e) => return Err(io_err("receive client command")(e)),
            }
        }
    }

    /// Datagrams from the client that were neither `$C` nor `$Q`.
    pub fn unknown_commands(&self) -> u64 {
        self.unknown_commands
    }
}

#[cfg(test)]
mod bound_tests {
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
        let deep_flow =
            format!("index: 1\nSN: x\ntimestamp: 0.5\ndata: {}{}\n", "[".repeat(12_000), "]".repeat(12_000));
        let e = decode_frame(deep_flow.as_bytes(), &[]).unwrap_err();
        assert!(e.to_string().contains("nesting"), "{e}");
        let deep_block: String = (0..200).map(|i| format!("{}k{i}:\n", " ".repeat(i))).collect();
        let e = decode_frame(deep_block.as_bytes(), &[]).unwrap_err();
        assert!(e.to_string().contains("nesting"), "{e}");
    }
}
