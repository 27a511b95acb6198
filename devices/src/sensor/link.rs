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
//! a UDP socket.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use async_trait::async_trait;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadHalf, WriteHalf};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::SensorLink;
use super::error::{SensorError, io_err};
use super::frame::SensorFrame;
use super::inbox::Inbox;
use super::stats::{BadReason, LinkStats};
use crate::motion::{DeviceFault, FaultKind};

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

#[cfg(test)]
mod crc_tests {
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
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    Start,
    Stop,
    Tare,
}

impl Command {
    pub fn kind(self) -> u8 {
        match self {
            Command::Start => kind::START,
            Command::Stop => kind::STOP,
            Command::Tare => kind::TARE,
        }
    }

    pub fn from_kind(k: u8) -> Option<Self> {
        match k {
            kind::START => Some(Command::Start),
            kind::STOP => Some(Command::Stop),
            kind::TARE => Some(Command::Tare),
            _ => None,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Command::Start => "START",
            Command::Stop => "STOP",
            Command::Tare => "TARE",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum LinkMessage {
    /// A frame; positions and displacements travel as f32.
    Frame(SensorFrame),
    Command(Command),
    Ack(Command),
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

/// Encode one message into its bytes on the wire.
pub fn encode(msg: &LinkMessage) -> Result<Vec<u8>, LinkEncodeError> {
    match msg {
        LinkMessage::Frame(f) => encode_raw(kind::FRAME, &frame_payload(f)?),
        LinkMessage::Command(c) => encode_raw(c.kind(), &[]),
        LinkMessage::Ack(c) => encode_raw(kind::ACK, &[c.kind()]),
    }
}

fn u32_at(b: &[u8], i: usize) -> u32 {
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
fn parse_payload(at: u64, k: u8, p: &[u8]) -> Result<LinkMessage, LinkError> {
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
            Ok(LinkMessage::Command(Command::from_kind(k).ok_or(LinkError::UnknownKind { at, kind: k })?))
        }
        kind::ACK => {
            if p.len() != 1 {
                return Err(len_err(1));
            }
            Command::from_kind(p[0]).map(LinkMessage::Ack).ok_or(LinkError::UnknownKind { at, kind: p[0] })
        }
        other => Err(LinkError::UnknownKind { at, kind: other }),
    }
}

/// What the fixed header says, after its checksum passed.
struct Header {
    version: u8,
    kind: u8,
    len: usize,
}

fn parse_header(at: u64, h: &[u8]) -> Result<Header, LinkError> {
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

/// Longest run of garbage reported as one [`LinkError::Garbage`]: a sender on
/// the wrong baud rate shows up in the stats without waiting for a sync.
pub const GARBAGE_REPORT: u64 = 1024;

/// Streaming decoder: feed bytes as they arrive with [`push`](Self::push),
/// take messages and errors with [`next_message`](Self::next_message) until it
/// says `None`. Resynchronises on the sync pattern after any error.
///
/// What it reports does not depend on how the bytes were chunked: a run of
/// garbage is one error (split every [`GARBAGE_REPORT`] bytes), reported when
/// the next message starts, and the bytes of a message already reported as
/// bad are not counted again as garbage.
#[derive(Debug, Default)]
pub struct LinkDecoder {
    buf: Vec<u8>,
    /// Start of undecoded bytes in `buf`.
    start: usize,
    /// Stream offset of `buf[0]`.
    base: u64,
    /// Stream offset before which skipped bytes are not reported as garbage:
    /// the rest of a message whose payload checksum failed.
    quiet_until: u64,
    /// After a bad header the message's end is unknown: skipped bytes stay
    /// quiet until the next sound header.
    quiet_run: bool,
    /// Garbage skipped and not reported yet: (stream offset, bytes).
    run: Option<(u64, u64)>,
}

impl LinkDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, bytes: &[u8]) {
        // Compact lazily so decoding a large frame is not quadratic.
        if self.start > 0 && self.start >= self.buf.len() / 2 {
            self.buf.drain(..self.start);
            self.base += self.start as u64;
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes held but not yet decoded.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.start
    }

    /// Step over `n` bytes, adding the loud ones to the garbage run.
    fn skip(&mut self, n: usize) {
        let at = self.base + self.start as u64;
        self.start += n;
        let end = self.base + self.start as u64;
        let from = self.quiet_until.max(at);
        if self.quiet_run || end <= from {
            return;
        }
        match &mut self.run {
            Some((_, len)) => *len += end - from,
            None => self.run = Some((from, end - from)),
        }
    }

    fn take_run(&mut self) -> Option<LinkError> {
        self.run.take().map(|(at, len)| LinkError::Garbage { at, skipped: len as usize })
    }

    pub fn next_message(&mut self) -> Option<Result<LinkMessage, LinkError>> {
        loop {
            let avail = &self.buf[self.start..];
            match avail.windows(2).position(|w| w == SYNC) {
                Some(0) => {}
                Some(k) => {
                    self.skip(k);
                    continue;
                }
                None => {
                    // Keep a trailing first sync byte: its partner may come next.
                    let keep = usize::from(avail.last() == Some(&SYNC[0]));
                    let mut n = avail.len() - keep;
                    if n == 0 {
                        return None;
                    }
                    // Cut the run at exactly GARBAGE_REPORT bytes, however the
                    // bytes were chunked.
                    if let Some((_, len)) = self.run {
                        n = n.min((GARBAGE_REPORT - len.min(GARBAGE_REPORT)).max(1) as usize);
                    } else if !self.quiet_run {
                        n = n.min(GARBAGE_REPORT as usize);
                    }
                    self.skip(n);
                    if matches!(self.run, Some((_, len)) if len >= GARBAGE_REPORT) {
                        return self.take_run().map(Err);
                    }
                    continue;
                }
            }
            // A message starts here: report the garbage before it first.
            if let Some(e) = self.take_run() {
                return Some(Err(e));
            }
            let avail = &self.buf[self.start..];
            if avail.len() < HEADER_LEN {
                return None;
            }
            let at = self.base + self.start as u64;
            let h = match parse_header(at, &avail[..HEADER_LEN]) {
                Ok(h) => h,
                Err(e) => {
                    // Not a real header (sync bytes inside data, or corruption):
                    // step past this sync and look again.
                    self.start += 1;
                    if at < self.quiet_until || self.quiet_run {
                        continue;
                    }
                    self.quiet_run = true;
                    return Some(Err(e));
                }
            };
            self.quiet_run = false;
            if h.len > MAX_PAYLOAD {
                self.start += SYNC.len();
                self.quiet_run = true;
                return Some(Err(LinkError::TooLong { at, len: h.len }));
            }
            let total = HEADER_LEN + h.len + CRC_LEN;
            if avail.len() < total {
                return None;
            }
            let payload = &avail[HEADER_LEN..HEADER_LEN + h.len];
            let computed = crc32(payload);
            let received = u32_at(avail, HEADER_LEN + h.len);
            if computed != received {
                // The header is sound, so the message really was this long, but
                // bytes may have been lost inside it and a next message may start
                // there: skip only the header and rescan the rest quietly.
                self.quiet_until = at + total as u64;
                self.start += HEADER_LEN;
                return Some(Err(LinkError::Checksum { at, computed, received }));
            }
            let result = if h.version != VERSION {
                Err(LinkError::Version { at, version: h.version })
            } else {
                parse_payload(at, h.kind, payload)
            };
            self.start += total;
            return Some(result);
        }
    }
}

/// Host-side settings of a [`LinkReceiver`].
#[derive(Debug, Clone)]
pub struct LinkConfig {
    /// Decoded frames held for the consumer; the oldest is dropped beyond this.
    pub queue_capacity: usize,
    /// Wait this long (real time) for each acknowledgement.
    pub ack_timeout: Duration,
    /// Times a command is sent before giving up (UDP may lose one).
    pub attempts: u32,
}

impl Default for LinkConfig {
    fn default() -> Self {
        Self { queue_capacity: 8, ack_timeout: Duration::from_millis(500), attempts: 3 }
    }
}

enum Writer {
    Stream(Box<dyn AsyncWrite + Unpin + Send>),
    Udp(Arc<UdpSocket>, SocketAddr),
}

impl std::fmt::Debug for Writer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Writer::Stream(_) => f.write_str("Writer::Stream"),
            Writer::Udp(_, to) => write!(f, "Writer::Udp({to})"),
        }
    }
}

