//! The TUI: drawing at several states (TestBackend), key handling, the
//! display loop against a fake sequencer over channels, and plain mode.

use devices::motion::AxisStatus;
use easycalib::diagnosis::DiagnoseOptions;
use easycalib::fit::{FitOptions, calibrate};
use easycalib::report::diagnose_run;
use easycalib::run::events::{
    DeviceStatus, FitUpdate, LogLevel, Progress, RunControl, RunEvent, RunPhase, RunSummary, SensorStatus,
};
use easycalib::tui::{DriveOptions, NO_RESULT_REASON, RunStatus, State, draw, drive, run_plain};
use ratatui::Terminal;
use ratatui::backend::TestBackend;
use ratatui::crossterm::event::{Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use sim::effects::{SimProfile, stage_backlash};
use sim::generator::{GeneratorConfig, generate};
use sim::physics::{Body, ContactPair};
use sim::recording::{Phase, Recording};
use std::time::Duration;
use tokio::sync::mpsc;

const W: u16 = 120;
const H: u16 = 40;

fn screen_of(buf: &ratatui::buffer::Buffer) -> String {
    let area = buf.area;
    let mut s = String::new();
    for y in 0..area.height {
        for x in 0..area.width {
            s.push_str(buf[(x, y)].symbol());
        }
        s.push('\n');
    }
    s
}

fn render(state: &State) -> String {
    let mut t = Terminal::new(TestBackend::new(W, H)).unwrap();
    t.draw(|f| draw(state, f)).unwrap();
    screen_of(t.backend().buffer())
}

fn key(c: char) -> KeyEvent {
    KeyEvent::new(KeyCode::Char(c), KeyModifiers::NONE)
}

fn recording() -> Recording {
    generate(&GeneratorConfig::default()).unwrap()
}

fn axis(position: f64, moving: bool, homed: bool) -> AxisStatus {
    AxisStatus { position, moving, homed, enabled: true, ..AxisStatus::default() }
}

fn devices() -> DeviceStatus {
    DeviceStatus {
        stage: axis(1.2345, true, true),
        rotation: axis(0.0, false, false),
        sensor: SensorStatus { rate_hz: 29.7, frames: 1234, dropped: 3, skipped: 5000, unmeasured: 0 },
    }
}

/// A run in the middle of the normal sweep: step 4 of 8, half done, with the
/// first 60 % of the generated normal samples and their running fit.
fn mid_normal() -> (State, FitUpdate, usize) {
    let rec = recording();
    let normal: Vec<_> = rec.phase(Phase::Normal).copied().collect();
    let n = normal.len() * 6 / 10;
    let fit = FitUpdate::estimate(&normal[..n], &rec.meta.indenter).unwrap();
    let mut st = State::new();
    st.apply(&RunEvent::StepStarted { index: 3, total: 8, name: "normal sweep".into(), phase: RunPhase::Normal });
    st.apply(&RunEvent::Progress(Progress { step_fraction: 0.5, elapsed_s: 42.0, eta_s: Some(60.0) }));
    st.apply(&RunEvent::DeviceStatus(devices()));
    for s in &normal[..n] {
        st.apply(&RunEvent::Sample(*s));
    }
    st.apply(&RunEvent::Fit(fit));
    st.apply(&RunEvent::Log { level: LogLevel::Info, message: "first contact at stage 0.412 mm".into() });
    st.apply(&RunEvent::Log { level: LogLevel::Warn, message: "sensor settled slowly".into() });
    (st, fit, n)
}

fn braille_in_rows(screen: &str, rows: std::ops::Range<usize>, cols: std::ops::Range<usize>) -> usize {
    screen
        .lines()
        .skip(rows.start)
        .take(rows.len())
        .map(|l| l.chars().skip(cols.start).take(cols.len()).filter(|c| ('\u{2801}'..='\u{28FF}').contains(c)).count())
        .sum()
}

#[test]
fn idle_screen_waits_for_the_sequencer() {
    let st = State::new();
    let s = render(&st);
    assert!(s.contains("WAITING"), "{s}");
    assert!(s.contains("waiting for the sequencer"));
    assert!(s.contains("no device status yet"));
    assert!(s.contains("samples: 0"));
    assert!(s.contains("0%  elapsed --  ETA --"), "{s}");
    assert!(s.contains("(0 pts)"));
    assert!(s.contains(" p  pause") && s.contains(" a  abort") && s.contains(" ?  help"));
    // No points, no fit: the chart areas carry no Braille dots.
    assert_eq!(braille_in_rows(&s, 6..24, 0..86), 0);
}

#[test]
fn mid_normal_sweep_shows_step_gauges_devices_points_and_fit() {
    let (st, fit, n) = mid_normal();
    let s = render(&st);
    assert!(s.contains("RUNNING"), "{s}");
    assert!(s.contains("step 4/8 normal sweep") && s.contains("phase: normal"), "{s}");
    assert!(s.contains(&format!("samples: {n}")));
    // Step gauge at 50 %, run gauge at (3 + 0.5) / 8 = 43.75 % -> 44 %.
    assert!(s.contains("50%"), "{s}");
    assert!(s.contains("44%  elapsed 42.0s  ETA 1m00.0s"), "{s}");
    // Device panel.
    assert!(s.contains("1.2345 mm"), "{s}");
    assert!(s.contains("moving") && s.contains("homed") && s.contains("not homed"));
    assert!(s.contains("29.7 Hz"));
    assert!(s.contains("frames 1234  lost 3"), "{s}");
    assert!(s.contains("skipped 5000  unmeasured 0"), "{s}");
    // Chart title counts the points; the running fit is shown by value.
    assert!(s.contains(&format!("normal sweep: gamma2 vs gamma1 ({n} pts)")), "{s}");
    assert!(s.contains(&format!("H1 {:>9}", format!("{:.4}", fit.h1.unwrap()))), "{s}");
    assert!(s.contains(&format!("fit H1={:.3}", fit.h1.unwrap())), "{s}");
    assert!(s.contains("E1  -- MPa"), "no E1 before torsion: {s}");
    // Points and fit line are drawn in the normal chart, none in torsion yet.
    assert!(braille_in_rows(&s, 6..24, 0..43) > 20, "{s}");
    assert!(s.contains("(0 pts)"));
    // Log pane.
    assert!(s.contains("info  first contact at stage 0.412 mm"));
    assert!(s.contains("warn  sensor settled slowly"));
}

#[test]
fn torsion_screen_shows_both_charts_and_e1() {
    let rec = recording();
    let (mut st, _, _) = mid_normal();
    st.apply(&RunEvent::StepStarted { index: 6, total: 8, name: "torsion sweep".into(), phase: RunPhase::Torsion });
    st.apply(&RunEvent::Progress(Progress { step_fraction: 0.25, elapsed_s: 75.5, eta_s: Some(9.0) }));
    let tors: Vec<_> = rec.phase(Phase::Torsion).copied().collect();
    for s in &tors {
        st.apply(&RunEvent::Sample(*s));
    }
    let fit = FitUpdate::estimate(&rec.samples, &rec.meta.indenter).unwrap();
    st.apply(&RunEvent::Fit(fit));
    let s = render(&st);
    assert!(s.contains("step 7/8 torsion sweep") && s.contains("phase: torsion"), "{s}");
    assert!(s.contains(&format!("torsion sweep: theta2 vs theta1 ({} pts)", tors.len())), "{s}");
    assert!(s.contains(&format!("E1  {:.4} MPa", fit.e1_mpa.unwrap())), "{s}");
    assert!(s.contains(&format!("nu1 {:.3}", fit.nu1.unwrap())), "{s}");
    assert!(s.contains(&format!("fit H3={:.3}", fit.h3.unwrap())), "{s}");
    // (6 + 0.25) / 8 = 78 %.
    assert!(s.contains("78%  elapsed 1m15.5s  ETA 9.0s"), "{s}");
    assert!(braille_in_rows(&s, 6..24, 43..86) > 10, "{s}");
}

#[test]
fn aborted_screen_says_why_and_offers_only_leave() {
    let (mut st, _, _) = mid_normal();
    st.apply(&RunEvent::Aborted { reason: "stage disconnected (pty closed)".into() });
    let s = render(&st);
    assert!(s.contains("ABORTED"));
    assert!(s.contains("RUN ABORTED"), "{s}");
    assert!(s.contains("stage disconnected (pty closed)"));
    assert!(s.contains("Motion stopped and the stage backed off."));
    assert!(s.contains("error aborted: stage disconnected (pty closed)"), "{s}");
    assert!(s.contains(" q  leave") && !s.contains(" p  pause"), "{s}");
}

#[test]
fn finished_screen_shows_the_result() {
    let (mut st, _, _) = mid_normal();
    let summary = RunSummary {
        samples: 91,
        wall_time_s: 3.2,
        rig_time_s: 84.0,
        e1_mpa: Some(0.3312),
        nu1: Some(0.388),
        e1_ci95: Some([0.3290, 0.3334]),
        nu1_ci95: Some([0.381, 0.395]),
        recording: Some("runs/x/recording.csv".into()),
        report: Some("runs/x/report.md".into()),
    };
    st.apply(&RunEvent::Finished { summary });
    let s = render(&st);
    assert!(s.contains("RUN FINISHED"), "{s}");
    assert!(s.contains("E1  = 0.3312 MPa  95% [0.3290, 0.3334]"), "{s}");
    assert!(s.contains("nu1 = 0.388  95% [0.381, 0.395]"));
    assert!(s.contains("recording: runs/x/recording.csv"));
    assert!(s.contains("100%  elapsed 42.0s  ETA 0.0s"), "{s}");
    // The history's verdict arrives after the result and joins the final panel.
    st.apply(&RunEvent::History {
        lines: vec![
            "history: gel-A — calibration 7 of 7 (half-space model)".into(),
            "  E1  +2.10 % against the 6 before (z step +6.10): CHANGED beyond the repeatability".into(),
        ],
    });
    let s = render(&st);
    assert!(s.contains("calibration 7 of 7"), "{s}");
    assert!(s.contains("E1  +2.10 % against the 6 before"), "{s}");
}

/// The final panel with the diagnosis the run made: its verdict and, when it
/// named an effect, the corrected E1 and nu1 (a diagnosis of the generator's
/// recording with stage backlash, as the run makes it).
#[test]
fn finished_screen_shows_the_diagnosis_verdict_and_corrected_values() {
    let pair = ContactPair { elastomer: Body::new(0.33, 0.39, 33.0), indenter: Body::new(1.1, 0.39, 5.0) };
    let profile = SimProfile {
        stage_backlash: Some(stage_backlash::Params { b_mm: 0.008, engaged: true }),
        ..Default::default()
    };
    let rec = generate(&GeneratorConfig { pair, profile, seed: 12, ..Default::default() }).unwrap();
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let d = diagnose_run(&rec, &cal, &DiagnoseOptions::default());
    assert!(d.corrected(), "{}", d.summary);
    let (mut st, _, _) = mid_normal();
    st.apply(&RunEvent::Diagnosis(Box::new(d.clone())));
    st.apply(&RunEvent::Finished { summary: RunSummary { e1_mpa: Some(cal.full.e1_mpa), ..RunSummary::default() } });
    assert_eq!(st.diagnosis(), Some(&d));
    let s = render(&st);
    assert!(s.contains("diagnosis: EFFECTS (stage_backlash"), "{s}");
    let e1 = format!("corrected E1  = {:.4} MPa  95% [{:.4}, {:.4}]", d.e1_mpa, d.ci95.e1_mpa[0], d.ci95.e1_mpa[1]);
    assert!(s.contains(&e1), "{e1}\n{s}");
    assert!(s.contains(&format!("corrected nu1 = {:.3}  95% [", d.nu1)), "{s}");
    assert!(s.contains(&format!("E1  = {:.4} MPa", cal.full.e1_mpa)), "{s}");

    // A diagnosis that could not be made says so, and why.
    let failed = diagnose_run(&rec, &cal, &DiagnoseOptions { noise_um: Some(0.0), ..Default::default() });
    st.apply(&RunEvent::Diagnosis(Box::new(failed)));
    let s = render(&st);
    assert!(s.contains("diagnosis: NOT MADE"), "{s}");
    assert!(s.contains("--noise-um must be > 0"), "{s}");
    assert!(!s.contains("corrected E1"), "{s}");
}

/// The closed loop in the TUI (issue 14): the panel shows the experiment the
/// loop chose and why, and each explanation still standing with its odds, from
/// the plan of a recording whose sweeps cannot tell a compliant frame from a
/// layer or a gain (the generator's frame of 3 um/N); the plain printer says the same.
#[test]
fn the_closed_loop_panel_shows_what_stands_with_its_odds_and_the_chosen_experiment() {
    use easycalib::plan::{PlanOptions, plan};
    use easycalib::run::events::LoopChoice;
    use sim::effects::frame_compliance;
    let profile =
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..SimProfile::default() };
    let rec = generate(&GeneratorConfig { profile, seed: 1, ..GeneratorConfig::default() }).unwrap();
    let p = plan(&rec, PlanOptions::default()).unwrap();
    let c = p.choice().expect("an experiment");
    let odds = p.odds();
    assert!(odds.len() >= 2 && (odds.iter().sum::<f64>() - 1.0).abs() < 1e-9, "{odds:?}");
    assert!(odds.windows(2).all(|w| w[0] >= w[1]), "best first: {odds:?}");
    let why = format!("separates {} from {}", p.hypotheses[0].effects.join(" + "), p.hypotheses[1].effects.join(" + "));
    let chosen =
        LoopChoice { name: c.name.to_string(), why: why.clone(), rig_time_s: c.rig_time_s, operator: c.operator };
    let view = p.view(0, Some(chosen), format!("running {}", c.name));
    let (mut st, _, _) = mid_normal();
    assert!(!render(&st).contains("closed loop"));
    st.apply(&RunEvent::ClosedLoop(Box::new(view.clone())));
    assert_eq!(st.closed_loop(), Some(&view));
    let s = render(&st);
    assert!(s.contains("closed loop"), "{s}");
    assert!(s.contains(&format!("step 1: {} ({:.0} s)", c.name, c.rig_time_s)), "{s}");
    for (h, o) in p.hypotheses.iter().zip(&odds) {
        let row = format!("{:>3.0} % {}", 100.0 * o, h.effects.join(" + "));
        assert!(s.contains(&row), "{row}\n{s}");
    }
    // The plain printer: one line with the same.
    let line = view.line();
    assert!(line.contains(&format!("runs {}", c.name)) && line.contains(&why), "{line}");
    assert!(line.contains(&format!("{} {:.0} %", p.hypotheses[0].effects.join(" + "), 100.0 * odds[0])), "{line}");
}

