//! Step 4 of the diagnosis, the result: the fits of the baseline and of the
//! chosen model turned into the schema (summaries with intervals, where the
//! mismatch is and what remains, the effects named and their parameters, the
//! residuals before and after, the sim profile) and the verdict.

use sim::effects::Reading;
use sim::recording::{Phase, Recording};

use super::baseline::Baseline;
use super::locate::{self, Floor, Quantity, Segment, SegmentReport};
use super::model::{Candidate, Fitted};
use super::search::{Search, chi2_crit};
use super::{
    Alternative, Ci95, DiagnoseError, Diagnosis, Explained, FitSummary, Mismatch, ParamEstimate, Rms, SampleResidual,
    prose,
};
use crate::numerics::stats::t_quantile_975;

/// The diagnosis from the baseline and the search's outcome.
pub(super) fn diagnosis(rec: &Recording, base: Baseline, search: Search) -> Result<Diagnosis, DiagnoseError> {
    let Baseline { model, fit: baseline, segs, floor_g, floor_t, before, warnings, standard_errors } = base;
    let Search { scores, mut ambiguous, degenerate, last, closest } = search;
    let after = locate::locate(rec, &last.readings, &segs, floor_g, floor_t);
    let mismatch = located_mismatch(rec, &baseline, &last, &segs, [floor_g, floor_t], &before, &after);
    let mut remaining = mismatches(&after);
    // The best explanation refused only because E1/nu1 can stand in for it
    // (degenerate) does explain what the baseline leaves: that is not a
    // mismatch no effect explains, but one these sweeps cannot attribute
    // (on a declared layer, a frame compliance of 4 µm/N left curvature
    // the compliance removed to chi²/dof 1.09, refused at variance inflation
    // 4000; docs/diagnosis.md, "Degenerate is not unexplained").
    let refused = last.cands.is_empty()
        && !closest.cands.is_empty()
        && closest.cands.iter().all(|c| degenerate.iter().any(|g| g.effect == c.name()));
    if refused && !remaining.is_empty() {
        let after_closest = locate::locate(rec, &closest.readings, &segs, floor_g, floor_t);
        if mismatches(&after_closest).is_empty() {
            remaining.clear();
            if ambiguous.is_empty() {
                let s = summary(rec, &closest);
                ambiguous.push(Alternative {
                    effects: closest.cands.iter().map(|c| c.name()).collect(),
                    delta_bic: 0.0,
                    e1_mpa: s.e1_mpa,
                    nu1: s.nu1,
                    ci95: s.ci95,
                });
            }
        }
    }
    let unexplained = !remaining.is_empty();
    // Never a forced attribution: when structure remains, or the data cannot
    // rank the explanations, nothing is named.
    let final_fit = if unexplained { &baseline } else { &last };
    let (mut effects, mut explanation) = if unexplained || !ambiguous.is_empty() {
        (Vec::new(), Vec::new())
    } else {
        (last.cands.iter().map(|c| c.name()).collect(), explained(final_fit))
    };
    // contact_offset is every fit's z0: named when it is significant at the same
    // guard. A recording whose stage zero the run already moved to the clean
    // model's z0 (docs/run.md, "Stage zero") has no recorded zero left to
    // judge: what z0 the effects' fit finds is that model's own correction.
    let zero_moved = rec.meta.extra.iter().any(|(k, _)| k == crate::fit::zero::ZERO_MOVED_KEY);
    if !unexplained
        && !zero_moved
        && let Some(e) = contact_offset(final_fit, rec.meta.contact_sd_mm())
    {
        effects.insert(0, e.effect);
        explanation.insert(0, e);
    }
    let profile = model.profile(&final_fit.cands, &final_fit.x).ok_or(DiagnoseError::Model)?;
    let residuals = sample_residuals(rec, &baseline, &last);
    let (g_mm, t_deg) = (model.noise_gamma1_mm(), model.noise_theta1_deg());
    let noise = Rms { normal_um: g_mm * 1e3, hold_um: g_mm * 1e3, torsion_deg: t_deg };
    let fin = summary(rec, final_fit);
    let mut d = Diagnosis {
        effects,
        unexplained,
        e1_mpa: fin.e1_mpa,
        nu1: fin.nu1,
        noise,
        standard_errors,
        baseline: summary(rec, &baseline),
        corrected: summary(rec, &last),
        mismatch,
        remaining,
        explanation,
        degenerate,
        ambiguous,
        candidates: scores,
        segments_before: before,
        segments_after: after,
        verdict: String::new(),
        warnings,
        residuals,
        profile,
    };
    if let Some(layer) = model.layer() {
        // Nothing named: no effect, or explanations the sweeps cannot rank.
        let nothing_named = final_fit.cands.is_empty() || !d.ambiguous.is_empty();
        layered_estimates(&mut d, layer, nothing_named);
    }
    d.verdict = prose::verdict(&d, &last.cands);
    Ok(d)
}

