//! Discriminating experiments: steps a rig runs after the standard sweeps to
//! tell apart explanations the sweeps leave standing (docs/experiments.md).
//!
//! [`ExperimentSpec`] is one step as a script or a generator plan names it;
//! [`Experiment`] is the `phase` its samples carry in the recording
//! (docs/recording-format.md). The stage and mount paths of each step are
//! defined here once, for the generator ([`crate::generator`]) and the
//! controller's sequencer alike.

use serde::{Deserialize, Serialize};

use crate::physics::Body;
use crate::recording::{Direction, Phase};

/// Young's modulus of the rigid ball an operator mounts for `rigid_ball`: steel, MPa.
/// Against a gel of a few tenths of a MPa it takes a few millionths of the travel.
pub const RIGID_BALL_E_MPA: f64 = 210_000.0;
/// Poisson's ratio of the steel ball.
pub const RIGID_BALL_NU: f64 = 0.3;

/// The recording phase of an experiment's samples. Each is a normal-state or
/// a torsion-state sample to the model ([`Experiment::kind`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Experiment {
    /// A hold at one depth, sampled in time.
    Dwell,
    /// Unload to a fraction of the depth and load back.
    Reload,
    /// A twist out, back through zero to the other side, and back to zero.
    Reversal,
    /// A torsion sweep at a second depth.
    Torsion2,
    /// A stretch of the loading branch again, with a long dwell before each sample.
    SlowRepeat,
    /// A stretch of the loading branch again, the stage at another speed.
    ApproachSpeed,
    /// A normal sweep with a rigid ball the operator mounted (operator-assisted).
    RigidBall,
    /// A normal sweep with a second indenter the operator mounted (operator-assisted).
    SwapIndenter,
}

impl Experiment {
    pub const ALL: [Experiment; 8] = [
        Experiment::Dwell,
        Experiment::Reload,
        Experiment::Reversal,
        Experiment::Torsion2,
        Experiment::SlowRepeat,
        Experiment::ApproachSpeed,
        Experiment::RigidBall,
        Experiment::SwapIndenter,
    ];

    /// The name in the recording's `phase` column.
    pub fn as_str(self) -> &'static str {
        match self {
            Experiment::Dwell => "dwell",
            Experiment::Reload => "reload",
            Experiment::Reversal => "reversal",
            Experiment::Torsion2 => "torsion2",
            Experiment::SlowRepeat => "slow_repeat",
            Experiment::ApproachSpeed => "approach_speed",
            Experiment::RigidBall => "rigid_ball",
            Experiment::SwapIndenter => "swap_indenter",
        }
    }

    pub fn parse(name: &str) -> Option<Experiment> {
        Experiment::ALL.into_iter().find(|e| e.as_str() == name)
    }

    /// What the model sees: a normal-state sample (gamma1 at a stage
    /// position) or a torsion-state one (also theta1 at a mount angle).
    pub fn kind(self) -> Phase {
        match self {
            Experiment::Dwell
            | Experiment::Reload
            | Experiment::SlowRepeat
            | Experiment::ApproachSpeed
            | Experiment::RigidBall
            | Experiment::SwapIndenter => Phase::Normal,
            Experiment::Reversal | Experiment::Torsion2 => Phase::Torsion,
        }
    }
}

