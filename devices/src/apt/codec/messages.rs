//! The messages of the APT protocol and their payloads, with each payload's
//! byte layout (written and read) next to its fields.

use std::fmt;

use super::status;
use super::wire::{Rd, put_i32, put_str, put_u16, put_u32};

/// Payload of HW_GET_INFO (84 bytes).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HwInfo {
    pub serial: u32,
    /// Model string, at most 8 bytes on the wire (NUL padded).
    pub model: String,
    pub hw_type: u16,
    /// Firmware version `(major, interim, minor)`.
    pub firmware: (u8, u8, u8),
    /// Notes string at offsets 18..66 (48 bytes, NUL padded).
    pub notes: String,
    /// Bytes 66..76 of the 60-byte block whose layout is [U] in the docs.
    pub reserved: [u8; 10],
    /// u16 at payload offset 76, read by pylablib as the stage id (9 Z825, 10 Z812).
    pub stage_id: u16,
    pub hw_version: u16,
    pub mod_state: u16,
    pub n_channels: u16,
}

/// Status payload shared by GET_DCSTATUSUPDATE (0x0491), GET_STATUSUPDATE
/// (0x0481), MOVE_COMPLETED (0x0464) and MOVE_STOPPED (0x0466): 14 bytes,
/// channel u16, position i32, four family-dependent bytes, status bits u32.
/// The middle four bytes are kept raw: a DC servo (KDC101) puts a 16-bit
/// velocity and a reserved/current word there, a stepper (K10CR1) an i32
/// encoder count, and an end-of-move frame does not say which family sent it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusPayload {
    pub chan: u16,
    pub position: i32,
    pub aux: [u8; 4],
    pub status: u32,
}

impl StatusPayload {
    /// DC servo layout: velocity (i16, units [U]) and reserved word.
    pub fn dc(chan: u16, position: i32, velocity: i16, status: u32) -> Self {
        let v = velocity.to_le_bytes();
        Self { chan, position, aux: [v[0], v[1], 0, 0], status }
    }
    /// Stepper layout: encoder count i32.
    pub fn stepper(chan: u16, position: i32, encoder: i32, status: u32) -> Self {
        Self { chan, position, aux: encoder.to_le_bytes(), status }
    }
    pub fn dc_velocity(&self) -> i16 {
        i16::from_le_bytes([self.aux[0], self.aux[1]])
    }
    pub fn stepper_encoder(&self) -> i32 {
        i32::from_le_bytes(self.aux)
    }
    pub fn is_moving(&self) -> bool {
        self.status & status::ANY_MOTION != 0
    }
}

/// VELPARAMS payload (14 bytes), device units (A.6).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VelParams {
    pub chan: u16,
    pub min_velocity: i32,
    pub acceleration: i32,
    pub max_velocity: i32,
}

/// JOGPARAMS payload (22 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JogParams {
    pub chan: u16,
    /// 1 continuous, 2 step.
    pub mode: u16,
    pub step: i32,
    pub min_velocity: i32,
    pub acceleration: i32,
    pub max_velocity: i32,
    /// 1 immediate, 2 profiled.
    pub stop_mode: u16,
}

/// HOMEPARAMS payload (14 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HomeParams {
    pub chan: u16,
    /// 1 forward, 2 reverse.
    pub direction: u16,
    /// 1 reverse/hardware-CCW, 4 forward (per thorlabs_apt_device).
    pub limit_switch: u16,
    pub velocity: i32,
    pub offset: i32,
}

/// LIMSWITCHPARAMS payload (16 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LimSwitchParams {
    pub chan: u16,
    pub cw_hard: u16,
    pub ccw_hard: u16,
    pub cw_soft: u32,
    pub ccw_soft: u32,
    pub soft_mode: u16,
}
/// MOT_MOVE_STOP mode (param2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopMode {
    Immediate,
    Profiled,
}

