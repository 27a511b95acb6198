//! Lines from the controller: one [`Response`] per line, and the bounded
//! splitter that cuts the byte stream into lines.

use thiserror::Error;

use super::{AlarmCode, AxisValues, ErrorCode, MAX_RESPONSE_LINE, MachineState, PositionKind, StatusReport};

/// One line from the controller.
#[derive(Debug, Clone, PartialEq)]
pub enum Response {
    /// `ok`: the oldest unacknowledged line was accepted.
    Ok,
    /// `error:N`: the oldest unacknowledged line was rejected.
    Error(ErrorCode),
    /// `ALARM:N`: alarm state entered.
    Alarm(AlarmCode),
    /// `Grbl 1.1h ['$' for help]`: start-up or soft reset.
    Welcome {
        version: String,
    },
    Status(StatusReport),
    /// `[MSG:...]`.
    Message(String),
    /// `[GC:...]`: parser state words.
    ParserState(Vec<String>),
    /// `[VER:1.1h.20190830:info]`.
    Version {
        version: String,
        info: String,
    },
    /// Any other `[TAG:...]` push (`OPT`, `HLP`, `G54`, `PRB`, `echo`...).
    Feedback {
        tag: String,
        body: String,
    },
    /// `$N=value` from `$$`.
    Setting {
        number: u16,
        value: f64,
    },
    /// `>line:ok` / `>line:error:N`: a stored start-up line ran.
    StartupLine {
        line: String,
        result: Result<(), ErrorCode>,
    },
    /// An empty line (GRBL prints CR LF before the banner).
    Empty,
}

impl Response {
    /// Whether this line answers (acknowledges) one sent line.
    pub fn is_ack(&self) -> bool {
        matches!(self, Self::Ok | Self::Error(_))
    }
}

/// What is wrong with a line, and where.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ParseError {
    #[error("line is not valid UTF-8 at byte {at}")]
    NotUtf8 { at: usize },
    #[error("line of {len} bytes exceeds the {max}-byte limit")]
    TooLong { len: usize, max: usize },
    #[error("unrecognised line {line:?}")]
    Unrecognised { line: String },
    #[error("bad {what} code {text:?} in {line:?}")]
    BadCode { what: &'static str, text: String, line: String },
    #[error("status report {line:?} is not closed by '>'")]
    UnterminatedStatus { line: String },
    #[error("unknown machine state {state:?} in {line:?}")]
    UnknownState { state: String, line: String },
    #[error("status report {line:?} has no MPos/WPos as its second field")]
    MissingPosition { line: String },
    #[error("bad value {text:?} in field {field:?} of {line:?}")]
    BadField { field: String, text: String, line: String },
    #[error("feedback message {line:?} is not closed by ']'")]
    UnterminatedFeedback { line: String },
    #[error("bad setting {line:?}")]
    BadSetting { line: String },
}

fn parse_code(text: &str, what: &'static str, line: &str) -> Result<u8, ParseError> {
    let bad = || ParseError::BadCode { what, text: text.to_string(), line: line.to_string() };
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad());
    }
    text.parse::<u8>().map_err(|_| bad())
}

fn parse_num(s: &str) -> Option<f64> {
    // GRBL prints plain decimals; reject "inf"/"nan" and exponents.
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit() || b == b'.' || b == b'-' || b == b'+') {
        return None;
    }
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}

fn parse_axes(field: &str, body: &str, line: &str) -> Result<AxisValues, ParseError> {
    let bad = || ParseError::BadField { field: field.to_string(), text: body.to_string(), line: line.to_string() };
    let mut v = [0.0; 6];
    let mut n = 0;
    for part in body.split(',') {
        if n == 6 {
            return Err(bad());
        }
        v[n] = parse_num(part).ok_or_else(bad)?;
        n += 1;
    }
    AxisValues::new(&v[..n]).ok_or_else(bad)
}

