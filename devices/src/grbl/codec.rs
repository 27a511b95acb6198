//! GRBL 1.1 line protocol as a pure codec: text lines from the controller
//! become [`Response`]s, commands become the exact bytes to send. No I/O here,
//! so every rule is tested with plain strings (hardware.md section B).

use std::fmt;

use thiserror::Error;

/// Size of GRBL's serial receive buffer (`RX_BUFFER_SIZE`); character
/// counting keeps the unacknowledged bytes at or below this.
pub const RX_BUFFER_SIZE: usize = 128;
/// GRBL's line buffer (`LINE_BUFFER_SIZE`): longer lines get `error:11`.
pub const LINE_BUFFER_SIZE: usize = 80;
/// Longest line we accept from the controller before declaring the stream
/// corrupt. GRBL's longest pushes (`$$` lines, status reports with every
/// field) stay well under this.
pub const MAX_RESPONSE_LINE: usize = 256;

/// Meaning of a GRBL 1.1 `error:N` code (gnea/grbl `error_codes_en_US.csv`).
pub fn error_meaning(code: u8) -> &'static str {
    match code {
        1 => "G-code words consist of a letter and a value. Letter was not found.",
        2 => "Numeric value format is not valid or missing an expected value.",
        3 => "Grbl '$' system command was not recognized or supported.",
        4 => "Negative value received for an expected positive value.",
        5 => "Homing cycle is not enabled via settings.",
        6 => "Minimum step pulse time must be greater than 3usec.",
        7 => "EEPROM read failed. Reset and restored to default values.",
        8 => "Grbl '$' command cannot be used unless Grbl is IDLE.",
        9 => "G-code locked out during alarm or jog state.",
        10 => "Soft limits cannot be enabled without homing also enabled.",
        11 => "Max characters per line exceeded. Line was not processed and executed.",
        12 => "Grbl '$' setting value exceeds the maximum step rate supported.",
        13 => "Safety door detected as opened and door state initiated.",
        14 => "Build info or startup line exceeded EEPROM line length limit.",
        15 => "Jog target exceeds machine travel. Command ignored.",
        16 => "Jog command with no '=' or contains prohibited g-code.",
        17 => "Laser mode requires PWM output.",
        20 => "Unsupported or invalid g-code command found in block.",
        21 => "More than one g-code command from same modal group found in block.",
        22 => "Feed rate has not yet been set or is undefined.",
        23 => "G-code command in block requires an integer value.",
        24 => "Two G-code commands that both require the use of the XYZ axis words were detected in the block.",
        25 => "A G-code word was repeated in the block.",
        26 => "A G-code command implicitly or explicitly requires XYZ axis words in the block, but none were detected.",
        27 => "N line number value is not within the valid range of 1 - 9,999,999.",
        28 => "A G-code command was sent, but is missing some required P or L value words in the line.",
        29 => "Grbl supports six work coordinate systems G54-G59. G59.1, G59.2, and G59.3 are not supported.",
        30 => "The G53 G-code command requires either a G0 seek or G1 feed motion mode to be active.",
        31 => "There are unused axis words in the block and G80 motion mode cancel is active.",
        32 => "A G2 or G3 arc was commanded but there are no XYZ axis words in the selected plane to trace the arc.",
        33 => "The motion command has an invalid target.",
        34 => {
            "A G2 or G3 arc, traced with the radius definition, had a mathematical error when computing the arc geometry."
        }
        35 => {
            "A G2 or G3 arc, traced with the offset definition, is missing the IJK offset word in the selected plane to trace the arc."
        }
        36 => "There are unused, leftover G-code words that aren't used by any command in the block.",
        37 => {
            "The G43.1 dynamic tool length offset command cannot apply an offset to an axis other than its configured axis."
        }
        38 => "Tool number greater than max supported value.",
        _ => "Unknown error code.",
    }
}

