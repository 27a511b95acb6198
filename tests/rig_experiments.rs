//! The experiment steps end to end on the emulated rig (issue 14): the real
//! APT drivers, the simulated sensor with the rig's effects, the sequencer's
//! guarded moves. One run with every kind of step; the recording must hold
//! each step's samples under its own phase, on the paths the script asked for.

#[path = "support/creep_drift.rs"]
mod creep_drift;
#[path = "support/emulated.rs"]
mod emulated;

use easycalib::run::Script;
use sim::effects::{SimProfile, frame_compliance};
use sim::experiment::{Experiment, ExperimentSpec};
use sim::recording::{Direction, Phase, Recording};

/// How far the run moved the recording's stage zero after streaming it
/// (docs/run.md, "Stage zero"; 0 when it did not): add it to a recorded
/// stage to get the streamed stage coordinate.
fn stage_zero_moved_mm(rec: &Recording) -> f64 {
    rec.meta
        .extra
        .iter()
        .find(|(k, _)| k == easycalib::fit::zero::ZERO_MOVED_KEY)
        .map_or(0.0, |(_, v)| v.parse().expect("the recording's stage_zero_moved_mm is a number"))
}

#[test]
fn every_experiment_runs_through_the_real_drivers_and_records_its_phase() {
    let script = Script {
        experiment: vec![
            ExperimentSpec::Dwell { hold_s: 10.0, every_s: 2.0 },
            ExperimentSpec::Reload { fraction: 0.5, steps: 3, cycles: 1 },
            ExperimentSpec::TwistReversal { amplitude_deg: 2.0, step_deg: 0.5 },
            ExperimentSpec::TorsionAtDepth { beta: 0.3, amplitude_deg: 8.0, step_deg: 0.4 },
        ],
        // The second depth goes deeper than the sweep: at beta 0.3 this gel's
        // gamma1 comes near the default 5 mm limit, which the guard's bound
        // (growing by every inward move) would reach first.
        limits: easycalib::run::script::LimitsSection { max_gamma1_mm: 8.0, ..Default::default() },
        ..Script::default()
    };
    let profile =
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..SimProfile::default() };
    let (out, rec) = emulated::run_script(3, profile, script);
    println!("{out:?}");
    // The steps' samples follow the sweeps, in the script's order, each under its phase.
    let first = rec.samples.iter().position(|s| s.experiment.is_some()).expect("experiment samples");
    assert!(rec.samples[..first].iter().all(|s| s.in_sweep()));
    let mut order: Vec<Experiment> = rec.samples[first..]
        .iter()
        .map(|s| s.experiment.expect("no sweep sample after the experiments began"))
        .collect();
    order.dedup();
    assert_eq!(order, [Experiment::Dwell, Experiment::Reload, Experiment::Reversal, Experiment::Torsion2]);
    let of = |e: Experiment| rec.samples.iter().filter(move |s| s.experiment == Some(e)).collect::<Vec<_>>();
    let torsion_stage = rec.sweep(Phase::Torsion).last().expect("torsion sweep").stage_mm;
    // Dwell: six samples at the torsion depth, due every 2 s of rig time (each
    // stamped when its settling ends).
    let dwell = of(Experiment::Dwell);
    assert_eq!(dwell.len(), 6);
    assert!(dwell.iter().all(|s| s.phase == Phase::Normal && (s.stage_mm - torsion_stage).abs() < 1e-6));
    let times: Vec<f64> = dwell.iter().map(|s| s.t_s).collect();
    assert!(times.windows(2).all(|w| (1.0..3.0).contains(&(w[1] - w[0]))), "{times:?}");
    assert!((times[5] - times[0] - 10.0).abs() < 1.0, "{times:?}");
    // Reload: down to half the travel past contact and back to the depth.
    let reload = of(Experiment::Reload);
    assert_eq!(reload.len(), 6);
    // (In the streamed stage coordinates: the run then moved the stage zero.)
    let moved = stage_zero_moved_mm(&rec);
    let lowest = reload.iter().map(|s| s.stage_mm).fold(f64::INFINITY, f64::min) + moved;
    let top = torsion_stage + moved;
    assert!((lowest - 0.5 * top).abs() < 0.002, "lowest {lowest} of {top}");
    assert_eq!(reload.iter().filter(|s| s.dir == Some(Direction::Unload)).count(), 3);
    assert!((reload.last().unwrap().stage_mm - torsion_stage).abs() < 1e-3);
    // Twist reversal: through zero to the other side; theta1 follows the sign.
    let rev = of(Experiment::Reversal);
    let (lo, hi) = rev.iter().fold((0.0f64, 0.0f64), |(a, b), s| (a.min(s.rot_deg), b.max(s.rot_deg)));
    assert!((lo + 2.0).abs() < 0.01 && (hi - 2.0).abs() < 0.01, "{lo} {hi}");
    let at_min = rev.iter().find(|s| (s.rot_deg - lo).abs() < 1e-9).unwrap();
    assert!(at_min.theta1_deg < 0.0 && at_min.phase == Phase::Torsion);
    // Torsion at the second depth: the measured beta there is 0.3.
    let t2 = of(Experiment::Torsion2);
    assert_eq!(t2.len(), 41);
    let beta = (t2[0].stage_mm + moved - t2[0].gamma1_mm) / rec.meta.indenter.r_mm;
    assert!((beta - 0.3).abs() < 0.005, "beta {beta}");
    // The run fitted and diagnosed the whole recording: the torsion at the
    // second depth tells the compliant frame from a layer (the standard sweeps
    // leave them ambiguous, tests/rig_effects.rs), and the correction holds
    // (named in each of the 9 runs of this seed checked while the test was written).
    assert_eq!(out.named, ["frame_compliance"], "{out:?}");
    assert!(out.corrected.0.abs() < 1.0 && out.corrected.1.abs() < 2.0, "{out:?}");
}

