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
    /// Index of the sample in the recording.
    sample: usize,
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
            out.push(Row { torsion, theta: false, unload, x, k, sample: i, j: Vector3::new(d(0), d(1), d(2)) });
        }
        if let Some(sd) = s.theta1_sd_deg.filter(|v| *v > 0.0 && torsion) {
            let d = |k: usize| (shifted[k][i].theta1_deg - base[i].theta1_deg) / steps[k] / sd;
            out.push(Row { torsion, theta: true, unload, x, k, sample: i, j: Vector3::new(d(0), d(1), d(2)) });
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
    // Stop-and-frames designs of the sweeps, with their rig time (see `Plan`).
    println!("designs with rig time (normal load+unload and torsion, moves and frames):");
    println!(
        "{:>5} {:>5} {:>4} {:>4} {:>4} {:>5} {:>4} {:>5} {:>4} {:>4} {:>6} {:>6} {:>6} {:>8} {:>8}",
        "fine",
        "coarse",
        "Fc",
        "Ftop",
        "unl",
        "Fu",
        "tstep",
        "Tmax",
        "Tmin",
        "pow",
        "stops",
        "N s",
        "T s",
        "E1 %",
        "nu1 %"
    );
    for plan in plans(xmax, tmax) {
        let (wf, stops, tn, tt) = plan.weights(&rs, rec.samples.len());
        let (e, n) = half_widths(&rs, nu1, |r| wf[r.sample]);
        println!(
            "{:>5.2} {:>5.2} {:>4} {:>4} {:>4.2} {:>5} {:>4.1} {:>5} {:>4} {:>4.1} {:>6} {:>6.1} {:>6.1} {:>8.4} {:>8.4}",
            plan.fine_to_mm,
            plan.coarse_mm,
            plan.f_coarse,
            plan.f_top,
            plan.unload_mm,
            plan.f_unload,
            plan.twist_step_deg,
            plan.f_twist_max,
            plan.f_twist_min,
            plan.twist_pow,
            stops,
            tn,
            tt,
            e,
            n
        );
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

/// A sweep design as stops and frames, evaluated on a step-by-step recording
/// (0.05 mm, 0.2 deg, 4 frames a sample): each stop takes the recorded sample
/// nearest to it in its branch, weighted by its frames over 4.
#[derive(Debug, Clone, Copy)]
struct Plan {
    /// Loading in 0.05 mm steps from 0.15 mm before contact up to this approach, mm (4 frames).
    fine_to_mm: f64,
    /// Then 0.1 mm steps up to 1.05 mm (the paper's window), 4 frames; then this step to the top.
    coarse_mm: f64,
    f_coarse: usize,
    /// Frames at the top of the loading branch (where the torsion sweep starts).
    f_top: usize,
    /// Unloading step from the top back to 0.15 mm before contact, and its frames.
    unload_mm: f64,
    f_unload: usize,
    twist_step_deg: f64,
    /// Torsion frames at a twist x: max(min, max * (x / amplitude)^pow).
    f_twist_max: usize,
    f_twist_min: usize,
    twist_pow: f64,
}

/// Rig time of a stage move of `d` mm (2.3 mm/s, 4 mm/s^2) or a mount move (10 deg/s, 20 deg/s^2).
fn move_s(d: f64, v: f64, a: f64) -> f64 {
    let d = d.abs();
    if d < v * v / a { 2.0 * (d / a).sqrt() } else { d / v + v / a }
}

/// Rig time of a sample averaging `f` frames: the settling reads two more (30 frames/s).
fn frames_s(f: usize) -> f64 {
    (f.max(4) + 2) as f64 / 30.0
}

impl Plan {
    /// Frames weight per recorded sample, the number of stops, and the rig
    /// time of the normal and the torsion sweeps.
    fn weights(&self, rs: &[Row], n_samples: usize) -> (Vec<f64>, usize, f64, f64) {
        let mut w = vec![0.0; n_samples];
        let nearest = |torsion: bool, unload: bool, x: f64| {
            rs.iter()
                .filter(|r| r.torsion == torsion && !r.theta && (r.unload == unload || (torsion && x == 0.0)))
                .min_by(|a, b| (a.x - x).abs().total_cmp(&(b.x - x).abs()))
                .map(|r| r.sample)
        };
        let top = rs.iter().filter(|r| !r.torsion).map(|r| r.x).fold(f64::MIN, f64::max);
        let mut load = vec![];
        let mut x = -0.15;
        while x < top - 1e-9 {
            load.push(x);
            x += if x < self.fine_to_mm - 1e-9 {
                0.05
            } else if x < 1.05 - 1e-9 {
                0.1
            } else {
                self.coarse_mm
            };
        }
        load.push(top);
        let mut unload = vec![];
        let mut x = top - self.unload_mm;
        while x > -0.15 + 1e-9 {
            unload.push(x);
            x -= self.unload_mm;
        }
        unload.push(-0.15);
        let (mut tn, mut tt, mut stops) = (0.0, 0.0, 0);
        let mut prev = -0.15 - 0.05;
        for (i, &x) in load.iter().enumerate() {
            let f = if i + 1 == load.len() {
                self.f_top
            } else if x < 1.05 - 1e-9 {
                4
            } else {
                self.f_coarse
            };
            tn += move_s(x - prev, 2.3, 4.0) + frames_s(f);
            prev = x;
            if let Some(s) = nearest(false, false, x) {
                w[s] += f as f64 / 4.0;
            }
            stops += 1;
        }
        for &x in &unload {
            tn += move_s(x - prev, 2.3, 4.0) + frames_s(self.f_unload);
            prev = x;
            if let Some(s) = nearest(false, true, x) {
                w[s] += self.f_unload as f64 / 4.0;
            }
            stops += 1;
        }
        let amp = rs.iter().filter(|r| r.torsion).map(|r| r.x).fold(0.0, f64::max);
        let n = (amp / self.twist_step_deg).round().max(1.0) as usize;
        let step = amp / n as f64;
        let mut prev = 0.0;
        for (i, k) in (0..=n).chain((0..n).rev()).enumerate() {
            let x = k as f64 * step;
            let f = ((self.f_twist_max as f64 * (x / amp).powf(self.twist_pow)).round() as usize).max(self.f_twist_min);
            tt += move_s(x - prev, 10.0, 20.0) + frames_s(f);
            prev = x;
            if let Some(s) = nearest(true, i > n, x) {
                w[s] += f as f64 / 4.0;
            }
            stops += 1;
        }
        (w, stops, tn, tt)
    }
}

fn plans(_xmax: f64, _tmax: f64) -> Vec<Plan> {
    let mut out = vec![
        // The default as recorded, for the time model's check.
        Plan {
            fine_to_mm: 10.0,
            coarse_mm: 0.05,
            f_coarse: 4,
            f_top: 4,
            unload_mm: 0.05,
            f_unload: 4,
            twist_step_deg: 0.2,
            f_twist_max: 4,
            f_twist_min: 4,
            twist_pow: 0.0,
        },
    ];
    let env = |k: &str, d: &str| std::env::var(k).unwrap_or_else(|_| d.to_string());
    let list = |k: &str, d: &str| -> Vec<f64> { env(k, d).split(',').filter_map(|v| v.parse().ok()).collect() };
    for fine in list("DI_FINE", "0.65") {
        for coarse in list("DI_COARSE", "0.5,1.0") {
            for fc in list("DI_FC", "8,16") {
                for ftop in list("DI_FTOP", "8,60") {
                    for unl in list("DI_UNL", "0.5,1.0") {
                        for fu in list("DI_FU", "8,16") {
                            for ts in list("DI_TSTEP", "1.0") {
                                for tmax in list("DI_TMAX", "40,80") {
                                    for pw in list("DI_POW", "2") {
                                        out.push(Plan {
                                            fine_to_mm: fine,
                                            coarse_mm: coarse,
                                            f_coarse: fc as usize,
                                            f_top: ftop as usize,
                                            unload_mm: unl,
                                            f_unload: fu as usize,
                                            twist_step_deg: ts,
                                            f_twist_max: tmax as usize,
                                            f_twist_min: 4,
                                            twist_pow: pw,
                                        });
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    out
}
