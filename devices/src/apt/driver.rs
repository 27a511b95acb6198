//! The APT axis: one driver, [`AptAxis`], for every APT unit the rig uses,
//! over any byte transport: [`AptStage`] (KDC101 + Z8 actuator, in [`Mm`])
//! and [`AptRotation`] (K10CR1, in [`Deg`]) are the same code with another
//! unit. The protocol runs in [`AptLink`] (`link.rs`).
//!
//! On top of the link's end-of-move detection the axis guarantees what
//! [`Axis`] promises: a wait confirms that the unit stands at the target
//! ([`arrival::confirm`]: a late MOVE_COMPLETED or MOVE_STOPPED must not end
//! the next move), and a stop returns once the unit is at rest, so the move
//! after it (the back-off of an abort) cannot take the stop's late answer for
//! its own end.

use std::io;
use std::marker::PhantomData;
use std::time::Duration;

use async_trait::async_trait;
use tokio::io::{AsyncRead, AsyncWrite};

use super::codec::{CodecError, HwInfo, USB_UNIT};
use super::link::AptLink;
use super::scaling::{OutOfRange, Scale};
use crate::motion::arrival::{self, STOP_WAIT, deadline_after};
use crate::motion::{Axis, AxisStatus, Deg, DeviceFault, DeviceInfo, FaultKind, Identify, Mm, Unit};
use crate::serial::open_serial;

