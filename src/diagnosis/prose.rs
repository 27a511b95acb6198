//! The diagnosis in words: the verdict, and the reasons an effect is reported
//! degenerate.

use super::model::Candidate;
use super::{Diagnosis, Mismatch};

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
    let b = &d.baseline;
    let c = &d.corrected;
    let rms = format!(
        "residual RMS normal {:.2} -> {:.2} µm, hold {:.2} -> {:.2} µm, torsion {:.4} -> {:.4} deg (noise {:.2} µm, {:.4} deg)",
        b.rms.normal_um,
        c.rms.normal_um,
        b.rms.hold_um,
        c.rms.hold_um,
        b.rms.torsion_deg,
        c.rms.torsion_deg,
        d.noise.normal_um,
        d.noise.torsion_deg
    );
    let mut s = if d.unexplained {
        let tried: Vec<String> = tried.iter().map(|c| c.name().to_string()).collect();
        format!(
            "UNEXPLAINED: a systematic mismatch remains that no effect of the library explains: {}.{} No effect is named; E1 and nu1 are the baseline's.",
            where_(&d.remaining),
            if tried.is_empty() {
                String::new()
            } else {
                format!(" (the closest candidate, {}, leaves it.)", tried.join(" + "))
            }
        )
    } else if !d.ambiguous.is_empty() {
        let alts: Vec<String> = d
            .ambiguous
            .iter()
            .map(|a| {
                format!("{} (dBIC {:.1}: E1 {:.4} MPa, nu1 {:.4})", a.effects.join(" + "), a.delta_bic, a.e1_mpa, a.nu1)
            })
            .collect();
        format!(
            "{}AMBIGUOUS: these sweeps cannot tell apart {}; none is named. E1 {:.4} -> {:.4} MPa, nu1 {:.4} -> {:.4} with the best of them.",
            if d.mismatch.is_empty() { String::new() } else { format!("Mismatch: {}. ", where_(&d.mismatch)) },
            alts.join(" / "),
            b.e1_mpa,
            c.e1_mpa,
            b.nu1,
            c.nu1
        )
    } else if d.effects.is_empty() {
        if d.mismatch.is_empty() {
            "No mismatch beyond the noise floor; no effect named.".to_string()
        } else {
            "No effect named.".to_string()
        }
    } else {
        let mut s = String::new();
        if !d.mismatch.is_empty() {
            s += &format!("Mismatch: {}. ", where_(&d.mismatch));
        } else {
            s += "The baseline residuals pass the whiteness tests, but a refit finds a significant effect. ";
        }
        for e in &d.explanation {
            s += e.sentence;
            s += " Fitted ";
            s += &e
                .params
                .iter()
                .map(|p| {
                    let f = |v: Option<f64>| v.map_or("open".to_string(), |v| format!("{v:.4}"));
                    format!(
                        "{} = {:.4} {} [{}, {}]{}",
                        p.name,
                        p.value,
                        p.unit,
                        f(p.ci95[0]),
                        f(p.ci95[1]),
                        if p.well_determined { "" } else { " (weakly determined by these sweeps)" }
                    )
                })
                .collect::<Vec<_>>()
                .join(", ");
            s += ". ";
        }
        s += &format!("E1 {:.4} -> {:.4} MPa, nu1 {:.4} -> {:.4}.", b.e1_mpa, c.e1_mpa, b.nu1, c.nu1);
        s
    };
    s += &format!(" {rms}.");
    for g in &d.degenerate {
        s += &format!(" Degenerate: {}", g.reason);
        if let Some(m) = g.separate_by {
            s += &format!("; to separate it: {m}");
        }
        s += ".";
    }
    s
}
