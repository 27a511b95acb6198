//! The I/O edges of the display: the interactive terminal loop and the plain
//! progress printer for logs. Both only translate between channels and
//! [`State`]; all decisions about what to show live in `state` and `draw`.

use std::io::{self, IsTerminal, Write};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use ratatui::Terminal;
use ratatui::backend::Backend;
use ratatui::crossterm::event::{self, Event};
use tokio::sync::mpsc;
use tokio::time::MissedTickBehavior;

use super::channel::{ControlSink, EventSource};
use super::draw::draw;
use super::state::State;
use crate::run::events::{ProgressLine, RunEvent};

/// What the display says when the sequencer's channel closes without a result.
pub const NO_RESULT_REASON: &str = "the sequencer stopped without reporting a result";

/// True when stdout is a terminal, i.e. when the TUI should be used rather
/// than plain progress lines.
pub fn stdout_is_terminal() -> bool {
    io::stdout().is_terminal()
}

/// How [`drive`] paces itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveOptions {
    /// Shortest time between two redraws; events arriving faster are folded
    /// into the state and drawn together.
    pub frame_interval: Duration,
    /// After the run ends, keep showing the result until the operator presses
    /// q / Enter / Esc (otherwise return as soon as the run ends).
    pub wait_for_key_at_end: bool,
}

impl Default for DriveOptions {
    fn default() -> Self {
        Self { frame_interval: Duration::from_millis(50), wait_for_key_at_end: true }
    }
}

/// The display loop over any ratatui backend: folds sequencer events and
/// terminal input into a [`State`], forwards the operator's controls, and
/// redraws at most once per `frame_interval`. Returns the final state when the
/// run is over and the operator has left (or, with `wait_for_key_at_end`
/// off, when the run is over). A second quit key before the sequencer has
/// answered the first leaves at once, with the run's status as last reported.
pub async fn drive<B: Backend, E: EventSource, C: ControlSink>(
    terminal: &mut Terminal<B>,
    mut events: E,
    controls: C,
    mut input: mpsc::Receiver<Event>,
    opts: DriveOptions,
) -> Result<State, B::Error> {
    let mut state = State::new();
    let mut events_open = true;
    let mut input_open = true;
    let mut dirty = true;
    let mut tick = tokio::time::interval(opts.frame_interval.max(Duration::from_millis(1)));
    tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    terminal.draw(|f| draw(&state, f))?;

    loop {
        let over = state.status().is_over();
        if !events_open && !over {
            // The sequencer is gone and never said how the run ended: say so
            // rather than leave a "running" screen behind.
            state.apply(&RunEvent::Aborted { reason: NO_RESULT_REASON.to_string() });
            dirty = true;
            continue;
        }
        if over && (state.quit_requested() || !opts.wait_for_key_at_end || !input_open) || state.force_quit() {
            break;
        }
        // Biased: a due redraw first (so a flood of events cannot starve the
        // screen), then events before keys, so a key acts on the newest state.
        tokio::select! {
            biased;
            _ = tick.tick() => {
                if dirty {
                    terminal.draw(|f| draw(&state, f))?;
                    dirty = false;
                }
            }
            ev = events.next_event(), if events_open => {
                match ev {
                    Some(ev) => state.apply(&ev),
                    None => events_open = false,
                }
                dirty = true;
            }
            inp = input.recv(), if input_open => match inp {
                Some(Event::Key(k)) => {
                    if let Some(c) = state.on_key(k) {
                        controls.send_control(c).await;
                    }
                    dirty = true;
                }
                Some(Event::Resize(..)) => dirty = true,
                Some(_) => {}
                None => input_open = false,
            },
        }
    }
    terminal.draw(|f| draw(&state, f))?;
    Ok(state)
}

/// Restores the terminal when dropped, so every way out of [`run_tui`]
/// (including an error or a panic unwinding through it) leaves the terminal
/// usable. `ratatui::try_init` also installs a panic hook that restores it
/// before the panic message prints.
struct RestoreOnDrop;

impl Drop for RestoreOnDrop {
    fn drop(&mut self) {
        ratatui::restore();
    }
}

/// Reads terminal input on a plain thread (crossterm's reads block) until
/// `stop` is set or the receiving side goes away.
fn read_input(tx: mpsc::Sender<Event>, stop: Arc<AtomicBool>) {
    while !stop.load(Ordering::Relaxed) {
        match event::poll(Duration::from_millis(50)) {
            Ok(true) => match event::read() {
                Ok(ev) => {
                    if tx.blocking_send(ev).is_err() {
                        break;
                    }
                }
                Err(_) => break,
            },
            Ok(false) => {}
            Err(_) => break,
        }
    }
}

