//! The sequencer against the in-process simulated rig (physics, noise, lag,
//! injected faults), against mockall mocks (order of device calls), and a
//! property test of the soft limits. No real-time waits: the simulated devices
//! answer at once and keep their own rig clock.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use async_trait::async_trait;
use devices::motion::FaultKind;
use easycalib::fit::{FitOptions, calibrate};
use easycalib::run::events::{RunControl, RunEvent, RunPhase, SensorStatus};
use easycalib::run::gauge::{Gauge, GaugeError, GaugeReading};
use easycalib::run::{Backoff, Culprit, RunOutcome, RunStatus, Script, Sequencer};
use sim::generator::CleanRig;
use sim::recording::{Direction, Phase, Recording};
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender, unbounded_channel};

#[path = "support/simrig.rs"]
mod simrig;
use simrig::{SimFaults, SimGauge, SimRig, SimRigConfig};

fn drain(rx: &mut UnboundedReceiver<RunEvent>) -> Vec<RunEvent> {
    let mut v = Vec::new();
    while let Ok(e) = rx.try_recv() {
        v.push(e);
    }
    v
}

/// Run `script` on a simulated rig with `cfg`; returns the outcome, events and the rig.
async fn run_sim(script: Script, cfg: SimRigConfig, path: &Path) -> (RunOutcome, Vec<RunEvent>, SimRig) {
    let rig = SimRig::new(cfg).unwrap();
    let (tx, mut rx) = unbounded_channel();
    let mut seq = Sequencer::new(script, rig.stage(), rig.mount(), rig.gauge(), path).unwrap().with_events(tx);
    let out = seq.run().await;
    (out, drain(&mut rx), rig)
}

/// The run's log lines that contain `needle`, in order.
fn logs_with<'a>(events: &'a [RunEvent], needle: &str) -> Vec<&'a str> {
    events
        .iter()
        .filter_map(|e| match e {
            RunEvent::Log { message, .. } if message.contains(needle) => Some(message.as_str()),
            _ => None,
        })
        .collect()
}

fn samples_in(events: &[RunEvent]) -> usize {
    events.iter().filter(|e| matches!(e, RunEvent::Sample(_))).count()
}

#[tokio::test]
async fn full_default_run_recovers_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("run/recording.csv");
    let cfg = SimRigConfig::default();
    let (out, events, rig) = run_sim(Script::default(), cfg, &path).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);

    // Steps in order, from connect to retract.
    let steps: Vec<(usize, RunPhase)> = events
        .iter()
        .filter_map(|e| match e {
            RunEvent::StepStarted { index, phase, total, .. } => {
                assert_eq!(*total, 8);
                Some((*index, *phase))
            }
            _ => None,
        })
        .collect();
    // The torsion sweep at the top of the loading branch, the unloading after it.
    let expect_phases = [
        RunPhase::Setup,
        RunPhase::Setup,
        RunPhase::Approach,
        RunPhase::Normal,
        RunPhase::Torsion,
        RunPhase::Torsion,
        RunPhase::Normal,
        RunPhase::Retract,
    ];
    assert_eq!(steps, expect_phases.iter().copied().enumerate().collect::<Vec<_>>());
    assert!(!events.iter().any(|e| matches!(e, RunEvent::Aborted { .. })));

    // The recording has every sample the events announced, and the fit recovers the truth.
    let rec = Recording::read_path(&path).unwrap();
    assert_eq!(rec.samples.len(), out.samples);
    assert_eq!(samples_in(&events), out.samples);
    let n_torsion = rec.phase(Phase::Torsion).count();
    assert_eq!(n_torsion, Script::default().twist_samples());
    // Both branches of the normal sweep, and the paper's method's window (at
    // least 4 samples with gamma1 in 0.2-0.8 mm) covered.
    let branch = |d: Direction| rec.phase(Phase::Normal).filter(|s| s.dir == Some(d)).count();
    assert!(branch(Direction::Load) >= 10 && branch(Direction::Unload) >= 10);
    assert!(rec.phase(Phase::Normal).filter(|s| (0.2..=0.8).contains(&s.gamma1_mm)).count() >= 4);
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let (e1, nu1) = (cfg.pair.elastomer.e_mpa, cfg.pair.elastomer.nu);
    assert!((cal.full.e1_mpa / e1 - 1.0).abs() < 0.01, "E1 {} vs {e1}", cal.full.e1_mpa);
    assert!((cal.full.nu1 / nu1 - 1.0).abs() < 0.02, "nu1 {} vs {nu1}", cal.full.nu1);

    // The contact point is found to a few micrometres, the torsion depth held at beta 0.2.
    let contact = out.contact_mm.unwrap();
    assert!((contact - cfg.surface_mm).abs() < 0.01, "contact {contact}");
    let beta = out.torsion_beta.unwrap();
    assert!((beta - 0.2).abs() < 0.002, "beta {beta}");

    // The running fit was reported and ends near the truth too.
    let last_fit = events
        .iter()
        .rev()
        .find_map(|e| match e {
            RunEvent::Fit(f) => Some(*f),
            _ => None,
        })
        .unwrap();
    // The running fit is the paper's method, which a few micrometres of contact
    // error move by several percent (the contact line is drawn through deeper,
    // lagging readings so that a marker grid's poor small-contact readings do not bias it).
    assert!((last_fit.e1_mpa.unwrap() / e1 - 1.0).abs() < 0.08, "{last_fit:?}");
    // Progress carried an ETA during the sweeps and reached the end.
    assert!(events.iter().any(|e| matches!(e, RunEvent::Progress(p) if p.eta_s.is_some_and(|t| t > 0.0))));
    assert!(events.iter().any(|e| matches!(e, RunEvent::DeviceStatus(d) if d.sensor.frames > 0)));
    // Once the sweeps are under way, elapsed + ETA predicts the end within 25 %.
    let total = out.rig_time_s;
    let mut checked = 0;
    for e in &events {
        if let RunEvent::Progress(p) = e
            && p.elapsed_s > 0.3 * total
            && p.elapsed_s < 0.9 * total
        {
            let eta = p.eta_s.expect("ETA known during the sweeps");
            assert!(
                ((p.elapsed_s + eta) / total - 1.0).abs() < 0.25,
                "at {} s ETA {} s, run took {total} s",
                p.elapsed_s,
                eta
            );
            checked += 1;
        }
    }
    // (About one event a sample and a move: ~60 samples since issue 15's design.)
    assert!(checked > 30, "{checked} progress events checked");
    // The stage ended at the park position, out of contact.
    assert_eq!(rig.state().stage_mm, Script::default().park_mm());
    eprintln!(
        "default run: {} samples, rig time {:.1} s (sweeps {:.1} s), wall {:.3} s, E1 {:.4} nu1 {:.4}",
        out.samples,
        out.rig_time_s,
        rec.samples[rec.samples.len() - 1].t_s - rec.samples[0].t_s,
        out.wall_time_s,
        cal.full.e1_mpa,
        cal.full.nu1
    );
    assert!(out.rig_time_s > 10.0 && out.rig_time_s < 120.0, "rig time {}", out.rig_time_s);
}