/// One experiment step (a `[[experiment]]` entry of a script, with `kind`).
/// Dwell and reload act at the depth where the rig stands when they begin
/// (the torsion depth, or the last `torsion_at_depth`'s); a twist reversal
/// twists about the mount's zero of the torsion sweep.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ExperimentSpec {
    /// Hold the stage for `hold_s`, one sample every `every_s`.
    Dwell { hold_s: f64, every_s: f64 },
    /// Unload to `fraction` of the stage travel past contact in `steps` steps and
    /// load back the same way, `cycles` times.
    Reload { fraction: f64, steps: u32, cycles: u32 },
    /// Twist to +amplitude, to -amplitude and back to 0 in `step_deg` steps.
    TwistReversal { amplitude_deg: f64, step_deg: f64 },
    /// Go to depth `beta` (gamma2/R2 as measured), twist out to `amplitude_deg` and back.
    TorsionAtDepth { beta: f64, amplitude_deg: f64, step_deg: f64 },
    /// Repeat the top of the loading branch slowly: unload to `fraction` of
    /// the stage travel past contact, then load back to where the stage
    /// stood in `steps` steps, waiting `dwell_s` at each stop (the bottom
    /// too) before its settled sample. A creeping gel reads deeper at the
    /// same stage than on the sweep's quick stops; a rate-independent
    /// effect reads the same (drift: by its rate times the extra time).
    SlowRepeat { fraction: f64, steps: u32, dwell_s: f64 },
    /// Load the top of the branch again at another stage speed: unload to
    /// `fraction` of the travel past contact at the stage's own speed, then
    /// load back in `steps` steps with the stage's top speed set to
    /// `speed_mm_s` (restored after), one settled sample per stop. Creep
    /// depends on the loading rate, drift on the time elapsed only.
    ApproachSpeed { fraction: f64, steps: u32, speed_mm_s: f64 },
    /// Operator-assisted: the rig retracts to park, the operator mounts a
    /// rigid (steel) ball of radius `r_mm` with its apex where the indenter's
    /// was, and the rig loads it `travel_mm` past contact in `steps` steps and
    /// unloads. With gamma2 = 0 the stage travel is gamma1 plus the frame's
    /// C F: the sensor's depth gain is measured.
    RigidBall { r_mm: f64, travel_mm: f64, steps: u32 },
    /// Operator-assisted: as `rigid_ball`, with a second indenter of modulus
    /// `e2_mpa`, Poisson's ratio `nu2` and radius `r2_mm`.
    SwapIndenter { e2_mpa: f64, nu2: f64, r2_mm: f64, travel_mm: f64, steps: u32 },
}

/// Most samples one experiment step may take (a typo would cost hours of rig time).
pub const MAX_EXPERIMENT_SAMPLES: usize = 2000;

/// An experiment step that cannot run: the field (`experiment[i].key`) and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("experiment {index} ({kind}) `{key}`: {message}")]
pub struct SpecError {
    pub index: usize,
    pub kind: &'static str,
    pub key: &'static str,
    pub message: String,
}

