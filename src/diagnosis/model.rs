//! The diagnosis's forward model: the recording's own commanded history run
//! through `sim::effects::simulate` (the same true-rig model the simulator
//! uses), with E1, nu1, the stage zero z0 and the parameters of zero or more
//! candidate effects, fitted by the project's Levenberg–Marquardt.

use std::sync::Arc;

use nalgebra::DMatrix;
use sim::effects::{
    self, CommandedPose, EffectInfo, Material, Reading, SimProfile, adhesion, contact_offset, finite_thickness,
    frame_compliance, partial_slip, rotation_backlash, sensor_gain, stage_backlash, thermal_drift, viscoelastic,
};
use sim::physics::{Body, ContactPair};
use sim::recording::{Phase, Recording};

use crate::fit::fe_law::LayeredBase;
use crate::fit::weights::SampleSd;
use crate::numerics::lm::{self, LmOptions};
use crate::numerics::stats::median;

/// An effect of the library the diagnosis can fit, with its parametrisation.
/// `contact_offset` is not here: z0 is part of every fit (the baseline's third parameter).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Candidate {
    FiniteThickness,
    Adhesion,
    /// `memory`: the gel's memory of a history before the first sample is
    /// fitted too (a recording that says the rig moved before it).
    Viscoelastic {
        memory: bool,
    },
    StageBacklash,
    FrameCompliance,
    PartialSlip,
    RotationBacklash,
    ThermalDrift,
    SensorGain,
}

/// Number of base parameters (ln E1, logit nu1, z0) ahead of the effects'
/// parameters on the half-space; on a declared layer whose fit found the
/// friction between indenter and gel, ln(friction) is a fourth
/// ([`Model::n_base`]).
pub const BASE: usize = 3;

/// Friction coefficients a layered refit may take (internal: its
/// logarithm). Below the range a refit is refused; above it the friction is
/// held at its top, where the twist sticks as it does at any larger one (a
/// flat cost, so a fit that found the twist stuck starts on the top and
/// moves its other parameters freely).
const FRICTION_RANGE: [f64; 2] = [1e-3, 1e3];

impl Candidate {
    /// The effects a diagnosis refits, in library order. `sensor_gain` is left
    /// out: it has no signature of its own, so it is probed for degeneracy instead.
    pub const FITTED: [Candidate; 8] = [
        Candidate::FiniteThickness,
        Candidate::Adhesion,
        Candidate::Viscoelastic { memory: false },
        Candidate::StageBacklash,
        Candidate::FrameCompliance,
        Candidate::PartialSlip,
        Candidate::RotationBacklash,
        Candidate::ThermalDrift,
    ];

    /// Whether the effect acts outside the contact (the rig's motion, frame
    /// or sensor), so that it wraps any contact model, a declared layer's too.
    pub fn acts_outside_the_contact(self) -> bool {
        !matches!(
            self,
            Candidate::FiniteThickness | Candidate::Adhesion | Candidate::Viscoelastic { .. } | Candidate::PartialSlip
        )
    }

    /// Whether the effect, on the standard sweeps, takes approach away in
    /// proportion to the load as a stiffer elastomer would (a compliant
    /// frame, a thin layer, a depth-scale error): E1 and nu1 nearly stand
    /// in for it, and two of these rank only on the noise draw
    /// (docs/diagnosis.md, "3. Explain").
    pub fn mimics_stiffness(self) -> bool {
        matches!(self, Candidate::FrameCompliance | Candidate::FiniteThickness | Candidate::SensorGain)
    }

