//! What the TUI shows, kept apart from how it is drawn: `State` changes only
//! through [`State::apply`] (an event from the sequencer) and
//! [`State::on_key`] (a key from the operator), and drawing reads it.

use std::collections::VecDeque;

use ratatui::crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use sim::recording::Phase;

use crate::run::events::{
    DeviceStatus, FitUpdate, LogLevel, LoopView, Progress, RunControl, RunEvent, RunPhase, RunSummary,
};

/// Log lines kept for the log pane; older ones are dropped.
pub const LOG_CAPACITY: usize = 200;

/// The step the sequencer is running.
#[derive(Debug, Clone, PartialEq)]
pub struct StepInfo {
    /// From 0.
    pub index: usize,
    pub total: usize,
    pub name: String,
    pub phase: RunPhase,
}

/// Where the run stands, as far as the events have told.
#[derive(Debug, Clone, PartialEq)]
pub enum RunStatus {
    /// No step has started yet.
    Idle,
    Running,
    Paused,
    Aborted {
        reason: String,
    },
    Finished(RunSummary),
}

impl RunStatus {
    /// The run has ended (aborted or finished): no more controls make sense.
    pub fn is_over(&self) -> bool {
        matches!(self, RunStatus::Aborted { .. } | RunStatus::Finished(_))
    }

