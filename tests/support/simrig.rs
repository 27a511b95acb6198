//! An in-process simulated rig: a stage, a rotation mount and a deformation
//! gauge that share one state driven by the contact physics of `sim::physics`
//! (Hertz–Tatara–Yoffe normal contact, Jäger torsion with the rod correction),
//! with seeded noise, a first-order elastomer lag (so settling matters) and
//! injectable faults. Every call answers at once; time is a rig clock that
//! moves and frames advance, so a whole run takes milliseconds of wall time.
//!
//! It fakes the instrument, not a driver: the real drivers over emulators are
//! the other way to run the sequencer. Every commanded target is logged so a
//! test can check it against the soft limits. The stage and the mount are one
//! [`SimAxis`], told apart by their unit ([`SimUnit`]), as the drivers are.
//!
//! Test support, not production code: included with
//! `#[path = "support/simrig.rs"] mod simrig;` by the tests (and benches) that
//! run the sequencer on it.

use std::marker::PhantomData;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use async_trait::async_trait;
use devices::motion::{Axis, AxisStatus, Deg, DeviceFault, DeviceInfo, FaultKind, Identify, Mm, Unit};
use easycalib::run::events::SensorStatus;
use easycalib::run::gauge::{Gauge, GaugeError, GaugeReading};
use sim::physics::{ContactPair, NormalModel, torsion_at};
use sim::rng::Rng;

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
    /// The run reads this many frames behind the sensor, as one that
    /// measures frames more slowly than they come finds a full link queue
    /// (0: each reading is made when asked for).
    pub queued_frames: usize,
    /// The frame's drift towards the gel, mm per second of rig time: the
    /// approach is the stage's travel past the surface plus this times the
    /// rig's time (docs/physics.md 2.9; 0: a still frame).
    pub frame_drift_mm_per_s: f64,
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
            queued_frames: 0,
            frame_drift_mm_per_s: 0.0,
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
    /// Readings made but not yet read ([`SimRigConfig::queued_frames`]).
    queue: std::collections::VecDeque<GaugeReading>,
    /// Readings discarded unread after a move.
    pub superseded: usize,
}

impl SimState {
    /// True gamma1, gamma2 (mm) and contact radius at the current stage position.
    fn truth(&self) -> (f64, f64, f64) {
        let drift = self.cfg.frame_drift_mm_per_s * self.t_s;
        let delta = (self.stage_mm - self.cfg.surface_mm + drift).min(self.model.max_approach_mm() * 0.999);
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

    /// The next frame's reading: one frame period of rig time passes.
    fn frame(&mut self) -> GaugeReading {
        let dt = 1.0 / self.cfg.frame_rate_hz;
        self.advance(dt);
        self.frames += 1;
        let (g1s, ths) = (self.cfg.gamma1_sigma_mm, self.cfg.theta1_sigma_deg);
        let noise_g = self.rng.gaussian(g1s);
        let noise_t = self.rng.gaussian(ths);
        let (_, _, a) = self.truth();
        if self.cfg.zero_out_of_contact && self.shown_gamma1 <= 0.0 {
            return GaugeReading::new(self.t_s, 0.0, 0.0, 0.0);
        }
        GaugeReading::new(self.t_s, self.shown_gamma1 - self.tare + noise_g, self.shown_theta1 + noise_t, a)
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
            queue: Default::default(),
            superseded: 0,
            max_true_gamma1: 0.0,
        };
        Ok(Self { state: Arc::new(Mutex::new(st)) })
    }

    /// Lock the shared state (tests read the logs through this).
    pub fn state(&self) -> MutexGuard<'_, SimState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn stage(&self) -> SimStage {
        SimAxis { rig: self.clone(), unit: PhantomData }
    }
    pub fn mount(&self) -> SimMount {
        SimAxis { rig: self.clone(), unit: PhantomData }
    }
    pub fn gauge(&self) -> SimGauge {
        SimGauge { rig: self.clone() }
    }
}

fn fault(device: &'static str, kind: FaultKind, message: impl Into<String>) -> SimFault {
    SimFault { device, kind, message: message.into() }
}

/// One simulated axis: the stage ([`SimStage`], in [`Mm`]) or the mount
/// ([`SimMount`], in [`Deg`]).
pub struct SimAxis<U> {
    rig: SimRig,
    unit: PhantomData<U>,
}
pub type SimStage = SimAxis<Mm>;
pub type SimMount = SimAxis<Deg>;
pub struct SimGauge {
    rig: SimRig,
}