/// Recorded samples are settled values, not lagging ones: the recorded
/// gamma1 agrees with the clean truth at that stage position. A slower
/// elastomer makes the sequencer wait longer per sample (adaptive settling;
/// a fixed wait would take the same time and record lagging values).
#[tokio::test]
async fn adaptive_settling_waits_longer_for_a_slower_elastomer() {
    let mut per_sample = Vec::new();
    for lag_s in [0.05, 0.15] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.csv");
        let cfg = SimRigConfig { lag_s, ..Default::default() };
        let (out, _, _) = run_sim(Script::default(), cfg, &path).await;
        assert!(out.completed(), "{:?}", out.status);
        let rec = Recording::read_path(&path).unwrap();
        let clean = CleanRig::new(cfg.pair).unwrap();
        let contact = out.contact_mm.unwrap();
        let errs: Vec<f64> = rec
            .phase(Phase::Normal)
            .map(|s| s.gamma1_mm - clean.normal(s.stage_mm + contact - cfg.surface_mm).unwrap().0)
            .collect();
        let worst = errs.iter().fold(0.0f64, |a, e| a.max(e.abs()));
        let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt();
        let cal = calibrate(&rec, &FitOptions::default()).unwrap();
        eprintln!(
            "lag {lag_s} s: gamma1 error rms {rms:.5} worst {worst:.5} mm, rig time {:.1} s, E1 {:.4}",
            out.rig_time_s, cal.full.e1_mpa
        );
        if lag_s == 0.05 {
            // Mean of two readings has 1.4 um of noise; the lag adds little on top.
            assert!(rms < 0.003, "lag {lag_s} s: rms gamma1 error {rms} mm");
            // The worst case includes the contact point's own error (a few um).
            assert!(worst < 0.008, "lag {lag_s} s: worst gamma1 error {worst} mm");
        } else {
            // Slow relaxation hides in the noise sooner: a residual lag of about
            // 10 um remains, of opposite sign on load and unload (so the fit holds).
            assert!(rms < 0.015, "lag {lag_s} s: rms gamma1 error {rms} mm");
        }
        assert!((cal.full.e1_mpa / 0.33 - 1.0).abs() < 0.01, "lag {lag_s}: E1 {}", cal.full.e1_mpa);
        per_sample.push(out.rig_time_s / out.samples as f64);
    }
    assert!(per_sample[1] > per_sample[0] * 1.1, "time per sample {per_sample:?}");
}

/// Readings eight frames late (a full queue of a link that holds eight, the
/// devices' default; the settling's windows take six): every sample is still
/// read where the rig stands once its move is done, not where it stood
/// before (docs/run.md, "Reading after a move").
#[tokio::test]
async fn a_run_reading_behind_the_sensor_records_each_sample_where_the_rig_stands() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("behind.csv");
    let cfg = SimRigConfig { queued_frames: 8, ..SimRigConfig::default() };
    let (out, _, rig) = run_sim(Script::default(), cfg, &path).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    // Each move after a reading left a full queue, and the run dropped it
    // (every twist comes after one).
    let st = rig.state();
    assert!(st.superseded % 8 == 0 && st.superseded >= 8 * st.mount_moves, "{} dropped", st.superseded);
    drop(st);
    let rec = Recording::read_path(&path).unwrap();
    let clean = CleanRig::new(cfg.pair).unwrap();
    let contact = out.contact_mm.unwrap();
    let stage = |s: &sim::recording::Sample| s.stage_mm + contact - cfg.surface_mm;
    // gamma1 at each normal sample's own stage position (the mean of two
    // frames carries ~1.4 um of noise, the contact's error a few um).
    let worst_g = rec
        .phase(Phase::Normal)
        .map(|s| (s.gamma1_mm - clean.normal(stage(s)).unwrap().0).abs())
        .fold(0.0f64, f64::max);
    // theta1 at each twist sample's own angle: a sample read on the queue
    // holds the previous angle's, 1.25 deg away per 2 deg step. (The sim's
    // elastomer lag leaves up to 0.09 deg at the sweep's first and last
    // angles, within the settle's noise tolerance, with or without a queue.)
    let worst_t = rec
        .phase(Phase::Torsion)
        .map(|s| (s.theta1_deg - clean.torsion_theta1_deg(stage(s), s.rot_deg).unwrap()).abs())
        .fold(0.0f64, f64::max);
    eprintln!("reading 8 frames behind: worst gamma1 error {worst_g:.5} mm, worst theta1 error {worst_t:.5} deg");
    assert!(worst_g < 0.008, "a normal sample {worst_g} mm from its stage position's gamma1");
    assert!(worst_t < 0.2, "a twist sample {worst_t} deg from its angle's theta1");
    let cal = calibrate(&rec, &FitOptions::default()).unwrap();
    let (e1, nu1) = (cfg.pair.elastomer.e_mpa, cfg.pair.elastomer.nu);
    assert!((cal.full.e1_mpa / e1 - 1.0).abs() < 0.01, "E1 {} vs {e1}", cal.full.e1_mpa);
    assert!((cal.full.nu1 / nu1 - 1.0).abs() < 0.02, "nu1 {} vs {nu1}", cal.full.nu1);
}

/// A frame processor reports exact zeros without contact, so the noise at
/// rest reads zero; the sequencer learns the in-contact noise from its
/// settled windows instead of demanding sub-noise stability (which would
/// make every sample wait for the settle timeout).
#[tokio::test]
async fn noise_free_rest_readings_do_not_stall_settling() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("z.csv");
    let cfg = SimRigConfig { zero_out_of_contact: true, ..Default::default() };
    let (out, events, _) = run_sim(Script::default(), cfg, &path).await;
    assert!(out.completed(), "{:?}", out.status);
    assert_eq!(out.noise_gamma1_mm, None, "rest readings were exact zeros");
    let timeouts = events
        .iter()
        .filter(|e| matches!(e, RunEvent::Log { message, .. } if message.starts_with("not settled")))
        .count();
    assert!(timeouts < 10, "{timeouts} samples hit the settle timeout");
    // As quick as with noisy rest readings (without the learnt noise it takes ~13 % longer).
    let (noisy, _, _) = run_sim(Script::default(), SimRigConfig::default(), &dir.path().join("n.csv")).await;
    assert!(out.rig_time_s < 1.05 * noisy.rig_time_s, "rig time {} vs {}", out.rig_time_s, noisy.rig_time_s);
    let cal = calibrate(&Recording::read_path(&path).unwrap(), &FitOptions::default()).unwrap();
    assert!((cal.full.e1_mpa / 0.33 - 1.0).abs() < 0.01, "E1 {}", cal.full.e1_mpa);
    assert!((cal.full.nu1 / 0.39 - 1.0).abs() < 0.02, "nu1 {}", cal.full.nu1);
}

