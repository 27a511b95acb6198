//! Opening a rig's devices from where they are: serial paths for the stage and
//! the rotation mount, a serial path or a UDP address for the sensor. The same
//! code opens the emulated rig's pseudo-terminals and a real rig's USB ports,
//! so what the tests exercise is what runs on hardware.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use async_trait::async_trait;
use devices::apt::{AptConfig, AptError, AptRotation, AptStage};
use devices::grbl::{GrblConfig, GrblError, GrblStage};
use devices::motion::{AxisStatus, DeviceFault, DeviceInfo, FaultKind, Identify, LinearStage};
use devices::sensor::link::{LinkConfig, LinkReceiver};
use devices::sensor::tac3d::{Tac3dReceiver, Tac3dReceiverConfig};
use devices::sensor::{LinkStats, SensorError, SensorFrame, SensorLink};
use devices::serial::{open_serial, open_serial_settle};
use tokio_serial::SerialStream;

use crate::run::gauge::SensorGauge;
use crate::sensing::{SensingConfig, SensingError, measure};

/// Where the stage is and which driver speaks to it.
#[derive(Debug, Clone, PartialEq)]
pub enum StageSpec {
    /// Thorlabs APT (KDC101 + Z8 actuator).
    Apt { path: PathBuf, cfg: AptConfig },
    /// A GRBL 1.1 controller driving a stepper micrometer.
    Grbl { path: PathBuf, cfg: GrblConfig },
}

impl StageSpec {
    pub fn path(&self) -> &std::path::Path {
        match self {
            StageSpec::Apt { path, .. } | StageSpec::Grbl { path, .. } => path,
        }
    }
}

/// Where the rotation mount (APT K10CR1) is.
#[derive(Debug, Clone, PartialEq)]
pub struct RotationSpec {
    pub path: PathBuf,
    pub cfg: AptConfig,
}

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
#[derive(Debug, Clone, PartialEq)]
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
    #[error("stage at {path}: {message}")]
    Stage { path: String, message: String },
    #[error("rotation mount at {path}: {message}")]
    Rotation { path: String, message: String },
    #[error("sensor ({what}): {message}")]
    Sensor { what: String, message: String },
}

/// Longest wait for a stopped stage to come to rest (a Z8 decelerates from
/// full speed in well under a second).
const STOP_WAIT: Duration = Duration::from_secs(5);

/// The stage, whichever driver it needs.
pub enum StageKind {
    Apt(AptStage<SerialStream>),
    Grbl(GrblStage<SerialStream>),
}

/// The stage as the sequencer sees it: the driver, plus a check that a move
/// really ended where it was sent. A driver may take a completion message
/// that belongs to an earlier move (or to a stop) for the end of the current
/// one; the sequencer would then read the sensor before the stage has even
/// started, get steady readings of the old depth, and record them at the new
/// position. So after the driver's wait, the position is checked against the
/// target, and the wait goes on (by status polls) until the stage is there,
/// stands still somewhere else for [`STALL_GRACE`], or the timeout ends.
pub struct StageDriver {
    pub kind: StageKind,
    target: Option<f64>,
}

impl StageDriver {
    pub fn new(kind: StageKind) -> Self {
        Self { kind, target: None }
    }
}

/// Distance from the target within which a move counts as arrived, mm
/// (tens of encoder counts or microsteps).
const ARRIVED_MM: f64 = 1e-3;
/// A stage standing still away from its target this long (wall time) has
/// stopped short (a limit, a stop): its position is returned as it is.
const STALL_GRACE: Duration = Duration::from_millis(300);
/// Status poll period while checking arrival.
const ARRIVAL_POLL: Duration = Duration::from_millis(2);

