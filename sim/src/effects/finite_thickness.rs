//! `finite_thickness`: the elastomer is a layer of thickness h bonded to a rigid
//! window (docs/physics.md 2.1).
//!
//! Model (normal): the elastomer's plane-strain modulus becomes E1* Phi(a/h)
//! at the current contact radius a (Dimitriadis et al. 2002, bonded layer), which
//! also divides the Tatara compliance b1 by Phi. Model (torsion): the elastomer's
//! torsional compliance is divided by 1 + zeta(3)/(4 pi) (a/h)^3, and the contact
//! radius of the rod correction is a35(beta) a / a_clean(gamma2) (the stiffer
//! layer makes a smaller contact at the same gamma2, which lowers the effective c).
//!
//! Shows as a smooth bow of the normal residual growing with gamma1 (load and
//! unload alike) and a low torsion slope H3. Quantitative for a/h up to about 1.

use serde::{Deserialize, Serialize};

use super::{EffectError, EffectInfo, Identifiability, ParamInfo, check};

pub const INFO: EffectInfo = EffectInfo {
    name: "finite_thickness",
    model: "E1* -> E1* Phi(a/h) (Dimitriadis bonded layer); torsion compliance / (1 + 0.0957 (a/h)^3); rod radius a35 a/a_clean",
    params: &[ParamInfo { name: "h_mm", unit: "mm", min: 0.5, max: 1000.0, typical: "2-6 mm on real sensors" }],
    signature: "normal: gamma1 falls below the model increasingly with gamma1 (smooth bow), same on load and unload; torsion: H3 low",
    identifiability: Identifiability::Good,
    sentence: "the elastomer is a thin layer on a rigid base, so it stiffens as the contact grows (bottom effect)",
    explanation: "A sensor's gel is not an infinite block: it is a few millimetres of silicone glued to a rigid window. \
Once the contact patch is no longer small against the layer thickness, the window underneath props the gel up and \
it feels stiffer than the half-space the paper assumes, more so the deeper the press. The normal sweep then bends \
away from the model at depth and the smaller contact patch changes the torsion split, so E1 and nu1 come out biased \
unless the thickness is fitted too.",
    separate_by: None,
};

/// Layer thickness.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Params {
    pub h_mm: f64,
}

impl Params {
    pub fn validate(&self) -> Result<(), EffectError> {
        check(&INFO, 0, self.h_mm)
    }
}

/// Dimitriadis' bonded-layer factor Phi(chi), chi = a/h, for Poisson's ratio nu.
pub fn phi(chi: f64, nu: f64) -> f64 {
    use std::f64::consts::PI;
    let alpha0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu * nu) / (1.0 - nu);
    let beta0 = (0.6387 - 1.0277 * nu + 1.5164 * nu * nu) / (1.0 - nu);
    let x = chi.max(0.0);
    1.0 - 2.0 * alpha0 / PI * x + 4.0 * alpha0 * alpha0 / (PI * PI) * x * x
        - 8.0 / PI.powi(3) * (alpha0.powi(3) + 4.0 * PI * PI / 15.0 * beta0) * x.powi(3)
        - 16.0 * alpha0 / PI.powi(4) * (alpha0.powi(3) + 3.0 * PI * PI / 5.0 * beta0) * x.powi(4)
}

/// Torsional stiffening of a bonded layer at leading order, 1 + zeta(3)/(4 pi) (a/h)^3.
pub fn torsion_factor(chi: f64) -> f64 {
    const ZETA3: f64 = 1.202_056_903_159_594;
    1.0 + ZETA3 / (4.0 * std::f64::consts::PI) * chi.max(0.0).powi(3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phi_reproduces_the_published_bonded_coefficients() {
        // At nu = 0.5: 1 + 1.133 chi + 1.283 chi^2 + 0.769 chi^3 + 0.0975 chi^4.
        for chi in [0.1f64, 0.5, 1.0] {
            let expect = 1.0 + 1.133 * chi + 1.283 * chi * chi + 0.769 * chi.powi(3) + 0.0975 * chi.powi(4);
            assert!((phi(chi, 0.4999999) / expect - 1.0).abs() < 2e-3, "chi {chi}: {} vs {expect}", phi(chi, 0.5));
        }
        assert_eq!(phi(0.0, 0.4), 1.0);
        assert!((torsion_factor(1.0) - 1.0957).abs() < 1e-4);
    }
}
