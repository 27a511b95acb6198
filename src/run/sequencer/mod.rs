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

mod experiments;
mod homing;
mod motion;
mod outcome;
mod progress;
mod record;
mod settle;
mod steps;
#[cfg(test)]
mod tests;
mod watch;

pub use outcome::{AbortInfo, AdaptiveStep, Backoff, Culprit, PhaseTime, RunOutcome, RunStatus};

use futures_util::{FutureExt, TryFutureExt};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

use devices::motion::{Axis, AxisStatus, DeviceFault, FaultKind, Identify, LinearStage, Mm, RotationMount};
use sim::experiment::{Experiment, ExperimentSpec};
use sim::recording::{CONTACT_SD_KEY, Direction, Metadata, Phase, RecordingWriter, Sample, Timing};
use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};

use crate::run::events::{DeviceStatus, FitUpdate, LogLevel, Progress, RunControl, RunEvent, RunPhase};
use crate::run::gauge::{Gauge, GaugeError, GaugeReading};
use crate::run::safety::{LimitViolation, SafetyGuard};
use crate::run::script::{Script, ScriptError};
use outcome::phase_times;
use record::sanitize;
use settle::{mean, std_dev};

/// Internal: why the procedure stopped.
#[derive(Debug)]
struct Halt {
    culprit: Culprit,
    message: String,
}

type Step<T> = Result<T, Halt>;

/// How many of a run's warnings its report keeps (then one line says there were more).
const MAX_KEPT_WARNINGS: usize = 100;

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
    Load {
        rep: u32,
        beta: f64,
    },
    Unload {
        rep: u32,
        left: usize,
    },
    Depth,
    Twist {
        left: usize,
    },
    /// Samples left in the experiment steps.
    Experiment {
        left: usize,
    },
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
    gamma1_bound_mm: f64,
    /// Inward travel of the last stage move: a reading right after a move may
    /// still lag behind the elastomer by up to this much.
    last_inward_mm: f64,
    /// The commanded position of the current stop (NaN before the first move).
    stop_mm: f64,
    /// Where the depth watch backed the current stop off to (`watch.rs`).
    backed_off: Option<watch::BackedOff>,
    /// Back-offs since the last reading within the depth limit.
    backoffs_in_a_row: u32,
    /// Back-offs of the whole run.
    depth_backoffs: u32,
    /// The current stop's latest gamma1 readings (the watch's mean).
    watch_recent: Vec<f64>,
    /// A reading passed the guard's bound, and the log said so.
    bound_passed_said: bool,
    noise: ReadingNoise,
    clock: RigClock,
    /// The recording's file, created at connect (a path that cannot be
    /// written stops the run before anything moves); its header is written
    /// once the contact is found, since it declares how well.
    recording_file: Option<File>,
    writer: Option<RecordingWriter<BufWriter<File>>>,
    samples: Vec<Sample>,
    contact_mm: Option<f64>,
    torsion_beta: Option<f64>,
    twist_zero: f64,
    pause_requested: bool,
    consecutive_timeouts: u32,
    last_fit: Option<FitUpdate>,
    track: Tracking,
    /// The recording's metadata, once written (the closed loop diagnoses the samples so far with it).
    meta: Option<Metadata>,
    adaptive: Vec<AdaptiveStep>,
    /// Every warning the run logged, in order (the report keeps them:
    /// `run.warnings` in report.json).
    warnings: std::sync::Mutex<Vec<String>>,
    /// On the emulated rig: the simulated sensor's indenter mount, through
    /// which the simulation performs an operator step itself (no prompt).
    /// `None` on a real rig: an operator step prompts and waits.
    emulated_operator: Option<sim::sensor::rig::IndenterMount>,
    /// Test facility: an operator step run after the sweeps, as the closed loop runs one it chose.
    forced_operator_step: Option<ExperimentSpec>,
    /// The operator steps' recordings written, in order.
    operator_recordings: Vec<PathBuf>,
    /// The contact while the normal sweep's first samples place it (their
    /// recording waits for the header, which declares the contact).
    pending: Option<PendingContact>,
}

/// The approach's provisional contact, awaiting the sweep's shallow samples.
#[derive(Debug)]
struct PendingContact {
    /// gamma1 above which a reading is in contact, mm.
    threshold: f64,
    /// The first pass's contact uncertainty, if the sweep's samples cannot place it.
    fallback_sd: Option<f64>,
    held: Vec<Held>,
}

