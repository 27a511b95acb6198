//! Hardware side of easycalib: one small async trait per capability (a
//! motion axis in its own unit, identity, sensor link) and the real drivers
//! that speak the devices' own protocols. Every driver is generic over its
//! transport (`AsyncRead + AsyncWrite`), so the same code runs over a USB
//! serial port, a pseudo-terminal to an emulator, or an in-memory pipe in a
//! unit test.
// Library code answers bad input with an error, never a panic: no unwrap or
// expect outside tests (ARCHITECTURE.md, "Conventions").
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub mod apt;
pub mod discovery;
pub mod grbl;
pub mod motion;
pub mod sensor;
pub mod serial;

pub use motion::{
    Axis, AxisFault, AxisStatus, Deg, DeviceFault, DeviceInfo, DynAxis, FaultKind, Identify, LinearStage, Mm,
    RotationMount, Unit,
};
