//! The device side of easycalib's sensor link protocol
//! (`devices::sensor::link`, docs/sensor-link.md): what a bridge program or a
//! microcontroller runs, emulated here for the simulated sensor and for the
//! end-to-end tests of the host's [`LinkReceiver`](devices::sensor::link::LinkReceiver).

use std::net::SocketAddr;

use devices::sensor::SensorFrame;
use devices::sensor::error::{SensorError, encode_err, io_err};
use devices::sensor::link::{LinkCommand, LinkDecoder, LinkMessage, decode_datagram, encode, encode_frame};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::UdpSocket;

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
        let bytes = encode_frame(frame).map_err(encode_err("link frame"))?;
        self.write(&bytes, "send frame").await
    }

    /// Write bytes as they are (a bridge relaying ready-made messages, or a
    /// test injecting noise); over UDP they form one datagram.
    pub async fn send_raw(&mut self, bytes: &[u8]) -> Result<(), SensorError> {
        self.write(bytes, "send raw bytes").await
    }

    /// Acknowledge a command the device carried out.
    pub async fn ack(&mut self, cmd: LinkCommand) -> Result<(), SensorError> {
        let out = encode(&LinkMessage::Ack(cmd)).map_err(encode_err("ack"))?;
        self.write(&out, "send ack").await
    }

    /// Wait for the host's next valid command.
    pub async fn next_command(&mut self) -> Result<LinkCommand, SensorError> {
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
