//! The calibration run: the script, the sequencer that executes it under the
//! safety guard, the gauge it reads, the events it emits and the controls it
//! accepts. (The in-process simulated rig the sequencer's tests run on is
//! test support: `tests/support/simrig.rs`.)

pub mod events;
pub mod gauge;
pub mod outdir;
pub mod safety;
pub mod script;
pub mod sequencer;

pub use gauge::{Gauge, GaugeError, GaugeReading, SensorGauge};
pub use safety::{LimitViolation, SafetyGuard, SoftLimits};
pub use script::{DEFAULT_SCRIPT_TOML, Script, ScriptError};
pub use sequencer::{AbortInfo, AdaptiveStep, Backoff, Culprit, PhaseTime, RunOutcome, RunStatus, Sequencer};
