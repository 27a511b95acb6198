//! The simulated tactile sensor: marker fields from a contact state.

pub mod field;
pub mod rng;
