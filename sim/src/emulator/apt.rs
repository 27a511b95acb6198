//! Emulator of the rig's Thorlabs APT units on pseudo-terminals: a KDC101
//! K-Cube driving a Z8 actuator (the rig's stage axis) and a K10CR1 rotation
//! mount (the rig's rotation axis). It speaks the wire protocol of
//! docs/hardware.md A.2-A.5 byte for byte, using the same codec as the driver, so
//! easycalib's own driver and independent clients (thorlabs_apt_device,
//! pylablib) can both talk to it through the slave tty.
//!
//! Motion runs on the rig's virtual clock (time-accelerated); the protocol
//! side (replies, 10 Hz pushed status updates) runs in wall time, because
//! that is what a client's timeouts are measured in.
//!
//! Checked by hand (not in CI) against two independent clients on the slave
//! tty: thorlabs_apt_device 0.3.8 `KDC101` (polled: home, absolute and
//! relative moves, MOVE_COMPLETED) and `APTDevice_Motor` with
//! `status_updates="auto"` on both units (pushed 0x0491 / 0x0481, keep-alive);
//! pylablib 1.4.5 `KinesisMotor` on both units (identify, stage autodetected
//! as Z825, home, moves), with its RTS toggle disabled because a pty has no
//! modem lines (A.1).
//!
//! Choices that are the emulator's, not documented device behaviour (A.5, A.7):
//! pushed updates pause after `keepalive_limit` unacknowledged ones and
//! resume at the next MOT_ACK_DCSTATUSUPDATE; a move outside the travel is
//! refused with an HW_RICHRESPONSE (code [`ERR_OUT_OF_TRAVEL`]) instead of
//! running into the limit switch; a disabled channel refuses moves likewise
//! (code [`ERR_CHANNEL_DISABLED`]); status direction bits take CW as forward.

use std::io;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use devices::apt::codec::{
    AptDecoder, AptMessage, Direction, HOST, HomeParams, HwInfo, JogParams, LimSwitchParams, StatusPayload, StopMode,
    USB_UNIT, VelParams, encode_into, status,
};
use devices::apt::scaling::{ControllerFamily, Scale};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::time::Instant;

use super::axis::{Axis, AxisConfig};
use super::pty::PtyMaster;
use super::rig::Rig;

/// HW_RICHRESPONSE code the emulator uses for a move outside the travel.
pub const ERR_OUT_OF_TRAVEL: u16 = 0x0101;
/// HW_RICHRESPONSE code for a move while the channel is disabled.
pub const ERR_CHANNEL_DISABLED: u16 = 0x0102;

/// Which axis of the rig a unit drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RigAxis {
    Stage,
    Rotation,
}

/// What one emulated unit is and how it behaves.
#[derive(Debug, Clone, PartialEq)]
pub struct AptEmulatorConfig {
    pub axis: RigAxis,
    /// Counts per user unit and controller family (velocity units, status layout).
    pub scale: Scale,
    pub model: String,
    pub serial: u32,
    /// `(major, interim, minor)`.
    pub firmware: (u8, u8, u8),
    /// Hardware type in HW_GET_INFO; the real values are [U] (A.7), 16 is a placeholder.
    pub hw_type: u16,
    /// Stage id at HW_GET_INFO payload offset 76 (pylablib: 9 Z825, 10 Z812; 0 none).
    pub stage_id: u16,
    /// Period of pushed status updates while HW_START_UPDATEMSGS is on (wall time).
    pub update_period: Duration,
    /// Pushed updates pause after this many without an ACK (`None` = never).
    pub keepalive_limit: Option<u32>,
    /// The home switch sits at the middle of the mechanical travel, not at
    /// the reverse limit: a rotation mount turns both ways from its zero and
    /// finds its switch within one turn.
    pub home_at_center: bool,
}