impl ExperimentSpec {
    /// The script's name of the step (`kind`).
    pub fn name(&self) -> &'static str {
        match self {
            ExperimentSpec::Dwell { .. } => "dwell",
            ExperimentSpec::Reload { .. } => "reload",
            ExperimentSpec::TwistReversal { .. } => "twist_reversal",
            ExperimentSpec::TorsionAtDepth { .. } => "torsion_at_depth",
            ExperimentSpec::SlowRepeat { .. } => "slow_repeat",
            ExperimentSpec::ApproachSpeed { .. } => "approach_speed",
            ExperimentSpec::RigidBall { .. } => "rigid_ball",
            ExperimentSpec::SwapIndenter { .. } => "swap_indenter",
        }
    }

    /// The indenter an operator-assisted step mounts; `None` for the steps the rig runs alone.
    pub fn operator_indenter(&self) -> Option<Body> {
        match *self {
            ExperimentSpec::RigidBall { r_mm, .. } => Some(Body::new(RIGID_BALL_E_MPA, RIGID_BALL_NU, r_mm)),
            ExperimentSpec::SwapIndenter { e2_mpa, nu2, r2_mm, .. } => Some(Body::new(e2_mpa, nu2, r2_mm)),
            _ => None,
        }
    }

    /// True for a step that needs an operator (a swap of the indenter).
    pub fn is_operator(&self) -> bool {
        self.operator_indenter().is_some()
    }

    /// The recording phase of its samples.
    pub fn phase(&self) -> Experiment {
        match self {
            ExperimentSpec::Dwell { .. } => Experiment::Dwell,
            ExperimentSpec::Reload { .. } => Experiment::Reload,
            ExperimentSpec::TwistReversal { .. } => Experiment::Reversal,
            ExperimentSpec::TorsionAtDepth { .. } => Experiment::Torsion2,
            ExperimentSpec::SlowRepeat { .. } => Experiment::SlowRepeat,
            ExperimentSpec::ApproachSpeed { .. } => Experiment::ApproachSpeed,
            ExperimentSpec::RigidBall { .. } => Experiment::RigidBall,
            ExperimentSpec::SwapIndenter { .. } => Experiment::SwapIndenter,
        }
    }

    /// Samples the step takes.
    pub fn samples(&self) -> usize {
        match *self {
            ExperimentSpec::Dwell { hold_s, every_s } => dwell_count(hold_s, every_s),
            ExperimentSpec::Reload { steps, cycles, .. } => (2 * steps as usize) * cycles as usize,
            ExperimentSpec::TwistReversal { amplitude_deg, step_deg } => reversal_angles(amplitude_deg, step_deg).len(),
            ExperimentSpec::TorsionAtDepth { amplitude_deg, step_deg, .. } => {
                sweep_angles(amplitude_deg, step_deg).len()
            }
            ExperimentSpec::SlowRepeat { steps, .. } | ExperimentSpec::ApproachSpeed { steps, .. } => {
                steps as usize + 1
            }
            ExperimentSpec::RigidBall { steps, .. } | ExperimentSpec::SwapIndenter { steps, .. } => 2 * steps as usize,
        }
    }

    /// Rig time the step takes, s, at `step_time_s` per settled sample (a dwell
    /// takes its hold whatever the sample time, a slow repeat its dwells on
    /// top). An approach at another speed also takes [`Self::slow_travel_s`].
    pub fn rig_time_s(&self, step_time_s: f64) -> f64 {
        match *self {
            ExperimentSpec::Dwell { hold_s, .. } => hold_s,
            ExperimentSpec::SlowRepeat { dwell_s, .. } => self.samples() as f64 * (step_time_s + dwell_s),
            _ => self.samples() as f64 * step_time_s,
        }
    }

    /// Rig time of the moves at the step's own stage speed, s, when the
    /// stage stands `travel_mm` past contact as the step begins: the load
    /// back from `fraction` of that travel (0 for the other steps).
    pub fn slow_travel_s(&self, travel_mm: f64) -> f64 {
        match *self {
            ExperimentSpec::ApproachSpeed { fraction, speed_mm_s, .. } => {
                (1.0 - fraction) * travel_mm.max(0.0) / speed_mm_s
            }
            _ => 0.0,
        }
    }

    /// Check the step's values (`index` names it in the error); twist
    /// amplitudes are bounded by `max_twist_deg` (the guard's twist limit).
    pub fn validate(&self, index: usize, max_twist_deg: f64) -> Result<(), SpecError> {
        let fail = |key: &'static str, message: String| SpecError { index, kind: self.name(), key, message };
        let in_range = |key: &'static str, x: f64, lo: f64, hi: f64| {
            if x.is_finite() && x > lo && x <= hi {
                Ok(())
            } else {
                Err(fail(key, format!("must lie in ({lo}, {hi}], got {x}")))
            }
        };
        match *self {
            ExperimentSpec::Dwell { hold_s, every_s } => {
                in_range("hold_s", hold_s, 0.0, 3600.0)?;
                in_range("every_s", every_s, 0.0, hold_s)?;
            }
            ExperimentSpec::Reload { fraction, steps, cycles } => {
                if !(fraction.is_finite() && (0.0..1.0).contains(&fraction)) {
                    return Err(fail("fraction", format!("must lie in [0, 1), got {fraction}")));
                }
                if !(1..=200).contains(&steps) {
                    return Err(fail("steps", format!("must be 1..=200, got {steps}")));
                }
                if !(1..=20).contains(&cycles) {
                    return Err(fail("cycles", format!("must be 1..=20, got {cycles}")));
                }
            }
            ExperimentSpec::TwistReversal { amplitude_deg, step_deg }
            | ExperimentSpec::TorsionAtDepth { amplitude_deg, step_deg, .. } => {
                in_range("amplitude_deg", amplitude_deg, 0.0, max_twist_deg)?;
                in_range("step_deg", step_deg, 0.0, amplitude_deg)?;
            }
            ExperimentSpec::SlowRepeat { fraction, steps, .. }
            | ExperimentSpec::ApproachSpeed { fraction, steps, .. } => {
                if !(fraction.is_finite() && (0.0..1.0).contains(&fraction)) {
                    return Err(fail("fraction", format!("must lie in [0, 1), got {fraction}")));
                }
                if !(1..=200).contains(&steps) {
                    return Err(fail("steps", format!("must be 1..=200, got {steps}")));
                }
            }
            ExperimentSpec::RigidBall { .. } | ExperimentSpec::SwapIndenter { .. } => {}
        }
        match *self {
            ExperimentSpec::SlowRepeat { dwell_s, .. } => in_range("dwell_s", dwell_s, 0.0, 600.0)?,
            ExperimentSpec::ApproachSpeed { speed_mm_s, .. } => in_range("speed_mm_s", speed_mm_s, 0.0, 10.0)?,
            _ => {}
        }
        if let ExperimentSpec::RigidBall { travel_mm, steps, .. }
        | ExperimentSpec::SwapIndenter { travel_mm, steps, .. } = *self
        {
            in_range("travel_mm", travel_mm, 0.0, 5.0)?;
            if !(1..=200).contains(&steps) {
                return Err(fail("steps", format!("must be 1..=200, got {steps}")));
            }
        }
        match *self {
            ExperimentSpec::RigidBall { r_mm, .. } => in_range("r_mm", r_mm, 0.0, 100.0)?,
            ExperimentSpec::SwapIndenter { e2_mpa, nu2, r2_mm, .. } => {
                in_range("e2_mpa", e2_mpa, 0.0, 1e6)?;
                if !(nu2.is_finite() && nu2 > 0.0 && nu2 < 0.5) {
                    return Err(fail("nu2", format!("must lie in (0, 0.5), got {nu2}")));
                }
                in_range("r2_mm", r2_mm, 0.0, 100.0)?;
            }
            _ => {}
        }
        if let ExperimentSpec::TorsionAtDepth { beta, .. } = *self {
            in_range("beta", beta, 0.0, 0.3)?;
        }
        let n = self.samples();
        if n > MAX_EXPERIMENT_SAMPLES {
            return Err(fail("kind", format!("takes {n} samples; the limit is {MAX_EXPERIMENT_SAMPLES}")));
        }
        Ok(())
    }
}

