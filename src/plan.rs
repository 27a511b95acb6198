//! Which experiment would separate what a diagnosis leaves standing
//! (docs/experiments.md, "Choosing an experiment"): each hypothesis the
//! diagnosis could not rank is refitted to the recording, each candidate
//! experiment is simulated after the recording under it, and the predicted
//! outcomes of the two best hypotheses are compared against the noise.

use serde::Serialize;
use sim::effects::{CommandedPose, SimProfile, TrueRig, simulate};
use sim::experiment::ExperimentSpec;
use sim::physics::{Body, ContactPair};
use sim::recording::{Phase, Recording, Sample};

use crate::diagnosis::model::{Base, Candidate, Fitted, Model};
use crate::diagnosis::{DiagnoseError, DiagnoseOptions, Diagnosis, diagnose};
use crate::fit::Ci95;
use crate::run::events::{LoopChoice, LoopHypothesis, LoopView};

/// A separation (sum of squared predicted differences over the noise) at or
/// above which an experiment decides: the realised chi² gain then falls below
/// the diagnosis's ambiguity margin (a BIC gap of 6) in about 3 % of runs,
/// its spread being 2 sqrt(separation).
pub const DECISIVE_SEPARATION: f64 = 24.0;

/// What an operator's indenter swap costs, in seconds of rig time it is
/// weighed as (docs/experiments.md, "Operator effort"): the rig retracts to
/// park, someone walks over, unscrews one indenter, mounts the other with its
/// apex on the same reference and confirms — about five minutes of a
/// person's time, and a chance to disturb the set-up. A rig-only experiment
/// that decides is therefore always preferred to a swap that decides.
pub const OPERATOR_EFFORT_S: f64 = 300.0;

/// What a plan may propose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanOptions {
    /// Operator-assisted steps (an indenter swap) may be proposed (`--no-operator`: not).
    pub operator: bool,
    /// The standard error one experiment sample will be recorded with
    /// (gamma1 mm, theta1 deg), when the caller knows it (a run: its reading
    /// noise over the frames an experiment sample averages). An experiment
    /// sample averages fewer frames than a sweep's, so it is noisier: the
    /// separations are computed against it ([`experiment_noise`]).
    pub experiment_sd: Option<[f64; 2]>,
}

impl Default for PlanOptions {
    fn default() -> Self {
        Self { operator: true, experiment_sd: None }
    }
}

/// How much noisier an experiment's samples are than the sweeps' (gamma1,
/// theta1 ratios of their standard errors): the recording's own experiment
/// samples when it has some (measured), else `opts.experiment_sd` over the
/// sweeps' median recorded standard error, else 1 (as noisy as the sweeps).
pub fn experiment_noise(rec: &Recording, opts: &PlanOptions) -> [f64; 2] {
    let med = |v: Vec<f64>| (!v.is_empty()).then(|| crate::numerics::stats::median(&mut v.clone()));
    let sd = |keep: &dyn Fn(&Sample) -> bool, theta: bool| {
        med(rec
            .samples
            .iter()
            .filter(|s| keep(s) && (!theta || s.phase == Phase::Torsion))
            .filter_map(|s| if theta { s.theta1_sd_deg } else { s.gamma1_sd_mm })
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect())
    };
    let sweep = |s: &Sample| s.in_sweep();
    let experiment = |s: &Sample| s.experiment.is_some();
    let ratio = |theta: bool| {
        let base = sd(&sweep, theta)?;
        let own = sd(&experiment, theta).or_else(|| opts.experiment_sd.map(|e| e[usize::from(theta)]))?;
        Some(own / base).filter(|r| r.is_finite() && *r > 0.0)
    };
    [ratio(false).unwrap_or(1.0), ratio(true).unwrap_or(1.0)]
}

/// The operator-assisted steps a plan weighs for `rec`: a steel ball of the
/// recording's indenter radius (sensor gain against frame compliance), and a
/// second indenter four times stiffer and twice the radius (a different
/// E2/R2: a different share of the stage travel goes into the indenter).
pub fn operator_candidates(rec: &Recording) -> Vec<ExperimentSpec> {
    let ind = rec.meta.indenter;
    vec![
        ExperimentSpec::RigidBall { r_mm: ind.r_mm, travel_mm: 2.5, steps: 20 },
        ExperimentSpec::SwapIndenter {
            e2_mpa: 4.0 * ind.e_mpa,
            nu2: ind.nu,
            r2_mm: 2.0 * ind.r_mm,
            travel_mm: 2.5,
            steps: 20,
        },
    ]
}

/// The experiments a plan weighs: what the rig can run alone.
pub fn candidates() -> Vec<ExperimentSpec> {
    vec![
        ExperimentSpec::Dwell { hold_s: 60.0, every_s: 2.0 },
        ExperimentSpec::Reload { fraction: 0.5, steps: 4, cycles: 1 },
        ExperimentSpec::TwistReversal { amplitude_deg: 4.0, step_deg: 0.5 },
        ExperimentSpec::TorsionAtDepth { beta: 0.1, amplitude_deg: 8.0, step_deg: 0.4 },
        ExperimentSpec::TorsionAtDepth { beta: 0.3, amplitude_deg: 8.0, step_deg: 0.4 },
        ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 3, dwell_s: 8.0 },
        ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 4, speed_mm_s: 0.1 },
    ]
}

/// One explanation still standing, refitted.
#[derive(Debug, Clone, Serialize)]
pub struct Hypothesis {
    pub effects: Vec<&'static str>,
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    /// The refit's chi² against the noise floor.
    pub chi2: f64,
    #[serde(skip)]
    pub profile: SimProfile,
    /// The refit itself (a plan refits it again with an experiment's predicted samples added).
    #[serde(skip)]
    pub fitted: Fitted,
}

