//! The full-model fit: E1, nu1 and the contact-point offset z0 fitted directly
//! against the forward model (Hertz–Tatara–Yoffe normal contact, Jäger torsion
//! with the rod correction) over every sample of both sweeps (docs/physics.md 1.6).
//! Unlike the paper's reduced relations it has no truncated series, no
//! nuisance H2 and no fixed beta: the torsion depth comes from the model's own
//! gamma2 at the torsion stage position.

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::Serialize;
use sim::physics::{Body, ContactPair, Layer, LayerBase, NormalModel, torsion_at};
use sim::recording::{Phase, Recording, Sample};

use super::weights::SampleSd;
use super::{FitError, Warning, start_points};
use crate::numerics::lm::{self, LmOptions, LmResult};
use crate::numerics::stats::{interval, noise_from_second_differences, r_squared, rms};

#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct FullOptions {
    /// Noise of gamma1 readings, mm; estimated from the data when `None`.
    pub gamma1_sigma_mm: Option<f64>,
    /// Noise of theta1 readings, degrees; estimated from the data when `None`.
    pub theta1_sigma_deg: Option<f64>,
}

/// Parameters of the clean forward model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ModelParams {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    /// Stage reading at true first contact, mm (true approach = stage - z0).
    pub contact_offset_mm: f64,
    /// Coulomb friction between indenter and gel in torsion (the FE layer model
    /// only; `None`: the contact sticks).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact_friction: Option<f64>,
    /// The FE layer model at large strain: the linear layer model times the
    /// large-strain ratios of the project's neo-Hookean reference (docs/physics.md,
    /// "Large strain"). Not a fitted parameter: the fit tries both and keeps the better.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub large_strain: bool,
}

/// The model's reading for one sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Prediction {
    pub gamma1_mm: f64,
    /// Predicted theta1 (torsion samples), degrees; 0 in the normal phase.
    pub theta1_deg: f64,
    /// Torsion depth gamma2 / R2 the model has at this sample.
    pub beta: f64,
}

/// Forward-predict every sample of `rec` with the given parameters (with a
/// declared layer: the tabulated frictionless FE law plus what friction adds
/// to the FE model there; docs/fem.md, "The tabulated law").
pub fn predict(rec: &Recording, p: &ModelParams) -> Result<Vec<Prediction>, FitError> {
    predict_with(rec, p, friction_at(rec, p)?.as_ref())
}

use super::layer_model::{Correction, friction_at, friction_correction, friction_correction_in_friction, predict_fe};

/// [`predict`], or with a declared layer and `correction`, the tabulated
/// frictionless law plus the correction as it stands at `p` (linear about
/// where it was taken).
fn predict_with(
    rec: &Recording,
    p: &ModelParams,
    correction: Option<&Correction>,
) -> Result<Vec<Prediction>, FitError> {
    if let Some(layer) = fe_layer(rec) {
        return match correction {
            None => predict(rec, p),
            Some(c) => predict_fe(rec, p, layer).map(|mut pred| {
                let r2 = rec.meta.indenter.r_mm;
                for (q, (dg, dt)) in pred.iter_mut().zip(c.at(p)) {
                    // The gel's deflection grows by what friction adds, the
                    // indenter's deformation (beta) shrinks by it.
                    q.gamma1_mm += dg;
                    q.beta -= dg / r2;
                    q.theta1_deg += dt;
                }
                pred
            }),
        };
    }
    let pair =
        ContactPair { elastomer: Body::new(p.e1_mpa, p.nu1, rec.meta.elastomer_r_mm), indenter: rec.meta.indenter };
    let model = NormalModel::new(pair)?;
    let mut out = Vec::with_capacity(rec.samples.len());
    // A sweep visits each stage position on loading and again on unloading,
    // and the torsion sweep holds one: solve each distinct position once.
    let mut solved: HashMap<u64, sim::physics::NormalState> = HashMap::with_capacity(rec.samples.len() / 2 + 1);
    for s in &rec.samples {
        let state = match solved.entry(s.stage_mm.to_bits()) {
            Entry::Occupied(e) => *e.get(),
            Entry::Vacant(e) => {
                let st = model.solve(s.stage_mm - p.contact_offset_mm)?;
                *e.insert(st)
            }
        };
        let beta = state.gamma2_mm / pair.indenter.r_mm;
        let theta1_deg = match s.phase {
            Phase::Normal => 0.0,
            Phase::Torsion => torsion_at(&pair, beta, s.rot_deg.to_radians()).theta1_rad.to_degrees(),
        };
        out.push(Prediction { gamma1_mm: state.gamma1_mm, theta1_deg, beta });
    }
    Ok(out)
}

/// The declared layer when the finite-element model takes it (a flat gel,
/// bonded to its window or sliding on it).
pub fn fe_layer(rec: &Recording) -> Option<Layer> {
    rec.meta.layer.filter(|_| rec.meta.elastomer_r_mm.is_infinite())
}

/// Residuals per group, in time order.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Residuals {
    /// gamma1 residuals of the normal sweep (dead-band zeros excluded), mm.
    pub normal_mm: Vec<f64>,
    /// gamma1 residuals while the torsion sweep holds the depth, mm.
    pub hold_mm: Vec<f64>,
    /// theta1 residuals of the torsion sweep, degrees.
    pub torsion_deg: Vec<f64>,
}