    pub fn info(self) -> &'static EffectInfo {
        match self {
            Candidate::FiniteThickness => &finite_thickness::INFO,
            Candidate::Adhesion => &adhesion::INFO,
            Candidate::Viscoelastic { .. } => &viscoelastic::INFO,
            Candidate::StageBacklash => &stage_backlash::INFO,
            Candidate::FrameCompliance => &frame_compliance::INFO,
            Candidate::PartialSlip => &partial_slip::INFO,
            Candidate::RotationBacklash => &rotation_backlash::INFO,
            Candidate::ThermalDrift => &thermal_drift::INFO,
            Candidate::SensorGain => &sensor_gain::INFO,
        }
    }

    pub fn name(self) -> &'static str {
        self.info().name
    }

    pub fn from_name(name: &str) -> Option<Candidate> {
        Candidate::FITTED.into_iter().chain([Candidate::SensorGain]).find(|c| c.name() == name)
    }

    /// Names and units of the fitted parameters as reported (the profile's own names).
    pub fn param_names(self) -> &'static [(&'static str, &'static str)] {
        match self {
            Candidate::FiniteThickness => &[("h_mm", "mm")],
            Candidate::Adhesion => &[("w_mJ_m2", "mJ/m^2"), ("eta", "")],
            Candidate::Viscoelastic { memory: false } => &[("rho", ""), ("tau_s", "s")],
            Candidate::Viscoelastic { memory: true } => &[("rho", ""), ("tau_s", "s"), ("memory_n", "N")],
            Candidate::StageBacklash => &[("b_mm", "mm")],
            Candidate::FrameCompliance => &[("c_mm_per_n", "mm/N")],
            Candidate::PartialSlip => &[("mu", "")],
            Candidate::RotationBacklash => &[("b_deg", "deg")],
            Candidate::ThermalDrift => &[("v_mm_per_s", "mm/s")],
            Candidate::SensorGain => &[("g", "")],
        }
    }

    pub fn n_params(self) -> usize {
        self.param_names().len()
    }

    /// The leading parameters that are the effect itself; the rest are
    /// nuisances of the recording (the creep's memory of an unrecorded
    /// history, an initial condition). Whether E1/nu1 can stand in for the
    /// effect is judged on these; a nuisance that trades with E1/nu1 widens
    /// their intervals through the covariance instead.
    pub fn n_identifying(self) -> usize {
        match self {
            Candidate::Viscoelastic { .. } => 2,
            c => c.n_params(),
        }
    }

    /// Starting point in internal coordinates: a small, typical amount of the effect.
    pub fn start(self) -> &'static [f64] {
        match self {
            // 1/h in 1/mm: a 10 mm layer.
            Candidate::FiniteThickness => &[0.1],
            // w / 100 mJ/m², eta.
            Candidate::Adhesion => &[0.3, 2.0],
            // rho - 1, ln tau (and the memory of an unrecorded history, N).
            Candidate::Viscoelastic { memory: false } => &[0.02, 1.609_437_912_434_100_3],
            Candidate::Viscoelastic { memory: true } => &[0.02, 1.609_437_912_434_100_3, 0.0],
            Candidate::StageBacklash => &[0.003],
            Candidate::FrameCompliance => &[0.003],
            // 1/mu: well inside full stick so that the start never hits gross slip.
            Candidate::PartialSlip => &[0.3],
            Candidate::RotationBacklash => &[0.05],
            // µm/s.
            Candidate::ThermalDrift => &[0.0],
            Candidate::SensorGain => &[1.0],
        }
    }

    /// A second start next to the neutral value, where the fit begins at the
    /// baseline's cost and so can only improve on it.
    pub fn near_neutral(self) -> &'static [f64] {
        match self {
            // 1/h below 1e-3 switches the layer off (a flat cost, no gradient):
            // start just above, a 500 mm layer, which is next to a half-space.
            Candidate::FiniteThickness => &[0.002],
            Candidate::Adhesion => &[0.0, 2.0],
            Candidate::Viscoelastic { memory: false } => &[0.0, 1.609_437_912_434_100_3],
            Candidate::Viscoelastic { memory: true } => &[0.0, 1.609_437_912_434_100_3, 0.0],
            Candidate::StageBacklash => &[0.0],
            Candidate::FrameCompliance => &[0.0],
            Candidate::PartialSlip => &[0.01],
            Candidate::RotationBacklash => &[0.0],
            Candidate::ThermalDrift => &[0.0],
            Candidate::SensorGain => &[1.0],
        }
    }

    /// Every start the refit tries (the adhesion landscape has separate basins
    /// for weak and strong tack, so it gets a ladder of w).
    pub fn starts(self) -> Vec<&'static [f64]> {
        match self {
            Candidate::Adhesion => vec![&[0.3, 2.0], &[0.0, 2.0], &[1.5, 2.0], &[4.0, 2.0]],
            Candidate::ThermalDrift | Candidate::SensorGain => vec![self.start()],
            _ => vec![self.start(), self.near_neutral()],
        }
    }

    /// Further starts tried only when the usual ones leave the fit far above
    /// the noise (a thin layer: the baseline is far off and the path from a
    /// thick-layer start runs into the model's no-solution region; strong
    /// creep, below).
    pub fn fallback_starts(self) -> Vec<&'static [f64]> {
        match self {
            Candidate::FiniteThickness => vec![&[0.3], &[0.6], &[1.0]],
            // A creeping gel lets go of the indenter early on unloading (its
            // surface recovers slower than the stage retracts): which samples
            // still touch changes with rho and tau in steps, each a cliff of
            // chi², which splits the landscape into basins. Strong creep at
            // short, medium and long retardation times (2, 8, 30 s) reaches them.
            Candidate::Viscoelastic { memory: false } => {
                vec![&[0.1, std::f64::consts::LN_2], &[0.1, 2.079_441_541_679_835_9], &[0.1, 3.401_197_381_662_155_4]]
            }
            Candidate::Viscoelastic { memory: true } => vec![
                &[0.1, std::f64::consts::LN_2, 0.0],
                &[0.1, 2.079_441_541_679_835_9, 0.0],
                &[0.1, 3.401_197_381_662_155_4, 0.0],
            ],
            _ => Vec::new(),
        }
    }

    /// Internal coordinate `j` to the reported physical value.
    pub fn physical(self, j: usize, x: f64) -> f64 {
        match (self, j) {
            (Candidate::FiniteThickness, _) => 1.0 / x,
            (Candidate::Adhesion, 0) => 100.0 * x,
            (Candidate::Viscoelastic { .. }, 0) => 1.0 + x,
            (Candidate::Viscoelastic { .. }, 1) => x.exp(),
            (Candidate::PartialSlip, _) => 1.0 / x,
            (Candidate::ThermalDrift, _) => x * 1e-3,
            _ => x,
        }
    }

    /// Put the effect with internal parameters `x` into `p`; false outside the model's bounds.
    fn apply(self, x: &[f64], p: &mut SimProfile) -> bool {
        let ok = |v: f64, lo: f64, hi: f64| v.is_finite() && v >= lo && v <= hi;
        match self {
            Candidate::FiniteThickness => {
                if !ok(x[0], 0.0, 2.0) {
                    return false;
                }
                // Thicker than the library's 1000 mm bound is a half-space: the layer is off.
                if x[0] >= 1e-3 {
                    p.finite_thickness = Some(finite_thickness::Params { h_mm: 1.0 / x[0] });
                }
            }
            Candidate::Adhesion => {
                if !ok(x[0], 0.0, 5.0) || !ok(x[1], 1.0, 20.0) {
                    return false;
                }
                p.adhesion = Some(adhesion::Params { w_mj_m2: 100.0 * x[0], eta: x[1] });
            }
            Candidate::Viscoelastic { memory } => {
                let memory_n = if memory { x[2] } else { 0.0 };
                if !ok(x[0], 0.0, 1.0) || !ok(x[1], 0.05f64.ln(), 1000f64.ln()) || !ok(memory_n, -100.0, 100.0) {
                    return false;
                }
                p.viscoelastic = Some(viscoelastic::Params { rho: 1.0 + x[0], tau_s: x[1].exp(), memory_n });
            }
            Candidate::StageBacklash => {
                if !ok(x[0], 0.0, 0.2) {
                    return false;
                }
                p.stage_backlash = Some(stage_backlash::Params { b_mm: x[0], engaged: true });
            }
            Candidate::FrameCompliance => {
                if !ok(x[0], 0.0, 0.2) {
                    return false;
                }
                p.frame_compliance = Some(frame_compliance::Params { c_mm_per_n: x[0] });
            }
            Candidate::PartialSlip => {
                if !ok(x[0], 0.01, 20.0) {
                    return false;
                }
                p.partial_slip = Some(partial_slip::Params { mu: 1.0 / x[0] });
            }
            Candidate::RotationBacklash => {
                if !ok(x[0], 0.0, 5.0) {
                    return false;
                }
                p.rotation_backlash = Some(rotation_backlash::Params { b_deg: x[0], engaged: true });
            }
            Candidate::ThermalDrift => {
                if !ok(x[0], -5.0, 5.0) {
                    return false;
                }
                p.thermal_drift = Some(thermal_drift::Params { v_mm_per_s: x[0] * 1e-3, vdot_mm_per_s2: 0.0 });
            }
            Candidate::SensorGain => {
                if !ok(x[0], 0.5, 1.5) {
                    return false;
                }
                p.sensor_gain = Some(sensor_gain::Params { g: x[0] });
            }
        }
        true
    }
}

