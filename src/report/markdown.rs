//! `report.md`: the result with units and intervals, fit quality, and the figures.

use std::fmt::Write;

use sim::recording::Recording;

use super::json::CalibrationOutput;

fn pm(ci: [f64; 2]) -> f64 {
    0.5 * (ci[1] - ci[0])
}

fn num(x: f64, d: usize) -> String {
    if x.is_finite() { format!("{x:.d$}") } else { "n/a".to_string() }
}

fn interval(ci: [f64; 2], d: usize) -> String {
    format!("[{}, {}]", num(ci[0], d), num(ci[1], d))
}

/// The Markdown report. `normal_svg` and `torsion_svg` are the figures' file
/// names relative to the report.
pub fn render_markdown(out: &CalibrationOutput, rec: &Recording, normal_svg: &str, torsion_svg: &str) -> String {
    let mut s = String::new();
    write_header(&mut s, out, rec);
    write_result(&mut s, out);
    write_diagnosis(&mut s, out);
    write_truth(&mut s, out);
    write_fit_quality(&mut s, out);
    write_figures(&mut s, normal_svg, torsion_svg);
    s
}

// Writing to a String cannot fail: the sections below ignore `writeln!`'s Ok.

/// Title and the table of what was calibrated, with what, and how long it took.
fn write_header(s: &mut String, out: &CalibrationOutput, rec: &Recording) {
    let meta = &rec.meta;
    let _ = writeln!(s, "# Calibration report\n");
    let _ = writeln!(s, "| | |\n| --- | --- |");
    let _ = writeln!(s, "| sensor | {} |", meta.sensor.as_deref().unwrap_or("(not named)"));
    if let Some(c) = &meta.created {
        let _ = writeln!(s, "| created | {c} |");
    }
    let _ = writeln!(s, "| recording | `{}` |", out.recording.as_deref().unwrap_or("(not written)"));
    let _ = writeln!(s, "| samples | {} normal, {} torsion |", out.samples.normal, out.samples.torsion);
    let _ = writeln!(
        s,
        "| indenter | E2 = {} MPa, nu2 = {}, R2 = {} mm |",
        meta.indenter.e_mpa, meta.indenter.nu, meta.indenter.r_mm
    );
    let _ = writeln!(s, "| elastomer | {} |", super::elastomer_words(meta));
    if let Some((_, moved)) = meta.extra.iter().find(|(k, _)| k == crate::fit::zero::ZERO_MOVED_KEY) {
        let moved_um =
            moved.trim().parse::<f64>().map(|m| format!("{:+.2} um", m * 1e3)).unwrap_or_else(|_| moved.clone());
        // The calibration that placed it models no effect; a diagnosis that
        // names some places the contact itself (under a compliant frame the
        // calibration reads the frame's give as a later contact).
        let named = out.diagnosis.as_ref().filter(|d| !d.effects.is_empty());
        let diagnosed = match named.and_then(|d| d.contact_offset_mm.map(|z| (d, z))) {
            Some((d, z)) => {
                let names: Vec<&str> = d.effects.iter().map(|e| e.name).collect();
                format!(
                    "; with {} named, the diagnosis places the contact {:+.2} um from this zero",
                    names.join(" + "),
                    z * 1e3
                )
            }
            None => String::new(),
        };
        let _ = writeln!(
            s,
            "| stage zero | moved {moved_um} after the sweep, to the contact the calibration's full fit (no effect modelled) places{diagnosed} (docs/run.md, \"Stage zero\") |"
        );
    }
    if let Some(t) = &out.run {
        let phases: Vec<String> = t.phases.iter().map(|p| format!("{} {:.1} s", p.phase, p.rig_time_s)).collect();
        let _ = writeln!(
            s,
            "| run | rig time {:.1} s ({}), wall time {:.1} s |",
            t.rig_time_s,
            phases.join(", "),
            t.wall_time_s
        );
        // The closed loop's chain: hypotheses -> experiment -> outcome (docs/experiments.md).
        for (i, e) in t.experiments.iter().enumerate() {
            let _ = writeln!(
                s,
                "| experiment {} | {} ({:.1} s of rig time): {}; then {} (E1 {:.4} MPa, nu1 {:.4}) |",
                i + 1,
                e.name,
                e.rig_time_s,
                e.why,
                e.outcome,
                e.e1_mpa,
                e.nu1
            );
        }
        for w in &t.warnings {
            // One table row each, whatever the message holds.
            let _ = writeln!(s, "| run warning | {} |", w.replace('|', "/").replace(['\n', '\r'], " "));
        }
    }
    let _ = writeln!(s);
}

