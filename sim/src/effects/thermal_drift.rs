//! `thermal_drift`: the frame's slow thermal drift (docs/physics.md 2.9).
//!
//! Model: the indenter-to-gel distance drifts, so the true approach is
//! delta = stage - offset + v t + vdot t^2 / 2 (t = the rig's time). The
//! contact is the one of that approach (gel and indenter share the extra
//! depth, the contact radius grows with it), and the sensor reads it as any
//! other contact. Without contact the sensor reads 0.
//!
//! Shows as a trend in time at constant stage (the torsion hold), an
//! unload/load split growing with time, and a beta off by the accumulated drift.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "thermal_drift",
    model: "approach = stage + v t + vdot t^2/2: the frame brings the indenter closer in time",
    params: &[
        ParamInfo { name: "v_mm_per_s", unit: "mm/s", min: -0.005, max: 0.005, typical: "-0.0005 to +0.0005 mm/s" },
        ParamInfo { name: "vdot_mm_per_s2", unit: "mm/s^2", min: -1e-4, max: 1e-4, typical: "small" },
    ],
    signature: "gamma1 trends in time at constant stage (torsion hold), load/unload split grows with time, at any load",
    identifiability: Identifiability::Good,
    sentence: "the rig's frame warms up and creeps, so the indenter presses a little deeper as time goes on",
    explanation: "While motors, lights and the room warm the rig, its frame, stage and sensor mount expand a little, and \
the distance between indenter and gel shrinks (or grows) by a fraction of a micrometre per second. Over a run of a few \
minutes that adds up to micrometres of extra press that the stage never commanded: the contact really changes, and the \
sensor sees it as it is. The calibration then pairs each stage position with a slightly deeper contact, which shifts \
the indenter deformation the method relies on. Unlike creep of the gel, the drift goes on at the same rate whatever \
the load, and it shows as a steady trend during holds.",
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