/// The closed loop on the emulated rig (`run --adaptive`): with a compliant
/// frame, which the standard sweeps cannot tell from a layer, the loop runs
/// the experiment `plan` chooses and the run's diagnosis then names the
/// frame; on a clean rig it runs nothing.
#[test]
fn the_closed_loop_runs_a_deciding_experiment_only_when_something_is_left_to_decide() {
    let adaptive = || Script {
        limits: easycalib::run::script::LimitsSection { max_gamma1_mm: 8.0, ..Default::default() },
        adaptive: easycalib::run::script::AdaptiveSection { enabled: true, ..Default::default() },
        ..Script::default()
    };
    let profile =
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..SimProfile::default() };
    let (out, rec) = emulated::run_script(5, profile, adaptive());
    println!("{out:#?}");
    assert!(!out.adaptive.is_empty(), "{out:?}");
    let spent: f64 = out.adaptive.iter().map(|s| s.rig_time_s).sum();
    assert!(spent > 0.0 && spent <= 120.0 + 60.0, "{spent} s");
    assert!(rec.samples.iter().any(|s| s.experiment.is_some()));
    // The chain in the report: experiment, why, rig time, outcome.
    let chain = &out.report_chain.0;
    assert_eq!(chain.as_array().map(Vec::len), Some(out.adaptive.len()), "{chain:#}");
    assert!(chain[0]["why"].as_str().is_some_and(|w| w.contains("separates")), "{chain:#}");
    assert!(chain[0]["outcome"].as_str().is_some_and(|o| o.contains("frame_compliance")), "{chain:#}");
    // E1 and nu1 after each step: the last one's are the run's corrected values.
    let last = &chain[out.adaptive.len() - 1];
    let (e1, nu1) = (last["E1_MPa"].as_f64().expect("E1_MPa"), last["nu1"].as_f64().expect("nu1"));
    assert!((e1 - out.adaptive[out.adaptive.len() - 1].e1_mpa).abs() < 1e-12 && nu1 > 0.0 && nu1 < 0.5, "{chain:#}");
    // ... with their 95 % intervals, which hold them.
    let ci = |k: &str| last["ci95"][k].as_array().map(|v| v.iter().filter_map(|x| x.as_f64()).collect::<Vec<f64>>());
    let (ce, cn) = (ci("E1_MPa").expect("ci95.E1_MPa"), ci("nu1").expect("ci95.nu1"));
    assert!(ce[0] < e1 && e1 < ce[1] && cn[0] < nu1 && nu1 < cn[1], "{chain:#}");
    assert_eq!(out.report_chain.1.len(), out.adaptive.len(), "{:?}", out.report_chain.1);
    assert!(out.report_chain.1[0].starts_with("| experiment 1 | torsion_at_depth"), "{:?}", out.report_chain.1);
    assert_eq!(out.named, ["frame_compliance"], "{out:?}");
    assert!(out.corrected.0.abs() < 1.0 && out.corrected.1.abs() < 2.0, "{out:?}");
    // `plan` on the recording as it stood before the loop's first step (read
    // back from the run's file, its stage zero moved by the fit) chooses the
    // experiment the loop ran, as the loop picks (decisive, within its gamma1 room).
    let first = rec.samples.iter().position(|s| s.experiment.is_some()).expect("the loop's samples");
    let before = sim::recording::Recording { meta: rec.meta.clone(), samples: rec.samples[..first].to_vec() };
    let p =
        easycalib::plan::plan(&before, easycalib::plan::PlanOptions { operator: false, experiment_sd: None }).unwrap();
    let room = 0.8 * 8.0;
    let pick = p.experiments.iter().find(|c| c.separates > 0 && c.peak_gamma1_mm <= room).map(|c| c.spec);
    assert_eq!(pick, Some(out.adaptive[0].spec), "{}", easycalib::plan::report(&p));

    // A clean rig: the loop runs an experiment only when the recording's own
    // diagnosis leaves more than one explanation standing, and names nothing
    // either way. How often a clean rig leaves one is a rate (no experiment
    // in 10 of 10 seeds, `closed_loop_rates_over_seeds`): the emulated rig's
    // recording varies with the machine's load, and about one run in 45
    // under load leaves a shallow stretch the diagnosis cannot rank. Which
    // experiment it then picks depends on the noise it expects of one
    // experiment sample, read from the sensor at that moment.
    let (clean, rec) = emulated::run_script(5, SimProfile::default(), adaptive());
    assert!(clean.named.is_empty(), "{clean:?}");
    assert!(clean.corrected.0.abs() < 1.0 && clean.corrected.1.abs() < 2.0, "{clean:?}");
    match clean.adaptive.first() {
        None => {
            assert!(clean.report_chain.0.is_null() && clean.report_chain.1.is_empty(), "{:?}", clean.report_chain);
            assert!(rec.samples.iter().all(|s| s.in_sweep()));
        }
        Some(step) => {
            assert!(step.why.contains("separates"), "{clean:?}");
            let first = rec.samples.iter().position(|s| s.experiment.is_some()).unwrap_or(rec.samples.len());
            let before = sim::recording::Recording { meta: rec.meta.clone(), samples: rec.samples[..first].to_vec() };
            let p =
                easycalib::plan::plan(&before, easycalib::plan::PlanOptions { operator: true, experiment_sd: None })
                    .unwrap();
            assert!(p.hypotheses.len() >= 2, "{}", easycalib::plan::report(&p));
        }
    }
}

