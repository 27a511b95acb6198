//! The diagnosis in words, written once: the verdict (the `verdict` field of
//! the JSON document), the human report `easycalib diagnose` prints, and the
//! reasons an effect is reported degenerate. Every number a sentence shows is
//! formatted by one phrase below, so the report and the verdict agree.

use std::fmt::Write as _;

use super::model::Candidate;
use super::{Diagnosis, FitSummary, Mismatch, ParamEstimate, Rms, StandardErrors};

/// A fitted parameter of an effect: value, unit and 95 % interval (an open
/// end is `open`), flagged when the sweeps determine it only weakly.
pub fn param(p: &ParamEstimate) -> String {
    let end = |v: Option<f64>| v.map_or("open".to_string(), |v| format!("{v:.5}"));
    format!(
        "{} = {:.5} {} (95% [{}, {}]){}",
        p.name,
        p.value,
        p.unit,
        end(p.ci95[0]),
        end(p.ci95[1]),
        if p.well_determined { "" } else { "  weakly determined" }
    )
}

/// E1 and nu1 of one fit with their 95 % intervals.
fn estimate(f: &FitSummary) -> String {
    format!(
        "E1 {:.4} MPa [{:.4}, {:.4}], nu1 {:.4} [{:.4}, {:.4}]",
        f.e1_mpa, f.ci95.e1_mpa[0], f.ci95.e1_mpa[1], f.nu1, f.ci95.nu1[0], f.ci95.nu1[1]
    )
}

/// E1 and nu1 from the baseline to the corrected fit.
fn estimate_change(b: &FitSummary, c: &FitSummary) -> String {
    format!("E1 {:.4} -> {:.4} MPa, nu1 {:.4} -> {:.4}", b.e1_mpa, c.e1_mpa, b.nu1, c.nu1)
}

/// From the baseline to the best of the explanations the sweeps cannot rank.
fn best_alternative_change(d: &Diagnosis) -> String {
    match d.ambiguous.first() {
        Some(a) => {
            format!("E1 {:.4} -> {:.4} MPa, nu1 {:.4} -> {:.4}", d.baseline.e1_mpa, a.e1_mpa, d.baseline.nu1, a.nu1)
        }
        None => estimate_change(&d.baseline, &d.corrected),
    }
}

/// The residual RMS per reading group, from the baseline to the corrected fit.
fn rms_change(b: &Rms, c: &Rms) -> String {
    format!(
        "normal {:.2} -> {:.2} µm, hold {:.2} -> {:.2} µm, torsion {:.4} -> {:.4} deg",
        b.normal_um, c.normal_um, b.hold_um, c.hold_um, b.torsion_deg, c.torsion_deg
    )
}

/// Why an effect that improves the fit is not picked.
pub(super) fn degenerate_reason(effect: &str, vif: f64) -> String {
    format!(
        "{effect} improves the fit, but with these sweeps E1/nu1 can stand in for it (variance inflation {vif:.0}), so it is not picked"
    )
}

/// Why a depth-scale error of the sensor is reported degenerate.
pub(super) fn sensor_gain_reason(vif: f64) -> String {
    format!(
        "a depth-scale error of the sensor cannot be told apart from a change of E1/nu1 with these sweeps (variance inflation {vif:.0}); E1 and nu1 are only as good as the sensor's depth calibration"
    )
}

fn where_(m: &[Mismatch]) -> String {
    m.iter()
        .map(|m| format!("{} {} {:.3}..{:.3} ({})", m.phase, m.axis, m.from, m.to, m.shape))
        .collect::<Vec<_>>()
        .join("; ")
}

/// The answer in a few sentences; `tried` is the chosen model's effects.
pub(super) fn verdict(d: &Diagnosis, tried: &[Candidate]) -> String {
    let mut s = if d.unexplained {
        unexplained_verdict(d, tried)
    } else if !d.ambiguous.is_empty() {
        ambiguous_verdict(d)
    } else if d.effects.is_empty() {
        if d.mismatch.is_empty() {
            "No mismatch beyond the noise floor; no effect named.".to_string()
        } else {
            "No effect named.".to_string()
        }
    } else {
        named_verdict(d)
    };
    let _ = write!(
        s,
        " residual RMS {} (noise {:.2} µm, {:.4} deg).",
        rms_change(&d.baseline.rms, &d.corrected.rms),
        d.noise.normal_um,
        d.noise.torsion_deg
    );
    for g in &d.degenerate {
        s += &format!(" Degenerate: {}", g.reason);
        if let Some(m) = g.separate_by {
            s += &format!("; to separate it: {m}");
        }
        s += ".";
    }
    s
}

