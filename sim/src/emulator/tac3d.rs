//! The Tac3D main program's side of its UDP stream (`devices::sensor::tac3d`,
//! docs/hardware.md C.1), emulated: frames out as the main program sends
//! them, `$C` / `$Q` back from the client.

use std::net::SocketAddr;

use devices::sensor::SensorFrame;
use devices::sensor::error::{SensorError, encode_err, io_err};
use devices::sensor::tac3d::{DEFAULT_MAX_DATAGRAM, Tac3dCommand, Tac3dFrame, encode_frame};
use tokio::net::UdpSocket;

/// Sensor serial the emulated sensor reports by default (a Tac3D-style SN).
pub const DEFAULT_SN: &str = "EC1-0000SIM";

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
        let packets = encode_frame(frame, self.cfg.max_datagram).map_err(encode_err("Tac3D frame"))?;
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
