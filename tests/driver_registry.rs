//! A third stage driver, defined here and nowhere else, registered at the one
//! registration point (`easycalib::rig::drivers`, a [`Driver`] entry) and
//! driven exactly as `easycalib run --rig` drives a rig: the rig file is read
//! against the registry, turned into a spec, opened, and run by the sequencer
//! through `run_calibration`; the recording is fitted.
//!
//! The driver speaks a small text protocol over a loopback TCP connection to
//! a device task that moves the emulated rig's stage, so the simulated sensor
//! sees the indentation; the rotation mount (APT) and the sensor (link
//! protocol) are the emulated rig's, named in the same rig file.

use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use async_trait::async_trait;
use devices::motion::arrival::{self, deadline_after};
use devices::{Axis, AxisStatus, DeviceFault, DeviceInfo, DynAxis, FaultKind, Identify, Mm};
use easycalib::rig::drivers::{Driver, Drivers, Keys, OpenAxis, OpenError};
use easycalib::rig::emulated::{EmulatedRig, SensorEndpoint, ServeOptions};
use easycalib::rig::{ConfigError, RigConfig, RunRequest, run_calibration};
use easycalib::run::{RunStatus, Script};
use sim::emulator::rig::Rig;
use sim::recording::Recording;
use sim::setup::SimSetupInput;
use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc::unbounded_channel;

// ---- the driver: what a new driver's author writes --------------------------