#[test]
fn help_overlay_opens_with_question_mark_and_any_key_closes_it() {
    let (mut st, _, _) = mid_normal();
    assert_eq!(st.on_key(key('?')), None);
    assert!(st.help_visible());
    let s = render(&st);
    assert!(s.contains("help: keys"), "{s}");
    assert!(s.contains("pause at the next safe point"));
    assert!(s.contains("abort: stop motion, back the stage off"));
    // A key while help is open only closes it: `p` does not pause.
    assert_eq!(st.on_key(key('p')), None);
    assert!(!st.help_visible());
    assert!(!render(&st).contains("help: keys"));
}

#[test]
fn keys_produce_controls_that_fit_the_status() {
    let (mut st, _, _) = mid_normal();
    // Resume means nothing while running.
    assert_eq!(st.on_key(key('r')), None);
    // Key releases are ignored (terminals that report them would double every key).
    let mut release = key('p');
    release.kind = KeyEventKind::Release;
    assert_eq!(st.on_key(release), None);

    assert_eq!(st.on_key(key('p')), Some(RunControl::Pause));
    assert_eq!(st.pending(), Some(RunControl::Pause));
    assert!(render(&st).contains("pausing at the next safe point"));
    // Until the sequencer confirms, the status stays running.
    assert_eq!(*st.status(), RunStatus::Running);
    st.apply(&RunEvent::Paused);
    assert_eq!(st.pending(), None);
    let s = render(&st);
    assert!(s.contains("PAUSED") && s.contains("Press r to resume, a to abort."), "{s}");
    assert_eq!(st.on_key(key('p')), None, "already paused");

    assert_eq!(st.on_key(key('r')), Some(RunControl::Resume));
    st.apply(&RunEvent::Resumed);
    assert_eq!(*st.status(), RunStatus::Running);
    assert!(!render(&st).contains("Press r to resume"));

    assert_eq!(st.on_key(key('a')), Some(RunControl::Abort));
    assert!(render(&st).contains("aborting: stopping motion and backing off"));
    st.apply(&RunEvent::Aborted { reason: "operator abort".into() });
    assert_eq!(st.on_key(key('a')), None, "nothing left to abort");
    assert!(!st.quit_requested());
    assert_eq!(st.on_key(key('q')), None, "quitting after the end sends nothing");
    assert!(st.quit_requested());
}

