//! `GrblStage`: one GRBL axis as a linear stage (an [`Axis`] in [`Mm`]),
//! over any async byte stream.
//!
//! Protocol rules followed (docs/hardware.md B.2-B.6):
//! * every line is answered by exactly one `ok`/`error:N`, in order; the
//!   driver keeps the byte count of unanswered lines and never lets it exceed
//!   GRBL's 128-byte RX buffer (character counting). Real-time bytes (`?`,
//!   `!`, `~`, 0x18) bypass the buffer and are not counted;
//! * `ok` for a move means "queued", so completion is found by polling `?`
//!   until `Idle` at the target;
//! * stop = feed hold `!`, wait for the hold to complete (position kept),
//!   then soft reset 0x18 to flush the planner, then re-read the position,
//!   then unlock (`$X`) if an alarm left GRBL locked, so the next move (the
//!   back-off of an abort) can go;
//! * timeouts are wall-clock (tokio timers), whatever speed the far end runs at.

use std::collections::VecDeque;
use std::io;
use std::path::Path;
use std::time::Duration;

use async_trait::async_trait;
use thiserror::Error;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;
use tokio_serial::{DataBits, FlowControl, Parity, SerialPortBuilderExt, SerialStream, StopBits};

use super::codec::{
    AlarmCode, AxisValues, Distance, EncodeError, ErrorCode, GrblCommand, LineSplitter, MachineState, ParseError,
    RX_BUFFER_SIZE, Realtime, Response, StatusReport, parse_line_bytes,
};
use crate::motion::{Axis, AxisStatus, DeviceFault, DeviceInfo, FaultKind, Identify, Mm};

