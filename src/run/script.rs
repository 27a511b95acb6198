//! The calibration script: what the sequencer does, as TOML. Every section and
//! key is optional (missing ones take the built-in default), unknown keys are
//! errors so a typo cannot silently fall back to a default.
//!
//! Positions are absolute stage positions after homing (mm, increasing towards
//! the sensor) and mount angles after homing (degrees).

use std::time::Duration;

use serde::{Deserialize, Serialize};
use sim::experiment::ExperimentSpec;
use sim::physics::{Body, Layer, LayerBase};

/// The built-in script, as `easycalib script --default` prints it.
pub const DEFAULT_SCRIPT_TOML: &str = r#"# easycalib calibration script (TOML). Every key is optional; a missing key
# takes the value shown here. Stage positions are absolute after homing, in mm,
# increasing towards the sensor; mount angles are degrees after homing.

# The calibration indenter (standard elastic hemisphere): E2, nu2, R2.
[indenter]
e_mpa = 1.1
nu = 0.39
r_mm = 5.0

# The sensor: effective radius R1 of its elastomer (inf for flat) and an
# optional name for the recording (the gauge's own description otherwise).
# A gel layer from the sensor's datasheet goes here too and into the
# recording, so the fit models it: elastomer_thickness_mm, elastomer_base
# ("bonded" or "sliding"; bonded by default) and elastomer_thickness_tol_mm
# (optional, one standard deviation). Absent: a half-space.
[sensor]
elastomer_r_mm = 33.0

# Approach: travel fast to start_mm (known to be clear of the sensor), estimate
# the gamma1 noise from noise_readings untouched readings, then step in by
# search_step_mm until gamma1 rises above contact_sigmas x noise (at least
# contact_min_mm). The contact point is then refined: the stage steps on (at
# most refine_steps steps of refine_step_mm) until gamma1 reaches
# refine_to_gamma1_mm, and a line through the settled readings with gamma1 in
# [refine_from_gamma1_mm, refine_to_gamma1_mm] is extrapolated to gamma1 = 0.
# Those deep readings teach the sensing the contact's shape; the stage then
# steps in again by step_mm from just above that point, and the line through the settled
# readings below refine_from_gamma1_mm (where gamma1 bends least) gives the
# contact point, and its uncertainty to the recording (every gamma2 of the
# paper's method hangs on it). The normal sweep starts pre_contact_mm before
# the contact.
[approach]
start_mm = 10.0
search_step_mm = 0.5
refine_step_mm = 0.2
step_mm = 0.05
noise_readings = 20
contact_sigmas = 6.0
contact_min_mm = 0.005
refine_steps = 20
refine_from_gamma1_mm = 0.25
refine_to_gamma1_mm = 0.5
pre_contact_mm = 0.15

# Normal sweep: step in by step_mm until the live depth
# beta = gamma2 / R2 = (approach - gamma1) / R2 reaches target_beta (the last
# step is shortened to land on it), then step back out by unload_step_mm to
# the last stop in contact (0: through the loading positions); repeated `repeats` times. Each sample
# averages `frames` settled frames (0: the settling's last two windows, see
# [settle]). A move costs as much rig time as many frames, so the sweep takes
# few, long samples (docs/run.md, "The sweeps' design"). Below gamma1 =
# approach.refine_to_gamma1_mm the steps are approach.step_mm (they pin the
# contact point), and where gamma1 lies in the paper's window (0.2-0.8 mm)
# they are window_step_mm (the paper's method fits only those samples; 0: the
# same steps everywhere); those samples take the settling's own frames.
[normal]
step_mm = 1.3
window_step_mm = 0.1
unload_step_mm = 1.0
target_beta = 0.2
repeats = 1
frames = 30

# Torsion sweep at target_beta: twist out to amplitude_deg in step_deg steps
# and back to 0. The torsion samples carry most of what the fit knows of E1,
# and much of nu1; a sample's information on the twist stiffness grows as the
# square of its twist, so a stop at twist x averages
# frames x (x / amplitude_deg)^frames_power settled frames (at least the
# settling's own; frames_power 0: `frames` everywhere). Without experiment
# steps or the closed loop, the sweep runs at the top of the loading branch,
# before the unloading.
[torsion]
amplitude_deg = 8.0
step_deg = 2.0
frames = 200
frames_power = 3.0

# Soft limits, checked before every move. Inside [stage_min_mm, start_mm] the
# indenter is clear of the sensor; deeper, a move is refused if gamma1 could
# exceed max_gamma1_mm. Twist is limited to +-max_twist_deg from the torsion
# start. On abort the stage backs off to retract_mm; a completed run leaves
# it at park_mm (inside the clear zone; default approach.start_mm, where the
# next run's approach starts).
[limits]
stage_min_mm = 0.0
stage_max_mm = 24.0
max_gamma1_mm = 5.0
max_twist_deg = 10.0
retract_mm = 0.0
# park_mm = 10.0

