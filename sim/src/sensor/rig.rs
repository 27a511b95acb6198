//! The simulated sensor coupled to the emulated rig: the stage's load position
//! sets the approach, the normal model (Hertz-Tatara-Yoffe) turns it into
//! gamma1 and the contact radius, and the mount angle turned while in contact
//! becomes theta1 through the torsion model (Jäger + rod) at the current depth.
//! Moving the emulated stage therefore changes what the sensor sees.

use std::sync::{Arc, Mutex};

use devices::sensor::SensorFrame;

use super::field::{ContactState, MarkerGrid, SimulatedSensor};
use crate::effects::{CommandedPose, EffectError, TrueRig};
use crate::emulator::rig::{Rig, RigPose};
use crate::physics::{Body, ContactPair, NormalModel, NormalState, torsion_at};
use crate::setup::SimSetup;

/// Everything that defines the simulated sensor: the simulated set-up
/// (elastomer, indenter, effects, noise, seed) and the sensor's own layout.
/// Defaults are those of a real Tac3D (docs/hardware.md C.1): 20 x 20 markers
/// at 1 mm pitch on a 33 mm dome, 4 um marker noise, exact zeros without
/// contact, 30 frames/s.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorSimConfig {
    /// The simulated rig, resolved once (its speed-up is the rig clock's).
    pub setup: SimSetup,
    pub grid: MarkerGrid,
    /// Frames per second of rig time.
    pub frame_rate_hz: f64,
    /// Where the indenter's axis meets the marker grid, mm.
    pub contact_center_mm: [f64; 2],
    /// Stage load position at which the indenter first touches the elastomer:
    /// the approach is `stage_mm - contact_stage_mm` (positive into the sensor).
    pub contact_stage_mm: f64,
    /// The first frame's counter (a Tac3D counts from its own start, not 0).
    pub first_index: u64,
}

impl Default for SensorSimConfig {
    fn default() -> Self {
        Self {
            setup: SimSetup::default(),
            grid: MarkerGrid::tac3d(),
            frame_rate_hz: 30.0,
            contact_center_mm: [0.0, 0.0],
            contact_stage_mm: 0.0,
            first_index: 1000,
        }
    }
}

/// The physical truth behind one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactTruth {
    /// Normal contact state at the current approach.
    pub normal: NormalState,
    /// Torsion depth beta = gamma2 / R2.
    pub beta: f64,
    /// Mount rotation since the contact was made, degrees.
    pub twist_deg: f64,
    /// Rotation of the contact relative to the elastomer, rad.
    pub theta1_rad: f64,
}

/// Which indenter the emulated rig has mounted, shared between the sensor
/// (which reads it before every frame) and whoever plays the operator
/// (`None`: the set-up's own indenter). Changing it is the emulated rig's
/// indenter swap (docs/experiments.md, "Operator-assisted steps").
#[derive(Debug, Clone, Default)]
pub struct IndenterMount(Arc<Mutex<Option<Body>>>);

impl IndenterMount {
    /// Mount `indenter` (`None`: the set-up's own) from the next frame on.
    pub fn mount(&self, indenter: Option<Body>) {
        let mut m = self.0.lock().unwrap_or_else(|p| p.into_inner());
        *m = indenter;
    }

    /// What is mounted (`None`: the set-up's own indenter).
    pub fn mounted(&self) -> Option<Body> {
        *self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// A simulated Tac3D looking at the emulated rig.
pub struct RigSensor {
    rig: Rig,
    model: NormalModel,
    /// The contact as mounted now: the set-up's elastomer with the set-up's
    /// indenter, or the one an operator step mounted.
    pair: ContactPair,
    mount: IndenterMount,
    /// What `pair` was built for (`None`: the set-up's indenter).
    mounted: Option<Body>,
    cfg: SensorSimConfig,
    sensor: SimulatedSensor,
    /// Mount angle when the current contact was made: twist before touching
    /// does not load the elastomer.
    twist_origin_deg: Option<f64>,
    /// The set-up's left-out physics; `None` for the paper's clean contact.
    effects: Option<TrueRig>,
    /// Readings the effect model could not give (e.g. gross slip), answered
    /// with the clean contact instead.
    effect_failures: u64,
}

impl std::fmt::Debug for RigSensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RigSensor")
            .field("cfg", &self.cfg)
            .field("sensor", &self.sensor)
            .field("twist_origin_deg", &self.twist_origin_deg)
            .finish_non_exhaustive()
    }
}