/// One candidate experiment, scored.
#[derive(Debug, Clone, Serialize)]
pub struct Scored {
    pub name: &'static str,
    pub spec: ExperimentSpec,
    pub samples: usize,
    pub rig_time_s: f64,
    /// Needs an operator to swap the indenter.
    pub operator: bool,
    /// What it is weighed at: its rig time, plus [`OPERATOR_EFFORT_S`] for an operator step, s.
    pub cost_s: f64,
    /// How far it separates the best hypothesis from the second: for a step
    /// the rig runs alone, the growth of the chi² gap once its samples, as
    /// the best predicts them (weighed at an experiment sample's noise), are
    /// added and both are refitted; for an operator step (another indenter, a
    /// recording of its own) `separation_no_refit`.
    pub separation: f64,
    /// The same without refitting: the sum over its samples of the squared
    /// difference between the two predictions, each over its reading's noise
    /// (an upper bound on what a refit leaves).
    pub separation_no_refit: f64,
    /// `separation` >= [`DECISIVE_SEPARATION`].
    pub decisive: bool,
    /// How many of the other hypotheses it separates from the best (refitted
    /// separation >= [`DECISIVE_SEPARATION`]); a step that separates one is
    /// worth running even when it leaves another pair for a later step.
    pub separates: usize,
    /// Every hypothesis after the best it would leave standing beside it
    /// (separation, refitted as above, below [`DECISIVE_SEPARATION`]), with
    /// that separation.
    pub leaves: Vec<(String, f64)>,
    /// The largest gamma1 the best hypothesis predicts during it, mm (a rig
    /// checks it against its soft limit before running it).
    pub peak_gamma1_mm: f64,
}

/// The plan for one recording.
#[derive(Debug, Clone, Serialize)]
pub struct Plan {
    /// The diagnosis's answer on the recording as it is, in one line ([`outcome_of`]).
    pub verdict: String,
    /// E1 and nu1 of that diagnosis (corrected when it names an effect).
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    pub hypotheses: Vec<Hypothesis>,
    /// Every candidate, best first.
    pub experiments: Vec<Scored>,
    /// Why nothing is proposed, when nothing is.
    pub nothing_because: Option<String>,
    /// Separations of effects no rig experiment can reach (degenerate ones), with what would.
    pub operator_steps: Vec<String>,
    /// Candidates left out because a hypothesis's rig could not run them
    /// (e.g. a second depth its contact model cannot reach), each with why.
    pub skipped: Vec<String>,
}

impl Plan {
    /// The experiment to run: the cheapest decisive one, else the one that
    /// separates most per second of rig time.
    pub fn choice(&self) -> Option<&Scored> {
        self.experiments.first().filter(|s| s.separation > 0.0)
    }

    /// The closed loop's view of this plan (`RunEvent::ClosedLoop`): the
    /// standing hypotheses with their odds, after `steps_run` experiments,
    /// with the experiment chosen (or none) and a note.
    pub fn view(&self, steps_run: usize, chosen: Option<LoopChoice>, note: String) -> LoopView {
        let hypotheses = self
            .hypotheses
            .iter()
            .zip(self.odds())
            .map(|(h, odds)| LoopHypothesis { effects: h.effects.join(" + "), odds, e1_mpa: h.e1_mpa, nu1: h.nu1 })
            .collect();
        LoopView { steps_run, hypotheses, chosen, note }
    }

