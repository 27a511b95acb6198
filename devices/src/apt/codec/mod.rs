//! Pure codec for the Thorlabs APT wire protocol (docs/hardware.md A.2/A.3): bytes
//! in, messages out and back, with no I/O. Every frame has a 6-byte header;
//! bit 7 of byte 4 marks a "long" frame whose header carries a data length
//! and is followed by that many bytes. All multi-byte fields are little-endian.

mod decode;
mod encode;
mod messages;
mod wire;

pub use decode::{Addressing, AptDecoder, CodecError, decode_frame};
pub use encode::{encode, encode_into};
pub use messages::{
    AptMessage, Direction, Frame, HomeParams, HwInfo, JogParams, LimSwitchParams, StatusPayload, StopMode, VelParams,
};

/// Address of the host PC.
pub const HOST: u8 = 0x01;
/// Address of a generic single-channel USB unit (KDC101, K10CR1).
pub const USB_UNIT: u8 = 0x50;
/// Rack controller / motherboard of a bay system.
pub const RACK: u8 = 0x11;
/// Bit 7 of header byte 4: a data packet follows.
pub(crate) const LONG_FLAG: u8 = 0x80;
/// The protocol states no data packet exceeds 255 bytes; anything longer is
/// treated as corruption (what thorlabs_apt_device does).
pub const MAX_DATA_LEN: usize = 255;
pub const HEADER_LEN: usize = 6;

/// Message ids (docs/hardware.md A.3).
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

/// Status bits (docs/hardware.md A.4), named as in the protocol document.
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

#[cfg(test)]
mod tests;