/// Meaning of a GRBL 1.1 `ALARM:N` code (gnea/grbl `alarm_codes_en_US.csv`).
pub fn alarm_meaning(code: u8) -> &'static str {
    match code {
        1 => {
            "Hard limit triggered. Machine position is likely lost due to sudden and immediate halt. Re-homing is highly recommended."
        }
        2 => "G-code motion target exceeds machine travel. Machine position safely retained. Alarm may be unlocked.",
        3 => {
            "Reset while in motion. Grbl cannot guarantee position. Lost steps are likely. Re-homing is highly recommended."
        }
        4 => "Probe fail. The probe is not in the expected initial state before starting probe cycle.",
        5 => "Probe fail. Probe did not contact the workpiece within the programmed travel.",
        6 => "Homing fail. Reset during active homing cycle.",
        7 => "Homing fail. Safety door was opened during active homing cycle.",
        8 => "Homing fail. Cycle failed to clear limit switch when pulling off.",
        9 => "Homing fail. Could not find limit switch within search distance.",
        10 => "Homing fail. On dual axis machines, could not find the second limit switch for self-squaring.",
        _ => "Unknown alarm code.",
    }
}

/// A GRBL `error:N` code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ErrorCode(pub u8);

impl ErrorCode {
    pub fn meaning(self) -> &'static str {
        error_meaning(self.0)
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "error:{} ({})", self.0, self.meaning())
    }
}

/// A GRBL `ALARM:N` code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct AlarmCode(pub u8);

impl AlarmCode {
    pub const HARD_LIMIT: AlarmCode = AlarmCode(1);
    pub const SOFT_LIMIT: AlarmCode = AlarmCode(2);
    pub const ABORT_CYCLE: AlarmCode = AlarmCode(3);

    pub fn meaning(self) -> &'static str {
        alarm_meaning(self.0)
    }
    /// Hard and soft limit alarms lock GRBL until a soft reset ("critical event").
    pub fn is_critical(self) -> bool {
        matches!(self.0, 1 | 2)
    }
}

impl fmt::Display for AlarmCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ALARM:{} ({})", self.0, self.meaning())
    }
}

/// Machine state, first field of a status report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MachineState {
    Idle,
    Run,
    /// `Hold:0` = hold complete (ready to resume), `Hold:1` = decelerating.
    Hold(u8),
    Jog,
    Alarm,
    /// `Door:0..3`.
    Door(u8),
    Check,
    Home,
    Sleep,
}

impl MachineState {
    fn parse(s: &str) -> Option<Self> {
        let (name, sub) = match s.split_once(':') {
            Some((n, v)) => (n, Some(v.parse::<u8>().ok()?)),
            None => (s, None),
        };
        Some(match (name, sub) {
            ("Idle", None) => Self::Idle,
            ("Run", None) => Self::Run,
            ("Hold", Some(v)) if v <= 1 => Self::Hold(v),
            // Firmware older than 1.1 sent a bare `Hold`; read it as "in progress".
            ("Hold", None) => Self::Hold(1),
            ("Jog", None) => Self::Jog,
            ("Alarm", None) => Self::Alarm,
            ("Door", Some(v)) if v <= 3 => Self::Door(v),
            ("Door", None) => Self::Door(0),
            ("Check", None) => Self::Check,
            ("Home", None) => Self::Home,
            ("Sleep", None) => Self::Sleep,
            _ => return None,
        })
    }
}

impl fmt::Display for MachineState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Idle => f.write_str("Idle"),
            Self::Run => f.write_str("Run"),
            Self::Hold(v) => write!(f, "Hold:{v}"),
            Self::Jog => f.write_str("Jog"),
            Self::Alarm => f.write_str("Alarm"),
            Self::Door(v) => write!(f, "Door:{v}"),
            Self::Check => f.write_str("Check"),
            Self::Home => f.write_str("Home"),
            Self::Sleep => f.write_str("Sleep"),
        }
    }
}

/// Which frame the report's position is in (chosen by `$10`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PositionKind {
    Machine,
    Work,
}

/// Up to six axis values (GRBL builds use 3; forks go to 6).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AxisValues {
    values: [f64; 6],
    len: u8,
}

