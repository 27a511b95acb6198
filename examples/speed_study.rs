//! Issue 15's figures: the default calibration on the emulated rig (real APT
//! drivers and the sensor link over pseudo-terminals, time-accelerated), one
//! run per seed, with its rig time per phase, the full fit's errors against
//! the truth and its 95 % interval widths, chi²/dof and the diagnosis verdict.
//!
//! ```sh
//! cargo run --release --example speed_study -- [--seeds 1..=10] [--script FILE] [--speedup 40]
//! ```
//!
//! Long (several seconds of wall time a seed): a study tool, not a CI test.

use std::path::PathBuf;

use easycalib::rig::emulated::{EmulatedRig, ServeOptions};
use easycalib::run::{RunStatus, Script};
use sim::setup::SimSetupInput;

struct Row {
    seed: u64,
    phases: Vec<(&'static str, f64)>,
    rig_s: f64,
    wall_s: f64,
    samples: usize,
    /// Full fit, relative error %: E1, nu1.
    err: (f64, f64),
    /// Full fit, 95 % interval width, % of the value: E1, nu1.
    ci: (f64, f64),
    chi2_dof: f64,
    verdict: String,
}

struct Args {
    seeds: Vec<u64>,
    script: Script,
    speedup: f64,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args { seeds: (1..=10).collect(), script: Script::default(), speedup: 40.0 };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--seeds" => {
                let v = value()?;
                let (lo, hi) = v.split_once("..=").ok_or_else(|| format!("--seeds {v}: expected A..=B"))?;
                let lo: u64 = lo.parse().map_err(|e| format!("--seeds {v}: {e}"))?;
                let hi: u64 = hi.parse().map_err(|e| format!("--seeds {v}: {e}"))?;
                args.seeds = (lo..=hi).collect();
            }
            "--script" => {
                let path = PathBuf::from(value()?);
                let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
                args.script = Script::from_toml(&text).map_err(|e| format!("{}: {e}", path.display()))?;
            }
            "--speedup" => args.speedup = value()?.parse().map_err(|e| format!("--speedup: {e}"))?,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    Ok(args)
}