/// Samples of a dwell: one every `every_s` over `hold_s`, the first at its start.
pub fn dwell_count(hold_s: f64, every_s: f64) -> usize {
    let n = (hold_s / every_s).round();
    if n.is_finite() && n >= 0.0 { (n as usize).min(MAX_EXPERIMENT_SAMPLES + 1) + 1 } else { 1 }
}

/// Steps of `step_deg` to `amplitude_deg`, at least one.
fn twist_steps(amplitude_deg: f64, step_deg: f64) -> usize {
    let n = (amplitude_deg / step_deg).round();
    if n.is_finite() && n >= 1.0 { (n as usize).min(MAX_EXPERIMENT_SAMPLES + 1) } else { 1 }
}

/// Mount angles (from the twist zero) of a torsion sweep out and back,
/// 0 included at both ends, with their direction.
pub fn sweep_angles(amplitude_deg: f64, step_deg: f64) -> Vec<(f64, Direction)> {
    let n = twist_steps(amplitude_deg, step_deg);
    let step = amplitude_deg / n as f64;
    let mut a: Vec<(f64, Direction)> = (0..=n).map(|i| (i as f64 * step, Direction::Load)).collect();
    a.extend((0..n).rev().map(|i| (i as f64 * step, Direction::Unload)));
    a
}