#[test]
fn ctrl_c_and_q_while_running_ask_the_sequencer_to_quit() {
    let (mut st, _, _) = mid_normal();
    assert_eq!(st.on_key(KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL)), Some(RunControl::Quit));
    assert!(st.quit_requested());
    let (mut st, _, _) = mid_normal();
    assert_eq!(st.on_key(key('q')), Some(RunControl::Quit));
    assert!(render(&st).contains("quitting: aborting the run first"));
    assert!(!st.force_quit());
    // A second q before the sequencer answered: leave without waiting.
    st.on_key(key('q'));
    assert!(st.force_quit());
}

#[tokio::test]
async fn second_quit_leaves_a_stuck_sequencer() {
    let (ev_tx, ev_rx) = mpsc::channel(16);
    let (ctl_tx, mut ctl_rx) = mpsc::channel(4);
    let (key_tx, key_rx) = mpsc::channel(4);
    ev_tx
        .send(RunEvent::StepStarted { index: 0, total: 3, name: "home".into(), phase: RunPhase::Setup })
        .await
        .unwrap();
    key_tx.send(Event::Key(key('q'))).await.unwrap();
    key_tx.send(Event::Key(key('q'))).await.unwrap();
    let mut term = Terminal::new(TestBackend::new(W, H)).unwrap();
    let opts = DriveOptions { frame_interval: Duration::from_millis(1), wait_for_key_at_end: true };
    // The sequencer keeps its sender open and never answers.
    let state = drive(&mut term, ev_rx, ctl_tx, key_rx, opts).await.unwrap();
    assert!(state.force_quit());
    assert_eq!(*state.status(), RunStatus::Running);
    assert_eq!(ctl_rx.recv().await, Some(RunControl::Quit));
    drop(ev_tx);
}