async fn run_seed(seed: u64, script: &Script, speedup: f64) -> Result<Row, String> {
    let setup = SimSetupInput { speedup, seed, ..SimSetupInput::default() }.resolve().map_err(|e| e.to_string())?;
    let rig = EmulatedRig::start(setup, ServeOptions::default()).await.map_err(|e| e.to_string())?;
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let truth = rig.truth();
    let r = rig.calibrate(script.clone(), dir.path()).await.map_err(|e| e.to_string())?;
    if r.outcome.status != RunStatus::Completed {
        return Err(format!("seed {seed}: {:?}", r.outcome.status));
    }
    let cal = r.calibration.as_ref().ok_or_else(|| format!("seed {seed}: no fit: {:?}", r.fit_error))?;
    let f = &cal.full;
    let pct = |x: f64, t: f64| 100.0 * (x / t - 1.0);
    let width = |ci: [f64; 2], v: f64| 100.0 * (ci[1] - ci[0]) / v;
    Ok(Row {
        seed,
        phases: r.outcome.phase_rig_time_s.iter().map(|p| (p.phase, p.rig_time_s)).collect(),
        rig_s: r.outcome.rig_time_s,
        wall_s: r.outcome.wall_time_s,
        samples: r.outcome.samples,
        err: (pct(f.e1_mpa, truth.e1_mpa), pct(f.nu1, truth.nu1)),
        ci: (width(f.ci95.e1_mpa, f.e1_mpa), width(f.ci95.nu1, f.nu1)),
        chi2_dof: f.chi2_dof.unwrap_or(f64::NAN),
        verdict: r.diagnosis.as_ref().map_or("-".to_string(), |d| d.verdict.as_str().to_string()),
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Issue 15's baseline: the default script before the issue's redesign, on
/// the same emulated rig (truth, noise, seeds 1-10; docs/run.md, "The sweeps'
/// design"): median rig time, s, and median 95 % interval widths, % of the
/// value, of E1 and nu1.
const BEFORE_RIG_S: f64 = 187.0;
const BEFORE_CI_E1_PCT: f64 = 0.096;
const BEFORE_CI_NU1_PCT: f64 = 0.329;

fn print_table(rows: &[Row]) {
    let names = ["homing", "approach", "normal", "torsion", "experiments", "retract"];
    println!(
        "seed  homing approach normal torsion  exper retract   rig_s  wall_s  n    E1_err%  nu1_err%  ciE1%  ciNu1%  chi2/dof  verdict"
    );
    for r in rows {
        let ph = |n: &str| r.phases.iter().find(|p| p.0 == n).map_or(0.0, |p| p.1);
        println!(
            "{:4}  {:6.1} {:8.1} {:6.1} {:7.1} {:6.1} {:7.1}  {:6.1}  {:6.2}  {:3}  {:+8.3}  {:+8.3}  {:5.3}  {:6.3}  {:8.2}  {}",
            r.seed,
            ph(names[0]),
            ph(names[1]),
            ph(names[2]),
            ph(names[3]),
            ph(names[4]),
            ph(names[5]),
            r.rig_s,
            r.wall_s,
            r.samples,
            r.err.0,
            r.err.1,
            r.ci.0,
            r.ci.1,
            r.chi2_dof,
            r.verdict
        );
    }
    let m = |f: fn(&Row) -> f64| median(rows.iter().map(f).collect());
    println!(
        "median rig {:.1} s, wall {:.2} s; CI width E1 {:.3} %, nu1 {:.3} %; chi2/dof {:.2}; max |err| E1 {:.3} %, nu1 {:.3} %",
        m(|r| r.rig_s),
        m(|r| r.wall_s),
        m(|r| r.ci.0),
        m(|r| r.ci.1),
        m(|r| r.chi2_dof),
        rows.iter().map(|r| r.err.0.abs()).fold(0.0, f64::max),
        rows.iter().map(|r| r.err.1.abs()).fold(0.0, f64::max),
    );
    let phase_median =
        |n: &str| median(rows.iter().map(|r| r.phases.iter().find(|p| p.0 == n).map_or(0.0, |p| p.1)).collect());
    println!(
        "median rig time per phase: {}",
        names.iter().map(|n| format!("{n} {:.1} s", phase_median(n))).collect::<Vec<_>>().join(", ")
    );
    // Issue 15's bars, against the baseline.
    let (rig, ci_e1, ci_nu1) = (m(|r| r.rig_s), m(|r| r.ci.0), m(|r| r.ci.1));
    let within = rows.iter().filter(|r| r.err.0.abs() <= 1.0 && r.err.1.abs() <= 2.0).count();
    let verdict = |ok: bool| if ok { "met" } else { "NOT MET" };
    println!(
        "before: median rig {BEFORE_RIG_S:.0} s, CI width E1 {BEFORE_CI_E1_PCT:.3} %, nu1 {BEFORE_CI_NU1_PCT:.3} %; \
         now: median rig {rig:.1} s, CI width E1 {ci_e1:.3} %, nu1 {ci_nu1:.3} %"
    );
    println!("bar: median rig time <= 90 s: {} ({rig:.1} s)", verdict(rig <= 90.0));
    println!(
        "bar: E1 within 1 % and nu1 within 2 % of the truth in every seed: {} ({within} of {})",
        verdict(within == rows.len()),
        rows.len()
    );
    println!(
        "bar: median interval widths no wider than before: {} (E1 {ci_e1:.3} vs {BEFORE_CI_E1_PCT:.3} %, nu1 {ci_nu1:.3} vs {BEFORE_CI_NU1_PCT:.3} %)",
        verdict(ci_e1 <= BEFORE_CI_E1_PCT && ci_nu1 <= BEFORE_CI_NU1_PCT)
    );
    let count = |v: &str| rows.iter().filter(|r| r.verdict == v).count();
    println!(
        "verdicts: clean {}, ambiguous {}, effects {}, unexplained {}",
        count("clean"),
        count("ambiguous"),
        count("effects"),
        count("unexplained")
    );
}

fn main() {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("speed_study: {e}");
            std::process::exit(2);
        }
    };
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("speed_study: tokio runtime: {e}");
            std::process::exit(1);
        }
    };
    let mut rows = Vec::new();
    for &seed in &args.seeds {
        match rt.block_on(run_seed(seed, &args.script, args.speedup)) {
            Ok(r) => rows.push(r),
            Err(e) => eprintln!("speed_study: seed {seed}: {e}"),
        }
    }
    print_table(&rows);
}