impl AptEmulatorConfig {
    /// KDC101 + Z8 actuator; the stage id follows the rig's travel (Z812 up to 12 mm, else Z825).
    pub fn kdc101_z8(travel_mm: f64) -> Self {
        Self {
            axis: RigAxis::Stage,
            scale: Scale::kdc101_z8(),
            model: "KDC101".into(),
            serial: 27_000_001,
            firmware: (3, 0, 10),
            hw_type: 16,
            stage_id: if travel_mm <= 12.5 { 10 } else { 9 },
            update_period: Duration::from_millis(100),
            keepalive_limit: Some(50),
            home_at_center: false,
        }
    }

    /// K10CR1 rotation mount.
    pub fn k10cr1() -> Self {
        Self {
            axis: RigAxis::Rotation,
            scale: Scale::k10cr1(),
            model: "K10CR1".into(),
            serial: 55_000_001,
            firmware: (1, 0, 3),
            hw_type: 16,
            stage_id: 0,
            update_period: Duration::from_millis(100),
            keepalive_limit: Some(50),
            home_at_center: true,
        }
    }
}

/// Axis preset for a Z8 actuator (A.7): 2.3 mm/s, 4 mm/s², one encoder count resolution.
pub fn z8_axis(travel_mm: f64) -> AxisConfig {
    AxisConfig {
        max_velocity: 2.3,
        acceleration: 4.0,
        min_position: 0.0,
        max_position: travel_mm,
        resolution: 1.0 / Scale::kdc101_z8().counts_per_unit,
        backlash: 0.0,
        home_velocity: 1.0,
        power_on_position: travel_mm * 0.2,
    }
}

/// The emulated K10CR1 turns one turn either way of its home switch.
const K10CR1_HALF_TRAVEL_DEG: f64 = 360.0;

/// Axis preset for a K10CR1 (A.7): 10 °/s, 20 °/s², homing at 5 °/s. The
/// mount turns freely; ±360° around the counter zero (its home switch, at
/// the middle of the travel) stands in for that. It powers on 5° past the
/// switch ([`k10cr1_axis_at`] for another angle).
pub fn k10cr1_axis() -> AxisConfig {
    k10cr1_axis_at(5.0)
}

/// [`k10cr1_axis`] powered on `deg_past_switch` (taken modulo one turn,
/// into [0, 360)) past its home switch in the homing direction: homing
/// turns that far back at 5 °/s, never more than one turn.
pub fn k10cr1_axis_at(deg_past_switch: f64) -> AxisConfig {
    let past = if deg_past_switch.is_finite() { deg_past_switch.rem_euclid(360.0) } else { 0.0 };
    AxisConfig {
        max_velocity: 10.0,
        acceleration: 20.0,
        min_position: 0.0,
        max_position: 2.0 * K10CR1_HALF_TRAVEL_DEG,
        resolution: 1.0 / Scale::k10cr1().counts_per_unit,
        backlash: 0.0,
        home_velocity: 5.0,
        power_on_position: K10CR1_HALF_TRAVEL_DEG + past,
    }
}

/// A device error the owner makes the unit send.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum InjectedError {
    /// Short HW_RESPONSE with these header parameters.
    Response { p1: u8, p2: u8 },
    /// HW_RICHRESPONSE: the id of the message at fault, a code and a text.
    Rich { msg_id: u16, code: u16, text: String },
}

enum Control {
    Send(AptMessage),
    Cut,
}

/// Owner's handle on a running emulator. Dropping it stops the emulator and
/// closes the pty.
#[derive(Debug)]
pub struct EmulatorHandle {
    path: PathBuf,
    ctl: mpsc::UnboundedSender<Control>,
    log: Arc<Mutex<Vec<u16>>>,
    task: tokio::task::JoinHandle<()>,
}

fn lock_log(log: &Mutex<Vec<u16>>) -> MutexGuard<'_, Vec<u16>> {
    log.lock().unwrap_or_else(|p| p.into_inner())
}

impl EmulatorHandle {
    /// The slave tty a client opens, e.g. `/dev/pts/7`.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Make the unit send a device error now.
    pub fn inject_error(&self, e: InjectedError) {
        let msg = match e {
            InjectedError::Response { p1, p2 } => AptMessage::HwResponse { p1, p2 },
            InjectedError::Rich { msg_id, code, text } => AptMessage::HwRichResponse { msg_id, code, text },
        };
        // A send error means the emulator already stopped: nothing to do.
        let _ = self.ctl.send(Control::Send(msg));
    }

