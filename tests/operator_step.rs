//! Operator-assisted steps in the sequencer (issue 14, docs/run.md "Operator
//! steps"), on the in-process simulated rig: the stage retracts clear of the
//! gel before the prompt, nothing moves while the prompt waits, a
//! confirmation runs the step into a recording of its own, and an abort at the
//! prompt ends the run by the one abort path. No real-time waits: the
//! simulated devices answer at once.

use std::path::Path;

use easycalib::run::events::{RunControl, RunEvent};
use easycalib::run::{Backoff, Culprit, RunOutcome, RunStatus, Sequencer};
use sim::experiment::{Experiment, ExperimentSpec, RIGID_BALL_E_MPA};
use sim::recording::{Direction, Recording};
use tokio::sync::mpsc::unbounded_channel;

#[path = "support/simrig.rs"]
mod simrig;
use simrig::{SimRig, SimRigConfig};

/// A quick script (tests/support/simrig.rs).
use simrig::stepwise_script as quick;

const BALL: ExperimentSpec = ExperimentSpec::RigidBall { r_mm: 5.0, travel_mm: 1.0, steps: 4 };

/// What the rig looked like when the prompt came, and what came of the run.
struct Prompted {
    out: RunOutcome,
    /// The prompt's step and indenter E, MPa.
    prompt: Option<(String, f64)>,
    /// Stage position, stage moves and rig time at the prompt, and the stage moves and rig time
    /// just before the answer was sent (after the operator task let the sequencer run).
    at_prompt: Option<(f64, usize, f64)>,
    before_answer: Option<(usize, f64)>,
    /// Stage targets commanded after the prompt.
    targets_after: Vec<f64>,
    events: Vec<RunEvent>,
    recordings: Vec<std::path::PathBuf>,
}