/// The interactive display on the real terminal: raw mode and the alternate
/// screen for the duration, keys read on a helper thread, redraws at most 20
/// times a second. Returns the final state (the run's outcome is
/// `state.status()`).
pub async fn run_tui(events: impl EventSource, controls: impl ControlSink) -> io::Result<State> {
    let _restore = RestoreOnDrop;
    let mut terminal = ratatui::try_init()?;
    let (tx, rx) = mpsc::channel(64);
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || read_input(tx, stop))
    };
    let result = drive(&mut terminal, events, controls, rx, DriveOptions::default()).await;
    stop.store(true, Ordering::Relaxed);
    // The reader wakes within one poll period; join it so no key is read
    // after the terminal is handed back.
    let _ = tokio::task::spawn_blocking(move || reader.join()).await;
    result
}

/// Plain progress for output that is not a terminal (CI logs): one line per
/// step start, per 10 % of a step, per log message, pause, abort and the
/// result, flushed as it goes. Returns the final state once the run is over
/// or the sequencer's channel closes.
pub async fn run_plain<W: Write>(mut events: impl EventSource, mut out: W) -> io::Result<State> {
    let mut state = State::new();
    let mut lines = ProgressLine::new();
    let mut emit = |ev: &RunEvent, state: &mut State, out: &mut W| -> io::Result<()> {
        state.apply(ev);
        if let Some(l) = lines.line(ev) {
            writeln!(out, "{l}")?;
            out.flush()?;
        }
        Ok(())
    };
    while let Some(ev) = events.next_event().await {
        emit(&ev, &mut state, &mut out)?;
        if state.status().is_over() {
            return Ok(state);
        }
    }
    emit(&RunEvent::Aborted { reason: NO_RESULT_REASON.to_string() }, &mut state, &mut out)?;
    Ok(state)
}

/// As [`run_plain`], answering operator steps on the command line: at an
/// [`RunEvent::OperatorPrompt`] a line goes to stderr and `answer` is called
/// on a thread of its own (it blocks: stdin, read a line); an empty line
/// confirms, `a` / `abort`, `q` / `quit` or the end of input abort. Events
/// keep being shown meanwhile (a Ctrl-C abort ends the run while the line
/// is still awaited). `controls` stays open until the run is over.
pub async fn run_plain_prompting<W, C, A>(
    mut events: impl EventSource,
    mut out: W,
    controls: C,
    answer: A,
) -> io::Result<State>
where
    W: Write,
    C: ControlSink,
    A: Fn() -> io::Result<Option<String>> + Send + Sync + Clone + 'static,
{
    let mut state = State::new();
    let mut lines = ProgressLine::new();
    let (ans_tx, mut ans_rx) = mpsc::unbounded_channel::<crate::run::events::RunControl>();
    loop {
        let ev = tokio::select! {
            ev = events.next_event() => ev,
            Some(c) = ans_rx.recv() => {
                if state.prompt().is_some() {
                    controls.send_control(c).await;
                }
                continue;
            }
        };
        let Some(ev) = ev else { break };
        state.apply(&ev);
        if let Some(l) = lines.line(&ev) {
            writeln!(out, "{l}")?;
            out.flush()?;
        }
        if let RunEvent::OperatorPrompt { step, .. } = &ev {
            eprintln!("{step}: press Enter once the indenter is mounted, or type a and Enter to abort");
            let (tx, read) = (ans_tx.clone(), answer.clone());
            std::thread::spawn(move || {
                let _ = tx.send(operator_answer(read()));
            });
        }
        if state.status().is_over() {
            return Ok(state);
        }
    }
    let ev = RunEvent::Aborted { reason: NO_RESULT_REASON.to_string() };
    state.apply(&ev);
    if let Some(l) = lines.line(&ev) {
        writeln!(out, "{l}")?;
    }
    Ok(state)
}

/// The control a typed line means at an operator prompt: an empty line
/// confirms; anything else (`a`, `abort`, `q`), the end of input or a read
/// error aborts (nobody confirmed).
pub fn operator_answer(line: io::Result<Option<String>>) -> crate::run::events::RunControl {
    use crate::run::events::RunControl;
    match line {
        Ok(Some(l)) if l.trim().is_empty() => RunControl::Confirm,
        _ => RunControl::Abort,
    }
}

/// One line of stdin (`None` at its end).
pub fn read_stdin_line() -> io::Result<Option<String>> {
    let mut l = String::new();
    match io::stdin().read_line(&mut l)? {
        0 => Ok(None),
        _ => Ok(Some(l)),
    }
}

/// The display the issue asks for: the TUI when stdout is a terminal, plain
/// progress lines on stdout otherwise. In plain mode an operator step is
/// answered on stdin ([`run_plain_prompting`]); `controls` stays open until
/// the run is over so the sequencer does not mistake a closed channel for an
/// operator leaving (Ctrl-C there is the caller's signal handler's job).
pub async fn run_display(events: impl EventSource, controls: impl ControlSink) -> io::Result<State> {
    if stdout_is_terminal() {
        run_tui(events, controls).await
    } else {
        run_plain_prompting(events, io::stdout(), controls, read_stdin_line).await
    }
}