/// The commanded history as the rig lived it (docs/diagnosis.md, "The
/// measurement"), from the recording's optional times: each move a ramp from
/// the previous sample's pose over the time it ran, and each sample the mean
/// of the readings over the frames it averaged (Simpson's rule on the first,
/// middle and last frame time). Without the times a sample is a step to its
/// pose at the previous sample's time, read at its own time.
struct TimedHistory {
    cmds: Vec<CommandedPose>,
    /// Per sample: the indices of its frames' first, middle and last points in `cmds`.
    frames: Vec<[usize; 3]>,
}

/// Intermediate poses of a ramp (the move's end is one more).
const RAMP_POINTS: usize = 3;

impl TimedHistory {
    fn of(rec: &Recording, sparse: &[CommandedPose]) -> Option<Self> {
        if rec.samples.iter().all(|s| s.timing.is_empty()) {
            return None;
        }
        let mut cmds: Vec<CommandedPose> = Vec::with_capacity(sparse.len() * (RAMP_POINTS + 4));
        let mut frames = Vec::with_capacity(sparse.len());
        let push = |cmds: &mut Vec<CommandedPose>, c: CommandedPose| {
            // Times never run backwards (the recorded ones are rounded to 1 ms).
            let t_s = cmds.last().map_or(c.t_s, |p| c.t_s.max(p.t_s));
            cmds.push(CommandedPose { t_s, ..c });
            cmds.len() - 1
        };
        for (i, (s, c)) in rec.samples.iter().zip(sparse).enumerate() {
            // The first sample's move came from the approach, whose poses
            // are not recorded: it starts at its pose, as without times.
            if let (Some((a, b)), Some(prev)) = (s.timing.move_s, i.checked_sub(1).map(|j| sparse[j])) {
                for k in 1..=RAMP_POINTS {
                    let f = k as f64 / (RAMP_POINTS + 1) as f64;
                    push(
                        &mut cmds,
                        CommandedPose {
                            t_s: a + f * (b - a),
                            stage_mm: prev.stage_mm + f * (c.stage_mm - prev.stage_mm),
                            rot_deg: prev.rot_deg + f * (c.rot_deg - prev.rot_deg),
                        },
                    );
                }
                push(&mut cmds, CommandedPose { t_s: b, ..*c });
            }
            let from = s.timing.frames_from_s.unwrap_or(c.t_s).min(c.t_s);
            let first = push(&mut cmds, CommandedPose { t_s: from, ..*c });
            let middle = push(&mut cmds, CommandedPose { t_s: 0.5 * (from + c.t_s), ..*c });
            let last = push(&mut cmds, *c);
            frames.push([first, middle, last]);
        }
        Some(Self { cmds, frames })
    }