/// A stage driver's error.
#[derive(Debug, thiserror::Error)]
pub enum StageError {
    #[error("APT: {0}")]
    Apt(#[from] AptError),
    #[error("GRBL: {0}")]
    Grbl(#[from] GrblError),
}

impl DeviceFault for StageError {
    fn kind(&self) -> FaultKind {
        match self {
            StageError::Apt(e) => e.kind(),
            StageError::Grbl(e) => e.kind(),
        }
    }
}

/// Delegate one async call to whichever driver is inside, mapping its error.
macro_rules! delegate {
    ($self:ident, $d:ident => $call:expr) => {
        match &mut $self.kind {
            StageKind::Apt($d) => $call.await.map_err(StageError::from),
            StageKind::Grbl($d) => $call.await.map_err(StageError::from),
        }
    };
}

#[async_trait]
impl Identify for StageDriver {
    type Error = StageError;
    async fn identify(&mut self) -> Result<DeviceInfo, StageError> {
        delegate!(self, d => d.identify())
    }
}

#[async_trait]
impl LinearStage for StageDriver {
    type Error = StageError;
    fn travel_mm(&self) -> (f64, f64) {
        match &self.kind {
            StageKind::Apt(d) => d.travel_mm(),
            StageKind::Grbl(d) => d.travel_mm(),
        }
    }
    async fn home(&mut self, timeout: Duration) -> Result<(), StageError> {
        self.target = None;
        delegate!(self, d => d.home(timeout))
    }
    async fn start_move_to_mm(&mut self, target_mm: f64) -> Result<(), StageError> {
        self.target = None;
        delegate!(self, d => d.start_move_to_mm(target_mm))?;
        self.target = Some(target_mm);
        Ok(())
    }
    async fn start_move_by_mm(&mut self, delta_mm: f64) -> Result<(), StageError> {
        self.target = None;
        delegate!(self, d => d.start_move_by_mm(delta_mm))
    }
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<f64, StageError> {
        let deadline = tokio::time::Instant::now() + timeout;
        let mut p = delegate!(self, d => d.wait_until_stopped(timeout))?;
        let Some(target) = self.target.take() else { return Ok(p) };
        let mut still_since: Option<tokio::time::Instant> = None;
        while (p - target).abs() > ARRIVED_MM {
            let now = tokio::time::Instant::now();
            if now >= deadline || still_since.is_some_and(|t| now.duration_since(t) >= STALL_GRACE) {
                break;
            }
            tokio::time::sleep(ARRIVAL_POLL).await;
            let s = delegate!(self, d => d.status())?;
            p = s.position;
            if s.moving {
                still_since = None;
            } else if still_since.is_none() {
                still_since = Some(tokio::time::Instant::now());
            }
        }
        Ok(p)
    }
    /// Stop and wait until the axis is at rest. The APT driver's stop only
    /// sends MOT_MOVE_STOP; a move commanded right after it (the backing off
    /// of an abort) could otherwise take that stop's late answer for its own
    /// end and report the stage backed off while it is still in contact.
    async fn stop(&mut self) -> Result<(), StageError> {
        self.target = None;
        match &mut self.kind {
            StageKind::Apt(d) => {
                d.stop().await?;
                d.wait_until_stopped(STOP_WAIT).await?;
                Ok(())
            }
            StageKind::Grbl(d) => {
                d.stop().await?;
                // An alarm leaves GRBL locked, and the indenter pressed into
                // the elastomer. The sequencer stops only to abort, and its
                // next move is the back-off, away from the sensor: unlock
                // ($X) so it can move. The position may be off after a limit
                // alarm (the abort message says so); re-home before the next run.
                if d.alarm().is_some() {
                    d.unlock().await?;
                }
                Ok(())
            }
        }
    }
    async fn position_mm(&mut self) -> Result<f64, StageError> {
        delegate!(self, d => d.position_mm())
    }
    async fn status(&mut self) -> Result<AxisStatus, StageError> {
        delegate!(self, d => d.status())
    }
}

/// The sensor, whichever link it uses.
#[derive(Debug)]
pub enum SensorDriver {
    Link(LinkReceiver),
    Tac3d(Tac3dReceiver),
}

macro_rules! delegate_sensor {
    ($self:ident, $d:ident => $call:expr) => {
        match $self {
            SensorDriver::Link($d) => $call,
            SensorDriver::Tac3d($d) => $call,
        }
    };
}

#[async_trait]
impl SensorLink for SensorDriver {
    async fn start(&mut self) -> Result<(), SensorError> {
        delegate_sensor!(self, d => d.start().await)
    }
    async fn stop(&mut self) -> Result<(), SensorError> {
        delegate_sensor!(self, d => d.stop().await)
    }
    async fn next_frame(&mut self, timeout: Duration) -> Result<SensorFrame, SensorError> {
        delegate_sensor!(self, d => d.next_frame(timeout).await)
    }
    async fn tare(&mut self) -> Result<(), SensorError> {
        delegate_sensor!(self, d => d.tare().await)
    }
    fn stats(&self) -> LinkStats {
        delegate_sensor!(self, d => d.stats())
    }
}

/// gamma1, theta1 and the contact radius of one frame. A frame without
/// contact is a valid reading of zero: the sequencer needs readings out of
/// contact to find the contact.
pub fn measure_frame(frame: &SensorFrame, cfg: &SensingConfig) -> Result<(f64, f64, f64), String> {
    match measure(frame, cfg) {
        Ok(m) => Ok((m.gamma1_mm, m.theta1_deg, m.contact_radius_mm)),
        Err(SensingError::NoContact { .. }) => Ok((0.0, 0.0, 0.0)),
        Err(e) => Err(e.to_string()),
    }
}

/// The gauge the sequencer reads: the sensor link plus [`measure_frame`].
pub type RigGauge = SensorGauge<SensorDriver, MeasureFn>;

/// The frame-measuring function of a [`RigGauge`]: [`measure_frame`] with the
/// rig's sensing settings.
pub type MeasureFn = Box<dyn Fn(&SensorFrame) -> Result<(f64, f64, f64), String> + Send + Sync>;

/// The opened devices of a rig.
pub struct RigDevices {
    pub stage: StageDriver,
    pub rotation: AptRotation<SerialStream>,
    pub gauge: RigGauge,
}

/// A serial port: an emulator's pty opens without the settle delay a USB
/// adapter needs (the delay is for boards that reset when the port opens).
async fn serial(path: &std::path::Path) -> std::io::Result<SerialStream> {
    if path.starts_with("/dev/pts") { open_serial_settle(path, Duration::ZERO).await } else { open_serial(path).await }
}

/// Open the stage (identify is the sequencer's first step).
pub async fn open_stage(spec: &StageSpec) -> Result<StageDriver, ConnectError> {
    let err = |message: String| ConnectError::Stage { path: spec.path().display().to_string(), message };
    match spec {
        StageSpec::Apt { path, cfg } => {
            let io = serial(path).await.map_err(|e| err(format!("cannot open the port: {e}")))?;
            let stage = AptStage::connect(io, cfg.clone()).await.map_err(|e| err(format!("APT connect: {e}")))?;
            Ok(StageDriver::new(StageKind::Apt(stage)))
        }
        StageSpec::Grbl { path, cfg } => {
            let stage = GrblStage::open(path, cfg.clone()).await.map_err(|e| err(format!("GRBL connect: {e}")))?;
            Ok(StageDriver::new(StageKind::Grbl(stage)))
        }
    }
}

/// Open the rotation mount.
pub async fn open_rotation(spec: &RotationSpec) -> Result<AptRotation<SerialStream>, ConnectError> {
    let err = |message: String| ConnectError::Rotation { path: spec.path.display().to_string(), message };
    let io = serial(&spec.path).await.map_err(|e| err(format!("cannot open the port: {e}")))?;
    AptRotation::connect(io, spec.cfg.clone()).await.map_err(|e| err(format!("APT connect: {e}")))
}

/// Frames the sensor link holds for the gauge. The sequencer wants the
/// elastomer's state *now*: a longer queue would hand it frames taken while
/// the stage was still moving, and a few stale frames agree with each other
/// well enough to pass as settled. Older frames are dropped (and counted).
pub const GAUGE_QUEUE: usize = 1;

/// Open the sensor link (streaming starts in the sequencer's connect step).
pub async fn open_sensor(spec: &SensorSpec) -> Result<SensorDriver, ConnectError> {
    let err = |message: String| ConnectError::Sensor { what: spec.describe(), message };
    match spec {
        SensorSpec::LinkSerial { path, baud } => {
            let path = path.to_str().ok_or_else(|| err("the path is not valid UTF-8".into()))?;
            let link = LinkReceiver::open_serial(path, *baud, link_cfg()).map_err(|e| err(e.to_string()))?;
            Ok(SensorDriver::Link(link))
        }
        SensorSpec::LinkUdp { bind, device } => {
            let link = LinkReceiver::udp(*bind, *device, link_cfg()).await.map_err(|e| err(e.to_string()))?;
            Ok(SensorDriver::Link(link))
        }
        SensorSpec::Tac3d { bind, source } => {
            let cfg = Tac3dReceiverConfig {
                bind: *bind,
                source: *source,
                queue_capacity: GAUGE_QUEUE,
                ..Tac3dReceiverConfig::default()
            };
            let rx = Tac3dReceiver::bind(cfg).await.map_err(|e| err(e.to_string()))?;
            Ok(SensorDriver::Tac3d(rx))
        }
    }
}

fn link_cfg() -> LinkConfig {
    LinkConfig { queue_capacity: GAUGE_QUEUE, ..LinkConfig::default() }
}

/// Open every device of the rig; frames are measured with `sensing`.
pub async fn open_rig(spec: &RigSpec, sensing: SensingConfig) -> Result<RigDevices, ConnectError> {
    let stage = open_stage(&spec.stage).await?;
    let rotation = open_rotation(&spec.rotation).await?;
    let sensor = open_sensor(&spec.sensor).await?;
    let measure: MeasureFn = Box::new(move |frame: &SensorFrame| measure_frame(frame, &sensing));
    let gauge = SensorGauge::new(sensor, measure, spec.sensor_name.clone());
    Ok(RigDevices { stage, rotation, gauge })
}
