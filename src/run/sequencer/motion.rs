//! Guarded motion: every move of a run goes through here (checkpoint, soft limits,
//! move, wait while taking the operator's controls), and the abort path.

use super::*;
use devices::motion::Unit;

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    /// The only way the stage moves during a run to a new stop: checkpoint,
    /// guard, move, wait.
    pub(super) async fn move_stage(&mut self, target: f64, context: &str) -> Step<f64> {
        self.backed_off = None;
        self.stop_mm = target;
        self.move_stage_within(target, context).await
    }

    /// A guarded stage move that keeps the stop (the depth watch's back-off:
    /// the stop's samples are recorded where it went, `watch.rs`).
    pub(super) async fn move_stage_within(&mut self, target: f64, context: &str) -> Step<f64> {
        self.checkpoint().await?;
        let from = self.stage_mm;
        if let Err(v) = self.guard.check_stage(from, self.gamma1_bound_mm, target) {
            return Err(self.safety(context, v));
        }
        self.watch_recent.clear();
        // From here on the stage may be anywhere up to the target.
        self.gamma1_bound_mm = self.guard.gamma1_bound(from, self.gamma1_bound_mm, target);
        self.last_inward_mm = if from.is_finite() { (target - from).max(0.0) } else { 0.0 };
        let timeout = self.script.move_timeout();
        if from.is_finite() {
            self.track.costs.note_move(self.clock.t_last, false, (target - from).abs());
        }
        let travel = if from.is_finite() { (target - from).abs() } else { 0.0 };
        self.clock.pending.moving(self.clock.t_last, true, travel);
        let moved =
            drive(&mut self.stage, target, timeout, &mut self.stage_mm, &mut self.controls, &mut self.pause_requested)
                .await;
        match moved {
            Ok(Ok(p)) => {
                self.after_move();
                Ok(p)
            }
            Ok(Err(e)) => Err(self.stage_fault(&format!("{context}: move to {target:.4} mm"), e)),
            Err(c) => Err(self.operator(c, context)),
        }
    }

    /// The only way the mount moves during a run.
    pub(super) async fn move_mount(&mut self, target: f64, context: &str) -> Step<f64> {
        self.checkpoint().await?;
        if let Err(v) = self.guard.check_mount(target) {
            return Err(self.safety(context, v));
        }
        let timeout = self.script.move_timeout();
        if self.mount_deg.is_finite() {
            self.track.costs.note_move(self.clock.t_last, true, (target - self.mount_deg).abs());
        }
        let turn = if self.mount_deg.is_finite() { (target - self.mount_deg).abs() } else { 0.0 };
        self.clock.pending.moving(self.clock.t_last, false, turn);
        let moved =
            drive(&mut self.mount, target, timeout, &mut self.mount_deg, &mut self.controls, &mut self.pause_requested)
                .await;
        match moved {
            Ok(Ok(p)) => {
                self.after_move();
                Ok(p)
            }
            Ok(Err(e)) => Err(self.mount_fault(&format!("{context}: move to {target:.3} deg"), e)),
            Err(c) => Err(self.operator(c, context)),
        }
    }

    /// The device said the move is done: what the sensor delivered before
    /// that shows the rig before or during it. A run that reads frames more
    /// slowly than they come (a loaded host, a slow estimator) finds up to a
    /// queue of them waiting, and averaging them would put the moving rig's
    /// deformation into the new pose's sample and date the move's end too
    /// early (docs/run.md, "Reading after a move").
    /// The link counts them (skipped, not lost).
    fn after_move(&mut self) {
        self.gauge.discard_queued();
    }

    pub(super) fn operator(&self, c: RunControl, context: &str) -> Halt {
        let verb = if c == RunControl::Quit { "quit" } else { "abort" };
        Halt { culprit: Culprit::Operator, message: format!("{verb} requested by the operator during {context}") }
    }

    /// A safe point: take queued controls; hold here while paused.
    pub(super) async fn checkpoint(&mut self) -> Step<()> {
        while let Some(rx) = self.controls.as_mut() {
            match rx.try_recv() {
                Ok(RunControl::Pause) => self.pause_requested = true,
                Ok(RunControl::Resume) => self.pause_requested = false,
                Ok(RunControl::Confirm) => {}
                Ok(c @ (RunControl::Abort | RunControl::Quit)) => return Err(self.operator(c, "a safe point")),
                Err(tokio::sync::mpsc::error::TryRecvError::Empty) => break,
                Err(tokio::sync::mpsc::error::TryRecvError::Disconnected) => self.controls = None,
            }
        }
        if !self.pause_requested {
            return Ok(());
        }
        self.emit(RunEvent::Paused);
        self.log(LogLevel::Info, "paused at a safe point (r resumes, a aborts)");
        loop {
            if self.controls.is_none() {
                return Err(Halt {
                    culprit: Culprit::Operator,
                    message: "paused, and the control channel closed: nobody can resume".into(),
                });
            }
            match next_control(&mut self.controls).await {
                RunControl::Resume => break,
                RunControl::Pause | RunControl::Confirm => {}
                c @ (RunControl::Abort | RunControl::Quit) => return Err(self.operator(c, "pause")),
            }
        }
        self.pause_requested = false;
        self.emit(RunEvent::Resumed);
        Ok(())
    }

    /// Stop everything, back the stage off, say what happened.
    pub(super) async fn abort(&mut self, halt: Halt) -> AbortInfo {
        self.log(LogLevel::Error, format!("{}: {}", halt.culprit.as_str(), halt.message));
        // Samples held while the sweep's start placed the contact are kept
        // too: the header with the contact as far as they place it.
        if self.pending.is_some()
            && let Err(e) = self.place_contact()
        {
            self.log(LogLevel::Warn, format!("held samples not written: {}", e.message));
        }
        if let Err(e) = self.stage.stop().await {
            self.log(LogLevel::Warn, format!("{} stop: {e}", self.stage_name));
        }
        if let Err(e) = self.mount.stop().await {
            self.log(LogLevel::Warn, format!("{} stop: {e}", self.mount_name));
        }
        let backoff = if !self.stage_homed {
            Backoff::NotHomed
        } else {
            let target = self.script.limits.retract_mm;
            // gamma1 is irrelevant when backing out: the retract point lies in the clear zone.
            match self.guard.check_stage(self.stage_mm, f64::NAN, target) {
                Err(v) => Backoff::Failed(v.to_string()),
                Ok(()) => {
                    let timeout = self.script.move_timeout();
                    let moved = match self.stage.start_move_to(Mm(target)).await {
                        Ok(()) => self.stage.wait_until_stopped(timeout).map_ok(f64::from).await,
                        Err(e) => Err(e),
                    };
                    match moved {
                        Ok(p) => {
                            self.stage_mm = p;
                            Backoff::To(p)
                        }
                        Err(e) => Backoff::Failed(format!("{}: {}: {e}", self.stage_name, kind_str(e.kind()))),
                    }
                }
            }
        };
        let info = AbortInfo { culprit: halt.culprit, message: halt.message, backoff };
        if let Backoff::Failed(_) = info.backoff {
            self.log(LogLevel::Error, info.to_string());
        }
        let _ = self.device_status().await;
        self.emit(RunEvent::Aborted { reason: info.to_string() });
        info
    }
}