fn unexplained_verdict(d: &Diagnosis, tried: &[Candidate]) -> String {
    let tried: Vec<&str> = tried.iter().map(|c| c.name()).collect();
    format!(
        "UNEXPLAINED: a systematic mismatch remains that no effect of the library explains: {}.{} No effect is named; E1 and nu1 are the baseline's.",
        where_(&d.remaining),
        if tried.is_empty() {
            String::new()
        } else {
            format!(" (the closest candidate, {}, leaves it.)", tried.join(" + "))
        }
    )
}

fn ambiguous_verdict(d: &Diagnosis) -> String {
    let alts: Vec<String> = d
        .ambiguous
        .iter()
        .map(|a| {
            format!("{} (dBIC {:.1}: E1 {:.4} MPa, nu1 {:.4})", a.effects.join(" + "), a.delta_bic, a.e1_mpa, a.nu1)
        })
        .collect();
    let mismatch = if d.mismatch.is_empty() { String::new() } else { format!("Mismatch: {}. ", where_(&d.mismatch)) };
    // One explanation alone: it is refused as degenerate (E1/nu1 can stand in for it).
    if let [only] = d.ambiguous.as_slice() {
        return format!(
            "{mismatch}AMBIGUOUS: {} explains the mismatch, but these sweeps cannot tell it from a change of E1/nu1 \
             (E1 {:.4} MPa, nu1 {:.4} with it); it is not named, and E1 and nu1 stay the calibration's.",
            only.effects.join(" + "),
            only.e1_mpa,
            only.nu1
        );
    }
    format!(
        "{mismatch}AMBIGUOUS: these sweeps cannot tell apart {}; none is named. {} with the best of them.",
        alts.join(" / "),
        best_alternative_change(d)
    )
}

fn named_verdict(d: &Diagnosis) -> String {
    let mut s = String::new();
    if !d.mismatch.is_empty() {
        s += &format!("Mismatch: {}. ", where_(&d.mismatch));
    } else {
        s += "The baseline residuals pass the whiteness tests, but a refit finds a significant effect. ";
    }
    for e in &d.explanation {
        s += e.sentence;
        s += " Fitted ";
        s += &e.params.iter().map(param).collect::<Vec<_>>().join(", ");
        s += ". ";
    }
    s += &estimate_change(&d.baseline, &d.corrected);
    s += ".";
    s
}

/// How the recorded standard errors entered the noise line.
fn standard_errors_note(e: &StandardErrors) -> String {
    let factor = |name: &str, k: Option<f64>| match k {
        Some(k) if k > 1.0 => Some(format!("{name} inflated x{k:.2} to the scatter between samples")),
        Some(_) => Some(format!("{name} as recorded")),
        None => None,
    };
    let parts: Vec<String> =
        [factor("gamma1", e.gamma1_factor), factor("theta1", e.theta1_factor)].into_iter().flatten().collect();
    let how = if e.inflated() { "; the recorded errors were too small" } else { "" };
    format!(" (per-sample standard errors, median shown: {}{how})", parts.join(", "))
}