    /// One reading per sample: the last frame's state, its gamma1 and theta1
    /// the mean over the frames.
    fn reduce(&self, dense: &[Reading]) -> Option<Vec<Reading>> {
        self.frames
            .iter()
            .map(|&[a, m, b]| {
                let (ra, rm, rb) = (dense.get(a)?, dense.get(m)?, dense.get(b)?);
                let simpson = |f: fn(&Reading) -> f64| (f(ra) + 4.0 * f(rm) + f(rb)) / 6.0;
                Some(Reading { gamma1_mm: simpson(|r| r.gamma1_mm), theta1_deg: simpson(|r| r.theta1_deg), ..*rb })
            })
            .collect()
    }
}

/// Whether `rec`'s readings of exactly zero are "no contact seen" rather
/// than measured depths: a recording that carries standard errors comes
/// from a sensor that estimates each reading (`easycalib run`), and such a
/// sensor reads a contact it cannot resolve as none. Those zeros weigh
/// nothing in the diagnosis, as in the full-model fit. (A generator's zeros
/// are the model's own dead band, exact, and pin z0.) The first live sample
/// decides, so this is cheap.
pub fn zeros_unseen(rec: &Recording) -> bool {
    rec.samples.iter().any(|s| s.gamma1_sd_mm.is_some())
}

/// Base parameters in physical units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Base {
    pub e1_mpa: f64,
    pub nu1: f64,
    pub contact_offset_mm: f64,
}

impl Base {
    pub fn internal(&self) -> [f64; 3] {
        let p = (self.nu1 / 0.5).clamp(1e-6, 1.0 - 1e-6);
        [self.e1_mpa.ln(), (p / (1.0 - p)).ln(), self.contact_offset_mm]
    }
    pub fn from_internal(x: &[f64]) -> Base {
        Base { e1_mpa: x[0].exp(), nu1: 0.5 / (1.0 + (-x[1]).exp()), contact_offset_mm: x[2] }
    }
}

/// One fitted model: which effects, where, how well.
#[derive(Debug, Clone)]
pub struct Fitted {
    pub cands: Vec<Candidate>,
    /// Internal coordinates: BASE base parameters, then each effect's in order.
    pub x: Vec<f64>,
    /// Weighted sum of squares (chi², with the noise floor as weights).
    pub chi2: f64,
    pub readings: Vec<Reading>,
    /// Weighted residuals at the optimum.
    pub residuals: Vec<f64>,
    /// Covariance of the internal coordinates (scaled by chi²/dof), if the
    /// Jacobian is regular; filled by [`Model::finish`].
    pub cov: Option<DMatrix<f64>>,
    /// Per parameter: how much its variance grows because E1, nu1 and z0 can
    /// take its place (1 = independent; base parameters themselves get 1).
    pub vif: Vec<f64>,
    pub dof: usize,
    pub iterations: usize,
    /// chi²/dof, the scale of `cov`.
    pub s2: f64,
    /// How many of `x`'s leading coordinates are base parameters ([`Model::n_base`]).
    pub n_base: usize,
}

impl Fitted {
    pub fn base(&self) -> Base {
        Base::from_internal(&self.x)
    }
    pub fn n_params(&self) -> usize {
        self.x.len()
    }
    /// Standard error of internal coordinate `j`.
    pub fn se(&self, j: usize) -> f64 {
        self.cov.as_ref().map_or(f64::INFINITY, |c| c[(j, j)].max(0.0).sqrt())
    }
    /// Standard error of internal coordinate `j` for unit noise scale (chi²/dof = 1),
    /// which makes fits with different misfit comparable.
    pub fn se_unscaled(&self, j: usize) -> f64 {
        self.se(j) / self.s2.max(1e-300).sqrt()
    }
    /// Offset of candidate `k`'s first parameter in `x`.
    pub fn offset_of(&self, k: usize) -> usize {
        self.n_base + self.cands[..k].iter().map(|c| c.n_params()).sum::<usize>()
    }
}

