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
        let n_load = self.loads_estimate();
        let frac = match self.track.cursor {
            Cursor::Setup => 0.0,
            Cursor::Load { beta, .. } => 0.5 * beta / self.script.normal.target_beta,
            Cursor::Unload { left, .. } => n_load.map(|n| 1.0 - 0.5 * left as f64 / n.max(1.0)).unwrap_or(0.5),
            Cursor::Depth => 0.5,
            Cursor::Twist { left } => 1.0 - left as f64 / twist_total.max(1) as f64,
            Cursor::Experiment { left } => 1.0 - left as f64 / self.experiment_samples().max(1) as f64,
            Cursor::Done => 1.0,
        };
        self.progress_fraction(frac);
    }

    /// Load samples per normal sweep: known after the first, extrapolated from beta before.
    pub(super) fn loads_estimate(&self) -> Option<f64> {
        if let Some(n) = self.track.loads_rep0 {
            return Some(n as f64);
        }
        match self.track.cursor {
            Cursor::Load { k, beta, .. } if beta > 0.02 => Some((k + 1) as f64 * self.script.normal.target_beta / beta),
            _ => None,
        }
    }

    /// Rig time of a torsion sample in normal samples': each costs the frames
    /// it averages, the settling's first window and a move (about ten frame
    /// periods on a stage or mount of the usual speed).
    pub(super) fn torsion_weight(&self) -> f64 {
        let n = self.script.settle.readings;
        let cost = |frames: usize| (frames.max(2 * n) + n) as f64 + 10.0;
        cost(self.script.torsion.frames) / cost(self.script.normal.frames)
    }

    /// Samples of the script's experiment steps (a dwell's counted as samples
    /// too: a rough share of the estimate).
    pub(super) fn experiment_samples(&self) -> usize {
        self.script.experiment.iter().map(ExperimentSpec::samples).sum()
    }

    /// Rig time left: samples left (a torsion sample counting
    /// [`Self::torsion_weight`] normal ones) times the time per sample so far.
    pub(super) fn eta(&self) -> Option<f64> {
        let (t_start, n_start) = self.track.sweep_start?;
        let since = self.samples.get(n_start..)?;
        if since.len() < 3 {
            return None;
        }
        let w = self.torsion_weight();
        let done: f64 = since.iter().map(|s| if s.phase == Phase::Torsion { w } else { 1.0 }).sum();
        let per = (self.clock.t_last - t_start) / done;
        let reps = self.script.normal.repeats as f64;
        let twist = self.script.twist_angles().len() as f64 * w + self.experiment_samples() as f64;
        let left = match self.track.cursor {
            Cursor::Setup => return None,
            Cursor::Load { rep, k, .. } => {
                let n = self.loads_estimate()?;
                (n - k as f64 - 1.0).max(0.0) + (n - 1.0) + (reps - rep as f64 - 1.0) * (2.0 * n - 1.0) + twist + 2.0
            }
            Cursor::Unload { rep, left } => {
                let n = self.loads_estimate()?;
                left as f64 - 1.0 + (reps - rep as f64 - 1.0) * (2.0 * n - 1.0) + twist + 2.0
            }
            Cursor::Depth => twist + 2.0,
            Cursor::Twist { left } => left as f64 * w + self.experiment_samples() as f64,
            Cursor::Experiment { left } => left as f64,
            Cursor::Done => 0.0,
        };
        Some(left.max(0.0) * per)
    }
}
