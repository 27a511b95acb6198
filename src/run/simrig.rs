//! An in-process simulated rig: a stage, a rotation mount and a deformation
//! gauge that share one state driven by the contact physics of `sim::physics`
//! (Hertz–Tatara–Yoffe normal contact, Jäger torsion with the rod correction),
//! with seeded noise, a first-order elastomer lag (so settling matters) and
//! injectable faults. Every call answers at once; time is a rig clock that
//! moves and frames advance, so a whole run takes milliseconds of wall time.
//!
//! It fakes the instrument, not a driver: the real drivers over emulators are
//! the other way to run the sequencer. Every commanded target is logged so a
//! test can check it against the soft limits.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use async_trait::async_trait;
use devices::motion::{AxisStatus, DeviceFault, DeviceInfo, FaultKind, Identify, LinearStage, RotationMount};
use sim::physics::{ContactPair, NormalModel, torsion_at};
use sim::rng::Rng;

use super::events::SensorStatus;
use super::gauge::{Gauge, GaugeError, GaugeReading};

/// A simulated device's error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{device}: {message}")]
pub struct SimFault {
    pub device: &'static str,
    pub kind: FaultKind,
    pub message: String,
}

impl DeviceFault for SimFault {
    fn kind(&self) -> FaultKind {
        self.kind
    }
}

/// Faults to inject. Move counts start at 1 and count commanded moves
/// (`start_move_to_*`) of that device; read counts count gauge reads.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SimFaults {
    /// The stage's n-th move fails with this kind; `Disconnected` also kills
    /// every later stage call (a cut cable), other kinds fail that move only.
    pub stage_move: Option<(usize, FaultKind)>,
    pub mount_move: Option<(usize, FaultKind)>,
    /// From the n-th read on, the sensor stream is silent (read timeouts).
    pub sensor_silent_from: Option<usize>,
    /// At the n-th read the sensor link closes.
    pub sensor_closed_at: Option<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimRigConfig {
    pub pair: ContactPair,
    /// Stage position where the indenter first touches the elastomer, mm.
    pub surface_mm: f64,
    pub stage_travel_mm: (f64, f64),
    pub mount_travel_deg: (f64, f64),
    pub stage_power_on_mm: f64,
    /// Speeds used for rig time: stage mm/s, mount deg/s, plus a fixed settle per move.
    pub stage_speed: f64,
    pub mount_speed: f64,
    pub move_overhead_s: f64,
    pub frame_rate_hz: f64,
    /// Time constant of the elastomer's lag behind the indenter, s.
    pub lag_s: f64,
    pub gamma1_sigma_mm: f64,
    pub theta1_sigma_deg: f64,
    pub seed: u64,
    /// Report exact zeros out of contact, as a frame processor that finds no
    /// contact does (the noise at rest then reads as zero).
    pub zero_out_of_contact: bool,
    pub faults: SimFaults,
}

impl Default for SimRigConfig {
    /// The simulator's default elastomer (E1 0.33 MPa, nu1 0.39, R1 33 mm) against the default script's indenter.
    fn default() -> Self {
        Self {
            pair: sim::defaults::pair(),
            surface_mm: 12.0,
            stage_travel_mm: (0.0, 25.0),
            mount_travel_deg: (-170.0, 170.0),
            stage_power_on_mm: 3.0,
            stage_speed: 2.0,
            mount_speed: 20.0,
            move_overhead_s: 0.05,
            frame_rate_hz: 30.0,
            lag_s: 0.05,
            gamma1_sigma_mm: sim::defaults::GAMMA1_SIGMA_MM,
            theta1_sigma_deg: sim::defaults::THETA1_SIGMA_DEG,
            seed: 1,
            zero_out_of_contact: false,
            faults: SimFaults::default(),
        }
    }
}

/// Everything the simulated devices share.
#[derive(Debug)]
pub struct SimState {
    pub cfg: SimRigConfig,
    model: NormalModel,
    rng: Rng,
    pub t_s: f64,
    pub stage_mm: f64,
    pub stage_homed: bool,
    stage_target: Option<f64>,
    pub mount_deg: f64,
    pub mount_homed: bool,
    mount_target: Option<f64>,
    /// What the elastomer shows (lagging the truth).
    shown_gamma1: f64,
    shown_theta1: f64,
    tare: f64,
    stage_dead: bool,
    mount_dead: bool,
    pub stage_moves: usize,
    pub mount_moves: usize,
    pub reads: usize,
    pub frames: u64,
    /// Every stage target ever commanded, in order.
    pub stage_targets: Vec<f64>,
    pub mount_targets: Vec<f64>,
    pub stage_stops: usize,
    pub mount_stops: usize,
    /// Largest true gamma1 the elastomer ever saw, mm.
    pub max_true_gamma1: f64,
}

