//! Motion: one [`Axis`] abstraction for the rig's linear stage (the
//! micrometer that presses the indenter) and its rotation mount (that twists
//! it for the torsion sweep).
//!
//! How it is built:
//! * **The unit is part of the type.** An axis names its unit as the
//!   associated type [`Axis::Unit`]: [`Mm`] for a stage, [`Deg`] for a mount
//!   ([`unit`]). Targets, positions and travel cross the trait in that type,
//!   so a stage cannot be sent degrees. [`AxisStatus`] keeps its position as
//!   a plain number in the axis' unit: it is a snapshot for displays and
//!   reports.
//! * **Stage and mount are one capability.** [`LinearStage`] is any
//!   `Axis<Unit = Mm>` and [`RotationMount`] any `Axis<Unit = Deg>` (marker
//!   traits with blanket impls), so code reads naturally and a driver family
//!   implements [`Axis`] once for both (the APT driver serves the KDC101 stage
//!   and the K10CR1 mount with the same code).
//! * **The driver guarantees "arrived and standing still".** A move is split
//!   into a start and a wait so a caller can stop it while it is under way;
//!   [`Axis::wait_until_stopped`] returns only once the axis stands still at
//!   the target, or stands still short of it (a limit, a stop). A driver
//!   whose end-of-move messages may belong to an earlier move confirms the
//!   arrival with [`arrival::confirm`]; [`Axis::stop`] returns once the axis
//!   is at rest and will take the next move.
//! * **Errors stay typed.** [`Identify::Error`] is the driver family's own
//!   error, which every [`Axis`] method returns; its [`FaultKind`] lets a
//!   caller react without knowing the protocol. Behind a registry a driver is
//!   a [`DynAxis`] ([`boxed`]): one dyn call per operation, its error an
//!   [`AxisFault`] that keeps the kind and the driver's error for downcasting.

use std::time::Duration;

use async_trait::async_trait;
use serde::Serialize;

pub mod arrival;
mod dynamic;
pub mod unit;

pub use dynamic::{AxisFault, DynAxis, DynMount, DynStage, boxed};
pub use unit::{Deg, Mm, Unit};

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

/// A snapshot of one axis, its position in the axis' own unit (mm or degrees).
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

/// Asks a device what it is. Its `Error` is the driver family's error, the
/// one every [`Axis`] method returns too.
#[async_trait]
pub trait Identify: Send {
    type Error: DeviceFault;
    async fn identify(&mut self) -> Result<DeviceInfo, Self::Error>;
}

/// One motorized axis: a translation stage ([`Mm`]) or a rotation mount ([`Deg`]).
#[async_trait]
pub trait Axis: Identify {
    /// The axis' unit, which is also the type of its positions.
    type Unit: Unit;

    /// Soft travel `(min, max)`; moves outside are refused before anything moves.
    fn travel(&self) -> (Self::Unit, Self::Unit);
    /// Drive to the home switch and zero the position; returns when homed.
    async fn home(&mut self, timeout: Duration) -> Result<(), Self::Error>;
    /// Start an absolute move and return without waiting for it to end.
    async fn start_move_to(&mut self, target: Self::Unit) -> Result<(), Self::Error>;
    /// Start a relative move and return without waiting for it to end.
    async fn start_move_by(&mut self, delta: Self::Unit) -> Result<(), Self::Error>;
    /// Wait until the move under way has ended with the axis standing still:
    /// at its target, or short of it once it stands still there (a limit, a
    /// stop). Returns the final position.
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<Self::Unit, Self::Error>;
    /// Decelerate and stop any motion; returns once the axis is at rest and
    /// will take the next move (the caller's next move is usually the way
    /// out, e.g. backing the indenter off after an abort).
    async fn stop(&mut self) -> Result<(), Self::Error>;
    async fn position(&mut self) -> Result<Self::Unit, Self::Error>;
    async fn status(&mut self) -> Result<AxisStatus, Self::Error>;
    /// Set the top speed of the moves that follow, units per second, and
    /// return the one it replaces (to restore it). `Ok(None)`: this driver
    /// cannot set its speed, and nothing was changed.
    async fn set_max_speed(&mut self, _speed: f64) -> Result<Option<f64>, Self::Error> {
        Ok(None)
    }

    /// Absolute move that waits for completion.
    async fn move_to(&mut self, target: Self::Unit, timeout: Duration) -> Result<Self::Unit, Self::Error> {
        self.start_move_to(target).await?;
        self.wait_until_stopped(timeout).await
    }
    /// Relative move that waits for completion.
    async fn move_by(&mut self, delta: Self::Unit, timeout: Duration) -> Result<Self::Unit, Self::Error> {
        self.start_move_by(delta).await?;
        self.wait_until_stopped(timeout).await
    }
}

/// A motorized translation stage: any [`Axis`] in [`Mm`].
pub trait LinearStage: Axis<Unit = Mm> {}
impl<A: Axis<Unit = Mm> + ?Sized> LinearStage for A {}

/// A motorized rotation mount: any [`Axis`] in [`Deg`].
pub trait RotationMount: Axis<Unit = Deg> {}
impl<A: Axis<Unit = Deg> + ?Sized> RotationMount for A {}