/// Rates of the closed loop over seeds (issue 14, "Must show", for the pair
/// this slice covers): with a compliant frame the true effect is named in at
/// least 90 % of seeds with E1 within 1 % and nu1 within 2 % of the truth; on
/// a clean rig no experiment is run in at least 95 % of seeds (here: at most
/// one of ten) and nothing is named. The median extra rig time is printed.
/// About 2 minutes on two cores (10/10 and 10/10, median 26 s, when written): `cargo test --release --test rig_experiments -- --ignored --nocapture`.
#[test]
#[ignore = "a rate study (20 emulated runs); run by hand or in the statistical suite"]
fn closed_loop_rates_over_seeds() {
    let adaptive = || Script {
        limits: easycalib::run::script::LimitsSection { max_gamma1_mm: 8.0, ..Default::default() },
        adaptive: easycalib::run::script::AdaptiveSection { enabled: true, ..Default::default() },
        ..Script::default()
    };
    let frame =
        SimProfile { frame_compliance: Some(frame_compliance::Params { c_mm_per_n: 0.003 }), ..SimProfile::default() };
    let (mut named, mut extra) = (0, Vec::new());
    for seed in 100..110 {
        let (o, _) = emulated::run_script(seed, frame.clone(), adaptive());
        let ok = o.named == ["frame_compliance"] && o.corrected.0.abs() < 1.0 && o.corrected.1.abs() < 2.0;
        named += usize::from(ok);
        extra.push(o.adaptive.iter().map(|s| s.rig_time_s).sum::<f64>());
        println!(
            "frame seed {seed}: {ok} {:?} {:?} {:?}",
            o.named,
            o.corrected,
            o.adaptive.iter().map(|s| (s.name, s.rig_time_s)).collect::<Vec<_>>()
        );
    }
    extra.sort_by(f64::total_cmp);
    println!("RATE frame_compliance: named within 1 %/2 % in {named}/10; median extra rig time {:.1} s", extra[5]);
    let mut quiet = 0;
    for seed in 100..110 {
        let (o, _) = emulated::run_script(seed, SimProfile::default(), adaptive());
        quiet += usize::from(o.adaptive.is_empty() && o.named.is_empty());
        println!("clean seed {seed}: {:?} {:?}", o.named, o.adaptive.iter().map(|s| s.name).collect::<Vec<_>>());
    }
    println!("RATE clean: no experiment and nothing named in {quiet}/10");
    assert!(named >= 9, "{named}/10");
    assert!(extra[5] <= 60.0, "median extra rig time {} s", extra[5]);
    assert!(quiet >= 9, "{quiet}/10");
}

/// A sensor gain on the emulated rig without an operator (`--no-operator`,
/// docs/experiments.md, "Operator-assisted steps"): what the loop does when
/// it may not mount the rigid ball. Printed, with one bar: it never names an
/// effect the rig does not have. `cargo test --release --test rig_experiments gain -- --ignored --nocapture`.
#[test]
#[ignore = "a rate study (5 emulated runs)"]
fn closed_loop_on_a_sensor_gain_without_an_operator() {
    let script = Script {
        limits: easycalib::run::script::LimitsSection { max_gamma1_mm: 8.0, ..Default::default() },
        adaptive: easycalib::run::script::AdaptiveSection { enabled: true, operator: false, ..Default::default() },
        ..Script::default()
    };
    let gain = SimProfile { sensor_gain: Some(sim::effects::sensor_gain::Params { g: 0.99 }), ..SimProfile::default() };
    let mut wrong = 0;
    for seed in 100..105 {
        let (o, _) = emulated::run_script(seed, gain.clone(), script.clone());
        assert!(o.adaptive.iter().all(|s| !s.spec.is_operator()), "{o:?}");
        wrong += usize::from(o.named.iter().any(|n| *n != "sensor_gain"));
        println!(
            "gain seed {seed}: {} {:?} {:?} {:?}",
            o.verdict,
            o.named,
            o.corrected,
            o.adaptive.iter().map(|s| (s.name, s.rig_time_s)).collect::<Vec<_>>()
        );
    }
    println!("RATE gain without operator: a wrong effect named in {wrong}/5");
    assert_eq!(wrong, 0);
}

