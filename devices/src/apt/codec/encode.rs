//! Messages to bytes.

use super::messages::{AptMessage, Direction, StopMode};
use super::wire::{put_i32, put_str, put_u16, put_u32};
use super::{HEADER_LEN, LONG_FLAG, id};

fn dir_byte(d: Direction) -> u8 {
    match d {
        Direction::Forward => 1,
        Direction::Reverse => 2,
    }
}

/// Body of a message: header parameters or a data packet.
enum Body {
    Short(u8, u8),
    Long(Vec<u8>),
}

/// A data packet of `len` bytes written by `fill`.
fn long(len: usize, fill: impl FnOnce(&mut Vec<u8>)) -> Body {
    let mut d = Vec::with_capacity(len);
    fill(&mut d);
    Body::Long(d)
}

fn chan_i32(chan: u16, v: i32) -> Body {
    long(6, |d| {
        put_u16(d, chan);
        put_i32(d, v);
    })
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

    /// The header parameters or data packet of this message.
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
            M::HwGetInfo(info) => long(84, |d| info.put(d)),
            M::HwRichResponse { msg_id, code, text } => long(68, |d| {
                put_u16(d, *msg_id);
                put_u16(d, *code);
                put_str(d, text, 64);
            }),
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
            M::MotSetVelParams(p) | M::MotGetVelParams(p) => long(14, |d| p.put(d)),
            M::MotSetJogParams(p) | M::MotGetJogParams(p) => long(22, |d| p.put(d)),
            M::MotSetLimSwitchParams(p) | M::MotGetLimSwitchParams(p) => long(16, |d| p.put(d)),
            M::MotGetStatusBits { chan, status } => long(6, |d| {
                put_u16(d, *chan);
                put_u32(d, *status);
            }),
            M::MotSetHomeParams(p) | M::MotGetHomeParams(p) => long(14, |d| p.put(d)),
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
                long(14, |d| s.put(d))
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
