//! The APT protocol engine both APT axes run on ([`AptLink`]): frames out,
//! frames in, the keep-alive, and the bookkeeping of the motion under way.
//!
//! All I/O happens inside the driver's own calls; there is no background
//! task. Replies are matched by id while unsolicited frames (end-of-move
//! messages, pushed status updates, device errors) are absorbed on the way.
//! Completion of a move is taken from MOVE_COMPLETED / MOVE_STOPPED /
//! MOVE_HOMED, with a status poll as a fallback for units that drop those
//! messages (docs/hardware.md A.9). While the driver waits it sends the
//! "server alive" MOT_ACK_DCSTATUSUPDATE once per `keepalive` period (A.5).

use std::io;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

use super::codec::{
    AptDecoder, AptMessage, CodecError, Frame, HOST, HwInfo, StatusPayload, StopMode, VelParams, encode, status,
};
use super::driver::{AptConfig, AptError, is_hangup};
use super::scaling::ControllerFamily;
use crate::motion::arrival::deadline_after as after;
use crate::motion::{AxisStatus, DeviceInfo};

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
    pub(super) cfg: AptConfig,
    last_ack: Instant,
    dead: Option<String>,
    pending: Option<Pending>,
    pub(super) last_status: Option<StatusPayload>,
    last_codec_error: Option<(CodecError, Vec<u8>)>,
    pub(super) info: Option<HwInfo>,
    rbuf: Vec<u8>,
    /// Where the last move was sent (user units), until its end is confirmed.
    arrive_at: Option<f64>,
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> AptLink<T> {
    pub(super) fn new(io: T, cfg: AptConfig) -> Self {
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
            arrive_at: None,
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
                    Some((e, bytes)) => AptError::from_codec(e, bytes),
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

    /// Open the session (docs/hardware.md A.5): no-flash, stop pushed updates,
    /// identify and check the model, enable the channel, set velocity.
    pub(super) async fn start_session(&mut self) -> Result<(), AptError> {
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
                source: None,
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
        self.arrive_at = None;
        self.check_alive()?;
        self.check_travel("target", target)?;
        let counts = self.counts("target", target)?;
        self.begin(PendingKind::Move, Some(counts));
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveAbsolute { chan, position: Some(counts) }).await?;
        self.arrive_at = Some(target);
        Ok(())
    }

    /// Relative move: the current position is read first so the resulting
    /// target can be checked against the travel before the move is sent.
    pub async fn move_by(&mut self, delta: f64) -> Result<(), AptError> {
        self.arrive_at = None;
        let now = self.query_status().await?;
        let here = self.cfg.scale.from_counts(now.position);
        self.check_travel("target", here + delta)?;
        let d = self.counts("distance", delta)?;
        self.begin(PendingKind::Move, Some(now.position.saturating_add(d)));
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveRelative { chan, distance: Some(d) }).await?;
        self.arrive_at = Some(here + delta);
        Ok(())
    }

    pub async fn home(&mut self, timeout: Duration) -> Result<(), AptError> {
        if let Some(v) = self.cfg.home_velocity {
            self.set_home_velocity(v).await?;
        }
        self.arrive_at = None;
        self.begin(PendingKind::Home, Some(0));
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveHome { chan }).await?;
        self.wait(timeout, "MOT_MOVE_HOMED").await.map(|_| ())
    }

    /// Read the unit's home parameters and, if its homing velocity is not
    /// `v` (user units per second), write them back with `v`: direction,
    /// limit switch and offset stay the unit's.
    pub async fn set_home_velocity(&mut self, v: f64) -> Result<(), AptError> {
        let chan = self.cfg.chan;
        let mut p = self
            .request(&AptMessage::MotReqHomeParams { chan }, "MOT_GET_HOMEPARAMS", |m| match m {
                AptMessage::MotGetHomeParams(p) => Some(*p),
                _ => None,
            })
            .await?;
        let want = self
            .cfg
            .scale
            .velocity_to_device(v)
            .map_err(|source| AptError::Setting { what: "home velocity", source })?;
        if p.velocity != want {
            p.velocity = want;
            p.chan = u16::from(chan);
            self.send(&AptMessage::MotSetHomeParams(p)).await?;
        }
        Ok(())
    }

    pub async fn stop(&mut self) -> Result<(), AptError> {
        self.arrive_at = None;
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

    /// Where the last move was sent, once: the axis confirms the arrival there.
    pub(super) fn take_arrival_target(&mut self) -> Option<f64> {
        self.arrive_at.take()
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
        let bad = |what| move |source| AptError::Setting { what, source };
        let p = VelParams {
            chan: u16::from(self.cfg.chan),
            min_velocity: 0,
            acceleration: self.cfg.scale.acceleration_to_device(a).map_err(bad("acceleration"))?,
            max_velocity: self.cfg.scale.velocity_to_device(v).map_err(bad("velocity"))?,
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

    pub(super) fn axis_status(&self, s: &StatusPayload) -> AxisStatus {
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

    pub(super) async fn identify(&mut self) -> Result<DeviceInfo, AptError> {
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
    pub(super) async fn close(mut self) -> Result<T, AptError> {
        let chan = self.cfg.chan;
        self.send(&AptMessage::MotMoveStop { chan, mode: StopMode::Profiled }).await?;
        self.send(&AptMessage::HwStopUpdateMsgs).await?;
        Ok(self.io)
    }
}