/// One axis' share of the [`SimState`].
pub struct Side<'a> {
    position: &'a mut f64,
    homed: &'a mut bool,
    target: &'a mut Option<f64>,
    dead: &'a mut bool,
    moves: &'a mut usize,
    targets: &'a mut Vec<f64>,
    stops: &'a mut usize,
}

/// What tells the stage and the mount apart: their unit.
pub trait SimUnit: Unit {
    /// Name in fault messages.
    const DEVICE: &'static str;
    const MODEL: &'static str;
    const SERIAL: &'static str;
    fn side(st: &mut SimState) -> Side<'_>;
    fn travel(cfg: &SimRigConfig) -> (f64, f64);
    /// Where homing leaves the axis.
    fn home(cfg: &SimRigConfig) -> f64;
    /// Speed in rig time, unit per s.
    fn speed(cfg: &SimRigConfig) -> f64;
    fn move_fault(cfg: &SimRigConfig) -> Option<(usize, FaultKind)>;
}

impl SimUnit for Mm {
    const DEVICE: &'static str = "sim stage";
    const MODEL: &'static str = "SIM-STAGE";
    const SERIAL: &'static str = "0001";
    fn side(st: &mut SimState) -> Side<'_> {
        Side {
            position: &mut st.stage_mm,
            homed: &mut st.stage_homed,
            target: &mut st.stage_target,
            dead: &mut st.stage_dead,
            moves: &mut st.stage_moves,
            targets: &mut st.stage_targets,
            stops: &mut st.stage_stops,
        }
    }
    fn travel(cfg: &SimRigConfig) -> (f64, f64) {
        cfg.stage_travel_mm
    }
    fn home(cfg: &SimRigConfig) -> f64 {
        cfg.stage_travel_mm.0.max(0.0)
    }
    fn speed(cfg: &SimRigConfig) -> f64 {
        cfg.stage_speed
    }
    fn move_fault(cfg: &SimRigConfig) -> Option<(usize, FaultKind)> {
        cfg.faults.stage_move
    }
}

impl SimUnit for Deg {
    const DEVICE: &'static str = "sim mount";
    const MODEL: &'static str = "SIM-MOUNT";
    const SERIAL: &'static str = "0002";
    fn side(st: &mut SimState) -> Side<'_> {
        Side {
            position: &mut st.mount_deg,
            homed: &mut st.mount_homed,
            target: &mut st.mount_target,
            dead: &mut st.mount_dead,
            moves: &mut st.mount_moves,
            targets: &mut st.mount_targets,
            stops: &mut st.mount_stops,
        }
    }
    fn travel(cfg: &SimRigConfig) -> (f64, f64) {
        cfg.mount_travel_deg
    }
    fn home(_cfg: &SimRigConfig) -> f64 {
        0.0
    }
    fn speed(cfg: &SimRigConfig) -> f64 {
        cfg.mount_speed
    }
    fn move_fault(cfg: &SimRigConfig) -> Option<(usize, FaultKind)> {
        cfg.faults.mount_move
    }
}

impl<U: SimUnit> SimAxis<U> {
    /// The shared state, once this axis' cable is known to be intact.
    fn alive(&self) -> Result<MutexGuard<'_, SimState>, SimFault> {
        let mut st = self.rig.state();
        if *U::side(&mut st).dead {
            return Err(fault(U::DEVICE, FaultKind::Disconnected, "port closed (cable cut)"));
        }
        Ok(st)
    }

    /// Let the rig time of a move from here to `to` pass, then be there.
    fn travel_to(st: &mut SimState, to: f64) {
        let dt = (to - *U::side(st).position).abs() / U::speed(&st.cfg) + st.cfg.move_overhead_s;
        // The elastomer follows the indenter during the move; lag shows after.
        st.advance(dt);
        *U::side(st).position = to;
    }
}

#[async_trait]
impl<U: SimUnit> Identify for SimAxis<U> {
    type Error = SimFault;
    async fn identify(&mut self) -> Result<DeviceInfo, SimFault> {
        drop(self.alive()?);
        Ok(DeviceInfo { model: U::MODEL.into(), serial: U::SERIAL.into(), firmware: "1.0.0".into() })
    }
}

#[async_trait]
impl<U: SimUnit> Axis for SimAxis<U> {
    type Unit = U;

