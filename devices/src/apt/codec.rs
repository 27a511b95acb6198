//! Pure codec for the Thorlabs APT wire protocol (hardware.md A.2/A.3): bytes
//! in, messages out and back, with no I/O. Every frame has a 6-byte header;
//! bit 7 of byte 4 marks a "long" frame whose header carries a data length
//! and is followed by that many bytes. All multi-byte fields are little-endian.

use std::fmt;

/// Address of the host PC.
pub const HOST: u8 = 0x01;
/// Address of a generic single-channel USB unit (KDC101, K10CR1).
pub const USB_UNIT: u8 = 0x50;
/// Rack controller / motherboard of a bay system.
pub const RACK: u8 = 0x11;
/// Bit 7 of header byte 4: a data packet follows.
const LONG_FLAG: u8 = 0x80;
/// The protocol states no data packet exceeds 255 bytes; anything longer is
/// treated as corruption (what thorlabs_apt_device does).
pub const MAX_DATA_LEN: usize = 255;
pub const HEADER_LEN: usize = 6;

/// Message ids (hardware.md A.3).
pub mod id {
    pub const HW_DISCONNECT: u16 = 0x0002;
    pub const HW_REQ_INFO: u16 = 0x0005;
    pub const HW_GET_INFO: u16 = 0x0006;
    pub const HW_START_UPDATEMSGS: u16 = 0x0011;
    pub const HW_STOP_UPDATEMSGS: u16 = 0x0012;
    pub const HW_YES_FLASH_PROGRAMMING: u16 = 0x0017;
    pub const HW_NO_FLASH_PROGRAMMING: u16 = 0x0018;
    pub const HW_RESPONSE: u16 = 0x0080;
    pub const HW_RICHRESPONSE: u16 = 0x0081;
    pub const MOD_SET_CHANENABLESTATE: u16 = 0x0210;
    pub const MOD_REQ_CHANENABLESTATE: u16 = 0x0211;
    pub const MOD_GET_CHANENABLESTATE: u16 = 0x0212;
    pub const MOD_IDENTIFY: u16 = 0x0223;
    pub const MOT_SET_ENCCOUNTER: u16 = 0x0409;
    pub const MOT_REQ_ENCCOUNTER: u16 = 0x040A;
    pub const MOT_GET_ENCCOUNTER: u16 = 0x040B;
    pub const MOT_SET_POSCOUNTER: u16 = 0x0410;
    pub const MOT_REQ_POSCOUNTER: u16 = 0x0411;
    pub const MOT_GET_POSCOUNTER: u16 = 0x0412;
    pub const MOT_SET_VELPARAMS: u16 = 0x0413;
    pub const MOT_REQ_VELPARAMS: u16 = 0x0414;
    pub const MOT_GET_VELPARAMS: u16 = 0x0415;
    pub const MOT_SET_JOGPARAMS: u16 = 0x0416;
    pub const MOT_REQ_JOGPARAMS: u16 = 0x0417;
    pub const MOT_GET_JOGPARAMS: u16 = 0x0418;
    pub const MOT_SET_LIMSWITCHPARAMS: u16 = 0x0423;
    pub const MOT_REQ_LIMSWITCHPARAMS: u16 = 0x0424;
    pub const MOT_GET_LIMSWITCHPARAMS: u16 = 0x0425;
    pub const MOT_REQ_STATUSBITS: u16 = 0x0429;
    pub const MOT_GET_STATUSBITS: u16 = 0x042A;
    pub const MOT_SET_GENMOVEPARAMS: u16 = 0x043A;
    pub const MOT_REQ_GENMOVEPARAMS: u16 = 0x043B;
    pub const MOT_GET_GENMOVEPARAMS: u16 = 0x043C;
    pub const MOT_SET_HOMEPARAMS: u16 = 0x0440;
    pub const MOT_REQ_HOMEPARAMS: u16 = 0x0441;
    pub const MOT_GET_HOMEPARAMS: u16 = 0x0442;
    pub const MOT_MOVE_HOME: u16 = 0x0443;
    pub const MOT_MOVE_HOMED: u16 = 0x0444;
    pub const MOT_SET_MOVERELPARAMS: u16 = 0x0445;
    pub const MOT_REQ_MOVERELPARAMS: u16 = 0x0446;
    pub const MOT_GET_MOVERELPARAMS: u16 = 0x0447;
    pub const MOT_MOVE_RELATIVE: u16 = 0x0448;
    pub const MOT_SET_MOVEABSPARAMS: u16 = 0x0450;
    pub const MOT_REQ_MOVEABSPARAMS: u16 = 0x0451;
    pub const MOT_GET_MOVEABSPARAMS: u16 = 0x0452;
    pub const MOT_MOVE_ABSOLUTE: u16 = 0x0453;
    pub const MOT_MOVE_VELOCITY: u16 = 0x0457;
    pub const MOT_MOVE_COMPLETED: u16 = 0x0464;
    pub const MOT_MOVE_STOP: u16 = 0x0465;
    pub const MOT_MOVE_STOPPED: u16 = 0x0466;
    pub const MOT_MOVE_JOG: u16 = 0x046A;
    pub const MOT_SUSPEND_ENDOFMOVEMSGS: u16 = 0x046B;
    pub const MOT_RESUME_ENDOFMOVEMSGS: u16 = 0x046C;
    pub const MOT_REQ_STATUSUPDATE: u16 = 0x0480;
    pub const MOT_GET_STATUSUPDATE: u16 = 0x0481;
    pub const MOT_REQ_DCSTATUSUPDATE: u16 = 0x0490;
    pub const MOT_GET_DCSTATUSUPDATE: u16 = 0x0491;
    pub const MOT_ACK_DCSTATUSUPDATE: u16 = 0x0492;
}

/// Status bits (hardware.md A.4), named as in the protocol document.
pub mod status {
    pub const CW_HW_LIMIT: u32 = 0x0000_0001;
    pub const CCW_HW_LIMIT: u32 = 0x0000_0002;
    pub const CW_SW_LIMIT: u32 = 0x0000_0004;
    pub const CCW_SW_LIMIT: u32 = 0x0000_0008;
    pub const MOVING_CW: u32 = 0x0000_0010;
    pub const MOVING_CCW: u32 = 0x0000_0020;
    pub const JOGGING_CW: u32 = 0x0000_0040;
    pub const JOGGING_CCW: u32 = 0x0000_0080;
    pub const MOTOR_CONNECTED: u32 = 0x0000_0100;
    pub const HOMING: u32 = 0x0000_0200;
    pub const HOMED: u32 = 0x0000_0400;
    pub const INITIALISING: u32 = 0x0000_0800;
    pub const TRACKING: u32 = 0x0000_1000;
    pub const SETTLED: u32 = 0x0000_2000;
    pub const MOTION_ERROR: u32 = 0x0000_4000;
    pub const INSTRUMENT_ERROR: u32 = 0x0000_8000;
    pub const INTERLOCK: u32 = 0x0001_0000;
    pub const OVERTEMP: u32 = 0x0002_0000;
    pub const POWER_OK: u32 = 0x1000_0000;
    pub const ACTIVE: u32 = 0x2000_0000;
    pub const ERROR: u32 = 0x4000_0000;
    pub const ENABLED: u32 = 0x8000_0000;
    /// Any of these means the axis is in motion. Direction bits disagree
    /// between sources (A.4), so motion is judged from all of them together.
    pub const ANY_MOTION: u32 = MOVING_CW | MOVING_CCW | JOGGING_CW | JOGGING_CCW | HOMING | ACTIVE;
    pub const ANY_LIMIT: u32 = CW_HW_LIMIT | CCW_HW_LIMIT | CW_SW_LIMIT | CCW_SW_LIMIT;
}

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