/// Wraps a gauge and, at a given read, sends a control and snapshots the
/// recording file as a killed process would leave it.
struct ScriptedGauge {
    inner: SimGauge,
    reads: usize,
    at: usize,
    control: Option<RunControl>,
    ctl: UnboundedSender<RunControl>,
    path: PathBuf,
    snapshot: Arc<Mutex<Option<Recording>>>,
}

#[async_trait]
impl Gauge for ScriptedGauge {
    async fn start(&mut self) -> Result<(), GaugeError> {
        self.inner.start().await
    }
    async fn read(&mut self, timeout: Duration) -> Result<GaugeReading, GaugeError> {
        self.reads += 1;
        if self.reads == self.at {
            *self.snapshot.lock().unwrap() = Some(Recording::read_path(&self.path).unwrap());
            if let Some(c) = self.control {
                self.ctl.send(c).unwrap();
            }
        }
        self.inner.read(timeout).await
    }
    fn discard_queued(&mut self) -> usize {
        self.inner.discard_queued()
    }
    async fn tare(&mut self) -> Result<(), GaugeError> {
        self.inner.tare().await
    }
    fn link_stats(&self) -> SensorStatus {
        self.inner.link_stats()
    }
    fn describe(&self) -> String {
        self.inner.describe()
    }
}

#[tokio::test]
async fn abort_mid_sweep_leaves_a_readable_recording_and_backs_off() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("killed.csv");
    let rig = SimRig::new(SimRigConfig::default()).unwrap();
    let (ctl_tx, ctl_rx) = unbounded_channel();
    let (tx, mut rx) = unbounded_channel();
    let snapshot = Arc::new(Mutex::new(None));
    // Read 600 falls in the normal sweep (about 7 reads per settled sample after ~100 approach reads).
    let gauge = ScriptedGauge {
        inner: rig.gauge(),
        reads: 0,
        at: 600,
        control: Some(RunControl::Abort),
        ctl: ctl_tx,
        path: path.clone(),
        snapshot: snapshot.clone(),
    };
    let mut seq = Sequencer::new(stepwise(), rig.stage(), rig.mount(), gauge, &path)
        .unwrap()
        .with_events(tx)
        .with_controls(ctl_rx);
    let out = seq.run().await;
    let events = drain(&mut rx);
    let RunStatus::Aborted(info) = &out.status else { panic!("not aborted: {:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Operator);
    assert_eq!(info.backoff, Backoff::To(0.0));
    assert!(info.to_string().contains("abort requested by the operator"), "{info}");
    assert!(info.to_string().contains("stage backed off to 0.000 mm"), "{info}");
    assert!(events.iter().any(|e| matches!(e, RunEvent::Aborted { reason } if reason == &info.to_string())));

    // What a kill at read 600 would have left: readable, every sample announced so far.
    let snap = snapshot.lock().unwrap().take().unwrap();
    assert!(snap.samples.len() >= 40, "{} samples", snap.samples.len());
    assert!(snap.samples.iter().all(|s| s.phase == Phase::Normal));
    // After the abort: all settled samples, no torsion, nothing lost.
    let rec = Recording::read_path(&path).unwrap();
    assert_eq!(rec.samples.len(), out.samples);
    assert_eq!(samples_in(&events), out.samples);
    assert_eq!(&rec.samples[..snap.samples.len()], &snap.samples[..]);
    assert!(out.samples <= snap.samples.len() + 1, "stopped at the next safe point");
    let st = rig.state();
    assert!(st.stage_stops >= 1 && st.mount_stops >= 1);
    assert_eq!(st.stage_targets.last(), Some(&0.0), "last commanded move is the back-off");
    assert_eq!(st.mount_moves, 0, "no torsion after the abort");
}

#[tokio::test]
async fn pause_holds_at_a_safe_point_and_resume_continues() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("paused.csv");
    let rig = SimRig::new(SimRigConfig::default()).unwrap();
    let (ctl_tx, ctl_rx) = unbounded_channel();
    let (tx, mut rx) = unbounded_channel();
    let gauge = ScriptedGauge {
        inner: rig.gauge(),
        reads: 0,
        at: 400,
        control: Some(RunControl::Pause),
        ctl: ctl_tx.clone(),
        path: path.clone(),
        snapshot: Arc::new(Mutex::new(None)),
    };
    let seq = Sequencer::new(Script::default(), rig.stage(), rig.mount(), gauge, &path)
        .unwrap()
        .with_events(tx)
        .with_controls(ctl_rx);
    // An operator that resumes once the run says it paused, noting whether anything moved while paused.
    let watcher_rig = rig.clone();
    let operator = tokio::spawn(async move {
        let mut log = Vec::new();
        let mut moves_at_pause = None;
        while let Some(ev) = rx.recv().await {
            if matches!(ev, RunEvent::Paused) {
                let counts = |r: &SimRig| {
                    let st = r.state();
                    (st.stage_moves, st.mount_moves, st.reads)
                };
                let here = counts(&watcher_rig);
                // Give the sequencer every chance to (wrongly) carry on.
                for _ in 0..10 {
                    tokio::task::yield_now().await;
                }
                moves_at_pause = Some((here, counts(&watcher_rig)));
                ctl_tx.send(RunControl::Resume).unwrap();
            }
            log.push(ev);
        }
        (log, moves_at_pause)
    });
    let mut seq = seq;
    let out = seq.run().await;
    drop(seq);
    let (events, moves) = operator.await.unwrap();
    assert!(out.completed(), "{:?}", out.status);
    let (before, after) = moves.expect("the run paused");
    assert_eq!(before, after, "nothing moved or read while paused");
    let p = events.iter().position(|e| matches!(e, RunEvent::Paused)).unwrap();
    let r = events.iter().position(|e| matches!(e, RunEvent::Resumed)).unwrap();
    assert!(p < r);
    assert_eq!(Recording::read_path(&path).unwrap().samples.len(), out.samples);
}

use simrig::stepwise_script as stepwise;

/// Run with one injected fault; returns the abort and the rig.
async fn faulted(faults: SimFaults) -> (RunOutcome, SimRig, Recording) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f.csv");
    let cfg = SimRigConfig { faults, ..Default::default() };
    let (out, events, rig) = run_sim(stepwise(), cfg, &path).await;
    assert!(events.iter().any(|e| matches!(e, RunEvent::Aborted { .. })));
    let rec = Recording::read_path(&path).unwrap();
    assert_eq!(rec.samples.len(), out.samples);
    (out, rig, rec)
}