impl SimState {
    /// True gamma1, gamma2 (mm) and contact radius at the current stage position.
    fn truth(&self) -> (f64, f64, f64) {
        let delta = (self.stage_mm - self.cfg.surface_mm).min(self.model.max_approach_mm() * 0.999);
        match self.model.solve(delta) {
            Ok(s) => (s.gamma1_mm, s.gamma2_mm, s.contact_radius_mm),
            Err(_) => (0.0, 0.0, 0.0),
        }
    }

    fn true_theta1(&self) -> f64 {
        let (g1, g2, _) = self.truth();
        if g1 <= 0.0 {
            return 0.0;
        }
        let beta = g2 / self.cfg.pair.indenter.r_mm;
        torsion_at(&self.cfg.pair, beta, self.mount_deg.to_radians()).theta1_rad.to_degrees()
    }

    /// Let rig time pass at the current pose: the elastomer relaxes towards the truth.
    fn advance(&mut self, dt: f64) {
        let (g1, _, _) = self.truth();
        let th = self.true_theta1();
        let k = if self.cfg.lag_s > 0.0 { (-dt / self.cfg.lag_s).exp() } else { 0.0 };
        self.shown_gamma1 = g1 + (self.shown_gamma1 - g1) * k;
        self.shown_theta1 = th + (self.shown_theta1 - th) * k;
        self.max_true_gamma1 = self.max_true_gamma1.max(g1);
        self.t_s += dt;
    }
}

/// Shared handle; `stage()`, `mount()` and `gauge()` give the three devices.
#[derive(Debug, Clone)]
pub struct SimRig {
    state: Arc<Mutex<SimState>>,
}

impl SimRig {
    pub fn new(cfg: SimRigConfig) -> Result<Self, sim::physics::ParamError> {
        let model = NormalModel::new(cfg.pair)?;
        let st = SimState {
            cfg,
            model,
            rng: Rng::seed_from(cfg.seed),
            t_s: 0.0,
            stage_mm: cfg.stage_power_on_mm,
            stage_homed: false,
            stage_target: None,
            mount_deg: 0.0,
            mount_homed: false,
            mount_target: None,
            shown_gamma1: 0.0,
            shown_theta1: 0.0,
            tare: 0.0,
            stage_dead: false,
            mount_dead: false,
            stage_moves: 0,
            mount_moves: 0,
            reads: 0,
            frames: 0,
            stage_targets: Vec::new(),
            mount_targets: Vec::new(),
            stage_stops: 0,
            mount_stops: 0,
            max_true_gamma1: 0.0,
        };
        Ok(Self { state: Arc::new(Mutex::new(st)) })
    }

    /// Lock the shared state (tests read the logs through this).
    pub fn state(&self) -> MutexGuard<'_, SimState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn stage(&self) -> SimStage {
        SimStage { rig: self.clone() }
    }
    pub fn mount(&self) -> SimMount {
        SimMount { rig: self.clone() }
    }
    pub fn gauge(&self) -> SimGauge {
        SimGauge { rig: self.clone() }
    }
}

fn fault(device: &'static str, kind: FaultKind, message: impl Into<String>) -> SimFault {
    SimFault { device, kind, message: message.into() }
}

pub struct SimStage {
    rig: SimRig,
}
pub struct SimMount {
    rig: SimRig,
}
pub struct SimGauge {
    rig: SimRig,
}

fn dead_stage(st: &SimState) -> Result<(), SimFault> {
    if st.stage_dead { Err(fault("sim stage", FaultKind::Disconnected, "port closed (cable cut)")) } else { Ok(()) }
}
fn dead_mount(st: &SimState) -> Result<(), SimFault> {
    if st.mount_dead { Err(fault("sim mount", FaultKind::Disconnected, "port closed (cable cut)")) } else { Ok(()) }
}

