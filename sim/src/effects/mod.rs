//! The physics and rig behaviour the paper leaves out (docs/physics.md section 2),
//! one module per effect, and the "true rig" that applies them.
//!
//! Each module carries its model, its parameters with bounds, where it shows
//! in a sweep and a plain explanation, both as doc comments and as data
//! ([`EffectInfo`]) that reports can print. A [`SimProfile`] (TOML) lists the
//! enabled effects with their parameters; [`TrueRig`] turns a commanded
//! stage / mount history into the readings a rig with those effects gives.
//!
//! # Public API (kept stable for the diagnosis and the simulated devices)
//!
//! * Catalogue: [`ALL`] (`[&EffectInfo; 10]`, docs/physics.md order), [`info`]`(name)`;
//!   [`EffectInfo`] `{ name, model, params: &[ParamInfo], signature,
//!   identifiability, sentence, explanation, separate_by }`, [`ParamInfo`]
//!   `{ name, unit, min, max, typical }` — `ParamInfo::name` is the TOML key.
//! * Parameters: `<effect>::Params` per module (plain `pub` fields, serde),
//!   each with `validate()`; extra helpers: `finite_thickness::{phi, torsion_factor}`,
//!   `adhesion::punch_displacement`, `thermal_drift::Params::offset_mm(t)`,
//!   `stage_backlash::Play` (the play operator), `partial_slip::{SlipState, elliptic_e}`.
//! * Profile: [`SimProfile`] `{ material: Option<Material>, <effect>: Option<Params>, .. }`
//!   with `from_toml_str`, `to_toml_string`, `load(&Path)`, `save(&Path)`,
//!   `validate`, `enabled() -> Vec<&'static str>`, `is_clean`. Absent sections are
//!   off; `material` (E1_MPa, nu1) overrides the elastomer of the pair given to
//!   the rig. Errors: [`EffectError`] (`OutOfBounds` names `effect.param`, `Toml`
//!   names unknown sections/keys, `Unsupported` for viscoelastic combined with
//!   adhesion or finite_thickness, `NoSolution`, `GrossSlip`, `Io`).
//! * True rig: [`TrueRig::new`]`(pair, &profile)`, [`TrueRig::read`]`(CommandedPose) ->
//!   Result<Reading, EffectError>` — a stateful stepper: feed commands in time
//!   order (stage backlash, adhesion, creep and slip keep history);
//!   `Clone` it to probe without disturbing the history. [`simulate`]`(pair,
//!   &profile, &[CommandedPose])` runs a whole history on a fresh rig.
//!   [`TrueRig::on_law`]`(pair, &profile, law)` and [`simulate_on`] wrap a
//!   contact solved elsewhere ([`ContactLaw`], the declared layer) in the
//!   rig-level effects.
//!   [`CommandedPose`] `{ t_s, stage_mm, rot_deg }` (commanded values; `rot_deg` is the
//!   mount angle since the twist began), [`Reading`] `{ gamma1_mm, theta1_deg }`
//!   as the sensor reports them (noise-free; 0 without contact) plus the true
//!   `gamma1_true_mm, gamma2_mm, force_n, contact_radius_mm, in_contact`.
//! * Generator: `crate::generator::GeneratorConfig::profile` switches effects on
//!   in synthetic recordings (an empty profile is the clean model bit for bit).
//!
//! The stage and mount inputs are the *commanded* positions: do not also give
//! the emulator's `Axis` a backlash when `stage_backlash`/`rotation_backlash` is on.

pub mod adhesion;
pub mod contact_offset;
pub mod finite_thickness;
pub mod frame_compliance;
pub mod law;
pub mod partial_slip;
pub mod rig;
pub mod rotation_backlash;
pub mod sensor_gain;
pub mod stage_backlash;
pub mod thermal_drift;
pub mod viscoelastic;

#[cfg(test)]
mod signatures;

use serde::{Deserialize, Serialize};

