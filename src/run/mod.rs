//! The calibration run: the events a sequencer emits and the controls it accepts.

pub mod events;
