//! The paper's reduced relations and their inversion to E1, nu1.

use super::YOFFE;
use super::params::{Body, ContactPair, Material};
use super::torsion::rod_correction_factor;

/// H1 of the reduced normal relation gamma2 = H1 gamma1 + H2 gamma1^1.5 (Eq. 22).
pub fn h1_from_materials(elastomer: &Body, indenter: &Body) -> f64 {
    YOFFE * (1.0 - indenter.nu * indenter.nu) / (1.0 - elastomer.nu * elastomer.nu) * elastomer.e_mpa / indenter.e_mpa
}

/// H3 of theta2 = H3 theta1 at depth beta (Eq. 38, with nu where the paper prints gamma).
pub fn h3_from_materials(elastomer: &Body, indenter: &Body, beta: f64) -> f64 {
    rod_correction_factor(beta) * (1.0 + indenter.nu) / (1.0 + elastomer.nu) * elastomer.e_mpa / indenter.e_mpa
}

/// Exact closed-form solution of H1(E1, nu1) and H3(E1, nu1) at depth beta (docs/physics.md 1.5).
pub fn invert_exact(h1: f64, h3: f64, indenter_e_mpa: f64, indenter_nu: f64, beta: f64) -> Material {
    let c = rod_correction_factor(beta);
    let nu1 = 1.0 - YOFFE / c * (h3 / h1) * (1.0 - indenter_nu);
    let e1 = h3 * indenter_e_mpa * (1.0 + nu1) / (c * (1.0 + indenter_nu));
    Material { e1_mpa: e1, nu1 }
}

/// The paper's Eqs. 39-40 with their rounded constants (valid only at beta = 0.2).
pub fn invert_paper_rounded(h1: f64, h3: f64, indenter_e_mpa: f64, indenter_nu: f64) -> Material {
    let ratio = h3 / h1 * (1.0 - indenter_nu);
    let e1 = (0.993 - 0.279 * ratio) * h3 * indenter_e_mpa / (1.0 + indenter_nu);
    let nu1 = 1.0 - 0.562 * ratio;
    Material { e1_mpa: e1, nu1 }
}

/// Convenience: both reduced coefficients of a pair at depth beta.
pub fn reduced_coefficients(pair: &ContactPair, beta: f64) -> (f64, f64) {
    (h1_from_materials(&pair.elastomer, &pair.indenter), h3_from_materials(&pair.elastomer, &pair.indenter, beta))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_numbers_through_rounded_constants() {
        // Section IV: H1 = 0.3397, H3 = 0.6023, E2 = 1.1035 MPa, nu2 = 0.3883.
        let r = invert_paper_rounded(0.3397, 0.6023, 1.1035, 0.3883);
        assert_eq!(format!("{:.4}", r.e1_mpa), "0.3305");
        assert_eq!(format!("{:.4}", r.nu1), "0.3905");
        let x = invert_exact(0.3397, 0.6023, 1.1035, 0.3883, 0.2);
        assert!((x.e1_mpa / r.e1_mpa - 1.0).abs() < 0.005, "{x:?}");
        assert!((x.nu1 / r.nu1 - 1.0).abs() < 0.005, "{x:?}");
    }

    #[test]
    fn exact_inversion_round_trips_materials() {
        let ind = Body::new(1.1, 0.39, 5.0);
        for (e1, nu1) in [(0.33, 0.39), (0.1, 0.05), (1.0, 0.49), (0.5, 0.25)] {
            for beta in [0.15, 0.2, 0.23] {
                let el = Body::new(e1, nu1, 33.0);
                let h1 = h1_from_materials(&el, &ind);
                let h3 = h3_from_materials(&el, &ind, beta);
                let x = invert_exact(h1, h3, ind.e_mpa, ind.nu, beta);
                assert!((x.e1_mpa - e1).abs() < 1e-12 && (x.nu1 - nu1).abs() < 1e-12, "{x:?}");
            }
        }
    }
}
