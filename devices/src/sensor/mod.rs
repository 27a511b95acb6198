//! The tactile sensor's link: frames of marker positions and displacements.
//!
//! [`SensorLink`] is what the sequencer reads. Two transports implement it:
//! [`tac3d::Tac3dReceiver`] (the Tac3D main program's UDP stream) and
//! [`link::LinkReceiver`] (easycalib's own framed protocol for bridge programs
//! and microcontrollers, over serial or UDP). Malformed input never ends a
//! link: it is counted by reason in [`LinkStats`].

use std::time::Duration;

use async_trait::async_trait;

pub mod error;
pub mod frame;
mod inbox;
pub mod link;
pub mod stats;
pub mod tac3d;
mod yaml;

pub use error::SensorError;
pub use frame::SensorFrame;
pub use stats::{BadReason, FrameTracker, LinkStats, Verdict};

/// A stream of sensor frames.
#[async_trait]
pub trait SensorLink: Send {
    /// Begin delivering frames (asks the device to stream where the protocol can).
    async fn start(&mut self) -> Result<(), SensorError>;
    /// Stop delivering frames; frames queued so far are discarded.
    async fn stop(&mut self) -> Result<(), SensorError>;
    /// The next good frame, waiting at most `timeout` (real time).
    async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError>;
    /// Take the current deformation as zero (sensor must be untouched).
    async fn tare(&mut self) -> Result<(), SensorError>;
    /// Counters so far.
    fn stats(&self) -> LinkStats;
}
