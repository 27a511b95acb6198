//! The GRBL controller's state machine: the serial input, the line buffer,
//! the planner queue, motion on the rig's stage axis, status reports, feed
//! hold, soft reset and alarms. The commands themselves are in `commands.rs`.

use std::collections::VecDeque;

use super::{GrblEmulatorConfig, GrblEmulatorStats};
use crate::emulator::rig::Rig;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum State {
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
pub(super) struct Block {
    /// Target of the driven axis, counter coordinates (mm from home).
    pub(super) target: f64,
    pub(super) feed: f64,
    pub(super) jog: bool,
    /// Runs onto a limit switch (soft limits off): hard-limit alarm on arrival.
    pub(super) to_switch: bool,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Blocker {
    /// `$H` answered when the homing count passes this.
    Homing { homes_before: u64 },
    /// `G4`: waits for the planner to empty, then dwells.
    Dwell { seconds: f64, started: Option<f64> },
    /// A motion block waiting for planner space.
    PlannerFull(Block),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Motion {
    Rapid,
    Feed,
}

pub(super) struct Emulator {
    pub(super) rig: Rig,
    pub(super) cfg: GrblEmulatorConfig,
    pub(super) axis: usize,
    pub(super) out: Vec<u8>,
    pub(super) stats: GrblEmulatorStats,
    pub(super) rx: VecDeque<u8>,
    pub(super) line: Vec<u8>,
    pub(super) line_overflow: bool,
    pub(super) state: State,
    pub(super) critical: bool,
    pub(super) blocker: Option<Blocker>,
    pub(super) queue: VecDeque<Block>,
    pub(super) current: Option<Block>,
    pub(super) motion: Motion,
    pub(super) absolute: bool,
    pub(super) feed: Option<f64>,
    /// Axes the rig does not drive jump straight to their targets.
    pub(super) other_axes: [f64; 3],
    pub(super) reports: u64,
    pub(super) settings: Vec<(u16, f64)>,
    /// A feed hold is cancelling a jog: end in Idle, not Hold.
    pub(super) jog_cancelled: bool,
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
    pub(super) fn new(rig: Rig, cfg: GrblEmulatorConfig) -> Self {
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

    pub(super) fn say(&mut self, line: &str) {
        self.out.extend_from_slice(line.as_bytes());
        self.out.extend_from_slice(b"\r\n");
    }

    pub(super) fn banner(&mut self) {
        let b = format!("\r\nGrbl {} ['$' for help]", self.cfg.version);
        self.say(&b);
        if self.state == State::Alarm {
            self.say("[MSG:'$H'|'$X' to unlock]");
        }
    }

    pub(super) fn busy(&self) -> bool {
        self.blocker.is_some() || !matches!(self.state, State::Idle | State::Alarm) || self.current.is_some()
    }

    pub(super) fn ok(&mut self) {
        self.say("ok");
    }

    pub(super) fn error(&mut self, code: u8) {
        self.stats.errors += 1;
        self.say(&format!("error:{code}"));
    }

    pub(super) fn ingest(&mut self, bytes: &[u8]) {
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

    pub(super) fn axis_now(&self) -> (f64, bool, u64, bool, bool, bool) {
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

    pub(super) fn status_report(&mut self) {
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

    pub(super) fn setting(&self, n: u16) -> f64 {
        self.settings.iter().find(|(k, _)| *k == n).map_or(0.0, |(_, v)| *v)
    }

    pub(super) fn feed_hold(&mut self) {
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

    pub(super) fn cycle_start(&mut self) {
        if matches!(self.state, State::Hold { complete: true }) {
            self.state = State::Run;
            match self.current {
                Some(b) => self.start_block(b),
                None => self.next_block(),
            }
        }
    }

    pub(super) fn soft_reset(&mut self) {
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

    pub(super) fn alarm_line(&mut self, code: u8) {
        self.stats.alarms += 1;
        self.say(&format!("ALARM:{code}"));
    }

    pub(super) fn raise_alarm(&mut self, code: u8) {
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
    pub(super) fn step_motion(&mut self) {
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

    pub(super) fn step(&mut self) {
        self.step_motion();
        self.process_lines();
    }

    pub(super) fn next_block(&mut self) {
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

    pub(super) fn start_block(&mut self, b: Block) {
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

    pub(super) fn enqueue(&mut self, b: Block) {
        if matches!(self.state, State::Idle) && self.current.is_none() {
            self.start_block(b);
        } else {
            self.queue.push_back(b);
        }
    }

    pub(super) fn process_lines(&mut self) {
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

    pub(super) fn execute(&mut self, raw: &[u8]) {
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
}