/// Host side of the link protocol, as a [`SensorLink`].
#[derive(Debug)]
pub struct LinkReceiver {
    writer: Writer,
    inbox: Arc<Inbox>,
    acks: mpsc::Receiver<Command>,
    cfg: LinkConfig,
    task: JoinHandle<()>,
}

impl Drop for LinkReceiver {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn dispatch(msg: Result<LinkMessage, LinkError>, inbox: &Inbox, acks: &mpsc::Sender<Command>) {
    match msg {
        Ok(LinkMessage::Frame(f)) => inbox.frame(f),
        Ok(LinkMessage::Ack(c)) => {
            // A full channel means nobody is waiting for these acks.
            let _ = acks.try_send(c);
        }
        // Commands flow host -> device only; one coming back is a wrong-way message.
        Ok(LinkMessage::Command(c)) => {
            let _ = c;
            inbox.bad(BadReason::UnknownKind)
        }
        Err(e) => inbox.bad(e.reason()),
    }
}

async fn stream_loop<R: AsyncRead + Unpin>(mut rd: R, inbox: Arc<Inbox>, acks: mpsc::Sender<Command>) {
    let mut dec = LinkDecoder::new();
    let mut buf = vec![0u8; 16384];
    loop {
        let n = match rd.read(&mut buf).await {
            Ok(0) => {
                inbox.close("end of stream".into());
                return;
            }
            Ok(n) => n,
            Err(e) => {
                inbox.close(format!("read failed: {e}"));
                return;
            }
        };
        dec.push(&buf[..n]);
        while let Some(m) = dec.next_message() {
            dispatch(m, &inbox, &acks);
        }
    }
}

async fn udp_loop(socket: Arc<UdpSocket>, device: SocketAddr, inbox: Arc<Inbox>, acks: mpsc::Sender<Command>) {
    let mut buf = vec![0u8; 65536];
    loop {
        match socket.recv_from(&mut buf).await {
            Ok((n, from)) if from == device => dispatch(decode_datagram(&buf[..n]), &inbox, &acks),
            // Datagrams from anyone else are not this sensor's business.
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {}
            Err(e) => {
                inbox.close(format!("UDP receive failed: {e}"));
                return;
            }
        }
    }
}

impl LinkReceiver {
    /// Over a byte stream: a serial port, a pty, a socket, a duplex pipe.
    pub fn new<T>(io: T, cfg: LinkConfig) -> Self
    where
        T: AsyncRead + AsyncWrite + Send + 'static,
    {
        let (rd, wr): (ReadHalf<T>, WriteHalf<T>) = tokio::io::split(io);
        let inbox = Arc::new(Inbox::new(cfg.queue_capacity));
        let (tx, acks) = mpsc::channel(16);
        let task = tokio::spawn(stream_loop(rd, inbox.clone(), tx));
        Self { writer: Writer::Stream(Box::new(wr)), inbox, acks, cfg, task }
    }

