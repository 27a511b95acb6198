//! What the GRBL emulator does with one line: `$` system commands and
//! settings, and G-code blocks (G0/G1 moves, G4 dwell, `$J=` jogs) planned
//! onto the stage axis, with GRBL's error codes.

use super::machine::{Block, Blocker, Emulator, Motion, State};

impl Emulator {
    pub(super) fn system_command(&mut self, rest: &str) {
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
                self.set_setting(rest);
            }
        }
    }

    /// `$N=value`: change setting N (GRBL's checks and error codes).
    fn set_setting(&mut self, rest: &str) {
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

    /// Parse and run one G-code block (or the body of a `$J=` jog).
    pub(super) fn gcode(&mut self, text: &str, jog: bool) -> Result<(), u8> {
        let b = BlockWords::of(&words(text)?, jog)?;
        let has_axes = b.axes.iter().any(Option::is_some);
        if jog {
            let f = b.feed.ok_or(16u8)?;
            if !has_axes {
                return Err(16);
            }
            return self.plan(b.axes, b.absolute.unwrap_or(self.absolute), f, true);
        }
        if let Some(a) = b.absolute {
            self.absolute = a;
        }
        if let Some(f) = b.feed {
            self.feed = Some(f);
        }
        if b.dwell {
            if has_axes {
                return Err(31);
            }
            let s = b.p.ok_or(28u8)?;
            if s < 0.0 {
                return Err(4);
            }
            self.blocker = Some(Blocker::Dwell { seconds: s, started: None });
            return Ok(());
        }
        if b.p.is_some() {
            return Err(36);
        }
        if let Some(m) = b.motion {
            self.motion = m;
        }
        if !has_axes {
            if b.motion.is_some() {
                return Err(26);
            }
            self.ok();
            return Ok(());
        }
        let f = match self.motion {
            Motion::Rapid => self.setting(110 + self.axis as u16),
            Motion::Feed => self.feed.ok_or(22u8)?,
        };
        self.plan(b.axes, self.absolute, f, false)
    }

    pub(super) fn plan(&mut self, words: [Option<f64>; 3], absolute: bool, feed: f64, jog: bool) -> Result<(), u8> {
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

/// The words of a block (`G1`, `Z2.5`, `F60`): a letter, then a number.
fn words(text: &str) -> Result<Vec<(char, f64)>, u8> {
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
        while i < bytes.len() && (bytes[i].is_ascii_digit() || bytes[i] == b'.' || bytes[i] == b'-' || bytes[i] == b'+')
        {
            i += 1;
        }
        let v: f64 = text[start..i].parse().map_err(|_| 2u8)?;
        words.push((letter, v));
    }
    Ok(words)
}

/// What one block asks for, each modal group at most once.
#[derive(Debug, Default)]
struct BlockWords {
    motion: Option<Motion>,
    absolute: Option<bool>,
    dwell: bool,
    /// X, Y, Z targets.
    axes: [Option<f64>; 3],
    feed: Option<f64>,
    p: Option<f64>,
}

impl BlockWords {
    /// Sort a block's words into their groups, with GRBL's error codes for
    /// repeated, conflicting or unsupported words (a jog allows fewer).
    fn of(words: &[(char, f64)], jog: bool) -> Result<Self, u8> {
        let mut b = BlockWords::default();
        for &(letter, v) in words {
            match letter {
                'G' => b.g_word(v, jog)?,
                'X' | 'Y' | 'Z' => {
                    let k = (letter as u8 - b'X') as usize;
                    if b.axes[k].is_some() {
                        return Err(25);
                    }
                    b.axes[k] = Some(v);
                }
                'F' => {
                    if b.feed.is_some() {
                        return Err(25);
                    }
                    if v <= 0.0 {
                        return Err(4);
                    }
                    b.feed = Some(v);
                }
                'P' => b.p = Some(v),
                'N' => {
                    if !(1.0..=9_999_999.0).contains(&v) {
                        return Err(27);
                    }
                }
                _ => return Err(if jog { 16 } else { 20 }),
            }
        }
        Ok(b)
    }

    fn g_word(&mut self, v: f64, jog: bool) -> Result<(), u8> {
        let code = (v * 10.0).round() as i64;
        match code {
            0 | 10 => {
                if self.motion.is_some() || jog {
                    return Err(if jog { 16 } else { 21 });
                }
                self.motion = Some(if code == 0 { Motion::Rapid } else { Motion::Feed });
            }
            40 => {
                if jog {
                    return Err(16);
                }
                self.dwell = true;
            }
            900 | 910 => {
                if self.absolute.is_some() {
                    return Err(21);
                }
                self.absolute = Some(code == 900);
            }
            // Plane, units mm, WCS 1, feed per minute: the state this emulator always has.
            170 | 210 | 540 | 940 => {}
            _ => return Err(if jog { 16 } else { 20 }),
        }
        Ok(())
    }
}