#[test]
fn small_terminals_draw_without_panicking() {
    let (mut st, _, _) = mid_normal();
    st.apply(&RunEvent::Aborted { reason: "a long reason that will not fit in a tiny terminal at all".into() });
    st.on_key(key('?'));
    for (w, h) in [(80, 24), (60, 20), (30, 10), (10, 4), (1, 1)] {
        let mut t = Terminal::new(TestBackend::new(w, h)).unwrap();
        t.draw(|f| draw(&st, f)).unwrap();
    }
    let mut t = Terminal::new(TestBackend::new(80, 24)).unwrap();
    t.draw(|f| draw(&st, f)).unwrap();
    assert!(screen_of(t.backend().buffer()).contains("ABORTED"));
}

#[test]
fn log_pane_keeps_the_newest_lines() {
    let mut st = State::new();
    for i in 0..300 {
        st.apply(&RunEvent::Log { level: LogLevel::Info, message: format!("line {i:03}") });
    }
    assert_eq!(st.log().len(), easycalib::tui::LOG_CAPACITY);
    let s = render(&st);
    assert!(s.contains("line 299") && s.contains("line 294"), "{s}");
    assert!(!s.contains("line 293"), "only the last six fit in the pane: {s}");
}

/// A fake sequencer: one step, then waits at a safe point for controls and
/// reacts the way the real one must (pause holds, resume continues, abort
/// backs off and ends). It reports each reaction on `acks` so the test knows
/// when the display has something new to show.
async fn fake_sequencer(
    events: mpsc::UnboundedSender<RunEvent>,
    mut controls: mpsc::UnboundedReceiver<RunControl>,
    acks: mpsc::UnboundedSender<&'static str>,
) -> Vec<RunControl> {
    let rec = recording();
    let mut seen = Vec::new();
    events
        .send(RunEvent::StepStarted { index: 3, total: 8, name: "normal sweep".into(), phase: RunPhase::Normal })
        .unwrap();
    for s in rec.phase(Phase::Normal).take(10) {
        events.send(RunEvent::Sample(*s)).unwrap();
    }
    acks.send("running").unwrap();
    while let Some(c) = controls.recv().await {
        seen.push(c);
        match c {
            RunControl::Pause => {
                events.send(RunEvent::Paused).unwrap();
                acks.send("paused").unwrap();
            }
            RunControl::Resume => {
                events.send(RunEvent::Resumed).unwrap();
                acks.send("resumed").unwrap();
            }
            RunControl::Confirm => {}
            RunControl::Abort | RunControl::Quit => {
                events
                    .send(RunEvent::Log { level: LogLevel::Warn, message: "backing the stage off 2.000 mm".into() })
                    .unwrap();
                events.send(RunEvent::Aborted { reason: "aborted by the operator".into() }).unwrap();
                acks.send("aborted").unwrap();
                break;
            }
        }
    }
    seen
}