    /// Open a serial device (or a pty's slave path) at `baud`.
    pub fn open_serial(path: &str, baud: u32, cfg: LinkConfig) -> Result<Self, SensorError> {
        use tokio_serial::SerialPortBuilderExt;
        let port = tokio_serial::new(path, baud)
            .open_native_async()
            .map_err(|e| SensorError::Io { what: "open serial port", source: e.into() })?;
        Ok(Self::new(port, cfg))
    }

    /// Over UDP: commands go to `device`, and only datagrams from `device`
    /// are read.
    pub async fn udp(bind: SocketAddr, device: SocketAddr, cfg: LinkConfig) -> Result<Self, SensorError> {
        let socket = Arc::new(UdpSocket::bind(bind).await.map_err(io_err("bind UDP socket"))?);
        let inbox = Arc::new(Inbox::new(cfg.queue_capacity));
        let (tx, acks) = mpsc::channel(16);
        let task = tokio::spawn(udp_loop(socket.clone(), device, inbox.clone(), tx));
        Ok(Self { writer: Writer::Udp(socket, device), inbox, acks, cfg, task })
    }

    async fn send(&mut self, cmd: Command) -> Result<(), SensorError> {
        let bytes = encode_raw(cmd.kind(), &[])
            .map_err(|e| SensorError::Io { what: "encode command", source: std::io::Error::other(e) })?;
        match &mut self.writer {
            Writer::Stream(w) => {
                w.write_all(&bytes).await.map_err(io_err("write command"))?;
                w.flush().await.map_err(io_err("flush command"))?;
            }
            Writer::Udp(s, to) => {
                s.send_to(&bytes, *to).await.map_err(io_err("send command"))?;
            }
        }
        Ok(())
    }

