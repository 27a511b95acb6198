//! Our FE against the finite-element dev recordings, at their truth (small strain, frictionless).
use fem::{Body, Material, Mesh, TwoBodyContact};
use sim::recording::Phase;

#[path = "common/mod.rs"]
mod common;

fn main() {
    for common::DevRecording { set, file, rec, e1, nu1 } in common::dev_recordings() {
        let ind = rec.meta.indenter;
        let t = std::time::Instant::now();
        let gel_mesh = Mesh::gel(15.0, 5.0, 0.05, 5.5, 1.5).unwrap();
        let rs: Vec<f64> = gel_mesh.surface_radii().into_iter().filter(|&r| r < 0.97 * ind.r_mm).collect();
        let gel = Body::new(gel_mesh, Material { e_mpa: e1, nu: nu1 }).unwrap();
        let hemi =
            Body::new(Mesh::hemisphere(ind.r_mm, &rs, 40).unwrap(), Material { e_mpa: ind.e_mpa, nu: ind.nu }).unwrap();
        let c = TwoBodyContact::new(&gel, Some(&hemi), ind.r_mm).unwrap();
        let setup = t.elapsed();
        let mut res = vec![];
        for s in rec.samples.iter().filter(|s| s.phase == Phase::Normal && s.stage_mm > 0.0) {
            let st = c.solve(s.stage_mm).unwrap();
            res.push((s.stage_mm, (s.gamma1_mm - st.gamma1_mm) * 1e3, st.contact_radius_mm[0]));
        }
        let n = res.len();
        let rms = (res.iter().map(|r| r.1 * r.1).sum::<f64>() / n as f64).sqrt();
        println!(
            "{set}/{:32} setup {setup:.2?}: resid um q1 {:+.1} mid {:+.1} last {:+.1} (stage {:.3}, a {:.2}) rms {rms:.1}",
            file,
            res[n / 4].1,
            res[n / 2].1,
            res[n - 1].1,
            res[n - 1].0,
            res[n - 1].2
        );
    }
}
