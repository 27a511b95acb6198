//! Bytes to messages: one frame ([`decode_frame`]) or a stream
//! ([`AptDecoder`]), checking each id's wire form and the addresses.

use super::messages::{
    AptMessage, Direction, Frame, HomeParams, HwInfo, JogParams, LimSwitchParams, StatusPayload, StopMode, VelParams,
};
use super::wire::Rd;
use super::{HEADER_LEN, HOST, LONG_FLAG, MAX_DATA_LEN, RACK, USB_UNIT, id};

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

fn parse_body(id: u16, p1: u8, p2: u8, data: Option<&[u8]>) -> Result<AptMessage, CodecError> {
    use AptMessage as M;
    use id::*;
    let mut r = Rd::new(data.unwrap_or(&[]));
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
        HW_GET_INFO => M::HwGetInfo(Box::new(HwInfo::read(&mut r))),
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
            let p = VelParams::read(&mut r);
            if id == MOT_SET_VELPARAMS { M::MotSetVelParams(p) } else { M::MotGetVelParams(p) }
        }
        MOT_REQ_VELPARAMS => M::MotReqVelParams { chan },
        MOT_SET_JOGPARAMS | MOT_GET_JOGPARAMS => {
            let p = JogParams::read(&mut r);
            if id == MOT_SET_JOGPARAMS { M::MotSetJogParams(p) } else { M::MotGetJogParams(p) }
        }
        MOT_REQ_JOGPARAMS => M::MotReqJogParams { chan },
        MOT_SET_LIMSWITCHPARAMS | MOT_GET_LIMSWITCHPARAMS => {
            let p = LimSwitchParams::read(&mut r);
            if id == MOT_SET_LIMSWITCHPARAMS { M::MotSetLimSwitchParams(p) } else { M::MotGetLimSwitchParams(p) }
        }
        MOT_REQ_LIMSWITCHPARAMS => M::MotReqLimSwitchParams { chan },
        MOT_REQ_STATUSBITS => M::MotReqStatusBits { chan },
        MOT_GET_STATUSBITS => M::MotGetStatusBits { chan: r.u16(), status: r.u32() },
        MOT_SET_GENMOVEPARAMS => M::MotSetGenMoveParams { chan: r.u16(), backlash: r.i32() },
        MOT_REQ_GENMOVEPARAMS => M::MotReqGenMoveParams { chan },
        MOT_GET_GENMOVEPARAMS => M::MotGetGenMoveParams { chan: r.u16(), backlash: r.i32() },
        MOT_SET_HOMEPARAMS | MOT_GET_HOMEPARAMS => {
            let p = HomeParams::read(&mut r);
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
        MOT_MOVE_COMPLETED => M::MotMoveCompleted(StatusPayload::read(&mut r)),
        MOT_MOVE_STOP => M::MotMoveStop { chan, mode: if p2 == 1 { StopMode::Immediate } else { StopMode::Profiled } },
        MOT_MOVE_STOPPED => M::MotMoveStopped(StatusPayload::read(&mut r)),
        MOT_SUSPEND_ENDOFMOVEMSGS => M::MotSuspendEndOfMoveMsgs,
        MOT_RESUME_ENDOFMOVEMSGS => M::MotResumeEndOfMoveMsgs,
        MOT_REQ_STATUSUPDATE => M::MotReqStatusUpdate { chan },
        MOT_GET_STATUSUPDATE => M::MotGetStatusUpdate(StatusPayload::read(&mut r)),
        MOT_REQ_DCSTATUSUPDATE => M::MotReqDcStatusUpdate { chan },
        MOT_GET_DCSTATUSUPDATE => M::MotGetDcStatusUpdate(StatusPayload::read(&mut r)),
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
