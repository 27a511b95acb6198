//! The whole emulated rig, served as a real one is reached: one mechanical
//! rig on a virtual clock, an APT KDC101 + Z825 stage (or a GRBL stage) and an
//! APT K10CR1 rotation mount on pseudo-terminals, and the simulated sensor
//! streaming through easycalib's link protocol on a third pty (or as a Tac3D
//! over UDP). Everything simulated comes from one [`SimSetup`]; drivers open
//! the device paths exactly as they would open a real rig's.

use std::io;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use super::tac3d::{Tac3dSender, Tac3dSenderConfig};

use super::apt::{EmulatorHandle, InjectedError, k10cr1_axis_at, spawn_apt_rotation, spawn_apt_stage, z8_axis};
use super::grbl::{GrblEmulatorConfig, GrblPort, serve_grbl_stage, stepper_stage_axis};
use super::pty::PtyMaster;
use super::rig::{Rig, RigPose};
use super::sensor_sink::{LinkPtySink, Tac3dSink};
use crate::clock::VirtualClock;
use crate::effects::EffectError;
use crate::sensor::rig::{RigSensor, SensorSimConfig};
use crate::sensor::stream::{SensorStream, spawn_rig_sensor};
use crate::setup::SimSetup;

/// Travel of the emulated Z825 stage, mm.
pub const STAGE_TRAVEL_MM: f64 = 25.0;
/// Stage position (after homing) where the indenter touches the elastomer,
/// mm: beyond the default script's `approach.start_mm` (10 mm).
pub const CONTACT_STAGE_MM: f64 = 12.0;

/// How the emulated sensor delivers its frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EmulatedSensor {
    /// easycalib's link protocol on a pty (the default).
    LinkPty,
    /// The Tac3D main program's UDP stream, sent to this address.
    Tac3d { to: SocketAddr },
}

/// How the emulated rig is served (what is simulated is the [`SimSetup`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ServeOptions {
    /// Serve the stage as a GRBL controller instead of an APT KDC101.
    pub grbl: bool,
    pub sensor: EmulatedSensor,
    /// Stage position of first contact, mm.
    pub contact_stage_mm: f64,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self { grbl: false, sensor: EmulatedSensor::LinkPty, contact_stage_mm: CONTACT_STAGE_MM }
    }
}

