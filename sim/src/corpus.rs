//! The concealed-data corpus (deliverable 3 of the diagnosis issue): for each
//! effect a recording where the effect hides from the paper's quality checks,
//! plus clean controls. The table here is the single source: the example
//! `make_corpus` writes `tests/data/*.csv` and `tests/data/corpus.toml` from it,
//! and the root test `tests/concealment.rs` regenerates each file to check it
//! is reproducible and then checks that it really conceals.
//!
//! Each case names which fit the concealed bias shows in (`bias_in`): `full`
//! when the full-model fit (E1, nu1, z0) is biased by several percent although
//! its residual RMS stays within 2x the noise; `paper` for the effects the
//! full-model fit absorbs or exposes before they bias it by several percent
//! (contact_offset is one of its parameters; backlash, drift and creep show in
//! its residuals first), where only the paper's method is biased.

use serde::{Deserialize, Serialize};

use crate::effects::{
    EffectError, SimProfile, adhesion, contact_offset, finite_thickness, frame_compliance, partial_slip,
    rotation_backlash, sensor_gain, stage_backlash, thermal_drift, viscoelastic,
};
use crate::generator::{GenerateError, GeneratorConfig, generate};
use crate::recording::Recording;

/// Which calibration the concealed bias shows in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BiasIn {
    /// The full-model fit (what easycalib reports).
    Full,
    /// Only the paper's method.
    Paper,
    /// A clean control: no bias beyond the noise.
    None,
}

/// One recording of the corpus.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorpusCase {
    /// CSV file name under `tests/data/`.
    pub file: String,
    /// The effect concealed in it (`clean` for a control).
    pub effect: String,
    pub seed: u64,
    /// True elastomer.
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    /// Noise the recording was generated with.
    pub gamma1_sigma_mm: f64,
    pub theta1_sigma_deg: f64,
    pub bias_in: BiasIn,
    /// The true effects and parameters.
    pub profile: SimProfile,
}

/// `tests/data/corpus.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorpusManifest {
    #[serde(rename = "case")]
    pub cases: Vec<CorpusCase>,
}

impl CorpusManifest {
    pub fn from_toml_str(text: &str) -> Result<Self, EffectError> {
        let m: CorpusManifest = toml::from_str(text).map_err(|e| EffectError::Toml(e.to_string()))?;
        for c in &m.cases {
            c.profile.validate()?;
        }
        Ok(m)
    }
    pub fn to_toml_string(&self) -> Result<String, EffectError> {
        toml::to_string(self).map_err(|e| EffectError::Toml(e.to_string()))
    }
}

impl CorpusCase {
    /// The generator configuration that produces this case's recording.
    pub fn config(&self) -> GeneratorConfig {
        let mut cfg = GeneratorConfig { seed: self.seed, profile: self.profile.clone(), ..Default::default() };
        cfg.pair.elastomer.e_mpa = self.e1_mpa;
        cfg.pair.elastomer.nu = self.nu1;
        cfg.noise.gamma1_sigma_mm = self.gamma1_sigma_mm;
        cfg.noise.theta1_sigma_deg = self.theta1_sigma_deg;
        cfg.sensor = format!("corpus-{}", self.effect);
        cfg
    }
    pub fn generate(&self) -> Result<Recording, GenerateError> {
        generate(&self.config())
    }
}

/// The corpus. Parameters and seeds were chosen (by running the paper's and the
/// full-model fits, see `tests/concealment.rs`) so that each case conceals.
pub fn cases() -> Vec<CorpusCase> {
    let d = SimProfile::default;
    let case = |effect: &str, seed: u64, bias_in: BiasIn, profile: SimProfile| CorpusCase {
        file: format!("{effect}.csv"),
        effect: effect.to_string(),
        seed,
        e1_mpa: crate::defaults::ELASTOMER_E_MPA,
        nu1: crate::defaults::ELASTOMER_NU,
        gamma1_sigma_mm: crate::defaults::GAMMA1_SIGMA_MM,
        theta1_sigma_deg: crate::defaults::THETA1_SIGMA_DEG,
        bias_in,
        profile,
    };
    let mut v = vec![
        case(
            "finite_thickness",
            21,
            BiasIn::Full,
            SimProfile { finite_thickness: Some(finite_thickness::Params { h_mm: 100.0 }), ..d() },
        ),
        case(
            "adhesion",
            22,
            BiasIn::Full,
            SimProfile { adhesion: Some(adhesion::Params { w_mj_m2: 400.0, eta: 2.0 }), ..d() },
        ),
        case(
            "viscoelastic",
            VISCO_SEED,
            BiasIn::Paper,
            SimProfile {
                viscoelastic: Some(viscoelastic::Params { rho: VISCO_RHO, tau_s: VISCO_TAU, memory_n: 0.0 }),
                ..d()
            },
        ),
        case(
            "contact_offset",
            23,
            BiasIn::Paper,
            SimProfile { contact_offset: Some(contact_offset::Params { contact_offset_mm: 0.005 }), ..d() },
        ),
        case(
            "stage_backlash",
            21,
            BiasIn::Paper,
            SimProfile { stage_backlash: Some(stage_backlash::Params { b_mm: 0.003, engaged: true }), ..d() },
        ),
        case(
            "frame_compliance",
            21,
            BiasIn::Full,
            SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..d() },
        ),
        case(
            "partial_slip",
            22,
            BiasIn::Full,
            SimProfile { partial_slip: Some(partial_slip::Params { mu: 0.5 }), ..d() },
        ),
        case(
            "rotation_backlash",
            21,
            BiasIn::Full,
            SimProfile { rotation_backlash: Some(rotation_backlash::Params { b_deg: 0.09, engaged: true }), ..d() },
        ),
        case(
            "thermal_drift",
            21,
            BiasIn::Paper,
            SimProfile { thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 2e-5, vdot_mm_per_s2: 0.0 }), ..d() },
        ),
        case(
            "sensor_gain",
            21,
            BiasIn::Full,
            SimProfile { sensor_gain: Some(sensor_gain::Params { g: 0.995 }), ..d() },
        ),
    ];
    for seed in [21, 22] {
        let mut c = case("clean", seed, BiasIn::None, d());
        c.file = format!("clean_{seed}.csv");
        v.push(c);
    }
    v
}

const VISCO_SEED: u64 = 21;
const VISCO_RHO: f64 = 1.015;
const VISCO_TAU: f64 = 8.0;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_case_per_effect_plus_two_controls_and_manifest_round_trips() {
        let cs = cases();
        for info in crate::effects::ALL {
            assert_eq!(cs.iter().filter(|c| c.effect == info.name).count(), 1, "{}", info.name);
            let c = cs.iter().find(|c| c.effect == info.name).unwrap();
            assert_eq!(c.profile.enabled(), vec![info.name]);
        }
        assert_eq!(cs.iter().filter(|c| c.effect == "clean" && c.profile.is_clean()).count(), 2);
        let m = CorpusManifest { cases: cs };
        let text = m.to_toml_string().unwrap();
        assert_eq!(CorpusManifest::from_toml_str(&text).unwrap(), m);
    }
}
