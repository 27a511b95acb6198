//! GRBL 1.1 motion controllers (Arduino + stepper on a micrometer head), the
//! low-cost alternative to the Thorlabs stage (docs/hardware.md section B).
//!
//! [`codec`] is the pure line protocol; [`driver`] runs it over any async byte
//! stream and implements [`crate::Axis`] in [`crate::Mm`] for one axis; [`probe`] asks a
//! port whether it is a GRBL without moving anything.

pub mod codec;
pub mod driver;
pub mod probe;

pub use codec::{AlarmCode, ErrorCode, MachineState, Response, StatusReport};
pub use driver::{GRBL_BAUD, GrblConfig, GrblError, GrblStage, open_serial};
pub use probe::{probe, probe_stream};