/// On a declared layer (docs/diagnosis.md, "On a declared layer"): with no
/// effect named (none found, or several the sweeps cannot rank) the estimate
/// is the full fit's, so `diagnose` and `fit` agree (the
/// refits here hold the fit's friction; the fit itself also fits it); with
/// one, the refit's intervals carry the layer model's own error in
/// quadrature, as the fit's do, and are never narrower than the fit's.
fn layered_estimates(d: &mut Diagnosis, layer: &crate::fit::fe_law::LayeredBase, nothing_named: bool) {
    let [(e1, e1_ci), (nu1, nu1_ci)] = layer.fitted();
    if nothing_named {
        (d.e1_mpa, d.nu1) = (e1, nu1);
        for s in [&mut d.baseline, &mut d.corrected] {
            (s.e1_mpa, s.nu1, s.ci95) = (e1, nu1, Ci95 { e1_mpa: e1_ci, nu1: nu1_ci });
        }
        return;
    }
    // A parameter added to a fit can only widen its intervals; the refits
    // here hold the friction the fit also fitted, so the corrected interval is
    // never narrower than the fit's own.
    let [sd_e1, sd_nu1] = layer.relative_model_sd();
    let c = &mut d.corrected;
    let widen = |ci: [f64; 2], v: f64, sd: f64, fit: [f64; 2]| {
        let half = (0.5 * (ci[1] - ci[0])).hypot(1.96 * sd * v).max(0.5 * (fit[1] - fit[0]));
        [v - half, v + half]
    };
    let nu1 = widen(c.ci95.nu1, c.nu1, sd_nu1, nu1_ci).map(|v| v.clamp(0.0, 0.5));
    c.ci95 = Ci95 { e1_mpa: widen(c.ci95.e1_mpa, c.e1_mpa, sd_e1, e1_ci), nu1 };
}

/// Where the baseline's residuals are systematic. A concealed effect can stay
/// below the branch tests (a theta1 floor from ~80 samples is uncertain by
/// ~11 %), yet the correction removes structure from one branch: that branch
/// is where the mismatch is.
fn located_mismatch(
    rec: &Recording,
    baseline: &Fitted,
    last: &Fitted,
    segs: &[Segment],
    [floor_g, floor_t]: [Floor; 2],
    before: &[SegmentReport],
    after: &[SegmentReport],
) -> Vec<Mismatch> {
    let mut mismatch = mismatches(before);
    if after.iter().any(|r| r.systematic) || last.cands.is_empty() {
        return mismatch;
    }
    for seg in segs {
        let fl = if seg.quantity == Quantity::Gamma1 { floor_g } else { floor_t };
        if mismatch.iter().any(|m| m.phase == seg.phase && m.quantity == seg.quantity) {
            continue;
        }
        if locate::chi2_gain(rec, &baseline.readings, &last.readings, seg, fl) > chi2_crit(1)
            && let Some(r) = locate::describe(rec, &baseline.readings, seg, fl)
        {
            let mut m = mismatches(std::slice::from_ref(&SegmentReport { systematic: true, ..r }));
            mismatch.append(&mut m);
        }
    }
    mismatch
}

/// The fitted stage zero z0 as an explanation when it is significant at the
/// guard. A recorder that declares how well it found the first contact
/// (`contact_sd_mm`: a rig's approach step) expects an offset of that size:
/// z0 is then judged against both errors, and named only beyond them.
fn contact_offset(fit: &Fitted, contact_sd_mm: Option<f64>) -> Option<Explained> {
    let (z0, z0_se) = (fit.base().contact_offset_mm, fit.se(2));
    let expected = z0_se.hypot(contact_sd_mm.unwrap_or(0.0));
    if !(z0_se.is_finite() && z0_se > 0.0 && (z0 / expected).powi(2) > chi2_crit(1)) {
        return None;
    }
    let t = t_quantile_975(fit.dof);
    let info = &sim::effects::contact_offset::INFO;
    Some(Explained {
        effect: info.name,
        sentence: info.sentence,
        params: vec![ParamEstimate {
            name: "z0_mm",
            unit: "mm",
            value: z0,
            ci95: [Some(z0 - t * z0_se), Some(z0 + t * z0_se)],
            well_determined: 2.0 * t * z0_se < z0.abs(),
        }],
    })
}

