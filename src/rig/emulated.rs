//! The built-in emulated rig: one mechanical rig on a virtual clock, an APT
//! KDC101 + Z825 stage (or a GRBL stage) and an APT K10CR1 rotation mount on
//! pseudo-terminals, and the simulated sensor streaming through easycalib's
//! link protocol on a third pty (or as a Tac3D over UDP). The run opens it
//! with the real drivers from its [`RigSpec`], exactly as a real rig.

use std::io;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

use devices::apt::AptConfig;
use devices::grbl::GrblConfig;
use devices::sensor::SensorFrame;
use devices::sensor::link::LinkCommand;
use sim::clock::VirtualClock;
use sim::effects::{EffectError, SimProfile};
use sim::emulator::apt::{EmulatorHandle, InjectedError, k10cr1_axis, spawn_apt_rotation, spawn_apt_stage, z8_axis};
use sim::emulator::grbl::{GrblEmulatorConfig, GrblPort, serve_grbl_stage, stepper_stage_axis};
use sim::emulator::pty::PtyMaster;
use sim::emulator::rig::{Rig, RigPose};
use sim::emulator::sensor_link::LinkDevice;
use sim::emulator::tac3d::{Tac3dSender, Tac3dSenderConfig};
use sim::physics::ContactPair;
use sim::sensor::rig::RigSensor;
use sim::sensor::rig::SensorSimConfig;
use sim::sensor::stream::{FrameSink, SensorStream, SinkError, spawn_rig_sensor};

use super::connect::{RigSpec, RotationSpec, SensorSpec, StageSpec};
use crate::report::Truth;

/// Travel of the emulated Z825 stage, mm.
pub const STAGE_TRAVEL_MM: f64 = 25.0;
/// Stage position (after homing) where the indenter touches the elastomer,
/// mm: beyond the default script's `approach.start_mm` (10 mm).
pub const CONTACT_STAGE_MM: f64 = 12.0;
/// Default time acceleration of the emulated rig.
pub const DEFAULT_SPEEDUP: f64 = 40.0;

/// How the emulated sensor delivers its frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EmulatedSensor {
    /// easycalib's link protocol on a pty (the default).
    LinkPty,
    /// The Tac3D main program's UDP stream, sent to this address.
    Tac3d { to: SocketAddr },
}

#[derive(Debug, Clone, PartialEq)]
pub struct EmulatedRigOptions {
    /// Rig time runs this many times faster than wall time (1 = real time).
    pub speedup: f64,
    /// Serve the stage as a GRBL controller instead of an APT KDC101.
    pub grbl: bool,
    /// The simulated elastomer and indenter.
    pub pair: ContactPair,
    /// Seed of the simulated sensor's noise.
    pub seed: u64,
    pub sensor: EmulatedSensor,
    /// Stage position of first contact, mm.
    pub contact_stage_mm: f64,
    /// Left-out physics the simulated contact has (e.g. what `easycalib
    /// diagnose --profile-out` found in a real recording); clean by default.
    pub profile: SimProfile,
}

