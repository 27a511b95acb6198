//! The large-strain reference against the dev recordings at their truth.
use fem::hyper::LargeStrainContact;
use fem::{Material, Mesh};
use sim::recording::Phase;

#[path = "common/mod.rs"]
mod common;

fn main() {
    let fine: f64 = std::env::var("FINE").ok().and_then(|v| v.parse().ok()).unwrap_or(0.06);
    let only = std::env::var("ONLY").unwrap_or_default();
    for common::DevRecording { set, file, rec, e1, nu1 } in common::dev_recordings() {
        if !only.is_empty() && !format!("{set}/{file}").contains(&only) {
            continue;
        }
        let ind = rec.meta.indenter;
        let t = std::time::Instant::now();
        let gel_mesh = fem::forward::gel_mesh_at(5.0, fine).unwrap();
        let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * ind.r_mm).collect();
        let hemi = Mesh::hemisphere(ind.r_mm, &rs, fem::forward::hemisphere_segments(fine)).unwrap();
        let mut c = LargeStrainContact::new(
            gel_mesh,
            Material { e_mpa: e1, nu: nu1 },
            hemi,
            Material { e_mpa: ind.e_mpa, nu: ind.nu },
            ind.r_mm,
        )
        .unwrap();
        let normal: Vec<_> = rec.samples.iter().filter(|s| s.phase == Phase::Normal).collect();
        let stages: Vec<f64> = normal.iter().map(|s| s.stage_mm).collect();
        let path = c.solve_path(&stages, 0.05).unwrap();
        let d: Vec<f64> = normal.iter().zip(&path).map(|(s, st)| (s.gamma1_mm - st.gamma1_mm) * 1e3).collect();
        let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
        println!("{set}/{file}: normal rms {rms:.2} um ({:.1?})", t.elapsed());
        for (s, st) in normal.iter().zip(&path).step_by(5) {
            println!(
                "  stage {:.3} gamma1 rec {:.4} fe {:.4} ({:+.2} um) g2/g1 {:.4} a {:.3} F {:.4}",
                s.stage_mm,
                s.gamma1_mm,
                st.gamma1_mm,
                (s.gamma1_mm - st.gamma1_mm) * 1e3,
                st.gamma2_mm / st.gamma1_mm,
                st.contact_radius_mm,
                st.force_n
            );
        }
        let tors: Vec<_> = rec.samples.iter().filter(|s| s.phase == Phase::Torsion && s.rot_deg > 0.0).collect();
        if let (Some(last), false) = (path.last(), tors.is_empty()) {
            let depth = tors[0].stage_mm;
            let st = c.solve_path(&[depth.max(last.delta_mm)], 0.05).unwrap().remove(0);
            let tw: Vec<f64> = tors.iter().map(|s| s.rot_deg.to_radians()).collect();
            let th = c.theta1_rad(&st, &tw, 0.4).unwrap();
            for (s, t) in tors.iter().zip(&th) {
                println!(
                    "  rot {:.3} theta1 rec {:.4} fe {:.4} ({:+.4})",
                    s.rot_deg,
                    s.theta1_deg,
                    t.to_degrees(),
                    s.theta1_deg - t.to_degrees()
                );
            }
        }
        println!("  total {:.1?}", t.elapsed());
    }
}
