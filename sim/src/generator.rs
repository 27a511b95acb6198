//! Synthetic recordings: what a rig would record for a known elastomer, with
//! or without the left-out physics of [`crate::effects`].
//!
//! The sweep follows the rig's own procedure: step the stage in until the
//! *measured* depth beta = (stage - gamma1) / R2 reaches the target, step back
//! out, then re-approach to the stage where the measured depth is the target
//! and twist out and back. Every reading comes from a [`TrueRig`] fed the
//! commanded history (so effects with memory, like backlash and creep, see the
//! real order of moves), carries seeded noise, and the stage and mount are
//! quantized to their resolution. An empty [`SimProfile`] is the paper's clean
//! model: the recording is then the clean physics plus noise, bit for bit.
//!
//! The recording's `stage_mm`, `rot_deg` and `t_s` are the commanded values, so
//! feeding them back to [`crate::effects::simulate`] reproduces the noise-free
//! readings exactly; that is how a diagnosis refits a recording.

use serde::{Deserialize, Serialize};

use std::sync::Arc;

use crate::effects::{CommandedPose, ContactLaw, EffectError, SimProfile, TrueRig};
use crate::experiment::{ExperimentSpec, reload_path, repeat_path, reversal_angles, sweep_angles};
use crate::physics::{ContactPair, Layer, NormalError, NormalModel, ParamError, torsion_at};
use crate::recording::{Direction, Metadata, Phase, Recording, Sample};
use crate::rng::Rng;

/// How the rig sweeps.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SweepPlan {
    /// Stage step of the normal sweep, mm.
    pub normal_step_mm: f64,
    /// Depth at which loading stops and torsion is done, beta = gamma2 / R2.
    pub target_beta: f64,
    /// Number of load/unload cycles of the normal sweep.
    pub repeats: u32,
    /// Twist amplitude of the torsion sweep (mount angle), degrees.
    pub torsion_amplitude_deg: f64,
    /// Mount step of the torsion sweep, degrees.
    pub torsion_step_deg: f64,
    /// Time per settled sample (move plus settle), s.
    pub step_time_s: f64,
}

impl Default for SweepPlan {
    fn default() -> Self {
        Self {
            normal_step_mm: 0.05,
            target_beta: 0.2,
            repeats: 1,
            torsion_amplitude_deg: 8.0,
            torsion_step_deg: 0.2,
            step_time_s: 0.8,
        }
    }
}

/// Measurement noise and actuator resolution.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NoiseSpec {
    pub gamma1_sigma_mm: f64,
    pub theta1_sigma_deg: f64,
    pub stage_resolution_mm: f64,
    pub rotation_resolution_deg: f64,
}

impl Default for NoiseSpec {
    fn default() -> Self {
        Self {
            gamma1_sigma_mm: crate::defaults::GAMMA1_SIGMA_MM,
            theta1_sigma_deg: crate::defaults::THETA1_SIGMA_DEG,
            stage_resolution_mm: crate::defaults::STAGE_RESOLUTION_MM,
            rotation_resolution_deg: crate::defaults::ROTATION_RESOLUTION_DEG,
        }
    }
}

/// Everything that defines one synthetic run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GeneratorConfig {
    pub pair: ContactPair,
    pub plan: SweepPlan,
    pub noise: NoiseSpec,
    pub seed: u64,
    pub sensor: String,
    /// Left-out physics the simulated rig has (empty: the paper's clean model).
    /// A `material` in the profile overrides `pair.elastomer`'s E1 and nu1.
    #[serde(default)]
    pub profile: SimProfile,
    /// Experiment steps after the torsion sweep, in order (docs/experiments.md).
    #[serde(default)]
    pub experiments: Vec<ExperimentSpec>,
}