/// A profile's `material`: the elastomer's E1, nu1 when a profile also fixes
/// them (a diagnosis writes its fitted values there so the simulated rig
/// reproduces the recording).
pub use crate::physics::Material;
use crate::physics::{Body, ContactPair};

pub use law::{ContactLaw, LawState};
pub use rig::{CommandedPose, Reading, TrueRig, simulate, simulate_on};

/// One parameter of an effect, with the range the model accepts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ParamInfo {
    pub name: &'static str,
    pub unit: &'static str,
    /// Smallest value the model accepts.
    pub min: f64,
    /// Largest value the model accepts.
    pub max: f64,
    /// Range seen on real rigs and sensors.
    pub typical: &'static str,
}

/// Whether the standard normal + torsion sweeps can tell the effect apart from
/// a change of E1 or nu1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Identifiability {
    Good,
    Weak,
    NotIdentifiable,
}

/// Everything a report needs to say about one effect.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EffectInfo {
    pub name: &'static str,
    /// One-line model.
    pub model: &'static str,
    pub params: &'static [ParamInfo],
    /// Where in a sweep it shows and with what shape.
    pub signature: &'static str,
    pub identifiability: Identifiability,
    /// The left-out physics in one sentence.
    pub sentence: &'static str,
    /// A plain paragraph for people who are not contact mechanicians.
    pub explanation: &'static str,
    /// For effects that cannot be separated from E1/nu1: what would separate them.
    pub separate_by: Option<&'static str>,
}

/// Every effect of the library, in docs/physics.md order.
pub const ALL: [&EffectInfo; 10] = [
    &finite_thickness::INFO,
    &adhesion::INFO,
    &viscoelastic::INFO,
    &contact_offset::INFO,
    &stage_backlash::INFO,
    &frame_compliance::INFO,
    &partial_slip::INFO,
    &rotation_backlash::INFO,
    &thermal_drift::INFO,
    &sensor_gain::INFO,
];