/// Why bytes could not be decoded. Offsets are into the slice given to
/// [`decode_frame`] (the decoder's buffer start for [`AptDecoder`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    #[error("truncated APT frame: need {needed} bytes, have {available}")]
    TruncatedFrame { needed: usize, available: usize },
    #[error("unknown APT message id 0x{id:04X}")]
    UnknownMessageId { id: u16 },
    #[error("bad APT header {header:02X?}: {reason}")]
    BadHeader { header: [u8; HEADER_LEN], reason: &'static str },
    #[error("APT frame 0x{id:04X} addressed to 0x{dest:02X}, expected one of {expected:02X?}")]
    BadDestination { id: u16, dest: u8, expected: Vec<u8> },
    #[error("APT message 0x{id:04X}: expected {expected}, got {got}")]
    LengthMismatch { id: u16, expected: &'static str, got: &'static str },
}

impl CodecError {
    /// The raw bytes involved, where the error knows them.
    pub fn header_bytes(&self) -> Option<[u8; HEADER_LEN]> {
        match self {
            CodecError::BadHeader { header, .. } => Some(*header),
            _ => None,
        }
    }
}

fn chan8(p1: u8) -> u8 {
    p1
}

fn dir_byte(d: Direction) -> u8 {
    match d {
        Direction::Forward => 1,
        Direction::Reverse => 2,
    }
}

