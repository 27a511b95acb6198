//! Homing, and the stretch of the approach that may overlap the mount's
//! homing (docs/run.md, "Homing"). The gate: the mount turns only while the
//! indenter is known clear of the gel. At power-on nothing proves that (the
//! sensor's reference may have been taken in contact), so the stage homes
//! first, to its retracted limit; from there the mount homes while the stage
//! makes the approach's fast move to `approach.start_mm` (inside the declared
//! clear zone) and the sensor is tared and its rest noise measured. The
//! contact search starts only once the mount reports homed and standing still.

use super::motion::until_done_or_stopped;
use super::*;
use devices::motion::Unit;

/// What stopped the stretch that runs beside the mount's homing.
enum ClearSide<E> {
    Stage(E),
    Sensor(&'static str, GaugeError),
    Dropout(u32),
}

/// Rest readings and where the stage ended.
struct ClearStart {
    stage_mm: f64,
    rest: Vec<GaugeReading>,
}

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    /// Home what is not homed and bring the stage to the approach's start with
    /// the sensor tared and its rest noise measured: the mount's homing runs
    /// beside the stage's fast move and the rest readings once the stage is
    /// homed. Returns the rest readings.
    pub(super) async fn home_and_start(&mut self) -> Step<Vec<GaugeReading>> {
        self.checkpoint().await?;
        // Devices that report homed have kept their position since they were
        // homed (the controller's own flag, cleared at power loss): trusted,
        // and homing again would only cost time (the K10CR1 homes at 5 deg/s).
        let stage = Axis::status(&mut self.stage).await.map_err(|e| self.stage_fault("status", e))?;
        let mount = Axis::status(&mut self.mount).await.map_err(|e| self.mount_fault("status", e))?;
        let trusted = stage.homed && mount.homed;
        let t = self.script.home_timeout();
        if !trusted {
            Axis::home(&mut self.stage, t).await.map_err(|e| self.stage_fault("homing", e))?;
        }
        self.stage_homed = true;
        self.stage_mm = self.stage.position().map_ok(f64::from).await.map_err(|e| self.stage_fault("position", e))?;
        // Inside the declared clear zone nothing touches the sensor.
        let clear = self.stage_mm <= self.guard.limits().clear_until_mm;
        self.gamma1_bound_mm = if clear { 0.0 } else { f64::NAN };
        let rest = if trusted {
            self.clear_start_alone().await?
        } else if clear {
            self.log(
                LogLevel::Info,
                format!("stage homed at {:.3} mm, clear of the sensor: the mount homes meanwhile", self.stage_mm),
            );
            self.home_mount_beside_clear_start().await?
        } else {
            // Homed outside the clear zone (a script whose clear zone excludes
            // the home position): the mount homes alone, as before.
            Axis::home(&mut self.mount, t).await.map_err(|e| self.mount_fault("homing", e))?;
            self.clear_start_alone().await?
        };
        self.mount_homed = true;
        self.mount_deg = self.mount.position().map_ok(f64::from).await.map_err(|e| self.mount_fault("position", e))?;
        let what = if trusted { "already homed, homing skipped" } else { "homed" };
        self.log(LogLevel::Info, format!("{what}: stage {:.3} mm, mount {:.3} deg", self.stage_mm, self.mount_deg));
        self.device_status().await?;
        Ok(rest)
    }

    /// The approach's fast move, tare and rest readings with nothing else moving.
    async fn clear_start_alone(&mut self) -> Step<Vec<GaugeReading>> {
        let a = self.script.approach;
        self.move_stage(a.start_mm, "approach start").await?;
        self.gauge.tare().await.map_err(|e| self.sensor_fault("tare", e))?;
        let mut rest = Vec::with_capacity(a.noise_readings);
        for _ in 0..a.noise_readings {
            rest.push(self.read().await?);
        }
        Ok(rest)
    }