/// Look an effect up by name.
pub fn info(name: &str) -> Option<&'static EffectInfo> {
    ALL.iter().copied().find(|i| i.name == name)
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EffectError {
    #[error("{effect}.{param} = {value} outside [{min}, {max}]")]
    OutOfBounds { effect: &'static str, param: &'static str, value: f64, min: f64, max: f64 },
    #[error("{0} cannot be combined with viscoelastic in this model")]
    Unsupported(&'static str),
    #[error("{0} changes the contact itself and is modelled on the half-space only, not on a declared gel layer")]
    NotOnLayer(&'static str),
    #[error("a declared gel layer is simulated flat: the elastomer's dome radius R1 = {r1_mm} mm must be inf")]
    DomedLayer { r1_mm: f64 },
    #[error("the contact model has no solution at stage {stage_mm:.4} mm: {why}")]
    NoSolution { stage_mm: f64, why: String },
    #[error("gross slip: the torque asked of the contact exceeds mu F a (twist {rot_deg:.3} deg)")]
    GrossSlip { rot_deg: f64 },
    #[error("invalid contact parameters: {0}")]
    Params(#[from] crate::physics::ParamError),
    #[error("sim profile TOML: {0}")]
    Toml(String),
    #[error("sim profile file {path}: {why}")]
    Io { path: String, why: String },
}

/// Reject a parameter outside its declared bounds, naming it.
pub(crate) fn check(effect: &'static EffectInfo, idx: usize, value: f64) -> Result<(), EffectError> {
    let p = &effect.params[idx];
    if value.is_finite() && value >= p.min && value <= p.max {
        Ok(())
    } else {
        Err(EffectError::OutOfBounds { effect: effect.name, param: p.name, value, min: p.min, max: p.max })
    }
}

/// Which effects a simulated rig has, with their parameters. Absent sections
/// are switched off; an empty profile is the paper's clean model.
///
/// ```toml
/// [finite_thickness]
/// h_mm = 5.0
///
/// [stage_backlash]
/// b_mm = 0.006
/// engaged = true
/// ```
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimProfile {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub material: Option<Material>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub finite_thickness: Option<finite_thickness::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adhesion: Option<adhesion::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub viscoelastic: Option<viscoelastic::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact_offset: Option<contact_offset::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stage_backlash: Option<stage_backlash::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frame_compliance: Option<frame_compliance::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub partial_slip: Option<partial_slip::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotation_backlash: Option<rotation_backlash::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub thermal_drift: Option<thermal_drift::Params>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sensor_gain: Option<sensor_gain::Params>,
}

impl SimProfile {
    /// Parse and validate a profile. Unknown sections or keys and parameters
    /// outside their bounds are errors that name the effect and parameter.
    pub fn from_toml_str(text: &str) -> Result<Self, EffectError> {
        let p: SimProfile = toml::from_str(text).map_err(|e| EffectError::Toml(e.to_string()))?;
        p.validate()?;
        Ok(p)
    }

    /// The profile as TOML (one section per enabled effect).
    pub fn to_toml_string(&self) -> Result<String, EffectError> {
        toml::to_string(self).map_err(|e| EffectError::Toml(e.to_string()))
    }

    /// Read and validate a profile file.
    pub fn load(path: &std::path::Path) -> Result<Self, EffectError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| EffectError::Io { path: path.display().to_string(), why: e.to_string() })?;
        Self::from_toml_str(&text).map_err(|e| match e {
            EffectError::Toml(why) => EffectError::Toml(format!("{}: {why}", path.display())),
            other => other,
        })
    }

    /// Validate and write the profile to a file.
    pub fn save(&self, path: &std::path::Path) -> Result<(), EffectError> {
        self.validate()?;
        let text = self.to_toml_string()?;
        std::fs::write(path, text).map_err(|e| EffectError::Io { path: path.display().to_string(), why: e.to_string() })
    }

    /// The contact pair a rig with this profile has: the profile's `material`,
    /// when set, replaces the given elastomer's E1 and nu1 (its radius R1 stays).
    /// The one place a profile's material is applied.
    pub fn true_pair(&self, given: ContactPair) -> ContactPair {
        match self.material {
            Some(m) => ContactPair { elastomer: Body::new(m.e1_mpa, m.nu1, given.elastomer.r_mm), ..given },
            None => given,
        }
    }

    /// True when no effect is enabled and no material is set: the paper's clean model.
    pub fn is_clean(&self) -> bool {
        self.enabled().is_empty() && self.material.is_none()
    }

    /// Names of the enabled effects, in library order.
    pub fn enabled(&self) -> Vec<&'static str> {
        let on = [
            self.finite_thickness.is_some(),
            self.adhesion.is_some(),
            self.viscoelastic.is_some(),
            self.contact_offset.is_some(),
            self.stage_backlash.is_some(),
            self.frame_compliance.is_some(),
            self.partial_slip.is_some(),
            self.rotation_backlash.is_some(),
            self.thermal_drift.is_some(),
            self.sensor_gain.is_some(),
        ];
        ALL.iter().zip(on).filter(|(_, on)| *on).map(|(i, _)| i.name).collect()
    }

    /// Check every enabled effect's parameters against its bounds.
    pub fn validate(&self) -> Result<(), EffectError> {
        if let Some(p) = &self.finite_thickness {
            p.validate()?;
        }
        if let Some(p) = &self.adhesion {
            p.validate()?;
        }
        if let Some(p) = &self.viscoelastic {
            p.validate()?;
            if self.adhesion.is_some() {
                return Err(EffectError::Unsupported("adhesion"));
            }
            if self.finite_thickness.is_some() {
                return Err(EffectError::Unsupported("finite_thickness"));
            }
        }
        if let Some(p) = &self.contact_offset {
            p.validate()?;
        }
        if let Some(p) = &self.stage_backlash {
            p.validate()?;
        }
        if let Some(p) = &self.frame_compliance {
            p.validate()?;
        }
        if let Some(p) = &self.partial_slip {
            p.validate()?;
        }
        if let Some(p) = &self.rotation_backlash {
            p.validate()?;
        }
        if let Some(p) = &self.thermal_drift {
            p.validate()?;
        }
        if let Some(p) = &self.sensor_gain {
            p.validate()?;
        }
        Ok(())
    }
}