/// Errors of the GRBL driver family.
#[derive(Debug, Error)]
pub enum GrblError {
    #[error("GRBL link closed while {during}")]
    Closed { during: &'static str },
    #[error("GRBL link failed while {during}: {source}")]
    Io {
        during: &'static str,
        #[source]
        source: io::Error,
    },
    #[error("GRBL was reset while {during}; the command was discarded")]
    ResetDuring { during: &'static str },
    #[error("no answer from GRBL within {after:?} while {during}")]
    Timeout { during: &'static str, after: Duration },
    #[error("malformed line from GRBL: {0}")]
    Parse(#[from] ParseError),
    #[error("cannot encode command: {0}")]
    Encode(#[from] EncodeError),
    #[error("expected {expected} from GRBL, got {got:?}")]
    Unexpected { expected: &'static str, got: String },
    #[error("GRBL rejected {line:?}: {code}")]
    Rejected { line: String, code: ErrorCode },
    #[error("GRBL alarm: {code}")]
    Alarm { code: AlarmCode },
    #[error("GRBL is in the Alarm state (locked); home ($H) or unlock ($X) first")]
    Locked,
    #[error("target {target_mm} mm is outside the travel {min_mm}..{max_mm} mm; nothing was sent")]
    OutOfTravel { target_mm: f64, min_mm: f64, max_mm: f64 },
    #[error("axis stopped at {position_mm} mm short of the target {target_mm} mm")]
    Stalled { target_mm: f64, position_mm: f64 },
}

impl DeviceFault for GrblError {
    fn kind(&self) -> FaultKind {
        match self {
            Self::Closed { .. } | Self::Io { .. } | Self::ResetDuring { .. } => FaultKind::Disconnected,
            Self::Timeout { .. } => FaultKind::Timeout,
            Self::Parse(_) | Self::Encode(_) | Self::Unexpected { .. } => FaultKind::Protocol,
            Self::Rejected { .. } | Self::Alarm { .. } | Self::Locked | Self::Stalled { .. } => {
                FaultKind::DeviceReported
            }
            Self::OutOfTravel { .. } => FaultKind::Limit,
        }
    }
}

/// Driver settings for one GRBL axis.
#[derive(Debug, Clone, PartialEq)]
pub struct GrblConfig {
    /// Axis letter driven by this stage (`X`..`C`); the rig's micrometer is `Z`.
    pub axis: char,
    /// Soft travel `(min_mm, max_mm)` in machine coordinates; checked before sending.
    pub travel_mm: (f64, f64),
    /// Feed rate of `G1` moves, mm/min.
    pub feed_mm_per_min: f64,
    /// Wall-clock limit for an `ok`/`error` or a status report.
    pub reply_timeout: Duration,
    /// Wall-clock limit for the banner after a soft reset (an Arduino that
    /// resets on port open needs 1-2 s of bootloader first).
    pub banner_timeout: Duration,
    /// Interval of `?` polls while waiting for a move (GRBL: 5-10 Hz on hardware).
    pub poll_interval: Duration,
    /// A move counts as arrived within this distance of its target, mm.
    pub position_tolerance_mm: f64,
    /// Wall-clock limit for a feed hold to decelerate the axis during `stop`.
    pub stop_timeout: Duration,
}

impl Default for GrblConfig {
    fn default() -> Self {
        Self {
            axis: 'Z',
            travel_mm: (0.0, 25.0),
            feed_mm_per_min: 60.0,
            reply_timeout: Duration::from_secs(2),
            banner_timeout: Duration::from_secs(3),
            poll_interval: Duration::from_millis(100),
            position_tolerance_mm: 0.002,
            stop_timeout: Duration::from_secs(5),
        }
    }
}

fn axis_index(axis: char) -> Option<usize> {
    "XYZABC".find(axis.to_ascii_uppercase())
}

/// Consecutive `Idle` reports away from the target before a wait gives up:
/// one report may predate the block's start.
const STALL_REPORTS: u32 = 3;

/// One GRBL axis as a linear stage.
pub struct GrblStage<T> {
    io: T,
    cfg: GrblConfig,
    axis: usize,
    splitter: LineSplitter,
    lines: VecDeque<Result<Vec<u8>, ParseError>>,
    /// (sequence number, bytes) of sent lines not yet answered, oldest first.
    pending: VecDeque<(u64, usize)>,
    next_seq: u64,
    /// Answers that arrived for lines nobody is waiting on yet.
    answered: VecDeque<(u64, Result<(), ErrorCode>)>,
    resets_seen: u64,
    version: Option<String>,
    last_status: Option<StatusReport>,
    wco: Option<AxisValues>,
    last_message: Option<String>,
    alarm: Option<AlarmCode>,
    homed: bool,
    /// End point of the last accepted move, machine mm.
    target: Option<f64>,
}

/// GRBL's line settings (docs/hardware.md B.1): 115200 baud, 8N1, no flow control.
pub const GRBL_BAUD: u32 = 115_200;

/// Open `path` with GRBL's line settings. Opening an Arduino's port toggles
/// DTR, which reboots most boards: [`GrblStage::connect`] waits for the banner.
pub fn open_serial(path: impl AsRef<Path>) -> Result<SerialStream, GrblError> {
    let path = path.as_ref().to_string_lossy().into_owned();
    tokio_serial::new(&path, GRBL_BAUD)
        .data_bits(DataBits::Eight)
        .parity(Parity::None)
        .stop_bits(StopBits::One)
        .flow_control(FlowControl::None)
        .open_native_async()
        .map_err(|e| GrblError::Io { during: "opening the serial port", source: io::Error::from(e) })
}

impl GrblStage<SerialStream> {
    /// Open a real port (or an emulator's pty) and [`connect`](GrblStage::connect).
    pub async fn open(path: impl AsRef<Path>, cfg: GrblConfig) -> Result<Self, GrblError> {
        let io = open_serial(path)?;
        Self::connect(io, cfg).await
    }
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> GrblStage<T> {
    /// Take over a freshly opened link: soft reset, wait for the banner (sent
    /// again once if the first reset was lost in the bootloader), read the
    /// state. Never moves the axis.
    pub async fn connect(io: T, cfg: GrblConfig) -> Result<Self, GrblError> {
        let axis = axis_index(cfg.axis).ok_or(EncodeError::BadAxis(cfg.axis))?;
        let mut stage = Self {
            io,
            cfg,
            axis,
            splitter: LineSplitter::new(),
            lines: VecDeque::new(),
            pending: VecDeque::new(),
            next_seq: 0,
            answered: VecDeque::new(),
            resets_seen: 0,
            version: None,
            last_status: None,
            wco: None,
            last_message: None,
            alarm: None,
            homed: false,
            target: None,
        };
        match stage.soft_reset().await {
            Err(GrblError::Timeout { .. }) => stage.soft_reset().await?,
            other => other?,
        }
        stage.sync().await?;
        Ok(stage)
    }

    pub fn config(&self) -> &GrblConfig {
        &self.cfg
    }
    /// Version from the last banner, e.g. `1.1h`.
    pub fn version(&self) -> Option<&str> {
        self.version.as_deref()
    }
    /// Most recent status report.
    pub fn last_status(&self) -> Option<&StatusReport> {
        self.last_status.as_ref()
    }
    /// Most recent `[MSG:...]`.
    pub fn last_message(&self) -> Option<&str> {
        self.last_message.as_deref()
    }
    /// Alarm raised and not yet cleared by `$H`, `$X` or a reset into a non-alarm state.
    pub fn alarm(&self) -> Option<AlarmCode> {
        self.alarm
    }
    /// Bytes of sent lines not yet answered (always <= 128).
    pub fn unacknowledged_bytes(&self) -> usize {
        self.pending.iter().map(|(_, n)| n).sum()
    }
    /// Give the transport back (e.g. to close it).
    pub fn into_inner(self) -> T {
        self.io
    }

    fn io_err(during: &'static str, e: io::Error) -> GrblError {
        match e.kind() {
            io::ErrorKind::UnexpectedEof | io::ErrorKind::BrokenPipe => GrblError::Closed { during },
            _ => GrblError::Io { during, source: e },
        }
    }

    async fn write_bytes(&mut self, bytes: &[u8], during: &'static str) -> Result<(), GrblError> {
        let deadline = Instant::now() + self.cfg.reply_timeout;
        let write = async {
            self.io.write_all(bytes).await?;
            self.io.flush().await
        };
        match tokio::time::timeout_at(deadline, write).await {
            Ok(r) => r.map_err(|e| Self::io_err(during, e)),
            Err(_) => Err(GrblError::Timeout { during, after: self.cfg.reply_timeout }),
        }
    }

    async fn send_realtime(&mut self, r: Realtime, during: &'static str) -> Result<(), GrblError> {
        self.write_bytes(&[r.byte()], during).await
    }

    /// Read and handle one line. `Ok(None)` when `deadline` passed first.
    async fn next_line(&mut self, deadline: Instant, during: &'static str) -> Result<Option<Response>, GrblError> {
        loop {
            if let Some(line) = self.lines.pop_front() {
                let resp = parse_line_bytes(&line?)?;
                self.absorb(&resp);
                return Ok(Some(resp));
            }
            let mut buf = [0u8; 256];
            match tokio::time::timeout_at(deadline, self.io.read(&mut buf)).await {
                Err(_) => return Ok(None),
                Ok(Ok(0)) => return Err(GrblError::Closed { during }),
                Ok(Ok(n)) => {
                    let mut out = Vec::new();
                    self.splitter.push(&buf[..n], &mut out);
                    self.lines.extend(out);
                }
                Ok(Err(e)) if e.kind() == io::ErrorKind::Interrupted => {}
                Ok(Err(e)) => return Err(Self::io_err(during, e)),
            }
        }
    }

    /// Bookkeeping every line goes through, whoever asked for it.
    fn absorb(&mut self, resp: &Response) {
        match resp {
            Response::Ok | Response::Error(_) => {
                // An answer with nothing pending (left over from before a
                // reset) cannot be matched to a line: drop it.
                if let Some((seq, _)) = self.pending.pop_front() {
                    let result = match resp {
                        Response::Error(code) => Err(*code),
                        _ => Ok(()),
                    };
                    self.answered.push_back((seq, result));
                }
            }
            Response::Alarm(code) => self.alarm = Some(*code),
            Response::Welcome { version } => {
                // A reset empties GRBL's RX buffer and planner: nothing
                // pending will ever be answered.
                self.version = Some(version.clone());
                self.pending.clear();
                self.answered.clear();
                self.resets_seen += 1;
                self.target = None;
            }
            Response::Status(s) => {
                if let Some(w) = s.wco {
                    self.wco = Some(w);
                }
                self.last_status = Some(s.clone());
            }
            Response::Message(m) => self.last_message = Some(m.clone()),
            _ => {}
        }
    }

    /// Send one line under character counting; returns its sequence number.
    async fn send_line(&mut self, cmd: &GrblCommand, during: &'static str) -> Result<u64, GrblError> {
        let line = cmd.encode()?;
        let n = line.len();
        let deadline = Instant::now() + self.cfg.reply_timeout;
        while self.unacknowledged_bytes() + n > RX_BUFFER_SIZE {
            if self.next_line(deadline, during).await?.is_none() {
                return Err(GrblError::Timeout { during, after: self.cfg.reply_timeout });
            }
        }
        let seq = self.next_seq;
        self.next_seq += 1;
        // Count the bytes before writing: GRBL may answer before write returns.
        self.pending.push_back((seq, n));
        if let Err(e) = self.write_bytes(line.as_bytes(), during).await {
            self.pending.retain(|(s, _)| *s != seq);
            return Err(e);
        }
        Ok(seq)
    }

    /// Wait for the answer to line `seq` (within `timeout`), failing early on an alarm or reset.
    async fn wait_answer(
        &mut self,
        seq: u64,
        line: &GrblCommand,
        timeout: Duration,
        during: &'static str,
    ) -> Result<(), GrblError> {
        let deadline = Instant::now() + timeout;
        let resets = self.resets_seen;
        let alarm_before = self.alarm;
        loop {
            // Answers to lines nobody waits for any more are stale.
            self.answered.retain(|(s, _)| *s >= seq);
            if let Some(pos) = self.answered.iter().position(|(s, _)| *s == seq) {
                let (_, result) = self.answered.remove(pos).unwrap_or((seq, Ok(())));
                return result.map_err(|code| GrblError::Rejected {
                    line: line.encode().unwrap_or_default().trim_end().to_string(),
                    code,
                });
            }
            if self.resets_seen != resets {
                return Err(GrblError::ResetDuring { during });
            }
            if let Some(code) = self.alarm
                && alarm_before != Some(code)
            {
                return Err(GrblError::Alarm { code });
            }
            if self.next_line(deadline, during).await?.is_none() {
                return Err(GrblError::Timeout { during, after: timeout });
            }
        }
    }

    async fn command(&mut self, cmd: GrblCommand, timeout: Duration, during: &'static str) -> Result<(), GrblError> {
        let seq = self.send_line(&cmd, during).await?;
        self.wait_answer(seq, &cmd, timeout, during).await
    }

    /// Send `?` and return the next status report.
    pub async fn query_status(&mut self) -> Result<StatusReport, GrblError> {
        const DURING: &str = "waiting for a status report";
        self.send_realtime(Realtime::StatusQuery, DURING).await?;
        let deadline = Instant::now() + self.cfg.reply_timeout;
        let alarm_before = self.alarm;
        loop {
            match self.next_line(deadline, DURING).await? {
                Some(Response::Status(s)) => return Ok(s),
                Some(_) => {
                    // GRBL does not answer `?` in a critical alarm: report the alarm, not a timeout.
                    if let Some(code) = self.alarm
                        && alarm_before != Some(code)
                        && code.is_critical()
                    {
                        return Err(GrblError::Alarm { code });
                    }
                }
                None => {
                    return Err(GrblError::Timeout { during: DURING, after: self.cfg.reply_timeout });
                }
            }
        }
    }

    fn machine_position(&self, s: &StatusReport) -> Result<f64, GrblError> {
        s.machine_position(self.axis, self.wco.as_ref()).ok_or_else(|| GrblError::Unexpected {
            expected: "a position for the configured axis (MPos, or WPos with a known WCO)",
            got: s.to_string(),
        })
    }

    /// Soft reset (0x18) and wait for the banner. Pending lines are discarded by GRBL.
    pub async fn soft_reset(&mut self) -> Result<(), GrblError> {
        const DURING: &str = "waiting for the banner after a soft reset";
        self.send_realtime(Realtime::SoftReset, DURING).await?;
        let deadline = Instant::now() + self.cfg.banner_timeout;
        loop {
            match self.next_line(deadline, DURING).await {
                Ok(Some(Response::Welcome { .. })) => return Ok(()),
                Ok(Some(_)) => {}
                // Garbage before the banner (bootloader noise, a line cut by the reset) is expected.
                Err(GrblError::Parse(_)) => {}
                Err(e) => return Err(e),
                Ok(None) => {
                    return Err(GrblError::Timeout { during: DURING, after: self.cfg.banner_timeout });
                }
            }
        }
    }

    /// Read the state after a reset; clears a remembered alarm once GRBL has left `Alarm`.
    async fn sync(&mut self) -> Result<StatusReport, GrblError> {
        let s = self.query_status().await?;
        if s.state == MachineState::Alarm {
            self.homed = false;
        } else {
            self.alarm = None;
        }
        Ok(s)
    }

    /// Send `!` and poll until the axis has decelerated (`Hold:0`), or was
    /// not moving (`Idle`), or an alarm ended the motion.
    async fn hold_and_wait(&mut self, during: &'static str) -> Result<StatusReport, GrblError> {
        self.send_realtime(Realtime::FeedHold, during).await?;
        let deadline = Instant::now() + self.cfg.stop_timeout;
        loop {
            let s = self.query_status().await?;
            if matches!(s.state, MachineState::Idle | MachineState::Hold(0) | MachineState::Alarm) {
                return Ok(s);
            }
            if Instant::now() >= deadline {
                return Err(GrblError::Timeout { during, after: self.cfg.stop_timeout });
            }
            let wake = Instant::now() + self.cfg.poll_interval.min(Duration::from_millis(20));
            while self.next_line(wake, during).await?.is_some() {}
        }
    }

    /// Feed hold (`!`): decelerate and pause the move under way, keeping the
    /// rest of it queued; returns the report once the axis stands
    /// (`Hold:0`, or `Idle` if nothing was moving). [`Self::resume`]
    /// continues; [`Axis::stop`] discards.
    pub async fn feed_hold(&mut self) -> Result<StatusReport, GrblError> {
        self.check_unlocked()?;
        self.hold_and_wait("holding").await
    }

    /// Cycle start (`~`): continue a held move. GRBL ignores it in any other state.
    pub async fn resume(&mut self) -> Result<(), GrblError> {
        self.check_unlocked()?;
        self.send_realtime(Realtime::CycleStart, "resuming").await
    }

    /// `$X`: leave the alarm lock without homing (position may be wrong).
    pub async fn unlock(&mut self) -> Result<(), GrblError> {
        if self.alarm.is_some_and(AlarmCode::is_critical) {
            self.soft_reset().await?;
        }
        self.command(GrblCommand::Unlock, self.cfg.reply_timeout, "unlocking").await?;
        self.alarm = None;
        Ok(())
    }

    fn check_travel(&self, target_mm: f64) -> Result<(), GrblError> {
        let (min_mm, max_mm) = self.cfg.travel_mm;
        if !target_mm.is_finite() || target_mm < min_mm || target_mm > max_mm {
            return Err(GrblError::OutOfTravel { target_mm, min_mm, max_mm });
        }
        Ok(())
    }

    fn check_unlocked(&self) -> Result<(), GrblError> {
        match self.alarm {
            Some(code) => Err(GrblError::Alarm { code }),
            None => Ok(()),
        }
    }

    async fn start_move(&mut self, target_mm: f64, cmd: GrblCommand) -> Result<(), GrblError> {
        self.command(cmd, self.cfg.reply_timeout, "queueing a move").await?;
        self.target = Some(target_mm);
        Ok(())
    }

    /// Where relative moves start from: the end of the last queued move, else the current position.
    async fn reference_mm(&mut self) -> Result<f64, GrblError> {
        match self.target {
            Some(t) => Ok(t),
            None => {
                let s = self.query_status().await?;
                self.machine_position(&s)
            }
        }
    }

    fn status_of(&self, s: &StatusReport, position: f64) -> AxisStatus {
        let letter = "XYZABC".as_bytes()[self.axis] as char;
        let pin = s.pin(letter);
        // GRBL has one limit input per axis; which end tripped is inferred from the position.
        let (min_mm, max_mm) = self.cfg.travel_mm;
        let near_min = (position - min_mm).abs() <= (position - max_mm).abs();
        AxisStatus {
            position,
            moving: matches!(
                s.state,
                MachineState::Run | MachineState::Jog | MachineState::Home | MachineState::Hold(1)
            ),
            homed: self.homed,
            homing: s.state == MachineState::Home,
            forward_limit: pin && !near_min,
            reverse_limit: pin && near_min,
            enabled: !matches!(s.state, MachineState::Alarm | MachineState::Sleep),
        }
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Axis for GrblStage<T> {
    type Unit = Mm;

    fn travel(&self) -> (Mm, Mm) {
        let (min_mm, max_mm) = self.cfg.travel_mm;
        (Mm(min_mm), Mm(max_mm))
    }

    async fn home(&mut self, timeout: Duration) -> Result<(), GrblError> {
        // A critical alarm ignores everything but a reset.
        if self.alarm.is_some_and(AlarmCode::is_critical) {
            self.soft_reset().await?;
        }
        // `$H`'s `ok` comes only when the cycle ends; GRBL answers no `?` meanwhile.
        self.command(GrblCommand::Home, timeout, "homing").await?;
        self.alarm = None;
        self.homed = true;
        self.target = None;
        self.sync().await?;
        Ok(())
    }

    async fn start_move_to(&mut self, Mm(target_mm): Mm) -> Result<(), GrblError> {
        self.check_travel(target_mm)?;
        self.check_unlocked()?;
        let cmd = GrblCommand::Feed {
            distance: Distance::Absolute,
            axis: self.cfg.axis,
            mm: target_mm,
            feed_mm_min: self.cfg.feed_mm_per_min,
        };
        self.start_move(target_mm, cmd).await
    }

    async fn start_move_by(&mut self, Mm(delta_mm): Mm) -> Result<(), GrblError> {
        self.check_unlocked()?;
        let from = self.reference_mm().await?;
        let target_mm = from + delta_mm;
        self.check_travel(target_mm)?;
        let cmd = GrblCommand::Feed {
            distance: Distance::Incremental,
            axis: self.cfg.axis,
            mm: delta_mm,
            feed_mm_min: self.cfg.feed_mm_per_min,
        };
        self.start_move(target_mm, cmd).await
    }

    /// Polls `?` until `Idle` at the target (within `position_tolerance_mm`);
    /// `Idle` elsewhere for [`STALL_REPORTS`] reports is [`GrblError::Stalled`].
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<Mm, GrblError> {
        const DURING: &str = "waiting for a move to end";
        let deadline = Instant::now() + timeout;
        let mut idle_away = 0;
        loop {
            self.check_unlocked()?;
            let s = self.query_status().await?;
            self.check_unlocked()?;
            let pos = self.machine_position(&s)?;
            match s.state {
                MachineState::Alarm => return Err(GrblError::Locked),
                MachineState::Idle => match self.target {
                    Some(t) if (pos - t).abs() > self.cfg.position_tolerance_mm => {
                        idle_away += 1;
                        if idle_away >= STALL_REPORTS {
                            self.target = None;
                            return Err(GrblError::Stalled { target_mm: t, position_mm: pos });
                        }
                    }
                    _ => {
                        self.target = None;
                        return Ok(Mm(pos));
                    }
                },
                _ => idle_away = 0,
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(GrblError::Timeout { during: DURING, after: timeout });
            }
            // Keep reading between polls so an alarm or a cut link is seen at once.
            let wake = (now + self.cfg.poll_interval).min(deadline);
            while self.next_line(wake, DURING).await?.is_some() {
                self.check_unlocked()?;
            }
        }
    }

    async fn stop(&mut self) -> Result<(), GrblError> {
        const DURING: &str = "stopping";
        if !self.alarm.is_some_and(AlarmCode::is_critical) {
            // Let the hold decelerate the axis: a reset while moving loses position (ALARM:3).
            match self.hold_and_wait(DURING).await {
                Ok(_) | Err(GrblError::Alarm { .. }) => {}
                Err(e) => return Err(e),
            }
        }
        // The reset discards the rest of the held block and anything queued.
        self.soft_reset().await?;
        self.target = None;
        self.sync().await?;
        // An alarm leaves GRBL locked, and the indenter possibly pressed into
        // the elastomer: a stop ends motion in order to move away, so unlock
        // ($X). The position may be off after a limit alarm (the alarm's own
        // error says so); re-home before the next run.
        if self.alarm.is_some() {
            self.unlock().await?;
        }
        Ok(())
    }

    async fn position(&mut self) -> Result<Mm, GrblError> {
        let s = self.query_status().await?;
        self.machine_position(&s).map(Mm)
    }

    async fn status(&mut self) -> Result<AxisStatus, GrblError> {
        let s = self.query_status().await?;
        let p = self.machine_position(&s)?;
        Ok(self.status_of(&s, p))
    }

    /// GRBL takes a move's speed with the move (`G1 ... F<mm/min>`), so this
    /// only changes the feed the next moves are sent with; nothing goes on
    /// the line. GRBL itself caps a feed at the axis's `$11x` max rate. A
    /// speed that is not a positive number is refused, the feed unchanged.
    async fn set_max_speed(&mut self, speed_mm_s: f64) -> Result<Option<f64>, GrblError> {
        let what = "stage top speed (mm/s)";
        if !speed_mm_s.is_finite() {
            return Err(EncodeError::NotFinite { what, value: speed_mm_s }.into());
        }
        if speed_mm_s <= 0.0 {
            return Err(EncodeError::NotPositive { what, value: speed_mm_s }.into());
        }
        let old = self.cfg.feed_mm_per_min / 60.0;
        self.cfg.feed_mm_per_min = speed_mm_s * 60.0;
        Ok(Some(old))
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Identify for GrblStage<T> {
    type Error = GrblError;

    /// `$I`: `[VER:1.1h.20190830:info]`. GRBL has no serial number; the
    /// user-settable build-info string (`$I=...`) stands in for one.
    async fn identify(&mut self) -> Result<DeviceInfo, GrblError> {
        const DURING: &str = "reading build info";
        let seq = self.send_line(&GrblCommand::BuildInfo, DURING).await?;
        let deadline = Instant::now() + self.cfg.reply_timeout;
        let mut ver: Option<(String, String)> = None;
        loop {
            if let Some(pos) = self.answered.iter().position(|(s, _)| *s == seq) {
                let (_, r) = self.answered.remove(pos).unwrap_or((seq, Ok(())));
                r.map_err(|code| GrblError::Rejected { line: "$I".into(), code })?;
                break;
            }
            match self.next_line(deadline, DURING).await? {
                Some(Response::Version { version, info }) => ver = Some((version, info)),
                Some(_) => {}
                None => {
                    return Err(GrblError::Timeout { during: DURING, after: self.cfg.reply_timeout });
                }
            }
        }
        let (firmware, serial) =
            ver.ok_or(GrblError::Unexpected { expected: "[VER:...] before ok", got: "ok".into() })?;
        let short = self.version.clone().unwrap_or_else(|| firmware.split('.').take(2).collect::<Vec<_>>().join("."));
        Ok(DeviceInfo { model: format!("GRBL {short}"), serial, firmware })
    }
}

#[cfg(test)]
#[path = "driver_tests.rs"]
mod tests;
