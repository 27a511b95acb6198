//! Normal contact: Hertz (Eqs. 2-3) with Tatara's finite-size correction
//! (Eq. 5) and Yoffe's correction of the indenter's Hertz term (Eq. 20).
//!
//! The contact radius `a` is the independent variable: with `F(a) = 4E*a³/(3R*)`
//! every quantity is a polynomial in `a`, which avoids the F^(2/3) power and
//! keeps the solve well conditioned down to a -> 0.

use serde::Serialize;

use super::YOFFE;
use super::params::{ContactPair, ParamError};

/// One solved state of the normal contact.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct NormalState {
    /// Approach of the two bodies, gamma1 + gamma2, mm.
    pub delta_mm: f64,
    /// Maximum normal displacement of the elastomer, mm.
    pub gamma1_mm: f64,
    /// Deformation of the indenter, mm.
    pub gamma2_mm: f64,
    /// Common contact force, N.
    pub force_n: f64,
    /// Contact radius, mm.
    pub contact_radius_mm: f64,
}

impl NormalState {
    pub const NONE: NormalState =
        NormalState { delta_mm: 0.0, gamma1_mm: 0.0, gamma2_mm: 0.0, force_n: 0.0, contact_radius_mm: 0.0 };
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NormalError {
    #[error("invalid contact parameters: {0}")]
    Params(#[from] ParamError),
    #[error("approach {delta_mm} mm is not a finite number")]
    NotFinite { delta_mm: f64 },
    #[error(
        "approach {delta_mm:.4} mm exceeds the model's limit {limit_mm:.4} mm \
         (past it the Tatara term gives negative stiffness)"
    )]
    BeyondModel { delta_mm: f64, limit_mm: f64 },
}

/// The normal-contact model for one contact pair, with its coefficients precomputed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalModel {
    pair: ContactPair,
    /// Hertz coefficient of the elastomer, A1 = E*/(E1* R*) (Eq. 7).
    a1: f64,
    /// Hertz coefficient of the indenter, with Yoffe's factor when enabled (Eq. 20).
    a2: f64,
    /// Tatara compliances b_i (Eq. 5), mm/N.
    b1: f64,
    b2: f64,
    /// F = k a³ with k = 4E*/(3R*) (Hertz).
    k_force: f64,
    /// delta(a) = P a² - Q a³.
    p: f64,
    q: f64,
    /// Largest contact radius where delta(a) still rises.
    a_turn: f64,
}

impl NormalModel {
    /// The paper's model: Hertz + Tatara + Yoffe.
    pub fn new(pair: ContactPair) -> Result<Self, ParamError> {
        Self::with_options(pair, true, true)
    }

    /// `yoffe`: apply Eq. 20 to the indenter; `tatara`: apply Eq. 5's finite-size term.
    pub fn with_options(pair: ContactPair, yoffe: bool, tatara: bool) -> Result<Self, ParamError> {
        pair.validate()?;
        let e_star = pair.composite_modulus_mpa();
        let r_star = pair.composite_radius_mm();
        let a1 = e_star / (pair.elastomer.plane_strain_mpa() * r_star);
        let a2 = e_star / (pair.indenter.plane_strain_mpa() * r_star) * if yoffe { YOFFE } else { 1.0 };
        let (b1, b2) =
            if tatara { (pair.elastomer.tatara_mm_per_n(), pair.indenter.tatara_mm_per_n()) } else { (0.0, 0.0) };
        let k_force = 4.0 * e_star / (3.0 * r_star);
        let p = a1 + a2;
        let q = (b1 + b2) * k_force;
        let a_turn = if q > 0.0 { 2.0 * p / (3.0 * q) } else { f64::INFINITY };
        Ok(Self { pair, a1, a2, b1, b2, k_force, p, q, a_turn })
    }

    pub fn pair(&self) -> &ContactPair {
        &self.pair
    }

    /// Hertz force at contact radius `a` (Eq. 2 with Eq. 5's F/a form).
    pub fn force_at_radius_n(&self, a_mm: f64) -> f64 {
        self.k_force * a_mm * a_mm * a_mm
    }

    /// Every quantity at a given contact radius (Eqs. 2, 5, 20).
    pub fn at_contact_radius(&self, a_mm: f64) -> NormalState {
        let a = a_mm.max(0.0);
        let f = self.force_at_radius_n(a);
        let gamma1 = self.a1 * a * a - self.b1 * f;
        let gamma2 = self.a2 * a * a - self.b2 * f;
        NormalState {
            delta_mm: gamma1 + gamma2,
            gamma1_mm: gamma1,
            gamma2_mm: gamma2,
            force_n: f,
            contact_radius_mm: a,
        }
    }

