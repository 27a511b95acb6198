//! Tac3D's UDP frame format (docs/hardware.md C.1), as the vendor's main program
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
//! [`Tac3dReceiver`] is the I/O edge on a tokio UDP socket. The main
//! program's side (the sender) is emulated in the `sim` crate
//! (`sim::emulator::tac3d`).

use super::frame::SensorFrame;
use super::stats::BadReason;
use crate::motion::{DeviceFault, FaultKind};

mod codec;
mod header;
mod reassembly;
mod receiver;
mod yaml;

pub use codec::{PacketHeader, decode_frame, encode_frame, encode_parts, parse_packet_header};
pub use reassembly::{MAX_BYTES_IN_FLIGHT, MAX_FRAME_BYTES, Tac3dReassembler};
pub use receiver::{Tac3dReceiver, Tac3dReceiverConfig};
pub use yaml::{YamlError, YamlErrorKind};

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

/// Largest UDP payload that fits one Ethernet frame without IP fragmentation
/// (1500 MTU - 20 IP - 8 UDP). The vendor's packet size is not documented
/// (docs/hardware.md C.1 [U]); any size up to 65 507 B reads back through PyTac3D,
/// which receives with a 65 535-byte buffer. Smaller packets also exercise the
/// reassembly path on loopback.
pub const DEFAULT_MAX_DATAGRAM: usize = 1472;

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

#[cfg(test)]
mod tests;
