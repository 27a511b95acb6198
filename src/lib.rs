//! easycalib: the rig controller — fitting, diagnosis, the calibration run, TUI and reports.

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
