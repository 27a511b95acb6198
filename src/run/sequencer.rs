//! The scripted calibration sequencer: connect, home, approach and find
//! contact, normal sweep(s) to the target depth and back, return to the depth
//! and twist out and back, retract. Every move goes through the
//! [`SafetyGuard`]; every settled sample is appended (and flushed) to the
//! recording before the next move, so a run that dies leaves a readable file.
//!
//! Controls are taken at safe points (before every move, between sensor
//! reads) and while a move is under way: an abort during a move stops it.
//! Any failure ends in [`Sequencer::abort`]: stop both axes, back the stage
//! off to the retract position, say which device did what.

use futures_util::{FutureExt, TryFutureExt};
use std::fmt;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

use devices::motion::{Axis, AxisStatus, Deg, DeviceFault, FaultKind, Identify, LinearStage, Mm, RotationMount};
use sim::recording::{Direction, Metadata, Phase, RecordingWriter, Sample};
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};

use super::events::{DeviceStatus, FitUpdate, LogLevel, Progress, RunControl, RunEvent, RunPhase, RunSummary};
use super::gauge::{Gauge, GaugeError, GaugeReading};
use super::safety::{LimitViolation, SafetyGuard};
use super::script::{Script, ScriptError};

/// Who or what ended a run early.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Culprit {
    /// Abort or quit from the operator (key, Ctrl-C).
    Operator,
    Stage,
    Mount,
    Sensor,
    /// A move would have left the soft limits.
    Safety,
    /// The recording could not be written.
    Recording,
    /// The procedure could not go on (no contact found, depth not reached).
    Procedure,
    /// easycalib itself failed (a panic in the run): the same safe path.
    Internal,
}

impl Culprit {
    pub fn as_str(self) -> &'static str {
        match self {
            Culprit::Operator => "operator",
            Culprit::Stage => "stage",
            Culprit::Mount => "rotation mount",
            Culprit::Sensor => "sensor",
            Culprit::Safety => "safety",
            Culprit::Recording => "recording",
            Culprit::Procedure => "procedure",
            Culprit::Internal => "internal error",
        }
    }
}

/// What happened to the stage after an abort.
#[derive(Debug, Clone, PartialEq)]
pub enum Backoff {
    /// The stage backed off and stopped here, mm.
    To(f64),
    /// The stage was never homed, so its position is unknown: left where it is.
    NotHomed,
    /// Backing off failed.
    Failed(String),
}

/// Why and how a run ended early.
#[derive(Debug, Clone, PartialEq)]
pub struct AbortInfo {
    pub culprit: Culprit,
    /// What happened, naming the device and the step.
    pub message: String,
    pub backoff: Backoff,
}

impl fmt::Display for AbortInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}; motion stopped", self.message)?;
        match &self.backoff {
            Backoff::To(mm) => write!(f, "; stage backed off to {mm:.3} mm"),
            Backoff::NotHomed => write!(f, "; stage was not homed, left where it is"),
            Backoff::Failed(e) => write!(f, "; COULD NOT back the stage off: {e}"),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum RunStatus {
    Completed,
    Aborted(AbortInfo),
}

/// Rig time of one phase of the procedure.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PhaseTime {
    pub phase: &'static str,
    pub rig_time_s: f64,
}

/// Durations between phase marks; the last phase runs to `end_s`.
fn phase_times(marks: &[(&'static str, f64)], end_s: f64) -> Vec<PhaseTime> {
    marks
        .iter()
        .enumerate()
        .map(|(i, &(phase, t))| {
            let next = marks.get(i + 1).map_or(end_s, |m| m.1);
            PhaseTime { phase, rig_time_s: (next - t).max(0.0) }
        })
        .collect()
}

/// What a run leaves behind. The caller fits the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RunOutcome {
    /// The recording (written and flushed sample by sample).
    pub recording: PathBuf,
    /// Settled samples recorded.
    pub samples: usize,
    /// Sensor time from the first reading to the last, s.
    pub rig_time_s: f64,
    pub wall_time_s: f64,
    /// Stage position of first contact, mm (absolute), once found.
    pub contact_mm: Option<f64>,
    /// gamma1 noise measured before the approach, mm.
    pub noise_gamma1_mm: Option<f64>,
    /// beta = gamma2 / R2 held during the torsion sweep.
    pub torsion_beta: Option<f64>,
    /// Rig time per phase of the procedure, in order (`homing`, `approach`,
    /// `normal`, `torsion`, `retract`), by the sensor's clock.
    pub phase_rig_time_s: Vec<PhaseTime>,
    pub status: RunStatus,
}

impl RunOutcome {
    pub fn completed(&self) -> bool {
        self.status == RunStatus::Completed
    }

    /// The run's summary with the fit's values (the full-model fit is the best estimate).
    pub fn summary(&self, cal: Option<&crate::fit::Calibration>) -> RunSummary {
        RunSummary {
            samples: self.samples,
            wall_time_s: self.wall_time_s,
            rig_time_s: self.rig_time_s,
            e1_mpa: cal.map(|c| c.full.e1_mpa),
            nu1: cal.map(|c| c.full.nu1),
            e1_ci95: cal.map(|c| c.full.ci95.e1_mpa),
            nu1_ci95: cal.map(|c| c.full.ci95.nu1),
            recording: Some(self.recording.display().to_string()),
            report: None,
        }
    }
}

/// Internal: why the procedure stopped.
#[derive(Debug)]
struct Halt {
    culprit: Culprit,
    message: String,
}

type Step<T> = Result<T, Halt>;

/// Upper bound on readings per settle, whatever the sensor's timestamps say.
const MAX_SETTLE_READINGS: usize = 2000;

fn kind_str(k: FaultKind) -> &'static str {
    match k {
        FaultKind::Timeout => "timeout",
        FaultKind::Protocol => "protocol error",
        FaultKind::DeviceReported => "device reported an error",
        FaultKind::Limit => "limit",
        FaultKind::Disconnected => "disconnected",
    }
}