    /// Each standing hypothesis's odds, in `hypotheses`' order: its share of
    /// the evidence among them, exp(-BIC/2) normalised (chi² of its refit plus
    /// k ln n; equal prior odds). Shown while the loop runs, not used to decide.
    pub fn odds(&self) -> Vec<f64> {
        let bic: Vec<f64> = self
            .hypotheses
            .iter()
            .map(|h| {
                let k = h.fitted.n_params();
                h.chi2 + k as f64 * ((h.fitted.dof + k).max(1) as f64).ln()
            })
            .collect();
        let best = bic.iter().copied().fold(f64::INFINITY, f64::min);
        let w: Vec<f64> = bic.iter().map(|b| (-(b - best) / 2.0).exp()).collect();
        let total: f64 = w.iter().sum();
        w.iter().map(|v| v / total).collect()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    #[error(transparent)]
    Diagnose(#[from] DiagnoseError),
    #[error("cannot simulate an experiment after this recording: {0}")]
    Simulate(String),
}

/// Plan the next experiment for `rec` (diagnosed here).
pub fn plan(rec: &Recording, opts: PlanOptions) -> Result<Plan, PlanError> {
    let d = diagnose(rec, &DiagnoseOptions::default())?;
    plan_for(rec, &d, opts)
}

/// Plan for `rec` given its diagnosis `d`.
pub fn plan_for(rec: &Recording, d: &Diagnosis, opts: PlanOptions) -> Result<Plan, PlanError> {
    let mut operator_steps: Vec<String> =
        d.degenerate.iter().filter_map(|g| g.separate_by.map(|s| format!("{}: {s}", g.effect))).collect();
    let verdict = outcome_of(d);
    let empty = |why: &str| Plan {
        verdict: verdict.clone(),
        e1_mpa: d.e1_mpa,
        nu1: d.nu1,
        hypotheses: vec![],
        experiments: vec![],
        nothing_because: Some(why.to_string()),
        operator_steps: operator_steps.clone(),
        skipped: Vec::new(),
    };
    if crate::fit::full::fe_layer(rec).is_some() {
        return Ok(empty(
            "experiments are planned on the half-space model; on a declared layer the loop does not plan yet",
        ));
    }
    if d.ambiguous.len() < 2 {
        return Ok(empty("the diagnosis leaves no two explanations standing: nothing to separate"));
    }
    let sigma_g = d.noise.normal_um * 1e-3;
    let sigma_t = d.noise.torsion_deg;
    let model = Model::new(rec, sigma_g, sigma_t);
    // An experiment's samples are weighed at their own noise.
    let [ratio_g, ratio_t] = experiment_noise(rec, &opts);
    let base_x =
        Base { e1_mpa: d.baseline.e1_mpa, nu1: d.baseline.nu1, contact_offset_mm: d.baseline.contact_offset_mm }
            .internal();
    let Some(base) = model.fit(&[], &base_x) else {
        return Ok(empty("the baseline cannot be refitted"));
    };
    let mut hypotheses: Vec<Hypothesis> = d.ambiguous.iter().filter_map(|a| refit(&model, &base, &a.effects)).collect();
    hypotheses.sort_by(|a, b| a.chi2.total_cmp(&b.chi2));
    if hypotheses.len() < 2 {
        return Ok(empty("fewer than two of the explanations could be refitted"));
    }
    let mut experiments = Vec::new();
    let mut left_to_operator = Vec::new();
    let mut skipped = Vec::new();
    let best = &hypotheses[0];
    for spec in candidates().into_iter().chain(operator_candidates(rec)) {
        let step_time_s = step_time(rec, spec.phase().kind());
        // The best's run of the step, appended to the recording, refits the
        // best once and every other hypothesis: what the diagnosis would see.
        let refitted = match spec.is_operator() {
            true => None,
            false => {
                let mut aug = rec.clone();
                match run_under(rec, best, &spec, step_time_s) {
                    Ok(run) => aug.samples.extend(run),
                    Err(e) => {
                        skipped.push(format!("{} {spec:?}: {e}", spec.name()));
                        continue;
                    }
                }
                Some(aug)
            }
        };
        let weights = |aug: &Recording| {
            let n = rec.samples.len();
            let w = |r: f64| Some((0..aug.samples.len()).map(|i| if i < n { 1.0 } else { r }).collect());
            crate::fit::weights::SampleSd { gamma1_mm: w(ratio_g), theta1_deg: w(ratio_t) }
        };
        let aug_model =
            refitted.as_ref().map(|aug| Model::new(aug, sigma_g, sigma_t).with_standard_errors(&weights(aug)));
        let best_after = aug_model.as_ref().and_then(|m| m.fit(&best.fitted.cands, &best.fitted.x));
        let (mut sep, mut separation_no_refit, mut peak_gamma1_mm) = (0.0, 0.0, 0.0f64);
        let mut leaves = Vec::new();
        let mut separates = 0;
        let mut failed = false;
        for (i, other) in hypotheses.iter().enumerate().skip(1) {
            let (bound, peak) =
                match separation(rec, best, other, &spec, step_time_s, sigma_g * ratio_g, sigma_t * ratio_t) {
                    Ok(x) => x,
                    Err(e) => {
                        skipped.push(format!("{} {spec:?} under {}: {e}", spec.name(), other.effects.join(" + ")));
                        failed = true;
                        break;
                    }
                };
            peak_gamma1_mm = peak_gamma1_mm.max(peak);
            // Refitted: the gap's growth (the best's own chi² grows too when
            // the new samples pull its parameters); the bound if a refit fails.
            let after = match (&aug_model, &best_after) {
                (Some(m), Some(fa)) => m
                    .fit(&other.fitted.cands, &other.fitted.x)
                    .map_or(bound, |fb| ((fb.chi2 - other.chi2) - (fa.chi2 - best.chi2)).max(0.0)),
                _ => bound,
            };
            if after < DECISIVE_SEPARATION {
                leaves.push((other.effects.join(" + "), after));
            } else {
                separates += 1;
            }
            // Scored against the second best (docs/experiments.md): against
            // all, a step that names the first of three when it holds would
            // lose to an operator's swap whenever the other two are one
            // pair no motion separates (a layer and a sensor gain).
            if i == 1 {
                (sep, separation_no_refit) = (after, bound);
            }
        }
        let travel_mm = rec.samples.last().map_or(0.0, |s| s.stage_mm);
        if failed {
            continue;
        }
        let rig_time_s = spec.rig_time_s(step_time_s) + seek_time(rec, &spec) + spec.slow_travel_s(travel_mm);
        let scored = Scored {
            name: spec.name(),
            spec,
            samples: spec.samples(),
            rig_time_s,
            operator: spec.is_operator(),
            cost_s: rig_time_s + if spec.is_operator() { OPERATOR_EFFORT_S } else { 0.0 },
            separation: sep,
            separation_no_refit,
            decisive: sep >= DECISIVE_SEPARATION,
            separates,
            leaves,
            peak_gamma1_mm,
        };
        if scored.operator && !opts.operator {
            left_to_operator.push(scored);
        } else {
            experiments.push(scored);
        }
    }
    // Those that separate the best from another first, the cheapest of them
    // (then the one separating more, then the larger separation from the
    // second); then the rest by separation per second of cost.
    experiments.sort_by(|a, b| {
        let (ua, ub) = (a.separates > 0, b.separates > 0);
        ub.cmp(&ua).then_with(|| match ua {
            true => a
                .cost_s
                .total_cmp(&b.cost_s)
                .then(b.separates.cmp(&a.separates))
                .then(b.separation.total_cmp(&a.separation)),
            false => (b.separation / b.cost_s).total_cmp(&(a.separation / a.cost_s)),
        })
    });
    // Without an operator: say what only a swap would have decided.
    if !experiments.iter().any(|e| e.separates > 0)
        && let Some(o) = left_to_operator.iter().filter(|o| o.decisive).min_by(|a, b| a.cost_s.total_cmp(&b.cost_s))
    {
        let names: Vec<String> = hypotheses.iter().take(2).map(|h| h.effects.join(" + ")).collect();
        operator_steps.push(format!(
            "{}: left standing without an operator; {} {:?} would separate them (separation {:.0})",
            names.join(" / "),
            o.name,
            o.spec,
            o.separation
        ));
    }
    Ok(Plan {
        verdict,
        e1_mpa: d.e1_mpa,
        nu1: d.nu1,
        hypotheses,
        experiments,
        nothing_because: None,
        operator_steps,
        skipped,
    })
}

/// A diagnosis in one line: what it named (with the corrected E1, nu1), what
/// it could not rank, or that nothing stands out.
pub fn outcome_of(d: &Diagnosis) -> String {
    let values = format!("E1 {:.4} MPa, nu1 {:.4}", d.e1_mpa, d.nu1);
    if !d.effects.is_empty() {
        format!("named {}: {values}", d.effects.join(" + "))
    } else if !d.ambiguous.is_empty() {
        let alts: Vec<String> = d.ambiguous.iter().map(|a| a.effects.join(" + ")).collect();
        format!("ambiguous: {} ({values} with the best)", alts.join(" / "))
    } else if d.unexplained {
        format!("unexplained mismatch: {values}")
    } else {
        format!("nothing named: {values}")
    }
}

/// Refit the recording with `effects` on top of the baseline.
fn refit(model: &Model, base: &Fitted, effects: &[&'static str]) -> Option<Hypothesis> {
    let mut fit = base.clone();
    for name in effects {
        fit = crate::diagnosis::search::extend(model, &fit, model.candidate(Candidate::from_name(name)?))?;
    }
    let profile = model.profile(&fit.cands, &fit.x)?;
    let b = fit.base();
    Some(Hypothesis { effects: effects.to_vec(), e1_mpa: b.e1_mpa, nu1: b.nu1, chi2: fit.chi2, profile, fitted: fit })
}

/// The recording's time per settled sample of this kind: the median step
/// between consecutive samples of its sweep, s (a twist settles longer than a
/// stage step on most rigs).
pub fn step_time(rec: &Recording, kind: Phase) -> f64 {
    let mut dt: Vec<f64> = rec
        .samples
        .windows(2)
        .filter(|w| w.iter().all(|s| s.in_sweep() && s.phase == kind))
        .map(|w| w[1].t_s - w[0].t_s)
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    if dt.is_empty() { 1.0 } else { crate::numerics::stats::median(&mut dt) }
}

/// Rig time to reach a second depth, s: what the recording's own return to the
/// torsion depth took (from the last sample of the normal sweep to the first of
/// the torsion sweep); 0 for the experiments that act where the rig stands.
fn seek_time(rec: &Recording, spec: &ExperimentSpec) -> f64 {
    if !matches!(spec, ExperimentSpec::TorsionAtDepth { .. }) {
        return 0.0;
    }
    let last_normal = rec.sweep(Phase::Normal).last().map(|s| s.t_s);
    let first_torsion = rec.sweep(Phase::Torsion).next().map(|s| s.t_s);
    match (last_normal, first_torsion) {
        (Some(a), Some(b)) if b > a => b - a,
        _ => 0.0,
    }
}

/// The commanded history of a recording, as the diagnosis replays it.
fn history(rec: &Recording) -> Vec<CommandedPose> {
    rec.samples
        .iter()
        .map(|s| CommandedPose {
            t_s: s.t_s,
            stage_mm: s.stage_mm,
            rot_deg: if s.phase == Phase::Torsion { s.rot_deg } else { 0.0 },
        })
        .collect()
}

fn pair_of(rec: &Recording, profile: &SimProfile) -> Option<ContactPair> {
    let m = profile.material?;
    Some(ContactPair { elastomer: Body::new(m.e1_mpa, m.nu1, rec.meta.elastomer_r_mm), indenter: rec.meta.indenter })
}

/// A predicted reading: gamma1 (mm), and theta1 (degrees) for a torsion-kind sample.
pub type Reading = (f64, Option<f64>);

/// How far apart `spec`'s outcomes are under hypotheses `a` and `b`, and the
/// largest gamma1 `a` predicts during it, mm. Both predict the step's
/// readings (gamma1, and theta1 for a torsion-kind sample), compared over
/// the noise.
///
/// A step the rig runs alone continues the recording: the rig runs it as it
/// would under `a` (the best), from the stage of the recording's last sample,
/// with the whole recorded history behind it. An operator step mounts its
/// indenter on each hypothesis's rig (its E1, nu1 and effects) from a fresh
/// history (the gel recovered while parked) and loads it along the step's
/// path after the recording.
fn separation(
    rec: &Recording,
    a: &Hypothesis,
    b: &Hypothesis,
    spec: &ExperimentSpec,
    step_time_s: f64,
    sigma_g: f64,
    sigma_t: f64,
) -> Result<(f64, f64), PlanError> {
    let (pa, pb) = predictions(rec, a, b, spec, step_time_s)?;
    // An operator's sweep is judged with its own contact offset fitted
    // ([`ball_chi2`]): what a shift of every depth alike explains separates
    // nothing (over such a sweep gamma1 follows the stage nearly one to one).
    let shift = match spec.is_operator() {
        true => {
            let live: Vec<f64> =
                pa.iter().zip(&pb).filter(|(a, b)| a.0 > 0.0 && b.0 > 0.0).map(|(a, b)| a.0 - b.0).collect();
            if live.is_empty() { 0.0 } else { live.iter().sum::<f64>() / live.len() as f64 }
        }
        false => 0.0,
    };
    let d = pa
        .iter()
        .zip(&pb)
        .map(|((ga, ta), (gb, tb))| {
            let t = match (ta, tb) {
                (Some(ta), Some(tb)) => ((ta - tb) / sigma_t).powi(2),
                _ => 0.0,
            };
            let g = if *ga > 0.0 && *gb > 0.0 { ga - gb - shift } else { ga - gb };
            (g / sigma_g).powi(2) + t
        })
        .sum();
    Ok((d, pa.iter().map(|p| p.0).fold(0.0, f64::max)))
}

/// The readings hypotheses `a` and `b` predict for `spec` after `rec`, sample
/// by sample (as [`separation`] compares them).
pub fn predictions(
    rec: &Recording,
    a: &Hypothesis,
    b: &Hypothesis,
    spec: &ExperimentSpec,
    step_time_s: f64,
) -> Result<(Vec<Reading>, Vec<Reading>), PlanError> {
    let fail = |e: String| PlanError::Simulate(e);
    // (gamma1, theta1 when torsion-kind) of each sample under a, then under b.
    let (pa, pb): (Vec<Reading>, Vec<Reading>) = match spec.operator_indenter() {
        Some(indenter) => {
            let (ExperimentSpec::RigidBall { travel_mm, steps, .. }
            | ExperimentSpec::SwapIndenter { travel_mm, steps, .. }) = *spec
            else {
                return Err(fail(format!("{} has no operator sweep", spec.name())));
            };
            let t0 = rec.samples.last().map_or(0.0, |s| s.t_s) + step_time_s;
            let cmds: Vec<CommandedPose> = sim::experiment::operator_path(travel_mm, steps)
                .iter()
                .enumerate()
                .map(|(i, &(stage, _))| CommandedPose {
                    t_s: t0 + i as f64 * step_time_s,
                    stage_mm: stage,
                    rot_deg: 0.0,
                })
                .collect();
            let read = |h: &Hypothesis| -> Result<Vec<Reading>, PlanError> {
                let pair = pair_of(rec, &h.profile).ok_or_else(|| fail("a hypothesis has no material".into()))?;
                let pair = ContactPair { indenter, ..pair };
                // The swapped indenter's contact is found by an approach of
                // its own: the recording's contact offset is not its.
                let profile = SimProfile { contact_offset: None, ..h.profile.clone() };
                let r = simulate(pair, &profile, &cmds).map_err(|e| fail(e.to_string()))?;
                Ok(r.iter().map(|r| (if r.in_contact { r.gamma1_mm } else { 0.0 }, None)).collect())
            };
            (read(a)?, read(b)?)
        }
        None => {
            let hist = history(rec);
            let Some(pair_b) = pair_of(rec, &b.profile) else {
                return Err(fail("a hypothesis has no material".into()));
            };
            let run = run_under(rec, a, spec, step_time_s)?;
            // The run's own poses, each timed move ramped (an approach at
            // another speed) as the generator drove it; one reading per sample.
            let mut cmds = hist.clone();
            let mut at = Vec::with_capacity(run.len());
            let mut prev = hist.last().copied();
            for s in &run {
                let here = CommandedPose { t_s: s.t_s, stage_mm: s.stage_mm, rot_deg: s.rot_deg };
                if let (Some((t0, t1)), Some(p)) = (s.timing.move_s, prev) {
                    let n = sim::effects::viscoelastic::substeps(t1 - t0);
                    cmds.push(CommandedPose { t_s: t0.max(p.t_s), ..p });
                    for k in 1..=n {
                        let f = k as f64 / n as f64;
                        cmds.push(CommandedPose {
                            t_s: (t0 + f * (t1 - t0)).max(p.t_s),
                            stage_mm: p.stage_mm + f * (here.stage_mm - p.stage_mm),
                            rot_deg: p.rot_deg + f * (here.rot_deg - p.rot_deg),
                        });
                    }
                }
                at.push(cmds.len());
                cmds.push(here);
                prev = Some(here);
            }
            let pred_b = simulate(pair_b, &b.profile, &cmds).map_err(|e| fail(e.to_string()))?;
            let torsion = |s: &Sample| s.phase == Phase::Torsion;
            let pa = run.iter().map(|s| (s.gamma1_mm, torsion(s).then_some(s.theta1_deg))).collect();
            let pb = run
                .iter()
                .zip(&at)
                .map(|(s, &i)| (pred_b[i].gamma1_mm, torsion(s).then_some(pred_b[i].theta1_deg)))
                .collect();
            (pa, pb)
        }
    };
    Ok((pa, pb))
}

/// The samples a rig that behaves as `h` records during `spec` (one the rig
/// runs alone) after `rec`, noise-free: it runs from the stage of the
/// recording's last sample, with the whole recorded history behind it.
fn run_under(
    rec: &Recording,
    h: &Hypothesis,
    spec: &ExperimentSpec,
    step_time_s: f64,
) -> Result<Vec<Sample>, PlanError> {
    let fail = |e: String| PlanError::Simulate(e);
    let pair = pair_of(rec, &h.profile).ok_or_else(|| fail("a hypothesis has no material".into()))?;
    let mut rig = TrueRig::new(pair, &h.profile).map_err(|e| fail(e.to_string()))?;
    for p in history(rec) {
        rig.read(p).map_err(|e| fail(e.to_string()))?;
    }
    let Some(last) = rec.samples.last() else { return Err(fail("the recording is empty".into())) };
    sim::generator::continue_run(rig, last.t_s + step_time_s, last.stage_mm, &[*spec], step_time_s)
        .map_err(|e| fail(e.to_string()))
}

/// The sensor's depth gain as a rigid-ball sweep measures it (docs/experiments.md,
/// "Operator-assisted steps").
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GainMeasure {
    /// gamma1 as read over gamma1 as it is.
    pub g: f64,
    /// Its standard error.
    pub g_sd: f64,
    /// In-contact samples used.
    pub samples: usize,
}

/// Measure the gain from a rigid-ball recording (its header's indenter is the
/// ball). With gamma2 = 0 and a stiff frame the stage travel past contact is
/// gamma1, and the sensor reads g gamma1: a straight line, read = g (stage -
/// z0), fitted by least squares with the reading (which carries the noise)
/// on the left. A compliant frame bends it (C F); whether the frame or the
/// gain explains the sweep is decided by the hypotheses' predictions
/// ([`decide_with_ball`]), since over the ball's small forces C F is close
/// to a line too.
pub fn rigid_ball_gain(ball: &Recording) -> Option<GainMeasure> {
    let live: Vec<&Sample> = ball.samples.iter().filter(|s| ball_resolved(ball, s)).collect();
    let n = live.len();
    if n < 5 {
        return None;
    }
    let nf = n as f64;
    let (sx, sy) = live.iter().fold((0.0, 0.0), |(a, b), s| (a + s.stage_mm, b + s.gamma1_mm));
    let (mx, my) = (sx / nf, sy / nf);
    let (sxx, sxy) = live
        .iter()
        .fold((0.0, 0.0), |(a, b), s| (a + (s.stage_mm - mx).powi(2), b + (s.stage_mm - mx) * (s.gamma1_mm - my)));
    let g = sxy / sxx;
    let rss: f64 = live.iter().map(|s| (s.gamma1_mm - my - g * (s.stage_mm - mx)).powi(2)).sum();
    let g_sd = (rss / (nf - 2.0) / sxx).sqrt();
    (g.is_finite() && g > 0.0).then_some(GainMeasure { g, g_sd, samples: n })
}

/// A rigid-ball sample the gain is measured on: in contact, and at least a
/// quarter of the sweep's deepest reading. A rig's marker-field estimator
/// reads contacts near the marker pitch with the curvature it learnt on the
/// run's own indenter, which is not the ball's: on the emulated rig the
/// ball's shallowest samples (below about 0.6 of 2.5 mm) read up to 10 %
/// low, which pulled a 0.99 gain to 0.998 (docs/experiments.md).
fn ball_resolved(ball: &Recording, s: &Sample) -> bool {
    let deepest = ball.samples.iter().map(|s| s.gamma1_mm).fold(0.0, f64::max);
    s.gamma1_mm > 0.0 && s.stage_mm > 0.0 && s.gamma1_mm >= 0.25 * deepest
}

/// What the closed loop makes of a rigid-ball sweep.
#[derive(Debug, Clone, Serialize)]
pub struct GainDecision {
    pub gain: GainMeasure,
    /// The hypothesis whose prediction of the ball's readings fits best, and
    /// each hypothesis's chi² on them.
    pub best: Vec<&'static str>,
    pub chi2: Vec<(String, f64)>,
    /// The best hypothesis holds the sensor gain and the gain differs from 1
    /// by more than four of its standard errors and 0.2 %.
    pub named: bool,
    /// Effects named: the sensor gain when it is, with what the recording's
    /// diagnosis names once its depths are divided by the measured gain.
    pub effects: Vec<&'static str>,
    #[serde(rename = "E1_MPa")]
    pub e1_mpa: f64,
    pub nu1: f64,
    /// 95 % intervals of `E1_MPa` and `nu1`: when the gain is named, those of
    /// the refit of the corrected recording, widened by the gain's own
    /// uncertainty ([`correct_for_gain`]); otherwise the diagnosis's.
    pub ci95: Ci95,
    /// One line, as [`outcome_of`].
    pub outcome: String,
}

/// A recording corrected for a measured depth gain: its depth readings (and
/// their standard errors) divided by g, diagnosed again.
#[derive(Debug, Clone)]
pub struct GainCorrected {
    /// `sensor_gain` first, then what the corrected recording's diagnosis names.
    pub effects: Vec<&'static str>,
    pub e1_mpa: f64,
    pub nu1: f64,
    /// The refit's 95 % intervals (the corrected fit's when the diagnosis
    /// names an effect, else its baseline's), each end moved out by the
    /// gain's share: 1.96 g_sd times the slope of the full-model fit's E1
    /// (nu1) in g, added in quadrature.
    pub ci95: Ci95,
    /// What the gain's standard error alone moves E1 and nu1 by (1.96 g_sd
    /// times the slope): the share of the intervals that is the ball's.
    pub gain_share: [f64; 2],
    /// The diagnosis of the corrected recording.
    pub diagnosis: Diagnosis,
}

fn divided_by(rec: &Recording, g: f64) -> Recording {
    let mut fixed = rec.clone();
    for s in &mut fixed.samples {
        s.gamma1_mm /= g;
        s.gamma1_sd_mm = s.gamma1_sd_mm.map(|v| v / g);
    }
    fixed
}

/// Divide `rec`'s depth readings by the gain a rigid ball measured and
/// diagnose it again (docs/experiments.md, "The headline after the loop").
/// The intervals are the refit's; the gain's own standard error adds to
/// them, through the full-model fit's slope of E1 and nu1 in g (two
/// full-model fits, at g -+ its standard error).
pub fn correct_for_gain(rec: &Recording, gain: &GainMeasure) -> Result<GainCorrected, PlanError> {
    let d2 = diagnose(&divided_by(rec, gain.g), &DiagnoseOptions::default())?;
    let fit = if d2.effects.is_empty() { &d2.baseline } else { &d2.corrected };
    let (e1_mpa, nu1) = (fit.e1_mpa, fit.nu1);
    let h = gain.g_sd.max(1e-5);
    let at = |g: f64| {
        crate::fit::calibrate(&divided_by(rec, g), &crate::fit::FitOptions::default())
            .map(|c| (c.full.e1_mpa, c.full.nu1))
            .map_err(|e| PlanError::Simulate(format!("cannot fit the recording divided by the gain {g:.5}: {e}")))
    };
    let (lo, hi) = (at(gain.g - h)?, at(gain.g + h)?);
    // d(value)/dg times 1.96 g_sd.
    let share = |a: f64, b: f64| ((b - a) / (2.0 * h) * 1.96 * gain.g_sd).abs();
    let gain_share = [share(lo.0, hi.0), share(lo.1, hi.1)];
    let widen = |v: f64, ci: [f64; 2], w: f64| [v - (v - ci[0]).hypot(w), v + (ci[1] - v).hypot(w)];
    let ci95 =
        Ci95 { e1_mpa: widen(e1_mpa, fit.ci95.e1_mpa, gain_share[0]), nu1: widen(nu1, fit.ci95.nu1, gain_share[1]) };
    let mut effects = vec!["sensor_gain"];
    effects.extend(d2.effects.iter().copied().filter(|e| *e != "sensor_gain"));
    Ok(GainCorrected { effects, e1_mpa, nu1, ci95, gain_share, diagnosis: d2 })
}

/// `E1 0.3300 MPa [0.3290, 0.3310], nu1 0.3900 [0.3850, 0.3950]`.
fn with_intervals(e1_mpa: f64, nu1: f64, ci: &Ci95) -> String {
    format!(
        "E1 {e1_mpa:.4} MPa [{:.4}, {:.4}], nu1 {nu1:.4} [{:.4}, {:.4}]",
        ci.e1_mpa[0], ci.e1_mpa[1], ci.nu1[0], ci.nu1[1]
    )
}

/// χ² of the ball's resolved readings under `profile` (the recording's
/// material and effects with the ball mounted), with the ball's own contact
/// offset fitted: the ball's contact was found by an approach of its own, a
/// micrometre or more off like any (`contact_sd_mm` of its recording, a
/// prior on the offset when declared), and the recording's offset says
/// nothing of it. Applying the recording's offset to the ball named the
/// wrong explanation of a compliant frame whenever the recording's zero had
/// been moved (a run rewrites it to its calibration's: 9 µm there, which the
/// frame's hypothesis then carried to the ball as 9 µm of depth).
fn ball_chi2(
    rec: &Recording,
    profile: &SimProfile,
    ball: &Recording,
    cmds: &[CommandedPose],
    sigma_g: f64,
) -> Result<f64, PlanError> {
    let fail = |e: String| PlanError::Simulate(e);
    let pair = pair_of(rec, profile).ok_or_else(|| fail("a hypothesis has no material".into()))?;
    let pair = ContactPair { indenter: ball.meta.indenter, ..pair };
    let residuals = |offset_mm: f64| -> Result<Vec<f64>, PlanError> {
        let offset = sim::effects::contact_offset::Params { contact_offset_mm: offset_mm };
        let profile = SimProfile { contact_offset: Some(offset), ..profile.clone() };
        let r = simulate(pair, &profile, cmds).map_err(|e| fail(e.to_string()))?;
        Ok(ball
            .samples
            .iter()
            .zip(&r)
            .filter(|(s, _)| ball_resolved(ball, s))
            .map(|(s, r)| (s.gamma1_mm - r.gamma1_mm) / sigma_g)
            .collect())
    };
    // Gauss–Newton in the one offset (the readings move nearly one to one with it).
    let prior = ball.meta.contact_sd_mm().filter(|sd| sd.is_finite() && *sd > 0.0);
    let cost = |z: f64, r: &[f64]| r.iter().map(|x| x * x).sum::<f64>() + prior.map_or(0.0, |sd| (z / sd).powi(2));
    const STEP_MM: f64 = 1e-4;
    let (mut z, mut r) = (0.0, residuals(0.0)?);
    for _ in 0..6 {
        let ahead = residuals(z + STEP_MM)?;
        let j: Vec<f64> = ahead.iter().zip(&r).map(|(a, b)| (a - b) / STEP_MM).collect();
        let jj = j.iter().map(|x| x * x).sum::<f64>() + prior.map_or(0.0, |sd| sd.powi(-2));
        let jr = j.iter().zip(&r).map(|(a, b)| a * b).sum::<f64>() + prior.map_or(0.0, |sd| z / sd.powi(2));
        if !(jj > 0.0 && jr.is_finite()) {
            break;
        }
        let next = z - jr / jj;
        let r_next = residuals(next)?;
        // Only a lower cost moves it (a NaN never does).
        if cost(next, &r_next).partial_cmp(&cost(z, &r)) != Some(std::cmp::Ordering::Less) {
            break;
        }
        let moved = (next - z).abs();
        (z, r) = (next, r_next);
        if moved < 1e-7 {
            break;
        }
    }
    Ok(cost(z, &r))
}

/// Decide with a rigid-ball recording taken after `rec` (diagnosed as `d`,
/// planned as `p`): each standing hypothesis predicts the ball's readings
/// (its E1, nu1 and effects with the ball mounted, as the plan scored it) and
/// the one with the least chi² stands. When that one holds the sensor gain and
/// the measured gain is off, the recording is corrected for it
/// ([`correct_for_gain`]): E1, nu1 and their intervals are then the
/// corrected recording's.
pub fn decide_with_ball(rec: &Recording, d: &Diagnosis, p: &Plan, ball: &Recording) -> Result<GainDecision, PlanError> {
    let fail = |e: String| PlanError::Simulate(e);
    let gain =
        rigid_ball_gain(ball).ok_or_else(|| fail("the rigid-ball sweep has too few samples in contact".into()))?;
    let sigma_g = d.noise.normal_um * 1e-3;
    let cmds: Vec<CommandedPose> =
        ball.samples.iter().map(|s| CommandedPose { t_s: s.t_s, stage_mm: s.stage_mm, rot_deg: 0.0 }).collect();
    let mut chi2 = Vec::new();
    for h in &p.hypotheses {
        chi2.push((h.effects.clone(), ball_chi2(rec, &h.profile, ball, &cmds, sigma_g)?));
    }
    let best = chi2.iter().min_by(|a, b| a.1.total_cmp(&b.1)).map(|b| b.0.clone()).unwrap_or_default();
    let named = best.contains(&"sensor_gain") && (gain.g - 1.0).abs() > (4.0 * gain.g_sd).max(0.002);
    if !named {
        // The gain is ruled out, but the ball weighed the rest too: a
        // compliant frame gives under the ball's load as under the
        // indenter's, a layer stiffens the ball's contact in its own way,
        // and the recording's baseline (no effect) predicts its readings
        // as well. One of those that fits the ball by DECISIVE_SEPARATION
        // better than each other one (the baseline included) stands.
        let base =
            Base { e1_mpa: d.baseline.e1_mpa, nu1: d.baseline.nu1, contact_offset_mm: d.baseline.contact_offset_mm };
        let model = Model::new(rec, sigma_g, d.noise.torsion_deg);
        let none = model
            .profile(&[], &base.internal())
            .and_then(|profile| ball_chi2(rec, &profile, ball, &cmds, sigma_g).ok());
        let mut rest: Vec<(&[&'static str], f64)> =
            chi2.iter().filter(|(e, _)| !e.contains(&"sensor_gain")).map(|(e, c)| (e.as_slice(), *c)).collect();
        rest.sort_by(|a, b| a.1.total_cmp(&b.1));
        let stands = match (rest.first(), none) {
            (Some(&(effects, c)), Some(c0)) => {
                let next = rest.get(1).map_or(f64::INFINITY, |r| r.1).min(c0);
                (c + DECISIVE_SEPARATION <= next).then(|| effects.to_vec())
            }
            _ => None,
        };
        let chi2_text: Vec<String> = chi2
            .iter()
            .map(|(e, c)| format!("{} {c:.1}", e.join(" + ")))
            .chain(none.map(|c| format!("no effect {c:.1}")))
            .collect();
        let ruled_out = format!(
            "sensor gain ruled out (rigid ball: g {:.4} +- {:.4}; ball chi2 {})",
            gain.g,
            gain.g_sd,
            chi2_text.join(", ")
        );
        let chi2: Vec<(String, f64)> = chi2.into_iter().map(|(e, c)| (e.join(" + "), c)).collect();
        if let Some(effects) = stands
            && let Some(alt) = d.ambiguous.iter().find(|a| a.effects == effects)
        {
            return Ok(GainDecision {
                gain,
                best: effects.clone(),
                chi2,
                named: false,
                effects: effects.clone(),
                e1_mpa: alt.e1_mpa,
                nu1: alt.nu1,
                ci95: alt.ci95,
                outcome: format!(
                    "{ruled_out}; the ball names {}: {}",
                    effects.join(" + "),
                    with_intervals(alt.e1_mpa, alt.nu1, &alt.ci95)
                ),
            });
        }
        let fit = if d.effects.is_empty() { &d.baseline } else { &d.corrected };
        return Ok(GainDecision {
            gain,
            best,
            chi2,
            named,
            effects: d.effects.clone(),
            e1_mpa: d.e1_mpa,
            nu1: d.nu1,
            ci95: fit.ci95,
            outcome: format!("{ruled_out}; {}", outcome_of(d)),
        });
    }
    let chi2: Vec<(String, f64)> = chi2.into_iter().map(|(e, c)| (e.join(" + "), c)).collect();
    let c = correct_for_gain(rec, &gain)?;
    let outcome = format!(
        "named {} (rigid ball: g {:.4} +- {:.4}): {}",
        c.effects.join(" + "),
        gain.g,
        gain.g_sd,
        with_intervals(c.e1_mpa, c.nu1, &c.ci95)
    );
    Ok(GainDecision {
        gain,
        best,
        chi2,
        named,
        effects: c.effects,
        e1_mpa: c.e1_mpa,
        nu1: c.nu1,
        ci95: c.ci95,
        outcome,
    })
}

/// The plan as text: the hypotheses, the choice with its time and what each outcome would mean, the others.
pub fn report(p: &Plan) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    if let Some(why) = &p.nothing_because {
        let _ = writeln!(s, "No experiment proposed: {why}.");
    }
    if !p.hypotheses.is_empty() {
        let _ = writeln!(s, "Standing (refitted, best first):");
        for h in &p.hypotheses {
            let _ = writeln!(
                s,
                "  {:<28} E1 {:.4} MPa, nu1 {:.4}, chi2 {:.1}",
                h.effects.join(" + "),
                h.e1_mpa,
                h.nu1,
                h.chi2
            );
        }
    }
    if let (Some(c), [a, b, ..]) = (p.choice(), p.hypotheses.as_slice()) {
        let verdict = match (c.decisive, c.leaves.is_empty(), c.separates) {
            (true, true, _) => "decides".to_string(),
            (_, _, n) if n > 0 => {
                let left: Vec<&str> = c.leaves.iter().map(|(h, _)| h.as_str()).collect();
                format!("separates the best from {n} of the others, leaves {} standing with it", left.join(", "))
            }
            _ => "separates best per second, but may not decide".to_string(),
        };
        let _ = writeln!(
            s,
            "Run: {}{} {:?} ({} samples, about {:.0} s of rig time): separation {:.1} (decisive at {DECISIVE_SEPARATION}), {verdict}.",
            c.name,
            if c.operator { " (an operator swaps the indenter)" } else { "" },
            c.spec,
            c.samples,
            c.rig_time_s,
            c.separation
        );
        for h in [a, b] {
            let effects = h.effects.join(" + ");
            let _ = writeln!(
                s,
                "  If its readings follow {effects}: {effects} is named, with E1 {:.4} MPa, nu1 {:.4}.",
                h.e1_mpa, h.nu1
            );
        }
        let _ = writeln!(s, "Candidates (separation refitted, without refit, rig time; what each leaves standing):");
        for e in &p.experiments {
            let who = if e.operator { " + operator" } else { "" };
            let leaves: Vec<String> = e.leaves.iter().map(|(h, d)| format!("{h} ({d:.1})")).collect();
            let leaves = if leaves.is_empty() { String::new() } else { format!("; leaves {}", leaves.join(", ")) };
            let _ = writeln!(
                s,
                "  {:<18} {:>8.1} {:>8.1} {:>6.0} s{who}  {:?}{leaves}",
                e.name, e.separation, e.separation_no_refit, e.rig_time_s, e.spec
            );
        }
    }
    for o in &p.operator_steps {
        let _ = writeln!(s, "Beyond what the rig can run alone: {o}");
    }
    for k in &p.skipped {
        let _ = writeln!(s, "Not weighed: {k}");
    }
    s
}
