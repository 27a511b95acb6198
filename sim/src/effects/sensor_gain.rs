//! `sensor_gain`: scale error of the sensor's depth reading (docs/physics.md 2.10).
//!
//! Model: gamma1_read = g gamma1; theta1 unaffected.
//!
//! Not identifiable from the sweep shapes: to first order it maps into
//! H1 -> (H1 + 1 - g)/g and trades off against E1 and nu1.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "sensor_gain",
    model: "gamma1_read = g gamma1",
    params: &[ParamInfo { name: "g", unit: "", min: 0.5, max: 1.5, typical: "0.97-1.03" }],
    signature: "none of its own: the curve keeps its shape, only its slope changes (H1 -> (H1 + 1 - g)/g)",
    identifiability: Identifiability::NotIdentifiable,
    sentence: "the sensor's depth scale is off (stale camera calibration, refractive index), which these sweeps cannot tell from a different E1/nu1",
    explanation: "If the sensor's own depth calibration is off by a percent, every depth it reports is a percent too large \
or too small. Because the indenter's deformation is worked out as stage travel minus that depth, a 1 % scale error \
moves nu1 by several percent, yet the curves keep exactly their shape. Nothing in the normal and torsion sweeps can \
tell such a scale error from a slightly different elastomer, so it must be checked by a separate measurement.",
    separate_by: Some(
        "press a rigid indenter (steel ball or flat: gamma2 = 0, so gamma1 = stage gives g), check the depth reading \
against a gauge block, or measure the contact force once",
    ),
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    pub g: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.g)
    }
}
