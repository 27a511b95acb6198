//! How far the dev set's noise alone lets a fit stray (docs/physics.md,
//! "Finite-element reference"): for each linear recording of
//! `tests/data/fem-dev`, our own layer model at the recording's truth
//! (friction 0.4, the same stage and twist schedule) plus the dev set's stated
//! noise (gamma1 2 µm, theta1 0.02°, Gaussian), fitted as `easycalib fit`
//! would. The spread of those recoveries is what noise does to a fit whose
//! model is exact; the dev recording's own recovery is printed beside it.
//!
//! Each fit is printed twice: the estimate `easycalib fit` reports (the
//! least-squares optimum) and that estimate less the fit's `curvature_bias`
//! (Box's second-order bias, which the fit reports but does not remove;
//! docs/physics.md, "The estimator's bias"). The same draws are scaled by each `--scales` factor
//! (common random numbers). Each recording gets its own draws: the dev
//! recordings share one stage and twist schedule, so shared draws
//! (`--shared-draws`, as the first version of this study did, with
//! `--original-draws` its order of draws) move all their errors together and
//! make one unlucky sample look like a bias of the method. `--antithetic`
//! fits every draw z and its mirror -z and keeps the pair's mean: the odd
//! orders of the noise cancel in it, so what is left is the estimator's bias,
//! measured to a fraction of itself with a few pairs (the plain mean needs
//! hundreds of draws to see a bias well below the spread).
//!
//! `cargo run --release --example dev_noise_study -- [--seeds N] [--first-seed S]
//! [--scales 0.5,1,2] [--only NAME_PART] [--fixed-sigma] [--antithetic]
//! [--shared-draws] [--original-draws] [--verbose] [--linear-only]` (about a second per fit on the
//! loaded 2-core machine). `--fixed-sigma` weighs the fit by the noise the
//! draws were made with instead of the noise floor the fit estimates from its
//! residuals (and `--scales 0` with it fits the noiseless recordings: what the
//! fit's own iterations leave). `--linear-only` fits the linear layer model
//! alone (one start near the truth) instead of choosing between the strain
//! models as `easycalib fit` does.

use easycalib::fit::{FitOptions, ModelParams, calibrate, fit_full};
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

/// Mean and its standard error.
fn mean_se(v: &[f64]) -> (f64, f64) {
    let (m, sd) = mean_sd(v);
    (m, sd / (v.len() as f64).sqrt())
}

/// One scale's recoveries, in percent of the truth.
#[derive(Default)]
struct Tally {
    raw_e: Vec<f64>,
    raw_n: Vec<f64>,
    e: Vec<f64>,
    n: Vec<f64>,
    other_model: usize,
    warned: usize,
    codes: std::collections::BTreeMap<&'static str, usize>,
}

impl Tally {
    fn line(&self) -> String {
        let f = |v: &[f64]| {
            let (m, se) = mean_se(v);
            format!("{m:+5.2} ± {se:4.2}")
        };
        format!(
            "E1 {} (less Box's bias {}, sd {:.2})  nu1 {} (less Box's {}, sd {:.2})  [{} entries{}{}]",
            f(&self.raw_e),
            f(&self.e),
            mean_sd(&self.raw_e).1,
            f(&self.raw_n),
            f(&self.n),
            mean_sd(&self.raw_n).1,
            self.e.len(),
            if self.other_model > 0 { format!(", {} large-strain", self.other_model) } else { String::new() },
            if self.warned > 0 { format!(", warnings {:?}", self.codes) } else { String::new() },
        )
    }
}

