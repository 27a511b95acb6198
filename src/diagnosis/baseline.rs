//! Steps 1 and 2 of the diagnosis, *compare* and *locate*: the paper's
//! physics fitted to the recording's own commanded history (started from the
//! full-model fit, else the paper's answer, else generic guesses), the noise
//! floors from its residuals, and the per-branch tests of the baseline.

use sim::recording::{Phase, Recording};

use super::locate::{self, Floor, Quantity, Segment, SegmentReport};
use super::model::{Base, Fitted, Model};
use super::{DiagnoseError, DiagnoseOptions, StandardErrors};
use crate::fit::ModelParams;
use crate::fit::fe_law::LayeredBase;
use crate::fit::full::fe_layer;
use crate::fit::weights::SampleSd;
use crate::fit::{Calibration, FitError, FitOptions, FullOptions, Warning, calibrate, fit_paper_or_widened};

/// The baseline of a diagnosis: the model weighted by the noise floors, its
/// fit without any effect, and where that fit's residuals are systematic.
pub(super) struct Baseline<'a> {
    pub model: Model<'a>,
    pub fit: Fitted,
    pub segs: Vec<Segment>,
    pub floor_g: Floor,
    pub floor_t: Floor,
    /// Per-branch statistics of the baseline.
    pub before: Vec<SegmentReport>,
    /// The full-model fit's warnings (empty when it failed).
    pub warnings: Vec<Warning>,
    /// How the recorded standard errors were used, when there are any.
    pub standard_errors: Option<StandardErrors>,
}

/// Where the baseline fit starts, and the noise the first fit is weighted with.
struct Starts {
    bases: Vec<Base>,
    sigma_g_mm: f64,
    sigma_t_deg: f64,
    warnings: Vec<Warning>,
    /// The declared layer's model the full fit ended on.
    layer: Option<LayeredBase>,
}

/// The calibration the diagnosis starts from (the full fit with the given
/// gamma1 noise, if any): made once per diagnosis, whatever passes follow.
pub(super) fn calibration(rec: &Recording, opts: &DiagnoseOptions) -> Result<Calibration, FitError> {
    calibrate(rec, &fit_options(opts.noise_um.map(|u| u * 1e-3)))
}

fn fit_options(sg_given: Option<f64>) -> FitOptions {
    FitOptions { full: FullOptions { gamma1_sigma_mm: sg_given, theta1_sigma_deg: None }, ..Default::default() }
}

/// Compare and locate: the baseline fit, the noise floors, the branch tests,
/// from the recording's calibration `cal` ([`calibration`]). On a declared
/// layer, `anchor` is where the layer model's friction correction is taken
/// (the full fit's optimum when `None`).
pub(super) fn compare<'a>(
    rec: &'a Recording,
    opts: &DiagnoseOptions,
    cal: &Result<Calibration, FitError>,
    anchor: Option<&ModelParams>,
) -> Result<Baseline<'a>, DiagnoseError> {
    let sg_given = opts.noise_um.map(|u| u * 1e-3);
    // A given gamma1 noise replaces that channel's recorded standard errors.
    let mut sd = SampleSd::of(rec);
    if sg_given.is_some() {
        sd.gamma1_mm = None;
    }
    let starts = start_points(rec, sg_given, cal, anchor)?;
    // With recorded errors, a channel's sigma is the factor on them: 1 to start.
    let sg0 = if sd.gamma1_mm.is_some() { 1.0 } else { starts.sigma_g_mm };
    let st0 = if sd.theta1_deg.is_some() { 1.0 } else { starts.sigma_t_deg };
    let mut model = Model::new(rec, sg0, st0).with_standard_errors(&sd);
    let mut warnings = starts.warnings;
    if let Some(layer) = starts.layer {
        model = model.on_layer(layer);
        warnings.push(Warning::new(
            "contact_effects_not_searched",
            "the declared layer is modelled with the FE layer model; only the effects that act outside the \
             contact (stage and mount play, frame compliance, thermal drift, the sensor's gain) are searched on \
             it: adhesion and creep are written on the half-space and are not",
        ));
    } else if fe_layer(rec).is_some() {
        return Err(DiagnoseError::Model);
    }
    model.max_iterations = opts.max_iterations.max(1);
    let base0 = starts.bases.iter().find_map(|b| model.fit(&[], &model.start(b))).ok_or(DiagnoseError::Model)?;

    // locate: noise floor from the baseline residuals, then the per-branch tests.
    let mut segs: Vec<Segment> = locate::segments(rec);
    locate::attach_standard_errors(&mut segs, &sd);
    let floor_of = |q: Quantity, recorded: bool| {
        if recorded {
            // Never below the recorded errors: only inflated when the scatter between samples asks for it.
            locate::standard_error_factor(rec, &base0.readings, &segs, q)
                .map(|f| Floor { sigma: f.sigma.max(1.0), ..f })
        } else {
            locate::noise_floor_dof(&locate::series(rec, &base0.readings, &segs, q))
                .map(|f| Floor { sigma: f.sigma.max(1e-6), ..f })
        }
    };
    let floor_g = sg_given
        .map(Floor::known)
        .or_else(|| floor_of(Quantity::Gamma1, sd.gamma1_mm.is_some()))
        .unwrap_or(Floor::known(sg0));
    let floor_t = floor_of(Quantity::Theta1, sd.theta1_deg.is_some()).unwrap_or(Floor::known(st0));
    model.sigma_g = floor_g.sigma;
    model.sigma_t = floor_t.sigma;
    let mut fit = model.fit(&[], &base0.x).ok_or(DiagnoseError::Model)?;
    model.finish(&mut fit);
    let before = locate::locate(rec, &fit.readings, &segs, floor_g, floor_t);
    let standard_errors = sd.any().then_some(StandardErrors {
        gamma1_factor: sd.gamma1_mm.as_ref().map(|_| floor_g.sigma),
        theta1_factor: sd.theta1_deg.as_ref().map(|_| floor_t.sigma),
    });
    Ok(Baseline { model, fit, segs, floor_g, floor_t, before, warnings, standard_errors })
}