    /// The largest approach the model can describe (delta at the turning radius).
    pub fn max_approach_mm(&self) -> f64 {
        if self.a_turn.is_finite() { self.p * self.a_turn * self.a_turn / 3.0 } else { f64::INFINITY }
    }

    /// Solve for the state at stage approach `delta_mm` (gamma1 + gamma2 = delta).
    /// delta <= 0 means no contact and gives all zeros.
    pub fn solve(&self, delta_mm: f64) -> Result<NormalState, NormalError> {
        if !delta_mm.is_finite() {
            return Err(NormalError::NotFinite { delta_mm });
        }
        if delta_mm <= 0.0 {
            return Ok(NormalState::NONE);
        }
        let limit = self.max_approach_mm();
        if delta_mm >= limit {
            return Err(NormalError::BeyondModel { delta_mm, limit_mm: limit });
        }
        // delta(a) <= P a², so the plain-Hertz radius is a lower bound on the root.
        let a0 = (delta_mm / self.p).sqrt();
        let a = solve_increasing_cubic(self.p, self.q, delta_mm, a0, self.a_turn);
        let mut state = self.at_contact_radius(a);
        state.delta_mm = delta_mm;
        Ok(state)
    }

    /// Solve for the state at which the indenter's deformation is `gamma2_mm`
    /// (the rig's torsion depth, beta = gamma2 / R2).
    pub fn solve_for_gamma2(&self, gamma2_mm: f64) -> Result<NormalState, NormalError> {
        if !gamma2_mm.is_finite() {
            return Err(NormalError::NotFinite { delta_mm: gamma2_mm });
        }
        if gamma2_mm <= 0.0 {
            return Ok(NormalState::NONE);
        }
        let q2 = self.b2 * self.k_force;
        let turn2 = if q2 > 0.0 { 2.0 * self.a2 / (3.0 * q2) } else { f64::INFINITY };
        let limit2 = if turn2.is_finite() { self.a2 * turn2 * turn2 / 3.0 } else { f64::INFINITY };
        let a = if gamma2_mm >= limit2 {
            return Err(NormalError::BeyondModel { delta_mm: gamma2_mm, limit_mm: limit2 });
        } else {
            solve_increasing_cubic(self.a2, q2, gamma2_mm, (gamma2_mm / self.a2).sqrt(), turn2)
        };
        let state = self.at_contact_radius(a.min(self.a_turn));
        if a >= self.a_turn {
            return Err(NormalError::BeyondModel { delta_mm: state.delta_mm, limit_mm: self.max_approach_mm() });
        }
        Ok(state)
    }
}

