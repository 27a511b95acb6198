//! How the large-strain reference's press converges with the element size at
//! the contact (docs/physics.md, "Mesh convergence"): gamma1 at even stage
//! positions on several meshes, and the first-order limit from the two
//! coarsest as the large-strain table takes it.
//!
//! `cargo run --release -p fem --example mesh_study -- E1 NU1 E2 NU2 DEPTH_MM [MESH_MM ...]`
//! (gel 5 mm bonded, R2 5 mm; meshes default to 0.06 0.04 0.03).

use fem::Material;
use fem::hyper::{LargeStrainContact, mesh_extrapolated};

fn main() {
    let args: Vec<f64> = std::env::args().skip(1).map(|a| a.parse().expect("numbers")).collect();
    assert!(args.len() >= 5, "usage: mesh_study E1 NU1 E2 NU2 DEPTH_MM [MESH_MM ...]");
    let (gel, ind) = (Material { e_mpa: args[0], nu: args[1] }, Material { e_mpa: args[2], nu: args[3] });
    let stages: Vec<f64> = (1..=8).map(|k| args[4] * k as f64 / 8.0).collect();
    let meshes: Vec<f64> = if args.len() > 5 { args[5..].to_vec() } else { vec![0.06, 0.04, 0.03] };
    let mut columns = Vec::new();
    for &h in &meshes {
        let t = std::time::Instant::now();
        let mut c = LargeStrainContact::for_layer_at(fem::Base::Bonded, 5.0, gel, ind, 5.0, h).expect("mesh");
        let path = c.solve_path(&stages, 0.05).expect("press");
        eprintln!("{h} mm: {:.0?}", t.elapsed());
        columns.push(path.iter().map(|s| s.gamma1_mm * 1e3).collect::<Vec<f64>>());
    }
    print!("stage_mm");
    for h in &meshes {
        print!(",gamma1_um_{h}");
    }
    println!(",limit_from_first_two_um");
    for (i, s) in stages.iter().enumerate() {
        print!("{s:.4}");
        for c in &columns {
            print!(",{:.2}", c[i]);
        }
        println!(",{:.2}", mesh_extrapolated(columns[1][i], columns[0][i], meshes[1], meshes[0]));
    }
}