/// Run `quick()` with the forced rigid-ball step; an operator task answers
/// the prompt with `answer` (`None`: the control channel is dropped before
/// the run starts, nobody can answer).
async fn run_with_operator(answer: Option<RunControl>, path: &Path) -> Prompted {
    let rig = SimRig::new(SimRigConfig::default()).unwrap();
    let (ev_tx, mut ev_rx) = unbounded_channel();
    let (ctl_tx, ctl_rx) = unbounded_channel();
    let mut seq = Sequencer::new(quick(), rig.stage(), rig.mount(), rig.gauge(), path)
        .unwrap()
        .with_events(ev_tx)
        .with_controls(ctl_rx)
        .with_forced_operator_step(Some(BALL));
    let watcher = rig.clone();
    let ctl = answer.map(|_| ctl_tx.clone());
    drop(ctl_tx);
    let operator = tokio::spawn(async move {
        let (mut prompt, mut at_prompt, mut before_answer, mut events) = (None, None, None, Vec::new());
        let mut targets_from = None;
        while let Some(ev) = ev_rx.recv().await {
            if let RunEvent::OperatorPrompt { step, indenter, .. } = &ev {
                prompt = Some((step.clone(), indenter.e_mpa));
                {
                    let st = watcher.state();
                    at_prompt = Some((st.stage_mm, st.stage_moves, st.t_s));
                    targets_from = Some(st.stage_targets.len());
                }
                // Let the sequencer run (it must not move while waiting).
                for _ in 0..200 {
                    tokio::task::yield_now().await;
                }
                before_answer = {
                    let st = watcher.state();
                    Some((st.stage_moves, st.t_s))
                };
                if let (Some(c), Some(a)) = (&ctl, answer) {
                    c.send(a).unwrap();
                }
            }
            events.push(ev);
        }
        let targets_after = targets_from.map_or_else(Vec::new, |i| watcher.state().stage_targets[i..].to_vec());
        (prompt, at_prompt, before_answer, targets_after, events)
    });
    let out = seq.run().await;
    let recordings = seq.operator_recordings().to_vec();
    drop(seq);
    let (prompt, at_prompt, before_answer, targets_after, events) = operator.await.unwrap();
    Prompted { out, prompt, at_prompt, before_answer, targets_after, events, recordings }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_prompt_waits_with_the_stage_clear_of_the_gel_and_a_confirmation_runs_the_step() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("recording.csv");
    let p = run_with_operator(Some(RunControl::Confirm), &path).await;
    assert_eq!(p.out.status, RunStatus::Completed, "{:?}", p.out.status);
    assert_eq!(p.prompt, Some(("rigid_ball".to_string(), RIGID_BALL_E_MPA)));
    let surface = SimRigConfig::default().surface_mm;
    let (stage, moves, t) = p.at_prompt.expect("a prompt");
    // Retracted to the script's park position, well clear of the gel.
    assert!((stage - quick().park_mm()).abs() < 1e-9 && stage < surface - 1.0, "stage at {stage} mm");
    // Nothing moved and no rig time passed while the prompt waited.
    assert_eq!(p.before_answer, Some((moves, t)));
    // Confirmed, then the sweep: 4 steps in, 4 out, from the run's contact.
    let confirmed = p.events.iter().position(|e| matches!(e, RunEvent::OperatorConfirmed { .. }));
    let prompted = p.events.iter().position(|e| matches!(e, RunEvent::OperatorPrompt { .. }));
    assert!(prompted < confirmed && confirmed.is_some(), "prompt {prompted:?}, confirmed {confirmed:?}");
    let contact = p.out.contact_mm.expect("a contact");
    let inward: Vec<f64> = p.targets_after.iter().map(|t| t - contact).filter(|d| *d > 1e-9).collect();
    let want = [0.25, 0.5, 0.75, 1.0, 0.75, 0.5, 0.25];
    assert_eq!(inward.len(), want.len(), "{inward:?}");
    assert!(inward.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6), "{inward:?}");
    // Its recording: the ball in the header, operator_step, every sample of its phase.
    assert_eq!(p.recordings, [dir.path().join("recording.rigid_ball.csv")]);
    let ball = Recording::read_path(&p.recordings[0]).unwrap();
    assert_eq!(ball.meta.indenter.e_mpa, RIGID_BALL_E_MPA);
    assert!(ball.meta.extra.iter().any(|(k, v)| k == "operator_step" && v == "rigid_ball"));
    assert_eq!(ball.samples.len(), 8);
    assert!(ball.samples.iter().all(|s| s.experiment == Some(Experiment::RigidBall)));
    assert_eq!(ball.samples.iter().filter(|s| s.dir == Some(Direction::Load)).count(), 4);
    assert!(ball.samples[3].gamma1_mm > ball.samples[0].gamma1_mm && ball.samples[3].gamma1_mm > 0.1);
    // None of it in the run's recording, which ends retracted.
    let rec = Recording::read_path(&path).unwrap();
    assert!(rec.samples.iter().all(|s| s.experiment.is_none()));
    assert!((p.targets_after.last().copied().unwrap() - quick().park_mm()).abs() < 1e-9, "{:?}", p.targets_after);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_abort_at_the_prompt_stops_the_run_safely_without_moving_in() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("recording.csv");
    let p = run_with_operator(Some(RunControl::Abort), &path).await;
    let RunStatus::Aborted(info) = &p.out.status else { panic!("not aborted: {:?}", p.out.status) };
    assert_eq!(info.culprit, Culprit::Operator);
    assert!(info.message.contains("rigid_ball prompt"), "{info}");
    assert!(matches!(info.backoff, Backoff::To(_)), "{info}");
    // Nothing went towards the gel after the prompt, and no ball recording.
    let surface = SimRigConfig::default().surface_mm;
    assert!(p.targets_after.iter().all(|t| *t < surface - 1.0), "{:?}", p.targets_after);
    assert!(p.recordings.is_empty());
    assert!(!dir.path().join("recording.rigid_ball.csv").exists());
    assert!(!p.events.iter().any(|e| matches!(e, RunEvent::OperatorConfirmed { .. })));
    // The run's recording stays whole.
    assert_eq!(Recording::read_path(&path).unwrap().samples.len(), p.out.samples);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_nobody_to_confirm_the_run_stops_at_the_prompt() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("recording.csv");
    let p = run_with_operator(None, &path).await;
    let RunStatus::Aborted(info) = &p.out.status else { panic!("not aborted: {:?}", p.out.status) };
    assert_eq!(info.culprit, Culprit::Operator);
    assert!(info.message.contains("nobody can give it"), "{info}");
    assert!(p.targets_after.iter().all(|t| *t < SimRigConfig::default().surface_mm - 1.0), "{:?}", p.targets_after);
}

