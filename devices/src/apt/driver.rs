//! APT drivers: `AptStage<T>` (KDC101 + Z8 actuator, a `LinearStage`) and
//! `AptRotation<T>` (K10CR1, a `RotationMount`), both over any byte transport.
//!
//! All I/O happens inside the driver's own calls; there is no background
//! task. Replies are matched by id while unsolicited frames (end-of-move
//! messages, pushed status updates, device errors) are absorbed on the way.
//! Completion of a move is taken from MOVE_COMPLETED / MOVE_STOPPED /
//! MOVE_HOMED, with a status poll as a fallback for units that drop those
//! messages (hardware.md A.9). While the driver waits it sends the "server
//! alive" MOT_ACK_DCSTATUSUPDATE once per `keepalive` period (A.5).

use std::io;
use std::time::Duration;

use async_trait::async_trait;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

use super::codec::{
    AptDecoder, AptMessage, CodecError, Frame, HOST, HwInfo, StatusPayload, StopMode, USB_UNIT, VelParams, encode,
    status,
};
use super::scaling::{ControllerFamily, Scale};
use crate::motion::{AxisStatus, DeviceFault, DeviceInfo, FaultKind, Identify, LinearStage, RotationMount};
use crate::serial::open_serial;

/// Typed error of the APT driver family.
#[derive(Debug, thiserror::Error)]
pub enum AptError {
    #[error("APT device did not send {waiting_for} within {timeout:?}")]
    Timeout { waiting_for: &'static str, timeout: Duration },
    #[error("APT protocol error: {detail} (bytes {bytes:02X?})")]
    Protocol { detail: String, bytes: Vec<u8> },
    #[error("APT device reported error code {code} for message 0x{msg_id:04X}: {text}")]
    DeviceReported { msg_id: u16, code: u16, text: String },
    #[error("{what} {requested} outside the travel [{min}, {max}]; nothing was sent")]
    Limit { what: &'static str, requested: f64, min: f64, max: f64 },
    #[error("APT link disconnected: {0}")]
    Disconnected(String),
    #[error("APT I/O error: {0}")]
    Io(#[from] io::Error),
}

impl DeviceFault for AptError {
    fn kind(&self) -> FaultKind {
        match self {
            AptError::Timeout { .. } => FaultKind::Timeout,
            AptError::Protocol { .. } => FaultKind::Protocol,
            AptError::DeviceReported { .. } => FaultKind::DeviceReported,
            AptError::Limit { .. } => FaultKind::Limit,
            // An I/O error other than a hang-up still leaves the link unusable.
            AptError::Disconnected(_) | AptError::Io(_) => FaultKind::Disconnected,
        }
    }
}

impl AptError {
    fn from_codec(e: &CodecError, bytes: &[u8]) -> Self {
        AptError::Protocol { detail: e.to_string(), bytes: bytes.to_vec() }
    }
}

/// Is this I/O error the far end going away (cable pulled, pty master closed)?
fn is_hangup(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::BrokenPipe
            | io::ErrorKind::UnexpectedEof
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::NotConnected
    ) || matches!(e.raw_os_error(), Some(5 /* EIO */ | 6 /* ENXIO */ | 19 /* ENODEV */))
}

/// `now + d`, saturating at a year ahead instead of overflowing on huge timeouts.
fn after(d: Duration) -> Instant {
    let now = Instant::now();
    now.checked_add(d).unwrap_or_else(|| now + Duration::from_secs(365 * 24 * 3600))
}

/// Driver settings for one APT unit.
#[derive(Debug, Clone, PartialEq)]
pub struct AptConfig {
    /// Unit conversion (counts per mm or degree, controller family).
    pub scale: Scale,
    /// Soft travel `(min, max)` in user units; moves outside are refused.
    pub travel: (f64, f64),
    /// Model strings accepted in HW_GET_INFO (empty = accept any).
    pub expect_models: Vec<String>,
    /// `(max velocity, acceleration)` in user units to set at connect.
    pub velocity: Option<(f64, f64)>,
    /// How long to wait for the reply to a request.
    pub reply_timeout: Duration,
    /// How often to send MOT_ACK_DCSTATUSUPDATE while the driver is active.
    pub keepalive: Duration,
    /// Status poll period while waiting for a move to end.
    pub poll_period: Duration,
    /// Destination address (0x50 for single-channel USB units).
    pub dest: u8,
    /// Channel (1 on single-channel units).
    pub chan: u8,
}

impl AptConfig {
    /// KDC101 driving a Z825B (25 mm travel), 2.3 mm/s and 4 mm/s² (A.7).
    pub fn kdc101_z825b() -> Self {
        Self {
            scale: Scale::kdc101_z8(),
            travel: (0.0, 25.0),
            expect_models: vec!["KDC101".into(), "TDC001".into()],
            velocity: Some((2.3, 4.0)),
            reply_timeout: Duration::from_secs(1),
            keepalive: Duration::from_millis(900),
            poll_period: Duration::from_millis(200),
            dest: USB_UNIT,
            chan: 1,
        }
    }

    /// KDC101 driving a Z812B (12 mm travel).
    pub fn kdc101_z812b() -> Self {
        Self { travel: (0.0, 12.0), ..Self::kdc101_z825b() }
    }

    /// K10CR1 rotation mount, 10 °/s and 20 °/s² (A.7); soft travel ±360°.
    pub fn k10cr1() -> Self {
        Self {
            scale: Scale::k10cr1(),
            travel: (-360.0, 360.0),
            expect_models: vec!["K10CR1".into(), "K10CR2".into()],
            velocity: Some((10.0, 20.0)),
            ..Self::kdc101_z825b()
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PendingKind {
    Move,
    Home,
    Stop,
}

/// The motion the driver has started and not yet seen end.
#[derive(Debug, Clone, Copy)]
struct Pending {
    kind: PendingKind,
    target: Option<i32>,
    started: Instant,
    seen_moving: bool,
    done: Option<StatusPayload>,
}

/// How long after a move command an idle status is believed even when the
/// target was not reached and no motion was ever seen (a move that the unit
/// refused or finished between two polls).
const IDLE_GRACE: Duration = Duration::from_millis(500);

/// Protocol engine shared by the stage and the rotation drivers.
#[derive(Debug)]
pub struct AptLink<T> {
    io: T,
    dec: AptDecoder,
    cfg: AptConfig,
    last_ack: Instant,
    dead: Option<String>,
    pending: Option<Pending>,
    last_status: Option<StatusPayload>,
    last_codec_error: Option<(CodecError, Vec<u8>)>,
    info: Option<HwInfo>,
    rbuf: Vec<u8>,
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> AptLink<T> {
    fn new(io: T, cfg: AptConfig) -> Self {
        Self {
            io,
            dec: AptDecoder::for_host(),
            cfg,
            last_ack: Instant::now(),
            dead: None,
            pending: None,
            last_status: None,
            last_codec_error: None,
            info: None,
            rbuf: vec![0u8; 512],
        }
    }

    fn check_alive(&self) -> Result<(), AptError> {
        match &self.dead {
            Some(why) => Err(AptError::Disconnected(why.clone())),
            None => Ok(()),
        }
    }

    fn io_error(&mut self, e: io::Error) -> AptError {
        if is_hangup(&e) {
            let why = format!("{e}");
            self.dead = Some(why.clone());
            AptError::Disconnected(why)
        } else {
            AptError::Io(e)
        }
    }

    /// Send one message to the unit.
    pub async fn send(&mut self, msg: &AptMessage) -> Result<(), AptError> {
        self.check_alive()?;
        self.ack_if_due().await?;
        self.write_msg(msg).await
    }

    async fn write_msg(&mut self, msg: &AptMessage) -> Result<(), AptError> {
        let bytes = encode(msg, self.cfg.dest, HOST);
        let res = match self.io.write_all(&bytes).await {
            Ok(()) => self.io.flush().await,
            Err(e) => Err(e),
        };
        res.map_err(|e| self.io_error(e))?;
        if matches!(msg, AptMessage::MotAckDcStatusUpdate) {
            self.last_ack = Instant::now();
        }
        Ok(())
    }

    async fn ack_if_due(&mut self) -> Result<(), AptError> {
        if self.last_ack.elapsed() >= self.cfg.keepalive {
            self.write_msg(&AptMessage::MotAckDcStatusUpdate).await?;
        }
        Ok(())
    }

    /// Next decoded frame, or `None` at `deadline`. Keeps the keep-alive going.
    async fn read_frame(&mut self, deadline: Instant) -> Result<Option<Frame>, AptError> {
        loop {
            self.check_alive()?;
            while let Some(r) = self.dec.next_frame() {
                match r {
                    Ok(f) => return Ok(Some(f)),
                    // Line noise is skipped (the decoder resynchronises), but
                    // remembered so a timeout can say what was seen instead.
                    Err(e) => {
                        let bytes = self.dec.last_bad_bytes().to_vec();
                        self.last_codec_error = Some((e, bytes));
                    }
                }
            }
            self.ack_if_due().await?;
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            let wake = match self.last_ack.checked_add(self.cfg.keepalive) {
                Some(k) => deadline.min(k),
                None => deadline,
            };
            let wake = wake.max(now + Duration::from_millis(1));
            match tokio::time::timeout_at(wake, self.io.read(&mut self.rbuf)).await {
                Ok(Ok(0)) => {
                    let why = "end of stream (port closed)".to_string();
                    self.dead = Some(why.clone());
                    return Err(AptError::Disconnected(why));
                }
                Ok(Ok(n)) => {
                    let (dec, buf) = (&mut self.dec, &self.rbuf);
                    dec.feed(&buf[..n]);
                }
                Ok(Err(e)) if e.kind() == io::ErrorKind::Interrupted => {}
                Ok(Err(e)) => return Err(self.io_error(e)),
                Err(_elapsed) => {}
            }
        }
    }

    /// Take note of a frame that is not (only) a reply: end-of-move
    /// messages, status updates, device errors.
    fn absorb(&mut self, msg: &AptMessage) -> Result<(), AptError> {
        match msg {
            AptMessage::HwResponse { p1, p2 } => Err(AptError::DeviceReported {
                msg_id: 0,
                code: u16::from_le_bytes([*p1, *p2]),
                text: "HW_RESPONSE".into(),
            }),
            AptMessage::HwRichResponse { msg_id, code, text } => {
                Err(AptError::DeviceReported { msg_id: *msg_id, code: *code, text: text.clone() })
            }
            AptMessage::MotMoveCompleted(s) => {
                self.last_status = Some(*s);
                if let Some(p) = &mut self.pending
                    && p.kind != PendingKind::Home
                {
                    p.done = Some(*s);
                }
                Ok(())
            }
            // A MOVE_STOPPED ends only a stop we asked for: a late one from
            // an earlier stop (units answer a stop even when idle) must not
            // end the next move. A move the unit stops by itself (limit,
            // front panel) is still seen ending by the status poll.
            AptMessage::MotMoveStopped(s) => {
                self.last_status = Some(*s);
                if let Some(p) = &mut self.pending
                    && p.kind == PendingKind::Stop
                {
                    p.done = Some(*s);
                }
                Ok(())
            }
            AptMessage::MotMoveHomed { .. } => {
                if let Some(p) = &mut self.pending
                    && p.kind == PendingKind::Home
                {
                    let mut s = self.last_status.unwrap_or_else(|| StatusPayload::dc(1, 0, 0, 0));
                    s.position = 0;
                    s.status = (s.status | status::HOMED) & !status::ANY_MOTION;
                    p.done = Some(s);
                }
                Ok(())
            }
            AptMessage::MotGetDcStatusUpdate(s) | AptMessage::MotGetStatusUpdate(s) => {
                self.note_status(*s);
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// Judge a polled or pushed status against the pending motion.
    fn note_status(&mut self, s: StatusPayload) {
        self.last_status = Some(s);
        let Some(p) = &mut self.pending else { return };
        if p.done.is_some() {
            return;
        }
        let moving = s.status & status::ANY_MOTION != 0;
        if moving {
            p.seen_moving = true;
            return;
        }
        let finished = match p.kind {
            PendingKind::Stop => true,
            PendingKind::Home => s.status & status::HOMED != 0 && (p.seen_moving || p.started.elapsed() > IDLE_GRACE),
            PendingKind::Move => p.target == Some(s.position) || p.seen_moving || p.started.elapsed() > IDLE_GRACE,
        };
        if finished {
            p.done = Some(s);
        }
    }

    /// Send `msg` and wait for the reply `pick` recognises.
    async fn request<R>(
        &mut self,
        msg: &AptMessage,
        waiting_for: &'static str,
        mut pick: impl FnMut(&AptMessage) -> Option<R>,
    ) -> Result<R, AptError> {
        self.last_codec_error = None;
        self.send(msg).await?;
        let deadline = after(self.cfg.reply_timeout);
        loop {
            let Some(frame) = self.read_frame(deadline).await? else {
                return Err(match self.last_codec_error.take() {
                    Some((e, bytes)) => AptError::from_codec(&e, &bytes),
                    None => AptError::Timeout { waiting_for, timeout: self.cfg.reply_timeout },
                });
            };
            self.absorb(&frame.message)?;
            if let Some(r) = pick(&frame.message) {
                return Ok(r);
            }
        }
    }

    /// Ask for HW_GET_INFO.
    pub async fn hw_info(&mut self) -> Result<HwInfo, AptError> {
        let info = self
            .request(&AptMessage::HwReqInfo, "HW_GET_INFO", |m| match m {
                AptMessage::HwGetInfo(i) => Some((**i).clone()),
                _ => None,
            })
            .await?;
        self.info = Some(info.clone());
        Ok(info)
    }

    /// Open the session (hardware.md A.5): no-flash, stop pushed updates,
    /// identify and check the model, enable the channel, set velocity.
    async fn start_session(&mut self) -> Result<(), AptError> {
        self.send(&AptMessage::HwNoFlashProgramming).await?;
        self.send(&AptMessage::HwStopUpdateMsgs).await?;
        let info = self.hw_info().await?;
        if !self.cfg.expect_models.is_empty() && !self.cfg.expect_models.contains(&info.model) {
            return Err(AptError::Protocol {
                detail: format!(
                    "HW_GET_INFO model {:?} (serial {}) is not one of {:?}",
                    info.model, info.serial, self.cfg.expect_models
                ),
                bytes: info.model.into_bytes(),
            });
        }
        let chan = self.cfg.chan;
        self.send(&AptMessage::ModSetChanEnableState { chan, enabled: true }).await?;
        if let Some((v, a)) = self.cfg.velocity {
            self.set_velocity_params(v, a).await?;
        }
        Ok(())
    }

    /// Current status: DC units answer MOT_REQ_DCSTATUSUPDATE; stepper units
    /// are asked for status bits and position counter, the pair every
    /// K10CR1 client uses (the 0x0481 update is [U] for it, A.7).
    pub async fn query_status(&mut self) -> Result<StatusPayload, AptError> {
        let chan = self.cfg.chan;
        let s = match self.cfg.scale.family {
            ControllerFamily::DcServo => {
                self.request(&AptMessage::MotReqDcStatusUpdate { chan }, "MOT_GET_DCSTATUSUPDATE", |m| match m {
                    AptMessage::MotGetDcStatusUpdate(s) => Some(*s),
                    _ => None,
                })
                .await?
            }
            ControllerFamily::Stepper => {
                let bits = self
                    .request(&AptMessage::MotReqStatusBits { chan }, "MOT_GET_STATUSBITS", |m| match m {
                        AptMessage::MotGetStatusBits { status, .. } => Some(*status),
                        _ => None,
                    })
                    .await?;
                let pos = self
                    .request(&AptMessage::MotReqPosCounter { chan }, "MOT_GET_POSCOUNTER", |m| match m {
                        AptMessage::MotGetPosCounter { position, .. } => Some(*position),
                        _ => None,
                    })
                    .await?;
                let s = StatusPayload::stepper(u16::from(chan), pos, 0, bits);
                self.note_status(s);
                s
            }
        };
        Ok(s)
    }

    fn check_travel(&self, what: &'static str, target: f64) -> Result<(), AptError> {
        let (min, max) = self.cfg.travel;
        let half_count = 0.5 / self.cfg.scale.counts_per_unit;
        if !target.is_finite() || target < min - half_count || target > max + half_count {
            return Err(AptError::Limit { what, requested: target, min, max });
        }
        Ok(())
    }

    fn counts(&self, what: &'static str, x: f64) -> Result<i32, AptError> {
        self.cfg.scale.to_counts(x).map_err(|_| AptError::Limit {
            what,
            requested: x,
            min: self.cfg.travel.0,
            max: self.cfg.travel.1,
        })
    }

    fn begin(&mut self, kind: PendingKind, target: Option<i32>) {
        self.pending = Some(Pending { kind, target, started: Instant::now(), seen_moving: false, done: None });
    }

    pub async fn move_to(&mut self, target: f64) -> Result<(), AptError> {
        self.check_alive()?;
        self.check_travel("target", target)?;
        let counts = self.counts("target", target)?;
        self.begin(PendingKind::Move, Some(counts));
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveAbsolute { chan, position: Some(counts) }).await
    }

    /// Relative move: the current position is read first so the resulting
    /// target can be checked against the travel before the move is sent.
    pub async fn move_by(&mut self, delta: f64) -> Result<(), AptError> {
        let now = self.query_status().await?;
        let here = self.cfg.scale.from_counts(now.position);
        self.check_travel("target", here + delta)?;
        let d = self.counts("distance", delta)?;
        self.begin(PendingKind::Move, Some(now.position.saturating_add(d)));
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveRelative { chan, distance: Some(d) }).await
    }

    pub async fn home(&mut self, timeout: Duration) -> Result<(), AptError> {
        self.begin(PendingKind::Home, Some(0));
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveHome { chan }).await?;
        self.wait(timeout, "MOT_MOVE_HOMED").await.map(|_| ())
    }

    pub async fn stop(&mut self) -> Result<(), AptError> {
        match &mut self.pending {
            // The move under way now ends in MOVE_STOPPED (or MOVE_COMPLETED
            // if it reached its target first); either completes the wait.
            Some(p) if p.done.is_none() => p.kind = PendingKind::Stop,
            _ => self.begin(PendingKind::Stop, None),
        }
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveStop { chan, mode: StopMode::Profiled }).await
    }

    /// Wait for the pending motion to end; returns the final position (user units).
    pub async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<f64, AptError> {
        let s = self.wait(timeout, "end of move").await?;
        Ok(self.cfg.scale.from_counts(s.position))
    }

    async fn wait(&mut self, timeout: Duration, waiting_for: &'static str) -> Result<StatusPayload, AptError> {
        self.check_alive()?;
        if self.pending.is_none() {
            return self.query_status().await;
        }
        let deadline = after(timeout);
        let mut next_poll = after(self.cfg.poll_period);
        loop {
            if let Some(done) = self.pending.and_then(|p| p.done) {
                self.pending = None;
                return Ok(done);
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(AptError::Timeout { waiting_for, timeout });
            }
            if now >= next_poll {
                self.query_status().await?;
                next_poll = after(self.cfg.poll_period);
                continue;
            }
            if let Some(f) = self.read_frame(next_poll.min(deadline)).await? {
                self.absorb(&f.message)?;
            }
        }
    }

    pub async fn set_velocity_params(&mut self, v: f64, a: f64) -> Result<(), AptError> {
        let bad = |what| AptError::Protocol { detail: format!("{what} out of the device's range"), bytes: Vec::new() };
        let p = VelParams {
            chan: u16::from(self.cfg.chan),
            min_velocity: 0,
            acceleration: self.cfg.scale.acceleration_to_device(a).map_err(|_| bad("acceleration"))?,
            max_velocity: self.cfg.scale.velocity_to_device(v).map_err(|_| bad("velocity"))?,
        };
        self.send(&AptMessage::MotSetVelParams(p)).await
    }

    /// `(max velocity, acceleration)` in user units as the unit reports them.
    pub async fn velocity_params(&mut self) -> Result<(f64, f64), AptError> {
        let chan = self.cfg.chan;
        let p = self
            .request(&AptMessage::MotReqVelParams { chan }, "MOT_GET_VELPARAMS", |m| match m {
                AptMessage::MotGetVelParams(p) => Some(*p),
                _ => None,
            })
            .await?;
        Ok((
            self.cfg.scale.velocity_from_device(p.max_velocity),
            self.cfg.scale.acceleration_from_device(p.acceleration),
        ))
    }

    fn axis_status(&self, s: &StatusPayload) -> AxisStatus {
        AxisStatus {
            position: self.cfg.scale.from_counts(s.position),
            moving: s.status & status::ANY_MOTION != 0,
            homed: s.status & status::HOMED != 0,
            homing: s.status & status::HOMING != 0,
            // Which physical direction CW/CCW means on these units is [U]
            // (A.4); CW is taken as forward, consistently with the emulator.
            forward_limit: s.status & (status::CW_HW_LIMIT | status::CW_SW_LIMIT) != 0,
            reverse_limit: s.status & (status::CCW_HW_LIMIT | status::CCW_SW_LIMIT) != 0,
            enabled: s.status & status::ENABLED != 0,
        }
    }

    async fn identify(&mut self) -> Result<DeviceInfo, AptError> {
        let i = self.hw_info().await?;
        let (major, interim, minor) = i.firmware;
        Ok(DeviceInfo {
            model: i.model,
            serial: format!("{:08}", i.serial),
            firmware: format!("{major}.{interim}.{minor}"),
        })
    }

    /// Ask the unit to push status updates (10 Hz); they are absorbed while
    /// the driver is waiting and acknowledged by the keep-alive.
    pub async fn start_updates(&mut self) -> Result<(), AptError> {
        self.send(&AptMessage::HwStartUpdateMsgs).await
    }

    pub async fn stop_updates(&mut self) -> Result<(), AptError> {
        self.send(&AptMessage::HwStopUpdateMsgs).await
    }

    /// Drain whatever the unit sent so far (pushed updates, events) for up to `dur`.
    pub async fn pump(&mut self, dur: Duration) -> Result<(), AptError> {
        let deadline = after(dur);
        while let Some(f) = self.read_frame(deadline).await? {
            self.absorb(&f.message)?;
        }
        Ok(())
    }

    /// Shutdown as thorlabs_apt_device does it: profiled stop, stop updates.
    async fn close(mut self) -> Result<T, AptError> {
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveStop { chan, mode: StopMode::Profiled }).await?;
        self.send(&AptMessage::HwStopUpdateMsgs).await?;
        Ok(self.io)
    }
}

macro_rules! apt_device {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(Debug)]
        pub struct $name<T> {
            link: AptLink<T>,
        }

        impl<T: AsyncRead + AsyncWrite + Unpin + Send> $name<T> {
            /// Open a session on `io` (see [`AptLink`] for the start-up sequence).
            pub async fn connect(io: T, cfg: AptConfig) -> Result<Self, AptError> {
                let mut link = AptLink::new(io, cfg);
                link.start_session().await?;
                Ok(Self { link })
            }

            /// The protocol engine, for messages the trait does not cover.
            pub fn link(&mut self) -> &mut AptLink<T> {
                &mut self.link
            }

            pub fn config(&self) -> &AptConfig {
                &self.link.cfg
            }

            /// HW_GET_INFO as read at connect.
            pub fn hw_info(&self) -> Option<&HwInfo> {
                self.link.info.as_ref()
            }

            /// Set `(max velocity, acceleration)` in user units (per s, per s²).
            pub async fn set_velocity_params(&mut self, v: f64, a: f64) -> Result<(), AptError> {
                self.link.set_velocity_params(v, a).await
            }

            pub async fn velocity_params(&mut self) -> Result<(f64, f64), AptError> {
                self.link.velocity_params().await
            }

            /// Latest status seen (polled, pushed or end-of-move), without asking.
            pub fn last_status(&self) -> Option<AxisStatus> {
                self.link.last_status.map(|s| self.link.axis_status(&s))
            }

            /// Profiled stop and HW_STOP_UPDATEMSGS; gives the transport back.
            pub async fn close(self) -> Result<T, AptError> {
                self.link.close().await
            }
        }

        #[async_trait]
        impl<T: AsyncRead + AsyncWrite + Unpin + Send> Identify for $name<T> {
            type Error = AptError;
            async fn identify(&mut self) -> Result<DeviceInfo, AptError> {
                self.link.identify().await
            }
        }
    };
}

apt_device!(
    /// KDC101 + Z8 actuator as a linear stage (mm).
    AptStage
);
apt_device!(
    /// K10CR1 rotation mount (degrees).
    AptRotation
);

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> LinearStage for AptStage<T> {
    type Error = AptError;

    fn travel_mm(&self) -> (f64, f64) {
        self.link.cfg.travel
    }
    async fn home(&mut self, timeout: Duration) -> Result<(), AptError> {
        self.link.home(timeout).await
    }
    async fn start_move_to_mm(&mut self, target_mm: f64) -> Result<(), AptError> {
        self.link.move_to(target_mm).await
    }
    async fn start_move_by_mm(&mut self, delta_mm: f64) -> Result<(), AptError> {
        self.link.move_by(delta_mm).await
    }
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<f64, AptError> {
        self.link.wait_until_stopped(timeout).await
    }
    async fn stop(&mut self) -> Result<(), AptError> {
        self.link.stop().await
    }
    async fn position_mm(&mut self) -> Result<f64, AptError> {
        let s = self.link.query_status().await?;
        Ok(self.link.cfg.scale.from_counts(s.position))
    }
    async fn status(&mut self) -> Result<AxisStatus, AptError> {
        let s = self.link.query_status().await?;
        Ok(self.link.axis_status(&s))
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> RotationMount for AptRotation<T> {
    type Error = AptError;

    fn travel_deg(&self) -> (f64, f64) {
        self.link.cfg.travel
    }
    async fn home(&mut self, timeout: Duration) -> Result<(), AptError> {
        self.link.home(timeout).await
    }
    async fn start_move_to_deg(&mut self, target_deg: f64) -> Result<(), AptError> {
        self.link.move_to(target_deg).await
    }
    async fn start_move_by_deg(&mut self, delta_deg: f64) -> Result<(), AptError> {
        self.link.move_by(delta_deg).await
    }
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<f64, AptError> {
        self.link.wait_until_stopped(timeout).await
    }
    async fn stop(&mut self) -> Result<(), AptError> {
        self.link.stop().await
    }
    async fn position_deg(&mut self) -> Result<f64, AptError> {
        let s = self.link.query_status().await?;
        Ok(self.link.cfg.scale.from_counts(s.position))
    }
    async fn status(&mut self) -> Result<AxisStatus, AptError> {
        let s = self.link.query_status().await?;
        Ok(self.link.axis_status(&s))
    }
}

/// Ask whatever answers on `port_path` whether it is an APT unit: open the
/// port with the APT line settings, send HW_REQ_INFO and wait up to `timeout`
/// for HW_GET_INFO. Nothing else is sent, so nothing moves and no setting
/// changes. HW_NO_FLASH_PROGRAMMING is deliberately not sent: its first byte
/// is 0x18 (Ctrl-X), which a GRBL board on the same probe would take as a
/// soft reset.
pub async fn probe(port_path: impl AsRef<std::path::Path>, timeout: Duration) -> Result<DeviceInfo, AptError> {
    let port = open_serial(port_path).await?;
    probe_on(port, timeout).await
}

/// [`probe`] over an already open transport.
pub async fn probe_on<T: AsyncRead + AsyncWrite + Unpin + Send>(
    io: T,
    timeout: Duration,
) -> Result<DeviceInfo, AptError> {
    let cfg = AptConfig {
        expect_models: Vec::new(),
        velocity: None,
        reply_timeout: timeout,
        // No keep-alive during a probe: only HW_REQ_INFO goes out.
        keepalive: Duration::MAX,
        ..AptConfig::kdc101_z825b()
    };
    let mut link = AptLink::new(io, cfg);
    link.identify().await
}

#[cfg(test)]
mod tests {
    //! Byte-exact transaction scripts against an in-memory pipe: the test
    //! plays the unit, reading exactly what the driver must write.
    use super::*;
    use crate::apt::codec::{AptMessage as M, HwInfo};
    use tokio::io::{DuplexStream, duplex};

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
    }

    async fn expect(dev: &mut DuplexStream, want: &str) {
        let want = hex(want);
        let mut got = vec![0u8; want.len()];
        dev.read_exact(&mut got).await.unwrap();
        assert_eq!(got, want);
    }

    async fn reply(dev: &mut DuplexStream, m: &AptMessage) {
        dev.write_all(&encode(m, HOST, USB_UNIT)).await.unwrap();
    }

    fn info() -> AptMessage {
        M::HwGetInfo(Box::new(HwInfo {
            serial: 27_000_123,
            model: "KDC101".into(),
            hw_type: 16,
            firmware: (3, 1, 4),
            notes: String::new(),
            reserved: [0; 10],
            stage_id: 9,
            hw_version: 1,
            mod_state: 0,
            n_channels: 1,
        }))
    }

    fn cfg() -> AptConfig {
        AptConfig { reply_timeout: Duration::from_millis(20), ..AptConfig::kdc101_z825b() }
    }

    /// Play the unit through the connect sequence; returns the connected stage.
    async fn connected() -> (AptStage<DuplexStream>, DuplexStream) {
        let (host, mut dev) = duplex(4096);
        let unit = async {
            expect(&mut dev, "18 00 00 00 50 01 12 00 00 00 50 01 05 00 00 00 50 01").await;
            reply(&mut dev, &info()).await;
            // Enable, then VELPARAMS 2.3 mm/s, 4 mm/s²: the A.8 example frame.
            expect(&mut dev, "10 02 01 01 50 01").await;
            expect(&mut dev, "13 04 0E 00 D0 01 01 00 00 00 00 00 1F 04 00 00 C1 20 1B 00").await;
            dev
        };
        let (stage, dev) = tokio::join!(AptStage::connect(host, cfg()), unit);
        (stage.unwrap(), dev)
    }

    #[tokio::test]
    async fn connect_sends_the_documented_bytes_and_reads_identity() {
        let (stage, _dev) = connected().await;
        let i = stage.hw_info().unwrap();
        assert_eq!((i.model.as_str(), i.serial, i.firmware), ("KDC101", 27_000_123, (3, 1, 4)));
    }

    #[tokio::test]
    async fn wrong_model_is_refused() {
        let (host, mut dev) = duplex(4096);
        let unit = async {
            expect(&mut dev, "18 00 00 00 50 01 12 00 00 00 50 01 05 00 00 00 50 01").await;
            let mut m = info();
            if let M::HwGetInfo(i) = &mut m {
                i.model = "KST101".into();
            }
            reply(&mut dev, &m).await;
            dev
        };
        let (r, _dev) = tokio::join!(AptStage::connect(host, cfg()), unit);
        assert_eq!(r.unwrap_err().kind(), FaultKind::Protocol);
    }

    #[tokio::test]
    async fn silence_is_a_timeout_and_garbage_a_protocol_error_with_its_bytes() {
        let (mut stage, mut dev) = connected().await;
        let e = stage.status().await.unwrap_err();
        assert!(matches!(e, AptError::Timeout { waiting_for: "MOT_GET_DCSTATUSUPDATE", .. }), "{e}");
        expect(&mut dev, "90 04 01 00 50 01").await;
        dev.write_all(&hex("34 12 00 00 01 50")).await.unwrap();
        match stage.status().await.unwrap_err() {
            AptError::Protocol { bytes, .. } => assert_eq!(&bytes[..2], &[0x34, 0x12]),
            e => panic!("{e}"),
        }
    }

    #[tokio::test]
    async fn a_late_move_stopped_does_not_end_the_next_move() {
        let (mut stage, mut dev) = connected().await;
        stage.start_move_to_mm(1.234).await.unwrap();
        expect(&mut dev, "53 04 06 00 D0 01 01 00 91 A6 00 00").await;
        let idle = StatusPayload::dc(1, 0, 0, status::HOMED | status::ENABLED);
        let done = StatusPayload::dc(1, 42_641, 0, status::HOMED | status::ENABLED);
        reply(&mut dev, &M::MotMoveStopped(idle)).await;
        reply(&mut dev, &M::MotMoveCompleted(done)).await;
        let p = stage.wait_until_stopped(Duration::from_secs(5)).await.unwrap();
        assert_eq!(stage.config().scale.to_counts(p).unwrap(), 42_641);
    }

    #[tokio::test]
    async fn device_errors_and_hangups_are_typed() {
        let (mut stage, mut dev) = connected().await;
        reply(&mut dev, &M::HwRichResponse { msg_id: 0x0443, code: 7, text: "no motor".into() }).await;
        let e = stage.home(Duration::from_secs(5)).await.unwrap_err();
        assert!(matches!(&e, AptError::DeviceReported { msg_id: 0x0443, code: 7, text } if text == "no motor"), "{e}");
        drop(dev);
        let e = stage.status().await.unwrap_err();
        assert_eq!(e.kind(), FaultKind::Disconnected, "{e}");
    }

    #[tokio::test]
    async fn soft_limit_refuses_without_writing() {
        let (mut stage, mut dev) = connected().await;
        assert_eq!(stage.start_move_to_mm(25.01).await.unwrap_err().kind(), FaultKind::Limit);
        assert_eq!(stage.start_move_to_mm(-0.01).await.unwrap_err().kind(), FaultKind::Limit);
        // Nothing was written: the next bytes the unit sees are the status request.
        let (r, ()) = tokio::join!(stage.status(), async {
            expect(&mut dev, "90 04 01 00 50 01").await;
            reply(&mut dev, &M::MotGetDcStatusUpdate(StatusPayload::dc(1, 5, 0, 0))).await;
        });
        assert_eq!(stage.config().scale.to_counts(r.unwrap().position).unwrap(), 5);
    }
}
