//! `easycalib fit`, `easycalib simulate` and the simulated `easycalib run`.

use std::path::Path;

use history::Source;
use sim::generator::{GeneratorConfig, generate};
use sim::recording::Recording;

use super::sim_setup::{SimSetupArgs, sim_setup};
use super::{CliError, ElastomerArgs, Fidelity, FitArgs, SimulateArgs};
use crate::fit::{FitError, FitOptions, calibrate};

pub use crate::report::json::{CalibrationOutput, calibration_output};

fn pm(ci: [f64; 2]) -> f64 {
    0.5 * (ci[1] - ci[0])
}

/// The human summary, with units.
pub fn human_summary(out: &CalibrationOutput, meta: &sim::recording::Metadata) -> String {
    let f = &out.full;
    let p = &out.paper;
    let mut s = String::new();
    let r1 = crate::report::elastomer_words(meta);
    s += &format!(
        "Recording: {} ({} normal + {} torsion samples); indenter E2 {} MPa, nu2 {}, R2 {} mm; elastomer {}\n\n",
        out.recording.as_deref().unwrap_or("(simulated)"),
        out.samples.normal,
        out.samples.torsion,
        meta.indenter.e_mpa,
        meta.indenter.nu,
        meta.indenter.r_mm,
        r1
    );
    s += "Elastomer (full-model fit, best estimate; ± is the 95% interval)\n";
    s += &format!(
        "  E1  = {:.4} MPa ± {:.4} MPa  [{:.4} .. {:.4}]\n",
        f.e1_mpa,
        pm(f.ci95.e1_mpa),
        f.ci95.e1_mpa[0],
        f.ci95.e1_mpa[1]
    );
    s += &format!(
        "  nu1 = {:.4}     ± {:.4}      [{:.4} .. {:.4}]\n",
        f.nu1,
        pm(f.ci95.nu1),
        f.ci95.nu1[0],
        f.ci95.nu1[1]
    );
    s += &format!(
        "  contact offset z0 = {:+.1} µm ± {:.1} µm; corr(E1, nu1) = {:+.3}; torsion depth beta = {:.4}\n",
        f.contact_offset_mm * 1e3,
        pm(f.ci95.contact_offset_mm) * 1e3,
        f.corr_e1_nu1,
        f.beta
    );
    s += &format!(
        "  residual RMS: normal {:.2} µm (noise floor {:.2} µm, R² {:.6}); torsion {:.4}° (noise floor {:.4}°, R² {:.6})\n",
        f.rms.normal_um,
        f.noise_floor.normal_um,
        f.r2.normal,
        f.rms.torsion_deg,
        f.noise_floor.torsion_deg,
        f.r2.torsion
    );
    if let Some(c) = f.chi2_dof {
        s += &format!(
            "  weighted by the recording's standard errors: chi²/dof {c:.2}{}\n",
            if c > 1.0 { " (the intervals are widened by its square root)" } else { "" }
        );
    }
    for w in &out.warnings {
        s += &format!("  warning ({}): {}\n", w.code, w.message);
    }
    s += &format!(
        "\nPaper's method (Eq. 22 over gamma1 {}-{} mm, {} samples; Eq. 38 through the origin, {} samples)\n",
        p.window_mm[0], p.window_mm[1], p.n_normal, p.n_torsion
    );
    s += &format!("  H1 = {:.4} ± {:.4}   H2 = {:+.4}   R² {:.6}\n", p.h1, pm(p.h1_ci95), p.h2, p.r2_normal);
    s += &format!(
        "  H3 = {:.4} ± {:.4}   R² {:.6}; beta = {:.4}, c(beta) = {:.4}\n",
        p.h3,
        pm(p.h3_ci95),
        p.r2_torsion,
        p.beta,
        p.rod_factor
    );
    s += &format!(
        "  exact inversion:   E1 = {:.4} MPa ± {:.4}, nu1 = {:.4} ± {:.4}, corr {:+.3}\n",
        p.e1_mpa,
        pm(p.ci95.e1_mpa),
        p.nu1,
        pm(p.ci95.nu1),
        p.corr_e1_nu1
    );
    s += &format!("  rounded constants: E1 = {:.4} MPa, nu1 = {:.4} (Eqs. 39-40)\n", p.e1_mpa_rounded, p.nu1_rounded);
    if let Some(t) = out.sim_truth {
        s += &format!(
            "\nSimulation truth: E1 = {:.4} MPa, nu1 = {:.4} -> full fit error E1 {:+.2}%, nu1 {:+.2}%; paper's method E1 {:+.2}%, nu1 {:+.2}%\n",
            t.e1_mpa,
            t.nu1,
            (f.e1_mpa / t.e1_mpa - 1.0) * 100.0,
            (f.nu1 / t.nu1 - 1.0) * 100.0,
            (p.e1_mpa / t.e1_mpa - 1.0) * 100.0,
            (p.nu1 / t.nu1 - 1.0) * 100.0
        );
        if let Some(d) = out.diagnosis.as_ref().filter(|d| d.corrected()) {
            s += &format!(
                "  diagnosis (corrected) error E1 {:+.2}%, nu1 {:+.2}%\n",
                (d.e1_mpa / t.e1_mpa - 1.0) * 100.0,
                (d.nu1 / t.nu1 - 1.0) * 100.0
            );
        }
    }
    s
}