impl AxisValues {
    pub fn new(values: &[f64]) -> Option<Self> {
        if values.is_empty() || values.len() > 6 {
            return None;
        }
        let mut v = [0.0; 6];
        v[..values.len()].copy_from_slice(values);
        Some(Self { values: v, len: values.len() as u8 })
    }
    pub fn as_slice(&self) -> &[f64] {
        &self.values[..self.len as usize]
    }
    pub fn get(&self, axis: usize) -> Option<f64> {
        self.as_slice().get(axis).copied()
    }
}

/// A parsed `<...>` status report.
#[derive(Debug, Clone, PartialEq)]
pub struct StatusReport {
    pub state: MachineState,
    pub position_kind: PositionKind,
    pub position: AxisValues,
    /// `WCO:` work coordinate offset (sent only now and then).
    pub wco: Option<AxisValues>,
    /// `Bf:` free planner blocks, free RX bytes.
    pub buffer: Option<(u16, u16)>,
    /// `Ln:` line number.
    pub line_number: Option<u32>,
    /// `F:` or `FS:` feed (mm/min).
    pub feed: Option<f64>,
    /// `FS:` spindle speed.
    pub spindle: Option<f64>,
    /// `Pn:` triggered input pins, e.g. `Z` or `XP`.
    pub pins: Option<String>,
    /// `Ov:` feed, rapid, spindle overrides in percent.
    pub overrides: Option<(u16, u16, u16)>,
    /// `A:` accessory state.
    pub accessory: Option<String>,
}

impl StatusReport {
    /// Machine position of `axis`, using `wco` (from this report or an
    /// earlier one) when the report carries work coordinates.
    pub fn machine_position(&self, axis: usize, wco: Option<&AxisValues>) -> Option<f64> {
        let p = self.position.get(axis)?;
        match self.position_kind {
            PositionKind::Machine => Some(p),
            PositionKind::Work => {
                let off = self.wco.as_ref().or(wco)?.get(axis)?;
                Some(p + off)
            }
        }
    }
    /// Whether limit pin `axis_letter` ('X', 'Y', 'Z') reads triggered.
    pub fn pin(&self, axis_letter: char) -> bool {
        self.pins.as_deref().is_some_and(|p| p.contains(axis_letter))
    }
}

fn fmt_axes(f: &mut fmt::Formatter<'_>, v: &AxisValues) -> fmt::Result {
    for (i, x) in v.as_slice().iter().enumerate() {
        if i > 0 {
            f.write_str(",")?;
        }
        write!(f, "{x:.3}")?;
    }
    Ok(())
}

impl fmt::Display for StatusReport {
    /// Same layout GRBL prints (field order as in `report.c`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "<{}|", self.state)?;
        f.write_str(match self.position_kind {
            PositionKind::Machine => "MPos:",
            PositionKind::Work => "WPos:",
        })?;
        fmt_axes(f, &self.position)?;
        if let Some((blocks, bytes)) = self.buffer {
            write!(f, "|Bf:{blocks},{bytes}")?;
        }
        if let Some(n) = self.line_number {
            write!(f, "|Ln:{n}")?;
        }
        match (self.feed, self.spindle) {
            (Some(feed), Some(s)) => write!(f, "|FS:{feed:.0},{s:.0}")?,
            (Some(feed), None) => write!(f, "|F:{feed:.0}")?,
            _ => {}
        }
        if let Some(p) = &self.pins {
            write!(f, "|Pn:{p}")?;
        }
        if let Some(w) = &self.wco {
            f.write_str("|WCO:")?;
            fmt_axes(f, w)?;
        }
        if let Some((a, b, c)) = self.overrides {
            write!(f, "|Ov:{a},{b},{c}")?;
        }
        if let Some(a) = &self.accessory {
            write!(f, "|A:{a}")?;
        }
        f.write_str(">")
    }
}

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
pub enum Command {
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

impl Command {
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn banner_ok_error_alarm() {
        assert_eq!(parse_line("Grbl 1.1h ['$' for help]\r").unwrap(), Response::Welcome { version: "1.1h".into() });
        assert_eq!(parse_line("ok").unwrap(), Response::Ok);
        assert_eq!(parse_line("").unwrap(), Response::Empty);
        let Response::Error(e) = parse_line("error:22").unwrap() else { panic!() };
        assert_eq!(e, ErrorCode(22));
        assert_eq!(e.meaning(), "Feed rate has not yet been set or is undefined.");
        let Response::Alarm(a) = parse_line("ALARM:2").unwrap() else { panic!() };
        assert_eq!(a, AlarmCode::SOFT_LIMIT);
        assert!(a.is_critical());
        assert!(a.meaning().starts_with("G-code motion target exceeds machine travel"));
        assert!(AlarmCode(1).meaning().starts_with("Hard limit triggered"));
        assert!(!AlarmCode(3).is_critical());
    }