#[async_trait]
impl Identify for SimStage {
    type Error = SimFault;
    async fn identify(&mut self) -> Result<DeviceInfo, SimFault> {
        dead_stage(&self.rig.state())?;
        Ok(DeviceInfo { model: "SIM-STAGE".into(), serial: "0001".into(), firmware: "1.0.0".into() })
    }
}

#[async_trait]
impl LinearStage for SimStage {
    type Error = SimFault;

    fn travel_mm(&self) -> (f64, f64) {
        self.rig.state().cfg.stage_travel_mm
    }
    async fn home(&mut self, _timeout: Duration) -> Result<(), SimFault> {
        let mut st = self.rig.state();
        dead_stage(&st)?;
        let dt = st.stage_mm.abs() / st.cfg.stage_speed + st.cfg.move_overhead_s;
        st.advance(dt);
        st.stage_mm = st.cfg.stage_travel_mm.0.max(0.0);
        st.stage_homed = true;
        Ok(())
    }
    async fn start_move_to_mm(&mut self, target_mm: f64) -> Result<(), SimFault> {
        let mut st = self.rig.state();
        dead_stage(&st)?;
        st.stage_moves += 1;
        if let Some((n, kind)) = st.cfg.faults.stage_move.filter(|f| f.0 == st.stage_moves) {
            if kind == FaultKind::Disconnected {
                st.stage_dead = true;
            }
            return Err(fault("sim stage", kind, format!("injected fault on move {n}")));
        }
        let (lo, hi) = st.cfg.stage_travel_mm;
        if !(target_mm >= lo && target_mm <= hi) {
            return Err(fault("sim stage", FaultKind::Limit, format!("target {target_mm} mm outside travel")));
        }
        st.stage_targets.push(target_mm);
        st.stage_target = Some(target_mm);
        Ok(())
    }
    async fn start_move_by_mm(&mut self, delta_mm: f64) -> Result<(), SimFault> {
        let target = self.rig.state().stage_mm + delta_mm;
        self.start_move_to_mm(target).await
    }
    async fn wait_until_stopped(&mut self, _timeout: Duration) -> Result<f64, SimFault> {
        let mut st = self.rig.state();
        dead_stage(&st)?;
        if let Some(t) = st.stage_target.take() {
            let dt = (t - st.stage_mm).abs() / st.cfg.stage_speed + st.cfg.move_overhead_s;
            // The elastomer follows the indenter during the move; lag shows after.
            st.advance(dt);
            st.stage_mm = t;
            let (g1, _, _) = st.truth();
            st.max_true_gamma1 = st.max_true_gamma1.max(g1);
        }
        Ok(st.stage_mm)
    }
    async fn stop(&mut self) -> Result<(), SimFault> {
        let mut st = self.rig.state();
        st.stage_stops += 1;
        dead_stage(&st)?;
        st.stage_target = None;
        Ok(())
    }
    async fn position_mm(&mut self) -> Result<f64, SimFault> {
        let st = self.rig.state();
        dead_stage(&st)?;
        Ok(st.stage_mm)
    }
    async fn status(&mut self) -> Result<AxisStatus, SimFault> {
        let st = self.rig.state();
        dead_stage(&st)?;
        Ok(AxisStatus {
            position: st.stage_mm,
            moving: st.stage_target.is_some(),
            homed: st.stage_homed,
            enabled: true,
            ..Default::default()
        })
    }
}

#[async_trait]
impl Identify for SimMount {
    type Error = SimFault;
    async fn identify(&mut self) -> Result<DeviceInfo, SimFault> {
        dead_mount(&self.rig.state())?;
        Ok(DeviceInfo { model: "SIM-MOUNT".into(), serial: "0002".into(), firmware: "1.0.0".into() })
    }
}

#[async_trait]
impl RotationMount for SimMount {
    type Error = SimFault;