    /// Cut the cable: close the pty; the client's next read sees a hang-up.
    pub fn cut(&self) {
        let _ = self.ctl.send(Control::Cut);
    }

    /// Ids of every message received from the host so far, in order.
    pub fn received(&self) -> Vec<u16> {
        lock_log(&self.log).clone()
    }

    /// Whether the emulator task has ended (cut, or the pty failed).
    pub fn is_finished(&self) -> bool {
        self.task.is_finished()
    }
}

impl Drop for EmulatorHandle {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Emulate a KDC101 + Z8 on the rig's stage axis.
pub fn spawn_apt_stage(rig: Rig) -> io::Result<EmulatorHandle> {
    let travel = rig.with_stage(|ax, _| ax.config().max_position - ax.config().min_position);
    spawn_apt(rig, AptEmulatorConfig::kdc101_z8(travel))
}

/// Emulate a K10CR1 on the rig's rotation axis.
pub fn spawn_apt_rotation(rig: Rig) -> io::Result<EmulatorHandle> {
    spawn_apt(rig, AptEmulatorConfig::k10cr1())
}

/// Open a pty and run an emulated unit on it. Needs a tokio runtime.
pub fn spawn_apt(rig: Rig, cfg: AptEmulatorConfig) -> io::Result<EmulatorHandle> {
    let pty = PtyMaster::open()?;
    let path = pty.slave_path().to_path_buf();
    let (tx, rx) = mpsc::unbounded_channel();
    let log = Arc::new(Mutex::new(Vec::new()));
    let unit = Unit::new(rig, cfg, log.clone());
    let task = tokio::spawn(run(unit, pty, rx));
    Ok(EmulatorHandle { path, ctl: tx, log, task })
}

/// Protocol state of one unit; the motion itself lives in the rig's axis.
struct Unit {
    rig: Rig,
    cfg: AptEmulatorConfig,
    log: Arc<Mutex<Vec<u16>>>,
    enabled: bool,
    updates_on: bool,
    unacked: u32,
    end_of_move_msgs: bool,
    vel: VelParams,
    jog: JogParams,
    home: HomeParams,
    lim: LimSwitchParams,
    backlash_counts: i32,
    rel_distance: i32,
    abs_position: i32,
    /// A stop was commanded: the next end of motion is MOVE_STOPPED.
    stop_requested: bool,
    seen_moves: u64,
    seen_homes: u64,
}

impl Unit {
    fn new(rig: Rig, cfg: AptEmulatorConfig, log: Arc<Mutex<Vec<u16>>>) -> Self {
        let s = cfg.scale;
        let (ax_cfg, moves, homes) = match cfg.axis {
            RigAxis::Stage => rig.with_stage(|ax, _| (*ax.config(), ax.moves_completed(), ax.homes_completed())),
            RigAxis::Rotation => rig.with_rotation(|ax, _| (*ax.config(), ax.moves_completed(), ax.homes_completed())),
        };
        let dv = |v: f64| s.velocity_to_device(v).unwrap_or(i32::MAX);
        let da = |a: f64| s.acceleration_to_device(a).unwrap_or(i32::MAX);
        let dc = |x: f64| s.to_counts(x).unwrap_or(i32::MAX);
        let chan = 1;
        let unit = Self {
            vel: VelParams {
                chan,
                min_velocity: 0,
                acceleration: da(ax_cfg.acceleration),
                max_velocity: dv(ax_cfg.max_velocity),
            },
            jog: JogParams {
                chan,
                mode: 2,
                step: dc(0.1),
                min_velocity: 0,
                acceleration: da(ax_cfg.acceleration),
                max_velocity: dv(ax_cfg.max_velocity),
                stop_mode: 2,
            },
            home: HomeParams { chan, direction: 2, limit_switch: 1, velocity: dv(ax_cfg.home_velocity), offset: 0 },
            lim: LimSwitchParams {
                chan,
                cw_hard: 2,
                ccw_hard: 2,
                cw_soft: dc(ax_cfg.max_position - ax_cfg.min_position).max(0) as u32,
                ccw_soft: 0,
                soft_mode: 1,
            },
            backlash_counts: dc(ax_cfg.backlash),
            rel_distance: 0,
            abs_position: 0,
            rig,
            log,
            enabled: true,
            updates_on: false,
            unacked: 0,
            end_of_move_msgs: true,
            stop_requested: false,
            seen_moves: moves,
            seen_homes: homes,
            cfg,
        };
        if unit.cfg.home_at_center {
            let half = (ax_cfg.max_position - ax_cfg.min_position) / 2.0;
            unit.with_axis(|ax, _| ax.set_home_switch(ax_cfg.min_position + half));
        }
        unit
    }