/// A settled sample held back until the contact is placed.
#[derive(Debug)]
struct Held {
    stage_mm: f64,
    reading: GaugeReading,
    rep: Option<u32>,
    timing: Timing,
}

/// The sensor's reading noise: measured at rest before the approach, and
/// learnt from settled windows in contact.
#[derive(Debug, Default)]
struct ReadingNoise {
    /// Standard deviation of one gamma1 reading at rest, mm.
    gamma1_mm: f64,
    /// Standard deviation of one theta1 reading at rest, degrees.
    theta1_deg: f64,
    /// (gamma1 mm, theta1 deg) learnt while settled in contact (a sensor may be
    /// noisier pressed than at rest, or report exact zeros out of contact).
    live: Option<(f64, f64)>,
}

/// Rig time, read off the sensor's clock.
#[derive(Debug, Default)]
struct RigClock {
    /// Sensor time of the first reading, s.
    t0: Option<f64>,
    /// Sensor time of the latest reading since `t0`, s.
    t_last: f64,
    /// Where each phase began.
    phase_marks: Vec<(&'static str, f64)>,
    /// The times of the sample being taken (recorded with it, docs/recording-format.md).
    pending: PendingTiming,
}

/// What the next sample's [`Timing`] will say, collected as it happens (rig time, s).
#[derive(Debug, Default)]
struct PendingTiming {
    /// The move timed for the sample: the longest since the last sample
    /// (any stage move before a mount move), as (stage?, distance, start,
    /// end). The smaller moves around it (a depth's corrections, the mount's
    /// return to zero) are not timed: the model holds the sample's pose
    /// after the timed move ends.
    timed: Option<(bool, f64, f64, Option<f64>)>,
    /// The move under way is the timed one, and its first reading is not in yet.
    arriving: bool,
    /// First frame of the mean being recorded.
    frames_from: Option<f64>,
}

impl PendingTiming {
    /// A move of `distance` (mm on the stage, degrees on the mount) starts
    /// after the reading at `t_last`.
    fn moving(&mut self, t_last: f64, stage: bool, distance: f64) {
        let longer = self.timed.is_none_or(|(s, d, _, _)| (stage, distance) >= (s, d));
        if longer {
            self.timed = Some((stage, distance, t_last, None));
        }
        self.arriving = longer;
    }

    /// A reading at `t`: the first after the timed move ends it.
    fn read(&mut self, t: f64) {
        if std::mem::take(&mut self.arriving)
            && let Some(m) = self.timed.as_mut()
        {
            m.3 = Some(t);
        }
    }

    /// A held sample's timing, to be recorded with it.
    fn restore(t: Timing) -> Self {
        Self { timed: t.move_s.map(|(a, b)| (true, 0.0, a, Some(b))), arriving: false, frames_from: t.frames_from_s }
    }

    /// The timing of the sample being recorded; the next one starts afresh.
    fn take(&mut self) -> Timing {
        let t = std::mem::take(self);
        let move_s = t.timed.and_then(|(_, _, a, b)| Some((a, b?))).filter(|(a, b)| b >= a);
        Timing { frames_from_s: t.frames_from, move_s }
    }
}

/// Where the procedure stands, for progress and the estimate of time left.
#[derive(Debug)]
struct Tracking {
    step_index: usize,
    cursor: Cursor,
    /// Load samples of the first normal sweep, once it ended.
    loads_rep0: Option<usize>,
    /// Rig time when the normal sweep began.
    sweep_start: Option<f64>,
    /// What moves and frames cost in rig time, as measured (for the estimate of time left).
    costs: Costs,
    /// Growth of gamma1 with the approach over the first refinement pass's deepest readings.
    gamma1_ratio: Option<f64>,
}

/// Rig time of moves and frames as the run measures them: a move's time runs
/// from the last reading before it to the first after it; short moves are
/// limited by acceleration, so their time grows as the square root of the
/// distance.
#[derive(Debug, Default)]
struct Costs {
    /// (rig time before, mount?, distance) of the move whose end is not yet read.
    open_move: Option<(f64, bool, f64)>,
    /// (sum of move times, sum of sqrt(distance)): stage, mount.
    stage: (f64, f64),
    mount: (f64, f64),
    /// Sum and count of the intervals between consecutive readings.
    frame: (f64, u32),
    last_read_s: Option<f64>,
}

impl Costs {
    fn note_move(&mut self, t_s: f64, mount: bool, distance: f64) {
        self.open_move = (distance > 0.0).then_some((t_s, mount, distance));
    }

