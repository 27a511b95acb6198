//! Builds the large-strain correction table (fem/data/large_strain.csv): for
//! each indenter-to-gel modulus ratio, gel and indenter Poisson's ratio, the
//! neo-Hookean reference and the linear one on the same meshes, pressed in
//! load steps; per step the ratios of gamma1 and of the stuck twist ratio
//! theta1 / twist (large / linear). E1 = 1 MPa and R2 = h = 5 mm: the ratios
//! depend only on the dimensionless groups (docs/physics.md, "Large strain").
//!
//! `cargo run --release -p fem --example large_strain_table > fem/data/large_strain.csv`
//! (`CASE=2,0.48,0.4` runs one case, `E_RATIO=2` one modulus ratio; `THREADS`
//! sets the workers, default 2; `FINE_MM` the element size at the contact,
//! default `fem::hyper::TABLE_FINE_MM`, 0.06 mm with `INTEGRATION=full`).
#[path = "support/cases.rs"]
mod cases;

use fem::hyper::LargeStrainContact;
use fem::torsion::{TorsionBody, stick_ratio};
use fem::{Body, Material, Mesh, TwoBodyContact};

const R2: f64 = 5.0;
const H: f64 = 5.0;
const STEP_MM: f64 = 0.05;

fn run(e_ratio: f64, nu1: f64, nu2: f64) -> Vec<String> {
    // The layer model's gel layout; the selective table on a finer mesh at
    // the contact (its deep presses are not converged on the layer model's
    // 0.06 mm), the fully integrated one, whose increments continue it, on 0.06 mm.
    let integration = cases::integration();
    let (gel_mesh, segments) = cases::gel_mesh(H, default_fine_mm());
    let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * R2).collect();
    let hemi_mesh = Mesh::hemisphere(R2, &rs, segments).unwrap();
    let (gm, im) = (Material { e_mpa: 1.0, nu: nu1 }, Material { e_mpa: e_ratio, nu: nu2 });
    let lin = TwoBodyContact::new(
        &Body::with_integration(gel_mesh.clone(), gm, integration).unwrap(),
        Some(&Body::with_integration(hemi_mesh.clone(), im, integration).unwrap()),
        R2,
    )
    .unwrap();
    let g = |m: &Material| m.e_mpa / (2.0 * (1.0 + m.nu));
    let scaled = |c: Vec<Vec<f64>>, m: &Material| -> Vec<Vec<f64>> {
        c.into_iter().map(|col| col.into_iter().map(|v| v / g(m)).collect()).collect()
    };
    let tg = scaled(TorsionBody::new(&gel_mesh).unwrap().surface_compliance(&gel_mesh.surface[..rs.len()]), &gm);
    let ti = scaled(TorsionBody::new(&hemi_mesh).unwrap().surface_compliance(&hemi_mesh.surface), &im);
    let mut large = LargeStrainContact::with_integration(gel_mesh, gm, hemi_mesh, im, R2, integration).unwrap();
    let mut out = Vec::new();
    for k in 1..=120 {
        let delta = k as f64 * STEP_MM;
        let Some(nl) = large.solve_path(&[delta], STEP_MM).ok().and_then(|mut v| v.pop()) else { break };
        let Ok(li) = lin.solve(delta) else { break };
        // The selective table stops once gamma2 passes 0.3 R2, past any
        // sweep's beta = 0.2; its continuation goes on to the flank, so that
        // a query between moduli reaches as deep as the stiff cases do.
        let deep_enough = integration == fem::Integration::Selective && nl.gamma2_mm > 0.3 * R2;
        if deep_enough || nl.contact_radius_mm > 0.95 * R2 {
            break;
        }
        let twist = if k % 2 == 0 {
            let last = li.nodal_force.iter().rposition(|&p| p > 0.0).unwrap_or(0);
            let lin_ratio = stick_ratio(&tg, &ti, &rs, last);
            let nl_ratio = large.theta1_rad(&nl, &[1e-3], f64::INFINITY).ok().map(|t| t[0] / 1e-3);
            match (nl_ratio, lin_ratio) {
                (Some(a), Some(b)) => format!("{:.6}", a / b),
                _ => String::new(),
            }
        } else {
            String::new()
        };
        out.push(format!(
            "{e_ratio},{nu1},{nu2},{:.4},{:.4},{:.6},{:.4},{}",
            H / R2,
            delta / R2,
            nl.gamma1_mm / li.gamma1_mm,
            nl.gamma2_mm / R2,
            twist
        ));
    }
    out
}

fn default_fine_mm() -> f64 {
    match cases::integration() {
        fem::Integration::Selective => fem::hyper::TABLE_FINE_MM,
        fem::Integration::Full => fem::forward::FINE_MM,
    }
}

fn main() {
    let results = cases::run_all(&cases::selected(), run);
    println!("# large-strain / linear ratios (fem/examples/large_strain_table.rs; docs/physics.md, \"Large strain\")");
    if cases::integration() == fem::Integration::Full {
        println!("# fully integrated elements (INTEGRATION=full): the depth extension of the selective table");
    }
    println!("# gel mesh {} mm at the contact (FINE_MM)", cases::fine_mm(default_fine_mm()));
    println!("e2_over_e1,nu1,nu2,h_over_r2,delta_over_r2,gamma1_ratio,gamma2_over_r2,twist_ratio");
    for rows in results {
        for r in rows {
            println!("{r}");
        }
    }
}