#[tokio::test]
async fn stage_cable_cut_mid_sweep_is_reported_and_recording_kept() {
    // Move 100: inside the normal sweep (the approach takes ~60 moves).
    let (out, rig, rec) =
        faulted(SimFaults { stage_move: Some((100, FaultKind::Disconnected)), ..Default::default() }).await;
    let RunStatus::Aborted(info) = &out.status else { panic!() };
    assert_eq!(info.culprit, Culprit::Stage);
    let msg = info.to_string();
    assert!(msg.contains("stage SIM-STAGE SN 0001") && msg.contains("disconnected"), "{msg}");
    // The cable is cut: backing off cannot work, and the message says so.
    assert!(matches!(info.backoff, Backoff::Failed(_)), "{msg}");
    assert!(msg.contains("COULD NOT back the stage off"), "{msg}");
    assert!(rec.samples.len() > 20);
    assert!(rig.state().mount_stops >= 1);
}

#[tokio::test]
async fn stage_device_error_stops_and_backs_off() {
    let (out, rig, rec) =
        faulted(SimFaults { stage_move: Some((100, FaultKind::DeviceReported)), ..Default::default() }).await;
    let RunStatus::Aborted(info) = &out.status else { panic!() };
    assert_eq!(info.culprit, Culprit::Stage);
    assert!(info.message.contains("device reported an error"), "{info}");
    assert_eq!(info.backoff, Backoff::To(0.0));
    let st = rig.state();
    assert!(st.stage_stops >= 1);
    assert_eq!(st.stage_mm, 0.0);
    assert!(rec.samples.len() > 20);
}

#[tokio::test]
async fn mount_fault_in_the_torsion_sweep_backs_the_stage_off() {
    let (out, rig, rec) =
        faulted(SimFaults { mount_move: Some((10, FaultKind::DeviceReported)), ..Default::default() }).await;
    let RunStatus::Aborted(info) = &out.status else { panic!() };
    assert_eq!(info.culprit, Culprit::Mount);
    assert!(info.message.contains("rotation mount SIM-MOUNT"), "{info}");
    assert_eq!(info.backoff, Backoff::To(0.0));
    assert_eq!(rig.state().stage_mm, 0.0);
    // The normal sweep and the first torsion samples are all there.
    assert_eq!(rec.phase(Phase::Torsion).count(), 9);
}

#[tokio::test]
async fn sensor_stream_stopping_aborts_after_the_dropout_timeout() {
    let (out, rig, rec) = faulted(SimFaults { sensor_silent_from: Some(700), ..Default::default() }).await;
    let RunStatus::Aborted(info) = &out.status else { panic!() };
    assert_eq!(info.culprit, Culprit::Sensor);
    // Default: 2.0 s dropout of 0.5 s reads = 4 consecutive timeouts.
    assert!(info.message.contains("4 consecutive read timeouts") && info.message.contains("stream stopped"), "{info}");
    assert_eq!(info.backoff, Backoff::To(0.0));
    assert_eq!(rig.state().reads, 699 + 4);
    assert!(rec.samples.len() > 40);
}

#[tokio::test]
async fn sensor_link_closing_aborts_at_once() {
    let (out, rig, _) = faulted(SimFaults { sensor_closed_at: Some(700), ..Default::default() }).await;
    let RunStatus::Aborted(info) = &out.status else { panic!() };
    assert_eq!(info.culprit, Culprit::Sensor);
    assert!(info.message.contains("disconnected") && info.message.contains("unplugged"), "{info}");
    assert_eq!(rig.state().reads, 700);
}