    fn with_axis<R>(&self, f: impl FnOnce(&mut Axis, f64) -> R) -> R {
        match self.cfg.axis {
            RigAxis::Stage => self.rig.with_stage(f),
            RigAxis::Rotation => self.rig.with_rotation(f),
        }
    }

    fn counts(&self, x: f64) -> i32 {
        let c = (x * self.cfg.scale.counts_per_unit).round();
        c.clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }

    fn units(&self, counts: i32) -> f64 {
        self.cfg.scale.from_counts(counts)
    }

    /// Status bits and payload of the axis as it is now.
    fn status_payload(&self) -> StatusPayload {
        let enabled = self.enabled;
        let (pos, vel, bits) = self.with_axis(|ax, _| {
            let mut b = status::MOTOR_CONNECTED;
            if enabled {
                b |= status::ENABLED;
            }
            if ax.is_homed() {
                b |= status::HOMED;
            }
            if ax.is_homing() {
                b |= status::HOMING;
            }
            if ax.is_moving() {
                b |= status::ACTIVE;
                if ax.velocity() > 0.0 {
                    b |= status::MOVING_CW;
                } else if ax.velocity() < 0.0 {
                    b |= status::MOVING_CCW;
                }
            }
            if ax.at_forward_limit() {
                b |= status::CW_HW_LIMIT;
            }
            if ax.at_reverse_limit() {
                b |= status::CCW_HW_LIMIT;
            }
            (ax.position(), ax.velocity(), b)
        });
        let p = self.counts(pos);
        match self.cfg.scale.family {
            ControllerFamily::DcServo => StatusPayload::dc(1, p, self.cfg.scale.status_velocity(vel), bits),
            // The K10CR1 has no encoder; what it reports there is [U] (A.3): 0.
            ControllerFamily::Stepper => StatusPayload::stepper(1, p, 0, bits),
        }
    }

    /// The periodic/requested status message in this controller's own layout.
    fn status_update(&self) -> AptMessage {
        match self.cfg.scale.family {
            ControllerFamily::DcServo => AptMessage::MotGetDcStatusUpdate(self.status_payload()),
            ControllerFamily::Stepper => AptMessage::MotGetStatusUpdate(self.status_payload()),
        }
    }

    fn hw_info(&self) -> HwInfo {
        HwInfo {
            serial: self.cfg.serial,
            model: self.cfg.model.clone(),
            hw_type: self.cfg.hw_type,
            firmware: self.cfg.firmware,
            notes: format!("easycalib emulated {}", self.cfg.model),
            reserved: [0; 10],
            stage_id: self.cfg.stage_id,
            hw_version: 1,
            mod_state: 0,
            n_channels: 1,
        }
    }

    fn refuse(&self, msg_id: u16, code: u16, text: &str) -> AptMessage {
        AptMessage::HwRichResponse { msg_id, code, text: text.into() }
    }

    /// Start an absolute move in counts; an error message if refused.
    fn move_to_counts(&mut self, msg_id: u16, target: i32, out: &mut Vec<AptMessage>) {
        if !self.enabled {
            out.push(self.refuse(msg_id, ERR_CHANNEL_DISABLED, "channel disabled"));
            return;
        }
        let x = self.units(target);
        if self.with_axis(|ax, t| ax.command_move_to(t, x)) {
            self.stop_requested = false;
        } else {
            out.push(self.refuse(msg_id, ERR_OUT_OF_TRAVEL, "move outside travel"));
        }
    }

