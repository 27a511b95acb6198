//! Where the emulated sensor's frames go: easycalib's link protocol on a
//! pseudo-terminal (the sensor side of a bridge program), or the Tac3D main
//! program's UDP stream.

use std::path::Path;
use std::time::Duration;

use super::sensor_link::LinkDevice;
use super::tac3d::Tac3dSender;
use devices::sensor::SensorFrame;
use devices::sensor::link::LinkCommand;

use super::pty::{PtyMaster, SlaveBacklog};
use crate::sensor::stream::{FrameSink, SinkError};

/// Unread bytes in the pty above which a frame is dropped: less than one
/// frame of the default 20 x 20 marker grid (about 9.7 kB).
const MAX_BACKLOG_BYTES: usize = 4096;

/// Longest a frame may wait for room in the pty before it is dropped.
const FRAME_WRITE_TIMEOUT: Duration = Duration::from_millis(200);

/// The simulated sensor's side of easycalib's link protocol on a pty: answers
/// START / STOP / TARE with acknowledgements and sends frames only while
/// started, as a bridge program does. Commands are polled between frames;
/// [`LinkDevice::next_command`] is cancel-safe, so a pending partial command
/// is kept for the next poll. Frames the host has not caught up with are
/// dropped, not queued ([`SlaveBacklog`] says why).
pub struct LinkPtySink {
    device: LinkDevice,
    streaming: bool,
    backlog: SlaveBacklog,
}

impl LinkPtySink {
    /// Serve the link protocol on `pty`, whose slave is at `slave_path`.
    pub fn new(pty: PtyMaster, slave_path: &Path) -> std::io::Result<Self> {
        let backlog = SlaveBacklog::open(slave_path)?;
        Ok(Self { device: LinkDevice::new(pty), streaming: false, backlog })
    }

    /// The next command already received, without waiting.
    async fn poll_command(&mut self) -> Option<LinkCommand> {
        tokio::select! {
            biased;
            c = self.device.next_command() => c.ok(),
            _ = std::future::ready(()) => None,
        }
    }
}

impl FrameSink for LinkPtySink {
    async fn send(&mut self, frame: &SensorFrame) -> Result<(), SinkError> {
        while let Some(cmd) = self.poll_command().await {
            match cmd {
                LinkCommand::Start => self.streaming = true,
                LinkCommand::Stop => self.streaming = false,
                // The simulated elastomer reads exact zeros untouched: nothing to re-zero.
                LinkCommand::Tare => {}
            }
            self.device.ack(cmd).await?;
        }
        // Drop this frame while the host has not taken the previous one yet.
        if self.streaming && self.backlog.bytes() >= MAX_BACKLOG_BYTES {
            return Ok(());
        }
        if self.streaming {
            // A host that stopped reading without saying STOP must not stall
            // the sensor (and its command handling): drop the frame instead. A
            // frame cut short is resynchronised by the receiver's CRCs.
            if let Ok(r) = tokio::time::timeout(FRAME_WRITE_TIMEOUT, self.device.send_frame(frame)).await {
                r?;
            }
        }
        Ok(())
    }
}

/// Frames as the Tac3D main program sends them.
pub struct Tac3dSink(pub Tac3dSender);

impl FrameSink for Tac3dSink {
    async fn send(&mut self, frame: &SensorFrame) -> Result<(), SinkError> {
        Ok(self.0.send(frame).await?)
    }
}
