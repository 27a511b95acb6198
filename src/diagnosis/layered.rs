//! The diagnosis of a recording whose declared layer the FE model takes
//! (docs/fem.md): the baseline is the layer model's own fit, so the numbers agree
//! with `fit`. The effect library is written on the half-space model and is not
//! searched here yet; a systematic remainder is reported as unexplained.

use sim::recording::{Phase, Recording};

use super::{Ci95, DiagnoseError, Diagnosis, FitSummary, Rms, SampleResidual, prose};
use crate::fit::full::{predict, residuals};
use crate::fit::{FitOptions, FullOptions, Warning, calibrate};
use crate::numerics::stats::rms;

pub fn diagnose_layered(rec: &Recording, noise_um: Option<f64>) -> Result<Diagnosis, DiagnoseError> {
    let opts = FitOptions {
        full: FullOptions { gamma1_sigma_mm: noise_um.map(|u| u * 1e-3), theta1_sigma_deg: None },
        ..Default::default()
    };
    let cal = calibrate(rec, &opts)?;
    let f = &cal.full;
    let p = f.params();
    let pred = predict(rec, &p)?;
    let r = residuals(rec, &pred);
    let rms_fit =
        Rms { normal_um: rms(&r.normal_mm) * 1e3, hold_um: rms(&r.hold_mm) * 1e3, torsion_deg: rms(&r.torsion_deg) };
    let noise = Rms {
        normal_um: f.noise_floor.normal_um,
        hold_um: f.noise_floor.normal_um,
        torsion_deg: f.noise_floor.torsion_deg,
    };
    let chi2 = {
        let sg = (f.noise_floor.normal_um * 1e-3).max(1e-6);
        let st = f.noise_floor.torsion_deg.max(1e-5);
        let s: f64 = r.normal_mm.iter().chain(&r.hold_mm).map(|v| (v / sg).powi(2)).sum::<f64>()
            + r.torsion_deg.iter().map(|v| (v / st).powi(2)).sum::<f64>();
        s / f.samples_used.saturating_sub(4).max(1) as f64
    };
    let summary = FitSummary {
        e1_mpa: f.e1_mpa,
        nu1: f.nu1,
        contact_offset_mm: f.contact_offset_mm,
        ci95: Ci95 { e1_mpa: f.ci95.e1_mpa, nu1: f.ci95.nu1 },
        rms: rms_fit,
        chi2_per_dof: chi2,
    };
    let unexplained = cal.warnings.iter().any(|w| w.code == "systematic_residuals");
    let residuals = rec
        .samples
        .iter()
        .zip(&pred)
        .map(|(s, q)| {
            let g = (s.gamma1_mm != 0.0).then_some(s.gamma1_mm - q.gamma1_mm);
            let t = (s.phase == Phase::Torsion).then_some(s.theta1_deg - q.theta1_deg);
            SampleResidual {
                t_s: s.t_s,
                torsion: s.phase == Phase::Torsion,
                gamma1_before_mm: g,
                gamma1_after_mm: g,
                theta1_before_deg: t,
                theta1_after_deg: t,
            }
        })
        .collect();
    let mut warnings = cal.warnings.clone();
    warnings.push(Warning::new(
        "layer_effects_not_searched",
        "the declared layer is fitted with the FE layer model; the effect library (written on the half-space \
         model) is not searched on it yet, so no effect is named",
    ));
    let verdict = prose::layered_verdict(unexplained, &summary, &noise, chi2, f.contact_friction);
    Ok(Diagnosis {
        effects: Vec::new(),
        unexplained,
        e1_mpa: f.e1_mpa,
        nu1: f.nu1,
        noise,
        standard_errors: None,
        baseline: summary.clone(),
        corrected: summary,
        mismatch: Vec::new(),
        remaining: Vec::new(),
        explanation: Vec::new(),
        degenerate: Vec::new(),
        ambiguous: Vec::new(),
        candidates: Vec::new(),
        segments_before: Vec::new(),
        segments_after: Vec::new(),
        verdict,
        warnings,
        residuals,
        profile: Default::default(),
    })
}