/// What one adaptive run with a sensor gain made of its rigid-ball step on the
/// emulated rig (real drivers over ptys, 40x time): the loop's steps, the
/// errors of E1 and nu1 after the ball (%, against the rig's truth), the
/// run's recording and the ball's. The run's folder is kept until the
/// recordings are read (`emulated::run_script`'s is gone when it returns).
struct BallRun {
    steps: Vec<easycalib::run::AdaptiveStep>,
    named: Vec<&'static str>,
    e1: f64,
    nu1: f64,
    rec: Recording,
    /// `None` when the loop never chose the rigid ball.
    ball: Option<Recording>,
    /// The run's report.json, its report.md, and the run's headline diagnosis
    /// (`RunResult::diagnosis`, what the CLI and the TUI's final panel show).
    report: serde_json::Value,
    markdown: String,
    headline: Option<easycalib::report::RunDiagnosis>,
    truth: sim::physics::Material,
}

fn ball_run(seed: u64, g: f64) -> BallRun {
    use easycalib::rig::emulated::{EmulatedRig, ServeOptions};
    let gain = SimProfile { sensor_gain: Some(sim::effects::sensor_gain::Params { g }), ..SimProfile::default() };
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
    rt.block_on(async {
        let setup =
            sim::setup::SimSetupInput { speedup: 40.0, seed, profile: gain, ..Default::default() }.resolve().unwrap();
        let rig = EmulatedRig::start(setup, ServeOptions::default()).await.unwrap();
        let truth = rig.truth();
        let dir = tempfile::tempdir().unwrap();
        let r = rig.calibrate(gain_script(), dir.path()).await.expect("devices open");
        assert_eq!(r.outcome.status, easycalib::run::RunStatus::Completed, "seed {seed}: {:?}", r.outcome.status);
        let rec = Recording::read_path(&r.outcome.recording).unwrap();
        let steps = r.outcome.adaptive.clone();
        let files = r.report.as_ref().expect("a report");
        let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&files.json).unwrap()).unwrap();
        let markdown = std::fs::read_to_string(&files.markdown).unwrap();
        let headline = r.diagnosis.clone();
        let Some(step) = steps.iter().find(|s| s.name == "rigid_ball") else {
            let (e1, nu1) = (f64::NAN, f64::NAN);
            return BallRun { named: vec![], e1, nu1, steps, rec, ball: None, report, markdown, headline, truth };
        };
        let path = step.recording.as_ref().expect("the step's recording");
        let ball = Recording::read_path(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        BallRun {
            named: step.effects.clone(),
            e1: 100.0 * (step.e1_mpa / truth.e1_mpa - 1.0),
            nu1: 100.0 * (step.nu1 / truth.nu1 - 1.0),
            steps,
            rec,
            ball: Some(ball),
            report,
            markdown,
            headline,
            truth,
        }
    })
}

fn gain_script() -> Script {
    Script {
        limits: easycalib::run::script::LimitsSection { max_gamma1_mm: 8.0, ..Default::default() },
        adaptive: easycalib::run::script::AdaptiveSection { enabled: true, ..Default::default() },
        ..Script::default()
    }
}

/// The operator step on the emulated rig (issue 14): with a sensor gain of
/// 0.99, which no sweep of the run's own indenter can tell from E1, the loop
/// chooses the rigid ball, the simulation mounts it (no prompt), the ball's
/// sweep goes to a recording of its own (the steel ball in its header,
/// `operator_step` among its keys), and the decision names sensor_gain with
/// E1 within 1 % and nu1 within 2 % of the rig's truth.
///
/// The emulated rig runs on wall time, so a seed's run is not repeatable to
/// the sample, and the loop's first choice is a rate: the ball after one
/// torsion in 10/10 seeds of `rigid_ball_rates_over_seeds`, but on a loaded CI
/// machine seed 101 once named a layer (`finite_thickness`, the known false
/// positive of this rig, docs/experiments.md) after its torsion and stopped
/// there. What this test checks is what follows the ball, on the first of
/// seeds 101 and 103 whose loop chose it; neither choosing it fails.
#[test]
fn the_emulated_rig_mounts_the_rigid_ball_and_the_loop_names_the_sensor_gain() {
    let mut missed = Vec::new();
    let mut chosen = None;
    for seed in [101, 103] {
        let run = ball_run(seed, 0.99);
        if run.ball.is_some() {
            chosen = Some((seed, run));
            break;
        }
        println!(
            "gain seed {seed}: no rigid-ball step: {:?}",
            run.steps.iter().map(|s| &s.outcome).collect::<Vec<_>>()
        );
        missed.push((seed, run.steps));
    }
    let (seed, BallRun { steps, named, e1, nu1, rec, ball, report, markdown, headline, truth }) =
        chosen.unwrap_or_else(|| panic!("no rigid-ball step in seeds 101 and 103: {missed:#?}"));
    let ball = ball.unwrap_or_else(|| panic!("no rigid-ball step: {steps:#?}"));
    println!(
        "gain seed {seed}: {named:?} E1 {e1:+.3} % nu1 {nu1:+.3} % steps {:?}",
        steps.iter().map(|s| (s.name, s.rig_time_s, s.outcome.clone())).collect::<Vec<_>>()
    );
    // The ball's recording: the steel ball mounted, every sample of its phase,
    // in and out along the step's path; none of it in the run's recording.
    assert_eq!(ball.meta.indenter.e_mpa, sim::experiment::RIGID_BALL_E_MPA);
    assert!(ball.meta.extra.iter().any(|(k, v)| k == "operator_step" && v == "rigid_ball"), "{:?}", ball.meta.extra);
    assert!(ball.samples.iter().all(|s| s.experiment == Some(Experiment::RigidBall)));
    assert_eq!(ball.samples.iter().filter(|s| s.dir == Some(Direction::Load)).count(), ball.samples.len() / 2);
    assert!(rec.samples.iter().all(|s| s.experiment != Some(Experiment::RigidBall)));
    // The gain the ball measured is the rig's, to a few of its standard errors.
    let g = easycalib::plan::rigid_ball_gain(&ball).expect("a gain from the ball");
    println!("measured gain {:.5} +- {:.5} ({} samples)", g.g, g.g_sd, g.samples);
    assert!((g.g - 0.99).abs() < 0.002, "{g:?}");
    assert_eq!(named.first(), Some(&"sensor_gain"), "{steps:#?}");
    assert!(e1.abs() < 1.0 && nu1.abs() < 2.0, "E1 {e1} %, nu1 {nu1} %");
    assert_headline_is_the_gain(&report, &markdown, headline.as_ref(), truth);
}

