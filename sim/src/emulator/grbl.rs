//! GRBL 1.1 emulator driving the rig's stage axis (hardware.md section B).
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

use std::collections::VecDeque;
use std::io;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::axis::AxisConfig;
use super::pty::PtyMaster;
use super::rig::Rig;

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

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    Run,
    /// `complete` once decelerated.
    Hold {
        complete: bool,
    },
    Jog,
    Alarm,
    Home,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Block {
    /// Target of the driven axis, counter coordinates (mm from home).
    target: f64,
    feed: f64,
    jog: bool,
    /// Runs onto a limit switch (soft limits off): hard-limit alarm on arrival.
    to_switch: bool,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Blocker {
    /// `$H` answered when the homing count passes this.
    Homing { homes_before: u64 },
    /// `G4`: waits for the planner to empty, then dwells.
    Dwell { seconds: f64, started: Option<f64> },
    /// A motion block waiting for planner space.
    PlannerFull(Block),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Motion {
    Rapid,
    Feed,
}

struct Emulator {
    rig: Rig,
    cfg: GrblEmulatorConfig,
    axis: usize,
    out: Vec<u8>,
    stats: GrblEmulatorStats,
    rx: VecDeque<u8>,
    line: Vec<u8>,
    line_overflow: bool,
    state: State,
    critical: bool,
    blocker: Option<Blocker>,
    queue: VecDeque<Block>,
    current: Option<Block>,
    motion: Motion,
    absolute: bool,
    feed: Option<f64>,
    /// Axes the rig does not drive jump straight to their targets.
    other_axes: [f64; 3],
    reports: u64,
    settings: Vec<(u16, f64)>,
    /// A feed hold is cancelling a jog: end in Idle, not Hold.
    jog_cancelled: bool,
}

/// `$$` settings of a stock GRBL 1.1 (values for a 6400 steps/mm micrometer on Z).
const DEFAULT_SETTINGS: &[(u16, f64)] = &[
    (0, 10.0),
    (1, 25.0),
    (2, 0.0),
    (3, 0.0),
    (4, 0.0),
    (5, 0.0),
    (6, 0.0),
    (10, 1.0),
    (11, 0.010),
    (12, 0.002),
    (13, 0.0),
    (20, 0.0),
    (21, 0.0),
    (22, 0.0),
    (23, 0.0),
    (24, 25.0),
    (25, 500.0),
    (26, 250.0),
    (27, 1.0),
    (30, 1000.0),
    (31, 0.0),
    (32, 0.0),
    (100, 250.0),
    (101, 250.0),
    (102, 6400.0),
    (110, 500.0),
    (111, 500.0),
    (112, 120.0),
    (120, 10.0),
    (121, 10.0),
    (122, 4.0),
    (130, 200.0),
    (131, 200.0),
    (132, 25.0),
];

impl Emulator {
    fn new(rig: Rig, cfg: GrblEmulatorConfig) -> Self {
        let axis = match cfg.axis.to_ascii_uppercase() {
            'X' => 0,
            'Y' => 1,
            _ => 2,
        };
        let mut settings = DEFAULT_SETTINGS.to_vec();
        let set = |s: &mut Vec<(u16, f64)>, n: u16, v: f64| {
            if let Some(e) = s.iter_mut().find(|(k, _)| *k == n) {
                e.1 = v;
            }
        };
        set(&mut settings, 10, f64::from(cfg.status_mask));
        set(&mut settings, 20, f64::from(u8::from(cfg.soft_limits)));
        set(&mut settings, 21, f64::from(u8::from(cfg.hard_limits)));
        set(&mut settings, 22, f64::from(u8::from(cfg.homing_enabled)));
        let (lo, hi) = rig.with_stage(|ax, _| (ax.config().min_position, ax.config().max_position));
        set(&mut settings, 132, hi - lo);
        let state = if cfg.homing_enabled { State::Alarm } else { State::Idle };
        Self {
            rig,
            cfg,
            axis,
            out: Vec::new(),
            stats: GrblEmulatorStats::default(),
            rx: VecDeque::new(),
            line: Vec::new(),
            line_overflow: false,
            state,
            critical: false,
            blocker: None,
            queue: VecDeque::new(),
            current: None,
            motion: Motion::Rapid,
            absolute: true,
            feed: None,
            other_axes: [0.0; 3],
            reports: 0,
            settings,
            jog_cancelled: false,
        }
    }

    fn say(&mut self, line: &str) {
        self.out.extend_from_slice(line.as_bytes());
        self.out.extend_from_slice(b"\r\n");
    }

    fn banner(&mut self) {
        let b = format!("\r\nGrbl {} ['$' for help]", self.cfg.version);
        self.say(&b);
        if self.state == State::Alarm {
            self.say("[MSG:'$H'|'$X' to unlock]");
        }
    }

    fn busy(&self) -> bool {
        self.blocker.is_some() || !matches!(self.state, State::Idle | State::Alarm) || self.current.is_some()
    }

    fn ok(&mut self) {
        self.say("ok");
    }

    fn error(&mut self, code: u8) {
        self.stats.errors += 1;
        self.say(&format!("error:{code}"));
    }

    fn ingest(&mut self, bytes: &[u8]) {
        for &b in bytes {
            match b {
                b'?' => {
                    self.step_motion();
                    self.status_report();
                }
                b'!' => self.feed_hold(),
                b'~' => self.cycle_start(),
                0x18 => self.soft_reset(),
                // Jog cancel and the override/accessory bytes: real-time, never buffered.
                0x80..=0xff => {
                    if b == 0x85 && self.state == State::Jog {
                        self.feed_hold();
                    }
                }
                _ => {
                    if self.rx.len() < self.cfg.rx_buffer {
                        self.rx.push_back(b);
                        self.stats.rx_high_water = self.stats.rx_high_water.max(self.rx.len());
                    } else {
                        self.stats.rx_overflow_bytes += 1;
                    }
                    // GRBL's main loop drains the buffer as lines complete; only
                    // a blocked planner or homing lets it fill up.
                    if b == b'\n' || b == b'\r' {
                        self.process_lines();
                    }
                }
            }
        }
        self.process_lines();
    }

    fn axis_now(&self) -> (f64, bool, u64, bool, bool, bool) {
        self.rig.with_stage(|ax, _| {
            (
                ax.position(),
                ax.is_moving(),
                ax.homes_completed(),
                ax.at_forward_limit(),
                ax.at_reverse_limit(),
                ax.is_homed(),
            )
        })
    }

    fn status_report(&mut self) {
        // GRBL answers no `?` while homing or locked in a critical alarm.
        if self.state == State::Home || self.critical {
            return;
        }
        self.stats.status_reports += 1;
        let (pos, moving, _, fwd, rev, homed) = self.axis_now();
        let mut axes = self.other_axes;
        axes[self.axis] = pos;
        let state = match self.state {
            State::Idle => "Idle".to_string(),
            State::Run => "Run".into(),
            State::Hold { complete } => format!("Hold:{}", if complete { 0 } else { 1 }),
            State::Jog => "Jog".into(),
            State::Alarm => "Alarm".into(),
            State::Home => "Home".into(),
        };
        let mask = self.setting(10) as u8;
        let kind = if mask & 1 == 1 { "MPos" } else { "WPos" };
        let mut s = format!("<{state}|{kind}:{:.3},{:.3},{:.3}", axes[0], axes[1], axes[2]);
        if mask & 2 == 2 {
            let free_blocks =
                self.cfg.planner_blocks.saturating_sub(self.queue.len() + usize::from(self.current.is_some()));
            let free_rx = self.cfg.rx_buffer - self.rx.len();
            s += &format!("|Bf:{free_blocks},{free_rx}");
        }
        let feed = match (self.current, moving) {
            (Some(b), true) => b.feed,
            _ => 0.0,
        };
        s += &format!("|FS:{feed:.0},0");
        // After homing GRBL pulls off the switch; the rig's axis rests on it, so
        // the reverse switch only reads triggered for an unhomed axis.
        let letter = ['X', 'Y', 'Z'][self.axis];
        if fwd || (rev && !homed) {
            s += &format!("|Pn:{letter}");
        }
        match self.reports % 10 {
            0 => s += "|WCO:0.000,0.000,0.000",
            1 => s += "|Ov:100,100,100",
            _ => {}
        }
        self.reports += 1;
        s.push('>');
        self.say(&s);
    }

    fn setting(&self, n: u16) -> f64 {
        self.settings.iter().find(|(k, _)| *k == n).map_or(0.0, |(_, v)| *v)
    }

    fn feed_hold(&mut self) {
        match self.state {
            State::Run | State::Jog => {
                self.rig.with_stage(|ax, t| ax.command_stop(t, false));
                if self.state == State::Jog {
                    // A hold cancels a jog: the rest of the jog is flushed.
                    self.queue.clear();
                    self.current = None;
                    self.state = State::Hold { complete: false };
                    self.jog_cancelled = true;
                } else {
                    self.state = State::Hold { complete: false };
                }
            }
            _ => {}
        }
    }

    fn cycle_start(&mut self) {
        if matches!(self.state, State::Hold { complete: true }) {
            self.state = State::Run;
            match self.current {
                Some(b) => self.start_block(b),
                None => self.next_block(),
            }
        }
    }

    fn soft_reset(&mut self) {
        let (_, moving, ..) = self.axis_now();
        let in_motion =
            moving || matches!(self.state, State::Run | State::Jog | State::Home | State::Hold { complete: false });
        if in_motion {
            self.rig.with_stage(|ax, t| ax.command_stop(t, true));
            let code = if self.state == State::Home { 6 } else { 3 };
            self.alarm_line(code);
            self.state = State::Alarm;
        }
        self.stats.resets += 1;
        self.critical = false;
        self.rx.clear();
        self.line.clear();
        self.line_overflow = false;
        self.queue.clear();
        self.current = None;
        self.blocker = None;
        self.motion = Motion::Rapid;
        self.absolute = true;
        if self.state != State::Alarm {
            self.state = State::Idle;
        }
        self.banner();
    }

    fn alarm_line(&mut self, code: u8) {
        self.stats.alarms += 1;
        self.say(&format!("ALARM:{code}"));
    }

    fn raise_alarm(&mut self, code: u8) {
        let critical = matches!(code, 1 | 2);
        let immediate = code != 2;
        self.rig.with_stage(|ax, t| ax.command_stop(t, immediate));
        self.queue.clear();
        self.current = None;
        self.blocker = None;
        self.alarm_line(code);
        if critical {
            self.say("[MSG:Reset to continue]");
            self.critical = true;
        }
        self.state = State::Alarm;
    }

    /// Advance motion: finish blocks, start queued ones, release blockers.
    fn step_motion(&mut self) {
        let (_, moving, homes, fwd, rev, _) = self.axis_now();
        match self.state {
            State::Home => {
                if let Some(Blocker::Homing { homes_before }) = self.blocker
                    && homes > homes_before
                    && !moving
                {
                    self.blocker = None;
                    self.state = State::Idle;
                    self.ok();
                }
            }
            State::Run | State::Jog if !moving => {
                if let Some(b) = self.current.take()
                    && b.to_switch
                    && (fwd || rev)
                    && self.cfg.hard_limits
                {
                    self.raise_alarm(1);
                    return;
                }
                self.next_block();
            }
            State::Hold { complete: false } if !moving => {
                if self.jog_cancelled {
                    self.jog_cancelled = false;
                    self.state = State::Idle;
                } else {
                    self.state = State::Hold { complete: true };
                }
            }
            _ => {}
        }
        if let Some(Blocker::PlannerFull(b)) = self.blocker
            && self.queue.len() + usize::from(self.current.is_some()) < self.cfg.planner_blocks
        {
            self.blocker = None;
            self.enqueue(b);
            self.ok();
        }
        if let Some(Blocker::Dwell { seconds, started }) = self.blocker
            && self.state == State::Idle
        {
            let now = self.rig.clock().now_s();
            match started {
                None => self.blocker = Some(Blocker::Dwell { seconds, started: Some(now) }),
                Some(t0) if now - t0 >= seconds => {
                    self.blocker = None;
                    self.ok();
                }
                Some(_) => {}
            }
        }
    }

    fn step(&mut self) {
        self.step_motion();
        self.process_lines();
    }

    fn next_block(&mut self) {
        match self.queue.pop_front() {
            Some(b) => self.start_block(b),
            None => {
                self.current = None;
                if matches!(self.state, State::Run | State::Jog) {
                    self.state = State::Idle;
                }
            }
        }
    }

    fn start_block(&mut self, b: Block) {
        self.current = Some(b);
        self.state = if b.jog { State::Jog } else { State::Run };
        let target = if b.to_switch {
            let (lo, hi) = self.rig.with_stage(|ax, _| ax.travel());
            b.target.clamp(lo, hi)
        } else {
            b.target
        };
        let accepted = self.rig.with_stage(|ax, t| ax.command_move_to(t, target));
        if !accepted {
            // Cannot happen after the travel checks; treat like a limit trip.
            self.raise_alarm(1);
        }
    }

    fn enqueue(&mut self, b: Block) {
        if matches!(self.state, State::Idle) && self.current.is_none() {
            self.start_block(b);
        } else {
            self.queue.push_back(b);
        }
    }

    fn process_lines(&mut self) {
        while self.blocker.is_none() && !self.critical && self.state != State::Home {
            let Some(b) = self.rx.pop_front() else { return };
            match b {
                b'\n' | b'\r' => {
                    let line = std::mem::take(&mut self.line);
                    if self.line_overflow {
                        self.line_overflow = false;
                        self.stats.lines += 1;
                        self.error(11);
                    } else {
                        // Like GRBL, CR LF counts as two lines (two `ok`s): send LF only.
                        self.stats.lines += 1;
                        self.execute(&line);
                    }
                }
                _ => {
                    if self.line.len() >= 79 {
                        self.line_overflow = true;
                    } else {
                        self.line.push(b);
                    }
                }
            }
        }
    }

    fn execute(&mut self, raw: &[u8]) {
        // GRBL drops spaces and comments and upper-cases before parsing.
        let mut text = String::new();
        let mut paren = false;
        for &c in raw {
            match c {
                b'(' => paren = true,
                b')' => paren = false,
                b';' if !paren => break,
                _ if paren => {}
                // GRBL throws away whitespace and control characters.
                _ if c <= b' ' => {}
                _ => text.push((c as char).to_ascii_uppercase()),
            }
        }
        if text.is_empty() {
            return self.ok();
        }
        if let Some(rest) = text.strip_prefix('$') {
            return self.system_command(rest);
        }
        if self.state == State::Alarm || self.state == State::Jog {
            return self.error(9);
        }
        match self.gcode(&text, false) {
            Ok(()) => {}
            Err(code) => self.error(code),
        }
    }

    fn system_command(&mut self, rest: &str) {
        match rest {
            "" => {
                self.say("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]");
                self.ok();
            }
            "$" => {
                let lines: Vec<String> = self
                    .settings
                    .iter()
                    .map(
                        |(n, v)| {
                            if v.fract() == 0.0 && *n < 100 { format!("${n}={v:.0}") } else { format!("${n}={v:.3}") }
                        },
                    )
                    .collect();
                for l in lines {
                    self.say(&l);
                }
                self.ok();
            }
            "I" => {
                let v = format!("[VER:{}.{}:{}]", self.cfg.version, self.cfg.build_date, self.cfg.build_info);
                self.say(&v);
                let o = format!("[OPT:V,{},{}]", self.cfg.planner_blocks + 1, self.cfg.rx_buffer);
                self.say(&o);
                self.ok();
            }
            "G" => {
                let m = match self.motion {
                    Motion::Rapid => "G0",
                    Motion::Feed => "G1",
                };
                let d = if self.absolute { "G90" } else { "G91" };
                let f = self.feed.unwrap_or(0.0);
                let l = format!("[GC:{m} G54 G17 G21 {d} G94 M5 M9 T0 F{f:.0} S0]");
                self.say(&l);
                self.ok();
            }
            "H" => {
                if self.setting(22) == 0.0 {
                    return self.error(5);
                }
                if !matches!(self.state, State::Idle | State::Alarm) {
                    return self.error(8);
                }
                let homes_before = self.rig.with_stage(|ax, t| {
                    let h = ax.homes_completed();
                    ax.command_home(t);
                    h
                });
                self.state = State::Home;
                self.blocker = Some(Blocker::Homing { homes_before });
            }
            "X" => {
                if self.state == State::Alarm {
                    self.say("[MSG:Caution: Unlocked]");
                    self.state = State::Idle;
                }
                self.ok();
            }
            _ => {
                if let Some(jog) = rest.strip_prefix("J=") {
                    if !matches!(self.state, State::Idle | State::Jog) {
                        return self.error(8);
                    }
                    return match self.gcode(jog, true) {
                        Ok(()) => {}
                        Err(code) => self.error(code),
                    };
                }
                if let Some(info) = rest.strip_prefix("I=") {
                    self.cfg.build_info = info.to_string();
                    return self.ok();
                }
                let Some((n, v)) = rest.split_once('=') else {
                    return self.error(3);
                };
                let (Ok(n), Ok(v)) = (n.parse::<u16>(), v.parse::<f64>()) else {
                    return self.error(3);
                };
                if !v.is_finite() {
                    return self.error(2);
                }
                if v < 0.0 {
                    return self.error(4);
                }
                if !self.settings.iter().any(|(k, _)| *k == n) {
                    return self.error(3);
                }
                if !matches!(self.state, State::Idle | State::Alarm) {
                    return self.error(8);
                }
                if n == 20 && v != 0.0 && self.setting(22) == 0.0 {
                    return self.error(10);
                }
                if let Some(e) = self.settings.iter_mut().find(|(k, _)| *k == n) {
                    e.1 = v;
                }
                match n {
                    20 => self.cfg.soft_limits = v != 0.0,
                    21 => self.cfg.hard_limits = v != 0.0,
                    22 => self.cfg.homing_enabled = v != 0.0,
                    _ => {}
                }
                self.ok();
            }
        }
    }

    /// Parse and run one G-code block (or the body of a `$J=` jog).
    fn gcode(&mut self, text: &str, jog: bool) -> Result<(), u8> {
        let bytes = text.as_bytes();
        let mut i = 0;
        let mut words: Vec<(char, f64)> = Vec::new();
        while i < bytes.len() {
            let letter = bytes[i] as char;
            if !letter.is_ascii_alphabetic() {
                return Err(1);
            }
            i += 1;
            let start = i;
            while i < bytes.len()
                && (bytes[i].is_ascii_digit() || bytes[i] == b'.' || bytes[i] == b'-' || bytes[i] == b'+')
            {
                i += 1;
            }
            let v: f64 = text[start..i].parse().map_err(|_| 2u8)?;
            words.push((letter, v));
        }
        let mut motion: Option<Motion> = None;
        let mut absolute: Option<bool> = None;
        let mut dwell = false;
        let mut axis_words = [None::<f64>; 3];
        let mut feed = None;
        let mut p = None;
        for (letter, v) in words {
            match letter {
                'G' => {
                    let code = (v * 10.0).round() as i64;
                    match code {
                        0 | 10 => {
                            if motion.is_some() || jog {
                                return Err(if jog { 16 } else { 21 });
                            }
                            motion = Some(if code == 0 { Motion::Rapid } else { Motion::Feed });
                        }
                        40 => {
                            if jog {
                                return Err(16);
                            }
                            dwell = true;
                        }
                        900 | 910 => {
                            if absolute.is_some() {
                                return Err(21);
                            }
                            absolute = Some(code == 900);
                        }
                        // Plane, units mm, WCS 1, feed per minute: the state this emulator always has.
                        170 | 210 | 540 | 940 => {}
                        _ => return Err(if jog { 16 } else { 20 }),
                    }
                }
                'X' | 'Y' | 'Z' => {
                    let k = (letter as u8 - b'X') as usize;
                    if axis_words[k].is_some() {
                        return Err(25);
                    }
                    axis_words[k] = Some(v);
                }
                'F' => {
                    if feed.is_some() {
                        return Err(25);
                    }
                    if v <= 0.0 {
                        return Err(4);
                    }
                    feed = Some(v);
                }
                'P' => p = Some(v),
                'N' => {
                    if !(1.0..=9_999_999.0).contains(&v) {
                        return Err(27);
                    }
                }
                _ => return Err(if jog { 16 } else { 20 }),
            }
        }
        let has_axes = axis_words.iter().any(Option::is_some);
        if jog {
            let f = feed.ok_or(16u8)?;
            if !has_axes {
                return Err(16);
            }
            return self.plan(axis_words, absolute.unwrap_or(self.absolute), f, true);
        }
        if let Some(a) = absolute {
            self.absolute = a;
        }
        if let Some(f) = feed {
            self.feed = Some(f);
        }
        if dwell {
            if has_axes {
                return Err(31);
            }
            let s = p.ok_or(28u8)?;
            if s < 0.0 {
                return Err(4);
            }
            self.blocker = Some(Blocker::Dwell { seconds: s, started: None });
            return Ok(());
        }
        if p.is_some() {
            return Err(36);
        }
        if let Some(m) = motion {
            self.motion = m;
        }
        if !has_axes {
            if motion.is_some() {
                return Err(26);
            }
            self.ok();
            return Ok(());
        }
        let f = match self.motion {
            Motion::Rapid => self.setting(110 + self.axis as u16),
            Motion::Feed => self.feed.ok_or(22u8)?,
        };
        self.plan(axis_words, self.absolute, f, false)
    }

    fn plan(&mut self, words: [Option<f64>; 3], absolute: bool, feed: f64, jog: bool) -> Result<(), u8> {
        // Where the driven axis will be when this block starts.
        let start = match (self.queue.back(), self.current) {
            (Some(b), _) => b.target,
            (None, Some(b)) => b.target,
            (None, None) => self.axis_now().0,
        };
        for (k, w) in words.iter().enumerate() {
            if k != self.axis
                && let Some(v) = w
            {
                self.other_axes[k] = if absolute { *v } else { self.other_axes[k] + v };
            }
        }
        let Some(w) = words[self.axis] else {
            self.ok();
            return Ok(());
        };
        let target = if absolute { w } else { start + w };
        let (lo, hi) = self.rig.with_stage(|ax, _| ax.travel());
        let inside = target >= lo - 1e-9 && target <= hi + 1e-9;
        if !inside && self.cfg.soft_limits {
            if jog {
                return Err(15);
            }
            self.raise_alarm(2);
            return Ok(());
        }
        let block = Block { target, feed, jog, to_switch: !inside };
        if self.queue.len() + usize::from(self.current.is_some()) >= self.cfg.planner_blocks {
            // `ok` only when the planner has room: the RX buffer fills meanwhile.
            self.blocker = Some(Blocker::PlannerFull(block));
            return Ok(());
        }
        self.enqueue(block);
        self.ok();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::VirtualClock;
    use tokio::io::{AsyncBufReadExt, BufReader, DuplexStream, ReadHalf, WriteHalf};

    fn rig(speedup: f64) -> Rig {
        Rig::new(VirtualClock::new(speedup), stepper_stage_axis(25.0), free_rotation_axis())
    }

    struct Host {
        rd: BufReader<ReadHalf<DuplexStream>>,
        wr: WriteHalf<DuplexStream>,
    }

    impl Host {
        async fn line(&mut self) -> String {
            let mut l = String::new();
            tokio::time::timeout(Duration::from_secs(5), self.rd.read_line(&mut l))
                .await
                .expect("emulator silent")
                .unwrap();
            l.trim_end().to_string()
        }
        /// Next line that is not a status report or empty.
        async fn reply(&mut self) -> String {
            loop {
                let l = self.line().await;
                if !l.is_empty() && !l.starts_with('<') {
                    return l;
                }
            }
        }
        async fn send(&mut self, s: &str) {
            self.wr.write_all(s.as_bytes()).await.unwrap();
        }
        async fn status(&mut self) -> String {
            self.send("?").await;
            loop {
                let l = self.line().await;
                if l.starts_with('<') {
                    return l;
                }
            }
        }
    }

    fn start(
        cfg: GrblEmulatorConfig,
        speedup: f64,
    ) -> (Host, GrblControl, Rig, JoinHandle<io::Result<GrblEmulatorStats>>) {
        let rig = rig(speedup);
        let (a, b) = tokio::io::duplex(4096);
        let (ctl, rx) = grbl_control();
        let task = tokio::spawn(run_grbl_emulator(b, rig.clone(), cfg, rx));
        let (rd, wr) = tokio::io::split(a);
        (Host { rd: BufReader::new(rd), wr }, ctl, rig, task)
    }

    fn z_of(status: &str) -> f64 {
        let p = status.split('|').nth(1).unwrap();
        p[5..].split(',').nth(2).unwrap().parse().unwrap()
    }

    #[tokio::test]
    async fn power_up_lock_home_and_move() {
        let (mut h, _ctl, rig, _t) = start(GrblEmulatorConfig::default(), 100.0);
        assert_eq!(h.line().await, "");
        assert_eq!(h.line().await, "Grbl 1.1h ['$' for help]");
        assert_eq!(h.line().await, "[MSG:'$H'|'$X' to unlock]");
        assert!(h.status().await.starts_with("<Alarm|MPos:0.000,0.000,3.000"));
        h.send("G1 Z1 F60\n").await;
        assert_eq!(h.reply().await, "error:9");
        h.send("$H\n").await;
        assert_eq!(h.reply().await, "ok");
        assert!(rig.with_stage(|ax, _| ax.is_homed()));
        let s = h.status().await;
        assert!(s.starts_with("<Idle|MPos:0.000,0.000,0.000"), "{s}");
        h.send("G1 Z2.5\n").await;
        assert_eq!(h.reply().await, "error:22");
        h.send("G90 G1 Z2.5 F120\n").await;
        assert_eq!(h.reply().await, "ok");
        assert!(h.status().await.starts_with("<Run|"));
        loop {
            let s = h.status().await;
            if s.starts_with("<Idle") {
                assert!((z_of(&s) - 2.5).abs() < 1e-3, "{s}");
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        h.send("G91 G0 Z-0.5\n").await;
        assert_eq!(h.reply().await, "ok");
        h.send("G4 P0.1\n").await;
        assert_eq!(h.reply().await, "ok");
        assert!((z_of(&h.status().await) - 2.0).abs() < 1e-3);
    }

    #[tokio::test]
    async fn soft_limit_alarm_is_critical_until_reset() {
        let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
        let (mut h, _ctl, rig, _t) = start(cfg, 100.0);
        h.send("G90 G1 Z30 F60\n").await;
        assert_eq!(h.reply().await, "ALARM:2");
        assert_eq!(h.reply().await, "[MSG:Reset to continue]");
        assert!(!rig.with_stage(|ax, _| ax.is_moving()));
        // Critical: lines and status requests get no answer until a reset.
        h.send("?$X\n").await;
        h.send("\u{18}").await;
        assert_eq!(h.line().await, "");
        assert_eq!(h.line().await, "Grbl 1.1h ['$' for help]");
        assert_eq!(h.line().await, "[MSG:'$H'|'$X' to unlock]");
        h.send("$X\n").await;
        assert_eq!(h.reply().await, "[MSG:Caution: Unlocked]");
        assert_eq!(h.reply().await, "ok");
        assert!((z_of(&h.status().await) - 3.0).abs() < 1e-9);
    }

    #[tokio::test]
    async fn hard_limit_when_soft_limits_off() {
        let cfg = GrblEmulatorConfig {
            homing_enabled: false,
            soft_limits: false,
            banner_on_start: false,
            ..Default::default()
        };
        let (mut h, _ctl, _rig, _t) = start(cfg, 200.0);
        h.send("G90 G0 Z-1\n").await;
        assert_eq!(h.reply().await, "ok");
        assert_eq!(h.reply().await, "ALARM:1");
    }

    #[tokio::test]
    async fn hold_resume_and_reset_during_motion() {
        let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
        let (mut h, _ctl, _rig, _t) = start(cfg, 20.0);
        h.send("G90 G1 Z20 F60\n").await;
        assert_eq!(h.reply().await, "ok");
        h.send("!").await;
        loop {
            let s = h.status().await;
            if s.starts_with("<Hold:0") {
                break;
            }
            assert!(s.starts_with("<Hold:1") || s.starts_with("<Run"), "{s}");
        }
        let held = z_of(&h.status().await);
        assert!(held < 20.0);
        h.send("~").await;
        assert!(h.status().await.starts_with("<Run"));
        // Reset while running: ALARM:3, banner, lock.
        h.send("\u{18}").await;
        assert_eq!(h.reply().await, "ALARM:3");
        assert_eq!(h.reply().await, "Grbl 1.1h ['$' for help]");
        assert_eq!(h.reply().await, "[MSG:'$H'|'$X' to unlock]");
        assert!(h.status().await.starts_with("<Alarm"));
    }

    #[tokio::test]
    async fn rx_buffer_overflow_drops_bytes() {
        let cfg = GrblEmulatorConfig {
            homing_enabled: false,
            banner_on_start: false,
            planner_blocks: 1,
            ..Default::default()
        };
        let (mut h, ctl, _rig, task) = start(cfg, 1.0);
        // One block runs, the next waits for planner space, the rest pile up in the RX buffer.
        let mut blast = String::new();
        for k in 0..10 {
            blast += &format!("G90 G1 Z{}.0000 F60.0000\n", 10 + k);
        }
        h.send(&blast).await;
        assert_eq!(h.reply().await, "ok");
        tokio::time::sleep(Duration::from_millis(50)).await;
        ctl.cut_cable();
        let stats = task.await.unwrap().unwrap();
        assert_eq!(stats.rx_high_water, 128);
        assert!(stats.rx_overflow_bytes > 0, "{stats:?}");
    }

    #[tokio::test]
    async fn errors_for_bad_lines() {
        let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
        let (mut h, _ctl, _rig, _t) = start(cfg, 1.0);
        for (line, want) in [
            ("1G0\n", "error:1"),
            ("G1 Zabc F10\n", "error:2"),
            ("$Q\n", "error:3"),
            ("G0 G1 Z1\n", "error:21"),
            ("G0 Z1 Z2\n", "error:25"),
            ("G1\n", "error:26"),
            ("G4\n", "error:28"),
            ("M3\n", "error:20"),
            ("$J=G91 Z1\n", "error:16"),
            ("$J=G90 Z99 F10\n", "error:15"),
            (&format!("G0 Z1 ({})\n", "x".repeat(90)), "error:11"),
            ("\n", "ok"),
        ] {
            h.send(line).await;
            assert_eq!(h.reply().await, want, "{line}");
        }
        h.send("$I\n").await;
        assert_eq!(h.reply().await, "[VER:1.1h.20190830:]");
        assert_eq!(h.reply().await, "[OPT:V,16,128]");
        assert_eq!(h.reply().await, "ok");
        h.send("$$\n").await;
        assert_eq!(h.reply().await, "$0=10");
    }

    #[tokio::test]
    async fn injected_alarm_and_cut() {
        let cfg = GrblEmulatorConfig { homing_enabled: false, banner_on_start: false, ..Default::default() };
        let (mut h, ctl, _rig, task) = start(cfg, 1.0);
        ctl.inject_alarm(1);
        assert_eq!(h.reply().await, "ALARM:1");
        ctl.cut_cable();
        task.await.unwrap().unwrap();
        let mut rest = String::new();
        h.rd.read_line(&mut rest).await.unwrap();
        // The stream is closed after the pending message.
        let mut more = String::new();
        assert_eq!(h.rd.read_line(&mut more).await.unwrap(), 0);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// Whatever a client sends, the emulator answers without panicking,
        /// and every complete line gets at most one `ok`/`error:N`.
        #[test]
        fn random_input_never_panics(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400)) {
            let cfg = GrblEmulatorConfig { homing_enabled: false, ..Default::default() };
            let mut emu = Emulator::new(rig(1000.0), cfg);
            emu.ingest(&bytes);
            emu.step();
            let out = String::from_utf8(emu.out.clone()).unwrap();
            let acks = out.lines().filter(|l| *l == "ok" || l.starts_with("error:")).count();
            let lines = bytes.iter().filter(|b| matches!(b, b'\n' | b'\r')).count();
            proptest::prop_assert!(acks <= lines, "{acks} answers to {lines} lines");
        }
    }
}
