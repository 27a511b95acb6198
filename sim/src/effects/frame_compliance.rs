//! `frame_compliance`: the rig's frame deflects under the contact force
//! (docs/physics.md 2.6).
//!
//! Model: true approach = stage - C F, i.e. gamma1 + gamma2 + C F = stage.
//!
//! Shows as a normal residual growing like F (load and unload alike) and a torsion
//! slope that disagrees with the normal sweep (the measured beta includes C F).

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "frame_compliance",
    model: "gamma1 + gamma2 + C F = stage",
    params: &[ParamInfo { name: "c_mm_per_n", unit: "mm/N", min: 0.0, max: 0.2, typical: "0.002-0.030 mm/N" }],
    signature: "normal residual grows like F (~gamma1^1.5), same on load and unload; torsion H3 low through the measured beta",
    identifiability: Identifiability::Good,
    sentence: "the rig's frame bends under the contact force, so part of the stage travel never reaches the contact",
    explanation: "A light or 3D-printed bracket is a spring in series with the contact. As the force grows, the bracket \
bends and swallows part of the stage travel, so the rig believes it pressed the indenter deeper than it did. The \
paper's curve fit absorbs this into its nuisance term, but the torsion depth the rig stops at is wrong, and that \
biases the torsion slope and with it E1 and nu1.",
    separate_by: None,
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Frame compliance, mm/N.
    pub c_mm_per_n: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.c_mm_per_n)
    }
}