    fn current_counts(&self) -> i32 {
        let p = self.with_axis(|ax, _| ax.position());
        self.counts(p)
    }

    /// Answer one message from the host; replies go to `out`.
    fn handle(&mut self, msg: AptMessage, out: &mut Vec<AptMessage>) {
        use AptMessage as M;
        lock_log(&self.log).push(msg.id());
        let scale = self.cfg.scale;
        match msg {
            M::HwReqInfo => out.push(M::HwGetInfo(Box::new(self.hw_info()))),
            M::HwStartUpdateMsgs => {
                self.updates_on = true;
                self.unacked = 0;
            }
            M::HwStopUpdateMsgs | M::HwDisconnect => self.updates_on = false,
            M::MotAckDcStatusUpdate => self.unacked = 0,
            M::ModSetChanEnableState { enabled, .. } => {
                self.enabled = enabled;
                if !enabled {
                    self.with_axis(|ax, t| ax.command_stop(t, true));
                }
            }
            M::ModReqChanEnableState { chan } => out.push(M::ModGetChanEnableState { chan, enabled: self.enabled }),
            M::MotReqPosCounter { chan } => {
                out.push(M::MotGetPosCounter { chan: u16::from(chan), position: self.current_counts() })
            }
            M::MotSetPosCounter { position, .. } => {
                let x = self.units(position);
                self.with_axis(|ax, _| ax.set_position_counter(x));
            }
            // Z8 and K10CR1 count on the motor side only: the encoder counter is the position.
            M::MotReqEncCounter { chan } => {
                out.push(M::MotGetEncCounter { chan: u16::from(chan), count: self.current_counts() })
            }
            M::MotSetEncCounter { count, .. } => {
                let x = self.units(count);
                self.with_axis(|ax, _| ax.set_position_counter(x));
            }
            M::MotSetVelParams(p) => {
                let v = scale.velocity_from_device(p.max_velocity);
                let a = scale.acceleration_from_device(p.acceleration);
                self.with_axis(|ax, _| ax.set_motion_params(v, a));
                self.vel = VelParams { chan: 1, ..p };
            }
            M::MotReqVelParams { .. } => out.push(M::MotGetVelParams(self.vel)),
            M::MotSetJogParams(p) => self.jog = JogParams { chan: 1, ..p },
            M::MotReqJogParams { .. } => out.push(M::MotGetJogParams(self.jog)),
            M::MotSetLimSwitchParams(p) => self.lim = LimSwitchParams { chan: 1, ..p },
            M::MotReqLimSwitchParams { .. } => out.push(M::MotGetLimSwitchParams(self.lim)),
            M::MotSetHomeParams(p) => {
                // The next homing runs at the velocity set (within the motor's limit).
                let v = scale.velocity_from_device(p.velocity);
                self.with_axis(|ax, _| ax.set_home_velocity(v));
                self.home = HomeParams { chan: 1, ..p };
            }
            M::MotReqHomeParams { .. } => out.push(M::MotGetHomeParams(self.home)),
            M::MotSetGenMoveParams { backlash, .. } => self.backlash_counts = backlash,
            M::MotReqGenMoveParams { .. } => {
                out.push(M::MotGetGenMoveParams { chan: 1, backlash: self.backlash_counts })
            }
            M::MotSetMoveRelParams { distance, .. } => self.rel_distance = distance,
            M::MotReqMoveRelParams { .. } => out.push(M::MotGetMoveRelParams { chan: 1, distance: self.rel_distance }),
            M::MotSetMoveAbsParams { position, .. } => self.abs_position = position,
            M::MotReqMoveAbsParams { .. } => out.push(M::MotGetMoveAbsParams { chan: 1, position: self.abs_position }),
            M::MotReqStatusBits { chan } => {
                out.push(M::MotGetStatusBits { chan: u16::from(chan), status: self.status_payload().status })
            }
            M::MotReqDcStatusUpdate { .. } => out.push(M::MotGetDcStatusUpdate(self.status_payload())),
            M::MotReqStatusUpdate { .. } => out.push(M::MotGetStatusUpdate(self.status_payload())),
            M::MotMoveHome { .. } => {
                if self.enabled {
                    self.stop_requested = false;
                    self.with_axis(|ax, t| ax.command_home(t));
                } else {
                    out.push(self.refuse(msg.id(), ERR_CHANNEL_DISABLED, "channel disabled"));
                }
            }
            M::MotMoveAbsolute { position, .. } => {
                let target = position.unwrap_or(self.abs_position);
                self.move_to_counts(msg.id(), target, out);
            }
            M::MotMoveRelative { distance, .. } => {
                let d = distance.unwrap_or(self.rel_distance);
                let target = self.current_counts().saturating_add(d);
                self.move_to_counts(msg.id(), target, out);
            }
            M::MotMoveJog { direction, .. } => {
                let step = self.jog.step.saturating_abs();
                let d = if direction == Direction::Forward { step } else { -step };
                let target = self.current_counts().saturating_add(d);
                self.move_to_counts(msg.id(), target, out);
            }
            M::MotMoveVelocity { direction, .. } => {
                // Run to the end of the travel (the limit switch) in that direction.
                let (lo, hi) = self.with_axis(|ax, _| ax.travel());
                let end = if direction == Direction::Forward { hi } else { lo };
                let target = self.counts(end);
                self.move_to_counts(msg.id(), target, out);
            }
            M::MotMoveStop { mode, .. } => {
                let moving = self.with_axis(|ax, t| {
                    let m = ax.is_moving();
                    ax.command_stop(t, mode == StopMode::Immediate);
                    m
                });
                if moving {
                    self.stop_requested = true;
                } else if self.end_of_move_msgs {
                    // Nothing was moving: answer at once so a client waiting for it returns.
                    out.push(M::MotMoveStopped(self.status_payload()));
                }
            }
            M::MotSuspendEndOfMoveMsgs => self.end_of_move_msgs = false,
            M::MotResumeEndOfMoveMsgs => self.end_of_move_msgs = true,
            // No reply defined: flash programming, identify (LED), and
            // device-to-host messages a confused client might echo back.
            _ => {}
        }
    }

