//! `rotation_backlash`: dead band of the rotation mount (docs/physics.md 2.8).
//!
//! Model: the play operator of [`super::stage_backlash::Play`] on the mount angle.
//!
//! Shows at the turn of the torsion sweep: theta1 flat for the first b of the
//! return, then a return branch parallel to the outgoing one.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "rotation_backlash",
    model: "play operator of width b on the mount angle",
    params: &[ParamInfo { name: "b_deg", unit: "deg", min: 0.0, max: 5.0, typical: "0.02-0.5 deg" }],
    signature: "torsion: flat step at the turn, return branch parallel to the outgoing one (offset b theta1/theta_tot)",
    identifiability: Identifiability::Good,
    sentence: "the rotation mount loses motion when it reverses, so the return twist lags the command",
    explanation: "A geared rotation stage has a little play. When the twist reverses, the first fraction of a degree of \
the return only takes up that play and the indenter does not turn back. The sensor's rotation stays flat for a moment \
and then follows a return line parallel to the outgoing one. A straight-line fit through both branches then has the \
wrong slope.",
    separate_by: None,
};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    pub b_deg: f64,
    #[serde(default = "engaged_default")]
    pub engaged: bool,
}

fn engaged_default() -> bool {
    true
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.b_deg)
    }
}