/// Root of p a² - q a³ = target on [a_lo, a_turn), where the left side rises
/// monotonically. Newton from the lower bound, guarded by bisection.
fn solve_increasing_cubic(p: f64, q: f64, target: f64, a_lo: f64, a_turn: f64) -> f64 {
    if q == 0.0 {
        return a_lo;
    }
    let f = |a: f64| p * a * a - q * a * a * a - target;
    let mut lo = a_lo;
    let mut hi = a_turn;
    let mut a = a_lo;
    for _ in 0..100 {
        let fa = f(a);
        if fa < 0.0 {
            lo = a;
        } else {
            hi = a;
        }
        let d = 2.0 * p * a - 3.0 * q * a * a;
        let mut next = if d > 0.0 { a - fa / d } else { f64::NAN };
        if !(next > lo && next < hi) {
            next = 0.5 * (lo + hi);
        }
        if (next - a).abs() <= 1e-15 * a.max(1e-300) + 1e-16 {
            return next;
        }
        a = next;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::params::Body;

    fn tac3d() -> ContactPair {
        ContactPair { elastomer: Body::new(0.33, 0.39, 33.0), indenter: Body::new(1.1, 0.39, 5.0) }
    }

    #[test]
    fn approach_residual_is_machine_precision_up_to_beta_0_3() {
        let m = NormalModel::new(tac3d()).unwrap();
        let top = m.solve_for_gamma2(0.3 * 5.0).unwrap().delta_mm;
        for i in 0..=2000 {
            let delta = top * (i as f64 / 2000.0).powi(3);
            let s = m.solve(delta).unwrap();
            assert!(s.gamma1_mm.is_finite() && s.gamma2_mm.is_finite() && s.force_n.is_finite());
            assert!((s.gamma1_mm + s.gamma2_mm - delta).abs() <= 1e-12 * (1.0 + delta), "delta {delta}");
            assert!(s.gamma1_mm >= 0.0 && s.gamma2_mm >= 0.0);
        }
        for delta in [1e-300, 1e-200, 1e-30, 1e-12, 1e-9] {
            let s = m.solve(delta).unwrap();
            assert!(s.gamma1_mm.is_finite() && s.gamma1_mm > 0.0, "delta {delta}: {s:?}");
        }
    }

    #[test]
    fn no_contact_below_zero_and_errors_beyond_model() {
        let m = NormalModel::new(tac3d()).unwrap();
        assert_eq!(m.solve(-0.1).unwrap(), NormalState::NONE);
        assert_eq!(m.solve(0.0).unwrap(), NormalState::NONE);
        assert!(matches!(m.solve(f64::NAN), Err(NormalError::NotFinite { .. })));
        let limit = m.max_approach_mm();
        assert!(limit > 20.0, "{limit}");
        assert!(matches!(m.solve(limit * 1.01), Err(NormalError::BeyondModel { .. })));
    }

    #[test]
    fn initial_slope_is_yoffe_times_modulus_ratio() {
        let pair = tac3d();
        let m = NormalModel::new(pair).unwrap();
        let s1 = m.solve(1e-14).unwrap();
        let s2 = m.solve(2e-14).unwrap();
        let slope = (s2.gamma2_mm - s1.gamma2_mm) / (s2.gamma1_mm - s1.gamma1_mm);
        let expect =
            32.0 / (9.0 * std::f64::consts::PI) * pair.elastomer.plane_strain_mpa() / pair.indenter.plane_strain_mpa();
        assert!((slope / expect - 1.0).abs() < 1e-6, "{slope} vs {expect}");
    }

    #[test]
    fn large_radii_recover_plain_hertz() {
        // R1, R2 -> infinity: the Tatara term vanishes; without Yoffe this is plain Hertz.
        let r = 1e12;
        let pair = ContactPair { elastomer: Body::new(0.33, 0.39, r), indenter: Body::new(1.1, 0.39, r) };
        let m = NormalModel::with_options(pair, false, true).unwrap();
        let e_star = pair.composite_modulus_mpa();
        let r_star = pair.composite_radius_mm();
        for delta in [0.01, 0.5, 3.0] {
            let s = m.solve(delta).unwrap();
            let f_hertz = 4.0 / 3.0 * e_star * r_star.sqrt() * delta.powf(1.5);
            assert!((s.force_n / f_hertz - 1.0).abs() < 1e-5, "{} vs {}", s.force_n, f_hertz);
            let k1 = pair.elastomer.plane_strain_mpa() / pair.indenter.plane_strain_mpa();
            assert!((s.gamma2_mm / s.gamma1_mm / k1 - 1.0).abs() < 1e-5);
        }
        // And the Tatara term itself is what separates finite radii from Hertz.
        let finite = NormalModel::with_options(tac3d(), false, true).unwrap().solve(3.0).unwrap();
        let no_tatara = NormalModel::with_options(tac3d(), false, false).unwrap().solve(3.0).unwrap();
        assert!(finite.force_n > no_tatara.force_n * 1.05);
    }

    #[test]
    fn solve_for_gamma2_inverts_solve() {
        let m = NormalModel::new(tac3d()).unwrap();
        let s = m.solve_for_gamma2(1.0).unwrap();
        assert!((s.gamma2_mm - 1.0).abs() < 1e-12);
        let back = m.solve(s.delta_mm).unwrap();
        assert!((back.gamma1_mm - s.gamma1_mm).abs() < 1e-10);
        // Orders of magnitude from docs/physics.md 1.2 for a Tac3D-like case (E2 = 2.5 E1 there).
        let pair = ContactPair { elastomer: Body::new(0.3, 0.4, 33.0), indenter: Body::new(0.75, 0.4, 5.0) };
        let s = NormalModel::new(pair).unwrap().solve_for_gamma2(1.0).unwrap();
        assert!((s.delta_mm - 4.0).abs() < 0.6, "{s:?}");
        assert!((s.force_n - 6.5).abs() < 1.5, "{s:?}");
        assert!((s.contact_radius_mm - 4.3).abs() < 0.5, "{s:?}");
    }
}