fn put_u16(out: &mut Vec<u8>, v: u16) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_i32(out: &mut Vec<u8>, v: i32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn put_str(out: &mut Vec<u8>, s: &str, width: usize) {
    let bytes = s.as_bytes();
    let n = bytes.len().min(width);
    out.extend_from_slice(&bytes[..n]);
    out.resize(out.len() + (width - n), 0);
}

fn put_status(out: &mut Vec<u8>, s: &StatusPayload) {
    put_u16(out, s.chan);
    put_i32(out, s.position);
    out.extend_from_slice(&s.aux);
    put_u32(out, s.status);
}

/// Body of a message: header parameters or a data packet.
enum Body {
    Short(u8, u8),
    Long(Vec<u8>),
}

fn chan_i32(chan: u16, v: i32) -> Body {
    let mut d = Vec::with_capacity(6);
    put_u16(&mut d, chan);
    put_i32(&mut d, v);
    Body::Long(d)
}

impl AptMessage {
    /// The message id on the wire.
    pub fn id(&self) -> u16 {
        use AptMessage as M;
        match self {
            M::HwDisconnect => id::HW_DISCONNECT,
            M::HwReqInfo => id::HW_REQ_INFO,
            M::HwGetInfo(_) => id::HW_GET_INFO,
            M::HwStartUpdateMsgs => id::HW_START_UPDATEMSGS,
            M::HwStopUpdateMsgs => id::HW_STOP_UPDATEMSGS,
            M::HwYesFlashProgramming => id::HW_YES_FLASH_PROGRAMMING,
            M::HwNoFlashProgramming => id::HW_NO_FLASH_PROGRAMMING,
            M::HwResponse { .. } => id::HW_RESPONSE,
            M::HwRichResponse { .. } => id::HW_RICHRESPONSE,
            M::ModIdentify { .. } => id::MOD_IDENTIFY,
            M::ModSetChanEnableState { .. } => id::MOD_SET_CHANENABLESTATE,
            M::ModReqChanEnableState { .. } => id::MOD_REQ_CHANENABLESTATE,
            M::ModGetChanEnableState { .. } => id::MOD_GET_CHANENABLESTATE,
            M::MotSetEncCounter { .. } => id::MOT_SET_ENCCOUNTER,
            M::MotReqEncCounter { .. } => id::MOT_REQ_ENCCOUNTER,
            M::MotGetEncCounter { .. } => id::MOT_GET_ENCCOUNTER,
            M::MotSetPosCounter { .. } => id::MOT_SET_POSCOUNTER,
            M::MotReqPosCounter { .. } => id::MOT_REQ_POSCOUNTER,
            M::MotGetPosCounter { .. } => id::MOT_GET_POSCOUNTER,
            M::MotSetVelParams(_) => id::MOT_SET_VELPARAMS,
            M::MotReqVelParams { .. } => id::MOT_REQ_VELPARAMS,
            M::MotGetVelParams(_) => id::MOT_GET_VELPARAMS,
            M::MotSetJogParams(_) => id::MOT_SET_JOGPARAMS,
            M::MotReqJogParams { .. } => id::MOT_REQ_JOGPARAMS,
            M::MotGetJogParams(_) => id::MOT_GET_JOGPARAMS,
            M::MotSetLimSwitchParams(_) => id::MOT_SET_LIMSWITCHPARAMS,
            M::MotReqLimSwitchParams { .. } => id::MOT_REQ_LIMSWITCHPARAMS,
            M::MotGetLimSwitchParams(_) => id::MOT_GET_LIMSWITCHPARAMS,
            M::MotReqStatusBits { .. } => id::MOT_REQ_STATUSBITS,
            M::MotGetStatusBits { .. } => id::MOT_GET_STATUSBITS,
            M::MotSetGenMoveParams { .. } => id::MOT_SET_GENMOVEPARAMS,
            M::MotReqGenMoveParams { .. } => id::MOT_REQ_GENMOVEPARAMS,
            M::MotGetGenMoveParams { .. } => id::MOT_GET_GENMOVEPARAMS,
            M::MotSetHomeParams(_) => id::MOT_SET_HOMEPARAMS,
            M::MotReqHomeParams { .. } => id::MOT_REQ_HOMEPARAMS,
            M::MotGetHomeParams(_) => id::MOT_GET_HOMEPARAMS,
            M::MotMoveHome { .. } => id::MOT_MOVE_HOME,
            M::MotMoveHomed { .. } => id::MOT_MOVE_HOMED,
            M::MotSetMoveRelParams { .. } => id::MOT_SET_MOVERELPARAMS,
            M::MotReqMoveRelParams { .. } => id::MOT_REQ_MOVERELPARAMS,
            M::MotGetMoveRelParams { .. } => id::MOT_GET_MOVERELPARAMS,
            M::MotMoveRelative { .. } => id::MOT_MOVE_RELATIVE,
            M::MotSetMoveAbsParams { .. } => id::MOT_SET_MOVEABSPARAMS,
            M::MotReqMoveAbsParams { .. } => id::MOT_REQ_MOVEABSPARAMS,
            M::MotGetMoveAbsParams { .. } => id::MOT_GET_MOVEABSPARAMS,
            M::MotMoveAbsolute { .. } => id::MOT_MOVE_ABSOLUTE,
            M::MotMoveVelocity { .. } => id::MOT_MOVE_VELOCITY,
            M::MotMoveJog { .. } => id::MOT_MOVE_JOG,
            M::MotMoveCompleted(_) => id::MOT_MOVE_COMPLETED,
            M::MotMoveStop { .. } => id::MOT_MOVE_STOP,
            M::MotMoveStopped(_) => id::MOT_MOVE_STOPPED,
            M::MotSuspendEndOfMoveMsgs => id::MOT_SUSPEND_ENDOFMOVEMSGS,
            M::MotResumeEndOfMoveMsgs => id::MOT_RESUME_ENDOFMOVEMSGS,
            M::MotReqStatusUpdate { .. } => id::MOT_REQ_STATUSUPDATE,
            M::MotGetStatusUpdate(_) => id::MOT_GET_STATUSUPDATE,
            M::MotReqDcStatusUpdate { .. } => id::MOT_REQ_DCSTATUSUPDATE,
            M::MotGetDcStatusUpdate(_) => id::MOT_GET_DCSTATUSUPDATE,
            M::MotAckDcStatusUpdate => id::MOT_ACK_DCSTATUSUPDATE,
        }
    }

    fn body(&self) -> Body {
        use AptMessage as M;
        match self {
            M::HwDisconnect
            | M::HwReqInfo
            | M::HwStartUpdateMsgs
            | M::HwStopUpdateMsgs
            | M::HwYesFlashProgramming
            | M::HwNoFlashProgramming
            | M::MotSuspendEndOfMoveMsgs
            | M::MotResumeEndOfMoveMsgs
            | M::MotAckDcStatusUpdate => Body::Short(0, 0),
            M::HwResponse { p1, p2 } => Body::Short(*p1, *p2),
            M::HwGetInfo(info) => {
                let mut d = Vec::with_capacity(84);
                put_u32(&mut d, info.serial);
                put_str(&mut d, &info.model, 8);
                put_u16(&mut d, info.hw_type);
                let (major, interim, minor) = info.firmware;
                d.extend_from_slice(&[minor, interim, major, 0]);
                put_str(&mut d, &info.notes, 48);
                d.extend_from_slice(&info.reserved);
                put_u16(&mut d, info.stage_id);
                put_u16(&mut d, info.hw_version);
                put_u16(&mut d, info.mod_state);
                put_u16(&mut d, info.n_channels);
                Body::Long(d)
            }
            M::HwRichResponse { msg_id, code, text } => {
                let mut d = Vec::with_capacity(68);
                put_u16(&mut d, *msg_id);
                put_u16(&mut d, *code);
                put_str(&mut d, text, 64);
                Body::Long(d)
            }
            M::ModIdentify { chan }
            | M::ModReqChanEnableState { chan }
            | M::MotReqEncCounter { chan }
            | M::MotReqPosCounter { chan }
            | M::MotReqVelParams { chan }
            | M::MotReqJogParams { chan }
            | M::MotReqLimSwitchParams { chan }
            | M::MotReqStatusBits { chan }
            | M::MotReqGenMoveParams { chan }
            | M::MotReqHomeParams { chan }
            | M::MotMoveHome { chan }
            | M::MotMoveHomed { chan }
            | M::MotReqMoveRelParams { chan }
            | M::MotReqMoveAbsParams { chan }
            | M::MotReqStatusUpdate { chan }
            | M::MotReqDcStatusUpdate { chan } => Body::Short(*chan, 0),
            M::ModSetChanEnableState { chan, enabled } | M::ModGetChanEnableState { chan, enabled } => {
                Body::Short(*chan, if *enabled { 1 } else { 2 })
            }
            M::MotSetEncCounter { chan, count } | M::MotGetEncCounter { chan, count } => chan_i32(*chan, *count),
            M::MotSetPosCounter { chan, position }
            | M::MotGetPosCounter { chan, position }
            | M::MotSetMoveAbsParams { chan, position }
            | M::MotGetMoveAbsParams { chan, position } => chan_i32(*chan, *position),
            M::MotSetGenMoveParams { chan, backlash } | M::MotGetGenMoveParams { chan, backlash } => {
                chan_i32(*chan, *backlash)
            }
            M::MotSetMoveRelParams { chan, distance } | M::MotGetMoveRelParams { chan, distance } => {
                chan_i32(*chan, *distance)
            }
            M::MotSetVelParams(p) | M::MotGetVelParams(p) => {
                let mut d = Vec::with_capacity(14);
                put_u16(&mut d, p.chan);
                put_i32(&mut d, p.min_velocity);
                put_i32(&mut d, p.acceleration);
                put_i32(&mut d, p.max_velocity);
                Body::Long(d)
            }
            M::MotSetJogParams(p) | M::MotGetJogParams(p) => {
                let mut d = Vec::with_capacity(22);
                put_u16(&mut d, p.chan);
                put_u16(&mut d, p.mode);
                put_i32(&mut d, p.step);
                put_i32(&mut d, p.min_velocity);
                put_i32(&mut d, p.acceleration);
                put_i32(&mut d, p.max_velocity);
                put_u16(&mut d, p.stop_mode);
                Body::Long(d)
            }
            M::MotSetLimSwitchParams(p) | M::MotGetLimSwitchParams(p) => {
                let mut d = Vec::with_capacity(16);
                put_u16(&mut d, p.chan);
                put_u16(&mut d, p.cw_hard);
                put_u16(&mut d, p.ccw_hard);
                put_u32(&mut d, p.cw_soft);
                put_u32(&mut d, p.ccw_soft);
                put_u16(&mut d, p.soft_mode);
                Body::Long(d)
            }
            M::MotGetStatusBits { chan, status } => {
                let mut d = Vec::with_capacity(6);
                put_u16(&mut d, *chan);
                put_u32(&mut d, *status);
                Body::Long(d)
            }
            M::MotSetHomeParams(p) | M::MotGetHomeParams(p) => {
                let mut d = Vec::with_capacity(14);
                put_u16(&mut d, p.chan);
                put_u16(&mut d, p.direction);
                put_u16(&mut d, p.limit_switch);
                put_i32(&mut d, p.velocity);
                put_i32(&mut d, p.offset);
                Body::Long(d)
            }
            M::MotMoveRelative { chan, distance: v } | M::MotMoveAbsolute { chan, position: v } => match v {
                None => Body::Short(*chan, 0),
                Some(v) => chan_i32(u16::from(*chan), *v),
            },
            M::MotMoveVelocity { chan, direction } | M::MotMoveJog { chan, direction } => {
                Body::Short(*chan, dir_byte(*direction))
            }
            M::MotMoveStop { chan, mode } => Body::Short(
                *chan,
                match mode {
                    StopMode::Immediate => 1,
                    StopMode::Profiled => 2,
                },
            ),
            M::MotMoveCompleted(s) | M::MotMoveStopped(s) | M::MotGetStatusUpdate(s) | M::MotGetDcStatusUpdate(s) => {
                let mut d = Vec::with_capacity(14);
                put_status(&mut d, s);
                Body::Long(d)
            }
        }
    }
}

/// Encode one message addressed to `dest` from `source`, appending to `out`.
pub fn encode_into(msg: &AptMessage, dest: u8, source: u8, out: &mut Vec<u8>) {
    let id = msg.id().to_le_bytes();
    match msg.body() {
        Body::Short(p1, p2) => out.extend_from_slice(&[id[0], id[1], p1, p2, dest & !LONG_FLAG, source]),
        Body::Long(data) => {
            // Every long payload defined here is at most 84 bytes.
            let len = (data.len() as u16).to_le_bytes();
            out.extend_from_slice(&[id[0], id[1], len[0], len[1], dest | LONG_FLAG, source]);
            out.extend_from_slice(&data);
        }
    }
}

/// Encode one message addressed to `dest` from `source`.
pub fn encode(msg: &AptMessage, dest: u8, source: u8) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + 16);
    encode_into(msg, dest, source, &mut out);
    out
}

