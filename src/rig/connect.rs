//! Opening a rig's devices from where they are: serial paths for the stage and
//! the rotation mount (each through the driver its spec names, see
//! [`super::drivers`]), a serial path or a UDP address for the sensor. The same
//! code opens the emulated rig's pseudo-terminals and a real rig's USB ports,
//! so what the tests exercise is what runs on hardware.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use async_trait::async_trait;
use devices::motion::{DynMount, DynStage};
use devices::sensor::link::{LinkConfig, LinkReceiver};
use devices::sensor::tac3d::{Tac3dReceiver, Tac3dReceiverConfig};
use devices::sensor::{LinkStats, SensorError, SensorFrame, SensorLink};

pub use super::drivers::{OpenError, RotationSpec, StageSpec};
use crate::run::gauge::{GaugeReading, SensorGauge};
use crate::sensing::{FrameEstimator, SensingConfig, SensingError};

/// Where the sensor's frames come from.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorSpec {
    /// easycalib's link protocol over a serial port (or a pty).
    LinkSerial { path: PathBuf, baud: u32 },
    /// easycalib's link protocol over UDP: bind locally, talk to `device`.
    LinkUdp { bind: SocketAddr, device: SocketAddr },
    /// The Tac3D main program's UDP stream, received at `bind`.
    /// Listen on `bind`; hear only `source` when given.
    Tac3d { bind: SocketAddr, source: Option<std::net::IpAddr> },
}

impl SensorSpec {
    /// A short description for messages and the recording.
    pub fn describe(&self) -> String {
        match self {
            SensorSpec::LinkSerial { path, .. } => format!("link {}", path.display()),
            SensorSpec::LinkUdp { device, .. } => format!("link udp://{device}"),
            SensorSpec::Tac3d { bind, .. } => format!("tac3d udp://{bind}"),
        }
    }
}

/// Everything needed to open a rig.
#[derive(Debug, Clone)]
pub struct RigSpec {
    pub stage: StageSpec,
    pub rotation: RotationSpec,
    pub sensor: SensorSpec,
    /// Name of the sensor for the recording and the output folder.
    pub sensor_name: String,
}

/// Why a device could not be opened; the message names the device and where it is.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    #[error("stage at {path}: {source}")]
    Stage {
        path: String,
        #[source]
        source: OpenError,
    },
    #[error("rotation mount at {path}: {source}")]
    Rotation {
        path: String,
        #[source]
        source: OpenError,
    },
    #[error("sensor ({what}): {source}")]
    Sensor {
        what: String,
        #[source]
        source: SensorError,
    },
    #[error("sensor ({what}): the path is not valid UTF-8")]
    SensorPath { what: String },
}

/// The sensor, whichever link it uses.
pub struct SensorDriver(Box<dyn SensorLink>);

impl std::fmt::Debug for SensorDriver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("SensorDriver").finish_non_exhaustive()
    }
}

#[async_trait]
impl SensorLink for SensorDriver {
    async fn start(&mut self) -> Result<(), SensorError> {
        self.0.start().await
    }
    async fn stop(&mut self) -> Result<(), SensorError> {
        self.0.stop().await
    }
    async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError> {
        self.0.next_frame(timeout).await
    }
    fn discard_queued(&mut self) -> usize {
        self.0.discard_queued()
    }
    async fn tare(&mut self) -> Result<(), SensorError> {
        self.0.tare().await
    }
    fn stats(&self) -> LinkStats {
        self.0.stats()
    }
    async fn close(&mut self) {
        self.0.close().await
    }
}