/// Root of an increasing-through-zero function on [lo, hi] with f(lo) < 0 <= f(hi):
/// Illinois false position, which keeps the bracket and converges superlinearly.
pub(crate) fn bracketed_root(
    mut f: impl FnMut(f64) -> f64,
    mut lo: f64,
    mut hi: f64,
    mut flo: f64,
    mut fhi: f64,
    tol: f64,
) -> f64 {
    let mut side = 0i8;
    for _ in 0..200 {
        let x = if fhi != flo { (lo * fhi - hi * flo) / (fhi - flo) } else { 0.5 * (lo + hi) };
        let x = if x > lo && x < hi { x } else { 0.5 * (lo + hi) };
        let fx = f(x);
        if fx == 0.0 || (hi - lo).abs() <= tol {
            return x;
        }
        if (fx < 0.0) == (flo < 0.0) {
            lo = x;
            flo = fx;
            if side == -1 {
                fhi *= 0.5;
            }
            side = -1;
        } else {
            hi = x;
            fhi = fx;
            if side == 1 {
                flo *= 0.5;
            }
            side = 1;
        }
        if (hi - lo).abs() <= tol {
            return 0.5 * (lo + hi);
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profile_round_trips_through_toml_and_rejects_bad_values() {
        let p = SimProfile {
            finite_thickness: Some(finite_thickness::Params { h_mm: 5.0 }),
            stage_backlash: Some(stage_backlash::Params { b_mm: 0.006, engaged: true }),
            partial_slip: Some(partial_slip::Params { mu: 1.2 }),
            ..Default::default()
        };
        let text = p.to_toml_string().unwrap();
        assert!(text.contains("[finite_thickness]") && text.contains("h_mm = 5.0"), "{text}");
        assert_eq!(SimProfile::from_toml_str(&text).unwrap(), p);
        assert_eq!(p.enabled(), vec!["finite_thickness", "stage_backlash", "partial_slip"]);
        let bad = SimProfile::from_toml_str("[finite_thickness]\nh_mm = -1.0\n").unwrap_err();
        assert!(bad.to_string().contains("finite_thickness.h_mm"), "{bad}");
        assert!(SimProfile::from_toml_str("[no_such_effect]\nx = 1\n").is_err());
        assert!(SimProfile::from_toml_str("").unwrap().enabled().is_empty());
    }

    #[test]
    fn every_effect_is_documented() {
        let names: Vec<_> = ALL.iter().map(|i| i.name).collect();
        assert_eq!(
            names,
            [
                "finite_thickness",
                "adhesion",
                "viscoelastic",
                "contact_offset",
                "stage_backlash",
                "frame_compliance",
                "partial_slip",
                "rotation_backlash",
                "thermal_drift",
                "sensor_gain"
            ]
        );
        for i in ALL {
            assert!(i.explanation.len() > 100 && !i.signature.is_empty() && !i.params.is_empty(), "{}", i.name);
            assert!(i.params.iter().all(|p| p.min < p.max));
        }
        assert!(info("sensor_gain").unwrap().separate_by.is_some());
    }

    #[test]
    fn illinois_finds_roots() {
        let r = bracketed_root(|x| x * x * x - 2.0, 0.0, 2.0, -2.0, 6.0, 1e-14);
        assert!((r - 2f64.cbrt()).abs() < 1e-12, "{r}");
    }
}