    #[test]
    fn malformed_codes_are_typed_errors() {
        for bad in ["error:", "error:x", "error:300", "ALARM:-1", "ALARM:1a"] {
            assert!(matches!(parse_line(bad), Err(ParseError::BadCode { .. })), "{bad}");
        }
        assert!(matches!(parse_line("okay"), Err(ParseError::Unrecognised { .. })));
        assert!(matches!(parse_line("<Idle|MPos:0,0,0"), Err(ParseError::UnterminatedStatus { .. })));
        assert!(matches!(parse_line("<Walk|MPos:0,0,0>"), Err(ParseError::UnknownState { .. })));
        assert!(matches!(parse_line("<Idle|FS:0,0>"), Err(ParseError::MissingPosition { .. })));
        match parse_line("<Idle|MPos:0,abc,0>") {
            Err(ParseError::BadField { field, text, .. }) => {
                assert_eq!(field, "MPos");
                assert_eq!(text, "0,abc,0");
            }
            other => panic!("{other:?}"),
        }
        assert!(matches!(parse_line("<Idle|MPos:0,0,0|Bf:15>"), Err(ParseError::BadField { .. })));
        assert!(matches!(parse_line("[MSG:oops"), Err(ParseError::UnterminatedFeedback { .. })));
        assert!(matches!(parse_line("$x=1"), Err(ParseError::BadSetting { .. })));
        assert!(matches!(parse_line_bytes(b"ok\xff"), Err(ParseError::NotUtf8 { at: 2 })));
    }

    #[test]
    fn status_report_all_fields() {
        let line =
            "<Hold:0|WPos:1.000,-2.500,0.750|Bf:15,128|Ln:99|FS:30,0|Pn:XZ|WCO:0.000,1.000,2.000|Ov:100,50,120|A:SF>";
        let Response::Status(s) = parse_line(line).unwrap() else { panic!() };
        assert_eq!(s.state, MachineState::Hold(0));
        assert_eq!(s.position_kind, PositionKind::Work);
        assert_eq!(s.position.as_slice(), &[1.0, -2.5, 0.75]);
        assert_eq!(s.buffer, Some((15, 128)));
        assert_eq!(s.line_number, Some(99));
        assert_eq!(s.feed, Some(30.0));
        assert_eq!(s.spindle, Some(0.0));
        assert!(s.pin('Z') && s.pin('X') && !s.pin('Y'));
        assert_eq!(s.overrides, Some((100, 50, 120)));
        assert_eq!(s.accessory.as_deref(), Some("SF"));
        // WPos + WCO = MPos.
        assert_eq!(s.machine_position(2, None), Some(2.75));
        assert_eq!(s.to_string(), line);
        let Response::Status(m) = parse_line("<Idle|MPos:0.000,0.000,1.234|FS:0,0>").unwrap() else { panic!() };
        assert_eq!(m.machine_position(2, None), Some(1.234));
        assert_eq!(m.state, MachineState::Idle);
        // WPos without any WCO known: position cannot be converted.
        let Response::Status(w) = parse_line("<Run|WPos:0,0,1|F:30>").unwrap() else { panic!() };
        assert_eq!(w.machine_position(2, None), None);
        let wco = AxisValues::new(&[0.0, 0.0, -1.0]).unwrap();
        assert_eq!(w.machine_position(2, Some(&wco)), Some(0.0));
    }