pub fn residuals(rec: &Recording, pred: &[Prediction]) -> Residuals {
    let mut r = Residuals::default();
    for (s, p) in rec.samples.iter().zip(pred) {
        match s.phase {
            Phase::Normal => {
                if s.gamma1_mm != 0.0 {
                    r.normal_mm.push(s.gamma1_mm - p.gamma1_mm);
                }
            }
            Phase::Torsion => {
                if s.gamma1_mm != 0.0 {
                    r.hold_mm.push(s.gamma1_mm - p.gamma1_mm);
                }
                r.torsion_deg.push(s.theta1_deg - p.theta1_deg);
            }
        }
    }
    r
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GroupFigures {
    /// gamma1 over the normal sweep, µm.
    pub normal_um: f64,
    /// theta1 over the torsion sweep, degrees.
    pub torsion_deg: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FullFit {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    pub contact_offset_mm: f64,
    #[serde(rename = "E1_MPa_se")]
    pub e1_se: f64,
    pub nu1_se: f64,
    pub contact_offset_se_mm: f64,
    pub ci95: FullCi95,
    #[serde(rename = "corr_E1_nu1")]
    pub corr_e1_nu1: f64,
    /// Torsion depth the fitted model reaches at the torsion stage position.
    pub beta: f64,
    /// Residual RMS per sweep.
    pub rms: GroupFigures,
    /// Noise floor per sweep, estimated from second differences of the residuals.
    pub noise_floor: GroupFigures,
    /// R² of gamma1 (normal) and theta1 (torsion).
    pub r2: R2,
    /// chi²/dof of the fit weighted by the recording's per-sample standard
    /// errors (absent when the recording has none); the covariance is scaled
    /// by max(1, chi²/dof).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub chi2_dof: Option<f64>,
    pub iterations: usize,
    pub converged: bool,
    pub samples_used: usize,
    /// The contact model fitted: `half-space` (the paper's), `layer-fe` (a
    /// declared bonded layer, linear elasticity) or `layer-fe-large-strain`.
    pub model: &'static str,
    /// Whether the layer model was taken at large strain.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub large_strain: bool,
    /// Fitted Coulomb friction in torsion (layer model only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact_friction: Option<f64>,
    /// The least-squares estimator's own second-order bias at this
    /// recording's noise (Box 1971; the layer model only; docs/physics.md,
    /// "The estimator's bias"): what the estimate is expected to lean by. It is
    /// reported, not removed (on the dev set it is a few hundredths of a
    /// percent, below what removing it costs in spread).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub curvature_bias: Option<CurvatureBias>,
    /// What the reader of this estimate should know (a bound reached, no convergence).
    pub warnings: Vec<Warning>,
    /// The fitted model's reading of every sample (recording order): what the
    /// choice between strain models judges the fits by (`super::choice`).
    #[serde(skip)]
    pub predictions: Vec<Prediction>,
}

/// The layer fit's second-order bias (Box's), in the fitted parameters: the
/// expected estimate minus the truth, to second order in the noise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CurvatureBias {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    pub contact_offset_mm: f64,
    /// Absent when the contact sticks and the friction is not determined.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub contact_friction: Option<f64>,
}

/// The full fit's 95 % intervals: E1 and nu1 as in [`super::Ci95`], and the
/// contact offset it fits with them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FullCi95 {
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: [f64; 2],
    pub nu1: [f64; 2],
    pub contact_offset_mm: [f64; 2],
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct R2 {
    pub normal: f64,
    pub torsion: f64,
}

/// Relative model error of the FE layer model (one standard deviation), added to
/// the intervals: the RMS error of its recoveries over the eight small-strain
/// recordings of the independent finite-element dev set (1.1 % in E1, 1.4 % in
/// nu1, noise included; docs/physics.md, "Finite-element reference").
const LAYER_MODEL_SD_E1: f64 = 0.011;
const LAYER_MODEL_SD_NU1: f64 = 0.014;

/// The layer model's own approximation error, relative, one standard
/// deviation, of E1 and nu1 on recording `rec` at `p`: the linear model's
/// above, or the large-strain model's (`super::large_strain::model_sd`, which
/// grows where the sweep goes deeper than its table); on a sliding base, in
/// quadrature, what the bonded gel's large-strain correction misses there
/// ([`SLIDING_SD_PER_R2`]). Added in quadrature to the intervals of the fit
/// and of the diagnosis's refits on a layer.
pub(super) fn layer_model_sd(rec: &Recording, p: &ModelParams) -> [f64; 2] {
    let [e1, nu1] =
        if p.large_strain { super::large_strain::model_sd(rec, p) } else { [LAYER_MODEL_SD_E1, LAYER_MODEL_SD_NU1] };
    match fe_layer(rec) {
        Some(l) if l.base == LayerBase::Sliding => {
            let depth = deepest_over_r2(rec, p);
            let [ke, kn] = SLIDING_SD_PER_R2[usize::from(p.large_strain)];
            [e1.hypot(ke * depth), nu1.hypot(kn * depth)]
        }
        _ => [e1, nu1],
    }
}

/// The deepest approach of the recording at `p`, in indenter radii.
pub(super) fn deepest_over_r2(rec: &Recording, p: &ModelParams) -> f64 {
    rec.samples.iter().map(|s| s.stage_mm - p.contact_offset_mm).fold(0.0, f64::max) / rec.meta.indenter.r_mm
}

/// The model error, relative, one standard deviation per unit of the
/// deepest approach over R2, of E1 and nu1 on a gel sliding on its window:
/// [the small-strain model, the large-strain one]. The large-strain
/// correction is tabulated on bonded gels only, and a sliding gel is softer
/// at depth and strains further (the pair below reaches beta 0.18 at a
/// 3.1 mm approach on a sliding gel, beta 0.2 at 1.75 mm on a bonded one). Measured on noiseless sweeps of the project's own
/// neo-Hookean reference of a sliding 5 mm gel (E2/E1 2, nu1 0.48, nu2 0.4)
/// to beta 0.05, 0.1, 0.15 and 0.18 (delta/R2 0.14-0.63), fitted by each
/// model: the small-strain one E1 -2.4 to -12.5 %, nu1 +1.4 to -62 %; with
/// the bonded gel's ratios E1 -0.4 to +1.7 %, nu1 +0.5 to -17.7 %; the
/// constants bound each measured miss per unit depth (docs/physics.md,
/// "A gel sliding on its window").
const SLIDING_SD_PER_R2: [[f64; 2]; 2] = [[0.35, 1.0], [0.08, 0.35]];

/// Distance from either end of nu1's range (0, 0.5) at which the fit counts as pinned.
const NU1_EDGE: f64 = 0.005;

/// An interval cut at the parameter's physical range.
fn clip(ci: [f64; 2], range: [f64; 2]) -> [f64; 2] {
    [ci[0].max(range[0]), ci[1].min(range[1])]
}

fn logit(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}
fn logistic(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Internal parametrisation keeps E1 > 0, 0 < nu1 < 0.5 (and mu > 0) without bounds.
fn to_internal(p: &ModelParams) -> Vec<f64> {
    let mut x = vec![p.e1_mpa.ln(), logit(p.nu1 / 0.5), p.contact_offset_mm];
    x.extend(p.contact_friction.map(f64::ln));
    x
}
fn from_internal(x: &[f64], like: &ModelParams) -> ModelParams {
    ModelParams {
        e1_mpa: x[0].exp(),
        nu1: 0.5 * logistic(x[1]),
        contact_offset_mm: x[2],
        contact_friction: x.get(3).map(|v| v.min(FRICTION_MAX.ln()).exp()),
        large_strain: like.large_strain,
    }
}

/// The largest friction coefficient the fit takes. Far below it the contact
/// already sticks through every twist a sweep makes (at 1195 the twist of
/// the neo-Hookean tableI_2 no longer depended on it; docs/physics.md), so
/// above it the residuals do not move and a search into the full-stick basin
/// stops there. Unbounded, ln(friction) ran to 700 and the friction to
/// infinity, where the correction's slope times its move is infinity times
/// zero and every residual NaN (a start at E1 0.5 MPa, nu1 0.39, friction 3
/// on the emulated unloading run ended so).
const FRICTION_MAX: f64 = 1e6;

fn from_physical(v: &[f64], like: &ModelParams) -> ModelParams {
    ModelParams {
        e1_mpa: v[0],
        nu1: v[1],
        contact_offset_mm: v[2],
        contact_friction: v.get(3).copied(),
        large_strain: like.large_strain,
    }
}

/// The noise each sample's residuals are divided by: the recording's own
/// standard errors where it carries them, else one floor per channel.
#[derive(Debug, Clone)]
struct Sigmas {
    gamma1_mm: Vec<f64>,
    theta1_deg: Vec<f64>,
    /// Whether a channel is weighted by recorded standard errors.
    recorded: bool,
}

impl Sigmas {
    fn new(sd: &SampleSd, n: usize, sg: f64, st: f64) -> Self {
        Sigmas {
            gamma1_mm: sd.gamma1_mm.clone().unwrap_or_else(|| vec![sg; n]),
            theta1_deg: sd.theta1_deg.clone().unwrap_or_else(|| vec![st; n]),
            recorded: sd.any(),
        }
    }
}

/// The recording's standard errors the fit weighs by: a noise given in the
/// options replaces its channel's.
fn recorded_errors(rec: &Recording, opts: &FullOptions) -> SampleSd {
    let mut sd = SampleSd::of(rec);
    if opts.gamma1_sigma_mm.is_some() {
        sd.gamma1_mm = None;
    }
    if opts.theta1_sigma_deg.is_some() {
        sd.theta1_deg = None;
    }
    sd
}

/// Weighted residual vector: gamma1 of every sample (dead band included: it pins z0),
/// then theta1 of every torsion sample, each divided by its sample's noise.
fn weighted_residuals(
    rec: &Recording,
    p: &ModelParams,
    correction: Option<&Correction>,
    sig: &Sigmas,
    out: &mut Vec<f64>,
) -> bool {
    let Ok(pred) = predict_with(rec, p, correction) else {
        return false;
    };
    out.clear();
    for ((s, q), sg) in rec.samples.iter().zip(&pred).zip(&sig.gamma1_mm) {
        // A reading of exactly zero is the sensor's dead band ("no contact
        // seen"), not a measured depth: with recorded errors it carries none
        // and is not counted as an observation (see `fit_full`).
        let dead_band = sig.recorded && s.gamma1_mm == 0.0;
        out.push(if dead_band { 0.0 } else { (s.gamma1_mm - q.gamma1_mm) / sg });
    }
    for ((s, q), st) in rec.samples.iter().zip(&pred).zip(&sig.theta1_deg) {
        if s.phase == Phase::Torsion {
            out.push((s.theta1_deg - q.theta1_deg) / st);
        }
    }
    true
}

/// Fit passes at most (two without a layer: nominal, then re-weighted noise).
const MAX_PASSES: usize = 7;

pub fn fit_full(rec: &Recording, opts: &FullOptions, start: ModelParams) -> Result<FullFit, FitError> {
    fit_full_within(rec, opts, start, MAX_PASSES)
}

/// [`fit_full`] with at most `max_passes` passes.
fn fit_full_within(
    rec: &Recording,
    opts: &FullOptions,
    start: ModelParams,
    max_passes: usize,
) -> Result<FullFit, FitError> {
    let (n_normal_live, n_torsion) = sample_counts(rec)?;
    let passes = fit_passes(rec, opts, usable_start(rec, start), max_passes)?;
    let params = passes.params;
    let mut warnings = limit_warnings(&params, passes.out.converged);
    // Dead-band rows carry no noise: count only noisy readings as observations.
    let n_obs = n_normal_live + rec.phase(Phase::Torsion).filter(|s| s.gamma1_mm != 0.0).count() + n_torsion;
    let cov = covariance(rec, &passes, n_obs, &mut warnings)?;
    let pred = predict_with(rec, &params, passes.correction.as_ref())?;
    let r = residuals(rec, &pred);
    warnings.extend(systematic_warning(&r));
    warnings.extend(super::large_strain::warning(rec, &params));
    let curvature_bias = curvature_bias(rec, &passes, &cov, &mut warnings);
    let se = standard_errors(rec, &params, &cov.matrix);
    let unsettled = passes.unsettled.and_then(|m| unsettled_warning(&params, m, [se[0], se[1]], max_passes));
    let converged = passes.out.converged && unsettled.is_none();
    warnings.extend(unsettled);
    let dof = cov.dof;
    Ok(FullFit {
        e1_mpa: params.e1_mpa,
        nu1: params.nu1,
        contact_offset_mm: params.contact_offset_mm,
        e1_se: se[0],
        nu1_se: se[1],
        contact_offset_se_mm: se[2],
        ci95: FullCi95 {
            e1_mpa: clip(interval(params.e1_mpa, se[0], dof), [0.0, f64::INFINITY]),
            nu1: clip(interval(params.nu1, se[1], dof), [0.0, 0.5]),
            contact_offset_mm: interval(params.contact_offset_mm, se[2], dof),
        },
        corr_e1_nu1: cov.corr_e1_nu1,
        beta: rec
            .samples
            .iter()
            .zip(&pred)
            .find(|(s, _)| s.phase == Phase::Torsion)
            .map(|(_, p)| p.beta)
            .unwrap_or(f64::NAN),
        rms: GroupFigures { normal_um: rms(&r.normal_mm) * 1e3, torsion_deg: rms(&r.torsion_deg) },
        noise_floor: GroupFigures {
            normal_um: noise_from_second_differences(&r.normal_mm).unwrap_or(f64::NAN) * 1e3,
            torsion_deg: noise_from_second_differences(&r.torsion_deg).unwrap_or(f64::NAN),
        },
        r2: r_squared_of(rec, &pred),
        chi2_dof: passes.sigma.recorded.then_some(cov.chi2_dof),
        iterations: passes.out.iterations,
        converged,
        samples_used: n_obs,
        model: match (params.contact_friction.is_some(), params.large_strain) {
            (true, true) => "layer-fe-large-strain",
            (true, false) => "layer-fe",
            _ => "half-space",
        },
        contact_friction: params.contact_friction,
        large_strain: params.large_strain,
        curvature_bias,
        warnings,
        predictions: pred,
    })
}

impl FullFit {
    /// The fitted model's parameters (to predict with them).
    pub fn params(&self) -> ModelParams {
        ModelParams {
            e1_mpa: self.e1_mpa,
            nu1: self.nu1,
            contact_offset_mm: self.contact_offset_mm,
            contact_friction: self.contact_friction,
            large_strain: self.large_strain,
        }
    }
}

/// Live normal samples (gamma1 off the dead band) and torsion samples, when
/// there are enough of both to fit.
fn sample_counts(rec: &Recording) -> Result<(usize, usize), FitError> {
    let n_torsion = rec.phase(Phase::Torsion).count();
    let n_normal_live = rec.phase(Phase::Normal).filter(|s| s.gamma1_mm != 0.0).count();
    if n_torsion < 3 {
        return Err(FitError::TooFewSamples { what: "torsion samples".into(), found: n_torsion, need: 3 });
    }
    if n_normal_live < 5 {
        return Err(FitError::TooFewSamples {
            what: "normal samples in contact".into(),
            found: n_normal_live,
            need: 5,
        });
    }
    Ok((n_normal_live, n_torsion))
}

/// The friction between indenter and gel a layer fit starts from, when it
/// is given none.
pub const FRICTION_START: f64 = 0.5;

/// `start` with an unusable E1 or nu1 replaced by a typical elastomer's; with
/// the FE layer model, torsion carries Coulomb friction as a nuisance parameter.
fn usable_start(rec: &Recording, mut start: ModelParams) -> ModelParams {
    let [typical, ..] = start_points::typical_elastomers(rec.meta.indenter.e_mpa);
    if !(start.e1_mpa.is_finite() && start.e1_mpa > 0.0) {
        start.e1_mpa = typical.e1_mpa;
    }
    if !(start.nu1 > 0.01 && start.nu1 < 0.49) {
        start.nu1 = typical.nu1;
    }
    start.contact_friction =
        fe_layer(rec).map(|_| start.contact_friction.filter(|m| *m > 0.0).unwrap_or(FRICTION_START));
    start
}

/// What the fit passes ended with.
struct Passes {
    params: ModelParams,
    out: LmResult,
    /// Per-sample noise of gamma1 and theta1 the last pass weighted by.
    sigma: Sigmas,
    /// The FE model's friction correction the last pass iterated on, if any.
    correction: Option<Correction>,
    /// When the passes ran out before the estimate settled: how far the last
    /// pass moved it (E1 relative, nu1 absolute).
    unsettled: Option<[f64; 2]>,
}

/// A last pass's move, in standard errors of E1 or nu1, past which the fit
/// does not count as converged. The friction correction's passes close in on
/// their fixed point geometrically, by a factor of 0.1-0.6 a pass (dev set and
/// emulated runs), so what is left after the last is up to 1.5 times its
/// move: a fifth of a standard error moves the interval visibly. Below it the
/// passes stop short only of the 1e-4 they aim at (an emulated run's unsettled
/// starts moved 0.01-0.03 standard errors at their fifth pass).
const UNSETTLED_SE: f64 = 0.2;

/// The warning (and an unconverged fit) when the passes ran out with the last
/// one still moving the estimate by more than [`UNSETTLED_SE`] standard errors.
fn unsettled_warning(params: &ModelParams, moved: [f64; 2], se: [f64; 2], passes: usize) -> Option<Warning> {
    let in_se = [moved[0].abs() * params.e1_mpa / se[0], moved[1].abs() / se[1]];
    (in_se.iter().any(|v| !(v.is_finite() && *v <= UNSETTLED_SE))).then(|| {
        Warning::new(
            "passes_unsettled",
            format!(
                "the fit's passes (the friction correction taken again between them) stopped after {passes} \
                 passes with the last still moving the estimate: it moved E1 by {:+.3} % and nu1 by {:+.4} ({:.2} and {:.2} \
                 standard errors); the estimate may lie that far again from the model's optimum",
                moved[0] * 100.0,
                moved[1],
                in_se[0],
                in_se[1]
            ),
        )
    })
}

/// How close to its optimum, in standard errors, a search on the FE layer
/// model ends ([`LmOptions::within_se`]): a twentieth of the estimate's
/// spread adds a quarter of a percent to its variance and moves neither the
/// estimate nor its interval in any digit that matters. The model's contact
/// nodes ripple the cost at about a tenth of a standard error: closer, a
/// search spends most of its model evaluations on refused trials (on the
/// dev set's tableI_2 a hundredth took 143 evaluations, a twentieth 119; the
/// half-space model is smooth and keeps the tolerances alone).
pub const FIT_WITHIN_SE: f64 = 0.05;

/// How near, in standard errors of E1 and nu1, the passes must settle to
/// where the friction correction's derivatives were taken for them to stand.
const SLOPES_NEAR_SE: f64 = 0.25;

/// Pass 1 with nominal noise, pass 2 re-weighted by the noise floor the data
/// show; with the FE layer model, more passes while the friction correction
/// still moves the estimate.
fn fit_passes(rec: &Recording, opts: &FullOptions, start: ModelParams, max_passes: usize) -> Result<Passes, FitError> {
    let mut sg = opts.gamma1_sigma_mm.unwrap_or(sim::defaults::GAMMA1_SIGMA_MM);
    let mut st = opts.theta1_sigma_deg.unwrap_or(sim::defaults::THETA1_SIGMA_DEG);
    let sd = recorded_errors(rec, opts);
    let mut sigma = Sigmas::new(&sd, rec.samples.len(), sg, st);
    let mut params = start;
    let mut res = None;
    // On a layer the first pass runs on the tabulated fast form alone: the
    // friction correction's frictional paths are followed from where it
    // ends, not from a start that may lie far from the optimum.
    let mut correction = fe_layer(rec).map(|_| Correction::none(rec, &params));
    let mut unsettled = None;
    for pass in 0..max_passes {
        // Taken again where the last pass ended (after the first pass it
        // was taken there already, with its derivatives).
        if pass >= 2 {
            // The first set of derivatives is the friction's alone (the
            // passes are still a few tenths of a standard error out); the
            // whole set is taken where the pass on it ends.
            let first = correction.as_ref().is_some_and(|c| c.follows_friction() && !c.has_slopes());
            correction = match first {
                true => friction_correction_in_friction(rec, &params)?,
                false => friction_correction(rec, &params, correction.as_ref())?,
            };
        }
        let x0 = to_internal(&params);
        let f = |x: &[f64], r: &mut Vec<f64>| {
            weighted_residuals(rec, &from_internal(x, &start), correction.as_ref(), &sigma, r)
        };
        // The FE layer model's evaluations are worth a core each.
        let out = match fe_layer(rec) {
            Some(_) => {
                lm::minimize_parallel(f, &x0, LmOptions { within_se: Some(FIT_WITHIN_SE), ..LmOptions::default() })
            }
            None => lm::minimize(f, &x0, LmOptions::default()),
        }?;
        let before = params;
        params = from_internal(&out.x, &start);
        res = Some(out);
        let moved = [params.e1_mpa / before.e1_mpa - 1.0, params.nu1 - before.nu1];
        // Settled once a pass moves the estimate by less than 1e-4, or by
        // less than the searches' own stopping distance in standard errors:
        // the correction's frictional paths step as nodes stick and slip,
        // and the passes then move about their fixed point by hundredths of
        // a standard error.
        let spread = match correction.as_ref().is_some_and(Correction::follows_friction) {
            true => pass_spread(rec, &params, correction.as_ref(), &sigma),
            false => None,
        };
        let within = |d: [f64; 2], tol: f64| {
            spread.is_some_and(|se| d[0].abs() * params.e1_mpa < tol * se[0] && d[1].abs() < tol * se[1])
        };
        let settled = (moved[0].abs() < 1e-4 && moved[1].abs() < 1e-4) || (pass >= 1 && within(moved, FIT_WITHIN_SE));
        // A pass on the friction's derivatives alone ends nothing: the next
        // takes the whole set where it ended.
        if correction.as_ref().is_some_and(Correction::is_partial) && pass + 1 < max_passes {
            unsettled = Some(moved);
            continue;
        }
        // A pass that settled far from where the correction's derivatives
        // were taken stands on derivatives of another place: they are taken
        // again here and the passes go on (the frictional paths step as
        // nodes stick and slip, and finite differences over them are only
        // good near where they were taken).
        let far = correction
            .as_ref()
            .is_some_and(|c| c.follows_friction() && !within(c.slopes_apart(&params), SLOPES_NEAR_SE));
        if settled && far && pass + 1 < max_passes {
            correction = friction_correction(rec, &params, None)?;
            unsettled = Some(moved);
            continue;
        }
        if pass >= 1 && (correction.as_ref().is_none_or(|c| !c.follows_friction()) || settled) {
            unsettled = None;
            break;
        }
        unsettled = Some(moved);
        if pass == 0 {
            // The noise floors of the residuals where the first pass ended,
            // of the whole model there: on a layer the table plus what
            // friction adds there, taken without its derivatives (they are
            // taken where the next pass ends, closer to the optimum).
            if fe_layer(rec).is_some() {
                correction = friction_at(rec, &params)?;
            }
            let pred = predict_with(rec, &params, correction.as_ref())?;
            let r = residuals(rec, &pred);
            // Channels weighted by recorded standard errors keep them.
            if opts.gamma1_sigma_mm.is_none() && sd.gamma1_mm.is_none() {
                if let Some(s) = noise_from_second_differences(&r.normal_mm) {
                    sg = s.max(1e-6);
                }
            }
            if opts.theta1_sigma_deg.is_none() && sd.theta1_deg.is_none() {
                if let Some(s) = noise_from_second_differences(&r.torsion_deg) {
                    st = s.max(1e-5);
                }
            }
            sigma = Sigmas::new(&sd, rec.samples.len(), sg, st);
        }
    }
    let out = res.ok_or_else(|| FitError::Model("no fit pass ran".into()))?;
    Ok(Passes { params, out, sigma, correction, unsettled })
}

/// nu1 is mapped onto (0, 0.5); an optimum pressed against either end means
/// the sweeps did not determine it, not that the elastomer is that odd: keep
/// the estimate, say so (its interval is cut at the physical range). And a
/// fit that stopped before converging.
fn limit_warnings(params: &ModelParams, converged: bool) -> Vec<Warning> {
    let mut warnings = Vec::new();
    if !(NU1_EDGE..=0.5 - NU1_EDGE).contains(&params.nu1) {
        warnings.push(Warning::new(
            "nu1_at_bound",
            format!(
                "the full-model fit ran to the edge of the physical range (nu1 = {:.4}): these sweeps do not \
                 determine nu1 under this model; check the contact point, the torsion sweep and the declared \
                 layer (easycalib diagnose)",
                params.nu1
            ),
        ));
    }
    if !converged {
        warnings.push(Warning::new("not_converged", "the full-model fit stopped before converging"));
    }
    warnings
}

/// The covariance of the fitted physical parameters (E1, nu1, z0), scaled by
/// the residuals, with its degrees of freedom and the E1-nu1 correlation.
struct Covariance {
    matrix: DMatrix<f64>,
    /// The weighted residuals' Jacobian at the optimum in the parameters the
    /// covariance is of (E1, nu1, z0[, friction]), and the friction correction
    /// it was taken with.
    jac: DMatrix<f64>,
    correction: Option<Correction>,
    dof: usize,
    corr_e1_nu1: f64,
    /// chi²/dof of the weighted residuals.
    chi2_dof: f64,
}

/// Covariance in physical parameters from a central-difference Jacobian at the
/// optimum. Friction that never limits the twist (the contact sticks
/// throughout) has no effect on the data: it is left out, with a warning.
fn covariance(
    rec: &Recording,
    passes: &Passes,
    n_obs: usize,
    warnings: &mut Vec<Warning>,
) -> Result<Covariance, FitError> {
    let params = &passes.params;
    let (jac, r0, correction) = physical_jacobian(rec, passes)?;
    let dof = n_obs.saturating_sub(jac.ncols()).max(1);
    let chi2_dof = r0.iter().map(|v| v * v).sum::<f64>() / dof as f64;
    // Weights from a floor the data set: chi²/dof is the residual variance in
    // its units. Weights from recorded standard errors: the errors already
    // set the scale, and only a misfit beyond them (the Birge ratio above 1,
    // model error or errors reported too small) widens the intervals.
    let s2 = if passes.sigma.recorded { chi2_dof.max(1.0) } else { chi2_dof };
    let mut np = jac.ncols();
    if np == 4 {
        let norm = |j: usize| jac.column(j).norm();
        // A fit that ran to full stick (friction infinite) has no finite
        // column for it at all.
        let mu = params.contact_friction.unwrap_or(1.0);
        let stuck = !mu.is_finite() || !norm(3).is_finite();
        if stuck || norm(3) * mu < 1e-6 * norm(0) * params.e1_mpa {
            np = 3;
            warnings.push(Warning::new(
                "friction_undetermined",
                "no slip shows in the torsion sweep: the contact sticks, and the friction coefficient is not determined",
            ));
        }
    }
    let jac = jac.columns(0, np).into_owned();
    let jtj = jac.transpose() * &jac;
    let cov = jtj
        .try_inverse()
        .ok_or_else(|| FitError::Degenerate("E1, nu1 and z0 cannot be separated by these sweeps".into()))?
        * s2;
    // A covariance that is not positive definite means the sweeps do not
    // determine the parameters: no interval can be given, so no answer either.
    let diag_ok = (0..np).all(|i| cov[(i, i)].is_finite() && cov[(i, i)] > 0.0);
    let corr = if diag_ok { cov[(0, 1)] / (cov[(0, 0)] * cov[(1, 1)]).sqrt() } else { f64::NAN };
    if !diag_ok || corr.is_nan() || corr.abs() >= 1.0 || !s2.is_finite() {
        return Err(FitError::Degenerate(
            "the covariance of E1, nu1 and z0 is not positive definite: these sweeps cannot separate them".into(),
        ));
    }
    Ok(Covariance { matrix: cov, jac, dof, corr_e1_nu1: corr, chi2_dof, correction })
}

/// The weighted residuals' Jacobian at the optimum, the residuals there, and
/// the friction correction they were taken with.
type AtOptimum = (DMatrix<f64>, Vec<f64>, Option<Correction>);

/// The weighted residuals at the optimum and their central-difference
/// Jacobian in the physical parameters (E1, nu1, z0[, friction]).
fn physical_jacobian(rec: &Recording, passes: &Passes) -> Result<AtOptimum, FitError> {
    // The last pass's correction: the passes stopped close to where it was
    // taken, where its linear form is what friction adds to the model there.
    let correction = passes.correction.clone();
    let (jac, r0) = jacobian_at(rec, &passes.params, correction.as_ref(), &passes.sigma)?;
    Ok((jac, r0, correction))
}

/// The weighted residuals at `params` and their central-difference Jacobian
/// in the physical parameters (E1, nu1, z0[, friction]) on the model the
/// passes iterate on (with `correction`).
fn jacobian_at(
    rec: &Recording,
    params: &ModelParams,
    correction: Option<&Correction>,
    sig: &Sigmas,
) -> Result<(DMatrix<f64>, Vec<f64>), FitError> {
    let mut phys = vec![params.e1_mpa, params.nu1, params.contact_offset_mm];
    phys.extend(params.contact_friction);
    let np = phys.len();
    let mut r0 = Vec::new();
    weighted_residuals(rec, params, correction, sig, &mut r0);
    let m = r0.len();
    let mut jac = DMatrix::zeros(m, np);
    let steps = [1e-5 * params.e1_mpa, 1e-5, 1e-6, 1e-4 * params.contact_friction.unwrap_or(1.0)];
    let probe = |j: usize| {
        let mut hi = phys.clone();
        let mut lo = phys.clone();
        hi[j] += steps[j];
        lo[j] -= steps[j];
        let (mut rp, mut rm) = (Vec::new(), Vec::new());
        let up = weighted_residuals(rec, &from_physical(&hi, params), correction, sig, &mut rp);
        let down = weighted_residuals(rec, &from_physical(&lo, params), correction, sig, &mut rm);
        (up, rp, down, rm)
    };
    // Each parameter's probes are independent: the FE layer model's on the
    // cores there are.
    let probes: Vec<_> = match fe_layer(rec) {
        Some(_) => (0..np).into_par_iter().map(probe).collect(),
        None => (0..np).map(probe).collect(),
    };
    for (j, (up, rp, down, rm)) in probes.into_iter().enumerate() {
        // Deep sweeps end close to the contact model's turning point, where a
        // step to one side may leave the model's range: difference one-sided then.
        for i in 0..m {
            jac[(i, j)] = match (up, down) {
                (true, true) => (rp[i] - rm[i]) / (2.0 * steps[j]),
                (true, false) => (rp[i] - r0[i]) / steps[j],
                (false, true) => (r0[i] - rm[i]) / steps[j],
                (false, false) => {
                    return Err(FitError::Model("the model cannot be evaluated next to the optimum".into()));
                }
            };
        }
    }
    Ok((jac, r0))
}

/// The standard errors of E1 and nu1 at `params` from the noise the
/// passes weigh by (scaled by the residuals as the covariance is), to judge
/// a pass's move by; `None` where they cannot be had.
fn pass_spread(
    rec: &Recording,
    params: &ModelParams,
    correction: Option<&Correction>,
    sig: &Sigmas,
) -> Option<[f64; 2]> {
    let (jac, r0) = jacobian_at(rec, params, correction, sig).ok()?;
    let dof = r0.len().saturating_sub(jac.ncols()).max(1) as f64;
    let chi2_dof = r0.iter().map(|v| v * v).sum::<f64>() / dof;
    let s2 = if sig.recorded { chi2_dof.max(1.0) } else { chi2_dof };
    let cov = (jac.transpose() * &jac).try_inverse()? * s2;
    let se = [cov[(0, 0)].sqrt(), cov[(1, 1)].sqrt()];
    se.iter().all(|v| v.is_finite() && *v > 0.0).then_some(se)
}

/// Box's second-order bias of the layer fit's optimum (docs/physics.md, "The
/// estimator's bias"), in the parameters of the covariance, with a warning when
/// it is not small against the estimate's spread. The noise is the fit's
/// weights (the recording's standard errors or the noise floors its residuals
/// show), not the residuals' spread: a misfit of the model is not noise and
/// has no curvature bias. The curvature is taken on the model the fit iterated
/// on (the frictionless press plus the friction correction, linear in the
/// parameters), one standard deviation along each principal axis of the
/// covariance. `None` for the half-space fit,
/// at an end of nu1's range (the expansion cannot see the bound) and where the
/// model cannot be evaluated a standard error away.
fn curvature_bias(
    rec: &Recording,
    passes: &Passes,
    cov: &Covariance,
    warnings: &mut Vec<Warning>,
) -> Option<CurvatureBias> {
    let params = &passes.params;
    params.contact_friction?;
    if !(NU1_EDGE..=0.5 - NU1_EDGE).contains(&params.nu1) {
        return None;
    }
    let np = cov.jac.ncols();
    let mut theta = vec![params.e1_mpa, params.nu1, params.contact_offset_mm];
    theta.extend(params.contact_friction);
    theta.truncate(np);
    let unit = (cov.jac.transpose() * &cov.jac).try_inverse()?;
    let se: Vec<f64> = (0..np).map(|j| unit[(j, j)].sqrt()).collect();
    let eval = |x: &[f64]| {
        let mut phys = x.to_vec();
        if let (3, Some(mu)) = (np, params.contact_friction) {
            phys.push(mu);
        }
        let mut r = Vec::new();
        weighted_residuals(rec, &from_physical(&phys, params), cov.correction.as_ref(), &passes.sigma, &mut r)
            .then_some(r)
    };
    let b = super::bias::box_bias(eval, &theta, &cov.jac)?;
    let ratio = |j: usize| b[j].abs() / se[j];
    if ratio(0) > BIAS_WARN_SE || ratio(1) > BIAS_WARN_SE {
        warnings.push(Warning::new(
            "curvature_bias",
            format!(
                "the least-squares estimate's own second-order bias is {:+.2} % in E1 ({:.2} of its standard error \
                 from the noise) and {:+.2} % in nu1 ({:.2}): at this noise the model bends over the estimate's \
                 spread, so the estimate leans and its interval covers the truth less often than it says; more \
                 samples or less noise remove it (it is not subtracted: full.curvature_bias)",
                b[0] / params.e1_mpa * 100.0,
                ratio(0),
                b[1] / params.nu1 * 100.0,
                ratio(1)
            ),
        ));
    }
    Some(CurvatureBias { e1_mpa: b[0], nu1: b[1], contact_offset_mm: b[2], contact_friction: b.get(3).copied() })
}

/// The curvature bias, in standard errors of E1 or nu1, beyond which the fit
/// warns: a quarter of a standard error moves a 95 % interval's coverage by
/// about a percent (94 % instead of 95 %).
const BIAS_WARN_SE: f64 = 0.25;

/// Standard errors of E1, nu1 and z0: the covariance's, with the layer
/// model's own approximation error in quadrature (docs/physics.md,
/// "Finite-element reference": the spread of its recoveries on independent
/// finite-element recordings).
fn standard_errors(rec: &Recording, params: &ModelParams, cov: &DMatrix<f64>) -> [f64; 3] {
    let model_sd = match params.contact_friction {
        Some(_) => {
            let [e1, nu1] = layer_model_sd(rec, params);
            [e1 * params.e1_mpa, nu1 * params.nu1, 0.0]
        }
        None => [0.0; 3],
    };
    std::array::from_fn(|i| (cov[(i, i)] + model_sd[i] * model_sd[i]).sqrt())
}

/// A warning when the normal sweep's residuals stand well above their noise floor.
fn systematic_warning(r: &Residuals) -> Option<Warning> {
    let floor = noise_from_second_differences(&r.normal_mm)?;
    let rms_n = rms(&r.normal_mm);
    (rms_n > 3.0 * floor.max(1e-4)).then(|| {
        Warning::new(
            "systematic_residuals",
            format!(
                "the model leaves systematic residuals in the normal sweep ({:.1} µm RMS against a noise floor of \
                 {:.1} µm): physics outside the model (large strain, an effect of the rig); the intervals are \
                 scaled by the residuals but the estimate may be biased — run `easycalib diagnose`",
                rms_n * 1e3,
                floor * 1e3
            ),
        )
    })
}

/// R² of gamma1 over the live normal samples and of theta1 over the torsion sweep.
fn r_squared_of(rec: &Recording, pred: &[Prediction]) -> R2 {
    let pairs = |keep: fn(&Sample) -> bool, read: fn(&Sample, &Prediction) -> (f64, f64)| -> (Vec<f64>, Vec<f64>) {
        rec.samples.iter().zip(pred).filter(|(s, _)| keep(s)).map(|(s, p)| read(s, p)).unzip()
    };
    let (lo_n, lp_n) = pairs(|s| s.phase == Phase::Normal && s.gamma1_mm != 0.0, |s, p| (s.gamma1_mm, p.gamma1_mm));
    let (lo_t, lp_t) = pairs(|s| s.phase == Phase::Torsion, |s, p| (s.theta1_deg, p.theta1_deg));
    R2 { normal: r_squared(&lo_n, &lp_n), torsion: r_squared(&lo_t, &lp_t) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The friction correction's passes on tableI_2 (E1 1, nu1 0.48) from a
    /// typical start: the second still moves E1 by -1.4 % and nu1 by +0.010
    /// (0.9 and 1.3 standard errors; tableI_3, once this test's file, now
    /// settles in two). Cut at two passes the
    /// fit must say it stopped moving, not converged; given its passes it
    /// settles, says nothing of them, and is converged.
    #[test]
    fn passes_cut_short_while_moving_say_so_and_do_not_count_as_converged() {
        let rec = crate::fit::dev_recording("tableI_2_E2-2.0_nu2-0.40.csv");
        let start =
            ModelParams { e1_mpa: 0.8, nu1: 0.35, contact_offset_mm: 0.0, contact_friction: None, large_strain: false };
        let opts = FullOptions::default();
        let cut = fit_full_within(&rec, &opts, start, 2).unwrap();
        let warned = cut.warnings.iter().find(|w| w.code == "passes_unsettled");
        println!("cut: E1 {:.4} nu1 {:.4} {:?}", cut.e1_mpa, cut.nu1, warned.map(|w| &w.message));
        assert!(warned.is_some() && !cut.converged, "{:?}", cut.warnings);
        let full = fit_full(&rec, &opts, start).unwrap();
        println!("full: E1 {:.4} nu1 {:.4}", full.e1_mpa, full.nu1);
        assert!(full.converged && full.warnings.iter().all(|w| w.code != "passes_unsettled"), "{:?}", full.warnings);
        assert!((full.e1_mpa - 1.0).abs() < 0.03 && (full.nu1 - 0.48).abs() < 0.01, "{} {}", full.e1_mpa, full.nu1);
    }
}
