//! Commands to the controller: real-time bytes and line commands.

use thiserror::Error;

use super::LINE_BUFFER_SIZE;

/// Single-byte real-time commands: never buffered, never acknowledged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Realtime {
    StatusQuery,
    FeedHold,
    CycleStart,
    SoftReset,
    JogCancel,
}

impl Realtime {
    pub fn byte(self) -> u8 {
        match self {
            Self::StatusQuery => b'?',
            Self::FeedHold => b'!',
            Self::CycleStart => b'~',
            Self::SoftReset => 0x18,
            Self::JogCancel => 0x85,
        }
    }
    pub fn from_byte(b: u8) -> Option<Self> {
        Some(match b {
            b'?' => Self::StatusQuery,
            b'!' => Self::FeedHold,
            b'~' => Self::CycleStart,
            0x18 => Self::SoftReset,
            0x85 => Self::JogCancel,
            _ => return None,
        })
    }
}

/// Distance mode of a move.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Distance {
    /// `G90`
    Absolute,
    /// `G91`
    Incremental,
}

/// Line commands (each answered by `ok` or `error:N`).
#[derive(Debug, Clone, PartialEq)]
pub enum GrblCommand {
    /// `G90|G91 G1 <axis><mm> F<mm/min>`: feed move.
    Feed { distance: Distance, axis: char, mm: f64, feed_mm_min: f64 },
    /// `G90|G91 G0 <axis><mm>`: rapid move.
    Rapid { distance: Distance, axis: char, mm: f64 },
    /// `$J=G90|G91 G21 <axis><mm> F<mm/min>`: jog.
    Jog { distance: Distance, axis: char, mm: f64, feed_mm_min: f64 },
    /// `G4 P<s>`: dwell; its `ok` arrives once the planner has emptied.
    Dwell { seconds: f64 },
    /// `$H`
    Home,
    /// `$X`
    Unlock,
    /// `$$`
    Settings,
    /// `$I`
    BuildInfo,
    /// `$G`
    ParserState,
    /// `$N=value`
    SetSetting { number: u16, value: f64 },
}

/// Why a command cannot be encoded.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum EncodeError {
    #[error("{what} is not a finite number ({value})")]
    NotFinite { what: &'static str, value: f64 },
    #[error("{what} must be positive, got {value}")]
    NotPositive { what: &'static str, value: f64 },
    #[error("axis {0:?} is not one of X Y Z A B C")]
    BadAxis(char),
    #[error("encoded line {line:?} is {len} bytes; GRBL accepts at most {max}")]
    TooLong { line: String, len: usize, max: usize },
}

fn finite(what: &'static str, value: f64) -> Result<f64, EncodeError> {
    if value.is_finite() { Ok(value) } else { Err(EncodeError::NotFinite { what, value }) }
}

fn positive(what: &'static str, value: f64) -> Result<f64, EncodeError> {
    let v = finite(what, value)?;
    if v > 0.0 { Ok(v) } else { Err(EncodeError::NotPositive { what, value }) }
}

fn axis_ok(axis: char) -> Result<char, EncodeError> {
    let a = axis.to_ascii_uppercase();
    if "XYZABC".contains(a) { Ok(a) } else { Err(EncodeError::BadAxis(axis)) }
}

/// Numbers as GRBL prints them: fixed point, 4 decimals (0.1 um) is below any
/// stepper's resolution and keeps lines short. "-0.0000" is normalised.
fn num(v: f64) -> String {
    let s = format!("{v:.4}");
    if s == "-0.0000" { "0.0000".into() } else { s }
}

fn mode(d: Distance) -> &'static str {
    match d {
        Distance::Absolute => "G90",
        Distance::Incremental => "G91",
    }
}

impl GrblCommand {
    /// The line to send, terminated by LF.
    pub fn encode(&self) -> Result<String, EncodeError> {
        let line = match self {
            Self::Feed { distance, axis, mm, feed_mm_min } => format!(
                "{} G1 {}{} F{}",
                mode(*distance),
                axis_ok(*axis)?,
                num(finite("target", *mm)?),
                num(positive("feed", *feed_mm_min)?)
            ),
            Self::Rapid { distance, axis, mm } => {
                format!("{} G0 {}{}", mode(*distance), axis_ok(*axis)?, num(finite("target", *mm)?))
            }
            Self::Jog { distance, axis, mm, feed_mm_min } => format!(
                "$J={} G21 {}{} F{}",
                mode(*distance),
                axis_ok(*axis)?,
                num(finite("target", *mm)?),
                num(positive("feed", *feed_mm_min)?)
            ),
            Self::Dwell { seconds } => {
                let s = finite("dwell", *seconds)?;
                if s < 0.0 {
                    return Err(EncodeError::NotPositive { what: "dwell", value: s });
                }
                format!("G4 P{}", num(s))
            }
            Self::Home => "$H".into(),
            Self::Unlock => "$X".into(),
            Self::Settings => "$$".into(),
            Self::BuildInfo => "$I".into(),
            Self::ParserState => "$G".into(),
            Self::SetSetting { number, value } => {
                format!("${number}={}", num(finite("setting value", *value)?))
            }
        };
        if line.len() > LINE_BUFFER_SIZE - 1 {
            return Err(EncodeError::TooLong { len: line.len(), line, max: LINE_BUFFER_SIZE - 1 });
        }
        Ok(line + "\n")
    }
}