    #[test]
    fn feedback_settings_startup_lines() {
        assert_eq!(parse_line("[MSG:'$H'|'$X' to unlock]").unwrap(), Response::Message("'$H'|'$X' to unlock".into()));
        assert_eq!(
            parse_line("[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]").unwrap(),
            Response::ParserState("G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0".split(' ').map(String::from).collect())
        );
        assert_eq!(
            parse_line("[VER:1.1h.20190830:rig-z]").unwrap(),
            Response::Version { version: "1.1h.20190830".into(), info: "rig-z".into() }
        );
        assert_eq!(
            parse_line("[OPT:V,15,128]").unwrap(),
            Response::Feedback { tag: "OPT".into(), body: "V,15,128".into() }
        );
        assert_eq!(parse_line("$102=6400.000").unwrap(), Response::Setting { number: 102, value: 6400.0 });
        assert_eq!(
            parse_line(">G21:error:20").unwrap(),
            Response::StartupLine { line: "G21".into(), result: Err(ErrorCode(20)) }
        );
        assert_eq!(parse_line(">G54:ok").unwrap(), Response::StartupLine { line: "G54".into(), result: Ok(()) });
    }

    #[test]
    fn encodes_documented_lines() {
        let c = Command::Feed { distance: Distance::Absolute, axis: 'Z', mm: 1.234, feed_mm_min: 60.0 };
        assert_eq!(c.encode().unwrap(), "G90 G1 Z1.2340 F60.0000\n");
        let c = Command::Feed { distance: Distance::Incremental, axis: 'z', mm: 0.05, feed_mm_min: 30.0 };
        assert_eq!(c.encode().unwrap(), "G91 G1 Z0.0500 F30.0000\n");
        let j = Command::Jog { distance: Distance::Incremental, axis: 'Z', mm: -0.0, feed_mm_min: 30.0 };
        assert_eq!(j.encode().unwrap(), "$J=G91 G21 Z0.0000 F30.0000\n");
        assert_eq!(Command::Home.encode().unwrap(), "$H\n");
        assert_eq!(Command::Unlock.encode().unwrap(), "$X\n");
        assert_eq!(Command::SetSetting { number: 20, value: 1.0 }.encode().unwrap(), "$20=1.0000\n");
        assert_eq!(Realtime::StatusQuery.byte(), b'?');
        assert_eq!(Realtime::FeedHold.byte(), b'!');
        assert_eq!(Realtime::CycleStart.byte(), b'~');
        assert_eq!(Realtime::SoftReset.byte(), 0x18);
        for r in
            [Realtime::StatusQuery, Realtime::FeedHold, Realtime::CycleStart, Realtime::SoftReset, Realtime::JogCancel]
        {
            assert_eq!(Realtime::from_byte(r.byte()), Some(r));
        }
    }

    #[test]
    fn encode_rejects_bad_values() {
        let mk = |mm: f64, f: f64| Command::Feed { distance: Distance::Absolute, axis: 'Z', mm, feed_mm_min: f };
        assert!(matches!(mk(f64::NAN, 1.0).encode(), Err(EncodeError::NotFinite { .. })));
        assert!(matches!(mk(1.0, 0.0).encode(), Err(EncodeError::NotPositive { .. })));
        assert!(matches!(mk(1e80, 1.0).encode(), Err(EncodeError::TooLong { .. })));
        assert!(matches!(
            Command::Rapid { distance: Distance::Absolute, axis: 'Q', mm: 0.0 }.encode(),
            Err(EncodeError::BadAxis('Q'))
        ));
    }