/// gamma1, theta1, the contact radius and their standard errors from one
/// frame, through the run's estimator (which learns the contact's curvature
/// from the frames it resolves: docs/sensing.md). A frame without contact is
/// a valid reading of zero: the sequencer needs readings out of contact to
/// find the contact.
pub fn measure_frame(estimator: &mut FrameEstimator, frame: &SensorFrame) -> Result<GaugeReading, String> {
    match estimator.measure(frame) {
        Ok(m) => Ok(GaugeReading::new(frame.t_s, m.gamma1_mm, m.theta1_deg, m.contact_radius_mm)
            .with_errors(m.gamma1_sd_mm, m.theta1_std_deg)
            .with_common_error(m.gamma1_common_sd_mm)),
        Err(SensingError::NoContact { .. }) => Ok(GaugeReading::new(frame.t_s, 0.0, 0.0, 0.0)),
        Err(e) => Err(e.to_string()),
    }
}

/// The gauge the sequencer reads: the sensor link plus [`measure_frame`].
pub type RigGauge = SensorGauge<SensorDriver, MeasureFn>;

/// The frame-measuring function of a [`RigGauge`]: [`measure_frame`] with the
/// rig's estimator.
pub type MeasureFn = Box<dyn FnMut(&SensorFrame) -> Result<GaugeReading, String> + Send>;

/// The opened devices of a rig.
pub struct RigDevices {
    pub stage: DynStage,
    pub rotation: DynMount,
    pub gauge: RigGauge,
}

/// Open the stage through its driver (identify is the sequencer's first step).
pub async fn open_stage(spec: &StageSpec) -> Result<DynStage, ConnectError> {
    spec.open().await.map_err(|source| ConnectError::Stage { path: spec.path.display().to_string(), source })
}

/// Open the rotation mount through its driver.
pub async fn open_rotation(spec: &RotationSpec) -> Result<DynMount, ConnectError> {
    spec.open().await.map_err(|source| ConnectError::Rotation { path: spec.path.display().to_string(), source })
}

/// Frames the sensor link holds for the gauge. The sequencer wants the
/// elastomer's state *now*: a longer queue would hand it frames taken while
/// the stage was still moving, and a few stale frames agree with each other
/// well enough to pass as settled. Older frames are dropped (and counted).
pub const GAUGE_QUEUE: usize = 1;

/// Open the sensor link (streaming starts in the sequencer's connect step).
pub async fn open_sensor(spec: &SensorSpec) -> Result<SensorDriver, ConnectError> {
    let err = |source| ConnectError::Sensor { what: spec.describe(), source };
    let link: Box<dyn SensorLink> = match spec {
        SensorSpec::LinkSerial { path, baud } => {
            let path = path.to_str().ok_or_else(|| ConnectError::SensorPath { what: spec.describe() })?;
            Box::new(LinkReceiver::open_serial(path, *baud, link_cfg()).map_err(err)?)
        }
        SensorSpec::LinkUdp { bind, device } => {
            Box::new(LinkReceiver::udp(*bind, *device, link_cfg()).await.map_err(err)?)
        }
        SensorSpec::Tac3d { bind, source } => {
            let cfg = Tac3dReceiverConfig {
                bind: *bind,
                source: *source,
                queue_capacity: GAUGE_QUEUE,
                ..Tac3dReceiverConfig::default()
            };
            Box::new(Tac3dReceiver::bind(cfg).await.map_err(err)?)
        }
    };
    Ok(SensorDriver(link))
}

fn link_cfg() -> LinkConfig {
    LinkConfig { queue_capacity: GAUGE_QUEUE, ..LinkConfig::default() }
}

/// Open every device of the rig; frames are measured with `sensing`.
pub async fn open_rig(spec: &RigSpec, sensing: SensingConfig) -> Result<RigDevices, ConnectError> {
    let stage = open_stage(&spec.stage).await?;
    let rotation = open_rotation(&spec.rotation).await?;
    let sensor = open_sensor(&spec.sensor).await?;
    let mut estimator = FrameEstimator::new(sensing);
    let measure: MeasureFn = Box::new(move |frame: &SensorFrame| measure_frame(&mut estimator, frame));
    let gauge = SensorGauge::new(sensor, measure, spec.sensor_name.clone());
    Ok(RigDevices { stage, rotation, gauge })
}