/// Expected wire form of a message id.
#[derive(Clone, Copy)]
enum Form {
    Short,
    Long(usize),
    /// Either short or long with this many bytes (MOVE_ABSOLUTE / MOVE_RELATIVE).
    Either(usize),
}

fn form_of(id: u16) -> Option<Form> {
    use Form::*;
    use id::*;
    Some(match id {
        HW_DISCONNECT
        | HW_REQ_INFO
        | HW_START_UPDATEMSGS
        | HW_STOP_UPDATEMSGS
        | HW_YES_FLASH_PROGRAMMING
        | HW_NO_FLASH_PROGRAMMING
        | HW_RESPONSE => Short,
        HW_GET_INFO => Long(84),
        HW_RICHRESPONSE => Long(68),
        MOD_IDENTIFY | MOD_SET_CHANENABLESTATE | MOD_REQ_CHANENABLESTATE | MOD_GET_CHANENABLESTATE => Short,
        MOT_SET_ENCCOUNTER
        | MOT_GET_ENCCOUNTER
        | MOT_SET_POSCOUNTER
        | MOT_GET_POSCOUNTER
        | MOT_GET_STATUSBITS
        | MOT_SET_GENMOVEPARAMS
        | MOT_GET_GENMOVEPARAMS
        | MOT_SET_MOVERELPARAMS
        | MOT_GET_MOVERELPARAMS
        | MOT_SET_MOVEABSPARAMS
        | MOT_GET_MOVEABSPARAMS => Long(6),
        MOT_REQ_ENCCOUNTER
        | MOT_REQ_POSCOUNTER
        | MOT_REQ_VELPARAMS
        | MOT_REQ_JOGPARAMS
        | MOT_REQ_LIMSWITCHPARAMS
        | MOT_REQ_STATUSBITS
        | MOT_REQ_GENMOVEPARAMS
        | MOT_REQ_HOMEPARAMS
        | MOT_MOVE_HOME
        | MOT_MOVE_HOMED
        | MOT_REQ_MOVERELPARAMS
        | MOT_REQ_MOVEABSPARAMS
        | MOT_MOVE_VELOCITY
        | MOT_MOVE_JOG
        | MOT_MOVE_STOP
        | MOT_SUSPEND_ENDOFMOVEMSGS
        | MOT_RESUME_ENDOFMOVEMSGS
        | MOT_REQ_STATUSUPDATE
        | MOT_REQ_DCSTATUSUPDATE
        | MOT_ACK_DCSTATUSUPDATE => Short,
        MOT_SET_VELPARAMS | MOT_GET_VELPARAMS | MOT_SET_HOMEPARAMS | MOT_GET_HOMEPARAMS => Long(14),
        MOT_SET_JOGPARAMS | MOT_GET_JOGPARAMS => Long(22),
        MOT_SET_LIMSWITCHPARAMS | MOT_GET_LIMSWITCHPARAMS => Long(16),
        MOT_MOVE_RELATIVE | MOT_MOVE_ABSOLUTE => Either(6),
        MOT_MOVE_COMPLETED | MOT_MOVE_STOPPED | MOT_GET_STATUSUPDATE | MOT_GET_DCSTATUSUPDATE => Long(14),
        _ => return None,
    })
}

fn form_name(f: Form) -> &'static str {
    match f {
        Form::Short => "a short (header-only) frame",
        Form::Long(6) | Form::Either(6) => "a 6-byte data packet",
        Form::Long(14) => "a 14-byte data packet",
        Form::Long(16) => "a 16-byte data packet",
        Form::Long(22) => "a 22-byte data packet",
        Form::Long(68) => "a 68-byte data packet",
        Form::Long(84) => "an 84-byte data packet",
        Form::Long(_) | Form::Either(_) => "a data packet of another length",
    }
}

fn got_name(len: Option<usize>) -> &'static str {
    match len {
        None => "a short frame",
        Some(0) => "an empty data packet",
        Some(n) if n < 6 => "a data packet under 6 bytes",
        Some(n) if n < 14 => "a data packet of 6-13 bytes",
        Some(n) if n < 84 => "a data packet of 14-83 bytes",
        Some(_) => "a data packet of 84 bytes or more",
    }
}

/// Little-endian reader over a data packet whose length was already checked.
struct Rd<'a> {
    d: &'a [u8],
    at: usize,
}

impl Rd<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        if let Some(src) = self.d.get(self.at..self.at + N) {
            out.copy_from_slice(src);
        }
        self.at += N;
        out
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take())
    }
    fn string(&mut self, width: usize) -> String {
        let end = (self.at + width).min(self.d.len());
        let raw = self.d.get(self.at..end).unwrap_or(&[]);
        self.at += width;
        let cut = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
        String::from_utf8_lossy(&raw[..cut]).into_owned()
    }
    fn status(&mut self) -> StatusPayload {
        StatusPayload { chan: self.u16(), position: self.i32(), aux: self.take(), status: self.u32() }
    }
}

