//! How far the dev set's noise alone lets a fit stray (docs/physics.md,
//! "Finite-element reference"): for each linear recording of
//! `tests/data/fem-dev`, our own layer model at the recording's truth
//! (friction 0.4, the same stage and twist schedule) plus the dev set's stated
//! noise (gamma1 2 µm, theta1 0.02°, Gaussian), fitted as `easycalib fit`
//! would. The spread of those recoveries is what noise does to a fit whose
//! model is exact; the dev recording's own recovery is printed beside it.
//!
//! `cargo run --release --example dev_noise_study -- [--seeds N]` (about a
//! minute per recording and ten seeds).

use easycalib::fit::{FitOptions, calibrate};
use fem::forward::Forward;
use sim::recording::{Phase, Recording};

const GAMMA1_NOISE_MM: f64 = 0.002;
const THETA1_NOISE_DEG: f64 = 0.02;
const FRICTION: f64 = 0.4;

/// Standard normal draws from a fixed seed (splitmix64 and Box–Muller).
struct Gauss(u64);

impl Gauss {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn draw(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len().max(2) - 1) as f64).sqrt())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = args.iter().position(|a| a == "--seeds").and_then(|i| args.get(i + 1)?.parse().ok()).unwrap_or(10);
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev/linear");
    let truth = std::fs::read_to_string(dir.join("truth.csv"))?;
    println!(
        "recording                        | dev: E1 %  nu1 % | own model + noise ({seeds} seeds): E1 mean ± sd %, nu1 mean ± sd %"
    );
    for line in truth.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let (e1, nu1): (f64, f64) = (f[1].parse()?, f[2].parse()?);
        let rec = Recording::read_path(&dir.join(f[0]))?;
        let dev = calibrate(&rec, &FitOptions::default())?;
        let ind = rec.meta.indenter;
        let thickness = rec.meta.layer.ok_or("the dev recording declares its layer")?.thickness_mm;
        let model = Forward::cached(thickness, ind.e_mpa, ind.nu, ind.r_mm)?.model(e1, nu1);
        let stages: Vec<f64> = rec.samples.iter().map(|s| s.stage_mm).collect();
        let deepest = stages.iter().copied().fold(0.0, f64::max);
        let states = model.normal_path(&stages, FRICTION, deepest / 60.0)?;
        let (mut de, mut dn) = (Vec::new(), Vec::new());
        for seed in 0..seeds {
            let mut noise = Gauss(seed + 1);
            let mut own = rec.clone();
            for (s, st) in own.samples.iter_mut().zip(&states) {
                s.gamma1_mm = if st.gamma1_mm > 0.0 { st.gamma1_mm + GAMMA1_NOISE_MM * noise.draw() } else { 0.0 };
                s.theta1_deg = match s.phase {
                    Phase::Torsion => {
                        let twist = s.rot_deg.to_radians();
                        let t = model.theta1_rad(st, twist.abs(), FRICTION).map_or(0.0, |t| t.to_degrees());
                        t * twist.signum() + THETA1_NOISE_DEG * noise.draw()
                    }
                    Phase::Normal => 0.0,
                };
            }
            let cal = calibrate(&own, &FitOptions::default())?;
            de.push((cal.full.e1_mpa / e1 - 1.0) * 100.0);
            dn.push((cal.full.nu1 / nu1 - 1.0) * 100.0);
        }
        let ((me, se), (mn, sn)) = (mean_sd(&de), mean_sd(&dn));
        println!(
            "{:32} | {:+6.2} {:+6.2} | E1 {me:+5.2} ± {se:4.2}  nu1 {mn:+5.2} ± {sn:4.2}  (worst E1 {:+.2}, nu1 {:+.2})",
            f[0],
            (dev.full.e1_mpa / e1 - 1.0) * 100.0,
            (dev.full.nu1 / nu1 - 1.0) * 100.0,
            de.iter().copied().fold(0.0, |a: f64, b| if b.abs() > a.abs() { b } else { a }),
            dn.iter().copied().fold(0.0, |a: f64, b| if b.abs() > a.abs() { b } else { a }),
        );
    }
    Ok(())
}