    pub fn label(&self) -> &'static str {
        match self {
            RunStatus::Idle => "WAITING",
            RunStatus::Running => "RUNNING",
            RunStatus::Paused => "PAUSED",
            RunStatus::Aborted { .. } => "ABORTED",
            RunStatus::Finished(_) => "FINISHED",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct LogEntry {
    pub level: LogLevel,
    pub message: String,
}

/// Everything the TUI displays.
#[derive(Debug, Clone, PartialEq)]
pub struct State {
    status: RunStatus,
    step: Option<StepInfo>,
    progress: Option<Progress>,
    devices: Option<DeviceStatus>,
    /// (gamma1, gamma2) of every normal sample, mm.
    normal: Vec<(f64, f64)>,
    /// (theta1, theta2) of every torsion sample, degrees.
    torsion: Vec<(f64, f64)>,
    samples: usize,
    fit: Option<FitUpdate>,
    log: VecDeque<LogEntry>,
    /// A control sent and not yet acknowledged by an event (shown as "pausing…").
    pending: Option<RunControl>,
    help: bool,
    quit: bool,
    /// The operator asked to quit again while the first request was pending.
    force_quit: bool,
    /// What the calibration history made of the finished run.
    history: Vec<String>,
    /// The diagnosis of the finished run's recording.
    diagnosis: Option<crate::report::RunDiagnosis>,
    /// An operator step waiting for the operator's confirmation.
    prompt: Option<OperatorPrompt>,
    /// The closed loop's latest decision point (`--adaptive`).
    closed_loop: Option<LoopView>,
}

/// What an operator step asks for ([`RunEvent::OperatorPrompt`]), shown in a
/// panel until confirmed (`c`) or aborted (`a`).
#[derive(Debug, Clone, PartialEq)]
pub struct OperatorPrompt {
    pub step: String,
    pub indenter: sim::physics::Body,
    pub message: String,
}

impl Default for State {
    fn default() -> Self {
        Self::new()
    }
}

impl State {
    pub fn new() -> Self {
        Self {
            status: RunStatus::Idle,
            history: Vec::new(),
            diagnosis: None,
            prompt: None,
            closed_loop: None,
            step: None,
            progress: None,
            devices: None,
            normal: Vec::new(),
            torsion: Vec::new(),
            samples: 0,
            fit: None,
            log: VecDeque::new(),
            pending: None,
            help: false,
            quit: false,
            force_quit: false,
        }
    }

    /// Fold one sequencer event into the state.
    pub fn apply(&mut self, ev: &RunEvent) {
        match ev {
            RunEvent::StepStarted { index, total, name, phase } => {
                self.step = Some(StepInfo { index: *index, total: *total, name: name.clone(), phase: *phase });
                if matches!(self.status, RunStatus::Idle) {
                    self.status = RunStatus::Running;
                }
            }
            RunEvent::Progress(p) => {
                self.progress = Some(*p);
                if matches!(self.status, RunStatus::Idle) {
                    self.status = RunStatus::Running;
                }
            }
            RunEvent::DeviceStatus(d) => self.devices = Some(*d),
            RunEvent::Sample(s) => {
                self.samples += 1;
                match s.phase {
                    Phase::Normal => self.normal.push((s.gamma1_mm, s.stage_mm - s.gamma1_mm)),
                    Phase::Torsion => self.torsion.push((s.theta1_deg, s.rot_deg - s.theta1_deg)),
                }
            }
            RunEvent::Fit(f) => self.fit = Some(*f),
            RunEvent::Log { level, message } => self.push_log(*level, message.clone()),
            RunEvent::Paused => {
                self.status = RunStatus::Paused;
                if self.pending == Some(RunControl::Pause) {
                    self.pending = None;
                }
            }
            RunEvent::Resumed => {
                self.status = RunStatus::Running;
                if self.pending == Some(RunControl::Resume) {
                    self.pending = None;
                }
            }
            RunEvent::OperatorPrompt { step, indenter, message } => {
                self.prompt =
                    Some(OperatorPrompt { step: step.clone(), indenter: *indenter, message: message.clone() });
                self.push_log(LogLevel::Warn, format!("{step}: {message}"));
            }
            RunEvent::OperatorConfirmed { step } => {
                self.prompt = None;
                if self.pending == Some(RunControl::Confirm) {
                    self.pending = None;
                }
                self.push_log(LogLevel::Info, format!("{step}: indenter mounted"));
            }
            RunEvent::Aborted { reason } => {
                self.status = RunStatus::Aborted { reason: reason.clone() };
                self.prompt = None;
                self.pending = None;
                self.push_log(LogLevel::Error, format!("aborted: {reason}"));
            }
            RunEvent::History { lines } => self.history = lines.clone(),
            RunEvent::ClosedLoop(v) => {
                self.push_log(LogLevel::Info, v.line());
                self.closed_loop = Some((**v).clone());
            }
            RunEvent::Diagnosis(d) => self.diagnosis = Some((**d).clone()),
            RunEvent::Finished { summary } => {
                self.status = RunStatus::Finished(summary.clone());
                self.pending = None;
            }
        }
    }

    fn push_log(&mut self, level: LogLevel, message: String) {
        if self.log.len() == LOG_CAPACITY {
            self.log.pop_front();
        }
        self.log.push_back(LogEntry { level, message });
    }

    /// React to a key; returns the control to send to the sequencer, if any.
    /// Keys that make no sense in the current status (resume while running,
    /// abort after the end) do nothing rather than confuse the sequencer.
    pub fn on_key(&mut self, key: KeyEvent) -> Option<RunControl> {
        if key.kind != KeyEventKind::Press {
            return None;
        }
        // Raw mode turns Ctrl-C into a key: treat it as the operator leaving.
        if key.modifiers.contains(KeyModifiers::CONTROL) && key.code == KeyCode::Char('c') {
            return self.request_quit();
        }
        if self.help {
            // Any key closes the help overlay; `q` still leaves.
            self.help = false;
            return match key.code {
                KeyCode::Char('q') => self.request_quit(),
                _ => None,
            };
        }
        match key.code {
            KeyCode::Char('?') | KeyCode::Char('h') | KeyCode::F(1) => {
                self.help = true;
                None
            }
            KeyCode::Char('p') if self.status == RunStatus::Running => {
                self.pending = Some(RunControl::Pause);
                Some(RunControl::Pause)
            }
            KeyCode::Char('r') if self.status == RunStatus::Paused => {
                self.pending = Some(RunControl::Resume);
                Some(RunControl::Resume)
            }
            KeyCode::Char('c') if self.prompt.is_some() && self.pending.is_none() => {
                self.pending = Some(RunControl::Confirm);
                Some(RunControl::Confirm)
            }
            KeyCode::Char('a') if !self.status.is_over() => {
                self.pending = Some(RunControl::Abort);
                Some(RunControl::Abort)
            }
            KeyCode::Char('q') | KeyCode::Esc => self.request_quit(),
            KeyCode::Enter if self.status.is_over() => {
                self.quit = true;
                None
            }
            _ => None,
        }
    }

    fn request_quit(&mut self) -> Option<RunControl> {
        // A second request while the sequencer has not answered the first
        // means it is stuck: let the operator leave anyway.
        if self.quit && !self.status.is_over() {
            self.force_quit = true;
        }
        self.quit = true;
        if self.status.is_over() {
            None
        } else {
            self.pending = Some(RunControl::Quit);
            Some(RunControl::Quit)
        }
    }

    pub fn status(&self) -> &RunStatus {
        &self.status
    }
    /// The history's verdict on the finished run (empty until it arrives).
    pub fn history(&self) -> &[String] {
        &self.history
    }
    /// The diagnosis of the finished run (none until it arrives, or when skipped).
    pub fn diagnosis(&self) -> Option<&crate::report::RunDiagnosis> {
        self.diagnosis.as_ref()
    }
    pub fn step(&self) -> Option<&StepInfo> {
        self.step.as_ref()
    }
    pub fn progress(&self) -> Option<&Progress> {
        self.progress.as_ref()
    }
    pub fn devices(&self) -> Option<&DeviceStatus> {
        self.devices.as_ref()
    }
    /// (gamma1, gamma2) of the normal samples so far, mm.
    pub fn normal_points(&self) -> &[(f64, f64)] {
        &self.normal
    }
    /// (theta1, theta2) of the torsion samples so far, degrees.
    pub fn torsion_points(&self) -> &[(f64, f64)] {
        &self.torsion
    }
    pub fn samples(&self) -> usize {
        self.samples
    }
    pub fn fit(&self) -> Option<&FitUpdate> {
        self.fit.as_ref()
    }
    pub fn log(&self) -> impl DoubleEndedIterator<Item = &LogEntry> + ExactSizeIterator {
        self.log.iter()
    }
    /// The closed loop's latest decision point, once it has planned.
    pub fn closed_loop(&self) -> Option<&LoopView> {
        self.closed_loop.as_ref()
    }
    /// The operator step waiting for confirmation, if any.
    pub fn prompt(&self) -> Option<&OperatorPrompt> {
        self.prompt.as_ref()
    }
    pub fn pending(&self) -> Option<RunControl> {
        self.pending
    }
    pub fn help_visible(&self) -> bool {
        self.help
    }
    /// The operator asked to leave (q, Esc, Ctrl-C, or Enter after the end).
    pub fn quit_requested(&self) -> bool {
        self.quit
    }
    /// The operator asked to quit twice before the run ended: the display
    /// leaves without waiting for the sequencer to confirm.
    pub fn force_quit(&self) -> bool {
        self.force_quit
    }

    /// Fraction of the current step, clamped to 0..=1 (0 when unknown).
    pub fn step_fraction(&self) -> f64 {
        match (&self.status, &self.progress) {
            (RunStatus::Finished(_), _) => 1.0,
            (_, Some(p)) if p.step_fraction.is_finite() => p.step_fraction.clamp(0.0, 1.0),
            _ => 0.0,
        }
    }

    /// Fraction of the whole run: finished steps plus the current step's share.
    pub fn overall_fraction(&self) -> f64 {
        if matches!(self.status, RunStatus::Finished(_)) {
            return 1.0;
        }
        match &self.step {
            Some(s) if s.total > 0 => ((s.index as f64 + self.step_fraction()) / s.total as f64).clamp(0.0, 1.0),
            _ => 0.0,
        }
    }
}