    /// Send a command and wait for its acknowledgement, resending on silence.
    pub async fn command(&mut self, cmd: Command) -> Result<(), SensorError> {
        // Acks left over from an earlier, timed-out exchange are not for this one.
        while self.acks.try_recv().is_ok() {}
        let attempts = self.cfg.attempts.max(1);
        for _ in 0..attempts {
            self.send(cmd).await?;
            let deadline = tokio::time::Instant::now() + self.cfg.ack_timeout;
            loop {
                match tokio::time::timeout_at(deadline, self.acks.recv()).await {
                    Ok(Some(c)) if c == cmd => return Ok(()),
                    Ok(Some(_other)) => continue,
                    Ok(None) => {
                        return Err(SensorError::Closed { reason: "receive task ended".into() });
                    }
                    Err(_) => break,
                }
            }
        }
        Err(SensorError::NoAck { command: cmd.name(), waited: self.cfg.ack_timeout * attempts })
    }
}

#[async_trait]
impl SensorLink for LinkReceiver {
    async fn start(&mut self) -> Result<(), SensorError> {
        // Open the gate first: the device may stream before its ack arrives.
        self.inbox.set_streaming(true);
        let r = self.command(Command::Start).await;
        if r.is_err() {
            self.inbox.set_streaming(false);
        }
        r
    }

    async fn stop(&mut self) -> Result<(), SensorError> {
        let r = self.command(Command::Stop).await;
        self.inbox.set_streaming(false);
        r
    }

    async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError> {
        self.inbox.next(timeout).await
    }

    async fn tare(&mut self) -> Result<(), SensorError> {
        self.command(Command::Tare).await
    }

    fn stats(&self) -> LinkStats {
        self.inbox.stats()
    }
}

enum DeviceIo {
    Stream {
        rd: Box<dyn AsyncRead + Unpin + Send>,
        wr: Box<dyn AsyncWrite + Unpin + Send>,
    },
    Udp {
        socket: UdpSocket,
        /// The host: fixed at construction or learnt from its first command.
        host: Option<SocketAddr>,
    },
}

impl std::fmt::Debug for DeviceIo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceIo::Stream { .. } => f.write_str("DeviceIo::Stream"),
            DeviceIo::Udp { host, .. } => write!(f, "DeviceIo::Udp({host:?})"),
        }
    }
}

/// The device side of the link protocol: what a bridge program, a
/// microcontroller or an emulator runs. It sends frames and acknowledgements
/// and reads the host's commands; malformed input is counted, never fatal.
///
/// [`LinkDevice::next_command`] is cancel-safe (bytes read stay in the
/// decoder), so a device loop can `select!` between it and a frame timer.
#[derive(Debug)]
pub struct LinkDevice {
    io: DeviceIo,
    decoder: LinkDecoder,
    rejected: u64,
}

impl LinkDevice {
    /// Over a byte stream (serial port, pty, socket, duplex pipe).
    pub fn new<T>(io: T) -> Self
    where
        T: AsyncRead + AsyncWrite + Send + 'static,
    {
        let (rd, wr) = tokio::io::split(io);
        Self { io: DeviceIo::Stream { rd: Box::new(rd), wr: Box::new(wr) }, decoder: LinkDecoder::new(), rejected: 0 }
    }

