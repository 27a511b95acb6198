//! Synthetic recordings: what a clean rig would record for a known elastomer.
//! The sweep follows the rig's own procedure: step the stage in until the
//! *measured* depth beta = (stage - gamma1) / R2 reaches the target, step back
//! out, then re-approach to the torsion depth and twist out and back. Every
//! reading carries seeded noise and the stage and mount are quantized to their
//! resolution, so the fits see what they would see on a real rig.

use serde::{Deserialize, Serialize};

use crate::physics::{Body, ContactPair, NormalError, NormalModel, ParamError, torsion_at};
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
            gamma1_sigma_mm: 0.002,
            theta1_sigma_deg: 0.02,
            stage_resolution_mm: 0.001,
            rotation_resolution_deg: 0.01,
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
}

impl Default for GeneratorConfig {
    /// A Tac3D-like elastomer (domed, R1 ~ 33 mm) against the paper's PDMS indenter.
    fn default() -> Self {
        Self {
            pair: ContactPair { elastomer: Body::new(0.33, 0.39, 33.0), indenter: Body::new(1.1, 0.39, 5.0) },
            plan: SweepPlan::default(),
            noise: NoiseSpec::default(),
            seed: 1,
            sensor: "sim-tac3d".to_string(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GenerateError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error(transparent)]
    Model(#[from] NormalError),
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

pub fn generate(cfg: &GeneratorConfig) -> Result<Recording, GenerateError> {
    let plan = cfg.plan;
    let noise = cfg.noise;
    if !(plan.normal_step_mm > 0.0 && plan.torsion_step_deg > 0.0 && plan.step_time_s > 0.0) {
        return Err(GenerateError::Plan("steps and step time must be > 0".into()));
    }
    if !(plan.target_beta > 0.0 && plan.target_beta <= 0.3) {
        return Err(GenerateError::Plan(format!("target beta {} outside (0, 0.3]", plan.target_beta)));
    }
    let rig = CleanRig::new(cfg.pair)?;
    let r2 = cfg.pair.indenter.r_mm;
    let mut rng = Rng::seed_from(cfg.seed);
    let mut samples = Vec::new();
    let mut t = 0.0;

    let read_gamma1 = |g: f64, rng: &mut Rng| if g > 0.0 { g + rng.gaussian(noise.gamma1_sigma_mm) } else { 0.0 };

    let max_steps = 10_000;
    for rep in 0..plan.repeats.max(1) {
        // Load until the measured depth reaches the target.
        let mut stage_path = Vec::new();
        let mut k = 0;
        loop {
            let stage = quantize(k as f64 * plan.normal_step_mm, noise.stage_resolution_mm);
            let (g1, _) = rig.normal(stage)?;
            let g1_read = read_gamma1(g1, &mut rng);
            samples.push(Sample {
                t_s: t,
                phase: Phase::Normal,
                stage_mm: stage,
                rot_deg: 0.0,
                gamma1_mm: g1_read,
                theta1_deg: 0.0,
                rep: Some(rep),
                dir: Some(Direction::Load),
            });
            t += plan.step_time_s;
            stage_path.push(stage);
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
            let (g1, _) = rig.normal(stage)?;
            samples.push(Sample {
                t_s: t,
                phase: Phase::Normal,
                stage_mm: stage,
                rot_deg: 0.0,
                gamma1_mm: read_gamma1(g1, &mut rng),
                theta1_deg: 0.0,
                rep: Some(rep),
                dir: Some(Direction::Unload),
            });
            t += plan.step_time_s;
        }
    }

    // Re-approach to the torsion depth and twist out and back.
    let depth = rig.model().solve_for_gamma2(plan.target_beta * r2)?;
    let stage_t = quantize(depth.delta_mm, noise.stage_resolution_mm);
    let (g1_t, _) = rig.normal(stage_t)?;
    let n_twist = (plan.torsion_amplitude_deg / plan.torsion_step_deg).round().max(1.0) as usize;
    let mut angles: Vec<(f64, Direction)> =
        (0..=n_twist).map(|i| (i as f64 * plan.torsion_step_deg, Direction::Load)).collect();
    angles.extend((0..n_twist).rev().map(|i| (i as f64 * plan.torsion_step_deg, Direction::Unload)));
    for (angle, dir) in angles {
        let rot = quantize(angle, noise.rotation_resolution_deg);
        let th1 = rig.torsion_theta1_deg(stage_t, rot)?;
        samples.push(Sample {
            t_s: t,
            phase: Phase::Torsion,
            stage_mm: stage_t,
            rot_deg: rot,
            gamma1_mm: read_gamma1(g1_t, &mut rng),
            theta1_deg: th1 + rng.gaussian(noise.theta1_sigma_deg),
            rep: None,
            dir: Some(dir),
        });
        t += plan.step_time_s;
    }

    Ok(Recording {
        meta: Metadata {
            sensor: Some(cfg.sensor.clone()),
            indenter: cfg.pair.indenter,
            elastomer_r_mm: cfg.pair.elastomer.r_mm,
            created: None,
            extra: vec![
                ("sim_E1_MPa".to_string(), format!("{}", cfg.pair.elastomer.e_mpa)),
                ("sim_nu1".to_string(), format!("{}", cfg.pair.elastomer.nu)),
                ("sim_seed".to_string(), format!("{}", cfg.seed)),
            ],
        },
        samples,
    })
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
}