fn parse_status(line: &str) -> Result<StatusReport, ParseError> {
    let inner = line
        .strip_prefix('<')
        .and_then(|s| s.strip_suffix('>'))
        .ok_or_else(|| ParseError::UnterminatedStatus { line: line.to_string() })?;
    let mut fields = inner.split('|');
    let state_text = fields.next().unwrap_or_default();
    let state = MachineState::parse(state_text)
        .ok_or_else(|| ParseError::UnknownState { state: state_text.to_string(), line: line.to_string() })?;
    let pos_field = fields.next().ok_or_else(|| ParseError::MissingPosition { line: line.to_string() })?;
    let (position_kind, pos_body) = if let Some(b) = pos_field.strip_prefix("MPos:") {
        (PositionKind::Machine, b)
    } else if let Some(b) = pos_field.strip_prefix("WPos:") {
        (PositionKind::Work, b)
    } else {
        return Err(ParseError::MissingPosition { line: line.to_string() });
    };
    let position = parse_axes(&pos_field[..4], pos_body, line)?;
    let mut report = StatusReport {
        state,
        position_kind,
        position,
        wco: None,
        buffer: None,
        line_number: None,
        feed: None,
        spindle: None,
        pins: None,
        overrides: None,
        accessory: None,
    };
    for field in fields {
        let (name, body) = field.split_once(':').ok_or_else(|| ParseError::BadField {
            field: field.to_string(),
            text: String::new(),
            line: line.to_string(),
        })?;
        let bad = || ParseError::BadField { field: name.to_string(), text: body.to_string(), line: line.to_string() };
        let ints = |n: usize| -> Result<Vec<u32>, ParseError> {
            let v: Option<Vec<u32>> = body.split(',').map(|p| p.parse::<u32>().ok()).collect();
            v.filter(|v| v.len() == n).ok_or_else(bad)
        };
        match name {
            "WCO" => report.wco = Some(parse_axes(name, body, line)?),
            "Bf" => {
                let v = ints(2)?;
                report.buffer =
                    Some((u16::try_from(v[0]).map_err(|_| bad())?, u16::try_from(v[1]).map_err(|_| bad())?));
            }
            "Ln" => report.line_number = Some(ints(1)?[0]),
            "F" => report.feed = Some(parse_num(body).ok_or_else(bad)?),
            "FS" => {
                let (f, s) = body.split_once(',').ok_or_else(bad)?;
                report.feed = Some(parse_num(f).ok_or_else(bad)?);
                report.spindle = Some(parse_num(s).ok_or_else(bad)?);
            }
            "Pn" => {
                if !body.bytes().all(|b| b"XYZABCPDHRS".contains(&b)) {
                    return Err(bad());
                }
                report.pins = Some(body.to_string());
            }
            "Ov" => {
                let v = ints(3)?;
                let pct = |x: u32| u16::try_from(x).map_err(|_| bad());
                report.overrides = Some((pct(v[0])?, pct(v[1])?, pct(v[2])?));
            }
            "A" => report.accessory = Some(body.to_string()),
            // Unknown fields are allowed by the spec ("may be added"): skip them.
            _ => {}
        }
    }
    Ok(report)
}

fn parse_feedback(line: &str) -> Result<Response, ParseError> {
    let inner = line
        .strip_prefix('[')
        .and_then(|s| s.strip_suffix(']'))
        .ok_or_else(|| ParseError::UnterminatedFeedback { line: line.to_string() })?;
    let Some((tag, body)) = inner.split_once(':') else {
        // `[echo:...]` always has a colon; a bare `[...]` is not GRBL 1.1.
        return Err(ParseError::Unrecognised { line: line.to_string() });
    };
    Ok(match tag {
        "MSG" => Response::Message(body.to_string()),
        "GC" => Response::ParserState(body.split_whitespace().map(str::to_string).collect()),
        "VER" => {
            let (version, info) = body.split_once(':').unwrap_or((body, ""));
            Response::Version { version: version.to_string(), info: info.to_string() }
        }
        _ => Response::Feedback { tag: tag.to_string(), body: body.to_string() },
    })
}

