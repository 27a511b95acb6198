//! GRBL 1.1 emulator driving the rig's stage axis (docs/hardware.md section B).
//!
//! Modelled: the banner on power-up and on soft reset, the homing lock
//! (Alarm at power-up with `$22=1`), `ok`/`error:N` for every line, status
//! reports (`$10` mask: MPos/WPos, `Bf:`), `WCO:`/`Ov:` now and then, `Pn:`,
//! the homing cycle (`ok` only when it ends, `?` unanswered meanwhile), G0/G1
//! moves queued in a 15-block planner, G4 dwell, `$J=` jogs, feed hold `!` /
//! resume `~` / soft reset 0x18 (ALARM:3 if reset while moving), soft limits
//! (ALARM:2, position kept) and hard limits (ALARM:1 when a move runs onto a
//! switch, position lost), critical alarms that ignore everything but a reset,
//! and a 128-byte RX buffer that drops bytes on overflow as GRBL's serial ISR
//! does.
//!
//! Not modelled: the feed rate does not change the axis speed (the rig's
//! `Axis` has one velocity profile); `F` is checked, remembered and reported
//! only. Inches (G20), arcs, probing, spindle/coolant, check mode `$C`, work
//! offsets (WCO is always 0). Homing sets the origin at the switch, as with
//! `HOMING_FORCE_SET_ORIGIN`, so travel is positive from home.

mod commands;
mod machine;

use std::io;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::axis::AxisConfig;
use super::pty::PtyMaster;
use super::rig::Rig;
use machine::Emulator;

/// Axis preset for a low-cost stepper micrometer on a GRBL board: a lead
/// screw at 6400 microsteps per mm, 2 mm/s, 4 mm/s², powered up 3 mm from home.
pub fn stepper_stage_axis(travel_mm: f64) -> AxisConfig {
    AxisConfig {
        max_velocity: 2.0,
        acceleration: 4.0,
        min_position: 0.0,
        max_position: travel_mm,
        resolution: 1.0 / 6400.0,
        backlash: 0.0,
        home_velocity: 2.0,
        power_on_position: 3.0,
    }
}

/// A rotation axis with no stops, for rigs whose controller drives the stage only.
pub fn free_rotation_axis() -> AxisConfig {
    AxisConfig {
        max_velocity: 10.0,
        acceleration: 20.0,
        min_position: -1e6,
        max_position: 1e6,
        resolution: 1e-4,
        backlash: 0.0,
        home_velocity: 5.0,
        power_on_position: 0.0,
    }
}

/// Emulated controller settings.
#[derive(Debug, Clone, PartialEq)]
pub struct GrblEmulatorConfig {
    /// Axis letter mapped onto the rig's stage axis.
    pub axis: char,
    /// Version printed in the banner, e.g. `1.1h`.
    pub version: String,
    /// Build date printed by `$I`.
    pub build_date: String,
    /// User build-info string (`$I=...`), printed by `$I`.
    pub build_info: String,
    /// `$22` homing enable (also the power-up homing lock).
    pub homing_enabled: bool,
    /// `$20` soft limits.
    pub soft_limits: bool,
    /// `$21` hard limits.
    pub hard_limits: bool,
    /// `$10` status report mask: bit 0 MPos (else WPos), bit 1 `Bf:`.
    pub status_mask: u8,
    /// Serial RX buffer, bytes.
    pub rx_buffer: usize,
    /// Planner blocks (GRBL on an Uno: 16, one kept free).
    pub planner_blocks: usize,
    /// Print the banner when the emulator starts (power-up).
    pub banner_on_start: bool,
}

impl Default for GrblEmulatorConfig {
    fn default() -> Self {
        Self {
            axis: 'Z',
            version: "1.1h".into(),
            build_date: "20190830".into(),
            build_info: String::new(),
            homing_enabled: true,
            soft_limits: true,
            hard_limits: true,
            status_mask: 1,
            rx_buffer: 128,
            planner_blocks: 15,
            banner_on_start: true,
        }
    }
}

