//! Our FE's torsion (full stick) against the dev recordings at their truth.
use fem::torsion::{TorsionBody, stick_ratio};
use fem::{Body, Material, Mesh, TwoBodyContact};
use sim::recording::Phase;

#[path = "common/mod.rs"]
mod common;

fn main() {
    for common::DevRecording { set, file, rec, e1, nu1 } in common::dev_recordings() {
        let ind = rec.meta.indenter;
        let gel_mesh = Mesh::gel(15.0, 5.0, 0.05, 5.5, 1.5).unwrap();
        let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * ind.r_mm).collect();
        let hemi_mesh = Mesh::hemisphere(ind.r_mm, &rs, 40).unwrap();
        let tg = TorsionBody::new(&gel_mesh).unwrap();
        let ti = TorsionBody::new(&hemi_mesh).unwrap();
        let (g1, g2) = (e1 / (2.0 * (1.0 + nu1)), ind.e_mpa / (2.0 * (1.0 + ind.nu)));
        let n = rs.len();
        let cg: Vec<Vec<f64>> = tg
            .surface_compliance(&gel_mesh.surface[..n])
            .into_iter()
            .map(|c| c.iter().map(|v| v / g1).collect())
            .collect();
        let ci: Vec<Vec<f64>> =
            ti.surface_compliance(&hemi_mesh.surface).into_iter().map(|c| c.iter().map(|v| v / g2).collect()).collect();
        let gel = Body::new(gel_mesh, Material { e_mpa: e1, nu: nu1 }).unwrap();
        let hemi = Body::new(hemi_mesh, Material { e_mpa: ind.e_mpa, nu: ind.nu }).unwrap();
        let c = TwoBodyContact::new(&gel, Some(&hemi), ind.r_mm).unwrap();
        let tors: Vec<_> = rec.samples.iter().filter(|s| s.phase == Phase::Torsion).collect();
        let stage = tors[0].stage_mm;
        let st = c.solve(stage).unwrap();
        let last = rs.iter().rposition(|&r| r <= st.contact_radius_mm[0]).unwrap();
        let ratio = stick_ratio(&cg, &ci, &rs, last).unwrap();
        let slope = |k: usize| {
            let v: Vec<_> = tors.iter().filter(|s| s.rot_deg > 0.0).take(k).collect();
            v.iter().map(|s| s.rot_deg * s.theta1_deg).sum::<f64>()
                / v.iter().map(|s| s.rot_deg * s.rot_deg).sum::<f64>()
        };
        let maxrot = tors.iter().map(|s| s.rot_deg).fold(0.0, f64::max);
        println!(
            "{set}/{:32} a {:.2}: FE stick theta1/rot {:.4} | data slope first3 {:.4} all {:.4} (max rot {maxrot:.2}) | data/FE {:.4} {:.4}",
            file,
            st.contact_radius_mm[0],
            ratio,
            slope(3),
            slope(100),
            slope(3) / ratio,
            slope(100) / ratio
        );
    }
}