    fn travel(&self) -> (U, U) {
        let (lo, hi) = U::travel(&self.rig.state().cfg);
        (U::new(lo), U::new(hi))
    }
    async fn home(&mut self, _timeout: Duration) -> Result<(), SimFault> {
        let mut st = self.alive()?;
        let home = U::home(&st.cfg);
        let dt = U::side(&mut st).position.abs() / U::speed(&st.cfg) + st.cfg.move_overhead_s;
        st.advance(dt);
        let side = U::side(&mut st);
        *side.position = home;
        *side.homed = true;
        Ok(())
    }
    async fn start_move_to(&mut self, target: U) -> Result<(), SimFault> {
        let target = target.value();
        let mut st = self.alive()?;
        let (fault_at, (lo, hi)) = (U::move_fault(&st.cfg), U::travel(&st.cfg));
        let side = U::side(&mut st);
        *side.moves += 1;
        if let Some((n, kind)) = fault_at.filter(|f| f.0 == *side.moves) {
            if kind == FaultKind::Disconnected {
                *side.dead = true;
            }
            return Err(fault(U::DEVICE, kind, format!("injected fault on move {n}")));
        }
        if !(target >= lo && target <= hi) {
            return Err(fault(U::DEVICE, FaultKind::Limit, format!("target {target} {} outside travel", U::SYMBOL)));
        }
        side.targets.push(target);
        *side.target = Some(target);
        Ok(())
    }
    async fn start_move_by(&mut self, delta: U) -> Result<(), SimFault> {
        let here = *U::side(&mut self.rig.state()).position;
        self.start_move_to(U::new(here + delta.value())).await
    }
    async fn wait_until_stopped(&mut self, _timeout: Duration) -> Result<U, SimFault> {
        let mut st = self.alive()?;
        if let Some(t) = U::side(&mut st).target.take() {
            Self::travel_to(&mut st, t);
            let (g1, _, _) = st.truth();
            st.max_true_gamma1 = st.max_true_gamma1.max(g1);
        }
        Ok(U::new(*U::side(&mut st).position))
    }
    async fn stop(&mut self) -> Result<(), SimFault> {
        *U::side(&mut self.rig.state()).stops += 1;
        let mut st = self.alive()?;
        *U::side(&mut st).target = None;
        Ok(())
    }
    async fn position(&mut self) -> Result<U, SimFault> {
        let mut st = self.alive()?;
        Ok(U::new(*U::side(&mut st).position))
    }
    async fn status(&mut self) -> Result<AxisStatus, SimFault> {
        let mut st = self.alive()?;
        let side = U::side(&mut st);
        Ok(AxisStatus {
            position: *side.position,
            moving: side.target.is_some(),
            homed: *side.homed,
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
        while st.queue.len() < st.cfg.queued_frames {
            let r = st.frame();
            st.queue.push_back(r);
        }
        let r = st.frame();
        st.queue.push_back(r);
        Ok(st.queue.pop_front().expect("a reading was queued above"))
    }
    /// Readings waiting behind the one read ([`SimRigConfig::queued_frames`]).
    fn discard_queued(&mut self) -> usize {
        let mut st = self.rig.state();
        let n = st.queue.len();
        st.queue.clear();
        st.superseded += n;
        n
    }
    async fn tare(&mut self) -> Result<(), GaugeError> {
        let mut st = self.rig.state();
        // Zero what the elastomer shows now (untouched: the truth is 0 there).
        st.tare = st.shown_gamma1;
        Ok(())
    }
    fn link_stats(&self) -> SensorStatus {
        let st = self.rig.state();
        SensorStatus {
            rate_hz: st.cfg.frame_rate_hz,
            frames: st.frames,
            skipped: st.superseded as u64,
            ..SensorStatus::default()
        }
    }
    fn describe(&self) -> String {
        "sim-gauge".into()
    }
}

/// The step-by-step design the default script had before issue 15 (0.05 mm
/// and 0.2 deg steps, samples of the settling's own frames): the fault,
/// abort and operator-step tests place their events by move and read counts
/// within it.
pub fn stepwise_script() -> easycalib::run::script::Script {
    let mut s = easycalib::run::script::Script::default();
    s.approach.search_step_mm = 0.05;
    s.normal.step_mm = 0.05;
    s.normal.frames = 0;
    s.torsion.step_deg = 0.2;
    s.torsion.frames = 0;
    s.settle.readings = 2;
    s
}
