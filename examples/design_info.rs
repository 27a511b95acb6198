//! Where a recording's information on (E1, nu1) comes from: the full fit's
//! Jacobian per sample (forward differences of `fit::predict` at the fitted
//! parameters, each row divided by the sample's standard error), summed into
//! Fisher information by group, and the 95 % half-widths other designs would
//! give (subsets of the rows, each weighted by the frames it would average).
//!
//! ```sh
//! cargo run --release --example design_info -- RECORDING.csv
//! ```

use easycalib::fit::{FitOptions, ModelParams, calibrate, predict};
use nalgebra::{Matrix3, Vector3};
use sim::recording::{Direction, Phase, Recording};

/// One observation: its Jacobian row (d/d ln E1, d/d nu1, d/d z0) over its sd.
struct Row {
    torsion: bool,
    theta: bool,
    unload: bool,
    /// Stage above contact (normal), or twist from the torsion start (torsion).
    x: f64,
    /// Index of the sample within its phase.
    k: usize,
    j: Vector3<f64>,
}

fn rows(rec: &Recording, p: &ModelParams) -> Result<Vec<Row>, String> {
    let base = predict(rec, p).map_err(|e| e.to_string())?;
    let steps = [1e-4, 1e-4, 1e-5];
    let mut shifted = Vec::new();
    for (k, h) in steps.iter().enumerate() {
        let mut q = *p;
        match k {
            0 => q.e1_mpa *= 1.0 + h,
            1 => q.nu1 += h,
            _ => q.contact_offset_mm += h,
        }
        shifted.push(predict(rec, &q).map_err(|e| e.to_string())?);
    }
    let twist0 = rec.phase(Phase::Torsion).next().map_or(0.0, |s| s.rot_deg);
    let mut out = Vec::new();
    let first_torsion = rec.samples.iter().position(|s| s.phase == Phase::Torsion).unwrap_or(0);
    for (i, s) in rec.samples.iter().enumerate() {
        let torsion = s.phase == Phase::Torsion;
        let k = if torsion { i - first_torsion } else { i };
        let unload = s.dir == Some(Direction::Unload);
        let x = if torsion { s.rot_deg - twist0 } else { s.stage_mm - p.contact_offset_mm };
        if let Some(sd) = s.gamma1_sd_mm.filter(|v| *v > 0.0) {
            let d = |k: usize| (shifted[k][i].gamma1_mm - base[i].gamma1_mm) / steps[k] / sd;
            out.push(Row { torsion, theta: false, unload, x, k, j: Vector3::new(d(0), d(1), d(2)) });
        }
        if let Some(sd) = s.theta1_sd_deg.filter(|v| *v > 0.0 && torsion) {
            let d = |k: usize| (shifted[k][i].theta1_deg - base[i].theta1_deg) / steps[k] / sd;
            out.push(Row { torsion, theta: true, unload, x, k, j: Vector3::new(d(0), d(1), d(2)) });
        }
    }
    Ok(out)
}