/// The report's headline after a rigid ball that named the gain (docs/experiments.md,
/// "The headline after the loop"): report.json's `effects`, `E1_MPa`, `nu1`
/// and `ci95` are the decision's, within 1 % and 2 % of the rig's truth with
/// intervals not grossly too narrow, taken from the refit of the corrected recording
/// (not the calibration's); the run recording's own diagnosis stays under
/// `standard`; report.md and the run's headline diagnosis (the CLI's last
/// lines, the TUI's final panel) say the same.
fn assert_headline_is_the_gain(
    j: &serde_json::Value,
    markdown: &str,
    headline: Option<&easycalib::report::RunDiagnosis>,
    truth: sim::physics::Material,
) {
    let f = |v: &serde_json::Value| v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"));
    let show = serde_json::to_string_pretty(j).unwrap();
    assert_eq!(j["effects"][0], "sensor_gain", "{show}");
    assert_eq!(j["decided_by"], "rigid_ball", "{show}");
    let (e1, nu1) = (f(&j["E1_MPa"]), f(&j["nu1"]));
    println!(
        "headline E1 {e1:.5} {} nu1 {nu1:.5} {} (truth {} {})",
        j["ci95"]["E1_MPa"], j["ci95"]["nu1"], truth.e1_mpa, truth.nu1
    );
    assert!((e1 / truth.e1_mpa - 1.0).abs() < 0.01, "E1 {e1} vs {}", truth.e1_mpa);
    assert!((nu1 / truth.nu1 - 1.0).abs() < 0.02, "nu1 {nu1} vs {}", truth.nu1);
    // One run's 95 % interval misses the truth one time in twenty by design
    // (the rate study counts how often it holds it): here, only that it is
    // not grossly too narrow, the truth within twice its half-width (about
    // four standard errors) of its centre.
    let near = |ci: &serde_json::Value, t: f64| (t - 0.5 * (f(&ci[0]) + f(&ci[1]))).abs() <= f(&ci[1]) - f(&ci[0]);
    assert!(near(&j["ci95"]["E1_MPa"], truth.e1_mpa), "E1 interval {} far from {}", j["ci95"]["E1_MPa"], truth.e1_mpa);
    assert!(near(&j["ci95"]["nu1"], truth.nu1), "nu1 interval {} far from {}", j["ci95"]["nu1"], truth.nu1);
    // The decision's own intervals, not the uncorrected fit's.
    assert_ne!(
        j["ci95"],
        j["full"]["ci95"]
            .clone()
            .as_object()
            .map(|o| { serde_json::json!({"E1_MPa": o["E1_MPa"], "nu1": o["nu1"]}) })
            .unwrap(),
        "{show}"
    );
    assert_ne!(f(&j["E1_MPa"]), f(&j["full"]["E1_MPa"]));
    // The diagnosis is the decision; the run's recording alone stays under `standard`.
    assert_eq!(j["diagnosis"]["verdict"], "effects", "{show}");
    assert_eq!(j["diagnosis"]["E1_MPa"], j["E1_MPa"]);
    assert!(
        j["diagnosis"]["summary"].as_str().is_some_and(|s| s.starts_with("CLOSED LOOP, after rigid_ball")),
        "{show}"
    );
    assert!(j["standard"]["verdict"].as_str().is_some_and(|v| v != "not_made"), "{show}");
    assert!(markdown.contains("the closed loop's decision after `rigid_ball`"), "{markdown}");
    assert!(markdown.contains("The run's recording alone"), "{markdown}");
    let h = headline.expect("the run's headline diagnosis");
    assert_eq!((h.e1_mpa, h.nu1), (e1, nu1));
    assert!(h.closed_loop().is_some() && h.effects[0].name == "sensor_gain", "{h:?}");
}

