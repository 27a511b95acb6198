//! The rig's side of a Tac3D link: a UDP socket, a receive task that
//! reassembles and decodes, and the [`SensorLink`] the sequencer reads.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use async_trait::async_trait;
use tokio::net::UdpSocket;
use tokio::task::JoinHandle;

use super::{CMD_CALIBRATE, CMD_QUIT, DEFAULT_PORT, Tac3dReassembler};
use crate::sensor::SensorLink;
use crate::sensor::error::{SensorError, io_err};
use crate::sensor::frame::SensorFrame;
use crate::sensor::inbox::Inbox;
use crate::sensor::stats::{BadReason, LinkStats};

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
                inbox.fail("UDP receive", e);
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

    fn discard_queued(&mut self) -> usize {
        self.inbox.discard_queued()
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

    /// The receive task holds the socket too: wait until it is gone, so that
    /// dropping the receiver frees the port.
    async fn close(&mut self) {
        self.task.abort();
        let _ = (&mut self.task).await;
    }
}
