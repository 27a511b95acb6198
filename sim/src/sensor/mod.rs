//! The simulated tactile sensor: marker fields from a contact state, a
//! sensor coupled to the emulated rig, and a frame stream the emulators send.

pub mod field;
pub mod rig;
pub mod shape;
pub mod stream;