/// Rate of the rigid-ball decision over seeds: sensor_gain named with E1
/// within 1 % and nu1 within 2 % in at least 9 of 10.
/// `cargo test --release --test rig_experiments rigid_ball_rates -- --ignored --nocapture`.
#[test]
#[ignore = "a rate study (10 emulated runs)"]
fn rigid_ball_rates_over_seeds() {
    let (mut ok, mut headline, mut extra) = (0, 0, Vec::new());
    for seed in 100..110 {
        let BallRun { steps, named, e1, nu1, report, truth, .. } = ball_run(seed, 0.99);
        let good = named.first() == Some(&"sensor_gain") && e1.abs() < 1.0 && nu1.abs() < 2.0;
        ok += usize::from(good);
        extra.push(steps.iter().map(|s| s.rig_time_s).sum::<f64>());
        // The report's headline: the gain named, within 1 %/2 %, intervals holding the truth.
        let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
        let holds = |ci: &serde_json::Value, t: f64| f(&ci[0]) <= t && t <= f(&ci[1]);
        let h = report["effects"][0] == "sensor_gain"
            && (f(&report["E1_MPa"]) / truth.e1_mpa - 1.0).abs() < 0.01
            && (f(&report["nu1"]) / truth.nu1 - 1.0).abs() < 0.02
            && holds(&report["ci95"]["E1_MPa"], truth.e1_mpa)
            && holds(&report["ci95"]["nu1"], truth.nu1);
        headline += usize::from(h);
        println!(
            "gain seed {seed} headline: {h} {} E1 {} {} nu1 {} {}",
            report["effects"], report["E1_MPa"], report["ci95"]["E1_MPa"], report["nu1"], report["ci95"]["nu1"]
        );
        println!(
            "gain seed {seed}: {good} {named:?} E1 {e1:+.3} % nu1 {nu1:+.3} % extra {:.0} s {:?}",
            steps.iter().map(|s| s.rig_time_s).sum::<f64>(),
            steps.iter().map(|s| (s.name, s.outcome.as_str())).collect::<Vec<_>>()
        );
    }
    extra.sort_by(f64::total_cmp);
    println!(
        "RATE sensor_gain with the rigid ball: {ok}/10; headline within 1 %/2 % with intervals holding the truth \
         {headline}/10; median extra rig time {:.1} s",
        0.5 * (extra[4] + extra[5])
    );
    assert!(ok >= 9, "{ok}/10");
    assert!(headline >= 9, "{headline}/10");
}

/// Why the plan called a second torsion decisive between a layer and a
/// sensor gain (docs/experiments.md, "Why the loop used to run two torsions
/// before the ball"): for two sensor-gain runs, the recorded standard errors
/// per phase, the plan on the recording before the loop's first step, each
/// hypothesis's predicted readings for the step the loop ran beside the
/// observed ones, and the plan after it. Printed only.
/// `cargo test --release --test rig_experiments torsion_prediction_probe -- --ignored --nocapture`.
#[test]
#[ignore = "a probe: prints predictions against observations"]
fn torsion_prediction_probe() {
    for seed in [100u64, 101] {
        let BallRun { steps, rec, .. } = ball_run(seed, 0.99);
        println!("seed {seed}: {:?}", steps.iter().map(|s| (s.name, s.spec, s.rig_time_s)).collect::<Vec<_>>());
        {
            use std::collections::BTreeMap;
            let mut m: BTreeMap<String, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
            for s in &rec.samples {
                let e = m.entry(format!("{:?}/{:?}", s.phase, s.experiment)).or_default();
                if let Some(v) = s.gamma1_sd_mm {
                    e.0.push(v * 1e3)
                }
                if let Some(v) = s.theta1_sd_deg {
                    e.1.push(v)
                }
            }
            for (k, (mut g, mut t)) in m {
                g.sort_by(f64::total_cmp);
                t.sort_by(f64::total_cmp);
                println!(
                    "SD {k}: n {} gamma1 um median {:?}, theta1 deg median {:?}",
                    g.len(),
                    g.get(g.len() / 2),
                    t.get(t.len() / 2)
                );
            }
            println!("meta extra {:?}", rec.meta.extra);
        }
        let Some(first) = rec.samples.iter().position(|s| s.experiment.is_some()) else { continue };
        let before = Recording { meta: rec.meta.clone(), samples: rec.samples[..first].to_vec() };
        let d = easycalib::diagnosis::diagnose(&before, &Default::default()).unwrap();
        let p = easycalib::plan::plan_for(
            &before,
            &d,
            easycalib::plan::PlanOptions { operator: true, experiment_sd: None },
        )
        .unwrap();
        print!("{}", easycalib::plan::report(&p));
        let spec = steps[0].spec;
        let (h0, h1) = (&p.hypotheses[0], &p.hypotheses[1]);
        let st = easycalib::plan::step_time(&before, spec.phase().kind());
        let (pa, pb) = easycalib::plan::predictions(&before, h0, h1, &spec, st).unwrap();
        let (qa, _) = easycalib::plan::predictions(&before, h0, h0, &spec, st).unwrap();
        let obs: Vec<_> =
            rec.samples[first..].iter().take_while(|s| s.experiment == rec.samples[first].experiment).collect();
        println!("noise g {} um t {} deg", d.noise.normal_um, d.noise.torsion_deg);
        println!("i  obs(g,t)  {}(g,t)  {}(g,t) selfcheck", h0.effects.join("+"), h1.effects.join("+"));
        for (i, ((a, b), q)) in pa.iter().zip(&pb).zip(&qa).enumerate() {
            let o = obs.get(i).map(|s| (s.gamma1_mm, s.theta1_deg, s.stage_mm, s.rot_deg));
            println!("{i:2} {o:?} | {:.5} {:?} | {:.5} {:?} | {:.5}", a.0, a.1, b.0, b.1, q.0);
        }
        let after = Recording { meta: rec.meta.clone(), samples: rec.samples[..first + obs.len()].to_vec() };
        let d2 = easycalib::diagnosis::diagnose(&after, &Default::default()).unwrap();
        let p2 = easycalib::plan::plan_for(
            &after,
            &d2,
            easycalib::plan::PlanOptions { operator: true, experiment_sd: None },
        )
        .unwrap();
        println!("AFTER: {}", p2.verdict);
        print!("{}", easycalib::plan::report(&p2));
    }
}

