//! Simulation side of easycalib: the contact physics of the EasyCalib method
//! (Hertz–Tatara normal contact, Jäger torsion with the rod correction), the
//! synthetic recording generator, and emulators of the rig's hardware.
// Library code answers bad input with an error, never a panic: no unwrap or
// expect outside tests (ARCHITECTURE.md, "Conventions").
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub mod clock;
pub mod corpus;
pub mod defaults;
pub mod effects;
pub mod emulator;
pub mod experiment;
pub mod generator;
pub mod physics;
pub mod recording;
pub mod rng;
pub mod sensor;
pub mod setup;