/// Why the emulated rig could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    #[error("cannot open a pseudo-terminal for the emulators: {0}")]
    Pty(#[from] io::Error),
    #[error("cannot build the simulated sensor: {0}")]
    Sensor(#[from] EffectError),
    #[error("cannot open the emulated Tac3D's UDP socket: {0}")]
    Tac3d(#[source] devices::sensor::SensorError),
}

/// The emulated stage's controller, for fault injection.
#[derive(Debug)]
pub enum StageEmulator {
    Apt(EmulatorHandle),
    Grbl(GrblPort),
}

impl StageEmulator {
    pub fn path(&self) -> &Path {
        match self {
            StageEmulator::Apt(h) => h.path(),
            StageEmulator::Grbl(p) => p.path(),
        }
    }

    /// Cut the stage's cable: its pty closes.
    pub fn cut(&self) {
        match self {
            StageEmulator::Apt(h) => h.cut(),
            StageEmulator::Grbl(p) => p.cut_cable(),
        }
    }
}

/// Where the emulated sensor can be reached.
#[derive(Debug, Clone, PartialEq)]
pub enum SensorEndpoint {
    Pty(PathBuf),
    Udp(SocketAddr),
}

/// How far the emulated K10CR1 powers on past its home switch, degrees in
/// [0, 360): a draw from the rig's seed (its own stream, so the sensor's noise
/// is the same as without it). A continuous-rotation mount stops anywhere in
/// a turn; homing turns it back to the switch at 5 deg/s (docs/run.md).
pub fn mount_power_on_deg(seed: u64) -> f64 {
    /// Separates this draw's stream from the sensor noise's (same seed).
    const STREAM: u64 = 0x6b31_3063_7231_0001;
    360.0 * crate::rng::Rng::seed_from(seed ^ STREAM).uniform()
}

/// A running emulated rig. Dropping it stops every emulator.
#[derive(Debug)]
pub struct ServedRig {
    setup: SimSetup,
    rig: Rig,
    stage: StageEmulator,
    rotation: EmulatorHandle,
    sensor: SensorStream,
    sensor_endpoint: SensorEndpoint,
    grbl: bool,
}

impl ServedRig {
    /// Start the emulators for `setup`. Needs a tokio runtime.
    pub async fn start(setup: SimSetup, opts: ServeOptions) -> Result<ServedRig, ServeError> {
        let clock = VirtualClock::new(setup.speedup());
        let stage_axis = if opts.grbl { stepper_stage_axis(STAGE_TRAVEL_MM) } else { z8_axis(STAGE_TRAVEL_MM) };
        let rig = Rig::new(clock, stage_axis, k10cr1_axis_at(mount_power_on_deg(setup.seed())));
        let stage = if opts.grbl {
            StageEmulator::Grbl(serve_grbl_stage(rig.clone(), GrblEmulatorConfig::default()).await?)
        } else {
            StageEmulator::Apt(spawn_apt_stage(rig.clone())?)
        };
        let rotation = spawn_apt_rotation(rig.clone())?;
        let cfg = SensorSimConfig {
            setup: setup.clone(),
            contact_stage_mm: opts.contact_stage_mm,
            ..SensorSimConfig::default()
        };
        let sensor_model = RigSensor::new(rig.clone(), cfg)?;
        let (sensor, sensor_endpoint) = match opts.sensor {
            EmulatedSensor::LinkPty => {
                let pty = PtyMaster::open()?;
                let path = pty.slave_path().to_path_buf();
                let sink = LinkPtySink::new(pty, &path)?;
                (spawn_rig_sensor(sensor_model, sink), SensorEndpoint::Pty(path))
            }
            EmulatedSensor::Tac3d { to } => {
                let bind = SocketAddr::new(to.ip(), 0);
                let sender =
                    Tac3dSender::bind(bind, to, Tac3dSenderConfig::default()).await.map_err(ServeError::Tac3d)?;
                (spawn_rig_sensor(sensor_model, Tac3dSink(sender)), SensorEndpoint::Udp(to))
            }
        };
        Ok(ServedRig { setup, rig, stage, rotation, sensor, sensor_endpoint, grbl: opts.grbl })
    }

    /// What is simulated: the set-up the rig was started with.
    pub fn setup(&self) -> &SimSetup {
        &self.setup
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// Where the indenter is now.
    pub fn pose(&self) -> RigPose {
        self.rig.pose()
    }

    pub fn speedup(&self) -> f64 {
        self.rig.clock().speedup()
    }

    /// True when the stage is served as a GRBL controller.
    pub fn is_grbl(&self) -> bool {
        self.grbl
    }

    pub fn stage(&self) -> &StageEmulator {
        &self.stage
    }

    pub fn rotation(&self) -> &EmulatorHandle {
        &self.rotation
    }

    /// Frames the simulated sensor drew as the clean contact because the
    /// set-up's effect model failed there (e.g. gross slip): 0 when the run
    /// saw every effect it was given.
    pub fn effect_failures(&self) -> u64 {
        self.sensor.effect_failures()
    }

    pub fn sensor_endpoint(&self) -> &SensorEndpoint {
        &self.sensor_endpoint
    }

    /// Cut the stage's cable (its pty closes).
    pub fn cut_stage(&self) {
        self.stage.cut();
    }

    /// Make the APT stage report a device error (`false` for a GRBL stage).
    pub fn inject_stage_error(&self, e: InjectedError) -> bool {
        match &self.stage {
            StageEmulator::Apt(h) => {
                h.inject_error(e);
                true
            }
            StageEmulator::Grbl(_) => false,
        }
    }

    /// Make the GRBL stage raise `ALARM:code` (`false` for an APT stage).
    pub fn inject_stage_alarm(&self, code: u8) -> bool {
        match &self.stage {
            StageEmulator::Grbl(p) => {
                p.inject_alarm(code);
                true
            }
            StageEmulator::Apt(_) => false,
        }
    }

    /// Silence the sensor (frames stop; the sensor's counter keeps going).
    pub fn silence_sensor(&self, on: bool) {
        self.sensor.set_silenced(on);
    }

    /// The simulated sensor's indenter mount: an operator step on the
    /// emulated rig mounts its indenter through it (the simulation plays the operator).
    pub fn indenter_mount(&self) -> crate::sensor::rig::IndenterMount {
        self.sensor.indenter_mount()
    }

    /// One line per device, `NAME PATH`, as `easycalib sim serve` prints them.
    pub fn device_lines(&self) -> Vec<String> {
        let sensor = match &self.sensor_endpoint {
            SensorEndpoint::Pty(p) => p.display().to_string(),
            SensorEndpoint::Udp(a) => format!("udp://{a}"),
        };
        vec![
            format!("stage {}", self.stage.path().display()),
            format!("rotation {}", self.rotation.path().display()),
            format!("sensor {sensor}"),
        ]
    }
}