/// One rate study of `run --adaptive` on the emulated rig (issue 14, "Must
/// show"): over seeds 100-109, the runs whose headline names `effect` alone
/// with E1 within 1 % and nu1 within 2 % of the truth, and the median extra
/// rig time. Printed as RATE lines; returns (named, median extra s).
fn adaptive_rate(label: &str, effect: &str, profile: SimProfile) -> (usize, f64) {
    let script = Script {
        limits: easycalib::run::script::LimitsSection { max_gamma1_mm: 8.0, ..Default::default() },
        adaptive: easycalib::run::script::AdaptiveSection { enabled: true, ..Default::default() },
        ..Script::default()
    };
    let (mut named, mut extra) = (0, Vec::new());
    for seed in 100..110 {
        let (o, _) = emulated::run_script(seed, profile.clone(), script.clone());
        let ok = o.named == [effect] && o.corrected.0.abs() < 1.0 && o.corrected.1.abs() < 2.0;
        named += usize::from(ok);
        extra.push(o.adaptive.iter().map(|s| s.rig_time_s).sum::<f64>() + 0.0);
        println!(
            "{label} seed {seed}: {ok} {} {:?} E1 {:+.3} % nu1 {:+.3} % {:?}",
            o.verdict,
            o.named,
            o.corrected.0,
            o.corrected.1,
            o.adaptive.iter().map(|s| (s.name, s.rig_time_s, s.outcome.as_str())).collect::<Vec<_>>()
        );
    }
    extra.sort_by(f64::total_cmp);
    let median = 0.5 * (extra[4] + extra[5]);
    println!("RATE {label}: {effect} named alone within 1 %/2 % in {named}/10; median extra rig time {median:.1} s");
    (named, median)
}

/// Rotation backlash (lost motion of the mount, b 0.2 deg, engaged) with
/// `--adaptive`, seeds 100-109: named alone with E1 within 1 % and nu1
/// within 2 % in at least 9/10. `cargo test --release --test rig_experiments
/// rotation_backlash_rates -- --ignored --nocapture`.
#[test]
#[ignore = "a rate study (10 emulated runs)"]
fn rotation_backlash_rates_over_seeds() {
    let profile = SimProfile {
        rotation_backlash: Some(sim::effects::rotation_backlash::Params { b_deg: 0.2, engaged: true }),
        ..SimProfile::default()
    };
    let (named, _) = adaptive_rate("rotation_backlash", "rotation_backlash", profile);
    assert!(named >= 9, "{named}/10");
}

/// Partial slip at the contact's edge (mu 0.3) with `--adaptive`, seeds
/// 100-109: named alone with E1 within 1 % and nu1 within 2 % in at least
/// 9/10. `cargo test --release --test rig_experiments partial_slip_rates --
/// --ignored --nocapture`.
#[test]
#[ignore = "a rate study (10 emulated runs)"]
fn partial_slip_rates_over_seeds() {
    let profile =
        SimProfile { partial_slip: Some(sim::effects::partial_slip::Params { mu: 0.3 }), ..SimProfile::default() };
    let (named, _) = adaptive_rate("partial_slip", "partial_slip", profile);
    assert!(named >= 9, "{named}/10");
}

/// The slow repeat and the approach at another speed on the emulated rig
/// (real APT drivers over ptys, a creeping gel: rho 1.06, tau 8 s): each
/// step's samples sit under its phase, the slow repeat's waited its dwell
/// on the sensor's clock after each move, the approach's load moves ran at
/// the speed set through the APT driver (MOT_SET_VELPARAMS: their times in
/// the recording are the travel over 0.1 mm/s), and the speed was restored
/// (the reload after it moves at the stage's own 2.3 mm/s again). The
/// diagnosis of the whole recording names the creep; on a drifting frame
/// (2.5 um/s) the same run names the drift.
#[test]
fn a_slow_repeat_and_an_approach_at_another_speed_run_through_the_real_drivers() {
    for (truth, profile) in creep_drift::creep_and_drift() {
        slow_and_speed_run(truth, profile);
    }
}