fn sample_residuals(rec: &Recording, baseline: &Fitted, last: &Fitted) -> Vec<SampleResidual> {
    rec.samples
        .iter()
        .enumerate()
        .map(|(i, s)| SampleResidual {
            t_s: s.t_s,
            torsion: s.phase == Phase::Torsion,
            gamma1_before_mm: locate::residual(rec, &baseline.readings, i, Quantity::Gamma1),
            gamma1_after_mm: locate::residual(rec, &last.readings, i, Quantity::Gamma1),
            theta1_before_deg: locate::residual(rec, &baseline.readings, i, Quantity::Theta1),
            theta1_after_deg: locate::residual(rec, &last.readings, i, Quantity::Theta1),
        })
        .collect()
}

fn rms_of(rec: &Recording, pred: &[Reading]) -> Rms {
    let mut n = (0.0, 0usize);
    let mut h = (0.0, 0usize);
    let mut t = (0.0, 0usize);
    for (i, s) in rec.samples.iter().enumerate() {
        if let Some(r) = locate::residual(rec, pred, i, Quantity::Gamma1) {
            let acc = if s.phase == Phase::Normal { &mut n } else { &mut h };
            acc.0 += r * r;
            acc.1 += 1;
        }
        if let Some(r) = locate::residual(rec, pred, i, Quantity::Theta1) {
            t.0 += r * r;
            t.1 += 1;
        }
    }
    let f = |a: (f64, usize)| if a.1 == 0 { 0.0 } else { (a.0 / a.1 as f64).sqrt() };
    Rms { normal_um: f(n) * 1e3, hold_um: f(h) * 1e3, torsion_deg: f(t) }
}

/// One model's fit of the recording: E1, nu1, z0 with intervals, RMS residuals, chi²/dof.
pub(super) fn summary(rec: &Recording, fit: &Fitted) -> FitSummary {
    let b = fit.base();
    let t = t_quantile_975(fit.dof);
    let (s0, s1) = (fit.se(0), fit.se(1));
    let nu = |x: f64| 0.5 / (1.0 + (-x).exp());
    FitSummary {
        e1_mpa: b.e1_mpa,
        nu1: b.nu1,
        contact_offset_mm: b.contact_offset_mm,
        ci95: Ci95 {
            e1_mpa: [(fit.x[0] - t * s0).exp(), (fit.x[0] + t * s0).exp()],
            nu1: [nu(fit.x[1] - t * s1), nu(fit.x[1] + t * s1)],
        },
        rms: rms_of(rec, &fit.readings),
        chi2_per_dof: fit.chi2 / fit.dof as f64,
    }
}

fn mismatches(reports: &[SegmentReport]) -> Vec<Mismatch> {
    reports
        .iter()
        .filter(|r| r.systematic)
        .map(|r| Mismatch {
            phase: r.phase,
            quantity: r.quantity,
            axis: r.axis,
            from: r.from,
            to: r.to,
            shape: r.shape.clone(),
            rms: r.rms,
        })
        .collect()
}

/// The named effects of `fit` with their parameters' values and 95 % intervals.
fn explained(fit: &Fitted) -> Vec<Explained> {
    let t = t_quantile_975(fit.dof);
    fit.cands
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let off = fit.offset_of(k);
            let params = c
                .param_names()
                .iter()
                .enumerate()
                .map(|(j, &(name, unit))| estimate(*c, j, name, unit, fit.x[off + j], t * fit.se(off + j)))
                .collect();
            Explained { effect: c.name(), sentence: c.info().sentence, params }
        })
        .collect()
}

/// Parameter `j` of candidate `c` at internal value `x`, its 95 % interval
/// `x ± half` mapped to physical units.
fn estimate(c: Candidate, j: usize, name: &'static str, unit: &'static str, x: f64, half: f64) -> ParamEstimate {
    let value = c.physical(j, x);
    let ends = [c.physical(j, x - half), c.physical(j, x + half)];
    // Reciprocal parametrisations (h, mu) flip and open up when 1/x reaches 0.
    let recip = matches!(c, Candidate::FiniteThickness | Candidate::PartialSlip);
    let (mut lo, mut hi) = (ends[0].min(ends[1]), ends[0].max(ends[1]));
    let mut open_hi = !hi.is_finite();
    if recip && x - half <= 0.0 {
        lo = ends[1];
        hi = f64::INFINITY;
        open_hi = true;
    }
    // Never report an interval end outside what the model accepts.
    if let Some(b) = c.info().params.iter().find(|b| b.name == name) {
        lo = lo.max(b.min);
        if hi > b.max {
            hi = b.max;
        }
    }
    let lo_v = lo.is_finite().then_some(lo);
    let hi_v = (!open_hi && hi.is_finite()).then_some(hi);
    let width = hi - lo;
    let well = lo_v.is_some() && hi_v.is_some() && width < value.abs().max(1e-300);
    ParamEstimate { name, unit, value, ci95: [lo_v, hi_v], well_determined: well }
}