/// Counters a test can assert on after the emulator ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GrblEmulatorStats {
    pub lines: u64,
    pub errors: u64,
    pub alarms: u64,
    pub resets: u64,
    pub status_reports: u64,
    /// Bytes dropped because the RX buffer was full (a host without flow control).
    pub rx_overflow_bytes: u64,
    /// Highest RX buffer fill seen, bytes.
    pub rx_high_water: usize,
}

#[derive(Debug)]
enum Control {
    Cut,
    Alarm(u8),
}

/// Commands into a running emulator.
#[derive(Debug, Clone)]
pub struct GrblControl {
    tx: mpsc::UnboundedSender<Control>,
}

/// Receiving end of [`GrblControl`], handed to [`run_grbl_emulator`].
#[derive(Debug)]
pub struct GrblControlRx {
    rx: mpsc::UnboundedReceiver<Control>,
}

/// A control channel for one emulator.
pub fn grbl_control() -> (GrblControl, GrblControlRx) {
    let (tx, rx) = mpsc::unbounded_channel();
    (GrblControl { tx }, GrblControlRx { rx })
}

impl GrblControl {
    /// Pull the cable: the emulator stops and drops its end of the link.
    pub fn cut_cable(&self) {
        let _ = self.tx.send(Control::Cut);
    }
    /// Raise `ALARM:code` as if the machine had tripped it (1 = hard limit).
    pub fn inject_alarm(&self, code: u8) {
        let _ = self.tx.send(Control::Alarm(code));
    }
}

/// A GRBL emulator serving a pseudo-terminal.
#[derive(Debug)]
pub struct GrblPort {
    /// Slave path for the driver to open, e.g. `/dev/pts/7`.
    pub path: PathBuf,
    pub task: JoinHandle<io::Result<GrblEmulatorStats>>,
    pub control: GrblControl,
}

impl GrblPort {
    /// Slave path for the driver to open.
    pub fn path(&self) -> &Path {
        &self.path
    }
    /// Close the pty master (the driver sees a hang-up).
    pub fn cut_cable(&self) {
        self.control.cut_cable();
    }
    pub fn inject_alarm(&self, code: u8) {
        self.control.inject_alarm(code);
    }
}

/// Start a GRBL emulator on a new pseudo-terminal, driving `rig`'s stage axis.
pub async fn serve_grbl_stage(rig: Rig, cfg: GrblEmulatorConfig) -> io::Result<GrblPort> {
    let master = PtyMaster::open()?;
    let path = master.slave_path().to_path_buf();
    let (control, rx) = grbl_control();
    let task = tokio::spawn(run_grbl_emulator(master, rig, cfg, rx));
    Ok(GrblPort { path, task, control })
}

/// Run the emulator over any byte stream until the stream ends or the cable is cut.
pub async fn run_grbl_emulator<T: AsyncRead + AsyncWrite + Unpin>(
    mut io: T,
    rig: Rig,
    cfg: GrblEmulatorConfig,
    mut control: GrblControlRx,
) -> io::Result<GrblEmulatorStats> {
    let mut emu = Emulator::new(rig, cfg);
    if emu.cfg.banner_on_start {
        emu.banner();
    }
    let mut buf = [0u8; 512];
    loop {
        if !emu.out.is_empty() {
            let out = std::mem::take(&mut emu.out);
            io.write_all(&out).await?;
            io.flush().await?;
        }
        let tick = if emu.busy() { Duration::from_millis(2) } else { Duration::from_millis(50) };
        tokio::select! {
            r = io.read(&mut buf) => {
                let n = r?;
                if n == 0 {
                    return Ok(emu.stats);
                }
                emu.ingest(&buf[..n]);
            }
            c = control.rx.recv() => match c {
                Some(Control::Cut) | None => return Ok(emu.stats),
                Some(Control::Alarm(code)) => emu.raise_alarm(code),
            },
            _ = tokio::time::sleep(tick) => {}
        }
        emu.step();
    }
}

#[cfg(test)]
mod tests;