    fn note_read(&mut self, t_s: f64) {
        if let Some(prev) = self.last_read_s {
            let dt = t_s - prev;
            if dt > 0.0 && dt < 0.2 && self.open_move.is_none() {
                self.frame.0 += dt;
                self.frame.1 += 1;
            }
        }
        self.last_read_s = Some(t_s);
        if let Some((t0, mount, d)) = self.open_move.take() {
            let acc = if mount { &mut self.mount } else { &mut self.stage };
            acc.0 += (t_s - t0).max(0.0);
            acc.1 += d.sqrt();
        }
    }

    /// Rig time per frame, s.
    fn frame_s(&self) -> Option<f64> {
        (self.frame.1 >= 10).then(|| self.frame.0 / self.frame.1 as f64)
    }

    /// Rig time of a move of `distance` (mm or degrees), s; the mount's
    /// unmeasured yet: a move of a twentieth of the stage's rate.
    fn move_s(&self, mount: bool, distance: f64) -> Option<f64> {
        let per = |a: (f64, f64)| (a.1 > 0.0).then(|| a.0 / a.1);
        let c =
            if mount { per(self.mount).or_else(|| per(self.stage).map(|c| c / 20f64.sqrt())) } else { per(self.stage) };
        c.map(|c| c * distance.abs().sqrt())
    }
}

/// The message a caught panic carried (`&str` or `String` payloads), or
/// "no message".
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "no message".to_string())
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
            gamma1_bound_mm: f64::NAN,
            last_inward_mm: 0.0,
            stop_mm: f64::NAN,
            backed_off: None,
            backoffs_in_a_row: 0,
            depth_backoffs: 0,
            watch_recent: Vec::with_capacity(watch::WATCH_READINGS),
            bound_passed_said: false,
            noise: ReadingNoise::default(),
            clock: RigClock::default(),
            recording_file: None,
            writer: None,
            samples: Vec::new(),
            contact_mm: None,
            torsion_beta: None,
            twist_zero: 0.0,
            pause_requested: false,
            consecutive_timeouts: 0,
            last_fit: None,
            track: Tracking {
                step_index: 0,
                cursor: Cursor::Setup,
                loads_rep0: None,
                sweep_start: None,
                costs: Costs::default(),
                gamma1_ratio: None,
            },
            meta: None,
            adaptive: Vec::new(),
            warnings: std::sync::Mutex::new(Vec::new()),
            emulated_operator: None,
            forced_operator_step: None,
            operator_recordings: Vec::new(),
            pending: None,
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

    /// The emulated rig's indenter mount: operator-assisted steps are then
    /// performed by the simulation (it mounts the step's indenter) instead of
    /// prompting an operator.
    pub fn with_emulated_operator(mut self, mount: sim::sensor::rig::IndenterMount) -> Self {
        self.emulated_operator = Some(mount);
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

    /// Test facility (tests/operator_step.rs): after the sweeps and the
    /// script's experiments, run the operator step `spec` as the closed loop
    /// runs one it chose (retract, prompt or simulated mount, its sweep to a
    /// recording of its own, retract), whatever a diagnosis would say.
    #[doc(hidden)]
    pub fn with_forced_operator_step(mut self, spec: Option<ExperimentSpec>) -> Self {
        self.forced_operator_step = spec;
        self
    }

    /// The recordings of the operator steps this run took, in order.
    pub fn operator_recordings(&self) -> &[PathBuf] {
        &self.operator_recordings
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
        6 + self.script.normal.repeats as usize + self.script.experiment.len() + usize::from(self.torsion_at_top())
    }

    /// The torsion sweep runs at the top of the last loading branch (the
    /// unloading after it) unless experiment steps or the closed loop follow
    /// it: they start at the torsion depth.
    fn torsion_at_top(&self) -> bool {
        self.script.experiment.is_empty() && !self.script.adaptive.enabled
    }

    fn emit(&self, ev: RunEvent) {
        if let Some(tx) = &self.events {
            let _ = tx.send(ev);
        }
    }

    fn log(&self, level: LogLevel, message: impl Into<String>) {
        let message = message.into();
        if level == LogLevel::Warn
            && let Ok(mut w) = self.warnings.lock()
        {
            // A sensor that drops out again and again could warn for every
            // stop: the report keeps the first ones and counts the rest.
            match w.len() {
                n if n < MAX_KEPT_WARNINGS => w.push(message.clone()),
                n if n == MAX_KEPT_WARNINGS => w.push("(more warnings: see the run's log)".to_string()),
                _ => {}
            }
        }
        self.emit(RunEvent::Log { level, message });
    }

    fn step(&mut self, index: usize, name: impl Into<String>, phase: RunPhase) {
        self.track.step_index = index;
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
                let what = panic_message(panic.as_ref());
                let halt = Halt { culprit: Culprit::Internal, message: format!("internal error (panic): {what}") };
                RunStatus::Aborted(self.abort(halt).await)
            }
        };
        RunOutcome {
            recording: self.recording_path.clone(),
            samples: self.samples.len(),
            rig_time_s: self.clock.t_last,
            wall_time_s: wall.elapsed().as_secs_f64(),
            contact_mm: self.contact_mm,
            noise_gamma1_mm: (self.noise.gamma1_mm > 0.0).then_some(self.noise.gamma1_mm),
            torsion_beta: self.torsion_beta,
            phase_rig_time_s: phase_times(&self.clock.phase_marks, self.clock.t_last),
            adaptive: self.adaptive.clone(),
            warnings: self.warnings.lock().map(|w| w.clone()).unwrap_or_default(),
            status,
        }
    }

    async fn procedure(&mut self) -> Step<()> {
        self.step(0, "connect and identify", RunPhase::Setup);
        self.connect().await?;
        self.step(1, "home", RunPhase::Setup);
        self.mark_phase("homing").await?;
        let rest = self.home_and_start().await?;
        self.step(2, "approach and find contact", RunPhase::Approach);
        self.mark_phase("approach").await?;
        self.approach(rest).await?;
        let reps = self.script.normal.repeats;
        let at_top = self.torsion_at_top();
        let mut path = Vec::new();
        for rep in 0..reps {
            self.step(3 + rep as usize, format!("normal sweep {}/{}", rep + 1, reps), RunPhase::Normal);
            if rep == 0 {
                self.mark_phase("normal").await?;
            }
            self.device_status().await?;
            path = self.normal_load(rep).await?;
            if !(at_top && rep + 1 == reps) {
                self.normal_unload(rep, &path).await?;
            }
        }
        let mut base = 3 + reps as usize;
        self.mark_phase("torsion").await?;
        if at_top {
            self.step(base, "hold the torsion depth", RunPhase::Torsion);
            self.hold_depth(&path).await?;
        } else {
            self.step(base, "return to torsion depth", RunPhase::Torsion);
            let crossing = self.load_crossing_of(&path)?;
            self.torsion_depth(crossing).await?;
        }
        self.step(base + 1, "torsion sweep", RunPhase::Torsion);
        self.device_status().await?;
        self.torsion_sweep().await?;
        if at_top {
            base += 1;
            self.step(base + 1, format!("normal unload {reps}/{reps}"), RunPhase::Normal);
            self.mark_phase("normal").await?;
            self.normal_unload(reps - 1, &path).await?;
        }
        let experiments = self.script.experiment.clone();
        if !experiments.is_empty() {
            self.mark_phase("experiments").await?;
        }
        for (i, spec) in experiments.iter().enumerate() {
            let phase = if spec.phase().kind() == Phase::Torsion { RunPhase::Torsion } else { RunPhase::Normal };
            self.step(base + 2 + i, format!("experiment {}/{}: {}", i + 1, experiments.len(), spec.name()), phase);
            self.device_status().await?;
            self.experiment(&experiments[i..]).await?;
        }
        if let Some(spec) = self.forced_operator_step {
            self.operator_step(spec).await?;
        }
        if self.script.adaptive.enabled {
            self.adaptive_loop().await?;
        }
        self.step(base + 2 + experiments.len(), "retract", RunPhase::Retract);
        self.mark_phase("retract").await?;
        self.retract().await?;
        self.mark_end().await;
        self.track.cursor = Cursor::Done;
        self.progress();
        self.log(
            LogLevel::Info,
            format!("run complete: {} samples in {}", self.samples.len(), self.recording_path.display()),
        );
        Ok(())
    }
}
