//! `adhesion`: JKR adhesion with contact-edge hysteresis (docs/physics.md 2.2).
//!
//! Model: a flat-punch displacement delta_p <= 0 at the contact radius a adds
//! 2 E* a delta_p to the force and delta_p (split by compliance, no Yoffe factor)
//! to gamma1 and gamma2. The energy release rate at the edge is
//! G = E* delta_p^2 / (2 pi a): G = w on an advancing edge, G = eta w on a
//! receding one, and in between the edge is pinned (a constant, delta_p follows
//! the stage). Contact is made at stage >= 0 and lost at pull-off.
//!
//! Shows at low gamma1: gamma2/gamma1 raised, unload below load at small stage,
//! and a negative gamma1 at zero stage on unload. Weakly identifiable.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "adhesion",
    model: "JKR: F = 4E*a^3/(3R*) + 2E* a delta_p, G = E* delta_p^2/(2 pi a) = w (advancing), eta w (receding), pinned in between",
    params: &[
        ParamInfo {
            name: "w_mJ_m2",
            unit: "mJ/m^2",
            min: 0.0,
            max: 500.0,
            typical: "40-100 clean PDMS, lower when coated or dusty",
        },
        ParamInfo { name: "eta", unit: "", min: 1.0, max: 20.0, typical: "1-5" },
    ],
    signature: "low gamma1: gamma2/gamma1 up, unload below load at small stage, negative gamma1 at zero stage on unload; fades with depth",
    identifiability: Identifiability::Weak,
    sentence: "the silicone is tacky: surface energy pulls the contact wider than Hertz at low load and holds it on retraction",
    explanation: "Clean silicone sticks to the indenter. Surface energy pulls the two surfaces together around the edge of the \
contact, so at light load the patch is larger than elastic theory says, and on the way back out the edge clings and \
lets go late. The effect is strongest in the first steps of each branch and fades as the press gets deeper, so it is \
seen mainly as a difference between loading and unloading near zero and a sensor that still reads contact (even a \
slightly negative depth) when the stage is back at zero.",
    separate_by: None,
};

/// Work of adhesion and edge hysteresis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    /// Work of adhesion, mJ/m^2 (= 1e-6 N/mm).
    #[serde(rename = "w_mJ_m2")]
    pub w_mj_m2: f64,
    /// Receding/advancing ratio of the energy release rate, >= 1.
    pub eta: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.w_mj_m2)?;
        check(&INFO, 1, self.eta)
    }
    /// Work of adhesion in N/mm.
    pub fn w_n_per_mm(&self) -> f64 {
        self.w_mj_m2 * 1e-6
    }
}

/// Punch displacement at radius a on an edge with energy release rate `g` (N/mm).
pub fn punch_displacement(g_n_per_mm: f64, a_mm: f64, e_star: f64) -> f64 {
    -(2.0 * std::f64::consts::PI * g_n_per_mm * a_mm.max(0.0) / e_star).sqrt()
}
