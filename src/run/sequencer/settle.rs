//! Reading the sensor: timestamps, dropouts, settling on a statistical criterion,
//! and the noise learnt while settled.

use super::*;

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    /// Timestamp the end of the procedure, best effort: the run is complete
    /// whatever the sensor says now.
    pub(super) async fn mark_end(&mut self) {
        if let (Ok(r), Some(t0)) = (self.gauge.read(self.script.read_timeout()).await, self.clock.t0) {
            self.clock.t_last = (r.t_s - t0).max(self.clock.t_last);
        }
    }

    /// Timestamp the start of a phase with one reading (the sensor's clock is
    /// the rig's; without a reading the stretch would have no time).
    pub(super) async fn mark_phase(&mut self, phase: &'static str) -> Step<()> {
        self.read().await?;
        self.clock.phase_marks.push((phase, self.clock.t_last));
        Ok(())
    }

    /// One reading; read timeouts adding up to the dropout timeout abort.
    pub(super) async fn read(&mut self) -> Step<GaugeReading> {
        let timeout = self.script.read_timeout();
        let mut unmeasured = 0u32;
        loop {
            match self.gauge.read(timeout).await {
                Ok(r) => {
                    self.consecutive_timeouts = 0;
                    self.note_reading(&r);
                    if let Some(seen) = self.past_depth_limit(&r) {
                        // Backed off: the next reading is the new stop's.
                        self.back_off(seen).await?;
                        continue;
                    }
                    self.backoffs_in_a_row = 0;
                    return Ok(r);
                }
                Err(GaugeError::Timeout { .. }) => {
                    self.consecutive_timeouts += 1;
                    if self.consecutive_timeouts >= self.script.dropout_reads() {
                        return Err(Halt {
                            culprit: Culprit::Sensor,
                            message: format!(
                                "sensor {}: no reading for {:.1} s ({} consecutive read timeouts of {:.2} s): the stream stopped",
                                self.gauge.describe(),
                                self.consecutive_timeouts as f64 * self.script.timeouts.read_s,
                                self.consecutive_timeouts,
                                self.script.timeouts.read_s
                            ),
                        });
                    }
                    if self.consecutive_timeouts == 1 {
                        self.log(LogLevel::Warn, "sensor reading timed out; waiting for the stream");
                    }
                    self.checkpoint().await?;
                }
                Err(e @ GaugeError::Measure { .. }) => {
                    unmeasured += 1;
                    if unmeasured >= 50 {
                        return Err(self.sensor_fault("50 frames in a row could not be measured; last", e));
                    }
                }
                Err(e) => return Err(self.sensor_fault("read", e)),
            }
        }
    }

    /// What a reading tells the run: the rig's time, the latest gamma1 and
    /// the bound on the true one.
    pub(super) fn note_reading(&mut self, r: &GaugeReading) {
        let t0 = *self.clock.t0.get_or_insert(r.t_s);
        self.clock.t_last = (r.t_s - t0).max(self.clock.t_last);
        self.track.costs.note_read(self.clock.t_last);
        self.clock.pending.read(self.clock.t_last);
        self.gamma1_mm = r.gamma1_mm;
        let margin = self.reading_margin();
        let from_reading = r.gamma1_mm + self.last_inward_mm + margin;
        if r.gamma1_mm > self.gamma1_bound_mm + margin {
            // The gel deformed past what the guard held possible here.
            self.note_bound_passed(r, margin);
            self.gamma1_bound_mm = from_reading;
        } else {
            self.gamma1_bound_mm = self.gamma1_bound_mm.min(from_reading);
        }
    }

    /// Read until the reading is stable, never a fixed wait. The readings
    /// are taken in windows of n; with three consecutive window means
    /// m1, m2, m3 the reading is settled when the last drift |m3 - m2| is
    /// within tolerance and, if the drifts shrink geometrically in one
    /// direction (an elastomer relaxing), the relaxation still to come,
    /// |d2| r / (1 - r) with r = d2 / d1, is within tolerance too.
    pub(super) async fn settle(&mut self) -> Step<GaugeReading> {
        self.settle_frames(0).await
    }

    /// [`Self::settle`], then read on until the sample averages `frames`
    /// settled frames (the last two windows count; fewer than those: just
    /// them). A move costs rig time that more frames at the same place do
    /// not: where the information per second is worth it, a sample takes more.
    pub(super) async fn settle_frames(&mut self, frames: usize) -> Step<GaugeReading> {
        let s = self.script.settle;
        let n = s.readings;
        // Two means of n noisy readings differ by ~sigma sqrt(2/n): never demand less than 3 of that.
        let se = (2.0 / n as f64).sqrt();
        let (live_g, live_t) = self.noise.live.unwrap_or((0.0, 0.0));
        let floor_g = self.noise.gamma1_mm.max(live_g);
        let floor_t = self.noise.theta1_deg.max(live_t);
        let mut buf: Vec<GaugeReading> = Vec::new();
        let mut t_start = None;
        let mut backoffs = self.depth_backoffs;
        loop {
            self.checkpoint().await?;
            let r = self.read().await?;
            if self.depth_backoffs != backoffs {
                // The depth watch moved the stage: settle afresh where it went.
                backoffs = self.depth_backoffs;
                buf.clear();
                t_start = None;
            }
            let t_first = *t_start.get_or_insert(r.t_s);
            buf.push(r);
            if buf.len() >= 3 * n {
                let k = buf.len();
                // Before the run knows the noise (the rest readings of a
                // sensor with a dead band are exact zeros, and none has
                // settled in contact yet), the readings' own (successive
                // differences: insensitive to a slow drift) set the
                // tolerance: a fixed one below the noise would hold a small
                // contact until the timeout.
                let (here_g, here_t) = diff_noise(&buf[k - 3 * n..]);
                let noise_g = if floor_g > 0.0 { floor_g } else { here_g };
                let noise_t = if floor_t > 0.0 { floor_t } else { here_t };
                let tol_g = s.tol_gamma1_mm.max(3.0 * noise_g * se);
                let tol_t = s.tol_theta1_deg.max(3.0 * noise_t * se);
                let m3 = mean(&buf[k - n..]);
                let m2 = mean(&buf[k - 2 * n..k - n]);
                let m1 = mean(&buf[k - 3 * n..k - 2 * n]);
                let g = remaining_relaxation(m1.gamma1_mm, m2.gamma1_mm, m3.gamma1_mm);
                let t = remaining_relaxation(m1.theta1_deg, m2.theta1_deg, m3.theta1_deg);
                if g <= tol_g && t <= tol_t {
                    // Settled: the mean is within the tolerance of where the elastomer is.
                    let upper = m3.gamma1_mm + tol_g + self.reading_margin() / (n as f64).sqrt();
                    self.gamma1_bound_mm = self.gamma1_bound_mm.min(upper);
                    self.guard.note_gamma1(self.stage_mm, upper);
                    self.last_inward_mm = 0.0;
                    // The last two windows agree within the tolerance: the
                    // sample is their mean, twice the frames of one window,
                    // and the frames read on at rest.
                    let mut settled = buf.split_off(k - 2 * n);
                    while settled.len() < frames {
                        self.checkpoint().await?;
                        settled.push(self.read().await?);
                    }
                    self.learn_noise(&settled);
                    self.frames_from(&settled);
                    return Ok(mean(&settled));
                }
                // Sensor time bounds the wait; the read count guards against a sensor whose clock stands still.
                if r.t_s - t_first >= s.timeout_s || buf.len() >= MAX_SETTLE_READINGS {
                    self.log(
                        LogLevel::Warn,
                        format!(
                            "not settled after {:.1} s (gamma1 still moving {:.2} um, theta1 {:.4} deg): recording the latest mean",
                            r.t_s - t_first,
                            g * 1e3,
                            t
                        ),
                    );
                    self.frames_from(&buf[k - n..]);
                    return Ok(m3);
                }
            }
        }
    }

    /// Update the live noise from a settled stretch of readings: successive
    /// differences (insensitive to what little drift is left), averaged
    /// exponentially over the run.
    pub(super) fn learn_noise(&mut self, rs: &[GaugeReading]) {
        if rs.len() < 3 {
            return;
        }
        let (g, t) = diff_noise(rs);
        self.noise.live = Some(match self.noise.live {
            None => (g, t),
            Some((g0, t0)) => ((0.9 * g0 * g0 + 0.1 * g * g).sqrt(), (0.9 * t0 * t0 + 0.1 * t * t).sqrt()),
        });
    }

    /// The sample being taken averages `frames`: note when its first was read.
    pub(super) fn frames_from(&mut self, frames: &[GaugeReading]) {
        let t0 = self.clock.t0.unwrap_or(0.0);
        self.clock.pending.frames_from = frames.first().map(|r| (r.t_s - t0).max(0.0));
    }

    /// How far one reading may lie below the truth by noise alone.
    pub(super) fn reading_margin(&self) -> f64 {
        (4.0 * self.noise.gamma1_mm).max(self.script.approach.contact_min_mm)
    }
}

