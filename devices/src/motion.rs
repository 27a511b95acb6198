//! Motion capabilities of the rig: a linear stage (mm) and a rotation mount
//! (degrees). Moves are split into "start" and "wait" so a caller can stop a
//! move that is under way; the provided `move_*` methods do both.

use std::time::Duration;

use async_trait::async_trait;
use serde::Serialize;

/// What a device says about itself when asked.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct DeviceInfo {
    /// Model string as the device reports it, e.g. `KDC101`, `K10CR1`, `GRBL 1.1h`.
    pub model: String,
    /// Serial number (empty when the protocol has none, e.g. GRBL).
    pub serial: String,
    /// Firmware version as `major.interim.minor` or the banner's version.
    pub firmware: String,
}

/// A snapshot of one axis, in the axis' own user unit (mm or degrees).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct AxisStatus {
    pub position: f64,
    pub moving: bool,
    pub homed: bool,
    pub homing: bool,
    pub forward_limit: bool,
    pub reverse_limit: bool,
    pub enabled: bool,
}

/// The categories every driver family's typed error falls into, so a
/// consumer (the sequencer) can react without knowing the protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum FaultKind {
    /// The device did not answer in time.
    Timeout,
    /// Bytes arrived that do not form a valid message.
    Protocol,
    /// The device itself reported an error or alarm.
    DeviceReported,
    /// A requested position lies outside the soft or hard limits; nothing moved.
    Limit,
    /// The link is gone (cable cut, port closed, device reset).
    Disconnected,
}

/// Implemented by each driver family's error type.
pub trait DeviceFault: std::error::Error + Send + Sync + 'static {
    fn kind(&self) -> FaultKind;
}

/// Asks a device what it is.
#[async_trait]
pub trait Identify: Send {
    type Error: DeviceFault;
    async fn identify(&mut self) -> Result<DeviceInfo, Self::Error>;
}

/// A motorized translation stage (the micrometer that presses the indenter).
#[async_trait]
pub trait LinearStage: Send {
    type Error: DeviceFault;

    /// Soft travel range `(min_mm, max_mm)`; moves outside are refused before anything moves.
    fn travel_mm(&self) -> (f64, f64);
    /// Drive to the home switch and zero the position; returns when homed.
    async fn home(&mut self, timeout: Duration) -> Result<(), Self::Error>;
    /// Start an absolute move and return without waiting for it to end.
    async fn start_move_to_mm(&mut self, target_mm: f64) -> Result<(), Self::Error>;
    /// Start a relative move and return without waiting for it to end.
    async fn start_move_by_mm(&mut self, delta_mm: f64) -> Result<(), Self::Error>;
    /// Wait until the current move has ended; returns the final position.
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<f64, Self::Error>;
    /// Decelerate and stop any motion now.
    async fn stop(&mut self) -> Result<(), Self::Error>;
    async fn position_mm(&mut self) -> Result<f64, Self::Error>;
    async fn status(&mut self) -> Result<AxisStatus, Self::Error>;

    /// Absolute move that waits for completion.
    async fn move_to_mm(&mut self, target_mm: f64, timeout: Duration) -> Result<f64, Self::Error> {
        self.start_move_to_mm(target_mm).await?;
        self.wait_until_stopped(timeout).await
    }
    /// Relative move that waits for completion.
    async fn move_by_mm(&mut self, delta_mm: f64, timeout: Duration) -> Result<f64, Self::Error> {
        self.start_move_by_mm(delta_mm).await?;
        self.wait_until_stopped(timeout).await
    }
}

/// A motorized rotation mount (twists the indenter for the torsion sweep).
#[async_trait]
pub trait RotationMount: Send {
    type Error: DeviceFault;

    /// Soft angular range `(min_deg, max_deg)`.
    fn travel_deg(&self) -> (f64, f64);
    async fn home(&mut self, timeout: Duration) -> Result<(), Self::Error>;
    async fn start_move_to_deg(&mut self, target_deg: f64) -> Result<(), Self::Error>;
    async fn start_move_by_deg(&mut self, delta_deg: f64) -> Result<(), Self::Error>;
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<f64, Self::Error>;
    async fn stop(&mut self) -> Result<(), Self::Error>;
    async fn position_deg(&mut self) -> Result<f64, Self::Error>;
    async fn status(&mut self) -> Result<AxisStatus, Self::Error>;

    async fn move_to_deg(&mut self, target_deg: f64, timeout: Duration) -> Result<f64, Self::Error> {
        self.start_move_to_deg(target_deg).await?;
        self.wait_until_stopped(timeout).await
    }
    async fn move_by_deg(&mut self, delta_deg: f64, timeout: Duration) -> Result<f64, Self::Error> {
        self.start_move_by_deg(delta_deg).await?;
        self.wait_until_stopped(timeout).await
    }
}