fn parse_body(id: u16, p1: u8, p2: u8, data: Option<&[u8]>) -> Result<AptMessage, CodecError> {
    use AptMessage as M;
    use id::*;
    let mut r = Rd { d: data.unwrap_or(&[]), at: 0 };
    let chan = chan8(p1);
    let dir = if p2 == 2 { Direction::Reverse } else { Direction::Forward };
    Ok(match id {
        HW_DISCONNECT => M::HwDisconnect,
        HW_REQ_INFO => M::HwReqInfo,
        HW_START_UPDATEMSGS => M::HwStartUpdateMsgs,
        HW_STOP_UPDATEMSGS => M::HwStopUpdateMsgs,
        HW_YES_FLASH_PROGRAMMING => M::HwYesFlashProgramming,
        HW_NO_FLASH_PROGRAMMING => M::HwNoFlashProgramming,
        HW_RESPONSE => M::HwResponse { p1, p2 },
        HW_GET_INFO => {
            let serial = r.u32();
            let model = r.string(8);
            let hw_type = r.u16();
            let minor = r.u8();
            let interim = r.u8();
            let major = r.u8();
            let _unused = r.u8();
            let notes = r.string(48);
            let reserved = r.take::<10>();
            M::HwGetInfo(Box::new(HwInfo {
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
            }))
        }
        HW_RICHRESPONSE => M::HwRichResponse { msg_id: r.u16(), code: r.u16(), text: r.string(64) },
        MOD_IDENTIFY => M::ModIdentify { chan },
        MOD_SET_CHANENABLESTATE => M::ModSetChanEnableState { chan, enabled: p2 == 1 },
        MOD_REQ_CHANENABLESTATE => M::ModReqChanEnableState { chan },
        MOD_GET_CHANENABLESTATE => M::ModGetChanEnableState { chan, enabled: p2 == 1 },
        MOT_SET_ENCCOUNTER => M::MotSetEncCounter { chan: r.u16(), count: r.i32() },
        MOT_REQ_ENCCOUNTER => M::MotReqEncCounter { chan },
        MOT_GET_ENCCOUNTER => M::MotGetEncCounter { chan: r.u16(), count: r.i32() },
        MOT_SET_POSCOUNTER => M::MotSetPosCounter { chan: r.u16(), position: r.i32() },
        MOT_REQ_POSCOUNTER => M::MotReqPosCounter { chan },
        MOT_GET_POSCOUNTER => M::MotGetPosCounter { chan: r.u16(), position: r.i32() },
        MOT_SET_VELPARAMS | MOT_GET_VELPARAMS => {
            let p = VelParams { chan: r.u16(), min_velocity: r.i32(), acceleration: r.i32(), max_velocity: r.i32() };
            if id == MOT_SET_VELPARAMS { M::MotSetVelParams(p) } else { M::MotGetVelParams(p) }
        }
        MOT_REQ_VELPARAMS => M::MotReqVelParams { chan },
        MOT_SET_JOGPARAMS | MOT_GET_JOGPARAMS => {
            let p = JogParams {
                chan: r.u16(),
                mode: r.u16(),
                step: r.i32(),
                min_velocity: r.i32(),
                acceleration: r.i32(),
                max_velocity: r.i32(),
                stop_mode: r.u16(),
            };
            if id == MOT_SET_JOGPARAMS { M::MotSetJogParams(p) } else { M::MotGetJogParams(p) }
        }
        MOT_REQ_JOGPARAMS => M::MotReqJogParams { chan },
        MOT_SET_LIMSWITCHPARAMS | MOT_GET_LIMSWITCHPARAMS => {
            let p = LimSwitchParams {
                chan: r.u16(),
                cw_hard: r.u16(),
                ccw_hard: r.u16(),
                cw_soft: r.u32(),
                ccw_soft: r.u32(),
                soft_mode: r.u16(),
            };
            if id == MOT_SET_LIMSWITCHPARAMS { M::MotSetLimSwitchParams(p) } else { M::MotGetLimSwitchParams(p) }
        }
        MOT_REQ_LIMSWITCHPARAMS => M::MotReqLimSwitchParams { chan },
        MOT_REQ_STATUSBITS => M::MotReqStatusBits { chan },
        MOT_GET_STATUSBITS => M::MotGetStatusBits { chan: r.u16(), status: r.u32() },
        MOT_SET_GENMOVEPARAMS => M::MotSetGenMoveParams { chan: r.u16(), backlash: r.i32() },
        MOT_REQ_GENMOVEPARAMS => M::MotReqGenMoveParams { chan },
        MOT_GET_GENMOVEPARAMS => M::MotGetGenMoveParams { chan: r.u16(), backlash: r.i32() },
        MOT_SET_HOMEPARAMS | MOT_GET_HOMEPARAMS => {
            let p = HomeParams {
                chan: r.u16(),
                direction: r.u16(),
                limit_switch: r.u16(),
                velocity: r.i32(),
                offset: r.i32(),
            };
            if id == MOT_SET_HOMEPARAMS { M::MotSetHomeParams(p) } else { M::MotGetHomeParams(p) }
        }
        MOT_REQ_HOMEPARAMS => M::MotReqHomeParams { chan },
        MOT_MOVE_HOME => M::MotMoveHome { chan },
        MOT_MOVE_HOMED => M::MotMoveHomed { chan },
        MOT_SET_MOVERELPARAMS => M::MotSetMoveRelParams { chan: r.u16(), distance: r.i32() },
        MOT_REQ_MOVERELPARAMS => M::MotReqMoveRelParams { chan },
        MOT_GET_MOVERELPARAMS => M::MotGetMoveRelParams { chan: r.u16(), distance: r.i32() },
        MOT_MOVE_RELATIVE | MOT_MOVE_ABSOLUTE => {
            let (chan, value) = match data {
                None => (chan, None),
                // Channel numbers of these units fit a byte; a long frame
                // carries it as a word, keep the low byte.
                Some(_) => (r.u16() as u8, Some(r.i32())),
            };
            if id == MOT_MOVE_RELATIVE {
                M::MotMoveRelative { chan, distance: value }
            } else {
                M::MotMoveAbsolute { chan, position: value }
            }
        }
        MOT_SET_MOVEABSPARAMS => M::MotSetMoveAbsParams { chan: r.u16(), position: r.i32() },
        MOT_REQ_MOVEABSPARAMS => M::MotReqMoveAbsParams { chan },
        MOT_GET_MOVEABSPARAMS => M::MotGetMoveAbsParams { chan: r.u16(), position: r.i32() },
        MOT_MOVE_VELOCITY => M::MotMoveVelocity { chan, direction: dir },
        MOT_MOVE_JOG => M::MotMoveJog { chan, direction: dir },
        MOT_MOVE_COMPLETED => M::MotMoveCompleted(r.status()),
        MOT_MOVE_STOP => M::MotMoveStop { chan, mode: if p2 == 1 { StopMode::Immediate } else { StopMode::Profiled } },
        MOT_MOVE_STOPPED => M::MotMoveStopped(r.status()),
        MOT_SUSPEND_ENDOFMOVEMSGS => M::MotSuspendEndOfMoveMsgs,
        MOT_RESUME_ENDOFMOVEMSGS => M::MotResumeEndOfMoveMsgs,
        MOT_REQ_STATUSUPDATE => M::MotReqStatusUpdate { chan },
        MOT_GET_STATUSUPDATE => M::MotGetStatusUpdate(r.status()),
        MOT_REQ_DCSTATUSUPDATE => M::MotReqDcStatusUpdate { chan },
        MOT_GET_DCSTATUSUPDATE => M::MotGetDcStatusUpdate(r.status()),
        MOT_ACK_DCSTATUSUPDATE => M::MotAckDcStatusUpdate,
        // form_of() and this match must list the same ids; if they ever
        // drift apart the frame is reported, not silently mistranslated.
        _ => return Err(CodecError::UnknownMessageId { id }),
    })
}

/// Addresses a decoder accepts: frames for anyone else are errors.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Addressing {
    pub accept_dest: Vec<u8>,
}

impl Addressing {
    /// What a host accepts: replies to 0x01 (and 0x00, which some devices use).
    pub fn host() -> Self {
        Self { accept_dest: vec![0x00, HOST] }
    }
    /// What a single-channel USB unit accepts.
    pub fn unit() -> Self {
        Self { accept_dest: vec![USB_UNIT] }
    }
}

fn known_source(s: u8) -> bool {
    matches!(s, 0x00 | HOST | RACK | 0x21..=0x2A | USB_UNIT)
}