/// The recording's commanded history and the weights of its readings.
pub struct Model<'a> {
    rec: &'a Recording,
    cmds: Vec<CommandedPose>,
    /// The history as the rig lived it, when the recording has the times.
    timed: Option<TimedHistory>,
    /// Noise of gamma1 readings, mm; with recorded standard errors, the
    /// factor they are multiplied by (1, or the inflation the data ask for).
    pub sigma_g: f64,
    /// Noise of theta1 readings, degrees; with recorded standard errors, their factor.
    pub sigma_t: f64,
    /// Per-sample gamma1 standard error (mm) where the recording carries them, else 1.
    sd_g: Vec<f64>,
    /// Per-sample theta1 standard error (degrees) where the recording carries them, else 1.
    sd_t: Vec<f64>,
    /// Iteration cap of each refit.
    pub max_iterations: usize,
    /// LM stops when a step lowers chi² by less than this fraction.
    pub cost_tolerance: f64,
    /// The recording carries standard errors (a sensor that estimates its
    /// readings, `easycalib run`): its readings of exactly zero are "no
    /// contact seen", not measured depths, and weigh nothing (as in the
    /// full-model fit, docs/diagnosis.md "1. Compare").
    zeros_unseen: bool,
    /// The declared layer's FE model the recording's fit ended on, which then
    /// replaces the paper's contact (docs/diagnosis.md, "On a declared layer").
    layer: Option<Arc<LayeredBase>>,
}

impl<'a> Model<'a> {
    pub fn new(rec: &'a Recording, sigma_g: f64, sigma_t: f64) -> Self {
        let cmds: Vec<CommandedPose> = rec
            .samples
            .iter()
            .map(|s| CommandedPose {
                t_s: s.t_s,
                stage_mm: s.stage_mm,
                rot_deg: if s.phase == Phase::Torsion { s.rot_deg } else { 0.0 },
            })
            .collect();
        let ones = vec![1.0; rec.samples.len()];
        let timed = TimedHistory::of(rec, &cmds);
        Self {
            rec,
            cmds,
            timed,
            sigma_g,
            sigma_t,
            sd_g: ones.clone(),
            sd_t: ones,
            max_iterations: 40,
            cost_tolerance: 1e-5,
            zeros_unseen: zeros_unseen(rec),
            layer: None,
        }
    }

    /// Model the contact with the declared layer's FE model `base` instead of
    /// the paper's; only the effects that act outside the contact are then
    /// candidates ([`Model::fitted_candidates`]).
    pub fn on_layer(mut self, base: LayeredBase) -> Self {
        self.layer = Some(Arc::new(base));
        self
    }

    /// The declared layer's model, when the contact is modelled with it.
    pub fn layer(&self) -> Option<&LayeredBase> {
        self.layer.as_deref()
    }

    /// How many base parameters a fit has: E1, nu1 and z0, and on a declared
    /// layer whose fit found a friction between indenter and gel, that
    /// friction too (the twist depends on it, and an effect the fit did not
    /// know about biases it: a drifting frame took it to 1.4 for a true 0.4).
    pub fn n_base(&self) -> usize {
        BASE + usize::from(self.layer.as_ref().is_some_and(|l| l.friction().is_some()))
    }

    /// The internal coordinates of base parameters `b` (with the layer fit's
    /// friction where it is one of them).
    pub fn start(&self, b: &Base) -> Vec<f64> {
        let mut x = b.internal().to_vec();
        // A fit that found the twist stuck ends at a friction of any size,
        // where the cost is flat: a refit starts from the fit's own first
        // guess instead, so that an effect that explains the stiff twist can
        // bring the friction back (a drifting frame took a neo-Hookean fit of
        // a gel with friction 0.4 to full stick).
        let friction = self.layer.as_ref().and_then(|l| l.friction()).filter(|_| self.n_base() > BASE);
        let friction = friction.map(|m| if m >= FRICTION_RANGE[1] { crate::fit::full::FRICTION_START } else { m });
        x.extend(friction.map(|m| m.clamp(FRICTION_RANGE[0], FRICTION_RANGE[1]).ln()));
        x
    }

    /// The internal base coordinates of where a previous pass's explanation
    /// ended, on a layer whose correction was taken there
    /// ([`LayeredBase::previous_explanation`]).
    pub fn previous_start(&self) -> Option<Vec<f64>> {
        let p = self.layer.as_ref()?.previous_explanation()?;
        Some(self.start(&Base { e1_mpa: p.e1_mpa, nu1: p.nu1, contact_offset_mm: p.contact_offset_mm }))
    }

