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

pub use error::SensorError;
pub use frame::SensorFrame;
pub use stats::{BadReason, FrameTracker, LinkStats, Verdict};

/// A stream of sensor frames.
///
/// Errors: [`SensorError::NotStreaming`] from `next_frame` before `start` or
/// after `stop`; [`SensorError::Timeout`] when no good frame came in time (the
/// link stays usable: a sensor that drops out and comes back just resumes);
/// [`SensorError::Closed`] once the transport is gone for good.
#[async_trait]
pub trait SensorLink: Send {
    /// Begin delivering frames (asks the device to stream where the protocol
    /// can). Frames that arrived before are not delivered.
    async fn start(&mut self) -> Result<(), SensorError>;
    /// Stop delivering frames; frames queued so far are discarded.
    async fn stop(&mut self) -> Result<(), SensorError>;
    /// The next good frame in arrival order, waiting at most `timeout` (real
    /// wall-clock time). If the consumer falls behind, the oldest queued
    /// frames are discarded and counted as [`BadReason::Overrun`].
    async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError>;
    /// Drop the frames received but not yet delivered (counted as
    /// [`BadReason::Superseded`]) and say how many: after a move they show
    /// the rig before or while it moved, and a consumer that fell behind
    /// would otherwise average them into the new pose.
    fn discard_queued(&mut self) -> usize;
    /// Take the current deformation as zero (sensor must be untouched). Tac3D
    /// does not acknowledge it; frames already in flight still carry the old
    /// zero, so wait for a frame or two before relying on it.
    async fn tare(&mut self) -> Result<(), SensorError>;
    /// Counters so far.
    fn stats(&self) -> LinkStats;
    /// End the link's background work now, so that once the link is dropped
    /// the transport (a serial port held exclusively, a bound UDP port) is
    /// free to be opened again at once: a second run on the same rig must not
    /// race the first one's port closing. Nothing is delivered afterwards.
    async fn close(&mut self) {}
}
