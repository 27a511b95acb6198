//! Progress and the estimate of rig time left.

use super::*;

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    pub(super) fn progress_fraction(&self, step_fraction: f64) {
        self.emit(RunEvent::Progress(Progress {
            step_fraction: step_fraction.clamp(0.0, 1.0),
            elapsed_s: self.clock.t_last,
            eta_s: self.eta(),
        }));
    }

    pub(super) fn progress(&self) {
        let twist_total = self.script.twist_angles().len();
        let frac = match self.track.cursor {
            Cursor::Setup => 0.0,
            Cursor::Load { beta, .. } => beta / self.script.normal.target_beta,
            Cursor::Unload { left, .. } => 1.0 - left as f64 / self.unloads_estimate().unwrap_or(1.0).max(1.0),
            Cursor::Depth => 0.0,
            Cursor::Twist { left } => 1.0 - left as f64 / twist_total.max(1) as f64,
            Cursor::Experiment { left } => 1.0 - left as f64 / self.experiment_samples().max(1) as f64,
            Cursor::Done => 1.0,
        };
        self.progress_fraction(frac);
    }

    /// The approach (stage past the contact, mm) at which the loading branch
    /// reaches the target depth: beta = approach (1 - gamma1 / approach) / R2,
    /// at the ratio of gamma1 to the approach the last sample read.
    fn top_approach_mm(&self) -> Option<f64> {
        let contact = self.contact_mm?;
        let last = self.samples.iter().rev().find(|s| s.phase == Phase::Normal && s.dir == Some(Direction::Load));
        let approach = last.map_or(self.stage_mm - contact, |s| s.stage_mm);
        let gamma1 = last.map_or(self.gamma1_mm, |s| s.gamma1_mm);
        // A resolved contact gives the ratio; before, the approach's deepest reading does.
        let ratio = if approach > 0.05 && gamma1 > 0.1 { gamma1 / approach } else { self.track.gamma1_ratio? };
        let ratio = ratio.clamp(0.0, 0.95);
        let approach = approach.max(0.0);
        let top = self.script.normal.target_beta * self.script.indenter.r_mm / (1.0 - ratio);
        Some(top.max(approach))
    }

    /// Samples of an unloading branch.
    pub(super) fn unloads_estimate(&self) -> Option<f64> {
        let n = self.script.normal;
        if n.unload_step_mm > 0.0 {
            let top = self.top_approach_mm()?;
            Some((top / n.unload_step_mm).ceil())
        } else {
            self.track.loads_rep0.map(|k| k as f64 - 1.0)
        }
    }

    /// Samples of the script's experiment steps (a dwell's counted as samples
    /// too: a rough share of the estimate).
    pub(super) fn experiment_samples(&self) -> usize {
        self.script.experiment.iter().map(ExperimentSpec::samples).sum()
    }

    /// Frames read at a stop averaging `frames`: the settling reads one
    /// window more than the two it keeps.
    fn reads_at(&self, frames: usize) -> f64 {
        let n = self.script.settle.readings;
        (frames.max(2 * n) + n) as f64
    }

    /// Rig time left, s: the stops still to make, each a move and its
    /// frames, at the move and frame times this run has measured.
    pub(super) fn eta(&self) -> Option<f64> {
        self.track.sweep_start?;
        let c = &self.track.costs;
        let frame = c.frame_s()?;
        let n = self.script.normal;
        let contact = self.contact_mm?;
        let reps = n.repeats as usize;
        let at_top = self.torsion_at_top();
        let top = self.top_approach_mm()?;
        let start = -self.script.approach.pre_contact_mm;
        // Rig time of `count` stage stops spread evenly over `span` mm, averaging `frames` each.
        let stage_stops = |count: f64, span: f64, frames: usize| -> Option<f64> {
            if count <= 0.0 {
                return Some(0.0);
            }
            Some(count * (c.move_s(false, span / count)? + self.reads_at(frames) * frame))
        };
        let unload = stage_stops(self.unloads_estimate()?, top - start, n.frames)?;
        let load_all = stage_stops(((top - start) / n.step_mm).ceil() + 10.0, top - start, n.frames)?;
        // The torsion sweep's stops from the `left`-th last on.
        let twist = |left: usize| -> Option<f64> {
            let angles = self.script.twist_angles();
            let from = angles.len().saturating_sub(left);
            let mut t = 0.0;
            for w in from.max(1)..angles.len() {
                let step = angles[w] - angles[w - 1];
                t += c.move_s(true, step)? + self.reads_at(self.script.twist_frames(angles[w])) * frame;
            }
            Some(t)
        };
        let all_twist = twist(usize::MAX)?;
        let experiments = self.experiment_samples() as f64 * (self.reads_at(n.frames) * frame);
        let seek = c.move_s(false, top - start)? + 2.0 * self.reads_at(0) * frame;
        let retract = c.move_s(false, (contact + top - self.script.park_mm()).abs())?;
        let later_reps = |rep: u32| (reps.saturating_sub(rep as usize + 1)) as f64 * (load_all + unload);
        let after_loads = |rep: u32| -> f64 {
            if at_top {
                later_reps(rep) + all_twist + unload + retract
            } else {
                unload + later_reps(rep) + seek + all_twist + experiments + retract
            }
        };
        let left = match self.track.cursor {
            Cursor::Setup => return None,
            Cursor::Load { rep, .. } => {
                let here = self.stage_mm - contact;
                let remaining = (top - here).max(0.0);
                stage_stops((remaining / n.step_mm).ceil(), remaining, n.frames)? + after_loads(rep)
            }
            Cursor::Unload { rep, left } => {
                let part = unload * left as f64 / self.unloads_estimate()?.max(1.0);
                let last = at_top && rep as usize + 1 == reps;
                if last { part + retract } else { part + later_reps(rep) + seek + all_twist + experiments + retract }
            }
            Cursor::Depth => all_twist + if at_top { unload } else { experiments } + retract,
            Cursor::Twist { left } => twist(left)? + if at_top { unload } else { experiments } + retract,
            Cursor::Experiment { left } => left as f64 * self.reads_at(n.frames) * frame + retract,
            Cursor::Done => 0.0,
        };
        Some(left.max(0.0))
    }
}