    fn travel_deg(&self) -> (f64, f64) {
        self.rig.state().cfg.mount_travel_deg
    }
    async fn home(&mut self, _timeout: Duration) -> Result<(), SimFault> {
        let mut st = self.rig.state();
        dead_mount(&st)?;
        let dt = st.mount_deg.abs() / st.cfg.mount_speed + st.cfg.move_overhead_s;
        st.advance(dt);
        st.mount_deg = 0.0;
        st.mount_homed = true;
        Ok(())
    }
    async fn start_move_to_deg(&mut self, target_deg: f64) -> Result<(), SimFault> {
        let mut st = self.rig.state();
        dead_mount(&st)?;
        st.mount_moves += 1;
        if let Some((n, kind)) = st.cfg.faults.mount_move.filter(|f| f.0 == st.mount_moves) {
            if kind == FaultKind::Disconnected {
                st.mount_dead = true;
            }
            return Err(fault("sim mount", kind, format!("injected fault on move {n}")));
        }
        let (lo, hi) = st.cfg.mount_travel_deg;
        if !(target_deg >= lo && target_deg <= hi) {
            return Err(fault("sim mount", FaultKind::Limit, format!("target {target_deg} deg outside travel")));
        }
        st.mount_targets.push(target_deg);
        st.mount_target = Some(target_deg);
        Ok(())
    }
    async fn start_move_by_deg(&mut self, delta_deg: f64) -> Result<(), SimFault> {
        let target = self.rig.state().mount_deg + delta_deg;
        self.start_move_to_deg(target).await
    }
    async fn wait_until_stopped(&mut self, _timeout: Duration) -> Result<f64, SimFault> {
        let mut st = self.rig.state();
        dead_mount(&st)?;
        if let Some(t) = st.mount_target.take() {
            let dt = (t - st.mount_deg).abs() / st.cfg.mount_speed + st.cfg.move_overhead_s;
            st.advance(dt);
            st.mount_deg = t;
        }
        Ok(st.mount_deg)
    }
    async fn stop(&mut self) -> Result<(), SimFault> {
        let mut st = self.rig.state();
        st.mount_stops += 1;
        dead_mount(&st)?;
        st.mount_target = None;
        Ok(())
    }
    async fn position_deg(&mut self) -> Result<f64, SimFault> {
        let st = self.rig.state();
        dead_mount(&st)?;
        Ok(st.mount_deg)
    }
    async fn status(&mut self) -> Result<AxisStatus, SimFault> {
        let st = self.rig.state();
        dead_mount(&st)?;
        Ok(AxisStatus {
            position: st.mount_deg,
            moving: st.mount_target.is_some(),
            homed: st.mount_homed,
            enabled: true,
            ..Default::default()
        })
    }
}

#[async_trait]
impl Gauge for SimGauge {
    async fn start(&mut self) -> Result<(), GaugeError> {
        Ok(())
    }
    async fn read(&mut self, timeout: Duration) -> Result<GaugeReading, GaugeError> {
        let mut st = self.rig.state();
        st.reads += 1;
        let n = st.reads;
        if st.cfg.faults.sensor_closed_at.is_some_and(|k| n >= k) {
            return Err(GaugeError::Link(devices::sensor::SensorError::Closed {
                reason: "sim sensor unplugged".into(),
            }));
        }
        if st.cfg.faults.sensor_silent_from.is_some_and(|k| n >= k) {
            return Err(GaugeError::Timeout { waited: timeout });
        }
        let dt = 1.0 / st.cfg.frame_rate_hz;
        st.advance(dt);
        st.frames += 1;
        let (g1s, ths) = (st.cfg.gamma1_sigma_mm, st.cfg.theta1_sigma_deg);
        let noise_g = st.rng.gaussian(g1s);
        let noise_t = st.rng.gaussian(ths);
        let (_, _, a) = st.truth();
        if st.cfg.zero_out_of_contact && st.shown_gamma1 <= 0.0 {
            return Ok(GaugeReading { t_s: st.t_s, gamma1_mm: 0.0, theta1_deg: 0.0, contact_radius_mm: 0.0 });
        }
        Ok(GaugeReading {
            t_s: st.t_s,
            gamma1_mm: st.shown_gamma1 - st.tare + noise_g,
            theta1_deg: st.shown_theta1 + noise_t,
            contact_radius_mm: a,
        })
    }
    async fn tare(&mut self) -> Result<(), GaugeError> {
        let mut st = self.rig.state();
        // Zero what the elastomer shows now (untouched: the truth is 0 there).
        st.tare = st.shown_gamma1;
        Ok(())
    }
    fn link_stats(&self) -> SensorStatus {
        let st = self.rig.state();
        SensorStatus { rate_hz: st.cfg.frame_rate_hz, frames: st.frames, ..SensorStatus::default() }
    }
    fn describe(&self) -> String {
        "sim-gauge".into()
    }
}