    #[test]
    fn splitter_handles_crlf_fragments_and_overflow() {
        let mut s = LineSplitter::new();
        let mut out = Vec::new();
        s.push(b"\r\nGrbl 1.1h ['$' for help]\r\no", &mut out);
        s.push(b"k\r\n", &mut out);
        let lines: Vec<_> = out.into_iter().map(|r| r.unwrap()).collect();
        assert_eq!(lines, vec![b"".to_vec(), b"Grbl 1.1h ['$' for help]".to_vec(), b"ok".to_vec()]);
        let mut out = Vec::new();
        s.push(&vec![b'x'; MAX_RESPONSE_LINE + 10], &mut out);
        s.push(b"\nok\n", &mut out);
        assert_eq!(out.len(), 2);
        assert!(matches!(out[0], Err(ParseError::TooLong { .. })));
        assert_eq!(out[1].as_deref().unwrap(), b"ok");
    }

    fn arb_state() -> impl Strategy<Value = MachineState> {
        prop_oneof![
            Just(MachineState::Idle),
            Just(MachineState::Run),
            (0u8..=1).prop_map(MachineState::Hold),
            Just(MachineState::Jog),
            Just(MachineState::Alarm),
            (0u8..=3).prop_map(MachineState::Door),
            Just(MachineState::Check),
            Just(MachineState::Home),
            Just(MachineState::Sleep),
        ]
    }

    fn arb_axes() -> impl Strategy<Value = AxisValues> {
        proptest::collection::vec(-1_000_000i64..1_000_000, 3)
            .prop_map(|v| AxisValues::new(&v.iter().map(|&x| x as f64 / 1000.0).collect::<Vec<_>>()).unwrap())
    }

    proptest! {
        #[test]
        fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
            let _ = parse_line_bytes(&bytes);
            let mut s = LineSplitter::new();
            let mut out = Vec::new();
            s.push(&bytes, &mut out);
            for l in out.into_iter().flatten() {
                let _ = parse_line_bytes(&l);
            }
        }

        #[test]
        fn grbl_like_lines_never_panic(line in "[<\\[$>]?[A-Za-z0-9:|,.\\-=\\]>\\[ ]{0,90}") {
            let _ = parse_line(&line);
        }

        #[test]
        fn status_round_trip(
            state in arb_state(),
            machine in any::<bool>(),
            pos in arb_axes(),
            wco in proptest::option::of(arb_axes()),
            buffer in proptest::option::of((0u16..=15, 0u16..=128)),
            feed in proptest::option::of(0u32..5000),
            pins in proptest::option::of("[XYZP]{1,4}"),
            ov in proptest::option::of((10u16..=200, 25u16..=100, 10u16..=200)),
        ) {
            let report = StatusReport {
                state,
                position_kind: if machine { PositionKind::Machine } else { PositionKind::Work },
                position: pos,
                wco,
                buffer,
                line_number: None,
                feed: feed.map(f64::from),
                spindle: feed.map(|_| 0.0),
                pins,
                overrides: ov,
                accessory: None,
            };
            let text = report.to_string();
            prop_assert_eq!(parse_line(&text).unwrap(), Response::Status(report));
        }

        #[test]
        fn error_and_alarm_codes_round_trip(code in any::<u8>()) {
            prop_assert_eq!(parse_line(&format!("error:{code}")).unwrap(), Response::Error(ErrorCode(code)));
            prop_assert_eq!(parse_line(&format!("ALARM:{code}")).unwrap(), Response::Alarm(AlarmCode(code)));
        }

        #[test]
        fn encoded_moves_are_short_and_parse_back(mm in -1000.0f64..1000.0, feed in 0.1f64..5000.0) {
            let line = Command::Feed { distance: Distance::Absolute, axis: 'Z', mm, feed_mm_min: feed }.encode().unwrap();
            prop_assert!(line.len() <= LINE_BUFFER_SIZE);
            prop_assert!(line.ends_with('\n'));
            let z: f64 = line.split_whitespace().find_map(|w| w.strip_prefix('Z')).unwrap().parse().unwrap();
            prop_assert!((z - mm).abs() <= 5e-5);
        }
    }
}