/// Decode the frame at the start of `bytes`. Returns the frame and the number
/// of bytes it used; `TruncatedFrame` when more bytes are needed.
pub fn decode_frame(bytes: &[u8], addr: &Addressing) -> Result<(Frame, usize), CodecError> {
    if bytes.len() < HEADER_LEN {
        return Err(CodecError::TruncatedFrame { needed: HEADER_LEN, available: bytes.len() });
    }
    let mut header = [0u8; HEADER_LEN];
    header.copy_from_slice(&bytes[..HEADER_LEN]);
    let id = u16::from_le_bytes([header[0], header[1]]);
    let long = header[4] & LONG_FLAG != 0;
    let dest = header[4] & !LONG_FLAG;
    let source = header[5];
    let data_len = if long {
        let n = u16::from_le_bytes([header[2], header[3]]) as usize;
        if n > MAX_DATA_LEN {
            return Err(CodecError::BadHeader { header, reason: "data length over 255 bytes" });
        }
        Some(n)
    } else {
        None
    };
    if !known_source(source) {
        return Err(CodecError::BadHeader { header, reason: "unknown source address" });
    }
    let Some(form) = form_of(id) else {
        return Err(CodecError::UnknownMessageId { id });
    };
    if !addr.accept_dest.contains(&dest) {
        return Err(CodecError::BadDestination { id, dest, expected: addr.accept_dest.clone() });
    }
    let ok = match (form, data_len) {
        (Form::Short, None) => true,
        (Form::Long(n), Some(m)) => n == m,
        (Form::Either(_), None) => true,
        (Form::Either(n), Some(m)) => n == m,
        _ => false,
    };
    if !ok {
        return Err(CodecError::LengthMismatch { id, expected: form_name(form), got: got_name(data_len) });
    }
    let total = HEADER_LEN + data_len.unwrap_or(0);
    if bytes.len() < total {
        return Err(CodecError::TruncatedFrame { needed: total, available: bytes.len() });
    }
    let data = data_len.map(|_| &bytes[HEADER_LEN..total]);
    let message = parse_body(id, header[2], header[3], data)?;
    Ok((Frame { message, dest, source }, total))
}

/// Streaming decoder: feed bytes as they arrive, take frames out. On a bad
/// header (unknown id, implausible length, foreign address, wrong length for
/// the id) it reports the error once and drops one byte, so it finds the next
/// frame boundary again.
#[derive(Debug, Clone)]
pub struct AptDecoder {
    buf: Vec<u8>,
    start: usize,
    addr: Addressing,
    /// Total bytes discarded while resynchronising.
    dropped: u64,
    /// Up to 16 bytes starting at the last rejected frame start, for error reports.
    last_bad: Vec<u8>,
}

impl AptDecoder {
    pub fn new(addr: Addressing) -> Self {
        Self { buf: Vec::with_capacity(512), start: 0, addr, dropped: 0, last_bad: Vec::new() }
    }

    pub fn for_host() -> Self {
        Self::new(Addressing::host())
    }

    pub fn for_unit() -> Self {
        Self::new(Addressing::unit())
    }

