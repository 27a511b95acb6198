//! Emulators of the rig's real hardware. They speak the devices' own protocols
//! on pseudo-terminals (and the sensors' on UDP), so easycalib's real drivers
//! and receivers are tested byte for byte;
//! [`served`] puts them together into the whole emulated rig.

pub mod apt;
pub mod axis;
pub mod grbl;
pub mod pty;
pub mod rig;
pub mod sensor_link;
pub mod sensor_sink;
pub mod served;
pub mod tac3d;
