//! Recording every settled sample (flushed before the next move) and telling the
//! event stream about it.

use super::*;

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    pub(super) fn record(
        &mut self,
        phase: Phase,
        stage_abs: f64,
        r: GaugeReading,
        rep: Option<u32>,
        dir: Option<Direction>,
        experiment: Option<Experiment>,
    ) -> Step<()> {
        // A stop the depth watch backed off is recorded where it went.
        let stage_abs = self.at_stop(stage_abs);
        let contact = self.contact_mm.unwrap_or(0.0);
        let t0 = self.clock.t0.unwrap_or(r.t_s);
        let t_s = (r.t_s - t0).max(self.samples.last().map(|s| s.t_s).unwrap_or(0.0));
        let sample = Sample {
            t_s,
            phase,
            stage_mm: stage_abs - contact,
            rot_deg: if phase == Phase::Torsion { self.mount_deg - self.twist_zero } else { 0.0 },
            gamma1_mm: r.gamma1_mm,
            theta1_deg: if phase == Phase::Torsion { r.theta1_deg } else { 0.0 },
            rep,
            dir,
            gamma1_sd_mm: r.gamma1_sd_mm,
            theta1_sd_deg: if phase == Phase::Torsion { r.theta1_sd_deg } else { None },
            experiment,
            timing: self.clock.pending.take(),
        };
        let Some(w) = self.writer.as_mut() else {
            return Err(Halt { culprit: Culprit::Recording, message: "recording is not open".into() });
        };
        w.append(&sample).map_err(|e| Halt {
            culprit: Culprit::Recording,
            message: format!("cannot append to the recording {}: {e}", self.recording_path.display()),
        })?;
        self.samples.push(sample);
        self.emit(RunEvent::Sample(sample));
        if self.panic_after_samples == Some(self.samples.len()) {
            panic!("injected test panic after {} samples", self.samples.len());
        }
        let fit = FitUpdate::estimate(&self.samples, &self.script.indenter);
        if fit.is_some() && fit != self.last_fit {
            self.last_fit = fit;
            if let Some(f) = fit {
                self.emit(RunEvent::Fit(f));
            }
        }
        self.snapshot();
        self.progress();
        Ok(())
    }

    /// Device panel update from what the sequencer knows (no device I/O in
    /// the sweep loop: the axes are at rest at their last reported positions).
    pub(super) fn snapshot(&self) {
        let axis = |position: f64, homed: bool| AxisStatus { position, homed, enabled: true, ..Default::default() };
        self.emit(RunEvent::DeviceStatus(DeviceStatus {
            stage: axis(self.stage_mm, self.stage_homed),
            rotation: axis(self.mount_deg, self.mount_homed),
            sensor: self.gauge.link_stats(),
        }));
    }

    pub(super) async fn device_status(&mut self) -> Step<()> {
        let stage = self.stage.status().await.map_err(|e| self.stage_fault("status", e))?;
        let rotation = self.mount.status().await.map_err(|e| self.mount_fault("status", e))?;
        self.emit(RunEvent::DeviceStatus(DeviceStatus { stage, rotation, sensor: self.gauge.link_stats() }));
        Ok(())
    }
}

pub(super) fn sanitize(s: &str) -> String {
    s.chars().map(|c| if c.is_control() { ' ' } else { c }).collect()
}