    /// The friction of internal coordinates `x` on a declared layer (the layer
    /// fit's when `x` has none), `None` when the twist sticks.
    pub fn friction(&self, x: &[f64]) -> Option<f64> {
        let fitted = self.layer.as_ref()?.friction()?;
        Some(x.get(BASE).filter(|_| self.n_base() > BASE).map_or(fitted, |y| y.exp().min(FRICTION_RANGE[1])))
    }

    /// Weigh each reading by its recorded standard error (the channels `sd`
    /// has); `sigma_g` / `sigma_t` then scale those errors.
    pub fn with_standard_errors(mut self, sd: &SampleSd) -> Self {
        if let Some(g) = &sd.gamma1_mm {
            self.sd_g.clone_from(g);
        }
        if let Some(t) = &sd.theta1_deg {
            self.sd_t.clone_from(t);
        }
        self
    }

    /// The gamma1 noise the residuals are judged against, mm: the floor, or
    /// the median recorded standard error of the live samples times its factor.
    pub fn noise_gamma1_mm(&self) -> f64 {
        let mut live: Vec<f64> =
            self.rec.samples.iter().zip(&self.sd_g).filter(|(s, _)| s.gamma1_mm != 0.0).map(|(_, v)| *v).collect();
        self.sigma_g * if live.is_empty() { 1.0 } else { median(&mut live) }
    }

    /// The theta1 noise the residuals are judged against, degrees (as [`Model::noise_gamma1_mm`]).
    pub fn noise_theta1_deg(&self) -> f64 {
        let mut tor: Vec<f64> = self
            .rec
            .samples
            .iter()
            .zip(&self.sd_t)
            .filter(|(s, _)| s.phase == Phase::Torsion)
            .map(|(_, v)| *v)
            .collect();
        self.sigma_t * if tor.is_empty() { 1.0 } else { median(&mut tor) }
    }

    pub fn recording(&self) -> &Recording {
        self.rec
    }

    /// `c` as this recording fits it: the viscoelastic candidate fits the
    /// gel's memory when the recording says the rig moved before its first
    /// sample (`t_move_start_s` on that row: an approach the recording does
    /// not hold; docs/diagnosis.md, "The measurement").
    pub fn candidate(&self, c: Candidate) -> Candidate {
        match c {
            Candidate::Viscoelastic { .. } => {
                Candidate::Viscoelastic { memory: self.rec.samples.first().is_some_and(|s| s.timing.move_s.is_some()) }
            }
            other => other,
        }
    }

    /// The candidates a diagnosis refits, as this recording fits them.
    /// On a declared layer, only those that act outside the contact (the
    /// layer is modelled, and the contact effects are written on the half-space).
    pub fn fitted_candidates(&self) -> Vec<Candidate> {
        Candidate::FITTED
            .into_iter()
            .filter(|&c| self.layer.is_none() || c.acts_outside_the_contact())
            .map(|c| self.candidate(c))
            .collect()
    }

    /// The sim profile of a parameter vector (None outside the bounds).
    pub fn profile(&self, cands: &[Candidate], x: &[f64]) -> Option<SimProfile> {
        let b = Base::from_internal(x);
        if !(b.e1_mpa.is_finite() && b.e1_mpa > 0.0 && (-0.5..=0.5).contains(&b.contact_offset_mm)) {
            return None;
        }
        let mut p = SimProfile {
            material: Some(Material { e1_mpa: b.e1_mpa, nu1: b.nu1 }),
            contact_offset: Some(contact_offset::Params { contact_offset_mm: b.contact_offset_mm }),
            ..Default::default()
        };
        if !cands.is_empty() && x.len() < self.n_base() {
            return None;
        }
        if self.n_base() > BASE && x.len() > BASE && (x[BASE].is_nan() || x[BASE].exp() < FRICTION_RANGE[0]) {
            return None;
        }
        let mut off = self.n_base();
        for c in cands {
            let n = c.n_params();
            if !c.apply(&x[off..off + n], &mut p) {
                return None;
            }
            off += n;
        }
        p.validate().ok()?;
        Some(p)
    }

    /// Noise-free readings of the recording's commanded history under `profile`.
    /// A profile whose rig changes with time alone (creep, drift) is run
    /// through the history as the rig lived it where the recording says
    /// when ([`TimedHistory`]); for the others that history reads the same.
    pub fn readings(&self, profile: &SimProfile) -> Option<Vec<Reading>> {
        self.readings_with(profile, self.layer.as_ref().and_then(|l| l.friction()))
    }