impl RigSensor {
    /// The sensor for `cfg.setup`'s contact, with its effects when it has any
    /// (so the rig reproduces what a diagnosed recording showed).
    pub fn new(rig: Rig, cfg: SensorSimConfig) -> Result<Self, EffectError> {
        let setup = &cfg.setup;
        let model = NormalModel::new(*setup.pair())?;
        let effects = match (setup.layer(), setup.effects().is_clean()) {
            // On a declared layer the true rig carries the layer's contact law,
            // so it answers every frame, clean or not.
            (Some(l), _) => Some(TrueRig::on_law(*setup.pair(), setup.effects(), l.law.clone())?),
            (None, true) => None,
            (None, false) => Some(TrueRig::new(*setup.pair(), setup.effects())?),
        };
        let sensor = SimulatedSensor::new(cfg.grid.clone(), *setup.noise(), setup.seed(), Box::new(|_| None))
            .with_first_index(cfg.first_index)
            .with_layer(setup.layer().and_then(|l| l.law.surface()));
        let pair = *setup.pair();
        Ok(Self {
            rig,
            model,
            pair,
            mount: IndenterMount::default(),
            mounted: None,
            cfg,
            sensor,
            twist_origin_deg: None,
            effects,
            effect_failures: 0,
        })
    }

    /// The handle through which the mounted indenter is changed (shared: clones act on this sensor).
    pub fn mount(&self) -> IndenterMount {
        self.mount.clone()
    }

    /// The contact pair as mounted now.
    pub fn pair(&self) -> &ContactPair {
        &self.pair
    }

    /// Follow the mount: when another indenter was mounted since the last
    /// frame, the normal model, the torsion pair and the effects' rig are
    /// rebuilt for it. The effects' history starts afresh, as the
    /// generator's operator recording does (the gel recovered while the
    /// stage was parked for the swap); the profile's effects (frame, gain,
    /// drift) stay. An indenter the models refuse leaves the previous one
    /// mounted and is counted as an effect failure.
    fn follow_mount(&mut self) {
        let want = self.mount.mounted();
        if want == self.mounted {
            return;
        }
        if self.cfg.setup.layer().is_some() {
            // A layer's contact law is for the set-up's own indenter: another
            // one cannot be mounted on it.
            self.effect_failures += 1;
            self.mounted = want;
            return;
        }
        let pair = ContactPair { indenter: want.unwrap_or(self.cfg.setup.pair().indenter), ..*self.cfg.setup.pair() };
        let model = match NormalModel::new(pair) {
            Ok(m) => m,
            Err(_) => {
                self.effect_failures += 1;
                self.mounted = want;
                return;
            }
        };
        let effects = match self.cfg.setup.effects().is_clean() {
            true => None,
            false => match TrueRig::new(pair, self.cfg.setup.effects()) {
                Ok(r) => Some(r),
                Err(_) => {
                    self.effect_failures += 1;
                    self.mounted = want;
                    return;
                }
            },
        };
        self.pair = pair;
        self.model = model;
        self.effects = effects;
        self.mounted = want;
        self.twist_origin_deg = None;
    }

    /// Readings the effect model could not give and the clean contact answered.
    pub fn effect_failures(&self) -> u64 {
        self.effect_failures
    }

    /// The reading with the profile's effects for a pose, or `None` when the
    /// rig has no effects or the effect model fails here.
    fn effect_state(&mut self, pose: &RigPose) -> Option<ContactState> {
        let effects = self.effects.as_mut()?;
        let twist_deg = self.twist_origin_deg.map_or(0.0, |o| pose.rot_deg - o);
        let cmd =
            CommandedPose { t_s: pose.t_s, stage_mm: pose.stage_mm - self.cfg.contact_stage_mm, rot_deg: twist_deg };
        match effects.read(cmd) {
            Ok(r) if r.in_contact && r.gamma1_mm > 0.0 && r.contact_radius_mm > 0.0 => Some(
                ContactState::new(
                    self.cfg.contact_center_mm,
                    r.gamma1_mm,
                    r.contact_radius_mm,
                    r.theta1_deg.to_radians(),
                )
                .with_nu1(self.pair.elastomer.nu)
                .with_punch(r.gamma1_punch_mm)
                .with_spheres(self.pair.indenter.r_mm, self.pair.elastomer.r_mm)
                .with_depth_gain(effects.profile().sensor_gain.map_or(1.0, |p| p.g)),
            ),
            Ok(_) => None,
            Err(_) => {
                self.effect_failures += 1;
                None
            }
        }
    }

    pub fn config(&self) -> &SensorSimConfig {
        &self.cfg
    }

    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// Frames lost so far by the simulated dropouts.
    pub fn dropped(&self) -> u64 {
        self.sensor.dropped()
    }

