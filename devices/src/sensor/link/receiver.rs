//! The host side of the link over a byte stream or UDP, as a [`SensorLink`].

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use async_trait::async_trait;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadHalf, WriteHalf};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::{LinkCommand, LinkDecoder, LinkError, LinkMessage, decode_datagram, encode_raw};
use crate::sensor::SensorLink;
use crate::sensor::error::{SensorError, encode_err, io_err};
use crate::sensor::frame::SensorFrame;
use crate::sensor::inbox::Inbox;
use crate::sensor::stats::{BadReason, LinkStats};

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
    acks: mpsc::Receiver<LinkCommand>,
    cfg: LinkConfig,
    task: JoinHandle<()>,
}

impl Drop for LinkReceiver {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn dispatch(msg: Result<LinkMessage, LinkError>, inbox: &Inbox, acks: &mpsc::Sender<LinkCommand>) {
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

async fn stream_loop<R: AsyncRead + Unpin>(mut rd: R, inbox: Arc<Inbox>, acks: mpsc::Sender<LinkCommand>) {
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
                inbox.fail("read", e);
                return;
            }
        };
        dec.push(&buf[..n]);
        while let Some(m) = dec.next_message() {
            dispatch(m, &inbox, &acks);
        }
    }
}

async fn udp_loop(socket: Arc<UdpSocket>, device: SocketAddr, inbox: Arc<Inbox>, acks: mpsc::Sender<LinkCommand>) {
    let mut buf = vec![0u8; 65536];
    loop {
        match socket.recv_from(&mut buf).await {
            Ok((n, from)) if from == device => dispatch(decode_datagram(&buf[..n]), &inbox, &acks),
            // Datagrams from anyone else are not this sensor's business.
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {}
            Err(e) => {
                inbox.fail("UDP receive", e);
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

    async fn send(&mut self, cmd: LinkCommand) -> Result<(), SensorError> {
        let bytes = encode_raw(cmd.kind(), &[]).map_err(encode_err("command"))?;
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
    pub async fn command(&mut self, cmd: LinkCommand) -> Result<(), SensorError> {
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
        let r = self.command(LinkCommand::Start).await;
        if r.is_err() {
            self.inbox.set_streaming(false);
        }
        r
    }

    async fn stop(&mut self) -> Result<(), SensorError> {
        let r = self.command(LinkCommand::Stop).await;
        self.inbox.set_streaming(false);
        r
    }

    async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError> {
        self.inbox.next(timeout).await
    }

    fn discard_queued(&mut self) -> usize {
        self.inbox.discard_queued()
    }

    async fn tare(&mut self) -> Result<(), SensorError> {
        self.command(LinkCommand::Tare).await
    }

    /// The receive task owns the read half of the transport: wait until it is
    /// gone, so that dropping the receiver (the write half) closes the port.
    async fn close(&mut self) {
        self.inbox.set_streaming(false);
        self.task.abort();
        let _ = (&mut self.task).await;
    }

    fn stats(&self) -> LinkStats {
        self.inbox.stats()
    }
}
