//! `thermal_drift`: slow drift of the depth reading (docs/physics.md 2.9).
//!
//! Model: while in contact gamma1_read = gamma1 + v t + vdot t^2 / 2 (t = the
//! recording's time); the dead band still reads 0.
//!
//! Shows as a linear trend in time at constant stage (the torsion hold), an
//! unload/load split growing with time, and a beta off by the accumulated drift.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "thermal_drift",
    model: "gamma1_read = gamma1 + v t + vdot t^2/2 while in contact",
    params: &[
        ParamInfo { name: "v_mm_per_s", unit: "mm/s", min: -0.005, max: 0.005, typical: "-0.0005 to +0.0005 mm/s" },
        ParamInfo { name: "vdot_mm_per_s2", unit: "mm/s^2", min: -1e-4, max: 1e-4, typical: "small" },
    ],
    signature: "gamma1 trends linearly in time at constant stage (torsion hold), load/unload split grows with time, at any load",
    identifiability: Identifiability::Good,
    sentence: "the depth reading drifts slowly in time (warm-up of camera, lighting or frame)",
    explanation: "While a sensor warms up, its camera, lighting and frame expand a little, and the depth it reports creeps \
by a fraction of a micrometre per second. Over a run of a few minutes that adds up to micrometres, which is enough to \
shift the indenter deformation the method relies on. Unlike creep of the gel, the drift is a straight line in time and \
does not depend on how hard the indenter presses.",
    separate_by: None,
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    pub v_mm_per_s: f64,
    #[serde(default)]
    pub vdot_mm_per_s2: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.v_mm_per_s)?;
        check(&INFO, 1, self.vdot_mm_per_s2)
    }
    pub fn offset_mm(&self, t_s: f64) -> f64 {
        self.v_mm_per_s * t_s + 0.5 * self.vdot_mm_per_s2 * t_s * t_s
    }
}