    /// Over UDP, bound at `bind`. With `host = None` frames go to whoever sent
    /// the latest command (so the host must send START first, as it does).
    pub async fn udp(bind: SocketAddr, host: Option<SocketAddr>) -> Result<Self, SensorError> {
        let socket = UdpSocket::bind(bind).await.map_err(io_err("bind UDP socket"))?;
        Ok(Self { io: DeviceIo::Udp { socket, host }, decoder: LinkDecoder::new(), rejected: 0 })
    }

    /// Local address of a UDP device.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        match &self.io {
            DeviceIo::Udp { socket, .. } => socket.local_addr().ok(),
            DeviceIo::Stream { .. } => None,
        }
    }

    /// Host input that was not a valid command (counted, then skipped).
    pub fn rejected(&self) -> u64 {
        self.rejected
    }

    async fn write(&mut self, bytes: &[u8], what: &'static str) -> Result<(), SensorError> {
        match &mut self.io {
            DeviceIo::Stream { wr, .. } => {
                wr.write_all(bytes).await.map_err(io_err(what))?;
                wr.flush().await.map_err(io_err(what))
            }
            DeviceIo::Udp { socket, host } => {
                let Some(to) = *host else {
                    return Err(SensorError::NoPeer { command: what });
                };
                match socket.send_to(bytes, to).await {
                    Ok(_) => Ok(()),
                    // The host went away; a UDP device keeps running for the next one.
                    Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => Ok(()),
                    Err(e) => Err(io_err(what)(e)),
                }
            }
        }
    }

    /// Send one frame (positions and displacements travel as f32).
    pub async fn send_frame(&mut self, frame: &SensorFrame) -> Result<(), SensorError> {
        let bytes = encode(&LinkMessage::Frame(frame.clone())).map_err(|e| SensorError::Io {
            what: "encode link frame",
            source: std::io::Error::new(std::io::ErrorKind::InvalidInput, e),
        })?;
        self.write(&bytes, "send frame").await
    }

    /// Write bytes as they are (a bridge relaying ready-made messages, or a
    /// test injecting noise); over UDP they form one datagram.
    pub async fn send_raw(&mut self, bytes: &[u8]) -> Result<(), SensorError> {
        self.write(bytes, "send raw bytes").await
    }

    /// Acknowledge a command the device carried out.
    pub async fn ack(&mut self, cmd: Command) -> Result<(), SensorError> {
        let out = encode(&LinkMessage::Ack(cmd)).map_err(|e| SensorError::Io {
            what: "encode ack",
            source: std::io::Error::new(std::io::ErrorKind::InvalidInput, e),
        })?;
        self.write(&out, "send ack").await
    }

    /// Wait for the host's next valid command.
    pub async fn next_command(&mut self) -> Result<Command, SensorError> {
        loop {
            while let Some(m) = self.decoder.next_message() {
                match m {
                    Ok(LinkMessage::Command(c)) => return Ok(c),
                    // Frames and acks flow device -> host only.
                    Ok(_) | Err(_) => self.rejected += 1,
                }
            }
            let mut buf = [0u8; 512];
            match &mut self.io {
                DeviceIo::Stream { rd, .. } => {
                    let n = rd.read(&mut buf).await.map_err(io_err("read command"))?;
                    if n == 0 {
                        return Err(SensorError::Closed { reason: "host closed the stream".into() });
                    }
                    self.decoder.push(&buf[..n]);
                }
                DeviceIo::Udp { socket, host } => {
                    let (n, from) = match socket.recv_from(&mut buf).await {
                        Ok(x) => x,
                        Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => continue,
                        Err(e) => return Err(io_err("receive command")(e)),
                    };
                    match decode_datagram(&buf[..n]) {
                        Ok(LinkMessage::Command(c)) => {
                            *host = Some(from);
                            return Ok(c);
                        }
                        Ok(_) | Err(_) => self.rejected += 1,
                    }
                }
            }
        }
    }
}