#[tokio::test]
async fn keys_reach_a_fake_sequencer_through_the_display_loop() {
    // Unbounded channels, as the real sequencer uses.
    let (ev_tx, ev_rx) = mpsc::unbounded_channel();
    let (ctl_tx, ctl_rx) = mpsc::unbounded_channel();
    let (key_tx, key_rx) = mpsc::channel(4);
    let (ack_tx, mut ack_rx) = mpsc::unbounded_channel();
    let seq = tokio::spawn(fake_sequencer(ev_tx, ctl_rx, ack_tx));
    // The operator: each key only after the sequencer has shown the state the
    // key is meant for (the display applies queued events before keys).
    let operator = tokio::spawn(async move {
        let press = |c| Event::Key(key(c));
        let mut acks = Vec::new();
        acks.push(ack_rx.recv().await.unwrap());
        key_tx.send(press('p')).await.unwrap();
        acks.push(ack_rx.recv().await.unwrap());
        key_tx.send(press('r')).await.unwrap();
        acks.push(ack_rx.recv().await.unwrap());
        key_tx.send(press('a')).await.unwrap();
        acks.push(ack_rx.recv().await.unwrap());
        key_tx.send(press('q')).await.unwrap();
        acks
    });
    let mut term = Terminal::new(TestBackend::new(W, H)).unwrap();
    let opts = DriveOptions { frame_interval: Duration::from_millis(1), wait_for_key_at_end: true };
    let state = drive(&mut term, ev_rx, ctl_tx, key_rx, opts).await.unwrap();

    assert_eq!(operator.await.unwrap(), vec!["running", "paused", "resumed", "aborted"]);
    assert_eq!(seq.await.unwrap(), vec![RunControl::Pause, RunControl::Resume, RunControl::Abort]);
    assert_eq!(*state.status(), RunStatus::Aborted { reason: "aborted by the operator".into() });
    assert_eq!(state.samples(), 10);
    assert!(state.quit_requested());
    let s = screen_of(term.backend().buffer());
    assert!(s.contains("RUN ABORTED") && s.contains("aborted by the operator"), "{s}");
    assert!(s.contains("backing the stage off 2.000 mm"), "{s}");
}

