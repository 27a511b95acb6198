//! GRBL 1.1 motion controllers (Arduino + stepper on a micrometer head), the
//! low-cost alternative to the Thorlabs stage (hardware.md section B).
//!
//! [`codec`] is the pure line protocol; [`driver`] runs it over any async byte
//! stream and implements [`crate::LinearStage`] for one axis.

pub mod codec;
pub mod driver;

pub use codec::{AlarmCode, ErrorCode, MachineState, Response, StatusReport};
pub use driver::{GrblConfig, GrblError, GrblStage};