#[test]
fn a_typed_line_at_the_prompt_confirms_only_when_empty() {
    use easycalib::tui::operator_answer;
    assert_eq!(operator_answer(Ok(Some("\n".into()))), RunControl::Confirm);
    assert_eq!(operator_answer(Ok(Some("a\n".into()))), RunControl::Abort);
    assert_eq!(operator_answer(Ok(Some("abort\n".into()))), RunControl::Abort);
    assert_eq!(operator_answer(Ok(None)), RunControl::Abort);
    assert_eq!(operator_answer(Err(std::io::Error::other("gone"))), RunControl::Abort);
}

/// The plain display answers a prompt with the typed line and stops asking once the run is over.
#[tokio::test]
async fn the_plain_display_sends_the_typed_answer() {
    let (ev_tx, ev_rx) = unbounded_channel();
    let (ctl_tx, mut ctl_rx) = unbounded_channel();
    let body = sim::physics::Body { e_mpa: RIGID_BALL_E_MPA, nu: 0.3, r_mm: 5.0 };
    ev_tx
        .send(RunEvent::OperatorPrompt { step: "rigid_ball".into(), indenter: body, message: "mount it".into() })
        .unwrap();
    let display =
        tokio::spawn(easycalib::tui::run_plain_prompting(ev_rx, Vec::new(), ctl_tx, || Ok(Some("\n".into()))));
    assert_eq!(ctl_rx.recv().await, Some(RunControl::Confirm));
    ev_tx.send(RunEvent::OperatorConfirmed { step: "rigid_ball".into() }).unwrap();
    ev_tx.send(RunEvent::Aborted { reason: "end".into() }).unwrap();
    let state = display.await.unwrap().unwrap();
    assert!(state.prompt().is_none() && state.status().is_over());
}

/// The TUI's prompt panel: shown from the prompt to the confirmation, `c`
/// confirms (once), `a` still aborts.
#[test]
fn the_tui_prompt_takes_c_to_confirm_and_a_to_abort() {
    use easycalib::run::events::RunPhase;
    use easycalib::tui::State;
    use ratatui::crossterm::event::{KeyCode, KeyEvent, KeyModifiers};
    let key = |c: char| KeyEvent::new(KeyCode::Char(c), KeyModifiers::NONE);
    let body = sim::physics::Body { e_mpa: RIGID_BALL_E_MPA, nu: 0.3, r_mm: 5.0 };
    let prompt = RunEvent::OperatorPrompt { step: "rigid_ball".into(), indenter: body, message: "mount it".into() };
    let started = || {
        let mut s = State::new();
        s.apply(&RunEvent::StepStarted {
            index: 8,
            total: 10,
            name: "adaptive: rigid_ball".into(),
            phase: RunPhase::Normal,
        });
        s
    };
    let mut s = started();
    // No prompt: c does nothing.
    assert_eq!(s.on_key(key('c')), None);
    s.apply(&prompt);
    assert_eq!(s.prompt().map(|p| (p.step.as_str(), p.indenter)), Some(("rigid_ball", body)));
    assert_eq!(s.on_key(key('c')), Some(RunControl::Confirm));
    assert_eq!(s.on_key(key('c')), None, "one confirmation while it is pending");
    s.apply(&RunEvent::OperatorConfirmed { step: "rigid_ball".into() });
    assert!(s.prompt().is_none() && s.pending().is_none());
    // A second prompt, aborted.
    s.apply(&prompt);
    assert_eq!(s.on_key(key('a')), Some(RunControl::Abort));
    s.apply(&RunEvent::Aborted { reason: "abort requested by the operator during the rigid_ball prompt".into() });
    assert!(s.prompt().is_none() && s.status().is_over());
    // The panel is drawn while a prompt waits.
    let mut s = started();
    s.apply(&prompt);
    let mut term = ratatui::Terminal::new(ratatui::backend::TestBackend::new(120, 40)).unwrap();
    term.draw(|f| easycalib::tui::draw(&s, f)).unwrap();
    let text: String = term.backend().buffer().content().iter().map(|c| c.symbol()).collect();
    assert!(text.contains("OPERATOR STEP") && text.contains("E 210000 MPa"), "panel not drawn");
}