    /// End-of-move messages for motions the axis finished since last time.
    fn poll_motion(&mut self, out: &mut Vec<AptMessage>) {
        let (moves, homes) = self.with_axis(|ax, _| (ax.moves_completed(), ax.homes_completed()));
        if homes != self.seen_homes {
            self.seen_homes = homes;
            if self.end_of_move_msgs {
                out.push(AptMessage::MotMoveHomed { chan: 1 });
            }
        }
        if moves != self.seen_moves {
            self.seen_moves = moves;
            let s = self.status_payload();
            let stopped = std::mem::take(&mut self.stop_requested);
            if self.end_of_move_msgs {
                out.push(if stopped { AptMessage::MotMoveStopped(s) } else { AptMessage::MotMoveCompleted(s) });
            }
        }
    }

    fn is_moving(&self) -> bool {
        self.with_axis(|ax, _| ax.is_moving())
    }

    /// Next pushed status update, if one is due under the keep-alive rule.
    fn push_update(&mut self) -> Option<AptMessage> {
        if !self.updates_on {
            return None;
        }
        if let Some(limit) = self.cfg.keepalive_limit
            && self.unacked >= limit
        {
            return None;
        }
        self.unacked = self.unacked.saturating_add(1);
        Some(self.status_update())
    }
}

/// How often the emulator looks at a moving axis for its end (wall time).
const MOTION_TICK: Duration = Duration::from_millis(2);
/// How often it looks when nothing moves (a stop from the owner side, homing started elsewhere).
const IDLE_TICK: Duration = Duration::from_millis(20);

async fn run(mut unit: Unit, mut pty: PtyMaster, mut ctl: mpsc::UnboundedReceiver<Control>) {
    let mut dec = AptDecoder::for_unit();
    let mut buf = vec![0u8; 1024];
    let mut out_msgs = Vec::new();
    let mut wire = Vec::with_capacity(256);
    let mut next_push = Instant::now() + unit.cfg.update_period;
    loop {
        let tick = if unit.is_moving() { MOTION_TICK } else { IDLE_TICK };
        let wake = next_push.min(Instant::now() + tick);
        tokio::select! {
            r = pty.read(&mut buf) => match r {
                // EOF/EIO cannot happen while we hold the slave open; if it does, the pty is gone.
                Ok(0) | Err(_) => return,
                Ok(n) => {
                    dec.feed(&buf[..n]);
                    while let Some(f) = dec.next_frame() {
                        // Garbage and foreign frames are skipped, as a unit does.
                        if let Ok(frame) = f {
                            unit.handle(frame.message, &mut out_msgs);
                        }
                    }
                }
            },
            c = ctl.recv() => match c {
                Some(Control::Send(m)) => out_msgs.push(m),
                // Cut, or the handle is gone: dropping the pty hangs up the client.
                Some(Control::Cut) | None => return,
            },
            _ = tokio::time::sleep_until(wake) => {}
        }
        unit.poll_motion(&mut out_msgs);
        if Instant::now() >= next_push {
            // Measured from now, not from the previous slot: the period
            // stretches by the processing time as a unit's does. A client
            // that reads with a timeout equal to the period
            // (thorlabs_apt_device: 0.1 s) otherwise never sees its read
            // time out and starves its own writes.
            next_push = Instant::now() + unit.cfg.update_period;
            if let Some(m) = unit.push_update() {
                out_msgs.push(m);
            }
        }
        if out_msgs.is_empty() {
            continue;
        }
        wire.clear();
        for m in out_msgs.drain(..) {
            encode_into(&m, HOST, USB_UNIT, &mut wire);
        }
        if pty.write_all(&wire).await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::VirtualClock;
    use devices::apt::codec::{Addressing, decode_frame, encode};

    fn unit(axis: RigAxis) -> Unit {
        let rig = Rig::new(VirtualClock::new(1000.0), z8_axis(25.0), k10cr1_axis());
        let cfg = match axis {
            RigAxis::Stage => AptEmulatorConfig::kdc101_z8(25.0),
            RigAxis::Rotation => AptEmulatorConfig::k10cr1(),
        };
        Unit::new(rig, cfg, Arc::new(Mutex::new(Vec::new())))
    }

    fn reply_bytes(u: &mut Unit, msg: AptMessage) -> Vec<u8> {
        let mut out = Vec::new();
        u.handle(msg, &mut out);
        let mut wire = Vec::new();
        for m in &out {
            encode_into(m, HOST, USB_UNIT, &mut wire);
        }
        wire
    }

    #[test]
    fn identify_reply_has_documented_header_and_model() {
        let mut u = unit(RigAxis::Stage);
        let b = reply_bytes(&mut u, AptMessage::HwReqInfo);
        assert_eq!(&b[..6], &[0x06, 0x00, 0x54, 0x00, 0x81, 0x50]);
        assert_eq!(b.len(), 6 + 84);
        assert_eq!(&b[6 + 4..6 + 12], b"KDC101\0\0");
        assert_eq!(u32::from_le_bytes(b[6..10].try_into().unwrap()), 27_000_001);
        // pylablib's stage detection: Z825 for a 25 mm rig.
        assert_eq!(u16::from_le_bytes([b[6 + 76], b[6 + 77]]), 9);
    }

    #[test]
    fn every_request_an_open_source_client_sends_gets_its_documented_reply() {
        // (request, expected reply id) per A.3, as thorlabs_apt_device and pylablib send them.
        let cases = [
            (AptMessage::HwReqInfo, Some(0x0006)),
            (AptMessage::MotReqVelParams { chan: 1 }, Some(0x0415)),
            (AptMessage::MotReqGenMoveParams { chan: 1 }, Some(0x043C)),
            (AptMessage::MotReqJogParams { chan: 1 }, Some(0x0418)),
            (AptMessage::MotReqHomeParams { chan: 1 }, Some(0x0442)),
            (AptMessage::MotReqLimSwitchParams { chan: 1 }, Some(0x0425)),
            (AptMessage::ModReqChanEnableState { chan: 1 }, Some(0x0212)),
            (AptMessage::MotReqStatusBits { chan: 1 }, Some(0x042A)),
            (AptMessage::MotReqPosCounter { chan: 1 }, Some(0x0412)),
            (AptMessage::MotReqEncCounter { chan: 1 }, Some(0x040B)),
            (AptMessage::MotReqDcStatusUpdate { chan: 1 }, Some(0x0491)),
            (AptMessage::MotReqStatusUpdate { chan: 1 }, Some(0x0481)),
            (AptMessage::MotReqMoveRelParams { chan: 1 }, Some(0x0447)),
            (AptMessage::MotReqMoveAbsParams { chan: 1 }, Some(0x0452)),
            (AptMessage::HwNoFlashProgramming, None),
            (AptMessage::HwStopUpdateMsgs, None),
            (AptMessage::HwStartUpdateMsgs, None),
            (AptMessage::MotAckDcStatusUpdate, None),
            (AptMessage::ModIdentify { chan: 1 }, None),
            (AptMessage::ModSetChanEnableState { chan: 1, enabled: true }, None),
        ];
        let mut u = unit(RigAxis::Stage);
        for (req, want) in cases {
            // Through the bytes a client sends, as the emulator's decoder sees them.
            let wire = encode(&req, USB_UNIT, HOST);
            let (frame, _) = decode_frame(&wire, &Addressing::unit()).unwrap();
            let b = reply_bytes(&mut u, frame.message);
            match want {
                None => assert!(b.is_empty(), "{req:?} got {b:02X?}"),
                Some(id) => {
                    let (f, n) = decode_frame(&b, &Addressing::host()).unwrap();
                    assert_eq!(n, b.len());
                    assert_eq!(f.message.id(), id, "{req:?}");
                    assert_eq!((f.dest, f.source), (HOST, USB_UNIT));
                }
            }
        }
    }

    #[test]
    fn status_bits_at_power_up_and_after_enable() {
        let mut u = unit(RigAxis::Stage);
        let s = u.status_payload();
        assert_eq!(s.status & status::HOMED, 0);
        assert_ne!(s.status & status::MOTOR_CONNECTED, 0);
        assert_ne!(s.status & status::ENABLED, 0);
        // 5 mm power-on position of the 25 mm preset, in Z8 counts.
        assert_eq!(s.position, 172_775);
        u.handle(AptMessage::ModSetChanEnableState { chan: 1, enabled: false }, &mut Vec::new());
        assert_eq!(u.status_payload().status & status::ENABLED, 0);
        let mut out = Vec::new();
        u.handle(AptMessage::MotMoveAbsolute { chan: 1, position: Some(1000) }, &mut out);
        assert!(matches!(out[0], AptMessage::HwRichResponse { code: ERR_CHANNEL_DISABLED, .. }));
    }

    #[test]
    fn keepalive_rule_pauses_pushed_updates_until_ack() {
        let mut u = unit(RigAxis::Rotation);
        assert!(u.push_update().is_none(), "updates are off at power-up");
        u.handle(AptMessage::HwStartUpdateMsgs, &mut Vec::new());
        for _ in 0..50 {
            assert!(matches!(u.push_update(), Some(AptMessage::MotGetStatusUpdate(_))));
        }
        assert!(u.push_update().is_none());
        u.handle(AptMessage::MotAckDcStatusUpdate, &mut Vec::new());
        assert!(u.push_update().is_some());
    }

    #[test]
    fn stop_when_idle_answers_move_stopped_and_rich_error_for_out_of_travel() {
        let mut u = unit(RigAxis::Stage);
        let mut out = Vec::new();
        u.handle(AptMessage::MotMoveStop { chan: 1, mode: StopMode::Profiled }, &mut out);
        assert!(matches!(out[0], AptMessage::MotMoveStopped(_)));
        out.clear();
        u.handle(AptMessage::MotMoveAbsolute { chan: 1, position: Some(2_000_000) }, &mut out);
        assert!(matches!(out[0], AptMessage::HwRichResponse { msg_id: 0x0453, code: ERR_OUT_OF_TRAVEL, .. }));
        assert!(!u.is_moving());
    }
}
