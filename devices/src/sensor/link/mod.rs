//! easycalib's own sensor link protocol (docs/sensor-link.md) for
//! microcontrollers and bridge programs that turn any camera-based tactile
//! sensor into a stream of marker frames. Small binary framing:
//!
//! ```text
//! offset  size  field
//!  0      2     sync 0xEC 0xCA
//!  2      1     version (1)
//!  3      1     kind
//!  4      4     payload length N, u32 little-endian
//!  8      4     header CRC-32 over bytes 0..8, little-endian
//! 12      N     payload
//! 12+N    4     payload CRC-32 over bytes 12..12+N, little-endian
//! ```
//!
//! The header has its own CRC so a corrupted length is caught at once and the
//! decoder resynchronises without waiting for bytes that will never come.
//! Everything is little-endian; floats are IEEE 754.
//!
//! The codec is pure ([`encode`], [`decode_datagram`], [`LinkDecoder`]);
//! [`LinkReceiver`] is the host side over a byte stream (serial port, pty) or
//! a UDP socket. The device side (what a bridge program runs) is emulated in
//! the `sim` crate (`sim::emulator::sensor_link`).

use super::frame::SensorFrame;
use super::stats::BadReason;
use crate::motion::{DeviceFault, FaultKind};

mod codec;
mod decoder;
mod receiver;

pub use codec::{decode_datagram, encode, encode_frame, encode_raw, encode_raw_version};
pub use decoder::{GARBAGE_REPORT, LinkDecoder};
pub use receiver::{LinkConfig, LinkReceiver};

pub const SYNC: [u8; 2] = [0xEC, 0xCA];
pub const VERSION: u8 = 1;
pub const HEADER_LEN: usize = 12;
pub const CRC_LEN: usize = 4;
/// Bytes of a frame payload before the marker arrays.
pub const FRAME_FIXED: usize = 8 + 8 + 4;
/// Bytes per marker in a frame payload: 3 + 3 f32.
pub const FRAME_PER_MARKER: usize = 24;
/// Largest marker count a frame may carry (a 128 x 128 grid).
pub const MAX_MARKERS: usize = 16384;
/// Largest payload any message may carry.
pub const MAX_PAYLOAD: usize = FRAME_FIXED + FRAME_PER_MARKER * MAX_MARKERS;

/// Message kinds (byte 3).
pub mod kind {
    /// Device -> host: one sensor frame.
    pub const FRAME: u8 = 0x01;
    /// Host -> device: begin streaming frames.
    pub const START: u8 = 0x10;
    /// Host -> device: stop streaming frames.
    pub const STOP: u8 = 0x11;
    /// Host -> device: take the current deformation as the new zero.
    pub const TARE: u8 = 0x12;
    /// Device -> host: command carried out; payload = the command's kind byte.
    pub const ACK: u8 = 0x20;
}

/// CRC-32/ISO-HDLC (the zlib / Ethernet CRC): reflected polynomial
/// 0xEDB88320, init 0xFFFFFFFF, final xor 0xFFFFFFFF; check("123456789") = 0xCBF43926.
/// Computed by `crc32fast`, which uses the CPU's carry-less multiply where it has one.
pub fn crc32(data: &[u8]) -> u32 {
    crc32fast::hash(data)
}

/// A host -> device command (acknowledged by the device with [`kind::ACK`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkCommand {
    Start,
    Stop,
    Tare,
}

impl LinkCommand {
    pub fn kind(self) -> u8 {
        match self {
            LinkCommand::Start => kind::START,
            LinkCommand::Stop => kind::STOP,
            LinkCommand::Tare => kind::TARE,
        }
    }

    pub fn from_kind(k: u8) -> Option<Self> {
        match k {
            kind::START => Some(LinkCommand::Start),
            kind::STOP => Some(LinkCommand::Stop),
            kind::TARE => Some(LinkCommand::Tare),
            _ => None,
        }
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            LinkCommand::Start => "START",
            LinkCommand::Stop => "STOP",
            LinkCommand::Tare => "TARE",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum LinkMessage {
    /// A frame; positions and displacements travel as f32.
    Frame(SensorFrame),
    Command(LinkCommand),
    Ack(LinkCommand),
}

/// Malformed link input, naming what and where (`at` = offset of the message
/// start in the stream, or 0 in a datagram).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinkError {
    #[error("skipped {skipped} bytes without a sync pattern at stream offset {at}")]
    Garbage { at: u64, skipped: usize },
    #[error("header checksum at offset {at}: computed {computed:#010x}, received {received:#010x}")]
    HeaderChecksum { at: u64, computed: u32, received: u32 },
    #[error("payload checksum at offset {at}: computed {computed:#010x}, received {received:#010x}")]
    Checksum { at: u64, computed: u32, received: u32 },
    #[error("message at offset {at} has version {version}; this decoder speaks {VERSION}")]
    Version { at: u64, version: u8 },
    #[error("message at offset {at} claims {len} payload bytes, over the limit {MAX_PAYLOAD}")]
    TooLong { at: u64, len: usize },
    #[error("message at offset {at} has unknown kind {kind:#04x}")]
    UnknownKind { at: u64, kind: u8 },
    #[error("message at offset {at}, kind {kind:#04x}: payload of {got} bytes, expected {expected}")]
    Length { at: u64, kind: u8, expected: usize, got: usize },
    #[error("datagram of {len} bytes holds no complete message ({what})")]
    Datagram { len: usize, what: &'static str },
    #[error("frame at offset {at}: {field} of marker {marker} is not finite")]
    NotFinite { at: u64, field: &'static str, marker: usize },
}

impl LinkError {
    pub fn reason(&self) -> BadReason {
        match self {
            LinkError::Garbage { .. } => BadReason::Garbage,
            LinkError::HeaderChecksum { .. } => BadReason::HeaderChecksum,
            LinkError::Checksum { .. } => BadReason::Checksum,
            LinkError::Version { .. } => BadReason::Version,
            LinkError::UnknownKind { .. } => BadReason::UnknownKind,
            LinkError::TooLong { .. } | LinkError::Length { .. } | LinkError::Datagram { .. } => BadReason::Length,
            LinkError::NotFinite { .. } => BadReason::NotFinite,
        }
    }
}

impl DeviceFault for LinkError {
    fn kind(&self) -> FaultKind {
        FaultKind::Protocol
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LinkEncodeError {
    #[error("frame has {positions} positions but {displacements} displacements")]
    MarkerMismatch { positions: usize, displacements: usize },
    #[error("frame has {0} markers; the protocol carries at most {MAX_MARKERS}")]
    TooManyMarkers(usize),
    #[error("{field} of marker {marker} is not finite as f32")]
    NotFinite { field: &'static str, marker: usize },
    #[error("payload of {0} bytes is over the limit {MAX_PAYLOAD}")]
    TooLong(usize),
}

#[cfg(test)]
mod tests;
