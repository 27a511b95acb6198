//! The experiment steps after the torsion sweep (docs/experiments.md): a dwell,
//! unload-reload cycles, a twist reversal, a torsion sweep at a second depth.
//! Every move goes through `move_stage` / `move_mount` (the guard), every
//! sample through `record`, with the experiment as its phase.

use super::*;
use sim::experiment::{dwell_count, reload_path, reversal_angles, sweep_angles};

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
                    self.move_stage(pos, "reload experiment").await?;
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
            // The script refuses them and the loop plans without them (no operator prompt yet).
            ExperimentSpec::RigidBall { .. } | ExperimentSpec::SwapIndenter { .. } => {
                return Err(Halt {
                    culprit: Culprit::Procedure,
                    message: format!("{} needs an operator to swap the indenter; not run", spec.name()),
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
            let planned = tokio::task::spawn_blocking(move || {
                crate::plan::plan(&rec, crate::plan::PlanOptions { operator: false })
            })
            .await;
            let p = match planned {
                Ok(Ok(p)) => p,
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
            }
            if self.adaptive.len() as u32 >= a.max_steps {
                self.log(LogLevel::Info, format!("adaptive: {} experiments run, the most allowed", a.max_steps));
                return Ok(());
            }
            // The guard would stop the run at a move that could pass the gamma1
            // limit: only experiments well inside it (its bound grows by each inward move).
            let room = 0.8 * self.script.limits.max_gamma1_mm;
            let Some(c) = p.experiments.iter().find(|c| c.decisive && c.peak_gamma1_mm <= room).cloned() else {
                let why = p.nothing_because.clone().unwrap_or_else(|| "no experiment decides".into());
                self.log(LogLevel::Info, format!("adaptive: no experiment run: {why}"));
                return Ok(());
            };
            if spent + c.rig_time_s > a.budget_s {
                self.log(
                    LogLevel::Info,
                    format!(
                        "adaptive: {} ({:.0} s) would exceed the budget ({:.0} s left)",
                        c.name,
                        c.rig_time_s,
                        a.budget_s - spent
                    ),
                );
                return Ok(());
            }
            let names: Vec<String> = p.hypotheses.iter().take(2).map(|h| h.effects.join(" + ")).collect();
            let why = format!("separates {} (separation {:.0})", names.join(" from "), c.separation);
            let phase = if c.spec.phase().kind() == Phase::Torsion { RunPhase::Torsion } else { RunPhase::Normal };
            self.step(self.track.step_index, format!("adaptive: {}", c.name), phase);
            self.log(LogLevel::Info, format!("adaptive: running {} ({:.0} s): {why}", c.name, c.rig_time_s));
            let t0 = self.clock.t_last;
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
            });
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
            let pos = last.0 + step;
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