/// Whether the recording has the samples a full-model fit needs at all.
fn full_fit_possible(rec: &Recording) -> bool {
    rec.phase(Phase::Torsion).count() >= 3 && rec.phase(Phase::Normal).filter(|s| s.gamma1_mm != 0.0).count() >= 5
}

/// Starts: the full-model fit, else the paper's answer, else generic guesses
/// (a recording far from the paper's physics can defeat both fits).
fn start_points(
    rec: &Recording,
    sg_given: Option<f64>,
    cal: &Result<Calibration, FitError>,
    anchor: Option<&ModelParams>,
) -> Result<Starts, DiagnoseError> {
    // compare: the full-model fit gives the start; refit on the true-rig model with our weights.
    let fit_opts = fit_options(sg_given);
    let mut starts = Vec::new();
    let (mut sg0, mut st0) = (sg_given.unwrap_or(sim::defaults::GAMMA1_SIGMA_MM), sim::defaults::THETA1_SIGMA_DEG);
    let pos = |v: f64, d: f64| if v.is_finite() && v > 0.0 { v } else { d };
    let mut warnings = Vec::new();
    let mut fallback = true;
    let mut pinned_start: Option<Base> = None;
    let mut layer = None;
    match cal {
        Ok(c) => {
            // A declared layer: the contact is the layer model the fit ended on.
            layer = LayeredBase::of(rec, &c.full, anchor)?;
            warnings = c.warnings.clone();
            sg0 = sg_given.unwrap_or(pos(c.full.noise_floor.normal_um * 1e-3, sg0));
            st0 = pos(c.full.noise_floor.torsion_deg, st0);
            // A fit pinned at a bound of nu1 is a poor start: keep it, but try the others too.
            fallback = c.warnings.iter().any(|w| w.code == "nu1_at_bound");
            let start = Base {
                e1_mpa: c.full.e1_mpa,
                nu1: c.full.nu1.clamp(0.05, 0.49),
                contact_offset_mm: c.full.contact_offset_mm,
            };
            if fallback {
                pinned_start = Some(start);
            } else {
                starts.push(start);
            }
        }
        Err(FitError::Implausible(e)) => return Err(FitError::Implausible(e.clone()).into()),
        Err(first) => {
            if !full_fit_possible(rec) {
                return Err(first.clone().into());
            }
        }
    }
    if fallback {
        if let Ok((p, _)) = fit_paper_or_widened(rec, &fit_opts.paper)
            && p.e1_mpa.is_finite()
            && p.e1_mpa > 0.0
        {
            starts.push(Base { e1_mpa: p.e1_mpa, nu1: p.nu1.clamp(0.05, 0.49), contact_offset_mm: 0.0 });
        }
        for m in crate::fit::start_points::stiffness_ladder(rec.meta.indenter.e_mpa) {
            starts.push(Base { e1_mpa: m.e1_mpa, nu1: m.nu1, contact_offset_mm: 0.0 });
        }
        starts.extend(pinned_start);
    }
    Ok(Starts { bases: starts, sigma_g_mm: sg0, sigma_t_deg: st0, warnings, layer })
}