    pub fn feed(&mut self, bytes: &[u8]) {
        if self.start > 0 && self.start >= self.buf.len() / 2 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Next frame, `None` when more bytes are needed, or the error that made
    /// the decoder drop a byte.
    pub fn next_frame(&mut self) -> Option<Result<Frame, CodecError>> {
        let pending = &self.buf[self.start..];
        match decode_frame(pending, &self.addr) {
            Ok((frame, used)) => {
                self.start += used;
                Some(Ok(frame))
            }
            Err(CodecError::TruncatedFrame { .. }) => None,
            Err(e) => {
                let end = (self.start + 16).min(self.buf.len());
                self.last_bad.clear();
                self.last_bad.extend_from_slice(&self.buf[self.start..end]);
                self.start += 1;
                self.dropped += 1;
                Some(Err(e))
            }
        }
    }

    /// Bytes held that do not yet form a complete frame.
    pub fn pending(&self) -> &[u8] {
        &self.buf[self.start..]
    }

    /// At end of stream: an error if a partial frame is left over.
    pub fn finish(&self) -> Result<(), CodecError> {
        let p = self.pending();
        if p.is_empty() {
            return Ok(());
        }
        match decode_frame(p, &self.addr) {
            Err(e) => Err(e),
            // Not reachable after next_frame() returned None; report as truncated anyway.
            Ok(_) => Err(CodecError::TruncatedFrame { needed: p.len() + 1, available: p.len() }),
        }
    }

    pub fn dropped_bytes(&self) -> u64 {
        self.dropped
    }

    /// The bytes (up to 16) at which the last error was found, first byte
    /// being the one that was dropped.
    pub fn last_bad_bytes(&self) -> &[u8] {
        &self.last_bad
    }
}

impl fmt::Display for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:04X} {:02X}->{:02X} {:?}", self.message.id(), self.source, self.dest, self.message)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace().map(|b| u8::from_str_radix(b, 16).unwrap()).collect()
    }

    fn info() -> HwInfo {
        HwInfo {
            serial: 27000001,
            model: "KDC101".into(),
            hw_type: 16,
            firmware: (3, 0, 10),
            notes: "Z825B emulated".into(),
            reserved: [0; 10],
            stage_id: 9,
            hw_version: 1,
            mod_state: 0,
            n_channels: 1,
        }
    }

    /// One sample of every message variant.
    fn samples() -> Vec<AptMessage> {
        use AptMessage as M;
        let vel = VelParams { chan: 1, min_velocity: 0, acceleration: 1055, max_velocity: 1_777_857 };
        let jog = JogParams {
            chan: 1,
            mode: 2,
            step: 3455,
            min_velocity: 0,
            acceleration: 1055,
            max_velocity: 1_000_000,
            stop_mode: 2,
        };
        let home = HomeParams { chan: 1, direction: 2, limit_switch: 1, velocity: 772_981, offset: 34_555 };
        let lim = LimSwitchParams { chan: 1, cw_hard: 2, ccw_hard: 2, cw_soft: 863_874, ccw_soft: 0, soft_mode: 1 };
        let st = StatusPayload::dc(1, 42641, -27, 0x8000_0500);
        let sst = StatusPayload::stepper(1, -136_533, 7, 0x8000_0410);
        vec![
            M::HwDisconnect,
            M::HwReqInfo,
            M::HwGetInfo(Box::new(info())),
            M::HwStartUpdateMsgs,
            M::HwStopUpdateMsgs,
            M::HwYesFlashProgramming,
            M::HwNoFlashProgramming,
            M::HwResponse { p1: 3, p2: 7 },
            M::HwRichResponse { msg_id: 0x0453, code: 40, text: "position outside travel".into() },
            M::ModIdentify { chan: 1 },
            M::ModSetChanEnableState { chan: 1, enabled: true },
            M::ModSetChanEnableState { chan: 1, enabled: false },
            M::ModReqChanEnableState { chan: 1 },
            M::ModGetChanEnableState { chan: 1, enabled: true },
            M::MotSetEncCounter { chan: 1, count: -5 },
            M::MotReqEncCounter { chan: 1 },
            M::MotGetEncCounter { chan: 1, count: 99 },
            M::MotSetPosCounter { chan: 1, position: 0 },
            M::MotReqPosCounter { chan: 1 },
            M::MotGetPosCounter { chan: 1, position: -42641 },
            M::MotSetVelParams(vel),
            M::MotReqVelParams { chan: 1 },
            M::MotGetVelParams(vel),
            M::MotSetJogParams(jog),
            M::MotReqJogParams { chan: 1 },
            M::MotGetJogParams(jog),
            M::MotSetLimSwitchParams(lim),
            M::MotReqLimSwitchParams { chan: 1 },
            M::MotGetLimSwitchParams(lim),
            M::MotReqStatusBits { chan: 1 },
            M::MotGetStatusBits { chan: 1, status: 0x8000_0410 },
            M::MotSetGenMoveParams { chan: 1, backlash: 35 },
            M::MotReqGenMoveParams { chan: 1 },
            M::MotGetGenMoveParams { chan: 1, backlash: 35 },
            M::MotSetHomeParams(home),
            M::MotReqHomeParams { chan: 1 },
            M::MotGetHomeParams(home),
            M::MotMoveHome { chan: 1 },
            M::MotMoveHomed { chan: 1 },
            M::MotSetMoveRelParams { chan: 1, distance: -3455 },
            M::MotReqMoveRelParams { chan: 1 },
            M::MotGetMoveRelParams { chan: 1, distance: -3455 },
            M::MotMoveRelative { chan: 1, distance: None },
            M::MotMoveRelative { chan: 1, distance: Some(-3455) },
            M::MotSetMoveAbsParams { chan: 1, position: 42641 },
            M::MotReqMoveAbsParams { chan: 1 },
            M::MotGetMoveAbsParams { chan: 1, position: 42641 },
            M::MotMoveAbsolute { chan: 1, position: None },
            M::MotMoveAbsolute { chan: 1, position: Some(42641) },
            M::MotMoveVelocity { chan: 1, direction: Direction::Reverse },
            M::MotMoveJog { chan: 1, direction: Direction::Forward },
            M::MotMoveCompleted(st),
            M::MotMoveStop { chan: 1, mode: StopMode::Profiled },
            M::MotMoveStop { chan: 1, mode: StopMode::Immediate },
            M::MotMoveStopped(st),
            M::MotSuspendEndOfMoveMsgs,
            M::MotResumeEndOfMoveMsgs,
            M::MotReqStatusUpdate { chan: 1 },
            M::MotGetStatusUpdate(sst),
            M::MotReqDcStatusUpdate { chan: 1 },
            M::MotGetDcStatusUpdate(st),
            M::MotAckDcStatusUpdate,
        ]
    }

    #[test]
    fn every_message_round_trips_both_directions() {
        for msg in samples() {
            // Host -> unit.
            let bytes = encode(&msg, USB_UNIT, HOST);
            let (frame, used) = decode_frame(&bytes, &Addressing::unit()).unwrap();
            assert_eq!(used, bytes.len(), "{msg:?}");
            assert_eq!(frame.message, msg);
            assert_eq!((frame.dest, frame.source), (USB_UNIT, HOST));
            // Unit -> host.
            let bytes = encode(&msg, HOST, USB_UNIT);
            let (frame, _) = decode_frame(&bytes, &Addressing::host()).unwrap();
            assert_eq!(frame.message, msg);
            assert_eq!((frame.dest, frame.source), (HOST, USB_UNIT));
        }
    }

    #[test]
    fn streaming_decoder_splits_a_concatenated_stream_fed_byte_by_byte() {
        let msgs = samples();
        let stream: Vec<u8> = msgs.iter().flat_map(|m| encode(m, HOST, USB_UNIT)).collect();
        let mut dec = AptDecoder::for_host();
        let mut out = Vec::new();
        for b in stream {
            dec.feed(&[b]);
            while let Some(f) = dec.next_frame() {
                out.push(f.unwrap().message);
            }
        }
        assert_eq!(out, msgs);
        assert!(dec.finish().is_ok());
        assert_eq!(dec.dropped_bytes(), 0);
    }

    #[test]
    fn byte_exact_encodings_match_hardware_md_a8() {
        let cases: Vec<(AptMessage, u8, u8, &str)> = vec![
            (AptMessage::HwNoFlashProgramming, USB_UNIT, HOST, "18 00 00 00 50 01"),
            (AptMessage::HwReqInfo, USB_UNIT, HOST, "05 00 00 00 50 01"),
            (AptMessage::ModIdentify { chan: 1 }, USB_UNIT, HOST, "23 02 01 00 50 01"),
            (AptMessage::ModSetChanEnableState { chan: 1, enabled: true }, USB_UNIT, HOST, "10 02 01 01 50 01"),
            (AptMessage::MotMoveHome { chan: 1 }, USB_UNIT, HOST, "43 04 01 00 50 01"),
            (AptMessage::MotMoveHomed { chan: 1 }, HOST, USB_UNIT, "44 04 01 00 01 50"),
            (
                AptMessage::MotMoveAbsolute { chan: 1, position: Some(42641) },
                USB_UNIT,
                HOST,
                "53 04 06 00 D0 01 01 00 91 A6 00 00",
            ),
            (
                AptMessage::MotMoveAbsolute { chan: 1, position: Some(2048) },
                USB_UNIT,
                HOST,
                "53 04 06 00 D0 01 01 00 00 08 00 00",
            ),
            (
                AptMessage::MotMoveRelative { chan: 1, distance: Some(-3455) },
                USB_UNIT,
                HOST,
                "48 04 06 00 D0 01 01 00 81 F2 FF FF",
            ),
            (
                AptMessage::MotSetVelParams(VelParams {
                    chan: 1,
                    min_velocity: 0,
                    acceleration: 1055,
                    max_velocity: 1_777_857,
                }),
                USB_UNIT,
                HOST,
                "13 04 0E 00 D0 01 01 00 00 00 00 00 1F 04 00 00 C1 20 1B 00",
            ),
            (AptMessage::MotReqDcStatusUpdate { chan: 1 }, USB_UNIT, HOST, "90 04 01 00 50 01"),
            (
                AptMessage::MotGetDcStatusUpdate(StatusPayload::dc(
                    1,
                    42641,
                    0,
                    status::HOMED | status::MOTOR_CONNECTED | status::ENABLED,
                )),
                HOST,
                USB_UNIT,
                "91 04 0E 00 81 50 01 00 91 A6 00 00 00 00 00 00 00 05 00 80",
            ),
            (AptMessage::MotAckDcStatusUpdate, USB_UNIT, HOST, "92 04 00 00 50 01"),
            (AptMessage::HwStartUpdateMsgs, USB_UNIT, HOST, "11 00 00 00 50 01"),
            (AptMessage::HwStopUpdateMsgs, USB_UNIT, HOST, "12 00 00 00 50 01"),
            (AptMessage::MotMoveStop { chan: 1, mode: StopMode::Profiled }, USB_UNIT, HOST, "65 04 01 02 50 01"),
        ];
        for (msg, dest, src, want) in cases {
            assert_eq!(encode(&msg, dest, src), hex(want), "{msg:?}");
        }
    }

    #[test]
    fn move_completed_uses_the_status_layout() {
        // 0x0464, 14-byte packet: chan 1, pos 42641, velocity 0, reserved, status.
        let msg = AptMessage::MotMoveCompleted(StatusPayload::dc(
            1,
            42641,
            0,
            status::HOMED | status::MOTOR_CONNECTED | status::ENABLED,
        ));
        assert_eq!(encode(&msg, HOST, USB_UNIT), hex("64 04 0E 00 81 50 01 00 91 A6 00 00 00 00 00 00 00 05 00 80"));
    }

    #[test]
    fn hw_get_info_layout_matches_documented_offsets() {
        let bytes = encode(&AptMessage::HwGetInfo(Box::new(info())), HOST, USB_UNIT);
        assert_eq!(&bytes[..6], &hex("06 00 54 00 81 50")[..]);
        let d = &bytes[6..];
        assert_eq!(d.len(), 84);
        assert_eq!(u32::from_le_bytes(d[0..4].try_into().unwrap()), 27000001);
        assert_eq!(&d[4..12], b"KDC101\0\0");
        assert_eq!(u16::from_le_bytes([d[12], d[13]]), 16);
        // Firmware minor, interim, major at 14, 15, 16.
        assert_eq!(&d[14..17], &[10, 0, 3]);
        assert_eq!(&d[18..32], b"Z825B emulated");
        // pylablib's stage id at 76, then hw version, mod state, channels.
        assert_eq!(u16::from_le_bytes([d[76], d[77]]), 9);
        assert_eq!(u16::from_le_bytes([d[78], d[79]]), 1);
        assert_eq!(u16::from_le_bytes([d[82], d[83]]), 1);
        // And the documented request.
        assert_eq!(encode(&AptMessage::HwReqInfo, USB_UNIT, HOST), hex("05 00 00 00 50 01"));
    }

    #[test]
    fn truncated_frame_is_a_typed_error() {
        let full = hex("53 04 06 00 D0 01 01 00 91 A6 00 00");
        for cut in 0..full.len() {
            match decode_frame(&full[..cut], &Addressing::unit()) {
                Err(CodecError::TruncatedFrame { needed, available }) => {
                    assert_eq!(available, cut);
                    assert!(needed > cut);
                }
                other => panic!("cut {cut}: {other:?}"),
            }
        }
        let mut dec = AptDecoder::for_unit();
        dec.feed(&full[..9]);
        assert!(dec.next_frame().is_none());
        assert!(matches!(dec.finish(), Err(CodecError::TruncatedFrame { needed: 12, available: 9 })));
    }

    #[test]
    fn unknown_id_is_a_typed_error_and_the_decoder_resynchronises() {
        let bad = hex("34 12 00 00 50 01");
        assert_eq!(decode_frame(&bad, &Addressing::unit()), Err(CodecError::UnknownMessageId { id: 0x1234 }));
        let mut dec = AptDecoder::for_unit();
        dec.feed(&bad);
        dec.feed(&hex("05 00 00 00 50 01"));
        let mut errors = 0;
        let mut frames = Vec::new();
        while let Some(r) = dec.next_frame() {
            match r {
                Ok(f) => frames.push(f.message),
                Err(_) => errors += 1,
            }
        }
        assert_eq!(frames, vec![AptMessage::HwReqInfo]);
        assert!(errors >= 1);
        assert_eq!(dec.dropped_bytes(), 6);
    }

    #[test]
    fn bad_destination_oversize_and_length_mismatch_are_typed() {
        // A reply addressed to the unit when the host decodes.
        assert!(matches!(
            decode_frame(&hex("05 00 00 00 50 01"), &Addressing::host()),
            Err(CodecError::BadDestination { id: 0x0005, dest: 0x50, .. })
        ));
        // Long frame announcing 0x0100 = 256 data bytes.
        assert!(matches!(
            decode_frame(&hex("64 04 00 01 81 50"), &Addressing::host()),
            Err(CodecError::BadHeader { .. })
        ));
        // Unknown source address.
        assert!(matches!(
            decode_frame(&hex("05 00 00 00 50 77"), &Addressing::unit()),
            Err(CodecError::BadHeader { .. })
        ));
        // MOVE_COMPLETED with 6 instead of 14 data bytes.
        assert!(matches!(
            decode_frame(&hex("64 04 06 00 81 50 01 00 00 00 00 00"), &Addressing::host()),
            Err(CodecError::LengthMismatch { id: 0x0464, .. })
        ));
        // A status request sent as a long frame.
        assert!(matches!(
            decode_frame(&hex("90 04 00 00 D0 01"), &Addressing::unit()),
            Err(CodecError::LengthMismatch { id: 0x0490, .. })
        ));
    }

    #[test]
    fn status_payload_accessors() {
        let s = StatusPayload::dc(1, 5, -300, status::MOVING_CCW);
        assert_eq!(s.dc_velocity(), -300);
        assert!(s.is_moving());
        let s = StatusPayload::stepper(1, 5, -123_456, status::HOMED);
        assert_eq!(s.stepper_encoder(), -123_456);
        assert!(!s.is_moving());
    }

    proptest! {
        #[test]
        fn random_bytes_never_panic_the_decoder(bytes in proptest::collection::vec(any::<u8>(), 0..600),
                                                split in 0usize..600) {
            let mut dec = AptDecoder::for_host();
            let split = split.min(bytes.len());
            dec.feed(&bytes[..split]);
            let mut n = 0usize;
            while dec.next_frame().is_some() { n += 1; }
            dec.feed(&bytes[split..]);
            while dec.next_frame().is_some() { n += 1; }
            // Every step either yields a frame or drops a byte: bounded work.
            prop_assert!(n <= bytes.len());
            let _ = dec.finish();
        }

        #[test]
        fn valid_frames_survive_leading_garbage(garbage in proptest::collection::vec(any::<u8>(), 0..40),
                                                pos in any::<i32>(), st in any::<u32>()) {
            let msg = AptMessage::MotGetDcStatusUpdate(StatusPayload::dc(1, pos, 0, st));
            let mut dec = AptDecoder::for_host();
            dec.feed(&garbage);
            // Repeat the frame so one copy is found after resynchronisation
            // even when the garbage ends in a prefix of a valid header.
            for _ in 0..6 { dec.feed(&encode(&msg, HOST, USB_UNIT)); }
            let mut found = false;
            while let Some(r) = dec.next_frame() {
                if let Ok(f) = r { if f.message == msg { found = true; } }
            }
            prop_assert!(found);
        }

        #[test]
        fn status_and_move_round_trip(pos in any::<i32>(), vel in any::<i16>(), st in any::<u32>(), chan in 1u8..=255) {
            for msg in [
                AptMessage::MotMoveAbsolute { chan, position: Some(pos) },
                AptMessage::MotMoveRelative { chan, distance: Some(pos) },
                AptMessage::MotMoveCompleted(StatusPayload::dc(u16::from(chan), pos, vel, st)),
                AptMessage::MotGetStatusBits { chan: u16::from(chan), status: st },
            ] {
                let b = encode(&msg, HOST, USB_UNIT);
                let (f, n) = decode_frame(&b, &Addressing::host()).unwrap();
                prop_assert_eq!(n, b.len());
                prop_assert_eq!(f.message, msg);
            }
        }
    }
}