/// Typed error of the APT driver family.
#[derive(Debug, thiserror::Error)]
pub enum AptError {
    #[error("APT device did not send {waiting_for} within {timeout:?}")]
    Timeout { waiting_for: &'static str, timeout: Duration },
    #[error("APT protocol error: {detail} (bytes {bytes:02X?})")]
    Protocol {
        detail: String,
        bytes: Vec<u8>,
        /// The decoder's reason, when the bytes did not decode.
        #[source]
        source: Option<CodecError>,
    },
    #[error("APT device reported error code {code} for message 0x{msg_id:04X}: {text}")]
    DeviceReported { msg_id: u16, code: u16, text: String },
    #[error("{what} {requested} outside the travel [{min}, {max}]; nothing was sent")]
    Limit { what: &'static str, requested: f64, min: f64, max: f64 },
    #[error("APT link disconnected: {0}")]
    Disconnected(String),
    #[error("APT I/O error: {0}")]
    Io(#[from] io::Error),
    #[error("APT {what} setting out of the device's range")]
    Setting {
        what: &'static str,
        #[source]
        source: OutOfRange,
    },
}

impl DeviceFault for AptError {
    fn kind(&self) -> FaultKind {
        match self {
            AptError::Timeout { .. } => FaultKind::Timeout,
            AptError::Protocol { .. } | AptError::Setting { .. } => FaultKind::Protocol,
            AptError::DeviceReported { .. } => FaultKind::DeviceReported,
            AptError::Limit { .. } => FaultKind::Limit,
            // An I/O error other than a hang-up still leaves the link unusable.
            AptError::Disconnected(_) | AptError::Io(_) => FaultKind::Disconnected,
        }
    }
}

impl AptError {
    pub(super) fn from_codec(e: CodecError, bytes: Vec<u8>) -> Self {
        AptError::Protocol { detail: e.to_string(), bytes, source: Some(e) }
    }
}

/// Is this I/O error the far end going away (cable pulled, pty master closed)?
pub(super) fn is_hangup(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::BrokenPipe
            | io::ErrorKind::UnexpectedEof
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::NotConnected
    ) || matches!(e.raw_os_error(), Some(5 /* EIO */ | 6 /* ENXIO */ | 19 /* ENODEV */))
}

/// Driver settings for one APT unit.
#[derive(Debug, Clone, PartialEq)]
pub struct AptConfig {
    /// Unit conversion (counts per mm or degree, controller family).
    pub scale: Scale,
    /// Soft travel `(min, max)` in user units; moves outside are refused.
    pub travel: (f64, f64),
    /// Model strings accepted in HW_GET_INFO (empty = accept any).
    pub expect_models: Vec<String>,
    /// `(max velocity, acceleration)` in user units to set at connect.
    pub velocity: Option<(f64, f64)>,
    /// Homing velocity in user units per second, set before each homing
    /// (None: the unit's own home parameters).
    pub home_velocity: Option<f64>,
    /// How long to wait for the reply to a request.
    pub reply_timeout: Duration,
    /// How often to send MOT_ACK_DCSTATUSUPDATE while the driver is active.
    pub keepalive: Duration,
    /// Status poll period while waiting for a move to end.
    pub poll_period: Duration,
    /// Destination address (0x50 for single-channel USB units).
    pub dest: u8,
    /// Channel (1 on single-channel units).
    pub chan: u8,
}

impl AptConfig {
    /// KDC101 driving a Z825B (25 mm travel), 2.3 mm/s and 4 mm/s² (A.7);
    /// it homes at the same 2.3 mm/s (a homing at the unit's default creeps
    /// to the retracted limit for seconds longer).
    pub fn kdc101_z825b() -> Self {
        Self {
            scale: Scale::kdc101_z8(),
            travel: (0.0, 25.0),
            expect_models: vec!["KDC101".into(), "TDC001".into()],
            velocity: Some((2.3, 4.0)),
            home_velocity: Some(2.3),
            reply_timeout: Duration::from_secs(1),
            keepalive: Duration::from_millis(900),
            poll_period: Duration::from_millis(200),
            dest: USB_UNIT,
            chan: 1,
        }
    }

    /// KDC101 driving a Z812B (12 mm travel).
    pub fn kdc101_z812b() -> Self {
        Self { travel: (0.0, 12.0), ..Self::kdc101_z825b() }
    }

    /// K10CR1 rotation mount, 10 °/s and 20 °/s² (A.7); soft travel ±360°.
    /// Its home parameters are left as they are: it homes at 5 °/s at most,
    /// the factory value, which its manual advises keeping.
    pub fn k10cr1() -> Self {
        Self {
            scale: Scale::k10cr1(),
            travel: (-360.0, 360.0),
            expect_models: vec!["K10CR1".into(), "K10CR2".into()],
            velocity: Some((10.0, 20.0)),
            home_velocity: None,
            ..Self::kdc101_z825b()
        }
    }
}

/// One APT unit as an [`Axis`] in unit `U`.
#[derive(Debug)]
pub struct AptAxis<T, U> {
    link: AptLink<T>,
    unit: PhantomData<U>,
}

/// KDC101 + Z8 actuator as a linear stage (mm).
pub type AptStage<T> = AptAxis<T, Mm>;
/// K10CR1 rotation mount (degrees).
pub type AptRotation<T> = AptAxis<T, Deg>;

impl<T: AsyncRead + AsyncWrite + Unpin + Send, U: Unit> AptAxis<T, U> {
    /// Open a session on `io` (see [`AptLink`] for the start-up sequence).
    pub async fn connect(io: T, cfg: AptConfig) -> Result<Self, AptError> {
        let mut link = AptLink::new(io, cfg);
        link.start_session().await?;
        Ok(Self { link, unit: PhantomData })
    }

    /// The protocol engine, for messages the trait does not cover.
    pub fn link(&mut self) -> &mut AptLink<T> {
        &mut self.link
    }

    pub fn config(&self) -> &AptConfig {
        &self.link.cfg
    }

    /// HW_GET_INFO as read at connect.
    pub fn hw_info(&self) -> Option<&HwInfo> {
        self.link.info.as_ref()
    }

    /// Set `(max velocity, acceleration)` in user units (per s, per s²).
    pub async fn set_velocity_params(&mut self, v: f64, a: f64) -> Result<(), AptError> {
        self.link.set_velocity_params(v, a).await
    }

    pub async fn velocity_params(&mut self) -> Result<(f64, f64), AptError> {
        self.link.velocity_params().await
    }

    /// Latest status seen (polled, pushed or end-of-move), without asking.
    pub fn last_status(&self) -> Option<AxisStatus> {
        self.link.last_status.map(|s| self.link.axis_status(&s))
    }

    /// Profiled stop and HW_STOP_UPDATEMSGS; gives the transport back.
    pub async fn close(self) -> Result<T, AptError> {
        self.link.close().await
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send, U: Unit> Identify for AptAxis<T, U> {
    type Error = AptError;
    async fn identify(&mut self) -> Result<DeviceInfo, AptError> {
        self.link.identify().await
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send, U: Unit> Axis for AptAxis<T, U> {
    type Unit = U;

    fn travel(&self) -> (U, U) {
        let (min, max) = self.link.cfg.travel;
        (U::new(min), U::new(max))
    }
    async fn home(&mut self, timeout: Duration) -> Result<(), AptError> {
        self.link.home(timeout).await
    }
    async fn start_move_to(&mut self, target: U) -> Result<(), AptError> {
        self.link.move_to(target.value()).await
    }
    async fn start_move_by(&mut self, delta: U) -> Result<(), AptError> {
        self.link.move_by(delta.value()).await
    }
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<U, AptError> {
        let deadline = deadline_after(timeout);
        let reached = U::new(self.link.wait_until_stopped(timeout).await?);
        match self.link.take_arrival_target() {
            Some(target) => arrival::confirm(self, U::new(target), reached, deadline).await,
            None => Ok(reached),
        }
    }
    /// MOT_MOVE_STOP only asks the unit to stop: wait for it to be at rest.
    async fn stop(&mut self) -> Result<(), AptError> {
        self.link.stop().await?;
        self.link.wait_until_stopped(STOP_WAIT).await?;
        Ok(())
    }
    async fn position(&mut self) -> Result<U, AptError> {
        let s = self.link.query_status().await?;
        Ok(U::new(self.link.cfg.scale.from_counts(s.position)))
    }
    async fn status(&mut self) -> Result<AxisStatus, AptError> {
        let s = self.link.query_status().await?;
        Ok(self.link.axis_status(&s))
    }
    /// MOT_REQ_VELPARAMS for the speed and acceleration in force, then
    /// MOT_SET_VELPARAMS with the new top speed and the same acceleration.
    async fn set_max_speed(&mut self, speed: f64) -> Result<Option<f64>, AptError> {
        let (old, accel) = self.link.velocity_params().await?;
        self.link.set_velocity_params(speed, accel).await?;
        Ok(Some(old))
    }
}

/// Ask whatever answers on `port_path` whether it is an APT unit: open the
/// port with the APT line settings, send HW_REQ_INFO and wait up to `timeout`
/// for HW_GET_INFO. Nothing else is sent, so nothing moves and no setting
/// changes. HW_NO_FLASH_PROGRAMMING is deliberately not sent: its first byte
/// is 0x18 (Ctrl-X), which a GRBL board on the same probe would take as a
/// soft reset.
pub async fn probe(port_path: impl AsRef<std::path::Path>, timeout: Duration) -> Result<DeviceInfo, AptError> {
    let port = open_serial(port_path).await?;
    probe_on(port, timeout).await
}

/// [`probe`] over an already open transport.
pub async fn probe_on<T: AsyncRead + AsyncWrite + Unpin + Send>(
    io: T,
    timeout: Duration,
) -> Result<DeviceInfo, AptError> {
    let cfg = AptConfig {
        expect_models: Vec::new(),
        velocity: None,
        home_velocity: None,
        reply_timeout: timeout,
        // No keep-alive during a probe: only HW_REQ_INFO goes out.
        keepalive: Duration::MAX,
        ..AptConfig::kdc101_z825b()
    };
    let mut link = AptLink::new(io, cfg);
    link.identify().await
}

#[cfg(test)]
#[path = "driver_tests.rs"]
mod tests;