# Adaptive settling after every move: read until the mean of the last
# `readings` readings differs from the mean of the `readings` before by at most
# tol_gamma1_mm / tol_theta1_deg (each raised to 3 noise standard errors when
# the measured noise is larger), or until timeout_s of sensor time has passed.
[settle]
readings = 2
tol_gamma1_mm = 0.001
tol_theta1_deg = 0.01
timeout_s = 5.0
# A stop that averages more frames than this records them as consecutive
# samples of at most this many: replicates at one place, the same information,
# and more residuals to judge the fit by (0: one sample a stop).
max_sample_frames = 10

# Real-time limits: one sensor read, the sensor dropout (consecutive read
# timeouts adding up to this abort the run), one move, one homing.
[timeouts]
read_s = 0.5
sensor_dropout_s = 2.0
move_s = 60.0
home_s = 120.0

# Experiment steps after the torsion sweep, in order (none by default; see
# docs/experiments.md). Dwell and reload act at the depth where the rig stands.
# [[experiment]]
# kind = "dwell"              # hold, one sample every every_s
# hold_s = 30.0
# every_s = 2.0
# [[experiment]]
# kind = "reload"             # unload to fraction of the travel past contact, load back
# fraction = 0.5
# steps = 4
# cycles = 1
# [[experiment]]
# kind = "twist_reversal"     # twist to +amplitude, to -amplitude, back to 0
# amplitude_deg = 4.0
# step_deg = 0.5
# [[experiment]]
# kind = "torsion_at_depth"   # torsion sweep at a second depth
# beta = 0.1
# amplitude_deg = 8.0
# step_deg = 0.5
# [[experiment]]
# kind = "slow_repeat"        # unload to fraction, load back waiting dwell_s at each stop
# fraction = 0.5
# steps = 3
# dwell_s = 8.0
# [[experiment]]
# kind = "approach_speed"     # unload to fraction, load back at speed_mm_s (restored after)
# fraction = 0.5
# steps = 4
# speed_mm_s = 0.1

# Closed loop (docs/experiments.md): after the sweeps and the experiment steps,
# while the diagnosis of the recording so far leaves explanations standing,
# run the experiment `easycalib plan` chooses when it is decisive, within
# budget_s of rig time and max_steps experiments. `run --adaptive` turns it on.
# operator = false (`run --no-operator`) forbids operator-assisted steps
# (a rigid ball or a second indenter, mounted by someone at a prompt).
[adaptive]
enabled = false
budget_s = 120.0
max_steps = 3
operator = true
"#;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Script {
    pub indenter: Body,
    pub sensor: SensorSection,
    pub approach: ApproachSection,
    pub normal: NormalSection,
    pub torsion: TorsionSection,
    pub limits: LimitsSection,
    pub settle: SettleSection,
    pub timeouts: TimeoutsSection,
    /// Experiment steps after the torsion sweep, in order (`[[experiment]]`, docs/experiments.md).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub experiment: Vec<ExperimentSpec>,
    pub adaptive: AdaptiveSection,
}

/// The closed loop after the experiment steps (docs/experiments.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptiveSection {
    pub enabled: bool,
    /// Rig time the loop may spend on experiments, s.
    pub budget_s: f64,
    /// Most experiments the loop runs.
    pub max_steps: u32,
    /// The loop may choose operator-assisted steps (a rigid ball, a second
    /// indenter): on a real rig they prompt and wait for the operator's
    /// confirmation; on the emulated rig the simulation mounts the indenter.
    pub operator: bool,
}

