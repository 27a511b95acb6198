//! The simulated rig's set-up, resolved once: elastomer (E1, nu1, R1),
//! indenter (E2, nu2, R2), left-out physics, sensor noise, noise seed and time
//! acceleration. The command line (or a test) fills a [`SimSetupInput`];
//! [`SimSetupInput::resolve`] checks it and applies a profile's `material`,
//! and the [`SimSetup`] it returns is what the emulators, the simulated sensor
//! and the effect model take, and what a run reports as the truth. Nothing
//! below changes it or reads it back from a model.

use std::sync::Arc;

use crate::defaults;
use crate::effects::{ContactLaw, EffectError, Material, SimProfile};
use crate::physics::{ContactPair, Layer, ParamError};
use crate::sensor::field::NoiseConfig;

/// What is asked of the simulated rig, before it is checked.
#[derive(Debug, Clone, PartialEq)]
pub struct SimSetupInput {
    /// Elastomer (1) and indenter (2).
    pub pair: ContactPair,
    /// Left-out physics; its `material`, when set, replaces the elastomer's E1
    /// and nu1 (R1 stays).
    pub profile: SimProfile,
    /// Marker noise, outliers and lost frames of the simulated sensor.
    pub noise: NoiseConfig,
    /// Seed of the sensor's noise.
    pub seed: u64,
    /// Rig time runs this many times faster than wall time (1 = real time).
    pub speedup: f64,
}

impl Default for SimSetupInput {
    /// The default sensor against the paper's indenter, clean, at the default speed-up.
    fn default() -> Self {
        Self {
            pair: defaults::pair(),
            profile: SimProfile::default(),
            noise: NoiseConfig::default(),
            seed: defaults::SEED,
            speedup: defaults::SPEEDUP,
        }
    }
}