fn arg<'a>(args: &'a [String], name: &str) -> Option<&'a str> {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).map(String::as_str)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let seeds: u64 = arg(&args, "--seeds").map(str::parse).transpose()?.unwrap_or(10);
    let first_seed: u64 = arg(&args, "--first-seed").map(str::parse).transpose()?.unwrap_or(1);
    let scales: Vec<f64> =
        arg(&args, "--scales").unwrap_or("1").split(',').map(str::parse).collect::<Result<_, _>>()?;
    let only = arg(&args, "--only");
    let fixed_sigma = args.iter().any(|a| a == "--fixed-sigma");
    let antithetic = args.iter().any(|a| a == "--antithetic");
    let shared = args.iter().any(|a| a == "--shared-draws");
    let original_draws = args.iter().any(|a| a == "--original-draws");
    let verbose = args.iter().any(|a| a == "--verbose");
    let linear_only = args.iter().any(|a| a == "--linear-only");
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fem-dev/linear");
    let truth = std::fs::read_to_string(dir.join("truth.csv"))?;
    println!(
        "own model + the dev set's noise x scale, seeds {first_seed}..{}{}{}{}, weights {}; mean ± its standard error, %",
        first_seed + seeds - 1,
        if shared { " shared by the recordings" } else { "" },
        if original_draws { " (the first version's draws)" } else { "" },
        if antithetic { ", antithetic pairs (each entry the mean of +z and -z)" } else { "" },
        if fixed_sigma { "fixed at the drawn noise" } else { "as easycalib fit (noise floors)" }
    );
    let mut pooled: Vec<Tally> = scales.iter().map(|_| Tally::default()).collect();
    for (index, line) in truth.lines().skip(1).enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        if only.is_some_and(|o| !f[0].contains(o)) {
            continue;
        }
        let (e1, nu1): (f64, f64) = (f[1].parse()?, f[2].parse()?);
        let rec = Recording::read_path(&dir.join(f[0]))?;
        let dev = calibrate(&rec, &FitOptions::default())?;
        let ind = rec.meta.indenter;
        let thickness = rec.meta.layer.ok_or("the dev recording declares its layer")?.thickness_mm;
        let forward = Forward::cached(thickness, ind.e_mpa, ind.nu, ind.r_mm)?;
        let model = forward.model(e1, nu1);
        // What taking the mesh to zero element size adds to gamma1, as the
        // fit's law (and the simulated rig's truth) has it (docs/physics.md,
        // "Mesh convergence").
        let mesh = forward.tabulated_at(e1, nu1);
        let mesh_mm = |delta: f64| mesh.as_ref().and_then(|at| at.mesh_gamma1_mm(delta)).unwrap_or(0.0);
        let stages: Vec<f64> = rec.samples.iter().map(|s| s.stage_mm).collect();
        let deepest = stages.iter().copied().fold(0.0, f64::max);
        let states = model.normal_path(&stages, FRICTION, deepest / 60.0)?;
        let clean: Vec<(f64, f64)> = rec
            .samples
            .iter()
            .zip(&states)
            .map(|(s, st)| {
                let t = match s.phase {
                    Phase::Torsion => {
                        let twist = s.rot_deg.to_radians();
                        model.theta1_rad(st, twist.abs(), FRICTION).map_or(0.0, |t| t.to_degrees()) * twist.signum()
                    }
                    Phase::Normal => 0.0,
                };
                let live = st.gamma1_mm > 0.0;
                (if live { st.gamma1_mm + mesh_mm(s.stage_mm) } else { 0.0 }, t)
            })
            .collect();
        println!(
            "{} | dev recording: E1 {:+.2} %, nu1 {:+.2} % (Box's bias {:+.3} %, {:+.3} %)",
            f[0],
            (dev.full.e1_mpa / e1 - 1.0) * 100.0,
            (dev.full.nu1 / nu1 - 1.0) * 100.0,
            dev.full.curvature_bias.map_or(0.0, |c| c.e1_mpa / e1 * 100.0),
            dev.full.curvature_bias.map_or(0.0, |c| c.nu1 / nu1 * 100.0),
        );
        let mut tallies: Vec<Tally> = scales.iter().map(|_| Tally::default()).collect();
        for seed in first_seed..first_seed + seeds {
            // Each recording its own draws unless asked otherwise: the dev
            // recordings share one stage and twist schedule, so shared draws
            // make their errors move together.
            let mut noise = Gauss(if shared { seed } else { seed + 1_000_003 * (index as u64 + 1) });
            let draws: Vec<(f64, f64)> = if original_draws {
                // The first version of this study: a draw per live gamma1, then
                // one per torsion theta1, in sample order.
                clean
                    .iter()
                    .zip(&rec.samples)
                    .map(|(&(g, _), s)| {
                        let zg = if g > 0.0 { noise.draw() } else { 0.0 };
                        (zg, if s.phase == Phase::Torsion { noise.draw() } else { 0.0 })
                    })
                    .collect()
            } else {
                clean.iter().map(|_| (noise.draw(), noise.draw())).collect()
            };
            for (k, &scale) in scales.iter().enumerate() {
                let signs: &[f64] = if antithetic { &[1.0, -1.0] } else { &[1.0] };
                let mut fits = Vec::new();
                for &sign in signs {
                    let mut own = rec.clone();
                    for ((s, &(g, t)), &(zg, zt)) in own.samples.iter_mut().zip(&clean).zip(&draws) {
                        s.gamma1_mm = if g > 0.0 { g + sign * scale * GAMMA1_NOISE_MM * zg } else { 0.0 };
                        s.theta1_deg = match s.phase {
                            Phase::Torsion => t + sign * scale * THETA1_NOISE_DEG * zt,
                            Phase::Normal => 0.0,
                        };
                    }
                    let mut opts = FitOptions::default();
                    if fixed_sigma {
                        // Noiseless recordings (scale 0) are weighted as at the set's noise.
                        let w = if scale > 0.0 { scale } else { 1.0 };
                        opts.full.gamma1_sigma_mm = Some(w * GAMMA1_NOISE_MM);
                        opts.full.theta1_sigma_deg = Some(w * THETA1_NOISE_DEG);
                    }
                    let full = if linear_only {
                        // The linear layer model alone, from 5 % and 0.03 off the truth.
                        let start = ModelParams {
                            e1_mpa: 1.05 * e1,
                            nu1: nu1 - 0.03,
                            contact_offset_mm: 0.0,
                            contact_friction: None,
                            large_strain: false,
                        };
                        fit_full(&own, &opts.full, start)?
                    } else {
                        calibrate(&own, &opts)?.full
                    };
                    if verbose {
                        let c = full.curvature_bias;
                        println!(
                            "    seed {seed} x{scale} {sign:+}: E1 {:+.3} % (Box's bias {:+.4} %), nu1 {:+.3} % (Box's bias {:+.4} %), \
                             se {:.3} %, {:.3} %, {}",
                            (full.e1_mpa / e1 - 1.0) * 100.0,
                            c.map_or(0.0, |c| c.e1_mpa / e1 * 100.0),
                            (full.nu1 / nu1 - 1.0) * 100.0,
                            c.map_or(0.0, |c| c.nu1 / nu1 * 100.0),
                            full.e1_se / e1 * 100.0,
                            full.nu1_se / nu1 * 100.0,
                            full.model
                        );
                    }
                    fits.push(full);
                }
                // With antithetic pairs the pair's mean cancels every odd order
                // of the noise: what is left is the bias (and higher even orders).
                let mean =
                    |f: &dyn Fn(&easycalib::fit::FullFit) -> f64| fits.iter().map(f).sum::<f64>() / fits.len() as f64;
                let raw_e = mean(&|f| (f.e1_mpa / e1 - 1.0) * 100.0);
                let raw_n = mean(&|f| (f.nu1 / nu1 - 1.0) * 100.0);
                let e = mean(&|f| ((f.e1_mpa - f.curvature_bias.map_or(0.0, |c| c.e1_mpa)) / e1 - 1.0) * 100.0);
                let n = mean(&|f| ((f.nu1 - f.curvature_bias.map_or(0.0, |c| c.nu1)) / nu1 - 1.0) * 100.0);
                for t in [&mut tallies[k], &mut pooled[k]] {
                    t.e.push(e);
                    t.n.push(n);
                    t.raw_e.push(raw_e);
                    t.raw_n.push(raw_n);
                    for full in &fits {
                        t.other_model += usize::from(full.model != "layer-fe");
                        t.warned += usize::from(!full.warnings.is_empty());
                        for w in &full.warnings {
                            *t.codes.entry(w.code).or_default() += 1;
                        }
                    }
                }
            }
        }
        for (scale, t) in scales.iter().zip(&tallies) {
            println!("  noise x{scale:<4} {}", t.line());
        }
    }
    for (scale, t) in scales.iter().zip(&pooled) {
        println!("all recordings, noise x{scale:<4} {}", t.line());
    }
    Ok(())
}
