//! A contact the rig's effects wrap but this crate does not solve: the
//! declared gel layer, whose exact contact (the finite-element layer model
//! of the `fem` crate, with the indenter held at its flat face) lives
//! downstream of `sim`. The rig-level effects (the stage's and the mount's
//! play, the stage zero, the frame's drift and compliance, the sensor's
//! gain) act outside the contact, so they wrap any contact the same way;
//! the effects that change the contact itself (adhesion, creep, the
//! half-space's slip and layer corrections) do not (docs/physics.md, "Rig
//! effects on a declared layer").

use super::{EffectError, SimProfile};

/// The clean contact at one approach, as a [`ContactLaw`] solves it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LawState {
    /// The elastomer's surface deflection on the axis, mm.
    pub gamma1_mm: f64,
    /// The indenter's deformation, mm.
    pub gamma2_mm: f64,
    pub force_n: f64,
    pub contact_radius_mm: f64,
}

impl From<crate::physics::NormalState> for LawState {
    fn from(s: crate::physics::NormalState) -> Self {
        Self {
            gamma1_mm: s.gamma1_mm,
            gamma2_mm: s.gamma2_mm,
            force_n: s.force_n,
            contact_radius_mm: s.contact_radius_mm,
        }
    }
}

/// The clean contact between the indenter and the elastomer, given the
/// approach of the indenter's platform past first touch (`delta_mm`, the
/// stage after every rig-level effect). Implementations must be pure
/// functions of their arguments (a cache inside is fine).
pub trait ContactLaw: Send + Sync + std::fmt::Debug {
    /// The normal contact at approach `delta_mm` > 0.
    fn normal(&self, delta_mm: f64) -> Result<LawState, String>;
    /// The elastomer's twist as the sensor reads it (degrees, the sign of
    /// `twist_deg`) when the platform, at approach `delta_mm`, has turned by
    /// `twist_deg` from where the twist began.
    fn theta1_deg(&self, delta_mm: f64, twist_deg: f64) -> Result<f64, String>;
    /// How the contact's normal surface field departs from Hertz's, for the
    /// simulated sensor to draw (`None`: it does not, or the law cannot say).
    fn surface(&self) -> Option<std::sync::Arc<crate::sensor::shape::SurfaceShape>> {
        None
    }
}

/// The effects of a profile that change the contact itself, which a
/// [`ContactLaw`] does not take: the first one `profile` has.
pub fn contact_effect(profile: &SimProfile) -> Option<&'static str> {
    [
        (profile.adhesion.is_some(), "adhesion"),
        (profile.viscoelastic.is_some(), "viscoelastic"),
        (profile.partial_slip.is_some(), "partial_slip"),
        (profile.finite_thickness.is_some(), "finite_thickness"),
    ]
    .into_iter()
    .find_map(|(on, name)| on.then_some(name))
}

/// Refuse a profile whose effects a contact law cannot carry.
pub(super) fn check(profile: &SimProfile) -> Result<(), EffectError> {
    contact_effect(profile).map_or(Ok(()), |name| Err(EffectError::NotOnLayer(name)))
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::effects::{
        CommandedPose, EffectError, SimProfile, TrueRig, adhesion, frame_compliance, rotation_backlash, sensor_gain,
        simulate, simulate_on, stage_backlash, thermal_drift,
    };
    use crate::physics::{ContactPair, NormalModel, torsion_at};

    /// The paper's own contact, as a law solved outside the rig.
    #[derive(Debug)]
    struct Paper(ContactPair, NormalModel);

    impl ContactLaw for Paper {
        fn normal(&self, delta_mm: f64) -> Result<LawState, String> {
            self.1.solve(delta_mm).map(LawState::from).map_err(|e| e.to_string())
        }
        fn theta1_deg(&self, delta_mm: f64, twist_deg: f64) -> Result<f64, String> {
            let beta = self.normal(delta_mm)?.gamma2_mm / self.0.indenter.r_mm;
            Ok(torsion_at(&self.0, beta, twist_deg.to_radians()).theta1_rad.to_degrees())
        }
    }

    /// Press to 1.6 mm, back off, press again, twist to 10° and back.
    fn history() -> Vec<CommandedPose> {
        let stage = (0..=32).map(|i| 0.05 * i as f64).chain((0..32).rev().map(|i| 0.05 * i as f64));
        let mut v: Vec<CommandedPose> =
            stage.enumerate().map(|(i, s)| CommandedPose { t_s: i as f64, stage_mm: s, rot_deg: 0.0 }).collect();
        let t0 = v.len() as f64;
        let twist = (0..=10).map(f64::from).chain((0..10).rev().map(f64::from));
        v.extend(twist.enumerate().map(|(i, r)| CommandedPose { t_s: t0 + i as f64, stage_mm: 1.6, rot_deg: r }));
        v
    }

    #[test]
    fn the_rig_effects_wrap_a_law_as_they_wrap_the_papers_contact() {
        let pair = crate::defaults::pair();
        let law: Arc<dyn ContactLaw> = Arc::new(Paper(pair, NormalModel::new(pair).unwrap()));
        let profile = SimProfile {
            stage_backlash: Some(stage_backlash::Params { b_mm: 0.02, engaged: false }),
            frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.005 }),
            rotation_backlash: Some(rotation_backlash::Params { b_deg: 0.3, engaged: false }),
            thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 2e-4, vdot_mm_per_s2: 0.0 }),
            sensor_gain: Some(sensor_gain::Params { g: 0.97 }),
            ..Default::default()
        };
        let closed = simulate(pair, &profile, &history()).unwrap();
        let wrapped = simulate_on(pair, &profile, law.clone(), &history()).unwrap();
        let mut compliant = 0;
        for (i, (a, b)) in closed.iter().zip(&wrapped).enumerate() {
            assert_eq!(a.in_contact, b.in_contact, "sample {i}");
            assert!((a.gamma1_mm - b.gamma1_mm).abs() < 1e-9, "sample {i}: {} vs {}", a.gamma1_mm, b.gamma1_mm);
            assert!((a.force_n - b.force_n).abs() < 1e-8 * a.force_n.max(1.0), "sample {i}");
            assert!((a.theta1_deg - b.theta1_deg).abs() < 1e-9, "sample {i}: {} vs {}", a.theta1_deg, b.theta1_deg);
            compliant += usize::from(a.force_n > 0.1);
        }
        assert!(compliant > 20, "the frame carries load in {compliant} samples");
        // Each effect moves the readings: the comparison is not of two clean rigs.
        let clean = simulate_on(pair, &SimProfile::default(), law, &history()).unwrap();
        let moved = clean.iter().zip(&wrapped).filter(|(a, b)| (a.gamma1_mm - b.gamma1_mm).abs() > 1e-3).count();
        assert!(moved > 30, "{moved}");
    }

    #[test]
    fn an_effect_inside_the_contact_is_refused_on_a_law() {
        let pair = crate::defaults::pair();
        let law: Arc<dyn ContactLaw> = Arc::new(Paper(pair, NormalModel::new(pair).unwrap()));
        let profile =
            SimProfile { adhesion: Some(adhesion::Params { w_mj_m2: 200.0, eta: 2.0 }), ..Default::default() };
        let err = TrueRig::on_law(pair, &profile, law).unwrap_err();
        assert_eq!(err, EffectError::NotOnLayer("adhesion"));
        assert!(err.to_string().contains("adhesion"), "{err}");
    }
}