/// Where the ETA estimate stands.
#[derive(Debug, Clone, Copy)]
enum Cursor {
    Setup,
    Load { rep: u32, k: usize, beta: f64 },
    Unload { rep: u32, left: usize },
    Depth,
    Twist { left: usize },
    Done,
}

/// Runs one calibration script on a stage, a mount and a gauge.
pub struct Sequencer<S, R, G> {
    script: Script,
    stage: S,
    mount: R,
    gauge: G,
    recording_path: PathBuf,
    events: Option<UnboundedSender<RunEvent>>,
    controls: Option<UnboundedReceiver<RunControl>>,
    extra_meta: Vec<(String, String)>,
    /// Test facility: panic after this many samples (proves the panic path).
    panic_after_samples: Option<usize>,
    guard: SafetyGuard,
    // Run state.
    stage_name: String,
    mount_name: String,
    stage_homed: bool,
    mount_homed: bool,
    /// Last known (or commanded) stage position, NaN while unknown.
    stage_mm: f64,
    mount_deg: f64,
    /// Latest gamma1 reading, mm (NaN while unknown).
    gamma1_mm: f64,
    /// Upper bound on the true gamma1 at the current stage position (NaN:
    /// unknown): grows by every inward move, tightened by readings. The
    /// guard's gamma1 limit is checked against it.
    g1_bound: f64,
    /// Inward travel of the last stage move: a reading right after a move may
    /// still lag behind the elastomer by up to this much.
    last_inward_mm: f64,
    noise_gamma1: f64,
    noise_theta1: f64,
    /// Reading noise learnt from settled windows in contact (a sensor may be
    /// noisier pressed than at rest, or report exact zeros out of contact).
    live_noise: Option<(f64, f64)>,
    t0: Option<f64>,
    t_last: f64,
    /// Where each phase began on the sensor's clock.
    phase_marks: Vec<(&'static str, f64)>,
    writer: Option<RecordingWriter<BufWriter<File>>>,
    samples: Vec<Sample>,
    contact_mm: Option<f64>,
    torsion_beta: Option<f64>,
    twist_zero: f64,
    pause_requested: bool,
    consecutive_timeouts: u32,
    last_fit: Option<FitUpdate>,
    step_index: usize,
    cursor: Cursor,
    loads_rep0: Option<usize>,
    sweep_start: Option<(f64, usize)>,
}

fn sanitize(s: &str) -> String {
    s.chars().map(|c| if c.is_control() { ' ' } else { c }).collect()
}

/// The next control, waiting for one; pends forever once the channel is closed
/// (no controller left means nobody can pause or abort, not "abort").
async fn next_control(ctl: &mut Option<UnboundedReceiver<RunControl>>) -> RunControl {
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
async fn until_done_or_stopped<T>(
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
            },
        }
    }
}

fn mean(xs: &[GaugeReading]) -> GaugeReading {
    let n = xs.len().max(1) as f64;
    let mut m = GaugeReading {
        t_s: xs.last().map(|r| r.t_s).unwrap_or(0.0),
        gamma1_mm: 0.0,
        theta1_deg: 0.0,
        contact_radius_mm: 0.0,
    };
    for r in xs {
        m.gamma1_mm += r.gamma1_mm / n;
        m.theta1_deg += r.theta1_deg / n;
        m.contact_radius_mm += r.contact_radius_mm / n;
    }
    m
}

fn std_dev(xs: impl Iterator<Item = f64> + Clone) -> f64 {
    let n = xs.clone().count();
    if n < 2 {
        return 0.0;
    }
    let m = xs.clone().sum::<f64>() / n as f64;
    (xs.map(|x| (x - m) * (x - m)).sum::<f64>() / (n - 1) as f64).sqrt()
}

