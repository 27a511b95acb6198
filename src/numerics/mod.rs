//! Numerics shared by the fits of a recording, the diagnosis and the frame
//! measurement: one least-squares solver ([`lm`]) and the statistics
//! ([`stats`]; distributions through `statrs`).

pub mod lm;
pub mod stats;