/// The loop driver's error.
#[derive(Debug, thiserror::Error)]
enum LoopError {
    #[error("loop stage link: {0}")]
    Io(#[from] std::io::Error),
    #[error("loop stage refused {command:?}: {reply}")]
    Refused { command: String, reply: String },
    #[error("loop stage did not stop within {0:?}")]
    Timeout(Duration),
}

impl DeviceFault for LoopError {
    fn kind(&self) -> FaultKind {
        match self {
            LoopError::Io(_) => FaultKind::Disconnected,
            LoopError::Refused { .. } => FaultKind::DeviceReported,
            LoopError::Timeout(_) => FaultKind::Timeout,
        }
    }
}

/// A stage on a line protocol: `ID?`, `HOME`, `MOVE mm`, `STOP`, `STATE?`.
struct LoopStage<T> {
    io: BufReader<T>,
    travel_mm: (f64, f64),
    target: Option<Mm>,
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send> LoopStage<T> {
    async fn ask(&mut self, command: &str) -> Result<String, LoopError> {
        self.io.get_mut().write_all(format!("{command}\n").as_bytes()).await?;
        let mut reply = String::new();
        if self.io.read_line(&mut reply).await? == 0 {
            return Err(std::io::Error::from(std::io::ErrorKind::UnexpectedEof).into());
        }
        let reply = reply.trim_end().to_string();
        if reply.starts_with("ERR") {
            return Err(LoopError::Refused { command: command.into(), reply });
        }
        Ok(reply)
    }

    /// Poll until the stage stands still.
    async fn until_still(&mut self, timeout: Duration) -> Result<AxisStatus, LoopError> {
        let deadline = deadline_after(timeout);
        loop {
            let s = self.status().await?;
            if !s.moving {
                return Ok(s);
            }
            if tokio::time::Instant::now() >= deadline {
                return Err(LoopError::Timeout(timeout));
            }
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Identify for LoopStage<T> {
    type Error = LoopError;
    async fn identify(&mut self) -> Result<DeviceInfo, LoopError> {
        let id = self.ask("ID?").await?;
        let mut words = id.split_whitespace().map(String::from);
        let (model, serial, firmware) = (words.next(), words.next(), words.next());
        Ok(DeviceInfo {
            model: model.unwrap_or_default(),
            serial: serial.unwrap_or_default(),
            firmware: firmware.unwrap_or_default(),
        })
    }
}

#[async_trait]
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Axis for LoopStage<T> {
    type Unit = Mm;
    fn travel(&self) -> (Mm, Mm) {
        (Mm(self.travel_mm.0), Mm(self.travel_mm.1))
    }
    async fn home(&mut self, timeout: Duration) -> Result<(), LoopError> {
        self.target = None;
        self.ask("HOME").await?;
        self.until_still(timeout).await.map(|_| ())
    }
    async fn start_move_to(&mut self, target: Mm) -> Result<(), LoopError> {
        self.target = None;
        self.ask(&format!("MOVE {}", target.0)).await?;
        self.target = Some(target);
        Ok(())
    }
    async fn start_move_by(&mut self, delta: Mm) -> Result<(), LoopError> {
        let here = self.position().await?;
        self.start_move_to(Mm(here.0 + delta.0)).await
    }
    async fn wait_until_stopped(&mut self, timeout: Duration) -> Result<Mm, LoopError> {
        let deadline = deadline_after(timeout);
        let reached = Mm(self.until_still(timeout).await?.position);
        match self.target.take() {
            // The shared check every driver may use: arrived, or standing short of it.
            Some(target) => arrival::confirm(self, target, reached, deadline).await,
            None => Ok(reached),
        }
    }
    async fn stop(&mut self) -> Result<(), LoopError> {
        self.target = None;
        self.ask("STOP").await?;
        self.until_still(arrival::STOP_WAIT).await.map(|_| ())
    }
    async fn position(&mut self) -> Result<Mm, LoopError> {
        Ok(Mm(self.status().await?.position))
    }
    async fn status(&mut self) -> Result<AxisStatus, LoopError> {
        let state = self.ask("STATE?").await?;
        let v: Vec<f64> = state.split_whitespace().filter_map(|w| w.parse().ok()).collect();
        let [position, moving, homed] = v[..] else {
            return Err(LoopError::Refused { command: "STATE?".into(), reply: state });
        };
        Ok(AxisStatus { position, moving: moving != 0.0, homed: homed != 0.0, enabled: true, ..AxisStatus::default() })
    }
}

/// The loop driver's settings: what its `[stage]` keys said.
#[derive(Debug, Clone, PartialEq)]
struct LoopSettings {
    travel_mm: (f64, f64),
}

/// The port is the device's loopback address, e.g. `127.0.0.1:4000`.
#[async_trait]
impl OpenAxis<Mm> for LoopSettings {
    async fn open(&self, path: &Path) -> Result<DynAxis<Mm>, OpenError> {
        let io = TcpStream::connect(path.to_string_lossy().as_ref()).await.map_err(OpenError::Port)?;
        Ok(devices::motion::boxed(LoopStage { io: BufReader::new(io), travel_mm: self.travel_mm, target: None }))
    }
}

/// `travel_mm = [min, max]` (default `[0, 25]`).
fn loop_stage(keys: &mut Keys) -> Result<Arc<dyn OpenAxis<Mm>>, ConfigError> {
    let [lo, hi] = keys.take::<[f64; 2]>("travel_mm")?.unwrap_or([0.0, 25.0]);
    Ok(Arc::new(LoopSettings { travel_mm: (lo, hi) }))
}

/// The registration: one entry.
const LOOP: Driver = Driver { name: "loop", stage: Some(loop_stage), rotation: None };

// ---- the device on the other end of the loopback ---------------------------

/// Serve one connection, moving the emulated rig's stage axis.
async fn serve_loop_stage(listener: TcpListener, rig: Rig) -> std::io::Result<()> {
    let (socket, _) = listener.accept().await?;
    let (rx, mut tx) = socket.into_split();
    let mut lines = BufReader::new(rx).lines();
    while let Some(line) = lines.next_line().await? {
        let mut words = line.split_whitespace();
        let reply = match (words.next(), words.next().map(str::parse::<f64>)) {
            (Some("ID?"), None) => "LOOP-STAGE 42 0.1".to_string(),
            (Some("HOME"), None) => {
                rig.with_stage(|ax, now| ax.command_home(now));
                "OK".into()
            }
            (Some("MOVE"), Some(Ok(mm))) => match rig.with_stage(|ax, now| ax.command_move_to(now, mm)) {
                true => "OK".into(),
                false => format!("ERR {mm} mm is outside the travel"),
            },
            (Some("STOP"), None) => {
                rig.with_stage(|ax, now| ax.command_stop(now, false));
                "OK".into()
            }
            (Some("STATE?"), None) => rig.with_stage(|ax, _| {
                format!("{} {} {}", ax.position(), u8::from(ax.is_moving() || ax.is_homing()), u8::from(ax.is_homed()))
            }),
            _ => format!("ERR unknown command {line:?}"),
        };
        tx.write_all(format!("{reply}\n").as_bytes()).await?;
    }
    Ok(())
}

fn rig_file(stage_addr: &str, rig: &EmulatedRig) -> String {
    let SensorEndpoint::Pty(sensor) = rig.sensor_endpoint() else { panic!("the emulated sensor is on a pty") };
    format!(
        "[stage]\ndriver = \"loop\"\nport = \"{stage_addr}\"\ntravel_mm = [0, 25]\n\
         [rotation]\ndriver = \"apt\"\nport = \"{}\"\n\
         [sensor]\nkind = \"link-serial\"\npath = \"{}\"\nname = \"sim-sensor\"\n",
        rig.rotation().path().display(),
        sensor.display()
    )
}

#[test]
fn a_registered_third_stage_driver_runs_a_calibration_from_a_rig_file() {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    rt.block_on(async {
        let rig = EmulatedRig::start(
            SimSetupInput { speedup: 40.0, ..SimSetupInput::default() }.resolve().unwrap(),
            ServeOptions::default(),
        )
        .await
        .unwrap();
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let device = tokio::spawn(serve_loop_stage(listener, rig.rig().clone()));
        let text = rig_file(&addr, &rig);

        // The built-in registry does not know the driver; registered, it is one of them.
        let e = RigConfig::from_toml(&text).unwrap_err().to_string();
        assert!(e.contains("stage.driver") && e.contains("`loop`"), "{e}");
        let drivers = Drivers::builtin().with(LOOP);
        let spec = RigConfig::from_toml_with(&text, &drivers).unwrap().to_spec_with(&drivers).unwrap();
        assert_eq!(spec.stage.settings::<LoopSettings>(), Some(&LoopSettings { travel_mm: (0.0, 25.0) }));

        let dir = tempfile::tempdir().unwrap();
        let req = RunRequest {
            spec,
            script: Script::default(),
            out_dir: dir.path().to_path_buf(),
            truth: Some(rig.truth()),
            metadata: Vec::new(),
            diagnose: false,
        };
        let (ev_tx, mut ev_rx) = unbounded_channel();
        let (_ctl_tx, ctl_rx) = unbounded_channel();
        let run = tokio::spawn(run_calibration(req, ev_tx, ctl_rx));
        while ev_rx.recv().await.is_some() {}
        let r = run.await.unwrap().expect("the devices open");
        assert_eq!(r.outcome.status, RunStatus::Completed, "{:?}", r.outcome.status);

        // The loop stage ran the run: it is named in the recording, and the
        // stage stands at the park position.
        let rec = Recording::read_path(&r.outcome.recording).unwrap();
        assert!(rec.meta.extra.iter().any(|(k, v)| k == "stage" && v.contains("LOOP-STAGE")), "{:?}", rec.meta.extra);
        assert!((rig.pose().stage_mm - Script::default().park_mm()).abs() < 1e-3, "{:?}", rig.pose());
        // And the calibration recovers the simulated elastomer as with the built-in drivers.
        let (truth, cal) = (rig.truth(), r.calibration.expect("fit"));
        assert!((cal.full.e1_mpa / truth.e1_mpa - 1.0).abs() < 0.01, "E1 {} vs {}", cal.full.e1_mpa, truth.e1_mpa);
        assert!((cal.full.nu1 / truth.nu1 - 1.0).abs() < 0.02, "nu1 {} vs {}", cal.full.nu1, truth.nu1);
        device.abort();
    });
}
