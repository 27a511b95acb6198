//! Simulation side of easycalib: the contact physics of the EasyCalib method
//! (Hertz–Tatara normal contact, Jäger torsion with the rod correction), the
//! synthetic recording generator, and emulators of the rig's hardware.

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