/// The mean of `xs`, with the standard error of the mean from theirs (`None`
/// unless every reading has one).
pub(super) fn mean(xs: &[GaugeReading]) -> GaugeReading {
    let n = xs.len().max(1) as f64;
    let t_s = xs.last().map(|r| r.t_s).unwrap_or(0.0);
    let mut m = GaugeReading::new(t_s, 0.0, 0.0, 0.0);
    for r in xs {
        m.gamma1_mm += r.gamma1_mm / n;
        m.theta1_deg += r.theta1_deg / n;
        m.contact_radius_mm += r.contact_radius_mm / n;
    }
    // A reading without an error among readings with one (the sensor's dead
    // band reads a contact of a few micrometres as none in some frames) is
    // as uncertain as they are: it takes their RMS error.
    let of_mean = |sd: fn(&GaugeReading) -> Option<f64>| -> Option<f64> {
        let known: Vec<f64> = xs.iter().filter_map(|r| sd(r).map(|v| v * v)).collect();
        if known.is_empty() {
            return None;
        }
        let typical = known.iter().sum::<f64>() / known.len() as f64;
        Some((known.iter().sum::<f64>() + typical * (xs.len() - known.len()) as f64).sqrt() / n)
    };
    // gamma1: the independent parts average down, the shared part does not
    // (sd^2 = independent^2 + shared^2 for each reading).
    let shared = xs.iter().map(|r| r.gamma1_common_sd_mm.unwrap_or(0.0)).sum::<f64>() / n;
    m.gamma1_sd_mm =
        of_mean(|r| r.gamma1_sd_mm.map(|sd| (sd * sd - r.gamma1_common_sd_mm.map_or(0.0, |c| c * c)).max(0.0).sqrt()))
            .map(|independent| independent.hypot(shared))
            .filter(|sd| *sd > 0.0);
    // Frames that saw the contact beside frames that saw none: the sensor is
    // at its detection limit here (an adhesive gel's first contact lifts the
    // markers nearest its centre, docs/sensing.md "Adhesive contacts"), and
    // the mean is only as good as the frames agree: its error is at least
    // their spread's.
    let seen = xs.iter().filter(|r| r.gamma1_mm != 0.0).count();
    if seen > 0 && seen < xs.len() {
        let spread = std_dev(xs.iter().map(|r| r.gamma1_mm)) / n.sqrt();
        m.gamma1_sd_mm = m.gamma1_sd_mm.map(|sd| sd.max(spread));
    }
    m.theta1_sd_deg = of_mean(|r| r.theta1_sd_deg);
    m.gamma1_common_sd_mm = (shared > 0.0).then_some(shared);
    m
}