/// Direction parameter of MOVE_VELOCITY / MOVE_JOG (param2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    Forward,
    Reverse,
}
/// Every APT message the rig uses, both directions.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AptMessage {
    HwDisconnect,
    HwReqInfo,
    HwGetInfo(Box<HwInfo>),
    HwStartUpdateMsgs,
    HwStopUpdateMsgs,
    HwYesFlashProgramming,
    HwNoFlashProgramming,
    /// Short error notification; the two header parameters are passed through.
    HwResponse {
        p1: u8,
        p2: u8,
    },
    /// Error with the id of the message that caused it, a code and a text.
    HwRichResponse {
        msg_id: u16,
        code: u16,
        text: String,
    },
    ModIdentify {
        chan: u8,
    },
    ModSetChanEnableState {
        chan: u8,
        enabled: bool,
    },
    ModReqChanEnableState {
        chan: u8,
    },
    ModGetChanEnableState {
        chan: u8,
        enabled: bool,
    },
    MotSetEncCounter {
        chan: u16,
        count: i32,
    },
    MotReqEncCounter {
        chan: u8,
    },
    MotGetEncCounter {
        chan: u16,
        count: i32,
    },
    MotSetPosCounter {
        chan: u16,
        position: i32,
    },
    MotReqPosCounter {
        chan: u8,
    },
    MotGetPosCounter {
        chan: u16,
        position: i32,
    },
    MotSetVelParams(VelParams),
    MotReqVelParams {
        chan: u8,
    },
    MotGetVelParams(VelParams),
    MotSetJogParams(JogParams),
    MotReqJogParams {
        chan: u8,
    },
    MotGetJogParams(JogParams),
    MotSetLimSwitchParams(LimSwitchParams),
    MotReqLimSwitchParams {
        chan: u8,
    },
    MotGetLimSwitchParams(LimSwitchParams),
    MotReqStatusBits {
        chan: u8,
    },
    MotGetStatusBits {
        chan: u16,
        status: u32,
    },
    MotSetGenMoveParams {
        chan: u16,
        backlash: i32,
    },
    MotReqGenMoveParams {
        chan: u8,
    },
    MotGetGenMoveParams {
        chan: u16,
        backlash: i32,
    },
    MotSetHomeParams(HomeParams),
    MotReqHomeParams {
        chan: u8,
    },
    MotGetHomeParams(HomeParams),
    MotMoveHome {
        chan: u8,
    },
    MotMoveHomed {
        chan: u8,
    },
    MotSetMoveRelParams {
        chan: u16,
        distance: i32,
    },
    MotReqMoveRelParams {
        chan: u8,
    },
    MotGetMoveRelParams {
        chan: u16,
        distance: i32,
    },
    /// Short form (no distance: use the stored MOVERELPARAMS) or long form.
    MotMoveRelative {
        chan: u8,
        distance: Option<i32>,
    },
    MotSetMoveAbsParams {
        chan: u16,
        position: i32,
    },
    MotReqMoveAbsParams {
        chan: u8,
    },
    MotGetMoveAbsParams {
        chan: u16,
        position: i32,
    },
    /// Short form (no position: use the stored MOVEABSPARAMS) or long form.
    MotMoveAbsolute {
        chan: u8,
        position: Option<i32>,
    },
    MotMoveVelocity {
        chan: u8,
        direction: Direction,
    },
    MotMoveJog {
        chan: u8,
        direction: Direction,
    },
    MotMoveCompleted(StatusPayload),
    MotMoveStop {
        chan: u8,
        mode: StopMode,
    },
    MotMoveStopped(StatusPayload),
    MotSuspendEndOfMoveMsgs,
    MotResumeEndOfMoveMsgs,
    MotReqStatusUpdate {
        chan: u8,
    },
    MotGetStatusUpdate(StatusPayload),
    MotReqDcStatusUpdate {
        chan: u8,
    },
    MotGetDcStatusUpdate(StatusPayload),
    MotAckDcStatusUpdate,
}
/// A decoded frame: the message and the header's addresses (destination
/// without the long-frame flag).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    pub message: AptMessage,
    pub dest: u8,
    pub source: u8,
}
impl fmt::Display for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X} {:02X}->{:02X} {:?}", self.message.id(), self.source, self.dest, self.message)
    }
}

