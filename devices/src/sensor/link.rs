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
pub fn crc32(data: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut t = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
                k += 1;
            }
            t[i] = c;
            i += 1;
        }
        t
    };
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c = TABLE[((c ^ u32::from(b)) & 0xFF) as usize] ^ (c >> 8);
    }
    c ^ 0xFFFF_FFFF
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

/// Streaming decoder: feed bytes as they arrive with [`push`](Self::push),
/// take messages and errors with [`next_message`](Self::next_message) until it
/// says `None`. Resynchronises on the sync pattern after any error.
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

    fn skip(&mut self, n: usize) -> Option<LinkError> {
        let at = self.base + self.start as u64;
        self.start += n;
        let end = self.base + self.start as u64;
        let loud = end.saturating_sub(self.quiet_until.max(at));
        (loud > 0).then_some(LinkError::Garbage { at: self.quiet_until.max(at), skipped: loud as usize })
    }

    pub fn next_message(&mut self) -> Option<Result<LinkMessage, LinkError>> {
        loop {
            let avail = &self.buf[self.start..];
            let sync_at = avail.windows(2).position(|w| w == SYNC);
            match sync_at {
                Some(0) => {}
                Some(k) => match self.skip(k) {
                    Some(e) => return Some(Err(e)),
                    None => continue,
                },
                None => {
                    // Keep a trailing first sync byte: its partner may come next.
                    let keep = usize::from(avail.last() == Some(&SYNC[0]));
                    let n = avail.len() - keep;
                    if n == 0 {
                        return None;
                    }
                    match self.skip(n) {
                        Some(e) => return Some(Err(e)),
                        None => return None,
                    }
                }
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
                    if at < self.quiet_until {
                        continue;
                    }
                    return Some(Err(e));
                }
            };
            if h.len > MAX_PAYLOAD {
                self.start += SYNC.len();
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