/// The human report `easycalib diagnose` prints: noise floor, baseline,
/// mismatch, the effects with their parameters, the corrected estimate,
/// residuals, degeneracies, warnings, then the verdict.
pub fn report(d: &Diagnosis) -> String {
    let mut s = String::new();
    let b = &d.baseline;
    let c = &d.corrected;
    // Writing to a String cannot fail.
    let _ = writeln!(
        s,
        "Noise floor: gamma1 {:.2} µm, theta1 {:.4} deg{}",
        d.noise.normal_um,
        d.noise.torsion_deg,
        d.standard_errors.map(|e| standard_errors_note(&e)).unwrap_or_default()
    );
    let _ =
        writeln!(s, "Baseline (paper's physics, full-model fit): {}, z0 {:+.4} mm", estimate(b), b.contact_offset_mm);
    if d.mismatch.is_empty() {
        let _ = writeln!(s, "Mismatch: none beyond the noise floor");
    } else {
        let _ = writeln!(s, "Mismatch:");
        for m in &d.mismatch {
            let _ = writeln!(s, "  {:<14} {} {:.3} .. {:.3}: {}", m.phase, m.axis, m.from, m.to, m.shape);
        }
    }
    if d.unexplained {
        let _ = writeln!(s, "Explanation: UNEXPLAINED by the effect library; nothing is attributed");
    } else if d.effects.is_empty() {
        let _ = writeln!(s, "Explanation: no effect named");
    } else {
        for e in &d.explanation {
            let _ = writeln!(s, "Effect {}: {}", e.effect, e.sentence);
            for p in &e.params {
                let _ = writeln!(s, "  {}", param(p));
            }
        }
        let _ = writeln!(s, "Corrected: {}", estimate(c));
    }
    let _ = writeln!(s, "Residual RMS: {}", rms_change(&b.rms, &c.rms));
    for g in &d.degenerate {
        let _ = writeln!(s, "Degenerate: {}", g.reason);
        if let Some(m) = g.separate_by {
            let _ = writeln!(s, "  to separate it: {m}");
        }
    }
    for w in &d.warnings {
        let _ = writeln!(s, "Warning ({}): {}", w.code, w.message);
    }
    let _ = writeln!(s, "\n{}", d.verdict);
    s
}

/// The diagnosis in a few lines, for the end of `easycalib run`: the verdict's
/// headline, each named effect with its parameters, and the corrected E1, nu1
/// beside the diagnosis' baseline. `easycalib diagnose` prints the whole report.
pub fn brief(d: &Diagnosis) -> String {
    let mut s = if d.unexplained {
        format!(
            "UNEXPLAINED: a systematic mismatch remains that no effect of the library explains ({}); no effect \
             is named, E1 and nu1 stay the calibration's.\n",
            where_(&d.remaining)
        )
    } else if let [only] = d.ambiguous.as_slice() {
        format!(
            "AMBIGUOUS: {} explains the mismatch, but these sweeps cannot tell it from a change of E1/nu1; it is \
             not named, E1 and nu1 stay the calibration's (with it: {}).\n",
            only.effects.join(" + "),
            best_alternative_change(d)
        )
    } else if !d.ambiguous.is_empty() {
        let alts: Vec<String> = d.ambiguous.iter().map(|a| a.effects.join(" + ")).collect();
        format!(
            "AMBIGUOUS: these sweeps cannot tell apart {}; none is named, E1 and nu1 stay the calibration's \
             (the best of them: {}).\n",
            alts.join(" / "),
            best_alternative_change(d)
        )
    } else if d.effects.is_empty() {
        if d.mismatch.is_empty() {
            "CLEAN: no mismatch beyond the noise floor; no effect named.\n".to_string()
        } else {
            format!("CLEAN: no effect named (a refit removes the mismatch at {}).\n", where_(&d.mismatch))
        }
    } else {
        format!("EFFECTS: {}.\n", d.effects.join(", "))
    };
    if !d.unexplained && d.ambiguous.is_empty() {
        for e in &d.explanation {
            let _ = writeln!(s, "  {}: {}", e.effect, e.params.iter().map(param).collect::<Vec<_>>().join(", "));
        }
        if !d.effects.is_empty() {
            let _ = writeln!(s, "  corrected {}", estimate(&d.corrected));
            let _ = writeln!(s, "  baseline  {}", estimate(&d.baseline));
        }
    }
    for g in &d.degenerate {
        let _ = writeln!(s, "  {} cannot be told from E1/nu1 here (variance inflation {:.0})", g.effect, g.vif);
    }
    s
}

/// Why a run's report has no diagnosis: it was tried and failed.
pub fn not_made(why: &str) -> String {
    format!("NOT MADE: the diagnosis could not be made ({why}); the calibration stands as fitted.\n")
}