#[tokio::test]
async fn a_limit_that_forbids_the_target_depth_stops_the_sweep_safely() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lim.csv");
    let mut script = Script::default();
    script.limits.max_gamma1_mm = 1.0;
    let (out, _, rig) = run_sim(script, SimRigConfig::default(), &path).await;
    let RunStatus::Aborted(info) = &out.status else { panic!("{:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Safety);
    assert!(info.message.contains("max gamma1") && info.message.contains("before the target"), "{info}");
    assert!(
        info.message.contains("lower [normal] target_beta"),
        "the abort says what would make the run possible: {info}"
    );
    let st = rig.state();
    assert!(st.max_true_gamma1 <= 1.0, "true gamma1 reached {}", st.max_true_gamma1);
    assert!(st.max_true_gamma1 > 0.8, "the sweep went as deep as the limit allows: {}", st.max_true_gamma1);
    assert_eq!(st.stage_mm, 0.0);
}

/// A pair whose target depth lies just inside the depth limit: the landing
/// step's worst case (all of it into the gel) passes the limit, the gel
/// takes only part of it, so the sweep shortens its steps to what the limit
/// allows and lands on the target instead of stopping short of it; the gel
/// is never pressed past the limit. A limit below the target still stops
/// the sweep (`a_limit_that_forbids_the_target_depth_stops_the_sweep_safely`).
#[tokio::test]
async fn a_target_just_inside_the_depth_limit_is_reached_by_shorter_steps() {
    // The depth each loading branch reached, as the sweep reports it
    // ("normal sweep 1: beta 0.2003 reached at stage ...").
    let reached = |events: &[RunEvent]| -> Vec<f64> {
        events
            .iter()
            .filter_map(|e| match e {
                RunEvent::Log { message, .. } if message.contains(" reached at stage ") => {
                    message.split("beta ").nth(1)?.split(' ').next()?.parse().ok()
                }
                _ => None,
            })
            .collect()
    };
    let dir = tempfile::tempdir().unwrap();
    let free = dir.path().join("free.csv");
    let (out, events, rig) = run_sim(Script::default(), SimRigConfig::default(), &free).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    let deepest = rig.state().max_true_gamma1;
    assert!(!reached(&events).is_empty());

    let mut script = Script::default();
    script.limits.max_gamma1_mm = deepest + 0.02;
    let path = dir.path().join("near.csv");
    let (out, events, rig) = run_sim(script.clone(), SimRigConfig::default(), &path).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    let shortened = events
        .iter()
        .filter(|e| matches!(e, RunEvent::Log { message, .. } if message.contains("shortened to")))
        .count();
    assert!(shortened > 0, "the limit shortened a step");
    let st = rig.state();
    assert!(st.max_true_gamma1 <= script.limits.max_gamma1_mm, "true gamma1 {}", st.max_true_gamma1);
    let betas = reached(&events);
    assert_eq!(betas.len(), script.normal.repeats as usize);
    for b in betas {
        assert!((b - script.normal.target_beta).abs() <= 0.0025 * script.normal.target_beta + 1e-4, "beta {b}");
    }
    assert_eq!(Recording::read_path(&path).unwrap().samples.len(), out.samples);
}

/// Experiment steps go through the same guard and abort path as the sweeps
/// (docs/experiments.md): with a gamma1 limit between the torsion depth's and
/// the second depth's, the run records the dwell, then stops before the
/// second depth with the guard's reason, backs the stage off and keeps the
/// recording; with room, or a limit just past what it needs (its steps in
/// shortened to the limit), the same script completes with every phase.
#[tokio::test]
async fn an_experiment_beyond_the_gamma1_limit_stops_safely_and_keeps_the_recording() {
    use sim::experiment::{Experiment, ExperimentSpec};
    let dir = tempfile::tempdir().unwrap();
    let mut script = Script {
        experiment: vec![
            ExperimentSpec::Dwell { hold_s: 4.0, every_s: 1.0 },
            ExperimentSpec::TorsionAtDepth { beta: 0.3, amplitude_deg: 2.0, step_deg: 0.5 },
        ],
        ..Script::default()
    };
    script.limits.max_gamma1_mm = 20.0;
    let path = dir.path().join("room.csv");
    let (out, _, rig) = run_sim(script.clone(), SimRigConfig::default(), &path).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    let rec = Recording::read_path(&path).unwrap();
    let of = |r: &Recording, e| r.samples.iter().filter(|s| s.experiment == Some(e)).count();
    assert_eq!((of(&rec, Experiment::Dwell), of(&rec, Experiment::Torsion2)), (5, 9));
    let deepest = rig.state().max_true_gamma1;
    let hold = rec.sweep(Phase::Torsion).map(|s| s.gamma1_mm).fold(0.0, f64::max);
    assert!(deepest > hold * 1.2, "the second depth is deeper: {deepest} vs {hold}");

    // A limit just past the second depth's gamma1: the steps in are
    // shortened to what it allows and the experiment completes.
    script.limits.max_gamma1_mm = deepest + 0.02;
    let path = dir.path().join("near.csv");
    let (out, events, rig) = run_sim(script.clone(), SimRigConfig::default(), &path).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    let shortened = logs_with(&events, "shortened to");
    println!("{shortened:#?}");
    assert!(!shortened.is_empty(), "a step near the limit was shortened");
    assert!(rig.state().max_true_gamma1 <= script.limits.max_gamma1_mm);
    let rec = Recording::read_path(&path).unwrap();
    assert_eq!((of(&rec, Experiment::Dwell), of(&rec, Experiment::Torsion2)), (5, 9));

    script.limits.max_gamma1_mm = 0.5 * (hold + deepest);
    let path = dir.path().join("limited.csv");
    let (out, _, rig) = run_sim(script.clone(), SimRigConfig::default(), &path).await;
    let RunStatus::Aborted(info) = &out.status else { panic!("{:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Safety, "{info}");
    assert!(info.message.contains("max gamma1"), "{info}");
    let st = rig.state();
    assert!(st.max_true_gamma1 <= script.limits.max_gamma1_mm, "true gamma1 reached {}", st.max_true_gamma1);
    assert_eq!(st.stage_mm, 0.0);
    let rec = Recording::read_path(&path).unwrap();
    assert_eq!((of(&rec, Experiment::Dwell), of(&rec, Experiment::Torsion2)), (5, 0));
}

/// A frame drifting into the gel makes the measured depth lag the stage's
/// (the approach grows at a standing stage), so the return to the torsion
/// depth after the unloading branch chases its target deeper than the
/// loading branch went, and with the depth limit close the limit leaves the
/// chase no step: the stage holds where it stands, the deepest the limit
/// allows, says so, and the run completes with its torsion sweep there. (It
/// used to command the move the guard refuses and abort: seen on the
/// emulated rig in CI, a_slow_repeat_and_an_approach_at_another_speed_run_
/// through_the_real_drivers.) The guard bounds the moves it is asked for;
/// the drift goes on pressing at the hold, and there the depth watch backs
/// the stage off whenever a reading passes the limit (without it the true
/// gamma1 went to 4.69 mm on the 4.6 mm limit): the true gamma1 stays
/// within the watch's noise margin and the gel's lag of the limit.
#[tokio::test]
async fn a_drifting_frame_at_the_depth_limit_holds_the_torsion_depth_there() {
    use sim::experiment::ExperimentSpec;
    let dir = tempfile::tempdir().unwrap();
    // An experiment after the sweeps: the torsion returns to its depth after
    // the unloading branch instead of twisting at the top of the loading one.
    let mut script =
        Script { experiment: vec![ExperimentSpec::Dwell { hold_s: 2.0, every_s: 1.0 }], ..Script::default() };
    // The loading branch's top reads 4.4 mm of gamma1; 4 um/s of drift adds
    // about 0.3 mm of approach by the return.
    let script_limit = 4.6;
    script.limits.max_gamma1_mm = script_limit;
    let cfg = SimRigConfig { frame_drift_mm_per_s: 4e-3, ..SimRigConfig::default() };
    let path = dir.path().join("drift.csv");
    let (out, events, rig) = run_sim(script, cfg, &path).await;
    assert_eq!(out.status, RunStatus::Completed, "{:?}", out.status);
    let returns = logs_with(&events, "return to depth");
    println!("{returns:#?}\ntrue gamma1 at most {:.4} mm", rig.state().max_true_gamma1);
    let held = returns.iter().find_map(|m| m.split("held at stage ").nth(1)?.split(' ').next()?.parse::<f64>().ok());
    let held = held.unwrap_or_else(|| panic!("the limit held the return to depth: {returns:?}"));
    let rec = Recording::read_path(&path).unwrap();
    let twists: Vec<_> = rec.sweep(Phase::Torsion).collect();
    assert!(twists.len() >= 10, "the torsion sweep ran at the held depth: {} samples", twists.len());
    // Every stage target the run commanded lies at or short of the hold.
    let st = rig.state();
    // No stage target past the hold after it.
    let at = st.stage_targets.iter().rposition(|t| (t - held).abs() < 1e-4).unwrap_or(0);
    assert!(st.stage_targets[at..].iter().all(|t| *t <= held + 1e-9), "a move past the hold: {:?}", st.stage_targets);
    let backoffs = logs_with(&events, "depth limit: gamma1");
    println!("{backoffs:#?}");
    assert!(!backoffs.is_empty(), "the drift took the gel past the limit at the hold: the watch backed off");
    // Four reading noises (2 um here) and what the gel's lag lets the drift add.
    assert!(
        st.max_true_gamma1 <= script_limit + 0.02,
        "the true gamma1 reached {:.4} mm on the {script_limit} mm limit",
        st.max_true_gamma1
    );
    // The twists the watch moved are recorded where the stage went.
    let depths: Vec<f64> = twists.iter().map(|s| s.stage_mm).collect();
    assert!(depths.windows(2).all(|w| w[1] <= w[0] + 1e-12), "the torsion depth only backs off: {depths:?}");
    assert!(depths.first() > depths.last(), "a twist recorded at the backed-off depth: {depths:?}");
}

mod mocks {
    use super::simrig::SimFault;
    use super::*;
    use devices::motion::{Axis, AxisStatus, Deg, DeviceInfo, Identify, Mm};
    use mockall::mock;

    mock! {
        pub Stage {}
        #[async_trait]
        impl Identify for Stage {
            type Error = SimFault;
            async fn identify(&mut self) -> Result<DeviceInfo, SimFault>;
        }
        #[async_trait]
        impl Axis for Stage {
            type Unit = Mm;
            fn travel(&self) -> (Mm, Mm);
            async fn home(&mut self, timeout: Duration) -> Result<(), SimFault>;
            async fn start_move_to(&mut self, target: Mm) -> Result<(), SimFault>;
            async fn start_move_by(&mut self, delta: Mm) -> Result<(), SimFault>;
            async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<Mm, SimFault>;
            async fn stop(&mut self) -> Result<(), SimFault>;
            async fn position(&mut self) -> Result<Mm, SimFault>;
            async fn status(&mut self) -> Result<AxisStatus, SimFault>;
        }
    }

    mock! {
        pub Mount {}
        #[async_trait]
        impl Identify for Mount {
            type Error = SimFault;
            async fn identify(&mut self) -> Result<DeviceInfo, SimFault>;
        }
        #[async_trait]
        impl Axis for Mount {
            type Unit = Deg;
            fn travel(&self) -> (Deg, Deg);
            async fn home(&mut self, timeout: Duration) -> Result<(), SimFault>;
            async fn start_move_to(&mut self, target: Deg) -> Result<(), SimFault>;
            async fn start_move_by(&mut self, delta: Deg) -> Result<(), SimFault>;
            async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<Deg, SimFault>;
            async fn stop(&mut self) -> Result<(), SimFault>;
            async fn position(&mut self) -> Result<Deg, SimFault>;
            async fn status(&mut self) -> Result<AxisStatus, SimFault>;
        }
    }

    mock! {
        pub Sensor {}
        #[async_trait]
        impl Gauge for Sensor {
            async fn start(&mut self) -> Result<(), GaugeError>;
            async fn read(&mut self, timeout: Duration) -> Result<GaugeReading, GaugeError>;
            fn discard_queued(&mut self) -> usize;
            async fn tare(&mut self) -> Result<(), GaugeError>;
            fn link_stats(&self) -> SensorStatus;
            fn describe(&self) -> String;
        }
    }

    type Log = Arc<Mutex<Vec<String>>>;

    fn info(model: &str) -> DeviceInfo {
        DeviceInfo { model: model.into(), serial: "1".into(), firmware: "1.0".into() }
    }

    /// A stage mock that logs every call; moves land where commanded.
    /// `fail_move` makes that move (1-based) report a device error.
    pub fn stage(log: &Log, fail_home: bool, fail_move: Option<usize>) -> MockStage {
        let mut m = MockStage::new();
        let pos = Arc::new(Mutex::new(5.0f64));
        let moves = Arc::new(Mutex::new(0usize));
        m.expect_travel().return_const((Mm(0.0), Mm(25.0)));
        let l = log.clone();
        m.expect_identify().returning(move || {
            l.lock().unwrap().push("stage.identify".into());
            Ok(info("MOCK-STAGE"))
        });
        let (l, p) = (log.clone(), pos.clone());
        m.expect_home().returning(move |_| {
            l.lock().unwrap().push("stage.home".into());
            if fail_home {
                return Err(SimFault {
                    device: "mock stage",
                    kind: FaultKind::Timeout,
                    message: "home timed out".into(),
                });
            }
            *p.lock().unwrap() = 0.0;
            Ok(())
        });
        let (l, p) = (log.clone(), pos.clone());
        m.expect_start_move_to().returning(move |Mm(t)| {
            let mut n = moves.lock().unwrap();
            *n += 1;
            l.lock().unwrap().push(format!("stage.move {t:.3}"));
            if Some(*n) == fail_move {
                return Err(SimFault {
                    device: "mock stage",
                    kind: FaultKind::DeviceReported,
                    message: "APT error".into(),
                });
            }
            *p.lock().unwrap() = t;
            Ok(())
        });
        m.expect_start_move_by().never();
        let p = pos.clone();
        m.expect_wait_until_stopped().returning(move |_| Ok(Mm(*p.lock().unwrap())));
        let l = log.clone();
        m.expect_stop().returning(move || {
            l.lock().unwrap().push("stage.stop".into());
            Ok(())
        });
        let p = pos.clone();
        m.expect_position().returning(move || Ok(Mm(*p.lock().unwrap())));
        let p = pos;
        m.expect_status().returning(move || Ok(AxisStatus { position: *p.lock().unwrap(), ..Default::default() }));
        m
    }

    pub fn mount(log: &Log) -> MockMount {
        let mut m = MockMount::new();
        m.expect_travel().return_const((Deg(-170.0), Deg(170.0)));
        let l = log.clone();
        m.expect_identify().returning(move || {
            l.lock().unwrap().push("mount.identify".into());
            Ok(info("MOCK-MOUNT"))
        });
        let l = log.clone();
        m.expect_home().returning(move |_| {
            l.lock().unwrap().push("mount.home".into());
            Ok(())
        });
        let l = log.clone();
        m.expect_start_move_to().returning(move |Deg(t)| {
            l.lock().unwrap().push(format!("mount.move {t:.3}"));
            Ok(())
        });
        m.expect_start_move_by().never();
        m.expect_wait_until_stopped().returning(|_| Ok(Deg(0.0)));
        let l = log.clone();
        m.expect_stop().returning(move || {
            l.lock().unwrap().push("mount.stop".into());
            Ok(())
        });
        m.expect_position().returning(|| Ok(Deg(0.0)));
        m.expect_status().returning(|| Ok(AxisStatus::default()));
        m
    }

    /// A sensor that never sees contact: flat noise-free zero.
    pub fn sensor() -> MockSensor {
        let mut m = MockSensor::new();
        m.expect_start().returning(|| Ok(()));
        m.expect_tare().returning(|| Ok(()));
        m.expect_discard_queued().return_const(0usize);
        let t = Arc::new(Mutex::new(0.0f64));
        m.expect_read().returning(move |_| {
            let mut t = t.lock().unwrap();
            *t += 0.04;
            Ok(GaugeReading::new(*t, 0.0, 0.0, 0.0))
        });
        m.expect_link_stats().returning(SensorStatus::default);
        m.expect_describe().return_const("mock-sensor".to_string());
        m
    }

    pub fn new_log() -> Log {
        Arc::new(Mutex::new(Vec::new()))
    }
}

fn index_of(log: &[String], prefix: &str) -> Option<usize> {
    log.iter().position(|l| l.starts_with(prefix))
}

#[tokio::test]
async fn mock_order_home_before_any_move_and_retract_after_the_failure() {
    let log = mocks::new_log();
    let dir = tempfile::tempdir().unwrap();
    // The sensor never reports contact: the approach runs to the stage limit and aborts.
    let mut script = Script::default();
    script.limits.stage_max_mm = 11.0;
    let mut seq = Sequencer::new(
        script,
        mocks::stage(&log, false, None),
        mocks::mount(&log),
        mocks::sensor(),
        dir.path().join("r.csv"),
    )
    .unwrap();
    let out = seq.run().await;
    let RunStatus::Aborted(info) = &out.status else { panic!("{:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Procedure);
    assert!(info.message.contains("no contact found"), "{info}");
    let log = log.lock().unwrap().clone();
    let first_move = index_of(&log, "stage.move").unwrap();
    assert!(index_of(&log, "stage.home").unwrap() < first_move, "{log:?}");
    assert!(index_of(&log, "mount.home").unwrap() < first_move, "{log:?}");
    assert!(index_of(&log, "stage.identify").unwrap() < index_of(&log, "stage.home").unwrap());
    // Every approach target stays inside the window; the end is stop, stop, back-off.
    let n = log.len();
    assert_eq!(&log[n - 3..], ["stage.stop", "mount.stop", "stage.move 0.000"], "{log:?}");
    assert!(log.iter().filter_map(|l| l.strip_prefix("stage.move ")).all(|t| t.parse::<f64>().unwrap() <= 11.0));
}

#[tokio::test]
async fn mock_order_device_error_stops_both_axes_then_backs_off() {
    let log = mocks::new_log();
    let dir = tempfile::tempdir().unwrap();
    let mut seq = Sequencer::new(
        Script::default(),
        mocks::stage(&log, false, Some(3)),
        mocks::mount(&log),
        mocks::sensor(),
        dir.path().join("r.csv"),
    )
    .unwrap();
    let out = seq.run().await;
    let RunStatus::Aborted(info) = &out.status else { panic!("{:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Stage);
    assert!(info.message.contains("MOCK-STAGE") && info.message.contains("APT error"), "{info}");
    let log = log.lock().unwrap().clone();
    let failed = log.iter().filter(|l| l.starts_with("stage.move")).nth(2).unwrap().clone();
    let at = log.iter().position(|l| *l == failed).unwrap();
    assert_eq!(&log[at + 1..], ["stage.stop", "mount.stop", "stage.move 0.000"], "{log:?}");
}

#[tokio::test]
async fn mock_order_abort_before_start_never_moves_and_failed_home_leaves_stage() {
    // Abort queued before the run: nothing is commanded at all.
    let log = mocks::new_log();
    let dir = tempfile::tempdir().unwrap();
    let (ctl_tx, ctl_rx) = unbounded_channel();
    ctl_tx.send(RunControl::Abort).unwrap();
    let mut seq = Sequencer::new(
        Script::default(),
        mocks::stage(&log, false, None),
        mocks::mount(&log),
        mocks::sensor(),
        dir.path().join("a.csv"),
    )
    .unwrap()
    .with_controls(ctl_rx);
    let out = seq.run().await;
    let RunStatus::Aborted(info) = &out.status else { panic!() };
    assert_eq!(info.culprit, Culprit::Operator);
    assert_eq!(info.backoff, Backoff::NotHomed);
    assert_eq!(*log.lock().unwrap(), ["stage.stop", "mount.stop"]);

    // Homing fails: the position is unknown, so the stage is stopped and not moved.
    let log = mocks::new_log();
    let mut seq = Sequencer::new(
        Script::default(),
        mocks::stage(&log, true, None),
        mocks::mount(&log),
        mocks::sensor(),
        dir.path().join("b.csv"),
    )
    .unwrap();
    let out = seq.run().await;
    let RunStatus::Aborted(info) = &out.status else { panic!() };
    assert_eq!(info.culprit, Culprit::Stage);
    assert!(info.to_string().contains("homing: timeout") && info.to_string().contains("not homed"), "{info}");
    let log = log.lock().unwrap().clone();
    assert!(index_of(&log, "stage.move").is_none(), "{log:?}");
    assert!(index_of(&log, "stage.stop").is_some());
}

mod limits {
    use super::*;
    use proptest::prelude::*;
    use sim::physics::{Body, ContactPair};

    fn fault_kind() -> impl Strategy<Value = FaultKind> {
        prop_oneof![Just(FaultKind::Disconnected), Just(FaultKind::DeviceReported), Just(FaultKind::Timeout)]
    }

    prop_compose! {
        fn scripts()(
            start in 6.0f64..11.5,
            approach_step in 0.02f64..0.2,
            normal_step in 0.03f64..0.3,
            beta in 0.05f64..0.3,
            repeats in 1u32..3,
            amp in 1.0f64..10.0,
            twist_step in 0.3f64..2.0,
            window in 0.5f64..14.0,
            max_g1 in 0.2f64..4.0,
            max_twist_extra in 0.0f64..3.0,
            retract_frac in 0.0f64..1.0,
        ) -> Script {
            let mut s = Script::default();
            s.approach.start_mm = start;
            s.approach.step_mm = approach_step;
            s.normal.step_mm = normal_step;
            s.normal.target_beta = beta;
            s.normal.repeats = repeats;
            s.torsion.amplitude_deg = amp;
            s.torsion.step_deg = twist_step;
            s.limits.stage_max_mm = start + window;
            s.limits.max_gamma1_mm = max_g1;
            s.limits.max_twist_deg = amp + max_twist_extra;
            s.limits.retract_mm = start * retract_frac;
            s
        }
    }

    prop_compose! {
        fn faults()(
            stage in proptest::option::of((1usize..150, fault_kind())),
            mount in proptest::option::of((1usize..40, fault_kind())),
            silent in proptest::option::of(1usize..2500),
            closed in proptest::option::of(1usize..2500),
        ) -> SimFaults {
            SimFaults { stage_move: stage, mount_move: mount, sensor_silent_from: silent, sensor_closed_at: closed }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 40, ..ProptestConfig::default() })]

        /// For random scripts, elastomers and faults, no commanded stage or
        /// mount position leaves the soft limits, and the elastomer is never
        /// pressed deeper than max gamma1.
        #[test]
        fn commanded_positions_never_leave_the_soft_limits(
            script in scripts(),
            faults in faults(),
            e1 in 0.1f64..1.0,
            nu1 in 0.2f64..0.49,
            surface in 11.6f64..16.0,
            seed in 0u64..1000,
        ) {
            let cfg = SimRigConfig {
                pair: ContactPair { elastomer: Body::new(e1, nu1, 33.0), indenter: Body::new(1.1, 0.39, 5.0) },
                surface_mm: surface,
                seed,
                faults,
                ..Default::default()
            };
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("p.csv");
            let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
            let (out, _, rig) = rt.block_on(run_sim(script.clone(), cfg, &path));
            let st = rig.state();
            let (lo, hi) = (script.limits.stage_min_mm.max(0.0), script.limits.stage_max_mm.min(25.0));
            for t in &st.stage_targets {
                prop_assert!(*t >= lo && *t <= hi, "stage target {} outside [{}, {}]", t, lo, hi);
            }
            for t in &st.mount_targets {
                prop_assert!(t.abs() <= script.limits.max_twist_deg + 1e-9, "twist {} > {}", t, script.limits.max_twist_deg);
            }
            prop_assert!(
                st.max_true_gamma1 <= script.limits.max_gamma1_mm,
                "true gamma1 {} > max {} ({:?})", st.max_true_gamma1, script.limits.max_gamma1_mm, out.status
            );
            // Whatever happened, the recording holds every sample taken.
            if out.samples > 0 {
                prop_assert_eq!(Recording::read_path(&path).unwrap().samples.len(), out.samples);
            }
        }
    }
}

/// A stage whose n-th move never ends by itself (a long travel), and which
/// presses the operator's abort key as that move starts.
struct StuckStage {
    inner: simrig::SimStage,
    moves: usize,
    stuck_at: usize,
    stuck: bool,
    ctl: UnboundedSender<RunControl>,
    log: Arc<Mutex<Vec<String>>>,
}

#[async_trait]
impl devices::motion::Identify for StuckStage {
    type Error = simrig::SimFault;
    async fn identify(&mut self) -> Result<devices::motion::DeviceInfo, Self::Error> {
        self.inner.identify().await
    }
}

#[async_trait]
impl devices::motion::Axis for StuckStage {
    type Unit = devices::motion::Mm;
    fn travel(&self) -> (Self::Unit, Self::Unit) {
        self.inner.travel()
    }
    async fn home(&mut self, t: Duration) -> Result<(), Self::Error> {
        self.inner.home(t).await
    }
    async fn start_move_to(&mut self, target: Self::Unit) -> Result<(), Self::Error> {
        let target_mm = target.0;
        self.moves += 1;
        self.log.lock().unwrap().push(format!("move {target_mm:.3}"));
        if self.moves == self.stuck_at {
            self.stuck = true;
            self.ctl.send(RunControl::Abort).unwrap();
        }
        self.inner.start_move_to(target).await
    }
    async fn start_move_by(&mut self, d: Self::Unit) -> Result<(), Self::Error> {
        self.inner.start_move_by(d).await
    }
    async fn wait_until_stopped(&mut self, t: Duration) -> Result<Self::Unit, Self::Error> {
        if self.stuck {
            self.log.lock().unwrap().push("waiting".into());
            std::future::pending::<()>().await;
        }
        self.inner.wait_until_stopped(t).await
    }
    async fn stop(&mut self) -> Result<(), Self::Error> {
        self.stuck = false;
        self.log.lock().unwrap().push("stop".into());
        self.inner.stop().await
    }
    async fn position(&mut self) -> Result<Self::Unit, Self::Error> {
        self.inner.position().await
    }
    async fn status(&mut self) -> Result<devices::motion::AxisStatus, Self::Error> {
        self.inner.status().await
    }
}

#[tokio::test]
async fn abort_during_a_move_stops_it_then_backs_off() {
    let dir = tempfile::tempdir().unwrap();
    let rig = SimRig::new(SimRigConfig::default()).unwrap();
    let (ctl_tx, ctl_rx) = unbounded_channel();
    let log = Arc::new(Mutex::new(Vec::new()));
    let stage = StuckStage { inner: rig.stage(), moves: 0, stuck_at: 80, stuck: false, ctl: ctl_tx, log: log.clone() };
    let mut seq = Sequencer::new(stepwise(), stage, rig.mount(), rig.gauge(), dir.path().join("m.csv"))
        .unwrap()
        .with_controls(ctl_rx);
    let out = seq.run().await;
    let RunStatus::Aborted(info) = &out.status else { panic!("{:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Operator);
    assert!(info.message.contains("during normal sweep"), "{info}");
    assert_eq!(info.backoff, Backoff::To(0.0));
    let log = log.lock().unwrap().clone();
    let n = log.len();
    assert_eq!(&log[n - 3..], ["waiting", "stop", "move 0.000"], "{log:?}");
}

/// The caller runs the sequencer in its own task (the TUI owns the terminal):
/// the run future must be `Send`.
#[tokio::test]
async fn the_run_can_be_spawned_on_a_task() {
    let dir = tempfile::tempdir().unwrap();
    let rig = SimRig::new(SimRigConfig::default()).unwrap();
    let mut seq =
        Sequencer::new(Script::default(), rig.stage(), rig.mount(), rig.gauge(), dir.path().join("s.csv")).unwrap();
    let out = tokio::spawn(async move { seq.run().await }).await.unwrap();
    assert!(out.completed());
}

/// A frame drifting into the gel at 0.2 mm/s (fifty times the rig tests'
/// drift): the approach grows by 7 um a frame wherever the stage stands.
/// The watch backs the stage off each time the readings pass the limit,
/// the guard's bound follows the readings, and the run stops on the limit
/// with the stage out of the gel. The true gamma1 stays within the watch's
/// allowance of the 4.6 mm limit (4.64 mm; without the watch 4.79 mm).
#[tokio::test]
async fn a_frame_drifting_fast_into_the_gel_is_backed_off_and_stops_the_run_out_of_it() {
    let dir = tempfile::tempdir().unwrap();
    let mut script = Script::default();
    script.limits.max_gamma1_mm = 4.6;
    let cfg = SimRigConfig { frame_drift_mm_per_s: 0.2, ..SimRigConfig::default() };
    let path = dir.path().join("drift.csv");
    let (out, events, rig) = run_sim(script, cfg, &path).await;
    let RunStatus::Aborted(info) = &out.status else { panic!("{:?}", out.status) };
    assert_eq!(info.culprit, Culprit::Safety, "{info}");
    let backoffs = logs_with(&events, "depth limit: gamma1");
    assert!(backoffs.len() >= 2, "{backoffs:#?}");
    let st = rig.state();
    assert!(st.max_true_gamma1 <= 4.65, "the true gamma1 reached {:.4} mm on the 4.6 mm limit", st.max_true_gamma1);
    assert_eq!(st.stage_mm, 0.0, "the abort backed the stage off to its retract position");
}