/// The best estimate with its warnings, and the table of every method's values.
fn write_result(s: &mut String, out: &CalibrationOutput) {
    let f = &out.full;
    let p = &out.paper;
    let _ = writeln!(s, "## Result\n");
    match out.decided_by {
        Some(by) => {
            let _ = writeln!(
                s,
                "Best estimate: **E1 = {} MPa {}**, **nu1 = {} {}** (95 % intervals): the closed loop's decision \
                 after `{by}`, corrected for {} (Diagnosis, below). The full-model fit of the recording alone, \
                 uncorrected: E1 = {} ± {} MPa, nu1 = {} ± {}.\n",
                num(out.e1_mpa, 4),
                interval(out.ci95.e1_mpa, 4),
                num(out.nu1, 4),
                interval(out.ci95.nu1, 4),
                out.effects.iter().map(|e| format!("`{e}`")).collect::<Vec<_>>().join(", "),
                num(f.e1_mpa, 4),
                num(pm(f.ci95.e1_mpa), 4),
                num(f.nu1, 4),
                num(pm(f.ci95.nu1), 4)
            );
        }
        None => {
            let _ = writeln!(
                s,
                "Best estimate: **E1 = {} ± {} MPa**, **nu1 = {} ± {}** (full-model fit; ± is the half-width of the 95 % interval).\n",
                num(f.e1_mpa, 4),
                num(pm(f.ci95.e1_mpa), 4),
                num(f.nu1, 4),
                num(pm(f.ci95.nu1), 4)
            );
        }
    }
    if !out.warnings.is_empty() {
        let _ = writeln!(s, "**Warnings**\n");
        for w in &out.warnings {
            let _ = writeln!(s, "- `{}`: {}", w.code, w.message);
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "| quantity | method | value | 95 % interval | unit |");
    let _ = writeln!(s, "| --- | --- | ---: | --- | --- |");
    let _ = writeln!(s, "| E1 | full model | {} | {} | MPa |", num(f.e1_mpa, 4), interval(f.ci95.e1_mpa, 4));
    let _ = writeln!(s, "| nu1 | full model | {} | {} | – |", num(f.nu1, 4), interval(f.ci95.nu1, 4));
    let _ = writeln!(
        s,
        "| z0 (contact offset) | full model | {} | {} | µm |",
        num(f.contact_offset_mm * 1e3, 1),
        interval([f.ci95.contact_offset_mm[0] * 1e3, f.ci95.contact_offset_mm[1] * 1e3], 1)
    );
    let _ =
        writeln!(s, "| E1 | paper, exact inversion | {} | {} | MPa |", num(p.e1_mpa, 4), interval(p.ci95.e1_mpa, 4));
    let _ = writeln!(s, "| nu1 | paper, exact inversion | {} | {} | – |", num(p.nu1, 4), interval(p.ci95.nu1, 4));
    let _ = writeln!(s, "| E1 | paper, rounded constants (Eqs. 39-40) | {} | | MPa |", num(p.e1_mpa_rounded, 4));
    let _ = writeln!(s, "| nu1 | paper, rounded constants (Eqs. 39-40) | {} | | – |", num(p.nu1_rounded, 4));
    let _ = writeln!(s);
}

/// The diagnosis made at the end of a run: verdict, effects, and the corrected
/// E1, nu1 beside the calibration's (docs/run.md).
fn write_diagnosis(s: &mut String, out: &CalibrationOutput) {
    let Some(d) = &out.diagnosis else { return };
    let f = &out.full;
    let _ = writeln!(
        s,
        "## Diagnosis
"
    );
    match out.decided_by {
        Some(by) => {
            let _ = writeln!(
                s,
                "Verdict: **{}**, the closed loop's decision after `{by}` ({:.2} s).\n",
                d.verdict.as_str(),
                d.wall_time_s
            );
        }
        None => {
            let _ = writeln!(
                s,
                "Verdict: **{}** (`easycalib diagnose` on the recording, {:.2} s).\n",
                d.verdict.as_str(),
                d.wall_time_s
            );
        }
    }
    let _ = writeln!(s, "```text\n{}```\n", d.summary);
    for e in &d.effects {
        let params: Vec<String> = e.params.iter().map(crate::diagnosis::prose::param).collect();
        let _ = writeln!(s, "- `{}`: {}", e.name, params.join(", "));
    }
    if !d.effects.is_empty() {
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "| quantity | calibration (full model) | 95 % interval | diagnosis | 95 % interval | unit |");
    let _ = writeln!(s, "| --- | ---: | --- | ---: | --- | --- |");
    let rows = [
        ("E1", "MPa", [f.e1_mpa, d.e1_mpa], [f.ci95.e1_mpa, d.ci95.e1_mpa]),
        ("nu1", "–", [f.nu1, d.nu1], [f.ci95.nu1, d.ci95.nu1]),
    ];
    for (name, unit, [fv, dv], [fci, dci]) in rows {
        let _ = writeln!(
            s,
            "| {name} | {} | {} | {} | {} | {unit} |",
            num(fv, 4),
            interval(fci, 4),
            num(dv, 4),
            interval(dci, 4)
        );
    }
    if out.decided_by.is_some() {
        let _ = writeln!(s, "\nThe report's best estimate is the diagnosis' (the closed loop decided).\n");
    } else {
        let _ = writeln!(
            s,
            "\nThe report's best estimate stays the calibration's; {}.\n",
            if d.corrected() {
                "the diagnosis' values are corrected for the effects it named"
            } else {
                "the diagnosis named nothing, so its values are the calibration's"
            }
        );
    }
    if let Some(st) = &out.standard {
        let _ = writeln!(
            s,
            "The run's recording alone (`standard` in report.json; the decision rests on samples outside it), \
             verdict **{}**: E1 = {} MPa {}, nu1 = {} {}.\n",
            st.verdict.as_str(),
            num(st.e1_mpa, 4),
            interval(st.ci95.e1_mpa, 4),
            num(st.nu1, 4),
            interval(st.ci95.nu1, 4)
        );
        let _ = writeln!(s, "```text\n{}```\n", st.summary);
    }
}

/// The simulated rig's true elastomer and each method's error against it (simulated runs only).
fn write_truth(s: &mut String, out: &CalibrationOutput) {
    let f = &out.full;
    let p = &out.paper;
    if let Some(t) = out.sim_truth {
        let _ = writeln!(s, "## Simulation truth\n");
        let _ = writeln!(s, "| | E1 (MPa) | nu1 |\n| --- | ---: | ---: |");
        let _ = writeln!(s, "| truth | {} | {} |", num(t.e1_mpa, 4), num(t.nu1, 4));
        let err = |est: f64, truth: f64| format!("{:+.2} %", (est / truth - 1.0) * 100.0);
        let _ = writeln!(s, "| full model error | {} | {} |", err(f.e1_mpa, t.e1_mpa), err(f.nu1, t.nu1));
        let _ = writeln!(s, "| paper's method error | {} | {} |", err(p.e1_mpa, t.e1_mpa), err(p.nu1, t.nu1));
        if let Some(d) = &out.diagnosis {
            let what = match out.decided_by {
                Some(by) => format!("the closed loop's decision after {by}"),
                None if d.corrected() => "corrected".to_string(),
                None => "nothing named: the full model's".to_string(),
            };
            let _ = writeln!(s, "| diagnosis ({what}) error | {} | {} |", err(d.e1_mpa, t.e1_mpa), err(d.nu1, t.nu1));
        }
        if let Some(st) = &out.standard {
            let _ = writeln!(
                s,
                "| the run's recording alone ({}) error | {} | {} |",
                st.verdict.as_str(),
                err(st.e1_mpa, t.e1_mpa),
                err(st.nu1, t.nu1)
            );
        }
        let _ = writeln!(s);
    }
}

/// Residuals, noise floors and R² per sweep; how each method got there.
fn write_fit_quality(s: &mut String, out: &CalibrationOutput) {
    let f = &out.full;
    let p = &out.paper;
    let _ = writeln!(s, "## Fit quality\n");
    let _ = writeln!(s, "| | normal sweep | torsion sweep |\n| --- | ---: | ---: |");
    let _ = writeln!(
        s,
        "| full model: residual RMS | {} µm | {} deg |",
        num(f.rms.normal_um, 2),
        num(f.rms.torsion_deg, 4)
    );
    let _ = writeln!(
        s,
        "| full model: noise floor | {} µm | {} deg |",
        num(f.noise_floor.normal_um, 2),
        num(f.noise_floor.torsion_deg, 4)
    );
    let _ = writeln!(s, "| full model: R² | {} | {} |", num(f.r2.normal, 6), num(f.r2.torsion, 6));
    let _ = writeln!(s, "| paper: R² | {} | {} |", num(p.r2_normal, 6), num(p.r2_torsion, 6));
    let _ = writeln!(s, "| paper: samples used | {} | {} |\n", p.n_normal, p.n_torsion);
    let _ = writeln!(
        s,
        "Paper's method: Eq. 22 over gamma1 {}–{} mm gives H1 = {} ± {} (H2 = {}); Eq. 38 gives H3 = {} ± {}; \
         torsion depth beta = {}, rod factor c(beta) = {}; corr(E1, nu1) = {}.\n",
        p.window_mm[0],
        p.window_mm[1],
        num(p.h1, 4),
        num(pm(p.h1_ci95), 4),
        num(p.h2, 4),
        num(p.h3, 4),
        num(pm(p.h3_ci95), 4),
        num(p.beta, 4),
        num(p.rod_factor, 4),
        num(p.corr_e1_nu1, 3)
    );
    let _ = writeln!(
        s,
        "Full model: {} samples, {} iterations, {}; model beta = {}; corr(E1, nu1) = {}.\n",
        f.samples_used,
        f.iterations,
        if f.converged { "converged" } else { "**stopped before converging**" },
        num(f.beta, 4),
        num(f.corr_e1_nu1, 3)
    );
}

/// The two sweep figures with their captions.
fn write_figures(s: &mut String, normal_svg: &str, torsion_svg: &str) {
    let _ = writeln!(s, "## Figures\n");
    let _ = writeln!(s, "Normal sweep with the paper's fit (Eq. 22) and the full model; residuals below.\n");
    let _ = writeln!(s, "![Normal sweep: gamma2 vs gamma1]({normal_svg})\n");
    let _ = writeln!(s, "Torsion sweep with the paper's fit (Eq. 38) and the full model; residuals below.\n");
    let _ = writeln!(s, "![Torsion sweep: theta2 vs theta1]({torsion_svg})");
}
