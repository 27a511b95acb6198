//! Hardware side of easycalib: one small async trait per capability (linear
//! stage, rotation mount, identity, sensor link) and the real drivers that speak
//! the devices' own protocols. Every driver is generic over its transport
//! (`AsyncRead + AsyncWrite`), so the same code runs over a USB serial port, a
//! pseudo-terminal to an emulator, or an in-memory pipe in a unit test.

pub mod apt;
pub mod discovery;
pub mod grbl;
pub mod motion;
pub mod ops;
pub mod sensor;
pub mod serial;

pub use motion::{AxisStatus, DeviceFault, DeviceInfo, FaultKind, Identify, LinearStage, RotationMount};