impl Default for GeneratorConfig {
    /// A Tac3D-like elastomer (domed, R1 ~ 33 mm) against the paper's PDMS indenter.
    fn default() -> Self {
        Self {
            pair: crate::defaults::pair(),
            plan: SweepPlan::default(),
            noise: NoiseSpec::default(),
            seed: crate::defaults::SEED,
            sensor: "sim-tac3d".to_string(),
            profile: SimProfile::default(),
            experiments: Vec::new(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GenerateError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error(transparent)]
    Model(#[from] NormalError),
    #[error(transparent)]
    Effect(#[from] EffectError),
    #[error("sweep plan: {0}")]
    Plan(String),
}

fn quantize(x: f64, step: f64) -> f64 {
    if step > 0.0 { (x / step).round() * step } else { x }
}

/// The readings of a real, clean rig at a commanded position: the truth the
/// generator and the simulated rig share.
pub struct CleanRig {
    model: NormalModel,
    pair: ContactPair,
}

impl CleanRig {
    pub fn new(pair: ContactPair) -> Result<Self, ParamError> {
        Ok(Self { model: NormalModel::new(pair)?, pair })
    }
    pub fn model(&self) -> &NormalModel {
        &self.model
    }
    /// True gamma1 and gamma2 at stage approach `stage_mm`.
    pub fn normal(&self, stage_mm: f64) -> Result<(f64, f64), NormalError> {
        let s = self.model.solve(stage_mm)?;
        Ok((s.gamma1_mm, s.gamma2_mm))
    }
    /// True theta1 (deg) for a mount angle at stage approach `stage_mm`.
    pub fn torsion_theta1_deg(&self, stage_mm: f64, rot_deg: f64) -> Result<f64, NormalError> {
        let (_, gamma2) = self.normal(stage_mm)?;
        let beta = gamma2 / self.pair.indenter.r_mm;
        Ok(torsion_at(&self.pair, beta, rot_deg.to_radians()).theta1_rad.to_degrees())
    }
}

/// Largest twist an experiment of the generator may ask for, degrees.
const MAX_TWIST_DEG: f64 = 45.0;

/// Bisection bound on the torsion-depth search, mm of stage.
const DEPTH_TOL_MM: f64 = 1e-10;

/// A declared gel layer as the generator's contact: its exact contact, solved
/// downstream of this crate (the FE layer model), and the layer the recording
/// declares.
#[derive(Debug, Clone)]
pub struct LayeredTruth {
    pub law: Arc<dyn ContactLaw>,
    pub layer: Layer,
}

/// Generate a recording of `cfg.plan` on a rig with `cfg.profile`'s effects.
pub fn generate(cfg: &GeneratorConfig) -> Result<Recording, GenerateError> {
    generate_on(cfg, None)
}

/// [`generate`] with the contact of a declared layer (`None`: the paper's
/// half-space): the profile's rig-level effects wrap it (`TrueRig::on_law`;
/// an effect inside the contact is refused), the recording declares the
/// layer, and experiment steps are refused (an operator's indenter would
/// need a law of its own).
pub fn generate_on(cfg: &GeneratorConfig, layered: Option<&LayeredTruth>) -> Result<Recording, GenerateError> {
    let plan = cfg.plan;
    let noise = cfg.noise;
    if !(plan.normal_step_mm > 0.0 && plan.torsion_step_deg > 0.0 && plan.step_time_s > 0.0) {
        return Err(GenerateError::Plan("steps and step time must be > 0".into()));
    }
    if !(plan.target_beta > 0.0 && plan.target_beta <= 0.3) {
        return Err(GenerateError::Plan(format!("target beta {} outside (0, 0.3]", plan.target_beta)));
    }
    cfg.pair.validate()?;
    for (i, e) in cfg.experiments.iter().enumerate() {
        e.validate(i, MAX_TWIST_DEG).map_err(|e| GenerateError::Plan(e.to_string()))?;
    }
    let mut rig = match layered {
        None => TrueRig::new(cfg.pair, &cfg.profile)?,
        Some(_) if !cfg.experiments.is_empty() => {
            return Err(GenerateError::Plan("experiment steps are not simulated on a declared layer".into()));
        }
        Some(l) => TrueRig::on_law(cfg.pair, &cfg.profile, l.law.clone())?,
    };
    let pair = *rig.pair();
    let r2 = pair.indenter.r_mm;
    let mut rng = Rng::seed_from(cfg.seed);
    let mut samples = Vec::new();
    let mut t = 0.0;

    // The sensor reads exactly 0 without contact (dead band, no noise).
    let read = |rig: &mut TrueRig, rng: &mut Rng, t: f64, stage: f64, rot: f64| -> Result<(f64, f64), GenerateError> {
        let r = rig.read(CommandedPose { t_s: t, stage_mm: stage, rot_deg: rot })?;
        let g1 = if r.in_contact { r.gamma1_mm + rng.gaussian(noise.gamma1_sigma_mm) } else { 0.0 };
        Ok((g1, r.theta1_deg))
    };

    let max_steps = 10_000;
    let mut top_stage: f64 = 0.0;
    for rep in 0..plan.repeats.max(1) {
        // Load until the measured depth reaches the target.
        let mut stage_path = Vec::new();
        let mut k = 0;
        loop {
            let stage = quantize(k as f64 * plan.normal_step_mm, noise.stage_resolution_mm);
            let (g1_read, _) = read(&mut rig, &mut rng, t, stage, 0.0)?;
            samples.push(Sample {
                t_s: t,
                phase: Phase::Normal,
                stage_mm: stage,
                rot_deg: 0.0,
                gamma1_mm: g1_read,
                theta1_deg: 0.0,
                rep: Some(rep),
                dir: Some(Direction::Load),
                gamma1_sd_mm: None,
                theta1_sd_deg: None,
                experiment: None,
                timing: Default::default(),
            });
            t += plan.step_time_s;
            stage_path.push(stage);
            top_stage = top_stage.max(stage);
            let beta_measured = (stage - g1_read) / r2;
            if beta_measured >= plan.target_beta {
                break;
            }
            k += 1;
            if k > max_steps {
                return Err(GenerateError::Plan("the target depth was not reached".into()));
            }
        }
        // Unload through the same stage positions.
        for &stage in stage_path.iter().rev().skip(1) {
            let (g1_read, _) = read(&mut rig, &mut rng, t, stage, 0.0)?;
            samples.push(Sample {
                t_s: t,
                phase: Phase::Normal,
                stage_mm: stage,
                rot_deg: 0.0,
                gamma1_mm: g1_read,
                theta1_deg: 0.0,
                rep: Some(rep),
                dir: Some(Direction::Unload),
                gamma1_sd_mm: None,
                theta1_sd_deg: None,
                experiment: None,
                timing: Default::default(),
            });
            t += plan.step_time_s;
        }
    }

    // Re-approach to the stage where the rig's (noise-free) measured depth is the
    // target, and twist out and back there.
    let stage_t = quantize(torsion_stage(&rig, t, plan.target_beta * r2, top_stage)?, noise.stage_resolution_mm);
    let n_twist = (plan.torsion_amplitude_deg / plan.torsion_step_deg).round().max(1.0) as usize;
    let mut angles: Vec<(f64, Direction)> =
        (0..=n_twist).map(|i| (i as f64 * plan.torsion_step_deg, Direction::Load)).collect();
    angles.extend((0..n_twist).rev().map(|i| (i as f64 * plan.torsion_step_deg, Direction::Unload)));
    for (angle, dir) in angles {
        let rot = quantize(angle, noise.rotation_resolution_deg);
        let (g1_read, th1) = read(&mut rig, &mut rng, t, stage_t, rot)?;
        samples.push(Sample {
            t_s: t,
            phase: Phase::Torsion,
            stage_mm: stage_t,
            rot_deg: rot,
            gamma1_mm: g1_read,
            theta1_deg: th1 + rng.gaussian(noise.theta1_sigma_deg),
            rep: None,
            dir: Some(dir),
            gamma1_sd_mm: None,
            theta1_sd_deg: None,
            experiment: None,
            timing: Default::default(),
        });
        t += plan.step_time_s;
    }
    let mut run = Continued { rig, rng, t, samples, noise, step_time_s: plan.step_time_s };
    let mut hold = stage_t;
    for spec in &cfg.experiments {
        hold = run.experiment(spec, hold, top_stage)?;
    }
    let samples = run.samples;

    let mut meta = sim_metadata(cfg, &pair);
    meta.layer = layered.map(|l| l.layer);
    Ok(Recording { meta, samples })
}

/// A generated recording's metadata: the simulated truth and seed, and the effects on.
fn sim_metadata(cfg: &GeneratorConfig, pair: &ContactPair) -> Metadata {
    let mut extra = vec![
        ("sim_E1_MPa".to_string(), format!("{}", pair.elastomer.e_mpa)),
        ("sim_nu1".to_string(), format!("{}", pair.elastomer.nu)),
        ("sim_seed".to_string(), format!("{}", cfg.seed)),
    ];
    let on = cfg.profile.enabled();
    if !on.is_empty() {
        extra.push(("sim_effects".to_string(), on.join(",")));
    }
    Metadata {
        sensor: Some(cfg.sensor.clone()),
        indenter: pair.indenter,
        elastomer_r_mm: pair.elastomer.r_mm,
        layer: None,
        created: None,
        extra,
    }
}

/// What `specs` would record, noise-free, on `rig` (already fed the run's
/// history up to time `t_s`) with the stage standing at `hold_stage_mm`: the
/// experiment steps as the generator runs them, one sample per `step_time_s`.
/// A plan predicts an experiment's outcome under a hypothesis with it.
pub fn continue_run(
    rig: TrueRig,
    t_s: f64,
    hold_stage_mm: f64,
    specs: &[ExperimentSpec],
    step_time_s: f64,
) -> Result<Vec<Sample>, GenerateError> {
    let noise = NoiseSpec {
        gamma1_sigma_mm: 0.0,
        theta1_sigma_deg: 0.0,
        stage_resolution_mm: 0.0,
        rotation_resolution_deg: 0.0,
    };
    let mut run = Continued { rig, rng: Rng::seed_from(0), t: t_s, samples: Vec::new(), noise, step_time_s };
    let mut hold = hold_stage_mm;
    for (i, spec) in specs.iter().enumerate() {
        spec.validate(i, MAX_TWIST_DEG).map_err(|e| GenerateError::Plan(e.to_string()))?;
        hold = run.experiment(spec, hold, hold)?;
    }
    Ok(run.samples)
}

/// A generated run after its standard sweeps, continued by experiment steps.
struct Continued {
    rig: TrueRig,
    rng: Rng,
    t: f64,
    samples: Vec<Sample>,
    noise: NoiseSpec,
    step_time_s: f64,
}

impl Continued {
    /// One reading at (stage, mount) now, recorded as a sample of `spec`'s
    /// phase; the clock then moves on by `dt_s`.
    fn take(
        &mut self,
        spec: &ExperimentSpec,
        stage: f64,
        rot: f64,
        dir: Option<Direction>,
        dt_s: f64,
    ) -> Result<(), GenerateError> {
        let (stage, rot) =
            (quantize(stage, self.noise.stage_resolution_mm), quantize(rot, self.noise.rotation_resolution_deg));
        let r = self.rig.read(CommandedPose { t_s: self.t, stage_mm: stage, rot_deg: rot })?;
        let g1 = if r.in_contact { r.gamma1_mm + self.rng.gaussian(self.noise.gamma1_sigma_mm) } else { 0.0 };
        let kind = spec.phase().kind();
        let th1 =
            if kind == Phase::Torsion { r.theta1_deg + self.rng.gaussian(self.noise.theta1_sigma_deg) } else { 0.0 };
        let s = Sample { dir, ..Sample::new(self.t, kind, stage, rot, g1, th1) };
        self.samples.push(s.of_experiment(spec.phase()));
        self.t += dt_s;
        Ok(())
    }

    /// Drive the stage from `from` to `to` at `speed_mm_s`, starting one
    /// sample time after the last reading (as every move of the generator
    /// does): the rig lives the ramp (a pose at most every
    /// [`crate::effects::viscoelastic::MAX_STEP_S`]), and the next reading
    /// comes one sample time after it ends. Returns the move's (start, end), s.
    fn ramp(&mut self, from: f64, to: f64, speed_mm_s: f64) -> Result<(f64, f64), GenerateError> {
        let dt = self.step_time_s;
        let a = self.samples.last().map_or(self.t - dt, |s| (self.t - dt).max(s.t_s));
        let to = quantize(to, self.noise.stage_resolution_mm);
        let d = (to - from).abs() / speed_mm_s;
        let n = crate::effects::viscoelastic::substeps(d);
        self.rig.read(CommandedPose { t_s: a, stage_mm: from, rot_deg: 0.0 })?;
        for k in 1..=n {
            let f = k as f64 / n as f64;
            self.rig.read(CommandedPose { t_s: a + f * d, stage_mm: from + f * (to - from), rot_deg: 0.0 })?;
        }
        self.t = a + d + dt;
        Ok((a, a + d))
    }

    /// Run one experiment step from the stage `hold`; returns where the stage stands after it.
    fn experiment(&mut self, spec: &ExperimentSpec, hold: f64, top_stage: f64) -> Result<f64, GenerateError> {
        let dt = self.step_time_s;
        match *spec {
            ExperimentSpec::Dwell { hold_s, every_s } => {
                let n = crate::experiment::dwell_count(hold_s, every_s);
                for i in 0..n {
                    self.take(spec, hold, 0.0, None, if i + 1 < n { every_s } else { dt })?;
                }
                Ok(hold)
            }
            ExperimentSpec::Reload { fraction, steps, cycles } => {
                for (stage, dir) in reload_path(hold, 0.0, fraction, steps, cycles) {
                    self.take(spec, stage, 0.0, Some(dir), dt)?;
                }
                Ok(hold)
            }
            ExperimentSpec::TwistReversal { amplitude_deg, step_deg } => {
                for (rot, dir) in reversal_angles(amplitude_deg, step_deg) {
                    self.take(spec, hold, rot, Some(dir), dt)?;
                }
                Ok(hold)
            }
            ExperimentSpec::TorsionAtDepth { beta, amplitude_deg, step_deg } => {
                let r2 = self.rig.pair().indenter.r_mm;
                let stage =
                    quantize(torsion_stage(&self.rig, self.t, beta * r2, top_stage)?, self.noise.stage_resolution_mm);
                for (rot, dir) in sweep_angles(amplitude_deg, step_deg) {
                    self.take(spec, stage, rot, Some(dir), dt)?;
                }
                Ok(stage)
            }
            ExperimentSpec::SlowRepeat { fraction, steps, dwell_s } => {
                // Each stop waits `dwell_s` on top of the usual settling.
                for (stage, dir) in repeat_path(hold, 0.0, fraction, steps) {
                    self.t += dwell_s;
                    self.take(spec, stage, 0.0, Some(dir), dt)?;
                }
                Ok(hold)
            }
            ExperimentSpec::ApproachSpeed { fraction, steps, speed_mm_s } => {
                // Out at the generator's usual (instant) stage, back in ramps at `speed_mm_s`.
                let mut from = hold;
                for (k, (stage, dir)) in repeat_path(hold, 0.0, fraction, steps).into_iter().enumerate() {
                    if k == 0 {
                        self.take(spec, stage, 0.0, Some(dir), dt)?;
                    } else {
                        let span = self.ramp(from, stage, speed_mm_s)?;
                        self.take(spec, stage, 0.0, Some(dir), dt)?;
                        if let Some(s) = self.samples.last_mut() {
                            s.timing.move_s = Some(span);
                        }
                    }
                    // From where the stage stood (at the stage's resolution).
                    from = self.samples.last().map_or(stage, |s| s.stage_mm);
                }
                Ok(hold)
            }
            ExperimentSpec::RigidBall { .. } | ExperimentSpec::SwapIndenter { .. } => {
                Err(GenerateError::Plan(format!(
                    "{} needs an operator to swap the indenter: its sweep is a recording of its own (operator_recording)",
                    spec.name()
                )))
            }
        }
    }
}

/// An operator-assisted step (`rigid_ball`, `swap_indenter`) after the run of
/// `cfg` (its experiments included) on the same rig: the rig retracted, the
/// operator mounted the step's indenter with its apex where the first one's
/// was (the stage zero is the contact point of both), and the rig loads it
/// along [`crate::experiment::operator_path`] from rig time `t_s`, one sample
/// per `cfg.plan.step_time_s`. The profile's effects stay (frame, gain,
/// drift); the gel's history starts afresh (it recovered while parked).
/// A recording of its own: its header's indenter is the mounted one, so
/// `fit` and `diagnose` read it as they read any recording.
pub fn operator_recording(cfg: &GeneratorConfig, spec: &ExperimentSpec, t_s: f64) -> Result<Recording, GenerateError> {
    let Some(indenter) = spec.operator_indenter() else {
        return Err(GenerateError::Plan(format!("{} is not an operator-assisted step", spec.name())));
    };
    spec.validate(0, MAX_TWIST_DEG).map_err(|e| GenerateError::Plan(e.to_string()))?;
    let (ExperimentSpec::RigidBall { travel_mm, steps, .. } | ExperimentSpec::SwapIndenter { travel_mm, steps, .. }) =
        *spec
    else {
        return Err(GenerateError::Plan(format!("{} has no operator sweep", spec.name())));
    };
    let swapped =
        GeneratorConfig { pair: ContactPair { indenter, ..cfg.pair }, experiments: Vec::new(), ..cfg.clone() };
    swapped.pair.validate()?;
    let rig = TrueRig::new(swapped.pair, &cfg.profile)?;
    let pair = *rig.pair();
    // Its own noise stream: the seed's, apart from the main run's.
    let rng = Rng::seed_from(cfg.seed ^ 0x6f70_6572_6174_6f72);
    let mut run =
        Continued { rig, rng, t: t_s, samples: Vec::new(), noise: cfg.noise, step_time_s: cfg.plan.step_time_s };
    for (stage, dir) in crate::experiment::operator_path(travel_mm, steps) {
        run.take(spec, stage, 0.0, Some(dir), cfg.plan.step_time_s)?;
    }
    let mut meta = sim_metadata(&swapped, &pair);
    meta.extra.push(("operator_step".to_string(), spec.name().to_string()));
    Ok(Recording { meta, samples: run.samples })
}

/// The commanded stage at which the rig's noise-free depth reading gives
/// stage - gamma1 = `gamma2_target` at time `t`, found on copies of the rig so
/// the probes leave no history. Effects that part stage - gamma1 from gamma2
/// (drift, gain, frame compliance, offset) therefore move the true torsion
/// depth, as on a real rig.
fn torsion_stage(rig: &TrueRig, t: f64, gamma2_target: f64, top_stage: f64) -> Result<f64, GenerateError> {
    let measured = |stage: f64| -> Result<f64, GenerateError> {
        let mut probe = rig.clone();
        let r = probe.read(CommandedPose { t_s: t, stage_mm: stage, rot_deg: 0.0 })?;
        Ok(stage - r.gamma1_mm - gamma2_target)
    };
    let mut lo = 0.0;
    let mut hi = top_stage.max(gamma2_target) * 1.2 + 0.01;
    let mut tries = 0;
    while measured(hi)? < 0.0 {
        lo = hi;
        hi *= 1.5;
        tries += 1;
        if tries > 20 {
            return Err(GenerateError::Plan("the torsion depth cannot be reached".into()));
        }
    }
    while hi - lo > DEPTH_TOL_MM {
        let mid = 0.5 * (lo + hi);
        if measured(mid)? < 0.0 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(0.5 * (lo + hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_run_reaches_beta_with_both_sweeps() {
        let rec = generate(&GeneratorConfig::default()).unwrap();
        let n = rec.samples.len();
        assert!((180..=300).contains(&n), "{n} samples");
        let torsion: Vec<_> = rec.phase(Phase::Torsion).collect();
        let beta = (torsion[0].stage_mm - torsion[0].gamma1_mm) / 5.0;
        assert!((beta - 0.2).abs() < 0.01, "beta {beta}");
        // Twist out and back: the last sample returns to zero.
        assert_eq!(torsion.last().unwrap().rot_deg, 0.0);
        assert!(torsion.iter().any(|s| (s.rot_deg - 8.0).abs() < 1e-9));
        // The dead band reads exactly zero.
        assert_eq!(rec.samples[0].gamma1_mm, 0.0);
        // Deterministic for a seed, different across seeds.
        let again = generate(&GeneratorConfig::default()).unwrap();
        assert_eq!(again, rec);
        let other = generate(&GeneratorConfig { seed: 2, ..Default::default() }).unwrap();
        assert_ne!(other.samples, rec.samples);
    }

    #[test]
    fn noise_matches_spec() {
        let cfg = GeneratorConfig::default();
        let rec = generate(&cfg).unwrap();
        let rig = CleanRig::new(cfg.pair).unwrap();
        let res: Vec<f64> = rec
            .phase(Phase::Normal)
            .filter(|s| s.stage_mm > 0.0)
            .map(|s| s.gamma1_mm - rig.normal(s.stage_mm).unwrap().0)
            .collect();
        let rms = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
        assert!((rms - 0.002).abs() < 0.0006, "{rms}");
    }

    /// The clean recording rebuilt independently from the paper's model and the
    /// same noise stream: an empty profile must give it bit for bit.
    #[test]
    fn empty_profile_is_clean_physics_bit_for_bit() {
        for seed in [1, 7] {
            let cfg = GeneratorConfig { seed, ..Default::default() };
            let rec = generate(&cfg).unwrap();
            let model = NormalModel::new(cfg.pair).unwrap();
            let mut rng = Rng::seed_from(seed);
            let torsion_stage = quantize(model.solve_for_gamma2(cfg.plan.target_beta * 5.0).unwrap().delta_mm, 0.001);
            for s in &rec.samples {
                let g1 = model.solve(s.stage_mm).unwrap().gamma1_mm;
                let expect = if g1 > 0.0 { g1 + rng.gaussian(cfg.noise.gamma1_sigma_mm) } else { 0.0 };
                assert_eq!(s.gamma1_mm, expect, "t {}", s.t_s);
                if s.phase == Phase::Torsion {
                    assert_eq!(s.stage_mm, torsion_stage);
                    let beta = model.solve(s.stage_mm).unwrap().gamma2_mm / 5.0;
                    let th = torsion_at(&cfg.pair, beta, s.rot_deg.to_radians()).theta1_rad.to_degrees();
                    let expect = th + rng.gaussian(cfg.noise.theta1_sigma_deg);
                    assert!((s.theta1_deg - expect).abs() < 1e-12, "{} vs {expect}", s.theta1_deg);
                }
            }
            assert!(!rec.meta.extra.iter().any(|(k, _)| k == "sim_effects"));
        }
    }

    /// The recorded commands fed back through `effects::simulate` give the
    /// noise-free readings of the generated recording (what a diagnosis refits).
    #[test]
    fn recording_with_effects_replays_through_simulate() {
        use crate::effects::{self, stage_backlash, thermal_drift, viscoelastic};
        let profile = SimProfile {
            viscoelastic: Some(viscoelastic::Params { rho: 1.05, tau_s: 4.0, memory_n: 0.0 }),
            stage_backlash: Some(stage_backlash::Params { b_mm: 0.008, engaged: true }),
            thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 2e-4, vdot_mm_per_s2: 0.0 }),
            ..Default::default()
        };
        let noiseless = NoiseSpec { gamma1_sigma_mm: 0.0, theta1_sigma_deg: 0.0, ..NoiseSpec::default() };
        let cfg = GeneratorConfig { profile: profile.clone(), noise: noiseless, ..Default::default() };
        let rec = generate(&cfg).unwrap();
        let cmds: Vec<CommandedPose> = rec
            .samples
            .iter()
            .map(|s| CommandedPose { t_s: s.t_s, stage_mm: s.stage_mm, rot_deg: s.rot_deg })
            .collect();
        let replay = effects::simulate(cfg.pair, &profile, &cmds).unwrap();
        for (s, r) in rec.samples.iter().zip(&replay) {
            assert_eq!(s.gamma1_mm, r.gamma1_mm);
            assert_eq!(s.theta1_deg, r.theta1_deg);
        }
        // The rig stops where stage - gamma1 says beta = 0.2, not at the true (drifted) depth.
        let first = rec.phase(Phase::Torsion).next().unwrap();
        assert!(((first.stage_mm - first.gamma1_mm) / 5.0 - 0.2).abs() < 2e-4);
        let i = rec.samples.iter().position(|s| s.phase == Phase::Torsion).unwrap();
        assert!((replay[i].gamma2_mm / 5.0 - 0.2).abs() > 1e-3, "true beta {}", replay[i].gamma2_mm / 5.0);
        let names = rec.meta.extra.iter().find(|(k, _)| k == "sim_effects").unwrap();
        assert_eq!(names.1, "viscoelastic,stage_backlash,thermal_drift");
        // An out-of-bound parameter is refused, naming it.
        let bad = GeneratorConfig {
            profile: SimProfile {
                stage_backlash: Some(stage_backlash::Params { b_mm: -1.0, engaged: true }),
                ..Default::default()
            },
            ..Default::default()
        };
        let err = generate(&bad).unwrap_err().to_string();
        assert!(err.contains("stage_backlash.b_mm"), "{err}");
    }

    /// docs/physics.md 2 and 2.6: the rig stops at the beta it measures, and frame
    /// compliance adds C F to the measured gamma2, so the true beta is low; an
    /// error of 50 um in gamma2 (delta beta = 0.01) lowers H3 by about 4 %.
    #[test]
    fn frame_compliance_lowers_h3_through_the_measured_depth() {
        use crate::effects::frame_compliance;
        use crate::physics::h3_from_materials;
        let noiseless = NoiseSpec {
            gamma1_sigma_mm: 0.0,
            theta1_sigma_deg: 0.0,
            stage_resolution_mm: 0.0,
            rotation_resolution_deg: 0.0,
        };
        let base = GeneratorConfig { noise: noiseless, ..Default::default() };
        let force = NormalModel::new(base.pair).unwrap().solve_for_gamma2(1.0).unwrap().force_n;
        // C such that C F = 50 um at the torsion depth.
        let c = 0.05 / force;
        let cfg = GeneratorConfig {
            profile: SimProfile {
                frame_compliance: Some(frame_compliance::Params { c_mm_per_n: c }),
                ..Default::default()
            },
            ..base.clone()
        };
        let rec = generate(&cfg).unwrap();
        let h3 = |r: &Recording| {
            let (sxy, sxx) = r.phase(Phase::Torsion).fold((0.0, 0.0), |(a, b), s| {
                (a + s.theta1_deg * (s.rot_deg - s.theta1_deg), b + s.theta1_deg * s.theta1_deg)
            });
            sxy / sxx
        };
        let clean_h3 = h3_from_materials(&base.pair.elastomer, &base.pair.indenter, 0.2);
        assert!((h3(&generate(&base).unwrap()) / clean_h3 - 1.0).abs() < 1e-9);
        let drop = 1.0 - h3(&rec) / clean_h3;
        assert!((drop - 0.04).abs() < 0.01, "H3 drop {drop}");
    }

    /// Real sensor layers (2-6 mm) at the standard sweep: the layer is not
    /// concealed, the generator must still produce the whole run (a/h up to ~2).
    #[test]
    fn thin_layers_generate_full_runs() {
        use crate::effects::finite_thickness;
        let clean = generate(&GeneratorConfig::default()).unwrap();
        let top = |r: &Recording| r.phase(Phase::Normal).map(|s| s.stage_mm).fold(0.0, f64::max);
        for h in [2.0, 3.0, 5.0, 6.0] {
            let cfg = GeneratorConfig {
                profile: SimProfile {
                    finite_thickness: Some(finite_thickness::Params { h_mm: h }),
                    ..Default::default()
                },
                ..Default::default()
            };
            let rec = generate(&cfg).unwrap();
            let first = rec.phase(Phase::Torsion).next().unwrap();
            assert!(((first.stage_mm - first.gamma1_mm) / 5.0 - 0.2).abs() < 0.01, "h {h}");
            // The stiffer layer deforms less at the same force: the target beta comes at a smaller stage.
            assert!(top(&rec) < top(&clean), "h {h}: {} vs {}", top(&rec), top(&clean));
        }
    }
}