/// A named design: the frames weight of each row relative to the recording.
type Design = (&'static str, Box<dyn Fn(&Row) -> f64>);

/// 95 % half-widths, % of E1 and of nu1, from rows weighted by `w`.
fn half_widths(rows: &[Row], nu1: f64, w: impl Fn(&Row) -> f64) -> (f64, f64) {
    let mut f = Matrix3::zeros();
    for r in rows {
        f += w(r) * r.j * r.j.transpose();
    }
    match f.try_inverse() {
        Some(c) => (196.0 * c[(0, 0)].sqrt(), 196.0 * c[(1, 1)].sqrt() / nu1),
        None => (f64::NAN, f64::NAN),
    }
}

fn main() {
    let Some(path) = std::env::args().nth(1) else {
        eprintln!("usage: design_info RECORDING.csv");
        std::process::exit(2);
    };
    let rec = match Recording::read_path(std::path::Path::new(&path)) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("design_info: {path}: {e}");
            std::process::exit(1);
        }
    };
    let cal = match calibrate(&rec, &FitOptions::default()) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("design_info: fit: {e}");
            std::process::exit(1);
        }
    };
    let p = cal.full.params();
    let rs = match rows(&rec, &p) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("design_info: {e}");
            std::process::exit(1);
        }
    };
    let nu1 = p.nu1;
    let w = 100.0 * (cal.full.ci95.e1_mpa[1] - cal.full.ci95.e1_mpa[0]) / 2.0 / p.e1_mpa;
    let wn = 100.0 * (cal.full.ci95.nu1[1] - cal.full.ci95.nu1[0]) / 2.0 / p.nu1;
    println!("fit's own 95% half-widths: E1 {w:.4} %, nu1 {wn:.4} %  (chi2/dof {:?})", cal.full.chi2_dof);
    let xmax = rs.iter().filter(|r| !r.torsion).map(|r| r.x).fold(0.0, f64::max);
    let tmax = rs.iter().filter(|r| r.torsion).map(|r| r.x.abs()).fold(0.0, f64::max);
    println!("normal depth up to {xmax:.3} mm, twist up to {tmax:.2} deg");
    let designs: Vec<Design> = vec![
        ("all, as recorded", Box::new(|_| 1.0)),
        ("normal only", Box::new(|r| if r.torsion { 0.0 } else { 1.0 })),
        ("torsion only", Box::new(|r| if r.torsion { 1.0 } else { 0.0 })),
        ("torsion theta1 only + normal", Box::new(|r| if r.torsion && !r.theta { 0.0 } else { 1.0 })),
        ("normal load only", Box::new(|r| if !r.torsion && r.unload { 0.0 } else { 1.0 })),
        ("normal x2 frames", Box::new(|r| if r.torsion { 1.0 } else { 2.0 })),
        ("torsion x2 frames", Box::new(|r| if r.torsion { 2.0 } else { 1.0 })),
        (
            "normal deeper half x2, shallow half x0",
            Box::new(move |r| {
                if r.torsion {
                    1.0
                } else if r.x > xmax / 2.0 {
                    2.0
                } else {
                    0.0
                }
            }),
        ),
        (
            "torsion |twist| > half x2, rest x0",
            Box::new(move |r| {
                if !r.torsion {
                    1.0
                } else if r.x.abs() > tmax / 2.0 {
                    2.0
                } else {
                    0.0
                }
            }),
        ),
        (
            "normal every 3rd x3",
            Box::new(|r| {
                if r.torsion {
                    1.0
                } else if r.k % 3 == 0 {
                    3.0
                } else {
                    0.0
                }
            }),
        ),
        (
            "normal every 4th x2",
            Box::new(|r| {
                if r.torsion {
                    1.0
                } else if r.k % 4 == 0 {
                    2.0
                } else {
                    0.0
                }
            }),
        ),
        ("normal every 4th x1", Box::new(|r| if r.torsion || r.k % 4 == 0 { 1.0 } else { 0.0 })),
        (
            "torsion every 5th x5",
            Box::new(|r| {
                if !r.torsion {
                    1.0
                } else if r.k % 5 == 0 {
                    5.0
                } else {
                    0.0
                }
            }),
        ),
        (
            "torsion every 5th x3",
            Box::new(|r| {
                if !r.torsion {
                    1.0
                } else if r.k % 5 == 0 {
                    3.0
                } else {
                    0.0
                }
            }),
        ),
        (
            "N every 4th x2, T every 5th x5",
            Box::new(|r| {
                if r.torsion {
                    if r.k % 5 == 0 { 5.0 } else { 0.0 }
                } else if r.k % 4 == 0 {
                    2.0
                } else {
                    0.0
                }
            }),
        ),
        (
            "N every 4th x1, T every 5th x4",
            Box::new(|r| {
                if r.torsion {
                    if r.k % 5 == 0 { 4.0 } else { 0.0 }
                } else if r.k % 4 == 0 {
                    1.0
                } else {
                    0.0
                }
            }),
        ),
    ];
    println!("{:45} {:>9} {:>9}", "design (weights = frames relative to now)", "E1 %", "nu1 %");
    for (name, wf) in &designs {
        let (e, n) = half_widths(&rs, nu1, wf);
        println!("{name:45} {e:9.4} {n:9.4}");
    }
    // A grid: every k-th normal sample at a frames multiple, torsion at another
    // (all of it, or only its outer half of twist), with the frames it takes
    // (4 a sample as recorded).
    println!(
        "{:>3} {:>4} {:>4} {:>6} {:>7} {:>7} {:>9} {:>9}",
        "k", "N x", "T x", "outer", "N fr", "T fr", "E1 %", "nu1 %"
    );
    for k in [1usize, 2, 4, 6] {
        for nx in [1.0, 2.0, 3.0] {
            for tx in [1.0, 2.0, 3.0] {
                for outer in [false, true] {
                    let wf = |r: &Row| {
                        if r.torsion {
                            if outer && r.x.abs() <= tmax / 2.0 { 0.0 } else { tx }
                        } else if r.k % k == 0 {
                            nx
                        } else {
                            0.0
                        }
                    };
                    let frames = |t: bool| 4.0 * rs.iter().filter(|r| r.torsion == t && !r.theta).map(&wf).sum::<f64>();
                    let (e, n) = half_widths(&rs, nu1, wf);
                    println!(
                        "{k:>3} {nx:>4} {tx:>4} {outer:>6} {:>7.0} {:>7.0} {e:>9.4} {n:>9.4}",
                        frames(false),
                        frames(true)
                    );
                }
            }
        }
    }
    // Information on E1 and nu1 by normal depth and twist, in tenths of the range.
    println!("share of Fisher information (diagonal) by tenth of the range:");
    println!("{:>6} {:>10} {:>10} {:>10} {:>10}", "tenth", "N: E1", "N: nu1", "T: E1", "T: nu1");
    let total = |f: &dyn Fn(&Row) -> bool, k: usize| rs.iter().filter(|r| f(r)).map(|r| r.j[k] * r.j[k]).sum::<f64>();
    let all = [total(&|_| true, 0), total(&|_| true, 1)];
    for b in 0..10 {
        let inb = |r: &Row, max: f64| ((r.x.abs() / max * 10.0).floor() as usize).min(9) == b;
        let n = |k: usize| 100.0 * total(&|r| !r.torsion && inb(r, xmax), k) / all[k];
        let t = |k: usize| 100.0 * total(&|r| r.torsion && inb(r, tmax), k) / all[k];
        println!("{b:>6} {:>10.2} {:>10.2} {:>10.2} {:>10.2}", n(0), n(1), t(0), t(1));
    }
}
