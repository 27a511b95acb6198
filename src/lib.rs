//! easycalib: the rig controller — fitting, diagnosis, the calibration run, TUI and reports.
// Library code answers bad input with an error, never a panic: no unwrap or
// expect outside tests (ARCHITECTURE.md, "Conventions").
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used))]

pub mod cli;
pub mod diagnosis;
pub mod fit;
pub mod layer;
pub mod numerics;
pub mod plan;
pub mod report;
pub mod rig;
pub mod run;
pub mod sensing;
pub mod tui;
