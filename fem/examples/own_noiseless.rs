//! A noiseless recording of the project's own large-strain reference,
//! extrapolated to zero element size as the large-strain table is
//! (`fem::hyper::mesh_extrapolated`; docs/physics.md, "Mesh convergence"):
//! the calibration sweep on the table's fine mesh, the same stage positions
//! on the coarse one, gamma1 extrapolated from the two; the twists are the
//! fine mesh's (the table's twist ratios are not extrapolated either).
//!
//! `cargo run --release -p fem --example own_noiseless -- E1 NU1 E2 NU2 > rec.csv`
//! (gel 5 mm bonded, or sliding on its window with `BASE=sliding`, R2 5 mm,
//! Coulomb mu 0.4 in the twist, to beta 0.2 or `BETA`; the files in
//! tests/data/fe-self/ marked noiseless).

use fem::hyper::{LargeStrainContact, SweepPlan, TABLE_COARSE_MM, TABLE_FINE_MM, calibration_sweep, mesh_extrapolated};
use fem::{Base, Material};

const H: f64 = 5.0;
const R2: f64 = 5.0;
const MU: f64 = 0.4;

fn main() {
    let args: Vec<f64> = std::env::args().skip(1).map(|a| a.parse().expect("four numbers: E1 nu1 E2 nu2")).collect();
    let [e1, nu1, e2, nu2] = args[..] else {
        panic!("usage: own_noiseless E1 NU1 E2 NU2");
    };
    let (gel, ind) = (Material { e_mpa: e1, nu: nu1 }, Material { e_mpa: e2, nu: nu2 });
    let (base, base_name) = match std::env::var("BASE").as_deref() {
        Ok("sliding") => (Base::Sliding, "sliding"),
        _ => (Base::Bonded, "bonded"),
    };
    let at = |fine_mm: f64| LargeStrainContact::for_layer_at(base, H, gel, ind, R2, fine_mm);
    let beta = std::env::var("BETA").ok().and_then(|b| b.parse().ok()).unwrap_or(0.2);
    let plan = SweepPlan { beta, normal_steps: 30, twists_deg: (0..=10).map(f64::from).collect(), friction: MU };
    let t = std::time::Instant::now();
    let fine = calibration_sweep(|| at(TABLE_FINE_MM), R2, &plan).expect("the fine sweep");
    let stages: Vec<f64> = fine.normal.iter().map(|s| s.delta_mm).collect();
    let mut coarse = at(TABLE_COARSE_MM).expect("the coarse mesh");
    let coarse_path = coarse.solve_path(&stages, 0.05).expect("the coarse press at the same stages");
    eprintln!("beta {:.3}, {:.0?}", fine.beta_reached, t.elapsed());
    println!("# easycalib-recording: 1");
    println!("# sensor: sim-fe");
    println!(
        "# source: easycalib large-strain FE reference (neo-Hookean, frictionless pressing, twist with Coulomb mu \
         {MU}); E1 {e1} MPa, nu1 {nu1}, E2 {e2} MPa, nu2 {nu2}, noiseless; gamma1 extrapolated to zero element \
         size from {TABLE_COARSE_MM} and {TABLE_FINE_MM} mm meshes, twists on {TABLE_FINE_MM} mm \
         (fem/examples/own_noiseless.rs, 30 steps to beta {beta}, reached {:.3}, twists 0-10 deg)",
        fine.beta_reached
    );
    println!("# indenter_E_MPa: {e2}");
    println!("# indenter_nu: {nu2}");
    println!("# indenter_R_mm: {R2}");
    println!("# elastomer_R_mm: inf");
    println!("# elastomer_thickness_mm: {H}");
    println!("# elastomer_base: {base_name}");
    println!("t_s,phase,stage_mm,rot_deg,gamma1_mm,theta1_deg,rep,dir");
    let mut t_s = 0.0;
    let mut g_last = 0.0;
    for (f, c) in fine.normal.iter().zip(&coarse_path) {
        let g = if f.delta_mm > 0.0 {
            mesh_extrapolated(f.gamma1_mm, c.gamma1_mm, TABLE_FINE_MM, TABLE_COARSE_MM)
        } else {
            0.0
        };
        println!("{t_s:.3},normal,{:.4},0.000,{g:.5},0.00000,,", f.delta_mm);
        t_s += 0.8;
        g_last = g;
    }
    let depth = stages.last().copied().unwrap_or(0.0);
    for &(rot, theta) in &fine.torsion_deg {
        let th = if rot > 0.0 { theta } else { 0.0 };
        println!("{t_s:.3},torsion,{depth:.4},{rot:.3},{g_last:.5},{th:.5},,");
        t_s += 0.8;
    }
}