#[tokio::test]
async fn display_loop_reports_a_sequencer_that_vanished() {
    let (ev_tx, ev_rx) = mpsc::channel(16);
    let (ctl_tx, _ctl_rx) = mpsc::channel(4);
    let (_key_tx, key_rx) = mpsc::channel(4);
    ev_tx
        .send(RunEvent::StepStarted { index: 0, total: 3, name: "home".into(), phase: RunPhase::Setup })
        .await
        .unwrap();
    drop(ev_tx);
    let mut term = Terminal::new(TestBackend::new(W, H)).unwrap();
    let opts = DriveOptions { frame_interval: Duration::from_millis(1), wait_for_key_at_end: false };
    let state = drive(&mut term, ev_rx, ctl_tx, key_rx, opts).await.unwrap();
    assert_eq!(*state.status(), RunStatus::Aborted { reason: NO_RESULT_REASON.into() });
    assert!(screen_of(term.backend().buffer()).contains(NO_RESULT_REASON));
}

#[tokio::test]
async fn plain_mode_prints_ci_lines() {
    let (tx, rx) = mpsc::channel(64);
    let rec = recording();
    let events = vec![
        RunEvent::StepStarted { index: 3, total: 8, name: "normal sweep".into(), phase: RunPhase::Normal },
        RunEvent::Sample(rec.samples[0]),
        RunEvent::Sample(rec.samples[1]),
        RunEvent::Progress(Progress { step_fraction: 0.5, elapsed_s: 42.0, eta_s: Some(60.0) }),
        RunEvent::Paused,
        RunEvent::Resumed,
        RunEvent::Finished {
            summary: RunSummary { samples: 2, rig_time_s: 80.0, wall_time_s: 2.0, ..RunSummary::default() },
        },
        // After the result nothing more is printed.
        RunEvent::Log { level: LogLevel::Info, message: "late".into() },
    ];
    for e in events {
        tx.send(e).await.unwrap();
    }
    let mut out = Vec::new();
    let state = run_plain(rx, &mut out).await.unwrap();
    let text = String::from_utf8(out).unwrap();
    assert_eq!(
        text.lines().collect::<Vec<_>>(),
        vec![
            "[4/8] normal sweep (normal) started",
            "[4/8] normal sweep  50% elapsed 42.0s eta 1m00.0s samples 2",
            "[4/8] normal sweep paused",
            "[4/8] normal sweep resumed",
            "finished: 2 samples, E1 = -- MPa, nu1 = --, rig time 1m20.0s, wall time 2.0s",
        ]
    );
    assert!(matches!(state.status(), RunStatus::Finished(_)));
    drop(tx);

    // A sequencer that disappears mid-run leaves a clear last line.
    let (tx, rx) = mpsc::channel(4);
    tx.send(RunEvent::StepStarted { index: 0, total: 8, name: "home".into(), phase: RunPhase::Setup }).await.unwrap();
    drop(tx);
    let mut out = Vec::new();
    run_plain(rx, &mut out).await.unwrap();
    let text = String::from_utf8(out).unwrap();
    assert_eq!(text.lines().last().unwrap(), format!("[1/8] home ABORTED: {NO_RESULT_REASON}"));
}

