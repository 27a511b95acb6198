//! The depth limit watched on every reading. The guard bounds the moves it
//! is asked for (`run/safety.rs`); what moves the gel while the stage
//! stands (a frame drifting into it, a gel creeping) only the readings
//! show. A reading past `max_gamma1_mm` by more than its noise backs the
//! stage off, and a stop's samples are recorded where the stage went
//! (docs/hardening.md, "The depth limit while the stage stands").

use super::*;

/// Back-offs in a row, each followed by a reading still past the limit,
/// before the run stops: the gel keeps deforming however far the stage
/// goes out.
pub(super) const MAX_BACKOFFS_IN_A_ROW: u32 = 4;

/// Readings of a stop whose mean the watch holds against the limit.
pub(super) const WATCH_READINGS: usize = 8;

/// What the watch saw past the limit: gamma1 as read (one reading, or the
/// mean of `readings`), its excess over the limit and the noise allowance
/// it passed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PastLimit {
    pub gamma1_mm: f64,
    pub readings: usize,
    pub excess_mm: f64,
    pub allowance_mm: f64,
}

/// Where a stop's stage went after its move: the back-off moves of the
/// current stop (commanded at `from_mm`, where the stage reported
/// `reported_mm`), now at `to_mm`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct BackedOff {
    pub from_mm: f64,
    pub reported_mm: f64,
    pub to_mm: f64,
}

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    /// The stage position of the stop commanded at `commanded_mm`: where a
    /// back-off of this stop took it, else `commanded_mm` itself.
    pub(super) fn at_stop(&self, commanded_mm: f64) -> f64 {
        match self.backed_off {
            Some(b) if b.from_mm == commanded_mm || b.reported_mm == commanded_mm => b.to_mm,
            _ => commanded_mm,
        }
    }

    /// A reading that shows the gel deformed more than the guard allowed for
    /// this position: the frame or the gel moved while the stage stood, so
    /// the guard's measured points no longer hold (said once a run).
    pub(super) fn note_bound_passed(&mut self, r: &GaugeReading, margin_mm: f64) {
        self.guard.forget_gamma1();
        if !std::mem::replace(&mut self.bound_passed_said, true) {
            self.log(
                LogLevel::Info,
                format!(
                    "gamma1 read {:.4} mm at stage {:.4} mm, more than the {:.4} mm the depth guard held possible there \
                     (the frame or the gel moved while the stage stood): its bound follows the readings, its measured \
                     points are forgotten",
                    r.gamma1_mm,
                    self.stage_mm,
                    self.gamma1_bound_mm + margin_mm
                ),
            );
        }
    }

    /// How far the gel lies past the depth limit, beyond what the readings'
    /// noise allows (`None`: within it, or the stage is not known to be in
    /// contact): `r` alone past it by four of a reading's standard
    /// deviations, or the mean of the stop's last [`WATCH_READINGS`] by four
    /// of the mean's.
    pub(super) fn past_depth_limit(&mut self, r: &GaugeReading) -> Option<PastLimit> {
        let max = self.guard.limits().max_gamma1_mm;
        let in_contact = self.stage_mm.is_finite() && self.stage_mm > self.guard.limits().clear_until_mm;
        if !(in_contact && r.gamma1_mm.is_finite()) {
            return None;
        }
        if self.watch_recent.len() == WATCH_READINGS {
            self.watch_recent.remove(0);
        }
        self.watch_recent.push(r.gamma1_mm);
        let margin = self.watch_margin();
        let k = self.watch_recent.len() as f64;
        let mean = self.watch_recent.iter().sum::<f64>() / k;
        let past = |gamma1_mm: f64, readings: usize, allowance_mm: f64| {
            (gamma1_mm - max > allowance_mm).then_some(PastLimit {
                gamma1_mm,
                readings,
                excess_mm: gamma1_mm - max,
                allowance_mm,
            })
        };
        past(r.gamma1_mm, 1, margin).or_else(|| past(mean, self.watch_recent.len(), margin / k.sqrt()))
    }

    /// A single reading's noise allowance against the limit: four standard
    /// deviations of the noisier of rest and contact, at least the contact
    /// threshold.
    pub(super) fn watch_margin(&self) -> f64 {
        let live = self.noise.live.map_or(0.0, |l| l.0);
        (4.0 * self.noise.gamma1_mm.max(live)).max(self.script.approach.contact_min_mm)
    }

    /// Back the stage off far enough that the gel's deflection, read at
    /// `gamma1_mm`, falls `2 margin` under the limit: the gel takes the
    /// fraction gamma1 / approach of a small move (Hertz's ratio of the two
    /// bodies' deflections holds along a sweep), so the move out is the
    /// excess over that fraction. Every such move is logged as a warning;
    /// [`MAX_BACKOFFS_IN_A_ROW`] without a reading back under the limit stop
    /// the run.
    pub(super) async fn back_off(&mut self, seen: PastLimit) -> Step<()> {
        let max = self.guard.limits().max_gamma1_mm;
        let gamma1_mm = seen.gamma1_mm;
        self.backoffs_in_a_row += 1;
        if self.backoffs_in_a_row > MAX_BACKOFFS_IN_A_ROW {
            let v = LimitViolation::Gamma1Read { stage_mm: self.stage_mm, gamma1_mm, max_mm: max };
            return Err(self
                .safety(&format!("after {MAX_BACKOFFS_IN_A_ROW} back-offs the gel still deforms past the limit"), v));
        }
        let margin = self.watch_margin();
        let approach = self.contact_mm.map_or(f64::NAN, |c| self.stage_mm - c);
        let fraction = if approach > 0.0 && gamma1_mm > 0.0 { (gamma1_mm / approach).clamp(0.1, 1.0) } else { 1.0 };
        let out = (seen.excess_mm + 2.0 * margin) / fraction;
        let from = self.stage_mm;
        let target = (from - out).max(self.guard.limits().stage_min_mm);
        let read =
            if seen.readings > 1 { format!("the mean of {} readings", seen.readings) } else { "a reading".into() };
        self.log(
            LogLevel::Warn,
            format!(
                "depth limit: gamma1 {gamma1_mm:.4} mm ({read}) at stage {from:.4} mm with the stage standing, \
                 {:.4} mm past max gamma1 {max:.4} mm (noise allows {:.4}): backing off {:.4} mm to {target:.4} mm",
                seen.excess_mm,
                seen.allowance_mm,
                from - target
            ),
        );
        let (commanded, reported) = self.backed_off.map_or((self.stop_mm, from), |b| (b.from_mm, b.reported_mm));
        self.move_stage_within(target, "depth limit back-off").await?;
        self.backed_off = Some(BackedOff { from_mm: commanded, reported_mm: reported, to_mm: target });
        self.depth_backoffs += 1;
        Ok(())
    }
}
