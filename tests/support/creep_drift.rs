//! The two time-dependent effects the closed loop must tell apart (issue 14),
//! at the sizes the tests give them: a creeping gel (rho 1.06, tau 8 s) and a
//! drifting frame (2.5 µm/s). Included with
//! `#[path = "support/creep_drift.rs"] mod creep_drift;`.

use sim::effects::{SimProfile, thermal_drift, viscoelastic};

/// (the effect's name, a profile with it alone): creep, then drift.
pub fn creep_and_drift() -> [(&'static str, SimProfile); 2] {
    let creep = SimProfile {
        viscoelastic: Some(viscoelastic::Params { rho: 1.06, tau_s: 8.0, memory_n: 0.0 }),
        ..SimProfile::default()
    };
    let drift = SimProfile {
        thermal_drift: Some(thermal_drift::Params { v_mm_per_s: 2.5e-3, vdot_mm_per_s2: 0.0 }),
        ..SimProfile::default()
    };
    [("viscoelastic", creep), ("thermal_drift", drift)]
}