/// Mount angles of a twist reversal from the twist zero: out to +A, through 0
/// to -A, back to 0 (the start at 0 is not repeated). `load` while |angle| grows.
pub fn reversal_angles(amplitude_deg: f64, step_deg: f64) -> Vec<(f64, Direction)> {
    let n = twist_steps(amplitude_deg, step_deg) as i64;
    let step = amplitude_deg / n as f64;
    let ks = (1..=n).chain((-n..n).rev()).chain(-n + 1..=0);
    let mut prev = 0i64;
    ks.map(|k| {
        let dir = if k.abs() > prev.abs() { Direction::Load } else { Direction::Unload };
        prev = k;
        (k as f64 * step, dir)
    })
    .collect()
}

/// Stage travel past contact of an operator-assisted step's sweep: in to
/// `travel_mm` in `steps` equal steps, out the same way to contact.
pub fn operator_path(travel_mm: f64, steps: u32) -> Vec<(f64, Direction)> {
    let n = steps.max(1);
    let at = |i: u32| travel_mm * i as f64 / n as f64;
    let mut out: Vec<(f64, Direction)> = (1..=n).map(|i| (at(i), Direction::Load)).collect();
    out.extend((0..n).rev().map(|i| (at(i), Direction::Unload)));
    out
}

/// Stage positions of a slow repeat or an approach at another speed: from
/// `top_mm`, one move out to `fraction` of the travel past `contact_mm`
/// (`unload`), then back to `top_mm` in `steps` equal steps (`load`).
pub fn repeat_path(top_mm: f64, contact_mm: f64, fraction: f64, steps: u32) -> Vec<(f64, Direction)> {
    let n = steps.max(1);
    let bottom = contact_mm + fraction * (top_mm - contact_mm);
    let at = |i: u32| bottom + (top_mm - bottom) * i as f64 / n as f64;
    let mut out = vec![(bottom, Direction::Unload)];
    out.extend((1..=n).map(|i| (at(i), Direction::Load)));
    out
}

