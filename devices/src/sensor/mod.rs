//! The tactile sensor's link: frames of marker positions and displacements.

pub mod frame;

pub use frame::SensorFrame;