fn fit_options(window: &[f64], noise_um: Option<f64>) -> Result<FitOptions, CliError> {
    let mut opts = FitOptions::default();
    if let [lo, hi] = window {
        opts.paper.window_mm = [*lo, *hi];
    }
    if let Some(n) = noise_um {
        if !(n.is_finite() && n > 0.0) {
            return Err(CliError::bad_input(format!("--noise-um must be a positive number of micrometres, got {n}")));
        }
        opts.full.gamma1_sigma_mm = Some(n * 1e-3);
    }
    Ok(opts)
}

pub fn fit(args: &FitArgs) -> Result<(), CliError> {
    let mut rec = Recording::read_path(&args.recording)
        .map_err(|e| CliError::bad_input(format!("{}: {e}", args.recording.display())))?;
    args.layer.apply(&mut rec)?;
    let opts = fit_options(&args.window_mm, args.noise_um)?;
    let cal = calibrate(&rec, &opts).map_err(|e| match e {
        FitError::Implausible(_) => CliError::bad_input(format!("{}: {e}", args.recording.display())),
        e => CliError::fit_failed(format!("{}: {e}", args.recording.display())),
    })?;
    let out = calibration_output(&rec, &cal, Some(&args.recording), None);
    print_output(&out, &rec, args.json)?;
    if args.record {
        let lines =
            super::history::record(&args.db, &args.recording, &rec, super::history::outcome_of_fit(&out, Source::Fit));
        print_history(&lines, args.json);
    }
    Ok(())
}

/// The history's lines: on stdout after a human report, on stderr beside JSON.
pub fn print_history(lines: &[String], json: bool) {
    for l in lines {
        if json {
            eprintln!("{l}");
        } else {
            println!("{l}");
        }
    }
}

fn print_output(out: &CalibrationOutput, rec: &Recording, json: bool) -> Result<(), CliError> {
    if json {
        let text = crate::report::json::to_json_explained(out).map_err(|e| CliError::other(e.to_string()))?;
        println!("{text}");
    } else {
        print!("{}", human_summary(out, &rec.meta));
    }
    Ok(())
}

/// The generator for the simulated elastomer and indenter of the flags, with
/// the effects of a sim profile (`--profile`; its material overrides the flags'
/// elastomer, which may then not be given).
pub fn generator_config(a: &ElastomerArgs, profile: Option<&Path>) -> Result<GeneratorConfig, CliError> {
    let setup = sim_setup(SimSetupArgs { elastomer: a, script: None, profile, speedup: sim::defaults::SPEEDUP })?;
    Ok(GeneratorConfig {
        pair: *setup.pair(),
        seed: setup.seed(),
        profile: setup.effects().clone(),
        ..GeneratorConfig::default()
    })
}

pub fn simulate(args: &SimulateArgs) -> Result<(), CliError> {
    if args.fidelity == Fidelity::Fe && args.profile.is_some() {
        return Err(CliError::bad_input(
            "--profile is simulated by the analytic generator (and on a declared layer, by the linear FE layer \
             model); --fidelity fe simulates the clean large-strain contact only",
        ));
    }
    let cfg = generator_config(&args.elastomer, args.profile.as_deref())?;
    let rec = match args.fidelity {
        Fidelity::Fe => super::simulate_fe::fe_recording(args)?,
        Fidelity::Analytic if args.layer.thickness_mm.is_some() => layered_recording(args, &cfg)?,
        Fidelity::Analytic => generate(&cfg).map_err(|e| CliError::bad_input(format!("cannot simulate: {e}")))?,
    };
    rec.write_path(&args.output)
        .map_err(|e| CliError::other(format!("cannot write {}: {e}", args.output.display())))?;
    eprintln!(
        "wrote {} ({} samples; E1 {} MPa, nu1 {}, seed {})",
        args.output.display(),
        rec.samples.len(),
        cfg.pair.elastomer.e_mpa,
        cfg.pair.elastomer.nu,
        cfg.seed
    );
    Ok(())
}

/// `simulate --thickness-mm`: the generator's sweeps on a gel layer bonded to
/// its window (or sliding on it, `--base sliding`), the contact from the linear FE layer model pressed and twisted
/// with Coulomb friction (`fit::fe_law::frictional_truth`), the profile's
/// rig-level effects around it (docs/physics.md, "The layer in the generator and the emulated rig").
fn layered_recording(args: &SimulateArgs, cfg: &GeneratorConfig) -> Result<Recording, CliError> {
    let Some(layer) = args.layer.layer()? else {
        return Err(CliError::bad_input("a layered recording needs --thickness-mm"));
    };
    if cfg.pair.elastomer.r_mm.is_finite() {
        return Err(CliError::bad_input(format!(
            "a declared layer is simulated flat: give --r1-mm inf (the elastomer's dome radius is {} mm)",
            cfg.pair.elastomer.r_mm
        )));
    }
    let (gel, indenter) = (cfg.pair.elastomer, cfg.pair.indenter);
    eprintln!("simulating on the linear finite-element layer model (a few seconds)...");
    let law = crate::fit::fe_law::frictional_truth(layer, indenter, gel.e_mpa, gel.nu, sim::defaults::GEL_FRICTION)
        .map_err(|e| CliError::bad_input(format!("cannot simulate the layer: {e}")))?;
    let truth = sim::generator::LayeredTruth { law, layer };
    sim::generator::generate_on(cfg, Some(&truth)).map_err(|e| CliError::bad_input(format!("cannot simulate: {e}")))
}