/// The standard deviation of one reading of gamma1 and of theta1 from the
/// successive differences of `rs` (a slow drift hardly enters them); zero
/// with fewer than two readings.
pub(super) fn diff_noise(rs: &[GaugeReading]) -> (f64, f64) {
    if rs.len() < 2 {
        return (0.0, 0.0);
    }
    let sd = |f: fn(&GaugeReading) -> f64| {
        let v = rs.windows(2).map(|w| (f(&w[1]) - f(&w[0])).powi(2)).sum::<f64>() / (rs.len() - 1) as f64;
        (v / 2.0).sqrt()
    };
    (sd(|r| r.gamma1_mm), sd(|r| r.theta1_deg))
}

pub(super) fn std_dev(xs: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = xs.clone().count();
    if n < 2 {
        return 0.0;
    }
    let m = xs.clone().sum::<f64>() / n as f64;
    (xs.map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1) as f64).sqrt()
}

/// How far a reading may still move, from three consecutive window means:
/// the last drift, or for a geometric (exponential) approach the whole tail
/// d2 r / (1 - r), r = d2 / d1.
pub(super) fn remaining_relaxation(m1: f64, m2: f64, m3: f64) -> f64 {
    let (d1, d2) = (m2 - m1, m3 - m2);
    if d1 * d2 > 0.0 && d2.abs() < d1.abs() {
        let r = d2 / d1;
        d2.abs() * r / (1.0 - r)
    } else if d1 * d2 > 0.0 {
        // Not slowing down: still moving at least this fast.
        d2.abs().max(d1.abs()) * 2.0
    } else {
        d2.abs()
    }
}
