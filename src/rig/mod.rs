//! The rig a calibration runs on: its devices opened from paths
//! ([`connect`]) by the drivers registered in [`drivers`], a real rig's
//! description ([`config`]), and the built-in
//! emulated rig ([`emulated`]) whose devices sit behind pseudo-terminals so
//! the real drivers drive it.

pub mod config;
pub mod connect;
pub mod drivers;
pub mod emulated;
pub mod session;

pub use config::{ConfigError, RigConfig};
pub use connect::{ConnectError, RigDevices, RigGauge, RigSpec, SensorDriver, SensorSpec, measure_frame, open_rig};
pub use drivers::{AxisSpec, Driver, Drivers, OpenAxis, OpenError, RotationSpec, StageSpec};
pub use emulated::{EmulatedRig, EmulatedSensor, ServeOptions, StageEmulator};
pub use session::{
    RECORDING_FILE, Reported, RunRequest, RunResult, StartError, fit_and_report, run_calibration, run_calibration_with,
};