/// Why a simulated set-up was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SetupError {
    /// An impossible elastomer or indenter (after the profile's material).
    #[error(transparent)]
    Params(#[from] ParamError),
    /// A profile parameter out of its bounds, or effects that cannot be combined.
    #[error("sim profile: {0}")]
    Profile(#[source] EffectError),
    #[error("speed-up must be a positive number, got {0}")]
    Speedup(f64),
}

impl SimSetupInput {
    /// Check everything once and resolve the true contact pair.
    pub fn resolve(self) -> Result<SimSetup, SetupError> {
        self.profile.validate().map_err(SetupError::Profile)?;
        let pair = self.profile.true_pair(self.pair);
        pair.validate()?;
        if !(self.speedup.is_finite() && self.speedup > 0.0) {
            return Err(SetupError::Speedup(self.speedup));
        }
        Ok(SimSetup::from_checked(SimSetupInput { pair, ..self }))
    }
}

/// The simulated rig, checked and resolved. Built by [`SimSetupInput::resolve`]
/// (or [`Default`]), so every value is valid.
#[derive(Debug, Clone, PartialEq)]
pub struct SimSetup {
    pair: ContactPair,
    effects: SimProfile,
    noise: NoiseConfig,
    seed: u64,
    speedup: f64,
    /// A declared gel layer's contact, solved downstream of this crate (the
    /// FE layer model), which then replaces the paper's contact.
    layer: Option<LayeredContact>,
}

/// A declared gel layer and its contact law (docs/physics.md, "Rig effects
/// on a declared layer"). Two are equal when they are the same law.
#[derive(Debug, Clone)]
pub struct LayeredContact {
    pub layer: Layer,
    pub law: Arc<dyn ContactLaw>,
}

impl PartialEq for LayeredContact {
    fn eq(&self, other: &Self) -> bool {
        self.layer == other.layer && Arc::ptr_eq(&self.law, &other.law)
    }
}

impl Default for SimSetup {
    fn default() -> Self {
        Self::from_checked(SimSetupInput::default())
    }
}

impl SimSetup {
    /// An input already checked (its pair with the material applied); the
    /// material leaves the effects, so nothing applies it twice.
    fn from_checked(input: SimSetupInput) -> Self {
        let SimSetupInput { pair, mut profile, noise, seed, speedup } = input;
        profile.material = None;
        Self { pair, effects: profile, noise, seed, speedup, layer: None }
    }

    /// The same set-up on a declared gel layer whose contact is `law` (for
    /// the set-up's elastomer and indenter). The profile's effects must act
    /// outside the contact, and the gel must be flat.
    pub fn on_layer(mut self, layer: Layer, law: Arc<dyn ContactLaw>) -> Result<Self, EffectError> {
        crate::effects::law::contact_effect(&self.effects).map_or(Ok(()), |e| Err(EffectError::NotOnLayer(e)))?;
        if self.pair.elastomer.r_mm.is_finite() {
            return Err(EffectError::DomedLayer { r1_mm: self.pair.elastomer.r_mm });
        }
        self.layer = Some(LayeredContact { layer, law });
        Ok(self)
    }

    /// The declared gel layer and its contact, when there is one.
    pub fn layer(&self) -> Option<&LayeredContact> {
        self.layer.as_ref()
    }

    /// The true elastomer and indenter (a profile's material applied).
    pub fn pair(&self) -> &ContactPair {
        &self.pair
    }

    /// The left-out physics of the simulated contact (without `material`: it
    /// is in [`SimSetup::pair`]).
    pub fn effects(&self) -> &SimProfile {
        &self.effects
    }

    pub fn noise(&self) -> &NoiseConfig {
        &self.noise
    }

    pub fn seed(&self) -> u64 {
        self.seed
    }

    pub fn speedup(&self) -> f64 {
        self.speedup
    }

    /// The elastomer's true E1 and nu1: what a run on this rig should recover.
    pub fn truth(&self) -> Material {
        Material { e1_mpa: self.pair.elastomer.e_mpa, nu1: self.pair.elastomer.nu }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::effects::sensor_gain;
    use crate::physics::Body;

    #[test]
    fn a_profile_material_is_the_truth_and_leaves_the_effects() {
        let profile = SimProfile {
            material: Some(Material { e1_mpa: 0.5, nu1: 0.3 }),
            sensor_gain: Some(sensor_gain::Params { g: 0.98 }),
            ..SimProfile::default()
        };
        let s = SimSetupInput { profile, ..SimSetupInput::default() }.resolve().unwrap();
        assert_eq!(s.pair().elastomer, Body::new(0.5, 0.3, defaults::ELASTOMER_R_MM));
        assert_eq!(s.pair().indenter, defaults::indenter());
        assert_eq!(s.truth(), Material { e1_mpa: 0.5, nu1: 0.3 });
        assert_eq!(s.effects().material, None);
        assert_eq!(s.effects().enabled(), vec!["sensor_gain"]);
        assert_eq!(SimSetup::default().truth(), Material { e1_mpa: 0.33, nu1: 0.39 });
    }

    #[test]
    fn impossible_set_ups_are_refused_naming_the_value() {
        let bad_nu = SimSetupInput {
            pair: ContactPair { elastomer: Body::new(0.33, 0.7, 33.0), ..defaults::pair() },
            ..SimSetupInput::default()
        };
        assert!(bad_nu.resolve().unwrap_err().to_string().contains("0.7"));
        let bad_material = SimSetupInput {
            profile: SimProfile { material: Some(Material { e1_mpa: -1.0, nu1: 0.3 }), ..SimProfile::default() },
            ..SimSetupInput::default()
        };
        assert!(matches!(bad_material.resolve(), Err(SetupError::Params(ParamError::Modulus { .. }))));
        for speedup in [0.0, -2.0, f64::NAN, f64::INFINITY] {
            let e = SimSetupInput { speedup, ..SimSetupInput::default() }.resolve().unwrap_err();
            assert!(matches!(e, SetupError::Speedup(_)), "{e}");
        }
        let bad_effect = SimSetupInput {
            profile: SimProfile { sensor_gain: Some(sensor_gain::Params { g: -1.0 }), ..SimProfile::default() },
            ..SimSetupInput::default()
        };
        assert!(bad_effect.resolve().unwrap_err().to_string().contains("sensor_gain.g"));
    }
}