    /// [`Model::readings`] with the friction between indenter and a declared
    /// layer (unused on the half-space).
    fn readings_with(&self, profile: &SimProfile, friction: Option<f64>) -> Option<Vec<Reading>> {
        let m = profile.material?;
        let pair = ContactPair {
            elastomer: Body::new(m.e1_mpa, m.nu1, self.rec.meta.elastomer_r_mm),
            indenter: self.rec.meta.indenter,
        };
        let timed = self.timed.as_ref().filter(|_| profile.viscoelastic.is_some() || profile.thermal_drift.is_some());
        let cmds = timed.map_or(&self.cmds, |h| &h.cmds);
        let dense = match &self.layer {
            None => effects::simulate(pair, profile, cmds).ok()?,
            Some(l) => effects::simulate_on(pair, profile, l.law(m.e1_mpa, m.nu1, friction).ok()?, cmds).ok()?,
        };
        let mut out = match timed {
            Some(h) => h.reduce(&dense)?,
            None => dense,
        };
        if let Some(l) = &self.layer {
            let z0 = profile.contact_offset.map_or(0.0, |c| c.contact_offset_mm);
            let gain = profile.sensor_gain.map_or(1.0, |g| g.g);
            l.correct(&mut out, m.e1_mpa, m.nu1, z0, friction, gain);
        }
        Some(out)
    }

    /// Weighted residuals: gamma1 of every sample (the dead band pins z0), then
    /// theta1 of every torsion sample, each divided by its noise.
    pub fn weighted(&self, pred: &[Reading], out: &mut Vec<f64>) {
        out.clear();
        for ((s, p), sd) in self.rec.samples.iter().zip(pred).zip(&self.sd_g) {
            let unseen = self.zeros_unseen && s.gamma1_mm == 0.0;
            out.push(if unseen { 0.0 } else { (s.gamma1_mm - p.gamma1_mm) / (self.sigma_g * sd) });
        }
        for ((s, p), sd) in self.rec.samples.iter().zip(pred).zip(&self.sd_t) {
            if s.phase == Phase::Torsion {
                out.push((s.theta1_deg - p.theta1_deg) / (self.sigma_t * sd));
            }
        }
    }

    /// chi² of `pred` with the recording's standard errors (where it has
    /// them) scaled by `sigma_g` and `sigma_t` instead of this model's factors:
    /// two models compared at one noise.
    pub fn chi2_at(&self, pred: &[Reading], sigma_g: f64, sigma_t: f64) -> f64 {
        let mut r = Vec::new();
        self.weighted(pred, &mut r);
        let n_g = self.rec.samples.len();
        let (kg, kt) = (self.sigma_g / sigma_g, self.sigma_t / sigma_t);
        r.iter().enumerate().map(|(i, v)| (v * if i < n_g { kg } else { kt }).powi(2)).sum()
    }

    fn eval(&self, cands: &[Candidate], x: &[f64], out: &mut Vec<f64>) -> bool {
        let Some(p) = self.profile(cands, x) else {
            return false;
        };
        let Some(r) = self.readings_with(&p, self.friction(x)) else {
            return false;
        };
        self.weighted(&r, out);
        out.iter().all(|v| v.is_finite())
    }

    /// Readings that carry noise (dead-band zeros excluded): the observation count.
    pub fn n_obs(&self) -> usize {
        let live = self.rec.samples.iter().filter(|s| s.gamma1_mm != 0.0).count();
        live + self.rec.phase(Phase::Torsion).count()
    }

    /// Fit E1, nu1, z0 and the candidates' parameters from `x0` (internal coordinates).
    pub fn fit(&self, cands: &[Candidate], x0: &[f64]) -> Option<Fitted> {
        self.fit_with(cands, x0, self.max_iterations, self.cost_tolerance)
    }

    /// [`Model::fit`] with its own iteration cap and cost tolerance.
    pub fn fit_with(
        &self,
        cands: &[Candidate],
        x0: &[f64],
        max_iterations: usize,
        cost_tolerance: f64,
    ) -> Option<Fitted> {
        // On the FE layer model a search ends within a twentieth of a standard
        // error of its optimum (the fit's rule, `fit::full`): the contact's
        // nodes ripple the model in its last digits, and the cost tolerance
        // alone spends refused trials there.
        let within_se = self.layer.as_ref().map(|_| crate::fit::full::FIT_WITHIN_SE);
        let opts = LmOptions { max_iterations, cost_tolerance, step_tolerance: 1e-6, fd_step: 1e-6, within_se };
        let out = lm::minimize(|x, r| self.eval(cands, x, r), x0, opts).ok()?;
        let profile = self.profile(cands, &out.x)?;
        let readings = self.readings_with(&profile, self.friction(&out.x))?;
        let n = out.x.len();
        let dof = self.n_obs().saturating_sub(n).max(1);
        let s2 = out.ssr / dof as f64;
        Some(Fitted {
            cands: cands.to_vec(),
            x: out.x,
            chi2: out.ssr,
            readings,
            residuals: out.residuals,
            cov: None,
            vif: Vec::new(),
            dof,
            iterations: out.iterations,
            s2,
            n_base: self.n_base(),
        })
    }

    /// Covariance and variance inflation of a fit (2 model runs per
    /// parameter, so only for the fits that are reported or compared).
    pub fn finish(&self, f: &mut Fitted) {
        if f.cov.is_none() && f.vif.is_empty() {
            let (cov, vif) = self.covariance(&f.cands, &f.x, &f.residuals, f.dof);
            f.cov = cov;
            f.vif = vif;
        }
    }