/// Stage positions of reload cycles between `top_mm` and the stage at
/// `fraction` of the travel past `contact_mm`: down in `steps` steps, back up.
pub fn reload_path(top_mm: f64, contact_mm: f64, fraction: f64, steps: u32, cycles: u32) -> Vec<(f64, Direction)> {
    let bottom = contact_mm + fraction * (top_mm - contact_mm);
    let at = |i: u32| top_mm - (top_mm - bottom) * i as f64 / steps.max(1) as f64;
    let mut out = Vec::new();
    for _ in 0..cycles {
        out.extend((1..=steps).map(|i| (at(i), Direction::Unload)));
        out.extend((0..steps).rev().map(|i| (at(i), Direction::Load)));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_turn_where_they_should() {
        let r = reversal_angles(2.0, 1.0);
        let angles: Vec<f64> = r.iter().map(|a| a.0).collect();
        assert_eq!(angles, vec![1.0, 2.0, 1.0, 0.0, -1.0, -2.0, -1.0, 0.0]);
        let dirs: Vec<Direction> = r.iter().map(|a| a.1).collect();
        use Direction::{Load as L, Unload as U};
        assert_eq!(dirs, vec![L, L, U, U, L, L, U, U]);
        let s: Vec<f64> = sweep_angles(1.0, 0.5).iter().map(|a| a.0).collect();
        assert_eq!(s, vec![0.0, 0.5, 1.0, 0.5, 0.0]);
        let p = reload_path(1.0, 0.0, 0.5, 2, 1);
        let stages: Vec<f64> = p.iter().map(|a| a.0).collect();
        assert_eq!(stages, vec![0.75, 0.5, 0.75, 1.0]);
        assert_eq!(dwell_count(10.0, 2.0), 6);
        let o: Vec<f64> = operator_path(1.0, 2).iter().map(|a| a.0).collect();
        assert_eq!(o, vec![0.5, 1.0, 0.5, 0.0]);
        assert_eq!(ExperimentSpec::RigidBall { r_mm: 5.0, travel_mm: 1.0, steps: 2 }.samples(), o.len());
        let r = repeat_path(1.0, 0.0, 0.5, 2);
        assert_eq!(r, vec![(0.5, Direction::Unload), (0.75, Direction::Load), (1.0, Direction::Load)]);
        let slow = ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 2, dwell_s: 10.0 };
        assert_eq!((slow.samples(), slow.rig_time_s(1.0)), (r.len(), 33.0));
        let fast = ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 2, speed_mm_s: 0.1 };
        assert_eq!(fast.samples(), r.len());
        assert!((fast.slow_travel_s(2.0) - 10.0).abs() < 1e-12);
    }

    #[test]
    fn validation_names_the_key() {
        let e = ExperimentSpec::Dwell { hold_s: 10.0, every_s: 0.0 }.validate(2, 10.0).unwrap_err();
        assert_eq!((e.index, e.key), (2, "every_s"));
        let e = ExperimentSpec::TwistReversal { amplitude_deg: 12.0, step_deg: 1.0 }.validate(0, 10.0).unwrap_err();
        assert_eq!(e.key, "amplitude_deg");
        let e = ExperimentSpec::TorsionAtDepth { beta: 0.4, amplitude_deg: 4.0, step_deg: 1.0 }
            .validate(0, 10.0)
            .unwrap_err();
        assert_eq!(e.key, "beta");
        let e = ExperimentSpec::Reload { fraction: 1.0, steps: 3, cycles: 1 }.validate(0, 10.0).unwrap_err();
        assert_eq!(e.key, "fraction");
        let e = ExperimentSpec::Dwell { hold_s: 3600.0, every_s: 0.01 }.validate(0, 10.0).unwrap_err();
        assert!(e.message.contains("limit"), "{e}");
        assert!(ExperimentSpec::Reload { fraction: 0.5, steps: 5, cycles: 2 }.validate(0, 10.0).is_ok());
        let e = ExperimentSpec::SwapIndenter { e2_mpa: 1.0, nu2: 0.5, r2_mm: 5.0, travel_mm: 1.0, steps: 4 }
            .validate(1, 10.0)
            .unwrap_err();
        assert_eq!((e.index, e.key), (1, "nu2"));
        let e = ExperimentSpec::RigidBall { r_mm: 5.0, travel_mm: 0.0, steps: 4 }.validate(0, 10.0).unwrap_err();
        assert_eq!(e.key, "travel_mm");
        let e = ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 3, dwell_s: 0.0 }.validate(4, 10.0).unwrap_err();
        assert_eq!((e.index, e.key), (4, "dwell_s"));
        let e =
            ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 3, speed_mm_s: 50.0 }.validate(0, 10.0).unwrap_err();
        assert_eq!(e.key, "speed_mm_s");
        let e =
            ExperimentSpec::ApproachSpeed { fraction: 1.2, steps: 3, speed_mm_s: 0.1 }.validate(0, 10.0).unwrap_err();
        assert_eq!(e.key, "fraction");
        let ball = ExperimentSpec::RigidBall { r_mm: 5.0, travel_mm: 1.0, steps: 4 };
        assert!(ball.validate(0, 10.0).is_ok() && ball.is_operator());
        assert!(!ExperimentSpec::Dwell { hold_s: 10.0, every_s: 2.0 }.is_operator());
        for e in Experiment::ALL {
            assert_eq!(Experiment::parse(e.as_str()), Some(e));
        }
    }
}
