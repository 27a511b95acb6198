//! The machine state and the `<...>` status report.

use std::fmt;

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
    pub(super) fn parse(s: &str) -> Option<Self> {
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