    /// Covariance from a central-difference Jacobian, and each parameter's
    /// variance inflation factor (from the normalised information matrix).
    fn covariance(&self, cands: &[Candidate], x: &[f64], r0: &[f64], dof: usize) -> (Option<DMatrix<f64>>, Vec<f64>) {
        let Some(jac) = self.jacobian(cands, x, r0.len()) else {
            return (None, vec![f64::INFINITY; x.len()]);
        };
        let s2 = r0.iter().map(|v| v * v).sum::<f64>() / dof as f64;
        let info = jac.transpose() * &jac;
        let n = x.len();
        let scale: Vec<f64> = (0..n).map(|j| info[(j, j)].max(1e-300).sqrt()).collect();
        let norm = DMatrix::from_fn(n, n, |i, j| info[(i, j)] / (scale[i] * scale[j]));
        let Some(inv) = norm.clone().try_inverse() else {
            return (None, vec![f64::INFINITY; n]);
        };
        // Each effect parameter against the base parameters alone (not against
        // the other parameters of its own effect).
        let nb = self.n_base();
        let vif: Vec<f64> = (0..n)
            .map(|j| {
                if j < nb {
                    return 1.0;
                }
                let idx: Vec<usize> = (0..nb).chain([j]).collect();
                let sub = DMatrix::from_fn(nb + 1, nb + 1, |a, b| norm[(idx[a], idx[b])]);
                sub.try_inverse().map_or(f64::INFINITY, |m| m[(nb, nb)])
            })
            .collect();
        if (0..n).any(|j| !inv[(j, j)].is_finite() || inv[(j, j)] <= 0.0) {
            return (None, vec![f64::INFINITY; n]);
        }
        let cov = DMatrix::from_fn(n, n, |i, j| inv[(i, j)] / (scale[i] * scale[j]) * s2);
        (Some(cov), vif)
    }

    /// Central-difference Jacobian of the weighted residuals (one-sided at a
    /// bound). A reading that jumps inside the difference step (a sample the
    /// model puts on the edge of losing contact: a creeping gel lets go of the
    /// indenter early on unloading) has no derivative there: its row is left
    /// at zero, so that it neither informs the parameters nor makes them look
    /// interchangeable. A jump is a change of more than one standard error in
    /// one step whose one-sided differences disagree by more than half.
    pub fn jacobian(&self, cands: &[Candidate], x: &[f64], m: usize) -> Option<DMatrix<f64>> {
        let n = x.len();
        let mut jac = DMatrix::zeros(m, n);
        let (mut rp, mut rm, mut r0) = (Vec::new(), Vec::new(), Vec::new());
        if !self.eval(cands, x, &mut r0) || r0.len() != m {
            return None;
        }
        let mut jumps = vec![false; m];
        let mut xp = x.to_vec();
        for j in 0..n {
            let h = 1e-5 * x[j].abs().max(1e-2);
            xp[j] = x[j] + h;
            let up = self.eval(cands, &xp, &mut rp);
            xp[j] = x[j] - h;
            let down = self.eval(cands, &xp, &mut rm);
            xp[j] = x[j];
            let (a, b, d) = match (up, down) {
                (true, true) => (&rp, &rm, 2.0 * h),
                (true, false) => (&rp, &r0, h),
                (false, true) => (&r0, &rm, h),
                (false, false) => return None,
            };
            if a.len() != m || b.len() != m {
                return None;
            }
            for i in 0..m {
                jac[(i, j)] = (a[i] - b[i]) / d;
                if up && down {
                    let (above, below) = (rp[i] - r0[i], r0[i] - rm[i]);
                    let step = above.abs().max(below.abs());
                    jumps[i] |= step > 1.0 && (above - below).abs() > 0.5 * step;
                }
            }
        }
        for (i, _) in jumps.iter().enumerate().filter(|(_, j)| **j) {
            jac.row_mut(i).fill(0.0);
        }
        Some(jac)
    }

    /// Variance inflation of an extra candidate's parameters against E1, nu1
    /// and z0 when added at its neutral value to `fit` (no refit: a local
    /// identifiability probe). Infinite when the information matrix is singular.
    pub fn probe_vif(&self, fit: &Fitted, extra: Candidate) -> Option<Vec<f64>> {
        let mut cands = fit.cands.clone();
        cands.push(extra);
        let mut x = fit.x.clone();
        x.extend_from_slice(extra.start());
        let mut r0 = Vec::new();
        if !self.eval(&cands, &x, &mut r0) {
            return None;
        }
        let dof = self.n_obs().saturating_sub(x.len()).max(1);
        let (_, vif) = self.covariance(&cands, &x, &r0, dof);
        Some(vif[fit.x.len()..].to_vec())
    }
}