    /// The contact behind a pose (`None`: not touching), with the twist
    /// counted from `twist_origin_deg` (the current pose's angle if `None`).
    pub fn truth_with_origin(&self, pose: &RigPose, twist_origin_deg: Option<f64>) -> Option<ContactTruth> {
        let delta = pose.stage_mm - self.cfg.contact_stage_mm;
        if delta.is_nan() || delta <= 0.0 {
            return None;
        }
        if let Some(l) = self.cfg.setup.layer() {
            let st = l.law.normal(delta).ok()?;
            if !(st.gamma1_mm > 0.0 && st.contact_radius_mm > 0.0) {
                return None;
            }
            let twist_deg = pose.rot_deg - twist_origin_deg.unwrap_or(pose.rot_deg);
            let theta1_deg = if twist_deg == 0.0 { 0.0 } else { l.law.theta1_deg(delta, twist_deg).ok()? };
            let normal = NormalState {
                delta_mm: delta,
                gamma1_mm: st.gamma1_mm,
                gamma2_mm: st.gamma2_mm,
                force_n: st.force_n,
                contact_radius_mm: st.contact_radius_mm,
            };
            let beta = st.gamma2_mm / self.pair.indenter.r_mm;
            return Some(ContactTruth { normal, beta, twist_deg, theta1_rad: theta1_deg.to_radians() });
        }
        // Past the model's limit the elastomer would be crushed; hold the
        // deepest state the model describes instead of failing the stream.
        let delta = delta.min(0.999 * self.model.max_approach_mm());
        let normal = self.model.solve(delta).ok()?;
        if !(normal.gamma1_mm > 0.0 && normal.contact_radius_mm > 0.0) {
            return None;
        }
        let beta = normal.gamma2_mm / self.pair.indenter.r_mm;
        let twist_deg = pose.rot_deg - twist_origin_deg.unwrap_or(pose.rot_deg);
        let theta1_rad = torsion_at(&self.pair, beta, twist_deg.to_radians()).theta1_rad;
        Some(ContactTruth { normal, beta, twist_deg, theta1_rad })
    }

    /// The contact behind a pose given the contact history so far.
    pub fn truth(&self, pose: &RigPose) -> Option<ContactTruth> {
        self.truth_with_origin(pose, self.twist_origin_deg)
    }

    /// The frame the sensor reports for `pose` (advances the frame counter,
    /// the noise and the contact history).
    pub fn frame_at_pose(&mut self, pose: &RigPose) -> SensorFrame {
        self.follow_mount();
        let truth = self.truth(pose);
        match truth {
            Some(_) if self.twist_origin_deg.is_none() => self.twist_origin_deg = Some(pose.rot_deg),
            None => self.twist_origin_deg = None,
            Some(_) => {}
        }
        let clean = truth.map(|t| {
            ContactState::new(self.cfg.contact_center_mm, t.normal.gamma1_mm, t.normal.contact_radius_mm, t.theta1_rad)
                .with_nu1(self.pair.elastomer.nu)
                .with_spheres(self.pair.indenter.r_mm, self.pair.elastomer.r_mm)
        });
        // With effects the history-dependent model answers; it is stepped on
        // every frame (in time order) so backlash, creep and drift see the
        // whole history. Out of contact, or if it fails, the clean contact.
        let state = match self.effects.is_some() {
            true => {
                let failures = self.effect_failures;
                let s = self.effect_state(pose);
                if self.effect_failures > failures { clean } else { s }
            }
            false => clean,
        };
        self.sensor.frame_for(state, pose.t_s)
    }

