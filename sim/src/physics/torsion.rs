//! Torsion at a fixed indentation: Jäger's relation (Eqs. 32-33) plus the
//! rod correction for the short indenter (Eqs. 34-37).

use std::f64::consts::PI;

use serde::Serialize;

use super::params::ContactPair;

/// Equivalent contact radius at depth beta = Δh/R2 (Eq. 35).
pub fn eq35_contact_radius_mm(indenter_radius_mm: f64, beta: f64) -> f64 {
    (1.0 + beta) * indenter_radius_mm * (2.0 * beta - beta * beta).max(0.0).sqrt()
}

/// c(beta) = 1 + Δθ2/θ2 (Eqs. 36-37): 2.01383 at beta = 0.2, computed, never assumed.
pub fn rod_correction_factor(beta: f64) -> f64 {
    let b = beta.clamp(0.0, 1.0);
    1.0 + 32.0 / (3.0 * PI) * (1.0 - b) * (2.0 * b - b * b).powf(1.5) * (1.0 + b).powi(3)
}

/// One state of the torsion sweep.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TorsionState {
    /// Total mount rotation theta1 + theta2*, rad.
    pub total_rad: f64,
    /// Rotation of the contact relative to the elastomer (what the sensor sees), rad.
    pub theta1_rad: f64,
    /// Indenter twist including the rod correction, rad.
    pub theta2_rad: f64,
    /// Transmitted torque, N·mm.
    pub torque_nmm: f64,
    /// c(beta) used.
    pub rod_factor: f64,
    /// Eq. 35 contact radius, mm.
    pub contact_radius_mm: f64,
}

/// Split a total twist between elastomer and indenter at depth `beta` (Eqs. 32-37).
pub fn torsion_at(pair: &ContactPair, beta: f64, total_rad: f64) -> TorsionState {
    let g1 = pair.elastomer.shear_mpa();
    let g2 = pair.indenter.shear_mpa();
    let c = rod_correction_factor(beta);
    let theta1 = total_rad / (1.0 + c * g1 / g2);
    let a = eq35_contact_radius_mm(pair.indenter.r_mm, beta);
    TorsionState {
        total_rad,
        theta1_rad: theta1,
        theta2_rad: total_rad - theta1,
        torque_nmm: 16.0 / 3.0 * g1 * a.powi(3) * theta1,
        rod_factor: c,
        contact_radius_mm: a,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::params::Body;

    #[test]
    fn rod_factor_matches_paper_at_beta_0_2() {
        let c = rod_correction_factor(0.2);
        assert!((c - 2.014).abs() < 5e-4, "{c}");
        assert!((c - 2.01383).abs() < 1e-5, "{c}");
        assert_eq!(rod_correction_factor(0.0), 1.0);
        // Steep around the working point: dc/dbeta ~ 8 (docs/physics.md 2).
        let slope = (rod_correction_factor(0.201) - rod_correction_factor(0.199)) / 0.002;
        assert!((slope - 8.0).abs() < 0.5, "{slope}");
    }

    #[test]
    fn torsion_split_follows_jaeger_and_rod() {
        let pair = ContactPair { elastomer: Body::new(0.33, 0.39, 33.0), indenter: Body::new(1.1, 0.39, 5.0) };
        let s = torsion_at(&pair, 0.2, 0.1);
        assert!((s.theta1_rad + s.theta2_rad - 0.1).abs() < 1e-15);
        let h3 = s.theta2_rad / s.theta1_rad;
        let expect = 2.01383 * (1.0 + 0.39) / (1.0 + 0.39) * 0.33 / 1.1;
        assert!((h3 / expect - 1.0).abs() < 1e-5, "{h3} vs {expect}");
        // Torque equal on both sides (Eq. 33 with the rod in series, Eq. 34).
        let g2 = pair.indenter.shear_mpa();
        let a = s.contact_radius_mm;
        let theta2_contact = s.torque_nmm * 3.0 / (16.0 * g2 * a.powi(3));
        let rod = s.torque_nmm * 2.0 * (5.0 - 1.0) / (PI * g2 * 5.0f64.powi(4));
        assert!((theta2_contact + rod - s.theta2_rad).abs() < 1e-12);
    }
}