/// Parse one line (without its CR/LF).
pub fn parse_line(line: &str) -> Result<Response, ParseError> {
    let line = line.trim_end_matches(['\r', '\n']);
    if line.len() > MAX_RESPONSE_LINE {
        return Err(ParseError::TooLong { len: line.len(), max: MAX_RESPONSE_LINE });
    }
    if line.is_empty() {
        return Ok(Response::Empty);
    }
    if line == "ok" {
        return Ok(Response::Ok);
    }
    if let Some(code) = line.strip_prefix("error:") {
        return Ok(Response::Error(ErrorCode(parse_code(code, "error", line)?)));
    }
    if let Some(code) = line.strip_prefix("ALARM:") {
        return Ok(Response::Alarm(AlarmCode(parse_code(code, "alarm", line)?)));
    }
    if line.starts_with('<') {
        return parse_status(line).map(Response::Status);
    }
    if line.starts_with('[') {
        return parse_feedback(line);
    }
    if let Some(rest) = line.strip_prefix("Grbl ") {
        let version = rest.split_whitespace().next().unwrap_or_default();
        if version.is_empty() {
            return Err(ParseError::Unrecognised { line: line.to_string() });
        }
        return Ok(Response::Welcome { version: version.to_string() });
    }
    if let Some(rest) = line.strip_prefix('$') {
        let bad = || ParseError::BadSetting { line: line.to_string() };
        let (n, v) = rest.split_once('=').ok_or_else(bad)?;
        let number = n.parse::<u16>().map_err(|_| bad())?;
        let value = parse_num(v).ok_or_else(bad)?;
        return Ok(Response::Setting { number, value });
    }
    if let Some(rest) = line.strip_prefix('>') {
        let bad = || ParseError::Unrecognised { line: line.to_string() };
        if let Some(l) = rest.strip_suffix(":ok") {
            return Ok(Response::StartupLine { line: l.to_string(), result: Ok(()) });
        }
        let (l, code) = rest.rsplit_once(":error:").ok_or_else(bad)?;
        return Ok(Response::StartupLine {
            line: l.to_string(),
            result: Err(ErrorCode(parse_code(code, "error", line)?)),
        });
    }
    Err(ParseError::Unrecognised { line: line.to_string() })
}

/// Parse one line given as raw bytes.
pub fn parse_line_bytes(line: &[u8]) -> Result<Response, ParseError> {
    let s = std::str::from_utf8(line).map_err(|e| ParseError::NotUtf8 { at: e.valid_up_to() })?;
    parse_line(s)
}

/// Splits a byte stream into lines at LF, dropping CR. Bounded: a line longer
/// than [`MAX_RESPONSE_LINE`] is reported once and then skipped up to its LF,
/// so garbage on the wire can never grow memory without limit.
#[derive(Debug, Default)]
pub struct LineSplitter {
    buf: Vec<u8>,
    overflowed: bool,
}

impl LineSplitter {
    pub fn new() -> Self {
        Self::default()
    }

    /// Feed bytes; complete lines (or overflow errors) are appended to `out`.
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<Result<Vec<u8>, ParseError>>) {
        for &b in bytes {
            match b {
                b'\n' => {
                    if self.overflowed {
                        self.overflowed = false;
                    } else {
                        out.push(Ok(std::mem::take(&mut self.buf)));
                    }
                    self.buf.clear();
                }
                b'\r' => {}
                _ if self.overflowed => {}
                _ => {
                    if self.buf.len() >= MAX_RESPONSE_LINE {
                        out.push(Err(ParseError::TooLong { len: self.buf.len() + 1, max: MAX_RESPONSE_LINE }));
                        self.buf.clear();
                        self.overflowed = true;
                    } else {
                        self.buf.push(b);
                    }
                }
            }
        }
    }

    /// Bytes held for an incomplete line.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    pub fn clear(&mut self) {
        self.buf.clear();
        self.overflowed = false;
    }
}
