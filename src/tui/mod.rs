//! The live display of a calibration run: a ratatui TUI when stdout is a
//! terminal, plain progress lines otherwise.
//!
//! State, update and drawing are kept apart: [`State`] changes only through
//! [`State::apply`] (sequencer events) and [`State::on_key`] (operator keys,
//! which may yield a [`RunControl`](crate::run::events::RunControl)), and
//! [`draw`] is a pure function of the state. [`drive`] is the loop over any
//! ratatui backend (tests use `TestBackend`); [`run_tui`] runs it on the real
//! terminal and [`run_plain`] prints lines for logs.

mod channel;
mod draw;
mod runner;
mod state;

pub use channel::{ControlSink, EventSource};
pub use draw::draw;
pub use runner::{
    DriveOptions, NO_RESULT_REASON, drive, operator_answer, read_stdin_line, run_display, run_plain,
    run_plain_prompting, run_tui, stdout_is_terminal,
};
pub use state::{LOG_CAPACITY, LogEntry, OperatorPrompt, RunStatus, State, StepInfo};
