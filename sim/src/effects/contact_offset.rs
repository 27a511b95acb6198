//! `contact_offset`: the stage zero is not the first contact (docs/physics.md 2.4).
//!
//! Model: true approach = stage - z0. Stage < z0 reads exactly 0 (dead band);
//! z0 < 0 means contact was already made at stage 0.
//!
//! Shows as a constant gamma2 offset over the whole normal sweep, load and unload
//! alike. It is the standard extra parameter of the full-model fit.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "contact_offset",
    model: "true approach = stage - z0",
    params: &[ParamInfo { name: "z0_mm", unit: "mm", min: -0.5, max: 0.5, typical: "-0.020 to +0.020 mm" }],
    signature: "constant gamma2 offset over the whole normal sweep, same on load and unload; dead-band zeros or a non-zero first sample",
    identifiability: Identifiability::Good,
    sentence: "the stage zero is not the true first contact, so every depth is off by a constant",
    explanation: "The rig counts the stage travel from where it believes the indenter first touched the gel. That touch point \
is found by eye or by a threshold and is typically off by a few micrometres. Because the indenter's own deformation \
is the small difference between stage travel and the gel's depth, a few micrometres of offset move the paper's H1 by \
several percent. The full-model fit includes the offset and reports it when it is significant.",
    separate_by: None,
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Stage reading at true first contact (z0), mm; the profile's TOML key is `z0_mm`.
    #[serde(rename = "z0_mm")]
    pub contact_offset_mm: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.contact_offset_mm)
    }
}