/// Child side of `terminal_is_set_up_and_restored_on_a_pty`: runs `run_tui`
/// on its own stdio (a pty). `mode` "quit" answers the operator's quit with an
/// abort; "panic" panics when the operator presses p.
fn tui_child(mode: &str) {
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let (ev_tx, ev_rx) = mpsc::unbounded_channel();
        let (ctl_tx, mut ctl_rx) = mpsc::unbounded_channel();
        ev_tx
            .send(RunEvent::StepStarted { index: 3, total: 8, name: "normal sweep".into(), phase: RunPhase::Normal })
            .unwrap();
        let seq = async move {
            while let Some(c) = ctl_rx.recv().await {
                match c {
                    RunControl::Pause => panic!("child panic for the test"),
                    RunControl::Quit | RunControl::Abort => {
                        ev_tx.send(RunEvent::Aborted { reason: "quit by the operator".into() }).unwrap();
                    }
                    RunControl::Resume | RunControl::Confirm => {}
                }
            }
            std::future::pending::<()>().await
        };
        let state = tokio::select! {
            s = easycalib::tui::run_tui(ev_rx, ctl_tx) => s.unwrap(),
            _ = seq => unreachable!(),
        };
        assert_eq!(mode, "quit", "only the quit child gets here");
        use std::io::Write;
        let mut out = std::io::stdout();
        write!(out, "child-finished: {}\r\n", state.status().label()).unwrap();
        out.flush().unwrap();
    });
}

