//! Builds the large-strain slip table (fem/data/large_strain_slip.csv): for
//! each case of the large-strain table (E2/E1, nu1, nu2; E1 = 1 MPa, R2 = h =
//! 5 mm), at every fourth load step of the neo-Hookean reference's press, the
//! fraction of the stuck twist that the twist keeps under Coulomb friction,
//! in the neo-Hookean reference over the same fraction in the linear layer
//! model the fit runs (its frictionless press at the same approach). The twist
//! is tabulated against twist / mu: with the normal state fixed the twist
//! problem is linear elasticity under caps mu N, so scaling the twist and mu
//! together scales the answer, and the fraction depends on their ratio alone
//! (docs/physics.md, "The twist at large strain").
//!
//! `cargo run --release -p fem --example large_strain_slip > fem/data/large_strain_slip.csv`
//! (`CASE=2,0.48,0.4` runs one case, `E_RATIO=2` one modulus ratio; `THREADS`
//! sets the workers, default 2).
#[path = "support/cases.rs"]
mod cases;

use fem::Material;
use fem::forward::Forward;
use fem::hyper::LargeStrainContact;

const R2: f64 = 5.0;
const H: f64 = 5.0;
const STEP_MM: f64 = 0.05;
/// Twist / mu at which the fractions are tabulated, degrees.
const TWIST_OVER_MU_DEG: [f64; 14] = [1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 12.5, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0];
/// A stuck twist small enough that nothing slips at mu = 1, rad.
const STUCK_RAD: f64 = 1e-4;

fn run(e_ratio: f64, nu1: f64, nu2: f64) -> Vec<String> {
    let (gel_mesh, segments) = cases::gel_mesh(H, fem::forward::FINE_MM);
    let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * R2).collect();
    let hemi_mesh = fem::Mesh::hemisphere(R2, &rs, segments).unwrap();
    let (gm, im) = (Material { e_mpa: 1.0, nu: nu1 }, Material { e_mpa: e_ratio, nu: nu2 });
    let integration = cases::integration();
    let mut large = LargeStrainContact::with_integration(gel_mesh, gm, hemi_mesh, im, R2, integration).unwrap();
    let forward = Forward::with_integration(H, e_ratio, nu2, R2, integration).unwrap();
    let linear = forward.model(1.0, nu1);
    let twists: Vec<f64> = TWIST_OVER_MU_DEG.iter().map(|d| d.to_radians()).collect();
    let mut out = Vec::new();
    for k in 1..=120 {
        let delta = k as f64 * STEP_MM;
        let Some(nl) = large.solve_path(&[delta], STEP_MM).ok().and_then(|mut v| v.pop()) else { break };
        // The selective table stops once gamma2 passes 0.3 R2, past any
        // sweep's beta = 0.2; its continuation goes on to the flank, so that
        // a query between moduli reaches as deep as the stiff cases do.
        let deep_enough = integration == fem::Integration::Selective && nl.gamma2_mm > 0.3 * R2;
        if deep_enough || nl.contact_radius_mm > 0.95 * R2 {
            break;
        }
        if k % 4 != 0 {
            continue;
        }
        let Ok(li) = linear.normal(delta) else { break };
        let nl_stuck = large.theta1_rad(&nl, &[STUCK_RAD], f64::INFINITY).ok().map(|t| t[0] / STUCK_RAD);
        let nl_slip = large.theta1_rad(&nl, &twists, 1.0).ok();
        // The linear twist over the nodes' edge: the fit's large-strain model
        // scales that twist by these ratios (fem::forward::TwistDisc).
        let edge = fem::forward::TwistDisc::NodeEdge;
        let li_stuck = linear
            .twist_setup_over(&li, f64::INFINITY, edge)
            .and_then(|s| linear.theta1_rad_at(&s, STUCK_RAD))
            .map(|t| t / STUCK_RAD);
        let li_setup = linear.twist_setup_over(&li, 1.0, edge);
        let (Some(ns), Some(nf), Some(ls), Some(setup)) = (nl_stuck, nl_slip, li_stuck, li_setup) else { continue };
        for (&x, (&tw, &n)) in TWIST_OVER_MU_DEG.iter().zip(twists.iter().zip(&nf)) {
            let Some(l) = linear.theta1_rad_at(&setup, tw) else { continue };
            out.push(format!(
                "{e_ratio},{nu1},{nu2},{:.4},{:.4},{x},{:.6}",
                H / R2,
                delta / R2,
                (n / (ns * tw)) / (l / (ls * tw))
            ));
        }
    }
    out
}

fn main() {
    let cases = cases::selected();
    let results = cases::run_all(&cases, run);
    println!(
        "# slip fraction, large strain over linear (fem/examples/large_strain_slip.rs; docs/physics.md, \"The twist at large strain\")"
    );
    if cases::integration() == fem::Integration::Full {
        println!("# fully integrated elements (INTEGRATION=full): the depth extension of the selective table");
    }
    println!("e2_over_e1,nu1,nu2,h_over_r2,delta_over_r2,twist_over_mu_deg,slip_ratio");
    for rows in results {
        for r in rows {
            println!("{r}");
        }
    }
}