impl Default for EmulatedRigOptions {
    fn default() -> Self {
        Self {
            speedup: DEFAULT_SPEEDUP,
            grbl: false,
            pair: SensorSimConfig::default().pair,
            seed: 1,
            sensor: EmulatedSensor::LinkPty,
            contact_stage_mm: CONTACT_STAGE_MM,
            profile: SimProfile::default(),
        }
    }
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

/// A running emulated rig. Dropping it stops every emulator.
#[derive(Debug)]
pub struct EmulatedRig {
    rig: Rig,
    stage: StageEmulator,
    rotation: EmulatorHandle,
    sensor: SensorStream,
    sensor_endpoint: SensorEndpoint,
    truth: Truth,
    grbl: bool,
}

/// The GRBL build's stage: a 1/6400 mm stepper micrometer, 2 mm/s.
impl EmulatedRig {
    /// Start the emulators. Needs a tokio runtime.
    pub async fn start(opts: EmulatedRigOptions) -> io::Result<EmulatedRig> {
        if !(opts.speedup.is_finite() && opts.speedup > 0.0) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("speed-up must be a positive number, got {}", opts.speedup),
            ));
        }
        opts.pair.validate().map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e.to_string()))?;
        let clock = VirtualClock::new(opts.speedup);
        let stage_axis = if opts.grbl { stepper_stage_axis(STAGE_TRAVEL_MM) } else { z8_axis(STAGE_TRAVEL_MM) };
        let rig = Rig::new(clock, stage_axis, k10cr1_axis());
        let stage = if opts.grbl {
            StageEmulator::Grbl(serve_grbl_stage(rig.clone(), GrblEmulatorConfig::default()).await?)
        } else {
            StageEmulator::Apt(spawn_apt_stage(rig.clone())?)
        };
        let rotation = spawn_apt_rotation(rig.clone())?;
        let cfg = SensorSimConfig {
            pair: opts.pair,
            contact_stage_mm: opts.contact_stage_mm,
            seed: opts.seed,
            ..SensorSimConfig::default()
        };
        let bad = |e: sim::physics::ParamError| io::Error::new(io::ErrorKind::InvalidInput, e.to_string());
        let invalid = |e: EffectError| io::Error::new(io::ErrorKind::InvalidInput, format!("sim profile: {e}"));
        let sensor_model =
            RigSensor::new(rig.clone(), cfg).map_err(bad)?.with_profile(&opts.profile).map_err(invalid)?;
        // A profile's `material` replaces the elastomer: that is the truth now.
        let effective = *sensor_model.pair();
        let (sensor, sensor_endpoint) = match opts.sensor {
            EmulatedSensor::LinkPty => {
                let pty = PtyMaster::open()?;
                let path = pty.slave_path().to_path_buf();
                let backlog = SlaveBacklog::open(&path)?;
                let sink = LinkPtySink { device: LinkDevice::new(pty), streaming: false, backlog };
                (spawn_rig_sensor(sensor_model, sink), SensorEndpoint::Pty(path))
            }
            EmulatedSensor::Tac3d { to } => {
                let bind = SocketAddr::new(to.ip(), 0);
                let sender = Tac3dSender::bind(bind, to, Tac3dSenderConfig::default())
                    .await
                    .map_err(|e| io::Error::other(e.to_string()))?;
                (spawn_rig_sensor(sensor_model, Tac3dSink(sender)), SensorEndpoint::Udp(to))
            }
        };
        let truth = Truth { e1_mpa: effective.elastomer.e_mpa, nu1: effective.elastomer.nu };
        Ok(EmulatedRig { rig, stage, rotation, sensor, sensor_endpoint, truth, grbl: opts.grbl })
    }

    /// How the real drivers reach this rig. Poll periods are shortened to
    /// the rig's time acceleration (moves finish `speedup` times sooner);
    /// every timeout stays a real wall-clock one.
    pub fn spec(&self) -> RigSpec {
        let speedup = self.rig.clock().speedup();
        let poll = |base: Duration| base.div_f64(speedup.max(1.0)).max(Duration::from_millis(2));
        let stage = if self.grbl {
            let cfg = GrblConfig {
                travel_mm: (0.0, STAGE_TRAVEL_MM),
                feed_mm_per_min: 120.0,
                poll_interval: poll(Duration::from_millis(100)),
                ..GrblConfig::default()
            };
            StageSpec::Grbl { path: self.stage.path().to_path_buf(), cfg }
        } else {
            let base = AptConfig::kdc101_z825b();
            let cfg = AptConfig { poll_period: poll(base.poll_period), ..base };
            StageSpec::Apt { path: self.stage.path().to_path_buf(), cfg }
        };
        let base = AptConfig::k10cr1();
        let rotation = RotationSpec {
            path: self.rotation.path().to_path_buf(),
            cfg: AptConfig { poll_period: poll(base.poll_period), ..base },
        };
        let sensor = match &self.sensor_endpoint {
            SensorEndpoint::Pty(path) => SensorSpec::LinkSerial { path: path.clone(), baud: 115_200 },
            SensorEndpoint::Udp(to) => SensorSpec::Tac3d { bind: *to, source: None },
        };
        RigSpec { stage, rotation, sensor, sensor_name: "sim-sensor".into() }
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

    /// The simulated elastomer's true E1 and nu1.
    pub fn truth(&self) -> Truth {
        self.truth
    }

    pub fn stage(&self) -> &StageEmulator {
        &self.stage
    }

    pub fn rotation(&self) -> &EmulatorHandle {
        &self.rotation
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

/// The simulated sensor's side of easycalib's link protocol on a pty: answers
/// START / STOP / TARE with acknowledgements and sends frames only while
/// started, as a bridge program does. Commands are polled between frames;
/// [`LinkDevice::next_command`] is cancel-safe, so a pending partial command
/// is kept for the next poll.
struct LinkPtySink {
    device: LinkDevice,
    streaming: bool,
    backlog: SlaveBacklog,
}

/// Bytes written to the pty that its reader has not taken yet (FIONREAD on
/// a descriptor of the slave side, which is never read from).
///
/// Why: time acceleration multiplies the link's wall-clock latency into rig
/// time. A producer that outpaces the reader fills the pty buffer (several
/// 10 kB frames), and every frame the host then reads is that many frames
/// old: at 50x a few milliseconds of backlog are a whole stage step, and a
/// run of stale frames agrees with itself well enough to pass as settled. A
/// real sensor on a slow link drops frames rather than queueing them; so
/// does this one, and the host sees the gaps as dropped frames.
struct SlaveBacklog(std::fs::File);

impl SlaveBacklog {
    fn open(path: &Path) -> io::Result<Self> {
        use std::os::unix::fs::OpenOptionsExt;
        let f = std::fs::OpenOptions::new().read(true).write(true).custom_flags(libc::O_NOCTTY).open(path)?;
        Ok(Self(f))
    }

    fn bytes(&self) -> usize {
        use std::os::fd::AsRawFd;
        let mut n: libc::c_int = 0;
        // SAFETY: FIONREAD writes one c_int through the pointer; the fd is ours and open.
        let rc = unsafe { libc::ioctl(self.0.as_raw_fd(), libc::FIONREAD, &mut n) };
        if rc < 0 { 0 } else { n.max(0) as usize }
    }
}

impl LinkPtySink {
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
            self.device.ack(cmd).await.map_err(|e| SinkError::Other(e.to_string()))?;
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
                r.map_err(|e| SinkError::Other(e.to_string()))?;
            }
        }
        Ok(())
    }
}

/// Unread bytes in the pty above which a frame is dropped: less than one
/// frame of the default 20 x 20 marker grid (about 9.7 kB).
const MAX_BACKLOG_BYTES: usize = 4096;

/// Longest a frame may wait for room in the pty before it is dropped.
const FRAME_WRITE_TIMEOUT: Duration = Duration::from_millis(200);

/// Frames as the Tac3D main program sends them.
struct Tac3dSink(Tac3dSender);

impl FrameSink for Tac3dSink {
    async fn send(&mut self, frame: &SensorFrame) -> Result<(), SinkError> {
        self.0.send(frame).await.map_err(|e| SinkError::Other(e.to_string()))
    }
}