    /// The mount homes while the stage moves inside the clear zone to the
    /// approach's start and the sensor takes its rest readings; returns once
    /// the mount reports homed and still.
    async fn home_mount_beside_clear_start(&mut self) -> Step<Vec<GaugeReading>> {
        let target = self.script.approach.start_mm;
        self.checkpoint().await?;
        let from = self.stage_mm;
        if let Err(v) = self.guard.check_stage(from, self.gamma1_bound_mm, target) {
            return Err(self.safety("approach start", v));
        }
        if target > self.guard.limits().clear_until_mm {
            return Err(Halt {
                culprit: Culprit::Safety,
                message: format!("approach start {target} mm lies beyond the clear zone: the mount may not turn there"),
            });
        }
        self.gamma1_bound_mm = self.guard.gamma1_bound(from, self.gamma1_bound_mm, target);
        self.last_inward_mm = 0.0;
        let (move_t, home_t, read_t) =
            (self.script.move_timeout(), self.script.home_timeout(), self.script.read_timeout());
        let (n, dropout) = (self.script.approach.noise_readings, self.script.dropout_reads());
        self.stage_mm = target;
        let mount = Axis::home(&mut self.mount, home_t);
        let side = clear_start(&mut self.stage, &mut self.gauge, target, n, (move_t, read_t), dropout);
        let both = futures_util::future::join(mount, side);
        let (mount, side) = match until_done_or_stopped(both, &mut self.controls, &mut self.pause_requested).await {
            Ok(r) => r,
            Err(c) => return Err(self.operator(c, "homing the mount")),
        };
        // The mount's fault first: it is the one that may have turned in the
        // wrong place; the other side's is reported when the mount is fine.
        mount.map_err(|e| self.mount_fault("homing", e))?;
        let start = match side {
            Ok(s) => s,
            Err(ClearSide::Stage(e)) => {
                return Err(self.stage_fault(&format!("approach start: move to {target:.4} mm"), e));
            }
            Err(ClearSide::Sensor(what, e)) => return Err(self.sensor_fault(what, e)),
            Err(ClearSide::Dropout(k)) => {
                return Err(Halt {
                    culprit: Culprit::Sensor,
                    message: format!(
                        "sensor {}: {k} consecutive read timeouts at rest: the stream stopped",
                        self.gauge.describe()
                    ),
                });
            }
        };
        self.stage_mm = start.stage_mm;
        for r in &start.rest {
            self.note_reading(r);
        }
        // Homed (its homing returned), and still: the contact search may start.
        let still = Axis::status(&mut self.mount).await.map_err(|e| self.mount_fault("status", e))?;
        if still.moving {
            return Err(Halt {
                culprit: Culprit::Mount,
                message: format!(
                    "{}: homing ended but the mount reports moving: no contact search with it turning",
                    self.mount_name
                ),
            });
        }
        Ok(start.rest)
    }
}

/// The stage's fast move to `target` (inside the clear zone), a tare, and `n`
/// rest readings; borrows only the stage and the sensor, so it can run beside
/// the mount's homing.
async fn clear_start<S: LinearStage, G: Gauge>(
    stage: &mut S,
    gauge: &mut G,
    target: f64,
    n: usize,
    (move_t, read_t): (std::time::Duration, std::time::Duration),
    dropout: u32,
) -> Result<ClearStart, ClearSide<S::Error>> {
    stage.start_move_to(Mm(target)).await.map_err(ClearSide::Stage)?;
    let stage_mm = stage.wait_until_stopped(move_t).await.map_err(ClearSide::Stage)?.value();
    gauge.tare().await.map_err(|e| ClearSide::Sensor("tare", e))?;
    let mut rest = Vec::with_capacity(n);
    let (mut timeouts, mut unmeasured) = (0u32, 0u32);
    while rest.len() < n {
        match gauge.read(read_t).await {
            Ok(r) => {
                timeouts = 0;
                rest.push(r);
            }
            Err(GaugeError::Timeout { .. }) => {
                timeouts += 1;
                if timeouts >= dropout {
                    return Err(ClearSide::Dropout(timeouts));
                }
            }
            Err(e @ GaugeError::Measure { .. }) => {
                unmeasured += 1;
                if unmeasured >= 50 {
                    return Err(ClearSide::Sensor("50 frames in a row could not be measured; last", e));
                }
            }
            Err(e) => return Err(ClearSide::Sensor("read", e)),
        }
    }
    Ok(ClearStart { stage_mm, rest })
}