fn stty(path: &std::path::Path, args: &[&str]) -> String {
    let out = std::process::Command::new("stty").arg("-F").arg(path).args(args).output().unwrap();
    assert!(out.status.success(), "stty {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn has_flag(stty_all: &str, flag: &str) -> bool {
    stty_all.split_whitespace().any(|w| w == flag)
}

/// Runs the real terminal setup in a child process on a pseudo-terminal:
/// raw mode and the alternate screen while the TUI runs, both undone when
/// it returns and when a panic unwinds through it.
#[test]
fn terminal_is_set_up_and_restored_on_a_pty() {
    if let Ok(mode) = std::env::var("EASYCALIB_TUI_CHILD") {
        tui_child(&mode);
        return;
    }
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    const ENTER_ALT: &[u8] = b"\x1b[?1049h";
    const LEAVE_ALT: &[u8] = b"\x1b[?1049l";
    fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
        hay.windows(needle.len()).position(|w| w == needle)
    }
    let rt = tokio::runtime::Runtime::new().unwrap();
    for (mode, key, marker) in
        [("quit", b"q", &b"child-finished: ABORTED"[..]), ("panic", b"p", b"child panic for the test")]
    {
        rt.block_on(async {
            let mut master = sim::emulator::pty::PtyMaster::open().unwrap();
            let slave = master.slave_path().to_path_buf();
            // A cooked terminal of known size, as a shell would leave it.
            stty(&slave, &["sane", "rows", "40", "cols", "120"]);
            assert!(has_flag(&stty(&slave, &["-a"]), "icanon"));
            let io = || std::fs::OpenOptions::new().read(true).write(true).open(&slave).unwrap();
            let mut child = tokio::process::Command::new(std::env::current_exe().unwrap())
                .args(["--exact", "terminal_is_set_up_and_restored_on_a_pty", "--nocapture", "--test-threads=1"])
                .env("EASYCALIB_TUI_CHILD", mode)
                .stdin(io())
                .stdout(io())
                .stderr(io())
                .kill_on_drop(true)
                .spawn()
                .unwrap();
            let mut seen = Vec::new();
            let mut buf = [0u8; 4096];
            // A guard against a hung child, not a timing assertion.
            let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
            while find(&seen, ENTER_ALT).is_none() {
                let n =
                    tokio::time::timeout_at(deadline, master.read(&mut buf)).await.expect("child never drew").unwrap();
                seen.extend_from_slice(&buf[..n]);
            }
            // Wait for the first frame (the header) so the TUI is in its loop.
            while find(&seen, b"easycalib run").is_none() {
                let n = tokio::time::timeout_at(deadline, master.read(&mut buf)).await.expect("no frame").unwrap();
                seen.extend_from_slice(&buf[..n]);
            }
            let during = stty(&slave, &["-a"]);
            assert!(has_flag(&during, "-icanon") && has_flag(&during, "-echo"), "raw mode while running: {during}");
            master.write_all(key).await.unwrap();
            while find(&seen, marker).is_none() {
                let n =
                    tokio::time::timeout_at(deadline, master.read(&mut buf)).await.expect("child never ended").unwrap();
                seen.extend_from_slice(&buf[..n]);
            }
            let status = tokio::time::timeout_at(deadline, child.wait()).await.unwrap().unwrap();
            let text = String::from_utf8_lossy(&seen);
            let leave =
                find(&seen, LEAVE_ALT).unwrap_or_else(|| panic!("{mode}: alternate screen never left: {text:?}"));
            let end = find(&seen, marker).unwrap();
            assert!(leave < end, "{mode}: the terminal is restored before the last words: {text:?}");
            let after = stty(&slave, &["-a"]);
            assert!(has_flag(&after, "icanon") && has_flag(&after, "echo"), "{mode}: cooked mode restored: {after}");
            match mode {
                "quit" => assert!(status.success(), "{text:?}"),
                _ => assert!(!status.success(), "a panicking child fails"),
            }
        });
    }
}

/// The lead spawns the display next to the sequencer: its futures must be Send.
#[test]
fn display_futures_can_be_spawned() {
    fn assert_send<T: Send>(_: &T) {}
    let (_etx, erx) = mpsc::unbounded_channel::<RunEvent>();
    let (ctx, _crx) = mpsc::unbounded_channel::<RunControl>();
    let f = easycalib::tui::run_display(erx, ctx);
    assert_send(&f);
    let (_etx, erx) = mpsc::channel::<RunEvent>(1);
    let (ctx, _crx) = mpsc::channel::<RunControl>(1);
    let f = easycalib::tui::run_tui(erx, ctx);
    assert_send(&f);
    let (_etx, erx) = mpsc::channel::<RunEvent>(1);
    let f = run_plain(erx, Vec::new());
    assert_send(&f);
}