/// The next control, waiting for one; pends forever once the channel is closed
/// (no controller left means nobody can pause or abort, not "abort").
pub(super) async fn next_control(ctl: &mut Option<UnboundedReceiver<RunControl>>) -> RunControl {
    loop {
        match ctl {
            None => std::future::pending::<()>().await,
            Some(rx) => match rx.recv().await {
                Some(c) => return c,
                None => *ctl = None,
            },
        }
    }
}

/// Wait for a move to end while still taking the operator's controls: abort
/// or quit interrupts the wait (the caller stops the device); pause and
/// resume are noted for the next safe point.
pub(super) async fn until_done_or_stopped<T>(
    done: impl std::future::Future<Output = T>,
    controls: &mut Option<UnboundedReceiver<RunControl>>,
    pause_requested: &mut bool,
) -> Result<T, RunControl> {
    tokio::pin!(done);
    loop {
        tokio::select! {
            biased;
            r = &mut done => return Ok(r),
            c = next_control(controls) => match c {
                RunControl::Abort | RunControl::Quit => return Err(c),
                RunControl::Pause => *pause_requested = true,
                RunControl::Resume => *pause_requested = false,
                RunControl::Confirm => {}
            },
        }
    }
}

/// Move one axis (stage or mount alike) to `target` in its own unit and wait
/// for the end while taking the operator's controls. `position` follows what
/// is known: the target once the move started, the device's answer at its end.
/// The outer error is the control that interrupted the wait (the caller stops
/// the device); the inner one the device's.
async fn drive<A: Axis>(
    axis: &mut A,
    target: f64,
    timeout: std::time::Duration,
    position: &mut f64,
    controls: &mut Option<UnboundedReceiver<RunControl>>,
    pause_requested: &mut bool,
) -> Result<Result<f64, A::Error>, RunControl> {
    if let Err(e) = axis.start_move_to(A::Unit::new(target)).await {
        return Ok(Err(e));
    }
    *position = target;
    let end = until_done_or_stopped(axis.wait_until_stopped(timeout), controls, pause_requested).await?;
    Ok(end.map(|p| {
        *position = p.value();
        p.value()
    }))
}
