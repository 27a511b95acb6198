//! The experiment steps after the torsion sweep (docs/experiments.md): a dwell,
//! unload-reload cycles, a twist reversal, a torsion sweep at a second depth.
//! Every move goes through `move_stage` / `move_mount` (the guard), every
//! sample through `record`, with the experiment as its phase.

use super::*;
use sim::experiment::{dwell_count, reload_path, repeat_path, reversal_angles, sweep_angles};
use sim::recording::Recording;

use crate::run::events::{LoopChoice, LoopView};

/// Where an operator step's recording goes: beside the run's, the step's
/// name before the extension (`recording.csv` -> `recording.rigid_ball.csv`).
pub(super) fn operator_recording_path(recording: &Path, step: &str) -> PathBuf {
    let stem = recording.file_stem().map_or_else(|| "recording".into(), |s| s.to_string_lossy().into_owned());
    recording.with_file_name(format!("{stem}.{step}.csv"))
}

/// Frames an experiment's sample averages: the settling's own. The sweeps'
/// `frames` are sized for their few long stops; an experiment's samples
/// follow its path closely, one settled sample a step.
const EXPERIMENT_FRAMES: usize = 0;

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    /// Run the first step of `left` (the steps still to run, for progress).
    pub(super) async fn experiment(&mut self, left: &[ExperimentSpec]) -> Step<()> {
        let Some(&spec) = left.first() else { return Ok(()) };
        let mut to_go: usize = left.iter().map(ExperimentSpec::samples).sum();
        let label = spec.phase();
        let hold = self.stage_mm;
        match spec {
            ExperimentSpec::Dwell { hold_s, every_s } => {
                let frames = EXPERIMENT_FRAMES;
                let t_start = self.clock.t_last;
                for i in 0..dwell_count(hold_s, every_s) {
                    self.track.cursor = Cursor::Experiment { left: to_go };
                    // Wait on the sensor's clock (the rig's time), reading as it streams.
                    let due = t_start + i as f64 * every_s;
                    while self.clock.t_last < due {
                        self.checkpoint().await?;
                        self.read().await?;
                    }
                    let r = self.settle_frames(frames).await?;
                    self.record(Phase::Normal, hold, r, None, None, Some(label))?;
                    to_go = to_go.saturating_sub(1);
                }
            }
            ExperimentSpec::Reload { fraction, steps, cycles } => {
                let contact = self.contact_mm.unwrap_or(hold);
                for (pos, dir) in reload_path(hold, contact, fraction, steps, cycles) {
                    self.track.cursor = Cursor::Experiment { left: to_go };
                    let pos = self.move_stage_limited(pos, "reload experiment").await?;
                    let r = self.settle_frames(EXPERIMENT_FRAMES).await?;
                    self.record(Phase::Normal, pos, r, None, Some(dir), Some(label))?;
                    to_go = to_go.saturating_sub(1);
                }
            }
            ExperimentSpec::TwistReversal { amplitude_deg, step_deg } => {
                self.twist_path(&reversal_angles(amplitude_deg, step_deg), label, &mut to_go).await?;
            }
            ExperimentSpec::TorsionAtDepth { beta, amplitude_deg, step_deg } => {
                let crossing = match self.load_crossing(beta) {
                    Some(c) => c,
                    None => self.step_in_to(beta).await?,
                };
                let reached = self.seek_depth(crossing, beta, 4).await?;
                self.log(
                    LogLevel::Info,
                    format!("holding beta {reached:.4} at stage {:.4} mm for the second torsion sweep", self.stage_mm),
                );
                self.twist_path(&sweep_angles(amplitude_deg, step_deg), label, &mut to_go).await?;
            }
            ExperimentSpec::SlowRepeat { fraction, steps, dwell_s } => {
                let contact = self.contact_mm.unwrap_or(hold);
                for (pos, dir) in repeat_path(hold, contact, fraction, steps) {
                    self.track.cursor = Cursor::Experiment { left: to_go };
                    let pos = self.move_stage_limited(pos, "slow repeat experiment").await?;
                    self.wait_rig(dwell_s).await?;
                    let r = self.settle_frames(EXPERIMENT_FRAMES).await?;
                    self.record(Phase::Normal, pos, r, None, Some(dir), Some(label))?;
                    to_go = to_go.saturating_sub(1);
                }
            }
            ExperimentSpec::ApproachSpeed { fraction, steps, speed_mm_s } => {
                let contact = self.contact_mm.unwrap_or(hold);
                let path = repeat_path(hold, contact, fraction, steps);
                // A move's timeout is the script's: a step that would take
                // most of it at this speed is refused before anything moves.
                let step_mm = (hold - contact) * (1.0 - fraction) / steps.max(1) as f64;
                let takes = step_mm / speed_mm_s;
                if takes > 0.5 * self.script.timeouts.move_s {
                    return Err(Halt {
                        culprit: Culprit::Procedure,
                        message: format!(
                            "approach_speed: a step of {step_mm:.3} mm at {speed_mm_s} mm/s takes {takes:.0} s, \
                             more than half the move timeout (timeouts.move_s = {} s)",
                            self.script.timeouts.move_s
                        ),
                    });
                }
                for (k, &(pos, dir)) in path.iter().enumerate() {
                    self.track.cursor = Cursor::Experiment { left: to_go };
                    if k == 1 {
                        let usual = self.set_stage_speed(speed_mm_s).await?;
                        self.log(
                            LogLevel::Info,
                            format!("approach_speed: stage top speed {speed_mm_s} mm/s (was {usual} mm/s)"),
                        );
                        // Put the usual speed back whatever the load does: an
                        // abort backs off at the speed in force.
                        let loaded = self.slow_load(&path[1..], label, &mut to_go).await;
                        let restored = self.set_stage_speed(usual).await;
                        loaded?;
                        restored?;
                        self.log(LogLevel::Info, format!("approach_speed: stage top speed back to {usual} mm/s"));
                        break;
                    }
                    let pos = self.move_stage_limited(pos, "approach speed experiment").await?;
                    let r = self.settle_frames(EXPERIMENT_FRAMES).await?;
                    self.record(Phase::Normal, pos, r, None, Some(dir), Some(label))?;
                    to_go = to_go.saturating_sub(1);
                }
            }
            // The script refuses them: only the closed loop runs them, through `operator_step`.
            ExperimentSpec::RigidBall { .. } | ExperimentSpec::SwapIndenter { .. } => {
                return Err(Halt {
                    culprit: Culprit::Procedure,
                    message: format!(
                        "{} needs an operator to swap the indenter: the closed loop runs it (operator_step)",
                        spec.name()
                    ),
                });
            }
        }
        Ok(())
    }

    /// The closed loop (docs/experiments.md): diagnose the samples so far
    /// and run the experiment the plan chooses while it is decisive, within
    /// the script's rig-time budget and step count. The planning runs off the
    /// async workers; the axes stand still meanwhile.
    pub(super) async fn adaptive_loop(&mut self) -> Step<()> {
        let a = self.script.adaptive;
        let mut spent = 0.0;
        for _ in 0..=a.max_steps {
            let Some(meta) = self.meta.clone() else { return Ok(()) };
            let rec = sim::recording::Recording { meta, samples: self.samples.clone() };
            // One experiment sample averages the settling's last two windows
            // and records the standard error the sensor declares for each
            // reading over their frames (`settle::mean`): one reading here,
            // in contact where the rig stands, gives it. Without declared
            // errors, the reading noise as the settling learnt it in contact.
            // (With EXPERIMENT_FRAMES 0: more frames would read on at rest; the guard below says so.)
            const _: () = assert!(EXPERIMENT_FRAMES == 0, "the plan's experiment noise assumes the settling's frames");
            let frames = (2 * self.script.settle.readings).max(1) as f64;
            let now = self.read().await?;
            let declared = now.gamma1_sd_mm.zip(now.theta1_sd_deg).map(|(g, t)| [g, t]);
            let reading = declared.or_else(|| self.noise.live.map(|(g, t)| [g, t]));
            let experiment_sd =
                reading.filter(|r| r.iter().all(|v| v.is_finite() && *v > 0.0)).map(|r| r.map(|v| v / frames.sqrt()));
            let opts = crate::plan::PlanOptions { operator: a.operator, experiment_sd };
            if let Some([g, t]) = experiment_sd {
                self.log(
                    LogLevel::Info,
                    format!(
                        "adaptive: an experiment sample's expected noise: gamma1 {:.3} um, theta1 {t:.5} deg",
                        g * 1e3
                    ),
                );
            }
            let planned = tokio::task::spawn_blocking(move || {
                // The recording as the run's report will read it (format,
                // stage zero): the loop stops on the decision the report shows.
                let rec = crate::fit::zero::as_reported(&rec);
                let d = crate::diagnosis::diagnose(&rec, &crate::diagnosis::DiagnoseOptions::default())?;
                let p = crate::plan::plan_for(&rec, &d, opts)?;
                Ok::<_, crate::plan::PlanError>((rec, d, p))
            })
            .await;
            let (rec, d, p) = match planned {
                Ok(Ok(x)) => x,
                Ok(Err(e)) => {
                    self.log(LogLevel::Warn, format!("adaptive: no plan: {e}"));
                    return Ok(());
                }
                Err(e) => {
                    self.log(LogLevel::Warn, format!("adaptive: the planner stopped: {e}"));
                    return Ok(());
                }
            };
            if let Some(last) = self.adaptive.last_mut() {
                last.outcome = p.verdict.clone();
                (last.e1_mpa, last.nu1) = (p.e1_mpa, p.nu1);
                last.ci95 = Some(if d.effects.is_empty() { d.baseline.ci95 } else { d.corrected.ci95 });
            }
            let steps_run = self.adaptive.len();
            let stop = |note: String| p.view(steps_run, None, note);
            if self.adaptive.len() as u32 >= a.max_steps {
                let note = format!("{} experiments run, the most allowed; {}", a.max_steps, p.verdict);
                self.emit(RunEvent::ClosedLoop(Box::new(stop(note))));
                self.log(LogLevel::Info, format!("adaptive: {} experiments run, the most allowed", a.max_steps));
                return Ok(());
            }
            // The guard would stop the run at a move that could pass the gamma1
            // limit: only experiments well inside it (its bound grows by each inward move).
            let room = 0.8 * self.script.limits.max_gamma1_mm;
            let Some(c) = p.experiments.iter().find(|c| c.separates > 0 && c.peak_gamma1_mm <= room).cloned() else {
                let why = p.nothing_because.clone().unwrap_or_else(|| "no experiment decides".into());
                self.emit(RunEvent::ClosedLoop(Box::new(stop(format!("no experiment run: {why}; {}", p.verdict)))));
                self.log(LogLevel::Info, format!("adaptive: no experiment run: {why}"));
                return Ok(());
            };
            if spent + c.rig_time_s > a.budget_s {
                let note = format!(
                    "{} ({:.0} s) would exceed the budget ({:.0} s left); {}",
                    c.name,
                    c.rig_time_s,
                    a.budget_s - spent,
                    p.verdict
                );
                self.emit(RunEvent::ClosedLoop(Box::new(stop(note.clone()))));
                self.log(LogLevel::Info, format!("adaptive: {note}"));
                return Ok(());
            }
            let names: Vec<String> = p.hypotheses.iter().take(2).map(|h| h.effects.join(" + ")).collect();
            let why = format!("separates {} (separation {:.0})", names.join(" from "), c.separation);
            let chosen = LoopChoice {
                name: c.name.to_string(),
                why: why.clone(),
                rig_time_s: c.rig_time_s,
                operator: c.operator,
            };
            self.emit(RunEvent::ClosedLoop(Box::new(p.view(steps_run, Some(chosen), format!("running {}", c.name)))));
            let standing = p.view(steps_run + 1, None, String::new());
            let phase = if c.spec.phase().kind() == Phase::Torsion { RunPhase::Torsion } else { RunPhase::Normal };
            self.step(self.track.step_index, format!("adaptive: {}", c.name), phase);
            self.log(LogLevel::Info, format!("adaptive: running {} ({:.0} s): {why}", c.name, c.rig_time_s));
            let t0 = self.clock.t_last;
            if c.operator {
                // An operator step ends the loop: its sweep is decided on
                // here (a rigid ball) or left to its own recording.
                let (ball, path) = self.operator_step(c.spec).await?;
                let took = self.clock.t_last - t0;
                let mut step = AdaptiveStep {
                    name: c.name,
                    spec: c.spec,
                    why,
                    rig_time_s: took,
                    outcome: String::new(),
                    e1_mpa: d.e1_mpa,
                    nu1: d.nu1,
                    ci95: None,
                    recording: Some(path.clone()),
                    effects: Vec::new(),
                };
                if matches!(c.spec, ExperimentSpec::RigidBall { .. }) {
                    let decided =
                        tokio::task::spawn_blocking(move || crate::plan::decide_with_ball(&rec, &d, &p, &ball)).await;
                    match decided {
                        Ok(Ok(g)) => {
                            step.outcome = g.outcome.clone();
                            (step.e1_mpa, step.nu1, step.ci95) = (g.e1_mpa, g.nu1, Some(g.ci95));
                            step.effects = g.effects.clone();
                        }
                        Ok(Err(e)) => step.outcome = format!("rigid ball: not decided: {e}"),
                        Err(e) => step.outcome = format!("rigid ball: the decision stopped: {e}"),
                    }
                } else {
                    step.outcome = format!(
                        "recorded in {} for `easycalib diagnose`; the loop decides on-line after a rigid ball only",
                        path.display()
                    );
                }
                self.log(LogLevel::Info, format!("adaptive: {}: {}", c.name, step.outcome));
                let note = format!("{}: {}", c.name, step.outcome);
                self.emit(RunEvent::ClosedLoop(Box::new(LoopView { note, ..standing })));
                self.adaptive.push(step);
                return Ok(());
            }
            self.experiment(&[c.spec]).await?;
            let took = self.clock.t_last - t0;
            spent += took;
            self.adaptive.push(AdaptiveStep {
                name: c.name,
                spec: c.spec,
                why,
                rig_time_s: took,
                outcome: String::new(),
                e1_mpa: f64::NAN,
                nu1: f64::NAN,
                ci95: None,
                recording: None,
                effects: Vec::new(),
            });
        }
        Ok(())
    }

    /// An operator-assisted step (docs/run.md, "Operator steps"): retract the
    /// stage clear of the gel (nothing waits with the stage in the gel), have
    /// the step's indenter mounted — by the simulation on the emulated rig,
    /// else by the operator at a prompt, waiting for `Confirm` (an abort there
    /// is the run's one abort path) — then load it along the step's path from
    /// the first indenter's contact (its apex mounted on the same reference)
    /// and retract again. Its samples go to a recording of their own next to
    /// the run's (the mounted indenter in its header, `operator_step` among
    /// its keys, docs/recording-format.md); returned with its path.
    pub(super) async fn operator_step(&mut self, spec: ExperimentSpec) -> Step<(Recording, PathBuf)> {
        let procedure = |m: String| Halt { culprit: Culprit::Procedure, message: m };
        let Some(indenter) = spec.operator_indenter() else {
            return Err(procedure(format!("{} is no operator step", spec.name())));
        };
        let (ExperimentSpec::RigidBall { travel_mm, steps, .. }
        | ExperimentSpec::SwapIndenter { travel_mm, steps, .. }) = spec
        else {
            return Err(procedure(format!("{} has no operator sweep", spec.name())));
        };
        let (Some(contact), Some(meta)) = (self.contact_mm, self.meta.clone()) else {
            return Err(procedure(format!("{}: no contact found before it", spec.name())));
        };
        self.retract().await?;
        self.await_operator(spec, indenter).await?;
        let label = spec.phase();
        let path = operator_recording_path(&self.recording_path, spec.name());
        let mut meta = Metadata { indenter, ..meta };
        meta.extra.push(("operator_step".to_string(), spec.name().to_string()));
        let mut ball = Recording { meta, samples: Vec::new() };
        let mut to_go = 2 * steps.max(1) as usize;
        let t0 = self.clock.t0.unwrap_or(0.0);
        for (travel, dir) in sim::experiment::operator_path(travel_mm, steps) {
            self.track.cursor = Cursor::Experiment { left: to_go };
            self.checkpoint().await?;
            self.move_stage(contact + travel, spec.name()).await?;
            let r = self.settle_frames(EXPERIMENT_FRAMES).await?;
            let t_s = (r.t_s - t0).max(ball.samples.last().map_or(0.0, |s| s.t_s));
            ball.samples.push(Sample {
                t_s,
                phase: Phase::Normal,
                stage_mm: self.stage_mm - contact,
                rot_deg: 0.0,
                gamma1_mm: r.gamma1_mm,
                theta1_deg: 0.0,
                rep: None,
                dir: Some(dir),
                gamma1_sd_mm: r.gamma1_sd_mm,
                theta1_sd_deg: None,
                experiment: Some(label),
                timing: Default::default(),
            });
            to_go = to_go.saturating_sub(1);
            self.progress();
        }
        self.retract().await?;
        let write = crate::run::outdir::create_nofollow(&path).and_then(|f| {
            use std::io::Write;
            let mut f = BufWriter::new(f);
            f.write_all(ball.to_csv_string().as_bytes())?;
            f.flush()
        });
        write.map_err(|e| Halt {
            culprit: Culprit::Recording,
            message: format!("cannot write the {} recording {}: {e}", spec.name(), path.display()),
        })?;
        match &self.emulated_operator {
            Some(mount) => {
                mount.mount(None);
                self.log(LogLevel::Info, format!("{}: the simulation mounted the run's indenter back", spec.name()));
            }
            None => self.log(
                LogLevel::Warn,
                format!(
                    "{}: the step's indenter is still mounted; mount the run's indenter back before the next run",
                    spec.name()
                ),
            ),
        }
        self.log(LogLevel::Info, format!("{}: {} samples in {}", spec.name(), ball.samples.len(), path.display()));
        self.operator_recordings.push(path.clone());
        Ok((ball, path))
    }

    /// Have `indenter` mounted for `spec`, the stage retracted: on the
    /// emulated rig the simulation mounts it; on a real rig the operator is
    /// asked ([`RunEvent::OperatorPrompt`]) and the run waits for `Confirm`.
    /// Abort or quit at the prompt, or a control channel that closes (nobody
    /// can confirm), stop the run by its one abort path.
    pub(super) async fn await_operator(&mut self, spec: ExperimentSpec, indenter: sim::physics::Body) -> Step<()> {
        let step = spec.name().to_string();
        if let Some(mount) = &self.emulated_operator {
            mount.mount(Some(indenter));
            self.log(
                LogLevel::Info,
                format!(
                    "{step}: emulated rig: the simulation mounted the indenter (E {} MPa, nu {}, R {} mm)",
                    indenter.e_mpa, indenter.nu, indenter.r_mm
                ),
            );
            self.emit(RunEvent::OperatorConfirmed { step });
            return Ok(());
        }
        let what = match spec {
            ExperimentSpec::RigidBall { .. } => "the rigid (steel) ball",
            _ => "the second indenter",
        };
        let message = format!(
            "the stage is retracted clear of the gel: mount {what} with its apex where the run's indenter's was, \
             then confirm (or abort)"
        );
        self.emit(RunEvent::OperatorPrompt { step: step.clone(), indenter, message });
        loop {
            let Some(rx) = self.controls.as_mut() else {
                return Err(Halt {
                    culprit: Culprit::Operator,
                    message: format!("{step} needs an operator's confirmation and nobody can give it (no controls)"),
                });
            };
            match rx.recv().await {
                Some(RunControl::Confirm) => break,
                Some(RunControl::Pause | RunControl::Resume) => {}
                Some(c @ (RunControl::Abort | RunControl::Quit)) => {
                    return Err(self.operator(c, &format!("the {step} prompt")));
                }
                None => self.controls = None,
            }
        }
        self.log(LogLevel::Info, format!("{step}: the operator confirmed the indenter"));
        self.emit(RunEvent::OperatorConfirmed { step });
        Ok(())
    }

    /// Wait `wait_s` of rig time (the sensor's clock) from now, reading as
    /// the sensor streams (one reading first: the clock stood still during a move).
    async fn wait_rig(&mut self, wait_s: f64) -> Step<()> {
        self.read().await?;
        let due = self.clock.t_last + wait_s;
        while self.clock.t_last < due {
            self.checkpoint().await?;
            self.read().await?;
        }
        Ok(())
    }

    /// Set the stage's top speed, mm/s; returns the one it replaced. A
    /// driver that cannot set it stops the step (its samples would not be
    /// what the step says).
    async fn set_stage_speed(&mut self, speed_mm_s: f64) -> Step<f64> {
        match self.stage.set_max_speed(speed_mm_s).await {
            Ok(Some(was)) => Ok(was),
            Ok(None) => Err(Halt {
                culprit: Culprit::Procedure,
                message: format!(
                    "approach_speed: the {} driver cannot set its speed (the step needs {speed_mm_s} mm/s)",
                    self.stage_name
                ),
            }),
            Err(e) => Err(self.stage_fault(&format!("set top speed {speed_mm_s} mm/s"), e)),
        }
    }

    /// The loading moves of an approach at another speed (the speed already set).
    async fn slow_load(&mut self, path: &[(f64, Direction)], label: Experiment, to_go: &mut usize) -> Step<()> {
        for &(pos, dir) in path {
            self.track.cursor = Cursor::Experiment { left: *to_go };
            let pos = self.move_stage_limited(pos, "approach speed experiment").await?;
            let r = self.settle_frames(EXPERIMENT_FRAMES).await?;
            self.record(Phase::Normal, pos, r, None, Some(dir), Some(label))?;
            *to_go = to_go.saturating_sub(1);
        }
        Ok(())
    }

    /// Twist through `angles` (from the torsion sweep's zero) at the stage where it stands.
    async fn twist_path(&mut self, angles: &[(f64, Direction)], label: Experiment, to_go: &mut usize) -> Step<()> {
        let hold = self.stage_mm;
        for &(angle, dir) in angles {
            self.track.cursor = Cursor::Experiment { left: *to_go };
            self.move_mount(self.twist_zero + angle, "twist experiment").await?;
            let r = self.settle_frames(EXPERIMENT_FRAMES).await?;
            self.record(Phase::Torsion, hold, r, None, Some(dir), Some(label))?;
            *to_go = to_go.saturating_sub(1);
        }
        Ok(())
    }

    /// Deeper than the sweep went: step in from where the stage stands, by the
    /// normal sweep's step (each move guarded), until the measured depth
    /// reaches `beta`; the last two points ((absolute stage mm, beta) each).
    async fn step_in_to(&mut self, beta: f64) -> Step<((f64, f64), (f64, f64))> {
        let contact = self.contact_mm.unwrap_or(self.stage_mm);
        let r2 = self.script.indenter.r_mm;
        let step = self.script.normal.step_mm;
        let here = self.settle().await?;
        let mut last = (self.stage_mm, ((self.stage_mm - contact) - here.gamma1_mm) / r2);
        loop {
            // Near the depth limit a step is shortened to what it allows (as
            // the normal sweep's are); a refused one aborts in the move.
            let pos = self.within_depth_limit(last.0 + step, "step in to the second depth");
            self.move_stage(pos, "step in to the second depth").await?;
            let r = self.settle().await?;
            let now = (pos, ((pos - contact) - r.gamma1_mm) / r2);
            if now.1 >= beta {
                return Ok((last, now));
            }
            last = now;
        }
    }

    /// The two load points of the first normal sweep around depth `beta`
    /// ((absolute stage mm, measured beta) each); `None` when the sweep never
    /// went that deep or recorded fewer than two load points.
    fn load_crossing(&self, beta: f64) -> Option<((f64, f64), (f64, f64))> {
        let contact = self.contact_mm.unwrap_or(0.0);
        let r2 = self.script.indenter.r_mm;
        let path: Vec<(f64, f64)> = self
            .samples
            .iter()
            .filter(|s| s.in_sweep() && s.phase == Phase::Normal && s.rep == Some(0) && s.dir == Some(Direction::Load))
            .map(|s| (s.stage_mm + contact, (s.stage_mm - s.gamma1_mm) / r2))
            .collect();
        let i = path.iter().position(|p| p.1 >= beta)?.max(1);
        Some((*path.get(i - 1)?, *path.get(i)?))
    }
}
