//! `viscoelastic`: the elastomer is a standard linear solid (docs/physics.md 2.3).
//!
//! Model: creep compliance J1(t) = J_inf - (J_inf - J0) exp(-t/tau), with
//! J_inf = (1 - nu1^2)/E1 (E1 is the relaxed modulus) and J0 = J_inf / rho.
//! Lee-Radok hereditary form a^3 = 3R*/4 (H + J2 F), H = int J1(t-s) dF(s),
//! solved at every time step for the force that matches the stage, with the
//! exact exponential recursion q <- e q + w dF. Each sample interval is the
//! move (at its start) followed by the dwell, stepped at most 0.2 s.
//! Torsion uses the same kernel on the elastomer's torsional compliance (in
//! series with the elastic indenter and rod), so theta1 creeps up after each
//! twist step. Simplifications: the torsion history is kept in torque at the
//! current contact (not in T = 3M/(16a^3)), and when `partial_slip` is also on
//! the slip model uses the relaxed modulus.
//!
//! Shows as load/unload hysteresis (unload above load) and a saturating creep
//! of gamma1 during holds (the torsion phase).

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "viscoelastic",
    model: "SLS creep J1(t) = J_inf - (J_inf - J0) exp(-t/tau), J0 = J_inf/rho, Lee-Radok hereditary contact",
    params: &[
        ParamInfo { name: "rho", unit: "", min: 1.0, max: 2.0, typical: "1.005-1.1 (E0/E_inf)" },
        ParamInfo { name: "tau_s", unit: "s", min: 0.05, max: 1000.0, typical: "1-20 s (retardation time)" },
        ParamInfo {
            name: "memory_n",
            unit: "N",
            min: -100.0,
            max: 100.0,
            typical: "0 for a rested gel; below 0 soon after an unload the recording does not hold",
        },
    ],
    signature: "load/unload hysteresis (gamma1 high on unload); gamma1 creeps upward and saturates during the torsion hold",
    identifiability: Identifiability::Good,
    sentence: "the silicone creeps: each sample sees a partly relaxed elastomer, so its stiffness depends on the loading history",
    explanation: "Silicone is not perfectly elastic: after each stage step it keeps sinking for a few seconds as it relaxes. \
A sample taken at the end of a short dwell therefore sees a slightly stiffer elastomer on the way in and a slightly \
softer one on the way out, and the depth reading keeps drifting up while the rig holds still for the torsion sweep. \
The modulus the calibration should report is the relaxed one; fitting the creep recovers it.",
    separate_by: None,
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// E0 / E_inf, > 1.
    pub rho: f64,
    /// Retardation time, s.
    pub tau_s: f64,
    /// The gel's memory of the load before the first reading: the part of
    /// that history's force not yet crept, q = int exp(-(t0 - s)/tau) dF(s),
    /// N (docs/physics.md 2.3). 0 for a gel at rest; negative soon after an
    /// unload, such as a rig's approach before its recording begins.
    #[serde(default)]
    pub memory_n: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.rho)?;
        check(&INFO, 1, self.tau_s)?;
        check(&INFO, 2, self.memory_n)
    }
}

/// Longest time step of the hereditary integration, s.
pub const MAX_STEP_S: f64 = 0.2;
/// Most sub-steps between two readings: a longer interval is stepped more
/// coarsely (each step stays exact for a linear force ramp), so the work per
/// reading is bounded whatever the time stamps say.
pub const MAX_SUBSTEPS: usize = 2000;

/// Number of sub-steps for an interval of `span_s` seconds.
pub fn substeps(span_s: f64) -> usize {
    let n = (span_s / MAX_STEP_S).ceil();
    if n.is_finite() && n >= 1.0 { (n as usize).min(MAX_SUBSTEPS) } else { 1 }
}
