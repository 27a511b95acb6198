//! The tabulated forward model against the dev recordings at their truth.
use fem::forward::Forward;
use sim::recording::Phase;

#[path = "common/mod.rs"]
mod common;

fn main() {
    for common::DevRecording { set, file, rec, e1, nu1 } in common::dev_recordings() {
        let ind = rec.meta.indenter;
        let t = std::time::Instant::now();
        let fw = Forward::new(5.0, ind.e_mpa, ind.nu, ind.r_mm).unwrap();
        let setup = t.elapsed();
        let t = std::time::Instant::now();
        let m = fw.model(e1, nu1);
        let stages: Vec<f64> = rec.samples.iter().map(|s| s.stage_mm).collect();
        let dmax = stages.iter().cloned().fold(0.0, f64::max);
        let coarse = m.normal_path(&stages, 0.4, dmax / 30.0).unwrap();
        let fine = m.normal_path(&stages, 0.4, dmax / 120.0).unwrap();
        let moved = coarse.iter().zip(&fine).map(|(a, b)| (a.gamma1_mm - b.gamma1_mm).abs()).fold(0.0, f64::max);
        println!("    load steps 30 -> 120: gamma1 moves at most {:.3} um", moved * 1e3);
        for mu in [0.0, 0.4, f64::INFINITY] {
            let path = m.normal_path(&stages, mu, dmax / 60.0).unwrap();
            let d: Vec<f64> = rec
                .samples
                .iter()
                .zip(&path)
                .filter(|(s, _)| s.phase == Phase::Normal)
                .map(|(s, st)| (s.gamma1_mm - st.gamma1_mm) * 1e3)
                .collect();
            let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
            println!("    path mu {mu}: normal rms {rms:.2} um last {:+.2} um", d[d.len() - 1]);
        }
        let mut rn = vec![];
        let mut rt = vec![];
        for s in &rec.samples {
            let st = m.normal(s.stage_mm).unwrap();
            match s.phase {
                Phase::Normal => rn.push((s.gamma1_mm - st.gamma1_mm) * 1e3),
                Phase::Torsion => {
                    if s.rot_deg > 0.0 {
                        let th = m.theta1_rad(&st, s.rot_deg.to_radians(), 0.4).unwrap().to_degrees();
                        rt.push(s.theta1_deg - th);
                    }
                }
            }
        }
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        println!(
            "{set}/{:32} setup {setup:.2?} eval {:.2?}: normal rms {:.1} um last {:+.1} | torsion rms {:.4} deg last {:+.4} (mu 0.4)",
            file,
            t.elapsed(),
            rms(&rn),
            rn[rn.len() - 1],
            rms(&rt),
            rt[rt.len() - 1]
        );
    }
}