impl Default for AdaptiveSection {
    fn default() -> Self {
        Self { enabled: false, budget_s: 120.0, max_steps: 3, operator: true }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorSection {
    /// Effective radius R1 of the elastomer, mm (`inf` for flat).
    #[serde(with = "radius")]
    pub elastomer_r_mm: f64,
    pub name: Option<String>,
    /// The gel layer's thickness from the sensor's datasheet, mm (absent: a half-space).
    pub elastomer_thickness_mm: Option<f64>,
    /// How the layer sits on its window: `bonded` (default) or `sliding`.
    pub elastomer_base: Option<String>,
    /// The thickness's uncertainty, mm (one standard deviation).
    pub elastomer_thickness_tol_mm: Option<f64>,
}

impl SensorSection {
    /// The declared layer, checked: each fault names its key.
    pub fn layer(&self) -> Result<Option<Layer>, ScriptError> {
        let Some(h) = self.elastomer_thickness_mm else {
            if self.elastomer_base.is_some() {
                return Err(invalid("sensor.elastomer_base", "is given without sensor.elastomer_thickness_mm"));
            }
            if self.elastomer_thickness_tol_mm.is_some() {
                return Err(invalid(
                    "sensor.elastomer_thickness_tol_mm",
                    "is given without sensor.elastomer_thickness_mm",
                ));
            }
            return Ok(None);
        };
        positive("sensor.elastomer_thickness_mm", h)?;
        let base = match self.elastomer_base.as_deref() {
            None => LayerBase::Bonded,
            Some(b) => LayerBase::parse(b).ok_or_else(|| {
                invalid("sensor.elastomer_base", format!("must be \"bonded\" or \"sliding\", got \"{b}\""))
            })?,
        };
        let layer = Layer { thickness_mm: h, base, thickness_tol_mm: self.elastomer_thickness_tol_mm };
        layer.validate().map_err(|e| invalid("sensor.elastomer_thickness_tol_mm", e.to_string()))?;
        Ok(Some(layer))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ApproachSection {
    pub start_mm: f64,
    /// Step of the search for first contact, mm.
    pub search_step_mm: f64,
    /// Step of the first refinement pass, mm (the second steps by `step_mm`).
    pub refine_step_mm: f64,
    pub step_mm: f64,
    pub noise_readings: usize,
    pub contact_sigmas: f64,
    pub contact_min_mm: f64,
    pub refine_steps: usize,
    pub refine_from_gamma1_mm: f64,
    pub refine_to_gamma1_mm: f64,
    pub pre_contact_mm: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NormalSection {
    pub step_mm: f64,
    /// Step while gamma1 is in the paper's window (fit::regression::PAPER_WINDOW_MM),
    /// mm, when finer than `step_mm`; 0: `step_mm` everywhere.
    pub window_step_mm: f64,
    /// Step of the unloading branch, mm; 0: the loading positions in reverse.
    pub unload_step_mm: f64,
    pub target_beta: f64,
    pub repeats: u32,
    /// Settled frames averaged into each sample (0: the settling's last two windows).
    pub frames: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TorsionSection {
    pub amplitude_deg: f64,
    pub step_deg: f64,
    /// Settled frames averaged into a sample at the full amplitude (0: the settling's last two windows).
    pub frames: usize,
    /// A sample at twist x averages `frames` (x / amplitude)^frames_power frames (0: `frames` everywhere).
    pub frames_power: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LimitsSection {
    pub stage_min_mm: f64,
    pub stage_max_mm: f64,
    pub max_gamma1_mm: f64,
    pub max_twist_deg: f64,
    pub retract_mm: f64,
    /// Where a completed run leaves the stage (None: `approach.start_mm`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub park_mm: Option<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SettleSection {
    pub readings: usize,
    pub tol_gamma1_mm: f64,
    pub tol_theta1_deg: f64,
    pub timeout_s: f64,
    /// Frames of one sample at most; a stop averaging more records several (0: one sample a stop).
    pub max_sample_frames: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TimeoutsSection {
    pub read_s: f64,
    pub sensor_dropout_s: f64,
    pub move_s: f64,
    pub home_s: f64,
}

/// TOML has no `inf` literal that every writer emits the same way; accept a
/// number or the strings "inf"/"flat", write `inf` as the string "inf".
mod radius {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(r: &f64, s: S) -> Result<S::Ok, S::Error> {
        if r.is_infinite() { s.serialize_str("inf") } else { s.serialize_f64(*r) }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum R {
            Num(f64),
            Int(i64),
            Text(String),
        }
        match R::deserialize(d)? {
            R::Num(x) => Ok(x),
            R::Int(i) => Ok(i as f64),
            R::Text(t) if t.eq_ignore_ascii_case("inf") || t.eq_ignore_ascii_case("flat") => Ok(f64::INFINITY),
            R::Text(t) => Err(serde::de::Error::custom(format!("`{t}` is not a radius (a number, or \"inf\")"))),
        }
    }
}

impl Default for SensorSection {
    fn default() -> Self {
        Self {
            elastomer_r_mm: sim::defaults::ELASTOMER_R_MM,
            name: None,
            elastomer_thickness_mm: None,
            elastomer_base: None,
            elastomer_thickness_tol_mm: None,
        }
    }
}
impl Default for ApproachSection {
    fn default() -> Self {
        Self {
            start_mm: 10.0,
            search_step_mm: 0.5,
            refine_step_mm: 0.2,
            step_mm: 0.05,
            noise_readings: 20,
            contact_sigmas: 6.0,
            contact_min_mm: 0.005,
            refine_steps: 20,
            refine_from_gamma1_mm: 0.25,
            refine_to_gamma1_mm: 0.5,
            pre_contact_mm: 0.15,
        }
    }
}
impl Default for NormalSection {
    fn default() -> Self {
        Self { step_mm: 1.3, window_step_mm: 0.1, unload_step_mm: 1.0, target_beta: 0.2, repeats: 1, frames: 30 }
    }
}
impl Default for TorsionSection {
    fn default() -> Self {
        Self { amplitude_deg: 8.0, step_deg: 2.0, frames: 200, frames_power: 3.0 }
    }
}
impl Default for LimitsSection {
    fn default() -> Self {
        Self {
            stage_min_mm: 0.0,
            stage_max_mm: 24.0,
            max_gamma1_mm: 5.0,
            max_twist_deg: 10.0,
            retract_mm: 0.0,
            park_mm: None,
        }
    }
}
impl Default for SettleSection {
    fn default() -> Self {
        Self { readings: 2, tol_gamma1_mm: 0.001, tol_theta1_deg: 0.01, timeout_s: 5.0, max_sample_frames: 10 }
    }
}
impl Default for TimeoutsSection {
    fn default() -> Self {
        Self { read_s: 0.5, sensor_dropout_s: 2.0, move_s: 60.0, home_s: 120.0 }
    }
}
impl Default for Script {
    fn default() -> Self {
        Self {
            indenter: sim::defaults::indenter(),
            sensor: SensorSection::default(),
            approach: ApproachSection::default(),
            normal: NormalSection::default(),
            torsion: TorsionSection::default(),
            limits: LimitsSection::default(),
            settle: SettleSection::default(),
            timeouts: TimeoutsSection::default(),
            experiment: Vec::new(),
            adaptive: AdaptiveSection::default(),
        }
    }
}

/// Why a script was refused; `field` is the TOML path of the offending key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScriptError {
    #[error("script is not valid TOML for easycalib: {0}")]
    Parse(#[from] toml::de::Error),
    #[error("script is not valid TOML for easycalib: {0}")]
    Encode(#[source] toml::ser::Error),
    #[error("script `{field}`: {message}")]
    Invalid { field: &'static str, message: String },
}

/// Bounds of every count, step and duration (docs/hardening.md): beyond them a
/// value is a typo, and would cost hours of rig time or a panic after homing.
pub const MAX_DURATION_S: f64 = 3600.0;
pub const MAX_READINGS: usize = 10_000;
pub const MAX_STEPS: f64 = 20_000.0;
pub const MIN_STEP_MM: f64 = 1e-4;

/// A validated duration in seconds as a `Duration` (clamped: never panics).
fn duration(s: f64) -> Duration {
    Duration::from_secs_f64(if s.is_finite() { s.clamp(0.0, MAX_DURATION_S) } else { MAX_DURATION_S })
}

fn invalid(field: &'static str, message: impl Into<String>) -> ScriptError {
    ScriptError::Invalid { field, message: message.into() }
}

fn positive(field: &'static str, x: f64) -> Result<(), ScriptError> {
    if x.is_finite() && x > 0.0 { Ok(()) } else { Err(invalid(field, format!("must be a finite number > 0, got {x}"))) }
}

fn finite(field: &'static str, x: f64) -> Result<(), ScriptError> {
    if x.is_finite() { Ok(()) } else { Err(invalid(field, format!("must be finite, got {x}"))) }
}

impl Script {
    /// Parse and validate a script.
    pub fn from_toml(text: &str) -> Result<Script, ScriptError> {
        let s: Script = toml::from_str(text)?;
        s.validate()?;
        Ok(s)
    }

    pub fn to_toml(&self) -> Result<String, ScriptError> {
        toml::to_string_pretty(self).map_err(ScriptError::Encode)
    }

    /// Refuse scripts that are inconsistent in themselves (device travel is
    /// checked when the devices are connected).
    /// The sections are checked in the order of the file; the first fault is reported.
    pub fn validate(&self) -> Result<(), ScriptError> {
        self.indenter.validate("indenter").map_err(|e| invalid("indenter", e.to_string()))?;
        let r1 = self.sensor.elastomer_r_mm;
        if r1.is_nan() || r1 <= 0.0 {
            return Err(invalid("sensor.elastomer_r_mm", format!("must be > 0 (or \"inf\"), got {r1}")));
        }
        self.sensor.layer()?;
        self.validate_approach()?;
        self.validate_normal()?;
        self.validate_torsion()?;
        self.validate_limits()?;
        self.validate_timing()?;
        let a = &self.adaptive;
        if !(a.budget_s.is_finite() && a.budget_s > 0.0 && a.budget_s <= MAX_DURATION_S) {
            return Err(invalid(
                "adaptive.budget_s",
                format!("must lie in (0, {MAX_DURATION_S}] s, got {}", a.budget_s),
            ));
        }
        if a.max_steps > 20 {
            return Err(invalid("adaptive.max_steps", format!("must be <= 20, got {}", a.max_steps)));
        }
        for (i, e) in self.experiment.iter().enumerate() {
            e.validate(i, self.limits.max_twist_deg).map_err(|e| invalid("experiment", e.to_string()))?;
            if e.is_operator() {
                return Err(invalid(
                    "experiment",
                    format!(
                        "experiment {i} ({}) needs an operator to swap the indenter: only the closed loop \
                         (`run --adaptive`) runs it, with its prompt; or take its sweep as a recording of its own \
                         (docs/experiments.md)",
                        e.name()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// `[approach]`: steps, contact detection, the refinement window (the
    /// number of moves is bounded against the `[limits]` stage window).
    fn validate_approach(&self) -> Result<(), ScriptError> {
        let a = &self.approach;
        finite("approach.start_mm", a.start_mm)?;
        positive("approach.step_mm", a.step_mm)?;
        positive("approach.search_step_mm", a.search_step_mm)?;
        // A refine step finer than step_mm is taken as step_mm (a script older than the key keeps working).
        positive("approach.refine_step_mm", a.refine_step_mm)?;
        if a.search_step_mm < a.step_mm {
            return Err(invalid(
                "approach.search_step_mm",
                format!("{} mm is finer than approach.step_mm {} mm", a.search_step_mm, a.step_mm),
            ));
        }
        positive("approach.contact_sigmas", a.contact_sigmas)?;
        positive("approach.contact_min_mm", a.contact_min_mm)?;
        if !(3..=MAX_READINGS).contains(&a.noise_readings) {
            return Err(invalid(
                "approach.noise_readings",
                format!("must be 3..={MAX_READINGS}, got {}", a.noise_readings),
            ));
        }
        // Step sizes bounded below through the number of moves they imply.
        let approach_steps =
            (a.start_mm - self.limits.stage_min_mm).abs().max(self.limits.stage_max_mm - a.start_mm) / a.step_mm;
        if approach_steps.is_nan() || approach_steps > MAX_STEPS || a.step_mm < MIN_STEP_MM {
            return Err(invalid(
                "approach.step_mm",
                format!(
                    "{} mm gives up to {approach_steps:.0} moves across the stage window (limit {MAX_STEPS:.0}, \
                     smallest step {MIN_STEP_MM} mm)",
                    a.step_mm
                ),
            ));
        }
        if a.refine_steps > MAX_READINGS {
            return Err(invalid("approach.refine_steps", format!("must be <= {MAX_READINGS}, got {}", a.refine_steps)));
        }
        if !(a.refine_from_gamma1_mm.is_finite()
            && a.refine_from_gamma1_mm >= 0.0
            && a.refine_to_gamma1_mm > a.refine_from_gamma1_mm)
        {
            return Err(invalid(
                "approach.refine_to_gamma1_mm",
                format!(
                    "the refinement window [{}, {}] mm must be non-empty and >= 0",
                    a.refine_from_gamma1_mm, a.refine_to_gamma1_mm
                ),
            ));
        }
        if !(a.pre_contact_mm.is_finite() && a.pre_contact_mm >= 0.0) {
            return Err(invalid("approach.pre_contact_mm", format!("must be >= 0, got {}", a.pre_contact_mm)));
        }
        Ok(())
    }

    /// `[normal]`: step (bounded through the moves across the stage window), depth, repeats.
    fn validate_normal(&self) -> Result<(), ScriptError> {
        let n = &self.normal;
        positive("normal.step_mm", n.step_mm)?;
        let normal_steps = (self.limits.stage_max_mm - self.limits.stage_min_mm) / n.step_mm;
        if normal_steps.is_nan() || normal_steps > MAX_STEPS || n.step_mm < MIN_STEP_MM {
            return Err(invalid(
                "normal.step_mm",
                format!(
                    "{} mm gives up to {normal_steps:.0} steps across the stage window (limit {MAX_STEPS:.0}, smallest \
                     step {MIN_STEP_MM} mm)",
                    n.step_mm
                ),
            ));
        }
        if !(n.target_beta > 0.0 && n.target_beta <= 0.3) {
            return Err(invalid("normal.target_beta", format!("must lie in (0, 0.3], got {}", n.target_beta)));
        }
        if !(n.window_step_mm == 0.0 || (n.window_step_mm.is_finite() && n.window_step_mm >= MIN_STEP_MM)) {
            return Err(invalid(
                "normal.window_step_mm",
                format!("must be 0 (off) or at least {MIN_STEP_MM} mm, got {}", n.window_step_mm),
            ));
        }
        if !(n.unload_step_mm == 0.0 || (n.unload_step_mm.is_finite() && n.unload_step_mm >= MIN_STEP_MM)) {
            return Err(invalid(
                "normal.unload_step_mm",
                format!("must be 0 (the loading positions) or at least {MIN_STEP_MM} mm, got {}", n.unload_step_mm),
            ));
        }
        if n.unload_step_mm > 0.0
            && (self.limits.stage_max_mm - self.limits.stage_min_mm) / n.unload_step_mm > MAX_STEPS
        {
            return Err(invalid(
                "normal.unload_step_mm",
                format!("more than {MAX_STEPS:.0} steps across the stage window"),
            ));
        }
        if n.repeats == 0 || n.repeats > 100 {
            return Err(invalid("normal.repeats", format!("must be 1..=100, got {}", n.repeats)));
        }
        if n.frames > MAX_READINGS {
            return Err(invalid("normal.frames", format!("must be <= {MAX_READINGS}, got {}", n.frames)));
        }
        Ok(())
    }

    /// `[torsion]`: amplitude and step.
    fn validate_torsion(&self) -> Result<(), ScriptError> {
        let t = &self.torsion;
        positive("torsion.amplitude_deg", t.amplitude_deg)?;
        positive("torsion.step_deg", t.step_deg)?;
        if t.amplitude_deg / t.step_deg > 10_000.0 {
            return Err(invalid("torsion.step_deg", "more than 10000 steps per half sweep"));
        }
        if t.frames > MAX_READINGS {
            return Err(invalid("torsion.frames", format!("must be <= {MAX_READINGS}, got {}", t.frames)));
        }
        if !(t.frames_power.is_finite() && (0.0..=4.0).contains(&t.frames_power)) {
            return Err(invalid("torsion.frames_power", format!("must lie in [0, 4], got {}", t.frames_power)));
        }
        Ok(())
    }

    /// `[limits]`, and the approach start, retract position and twist amplitude against them.
    fn validate_limits(&self) -> Result<(), ScriptError> {
        let (l, a, t) = (&self.limits, &self.approach, &self.torsion);
        finite("limits.stage_min_mm", l.stage_min_mm)?;
        finite("limits.stage_max_mm", l.stage_max_mm)?;
        finite("limits.retract_mm", l.retract_mm)?;
        positive("limits.max_gamma1_mm", l.max_gamma1_mm)?;
        positive("limits.max_twist_deg", l.max_twist_deg)?;
        if l.stage_min_mm >= l.stage_max_mm {
            return Err(invalid(
                "limits.stage_max_mm",
                format!("{} must exceed stage_min_mm {}", l.stage_max_mm, l.stage_min_mm),
            ));
        }
        for (field, x) in [("limits.retract_mm", l.retract_mm), ("approach.start_mm", a.start_mm)] {
            if !(l.stage_min_mm..=l.stage_max_mm).contains(&x) {
                return Err(invalid(
                    field,
                    format!("{x} mm lies outside the stage window [{}, {}] mm", l.stage_min_mm, l.stage_max_mm),
                ));
            }
        }
        if let Some(park) = l.park_mm
            && !(park.is_finite() && l.stage_min_mm <= park && park <= a.start_mm)
        {
            return Err(invalid(
                "limits.park_mm",
                format!(
                    "{park} mm lies outside the clear zone [{}, {}] mm (stage_min_mm to approach.start_mm)",
                    l.stage_min_mm, a.start_mm
                ),
            ));
        }
        if l.retract_mm > a.start_mm {
            return Err(invalid(
                "limits.retract_mm",
                format!("{} mm is deeper than the clear approach start {} mm", l.retract_mm, a.start_mm),
            ));
        }
        if t.amplitude_deg > l.max_twist_deg {
            return Err(invalid(
                "torsion.amplitude_deg",
                format!("{} exceeds limits.max_twist_deg {}", t.amplitude_deg, l.max_twist_deg),
            ));
        }
        Ok(())
    }

    /// `[settle]` and `[timeouts]`: counts, tolerances, and every duration under an hour.
    fn validate_timing(&self) -> Result<(), ScriptError> {
        let s = &self.settle;
        if !(1..=100).contains(&s.readings) {
            return Err(invalid("settle.readings", format!("must be 1..=100, got {}", s.readings)));
        }
        positive("settle.tol_gamma1_mm", s.tol_gamma1_mm)?;
        if s.max_sample_frames > MAX_READINGS {
            return Err(invalid(
                "settle.max_sample_frames",
                format!("must be <= {MAX_READINGS}, got {}", s.max_sample_frames),
            ));
        }
        positive("settle.tol_theta1_deg", s.tol_theta1_deg)?;
        positive("settle.timeout_s", s.timeout_s)?;
        let o = &self.timeouts;
        for (key, v) in [
            ("settle.timeout_s", s.timeout_s),
            ("timeouts.read_s", o.read_s),
            ("timeouts.sensor_dropout_s", o.sensor_dropout_s),
            ("timeouts.move_s", o.move_s),
            ("timeouts.home_s", o.home_s),
        ] {
            positive(key, v)?;
            if v > MAX_DURATION_S {
                return Err(invalid(key, format!("{v} s exceeds the limit of {MAX_DURATION_S} s (one hour)")));
            }
        }
        Ok(())
    }

    pub fn read_timeout(&self) -> Duration {
        // validate() bounds every duration; the clamp keeps a caller that skipped it from panicking.
        duration(self.timeouts.read_s)
    }
    pub fn move_timeout(&self) -> Duration {
        duration(self.timeouts.move_s)
    }
    pub fn home_timeout(&self) -> Duration {
        duration(self.timeouts.home_s)
    }
    /// Consecutive read timeouts that make a sensor dropout.
    pub fn dropout_reads(&self) -> u32 {
        (self.timeouts.sensor_dropout_s / self.timeouts.read_s).ceil().max(1.0) as u32
    }
    /// Where a completed run leaves the stage: `limits.park_mm`, else `approach.start_mm`.
    pub fn park_mm(&self) -> f64 {
        self.limits.park_mm.unwrap_or(self.approach.start_mm)
    }

    /// Settled frames of a torsion sample at `twist_deg` from the start (0: the settling's own).
    pub fn twist_frames(&self, twist_deg: f64) -> usize {
        let t = &self.torsion;
        if t.frames_power == 0.0 {
            return t.frames;
        }
        let share = (twist_deg.abs() / t.amplitude_deg).min(1.0).powf(t.frames_power);
        (t.frames as f64 * share).round() as usize
    }

    /// The frames of the samples one stop averaging `frames` records: parts
    /// of at most `settle.max_sample_frames` (near equal), or `[frames]`
    /// when that is 0 or `frames` fits.
    pub fn sample_parts(&self, frames: usize) -> Vec<usize> {
        let max = self.settle.max_sample_frames;
        if max == 0 || frames <= max {
            return vec![frames];
        }
        let parts = frames.div_ceil(max);
        (0..parts).map(|i| frames / parts + usize::from(i < frames % parts)).collect()
    }

    /// Samples the torsion sweep records (its stops' replicates counted).
    pub fn twist_samples(&self) -> usize {
        self.twist_angles().iter().map(|a| self.sample_parts(self.twist_frames(*a)).len()).sum()
    }

    /// Twist positions of the torsion sweep relative to its start: out, then back to 0.
    pub fn twist_angles(&self) -> Vec<f64> {
        let n = (self.torsion.amplitude_deg / self.torsion.step_deg).round().max(1.0) as usize;
        let step = self.torsion.amplitude_deg / n as f64;
        (0..=n).chain((0..n).rev()).map(|i| i as f64 * step).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_text_is_the_default_script() {
        let parsed = Script::from_toml(DEFAULT_SCRIPT_TOML).unwrap();
        assert_eq!(parsed, Script::default());
        // And the serializer's output reads back to the same script.
        let again = Script::from_toml(&parsed.to_toml().unwrap()).unwrap();
        assert_eq!(again, parsed);
    }

    #[test]
    fn the_sensors_gel_layer_is_declared_in_the_sensor_section() {
        let s = Script::from_toml(
            "[sensor]\nelastomer_r_mm = \"inf\"\nelastomer_thickness_mm = 5.0\nelastomer_thickness_tol_mm = 0.1\n",
        )
        .unwrap();
        let layer = s.sensor.layer().unwrap().unwrap();
        assert_eq!((layer.thickness_mm, layer.base, layer.thickness_tol_mm), (5.0, LayerBase::Bonded, Some(0.1)));
        let again = Script::from_toml(&s.to_toml().unwrap()).unwrap();
        assert_eq!(again, s);
        assert_eq!(Script::default().sensor.layer().unwrap(), None);
        for (text, key) in [
            ("elastomer_thickness_mm = 0.0", "sensor.elastomer_thickness_mm"),
            ("elastomer_thickness_mm = 5.0\nelastomer_base = \"glued\"", "sensor.elastomer_base"),
            ("elastomer_base = \"bonded\"", "sensor.elastomer_base"),
            ("elastomer_thickness_mm = 5.0\nelastomer_thickness_tol_mm = 6.0", "sensor.elastomer_thickness_tol_mm"),
            ("elastomer_thickness_tol_mm = 0.1", "sensor.elastomer_thickness_tol_mm"),
        ] {
            let e = Script::from_toml(&format!("[sensor]\n{text}\n")).unwrap_err();
            assert!(e.to_string().contains(key), "{text}: {e}");
        }
    }

    #[test]
    fn partial_scripts_take_defaults_and_typos_are_refused() {
        let s = Script::from_toml("[normal]\nstep_mm = 0.02\n[sensor]\nelastomer_r_mm = \"inf\"\n").unwrap();
        assert_eq!(s.normal.step_mm, 0.02);
        assert_eq!(s.normal.target_beta, 0.2);
        assert!(s.sensor.elastomer_r_mm.is_infinite());
        let e = Script::from_toml("[normal]\nstep_m = 0.02\n").unwrap_err();
        assert!(e.to_string().contains("step_m"), "{e}");
    }

    #[test]
    fn inconsistent_scripts_name_the_field() {
        let cases = [
            ("[normal]\ntarget_beta = 0.5\n", "normal.target_beta"),
            ("[normal]\nstep_mm = 0\n", "normal.step_mm"),
            ("[limits]\nstage_min_mm = 5.0\nstage_max_mm = 4.0\n", "limits.stage_max_mm"),
            ("[limits]\nretract_mm = 30.0\n", "limits.retract_mm"),
            ("[torsion]\namplitude_deg = 12.0\n", "torsion.amplitude_deg"),
            ("[indenter]\ne_mpa = 1.1\nnu = 0.7\nr_mm = 5.0\n", "indenter"),
            ("[settle]\nreadings = 0\n", "settle.readings"),
            // Issue 11's reproducers: accepted once, they panicked or ran for minutes after homing.
            ("[timeouts]\nmove_s = 1e20\n", "timeouts.move_s"),
            ("[timeouts]\nread_s = 1e300\n", "timeouts.read_s"),
            ("[settle]\ntimeout_s = 1e9\n", "settle.timeout_s"),
            ("[approach]\nnoise_readings = 1000000000\n", "approach.noise_readings"),
            ("[approach]\nstep_mm = 1e-7\n", "approach.step_mm"),
            ("[normal]\nstep_mm = 1e-6\n", "normal.step_mm"),
            ("[approach]\nrefine_steps = 100000000\n", "approach.refine_steps"),
            ("[approach]\nsearch_step_mm = 0.01\n", "approach.search_step_mm"),
            ("[normal]\nframes = 100000000\n", "normal.frames"),
            ("[torsion]\nframes = 100000000\n", "torsion.frames"),
        ];
        for (text, field) in cases {
            match Script::from_toml(text) {
                Err(ScriptError::Invalid { field: f, .. }) => assert_eq!(f, field, "{text}"),
                other => panic!("{text}: {other:?}"),
            }
        }
    }

    #[test]
    fn experiments_parse_validate_and_round_trip() {
        let text = "[[experiment]]\nkind = \"dwell\"\nhold_s = 20.0\nevery_s = 2.0\n\
                    [[experiment]]\nkind = \"torsion_at_depth\"\nbeta = 0.1\namplitude_deg = 6.0\nstep_deg = 0.5\n";
        let s = Script::from_toml(text).unwrap();
        assert_eq!(
            s.experiment,
            vec![
                ExperimentSpec::Dwell { hold_s: 20.0, every_s: 2.0 },
                ExperimentSpec::TorsionAtDepth { beta: 0.1, amplitude_deg: 6.0, step_deg: 0.5 }
            ]
        );
        assert_eq!(Script::from_toml(&s.to_toml().unwrap()).unwrap(), s);
        // A twist beyond the guard's limit, an unknown kind or key: refused, named.
        let e = Script::from_toml(&text.replace("amplitude_deg = 6.0", "amplitude_deg = 12.0")).unwrap_err();
        assert!(e.to_string().contains("amplitude_deg"), "{e}");
        let e = Script::from_toml(&text.replace("\"dwell\"", "\"nap\"")).unwrap_err();
        assert!(e.to_string().contains("nap"), "{e}");
        // The slow repeat and the approach at another speed, as the default script shows them.
        let slow = "[[experiment]]\nkind = \"slow_repeat\"\nfraction = 0.5\nsteps = 3\ndwell_s = 8.0\n\
                    [[experiment]]\nkind = \"approach_speed\"\nfraction = 0.5\nsteps = 4\nspeed_mm_s = 0.1\n";
        assert_eq!(
            Script::from_toml(slow).unwrap().experiment,
            vec![
                ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 3, dwell_s: 8.0 },
                ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 4, speed_mm_s: 0.1 }
            ]
        );
        let e = Script::from_toml(&slow.replace("speed_mm_s = 0.1", "speed_mm_s = 0.0")).unwrap_err();
        assert!(e.to_string().contains("experiment 1 (approach_speed) `speed_mm_s`"), "{e}");
        let uncommented: String = DEFAULT_SCRIPT_TOML
            .lines()
            .skip_while(|l| !l.starts_with("# [[experiment]]"))
            .take_while(|l| l.starts_with('#'))
            .filter_map(|l| l.strip_prefix("# "))
            .map(|l| format!("{l}\n"))
            .collect();
        let listed = Script::from_toml(&uncommented).unwrap().experiment;
        assert_eq!(listed.len(), 6, "{uncommented}");
        let e = Script::from_toml(&text.replace("every_s", "each_s")).unwrap_err();
        assert!(e.to_string().contains("each_s"), "{e}");
    }

    #[test]
    fn twist_angles_go_out_and_back() {
        let s = Script {
            torsion: TorsionSection { amplitude_deg: 1.0, step_deg: 0.25, frames: 0, frames_power: 0.0 },
            ..Default::default()
        };
        assert_eq!(s.twist_angles(), vec![0.0, 0.25, 0.5, 0.75, 1.0, 0.75, 0.5, 0.25, 0.0]);
        assert_eq!(Script::default().dropout_reads(), 4);
    }

    #[test]
    fn torsion_frames_grow_with_twist_and_long_stops_split_into_replicates() {
        let s = Script::default();
        // 200 (x / 8 deg)^3 frames: the settling's own at 2 deg, 25 at 4, 84 at 6, 200 at 8.
        let frames: Vec<usize> = [0.0, 2.0, 4.0, 6.0, 8.0].iter().map(|x| s.twist_frames(*x)).collect();
        assert_eq!(frames, [0, 3, 25, 84, 200]);
        // At most 10 frames a sample, the parts near equal, none lost.
        assert_eq!(s.sample_parts(25), vec![9, 8, 8]);
        assert_eq!(s.sample_parts(84).iter().sum::<usize>(), 84);
        assert_eq!(s.sample_parts(200), vec![10; 20]);
        assert_eq!(s.sample_parts(7), vec![7]);
        // 0, 2, 4, 6, 8, 6, 4, 2, 0 deg.
        assert_eq!(s.twist_samples(), 1 + 1 + 3 + 9 + 20 + 9 + 3 + 1 + 1);
        // Frames the same everywhere with power 0, one sample a stop without a maximum.
        let even = Script {
            torsion: TorsionSection { frames_power: 0.0, ..s.torsion },
            settle: SettleSection { max_sample_frames: 0, ..s.settle },
            ..s.clone()
        };
        assert_eq!(even.twist_frames(2.0), 200);
        assert_eq!(even.sample_parts(200), vec![200]);
        assert_eq!(even.twist_samples(), even.twist_angles().len());
    }
}