    /// The frame for the rig as it is now.
    pub fn frame(&mut self) -> SensorFrame {
        let pose = self.rig.pose();
        self.frame_at_pose(&pose)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::VirtualClock;
    use crate::effects::SimProfile;
    use crate::emulator::axis::AxisConfig;
    use crate::sensor::field::NoiseConfig;
    use crate::setup::SimSetupInput;

    /// A noiseless sensor with `profile`'s effects, first contact at `contact_stage_mm`.
    fn quiet(profile: SimProfile, contact_stage_mm: f64) -> SensorSimConfig {
        let setup = SimSetupInput { noise: NoiseConfig::NONE, profile, ..SimSetupInput::default() }.resolve().unwrap();
        SensorSimConfig { setup, contact_stage_mm, ..SensorSimConfig::default() }
    }

    fn axis(lo: f64, hi: f64) -> AxisConfig {
        AxisConfig {
            max_velocity: 1e6,
            acceleration: 1e9,
            min_position: lo,
            max_position: hi,
            resolution: 0.0,
            backlash: 0.0,
            home_velocity: 1.0,
            power_on_position: 0.0,
        }
    }

    #[test]
    fn stage_sets_depth_and_twist_counts_from_contact() {
        let rig = Rig::new(VirtualClock::new(1.0), axis(-10.0, 10.0), axis(-360.0, 360.0));
        let cfg = quiet(SimProfile::default(), 1.0);
        let model = NormalModel::new(*cfg.setup.pair()).unwrap();
        let mut s = RigSensor::new(rig, cfg).unwrap();
        let pose = |stage_mm, rot_deg| RigPose { t_s: 0.0, stage_mm, rot_deg };
        // Twisting before touching loads nothing.
        let f = s.frame_at_pose(&pose(0.9, 3.0));
        assert!(f.displacements.iter().all(|d| *d == [0.0; 3]));
        // Touch at 3 degrees, then twist by 2 degrees.
        let f = s.frame_at_pose(&pose(3.0, 3.0));
        let centre = f.positions.iter().position(|p| p[0] == -0.5 && p[1] == -0.5).unwrap();
        let state = model.solve(2.0).unwrap();
        let a = state.contact_radius_mm;
        // Hertz's field with the spheres' sag (the marker is 0.71 mm out).
        let pair = s.config().setup.pair();
        let sag = crate::sensor::field::spheres_sag_mm(0.5f64.sqrt(), a, pair.indenter.r_mm, pair.elastomer.r_mm);
        let expected = -state.gamma1_mm * (1.0 - 0.5 * 0.5 / (a * a)) + sag;
        assert!((f.displacements[centre][2] - expected).abs() < 1e-12);
        let t = s.truth(&pose(3.0, 5.0)).unwrap();
        assert!((t.twist_deg - 2.0).abs() < 1e-12);
        let beta = state.gamma2_mm / 5.0;
        let th = torsion_at(s.config().setup.pair(), beta, 2f64.to_radians()).theta1_rad;
        assert!((t.theta1_rad - th).abs() < 1e-15 && th > 0.0);
        // Losing contact resets the twist reference.
        s.frame_at_pose(&pose(0.5, 5.0));
        s.frame_at_pose(&pose(3.0, 7.0));
        assert_eq!(s.truth(&pose(3.0, 7.0)).unwrap().twist_deg, 0.0);
        // Frame counter starts at the configured value and counts up.
        let f2 = s.frame_at_pose(&pose(3.0, 7.0));
        assert_eq!(f2.index, 1000 + 4);
    }

    #[test]
    fn moving_the_emulated_stage_changes_the_frames() {
        let clock = VirtualClock::new(1000.0);
        let rig = Rig::new(clock, axis(-10.0, 10.0), axis(-360.0, 360.0));
        let mut s = RigSensor::new(rig.clone(), quiet(SimProfile::default(), 0.0)).unwrap();
        let before = s.frame();
        assert!(before.displacements.iter().all(|d| *d == [0.0; 3]));
        rig.with_stage(|ax, t| ax.command_move_to(t, 0.5));
        // The axis is nearly instantaneous; wait a few ms of wall time for it.
        std::thread::sleep(std::time::Duration::from_millis(5));
        let after = s.frame();
        let peak = after.displacements.iter().map(|d| -d[2]).fold(0.0, f64::max);
        assert!(peak > 0.1, "peak {peak}");
    }

    #[test]
    fn a_failing_effect_model_is_counted_and_the_clean_contact_drawn() {
        let rig = Rig::new(VirtualClock::new(1.0), axis(-10.0, 10.0), axis(-360.0, 360.0));
        let pose = |stage_mm, rot_deg| RigPose { t_s: 0.0, stage_mm, rot_deg };
        // Little friction: 30 degrees of twist is gross slip, which the slip model refuses.
        let slip = SimProfile {
            partial_slip: Some(crate::effects::partial_slip::Params { mu: 0.05 }),
            ..SimProfile::default()
        };
        let mut s = RigSensor::new(rig.clone(), quiet(slip, 1.0)).unwrap();
        let mut clean = RigSensor::new(rig, quiet(SimProfile::default(), 1.0)).unwrap();
        s.frame_at_pose(&pose(3.0, 0.0));
        clean.frame_at_pose(&pose(3.0, 0.0));
        assert_eq!(s.effect_failures(), 0);
        let f = s.frame_at_pose(&pose(3.0, 30.0));
        assert_eq!(s.effect_failures(), 1);
        assert_eq!(f.displacements, clean.frame_at_pose(&pose(3.0, 30.0)).displacements);
    }

    fn peak_depth(f: &SensorFrame) -> f64 {
        f.displacements.iter().map(|d| -d[2]).fold(0.0, f64::max)
    }

    #[test]
    fn a_profile_gives_the_frames_its_effects() {
        let rig = Rig::new(VirtualClock::new(1.0), axis(-10.0, 10.0), axis(-360.0, 360.0));
        let pose = |stage_mm| RigPose { t_s: 0.0, stage_mm, rot_deg: 0.0 };
        let mut clean = RigSensor::new(rig.clone(), quiet(SimProfile::default(), 1.0)).unwrap();

        // A clean profile changes nothing.
        let mut same = RigSensor::new(rig.clone(), quiet(SimProfile::default(), 1.0)).unwrap();
        assert_eq!(same.frame_at_pose(&pose(3.0)).displacements, clean.frame_at_pose(&pose(3.0)).displacements);

        // A contact offset of 0.1 mm: the stage must go 0.1 mm further for the same contact.
        let offset = SimProfile {
            contact_offset: Some(crate::effects::contact_offset::Params { contact_offset_mm: 0.1 }),
            ..SimProfile::default()
        };
        let mut shifted = RigSensor::new(rig.clone(), quiet(offset, 1.0)).unwrap();
        let want = peak_depth(&clean.frame_at_pose(&pose(2.9)));
        let got = peak_depth(&shifted.frame_at_pose(&pose(3.0)));
        assert!((got - want).abs() < 1e-6 && want > 0.5, "{got} vs {want}");

        // A depth gain of 0.9 scales what the sensor reports.
        let gain =
            SimProfile { sensor_gain: Some(crate::effects::sensor_gain::Params { g: 0.9 }), ..SimProfile::default() };
        let mut scaled = RigSensor::new(rig, quiet(gain, 1.0)).unwrap();
        let want = 0.9 * peak_depth(&clean.frame_at_pose(&pose(3.0)));
        let got = peak_depth(&scaled.frame_at_pose(&pose(3.0)));
        assert!((got - want).abs() < 1e-6, "{got} vs {want}");
        assert_eq!(scaled.effect_failures(), 0);
    }

    #[test]
    fn a_mounted_rigid_ball_reads_the_travel_times_the_gain_and_unmounting_restores() {
        let rig = Rig::new(VirtualClock::new(1.0), axis(-10.0, 10.0), axis(-360.0, 360.0));
        let pose = |stage_mm| RigPose { t_s: 0.0, stage_mm, rot_deg: 0.0 };
        let gain =
            SimProfile { sensor_gain: Some(crate::effects::sensor_gain::Params { g: 0.99 }), ..SimProfile::default() };
        let mut s = RigSensor::new(rig.clone(), quiet(gain, 1.0)).unwrap();
        let mut plain = RigSensor::new(rig, quiet(SimProfile::default(), 1.0)).unwrap();
        let soft = peak_depth(&s.frame_at_pose(&pose(2.0)));
        let mount = s.mount();
        let ball = Body { e_mpa: crate::experiment::RIGID_BALL_E_MPA, nu: crate::experiment::RIGID_BALL_NU, r_mm: 5.0 };
        mount.mount(Some(ball));
        s.frame_at_pose(&pose(0.5));
        assert_eq!(s.pair().indenter, ball);
        // A steel ball takes (almost) none of the 1 mm travel: the gel takes it all ...
        let g1 = s.truth(&pose(2.0)).unwrap().normal.gamma1_mm;
        assert!((g1 - 1.0).abs() < 1e-4, "gamma1 under the ball {g1}, want the travel 1 mm");
        // ... and the sensor reads it times its gain.
        plain.mount().mount(Some(ball));
        plain.frame_at_pose(&pose(0.5));
        let hard = peak_depth(&s.frame_at_pose(&pose(2.0)));
        let hard_plain = peak_depth(&plain.frame_at_pose(&pose(2.0)));
        assert!((hard / hard_plain - 0.99).abs() < 1e-6, "ball reads {hard} against {hard_plain} without the gain");
        assert!(hard > soft + 0.05, "the ball {hard} must press deeper than the soft indenter {soft}");
        mount.mount(None);
        s.frame_at_pose(&pose(0.5));
        let again = peak_depth(&s.frame_at_pose(&pose(2.0)));
        assert!((again - soft).abs() < 1e-9, "{again} vs {soft}");
        assert_eq!(s.effect_failures(), 0);
    }
}