impl<S, R, G> Sequencer<S, R, G>
where
    S: LinearStage + Identify,
    R: RotationMount + Identify,
    G: Gauge,
{
    /// A sequencer for `script` that will write its recording to `recording_path`.
    /// The soft limits are the script's, narrowed to the devices' travel.
    pub fn new(
        script: Script,
        stage: S,
        mount: R,
        gauge: G,
        recording_path: impl Into<PathBuf>,
    ) -> Result<Self, ScriptError> {
        script.validate()?;
        let guard = SafetyGuard::new(&script, stage.travel(), mount.travel());
        Ok(Self {
            script,
            stage,
            mount,
            gauge,
            recording_path: recording_path.into(),
            events: None,
            controls: None,
            extra_meta: Vec::new(),
            panic_after_samples: None,
            guard,
            stage_name: "stage".into(),
            mount_name: "rotation mount".into(),
            stage_homed: false,
            mount_homed: false,
            stage_mm: f64::NAN,
            mount_deg: f64::NAN,
            gamma1_mm: f64::NAN,
            g1_bound: f64::NAN,
            last_inward_mm: 0.0,
            noise_gamma1: 0.0,
            noise_theta1: 0.0,
            live_noise: None,
            t0: None,
            t_last: 0.0,
            phase_marks: Vec::new(),
            writer: None,
            samples: Vec::new(),
            contact_mm: None,
            torsion_beta: None,
            twist_zero: 0.0,
            pause_requested: false,
            consecutive_timeouts: 0,
            last_fit: None,
            step_index: 0,
            cursor: Cursor::Setup,
            loads_rep0: None,
            sweep_start: None,
        })
    }

    /// Send events here (sending never blocks the rig; a dropped receiver is ignored).
    pub fn with_events(mut self, tx: UnboundedSender<RunEvent>) -> Self {
        self.events = Some(tx);
        self
    }

    /// Take pause / resume / abort / quit from here.
    pub fn with_controls(mut self, rx: UnboundedReceiver<RunControl>) -> Self {
        self.controls = Some(rx);
        self
    }

    /// Extra `# key: value` metadata for the recording (e.g. a simulation's truth).
    pub fn with_metadata(mut self, extra: Vec<(String, String)>) -> Self {
        self.extra_meta = extra;
        self
    }

    /// Test facility (docs/hardening.md): panic inside the run after `n`
    /// samples, to prove that a panic ends in the same safe path as any fault.
    #[doc(hidden)]
    pub fn with_panic_after_samples(mut self, n: Option<usize>) -> Self {
        self.panic_after_samples = n;
        self
    }

    pub fn script(&self) -> &Script {
        &self.script
    }

    /// The settled samples recorded so far.
    pub fn samples(&self) -> &[Sample] {
        &self.samples
    }

    pub fn into_parts(self) -> (S, R, G) {
        (self.stage, self.mount, self.gauge)
    }

    fn total_steps(&self) -> usize {
        6 + self.script.normal.repeats as usize
    }

    fn emit(&self, ev: RunEvent) {
        if let Some(tx) = &self.events {
            let _ = tx.send(ev);
        }
    }

    fn log(&self, level: LogLevel, message: impl Into<String>) {
        self.emit(RunEvent::Log { level, message: message.into() });
    }

    fn step(&mut self, index: usize, name: impl Into<String>, phase: RunPhase) {
        self.step_index = index;
        self.emit(RunEvent::StepStarted { index, total: self.total_steps(), name: name.into(), phase });
        self.progress();
    }

    fn stage_fault<E: DeviceFault>(&self, what: &str, e: E) -> Halt {
        Halt { culprit: Culprit::Stage, message: format!("{} {what}: {}: {e}", self.stage_name, kind_str(e.kind())) }
    }

    fn mount_fault<E: DeviceFault>(&self, what: &str, e: E) -> Halt {
        Halt { culprit: Culprit::Mount, message: format!("{} {what}: {}: {e}", self.mount_name, kind_str(e.kind())) }
    }

    fn sensor_fault(&self, what: &str, e: GaugeError) -> Halt {
        Halt {
            culprit: Culprit::Sensor,
            message: format!("sensor {} {what}: {}: {e}", self.gauge.describe(), kind_str(e.kind())),
        }
    }

    fn safety(&self, context: &str, v: LimitViolation) -> Halt {
        Halt { culprit: Culprit::Safety, message: format!("soft limit, {context}: {v}") }
    }

    /// Run the script to its end or to an abort. Never panics on device
    /// trouble: every failure is an [`AbortInfo`] in the outcome.
    pub async fn run(&mut self) -> RunOutcome {
        let wall = Instant::now();
        // A panic anywhere in the procedure is caught here and ends like any
        // fault: stop, back off, keep the recording (docs/hardening.md).
        let result = std::panic::AssertUnwindSafe(self.procedure()).catch_unwind().await;
        let status = match result {
            Ok(Ok(())) => RunStatus::Completed,
            Ok(Err(halt)) => RunStatus::Aborted(self.abort(halt).await),
            Err(panic) => {
                let what = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic".into());
                let halt = Halt { culprit: Culprit::Internal, message: format!("internal error (panic): {what}") };
                RunStatus::Aborted(self.abort(halt).await)
            }
        };
        RunOutcome {
            recording: self.recording_path.clone(),
            samples: self.samples.len(),
            rig_time_s: self.t_last,
            wall_time_s: wall.elapsed().as_secs_f64(),
            contact_mm: self.contact_mm,
            noise_gamma1_mm: (self.noise_gamma1 > 0.0).then_some(self.noise_gamma1),
            torsion_beta: self.torsion_beta,
            phase_rig_time_s: phase_times(&self.phase_marks, self.t_last),
            status,
        }
    }

    async fn procedure(&mut self) -> Step<()> {
        self.step(0, "connect and identify", RunPhase::Setup);
        self.connect().await?;
        self.step(1, "home", RunPhase::Setup);
        self.mark_phase("homing").await?;
        self.home().await?;
        self.step(2, "approach and find contact", RunPhase::Approach);
        self.mark_phase("approach").await?;
        self.approach().await?;
        let reps = self.script.normal.repeats;
        let mut crossing = None;
        for rep in 0..reps {
            self.step(3 + rep as usize, format!("normal sweep {}/{}", rep + 1, reps), RunPhase::Normal);
            if rep == 0 {
                self.mark_phase("normal").await?;
            }
            self.device_status().await?;
            crossing = Some(self.normal_sweep(rep).await?);
        }
        let base = 3 + reps as usize;
        self.step(base, "return to torsion depth", RunPhase::Torsion);
        self.mark_phase("torsion").await?;
        let crossing =
            crossing.ok_or_else(|| Halt { culprit: Culprit::Procedure, message: "no normal sweep ran".into() })?;
        self.torsion_depth(crossing).await?;
        self.step(base + 1, "torsion sweep", RunPhase::Torsion);
        self.device_status().await?;
        self.torsion_sweep().await?;
        self.step(base + 2, "retract", RunPhase::Retract);
        self.mark_phase("retract").await?;
        self.retract().await?;
        self.mark_end().await;
        self.cursor = Cursor::Done;
        self.progress();
        self.log(
            LogLevel::Info,
            format!("run complete: {} samples in {}", self.samples.len(), self.recording_path.display()),
        );
        Ok(())
    }

    // ---- steps -------------------------------------------------------------

    async fn connect(&mut self) -> Step<()> {
        self.checkpoint().await?;
        for (name, x) in
            [("limits.retract_mm", self.script.limits.retract_mm), ("approach.start_mm", self.script.approach.start_mm)]
        {
            if !self.guard.stage_in_travel(x) {
                let l = self.guard.limits();
                return Err(Halt {
                    culprit: Culprit::Safety,
                    message: format!(
                        "soft limit: script {name} = {x} mm lies outside the stage's travel [{}, {}] mm",
                        l.stage_min_mm, l.stage_max_mm
                    ),
                });
            }
        }
        let info = Identify::identify(&mut self.stage).await.map_err(|e| self.stage_fault("identify", e))?;
        self.stage_name = format!("stage {} SN {}", info.model, info.serial).trim().to_string();
        self.log(LogLevel::Info, format!("{} firmware {}", self.stage_name, info.firmware));
        let info = Identify::identify(&mut self.mount).await.map_err(|e| self.mount_fault("identify", e))?;
        self.mount_name = format!("rotation mount {} SN {}", info.model, info.serial).trim().to_string();
        self.log(LogLevel::Info, format!("{} firmware {}", self.mount_name, info.firmware));
        self.gauge.start().await.map_err(|e| self.sensor_fault("start", e))?;
        self.log(LogLevel::Info, format!("sensor {} streaming", self.gauge.describe()));
        self.open_recording()
    }

    fn open_recording(&mut self) -> Step<()> {
        let fail = |e: std::io::Error, path: &Path| Halt {
            culprit: Culprit::Recording,
            message: format!("cannot write the recording {}: {e}", path.display()),
        };
        if let Some(dir) = self.recording_path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| fail(e, &self.recording_path))?;
        }
        let file = super::outdir::create_nofollow(&self.recording_path).map_err(|e| fail(e, &self.recording_path))?;
        let mut extra =
            vec![("stage".to_string(), sanitize(&self.stage_name)), ("mount".to_string(), sanitize(&self.mount_name))];
        extra.extend(self.extra_meta.iter().map(|(k, v)| (sanitize(k), sanitize(v))));
        let meta = Metadata {
            sensor: Some(sanitize(self.script.sensor.name.as_deref().unwrap_or(&self.gauge.describe()))),
            indenter: self.script.indenter,
            elastomer_r_mm: self.script.sensor.elastomer_r_mm,
            layer: None,
            created: Some(crate::report::rfc3339_utc(SystemTime::now())),
            extra,
        };
        let w = RecordingWriter::new(BufWriter::new(file), &meta).map_err(|e| fail(e, &self.recording_path))?;
        self.writer = Some(w);
        Ok(())
    }

    async fn home(&mut self) -> Step<()> {
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
        self.g1_bound = if self.stage_mm <= self.guard.limits().clear_until_mm { 0.0 } else { f64::NAN };
        if !trusted {
            Axis::home(&mut self.mount, t).await.map_err(|e| self.mount_fault("homing", e))?;
        }
        self.mount_homed = true;
        self.mount_deg = self.mount.position().map_ok(f64::from).await.map_err(|e| self.mount_fault("position", e))?;
        let what = if trusted { "already homed, homing skipped" } else { "homed" };
        self.log(LogLevel::Info, format!("{what}: stage {:.3} mm, mount {:.3} deg", self.stage_mm, self.mount_deg));
        self.device_status().await
    }

    async fn approach(&mut self) -> Step<()> {
        let a = self.script.approach;
        self.move_stage(a.start_mm, "approach start").await?;
        // The elastomer is untouched here: zero the gauge and measure its noise.
        self.gauge.tare().await.map_err(|e| self.sensor_fault("tare", e))?;
        let mut rest = Vec::with_capacity(a.noise_readings);
        for _ in 0..a.noise_readings {
            rest.push(self.read().await?);
        }
        self.noise_gamma1 = std_dev(rest.iter().map(|r| r.gamma1_mm));
        self.noise_theta1 = std_dev(rest.iter().map(|r| r.theta1_deg));
        let offset = mean(&rest).gamma1_mm;
        let threshold = (a.contact_sigmas * self.noise_gamma1).max(a.contact_min_mm) + offset.abs();
        self.log(
            LogLevel::Info,
            format!(
                "gamma1 noise {:.2} um, theta1 noise {:.4} deg; contact threshold {:.2} um",
                self.noise_gamma1 * 1e3,
                self.noise_theta1,
                threshold * 1e3
            ),
        );
        // Step in until two consecutive readings rise above the threshold.
        let mut pos = a.start_mm;
        let mut last_clear = pos;
        loop {
            let next = pos + a.step_mm;
            if !self.guard.stage_in_travel(next) {
                return Err(Halt {
                    culprit: Culprit::Procedure,
                    message: format!(
                        "approach: no contact found up to the stage limit {:.3} mm (gamma1 {:.4} mm, threshold {:.4} mm)",
                        pos, self.gamma1_mm, threshold
                    ),
                });
            }
            self.move_stage(next, "approach").await?;
            pos = next;
            let r1 = self.read().await?;
            let r2 = self.read().await?;
            if r1.gamma1_mm > threshold && r2.gamma1_mm > threshold {
                break;
            }
            last_clear = pos;
            self.progress_fraction((pos - a.start_mm) / (self.guard.limits().stage_max_mm - a.start_mm));
        }
        // Refine: settled readings deeper in, where the grid resolves the
        // contact, and a line through them back to gamma1 = 0.
        let mut pts = Vec::new();
        let first = self.settle().await?;
        pts.push((pos, first.gamma1_mm));
        for _ in 0..a.refine_steps {
            if pts.last().is_some_and(|p| p.1 >= a.refine_to_gamma1_mm) {
                break;
            }
            let next = pos + a.step_mm;
            if self.guard.check_stage(self.stage_mm, self.g1_bound, next).is_err() {
                break;
            }
            self.move_stage(next, "contact refinement").await?;
            pos = next;
            pts.push((pos, self.settle().await?.gamma1_mm));
        }
        let window: Vec<(f64, f64)> =
            pts.iter().copied().filter(|p| (a.refine_from_gamma1_mm..=a.refine_to_gamma1_mm).contains(&p.1)).collect();
        let line = if window.len() >= 2 { contact_from_line(&window, threshold) } else { None };
        let contact = line
            .or_else(|| contact_from_line(&pts, threshold))
            .unwrap_or(0.5 * (last_clear + pts[0].0))
            .clamp(last_clear - a.step_mm, pts[0].0);
        self.contact_mm = Some(contact);
        self.log(LogLevel::Info, format!("first contact at stage {contact:.4} mm"));
        // Back off to the normal sweep's start (the same direction of travel as loading follows).
        let start = (contact - a.pre_contact_mm).max(self.guard.limits().stage_min_mm);
        self.move_stage(start, "back to the normal sweep start").await?;
        Ok(())
    }

    /// One load/unload cycle. Returns the two load points around the target
    /// depth: ((stage_mm, beta) before, (stage_mm, beta) at/after).
    async fn normal_sweep(&mut self, rep: u32) -> Step<((f64, f64), (f64, f64))> {
        let contact = self.contact_mm.unwrap_or(self.stage_mm);
        let n = self.script.normal;
        let r2 = self.script.indenter.r_mm;
        let start = (contact - self.script.approach.pre_contact_mm).max(self.guard.limits().stage_min_mm);
        let mut path: Vec<(f64, f64)> = Vec::new();
        let mut k = 0usize;
        if self.sweep_start.is_none() {
            self.sweep_start = Some((self.t_last, self.samples.len()));
        }
        loop {
            let pos = start + k as f64 * n.step_mm;
            let beta_now = path.last().map(|p| p.1).unwrap_or(0.0);
            if let Err(v) = self.guard.check_stage(self.stage_mm, self.g1_bound, pos) {
                return Err(self.safety(
                    &format!(
                        "normal sweep {} stopped at beta {beta_now:.4} before the target {}",
                        rep + 1,
                        n.target_beta
                    ),
                    v,
                ));
            }
            self.move_stage(pos, "normal sweep").await?;
            let r = self.settle().await?;
            let beta = ((pos - contact) - r.gamma1_mm) / r2;
            self.cursor = Cursor::Load { rep, k, beta };
            self.record(Phase::Normal, pos, r, Some(rep), Some(Direction::Load))?;
            path.push((pos, beta));
            if beta >= n.target_beta {
                break;
            }
            k += 1;
        }
        if rep == 0 {
            self.loads_rep0 = Some(path.len());
        }
        self.log(
            LogLevel::Info,
            format!(
                "normal sweep {}: beta {:.4} reached at stage {:.4} mm",
                rep + 1,
                path.last().map(|p| p.1).unwrap_or(0.0),
                path.last().map(|p| p.0).unwrap_or(0.0)
            ),
        );
        let crossing = match path.as_slice() {
            [.., a, b] => (*a, *b),
            [b] => ((start, 0.0), *b),
            [] => unreachable_path()?,
        };
        let back: Vec<f64> = path.iter().rev().skip(1).map(|p| p.0).collect();
        for (i, pos) in back.iter().enumerate() {
            self.cursor = Cursor::Unload { rep, left: back.len() - i };
            self.move_stage(*pos, "normal unload").await?;
            let r = self.settle().await?;
            self.record(Phase::Normal, *pos, r, Some(rep), Some(Direction::Unload))?;
        }
        Ok(crossing)
    }

    async fn torsion_depth(&mut self, crossing: ((f64, f64), (f64, f64))) -> Step<()> {
        self.cursor = Cursor::Depth;
        let contact = self.contact_mm.unwrap_or(self.stage_mm);
        let target = self.script.normal.target_beta;
        let r2 = self.script.indenter.r_mm;
        let ((p0, b0), (p1, b1)) = crossing;
        let slope = if (p1 - p0).abs() > 0.0 && b1 > b0 { (b1 - b0) / (p1 - p0) } else { 1.0 / r2 };
        let mut pos = if b1 > b0 { p0 + (target - b0) / slope } else { p1 };
        let step = self.script.normal.step_mm;
        let mut beta = f64::NAN;
        for _ in 0..4 {
            self.move_stage(pos, "return to torsion depth").await?;
            let r = self.settle().await?;
            beta = ((pos - contact) - r.gamma1_mm) / r2;
            // Good to a quarter of a percent of the target, or as good as the step allows.
            if (beta - target).abs() <= 0.0025 * target {
                break;
            }
            pos += ((target - beta) / slope).clamp(-step, step);
        }
        self.torsion_beta = Some(beta);
        self.log(LogLevel::Info, format!("holding beta {beta:.4} at stage {pos:.4} mm for the torsion sweep"));
        Ok(())
    }

    async fn torsion_sweep(&mut self) -> Step<()> {
        self.twist_zero = self.mount_deg;
        self.guard.set_twist_zero(self.mount_deg);
        let angles = self.script.twist_angles();
        let half = angles.len() / 2;
        let hold = self.stage_mm;
        for (i, angle) in angles.iter().enumerate() {
            self.cursor = Cursor::Twist { left: angles.len() - i };
            let target = self.twist_zero + angle;
            self.move_mount(target, "torsion sweep").await?;
            let r = self.settle().await?;
            let dir = if i <= half { Direction::Load } else { Direction::Unload };
            self.record(Phase::Torsion, hold, r, None, Some(dir))?;
        }
        Ok(())
    }

    async fn retract(&mut self) -> Step<()> {
        let retract = self.script.limits.retract_mm;
        self.move_stage(retract, "retract").await?;
        if (self.mount_deg - self.twist_zero).abs() > 1e-9 {
            self.move_mount(self.twist_zero, "retract").await?;
        }
        self.device_status().await
    }

    // ---- motion ------------------------------------------------------------

    /// The only way the stage moves during a run: checkpoint, guard, move, wait.
    async fn move_stage(&mut self, target: f64, context: &str) -> Step<f64> {
        self.checkpoint().await?;
        let from = self.stage_mm;
        if let Err(v) = self.guard.check_stage(from, self.g1_bound, target) {
            return Err(self.safety(context, v));
        }
        // From here on the stage may be anywhere up to the target.
        self.g1_bound = self.guard.gamma1_bound(from, self.g1_bound, target);
        self.last_inward_mm = if from.is_finite() { (target - from).max(0.0) } else { 0.0 };
        self.stage
            .start_move_to(Mm(target))
            .await
            .map_err(|e| self.stage_fault(&format!("{context}: move to {target:.4} mm"), e))?;
        self.stage_mm = target;
        let timeout = self.script.move_timeout();
        let res = until_done_or_stopped(
            self.stage.wait_until_stopped(timeout).map_ok(f64::from),
            &mut self.controls,
            &mut self.pause_requested,
        )
        .await;
        match res {
            Ok(Ok(p)) => {
                self.stage_mm = p;
                Ok(p)
            }
            Ok(Err(e)) => Err(self.stage_fault(&format!("{context}: move to {target:.4} mm"), e)),
            Err(c) => Err(self.operator(c, context)),
        }
    }

    /// The only way the mount moves during a run.
    async fn move_mount(&mut self, target: f64, context: &str) -> Step<f64> {
        self.checkpoint().await?;
        if let Err(v) = self.guard.check_mount(target) {
            return Err(self.safety(context, v));
        }
        self.mount
            .start_move_to(Deg(target))
            .await
            .map_err(|e| self.mount_fault(&format!("{context}: move to {target:.3} deg"), e))?;
        self.mount_deg = target;
        let timeout = self.script.move_timeout();
        let res = until_done_or_stopped(
            self.mount.wait_until_stopped(timeout).map_ok(f64::from),
            &mut self.controls,
            &mut self.pause_requested,
        )
        .await;
        match res {
            Ok(Ok(p)) => {
                self.mount_deg = p;
                Ok(p)
            }
            Ok(Err(e)) => Err(self.mount_fault(&format!("{context}: move to {target:.3} deg"), e)),
            Err(c) => Err(self.operator(c, context)),
        }
    }

    fn operator(&self, c: RunControl, context: &str) -> Halt {
        let verb = if c == RunControl::Quit { "quit" } else { "abort" };
        Halt { culprit: Culprit::Operator, message: format!("{verb} requested by the operator during {context}") }
    }

    /// A safe point: take queued controls; hold here while paused.
    async fn checkpoint(&mut self) -> Step<()> {
        while let Some(rx) = self.controls.as_mut() {
            match rx.try_recv() {
                Ok(RunControl::Pause) => self.pause_requested = true,
                Ok(RunControl::Resume) => self.pause_requested = false,
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
                RunControl::Pause => {}
                c @ (RunControl::Abort | RunControl::Quit) => return Err(self.operator(c, "pause")),
            }
        }
        self.pause_requested = false;
        self.emit(RunEvent::Resumed);
        Ok(())
    }

    // ---- sensing -----------------------------------------------------------

    /// Timestamp the end of the procedure, best effort: the run is complete
    /// whatever the sensor says now.
    async fn mark_end(&mut self) {
        if let (Ok(r), Some(t0)) = (self.gauge.read(self.script.read_timeout()).await, self.t0) {
            self.t_last = (r.t_s - t0).max(self.t_last);
        }
    }

    /// Timestamp the start of a phase with one reading (the sensor's clock is
    /// the rig's; without a reading the stretch would have no time).
    async fn mark_phase(&mut self, phase: &'static str) -> Step<()> {
        self.read().await?;
        self.phase_marks.push((phase, self.t_last));
        Ok(())
    }

    /// One reading; read timeouts adding up to the dropout timeout abort.
    async fn read(&mut self) -> Step<GaugeReading> {
        let timeout = self.script.read_timeout();
        let mut unmeasured = 0u32;
        loop {
            match self.gauge.read(timeout).await {
                Ok(r) => {
                    self.consecutive_timeouts = 0;
                    let t0 = *self.t0.get_or_insert(r.t_s);
                    self.t_last = (r.t_s - t0).max(self.t_last);
                    self.gamma1_mm = r.gamma1_mm;
                    self.g1_bound = self.g1_bound.min(r.gamma1_mm + self.last_inward_mm + self.reading_margin());
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

    /// Read until the reading is stable, never a fixed wait. The readings
    /// are taken in windows of n; with three consecutive window means
    /// m1, m2, m3 the reading is settled when the last drift |m3 - m2| is
    /// within tolerance and, if the drifts shrink geometrically in one
    /// direction (an elastomer relaxing), the relaxation still to come,
    /// |d2| r / (1 - r) with r = d2 / d1, is within tolerance too.
    async fn settle(&mut self) -> Step<GaugeReading> {
        let s = self.script.settle;
        let n = s.readings;
        // Two means of n noisy readings differ by ~sigma sqrt(2/n): never demand less than 3 of that.
        let se = (2.0 / n as f64).sqrt();
        let (live_g, live_t) = self.live_noise.unwrap_or((0.0, 0.0));
        let tol_g = s.tol_gamma1_mm.max(3.0 * self.noise_gamma1.max(live_g) * se);
        let tol_t = s.tol_theta1_deg.max(3.0 * self.noise_theta1.max(live_t) * se);
        let mut buf: Vec<GaugeReading> = Vec::new();
        let mut t_start = None;
        loop {
            self.checkpoint().await?;
            let r = self.read().await?;
            let t_first = *t_start.get_or_insert(r.t_s);
            buf.push(r);
            if buf.len() >= 3 * n {
                let k = buf.len();
                let m3 = mean(&buf[k - n..]);
                let m2 = mean(&buf[k - 2 * n..k - n]);
                let m1 = mean(&buf[k - 3 * n..k - 2 * n]);
                let g = remaining_relaxation(m1.gamma1_mm, m2.gamma1_mm, m3.gamma1_mm);
                let t = remaining_relaxation(m1.theta1_deg, m2.theta1_deg, m3.theta1_deg);
                if g <= tol_g && t <= tol_t {
                    // Settled: the mean is within the tolerance of where the elastomer is.
                    let upper = m3.gamma1_mm + tol_g + self.reading_margin() / (n as f64).sqrt();
                    self.g1_bound = self.g1_bound.min(upper);
                    self.guard.note_gamma1(self.stage_mm, upper);
                    self.last_inward_mm = 0.0;
                    self.learn_noise(&buf[k - 2 * n..]);
                    return Ok(m3);
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
                    return Ok(m3);
                }
            }
        }
    }

    /// Update the live noise from a settled stretch of readings: successive
    /// differences (insensitive to what little drift is left), averaged
    /// exponentially over the run.
    fn learn_noise(&mut self, rs: &[GaugeReading]) {
        if rs.len() < 3 {
            return;
        }
        let sd = |f: fn(&GaugeReading) -> f64| {
            let v = rs.windows(2).map(|w| (f(&w[1]) - f(&w[0])).powi(2)).sum::<f64>() / (rs.len() - 1) as f64;
            (v / 2.0).sqrt()
        };
        let (g, t) = (sd(|r| r.gamma1_mm), sd(|r| r.theta1_deg));
        self.live_noise = Some(match self.live_noise {
            None => (g, t),
            Some((g0, t0)) => ((0.9 * g0 * g0 + 0.1 * g * g).sqrt(), (0.9 * t0 * t0 + 0.1 * t * t).sqrt()),
        });
    }

    /// How far one reading may lie below the truth by noise alone.
    fn reading_margin(&self) -> f64 {
        (4.0 * self.noise_gamma1).max(self.script.approach.contact_min_mm)
    }

    // ---- recording and reporting -------------------------------------------

    fn record(
        &mut self,
        phase: Phase,
        stage_abs: f64,
        r: GaugeReading,
        rep: Option<u32>,
        dir: Option<Direction>,
    ) -> Step<()> {
        let contact = self.contact_mm.unwrap_or(0.0);
        let t0 = self.t0.unwrap_or(r.t_s);
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
    fn snapshot(&self) {
        let axis = |position: f64, homed: bool| AxisStatus { position, homed, enabled: true, ..Default::default() };
        self.emit(RunEvent::DeviceStatus(DeviceStatus {
            stage: axis(self.stage_mm, self.stage_homed),
            rotation: axis(self.mount_deg, self.mount_homed),
            sensor: self.gauge.link_stats(),
        }));
    }

    async fn device_status(&mut self) -> Step<()> {
        let stage = self.stage.status().await.map_err(|e| self.stage_fault("status", e))?;
        let rotation = self.mount.status().await.map_err(|e| self.mount_fault("status", e))?;
        self.emit(RunEvent::DeviceStatus(DeviceStatus { stage, rotation, sensor: self.gauge.link_stats() }));
        Ok(())
    }

    fn progress_fraction(&self, step_fraction: f64) {
        self.emit(RunEvent::Progress(Progress {
            step_fraction: step_fraction.clamp(0.0, 1.0),
            elapsed_s: self.t_last,
            eta_s: self.eta(),
        }));
    }

    fn progress(&self) {
        let twist_total = self.script.twist_angles().len();
        let n_load = self.loads_estimate();
        let frac = match self.cursor {
            Cursor::Setup => 0.0,
            Cursor::Load { beta, .. } => 0.5 * beta / self.script.normal.target_beta,
            Cursor::Unload { left, .. } => n_load.map(|n| 1.0 - 0.5 * left as f64 / n.max(1.0)).unwrap_or(0.5),
            Cursor::Depth => 0.5,
            Cursor::Twist { left } => 1.0 - left as f64 / twist_total.max(1) as f64,
            Cursor::Done => 1.0,
        };
        self.progress_fraction(frac);
    }

    /// Load samples per normal sweep: known after the first, extrapolated from beta before.
    fn loads_estimate(&self) -> Option<f64> {
        if let Some(n) = self.loads_rep0 {
            return Some(n as f64);
        }
        match self.cursor {
            Cursor::Load { k, beta, .. } if beta > 0.02 => Some((k + 1) as f64 * self.script.normal.target_beta / beta),
            _ => None,
        }
    }

    /// Rig time left: samples left times the mean time per sample so far.
    fn eta(&self) -> Option<f64> {
        let (t_start, n_start) = self.sweep_start?;
        let done = self.samples.len().checked_sub(n_start)?;
        if done < 3 {
            return None;
        }
        let per = (self.t_last - t_start) / done as f64;
        let reps = self.script.normal.repeats as f64;
        let twist = self.script.twist_angles().len() as f64;
        let left = match self.cursor {
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
            Cursor::Twist { left } => left as f64,
            Cursor::Done => 0.0,
        };
        Some(left.max(0.0) * per)
    }

    /// Stop everything, back the stage off, say what happened.
    async fn abort(&mut self, halt: Halt) -> AbortInfo {
        self.log(LogLevel::Error, format!("{}: {}", halt.culprit.as_str(), halt.message));
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

/// How far a reading may still move, from three consecutive window means:
/// the last drift, or for a geometric (exponential) approach the whole tail
/// d2 r / (1 - r), r = d2 / d1.
fn remaining_relaxation(m1: f64, m2: f64, m3: f64) -> f64 {
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

fn unreachable_path<T>() -> Step<T> {
    Err(Halt { culprit: Culprit::Procedure, message: "normal sweep recorded no load point".into() })
}

/// Stage position where a line through the in-contact points (gamma1 above
/// `threshold`) reaches gamma1 = 0. Near contact gamma1 is proportional to the
/// approach (Hertz: both are a^2 terms), so the line is the right shape.
fn contact_from_line(pts: &[(f64, f64)], threshold: f64) -> Option<f64> {
    let p: Vec<(f64, f64)> = pts.iter().copied().filter(|&(_, g)| g > threshold).collect();
    if p.len() < 2 {
        return None;
    }
    let n = p.len() as f64;
    let mx = p.iter().map(|q| q.0).sum::<f64>() / n;
    let my = p.iter().map(|q| q.1).sum::<f64>() / n;
    let sxx: f64 = p.iter().map(|q| (q.0 - mx) * (q.0 - mx)).sum();
    let sxy: f64 = p.iter().map(|q| (q.0 - mx) * (q.1 - my)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    if slope.is_nan() || slope <= 0.0 {
        return None;
    }
    let x0 = mx - my / slope;
    x0.is_finite().then_some(x0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contact_line_extrapolates_to_zero() {
        let pts = [(12.05, 0.0), (12.10, 0.075), (12.15, 0.15), (12.20, 0.225)];
        let c = contact_from_line(&pts, 0.01).unwrap();
        assert!((c - 12.05).abs() < 1e-9, "{c}");
        assert_eq!(contact_from_line(&pts[..2], 0.01), None);
        assert_eq!(contact_from_line(&[(1.0, 0.5), (2.0, 0.2)], 0.01), None, "falling gamma1 is no contact line");
    }

    #[test]
    fn relaxation_tail_is_extrapolated() {
        // Exponential approach to 1.0 with ratio 0.5 per window: 0.5, 0.75, 0.875 -> tail 0.125.
        assert!((remaining_relaxation(0.5, 0.75, 0.875) - 0.125).abs() < 1e-12);
        // Noise without a trend: just the last drift.
        assert!((remaining_relaxation(1.0, 1.002, 1.001) - 0.001).abs() < 1e-12);
        // Still speeding up: at least twice the larger drift.
        assert!((remaining_relaxation(0.0, 0.1, 0.3) - 0.4).abs() < 1e-12);
    }

    #[test]
    fn abort_message_says_what_and_where_the_stage_went() {
        let a = AbortInfo {
            culprit: Culprit::Stage,
            message: "stage KDC101 SN 1: disconnected: pty closed".into(),
            backoff: Backoff::To(0.0),
        };
        assert_eq!(
            a.to_string(),
            "stage KDC101 SN 1: disconnected: pty closed; motion stopped; stage backed off to 0.000 mm"
        );
        let b = AbortInfo { backoff: Backoff::Failed("gone".into()), ..a };
        assert!(b.to_string().contains("COULD NOT back the stage off: gone"));
    }
}