fn slow_and_speed_run(truth: &str, profile: SimProfile) {
    let script = Script {
        experiment: vec![
            ExperimentSpec::SlowRepeat { fraction: 0.5, steps: 3, dwell_s: 8.0 },
            ExperimentSpec::ApproachSpeed { fraction: 0.5, steps: 4, speed_mm_s: 0.1 },
            ExperimentSpec::Reload { fraction: 0.5, steps: 2, cycles: 1 },
        ],
        ..Script::default()
    };
    let (out, rec) = emulated::run_script(7, profile, script);
    println!("{out:?}");
    let first = rec.samples.iter().position(|s| s.experiment.is_some()).expect("experiment samples");
    let mut order: Vec<Experiment> = rec.samples[first..].iter().map(|s| s.experiment.expect("in order")).collect();
    order.dedup();
    assert_eq!(order, [Experiment::SlowRepeat, Experiment::ApproachSpeed, Experiment::Reload]);
    let of = |e: Experiment| rec.samples.iter().filter(move |s| s.experiment == Some(e)).collect::<Vec<_>>();
    let torsion_stage = rec.sweep(Phase::Torsion).last().expect("torsion sweep").stage_mm;
    let moved = stage_zero_moved_mm(&rec);

    // Slow repeat: out to half the travel, back in three steps, each sample
    // at least the dwell after its move ended.
    let slow = of(Experiment::SlowRepeat);
    assert_eq!(slow.len(), 4);
    let top = torsion_stage + moved;
    assert!((slow[0].stage_mm + moved - 0.5 * top).abs() < 0.002, "{} of {top}", slow[0].stage_mm + moved);
    // Back at the torsion depth; on the drifting frame the gel passed the
    // depth limit there since (the drift pressed on through the torsion
    // sweep), so the return stops short of it, where the limit allows.
    if truth == "thermal_drift" {
        let short = torsion_stage - slow[3].stage_mm;
        assert!((-1e-3..0.3).contains(&short), "{short} mm short of the torsion depth {torsion_stage}");
    } else {
        assert!((slow[3].stage_mm - torsion_stage).abs() < 1e-3);
    }
    let waits: Vec<f64> = slow.iter().filter_map(|s| s.timing.move_s.map(|(_, end)| s.t_s - end)).collect();
    println!("{truth}: slow repeat, waited after each move {waits:?} s");
    for s in &slow {
        let (_, end) = s.timing.move_s.expect("each stop follows a move");
        assert!(s.t_s - end >= 8.0 && s.t_s - end < 12.0, "waited {} s", s.t_s - end);
    }

    // Approach at 0.1 mm/s: the out move at the stage's speed, the four load moves slow.
    let fast = of(Experiment::ApproachSpeed);
    assert_eq!(fast.len(), 5);
    let took = |s: &sim::recording::Sample| s.timing.move_s.map(|(a, b)| b - a).expect("timed move");
    let moves: Vec<(f64, f64)> = fast.windows(2).map(|w| (w[1].stage_mm - w[0].stage_mm, took(w[1]))).collect();
    println!("{truth}: approach at 0.1 mm/s, out in {} s, load moves (mm, s) {moves:?}", took(fast[0]));
    // Out by half the travel (2.5-2.9 mm here): 1.7-1.8 s at the stage's own
    // speed, 25 s or more at the experiment's. The emulated clock is wall
    // time sped up 40 times, so a loaded machine stretches it (2.0 s seen);
    // a third of the slow move's time still tells the two apart.
    let i0 = rec.samples.iter().position(|s| s.experiment == Some(Experiment::ApproachSpeed)).expect("its samples");
    let out_mm = (rec.samples[i0].stage_mm - rec.samples[i0 - 1].stage_mm).abs();
    assert!(took(fast[0]) < out_mm / 0.1 / 3.0, "out by {out_mm} mm at the usual speed: {} s", took(fast[0]));
    for w in fast.windows(2) {
        let travel = w[1].stage_mm - w[0].stage_mm;
        let expect = travel / 0.1;
        assert!(travel > 0.1 && (took(w[1]) - expect).abs() < 0.1 * expect + 0.5, "{travel} mm in {} s", took(w[1]));
    }
    // The reload after it: the stage's own speed again. Its moves are a
    // quarter of the travel (about 1.25 mm here): 1.1-1.3 s at the stage's
    // speed, 12 s or more at the experiment's; the wall clock of a loaded
    // machine stretches them (1.7 s seen in CI), so, as for the out move, a
    // third of the slow move's time tells the two apart.
    for w in rec.samples.windows(2).filter(|w| w[1].experiment == Some(Experiment::Reload)) {
        let travel = (w[1].stage_mm - w[0].stage_mm).abs();
        assert!(
            took(&w[1]) < travel / 0.1 / 3.0,
            "the reload's move of {travel} mm took {} s: the speed was not restored",
            took(&w[1])
        );
    }
    assert_eq!(out.named, [truth], "{out:?}");
    assert!(out.corrected.0.abs() < 1.0 && out.corrected.1.abs() < 2.0, "{out:?}");
}

/// Creep (rho 1.06, tau 8 s) and thermal drift (2.5 um/s) with `--adaptive`,
/// seeds 100-109, the slow repeat and the approach at another speed among
/// the plan's candidates: each named alone with E1 within 1 % and nu1
/// within 2 % in at least 9/10, and what the loop ran printed (the standard
/// sweeps name both, so nothing is left to separate). `cargo test --release
/// --test rig_experiments creep_and_drift_rates -- --ignored --nocapture`.
#[test]
#[ignore = "a rate study (20 emulated runs)"]
fn creep_and_drift_rates_over_seeds() {
    let [(_, creep), (_, drift)] = creep_drift::creep_and_drift();
    let (c, _) = adaptive_rate("viscoelastic", "viscoelastic", creep);
    let (d, _) = adaptive_rate("thermal_drift", "thermal_drift", drift);
    assert!(c >= 9 && d >= 9, "creep {c}/10, drift {d}/10");
}