impl HwInfo {
    pub(super) fn put(&self, d: &mut Vec<u8>) {
        put_u32(d, self.serial);
        put_str(d, &self.model, 8);
        put_u16(d, self.hw_type);
        let (major, interim, minor) = self.firmware;
        d.extend_from_slice(&[minor, interim, major, 0]);
        put_str(d, &self.notes, 48);
        d.extend_from_slice(&self.reserved);
        put_u16(d, self.stage_id);
        put_u16(d, self.hw_version);
        put_u16(d, self.mod_state);
        put_u16(d, self.n_channels);
    }

    pub(super) fn read(r: &mut Rd<'_>) -> Self {
        let serial = r.u32();
        let model = r.string(8);
        let hw_type = r.u16();
        let minor = r.u8();
        let interim = r.u8();
        let major = r.u8();
        let _unused = r.u8();
        let notes = r.string(48);
        let reserved = r.take::<10>();
        HwInfo {
            serial,
            model,
            hw_type,
            firmware: (major, interim, minor),
            notes,
            reserved,
            stage_id: r.u16(),
            hw_version: r.u16(),
            mod_state: r.u16(),
            n_channels: r.u16(),
        }
    }
}

impl StatusPayload {
    pub(super) fn put(&self, d: &mut Vec<u8>) {
        put_u16(d, self.chan);
        put_i32(d, self.position);
        d.extend_from_slice(&self.aux);
        put_u32(d, self.status);
    }

    pub(super) fn read(r: &mut Rd<'_>) -> Self {
        StatusPayload { chan: r.u16(), position: r.i32(), aux: r.take(), status: r.u32() }
    }
}

impl VelParams {
    pub(super) fn put(&self, d: &mut Vec<u8>) {
        put_u16(d, self.chan);
        put_i32(d, self.min_velocity);
        put_i32(d, self.acceleration);
        put_i32(d, self.max_velocity);
    }

    pub(super) fn read(r: &mut Rd<'_>) -> Self {
        VelParams { chan: r.u16(), min_velocity: r.i32(), acceleration: r.i32(), max_velocity: r.i32() }
    }
}

impl JogParams {
    pub(super) fn put(&self, d: &mut Vec<u8>) {
        put_u16(d, self.chan);
        put_u16(d, self.mode);
        put_i32(d, self.step);
        put_i32(d, self.min_velocity);
        put_i32(d, self.acceleration);
        put_i32(d, self.max_velocity);
        put_u16(d, self.stop_mode);
    }

    pub(super) fn read(r: &mut Rd<'_>) -> Self {
        JogParams {
            chan: r.u16(),
            mode: r.u16(),
            step: r.i32(),
            min_velocity: r.i32(),
            acceleration: r.i32(),
            max_velocity: r.i32(),
            stop_mode: r.u16(),
        }
    }
}

impl HomeParams {
    pub(super) fn put(&self, d: &mut Vec<u8>) {
        put_u16(d, self.chan);
        put_u16(d, self.direction);
        put_u16(d, self.limit_switch);
        put_i32(d, self.velocity);
        put_i32(d, self.offset);
    }

    pub(super) fn read(r: &mut Rd<'_>) -> Self {
        HomeParams { chan: r.u16(), direction: r.u16(), limit_switch: r.u16(), velocity: r.i32(), offset: r.i32() }
    }
}

impl LimSwitchParams {
    pub(super) fn put(&self, d: &mut Vec<u8>) {
        put_u16(d, self.chan);
        put_u16(d, self.cw_hard);
        put_u16(d, self.ccw_hard);
        put_u32(d, self.cw_soft);
        put_u32(d, self.ccw_soft);
        put_u16(d, self.soft_mode);
    }

    pub(super) fn read(r: &mut Rd<'_>) -> Self {
        LimSwitchParams {
            chan: r.u16(),
            cw_hard: r.u16(),
            ccw_hard: r.u16(),
            cw_soft: r.u32(),
            ccw_soft: r.u32(),
            soft_mode: r.u16(),
        }
    }
}
